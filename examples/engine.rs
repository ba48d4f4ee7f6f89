//! An engine that owns its Vulkan instance, device, frame loop, pipelines and command buffers,
//! written with raw ash, with two frames in flight, reverse-Z with an infinite far plane, its own
//! camera matrices as plain arrays (no glam), and one submission per frame. It culls with
//! `coherent-cull`'s CHC++ in the `predicated` mode (exact: what was invisible is drawn under its
//! query's predicate on the device, `VK_EXT_conditional_rendering`) reading each frame's queries
//! two frames later to steer the next frames, and records the culler's occlusion queries with
//! `coherent-ash`'s `QueryBackend`: the engine creates no query pool and records no query,
//! reset, result copy or predicate itself. On a device without the extension it says so and
//! runs `next-frame` (objects coming into view appear two frames late).
//!
//! Frame N in slot s = N mod 2: wait for slot s's fence (frame N-2: the engine's frame pacing,
//! timed as `pace ms`); begin the command buffer; `QueryBackend::begin_frame` (reads frame N-2's
//! results from host memory, records the reset of the slot's queries); begin rendering;
//! `cull_frame` (draws come back through the engine's draw callback, queries go through the
//! backend; once per frame the backend ends rendering to turn the results into predicates and
//! the engine's resume callback begins it again with LOAD ops); end rendering;
//! `QueryBackend::end_frame` (records the copy of this frame's results); one `vkQueueSubmit`,
//! no wait.
//!
//! Run: `cargo run --release --example engine -- [--frames N] [--policy cpu|gpu]` (validation
//! on; exits non-zero on any validation message, or if a frame submitted more than once or
//! waited). `--policy` picks the predicated mode's policy, which follows the device type by
//! default: `gpu` (`ChcppParams::for_gpu`) keeps one predicate level, `cpu` splits queried
//! nodes into parts.

use std::sync::atomic::Ordering;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use ash::{ext, vk};
use coherent::scene::Scene;
use coherent_ash::{DrawObjects, QueryBackend, QueryBackendDesc};
use coherent_cull::chcpp::{Chcpp, ChcppParams};
use coherent_cull::{CameraView, Culler, DepthConvention, FrameInput, Latency, ObjectBvh};

#[path = "common/raw_host.rs"]
mod raw_host;

use raw_host::{Memory, HEIGHT, MESSAGES, WIDTH};

/// Frames in flight: the engine's own choice, handed to the culler and the query backend.
const FRAMES_IN_FLIGHT: u32 = 2;
const COLOR_FORMAT: vk::Format = vk::Format::R8G8B8A8_UNORM;
const DEPTH_FORMAT: vk::Format = vk::Format::D32_SFLOAT;

// ---------------------------------------------------------------------------------------------
// What concerns the culler: the query backend, the draw callback, the frame.

/// The engine's draws as the culler's "draw these objects": one indexed draw per object; after
/// the query backend's box pipeline was bound (`rebind`), the scene state is bound again.
struct SceneDraws<'a> {
    device: &'a ash::Device,
    scene: &'a SceneState,
    push: &'a [f32; 20],
    draws: &'a mut u32,
    /// Draw orders the culler sent (predicated mode: once, until the hierarchy's leaves change).
    orders: &'a mut u32,
}

impl DrawObjects for SceneDraws<'_> {
    fn draw(
        &mut self,
        cmd: vk::CommandBuffer,
        objects: &[u32],
        rebind: bool,
    ) -> coherent_cull::Result<()> {
        // SAFETY: recording inside the frame's rendering; the scene state is valid.
        unsafe {
            if rebind {
                self.scene.bind(self.device, cmd, self.push);
            }
            for &o in objects {
                let Some(&(count, first, offset)) = self.scene.objects.get(o as usize) else {
                    return Err(coherent_cull::Error::Input(format!("no object {o}")));
                };
                self.device
                    .cmd_draw_indexed(cmd, count, 1, first, offset, o);
            }
        }
        *self.draws += objects.len() as u32;
        Ok(())
    }

    /// An engine with one indirect command per object could lay them out in this order and
    /// draw a run of a predicate's objects as one multi-draw; this one only counts it.
    fn set_order(&mut self, order: &[u32]) -> coherent_cull::Result<()> {
        if order.len() != self.scene.objects.len() {
            return Err(coherent_cull::Error::Input(
                "an order of other objects".into(),
            ));
        }
        *self.orders += 1;
        Ok(())
    }
}

