//! `GiRenderer`: the GPU half of incremental instant radiosity. Owns the world-space scene
//! buffer, the layered shadow maps, the G-buffer and the pipelines, and renders one frame from a
//! spotlight and its VPLs: G-buffer, one layered shadow pass for the new VPLs (plus the
//! spotlight), the interleaved gather, and the resolve. With more VPL layers than the array
//! holds, VPLs are processed in chunks whose shadow maps are all re-rendered (the reference).

use std::collections::HashSet;
use std::sync::Arc;
use std::time::Instant;

use ash::vk;
use gpu_allocator::MemoryLocation;

use super::deferred::GBuffer;
use super::geometry::{WorldGeometry, VERTEX_FLOATS};
use super::ism::{self, ImperfectShadowMaps, IsmOptions};
use super::light::Spotlight;
use super::shadow::{ShadowMaps, ShadowPass, ShadowSlot};
use super::vpl::Vpl;
use crate::error::{Error, Result};
use crate::gpu::queries::QueryPools;
use crate::gpu::{
    as_bytes, shaders, targets, Binding, Buffer, CommandCounts, CommandPool, ComputePipeline,
    DescriptorSets, GpuContext, Image, ImageUse, OneShot, PipelineLayout, Recorder, Sampler,
    Timeline,
};
use crate::scene::camera::Camera;

/// Floats per VPL in the gather's storage buffer (three vec4).
const VPL_FLOATS: usize = 12;
/// Floats per shadow slot (two vec4).
const SLOT_FLOATS: usize = 8;
/// Graphics push block: view_proj, eye, params.
const GRAPHICS_PUSH: u32 = 96;
/// Longest triangle edge uploaded, as a fraction of the scene's diagonal.
pub const MAX_EDGE_FRACTION: f32 = 1.0 / 16.0;
/// The compute passes.
const GATHER: &[u8] = shaders::GI_GATHER_COMP;
const RESOLVE: &[u8] = shaders::GI_RESOLVE_COMP;
const BLUR: &[u8] = shaders::GI_BLUR_COMP;
/// Storage images of the compute passes (G-buffer 3, indirect, output, half position, half
/// normal, blurred).
const STORAGE_IMAGES: u32 = 8;
/// Compute push block: five vec4.
const COMPUTE_PUSH: u32 = 80;

/// What the resolve pass writes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum OutputMode {
    /// Direct plus indirect light.
    #[default]
    Full,
    /// Indirect light only (VPLs).
    IndirectOnly,
    /// Direct light only (spotlight).
    DirectOnly,
}

/// Sizes of a [`GiRenderer`].
#[derive(Clone, Copy, Debug)]
pub struct GiOptions {
    /// Output width.
    pub width: u32,
    /// Output height.
    pub height: u32,
    /// VPL layers of the shadow array (N; one more layer holds the spotlight's map).
    pub vpl_layers: u32,
    /// Most VPLs one frame may pass (more than `vpl_layers` means chunked rendering).
    pub max_vpls: u32,
    /// Width and height of each shadow map.
    pub shadow_size: u32,
}

/// What one GI frame cost.
#[derive(Clone, Debug, Default)]
pub struct GiFrame {
    /// Wall clock from the start of recording until the GPU finished.
    pub frame_ms: f64,
    /// VPL shadow maps rendered (from the triangles the recorder counted).
    pub shadow_maps_rendered: u32,
    /// VPL imperfect shadow maps built from points (every VPL's, in ism mode).
    pub ism_maps: u32,
    /// Shadow/gather chunks (1 unless the VPLs need more layers than the array has).
    pub chunks: u32,
    /// VPLs shaded.
    pub vpls: u32,
    /// GPU time of the G-buffer pass, ms (timestamps).
    pub gbuffer_ms: f64,
    /// GPU time of the shadow-map passes (spotlight and VPLs), ms.
    pub shadow_ms: f64,
    /// GPU time of the gather passes, ms.
    pub gather_ms: f64,
    /// GPU time of the blur of the gathered light, ms.
    pub blur_ms: f64,
    /// GPU time of the resolve pass, ms.
    pub resolve_ms: f64,
    /// Everything the recorder counted.
    pub counts: CommandCounts,
}

