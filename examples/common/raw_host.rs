//! The engine example's own raw-ash plumbing, none of it about culling: the validation
//! messenger and instance, host-visible buffers, render targets and the scene pipeline.
//! `engine.rs` includes this file with `#[path = "common/raw_host.rs"] mod raw_host;`; nothing
//! here goes through coherent's own GPU code.

use std::ffi::c_void;
use std::sync::atomic::{AtomicUsize, Ordering};

use anyhow::{Context, Result};
use ash::{ext, vk};

pub const WIDTH: u32 = 320;
pub const HEIGHT: u32 = 180;

/// Validation warnings and errors seen so far (the examples exit non-zero if any).
pub static MESSAGES: AtomicUsize = AtomicUsize::new(0);

unsafe extern "system" fn on_message(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    _: *mut c_void,
) -> vk::Bool32 {
    if severity.intersects(
        vk::DebugUtilsMessageSeverityFlagsEXT::WARNING
            | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
    ) {
        MESSAGES.fetch_add(1, Ordering::SeqCst);
        // SAFETY: the layer passes a valid callback data struct for the duration of the call.
        if let Some(msg) = unsafe { data.as_ref() }.and_then(|d| unsafe { d.message_as_c_str() }) {
            eprintln!("validation: {}", msg.to_string_lossy());
        }
    }
    vk::FALSE
}

/// A buffer or image allocation in host-visible memory (the host keeps things simple).
pub struct Memory {
    pub memory: vk::DeviceMemory,
}

/// The Vulkan loader, a 1.3 instance with the Khronos validation layer, and a messenger that
/// counts warnings and errors in [`MESSAGES`].
pub fn instance() -> Result<(
    ash::Entry,
    ash::Instance,
    ext::debug_utils::Instance,
    vk::DebugUtilsMessengerEXT,
)> {
    // SAFETY: loads the system loader once.
    let entry = unsafe { ash::Entry::load() }.context("loading Vulkan")?;
    let layers = [c"VK_LAYER_KHRONOS_validation".as_ptr()];
    let exts = [ext::debug_utils::NAME.as_ptr()];
    let app = vk::ApplicationInfo::default().api_version(vk::API_VERSION_1_3);
    // Core and synchronization validation (best practices would flag this simple host's own
    // one-allocation-per-buffer memory; coherent-ash itself is tested with them on).
    let enables = [vk::ValidationFeatureEnableEXT::SYNCHRONIZATION_VALIDATION];
    let mut features = vk::ValidationFeaturesEXT::default().enabled_validation_features(&enables);
    let info = vk::InstanceCreateInfo::default()
        .application_info(&app)
        .enabled_layer_names(&layers)
        .enabled_extension_names(&exts)
        .push_next(&mut features);
    // SAFETY: valid create info.
    let instance = unsafe { entry.create_instance(&info, None) }
        .context("instance (is vulkan-validationlayers installed?)")?;
    let debug = ext::debug_utils::Instance::new(&entry, &instance);
    let messenger_info = vk::DebugUtilsMessengerCreateInfoEXT::default()
        .message_severity(
            vk::DebugUtilsMessageSeverityFlagsEXT::WARNING
                | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
        )
        .message_type(
            vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
        )
        .pfn_user_callback(Some(on_message));
    // SAFETY: valid instance.
    let messenger = unsafe { debug.create_debug_utils_messenger(&messenger_info, None) }?;
    Ok((entry, instance, debug, messenger))
}

fn memory_type(
    memory_types: &vk::PhysicalDeviceMemoryProperties,
    bits: u32,
    flags: vk::MemoryPropertyFlags,
) -> Result<u32> {
    (0..memory_types.memory_type_count)
        .find(|&i| {
            bits & (1 << i) != 0
                && memory_types.memory_types[i as usize]
                    .property_flags
                    .contains(flags)
        })
        .context("no suitable memory type")
}

/// Memory for `req` of a type with `flags`.
fn allocate(
    device: &ash::Device,
    memory_types: &vk::PhysicalDeviceMemoryProperties,
    req: vk::MemoryRequirements,
    flags: vk::MemoryPropertyFlags,
) -> Result<vk::DeviceMemory> {
    let kind = memory_type(memory_types, req.memory_type_bits, flags)?;
    // SAFETY: valid device and allocate info; the caller binds and frees the memory.
    let memory = unsafe {
        device.allocate_memory(
            &vk::MemoryAllocateInfo::default()
                .allocation_size(req.size)
                .memory_type_index(kind),
            None,
        )?
    };
    Ok(memory)
}