/// Creates the query backend for the engine's depth pass.
fn query_backend(engine: &Engine) -> Result<QueryBackend> {
    let desc = QueryBackendDesc {
        frames_in_flight: FRAMES_IN_FLIGHT,
        depth_format: DEPTH_FORMAT,
        color_formats: vec![COLOR_FORMAT],
        depth: DepthConvention::REVERSE_Z_INFINITE,
        predicates: engine.predicated,
        ..QueryBackendDesc::default()
    };
    // SAFETY: the device was created from this physical device with dynamic rendering and
    // precise occlusion queries, and outlives the backend (dropped first in Engine::drop).
    Ok(unsafe { QueryBackend::new(&engine.instance, engine.physical, &engine.device, desc) }?)
}

/// What one frame did.
#[derive(Default)]
struct FrameReport {
    cull_ms: f64,
    pace_ms: f64,
    draws: u32,
    orders: u32,
    submits: u32,
    /// Times the culler blocked on a result inside the frame (coherent-ash refuses waits, so a
    /// culler that tried would fail the frame instead).
    waits: u32,
    visible_results: u32,
}

/// One frame: pace, begin, cull inside the depth pass, end, submit once.
fn frame(
    engine: &mut Engine,
    queries: &mut QueryBackend,
    culler: &mut Chcpp,
    bvh: &ObjectBvh,
    (frame, view_proj, eye): (u64, [f32; 16], [f32; 3]),
) -> Result<FrameReport> {
    let slot = (frame % u64::from(FRAMES_IN_FLIGHT)) as usize;
    let mut report = FrameReport {
        pace_ms: engine.wait_slot(slot)?,
        ..FrameReport::default()
    };
    engine.push[..16].copy_from_slice(&view_proj);
    let cmd = engine.slots[slot].cmd;
    // SAFETY: the slot's fence was waited for: its command buffer and queries are free.
    unsafe {
        engine.begin_commands(slot)?;
        queries.begin_frame(cmd, slot as u32)?;
        engine.begin_rendering(slot);
    }
    let start = Instant::now();
    let input = FrameInput {
        bvh,
        // One sample a pixel on a WIDTH x HEIGHT target: objects that fall between pixel
        // centres can own no pixel and are culled with those outside the frustum.
        view: CameraView::new(view_proj, eye, DepthConvention::REVERSE_Z_INFINITE)
            .with_pixel_grid(WIDTH, HEIGHT),
        frame,
        exact_visible: None,
    };
    let draws = SceneDraws {
        device: &engine.device,
        scene: &engine.scene,
        push: &engine.push,
        draws: &mut report.draws,
        orders: &mut report.orders,
    };
    let resume = |_cmd| {
        // SAFETY: the backend ended the rendering begun above and recorded its copy.
        unsafe { engine.resume_rendering(slot) };
        Ok(())
    };
    let mut backend = queries.frame(cmd, view_proj, draws).with_resume(resume);
    let stats = culler.cull_frame(&input, &mut backend)?;
    drop(backend);
    report.cull_ms = start.elapsed().as_secs_f64() * 1e3;
    report.visible_results = stats.visible_results;
    // SAFETY: recording inside the rendering begun above.
    unsafe {
        engine.device.cmd_end_rendering(cmd);
        queries.end_frame(cmd)?;
    }
    report.waits = stats.blocking_waits;
    let before = engine.submits;
    engine.submit(slot)?;
    report.submits = engine.submits - before;
    Ok(report)
}

// ---------------------------------------------------------------------------------------------
// The engine's own camera math: column-major [f32; 16], no math crate.

type Mat = [f32; 16];