/// The GI renderer (see the module docs).
pub struct GiRenderer {
    ctx: Arc<GpuContext>,
    // The timeline is dropped first: it waits for the last frame.
    timeline: Timeline,
    commands: CommandPool,
    // Sets before the pipelines, pipelines and images before the layouts.
    descriptors: DescriptorSets,
    /// Imperfect shadow maps (the `ism` mode), or none.
    ism: Option<ImperfectShadowMaps>,
    /// The image the gather's ISM binding points at when there are none.
    ism_unused: Option<Image>,
    gather: ComputePipeline,
    blur: ComputePipeline,
    resolve: ComputePipeline,
    shadow: ShadowMaps,
    gbuffer: GBuffer,
    graphics_layout: PipelineLayout,
    compute_layout: PipelineLayout,
    #[allow(dead_code)] // owned here; the descriptor sets point at them
    sampler: Sampler,
    vertices: Buffer,
    slots: Buffer,
    vpl_buffer: Buffer,
    recorder: Recorder,
    /// Timestamps around the passes of a frame (see [`Stamp`]).
    timestamps: QueryPools,
    /// What each timestamp of the frame being recorded ends.
    stamps: Vec<Stamp>,
    oneshot: OneShot,
    vertex_count: u32,
    /// The vertex buffer's contents, kept while a pass draws it indexed (its indices are
    /// merged again after moves); empty otherwise.
    vertex_data: Vec<f32>,
    max_vpls: u32,
    max_slots: u32,
    /// Entries of the VPL buffer (indexed by layer).
    vpl_entries: u32,
    far: f32,
    /// What the resolve pass writes.
    pub output: OutputMode,
    /// Multiplier before tone mapping.
    pub exposure: f32,
    /// Geometry-term clamp distance (world units); see gi_gather.comp.
    pub clamp_distance: f32,
    /// Constant part of the shadow-lookup depth bias (world units).
    pub shadow_bias: f32,
    /// Receiver offset along its normal before shadow lookups (world units).
    pub normal_offset: f32,
    /// Largest plane distance between blurred neighbours (world units).
    pub blur_threshold: f32,
}

/// The pass a timestamp ends (the time since the previous timestamp is charged to it).
#[derive(Clone, Copy, Debug)]
enum Stamp {
    Start,
    GBuffer,
    Shadow,
    Gather,
    Blur,
    Resolve,
}

/// One chunk of a frame: the VPLs it gathers and the shadow maps it renders first.
struct Chunk {
    first_vpl: u32,
    vpl_count: u32,
    first_slot: u32,
    /// Layers (within the chunk) whose maps are rendered.
    layers: Vec<u32>,
    /// VPL slots after the spotlight's whose imperfect shadow maps are built (ISM only).
    ism_slots: u32,
}

impl GiRenderer {
    /// Uploads `geometry` and creates everything for `options`.
    pub fn new(
        ctx: &Arc<GpuContext>,
        geometry: &WorldGeometry,
        options: GiOptions,
    ) -> Result<GiRenderer> {
        Self::build(ctx, geometry, options, None)
    }

    /// Like [`GiRenderer::new`], with imperfect shadow maps for the VPLs: every frame rebuilds
    /// every VPL's map from the scene's surface points (see [`super::ism`]) instead of rendering
    /// the new VPLs' maps from triangles.
    pub fn with_ism(
        ctx: &Arc<GpuContext>,
        geometry: &WorldGeometry,
        options: GiOptions,
        ism: IsmOptions,
    ) -> Result<GiRenderer> {
        if options.max_vpls > options.vpl_layers {
            return Err(Error::Input(
                "imperfect shadow maps need every VPL in one chunk (max_vpls <= vpl_layers)".into(),
            ));
        }
        Self::build(ctx, geometry, options, Some(ism))
    }

