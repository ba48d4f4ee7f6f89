//! The box pipeline: world-space box corners through the frame's view-projection (a push
//! constant), depth test *or-equal* towards the eye with a small bias towards it, no writes, for
//! the host's attachment formats (dynamic rendering) or the host's render pass.

use std::ffi::CStr;

use ash::vk;
use coherent_cull::{DepthConvention, Error, Result};

use crate::{vk_err, QUERY_BOX_VERT_SPV};

/// How the host renders, for [`BoxPipeline::new`].
#[derive(Clone, Debug)]
pub struct BoxPipelineDesc {
    /// Depth attachment format of the host's depth pass.
    pub depth_format: vk::Format,
    /// Color attachment formats of the host's depth pass (the box pipeline writes none).
    pub color_formats: Vec<vk::Format>,
    /// Rasterization samples of the host's attachments.
    pub samples: vk::SampleCountFlags,
    /// View mask of the host's rendering (0 without multiview).
    pub view_mask: u32,
    /// The host's depth convention: which depth compare and bias face the eye.
    pub depth: DepthConvention,
    /// The winding of a box face seen from outside, as the host's viewport shows it
    /// ([`crate::BOX_FACES`] winds counter-clockwise seen from outside in world space): with it,
    /// back faces are culled, which halves the boxes' fill and needs the eye outside every
    /// queried box (the culler draws a node whose box holds the eye instead of querying it).
    /// `None` draws both faces.
    pub cull_back_faces: Option<vk::FrontFace>,
    /// The host's pipeline layout, whose push constants hold the column-major
    /// world-to-clip matrix at offset 0 for the vertex stage (then the box pipeline shares the
    /// host's push block and never pushes). `None`: a layout of its own, pushed at each
    /// [`crate::QuerySet::bind`].
    pub layout: Option<vk::PipelineLayout>,
    /// The host's render pass, for a host that renders its depth pass in a `VkRenderPass`
    /// instead of with dynamic rendering: the pipeline is made for its subpass `subpass`
    /// (`color_formats` then gives only the number of the subpass's color attachments; the
    /// render pass holds the formats, samples and view mask). Null (the default): dynamic
    /// rendering.
    pub render_pass: vk::RenderPass,
    /// The subpass of `render_pass` the boxes are drawn in.
    pub subpass: u32,
}

impl Default for BoxPipelineDesc {
    fn default() -> Self {
        BoxPipelineDesc {
            depth_format: vk::Format::D32_SFLOAT,
            color_formats: Vec::new(),
            samples: vk::SampleCountFlags::TYPE_1,
            view_mask: 0,
            depth: DepthConvention::REVERSE_Z_INFINITE,
            cull_back_faces: None,
            layout: None,
            render_pass: vk::RenderPass::null(),
            subpass: 0,
        }
    }
}

/// The pipeline query boxes are drawn with, built from the SPIR-V shipped in this crate.
pub struct BoxPipeline {
    device: ash::Device,
    /// A layout of its own (destroyed with the pipeline), or null with the host's.
    own_layout: vk::PipelineLayout,
    layout: vk::PipelineLayout,
    pipeline: vk::Pipeline,
}

impl BoxPipeline {
    /// Creates the pipeline (and its layout, unless the host's is given) for `desc`'s formats,
    /// depth convention and culling.
    ///
    /// # Safety
    /// `device` is valid, with dynamic rendering enabled unless `desc.render_pass` is set, and
    /// outlives the pipeline; a host layout or render pass in `desc` was made on it and
    /// outlives the pipeline.
    pub unsafe fn new(device: &ash::Device, desc: &BoxPipelineDesc) -> Result<BoxPipeline> {
        let words = spirv_words(QUERY_BOX_VERT_SPV)?;
        let mut out = BoxPipeline {
            device: device.clone(),
            own_layout: vk::PipelineLayout::null(),
            layout: vk::PipelineLayout::null(),
            pipeline: vk::Pipeline::null(),
        };
        let push = [vk::PushConstantRange::default()
            .stage_flags(vk::ShaderStageFlags::VERTEX)
            .offset(0)
            .size(64)];
        // SAFETY: valid device and create infos; what was created is destroyed when `out` is
        // dropped on an error.
        unsafe {
            out.layout = match desc.layout {
                Some(layout) => layout,
                None => {
                    out.own_layout = device
                        .create_pipeline_layout(
                            &vk::PipelineLayoutCreateInfo::default().push_constant_ranges(&push),
                            None,
                        )
                        .map_err(vk_err("vkCreatePipelineLayout"))?;
                    out.own_layout
                }
            };
            let module = device
                .create_shader_module(&vk::ShaderModuleCreateInfo::default().code(&words), None)
                .map_err(vk_err("vkCreateShaderModule"))?;
            let made = out.create_pipeline(device, desc, module);
            device.destroy_shader_module(module, None);
            out.pipeline = made?;
        }
        Ok(out)
    }

