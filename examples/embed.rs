//! A host engine that owns its Vulkan instance, device, memory, pipelines and command buffers,
//! written with raw ash, and uses coherent's CHC++ culler only through the `OcclusionBackend`
//! trait: "draw these objects", "draw these boxes inside a query", "submit", "is it ready".
//!
//! Run: `cargo run --release --example embed` (validation on; exits non-zero on any message).

use std::sync::atomic::Ordering;

use anyhow::{bail, Context, Result};
use ash::{ext, vk};
use coherent::bvh::ObjectBvh;
use coherent::culling::{ChcppParams, Culler, FrameInput, OcclusionBackend, QueryId};
use coherent::scene::camera::Camera;
use coherent::scene::{Aabb, Scene};

const MAX_QUERIES: u32 = 8192;
const MAX_BOXES: u64 = 65536;

#[path = "common/raw_host.rs"]
mod raw_host;

use raw_host::{Memory, HEIGHT, MESSAGES, WIDTH};

/// The host engine's renderer.
struct Host {
    _entry: ash::Entry,
    instance: ash::Instance,
    debug: ext::debug_utils::Instance,
    messenger: vk::DebugUtilsMessengerEXT,
    device: ash::Device,
    queue: vk::Queue,
    memory_types: vk::PhysicalDeviceMemoryProperties,
    buffers: Vec<(vk::Buffer, Memory)>,
    images: Vec<(vk::Image, vk::ImageView, vk::DeviceMemory)>,
    /// Set 0 (the object buffer) and the pipeline layout.
    set: raw_host::StorageSet,
    render_pipeline: vk::Pipeline,
    query_pipeline: vk::Pipeline,
    command_pool: vk::CommandPool,
    segments: Vec<(vk::CommandBuffer, vk::Fence)>,
    used: usize,
    recording: bool,
    query_pool: vk::QueryPool,
    queries: u32,
    query_segment: Vec<usize>,
    objects: Vec<(u32, u32, i32)>,
    bound_query_state: Option<bool>,
    boxes_used: u64,
    push: [f32; 20],
    // Host statistics.
    draws: u32,
    submits: u32,
    switches: u32,
}