    fn build(
        ctx: &Arc<GpuContext>,
        geometry: &WorldGeometry,
        options: GiOptions,
        ism_options: Option<IsmOptions>,
    ) -> Result<GiRenderer> {
        check_device(ctx, &options)?;
        let GpuGeometry {
            vertex_data,
            vertex_count,
            masks,
            textures,
        } = gpu_vertices(ctx, geometry)?;
        // The shaders pull every world-space vertex from one storage buffer: say so when a
        // scene is too large for the device's binding (lavapipe: 128 MiB, about 930,000
        // triangles).
        ctx.info.check_storage_buffer(
            &format!(
                "gi: {} world-space triangles (the scene's, long ones split; this device's \
                 binding holds {}) in one storage buffer",
                vertex_count / 3,
                u64::from(ctx.info.max_storage_buffer_range) / (3 * VERTEX_FLOATS as u64 * 4)
            ),
            vertex_data.len() as u64 * 4,
        )?;
        let (graphics_layout, compute_layout) = create_layouts(ctx)?;
        let mut shadow = ShadowMaps::new(
            ctx,
            &graphics_layout,
            options.vpl_layers,
            options.shadow_size,
        )?;
        let (ism, ism_unused) = create_ism(
            ctx,
            &graphics_layout,
            geometry,
            options.vpl_layers,
            ism_options,
        )?;
        let mut gbuffer = GBuffer::new(ctx, &graphics_layout, options.width, options.height)?;
        // Pulled by the shaders, and read as vertex attributes by the indexed G-buffer pass.
        let mut vertices = Buffer::new(
            ctx,
            "gi vertices",
            vertex_data.len() as u64 * 4,
            vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::VERTEX_BUFFER,
            MemoryLocation::CpuToGpu,
        )?;
        vertices.write(0, &as_bytes(&vertex_data))?;
        let max_vpls = options.max_vpls.max(options.vpl_layers);
        let max_slots = max_vpls + max_vpls.div_ceil(options.vpl_layers) + 1;
        let slots = host_storage(ctx, "gi shadow slots", max_slots as usize * SLOT_FLOATS)?;
        enable_masks(ctx, &masks, &mut shadow, &mut gbuffer, &vertices, &slots)?;
        if let Some(t) = &textures {
            let masks = shadow.mask_buffers();
            gbuffer.enable_textures(ctx, GRAPHICS_PUSH, (&vertices, &slots), masks, t)?;
        }
        shadow.enable_indexed(ctx, &graphics_layout, &vertex_data)?;
        gbuffer.enable_indexed(ctx, &graphics_layout, &vertex_data)?;
        let vertex_data = match shadow.indexed() || gbuffer.indexed() {
            true => vertex_data,
            false => Vec::new(),
        };
        // Entries are indexed by layer, a whole number of chunks of `vpl_layers`.
        let vpl_entries = max_vpls.div_ceil(options.vpl_layers) * options.vpl_layers;
        let vpl_buffer = host_storage(ctx, "gi vpls", vpl_entries as usize * VPL_FLOATS)?;
        let sampler = Sampler::nearest_clamp(ctx)?;
        let resources = Resources {
            vertices: &vertices,
            slots: &slots,
            vpls: &vpl_buffer,
            gbuffer: &gbuffer,
            shadow: &shadow,
            sampler: &sampler,
            ism: ism.as_ref(),
            ism_unused: ism_unused.as_ref(),
        };
        let descriptors = create_sets(ctx, &graphics_layout, &compute_layout, &resources)?;
        let diag = geometry.diagonal();
        Ok(GiRenderer {
            ctx: ctx.clone(),
            timeline: Timeline::new(ctx)?,
            commands: CommandPool::new(ctx)?,
            descriptors,
            ism,
            ism_unused,
            gather: ComputePipeline::new(ctx, &compute_layout, "gi gather", GATHER)?,
            blur: ComputePipeline::new(ctx, &compute_layout, "gi blur", BLUR)?,
            resolve: ComputePipeline::new(ctx, &compute_layout, "gi resolve", RESOLVE)?,
            shadow,
            gbuffer,
            graphics_layout,
            compute_layout,
            sampler,
            vertices,
            slots,
            vpl_buffer,
            recorder: Recorder::new(ctx),
            timestamps: QueryPools::new(ctx, vk::QueryType::TIMESTAMP, 64)?,
            stamps: Vec::new(),
            oneshot: OneShot::new(ctx)?,
            vertex_count,
            vertex_data,
            max_vpls,
            max_slots,
            vpl_entries,
            far: diag * 1.5,
            output: OutputMode::Full,
            exposure: 1.0,
            clamp_distance: 0.02 * diag,
            shadow_bias: 0.004 * diag,
            normal_offset: 0.002 * diag,
            blur_threshold: 0.01 * diag,
        })
    }

    /// Whether the shadow maps are drawn from the indexed mesh with fixed-function clipping
    /// (devices with `shaderClipDistance`, scenes without alpha masks).
    pub fn indexed_shadows(&self) -> bool {
        self.shadow.indexed()
    }

    /// Renders later shadow maps with the exact variant (clipping at each hemisphere's base
    /// plane in the vertex shader, as on devices without `shaderClipDistance`): slower; for
    /// comparing the two.
    pub fn use_exact_shadow_clipping(&mut self) -> Result<()> {
        self.shadow
            .use_exact_clipping(&self.ctx, &self.graphics_layout)
    }