fn mul(a: &Mat, b: &Mat) -> Mat {
    let mut m = [0.0; 16];
    for c in 0..4 {
        for r in 0..4 {
            m[c * 4 + r] = (0..4).map(|k| a[k * 4 + r] * b[c * 4 + k]).sum();
        }
    }
    m
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn normalize(a: [f32; 3]) -> [f32; 3] {
    let l = dot(a, a).sqrt().max(1e-20);
    [a[0] / l, a[1] / l, a[2] / l]
}

/// Right-handed look-at view matrix (camera looks down -z).
fn look_at(eye: [f32; 3], target: [f32; 3]) -> Mat {
    let f = normalize(sub(target, eye));
    let s = normalize(cross(f, [0.0, 1.0, 0.0]));
    let u = cross(s, f);
    [
        s[0],
        u[0],
        -f[0],
        0.0,
        s[1],
        u[1],
        -f[1],
        0.0,
        s[2],
        u[2],
        -f[2],
        0.0,
        -dot(s, eye),
        -dot(u, eye),
        dot(f, eye),
        1.0,
    ]
}

/// Reverse-Z perspective with an infinite far plane: depth = near / distance (1 at the near
/// plane, 0 at infinity). Clip y up; the viewport flips it.
fn reverse_z_infinite(fov_y: f32, aspect: f32, near: f32) -> Mat {
    let f = 1.0 / (fov_y * 0.5).tan();
    [
        f / aspect,
        0.0,
        0.0,
        0.0,
        0.0,
        f,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        -1.0,
        0.0,
        0.0,
        near,
        0.0,
    ]
}

// ---------------------------------------------------------------------------------------------
// The engine's renderer (nothing here knows about culling).

/// Everything one frame in flight owns.
struct FrameSlot {
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
    color: (vk::Image, vk::ImageView, vk::DeviceMemory),
    depth: (vk::Image, vk::ImageView, vk::DeviceMemory),
}

/// The scene's draw state: pipeline, descriptor set, buffers and each object's index range.
struct SceneState {
    set: raw_host::StorageSet,
    pipeline: vk::Pipeline,
    vertices: vk::Buffer,
    indices: vk::Buffer,
    /// (index count, first index, vertex offset) per object.
    objects: Vec<(u32, u32, i32)>,
}

impl SceneState {
    /// Binds the scene pipeline, its buffers, descriptor set and push constants.
    ///
    /// # Safety
    /// `cmd` is recording inside the frame's rendering.
    unsafe fn bind(&self, device: &ash::Device, cmd: vk::CommandBuffer, push: &[f32; 20]) {
        let mut bytes = [0u8; 80];
        for (chunk, f) in bytes.chunks_exact_mut(4).zip(push) {
            chunk.copy_from_slice(&f.to_le_bytes());
        }
        // SAFETY: per the caller; every handle is valid.
        unsafe {
            raw_host::bind_state(device, cmd, self.pipeline, self.vertices, self.indices);
            device.cmd_bind_descriptor_sets(
                cmd,
                vk::PipelineBindPoint::GRAPHICS,
                self.set.layout,
                0,
                &[self.set.set],
                &[],
            );
            device.cmd_push_constants(
                cmd,
                self.set.layout,
                vk::ShaderStageFlags::VERTEX
                    | vk::ShaderStageFlags::FRAGMENT
                    | vk::ShaderStageFlags::COMPUTE,
                0,
                &bytes,
            );
        }
    }
}

struct Engine {
    _entry: ash::Entry,
    instance: ash::Instance,
    debug: ext::debug_utils::Instance,
    messenger: vk::DebugUtilsMessengerEXT,
    physical: vk::PhysicalDevice,
    device: ash::Device,
    queue: vk::Queue,
    memory_types: vk::PhysicalDeviceMemoryProperties,
    /// Vertex, index and object buffers (never written after creation).
    buffers: Vec<(vk::Buffer, Memory)>,
    scene: SceneState,
    command_pool: vk::CommandPool,
    slots: Vec<FrameSlot>,
    /// View-projection and sun direction, the scene shader's push constants.
    push: [f32; 20],
    /// `vkQueueSubmit` calls so far.
    submits: u32,
    /// The device has `VK_EXT_conditional_rendering` (enabled): the culler runs predicated.
    predicated: bool,
}

const COLOR_WRITE: vk::AccessFlags2 = vk::AccessFlags2::COLOR_ATTACHMENT_WRITE;
const DEPTH_READ_WRITE: vk::AccessFlags2 = vk::AccessFlags2::from_raw(
    vk::AccessFlags2::DEPTH_STENCIL_ATTACHMENT_WRITE.as_raw()
        | vk::AccessFlags2::DEPTH_STENCIL_ATTACHMENT_READ.as_raw(),
);
const DEPTH_STAGES: vk::PipelineStageFlags2 = vk::PipelineStageFlags2::from_raw(
    vk::PipelineStageFlags2::EARLY_FRAGMENT_TESTS.as_raw()
        | vk::PipelineStageFlags2::LATE_FRAGMENT_TESTS.as_raw(),
);

/// A barrier on a whole single-level attachment image: layouts `(old, new)`, within `stage`,
/// accesses `(before, after)`.
fn attachment_barrier(
    image: vk::Image,
    aspect: vk::ImageAspectFlags,
    (old, new): (vk::ImageLayout, vk::ImageLayout),
    stage: vk::PipelineStageFlags2,
    (before, after): (vk::AccessFlags2, vk::AccessFlags2),
) -> vk::ImageMemoryBarrier2<'static> {
    vk::ImageMemoryBarrier2::default()
        .image(image)
        .subresource_range(
            vk::ImageSubresourceRange::default()
                .aspect_mask(aspect)
                .level_count(1)
                .layer_count(1),
        )
        .old_layout(old)
        .new_layout(new)
        .src_stage_mask(stage)
        .src_access_mask(before)
        .dst_stage_mask(stage)
        .dst_access_mask(after)
}

