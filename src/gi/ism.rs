//! Imperfect shadow maps (Ritschel et al. 2008): the scene as a fixed set of surface points,
//! sampled once (area-weighted); every frame each VPL's small paraboloid map is splatted from its
//! own subset of the points (point i belongs to VPL i mod n), all maps in one pass into one
//! layered depth image, then holes are filled by pull-push into a float map array that the
//! gather samples. Every map is rebuilt every frame, so moving geometry needs no bookkeeping.

use std::sync::Arc;

use ash::vk;
use glam::Vec3;
use gpu_allocator::MemoryLocation;

use super::geometry::WorldGeometry;
use crate::error::{Error, Result};
use crate::gpu::{
    as_bytes, shaders, Attachment, Buffer, ComputePipeline, DescriptorSet, GpuContext, Image,
    ImageUse, Load, Pipeline, PipelineDesc, PipelineKind, PipelineLayout, Recorder,
};
use crate::scene::mesh::Rng;

/// Depth format of the splatted maps.
const SPLAT_FORMAT: vk::Format = vk::Format::D32_SFLOAT;
/// Format of the hole-filled maps the gather samples.
pub const MAP_FORMAT: vk::Format = vk::Format::R32_SFLOAT;
/// Workgroup edge of the pull-push shader (one workgroup per map).
const PULL_PUSH_GROUP: u32 = 8;
/// Largest map edge the pull-push shader's shared-memory pyramid holds.
pub const MAX_MAP_SIZE: u32 = 32;
/// Shared memory the pull-push pyramid needs: values and weights of a 32² pyramid.
const PULL_PUSH_SHARED_BYTES: u32 = 2 * 4 * 1365;

/// Sizes of the imperfect shadow maps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IsmOptions {
    /// Edge of each VPL's map in texels (a power of two, at most [`MAX_MAP_SIZE`]).
    pub map_size: u32,
    /// Surface points splatted into each map.
    pub points_per_vpl: u32,
}

impl Default for IsmOptions {
    fn default() -> Self {
        IsmOptions {
            map_size: 32,
            points_per_vpl: 2048,
        }
    }
}

/// `count` points on the surfaces of `geometry`, area-weighted (uniform per unit area), in a
/// deterministic random order, as vec4 (w = 1); none on the masked-out texels of alpha masks.
/// Any contiguous or strided subset is itself a uniform sample of the surfaces.
pub fn sample_surface_points(geometry: &WorldGeometry, count: usize, seed: u64) -> Vec<[f32; 4]> {
    sample_surface(geometry, count, seed)
        .iter()
        .map(|s| s.point(geometry))
        .collect()
}

/// A surface point as its triangle and barycentric coordinates, so it follows the triangle
/// when it moves.
#[derive(Clone, Copy, Debug)]
pub struct SurfaceSample {
    /// Triangle index.
    pub triangle: u32,
    /// Weight of corner 1.
    pub a: f32,
    /// Weight of corner 2.
    pub b: f32,
}

impl SurfaceSample {
    /// The point on `geometry`'s triangle, as vec4 (w = 1).
    pub fn point(&self, geometry: &WorldGeometry) -> [f32; 4] {
        self.point_on(&geometry.triangles[self.triangle as usize])
    }

    /// The point on triangle `t`, as vec4 (w = 1).
    pub fn point_on(&self, t: &[Vec3; 3]) -> [f32; 4] {
        let p: Vec3 = t[0] + (t[1] - t[0]) * self.a + (t[2] - t[0]) * self.b;
        [p.x, p.y, p.z, 1.0]
    }
}

