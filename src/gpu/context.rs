//! The Vulkan context: instance, validation capture, physical-device choice, logical device,
//! queue and the memory allocator. One `GpuContext` owns them and destroys them in reverse order.

use std::ffi::{c_void, CStr, CString};
use std::mem::ManuallyDrop;
use std::sync::{Arc, Mutex};

use ash::{ext, vk};
use gpu_allocator::vulkan::{Allocator, AllocatorCreateDesc};

use crate::error::{Error, Result, VkContext};

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

/// Severity of a captured validation message.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Severity {
    /// A warning (best practice, likely misuse).
    Warning,
    /// An error (invalid usage).
    Error,
}

/// One message from the validation layer.
#[derive(Clone, Debug)]
pub struct ValidationMessage {
    /// Warning or error.
    pub severity: Severity,
    /// The message ID name (a VUID or UNASSIGNED-...).
    pub id: String,
    /// The full text.
    pub text: String,
}

/// The messages a context's validation messenger captured. Shared, so that a test can keep it
/// after the context is dropped and see the teardown reports ("not destroyed") too.
#[derive(Debug, Default)]
pub struct ValidationLog {
    messages: Mutex<Vec<ValidationMessage>>,
    others: Mutex<Vec<ValidationMessage>>,
    allowed: Mutex<Vec<ValidationMessage>>,
    echo: bool,
}

impl ValidationLog {
    /// A copy of every message captured so far.
    pub fn messages(&self) -> Vec<ValidationMessage> {
        self.messages.lock().map(|m| m.clone()).unwrap_or_default()
    }
    /// Number of warnings and errors captured so far.
    pub fn count(&self) -> usize {
        self.messages.lock().map(|m| m.len()).unwrap_or(0)
    }
    /// Messages from the loader and layers other than validation (e.g. the loader's warning
    /// that `VK_INSTANCE_LAYERS` injected a layer): printed to stderr, never counted.
    pub fn other_messages(&self) -> Vec<ValidationMessage> {
        self.others.lock().map(|m| m.clone()).unwrap_or_default()
    }
    /// Messages on the allow-list ([`ALLOWED_MESSAGES`]): kept, not printed, not counted.
    pub fn allowed_messages(&self) -> Vec<ValidationMessage> {
        self.allowed.lock().map(|m| m.clone()).unwrap_or_default()
    }
    fn push_allowed(&self, m: ValidationMessage) {
        if let Ok(mut v) = self.allowed.lock() {
            v.push(m);
        }
    }
    fn push_other(&self, m: ValidationMessage) {
        eprintln!(
            "vulkan {:?} (not validation, not counted): {}",
            m.severity, m.text
        );
        if let Ok(mut v) = self.others.lock() {
            v.push(m);
        }
    }
    fn push(&self, m: ValidationMessage) {
        if self.echo {
            eprintln!("validation {:?}: {}", m.severity, m.text);
        }
        if let Ok(mut v) = self.messages.lock() {
            v.push(m);
        }
    }
}

unsafe extern "system" fn debug_callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user: *mut c_void,
) -> vk::Bool32 {
    let sev = if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR) {
        Severity::Error
    } else if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::WARNING) {
        Severity::Warning
    } else {
        return vk::FALSE;
    };
    if user.is_null() || data.is_null() {
        return vk::FALSE;
    }
    // SAFETY: `user` is the pointer from `Arc::into_raw` that the context keeps alive until after
    // the messenger and instance are destroyed; `data` is valid for the callback's duration.
    let (log, data) = unsafe { (&*(user as *const ValidationLog), &*data) };
    // SAFETY: the strings are null-terminated and valid for the duration of the callback.
    let id = unsafe { data.message_id_name_as_c_str() }
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    // SAFETY: as above.
    let text = unsafe { data.message_as_c_str() }
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let message = ValidationMessage {
        severity: sev,
        id,
        text,
    };
    if allowed(&message.id) {
        log.push_allowed(message);
    } else if is_validation_message(types, &message.id) {
        log.push(message);
    } else {
        log.push_other(message);
    }
    vk::FALSE
}

/// Validation messages that do not fail a run, by message ID, each with the reason. This is
/// the one allow-list; keep it short.
pub const ALLOWED_MESSAGES: &[(&str, &str)] = &[
    (
        "UNASSIGNED-BestPractices-vkCreateInstance-specialuse-extension-debugging",
        "best practices advises against VK_EXT_debug_utils and VK_EXT_validation_features, \
         which are enabled only together with the validation layer, to capture and configure it",
    ),
    (
        "UNASSIGNED-BestPractices-SpirvDeprecated_WorkgroupSize",
        "glslang declares the WorkgroupSize built-in in every compute shader; it is deprecated \
         only from SPIR-V 1.6 and ours are SPIR-V 1.5 (Vulkan 1.2 target), but layer 1.3.239 \
         warns whatever the module's version",
    ),
];

/// Whether a message ID is on [`ALLOWED_MESSAGES`].
fn allowed(id: &str) -> bool {
    ALLOWED_MESSAGES.iter().any(|(allowed, _)| *allowed == id)
}