/// Whether the device has `VK_EXT_conditional_rendering` with `conditionalRendering`.
fn has_conditional_rendering(instance: &ash::Instance, physical: vk::PhysicalDevice) -> bool {
    // SAFETY: valid physical device; plain queries.
    let listed = unsafe { instance.enumerate_device_extension_properties(physical) }
        .unwrap_or_default()
        .iter()
        .any(|e| e.extension_name_as_c_str() == Ok(ext::conditional_rendering::NAME));
    let mut cr = vk::PhysicalDeviceConditionalRenderingFeaturesEXT::default();
    let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut cr);
    // SAFETY: as above; the chain outlives the call.
    unsafe { instance.get_physical_device_features2(physical, &mut f2) };
    listed && cr.conditional_rendering != 0
}

fn pick_device(instance: &ash::Instance) -> Result<vk::PhysicalDevice> {
    // SAFETY: valid instance.
    let all = unsafe { instance.enumerate_physical_devices() }?;
    let wanted = std::env::var("COHERENT_DEVICE").unwrap_or_default();
    all.into_iter()
        .find(|&p| {
            // SAFETY: valid physical device.
            let props = unsafe { instance.get_physical_device_properties(p) };
            let name = props
                .device_name_as_c_str()
                .map(|n| n.to_string_lossy().to_lowercase())
                .unwrap_or_default();
            name.contains(&wanted.to_lowercase())
        })
        .context("no Vulkan device (COHERENT_DEVICE names a substring of its name)")
}

impl Engine {
    /// Whether the device is a CPU rasterizer (lavapipe) rather than a GPU.
    fn is_cpu(&self) -> bool {
        // SAFETY: valid physical device of this instance.
        let props = unsafe { self.instance.get_physical_device_properties(self.physical) };
        props.device_type == vk::PhysicalDeviceType::CPU
    }