/// [`sample_surface_points`] as triangles and barycentric coordinates.
pub fn sample_surface(geometry: &WorldGeometry, count: usize, seed: u64) -> Vec<SurfaceSample> {
    let mut cumulative = Vec::with_capacity(geometry.triangles.len());
    let mut total = 0.0f64;
    for t in &geometry.triangles {
        total += f64::from(0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length());
        cumulative.push(total);
    }
    if total <= 0.0 {
        return Vec::new();
    }
    let mut rng = Rng::new(seed);
    // With alpha masks, samples on masked-out texels are drawn again (at most 16 draws per
    // point on average, so a scene that is nearly all holes gets fewer points); without, every
    // draw is kept, the same sequence as always.
    let masks = &geometry.masks;
    let draws = if masks.any() {
        count.saturating_mul(16)
    } else {
        count
    };
    let mut out = Vec::with_capacity(count);
    for _ in 0..draws {
        if out.len() == count {
            break;
        }
        let u = f64::from(rng.f32()) * total;
        let i = cumulative
            .partition_point(|&c| c <= u)
            .min(cumulative.len() - 1);
        let (mut a, mut b) = (rng.f32(), rng.f32());
        if a + b > 1.0 {
            (a, b) = (1.0 - a, 1.0 - b);
        }
        if masks.any() && !masks.keeps(i, a, b) {
            continue;
        }
        out.push(SurfaceSample {
            triangle: i as u32,
            a,
            b,
        });
    }
    out
}

/// The point buffer, the layered splat target, the hole-filled maps and their passes.
pub struct ImperfectShadowMaps {
    // Pipelines and sets before what they refer to.
    splat: Pipeline,
    pull_push: ComputePipeline,
    pull_push_layout: PipelineLayout,
    /// Layered depth image: one `map_size`² layer per VPL layer, splatted every frame.
    pub depth: Image,
    /// The hole-filled maps (R32F, one layer per VPL layer), sampled by the gather.
    pub maps: Image,
    /// Where the splats are rendered in chunks of layers when `depth` has more layers than one
    /// rendering may span (`maxFramebufferLayers`); each chunk is then copied into `depth`.
    staging: Option<Image>,
    /// The surface points (vec4 each).
    pub points: Buffer,
    /// Where each point lies (its triangle and barycentrics) and its current place, kept to
    /// move the points on moving objects.
    samples: Vec<SurfaceSample>,
    placed: Vec<[f32; 4]>,
    /// Points drawn per frame.
    pub point_count: u32,
    /// Edge of each map.
    pub map_size: u32,
    /// Layers (VPL layers; at least 2 so the views are arrays).
    pub layers: u32,
}

impl ImperfectShadowMaps {
    /// Samples `points_per_vpl * vpl_layers` points of `geometry` and creates the images and
    /// passes, after checking the device limits they rely on.
    pub fn new(
        ctx: &Arc<GpuContext>,
        graphics_layout: &PipelineLayout,
        geometry: &WorldGeometry,
        vpl_layers: u32,
        options: IsmOptions,
    ) -> Result<ImperfectShadowMaps> {
        let size = options.map_size;
        if !size.is_power_of_two() || !(4..=MAX_MAP_SIZE).contains(&size) {
            return Err(Error::Input(format!(
                "imperfect shadow maps must be 4 to {MAX_MAP_SIZE} texels, a power of two (got {size})"
            )));
        }
        check_limits(ctx, vpl_layers)?;
        let layers = vpl_layers.max(2);
        let count = u64::from(options.points_per_vpl) * u64::from(vpl_layers);
        let point_count = u32::try_from(count)
            .ok()
            .filter(|c| c.checked_mul(3).is_some())
            .ok_or_else(|| Error::Input(format!("{count} ISM points are too many")))?;
        let samples = sample_surface(geometry, point_count as usize, 0x15a);
        let data: Vec<[f32; 4]> = samples.iter().map(|s| s.point(geometry)).collect();
        let mut points = Buffer::new(
            ctx,
            "ism points",
            (data.len().max(1) * 16) as u64,
            vk::BufferUsageFlags::STORAGE_BUFFER,
            MemoryLocation::CpuToGpu,
        )?;
        if !data.is_empty() {
            points.write(0, &as_bytes(&data))?;
        }
        let storage = vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::SAMPLED;
        let attachment = vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT;
        let depth_use =
            attachment | vk::ImageUsageFlags::SAMPLED | vk::ImageUsageFlags::TRANSFER_DST;
        let extent = (size, size);
        let depth = Image::new(ctx, "ism splats", SPLAT_FORMAT, extent, layers, depth_use)?;
        let max_pass = ctx.info.max_framebuffer_layers;
        let staging = if layers > max_pass {
            let usage = attachment | vk::ImageUsageFlags::TRANSFER_SRC;
            let name = "ism splat staging";
            Some(Image::new(
                ctx,
                name,
                SPLAT_FORMAT,
                extent,
                max_pass,
                usage,
            )?)
        } else {
            None
        };
        let maps = Image::new(ctx, "ism maps", MAP_FORMAT, extent, layers, storage)?;
        let pull_push_layout = PipelineLayout::new(
            ctx,
            &[
                vk::DescriptorType::COMBINED_IMAGE_SAMPLER,
                vk::DescriptorType::STORAGE_IMAGE,
            ],
            16,
        )?;
        let pull_push = ComputePipeline::new(
            ctx,
            &pull_push_layout,
            "ism pull-push",
            shaders::GI_ISM_PULL_PUSH_COMP,
        )?;
        let splat = Pipeline::graphics(ctx, graphics_layout, &splat_desc())?;
        Ok(ImperfectShadowMaps {
            splat,
            pull_push,
            pull_push_layout,
            depth,
            maps,
            staging,
            points,
            point_count: data.len() as u32,
            samples,
            placed: data,
            map_size: size,
            layers,
        })
    }

