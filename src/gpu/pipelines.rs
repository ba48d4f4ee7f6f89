//! Explicit pipeline state objects for dynamic rendering, and the pipeline layout they share.

use std::sync::Arc;

use ash::vk;

use super::{shaders, GpuContext};
use crate::error::{Result, VkContext};

/// Which state a pipeline puts the command stream in: rendering geometry or issuing queries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PipelineKind {
    /// Shaded geometry (color and depth writes).
    Render,
    /// Occlusion-query boxes (depth test, no writes).
    Query,
    /// Anything else (ID pass, shadow maps, G-buffer...).
    Other,
}

/// A graphics pipeline description for dynamic rendering.
pub struct PipelineDesc<'a> {
    /// Debug name.
    pub name: &'a str,
    /// Vertex shader SPIR-V.
    pub vert: &'a [u8],
    /// Fragment shader SPIR-V (none for depth-only pipelines).
    pub frag: Option<&'a [u8]>,
    /// Stride of vertex binding 0.
    pub vertex_stride: u32,
    /// (location, format, offset) of each attribute in binding 0.
    pub attributes: &'a [(u32, vk::Format, u32)],
    /// Formats of the color attachments.
    pub color_formats: &'a [vk::Format],
    /// Whether color is written.
    pub color_write: bool,
    /// Depth attachment format (UNDEFINED for none).
    pub depth_format: vk::Format,
    /// Depth compare op (depth test is always on when there is a depth attachment).
    pub depth_compare: vk::CompareOp,
    /// Whether depth is written.
    pub depth_write: bool,
    /// Face culling.
    pub cull: vk::CullModeFlags,
    /// Whether it renders state or queries.
    pub kind: PipelineKind,
    /// Constant depth bias and slope factor (0 for none).
    pub depth_bias: (f32, f32),
    /// Whether color is blended over the attachment by the fragment's alpha (source alpha,
    /// one minus source alpha); else written as is.
    pub blend: bool,
}

/// A pipeline layout with one storage-buffer descriptor set and a push-constant range.
pub struct PipelineLayout {
    ctx: Arc<GpuContext>,
    /// The layout handle.
    pub handle: vk::PipelineLayout,
    /// Set 0's layout.
    pub set_layout: vk::DescriptorSetLayout,
    /// Push-constant bytes.
    pub push_size: u32,
    bindings: Vec<vk::DescriptorType>,
}

impl PipelineLayout {
    /// The stages every binding and the push-constant range are visible to.
    pub(crate) const STAGES: vk::ShaderStageFlags = vk::ShaderStageFlags::from_raw(
        vk::ShaderStageFlags::VERTEX.as_raw()
            | vk::ShaderStageFlags::FRAGMENT.as_raw()
            | vk::ShaderStageFlags::COMPUTE.as_raw(),
    );

    /// The descriptor types of set 0's bindings, in binding order.
    pub fn bindings(&self) -> &[vk::DescriptorType] {
        &self.bindings
    }

    /// Set 0: `bindings` storage buffers (vertex+fragment) or combined image samplers given by
    /// kind; push constants of `push_size` bytes for vertex and fragment stages.
    pub fn new(
        ctx: &Arc<GpuContext>,
        bindings: &[vk::DescriptorType],
        push_size: u32,
    ) -> Result<PipelineLayout> {
        ctx.info
            .check_push_constants("pipeline layout", push_size)?;
        let b: Vec<_> = bindings
            .iter()
            .enumerate()
            .map(|(i, &t)| {
                vk::DescriptorSetLayoutBinding::default()
                    .binding(i as u32)
                    .descriptor_type(t)
                    .descriptor_count(1)
                    .stage_flags(Self::STAGES)
            })
            .collect();
        let info = vk::DescriptorSetLayoutCreateInfo::default().bindings(&b);
        // SAFETY: valid device and create info.
        let set_layout = unsafe { ctx.device.create_descriptor_set_layout(&info, None) }
            .vk("vkCreateDescriptorSetLayout")?;
        let ranges = [vk::PushConstantRange::default()
            .stage_flags(Self::STAGES)
            .offset(0)
            .size(push_size)];
        let layouts = [set_layout];
        let info = vk::PipelineLayoutCreateInfo::default()
            .set_layouts(&layouts)
            .push_constant_ranges(&ranges);
        // SAFETY: valid device and create info.
        match unsafe { ctx.device.create_pipeline_layout(&info, None) } {
            Ok(handle) => Ok(PipelineLayout {
                ctx: ctx.clone(),
                handle,
                set_layout,
                push_size,
                bindings: bindings.to_vec(),
            }),
            Err(e) => {
                // SAFETY: created above, unused.
                unsafe { ctx.device.destroy_descriptor_set_layout(set_layout, None) };
                Err(crate::Error::Vulkan {
                    call: "vkCreatePipelineLayout",
                    result: e,
                })
            }
        }
    }
}

