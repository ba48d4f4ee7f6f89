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
use super::light::Spotlight;
use super::shadow::{ShadowMaps, ShadowPass, ShadowSlot};
use super::vpl::Vpl;
use crate::error::{Error, Result};
use crate::gpu::{
    as_bytes, shaders, targets, Binding, Buffer, CommandCounts, CommandPool, ComputePipeline,
    DescriptorSets, GpuContext, OneShot, PipelineLayout, Recorder, Sampler, Timeline,
};
use crate::scene::camera::Camera;

/// Floats per VPL in the gather's storage buffer (three vec4).
const VPL_FLOATS: usize = 12;
/// Floats per shadow slot (two vec4).
const SLOT_FLOATS: usize = 8;
/// Graphics push block: view_proj, eye, params.
const GRAPHICS_PUSH: u32 = 96;
/// Longest triangle edge uploaded, as a fraction of the scene's diagonal.
const MAX_EDGE_FRACTION: f32 = 1.0 / 16.0;
/// The compute passes.
const GATHER: &[u8] = shaders::GI_GATHER_COMP;
const RESOLVE: &[u8] = shaders::GI_RESOLVE_COMP;
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
    /// Shadow/gather chunks (1 unless the VPLs need more layers than the array has).
    pub chunks: u32,
    /// VPLs shaded.
    pub vpls: u32,
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
    gather: ComputePipeline,
    resolve: ComputePipeline,
    shadow: ShadowMaps,
    gbuffer: GBuffer,
    graphics_layout: PipelineLayout,
    compute_layout: PipelineLayout,
    #[allow(dead_code)] // owned here; the descriptor sets point at them
    sampler: Sampler,
    #[allow(dead_code)]
    vertices: Buffer,
    slots: Buffer,
    vpl_buffer: Buffer,
    recorder: Recorder,
    oneshot: OneShot,
    vertex_count: u32,
    max_vpls: u32,
    max_slots: u32,
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

/// One chunk of a frame: the VPLs it gathers and the shadow maps it renders first.
struct Chunk {
    first_vpl: u32,
    vpl_count: u32,
    first_slot: u32,
    /// Layers (within the chunk) whose maps are rendered.
    layers: Vec<u32>,
}

impl GiRenderer {
    /// Uploads `geometry` and creates everything for `options`.
    pub fn new(
        ctx: &Arc<GpuContext>,
        geometry: &WorldGeometry,
        options: GiOptions,
    ) -> Result<GiRenderer> {
        if options.vpl_layers == 0 || options.shadow_size == 0 {
            return Err(Error::Input(
                "GI needs at least one VPL layer and a non-empty shadow map".into(),
            ));
        }
        let (vertex_data, vertex_count) = gpu_vertices(geometry)?;
        let (graphics_layout, compute_layout) = create_layouts(ctx)?;
        let shadow = ShadowMaps::new(
            ctx,
            &graphics_layout,
            options.vpl_layers,
            options.shadow_size,
        )?;
        let gbuffer = GBuffer::new(ctx, &graphics_layout, options.width, options.height)?;
        let mut vertices = host_storage(ctx, "gi vertices", vertex_data.len())?;
        vertices.write(0, &as_bytes(&vertex_data))?;
        let max_vpls = options.max_vpls.max(options.vpl_layers);
        let max_slots = max_vpls + max_vpls.div_ceil(options.vpl_layers) + 1;
        let slots = host_storage(ctx, "gi shadow slots", max_slots as usize * SLOT_FLOATS)?;
        let vpl_buffer = host_storage(ctx, "gi vpls", max_vpls as usize * VPL_FLOATS)?;
        let sampler = Sampler::nearest_clamp(ctx)?;
        let descriptors = DescriptorSets::new(
            ctx,
            &[
                (
                    &graphics_layout,
                    &[
                        Binding::StorageBuffer(&vertices),
                        Binding::StorageBuffer(&slots),
                    ],
                ),
                (
                    &compute_layout,
                    &compute_bindings(&gbuffer, &vpl_buffer, &shadow, &sampler),
                ),
            ],
        )?;
        let diag = geometry.diagonal();
        Ok(GiRenderer {
            ctx: ctx.clone(),
            timeline: Timeline::new(ctx)?,
            commands: CommandPool::new(ctx)?,
            descriptors,
            gather: ComputePipeline::new(ctx, &compute_layout, "gi gather", GATHER)?,
            resolve: ComputePipeline::new(ctx, &compute_layout, "gi resolve", RESOLVE)?,
            shadow,
            gbuffer,
            graphics_layout,
            compute_layout,
            sampler,
            vertices,
            slots,
            vpl_buffer,
            recorder: Recorder::new(ctx.device.clone()),
            oneshot: OneShot::new(ctx)?,
            vertex_count,
            max_vpls,
            max_slots,
            far: diag * 1.5,
            output: OutputMode::Full,
            exposure: 1.0,
            clamp_distance: 0.02 * diag,
            shadow_bias: 0.004 * diag,
            normal_offset: 0.002 * diag,
            blur_threshold: 0.01 * diag,
        })
    }

    /// VPL layers of the shadow array.
    pub fn vpl_layers(&self) -> u32 {
        self.shadow.vpl_layers
    }

