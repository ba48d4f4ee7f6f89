//! coherent-ash on a Vulkan 1.2 host: an instance made for Vulkan 1.2 and a device with
//! `VK_KHR_dynamic_rendering` and `VK_EXT_conditional_rendering` (no Vulkan 1.3 commands, no
//! `synchronization2`), under strict validation (core, synchronization, best practices), as an
//! engine on a 1.2 driver has it. The host's own plumbing is raw ash, none of it from coherent.

use std::ffi::{c_void, CStr};
use std::sync::Mutex;

use ash::{ext, khr, vk};
use coherent_ash::{QueryBackend, QueryBackendDesc};
use coherent_cull::chcpp::{Chcpp, ChcppParams};
use coherent_cull::{CameraView, Culler, DepthConvention, FrameInput, Latency};

use crate::query_backend::{
    assert_front_in_every_frame, assert_walled, depth_at, row, set_viewport, FrameSlots, EXTENT,
};

/// The validation messages (warnings and errors) of this file's instance.
static MESSAGES: Mutex<Vec<String>> = Mutex::new(Vec::new());

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
        // SAFETY: the layer passes valid callback data for the duration of the call.
        let text = unsafe { data.as_ref().and_then(|d| d.message_as_c_str()) }
            .map(|m| m.to_string_lossy().into_owned())
            .unwrap_or_default();
        if let Ok(mut m) = MESSAGES.lock() {
            m.push(text);
        }
    }
    vk::FALSE
}

/// The host: a Vulkan 1.2 instance with strict validation, the first device (or the one
/// `COHERENT_DEVICE` names) with the two extensions, one queue, a depth image.
struct Host {
    _entry: ash::Entry,
    instance: ash::Instance,
    debug: (ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT),
    physical_device: vk::PhysicalDevice,
    device: ash::Device,
    rendering: khr::dynamic_rendering::Device,
    queue: vk::Queue,
    queue_family: u32,
    depth: (vk::Image, vk::ImageView, vk::DeviceMemory),
}

impl Host {
    fn new() -> Host {
        // SAFETY: every create info below outlives its call; the handles are destroyed in drop.
        unsafe {
            let entry = ash::Entry::load().expect("Vulkan loader");
            let layers = [c"VK_LAYER_KHRONOS_validation".as_ptr()];
            let exts = [
                ext::debug_utils::NAME.as_ptr(),
                ext::validation_features::NAME.as_ptr(),
            ];
            let app = vk::ApplicationInfo::default().api_version(vk::API_VERSION_1_2);
            let enables = [
                vk::ValidationFeatureEnableEXT::SYNCHRONIZATION_VALIDATION,
                vk::ValidationFeatureEnableEXT::BEST_PRACTICES,
            ];
            let mut features =
                vk::ValidationFeaturesEXT::default().enabled_validation_features(&enables);
            let instance = entry
                .create_instance(
                    &vk::InstanceCreateInfo::default()
                        .application_info(&app)
                        .enabled_layer_names(&layers)
                        .enabled_extension_names(&exts)
                        .push_next(&mut features),
                    None,
                )
                .expect("a Vulkan 1.2 instance with the validation layer");
            let utils = ext::debug_utils::Instance::new(&entry, &instance);
            let messenger = utils
                .create_debug_utils_messenger(
                    &vk::DebugUtilsMessengerCreateInfoEXT::default()
                        .message_severity(
                            vk::DebugUtilsMessageSeverityFlagsEXT::WARNING
                                | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
                        )
                        .message_type(
                            vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                                | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
                        )
                        .pfn_user_callback(Some(on_message)),
                    None,
                )
                .expect("messenger");
            let filter = std::env::var("COHERENT_DEVICE")
                .unwrap_or_default()
                .to_lowercase();
            let physical_device = instance
                .enumerate_physical_devices()
                .expect("devices")
                .into_iter()
                .find(|&p| {
                    let props = instance.get_physical_device_properties(p);
                    let name = props.device_name_as_c_str().unwrap_or(c"");
                    name.to_string_lossy().to_lowercase().contains(&filter)
                })
                .expect("a device");
            let queue_family = instance
                .get_physical_device_queue_family_properties(physical_device)
                .iter()
                .position(|f| f.queue_flags.contains(vk::QueueFlags::GRAPHICS))
                .expect("a graphics queue") as u32;
            // (Best practices: features looked at before the device is made.)
            let available = instance.get_physical_device_features(physical_device);
            assert_eq!(available.occlusion_query_precise, vk::TRUE);
            let device_exts = [
                khr::dynamic_rendering::NAME.as_ptr(),
                ext::conditional_rendering::NAME.as_ptr(),
            ];
            let mut dynamic =
                vk::PhysicalDeviceDynamicRenderingFeatures::default().dynamic_rendering(true);
            let mut conditional = vk::PhysicalDeviceConditionalRenderingFeaturesEXT::default()
                .conditional_rendering(true);
            let core = vk::PhysicalDeviceFeatures::default().occlusion_query_precise(true);
            let priorities = [1.0];
            let queues = [vk::DeviceQueueCreateInfo::default()
                .queue_family_index(queue_family)
                .queue_priorities(&priorities)];
            let device = instance
                .create_device(
                    physical_device,
                    &vk::DeviceCreateInfo::default()
                        .queue_create_infos(&queues)
                        .enabled_extension_names(&device_exts)
                        .enabled_features(&core)
                        .push_next(&mut dynamic)
                        .push_next(&mut conditional),
                    None,
                )
                .expect("a device with VK_KHR_dynamic_rendering and VK_EXT_conditional_rendering");
            let rendering = khr::dynamic_rendering::Device::new(&instance, &device);
            let queue = device.get_device_queue(queue_family, 0);
            let depth = depth_image(&instance, physical_device, &device);
            Host {
                _entry: entry,
                instance,
                debug: (utils, messenger),
                physical_device,
                device,
                rendering,
                queue,
                queue_family,
                depth,
            }
        }
    }

