//! `GiRenderer`: the GPU half of incremental instant radiosity. Owns the world-space scene
//! buffer, the layered shadow maps, the G-buffer and the pipelines, and renders one frame from a
//! spotlight and its VPLs: G-buffer, one layered shadow pass for the new VPLs (plus the
//! spotlight), the interleaved gather, and the resolve. With more VPL layers than the array
//! holds, VPLs are processed in chunks whose shadow maps are all re-rendered (the reference).

use std::collections::HashSet;
use std::sync::Arc;
use std::time::Instant;

use ash::vk;
use glam::Vec3;
use gpu_allocator::MemoryLocation;

use super::deferred::{ComputePipeline, GBuffer, GATHER_COMP, RESOLVE_COMP};
use super::geometry::{WorldGeometry, VERTEX_FLOATS};
use super::light::Spotlight;
use super::shadow::{ShadowMaps, ShadowSlot};
use super::vpl::Vpl;
use crate::error::{Error, Result, VkContext};
use crate::gpu::memory::Buffer;
use crate::gpu::pipelines::PipelineLayout;
use crate::gpu::{commands, targets, CommandCounts, GpuContext, OneShot, Recorder};
use crate::render::upload::as_bytes;
use crate::scene::camera::Camera;

/// Floats per VPL in the gather's storage buffer (three vec4).
const VPL_FLOATS: usize = 12;
/// Floats per shadow slot (two vec4).
const SLOT_FLOATS: usize = 8;
/// Graphics push block: view_proj, eye, params.
const GRAPHICS_PUSH: u32 = 96;
/// Longest triangle edge uploaded, as a fraction of the scene's diagonal.
const MAX_EDGE_FRACTION: f32 = 1.0 / 16.0;
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
    // Pipelines and images first: they are dropped before the layouts and after Drop::drop waited.
    gather: ComputePipeline,
    resolve: ComputePipeline,
    shadow: ShadowMaps,
    gbuffer: GBuffer,
    graphics_layout: PipelineLayout,
    compute_layout: PipelineLayout,
    vertices: Buffer,
    slots: Buffer,
    vpl_buffer: Buffer,
    sampler: vk::Sampler,
    descriptor_pool: vk::DescriptorPool,
    graphics_set: vk::DescriptorSet,
    compute_set: vk::DescriptorSet,
    command_pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
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
        // Long triangles are split so the paraboloid maps' straight-edge error stays small.
        let vertex_data = geometry
            .tessellated(geometry.diagonal() * MAX_EDGE_FRACTION)
            .gpu_vertices();
        let vertex_count = u32::try_from(vertex_data.len() / VERTEX_FLOATS)
            .map_err(|_| Error::Input("scene has too many triangles for GI".into()))?;
        let storage = vk::DescriptorType::STORAGE_BUFFER;
        let image = vk::DescriptorType::STORAGE_IMAGE;
        let graphics_layout = PipelineLayout::new(ctx, &[storage, storage], GRAPHICS_PUSH)?;
        let compute_layout = PipelineLayout::new(
            ctx,
            &[
                image,
                image,
                image,
                storage,
                vk::DescriptorType::COMBINED_IMAGE_SAMPLER,
                image,
                image,
            ],
            COMPUTE_PUSH,
        )?;
        let shadow = ShadowMaps::new(
            ctx,
            &graphics_layout,
            options.vpl_layers,
            options.shadow_size,
        )?;
        let gbuffer = GBuffer::new(ctx, &graphics_layout, options.width, options.height)?;
        let gather = ComputePipeline::new(ctx, &compute_layout, "gi gather", GATHER_COMP)?;
        let resolve = ComputePipeline::new(ctx, &compute_layout, "gi resolve", RESOLVE_COMP)?;
        let vertices = Buffer::with_data(
            ctx,
            "gi vertices",
            &as_bytes(&vertex_data),
            vk::BufferUsageFlags::STORAGE_BUFFER,
        )?;
        let max_vpls = options.max_vpls.max(options.vpl_layers);
        let max_slots = max_vpls + max_vpls.div_ceil(options.vpl_layers) + 1;
        let slots = Buffer::new(
            ctx,
            "gi shadow slots",
            max_slots as u64 * SLOT_FLOATS as u64 * 4,
            vk::BufferUsageFlags::STORAGE_BUFFER,
            MemoryLocation::CpuToGpu,
        )?;
        let vpl_buffer = Buffer::new(
            ctx,
            "gi vpls",
            max_vpls as u64 * VPL_FLOATS as u64 * 4,
            vk::BufferUsageFlags::STORAGE_BUFFER,
            MemoryLocation::CpuToGpu,
        )?;
        let far = geometry.diagonal() * 1.5;
        let diag = geometry.diagonal();
        let mut me = GiRenderer {
            ctx: ctx.clone(),
            gather,
            resolve,
            shadow,
            gbuffer,
            graphics_layout,
            compute_layout,
            vertices,
            slots,
            vpl_buffer,
            sampler: vk::Sampler::null(),
            descriptor_pool: vk::DescriptorPool::null(),
            graphics_set: vk::DescriptorSet::null(),
            compute_set: vk::DescriptorSet::null(),
            command_pool: vk::CommandPool::null(),
            cmd: vk::CommandBuffer::null(),
            fence: vk::Fence::null(),
            recorder: Recorder::new(ctx.device.clone()),
            oneshot: OneShot::new(ctx)?,
            vertex_count,
            max_vpls,
            max_slots,
            far,
            output: OutputMode::Full,
            exposure: 1.0,
            clamp_distance: 0.02 * diag,
            shadow_bias: 0.004 * diag,
            normal_offset: 0.002 * diag,
            blur_threshold: 0.01 * diag,
        };
        me.create_vulkan_objects()?;
        Ok(me)
    }

    /// Sampler, descriptor sets, command buffer and fence; on error, Drop frees what exists.
    fn create_vulkan_objects(&mut self) -> Result<()> {
        let d = &self.ctx.device;
        let sampler_info = vk::SamplerCreateInfo::default()
            .mag_filter(vk::Filter::NEAREST)
            .min_filter(vk::Filter::NEAREST)
            .mipmap_mode(vk::SamplerMipmapMode::NEAREST)
            .address_mode_u(vk::SamplerAddressMode::CLAMP_TO_EDGE)
            .address_mode_v(vk::SamplerAddressMode::CLAMP_TO_EDGE)
            .address_mode_w(vk::SamplerAddressMode::CLAMP_TO_EDGE)
            .max_lod(0.0);
        // SAFETY: valid device and create info.
        self.sampler = unsafe { d.create_sampler(&sampler_info, None) }.vk("vkCreateSampler")?;
        let sizes = [
            vk::DescriptorPoolSize {
                ty: vk::DescriptorType::STORAGE_BUFFER,
                descriptor_count: 3,
            },
            vk::DescriptorPoolSize {
                ty: vk::DescriptorType::STORAGE_IMAGE,
                descriptor_count: 5,
            },
            vk::DescriptorPoolSize {
                ty: vk::DescriptorType::COMBINED_IMAGE_SAMPLER,
                descriptor_count: 1,
            },
        ];
        let pool_info = vk::DescriptorPoolCreateInfo::default()
            .max_sets(2)
            .pool_sizes(&sizes);
        // SAFETY: valid device and create info.
        self.descriptor_pool =
            unsafe { d.create_descriptor_pool(&pool_info, None) }.vk("vkCreateDescriptorPool")?;
        let layouts = [
            self.graphics_layout.set_layout,
            self.compute_layout.set_layout,
        ];
        let alloc = vk::DescriptorSetAllocateInfo::default()
            .descriptor_pool(self.descriptor_pool)
            .set_layouts(&layouts);
        // SAFETY: the pool has room for both sets.
        let sets = unsafe { d.allocate_descriptor_sets(&alloc) }.vk("vkAllocateDescriptorSets")?;
        self.graphics_set = sets[0];
        self.compute_set = sets[1];
        let buffer = |b: &Buffer| {
            [vk::DescriptorBufferInfo {
                buffer: b.handle,
                offset: 0,
                range: vk::WHOLE_SIZE,
            }]
        };
        let storage_image = |view: vk::ImageView| {
            [vk::DescriptorImageInfo {
                sampler: vk::Sampler::null(),
                image_view: view,
                image_layout: vk::ImageLayout::GENERAL,
            }]
        };
        let (vb, sb, pb) = (
            buffer(&self.vertices),
            buffer(&self.slots),
            buffer(&self.vpl_buffer),
        );
        let g = &self.gbuffer;
        let imgs = [
            storage_image(g.position.view),
            storage_image(g.normal.view),
            storage_image(g.albedo.view),
            storage_image(g.indirect.view),
            storage_image(g.output.view),
        ];
        let shadow_info = [vk::DescriptorImageInfo {
            sampler: self.sampler,
            image_view: self.shadow.image.view,
            image_layout: vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL,
        }];
        let writes = [
            buf_write(self.graphics_set, 0, &vb),
            buf_write(self.graphics_set, 1, &sb),
            img_write(self.compute_set, 0, &imgs[0]),
            img_write(self.compute_set, 1, &imgs[1]),
            img_write(self.compute_set, 2, &imgs[2]),
            buf_write(self.compute_set, 3, &pb),
            vk::WriteDescriptorSet::default()
                .dst_set(self.compute_set)
                .dst_binding(4)
                .descriptor_type(vk::DescriptorType::COMBINED_IMAGE_SAMPLER)
                .image_info(&shadow_info),
            img_write(self.compute_set, 5, &imgs[3]),
            img_write(self.compute_set, 6, &imgs[4]),
        ];
        // SAFETY: the sets, buffers, views and sampler are valid and not in use.
        unsafe { d.update_descriptor_sets(&writes, &[]) };
        let pool_info = vk::CommandPoolCreateInfo::default()
            .queue_family_index(self.ctx.queue_family)
            .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER);
        // SAFETY: valid device.
        self.command_pool =
            unsafe { d.create_command_pool(&pool_info, None) }.vk("vkCreateCommandPool")?;
        let alloc = vk::CommandBufferAllocateInfo::default()
            .command_pool(self.command_pool)
            .level(vk::CommandBufferLevel::PRIMARY)
            .command_buffer_count(1);
        // SAFETY: valid pool.
        self.cmd = unsafe { d.allocate_command_buffers(&alloc) }.vk("vkAllocateCommandBuffers")?[0];
        // SAFETY: valid device.
        self.fence =
            unsafe { d.create_fence(&vk::FenceCreateInfo::default(), None) }.vk("vkCreateFence")?;
        Ok(())
    }

    /// VPL layers of the shadow array.
    pub fn vpl_layers(&self) -> u32 {
        self.shadow.vpl_layers
    }

    /// Output size.
    pub fn size(&self) -> (u32, u32) {
        (self.gbuffer.extent.width, self.gbuffer.extent.height)
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
        if vpls.len() > self.max_vpls as usize {
            return Err(Error::Input(format!(
                "{} VPLs exceed this renderer's {}",
                vpls.len(),
                self.max_vpls
            )));
        }
        let cap = self.shadow.vpl_layers;
        let max_layer = vpls.iter().map(|v| v.layer).max().unwrap_or(0);
        let chunks = max_layer / cap + 1;
        if vpls.len() as u32 + chunks > self.max_slots {
            return Err(Error::Input(format!(
                "VPL layers up to {max_layer} need too many chunks"
            )));
        }
        let new: HashSet<u32> = new_layers.iter().copied().collect();
        let dir = light.direction.try_normalize().unwrap_or(Vec3::NEG_Y);
        let spot = ShadowSlot {
            position: light.position,
            normal: dir,
            layer: cap,
        };
        let mut vpl_data: Vec<f32> = Vec::with_capacity(vpls.len() * VPL_FLOATS);
        let mut slot_data: Vec<f32> =
            Vec::with_capacity((vpls.len() + chunks as usize) * SLOT_FLOATS);
        // Per chunk: (first VPL, VPL count, first slot, layers to render).
        let mut plan = Vec::new();
        for c in 0..chunks {
            let first_vpl = (vpl_data.len() / VPL_FLOATS) as u32;
            let first_slot = (slot_data.len() / SLOT_FLOATS) as u32;
            slot_data.extend_from_slice(&spot.to_floats());
            let mut layers = Vec::new();
            for v in vpls.iter().filter(|v| v.layer / cap == c) {
                let local = v.layer - c * cap;
                let flux = light.power * v.weight * v.albedo;
                vpl_data.extend_from_slice(&[
                    v.position.x,
                    v.position.y,
                    v.position.z,
                    local as f32,
                ]);
                vpl_data.extend_from_slice(&[v.normal.x, v.normal.y, v.normal.z, 0.0]);
                vpl_data.extend_from_slice(&[flux.x, flux.y, flux.z, 0.0]);
                if chunks > 1 || new.contains(&v.layer) {
                    let slot = ShadowSlot {
                        position: v.position,
                        normal: v.normal,
                        layer: local,
                    };
                    slot_data.extend_from_slice(&slot.to_floats());
                    layers.push(local);
                }
            }
            let count = (vpl_data.len() / VPL_FLOATS) as u32 - first_vpl;
            plan.push((first_vpl, count, first_slot, layers));
        }
        if !vpl_data.is_empty() {
            self.vpl_buffer.write(0, &as_bytes(&vpl_data))?;
        }
        self.slots.write(0, &as_bytes(&slot_data))?;

        // Not in flight: the previous frame waited for its fence.
        commands::begin_one_time(&self.ctx.device, self.cmd, true)?;
        let d = &self.ctx.device;
        self.recorder.take_counts();
        self.recorder.set_command_buffer(self.cmd);
        let mut gpush = [0f32; 24];
        gpush[..16].copy_from_slice(&camera.view_proj().to_cols_array());
        gpush[16..19].copy_from_slice(&camera.eye.to_array());
        self.gbuffer.record_gbuffer(
            &mut self.recorder,
            &self.graphics_layout,
            self.graphics_set,
            &gpush,
            self.vertex_count,
        );
        let mode = match self.output {
            OutputMode::Full => 0.0,
            OutputMode::IndirectOnly => 1.0,
            OutputMode::DirectOnly => 2.0,
        };
        let mut cpush = [0f32; 20];
        cpush[..4].copy_from_slice(&[
            light.position.x,
            light.position.y,
            light.position.z,
            cap as f32,
        ]);
        cpush[4..8].copy_from_slice(&[dir.x, dir.y, dir.z, self.far]);
        cpush[8..12].copy_from_slice(&[light.power.x, light.power.y, light.power.z, mode]);
        cpush[16..20].copy_from_slice(&[
            self.shadow_bias,
            self.exposure,
            self.normal_offset,
            self.blur_threshold,
        ]);
        let stages = vk::ShaderStageFlags::VERTEX
            | vk::ShaderStageFlags::FRAGMENT
            | vk::ShaderStageFlags::COMPUTE;
        let mut maps = 0;
        for (c, (first_vpl, count, first_slot, layers)) in plan.iter().enumerate() {
            maps += self.shadow.record(
                &mut self.recorder,
                &self.graphics_layout,
                self.graphics_set,
                &mut gpush,
                *first_slot,
                layers,
                self.vertex_count,
                self.far,
            )?;
            self.recorder.bind_descriptor_set(
                vk::PipelineBindPoint::COMPUTE,
                self.compute_layout.handle,
                self.compute_set,
            );
            cpush[12..16].copy_from_slice(&[
                *first_vpl as f32,
                *count as f32,
                if c > 0 { 1.0 } else { 0.0 },
                self.clamp_distance,
            ]);
            self.recorder
                .push_constants(self.compute_layout.handle, stages, &as_bytes(&cpush));
            self.gbuffer
                .record_dispatch(&mut self.recorder, &self.gather);
            self.gbuffer.record_compute_barrier(&mut self.recorder);
        }
        self.gbuffer
            .record_dispatch(&mut self.recorder, &self.resolve);
        let cmds = [self.cmd];
        let submit = vk::SubmitInfo::default().command_buffers(&cmds);
        // SAFETY: recorded completely above; the fence is unsignaled.
        unsafe {
            d.end_command_buffer(self.cmd).vk("vkEndCommandBuffer")?;
            d.queue_submit(self.ctx.queue, &[submit], self.fence)
                .vk("vkQueueSubmit")?;
        }
        self.recorder.note_submit();
        // SAFETY: submitted with this fence just above.
        unsafe {
            d.wait_for_fences(&[self.fence], true, u64::MAX)
                .vk("vkWaitForFences")?;
            d.reset_fences(&[self.fence]).vk("vkResetFences")?;
        }
        let frame_ms = start.elapsed().as_secs_f64() * 1e3;
        Ok(GiFrame {
            frame_ms,
            shadow_maps_rendered: maps,
            chunks,
            vpls: vpls.len() as u32,
            counts: self.recorder.take_counts(),
        })
    }

    /// Reads the last frame's tone-mapped image as RGBA8 rows, top row first.
    pub fn read_output(&mut self) -> Result<Vec<u8>> {
        let (layout, stage, access) = GBuffer::output_state();
        targets::read_image(
            &self.ctx,
            &self.oneshot,
            &mut self.recorder,
            &self.gbuffer.output,
            layout,
            stage,
            access,
        )
    }
}