    fn new(scene: &Scene) -> Result<Engine> {
        let (entry, instance, debug, messenger) = raw_host::instance()?;
        let physical = pick_device(&instance)?;
        // SAFETY: valid physical device.
        let memory_types = unsafe { instance.get_physical_device_memory_properties(physical) };
        let priorities = [1.0];
        let queues = [vk::DeviceQueueCreateInfo::default()
            .queue_family_index(0)
            .queue_priorities(&priorities)];
        let f10 = vk::PhysicalDeviceFeatures::default().occlusion_query_precise(true);
        let mut f13 = vk::PhysicalDeviceVulkan13Features::default()
            .dynamic_rendering(true)
            .synchronization2(true)
            .maintenance4(true);
        // Conditional rendering for the predicated mode, when the device has it.
        let predicated = has_conditional_rendering(&instance, physical);
        let mut conditional = vk::PhysicalDeviceConditionalRenderingFeaturesEXT::default()
            .conditional_rendering(true);
        let extensions = [ext::conditional_rendering::NAME.as_ptr()];
        let mut info = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queues)
            .enabled_features(&f10)
            .push_next(&mut f13);
        if predicated {
            info = info
                .enabled_extension_names(&extensions)
                .push_next(&mut conditional);
        }
        // SAFETY: valid physical device and create info.
        let device = unsafe { instance.create_device(physical, &info, None) }?;
        // SAFETY: family 0 was created with one queue.
        let queue = unsafe { device.get_device_queue(0, 0) };
        let mut engine = Engine {
            _entry: entry,
            instance,
            debug,
            messenger,
            physical,
            device,
            queue,
            memory_types,
            buffers: Vec::new(),
            scene: SceneState {
                set: raw_host::StorageSet::null(),
                pipeline: vk::Pipeline::null(),
                vertices: vk::Buffer::null(),
                indices: vk::Buffer::null(),
                objects: scene
                    .objects
                    .iter()
                    .map(|o| (o.index_count, o.first_index, o.vertex_offset as i32))
                    .collect(),
            },
            command_pool: vk::CommandPool::null(),
            slots: Vec::new(),
            push: [0.0; 20],
            submits: 0,
            predicated,
        };
        let sun = scene.sun_dir;
        engine.push[16..19].copy_from_slice(&[sun.x, sun.y, sun.z]);
        engine.buffers = raw_host::scene_buffers(&engine.device, &engine.memory_types, scene)?;
        engine.scene.vertices = engine.buffers[0].0;
        engine.scene.indices = engine.buffers[1].0;
        engine.scene.set = raw_host::storage_set(&engine.device, engine.buffers[2].0)?;
        engine.scene.pipeline =
            raw_host::scene_pipeline(&engine.device, engine.scene.set.layout, true)?;
        // SAFETY: valid device and create info; destroyed in Drop.
        engine.command_pool = unsafe {
            engine.device.create_command_pool(
                &vk::CommandPoolCreateInfo::default()
                    .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER),
                None,
            )
        }?;
        for _ in 0..FRAMES_IN_FLIGHT {
            let slot = engine.create_slot()?;
            engine.slots.push(slot);
        }
        Ok(engine)
    }

    fn image(
        &self,
        format: vk::Format,
        usage: vk::ImageUsageFlags,
        aspect: vk::ImageAspectFlags,
    ) -> Result<(vk::Image, vk::ImageView, vk::DeviceMemory)> {
        raw_host::image(&self.device, &self.memory_types, format, usage, aspect)
    }

    /// One frame-in-flight slot; its fence starts signaled (nothing in flight yet).
    fn create_slot(&self) -> Result<FrameSlot> {
        // SAFETY: valid device, pool and create infos; destroyed in Drop.
        let (cmd, fence) = unsafe {
            let cmd = self.device.allocate_command_buffers(
                &vk::CommandBufferAllocateInfo::default()
                    .command_pool(self.command_pool)
                    .command_buffer_count(1),
            )?[0];
            let fence = self.device.create_fence(
                &vk::FenceCreateInfo::default().flags(vk::FenceCreateFlags::SIGNALED),
                None,
            )?;
            (cmd, fence)
        };
        Ok(FrameSlot {
            cmd,
            fence,
            color: self.image(
                COLOR_FORMAT,
                vk::ImageUsageFlags::COLOR_ATTACHMENT,
                vk::ImageAspectFlags::COLOR,
            )?,
            depth: self.image(
                DEPTH_FORMAT,
                vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT,
                vk::ImageAspectFlags::DEPTH,
            )?,
        })
    }

    /// Waits for the slot's previous frame (the pacing of frames in flight); returns the
    /// wait in ms.
    fn wait_slot(&mut self, slot: usize) -> Result<f64> {
        let s = &self.slots[slot];
        let start = Instant::now();
        // SAFETY: the fence belongs to the slot's last submission (or starts signaled).
        unsafe {
            self.device.wait_for_fences(&[s.fence], true, u64::MAX)?;
            self.device.reset_fences(&[s.fence])?;
            self.device
                .reset_command_buffer(s.cmd, vk::CommandBufferResetFlags::empty())?;
        }
        Ok(start.elapsed().as_secs_f64() * 1e3)
    }

    /// Begins the slot's command buffer.
    ///
    /// # Safety
    /// The slot's fence was waited for.
    unsafe fn begin_commands(&mut self, slot: usize) -> Result<()> {
        // SAFETY: per the caller, the buffer is not in use.
        unsafe {
            self.device
                .begin_command_buffer(self.slots[slot].cmd, &vk::CommandBufferBeginInfo::default())
        }?;
        Ok(())
    }

    /// Moves the slot's targets into attachment layouts and begins the frame's one pass
    /// (clear, reverse-Z: the far plane at infinity is depth 0) with the scene state bound.
    ///
    /// # Safety
    /// The slot's command buffer is recording, outside rendering.
    unsafe fn begin_rendering(&mut self, slot_index: usize) {
        let slot = &self.slots[slot_index];
        let cmd = slot.cmd;
        let undefined = vk::ImageLayout::UNDEFINED;
        let barriers = [
            attachment_barrier(
                slot.color.0,
                vk::ImageAspectFlags::COLOR,
                (undefined, vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL),
                vk::PipelineStageFlags2::COLOR_ATTACHMENT_OUTPUT,
                (COLOR_WRITE, COLOR_WRITE),
            ),
            attachment_barrier(
                slot.depth.0,
                vk::ImageAspectFlags::DEPTH,
                (undefined, vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL),
                DEPTH_STAGES,
                (DEPTH_READ_WRITE, DEPTH_READ_WRITE),
            ),
        ];
        let color_att = [vk::RenderingAttachmentInfo::default()
            .image_view(slot.color.1)
            .image_layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)
            .load_op(vk::AttachmentLoadOp::CLEAR)
            .store_op(vk::AttachmentStoreOp::STORE)
            .clear_value(vk::ClearValue {
                color: vk::ClearColorValue {
                    float32: [0.1, 0.1, 0.15, 1.0],
                },
            })];
        // Reverse-Z: the far plane (infinity) is depth 0.
        let depth_att = vk::RenderingAttachmentInfo::default()
            .image_view(slot.depth.1)
            .image_layout(vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL)
            .load_op(vk::AttachmentLoadOp::CLEAR)
            // Stored: a predicated frame resumes the pass with LOAD ops.
            .store_op(vk::AttachmentStoreOp::STORE)
            .clear_value(vk::ClearValue {
                depth_stencil: vk::ClearDepthStencilValue {
                    depth: 0.0,
                    stencil: 0,
                },
            });
        // SAFETY: per the caller.
        unsafe {
            self.device.cmd_pipeline_barrier2(
                cmd,
                &vk::DependencyInfo::default().image_memory_barriers(&barriers),
            );
            raw_host::begin_rendering(&self.device, cmd, &color_att, &depth_att);
            self.scene.bind(&self.device, cmd, &self.push);
        }
    }

    /// Begins the slot's depth pass again after the query backend ended it to resolve its
    /// predicates: the attachment writes before it happen before the LOAD of the new pass.
    ///
    /// # Safety
    /// The slot's command buffer is recording, outside rendering, after its first pass.
    unsafe fn resume_rendering(&self, slot_index: usize) {
        let slot = &self.slots[slot_index];
        let (color, depth) = (
            vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL,
            vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL,
        );
        let barriers = [
            attachment_barrier(
                slot.color.0,
                vk::ImageAspectFlags::COLOR,
                (color, color),
                vk::PipelineStageFlags2::COLOR_ATTACHMENT_OUTPUT,
                (
                    COLOR_WRITE,
                    COLOR_WRITE | vk::AccessFlags2::COLOR_ATTACHMENT_READ,
                ),
            ),
            attachment_barrier(
                slot.depth.0,
                vk::ImageAspectFlags::DEPTH,
                (depth, depth),
                DEPTH_STAGES,
                (
                    vk::AccessFlags2::DEPTH_STENCIL_ATTACHMENT_WRITE,
                    DEPTH_READ_WRITE,
                ),
            ),
        ];
        let color_att = [vk::RenderingAttachmentInfo::default()
            .image_view(slot.color.1)
            .image_layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)
            .load_op(vk::AttachmentLoadOp::LOAD)
            .store_op(vk::AttachmentStoreOp::STORE)];
        let depth_att = vk::RenderingAttachmentInfo::default()
            .image_view(slot.depth.1)
            .image_layout(vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL)
            .load_op(vk::AttachmentLoadOp::LOAD)
            .store_op(vk::AttachmentStoreOp::STORE);
        // SAFETY: per the caller.
        unsafe {
            self.device.cmd_pipeline_barrier2(
                slot.cmd,
                &vk::DependencyInfo::default().image_memory_barriers(&barriers),
            );
            raw_host::begin_rendering(&self.device, slot.cmd, &color_att, &depth_att);
            self.scene.bind(&self.device, slot.cmd, &self.push);
        }
    }

    /// Ends the slot's command buffer and submits it, signalling the slot's fence.
    fn submit(&mut self, slot: usize) -> Result<()> {
        let s = &self.slots[slot];
        let cmds = [s.cmd];
        // SAFETY: the buffer is recording outside rendering; the fence was reset.
        unsafe {
            self.device.end_command_buffer(s.cmd)?;
            self.device.queue_submit(
                self.queue,
                &[vk::SubmitInfo::default().command_buffers(&cmds)],
                s.fence,
            )?;
        }
        self.submits += 1;
        Ok(())
    }

    /// Waits until the device has finished every frame.
    fn idle(&self) -> Result<()> {
        // SAFETY: valid device.
        unsafe { self.device.device_wait_idle() }?;
        Ok(())
    }
}