/// Message-ID prefixes of the Khronos validation layer (core checks, object tracker, thread
/// safety, synchronization validation, best practices).
const VALIDATION_ID_PREFIXES: &[&str] = &["VUID-", "UNASSIGNED-", "SYNC-", "BestPractices-"];

/// Whether a debug-utils message comes from the validation layer (and so counts as a failure):
/// its type is VALIDATION or its ID is one of the layer's. The loader and other layers (a
/// capture layer, an overlay) send GENERAL messages without such IDs.
pub(crate) fn is_validation_message(types: vk::DebugUtilsMessageTypeFlagsEXT, id: &str) -> bool {
    types.contains(vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION)
        || VALIDATION_ID_PREFIXES.iter().any(|p| id.starts_with(p))
}

/// How to create a context.
#[derive(Clone, Debug, Default)]
pub struct ContextOptions {
    /// Enable `VK_LAYER_KHRONOS_validation` and capture its messages (an error if not installed).
    pub validation: bool,
    /// Print captured messages to stderr as they arrive.
    pub echo_validation: bool,
    /// With `validation`: also enable synchronization validation and best practices
    /// (`VkValidationFeaturesEXT`). [`GpuContext::headless`] (the test suite's contexts) turns
    /// it on; `COHERENT_STRICT_VALIDATION=1` (or `=0`) turns it on (off) for every validated
    /// context.
    pub strict_validation: bool,
    /// Pick the first device whose name contains this (case-insensitive). `COHERENT_DEVICE`
    /// is used when this is `None`.
    pub device_filter: Option<String>,
    /// Instance extensions needed by the caller (e.g. surface extensions for a window).
    pub instance_extensions: Vec<CString>,
    /// Device extensions needed by the caller (e.g. `VK_KHR_swapchain`).
    pub device_extensions: Vec<CString>,
    /// At most this many bytes of GPU memory may be allocated through the context; an
    /// allocation beyond it fails with [`Error::OutOfDeviceMemory`] (`None`: no budget).
    pub memory_budget: Option<u64>,
    /// Device limits to lower below what the device reports, so that lavapipe runs the code
    /// paths of devices with smaller limits (tests); see [`LimitOverrides`].
    pub lower_limits: LimitOverrides,
    /// Leave `VK_EXT_conditional_rendering` off even where the device has it, to run what a
    /// device without it does (tests).
    pub without_conditional_rendering: bool,
}

/// Limits a context uses below the device's (each `None` keeps the device's; a value above the
/// device's is ignored: a limit is only ever lowered). Every check and every split of work
/// reads [`DeviceInfo`], so a lowered limit takes the same paths a device with that limit
/// would.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LimitOverrides {
    /// `maxFramebufferLayers`.
    pub max_framebuffer_layers: Option<u32>,
    /// `maxImageArrayLayers`.
    pub max_image_array_layers: Option<u32>,
    /// `maxComputeWorkGroupCount`.
    pub max_compute_work_group_count: Option<[u32; 3]>,
    /// `maxStorageBufferRange`.
    pub max_storage_buffer_range: Option<u32>,
}

/// What the context's allocator holds (gpu-allocator's report), for soak runs and leak checks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MemoryUsage {
    /// Bytes in live allocations.
    pub allocated_bytes: u64,
    /// Bytes of device memory blocks the allocator holds (allocated or free within a block).
    pub capacity_bytes: u64,
    /// Live allocations.
    pub allocations: usize,
    /// Device memory blocks.
    pub blocks: usize,
}

/// What was chosen and why, for `coherent info`.
#[derive(Clone, Debug)]
pub struct DeviceInfo {
    /// Device name, e.g. "llvmpipe (LLVM 15.0.6, 256 bits)".
    pub name: String,
    /// Device type as text.
    pub device_type: String,
    /// Driver name and info.
    pub driver: String,
    /// The device's Vulkan version, "1.3.238".
    pub api_version: String,
    /// Why this device was chosen.
    pub reason: String,
    /// All devices that were seen.
    pub candidates: Vec<String>,
    /// Nanoseconds per timestamp tick.
    pub timestamp_period_ns: f32,
    /// Whether validation is on.
    pub validation: bool,
    /// Largest 2D-array layer count.
    pub max_image_array_layers: u32,
    /// Largest layer count of a (layered) rendering.
    pub max_framebuffer_layers: u32,
    /// Largest width or height of a 2D image.
    pub max_image_dimension_2d: u32,
    /// Largest width and height of a rendering area.
    pub max_framebuffer_size: (u32, u32),
    /// Largest range of one storage-buffer descriptor, in bytes.
    pub max_storage_buffer_range: u32,
    /// Largest range of one uniform-buffer descriptor, in bytes.
    pub max_uniform_buffer_range: u32,
    /// Largest push-constant block, in bytes.
    pub max_push_constants_size: u32,
    /// Largest local workgroup size of a compute shader, per dimension.
    pub max_compute_work_group_size: [u32; 3],
    /// Largest number of invocations in one compute workgroup.
    pub max_compute_work_group_invocations: u32,
    /// Largest number of workgroups of one dispatch, per dimension.
    pub max_compute_work_group_count: [u32; 3],
    /// Largest draw count of one indirect draw.
    pub max_draw_indirect_count: u32,
    /// Most storage images one shader stage may access.
    pub max_per_stage_storage_images: u32,
    /// Optional features found on the device (and enabled when present).
    pub optional: OptionalFeatures,
}

