//! A second host, written like an engine: its own raw-ash instance, device and render loop with
//! two frames in flight (a command buffer, fence, query pool, result buffer, box buffer and
//! render target per frame-in-flight slot), one submission per frame and no wait inside a
//! frame, its own camera matrices (reverse-Z, infinite far plane) as plain arrays, and
//! coherent's CHC++ in `next-frame` mode reading each frame's queries two frames later — all
//! through the public API (`OcclusionBackend`, `CameraView`, `ObjectBvh`), no glam.
//!
//! Frame N in slot s = N mod 2: wait for slot s's fence (frame N-2: the host's frame pacing,
//! timed as `pace ms`), then `cull_frame`: the culler first reads frame N-2's results from
//! slot s's result buffer (copied there by `vkCmdCopyQueryPoolResults` at the end of frame
//! N-2, so reading is a plain memory read on every driver), then records draws and queries
//! into slot s's command buffer (which starts with `vkCmdResetQueryPool`), and ends with
//! `submit_frame`: one `vkQueueSubmit`, no wait.
//!
//! Run: `cargo run --release --example engine -- [--frames N]` (validation on; exits
//! non-zero on any validation message, on a second submission in a frame or on a wait).

use std::sync::atomic::Ordering;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use ash::{ext, vk};
use coherent::bvh::ObjectBvh;
use coherent::culling::chcpp::{Chcpp, ChcppParams};
use coherent::culling::{Culler, FrameInput, Latency, OcclusionBackend, QueryId, QueryPurpose};
use coherent::scene::camera::{CameraView, DepthConvention};
use coherent::scene::{Aabb, Scene};

#[path = "common/raw_host.rs"]
mod raw_host;

use raw_host::{Memory, HEIGHT, MESSAGES, WIDTH};

/// Frames in flight: the host's own choice, handed to the culler as `k`.
const FRAMES_IN_FLIGHT: usize = 2;
const MAX_QUERIES: u32 = 8192;
const MAX_BOXES: u64 = 65536;

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
// The engine's renderer.

/// Everything one frame in flight owns.
struct FrameSlot {
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
    query_pool: vk::QueryPool,
    /// Where `vkCmdCopyQueryPoolResults` puts the frame's results (value, availability).
    results: (vk::Buffer, Memory),
    /// Query box corners of this frame.
    boxes: (vk::Buffer, Memory),
    color: (vk::Image, vk::ImageView, vk::DeviceMemory),
    depth: (vk::Image, vk::ImageView, vk::DeviceMemory),
    /// Queries issued by the frame last recorded in this slot.
    queries: u32,
    /// That frame has completed (its fence was waited for): its results are readable.
    complete: bool,
}

/// Per-frame statistics of the engine.
#[derive(Default, Clone, Copy)]
struct FrameStats {
    draws: u32,
    queries: u32,
    multiqueries: u32,
    submits: u32,
    /// Calls the culler made that would wait or split the frame (must stay 0).
    waits: u32,
    boxes: u64,
}