impl Drop for Engine {
    fn drop(&mut self) {
        // SAFETY: the device is idle; every object is destroyed once, children before parents.
        unsafe {
            let _ = self.device.device_wait_idle();
            for slot in self.slots.drain(..) {
                self.device.destroy_fence(slot.fence, None);
                for image in [slot.color, slot.depth] {
                    raw_host::destroy_image(&self.device, image);
                }
            }
            self.device.destroy_command_pool(self.command_pool, None);
            self.device.destroy_pipeline(self.scene.pipeline, None);
            raw_host::destroy_storage_set(&self.device, &self.scene.set);
            for buffer in self.buffers.drain(..) {
                raw_host::destroy_buffer(&self.device, buffer);
            }
            self.device.destroy_device(None);
            self.debug
                .destroy_debug_utils_messenger(self.messenger, None);
            self.instance.destroy_instance(None);
        }
    }
}

const USAGE: &str = "usage: engine [--frames N] [--policy cpu|gpu]  (frames of the street \
                     walk, 24 by default; the predicated mode's policy, by device type by default: \
                     cpu splits queried nodes into parts, gpu keeps one predicate level)";

/// What the command line asks for.
struct Args {
    frames: usize,
    /// `Some(true)`: the GPU policy (`ChcppParams::for_gpu`); `None`: by device type.
    gpu_policy: Option<bool>,
}