    /// The pipeline handle (a host that tracks its bound pipeline compares it).
    pub fn handle(&self) -> vk::Pipeline {
        self.pipeline
    }

    unsafe fn create_pipeline(
        &self,
        device: &ash::Device,
        desc: &BoxPipelineDesc,
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
        // report more pixels, never fewer. Both faces are drawn unless the host says how its
        // viewport shows the boxes' winding.
        let towards_eye = if desc.depth.reverse_z { 1.0 } else { -1.0 };
        let (cull, front) = match desc.cull_back_faces {
            Some(front) => (vk::CullModeFlags::BACK, front),
            None => (vk::CullModeFlags::NONE, vk::FrontFace::COUNTER_CLOCKWISE),
        };
        let raster = vk::PipelineRasterizationStateCreateInfo::default()
            .polygon_mode(vk::PolygonMode::FILL)
            .cull_mode(cull)
            .front_face(front)
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
        let mut info = vk::GraphicsPipelineCreateInfo::default()
            .stages(&stages)
            .vertex_input_state(&vertex_input)
            .input_assembly_state(&assembly)
            .viewport_state(&viewport)
            .rasterization_state(&raster)
            .multisample_state(&multisample)
            .depth_stencil_state(&depth)
            .color_blend_state(&blend)
            .dynamic_state(&dynamic)
            .layout(self.layout);
        info = if desc.render_pass == vk::RenderPass::null() {
            info.push_next(&mut rendering)
        } else {
            info.render_pass(desc.render_pass).subpass(desc.subpass)
        };
        // SAFETY: valid device and create info.
        let pipelines =
            unsafe { device.create_graphics_pipelines(vk::PipelineCache::null(), &[info], None) };
        match pipelines {
            Ok(p) => Ok(p[0]),
            Err((_, e)) => Err(vk_err("vkCreateGraphicsPipelines")(e)),
        }
    }

    /// Binds the pipeline and, with a layout of its own, pushes the view-projection.
    ///
    /// # Safety
    /// `cmd` is recording inside a rendering compatible with the pipeline, on `device`.
    pub(crate) unsafe fn bind(
        &self,
        device: &ash::Device,
        cmd: vk::CommandBuffer,
        view_proj: &[f32; 16],
    ) {
        // SAFETY: per the caller; the handles live as long as the pipeline.
        unsafe {
            device.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::GRAPHICS, self.pipeline);
            if self.own_layout != vk::PipelineLayout::null() {
                let mut push = [0u8; 64];
                for (i, v) in view_proj.iter().enumerate() {
                    push[4 * i..4 * i + 4].copy_from_slice(&v.to_ne_bytes());
                }
                device.cmd_push_constants(cmd, self.layout, vk::ShaderStageFlags::VERTEX, 0, &push);
            }
        }
    }
}

impl Drop for BoxPipeline {
    fn drop(&mut self) {
        // SAFETY: the owner drops the pipeline only once the device no longer uses it; null
        // handles are skipped.
        unsafe {
            if self.pipeline != vk::Pipeline::null() {
                self.device.destroy_pipeline(self.pipeline, None);
            }
            if self.own_layout != vk::PipelineLayout::null() {
                self.device.destroy_pipeline_layout(self.own_layout, None);
            }
        }
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