    /// Whether VPL visibility comes from imperfect shadow maps.
    pub fn uses_ism(&self) -> bool {
        self.ism.is_some()
    }

    /// VPL layers of the shadow array.
    pub fn vpl_layers(&self) -> u32 {
        self.shadow.vpl_layers
    }

    /// Output size.
    pub fn size(&self) -> (u32, u32) {
        self.gbuffer.size
    }

    /// Triangles in the vertex buffer (after the long ones were split).
    pub fn triangle_count(&self) -> u32 {
        self.vertex_count / 3
    }

    /// Replaces triangles `first..` with `tail`'s (moving objects at their new places; with
    /// imperfect shadow maps, the points on them move too). Call between frames.
    pub fn move_triangles(&mut self, first: u32, tail: &WorldGeometry) -> Result<()> {
        if first as usize + tail.triangles.len() > self.triangle_count() as usize {
            return Err(Error::Input(format!(
                "{} moved triangles from {first} exceed the renderer's {}",
                tail.triangles.len(),
                self.triangle_count()
            )));
        }
        let offset = first as usize * 3 * VERTEX_FLOATS * 4;
        let moved = tail.gpu_vertices();
        self.vertices.write(offset, &as_bytes(&moved))?;
        if self.shadow.indexed() || self.gbuffer.indexed() {
            // The indexed passes merge identical vertices: the moved ones again (with each
            // other and with the unchanged vertices before them).
            let start = offset / 4;
            self.vertex_data[start..start + moved.len()].copy_from_slice(&moved);
            let first_vertex = first as usize * 3;
            self.shadow.reindex(&self.vertex_data, first_vertex)?;
            self.gbuffer.reindex(&self.vertex_data, first_vertex)?;
        }
        if let Some(ism) = &mut self.ism {
            ism.move_points(first, tail)?;
        }
        Ok(())
    }

    /// Renders one frame: G-buffer from `camera`; shadow maps for the spotlight and for the VPLs
    /// whose layer is in `new_layers` (all VPLs' maps when they span several chunks); gather of
    /// every VPL in `vpls`; resolve. Blocks until the GPU is done.
    pub fn frame(
        &mut self,
        light: &Spotlight,
        vpls: &[Vpl],
        new_layers: &[u32],
        camera: &Camera,
    ) -> Result<GiFrame> {
        let start = Instant::now();
        let chunks = self.upload_chunks(light, vpls, new_layers)?;
        self.commands.reset(&self.timeline)?;
        self.timestamps.reset();
        self.recorder.take_counts();
        self.recorder
            .set_command_buffer(self.commands.begin_next()?);
        self.stamp(Stamp::Start)?;
        let mut gpush = [0f32; 24];
        gpush[..16].copy_from_slice(&camera.view_proj().to_cols_array());
        gpush[16..19].copy_from_slice(&camera.eye.to_array());
        let (layout, set) = self
            .shadow
            .masked_set()
            .unwrap_or((&self.graphics_layout, self.descriptors.get(0)));
        self.gbuffer.record_gbuffer(
            &mut self.recorder,
            layout,
            set,
            &gpush,
            (&self.vertices, self.vertex_count),
        )?;
        self.stamp(Stamp::GBuffer)?;
        let mut cpush = self.compute_push(light);
        let mut maps = 0;
        for (c, chunk) in chunks.iter().enumerate() {
            maps += self.record_chunk(chunk, c > 0, &mut gpush, &mut cpush)?;
        }
        let ism_maps = chunks.iter().map(|c| c.ism_slots).sum();
        self.gbuffer
            .record_half_dispatch(&mut self.recorder, &self.blur)?;
        self.gbuffer.record_compute_barrier(&mut self.recorder);
        self.stamp(Stamp::Blur)?;
        self.gbuffer
            .record_dispatch(&mut self.recorder, &self.resolve)?;
        self.stamp(Stamp::Resolve)?;
        let submitted = self.timeline.submit(&mut self.recorder)?;
        self.timeline.wait(submitted)?;
        let frame_ms = start.elapsed().as_secs_f64() * 1e3;
        let mut frame = GiFrame {
            frame_ms,
            shadow_maps_rendered: maps,
            ism_maps,
            chunks: chunks.len() as u32,
            vpls: vpls.len() as u32,
            counts: self.recorder.take_counts(),
            ..GiFrame::default()
        };
        self.read_pass_times(&mut frame)?;
        Ok(frame)
    }

