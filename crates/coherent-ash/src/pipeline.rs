//! The box pipeline: world-space box corners through the frame's view-projection (a push
//! constant), depth test *or-equal* towards the eye with a small bias towards it, no writes, for
//! the host's attachment formats (dynamic rendering).

use std::ffi::CStr;

use ash::vk;
use coherent_cull::{Error, Result};

use crate::{vk_err, QueryBackendDesc, QUERY_BOX_VERT_SPV};

/// The box pipeline and its layout.
pub(crate) struct BoxPipeline {
    layout: vk::PipelineLayout,
    pipeline: vk::Pipeline,
}

impl BoxPipeline {
    /// Owns nothing yet.
    pub fn null() -> BoxPipeline {
        BoxPipeline {
            layout: vk::PipelineLayout::null(),
            pipeline: vk::Pipeline::null(),
        }
    }

    /// Creates the layout and the pipeline for `desc`'s formats and depth convention.
    ///
    /// # Safety
    /// `device` is valid, with dynamic rendering enabled.
    pub unsafe fn new(device: &ash::Device, desc: &QueryBackendDesc) -> Result<BoxPipeline> {
        let words = spirv_words(QUERY_BOX_VERT_SPV)?;
        let mut out = BoxPipeline::null();
        let push = [vk::PushConstantRange::default()
            .stage_flags(vk::ShaderStageFlags::VERTEX)
            .offset(0)
            .size(64)];
        // SAFETY: valid device and create infos; everything created is destroyed on error.
        unsafe {
            out.layout = device
                .create_pipeline_layout(
                    &vk::PipelineLayoutCreateInfo::default().push_constant_ranges(&push),
                    None,
                )
                .map_err(vk_err("vkCreatePipelineLayout"))?;
            let module = match device
                .create_shader_module(&vk::ShaderModuleCreateInfo::default().code(&words), None)
            {
                Ok(m) => m,
                Err(e) => {
                    out.destroy(device);
                    return Err(vk_err("vkCreateShaderModule")(e));
                }
            };
            let made = out.create_pipeline(device, desc, module);
            device.destroy_shader_module(module, None);
            match made {
                Ok(p) => out.pipeline = p,
                Err(e) => {
                    out.destroy(device);
                    return Err(e);
                }
            }
        }
        Ok(out)
    }