impl Host {
    fn new(scene: &Scene) -> Result<Host> {
        let (entry, instance, debug, messenger) = raw_host::instance()?;
        // SAFETY: valid instance.
        let physical = unsafe { instance.enumerate_physical_devices() }?
            .into_iter()
            .next()
            .context("no Vulkan device")?;
        // SAFETY: valid physical device.
        let memory_types = unsafe { instance.get_physical_device_memory_properties(physical) };
        let priorities = [1.0];
        let queues = [vk::DeviceQueueCreateInfo::default()
            .queue_family_index(0)
            .queue_priorities(&priorities)];
        let f10 = vk::PhysicalDeviceFeatures::default().occlusion_query_precise(true);
        let mut f12 = vk::PhysicalDeviceVulkan12Features::default().host_query_reset(true);
        let mut f13 = vk::PhysicalDeviceVulkan13Features::default()
            .dynamic_rendering(true)
            .synchronization2(true)
            .maintenance4(true);
        let info = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queues)
            .enabled_features(&f10)
            .push_next(&mut f12)
            .push_next(&mut f13);
        // SAFETY: valid physical device and create info.
        let device = unsafe { instance.create_device(physical, &info, None) }?;
        // SAFETY: family 0 was created with one queue.
        let queue = unsafe { device.get_device_queue(0, 0) };
        let mut host = Host {
            _entry: entry,
            instance,
            debug,
            messenger,
            device,
            queue,
            memory_types,
            buffers: Vec::new(),
            images: Vec::new(),
            set: raw_host::StorageSet::null(),
            render_pipeline: vk::Pipeline::null(),
            query_pipeline: vk::Pipeline::null(),
            command_pool: vk::CommandPool::null(),
            segments: Vec::new(),
            used: 0,
            recording: false,
            query_pool: vk::QueryPool::null(),
            queries: 0,
            query_segment: Vec::new(),
            objects: scene
                .objects
                .iter()
                .map(|o| (o.index_count, o.first_index, o.vertex_offset as i32))
                .collect(),
            bound_query_state: None,
            boxes_used: 0,
            push: [0.0; 20],
            draws: 0,
            submits: 0,
            switches: 0,
        };
        host.create_resources(scene)?;
        Ok(host)
    }

    fn buffer(
        &mut self,
        size: u64,
        usage: vk::BufferUsageFlags,
        data: &[u8],
    ) -> Result<vk::Buffer> {
        let (buffer, memory) =
            raw_host::buffer(&self.device, &self.memory_types, size, usage, data)?;
        self.buffers.push((buffer, memory));
        Ok(buffer)
    }

    fn image(
        &mut self,
        format: vk::Format,
        usage: vk::ImageUsageFlags,
        aspect: vk::ImageAspectFlags,
    ) -> Result<vk::ImageView> {
        let image = raw_host::image(&self.device, &self.memory_types, format, usage, aspect)?;
        self.images.push(image);
        Ok(image.1)
    }

    fn create_resources(&mut self, scene: &Scene) -> Result<()> {
        // Vertices, indices, objects, box indices (0..=3), then the box corners (4).
        self.buffers = raw_host::scene_buffers(&self.device, &self.memory_types, scene)?;
        self.buffer(MAX_BOXES * 96, vk::BufferUsageFlags::VERTEX_BUFFER, &[])?;
        self.image(
            vk::Format::R8G8B8A8_UNORM,
            vk::ImageUsageFlags::COLOR_ATTACHMENT | vk::ImageUsageFlags::TRANSFER_SRC,
            vk::ImageAspectFlags::COLOR,
        )?;
        self.image(
            vk::Format::D32_SFLOAT,
            vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT,
            vk::ImageAspectFlags::DEPTH,
        )?;
        self.set = raw_host::storage_set(&self.device, self.buffers[2].0)?;
        // SAFETY: valid device and create infos; everything is destroyed in Drop.
        unsafe {
            self.command_pool = self
                .device
                .create_command_pool(&vk::CommandPoolCreateInfo::default(), None)?;
            self.query_pool = self.device.create_query_pool(
                &vk::QueryPoolCreateInfo::default()
                    .query_type(vk::QueryType::OCCLUSION)
                    .query_count(MAX_QUERIES),
                None,
            )?;
            self.device
                .reset_query_pool(self.query_pool, 0, MAX_QUERIES);
        }
        (self.render_pipeline, self.query_pipeline) =
            raw_host::scene_and_query_pipelines(&self.device, self.set.layout, false)?;
        Ok(())
    }

    fn begin_frame(&mut self, camera: &Camera, sun: glam::Vec3) -> Result<()> {
        // SAFETY: the previous frame waited for all its fences.
        unsafe {
            self.device
                .reset_command_pool(self.command_pool, vk::CommandPoolResetFlags::empty())?;
            let fences: Vec<_> = self.segments[..self.used].iter().map(|s| s.1).collect();
            if !fences.is_empty() {
                self.device.reset_fences(&fences)?;
            }
            if self.queries > 0 {
                self.device
                    .reset_query_pool(self.query_pool, 0, self.queries);
            }
        }
        self.used = 0;
        self.queries = 0;
        self.query_segment.clear();
        self.boxes_used = 0;
        self.draws = 0;
        self.submits = 0;
        self.switches = 0;
        self.push[..16].copy_from_slice(&camera.view_proj().to_cols_array());
        self.push[16..19].copy_from_slice(&sun.to_array());
        Ok(())
    }

    /// Starts a new command buffer that resumes rendering (clears on the frame's first one).
    fn ensure_recording(&mut self) -> Result<()> {
        if self.recording {
            return Ok(());
        }
        if self.used == self.segments.len() {
            // SAFETY: valid pool and device.
            unsafe {
                let cmd = self.device.allocate_command_buffers(
                    &vk::CommandBufferAllocateInfo::default()
                        .command_pool(self.command_pool)
                        .command_buffer_count(1),
                )?[0];
                let fence = self
                    .device
                    .create_fence(&vk::FenceCreateInfo::default(), None)?;
                self.segments.push((cmd, fence));
            }
        }
        let first = self.used == 0;
        let cmd = self.segments[self.used].0;
        self.used += 1;
        let (color, color_view) = (self.images[0].0, self.images[0].1);
        let (depth, depth_view) = (self.images[1].0, self.images[1].1);
        let barrier = |image, aspect, layout, stage, access| {
            vk::ImageMemoryBarrier2::default()
                .image(image)
                .subresource_range(
                    vk::ImageSubresourceRange::default()
                        .aspect_mask(aspect)
                        .level_count(1)
                        .layer_count(1),
                )
                .old_layout(if first {
                    vk::ImageLayout::UNDEFINED
                } else {
                    layout
                })
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
                color,
                vk::ImageAspectFlags::COLOR,
                vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL,
                vk::PipelineStageFlags2::COLOR_ATTACHMENT_OUTPUT,
                vk::AccessFlags2::COLOR_ATTACHMENT_WRITE | vk::AccessFlags2::COLOR_ATTACHMENT_READ,
            ),
            barrier(
                depth,
                vk::ImageAspectFlags::DEPTH,
                vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL,
                depth_stages,
                vk::AccessFlags2::DEPTH_STENCIL_ATTACHMENT_WRITE
                    | vk::AccessFlags2::DEPTH_STENCIL_ATTACHMENT_READ,
            ),
        ];
        let load = if first {
            vk::AttachmentLoadOp::CLEAR
        } else {
            vk::AttachmentLoadOp::LOAD
        };
        let color_att = [vk::RenderingAttachmentInfo::default()
            .image_view(color_view)
            .image_layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)
            .load_op(load)
            .store_op(vk::AttachmentStoreOp::STORE)
            .clear_value(vk::ClearValue {
                color: vk::ClearColorValue {
                    float32: [0.1, 0.1, 0.15, 1.0],
                },
            })];
        let depth_att = vk::RenderingAttachmentInfo::default()
            .image_view(depth_view)
            .image_layout(vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL)
            .load_op(load)
            .store_op(vk::AttachmentStoreOp::STORE)
            .clear_value(vk::ClearValue {
                depth_stencil: vk::ClearDepthStencilValue {
                    depth: 1.0,
                    stencil: 0,
                },
            });
        // SAFETY: the buffer was reset with its pool; attachments are in the right layouts.
        unsafe {
            self.device
                .begin_command_buffer(cmd, &vk::CommandBufferBeginInfo::default())?;
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
        let cmd = self.segments[self.used - 1].0;
        let (pipeline, vb, ib) = if query {
            (self.query_pipeline, self.buffers[4].0, self.buffers[3].0)
        } else {
            (self.render_pipeline, self.buffers[0].0, self.buffers[1].0)
        };
        // SAFETY: recording inside rendering; buffers and pipeline are valid.
        unsafe { raw_host::bind_state(&self.device, cmd, pipeline, vb, ib) };
        if self.bound_query_state.is_some() {
            self.switches += 1;
        }
        self.bound_query_state = Some(query);
    }
}

