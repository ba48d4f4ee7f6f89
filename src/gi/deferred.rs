//! Deferred shading for GI: the G-buffer (world position, normal, albedo) rendered from the
//! camera, the interleaved VPL gather (compute), and the resolve pass (geometry-aware blur,
//! direct spotlight, tone mapping into RGBA8).

use std::sync::Arc;

use ash::vk;

use crate::error::{Result, VkContext};
use crate::gpu::commands::image_barrier;
use crate::gpu::memory::Image;
use crate::gpu::pipelines::{Pipeline, PipelineDesc, PipelineKind, PipelineLayout};
use crate::gpu::{shaders, targets, GpuContext, Recorder};

const GBUFFER_VERT: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/gi_gbuffer.vert.spv"));
const GBUFFER_FRAG: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/gi_gbuffer.frag.spv"));
/// The gather compute shader.
pub const GATHER_COMP: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/gi_gather.comp.spv"));
/// The resolve compute shader.
pub const RESOLVE_COMP: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/gi_resolve.comp.spv"));

/// G-buffer position and normal format (also the indirect accumulation format).
pub const FLOAT_FORMAT: vk::Format = vk::Format::R32G32B32A32_SFLOAT;
/// Albedo and output format.
pub const UNORM_FORMAT: vk::Format = vk::Format::R8G8B8A8_UNORM;
const DEPTH_FORMAT: vk::Format = vk::Format::D32_SFLOAT;

/// A compute pipeline (destroyed on drop).
pub struct ComputePipeline {
    ctx: Arc<GpuContext>,
    /// The pipeline handle.
    pub handle: vk::Pipeline,
}

impl ComputePipeline {
    /// Builds a compute pipeline from SPIR-V with `layout`.
    pub fn new(
        ctx: &Arc<GpuContext>,
        layout: &PipelineLayout,
        name: &str,
        spirv: &[u8],
    ) -> Result<ComputePipeline> {
        let module = shaders::module(ctx, name, spirv)?;
        let stage = vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::COMPUTE)
            .module(module)
            .name(c"main");
        let info = vk::ComputePipelineCreateInfo::default()
            .stage(stage)
            .layout(layout.handle);
        // SAFETY: valid module and layout; the info outlives the call.
        let result = unsafe {
            ctx.device
                .create_compute_pipelines(vk::PipelineCache::null(), &[info], None)
        };
        // SAFETY: the module is not needed once the pipeline exists (or failed).
        unsafe { ctx.device.destroy_shader_module(module, None) };
        let handle = result.map_err(|(_, e)| e).vk("vkCreateComputePipelines")?[0];
        Ok(ComputePipeline {
            ctx: ctx.clone(),
            handle,
        })
    }
}

impl Drop for ComputePipeline {
    fn drop(&mut self) {
        // SAFETY: the owner waits for the device before dropping.
        unsafe { self.ctx.device.destroy_pipeline(self.handle, None) };
    }
}

/// The G-buffer, the indirect-light accumulation image and the tone-mapped output.
pub struct GBuffer {
    gbuffer_pipeline: Pipeline,
    /// World position (w = 1 where a surface was hit).
    pub position: Image,
    /// World normal, facing the camera.
    pub normal: Image,
    /// Diffuse albedo.
    pub albedo: Image,
    /// Depth for the G-buffer pass.
    pub depth: Image,
    /// Interleaved indirect irradiance (gather output, resolve input).
    pub indirect: Image,
    /// Tone-mapped RGBA8 result.
    pub output: Image,
    /// Size.
    pub extent: vk::Extent2D,
}