impl DeviceInfo {
    /// Whether the device is a CPU implementation (lavapipe) rather than a GPU: rasterization
    /// then costs CPU time, which changes what pays in the predicated mode
    /// ([`crate::culling::ChcppParams::for_gpu`]).
    pub fn is_cpu(&self) -> bool {
        self.device_type == format!("{:?}", vk::PhysicalDeviceType::CPU)
    }

    /// [`Error::Limit`] unless `value <= max`.
    fn within(what: &str, limit: &'static str, value: u64, max: u64) -> Result<()> {
        if value <= max {
            Ok(())
        } else {
            Err(Error::Limit {
                what: what.to_string(),
                limit,
                value,
                max,
            })
        }
    }

    /// A 2D (array) image of `width`x`height`x`layers` fits `maxImageDimension2D` and
    /// `maxImageArrayLayers`, and, when `attachment`, the rendering area limits
    /// `maxFramebufferWidth`/`Height`.
    pub fn check_image(
        &self,
        what: &str,
        (w, h): (u32, u32),
        layers: u32,
        attachment: bool,
    ) -> Result<()> {
        let dim = u64::from(self.max_image_dimension_2d);
        Self::within(what, "maxImageDimension2D", u64::from(w.max(h)), dim)?;
        Self::within(
            what,
            "maxImageArrayLayers",
            layers.into(),
            self.max_image_array_layers.into(),
        )?;
        if attachment {
            let (fw, fh) = self.max_framebuffer_size;
            Self::within(what, "maxFramebufferWidth", w.into(), fw.into())?;
            Self::within(what, "maxFramebufferHeight", h.into(), fh.into())?;
        }
        Ok(())
    }

    /// A layered rendering over `layers` layers fits `maxFramebufferLayers`.
    pub fn check_framebuffer_layers(&self, what: &str, layers: u32) -> Result<()> {
        Self::within(
            what,
            "maxFramebufferLayers",
            layers.into(),
            self.max_framebuffer_layers.into(),
        )
    }

    /// A storage-buffer descriptor over `bytes` fits `maxStorageBufferRange`.
    pub fn check_storage_buffer(&self, what: &str, bytes: u64) -> Result<()> {
        Self::within(
            what,
            "maxStorageBufferRange",
            bytes,
            self.max_storage_buffer_range.into(),
        )
    }

    /// A push-constant block of `bytes` fits `maxPushConstantsSize`.
    pub fn check_push_constants(&self, what: &str, bytes: u32) -> Result<()> {
        Self::within(
            what,
            "maxPushConstantsSize",
            bytes.into(),
            self.max_push_constants_size.into(),
        )
    }

    /// A compute shader's local size fits `maxComputeWorkGroupSize` and
    /// `maxComputeWorkGroupInvocations`.
    pub fn check_workgroup(&self, what: &str, size: [u32; 3]) -> Result<()> {
        const NAMES: [&str; 3] = [
            "maxComputeWorkGroupSize[0]",
            "maxComputeWorkGroupSize[1]",
            "maxComputeWorkGroupSize[2]",
        ];
        for ((name, v), max) in NAMES.iter().zip(size).zip(self.max_compute_work_group_size) {
            Self::within(what, name, v.into(), max.into())?;
        }
        let invocations = size.iter().map(|&v| u64::from(v)).product();
        let max = self.max_compute_work_group_invocations.into();
        Self::within(what, "maxComputeWorkGroupInvocations", invocations, max)
    }

    /// Lowers the limits named in `lower` (never raises one).
    pub fn lower_limits(&mut self, lower: &LimitOverrides) {
        let min = |v: &mut u32, o: Option<u32>| *v = o.map_or(*v, |o| o.min(*v));
        min(
            &mut self.max_framebuffer_layers,
            lower.max_framebuffer_layers,
        );
        min(
            &mut self.max_image_array_layers,
            lower.max_image_array_layers,
        );
        min(
            &mut self.max_storage_buffer_range,
            lower.max_storage_buffer_range,
        );
        if let Some(counts) = lower.max_compute_work_group_count {
            for (v, o) in self.max_compute_work_group_count.iter_mut().zip(counts) {
                min(v, Some(o));
            }
        }
    }

    /// A dispatch of `groups` workgroups fits `maxComputeWorkGroupCount`.
    pub fn check_dispatch(&self, what: &str, groups: [u32; 3]) -> Result<()> {
        Self::check_group_count(what, groups, self.max_compute_work_group_count)
    }

    /// [`DeviceInfo::check_dispatch`] against the limit `max` (the recorder keeps a copy).
    pub(crate) fn check_group_count(what: &str, groups: [u32; 3], max: [u32; 3]) -> Result<()> {
        const NAMES: [&str; 3] = [
            "maxComputeWorkGroupCount[0]",
            "maxComputeWorkGroupCount[1]",
            "maxComputeWorkGroupCount[2]",
        ];
        for ((name, v), max) in NAMES.iter().zip(groups).zip(max) {
            Self::within(what, name, v.into(), max.into())?;
        }
        Ok(())
    }
}