type CullResult<T> = coherent::Result<T>;

fn host_error(e: impl std::fmt::Display) -> coherent::Error {
    coherent::Error::Input(format!("host renderer: {e}"))
}

impl OcclusionBackend for Host {
    fn draw_objects(&mut self, objects: &[u32]) -> CullResult<()> {
        if objects.is_empty() {
            return Ok(());
        }
        self.ensure_recording().map_err(host_error)?;
        self.set_state(false);
        let cmd = self.segments[self.used - 1].0;
        for &o in objects {
            let (count, first, offset) = self.objects[o as usize];
            // SAFETY: recording inside rendering with the render pipeline bound.
            unsafe {
                self.device
                    .cmd_draw_indexed(cmd, count, 1, first, offset, o)
            };
            self.draws += 1;
        }
        Ok(())
    }

    fn issue_query(&mut self, boxes: &[Aabb]) -> CullResult<QueryId> {
        if self.queries == MAX_QUERIES
            || self.boxes_used + boxes.len() as u64 > MAX_BOXES
            || boxes.len() > 1024
        {
            return Err(host_error("query budget of this simple host exceeded"));
        }
        self.ensure_recording().map_err(host_error)?;
        self.set_state(true);
        let cmd = self.segments[self.used - 1].0;
        let corners: Vec<f32> = boxes
            .iter()
            .flat_map(|b| {
                (0..8).flat_map(move |c| {
                    [
                        if c & 1 == 0 { b.min.x } else { b.max.x },
                        if c & 2 == 0 { b.min.y } else { b.max.y },
                        if c & 4 == 0 { b.min.z } else { b.max.z },
                    ]
                })
            })
            .collect();
        let ptr = self.buffers[4].1.ptr;
        // SAFETY: the box buffer is mapped, large enough (checked above) and this range is unused
        // by submitted work (ranges only grow within a frame).
        unsafe {
            std::ptr::copy_nonoverlapping(
                corners.as_ptr() as *const u8,
                ptr.add((self.boxes_used * 96) as usize),
                corners.len() * 4,
            );
        }
        let id = self.queries;
        // SAFETY: the query was reset at frame start; recording inside rendering.
        unsafe {
            self.device
                .cmd_begin_query(cmd, self.query_pool, id, vk::QueryControlFlags::PRECISE);
            self.device.cmd_draw_indexed(
                cmd,
                36 * boxes.len() as u32,
                1,
                0,
                (self.boxes_used * 8) as i32,
                0,
            );
            self.device.cmd_end_query(cmd, self.query_pool, id);
        }
        self.boxes_used += boxes.len() as u64;
        self.queries += 1;
        self.query_segment.push(self.used - 1);
        Ok(id)
    }