    /// Writes the next timestamp, recording which pass it ends.
    fn stamp(&mut self, stamp: Stamp) -> Result<()> {
        let id = self.timestamps.allocate()?;
        self.recorder.write_timestamp(&self.timestamps, id);
        self.stamps.push(stamp);
        Ok(())
    }

    /// Sums the time between consecutive timestamps into the pass each one ends.
    fn read_pass_times(&mut self, frame: &mut GiFrame) -> Result<()> {
        let tick_ms = f64::from(self.ctx.info.timestamp_period_ns) * 1e-6;
        let mut prev = None;
        for (id, stamp) in std::mem::take(&mut self.stamps).into_iter().enumerate() {
            // The frame was waited for: every timestamp is available.
            let Some(t) = self.timestamps.poll(id as u32)? else {
                continue;
            };
            let ms = prev.map_or(0.0, |p: u64| t.saturating_sub(p) as f64 * tick_ms);
            match stamp {
                Stamp::Start => {}
                Stamp::GBuffer => frame.gbuffer_ms += ms,
                Stamp::Shadow => frame.shadow_ms += ms,
                Stamp::Gather => frame.gather_ms += ms,
                Stamp::Blur => frame.blur_ms += ms,
                Stamp::Resolve => frame.resolve_ms += ms,
            }
            prev = Some(t);
        }
        Ok(())
    }

    /// Checks the VPLs against this renderer's capacity, splits them into chunks of at most
    /// `vpl_layers` layers, and writes their data and the shadow slots to the GPU buffers.
    fn upload_chunks(
        &mut self,
        light: &Spotlight,
        vpls: &[Vpl],
        new_layers: &[u32],
    ) -> Result<Vec<Chunk>> {
        let (cap, chunk_count) = self.check_capacity(vpls)?;
        let ism = self.ism.is_some();
        let new: HashSet<u32> = new_layers.iter().copied().collect();
        let spot = ShadowSlot {
            position: light.position,
            normal: light.axis(),
            layer: cap,
        };
        // The VPL buffer is indexed by layer, so a VPL's interleave class (its chunk-local
        // layer mod 16) stays the same for as long as it lives; free layers stay empty.
        let mut vpl_data = vec![0f32; (chunk_count * cap) as usize * VPL_FLOATS];
        let mut slot_data: Vec<f32> =
            Vec::with_capacity((vpls.len() + chunk_count as usize) * SLOT_FLOATS);
        let mut chunks = Vec::with_capacity(chunk_count as usize);
        for c in 0..chunk_count {
            let first_slot = (slot_data.len() / SLOT_FLOATS) as u32;
            let mut vpl_slots = Vec::new();
            let mut vpl_count = 0;
            for v in vpls.iter().filter(|v| v.layer / cap == c) {
                let local = v.layer - c * cap;
                let at = v.layer as usize * VPL_FLOATS;
                vpl_data[at..at + VPL_FLOATS].copy_from_slice(&vpl_floats(light, v, local, ism));
                vpl_count = vpl_count.max(local + 1);
                if ism || chunk_count > 1 || new.contains(&v.layer) {
                    vpl_slots.push(ShadowSlot {
                        position: v.position,
                        normal: v.normal,
                        layer: local,
                    });
                }
            }
            let (layers, ism_slots) = if ism {
                (Vec::new(), vpl_slots.len() as u32)
            } else {
                (vpl_slots.iter().map(|s| s.layer).collect(), 0)
            };
            // A staged pass renders into the staging image's layers 0 (spotlight), 1, 2, ..
            let staged = self.shadow.staged(layers.len());
            let spot_slot = ShadowSlot {
                layer: if staged { 0 } else { cap },
                ..spot
            };
            slot_data.extend_from_slice(&spot_slot.to_floats());
            for (i, slot) in vpl_slots.iter().enumerate() {
                let layer = if staged && !ism {
                    self.shadow.staged_layer(i)
                } else {
                    slot.layer
                };
                slot_data.extend_from_slice(&ShadowSlot { layer, ..*slot }.to_floats());
            }
            chunks.push(Chunk {
                first_vpl: c * cap,
                vpl_count,
                first_slot,
                layers,
                ism_slots,
            });
        }
        self.vpl_buffer.write(0, &as_bytes(&vpl_data))?;
        self.slots.write(0, &as_bytes(&slot_data))?;
        Ok(chunks)
    }