/// Optional device features: enabled when the device has them; the code that needs one checks
/// it here and falls back or reports [`Error::Unsupported`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct OptionalFeatures {
    /// `vkCmdDrawIndexedIndirectCount` (Vulkan 1.2 `drawIndirectCount`).
    pub draw_indirect_count: bool,
    /// Indirect draws with more than one command (`multiDrawIndirect`).
    pub multi_draw_indirect: bool,
    /// Indirect draw commands with a non-zero `firstInstance` (`drawIndirectFirstInstance`).
    pub draw_indirect_first_instance: bool,
    /// Min/max reduction samplers (Vulkan 1.2 `samplerFilterMinmax`).
    pub sampler_filter_minmax: bool,
    /// D32_SFLOAT images can be sampled (optimal tiling): compute passes read the depth target.
    pub depth_sampled: bool,
    /// R32_SFLOAT images can be storage images and sampled (optimal tiling): the depth pyramid.
    pub r32f_storage: bool,
    /// `gl_ClipDistance` in shaders (`shaderClipDistance`): the GI shadow maps clip at the
    /// hemisphere's base plane in fixed function (else in the vertex shader, slower).
    pub shader_clip_distance: bool,
    /// `VK_EXT_conditional_rendering` with its `conditionalRendering` feature: draws under a
    /// query's predicate (the predicated latency mode).
    pub conditional_rendering: bool,
    /// Storage-buffer writes from fragment shaders (`fragmentStoresAndAtomics`): the box
    /// oracle (`oracle-box`) marks the objects whose box passed the depth test.
    pub fragment_stores: bool,
}

/// The features `coherent` relies on, for `coherent info`.
pub const REQUIRED_FEATURES: &[&str] = &[
    "Vulkan 1.3",
    "dynamicRendering",
    "synchronization2",
    "maintenance4",
    "hostQueryReset",
    "occlusionQueryPrecise",
    "shaderOutputLayer",
    "timelineSemaphore",
];

/// Instance, device, queue and allocator. Create it with [`GpuContext::headless`] (tests,
/// benchmarks) or [`GpuContext::new`]; share it with `Arc`. GPU resources hold an `Arc` to it, so
/// it is destroyed last.
pub struct GpuContext {
    /// The loaded Vulkan entry points.
    pub entry: ash::Entry,
    /// The instance.
    pub instance: ash::Instance,
    /// The chosen physical device.
    pub physical_device: vk::PhysicalDevice,
    /// The logical device.
    pub device: ash::Device,
    /// The graphics queue.
    pub queue: vk::Queue,
    /// Its family.
    pub queue_family: u32,
    /// What was chosen.
    pub info: DeviceInfo,
    allocator: ManuallyDrop<Mutex<Allocator>>,
    memory_budget: Option<u64>,
    debug: Option<(ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    log: Arc<ValidationLog>,
    log_raw: *const ValidationLog,
}

// SAFETY: the raw log pointer is only read by the validation callback (it points at data behind an
// `Arc` that lives as long as the context); every other field is Send + Sync.
unsafe impl Send for GpuContext {}
// SAFETY: as above.
unsafe impl Sync for GpuContext {}

impl GpuContext {
    /// A context with strict validation on (core checks, synchronization validation and best
    /// practices, see [`ContextOptions::strict_validation`]), for tests:
    /// `GpuContext::headless()?`.
    pub fn headless() -> Result<Arc<GpuContext>> {
        Self::new(&ContextOptions {
            validation: true,
            strict_validation: true,
            ..Default::default()
        })
    }

    /// Creates instance, device and allocator.
    pub fn new(options: &ContextOptions) -> Result<Arc<GpuContext>> {
        // SAFETY: loading the system Vulkan loader; no other Vulkan state exists yet.
        let entry = unsafe { ash::Entry::load() }.map_err(|e| {
            Error::Loader(format!("{e} (install libvulkan1 and mesa-vulkan-drivers)"))
        })?;
        let log = Arc::new(ValidationLog {
            messages: Mutex::default(),
            others: Mutex::default(),
            allowed: Mutex::default(),
            echo: options.echo_validation,
        });
        let log_raw = Arc::into_raw(log.clone());
        match Self::create(entry, options, log, log_raw) {
            Ok(ctx) => Ok(Arc::new(ctx)),
            Err(e) => {
                // SAFETY: the pointer came from Arc::into_raw above and nothing else uses it now.
                unsafe { drop(Arc::from_raw(log_raw)) };
                Err(e)
            }
        }
    }