    fn flush(&mut self) -> CullResult<()> {
        if !self.recording {
            return Ok(());
        }
        let (cmd, fence) = self.segments[self.used - 1];
        let cmds = [cmd];
        // SAFETY: recording inside rendering; the fence is unsignaled.
        unsafe {
            self.device.cmd_end_rendering(cmd);
            self.device.end_command_buffer(cmd).map_err(host_error)?;
            self.device
                .queue_submit(
                    self.queue,
                    &[vk::SubmitInfo::default().command_buffers(&cmds)],
                    fence,
                )
                .map_err(host_error)?;
        }
        self.recording = false;
        self.submits += 1;
        Ok(())
    }

    fn query_result(&mut self, query: QueryId) -> CullResult<Option<u64>> {
        if self.recording && self.query_segment[query as usize] == self.used - 1 {
            return Ok(None);
        }
        let mut data = [[0u64; 2]];
        // SAFETY: the query's command buffer was submitted; no WAIT flag.
        let r = unsafe {
            self.device.get_query_pool_results(
                self.query_pool,
                query,
                &mut data,
                vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WITH_AVAILABILITY,
            )
        };
        match r {
            Ok(()) if data[0][1] != 0 => Ok(Some(data[0][0])),
            Ok(()) | Err(vk::Result::NOT_READY) => Ok(None),
            Err(e) => Err(host_error(e)),
        }
    }

    fn wait_query(&mut self, query: QueryId) -> CullResult<u64> {
        if self.recording && self.query_segment[query as usize] == self.used - 1 {
            self.flush()?;
        }
        let fence = self.segments[self.query_segment[query as usize]].1;
        // SAFETY: the segment was submitted with this fence.
        unsafe { self.device.wait_for_fences(&[fence], true, u64::MAX) }.map_err(host_error)?;
        loop {
            if let Some(v) = self.query_result(query)? {
                return Ok(v);
            }
        }
    }

    fn finish(&mut self) -> CullResult<()> {
        if self.used == 0 {
            self.ensure_recording().map_err(host_error)?;
        }
        self.flush()?;
        let fences: Vec<_> = self.segments[..self.used].iter().map(|s| s.1).collect();
        // SAFETY: every used segment was submitted.
        unsafe { self.device.wait_for_fences(&fences, true, u64::MAX) }.map_err(host_error)
    }
}