impl Drop for PipelineLayout {
    fn drop(&mut self) {
        // SAFETY: pipelines using this layout are gone before it (owners drop them first).
        unsafe {
            self.ctx.device.destroy_pipeline_layout(self.handle, None);
            self.ctx
                .device
                .destroy_descriptor_set_layout(self.set_layout, None);
        }
    }
}

/// A graphics pipeline.
pub struct Pipeline {
    ctx: Arc<GpuContext>,
    /// The pipeline handle.
    pub handle: vk::Pipeline,
    /// Render, query or other.
    pub kind: PipelineKind,
}

impl Pipeline {
    /// Builds a graphics pipeline for dynamic rendering with dynamic viewport and scissor.
    pub fn graphics(
        ctx: &Arc<GpuContext>,
        layout: &PipelineLayout,
        desc: &PipelineDesc,
    ) -> Result<Pipeline> {
        let vert = shaders::module(ctx, desc.name, desc.vert)?;
        let frag = match desc.frag {
            Some(f) => match shaders::module(ctx, desc.name, f) {
                Ok(m) => Some(m),
                Err(e) => {
                    // SAFETY: created above, unused.
                    unsafe { ctx.device.destroy_shader_module(vert, None) };
                    return Err(e);
                }
            },
            None => None,
        };
        let result = Self::build(ctx, layout, desc, vert, frag);
        // SAFETY: modules are no longer needed once the pipeline exists (or failed).
        unsafe {
            ctx.device.destroy_shader_module(vert, None);
            if let Some(f) = frag {
                ctx.device.destroy_shader_module(f, None);
            }
        }
        result
    }

    fn build(
        ctx: &Arc<GpuContext>,
        layout: &PipelineLayout,
        desc: &PipelineDesc,
        vert: vk::ShaderModule,
        frag: Option<vk::ShaderModule>,
    ) -> Result<Pipeline> {
        let mut stages = vec![vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::VERTEX)
            .module(vert)
            .name(c"main")];
        if let Some(f) = frag {
            stages.push(
                vk::PipelineShaderStageCreateInfo::default()
                    .stage(vk::ShaderStageFlags::FRAGMENT)
                    .module(f)
                    .name(c"main"),
            );
        }
        let bindings = [vk::VertexInputBindingDescription::default()
            .binding(0)
            .stride(desc.vertex_stride)
            .input_rate(vk::VertexInputRate::VERTEX)];
        let attributes = vertex_attributes(desc);
        let vertex_input = if desc.attributes.is_empty() {
            vk::PipelineVertexInputStateCreateInfo::default()
        } else {
            vk::PipelineVertexInputStateCreateInfo::default()
                .vertex_binding_descriptions(&bindings)
                .vertex_attribute_descriptions(&attributes)
        };
        let input_assembly = vk::PipelineInputAssemblyStateCreateInfo::default()
            .topology(vk::PrimitiveTopology::TRIANGLE_LIST);
        let viewport = vk::PipelineViewportStateCreateInfo::default()
            .viewport_count(1)
            .scissor_count(1);
        let raster = rasterization(desc);
        let multisample = vk::PipelineMultisampleStateCreateInfo::default()
            .rasterization_samples(vk::SampleCountFlags::TYPE_1);
        let depth = depth_stencil(desc);
        let blend_attachments = blend_attachments(desc);
        let blend =
            vk::PipelineColorBlendStateCreateInfo::default().attachments(&blend_attachments);
        let dynamic_states = [vk::DynamicState::VIEWPORT, vk::DynamicState::SCISSOR];
        let dynamic = vk::PipelineDynamicStateCreateInfo::default().dynamic_states(&dynamic_states);
        let mut rendering = vk::PipelineRenderingCreateInfo::default()
            .color_attachment_formats(desc.color_formats)
            .depth_attachment_format(desc.depth_format);
        let info = vk::GraphicsPipelineCreateInfo::default()
            .stages(&stages)
            .vertex_input_state(&vertex_input)
            .input_assembly_state(&input_assembly)
            .viewport_state(&viewport)
            .rasterization_state(&raster)
            .multisample_state(&multisample)
            .depth_stencil_state(&depth)
            .color_blend_state(&blend)
            .dynamic_state(&dynamic)
            .layout(layout.handle)
            .push_next(&mut rendering);
        // SAFETY: all referenced state outlives the call; modules are valid.
        let handle = unsafe {
            ctx.device
                .create_graphics_pipelines(vk::PipelineCache::null(), &[info], None)
        }
        .map_err(|(_, e)| crate::Error::Vulkan {
            call: "vkCreateGraphicsPipelines",
            result: e,
        })?[0];
        Ok(Pipeline {
            ctx: ctx.clone(),
            handle,
            kind: desc.kind,
        })
    }
}