/// A host-visible, coherent, mapped buffer filled with `data`.
pub fn buffer(
    device: &ash::Device,
    memory_types: &vk::PhysicalDeviceMemoryProperties,
    size: u64,
    usage: vk::BufferUsageFlags,
    data: &[u8],
) -> Result<(vk::Buffer, Memory)> {
    let info = vk::BufferCreateInfo::default()
        .size(size.max(16))
        .usage(usage);
    // SAFETY: valid device and create info; memory is bound right after.
    unsafe {
        let buffer = device.create_buffer(&info, None)?;
        let req = device.get_buffer_memory_requirements(buffer);
        let memory = allocate(
            device,
            memory_types,
            req,
            vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT,
        )?;
        device.bind_buffer_memory(buffer, memory, 0)?;
        let ptr =
            device.map_memory(memory, 0, vk::WHOLE_SIZE, vk::MemoryMapFlags::empty())? as *mut u8;
        std::ptr::copy_nonoverlapping(data.as_ptr(), ptr, data.len().min(req.size as usize));
        Ok((buffer, Memory { memory }))
    }
}

/// A `WIDTH` x `HEIGHT` device-local render target with a view of `aspect`.
pub fn image(
    device: &ash::Device,
    memory_types: &vk::PhysicalDeviceMemoryProperties,
    format: vk::Format,
    usage: vk::ImageUsageFlags,
    aspect: vk::ImageAspectFlags,
) -> Result<(vk::Image, vk::ImageView, vk::DeviceMemory)> {
    let info = vk::ImageCreateInfo::default()
        .image_type(vk::ImageType::TYPE_2D)
        .format(format)
        .extent(vk::Extent3D {
            width: WIDTH,
            height: HEIGHT,
            depth: 1,
        })
        .mip_levels(1)
        .array_layers(1)
        .samples(vk::SampleCountFlags::TYPE_1)
        .usage(usage);
    // SAFETY: valid device and create infos; memory bound before the view is created.
    unsafe {
        let image = device.create_image(&info, None)?;
        let req = device.get_image_memory_requirements(image);
        let memory = allocate(
            device,
            memory_types,
            req,
            vk::MemoryPropertyFlags::DEVICE_LOCAL,
        )?;
        device.bind_image_memory(image, memory, 0)?;
        let view = device.create_image_view(
            &vk::ImageViewCreateInfo::default()
                .image(image)
                .view_type(vk::ImageViewType::TYPE_2D)
                .format(format)
                .subresource_range(
                    vk::ImageSubresourceRange::default()
                        .aspect_mask(aspect)
                        .level_count(1)
                        .layer_count(1),
                ),
            None,
        )?;
        Ok((image, view, memory))
    }
}

/// The scene's buffers, in this order: vertices (position and normal), indices, per-object data
/// (model matrix, normal matrix, color: a storage buffer) and the index pattern of 1024 query
/// boxes (8 corners each, 36 indices).
pub fn scene_buffers(
    device: &ash::Device,
    memory_types: &vk::PhysicalDeviceMemoryProperties,
    scene: &coherent::scene::Scene,
) -> Result<Vec<(vk::Buffer, Memory)>> {
    let bytes = |v: &[f32]| v.iter().flat_map(|f| f.to_le_bytes()).collect::<Vec<u8>>();
    let verts: Vec<f32> = scene
        .vertices
        .iter()
        .flat_map(|v| v.position.into_iter().chain(v.normal))
        .collect();
    let indices: Vec<u8> = scene.indices.iter().flat_map(|i| i.to_le_bytes()).collect();
    let mut objects = Vec::new();
    for o in &scene.objects {
        objects.extend(o.transform.to_cols_array());
        objects.extend(o.transform.inverse().transpose().to_cols_array());
        objects.extend(o.color.to_array());
    }
    let faces: [u32; 36] = [
        0, 2, 1, 1, 2, 3, 4, 5, 6, 5, 7, 6, 0, 1, 4, 1, 5, 4, 2, 6, 3, 3, 6, 7, 0, 4, 2, 2, 4, 6,
        1, 3, 5, 3, 7, 5,
    ];
    let box_indices: Vec<u8> = (0..1024u32)
        .flat_map(|b| faces.map(|i| i + 8 * b))
        .flat_map(|i| i.to_le_bytes())
        .collect();
    let contents = [
        (bytes(&verts), vk::BufferUsageFlags::VERTEX_BUFFER),
        (indices, vk::BufferUsageFlags::INDEX_BUFFER),
        (bytes(&objects), vk::BufferUsageFlags::STORAGE_BUFFER),
        (box_indices, vk::BufferUsageFlags::INDEX_BUFFER),
    ];
    let mut out = Vec::with_capacity(contents.len());
    for (data, usage) in contents {
        match buffer(device, memory_types, data.len() as u64, usage, &data) {
            Ok(b) => out.push(b),
            Err(e) => {
                for b in out {
                    // SAFETY: nothing has used these buffers yet.
                    unsafe { destroy_buffer(device, b) };
                }
                return Err(e);
            }
        }
    }
    Ok(out)
}