    fn create(
        entry: ash::Entry,
        options: &ContextOptions,
        log: Arc<ValidationLog>,
        log_raw: *const ValidationLog,
    ) -> Result<GpuContext> {
        let instance = create_instance(&entry, options, log_raw)?;
        let mut partial = Partial {
            instance: Some(instance.clone()),
            debug: None,
            device: None,
        };
        if options.validation {
            let du = ext::debug_utils::Instance::new(&entry, &instance);
            // SAFETY: valid instance; the user data outlives the messenger.
            let messenger =
                unsafe { du.create_debug_utils_messenger(&messenger_info(log_raw), None) }
                    .vk("vkCreateDebugUtilsMessengerEXT")?;
            partial.debug = Some((du, messenger));
        }
        let filter = options.device_filter.clone().or_else(|| {
            std::env::var("COHERENT_DEVICE")
                .ok()
                .filter(|s| !s.is_empty())
        });
        let (physical_device, queue_family, mut info) = pick_device(&instance, filter.as_deref())?;
        info.validation = options.validation;
        info.lower_limits(&options.lower_limits);
        check_features(&instance, physical_device)?;
        info.optional = optional_features(&instance, physical_device);
        info.optional.conditional_rendering &= !options.without_conditional_rendering;
        let device = create_device(
            &instance,
            physical_device,
            queue_family,
            options,
            info.optional,
        )?;
        partial.device = Some(device.clone());
        // SAFETY: the family was created with one queue.
        let queue = unsafe { device.get_device_queue(queue_family, 0) };
        let allocator = Allocator::new(&AllocatorCreateDesc {
            instance: instance.clone(),
            device: device.clone(),
            physical_device,
            debug_settings: Default::default(),
            buffer_device_address: false,
            allocation_sizes: Default::default(),
        })
        .map_err(|e| Error::from_alloc("the allocator", e))?;
        let debug = partial.debug.take();
        partial.instance = None;
        partial.device = None;
        Ok(GpuContext {
            entry,
            instance,
            physical_device,
            device,
            queue,
            queue_family,
            info,
            allocator: ManuallyDrop::new(Mutex::new(allocator)),
            memory_budget: options.memory_budget,
            debug,
            log,
            log_raw,
        })
    }

    /// The validation messages of this context (shared; survives the context).
    pub fn validation_log(&self) -> Arc<ValidationLog> {
        self.log.clone()
    }

    /// The memory allocator.
    pub(crate) fn allocator(&self) -> std::sync::MutexGuard<'_, Allocator> {
        // A poisoned lock only means another thread panicked mid-allocation; the allocator's
        // bookkeeping is still usable for freeing.
        self.allocator.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The memory budget of [`ContextOptions::memory_budget`].
    pub fn memory_budget(&self) -> Option<u64> {
        self.memory_budget
    }

    /// What the allocator holds now.
    pub fn memory_usage(&self) -> MemoryUsage {
        let report = self.allocator().generate_report();
        MemoryUsage {
            allocated_bytes: report.total_allocated_bytes,
            capacity_bytes: report.total_capacity_bytes,
            allocations: report.allocations.len(),
            blocks: report.blocks.len(),
        }
    }

    /// Waits until the device is idle.
    pub fn wait_idle(&self) -> Result<()> {
        // SAFETY: valid device.
        unsafe { self.device.device_wait_idle() }.vk("vkDeviceWaitIdle")
    }