    /// Output size.
    pub fn size(&self) -> (u32, u32) {
        self.gbuffer.size
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
        self.recorder.take_counts();
        self.recorder
            .set_command_buffer(self.commands.begin_next()?);
        let mut gpush = [0f32; 24];
        gpush[..16].copy_from_slice(&camera.view_proj().to_cols_array());
        gpush[16..19].copy_from_slice(&camera.eye.to_array());
        self.gbuffer.record_gbuffer(
            &mut self.recorder,
            &self.graphics_layout,
            self.descriptors.get(0),
            &gpush,
            self.vertex_count,
        )?;
        let mut cpush = self.compute_push(light);
        let mut maps = 0;
        for (c, chunk) in chunks.iter().enumerate() {
            maps += self.record_chunk(chunk, c > 0, &mut gpush, &mut cpush)?;
        }
        self.gbuffer
            .record_dispatch(&mut self.recorder, &self.resolve);
        let submitted = self.timeline.submit(&mut self.recorder)?;
        self.timeline.wait(submitted)?;
        Ok(GiFrame {
            frame_ms: start.elapsed().as_secs_f64() * 1e3,
            shadow_maps_rendered: maps,
            chunks: chunks.len() as u32,
            vpls: vpls.len() as u32,
            counts: self.recorder.take_counts(),
        })
    }

    /// Checks the VPLs against this renderer's capacity, splits them into chunks of at most
    /// `vpl_layers` layers, and writes their data and the shadow slots to the GPU buffers.
    fn upload_chunks(
        &mut self,
        light: &Spotlight,
        vpls: &[Vpl],
        new_layers: &[u32],
    ) -> Result<Vec<Chunk>> {
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
        if vpls.len() as u32 + chunk_count > self.max_slots {
            return Err(Error::Input(format!(
                "VPL layers up to {max_layer} need too many chunks"
            )));
        }
        let new: HashSet<u32> = new_layers.iter().copied().collect();
        let spot = ShadowSlot {
            position: light.position,
            normal: light.axis(),
            layer: cap,
        };
        let mut vpl_data: Vec<f32> = Vec::with_capacity(vpls.len() * VPL_FLOATS);
        let mut slot_data: Vec<f32> =
            Vec::with_capacity((vpls.len() + chunk_count as usize) * SLOT_FLOATS);
        let mut chunks = Vec::with_capacity(chunk_count as usize);
        for c in 0..chunk_count {
            let first_vpl = (vpl_data.len() / VPL_FLOATS) as u32;
            let first_slot = (slot_data.len() / SLOT_FLOATS) as u32;
            slot_data.extend_from_slice(&spot.to_floats());
            let mut layers = Vec::new();
            for v in vpls.iter().filter(|v| v.layer / cap == c) {
                let local = v.layer - c * cap;
                vpl_data.extend_from_slice(&vpl_floats(light, v, local));
                if chunk_count > 1 || new.contains(&v.layer) {
                    let slot = ShadowSlot {
                        position: v.position,
                        normal: v.normal,
                        layer: local,
                    };
                    slot_data.extend_from_slice(&slot.to_floats());
                    layers.push(local);
                }
            }
            chunks.push(Chunk {
                first_vpl,
                vpl_count: (vpl_data.len() / VPL_FLOATS) as u32 - first_vpl,
                first_slot,
                layers,
            });
        }
        if !vpl_data.is_empty() {
            self.vpl_buffer.write(0, &as_bytes(&vpl_data))?;
        }
        self.slots.write(0, &as_bytes(&slot_data))?;
        Ok(chunks)
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
            .record_dispatch(&mut self.recorder, &self.gather);
        self.gbuffer.record_compute_barrier(&mut self.recorder);
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

/// The gather's three vec4 for one VPL: position and chunk-local layer, normal, flux.
fn vpl_floats(light: &Spotlight, v: &Vpl, local_layer: u32) -> [f32; VPL_FLOATS] {
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
        0.0,
        flux.x,
        flux.y,
        flux.z,
        0.0,
    ]
}

/// The graphics layout (set 0: world-space vertices, shadow slots) and the compute layout
/// (G-buffer position, normal, albedo; VPLs; shadow maps; indirect; output).
fn create_layouts(ctx: &Arc<GpuContext>) -> Result<(PipelineLayout, PipelineLayout)> {
    let storage = vk::DescriptorType::STORAGE_BUFFER;
    let image = vk::DescriptorType::STORAGE_IMAGE;
    let sampled = vk::DescriptorType::COMBINED_IMAGE_SAMPLER;
    let graphics = PipelineLayout::new(ctx, &[storage, storage], GRAPHICS_PUSH)?;
    let compute = PipelineLayout::new(
        ctx,
        &[image, image, image, storage, sampled, image, image],
        COMPUTE_PUSH,
    )?;
    Ok((graphics, compute))
}

/// The compute set's bindings, in the order of [`create_layouts`].
fn compute_bindings<'a>(
    gbuffer: &'a GBuffer,
    vpls: &'a Buffer,
    shadow: &'a ShadowMaps,
    sampler: &'a Sampler,
) -> [Binding<'a>; 7] {
    [
        Binding::StorageImage(&gbuffer.position),
        Binding::StorageImage(&gbuffer.normal),
        Binding::StorageImage(&gbuffer.albedo),
        Binding::StorageBuffer(vpls),
        Binding::Sampled(&shadow.image, sampler),
        Binding::StorageImage(&gbuffer.indirect),
        Binding::StorageImage(&gbuffer.output),
    ]
}

/// The geometry's triangles as the shaders' vertex floats, long triangles split so the
/// paraboloid maps' straight-edge error stays small; and the vertex count.
fn gpu_vertices(geometry: &WorldGeometry) -> Result<(Vec<f32>, u32)> {
    let data = geometry
        .tessellated(geometry.diagonal() * MAX_EDGE_FRACTION)
        .gpu_vertices();
    let count = u32::try_from(data.len() / VERTEX_FLOATS)
        .map_err(|_| Error::Input("scene has too many triangles for GI".into()))?;
    Ok((data, count))
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