    /// Moves the points on triangles `first..` to those triangles' places in `tail` (moving
    /// objects; their triangles are the last ones) and uploads them. Call between frames.
    pub fn move_points(&mut self, first: u32, tail: &WorldGeometry) -> Result<()> {
        let mut moved = false;
        for (s, p) in self.samples.iter().zip(self.placed.iter_mut()) {
            if let Some(t) = s.triangle.checked_sub(first) {
                let t = tail.triangles.get(t as usize).ok_or_else(|| {
                    Error::Input(format!(
                        "ISM point on triangle {} has no new place",
                        s.triangle
                    ))
                })?;
                *p = s.point_on(t);
                moved = true;
            }
        }
        if moved {
            self.points.write(0, &as_bytes(&self.placed))?;
        }
        Ok(())
    }

    /// The pull-push pass's layout (its set: the splats sampled, the maps as storage).
    pub fn pull_push_layout(&self) -> &PipelineLayout {
        &self.pull_push_layout
    }

    /// Records the splat of every point into its VPL's layer (`slots` = (first, count) of the
    /// slot buffer; `sets.0` binds the points and the slots in the graphics `layout`), then the
    /// pull-push (`sets.1`) into `maps`, left sampled by compute.
    pub fn record(
        &self,
        rec: &mut Recorder,
        layout: &PipelineLayout,
        sets: (DescriptorSet, DescriptorSet),
        push: &mut [f32; 24],
        slots: (u32, u32),
        far: f32,
    ) -> Result<()> {
        let (set, pull_push_set) = sets;
        let (first_slot, vpl_count) = slots;
        let splat = Splat {
            layout,
            set,
            first_slot,
            vpl_count,
            far,
        };
        // push[16] (eye.x, unused by the splat) and push[23] (params.w) carry the rendering's
        // layer count and first layer; restored afterwards for the other passes.
        let saved = (push[16], push[23]);
        match &self.staging {
            None => self.splat_layers(rec, &self.depth, &splat, push, (0, self.layers))?,
            Some(staging) => {
                let mut pairs = Vec::with_capacity(staging.layers as usize);
                for base in (0..self.layers).step_by(staging.layers as usize) {
                    let count = staging.layers.min(self.layers - base);
                    self.splat_layers(rec, staging, &splat, push, (base, count))?;
                    rec.transition(staging, ImageUse::TransferSrc);
                    rec.transition(&self.depth, ImageUse::TransferDst);
                    pairs.clear();
                    pairs.extend((0..count).map(|i| (i, base + i)));
                    rec.copy_layers(staging, &self.depth, &pairs)?;
                }
            }
        }
        (push[16], push[23]) = saved;
        rec.transition(&self.depth, ImageUse::SampledByCompute);
        rec.discard(&self.maps, ImageUse::ComputeReadWrite);
        rec.bind_compute_pipeline(&self.pull_push);
        rec.bind_compute_set(&self.pull_push_layout, pull_push_set);
        rec.dispatch("ism pull-push", self.layers, 1, 1)?;
        rec.transition(&self.maps, ImageUse::SampledByCompute);
        Ok(())
    }