    /// Checks the VPLs against this renderer's capacity; returns the VPL layers of a chunk and
    /// the number of chunks the VPLs' layers need.
    fn check_capacity(&self, vpls: &[Vpl]) -> Result<(u32, u32)> {
        if vpls.len() > self.max_vpls as usize {
            return Err(Error::Input(format!(
                "{} VPLs exceed this renderer's {}",
                vpls.len(),
                self.max_vpls
            )));
        }
        let cap = self.shadow.vpl_layers;
        let max_layer = vpls.iter().map(|v| v.layer).max().unwrap_or(0);
        let chunk_count = max_layer / cap + 1;
        if chunk_count * cap > self.vpl_entries {
            return Err(Error::Input(format!(
                "VPL layer {max_layer} exceeds this renderer's {} VPL entries",
                self.vpl_entries
            )));
        }
        if vpls.len() as u32 + chunk_count > self.max_slots {
            return Err(Error::Input(format!(
                "VPL layers up to {max_layer} need too many chunks"
            )));
        }
        if self.ism.is_some() && chunk_count > 1 {
            return Err(Error::Input(format!(
                "VPL layer {max_layer} is beyond the imperfect shadow maps' {cap} layers"
            )));
        }
        Ok((cap, chunk_count))
    }

    /// The compute push block: spotlight, far distance, power, output mode and the biases;
    /// floats 12..16 (the chunk) are set per chunk.
    fn compute_push(&self, light: &Spotlight) -> [f32; 20] {
        let dir = light.axis();
        let mode = match self.output {
            OutputMode::Full => 0.0,
            OutputMode::IndirectOnly => 1.0,
            OutputMode::DirectOnly => 2.0,
        };
        let p = light.position;
        let mut cpush = [0f32; 20];
        cpush[..4].copy_from_slice(&[p.x, p.y, p.z, self.shadow.vpl_layers as f32]);
        cpush[4..8].copy_from_slice(&[dir.x, dir.y, dir.z, self.far]);
        cpush[8..12].copy_from_slice(&[light.power.x, light.power.y, light.power.z, mode]);
        cpush[16..20].copy_from_slice(&[
            self.shadow_bias,
            self.exposure,
            self.normal_offset,
            self.blur_threshold,
        ]);
        cpush
    }

    /// Records one chunk: its shadow maps, then the gather of its VPLs (accumulating onto the
    /// previous chunks' result when `accumulate`). Returns the VPL shadow maps rendered.
    fn record_chunk(
        &mut self,
        chunk: &Chunk,
        accumulate: bool,
        gpush: &mut [f32; 24],
        cpush: &mut [f32; 20],
    ) -> Result<u32> {
        let pass = ShadowPass {
            layout: &self.graphics_layout,
            set: self.descriptors.get(0),
            vertices: &self.vertices,
            vertex_count: self.vertex_count,
            far: self.far,
        };
        let maps = self.shadow.record(
            &mut self.recorder,
            &pass,
            gpush,
            chunk.first_slot,
            &chunk.layers,
        )?;
        match (&self.ism, &self.ism_unused) {
            (Some(ism), _) => ism.record(
                &mut self.recorder,
                &self.graphics_layout,
                (self.descriptors.get(2), self.descriptors.get(3)),
                gpush,
                (chunk.first_slot + 1, chunk.ism_slots),
                self.far,
            )?,
            (None, Some(unused)) => {
                // Never written: through GENERAL first, as an UNDEFINED -> read-only
                // transition is a best-practices warning (its contents are never sampled).
                self.recorder.transition(unused, ImageUse::ComputeRead);
                self.recorder.transition(unused, ImageUse::SampledByCompute)
            }
            (None, None) => {}
        }
        self.stamp(Stamp::Shadow)?;
        self.recorder
            .bind_compute_set(&self.compute_layout, self.descriptors.get(1));
        cpush[12..16].copy_from_slice(&[
            chunk.first_vpl as f32,
            chunk.vpl_count as f32,
            if accumulate { 1.0 } else { 0.0 },
            self.clamp_distance,
        ]);
        self.recorder
            .push_constants(&self.compute_layout, &as_bytes(&cpush[..]));
        self.gbuffer
            .record_half_dispatch(&mut self.recorder, &self.gather)?;
        self.gbuffer.record_compute_barrier(&mut self.recorder);
        self.stamp(Stamp::Gather)?;
        Ok(maps)
    }

    /// Reads the last frame's tone-mapped image as RGBA8 rows, top row first.
    pub fn read_output(&mut self) -> Result<Vec<u8>> {
        targets::read_image(
            &self.ctx,
            &mut self.oneshot,
            &mut self.recorder,
            &self.gbuffer.output,
        )
    }
}