    /// Deliberately breaks a valid-usage rule once (a buffer with no usage flags), so tests can
    /// prove that this context's messenger captures errors. The buffer is destroyed again.
    #[doc(hidden)]
    pub fn provoke_validation_error(&self) -> Result<()> {
        let info = vk::BufferCreateInfo::default()
            .size(256)
            .usage(vk::BufferUsageFlags::empty())
            .sharing_mode(vk::SharingMode::EXCLUSIVE);
        // SAFETY: lavapipe accepts an empty usage mask; the layer reports it, which is the point.
        let buffer = unsafe { self.device.create_buffer(&info, None) }.vk("vkCreateBuffer")?;
        // SAFETY: created above, never used.
        unsafe { self.device.destroy_buffer(buffer, None) };
        Ok(())
    }
}

/// Cleans up a half-built context when creation fails.
struct Partial {
    instance: Option<ash::Instance>,
    debug: Option<(ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    device: Option<ash::Device>,
}

impl Drop for Partial {
    fn drop(&mut self) {
        // SAFETY: objects created by this module and not handed out; destroyed in reverse order.
        unsafe {
            if let Some(d) = self.device.take() {
                d.destroy_device(None);
            }
            if let Some((du, m)) = self.debug.take() {
                du.destroy_debug_utils_messenger(m, None);
            }
            if let Some(i) = self.instance.take() {
                i.destroy_instance(None);
            }
        }
    }
}

impl Drop for GpuContext {
    fn drop(&mut self) {
        // SAFETY: every resource holds an Arc to this context, so none is alive now; the
        // allocator goes before the device, the messenger before the instance, and the log's
        // raw pointer is released last.
        unsafe {
            let _ = self.device.device_wait_idle();
            ManuallyDrop::drop(&mut self.allocator);
            self.device.destroy_device(None);
            if let Some((du, m)) = self.debug.take() {
                du.destroy_debug_utils_messenger(m, None);
            }
            self.instance.destroy_instance(None);
            drop(Arc::from_raw(self.log_raw));
        }
    }
}

fn version_string(v: u32) -> String {
    format!(
        "{}.{}.{}",
        vk::api_version_major(v),
        vk::api_version_minor(v),
        vk::api_version_patch(v)
    )
}

/// The messenger that captures warnings and errors into the log behind `log_raw`.
fn messenger_info(log_raw: *const ValidationLog) -> vk::DebugUtilsMessengerCreateInfoEXT<'static> {
    vk::DebugUtilsMessengerCreateInfoEXT::default()
        .message_severity(
            vk::DebugUtilsMessageSeverityFlagsEXT::WARNING
                | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
        )
        .message_type(
            vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
        )
        .pfn_user_callback(Some(debug_callback))
        .user_data(log_raw as *mut c_void)
}

/// A Vulkan 1.3 instance with the caller's extensions and, when asked, the validation layer
/// (its messenger also covers instance creation and destruction).
fn create_instance(
    entry: &ash::Entry,
    options: &ContextOptions,
    log_raw: *const ValidationLog,
) -> Result<ash::Instance> {
    // SAFETY: plain query of the loader.
    let version = unsafe { entry.try_enumerate_instance_version() }
        .vk("vkEnumerateInstanceVersion")?
        .unwrap_or(vk::API_VERSION_1_0);
    if version < vk::API_VERSION_1_3 {
        return Err(Error::Unsupported {
            feature: "Vulkan 1.3 instance".into(),
        });
    }
    let mut layers: Vec<*const i8> = Vec::new();
    let mut extensions: Vec<*const i8> = options
        .instance_extensions
        .iter()
        .map(|e| e.as_ptr())
        .collect();
    if options.validation {
        require_validation_layer(entry)?;
        layers.push(VALIDATION_LAYER.as_ptr());
        extensions.push(ext::debug_utils::NAME.as_ptr());
    }
    let app = vk::ApplicationInfo::default()
        .application_name(c"coherent")
        .engine_name(c"coherent")
        .api_version(vk::API_VERSION_1_3);
    let strict = options.validation && strict_validation(options);
    if strict {
        extensions.push(ext::validation_features::NAME.as_ptr());
    }
    let mut messenger = messenger_info(log_raw);
    let mut features = vk::ValidationFeaturesEXT::default()
        .enabled_validation_features(STRICT_VALIDATION_FEATURES);
    let mut create_info = vk::InstanceCreateInfo::default()
        .application_info(&app)
        .enabled_layer_names(&layers)
        .enabled_extension_names(&extensions);
    if options.validation {
        create_info = create_info.push_next(&mut messenger);
    }
    if strict {
        create_info = create_info.push_next(&mut features);
    }
    // SAFETY: all pointers in create_info outlive the call.
    unsafe { entry.create_instance(&create_info, None) }.vk("vkCreateInstance")
}

/// What strict validation adds to the layer's core checks.
const STRICT_VALIDATION_FEATURES: &[vk::ValidationFeatureEnableEXT] = &[
    vk::ValidationFeatureEnableEXT::SYNCHRONIZATION_VALIDATION,
    vk::ValidationFeatureEnableEXT::BEST_PRACTICES,
];

/// Whether the options ask for strict validation; `COHERENT_STRICT_VALIDATION=1` or `=0`
/// overrides them.
fn strict_validation(options: &ContextOptions) -> bool {
    match std::env::var("COHERENT_STRICT_VALIDATION").as_deref() {
        Ok("1") => true,
        Ok("0") => false,
        _ => options.strict_validation,
    }
}

/// An error naming the package when the Khronos validation layer is not installed.
fn require_validation_layer(entry: &ash::Entry) -> Result<()> {
    // SAFETY: plain query of the loader.
    let available = unsafe { entry.enumerate_instance_layer_properties() }
        .vk("vkEnumerateInstanceLayerProperties")?;
    let found = available.iter().any(|l| {
        l.layer_name_as_c_str()
            .map(|n| n == VALIDATION_LAYER)
            .unwrap_or(false)
    });
    if found {
        Ok(())
    } else {
        Err(Error::Unsupported {
            feature: "VK_LAYER_KHRONOS_validation (apt install vulkan-validationlayers)".into(),
        })
    }
}

/// The logical device with one queue of `family` and every feature of [`REQUIRED_FEATURES`].
fn create_device(
    instance: &ash::Instance,
    physical_device: vk::PhysicalDevice,
    family: u32,
    options: &ContextOptions,
    optional: OptionalFeatures,
) -> Result<ash::Device> {
    let priorities = [1.0f32];
    let queue_info = [vk::DeviceQueueCreateInfo::default()
        .queue_family_index(family)
        .queue_priorities(&priorities)];
    let features10 = vk::PhysicalDeviceFeatures::default()
        .occlusion_query_precise(true)
        .multi_draw_indirect(optional.multi_draw_indirect)
        .draw_indirect_first_instance(optional.draw_indirect_first_instance)
        .shader_clip_distance(optional.shader_clip_distance)
        .fragment_stores_and_atomics(optional.fragment_stores);
    let mut features12 = vk::PhysicalDeviceVulkan12Features::default()
        .host_query_reset(true)
        .shader_output_layer(true)
        .timeline_semaphore(true)
        .draw_indirect_count(optional.draw_indirect_count)
        .sampler_filter_minmax(optional.sampler_filter_minmax);
    let mut features13 = vk::PhysicalDeviceVulkan13Features::default()
        .dynamic_rendering(true)
        .synchronization2(true)
        .maintenance4(true);
    let mut dev_ext: Vec<*const i8> = options
        .device_extensions
        .iter()
        .map(|e| e.as_ptr())
        .collect();
    let mut conditional =
        vk::PhysicalDeviceConditionalRenderingFeaturesEXT::default().conditional_rendering(true);
    let mut device_info = vk::DeviceCreateInfo::default()
        .queue_create_infos(&queue_info)
        .enabled_features(&features10)
        .push_next(&mut features12)
        .push_next(&mut features13);
    if optional.conditional_rendering {
        dev_ext.push(ext::conditional_rendering::NAME.as_ptr());
        device_info = device_info.push_next(&mut conditional);
    }
    let device_info = device_info.enabled_extension_names(&dev_ext);
    // SAFETY: physical device from this instance; pointers outlive the call.
    unsafe { instance.create_device(physical_device, &device_info, None) }.vk("vkCreateDevice")
}

/// Chooses the device: the best type (discrete > integrated > virtual > CPU) among Vulkan 1.3
/// devices with a graphics queue that has timestamps, or the first whose name contains
/// `filter`. Returns it, its queue family and a description.
fn pick_device(
    instance: &ash::Instance,
    filter: Option<&str>,
) -> Result<(vk::PhysicalDevice, u32, DeviceInfo)> {
    // SAFETY: valid instance.
    let devices =
        unsafe { instance.enumerate_physical_devices() }.vk("vkEnumeratePhysicalDevices")?;
    let mut candidates = Vec::new();
    let mut best: Option<(i32, vk::PhysicalDevice, u32, DeviceInfo)> = None;
    for pd in devices {
        let (props, info) = describe(instance, pd);
        candidates.push(format!("{} ({:?})", info.name, props.device_type));
        let Some(family) = graphics_family(instance, pd) else {
            continue;
        };
        let (score, why) = type_score(props.device_type);
        if filter.is_some_and(|f| !info.name.to_lowercase().contains(&f.to_lowercase())) {
            continue;
        }
        if props.api_version < vk::API_VERSION_1_3 {
            continue;
        }
        let reason = match filter {
            Some(f) => format!("COHERENT_DEVICE/--device matched \"{f}\""),
            None => format!("preferred {why}"),
        };
        if best.as_ref().map(|b| score > b.0).unwrap_or(true) {
            best = Some((score, pd, family, DeviceInfo { reason, ..info }));
        }
    }
    match best {
        Some((_, pd, fam, mut info)) => {
            info.candidates = candidates;
            Ok((pd, fam, info))
        }
        None => Err(no_device(filter, &candidates)),
    }
}

/// A device's properties and its description (reason and candidates left empty).
fn describe(
    instance: &ash::Instance,
    pd: vk::PhysicalDevice,
) -> (vk::PhysicalDeviceProperties, DeviceInfo) {
    // SAFETY: pd from this instance.
    let props = unsafe { instance.get_physical_device_properties(pd) };
    let mut driver = vk::PhysicalDeviceDriverProperties::default();
    let mut props2 = vk::PhysicalDeviceProperties2::default().push_next(&mut driver);
    // SAFETY: as above.
    unsafe { instance.get_physical_device_properties2(pd, &mut props2) };
    let text = |s: std::result::Result<&CStr, _>| {
        s.map(|s: &CStr| s.to_string_lossy().into_owned())
            .unwrap_or_default()
    };
    let driver_name = format!(
        "{} {}",
        text(driver.driver_name_as_c_str()),
        text(driver.driver_info_as_c_str())
    );
    let info = DeviceInfo {
        name: text(props.device_name_as_c_str()),
        device_type: format!("{:?}", props.device_type),
        driver: driver_name.trim().to_string(),
        api_version: version_string(props.api_version),
        reason: String::new(),
        candidates: Vec::new(),
        timestamp_period_ns: props.limits.timestamp_period,
        validation: false,
        max_image_array_layers: props.limits.max_image_array_layers,
        max_framebuffer_layers: props.limits.max_framebuffer_layers,
        max_image_dimension_2d: props.limits.max_image_dimension2_d,
        max_framebuffer_size: (
            props.limits.max_framebuffer_width,
            props.limits.max_framebuffer_height,
        ),
        max_storage_buffer_range: props.limits.max_storage_buffer_range,
        max_uniform_buffer_range: props.limits.max_uniform_buffer_range,
        max_push_constants_size: props.limits.max_push_constants_size,
        max_compute_work_group_size: props.limits.max_compute_work_group_size,
        max_compute_work_group_invocations: props.limits.max_compute_work_group_invocations,
        max_compute_work_group_count: props.limits.max_compute_work_group_count,
        max_draw_indirect_count: props.limits.max_draw_indirect_count,
        optional: OptionalFeatures::default(),
        max_per_stage_storage_images: props.limits.max_per_stage_descriptor_storage_images,
    };
    (props, info)
}

/// The first queue family with graphics and timestamps.
fn graphics_family(instance: &ash::Instance, pd: vk::PhysicalDevice) -> Option<u32> {
    // SAFETY: pd from this instance.
    let families = unsafe { instance.get_physical_device_queue_family_properties(pd) };
    families
        .iter()
        .position(|f| {
            f.queue_flags.contains(vk::QueueFlags::GRAPHICS) && f.timestamp_valid_bits > 0
        })
        .map(|i| i as u32)
}

/// Preference of a device type, and how to say it.
fn type_score(ty: vk::PhysicalDeviceType) -> (i32, &'static str) {
    match ty {
        vk::PhysicalDeviceType::DISCRETE_GPU => (4, "a discrete GPU"),
        vk::PhysicalDeviceType::INTEGRATED_GPU => (3, "an integrated GPU"),
        vk::PhysicalDeviceType::VIRTUAL_GPU => (2, "a virtual GPU"),
        vk::PhysicalDeviceType::CPU => (1, "the CPU device (no GPU present)"),
        _ => (0, "the only device"),
    }
}

/// The error when no device qualifies, listing what was seen.
fn no_device(filter: Option<&str>, candidates: &[String]) -> Error {
    let seen = if candidates.is_empty() {
        "none".to_string()
    } else {
        candidates.join(", ")
    };
    Error::Unsupported {
        feature: match filter {
            Some(f) => format!(
                "a Vulkan 1.3 device matching \"{f}\" with a graphics queue (seen: {seen})"
            ),
            None => format!(
                "a Vulkan 1.3 device with a graphics queue (seen: {seen}); install mesa-vulkan-drivers"
            ),
        },
    }
}

/// Which of the [`OptionalFeatures`] the device has.
fn optional_features(instance: &ash::Instance, pd: vk::PhysicalDevice) -> OptionalFeatures {
    // SAFETY: valid physical device; a plain query.
    let has_conditional = unsafe { instance.enumerate_device_extension_properties(pd) }
        .unwrap_or_default()
        .iter()
        .any(|e| e.extension_name_as_c_str() == Ok(ext::conditional_rendering::NAME));
    let mut f12 = vk::PhysicalDeviceVulkan12Features::default();
    let mut cr = vk::PhysicalDeviceConditionalRenderingFeaturesEXT::default();
    let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut f12);
    if has_conditional {
        f2 = f2.push_next(&mut cr);
    }
    // SAFETY: valid physical device; the chain outlives the call.
    unsafe { instance.get_physical_device_features2(pd, &mut f2) };
    let f10 = f2.features;
    let has = |format: vk::Format, wanted: vk::FormatFeatureFlags| {
        // SAFETY: valid physical device; a plain query.
        unsafe { instance.get_physical_device_format_properties(pd, format) }
            .optimal_tiling_features
            .contains(wanted)
    };
    OptionalFeatures {
        depth_sampled: has(
            vk::Format::D32_SFLOAT,
            vk::FormatFeatureFlags::SAMPLED_IMAGE,
        ),
        r32f_storage: has(
            vk::Format::R32_SFLOAT,
            vk::FormatFeatureFlags::STORAGE_IMAGE | vk::FormatFeatureFlags::SAMPLED_IMAGE,
        ),
        draw_indirect_count: f12.draw_indirect_count != 0,
        multi_draw_indirect: f10.multi_draw_indirect != 0,
        draw_indirect_first_instance: f10.draw_indirect_first_instance != 0,
        sampler_filter_minmax: f12.sampler_filter_minmax != 0,
        shader_clip_distance: f10.shader_clip_distance != 0,
        conditional_rendering: has_conditional && cr.conditional_rendering != 0,
        fragment_stores: f10.fragment_stores_and_atomics != 0,
    }
}