/// The one descriptor set both hosts use: a storage buffer (`objects`) at binding 0 of set 0,
/// and 80 bytes of push constants, for every graphics and compute stage.
pub struct StorageSet {
    pub set_layout: vk::DescriptorSetLayout,
    pub layout: vk::PipelineLayout,
    pub pool: vk::DescriptorPool,
    pub set: vk::DescriptorSet,
}

impl StorageSet {
    /// No objects yet (what a host holds before `storage_set`; destroying it does nothing).
    pub fn null() -> StorageSet {
        StorageSet {
            set_layout: vk::DescriptorSetLayout::null(),
            layout: vk::PipelineLayout::null(),
            pool: vk::DescriptorPool::null(),
            set: vk::DescriptorSet::null(),
        }
    }
}

/// Creates the [`StorageSet`] and points it at `objects`.
pub fn storage_set(device: &ash::Device, objects: vk::Buffer) -> Result<StorageSet> {
    let all = vk::ShaderStageFlags::VERTEX
        | vk::ShaderStageFlags::FRAGMENT
        | vk::ShaderStageFlags::COMPUTE;
    let binding = [vk::DescriptorSetLayoutBinding::default()
        .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
        .descriptor_count(1)
        .stage_flags(all)];
    let ranges = [vk::PushConstantRange::default().stage_flags(all).size(80)];
    let sizes = [vk::DescriptorPoolSize {
        ty: vk::DescriptorType::STORAGE_BUFFER,
        descriptor_count: 1,
    }];
    // SAFETY: valid device and create infos; the caller destroys the result with
    // `destroy_storage_set`. A failure part way leaks nothing the example keeps running with:
    // the examples exit on any error.
    unsafe {
        let set_layout = device.create_descriptor_set_layout(
            &vk::DescriptorSetLayoutCreateInfo::default().bindings(&binding),
            None,
        )?;
        let set_layouts = [set_layout];
        let layout = device.create_pipeline_layout(
            &vk::PipelineLayoutCreateInfo::default()
                .set_layouts(&set_layouts)
                .push_constant_ranges(&ranges),
            None,
        )?;
        let pool = device.create_descriptor_pool(
            &vk::DescriptorPoolCreateInfo::default()
                .max_sets(1)
                .pool_sizes(&sizes),
            None,
        )?;
        let set = device.allocate_descriptor_sets(
            &vk::DescriptorSetAllocateInfo::default()
                .descriptor_pool(pool)
                .set_layouts(&set_layouts),
        )?[0];
        let info = [vk::DescriptorBufferInfo {
            buffer: objects,
            offset: 0,
            range: vk::WHOLE_SIZE,
        }];
        let write = vk::WriteDescriptorSet::default()
            .dst_set(set)
            .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
            .buffer_info(&info);
        device.update_descriptor_sets(&[write], &[]);
        Ok(StorageSet {
            set_layout,
            layout,
            pool,
            set,
        })
    }
}

/// Destroys a [`StorageSet`] (null handles are ignored by Vulkan).
///
/// # Safety
/// The device is idle and the set is destroyed once.
pub unsafe fn destroy_storage_set(device: &ash::Device, s: &StorageSet) {
    // SAFETY: the caller guarantees nothing uses the set any more.
    unsafe {
        device.destroy_descriptor_pool(s.pool, None);
        device.destroy_pipeline_layout(s.layout, None);
        device.destroy_descriptor_set_layout(s.set_layout, None);
    }
}