    unsafe fn create_pipeline(
        &self,
        device: &ash::Device,
        desc: &QueryBackendDesc,
        module: vk::ShaderModule,
    ) -> Result<vk::Pipeline> {
        const MAIN: &CStr = c"main";
        let stages = [vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::VERTEX)
            .module(module)
            .name(MAIN)];
        let bindings = [vk::VertexInputBindingDescription::default()
            .binding(0)
            .stride(12)
            .input_rate(vk::VertexInputRate::VERTEX)];
        let attributes = [vk::VertexInputAttributeDescription::default()
            .location(0)
            .binding(0)
            .format(vk::Format::R32G32B32_SFLOAT)
            .offset(0)];
        let vertex_input = vk::PipelineVertexInputStateCreateInfo::default()
            .vertex_binding_descriptions(&bindings)
            .vertex_attribute_descriptions(&attributes);
        let assembly = vk::PipelineInputAssemblyStateCreateInfo::default()
            .topology(vk::PrimitiveTopology::TRIANGLE_LIST);
        let viewport = vk::PipelineViewportStateCreateInfo::default()
            .viewport_count(1)
            .scissor_count(1);
        // Towards the eye is smaller depth in the standard convention, larger in reverse-Z: a
        // box face lying on the surface it bounds then passes the test, so a query can only
        // report more pixels, never fewer. Both faces are drawn: the host's winding and
        // viewport orientation are not known here.
        let towards_eye = if desc.depth.reverse_z { 1.0 } else { -1.0 };
        let raster = vk::PipelineRasterizationStateCreateInfo::default()
            .polygon_mode(vk::PolygonMode::FILL)
            .cull_mode(vk::CullModeFlags::NONE)
            .front_face(vk::FrontFace::COUNTER_CLOCKWISE)
            .line_width(1.0)
            .depth_bias_enable(true)
            .depth_bias_constant_factor(4.0 * towards_eye)
            .depth_bias_slope_factor(towards_eye);
        let multisample =
            vk::PipelineMultisampleStateCreateInfo::default().rasterization_samples(desc.samples);
        let compare = if desc.depth.reverse_z {
            vk::CompareOp::GREATER_OR_EQUAL
        } else {
            vk::CompareOp::LESS_OR_EQUAL
        };
        let depth = vk::PipelineDepthStencilStateCreateInfo::default()
            .depth_test_enable(true)
            .depth_write_enable(false)
            .depth_compare_op(compare);
        let blend_attachments: Vec<_> = desc
            .color_formats
            .iter()
            .map(|_| {
                vk::PipelineColorBlendAttachmentState::default()
                    .color_write_mask(vk::ColorComponentFlags::empty())
            })
            .collect();
        let blend =
            vk::PipelineColorBlendStateCreateInfo::default().attachments(&blend_attachments);
        let dynamic_states = [vk::DynamicState::VIEWPORT, vk::DynamicState::SCISSOR];
        let dynamic = vk::PipelineDynamicStateCreateInfo::default().dynamic_states(&dynamic_states);
        let mut rendering = vk::PipelineRenderingCreateInfo::default()
            .view_mask(desc.view_mask)
            .color_attachment_formats(&desc.color_formats)
            .depth_attachment_format(desc.depth_format);
        let info = vk::GraphicsPipelineCreateInfo::default()
            .stages(&stages)
            .vertex_input_state(&vertex_input)
            .input_assembly_state(&assembly)
            .viewport_state(&viewport)
            .rasterization_state(&raster)
            .multisample_state(&multisample)
            .depth_stencil_state(&depth)
            .color_blend_state(&blend)
            .dynamic_state(&dynamic)
            .layout(self.layout)
            .push_next(&mut rendering);
        // SAFETY: valid device and create info.
        let pipelines =
            unsafe { device.create_graphics_pipelines(vk::PipelineCache::null(), &[info], None) };
        match pipelines {
            Ok(p) => Ok(p[0]),
            Err((_, e)) => Err(vk_err("vkCreateGraphicsPipelines")(e)),
        }
    }

    /// Binds the pipeline, pushes the view-projection and binds the box vertex and index
    /// buffers.
    ///
    /// # Safety
    /// `cmd` is recording inside a rendering compatible with the pipeline.
    pub unsafe fn bind(
        &self,
        device: &ash::Device,
        cmd: vk::CommandBuffer,
        view_proj: &[f32; 16],
        vertices: vk::Buffer,
        indices: vk::Buffer,
    ) {
        let mut push = [0u8; 64];
        for (i, v) in view_proj.iter().enumerate() {
            push[4 * i..4 * i + 4].copy_from_slice(&v.to_ne_bytes());
        }
        // SAFETY: per the caller; the handles live as long as the backend.
        unsafe {
            device.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::GRAPHICS, self.pipeline);
            device.cmd_push_constants(cmd, self.layout, vk::ShaderStageFlags::VERTEX, 0, &push);
            device.cmd_bind_vertex_buffers(cmd, 0, &[vertices], &[0]);
            device.cmd_bind_index_buffer(cmd, indices, 0, vk::IndexType::UINT32);
        }
    }

    /// Destroys the pipeline and its layout.
    ///
    /// # Safety
    /// The device no longer uses them.
    pub unsafe fn destroy(&mut self, device: &ash::Device) {
        // SAFETY: per the caller; null handles are skipped.
        unsafe {
            if self.pipeline != vk::Pipeline::null() {
                device.destroy_pipeline(self.pipeline, None);
            }
            if self.layout != vk::PipelineLayout::null() {
                device.destroy_pipeline_layout(self.layout, None);
            }
        }
        *self = BoxPipeline::null();
    }
}

/// The shipped SPIR-V as words (checked: a whole number of words, the SPIR-V magic).
fn spirv_words(bytes: &[u8]) -> Result<Vec<u32>> {
    if !bytes.len().is_multiple_of(4) || bytes.len() < 20 {
        return Err(Error::Input("the shipped box shader is not SPIR-V".into()));
    }
    let words: Vec<u32> = bytes
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    if words[0] != 0x0723_0203 {
        return Err(Error::Input("the shipped box shader is not SPIR-V".into()));
    }
    Ok(words)
}