impl Drop for GiRenderer {
    fn drop(&mut self) {
        // SAFETY: after the device is idle nothing uses these objects; null handles are ignored.
        unsafe {
            let _ = self.ctx.device.device_wait_idle();
            self.ctx.device.destroy_fence(self.fence, None);
            self.ctx
                .device
                .destroy_command_pool(self.command_pool, None);
            self.ctx
                .device
                .destroy_descriptor_pool(self.descriptor_pool, None);
            self.ctx.device.destroy_sampler(self.sampler, None);
        }
    }
}

fn buf_write<'a>(
    set: vk::DescriptorSet,
    binding: u32,
    info: &'a [vk::DescriptorBufferInfo; 1],
) -> vk::WriteDescriptorSet<'a> {
    vk::WriteDescriptorSet::default()
        .dst_set(set)
        .dst_binding(binding)
        .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
        .buffer_info(info)
}

fn img_write<'a>(
    set: vk::DescriptorSet,
    binding: u32,
    info: &'a [vk::DescriptorImageInfo; 1],
) -> vk::WriteDescriptorSet<'a> {
    vk::WriteDescriptorSet::default()
        .dst_set(set)
        .dst_binding(binding)
        .descriptor_type(vk::DescriptorType::STORAGE_IMAGE)
        .image_info(info)
}