    /// One layered rendering into `target` of the splats whose layer lies in `layers` =
    /// (first, count), drawn at target layer `layer - first` (the others are dropped by the
    /// shader).
    fn splat_layers(
        &self,
        rec: &mut Recorder,
        target: &Image,
        splat: &Splat,
        push: &mut [f32; 24],
        (first, count): (u32, u32),
    ) -> Result<()> {
        rec.discard(target, ImageUse::DepthAttachment);
        let depth = Attachment {
            image: target,
            load: Load::ClearDepth(1.0),
            store: true,
        };
        rec.begin_rendering(&[], Some(depth), count)?;
        if splat.vpl_count > 0 && self.point_count > 0 {
            rec.bind_pipeline(&self.splat);
            rec.bind_graphics_set(splat.layout, splat.set);
            push[16] = count as f32;
            push[19] = splat.vpl_count as f32;
            push[20] = splat.first_slot as f32;
            push[21] = splat.far;
            push[22] = self.map_size as f32;
            push[23] = first as f32;
            rec.push_constants(splat.layout, &as_bytes(&push[..]));
            rec.draw(self.point_count * 3, 1);
        }
        rec.end_rendering();
        Ok(())
    }
}

/// What one splat rendering draws: the graphics layout and set of the points and slots, the
/// slots used and the far distance.
struct Splat<'a> {
    layout: &'a PipelineLayout,
    set: DescriptorSet,
    first_slot: u32,
    vpl_count: u32,
    far: f32,
}

/// The device limits the maps rely on: an array of every VPL layer (rendered in chunks of at
/// most `maxFramebufferLayers` layers, at least 2), a 64-invocation workgroup and the pull-push
/// pyramid in shared memory.
fn check_limits(ctx: &GpuContext, vpl_layers: u32) -> Result<()> {
    let info = &ctx.info;
    if vpl_layers.max(2) > info.max_image_array_layers {
        return Err(Error::Input(format!(
            "{vpl_layers} imperfect shadow maps exceed the device's {} array layers",
            info.max_image_array_layers
        )));
    }
    if info.max_framebuffer_layers < 2 {
        return Err(Error::Unsupported {
            feature: format!(
                "layered rendering over 2 layers (the device's maxFramebufferLayers is {})",
                info.max_framebuffer_layers
            ),
        });
    }
    // Vulkan guarantees 128 invocations and 16 KiB of shared memory per workgroup; the
    // pull-push shader uses 64 and under 11 KiB, so no device lacks them.
    const _: () = assert!(PULL_PUSH_GROUP * PULL_PUSH_GROUP <= 128);
    const _: () = assert!(PULL_PUSH_SHARED_BYTES <= 16384);
    Ok(())
}

/// The splat pipeline: depth-only triangles (one small triangle per point), layered.
fn splat_desc() -> PipelineDesc<'static> {
    PipelineDesc {
        name: "ism splat",
        vert: shaders::GI_ISM_SPLAT_VERT,
        frag: None,
        vertex_stride: 0,
        attributes: &[],
        color_formats: &[],
        color_write: false,
        depth_format: SPLAT_FORMAT,
        depth_compare: vk::CompareOp::LESS,
        depth_write: true,
        cull: vk::CullModeFlags::NONE,
        kind: PipelineKind::Other,
        depth_bias: (0.0, 0.0),
        blend: false,
    }
}