/// Destroys a buffer from [`buffer`] and frees its memory.
///
/// # Safety
/// The device is idle and the buffer is destroyed once.
pub unsafe fn destroy_buffer(device: &ash::Device, (buffer, memory): (vk::Buffer, Memory)) {
    // SAFETY: the caller guarantees the buffer is no longer in use.
    unsafe {
        device.destroy_buffer(buffer, None);
        device.free_memory(memory.memory, None);
    }
}

/// Destroys an image from [`image`], its view and its memory.
///
/// # Safety
/// The device is idle and the image is destroyed once.
pub unsafe fn destroy_image(
    device: &ash::Device,
    (image, view, memory): (vk::Image, vk::ImageView, vk::DeviceMemory),
) {
    // SAFETY: the caller guarantees the image is no longer in use.
    unsafe {
        device.destroy_image_view(view, None);
        device.destroy_image(image, None);
        device.free_memory(memory, None);
    }
}

/// The scene pipeline (`query` false: position and normal, back-face culling, depth write) or
/// the query-box pipeline (`query` true: position only, no culling, no depth or color write).
/// With `reverse_z`, nearer is greater.
pub fn pipeline(
    device: &ash::Device,
    layout: vk::PipelineLayout,
    vert: &[u8],
    frag: Option<&[u8]>,
    query: bool,
    reverse_z: bool,
) -> Result<vk::Pipeline> {
    let module = |bytes: &[u8]| -> Result<vk::ShaderModule> {
        let words = ash::util::read_spv(&mut std::io::Cursor::new(bytes))?;
        // SAFETY: valid SPIR-V from coherent's build.
        Ok(unsafe {
            device.create_shader_module(&vk::ShaderModuleCreateInfo::default().code(&words), None)
        }?)
    };
    let vs = module(vert)?;
    let fs = frag.map(module).transpose()?;
    let mut stages = vec![vk::PipelineShaderStageCreateInfo::default()
        .stage(vk::ShaderStageFlags::VERTEX)
        .module(vs)
        .name(c"main")];
    if let Some(fs) = fs {
        stages.push(
            vk::PipelineShaderStageCreateInfo::default()
                .stage(vk::ShaderStageFlags::FRAGMENT)
                .module(fs)
                .name(c"main"),
        );
    }
    let stride = if query { 12 } else { 24 };
    let bindings = [vk::VertexInputBindingDescription::default().stride(stride)];
    let attrs_scene = [
        vk::VertexInputAttributeDescription::default()
            .location(0)
            .format(vk::Format::R32G32B32_SFLOAT),
        vk::VertexInputAttributeDescription::default()
            .location(1)
            .format(vk::Format::R32G32B32_SFLOAT)
            .offset(12),
    ];
    let attrs = if query {
        &attrs_scene[..1]
    } else {
        &attrs_scene[..]
    };
    let vertex = vk::PipelineVertexInputStateCreateInfo::default()
        .vertex_binding_descriptions(&bindings)
        .vertex_attribute_descriptions(attrs);
    let assembly = vk::PipelineInputAssemblyStateCreateInfo::default()
        .topology(vk::PrimitiveTopology::TRIANGLE_LIST);
    let viewport = vk::PipelineViewportStateCreateInfo::default()
        .viewport_count(1)
        .scissor_count(1);
    let raster = vk::PipelineRasterizationStateCreateInfo::default()
        .cull_mode(if query {
            vk::CullModeFlags::NONE
        } else {
            vk::CullModeFlags::BACK
        })
        .front_face(vk::FrontFace::COUNTER_CLOCKWISE)
        .line_width(1.0);
    let ms = vk::PipelineMultisampleStateCreateInfo::default()
        .rasterization_samples(vk::SampleCountFlags::TYPE_1);
    let depth = vk::PipelineDepthStencilStateCreateInfo::default()
        .depth_test_enable(true)
        .depth_write_enable(!query)
        .depth_compare_op(match (query, reverse_z) {
            (true, false) => vk::CompareOp::LESS_OR_EQUAL,
            (false, false) => vk::CompareOp::LESS,
            // Reverse-Z: nearer is greater; a query box passes where it is at least as near.
            (true, true) => vk::CompareOp::GREATER_OR_EQUAL,
            (false, true) => vk::CompareOp::GREATER,
        });
    let mask = if query {
        vk::ColorComponentFlags::empty()
    } else {
        vk::ColorComponentFlags::RGBA
    };
    let blend_att = [vk::PipelineColorBlendAttachmentState::default().color_write_mask(mask)];
    let blend = vk::PipelineColorBlendStateCreateInfo::default().attachments(&blend_att);
    let dynamic_states = [vk::DynamicState::VIEWPORT, vk::DynamicState::SCISSOR];
    let dynamic = vk::PipelineDynamicStateCreateInfo::default().dynamic_states(&dynamic_states);
    let formats = [vk::Format::R8G8B8A8_UNORM];
    let mut rendering = vk::PipelineRenderingCreateInfo::default()
        .color_attachment_formats(&formats)
        .depth_attachment_format(vk::Format::D32_SFLOAT);
    let info = vk::GraphicsPipelineCreateInfo::default()
        .stages(&stages)
        .vertex_input_state(&vertex)
        .input_assembly_state(&assembly)
        .viewport_state(&viewport)
        .rasterization_state(&raster)
        .multisample_state(&ms)
        .depth_stencil_state(&depth)
        .color_blend_state(&blend)
        .dynamic_state(&dynamic)
        .layout(layout)
        .push_next(&mut rendering);
    // SAFETY: all state outlives the call; modules are destroyed after creation.
    let pipeline =
        unsafe { device.create_graphics_pipelines(vk::PipelineCache::null(), &[info], None) }
            .map_err(|(_, e)| e)?[0];
    // SAFETY: no longer needed once the pipeline exists.
    unsafe {
        device.destroy_shader_module(vs, None);
        if let Some(fs) = fs {
            device.destroy_shader_module(fs, None);
        }
    }
    Ok(pipeline)
}