fn vertex_attributes(desc: &PipelineDesc) -> Vec<vk::VertexInputAttributeDescription> {
    desc.attributes
        .iter()
        .map(|&(location, format, offset)| {
            vk::VertexInputAttributeDescription::default()
                .binding(0)
                .location(location)
                .format(format)
                .offset(offset)
        })
        .collect()
}

fn rasterization(desc: &PipelineDesc) -> vk::PipelineRasterizationStateCreateInfo<'static> {
    vk::PipelineRasterizationStateCreateInfo::default()
        .polygon_mode(vk::PolygonMode::FILL)
        .cull_mode(desc.cull)
        .front_face(vk::FrontFace::COUNTER_CLOCKWISE)
        .line_width(1.0)
        .depth_bias_enable(desc.depth_bias != (0.0, 0.0))
        .depth_bias_constant_factor(desc.depth_bias.0)
        .depth_bias_slope_factor(desc.depth_bias.1)
}

fn depth_stencil(desc: &PipelineDesc) -> vk::PipelineDepthStencilStateCreateInfo<'static> {
    let has_depth = desc.depth_format != vk::Format::UNDEFINED;
    vk::PipelineDepthStencilStateCreateInfo::default()
        .depth_test_enable(has_depth)
        .depth_write_enable(has_depth && desc.depth_write)
        .depth_compare_op(desc.depth_compare)
}

fn blend_attachments(desc: &PipelineDesc) -> Vec<vk::PipelineColorBlendAttachmentState> {
    let mask = if desc.color_write {
        vk::ColorComponentFlags::RGBA
    } else {
        vk::ColorComponentFlags::empty()
    };
    let state = vk::PipelineColorBlendAttachmentState::default().color_write_mask(mask);
    let state = if desc.blend {
        state
            .blend_enable(true)
            .src_color_blend_factor(vk::BlendFactor::SRC_ALPHA)
            .dst_color_blend_factor(vk::BlendFactor::ONE_MINUS_SRC_ALPHA)
            .color_blend_op(vk::BlendOp::ADD)
            .src_alpha_blend_factor(vk::BlendFactor::ONE)
            .dst_alpha_blend_factor(vk::BlendFactor::ONE_MINUS_SRC_ALPHA)
            .alpha_blend_op(vk::BlendOp::ADD)
    } else {
        state
    };
    desc.color_formats.iter().map(|_| state).collect()
}

impl Drop for Pipeline {
    fn drop(&mut self) {
        // SAFETY: the owner guarantees no command buffer in flight uses it.
        unsafe { self.ctx.device.destroy_pipeline(self.handle, None) };
    }
}

/// A compute pipeline (destroyed on drop).
pub struct ComputePipeline {
    ctx: Arc<GpuContext>,
    /// The pipeline handle.
    pub(crate) handle: vk::Pipeline,
}

impl ComputePipeline {
    /// Builds a compute pipeline from SPIR-V with `layout`.
    pub fn new(
        ctx: &Arc<GpuContext>,
        layout: &PipelineLayout,
        name: &str,
        spirv: &[u8],
    ) -> Result<ComputePipeline> {
        if let Some(size) = local_size(spirv) {
            ctx.info.check_workgroup(name, size)?;
        }
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

/// The `LocalSize` execution mode of a compute shader's SPIR-V (`OpExecutionMode %main
/// LocalSize x y z`), if it declares one.
pub(crate) fn local_size(spirv: &[u8]) -> Option<[u32; 3]> {
    const OP_EXECUTION_MODE: u32 = 16;
    const LOCAL_SIZE: u32 = 17;
    let words: Vec<u32> = spirv
        .chunks_exact(4)
        .map(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]]))
        .collect();
    // The header is five words; then instructions, each `word count << 16 | opcode`.
    let mut i = 5;
    while let Some(&first) = words.get(i) {
        let (count, opcode) = ((first >> 16) as usize, first & 0xffff);
        if opcode == OP_EXECUTION_MODE && count >= 6 && words.get(i + 2) == Some(&LOCAL_SIZE) {
            return words.get(i + 3..i + 6).and_then(|w| w.try_into().ok());
        }
        i += count.max(1);
    }
    None
}

#[cfg(test)]
mod local_size_tests {
    use super::local_size;
    use crate::gpu::shaders;

    #[test]
    fn reads_the_compute_shaders_local_size() {
        assert_eq!(local_size(shaders::GI_GATHER_COMP), Some([8, 8, 1]));
        assert_eq!(local_size(shaders::GI_RESOLVE_COMP), Some([8, 8, 1]));
        assert_eq!(local_size(shaders::SCENE_VERT), None);
        assert_eq!(local_size(&shaders::GI_GATHER_COMP[..40]), None);
    }
}