    /// Begins the depth pass into the host's depth image: cleared to `clear` (or loaded, for
    /// the resume after a predicate resolve), stored; after a barrier from the depth writes
    /// before it. Viewport and scissor set.
    ///
    /// # Safety
    /// `cmd` is recording outside rendering.
    unsafe fn begin_pass(&self, cmd: vk::CommandBuffer, clear: Option<f32>) {
        let d = &self.device;
        let tests = vk::PipelineStageFlags::EARLY_FRAGMENT_TESTS
            | vk::PipelineStageFlags::LATE_FRAGMENT_TESTS;
        let layout = vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL;
        let barrier = vk::ImageMemoryBarrier::default()
            .image(self.depth.0)
            .subresource_range(
                vk::ImageSubresourceRange::default()
                    .aspect_mask(vk::ImageAspectFlags::DEPTH)
                    .level_count(1)
                    .layer_count(1),
            )
            .old_layout(if clear.is_some() {
                vk::ImageLayout::UNDEFINED
            } else {
                layout
            })
            .new_layout(layout)
            .src_access_mask(vk::AccessFlags::DEPTH_STENCIL_ATTACHMENT_WRITE)
            .dst_access_mask(
                vk::AccessFlags::DEPTH_STENCIL_ATTACHMENT_READ
                    | vk::AccessFlags::DEPTH_STENCIL_ATTACHMENT_WRITE,
            );
        let attachment = vk::RenderingAttachmentInfo::default()
            .image_view(self.depth.1)
            .image_layout(layout)
            .load_op(if clear.is_some() {
                vk::AttachmentLoadOp::CLEAR
            } else {
                vk::AttachmentLoadOp::LOAD
            })
            .store_op(vk::AttachmentStoreOp::STORE)
            .clear_value(vk::ClearValue {
                depth_stencil: vk::ClearDepthStencilValue {
                    depth: clear.unwrap_or(1.0),
                    stencil: 0,
                },
            });
        // SAFETY: per the caller.
        unsafe {
            d.cmd_pipeline_barrier(
                cmd,
                tests,
                tests,
                vk::DependencyFlags::empty(),
                &[],
                &[],
                &[barrier],
            );
            self.rendering.cmd_begin_rendering(
                cmd,
                &vk::RenderingInfo::default()
                    .render_area(EXTENT.into())
                    .layer_count(1)
                    .depth_attachment(&attachment),
            );
            set_viewport(d, cmd);
        }
    }
}

impl Drop for Host {
    fn drop(&mut self) {
        // SAFETY: the device is idle (the test waited); children before parents.
        unsafe {
            let _ = self.device.device_wait_idle();
            self.device.destroy_image_view(self.depth.1, None);
            self.device.destroy_image(self.depth.0, None);
            self.device.free_memory(self.depth.2, None);
            self.device.destroy_device(None);
            self.debug
                .0
                .destroy_debug_utils_messenger(self.debug.1, None);
            self.instance.destroy_instance(None);
        }
    }
}

/// A device-local `EXTENT` D32 depth attachment, at the start of a 2 MiB block.
///
/// # Safety
/// The handles belong together.
unsafe fn depth_image(
    instance: &ash::Instance,
    physical_device: vk::PhysicalDevice,
    device: &ash::Device,
) -> (vk::Image, vk::ImageView, vk::DeviceMemory) {
    // SAFETY: per the caller; memory is bound before the view is made.
    unsafe {
        let image = device
            .create_image(
                &vk::ImageCreateInfo::default()
                    .image_type(vk::ImageType::TYPE_2D)
                    .format(vk::Format::D32_SFLOAT)
                    .extent(EXTENT.into())
                    .mip_levels(1)
                    .array_layers(1)
                    .samples(vk::SampleCountFlags::TYPE_1)
                    .usage(vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT),
                None,
            )
            .expect("depth image");
        let req = device.get_image_memory_requirements(image);
        let types = instance.get_physical_device_memory_properties(physical_device);
        let kind = (0..types.memory_type_count)
            .find(|&i| {
                req.memory_type_bits & (1 << i) != 0
                    && types.memory_types[i as usize]
                        .property_flags
                        .contains(vk::MemoryPropertyFlags::DEVICE_LOCAL)
            })
            .expect("device-local memory");
        // One block larger than the image, as a host sub-allocates (best practices).
        let memory = device
            .allocate_memory(
                &vk::MemoryAllocateInfo::default()
                    .allocation_size(req.size.max(2 << 20))
                    .memory_type_index(kind),
                None,
            )
            .expect("memory");
        device
            .bind_image_memory(image, memory, 0)
            .expect("bind memory");
        let view = device
            .create_image_view(
                &vk::ImageViewCreateInfo::default()
                    .image(image)
                    .view_type(vk::ImageViewType::TYPE_2D)
                    .format(vk::Format::D32_SFLOAT)
                    .subresource_range(
                        vk::ImageSubresourceRange::default()
                            .aspect_mask(vk::ImageAspectFlags::DEPTH)
                            .level_count(1)
                            .layer_count(1),
                    ),
                None,
            )
            .expect("depth view");
        (image, view, memory)
    }
}