impl Drop for Host {
    fn drop(&mut self) {
        // SAFETY: the device is idle; every object is destroyed once, children before parents.
        unsafe {
            let _ = self.device.device_wait_idle();
            for (_, fence) in &self.segments {
                self.device.destroy_fence(*fence, None);
            }
            self.device.destroy_command_pool(self.command_pool, None);
            self.device.destroy_query_pool(self.query_pool, None);
            self.device.destroy_pipeline(self.render_pipeline, None);
            self.device.destroy_pipeline(self.query_pipeline, None);
            raw_host::destroy_storage_set(&self.device, &self.set);
            for image in self.images.drain(..) {
                raw_host::destroy_image(&self.device, image);
            }
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

impl Host {
    /// Moves `object`: rewrites its model and normal matrices in the (host-coherent) object
    /// buffer. Called between frames, when no segment is in flight.
    fn set_transform(&mut self, object: u32, m: &glam::Mat4) {
        let mut data = [0f32; 32];
        data[..16].copy_from_slice(&m.to_cols_array());
        data[16..].copy_from_slice(&m.inverse().transpose().to_cols_array());
        let (_, memory) = &self.buffers[2]; // vertices, indices, objects
                                            // SAFETY: the object buffer is mapped and holds 36 floats per object; `object` is one
                                            // of the scene's; the previous frame has completed (end of cull_frame waited for it).
        unsafe {
            std::ptr::copy_nonoverlapping(
                data.as_ptr() as *const u8,
                memory.ptr.add(object as usize * 36 * 4),
                32 * 4,
            );
        }
    }
}

/// The moving object of the demo: the scene's last object (a piece of street furniture) driving
/// down the first street towards the camera. An object-space box around it (the world box taken
/// back through the inverse transform) and its transform at `frame`.
fn mover_at(scene: &Scene, car: u32, frame: u32) -> (Aabb, glam::Mat4) {
    let o = &scene.objects[car as usize];
    let local = o.bounds.transformed(&o.transform.inverse());
    let m = glam::Mat4::from_translation(glam::Vec3::new(49.0, 0.0, 90.0 - frame as f32 * 3.0))
        * glam::Mat4::from_rotation_y(std::f32::consts::FRAC_PI_2);
    (local, m)
}

fn main() -> Result<()> {
    let scene = Scene::load("city", 0.25, 4096)?;
    let bounds: Vec<_> = scene.objects.iter().map(|o| o.bounds).collect();
    let mut bvh = ObjectBvh::build(&bounds, 1);
    // An object of the city that the host moves through the scene.
    let car = (scene.objects.len() - 1) as u32;
    let path = scene.path("street")?.clone();
    let mut host = Host::new(&scene)?;
    let mut culler = coherent::culling::chcpp::Chcpp::new(ChcppParams::default());
    println!(
        "host engine: {} objects, {} triangles; culling with {}",
        scene.objects.len(),
        scene.triangle_count(),
        culler.name()
    );
    println!("frame  ms      draws  queries  visible  state-switches  submits  refit-nodes");
    for frame in 0..12u32 {
        // The host moves its object through the public API: new box into the hierarchy (then
        // update: refit), new transform into its own object buffer.
        let (local, m) = mover_at(&scene, car, frame);
        bvh.set_bounds(car, local.transformed(&m))?;
        let update = bvh.update();
        host.set_transform(car, &m);
        let pose = path.pose_at(frame as f32 * 4.0);
        let far = bvh.nodes[0].bounds.extent().length() * 2.0;
        let camera = Camera::from_pose(pose, WIDTH as f32 / HEIGHT as f32, far);
        host.begin_frame(&camera, scene.sun_dir)?;
        let start = std::time::Instant::now();
        let input = FrameInput {
            bvh: &bvh,
            view: (&camera).into(),
            frame: frame as u64,
            exact_visible: None,
        };
        let stats = culler.cull_frame(&input, &mut host)?;
        let ms = start.elapsed().as_secs_f64() * 1e3;
        println!(
            "{frame:5}  {ms:6.1}  {:5}  {:7}  {:7}  {:14}  {:7}  {:11}",
            host.draws,
            stats.queries,
            stats.visible_results,
            host.switches,
            host.submits,
            update.refitted_nodes
        );
    }
    drop(host);
    let n = MESSAGES.load(Ordering::SeqCst);
    if n > 0 {
        bail!("{n} validation messages");
    }
    println!("validation: no messages");
    Ok(())
}