/// Begins rendering to the `WIDTH` x `HEIGHT` attachments and sets the viewport (flipped, so
/// clip y is up) and the scissor; the caller binds its pipeline state.
///
/// # Safety
/// `cmd` is recording outside rendering; the attachments are in their attachment layouts.
pub unsafe fn begin_rendering(
    device: &ash::Device,
    cmd: vk::CommandBuffer,
    color_att: &[vk::RenderingAttachmentInfo<'_>],
    depth_att: &vk::RenderingAttachmentInfo<'_>,
) {
    let extent = vk::Extent2D {
        width: WIDTH,
        height: HEIGHT,
    };
    let rendering = vk::RenderingInfo::default()
        .render_area(extent.into())
        .layer_count(1)
        .color_attachments(color_att)
        .depth_attachment(depth_att);
    // SAFETY: the caller guarantees `cmd` is recording outside rendering.
    unsafe {
        device.cmd_begin_rendering(cmd, &rendering);
        let viewport = vk::Viewport {
            x: 0.0,
            y: HEIGHT as f32,
            width: WIDTH as f32,
            height: -(HEIGHT as f32),
            min_depth: 0.0,
            max_depth: 1.0,
        };
        device.cmd_set_viewport(cmd, 0, &[viewport]);
        device.cmd_set_scissor(cmd, 0, &[extent.into()]);
    }
}

/// The scene pipeline (see [`pipeline`]).
pub fn scene_pipeline(
    device: &ash::Device,
    layout: vk::PipelineLayout,
    reverse_z: bool,
) -> Result<vk::Pipeline> {
    use coherent::gpu::shaders::{SCENE_FRAG, SCENE_VERT};
    pipeline(
        device,
        layout,
        SCENE_VERT,
        Some(SCENE_FRAG),
        false,
        reverse_z,
    )
}

/// Binds `pipeline` with its vertex buffer `vb` and its 32-bit index buffer `ib`: the engine's
/// scene state.
///
/// # Safety
/// `cmd` is recording inside a rendering; the pipeline and buffers are valid.
pub unsafe fn bind_state(
    device: &ash::Device,
    cmd: vk::CommandBuffer,
    pipeline: vk::Pipeline,
    vb: vk::Buffer,
    ib: vk::Buffer,
) {
    // SAFETY: guaranteed by the caller.
    unsafe {
        device.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::GRAPHICS, pipeline);
        device.cmd_bind_vertex_buffers(cmd, 0, &[vb], &[0]);
        device.cmd_bind_index_buffer(cmd, ib, 0, vk::IndexType::UINT32);
    }
}