const GENERAL_COMPUTE: (vk::ImageLayout, vk::PipelineStageFlags2, vk::AccessFlags2) = (
    vk::ImageLayout::GENERAL,
    vk::PipelineStageFlags2::COMPUTE_SHADER,
    vk::AccessFlags2::from_raw(
        vk::AccessFlags2::SHADER_STORAGE_READ.as_raw()
            | vk::AccessFlags2::SHADER_STORAGE_WRITE.as_raw(),
    ),
);
const UNDEFINED: (vk::ImageLayout, vk::PipelineStageFlags2, vk::AccessFlags2) = (
    vk::ImageLayout::UNDEFINED,
    vk::PipelineStageFlags2::NONE,
    vk::AccessFlags2::NONE,
);

impl GBuffer {
    /// Creates the images and the G-buffer pipeline (sharing the graphics `layout`).
    pub fn new(
        ctx: &Arc<GpuContext>,
        layout: &PipelineLayout,
        width: u32,
        height: u32,
    ) -> Result<GBuffer> {
        let extent = vk::Extent2D { width, height };
        let attach = vk::ImageUsageFlags::COLOR_ATTACHMENT | vk::ImageUsageFlags::STORAGE;
        let position = Image::new(ctx, "gbuffer position", FLOAT_FORMAT, extent, 1, attach)?;
        let normal = Image::new(ctx, "gbuffer normal", FLOAT_FORMAT, extent, 1, attach)?;
        let albedo = Image::new(ctx, "gbuffer albedo", UNORM_FORMAT, extent, 1, attach)?;
        let depth = Image::new(
            ctx,
            "gbuffer depth",
            DEPTH_FORMAT,
            extent,
            1,
            vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT,
        )?;
        let indirect = Image::new(
            ctx,
            "indirect",
            FLOAT_FORMAT,
            extent,
            1,
            vk::ImageUsageFlags::STORAGE,
        )?;
        let output = Image::new(
            ctx,
            "gi output",
            UNORM_FORMAT,
            extent,
            1,
            vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::TRANSFER_SRC,
        )?;
        let gbuffer_pipeline = Pipeline::graphics(
            ctx,
            layout,
            &PipelineDesc {
                name: "gi gbuffer",
                vert: GBUFFER_VERT,
                frag: Some(GBUFFER_FRAG),
                vertex_stride: 0,
                attributes: &[],
                color_formats: &[FLOAT_FORMAT, FLOAT_FORMAT, UNORM_FORMAT],
                color_write: true,
                depth_format: DEPTH_FORMAT,
                depth_compare: vk::CompareOp::LESS,
                depth_write: true,
                cull: vk::CullModeFlags::NONE,
                kind: PipelineKind::Other,
                depth_bias: (0.0, 0.0),
            },
        )?;
        Ok(GBuffer {
            gbuffer_pipeline,
            position,
            normal,
            albedo,
            depth,
            indirect,
            output,
            extent,
        })
    }