/// The gather's three vec4 for one VPL: position and chunk-local layer, normal and 1 (an
/// occupied entry; free layers are all zero), flux and 1 if its visibility comes from the
/// imperfect shadow maps.
fn vpl_floats(light: &Spotlight, v: &Vpl, local_layer: u32, ism: bool) -> [f32; VPL_FLOATS] {
    let flux = light.power * v.weight * v.albedo;
    let (p, n) = (v.position, v.normal);
    [
        p.x,
        p.y,
        p.z,
        local_layer as f32,
        n.x,
        n.y,
        n.z,
        1.0,
        flux.x,
        flux.y,
        flux.z,
        if ism { 1.0 } else { 0.0 },
    ]
}

/// The graphics layout (set 0: world-space vertices, shadow slots) and the compute layout
/// (G-buffer position, normal, albedo; VPLs; shadow maps; indirect; output; half-resolution
/// position and normal; blurred indirect; imperfect shadow maps).
fn create_layouts(ctx: &Arc<GpuContext>) -> Result<(PipelineLayout, PipelineLayout)> {
    let storage = vk::DescriptorType::STORAGE_BUFFER;
    let image = vk::DescriptorType::STORAGE_IMAGE;
    let sampled = vk::DescriptorType::COMBINED_IMAGE_SAMPLER;
    let graphics = PipelineLayout::new(ctx, &[storage, storage], GRAPHICS_PUSH)?;
    let compute = PipelineLayout::new(
        ctx,
        &[
            image, image, image, storage, sampled, image, image, image, image, image, sampled,
        ],
        COMPUTE_PUSH,
    )?;
    Ok((graphics, compute))
}

/// What the descriptor sets point at.
struct Resources<'a> {
    vertices: &'a Buffer,
    slots: &'a Buffer,
    vpls: &'a Buffer,
    gbuffer: &'a GBuffer,
    shadow: &'a ShadowMaps,
    sampler: &'a Sampler,
    ism: Option<&'a ImperfectShadowMaps>,
    ism_unused: Option<&'a Image>,
}

/// Set 0: the graphics set (vertices, slots); set 1: the compute set (in the order of
/// [`create_layouts`]); with imperfect shadow maps, set 2: the splat set (points, slots) and
/// set 3: the pull-push set (splats sampled, maps as storage).
fn create_sets(
    ctx: &Arc<GpuContext>,
    graphics: &PipelineLayout,
    compute: &PipelineLayout,
    r: &Resources,
) -> Result<DescriptorSets> {
    let ism_maps = match (r.ism, r.ism_unused) {
        (Some(ism), _) => &ism.maps,
        (None, Some(unused)) => unused,
        (None, None) => return Err(Error::Input("GI needs an ISM map image".into())),
    };
    let g = r.gbuffer;
    let graphics_set = [
        Binding::StorageBuffer(r.vertices),
        Binding::StorageBuffer(r.slots),
    ];
    let compute_set = [
        Binding::StorageImage(&g.position),
        Binding::StorageImage(&g.normal),
        Binding::StorageImage(&g.albedo),
        Binding::StorageBuffer(r.vpls),
        Binding::Sampled(&r.shadow.image, r.sampler),
        Binding::StorageImage(&g.indirect),
        Binding::StorageImage(&g.output),
        Binding::StorageImage(&g.half_position),
        Binding::StorageImage(&g.half_normal),
        Binding::StorageImage(&g.blurred),
        Binding::Sampled(ism_maps, r.sampler),
    ];
    let Some(ism) = r.ism else {
        return DescriptorSets::new(ctx, &[(graphics, &graphics_set), (compute, &compute_set)]);
    };
    let splat_set = [
        Binding::StorageBuffer(&ism.points),
        Binding::StorageBuffer(r.slots),
    ];
    let pull_push_set = [
        Binding::Sampled(&ism.depth, r.sampler),
        Binding::StorageImage(&ism.maps),
    ];
    DescriptorSets::new(
        ctx,
        &[
            (graphics, &graphics_set),
            (compute, &compute_set),
            (graphics, &splat_set),
            (ism.pull_push_layout(), &pull_push_set),
        ],
    )
}