struct Engine {
    _entry: ash::Entry,
    instance: ash::Instance,
    debug: ext::debug_utils::Instance,
    messenger: vk::DebugUtilsMessengerEXT,
    device: ash::Device,
    queue: vk::Queue,
    memory_types: vk::PhysicalDeviceMemoryProperties,
    /// Vertex, index, object and box-index buffers (shared by all frames, never written after
    /// creation).
    buffers: Vec<(vk::Buffer, Memory)>,
    /// Set 0 (the object buffer) and the pipeline layout.
    set: raw_host::StorageSet,
    render_pipeline: vk::Pipeline,
    query_pipeline: vk::Pipeline,
    command_pool: vk::CommandPool,
    slots: Vec<FrameSlot>,
    /// The slot being recorded.
    current: usize,
    recording: bool,
    bound_query_state: Option<bool>,
    push: [f32; 20],
    objects: Vec<(u32, u32, i32)>,
    stats: FrameStats,
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
    fn new(scene: &Scene) -> Result<Engine> {
        let (entry, instance, debug, messenger) = raw_host::instance()?;
        let physical = pick_device(&instance)?;
        // SAFETY: valid physical device.
        let memory_types = unsafe { instance.get_physical_device_memory_properties(physical) };
        // SAFETY: valid physical device.
        let features = unsafe { instance.get_physical_device_features(physical) };
        if features.occlusion_query_precise == vk::FALSE {
            bail!("the device lacks occlusionQueryPrecise");
        }
        let priorities = [1.0];
        let queues = [vk::DeviceQueueCreateInfo::default()
            .queue_family_index(0)
            .queue_priorities(&priorities)];
        let f10 = vk::PhysicalDeviceFeatures::default().occlusion_query_precise(true);
        let mut f13 = vk::PhysicalDeviceVulkan13Features::default()
            .dynamic_rendering(true)
            .synchronization2(true)
            .maintenance4(true);
        let info = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queues)
            .enabled_features(&f10)
            .push_next(&mut f13);
        // SAFETY: valid physical device and create info.
        let device = unsafe { instance.create_device(physical, &info, None) }?;
        // SAFETY: family 0 was created with one queue.
        let queue = unsafe { device.get_device_queue(0, 0) };
        let mut engine = Engine {
            _entry: entry,
            instance,
            debug,
            messenger,
            device,
            queue,
            memory_types,
            buffers: Vec::new(),
            set: raw_host::StorageSet::null(),
            render_pipeline: vk::Pipeline::null(),
            query_pipeline: vk::Pipeline::null(),
            command_pool: vk::CommandPool::null(),
            slots: Vec::new(),
            current: 0,
            recording: false,
            bound_query_state: None,
            push: [0.0; 20],
            objects: scene
                .objects
                .iter()
                .map(|o| (o.index_count, o.first_index, o.vertex_offset as i32))
                .collect(),
            stats: FrameStats::default(),
        };
        engine.buffers = raw_host::scene_buffers(&engine.device, &engine.memory_types, scene)?;
        engine.create_pipelines()?;
        for _ in 0..FRAMES_IN_FLIGHT {
            let slot = engine.create_slot()?;
            engine.slots.push(slot);
        }
        Ok(engine)
    }

    fn buffer(
        &self,
        size: u64,
        usage: vk::BufferUsageFlags,
        data: &[u8],
    ) -> Result<(vk::Buffer, Memory)> {
        raw_host::buffer(&self.device, &self.memory_types, size, usage, data)
    }

    fn image(
        &self,
        format: vk::Format,
        usage: vk::ImageUsageFlags,
        aspect: vk::ImageAspectFlags,
    ) -> Result<(vk::Image, vk::ImageView, vk::DeviceMemory)> {
        raw_host::image(&self.device, &self.memory_types, format, usage, aspect)
    }

    /// Layout, descriptor set, the opaque and the query pipeline (reverse-Z compares).
    fn create_pipelines(&mut self) -> Result<()> {
        self.set = raw_host::storage_set(&self.device, self.buffers[2].0)?;
        // SAFETY: valid device and create info; destroyed in Drop.
        unsafe {
            self.command_pool = self.device.create_command_pool(
                &vk::CommandPoolCreateInfo::default()
                    .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER),
                None,
            )?;
        }
        (self.render_pipeline, self.query_pipeline) =
            raw_host::scene_and_query_pipelines(&self.device, self.set.layout, true)?;
        Ok(())
    }

    /// One frame-in-flight slot; its fence starts signaled (nothing in flight yet).
    fn create_slot(&self) -> Result<FrameSlot> {
        // SAFETY: valid device, pool and create infos; destroyed in Drop.
        let (cmd, fence, query_pool) = unsafe {
            let cmd = self.device.allocate_command_buffers(
                &vk::CommandBufferAllocateInfo::default()
                    .command_pool(self.command_pool)
                    .command_buffer_count(1),
            )?[0];
            let fence = self.device.create_fence(
                &vk::FenceCreateInfo::default().flags(vk::FenceCreateFlags::SIGNALED),
                None,
            )?;
            let query_pool = self.device.create_query_pool(
                &vk::QueryPoolCreateInfo::default()
                    .query_type(vk::QueryType::OCCLUSION)
                    .query_count(MAX_QUERIES),
                None,
            )?;
            (cmd, fence, query_pool)
        };
        Ok(FrameSlot {
            cmd,
            fence,
            query_pool,
            results: self.buffer(
                u64::from(MAX_QUERIES) * 16,
                vk::BufferUsageFlags::TRANSFER_DST,
                &[],
            )?,
            boxes: self.buffer(MAX_BOXES * 96, vk::BufferUsageFlags::VERTEX_BUFFER, &[])?,
            color: self.image(
                vk::Format::R8G8B8A8_UNORM,
                vk::ImageUsageFlags::COLOR_ATTACHMENT,
                vk::ImageAspectFlags::COLOR,
            )?,
            depth: self.image(
                vk::Format::D32_SFLOAT,
                vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT,
                vk::ImageAspectFlags::DEPTH,
            )?,
            queries: 0,
            complete: true,
        })
    }

    /// Starts frame `frame`: waits for its slot's previous frame (the pacing of two frames
    /// in flight; returns the wait in ms), after which that frame's results are readable.
    fn begin_frame(&mut self, frame: usize, view_proj: &Mat, sun: [f32; 3]) -> Result<f64> {
        self.current = frame % FRAMES_IN_FLIGHT;
        let slot = &mut self.slots[self.current];
        let start = Instant::now();
        // SAFETY: the fence belongs to the slot's last submission (or starts signaled).
        unsafe {
            self.device.wait_for_fences(&[slot.fence], true, u64::MAX)?;
            self.device.reset_fences(&[slot.fence])?;
            self.device
                .reset_command_buffer(slot.cmd, vk::CommandBufferResetFlags::empty())?;
        }
        slot.complete = true;
        self.stats = FrameStats::default();
        self.push[..16].copy_from_slice(view_proj);
        self.push[16..19].copy_from_slice(&sun);
        Ok(start.elapsed().as_secs_f64() * 1e3)
    }

    /// The frame's first command: reset the slot's query pool (its old results were copied
    /// out and read by the culler before this), then begin the one pass of the frame.
    fn ensure_recording(&mut self) -> Result<()> {
        if self.recording {
            return Ok(());
        }
        let slot = &mut self.slots[self.current];
        slot.queries = 0;
        slot.complete = false;
        let cmd = slot.cmd;
        let barrier = |image, aspect, layout, stage, access| {
            vk::ImageMemoryBarrier2::default()
                .image(image)
                .subresource_range(
                    vk::ImageSubresourceRange::default()
                        .aspect_mask(aspect)
                        .level_count(1)
                        .layer_count(1),
                )
                .old_layout(vk::ImageLayout::UNDEFINED)
                .new_layout(layout)
                .src_stage_mask(stage)
                .src_access_mask(access)
                .dst_stage_mask(stage)
                .dst_access_mask(access)
        };
        let depth_stages = vk::PipelineStageFlags2::EARLY_FRAGMENT_TESTS
            | vk::PipelineStageFlags2::LATE_FRAGMENT_TESTS;
        let barriers = [
            barrier(
                slot.color.0,
                vk::ImageAspectFlags::COLOR,
                vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL,
                vk::PipelineStageFlags2::COLOR_ATTACHMENT_OUTPUT,
                vk::AccessFlags2::COLOR_ATTACHMENT_WRITE,
            ),
            barrier(
                slot.depth.0,
                vk::ImageAspectFlags::DEPTH,
                vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL,
                depth_stages,
                vk::AccessFlags2::DEPTH_STENCIL_ATTACHMENT_WRITE
                    | vk::AccessFlags2::DEPTH_STENCIL_ATTACHMENT_READ,
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
            .store_op(vk::AttachmentStoreOp::DONT_CARE)
            .clear_value(vk::ClearValue {
                depth_stencil: vk::ClearDepthStencilValue {
                    depth: 0.0,
                    stencil: 0,
                },
            });
        // SAFETY: the buffer was reset after its fence; the pool is reset outside rendering.
        unsafe {
            self.device
                .begin_command_buffer(cmd, &vk::CommandBufferBeginInfo::default())?;
            self.device
                .cmd_reset_query_pool(cmd, slot.query_pool, 0, MAX_QUERIES);
            self.device.cmd_pipeline_barrier2(
                cmd,
                &vk::DependencyInfo::default().image_memory_barriers(&barriers),
            );
            raw_host::begin_rendering(
                &self.device,
                cmd,
                &color_att,
                &depth_att,
                (self.set.layout, self.set.set),
                &self.push,
            );
        }
        self.recording = true;
        self.bound_query_state = None;
        Ok(())
    }

    fn set_state(&mut self, query: bool) {
        if self.bound_query_state == Some(query) {
            return;
        }
        let slot = &self.slots[self.current];
        let (pipeline, vb, ib) = if query {
            (self.query_pipeline, slot.boxes.0, self.buffers[3].0)
        } else {
            (self.render_pipeline, self.buffers[0].0, self.buffers[1].0)
        };
        // SAFETY: recording inside rendering; buffers and pipeline are valid.
        unsafe { raw_host::bind_state(&self.device, slot.cmd, pipeline, vb, ib) };
        self.bound_query_state = Some(query);
    }

    /// Ends the frame's pass, copies the query results into the slot's host-visible buffer
    /// (read two frames later) and submits the frame, signalling the slot's fence.
    fn submit(&mut self) -> Result<()> {
        self.ensure_recording()?;
        let slot = &self.slots[self.current];
        let cmds = [slot.cmd];
        let to_host = [vk::MemoryBarrier2::default()
            .src_stage_mask(vk::PipelineStageFlags2::COPY)
            .src_access_mask(vk::AccessFlags2::TRANSFER_WRITE)
            .dst_stage_mask(vk::PipelineStageFlags2::HOST)
            .dst_access_mask(vk::AccessFlags2::HOST_READ)];
        // SAFETY: recording inside rendering; the queries were ended in this buffer; the
        // fence was reset in begin_frame.
        unsafe {
            self.device.cmd_end_rendering(slot.cmd);
            if slot.queries > 0 {
                self.device.cmd_copy_query_pool_results(
                    slot.cmd,
                    slot.query_pool,
                    0,
                    slot.queries,
                    slot.results.0,
                    0,
                    16,
                    // WAIT: the copy (on the GPU timeline, not the host) waits for each
                    // query's result; without it an implementation may copy a query that
                    // has not finished as unavailable (lavapipe does, its rasterizer
                    // threads finish after the copy starts) and the culler never sees it.
                    vk::QueryResultFlags::TYPE_64
                        | vk::QueryResultFlags::WITH_AVAILABILITY
                        | vk::QueryResultFlags::WAIT,
                );
                self.device.cmd_pipeline_barrier2(
                    slot.cmd,
                    &vk::DependencyInfo::default().memory_barriers(&to_host),
                );
            }
            self.device.end_command_buffer(slot.cmd)?;
            self.device.queue_submit(
                self.queue,
                &[vk::SubmitInfo::default().command_buffers(&cmds)],
                slot.fence,
            )?;
        }
        self.recording = false;
        self.stats.submits += 1;
        Ok(())
    }
}

type CullResult<T> = coherent::Result<T>;

fn host_error(e: impl std::fmt::Display) -> coherent::Error {
    coherent::Error::Input(format!("engine: {e}"))
}

/// The culler's view of the engine. Query ids name the slot: `slot · MAX_QUERIES + index`.
impl OcclusionBackend for Engine {
    fn draw_objects(&mut self, objects: &[u32]) -> CullResult<()> {
        if objects.is_empty() {
            return Ok(());
        }
        self.ensure_recording().map_err(host_error)?;
        self.set_state(false);
        let cmd = self.slots[self.current].cmd;
        for &o in objects {
            let (count, first, offset) = *self
                .objects
                .get(o as usize)
                .ok_or_else(|| host_error(format!("no object {o}")))?;
            // SAFETY: recording inside rendering with the render pipeline bound.
            unsafe {
                self.device
                    .cmd_draw_indexed(cmd, count, 1, first, offset, o)
            };
            self.stats.draws += 1;
        }
        Ok(())
    }

    fn issue_query(&mut self, boxes: &[Aabb]) -> CullResult<QueryId> {
        self.issue_query_for(boxes, QueryPurpose::Node)
    }

    fn issue_query_for(&mut self, boxes: &[Aabb], purpose: QueryPurpose) -> CullResult<QueryId> {
        // First: starting the frame's recording resets the slot's query count, so the count
        // read after it is this frame's (before it, the first query of a frame took the index
        // after the last one of the slot's previous frame: a query begun twice).
        self.ensure_recording().map_err(host_error)?;
        let queries = self.slots[self.current].queries;
        if queries == MAX_QUERIES || self.stats.boxes + boxes.len() as u64 > MAX_BOXES {
            return Err(host_error("query budget of this engine exceeded"));
        }
        if boxes.len() > 1024 {
            return Err(host_error("more than 1024 boxes in one query"));
        }
        self.set_state(true);
        let corners: Vec<f32> = boxes
            .iter()
            .flat_map(|b| {
                let [min, max] = b.to_arrays();
                (0..8).flat_map(move |c| {
                    [0, 1, 2].map(|axis| {
                        if c & (1 << axis) == 0 {
                            min[axis]
                        } else {
                            max[axis]
                        }
                    })
                })
            })
            .collect();
        let slot = &self.slots[self.current];
        // SAFETY: the slot's box buffer is mapped and large enough (checked above); its
        // previous frame has completed (fence waited in begin_frame).
        unsafe {
            std::ptr::copy_nonoverlapping(
                corners.as_ptr() as *const u8,
                slot.boxes.1.ptr.add((self.stats.boxes * 96) as usize),
                corners.len() * 4,
            );
        }
        // SAFETY: the pool was reset at the start of this command buffer; inside rendering.
        unsafe {
            self.device.cmd_begin_query(
                slot.cmd,
                slot.query_pool,
                queries,
                vk::QueryControlFlags::PRECISE,
            );
            self.device.cmd_draw_indexed(
                slot.cmd,
                36 * boxes.len() as u32,
                1,
                0,
                (self.stats.boxes * 8) as i32,
                0,
            );
            self.device
                .cmd_end_query(slot.cmd, slot.query_pool, queries);
        }
        self.stats.boxes += boxes.len() as u64;
        self.stats.queries += 1;
        if purpose == QueryPurpose::Multiquery {
            self.stats.multiqueries += 1;
        }
        self.slots[self.current].queries += 1;
        Ok(self.current as u32 * MAX_QUERIES + queries)
    }

    /// This engine submits once per frame: a culler that wants a mid-frame submission is
    /// in the wrong mode.
    fn flush(&mut self) -> CullResult<()> {
        self.stats.waits += 1;
        Err(host_error("flush: this engine submits once per frame"))
    }

    /// A plain memory read of the slot's result buffer once its frame has completed.
    fn query_result(&mut self, query: QueryId) -> CullResult<Option<u64>> {
        let (slot, index) = ((query / MAX_QUERIES) as usize, query % MAX_QUERIES);
        let s = self
            .slots
            .get(slot)
            .ok_or_else(|| host_error(format!("query {query} names no slot")))?;
        if !s.complete || index >= s.queries {
            return Ok(None);
        }
        let mut pair = [0u64; 2];
        // SAFETY: the buffer is mapped, coherent and holds `queries` pairs, written by a
        // submission whose fence has been waited for.
        unsafe {
            std::ptr::copy_nonoverlapping(
                s.results.1.ptr.add(index as usize * 16),
                pair.as_mut_ptr() as *mut u8,
                16,
            );
        }
        Ok((pair[1] != 0).then_some(pair[0]))
    }

    fn wait_query(&mut self, query: QueryId) -> CullResult<u64> {
        self.stats.waits += 1;
        Err(host_error(format!(
            "wait_query({query}): this engine never waits inside a frame"
        )))
    }

    fn finish(&mut self) -> CullResult<()> {
        self.stats.waits += 1;
        Err(host_error(
            "finish: this engine does not wait for its frames",
        ))
    }

    fn frames_in_flight(&self) -> u32 {
        FRAMES_IN_FLIGHT as u32
    }

    fn submit_frame(&mut self) -> CullResult<()> {
        self.submit().map_err(host_error)
    }
}

impl Drop for Engine {
    fn drop(&mut self) {
        // SAFETY: the device is idle; every object is destroyed once, children before parents.
        unsafe {
            let _ = self.device.device_wait_idle();
            for slot in self.slots.drain(..) {
                self.device.destroy_fence(slot.fence, None);
                self.device.destroy_query_pool(slot.query_pool, None);
                for buffer in [slot.results, slot.boxes] {
                    raw_host::destroy_buffer(&self.device, buffer);
                }
                for image in [slot.color, slot.depth] {
                    raw_host::destroy_image(&self.device, image);
                }
            }
            self.device.destroy_command_pool(self.command_pool, None);
            self.device.destroy_pipeline(self.render_pipeline, None);
            self.device.destroy_pipeline(self.query_pipeline, None);
            raw_host::destroy_storage_set(&self.device, &self.set);
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

fn frames_arg() -> Result<usize> {
    let args: Vec<String> = std::env::args().collect();
    match args.iter().position(|a| a == "--frames") {
        Some(i) => args
            .get(i + 1)
            .context("--frames needs a number")?
            .parse()
            .context("--frames needs a number"),
        None => Ok(24),
    }
}

fn main() -> Result<()> {
    let frames = frames_arg()?;
    let scene = Scene::load("city", 0.25, 4096)?;
    // The hierarchy from plain arrays: the engine's own boxes, object i = draw i.
    let boxes: Vec<[[f32; 3]; 2]> = scene.objects.iter().map(|o| o.bounds.to_arrays()).collect();
    let bvh = ObjectBvh::from_boxes(boxes, 1);
    let path = scene.path("street")?.clone();
    let mut engine = Engine::new(&scene)?;
    let mut culler = Chcpp::new(ChcppParams::default())
        .with_latency(Latency::NextFrame)
        .with_frames_in_flight(FRAMES_IN_FLIGHT as u32);
    println!(
        "engine: {} objects, {} triangles; {} frames in flight, {} in {} mode reading {} frames late",
        scene.objects.len(),
        scene.triangle_count(),
        FRAMES_IN_FLIGHT,
        culler.name(),
        culler.latency().name(),
        culler.frames_in_flight()
    );
    println!("frame  cull ms  pace ms  draws  queries  multi  visible  submits  waits");
    let sun = [scene.sun_dir.x, scene.sun_dir.y, scene.sun_dir.z];
    let mut bad_frames = 0;
    for frame in 0..frames {
        let pose = path.pose_at(frame as f32 * 2.0);
        let eye = [pose.eye.x, pose.eye.y, pose.eye.z];
        let target = [pose.target.x, pose.target.y, pose.target.z];
        let proj = reverse_z_infinite(1.0, WIDTH as f32 / HEIGHT as f32, 0.1);
        let view_proj = mul(&proj, &look_at(eye, target));
        let pace_ms = engine.begin_frame(frame, &view_proj, sun)?;
        let start = Instant::now();
        let input = FrameInput {
            bvh: &bvh,
            view: CameraView::new(view_proj, eye, DepthConvention::REVERSE_Z_INFINITE),
            frame: frame as u64,
            exact_visible: None,
        };
        let stats = culler.cull_frame(&input, &mut engine)?;
        let ms = start.elapsed().as_secs_f64() * 1e3;
        let s = engine.stats;
        println!(
            "{frame:5}  {ms:7.1}  {pace_ms:7.1}  {:5}  {:7}  {:5}  {:7}  {:7}  {:5}",
            s.draws, s.queries, s.multiqueries, stats.visible_results, s.submits, s.waits
        );
        if s.submits != 1 || s.waits != 0 {
            bad_frames += 1;
        }
    }
    drop(engine);
    let n = MESSAGES.load(Ordering::SeqCst);
    if n > 0 {
        bail!("{n} validation messages");
    }
    if bad_frames > 0 {
        bail!("{bad_frames} frames did not submit exactly once without waiting");
    }
    println!("validation: no messages; one submission per frame, no waits");
    Ok(())
}