/// The command line; `None` where the user asked for help.
fn parse_args() -> Result<Option<Args>> {
    let mut a = Args {
        frames: 24,
        gpu_policy: None,
    };
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--frames" => {
                a.frames = args
                    .next()
                    .and_then(|n| n.parse().ok())
                    .context("--frames needs a number")?
            }
            "--policy" => {
                a.gpu_policy = match args.next().unwrap_or_default().as_str() {
                    "cpu" => Some(false),
                    "gpu" => Some(true),
                    other => bail!("--policy needs cpu or gpu, not {other:?}; {USAGE}"),
                }
            }
            "--help" | "-h" => {
                println!("{USAGE}");
                return Ok(None);
            }
            other => bail!("unknown argument {other:?}; {USAGE}"),
        }
    }
    Ok(Some(a))
}

// ---------------------------------------------------------------------------------------------
// The engine's main loop: load, create, run frames, report.

fn main() -> Result<()> {
    let Some(Args { frames, gpu_policy }) = parse_args()? else {
        return Ok(());
    };
    let scene = Scene::load("city", 0.25, 4096)?;
    // The hierarchy from plain arrays: the engine's own boxes, object i = draw i.
    let boxes: Vec<[[f32; 3]; 2]> = scene.objects.iter().map(|o| o.bounds.to_arrays()).collect();
    let bvh = ObjectBvh::from_boxes(boxes, 1);
    let path = scene.path("street")?.clone();
    let mut engine = Engine::new(&scene)?;
    let mut queries = query_backend(&engine)?;
    let latency = if engine.predicated {
        Latency::Predicated
    } else {
        println!("engine: the device lacks VK_EXT_conditional_rendering: next-frame instead of predicated");
        Latency::NextFrame
    };
    // On a GPU, recording parts of split nodes costs more than the extra objects they save.
    let (params, policy) = if gpu_policy.unwrap_or(!engine.is_cpu()) {
        (ChcppParams::for_gpu(), "one predicate level (GPU policy)")
    } else {
        (
            ChcppParams::default(),
            "queried nodes split into parts (CPU policy)",
        )
    };
    let mut culler = Chcpp::new(params)
        .with_latency(latency)
        .with_frames_in_flight(FRAMES_IN_FLIGHT);
    println!(
        "engine: {} objects, {} triangles; {FRAMES_IN_FLIGHT} frames in flight; {} in {} mode \
         reading {} frames late, {policy}; queries recorded by coherent-ash",
        scene.objects.len(),
        scene.triangle_count(),
        culler.name(),
        culler.latency().name(),
        culler.frames_in_flight()
    );
    println!(
        "frame  cull ms  pace ms  draws  predicated  breaks  queries  multi  binds  switches  visible  submits  waits"
    );
    let proj = reverse_z_infinite(1.0, WIDTH as f32 / HEIGHT as f32, 0.1);
    let (mut bad_frames, mut orders) = (0, 0);
    for f in 0..frames as u64 {
        let pose = path.pose_at(f as f32 * 2.0);
        let eye = [pose.eye.x, pose.eye.y, pose.eye.z];
        let target = [pose.target.x, pose.target.y, pose.target.z];
        let view_proj = mul(&proj, &look_at(eye, target));
        let r = frame(
            &mut engine,
            &mut queries,
            &mut culler,
            &bvh,
            (f, view_proj, eye),
        )?;
        let q = queries.counts();
        println!(
            "{f:5}  {:7.1}  {:7.1}  {:5}  {:10}  {:6}  {:7}  {:5}  {:5}  {:8}  {:7}  {:7}  {:5}",
            r.cull_ms,
            r.pace_ms,
            r.draws,
            q.predicated_objects,
            q.resolves,
            q.queries,
            q.multiqueries,
            q.pipeline_binds,
            q.state_changes,
            r.visible_results,
            r.submits,
            r.waits
        );
        orders += r.orders;
        if r.submits != 1 || r.waits != 0 {
            bad_frames += 1;
        }
    }
    engine.idle()?;
    drop(queries);
    drop(engine);
    let n = MESSAGES.load(Ordering::SeqCst);
    if n > 0 {
        bail!("{n} validation messages");
    }
    if bad_frames > 0 {
        bail!("{bad_frames} frames did not submit exactly once without waiting");
    }
    println!(
        "validation: no messages; {} mode: one submission per frame, no waits inside a frame; \
         draw order received {orders} time(s)",
        culler.latency().name()
    );
    Ok(())
}