/// The imperfect shadow maps if `options` asks for them; without them, the unused image the
/// gather's ISM binding points at instead.
fn create_ism(
    ctx: &Arc<GpuContext>,
    graphics_layout: &PipelineLayout,
    geometry: &WorldGeometry,
    vpl_layers: u32,
    options: Option<IsmOptions>,
) -> Result<(Option<ImperfectShadowMaps>, Option<Image>)> {
    if let Some(o) = options {
        let ism = ImperfectShadowMaps::new(ctx, graphics_layout, geometry, vpl_layers, o)?;
        return Ok((Some(ism), None));
    }
    let unused = Image::new(
        ctx,
        "ism maps (unused)",
        ism::MAP_FORMAT,
        (1, 1),
        2,
        vk::ImageUsageFlags::SAMPLED,
    )?;
    Ok((None, Some(unused)))
}

/// The device limits the renderer relies on beyond the baseline, and its own inputs.
fn check_device(ctx: &GpuContext, options: &GiOptions) -> Result<()> {
    if options.vpl_layers == 0 || options.shadow_size == 0 {
        return Err(Error::Input(
            "GI needs at least one VPL layer and a non-empty shadow map".into(),
        ));
    }
    if ctx.info.max_per_stage_storage_images < STORAGE_IMAGES {
        return Err(Error::Unsupported {
            feature: format!(
                "{STORAGE_IMAGES} storage images in a compute shader (the device allows {})",
                ctx.info.max_per_stage_storage_images
            ),
        });
    }
    Ok(())
}

/// With `masks`, switches the shadow and G-buffer passes to their masked pipelines (which read
/// `vertices`, `slots` and the mask data); without, leaves them as they are.
fn enable_masks(
    ctx: &Arc<GpuContext>,
    masks: &Option<MaskData>,
    shadow: &mut ShadowMaps,
    gbuffer: &mut GBuffer,
    vertices: &Buffer,
    slots: &Buffer,
) -> Result<()> {
    let Some(masks) = masks else {
        return Ok(());
    };
    shadow.enable_masks(ctx, GRAPHICS_PUSH, vertices, slots, masks)?;
    if let Some((layout, _)) = shadow.masked_set() {
        gbuffer.enable_masks(ctx, layout)?;
    }
    Ok(())
}

/// What the masked shadow pass reads: a vec4 per GPU vertex and the packed mask images.
type MaskData = (Vec<f32>, Vec<u32>);

/// What the textured G-buffer pass reads: two vec4 per GPU vertex and the packed images.
type TextureData = (Vec<f32>, Vec<u32>);

/// The geometry as the renderer's passes read it (see [`gpu_vertices`]).
struct GpuGeometry {
    /// The shaders' vertex floats, [`VERTEX_FLOATS`] per vertex.
    vertex_data: Vec<f32>,
    vertex_count: u32,
    /// When triangles are alpha-masked, what the masked shadow pass reads (see
    /// `TriangleMasks::gpu_data`).
    masks: Option<MaskData>,
    /// When triangles are textured, what the textured G-buffer pass reads (see
    /// `TriangleTextures::gpu_data`; its images within the device's storage buffer range).
    textures: Option<TextureData>,
}

/// The geometry's triangles for the GPU, long triangles split so the paraboloid maps'
/// straight-edge error stays small.
fn gpu_vertices(ctx: &GpuContext, geometry: &WorldGeometry) -> Result<GpuGeometry> {
    let tessellated = geometry.tessellated(geometry.diagonal() * MAX_EDGE_FRACTION);
    let vertex_data = tessellated.gpu_vertices();
    let vertex_count = u32::try_from(vertex_data.len() / VERTEX_FLOATS)
        .map_err(|_| Error::Input("scene has too many triangles for GI".into()))?;
    let triangles = tessellated.triangles.len();
    let max_bytes = crate::gi::textures::MAX_BYTES.min(ctx.info.max_storage_buffer_range.into());
    Ok(GpuGeometry {
        vertex_data,
        vertex_count,
        masks: tessellated.masks.gpu_data(triangles),
        textures: tessellated.textures.gpu_data(triangles, max_bytes),
    })
}

/// A host-visible storage buffer of `floats` f32.
fn host_storage(ctx: &Arc<GpuContext>, name: &str, floats: usize) -> Result<Buffer> {
    Buffer::new(
        ctx,
        name,
        floats as u64 * 4,
        vk::BufferUsageFlags::STORAGE_BUFFER,
        MemoryLocation::CpuToGpu,
    )
}

impl Drop for GiRenderer {
    fn drop(&mut self) {
        // Nothing may be in flight when the fields (pools, sets, images) are destroyed.
        let _ = self.ctx.wait_idle();
    }
}