fn check_features(instance: &ash::Instance, pd: vk::PhysicalDevice) -> Result<()> {
    let mut f12 = vk::PhysicalDeviceVulkan12Features::default();
    let mut f13 = vk::PhysicalDeviceVulkan13Features::default();
    let mut f2 = vk::PhysicalDeviceFeatures2::default()
        .push_next(&mut f12)
        .push_next(&mut f13);
    // SAFETY: valid physical device; the chain outlives the call.
    unsafe { instance.get_physical_device_features2(pd, &mut f2) };
    let f10 = f2.features;
    let mut missing = Vec::new();
    if f13.dynamic_rendering == 0 {
        missing.push("dynamicRendering");
    }
    if f13.maintenance4 == 0 {
        missing.push("maintenance4");
    }
    if f13.synchronization2 == 0 {
        missing.push("synchronization2");
    }
    if f12.host_query_reset == 0 {
        missing.push("hostQueryReset");
    }
    if f12.shader_output_layer == 0 {
        missing.push("shaderOutputLayer");
    }
    if f12.timeline_semaphore == 0 {
        missing.push("timelineSemaphore");
    }
    if f10.occlusion_query_precise == 0 {
        missing.push("occlusionQueryPrecise");
    }
    if missing.is_empty() {
        Ok(())
    } else {
        Err(Error::Unsupported {
            feature: missing.join(", "),
        })
    }
}