/// Runs 12 frames of chcpp in `latency` with two frames in flight through a `QueryBackend` on
/// the 1.2 host; the depth pass is cleared to a wall 10.5 units away (boxes 0-2 in front of
/// it). Returns the objects handed over in each frame and the number of predicate resolves.
fn run(host: &Host, latency: Latency) -> (Vec<Vec<u32>>, u32) {
    let (bvh, cam) = row();
    let view: CameraView = (&cam).into();
    let view_proj = view.view_proj.to_cols_array();
    let wall = depth_at(&cam, 10.5);
    let desc = QueryBackendDesc {
        predicates: latency == Latency::Predicated,
        depth: DepthConvention::STANDARD,
        max_queries: 256,
        max_boxes: 1024,
        ..QueryBackendDesc::default()
    };
    let d = &host.device;
    let mut frames = Vec::new();
    let mut resolves = 0;
    // SAFETY: the host's handles belong together and outlive everything made here; each
    // slot's fence is waited for before its pool and queries are reused; the device is idle
    // before anything is destroyed.
    unsafe {
        let mut queries = QueryBackend::new(&host.instance, host.physical_device, d, desc)
            .expect("QueryBackend on the 1.2 host");
        let mut culler = Chcpp::new(ChcppParams::default())
            .with_latency(latency)
            .with_frames_in_flight(2);
        let slots = FrameSlots::new(d, host.queue_family, 2);
        for frame in 0..12u64 {
            let slot = (frame % 2) as usize;
            let cmd = slots.begin(d, slot);
            queries.begin_frame(cmd, slot as u32).expect("begin_frame");
            host.begin_pass(cmd, Some(wall));
            let mut objects = Vec::new();
            let draw = |_: vk::CommandBuffer, o: &[u32], _rebind: bool| {
                objects.extend_from_slice(o);
                Ok(())
            };
            let resume = |cmd| {
                host.begin_pass(cmd, None);
                Ok(())
            };
            let mut backend = queries.frame(cmd, view_proj, draw).with_resume(resume);
            let input = FrameInput {
                bvh: &bvh,
                view,
                frame,
                exact_visible: None,
            };
            culler.cull_frame(&input, &mut backend).expect("cull_frame");
            drop(backend);
            host.rendering.cmd_end_rendering(cmd);
            queries.end_frame(cmd).expect("end_frame");
            resolves += queries.counts().resolves;
            slots.submit(d, host.queue, slot);
            objects.sort_unstable();
            objects.dedup();
            frames.push(objects);
        }
        d.device_wait_idle().expect("idle");
        drop(queries);
        slots.destroy(d);
    }
    (frames, resolves)
}

/// The next-frame and predicated modes through `QueryBackend` on a Vulkan 1.2 host: the
/// backend records no Vulkan 1.3 command (its copy barriers are Vulkan 1.0 barriers; a resolve
/// ends the rendering through `vkCmdEndRenderingKHR`). Next-frame culls the boxes behind the
/// wall from results read two frames late; predicated hands over the boxes in front of the
/// wall in every frame, resolving its predicates. Validation stays silent.
#[test]
fn query_backend_runs_on_a_vulkan_1_2_host() {
    let host = Host::new();
    let has = |name: &CStr| {
        // SAFETY: the host's instance and physical device.
        unsafe {
            host.instance
                .enumerate_device_extension_properties(host.physical_device)
                .unwrap_or_default()
                .iter()
                .any(|e| e.extension_name_as_c_str() == Ok(name))
        }
    };
    assert!(has(khr::dynamic_rendering::NAME) && has(ext::conditional_rendering::NAME));
    let (next, _) = run(&host, Latency::NextFrame);
    assert_walled(&next, 3);
    let (predicated, resolves) = run(&host, Latency::Predicated);
    assert_front_in_every_frame(&predicated);
    assert!(resolves > 0, "no predicate resolve");
    drop(host);
    let messages = MESSAGES.lock().map(|m| m.clone()).unwrap_or_default();
    assert!(messages.is_empty(), "validation: {messages:#?}");
}