    /// Records the G-buffer pass (all `vertex_count` world-space vertices, pulled in the shader)
    /// and leaves its images, the indirect and the output image in GENERAL for compute.
    pub fn record_gbuffer(
        &self,
        rec: &mut Recorder,
        layout: &PipelineLayout,
        set: vk::DescriptorSet,
        push: &[f32; 24],
        vertex_count: u32,
    ) {
        let color = (
            vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL,
            vk::PipelineStageFlags2::COLOR_ATTACHMENT_OUTPUT,
            vk::AccessFlags2::COLOR_ATTACHMENT_WRITE,
        );
        let depth = (
            vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL,
            vk::PipelineStageFlags2::EARLY_FRAGMENT_TESTS
                | vk::PipelineStageFlags2::LATE_FRAGMENT_TESTS,
            vk::AccessFlags2::DEPTH_STENCIL_ATTACHMENT_WRITE
                | vk::AccessFlags2::DEPTH_STENCIL_ATTACHMENT_READ,
        );
        // Last frame's compute passes read these images: wait for them before overwriting.
        let prev = (
            vk::ImageLayout::UNDEFINED,
            vk::PipelineStageFlags2::COMPUTE_SHADER,
            vk::AccessFlags2::NONE,
        );
        rec.barrier(
            &[
                image_barrier(
                    self.position.handle,
                    self.position.full_range(),
                    prev,
                    color,
                ),
                image_barrier(self.normal.handle, self.normal.full_range(), prev, color),
                image_barrier(self.albedo.handle, self.albedo.full_range(), prev, color),
                image_barrier(self.depth.handle, self.depth.full_range(), UNDEFINED, depth),
                image_barrier(
                    self.indirect.handle,
                    self.indirect.full_range(),
                    prev,
                    GENERAL_COMPUTE,
                ),
                image_barrier(
                    self.output.handle,
                    self.output.full_range(),
                    UNDEFINED,
                    GENERAL_COMPUTE,
                ),
            ],
            &[],
        );
        let clear = vk::ClearValue {
            color: vk::ClearColorValue { float32: [0.0; 4] },
        };
        let atts: Vec<_> = [&self.position, &self.normal, &self.albedo]
            .iter()
            .map(|img| {
                vk::RenderingAttachmentInfo::default()
                    .image_view(img.view)
                    .image_layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)
                    .load_op(vk::AttachmentLoadOp::CLEAR)
                    .store_op(vk::AttachmentStoreOp::STORE)
                    .clear_value(clear)
            })
            .collect();
        let depth_att = targets::depth_attachment(
            self.depth.view,
            vk::AttachmentLoadOp::CLEAR,
            vk::AttachmentStoreOp::DONT_CARE,
        );
        let info = vk::RenderingInfo::default()
            .render_area(vk::Rect2D {
                offset: vk::Offset2D::default(),
                extent: self.extent,
            })
            .layer_count(1)
            .color_attachments(&atts)
            .depth_attachment(&depth_att);
        rec.begin_rendering(&info);
        rec.set_viewport(self.extent);
        rec.bind_pipeline(&self.gbuffer_pipeline);
        rec.bind_descriptor_set(vk::PipelineBindPoint::GRAPHICS, layout.handle, set);
        rec.push_constants(
            layout.handle,
            vk::ShaderStageFlags::VERTEX
                | vk::ShaderStageFlags::FRAGMENT
                | vk::ShaderStageFlags::COMPUTE,
            &crate::render::upload::as_bytes(&push[..]),
        );
        if vertex_count > 0 {
            rec.draw(vertex_count, 1);
        }
        rec.end_rendering();
        let general_read = (
            vk::ImageLayout::GENERAL,
            vk::PipelineStageFlags2::COMPUTE_SHADER,
            vk::AccessFlags2::SHADER_STORAGE_READ,
        );
        rec.barrier(
            &[
                image_barrier(
                    self.position.handle,
                    self.position.full_range(),
                    color,
                    general_read,
                ),
                image_barrier(
                    self.normal.handle,
                    self.normal.full_range(),
                    color,
                    general_read,
                ),
                image_barrier(
                    self.albedo.handle,
                    self.albedo.full_range(),
                    color,
                    general_read,
                ),
            ],
            &[],
        );
    }

    /// Barrier between two compute passes that read and write the indirect image.
    pub fn record_compute_barrier(&self, rec: &mut Recorder) {
        rec.barrier(
            &[image_barrier(
                self.indirect.handle,
                self.indirect.full_range(),
                GENERAL_COMPUTE,
                GENERAL_COMPUTE,
            )],
            &[],
        );
    }

    /// Dispatches `pipeline` over the image in 8x8 groups.
    pub fn record_dispatch(&self, rec: &mut Recorder, pipeline: &ComputePipeline) {
        rec.bind_compute_pipeline(pipeline.handle);
        rec.dispatch(
            self.extent.width.div_ceil(8),
            self.extent.height.div_ceil(8),
            1,
        );
    }

    /// The output's layout, stage and access after the resolve pass (for readback).
    pub fn output_state() -> (vk::ImageLayout, vk::PipelineStageFlags2, vk::AccessFlags2) {
        GENERAL_COMPUTE
    }
}
