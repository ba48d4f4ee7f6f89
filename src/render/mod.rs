//! Frame orchestration: the forward renderer that implements [`OcclusionBackend`]. A frame is a
//! chain of segments (command buffers): when a culler needs query results the current segment is
//! submitted and recording goes on in the next one, which resumes rendering with LOAD ops.

pub mod frame;
pub mod overlay;
pub mod upload;
pub mod viewer;
pub mod walk;

use std::sync::Arc;
use std::time::{Duration, Instant};

use ash::vk;
use gpu_allocator::MemoryLocation;

use crate::bvh::ObjectBvh;
use crate::culling::{CullStats, Culler, FrameInput, OcclusionBackend, QueryId};
use crate::error::{Error, Result, VkContext};
use crate::gpu::commands::{begin_one_time, image_barrier};
use crate::gpu::memory::{Buffer, Image};
use crate::gpu::pipelines::{Pipeline, PipelineDesc, PipelineKind, PipelineLayout};
use crate::gpu::queries::QueryPools;
use crate::gpu::targets::{self, Target, COLOR_FORMAT, DEPTH_FORMAT, ID_FORMAT};
use crate::gpu::{shaders, CommandCounts, GpuContext, OneShot, Recorder};
use crate::scene::camera::Camera;
use crate::scene::{Aabb, Scene};

pub use frame::FrameResult;

/// Boxes per box-vertex chunk (8 corners each).
const BOX_CHUNK: u32 = 16384;
/// Push-constant block: view_proj (64 bytes) and sun direction (16 bytes).
const PUSH_SIZE: u32 = 80;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Bound {
    Scene,
    Boxes(usize),
}

struct Segment {
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
}

#[derive(Clone, Copy, Debug)]
struct ObjectDraw {
    first_index: u32,
    index_count: u32,
    vertex_offset: i32,
}

/// The forward renderer: scene geometry on the GPU, the render/query/ID pipelines, an offscreen
/// target, and the segment machinery that lets a culler read query results within a frame.
pub struct Renderer {
    ctx: Arc<GpuContext>,
    objects: Vec<ObjectDraw>,
    triangles: u64,
    // Pipelines are declared before the layout so they are dropped first.
    render_pipeline: Pipeline,
    query_pipeline: Pipeline,
    id_pipeline: Pipeline,
    layout: PipelineLayout,
    vertex_buffer: Buffer,
    index_buffer: Buffer,
    #[allow(dead_code)] // owned here; the descriptor set points at it
    object_buffer: Buffer,
    box_index_buffer: Buffer,
    box_chunks: Vec<Buffer>,
    box_chunk: usize,
    box_used: u32,
    target: Target,
    id_image: Option<Image>,
    descriptor_pool: vk::DescriptorPool,
    descriptor_set: vk::DescriptorSet,
    command_pool: vk::CommandPool,
    segments: Vec<Segment>,
    segments_used: usize,
    recording: bool,
    occlusion: QueryPools,
    timestamps: QueryPools,
    query_segment: Vec<u32>,
    query_read: Vec<bool>,
    recorder: Recorder,
    oneshot: OneShot,
    push: [u8; PUSH_SIZE as usize],
    bound: Option<Bound>,
    stall: Duration,
    prepass_counts: CommandCounts,
    /// Pixel count above which a query result means visible (for counting wasted queries).
    pub visibility_threshold: u64,
}

impl Renderer {
    /// Uploads `scene` and creates pipelines and a `width`x`height` target.
    pub fn new(ctx: &Arc<GpuContext>, scene: &Scene, width: u32, height: u32) -> Result<Renderer> {
        let target = Target::new(ctx, width, height)?;
        let uploaded = upload::upload_scene(ctx, scene)?;
        let layout = PipelineLayout::new(ctx, &[vk::DescriptorType::STORAGE_BUFFER], PUSH_SIZE)?;
        let scene_attrs = [
            (0, vk::Format::R32G32B32_SFLOAT, 0),
            (1, vk::Format::R32G32B32_SFLOAT, 12),
        ];
        let render_pipeline = Pipeline::graphics(
            ctx,
            &layout,
            &PipelineDesc {
                name: "render",
                vert: shaders::SCENE_VERT,
                frag: Some(shaders::SCENE_FRAG),
                vertex_stride: 24,
                attributes: &scene_attrs,
                color_formats: &[COLOR_FORMAT],
                color_write: true,
                depth_format: DEPTH_FORMAT,
                depth_compare: vk::CompareOp::LESS,
                depth_write: true,
                cull: vk::CullModeFlags::BACK,
                kind: PipelineKind::Render,
                depth_bias: (0.0, 0.0),
            },
        )?;
        let query_pipeline = Pipeline::graphics(
            ctx,
            &layout,
            &PipelineDesc {
                name: "query",
                vert: shaders::BOX_VERT,
                frag: None,
                vertex_stride: 12,
                attributes: &[(0, vk::Format::R32G32B32_SFLOAT, 0)],
                color_formats: &[COLOR_FORMAT],
                color_write: false,
                depth_format: DEPTH_FORMAT,
                depth_compare: vk::CompareOp::LESS_OR_EQUAL,
                depth_write: false,
                // Front faces suffice: the camera is never inside a queried box (enlarged by the
                // near-plane corner distance), so every visible point of a box is covered by a
                // front face at most as deep. Halves the query fill.
                cull: vk::CullModeFlags::BACK,
                kind: PipelineKind::Query,
                depth_bias: (0.0, 0.0),
            },
        )?;
        let id_pipeline = Pipeline::graphics(
            ctx,
            &layout,
            &PipelineDesc {
                name: "id",
                vert: shaders::SCENE_VERT,
                frag: Some(shaders::ID_FRAG),
                vertex_stride: 24,
                attributes: &scene_attrs,
                color_formats: &[ID_FORMAT],
                color_write: true,
                depth_format: DEPTH_FORMAT,
                depth_compare: vk::CompareOp::LESS,
                depth_write: true,
                cull: vk::CullModeFlags::BACK,
                kind: PipelineKind::Other,
                depth_bias: (0.0, 0.0),
            },
        )?;
        let box_index_buffer = Buffer::with_data(
            ctx,
            "box indices",
            &upload::as_bytes(&upload::box_indices(BOX_CHUNK)),
            vk::BufferUsageFlags::INDEX_BUFFER,
        )?;
        let first_chunk = Buffer::new(
            ctx,
            "box corners",
            BOX_CHUNK as u64 * 8 * 12,
            vk::BufferUsageFlags::VERTEX_BUFFER,
            MemoryLocation::CpuToGpu,
        )?;
        let pool_sizes = [vk::DescriptorPoolSize {
            ty: vk::DescriptorType::STORAGE_BUFFER,
            descriptor_count: 1,
        }];
        let pool_info = vk::DescriptorPoolCreateInfo::default()
            .max_sets(1)
            .pool_sizes(&pool_sizes);
        // SAFETY: valid device and create info.
        let descriptor_pool = unsafe { ctx.device.create_descriptor_pool(&pool_info, None) }
            .vk("vkCreateDescriptorPool")?;
        let layouts = [layout.set_layout];
        let alloc = vk::DescriptorSetAllocateInfo::default()
            .descriptor_pool(descriptor_pool)
            .set_layouts(&layouts);
        // SAFETY: pool has room for one set.
        let sets = unsafe { ctx.device.allocate_descriptor_sets(&alloc) };
        let descriptor_set = match sets {
            Ok(s) => s[0],
            Err(e) => {
                // SAFETY: created above, unused.
                unsafe { ctx.device.destroy_descriptor_pool(descriptor_pool, None) };
                return Err(Error::Vulkan {
                    call: "vkAllocateDescriptorSets",
                    result: e,
                });
            }
        };
        let buffer_info = [vk::DescriptorBufferInfo {
            buffer: uploaded.objects.handle,
            offset: 0,
            range: vk::WHOLE_SIZE,
        }];
        let write = vk::WriteDescriptorSet::default()
            .dst_set(descriptor_set)
            .dst_binding(0)
            .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
            .buffer_info(&buffer_info);
        // SAFETY: set and buffer are valid; the set is not in use.
        unsafe { ctx.device.update_descriptor_sets(&[write], &[]) };
        let pool_info = vk::CommandPoolCreateInfo::default().queue_family_index(ctx.queue_family);
        // SAFETY: valid device.
        let command_pool = match unsafe { ctx.device.create_command_pool(&pool_info, None) } {
            Ok(p) => p,
            Err(e) => {
                // SAFETY: created above, unused.
                unsafe { ctx.device.destroy_descriptor_pool(descriptor_pool, None) };
                return Err(Error::Vulkan {
                    call: "vkCreateCommandPool",
                    result: e,
                });
            }
        };
        let mut sun = [0u8; 16];
        sun[..12].copy_from_slice(&upload::as_bytes(
            &scene.sun_dir.normalize_or(glam::Vec3::Y).to_array(),
        ));
        let mut push = [0u8; PUSH_SIZE as usize];
        push[64..80].copy_from_slice(&sun);
        let renderer = Renderer {
            ctx: ctx.clone(),
            objects: scene
                .objects
                .iter()
                .map(|o| ObjectDraw {
                    first_index: o.first_index,
                    index_count: o.index_count,
                    vertex_offset: o.vertex_offset as i32,
                })
                .collect(),
            triangles: scene.objects.iter().map(|o| o.triangle_count()).sum(),
            render_pipeline,
            query_pipeline,
            id_pipeline,
            layout,
            vertex_buffer: uploaded.vertices,
            index_buffer: uploaded.indices,
            object_buffer: uploaded.objects,
            box_index_buffer,
            box_chunks: vec![first_chunk],
            box_chunk: 0,
            box_used: 0,
            target,
            id_image: None,
            descriptor_pool,
            descriptor_set,
            command_pool,
            segments: Vec::new(),
            segments_used: 0,
            recording: false,
            occlusion: QueryPools::new(ctx, vk::QueryType::OCCLUSION, 1024)?,
            timestamps: QueryPools::new(ctx, vk::QueryType::TIMESTAMP, 256)?,
            query_segment: Vec::new(),
            query_read: Vec::new(),
            recorder: Recorder::new(ctx.device.clone()),
            oneshot: OneShot::new(ctx)?,
            push,
            bound: None,
            stall: Duration::ZERO,
            prepass_counts: CommandCounts::default(),
            visibility_threshold: 0,
        };
        Ok(renderer)
    }

    /// The context.
    pub fn context(&self) -> &Arc<GpuContext> {
        &self.ctx
    }

    /// Target size.
    pub fn size(&self) -> (u32, u32) {
        (self.target.extent.width, self.target.extent.height)
    }

    /// The offscreen color image; after [`Renderer::render_frame`] it is in
    /// COLOR_ATTACHMENT_OPTIMAL (the viewer blits it to the window).
    pub fn color_image(&self) -> &Image {
        &self.target.color
    }

    /// Binds, draws, triangles and submits of the exact-visibility pre-pass
    /// ([`Renderer::exact_visible`], the oracle's) since the last call. They are not in
    /// [`FrameResult::counts`] (the pass is a reference, not part of the algorithm) but are
    /// submitted all the same, so the viewer adds them to its per-frame totals.
    pub fn take_prepass_counts(&mut self) -> CommandCounts {
        std::mem::take(&mut self.prepass_counts)
    }

    /// Triangles in the scene.
    pub fn scene_triangles(&self) -> u64 {
        self.triangles
    }

    /// Capacity of the occlusion query pools now (they grow on demand).
    pub fn query_capacity(&self) -> u32 {
        self.occlusion.capacity()
    }

    /// A camera with this target's aspect ratio for `pose`, with a far plane that covers `bvh`.
    pub fn camera(&self, pose: crate::scene::CameraPose, bvh: &ObjectBvh) -> Camera {
        let b = bvh.nodes[0].bounds;
        let far = (b.extent().length() * 2.0 + (pose.eye - b.center()).length()).max(10.0);
        let (w, h) = self.size();
        Camera::from_pose(pose, w as f32 / h as f32, far)
    }

    /// Renders one frame with `culler` and reports it.
    pub fn render_frame(
        &mut self,
        culler: &mut dyn Culler,
        bvh: &ObjectBvh,
        camera: &Camera,
        frame: u64,
    ) -> Result<FrameResult> {
        let exact = if culler.needs_exact_visibility() {
            Some(self.exact_visible(bvh, camera)?)
        } else {
            None
        };
        self.begin_frame(camera)?;
        let start = Instant::now();
        let input = FrameInput {
            bvh,
            camera,
            frame,
            exact_visible: exact.as_deref(),
        };
        let cull = culler.cull_frame(&input, self);
        let finished = self.finish();
        let frame_time = start.elapsed();
        let cull: CullStats = cull?;
        finished?;
        let gpu_ms = self.gpu_time_ms()?;
        let counts: CommandCounts = self.recorder.take_counts();
        let unread = self.query_read.iter().filter(|r| !**r).count();
        if unread > 0 {
            return Err(Error::Input(format!(
                "{}: {unread} occlusion queries were issued but never read back",
                culler.name()
            )));
        }
        Ok(FrameResult {
            frame_ms: frame_time.as_secs_f64() * 1e3,
            gpu_ms,
            stall_ms: self.stall.as_secs_f64() * 1e3,
            counts,
            cull,
        })
    }

    /// Reads the color target back as RGBA8 rows (bottom row last).
    pub fn read_color(&mut self) -> Result<Vec<u8>> {
        targets::read_image(
            &self.ctx,
            &self.oneshot,
            &mut self.recorder,
            &self.target.color,
            vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL,
            vk::PipelineStageFlags2::COLOR_ATTACHMENT_OUTPUT,
            vk::AccessFlags2::COLOR_ATTACHMENT_WRITE,
        )
    }

    /// Saves the color target as a PNG.
    pub fn save_png(&mut self, path: &std::path::Path) -> Result<()> {
        let (w, h) = self.size();
        let pixels = self.read_color()?;
        save_rgba_png(path, w, h, pixels)
    }

    fn begin_frame(&mut self, camera: &Camera) -> Result<()> {
        // SAFETY: the previous frame's finish() waited for all its fences.
        unsafe {
            self.ctx
                .device
                .reset_command_pool(self.command_pool, vk::CommandPoolResetFlags::empty())
                .vk("vkResetCommandPool")?;
            let fences: Vec<_> = self.segments[..self.segments_used]
                .iter()
                .map(|s| s.fence)
                .collect();
            if !fences.is_empty() {
                self.ctx.device.reset_fences(&fences).vk("vkResetFences")?;
            }
        }
        self.segments_used = 0;
        self.recording = false;
        self.occlusion.reset();
        self.timestamps.reset();
        self.query_segment.clear();
        self.query_read.clear();
        self.box_chunk = 0;
        self.box_used = 0;
        self.stall = Duration::ZERO;
        self.recorder.take_counts();
        let vp = camera.view_proj();
        self.push[..64].copy_from_slice(&upload::as_bytes(&vp.to_cols_array()));
        Ok(())
    }

    fn ensure_recording(&mut self) -> Result<()> {
        if self.recording {
            return Ok(());
        }
        let d = &self.ctx.device;
        if self.segments_used == self.segments.len() {
            let alloc = vk::CommandBufferAllocateInfo::default()
                .command_pool(self.command_pool)
                .level(vk::CommandBufferLevel::PRIMARY)
                .command_buffer_count(1);
            // SAFETY: valid pool; the buffer is owned by it.
            let cmd =
                unsafe { d.allocate_command_buffers(&alloc) }.vk("vkAllocateCommandBuffers")?[0];
            // SAFETY: valid device.
            let fence = unsafe { d.create_fence(&vk::FenceCreateInfo::default(), None) }
                .vk("vkCreateFence")?;
            self.segments.push(Segment { cmd, fence });
        }
        let first = self.segments_used == 0;
        let cmd = self.segments[self.segments_used].cmd;
        self.segments_used += 1;
        // The pool was reset at frame start; this buffer is not in flight.
        begin_one_time(d, cmd, false)?;
        self.recorder.set_command_buffer(cmd);
        self.bound = None;
        let ts = self.timestamps.allocate()?;
        let (pool, slot) = self.timestamps.location(ts);
        self.recorder.write_timestamp(pool, slot);
        let color = &self.target.color;
        let depth = &self.target.depth;
        let color_state = (
            vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL,
            vk::PipelineStageFlags2::COLOR_ATTACHMENT_OUTPUT,
            vk::AccessFlags2::COLOR_ATTACHMENT_WRITE | vk::AccessFlags2::COLOR_ATTACHMENT_READ,
        );
        let depth_stages = vk::PipelineStageFlags2::EARLY_FRAGMENT_TESTS
            | vk::PipelineStageFlags2::LATE_FRAGMENT_TESTS;
        let depth_state = (
            vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL,
            depth_stages,
            vk::AccessFlags2::DEPTH_STENCIL_ATTACHMENT_WRITE
                | vk::AccessFlags2::DEPTH_STENCIL_ATTACHMENT_READ,
        );
        let undefined = (
            vk::ImageLayout::UNDEFINED,
            vk::PipelineStageFlags2::NONE,
            vk::AccessFlags2::NONE,
        );
        let (cfrom, dfrom) = if first {
            (undefined, undefined)
        } else {
            (color_state, depth_state)
        };
        self.recorder.barrier(
            &[
                image_barrier(color.handle, color.full_range(), cfrom, color_state),
                image_barrier(depth.handle, depth.full_range(), dfrom, depth_state),
            ],
            &[],
        );
        let load = if first {
            vk::AttachmentLoadOp::CLEAR
        } else {
            vk::AttachmentLoadOp::LOAD
        };
        let color_att = [vk::RenderingAttachmentInfo::default()
            .image_view(color.view)
            .image_layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)
            .load_op(load)
            .store_op(vk::AttachmentStoreOp::STORE)
            .clear_value(vk::ClearValue {
                color: vk::ClearColorValue {
                    float32: [0.62, 0.74, 0.86, 1.0],
                },
            })];
        let depth_att = targets::depth_attachment(depth.view, load, vk::AttachmentStoreOp::STORE);
        let info = vk::RenderingInfo::default()
            .render_area(vk::Rect2D {
                offset: vk::Offset2D::default(),
                extent: self.target.extent,
            })
            .layer_count(1)
            .color_attachments(&color_att)
            .depth_attachment(&depth_att);
        self.recorder.begin_rendering(&info);
        self.recorder.set_viewport(self.target.extent);
        self.recorder.bind_descriptor_set(
            vk::PipelineBindPoint::GRAPHICS,
            self.layout.handle,
            self.descriptor_set,
        );
        self.recorder.push_constants(
            self.layout.handle,
            vk::ShaderStageFlags::VERTEX
                | vk::ShaderStageFlags::FRAGMENT
                | vk::ShaderStageFlags::COMPUTE,
            &self.push,
        );
        self.recording = true;
        Ok(())
    }

    fn submit_segment(&mut self) -> Result<()> {
        if !self.recording {
            return Ok(());
        }
        self.recorder.end_rendering();
        let ts = self.timestamps.allocate()?;
        let (pool, slot) = self.timestamps.location(ts);
        self.recorder.write_timestamp(pool, slot);
        let seg = &self.segments[self.segments_used - 1];
        let cmds = [seg.cmd];
        let submit = vk::SubmitInfo::default().command_buffers(&cmds);
        // SAFETY: recorded completely above; the fence is unsignaled (reset at frame start).
        unsafe {
            self.ctx
                .device
                .end_command_buffer(seg.cmd)
                .vk("vkEndCommandBuffer")?;
            self.ctx
                .device
                .queue_submit(self.ctx.queue, &[submit], seg.fence)
                .vk("vkQueueSubmit")?;
        }
        self.recorder.note_submit();
        self.recording = false;
        Ok(())
    }

    fn gpu_time_ms(&self) -> Result<f64> {
        let mut total = 0u64;
        let n = self.timestamps.used();
        let mut i = 0;
        while i + 1 < n {
            let a = self.timestamps.poll(i)?.unwrap_or(0);
            let b = self.timestamps.poll(i + 1)?.unwrap_or(a);
            total += b.saturating_sub(a);
            i += 2;
        }
        Ok(total as f64 * self.ctx.info.timestamp_period_ns as f64 * 1e-6)
    }

    fn use_pipeline(&mut self, kind: PipelineKind) {
        let p = if kind == PipelineKind::Query {
            &self.query_pipeline
        } else {
            &self.render_pipeline
        };
        self.recorder.bind_pipeline(p);
    }

    /// Finds the objects that cover at least one pixel: renders the frustum's objects into an
    /// object-ID image and reads it back. Not part of any frame's time or counts.
    pub fn exact_visible(&mut self, bvh: &ObjectBvh, camera: &Camera) -> Result<Vec<u32>> {
        if self.id_image.is_none() {
            self.id_image = Some(Image::new(
                &self.ctx,
                "object ids",
                ID_FORMAT,
                self.target.extent,
                1,
                vk::ImageUsageFlags::COLOR_ATTACHMENT | vk::ImageUsageFlags::TRANSFER_SRC,
            )?);
        }
        let frustum = camera.frustum();
        let mut candidates = Vec::new();
        bvh.front_to_back(camera.eye, |id, node| {
            if !frustum.intersects(&node.bounds) {
                return false;
            }
            candidates.extend_from_slice(bvh.objects(id));
            true
        });
        let mut push = self.push;
        push[..64].copy_from_slice(&upload::as_bytes(&camera.view_proj().to_cols_array()));
        let Some(ids) = self.id_image.as_ref() else {
            return Ok(Vec::new());
        };
        let depth = &self.target.depth;
        let extent = self.target.extent;
        let (layout, set) = (self.layout.handle, self.descriptor_set);
        let (pipeline, vb, ib) = (
            &self.id_pipeline,
            self.vertex_buffer.handle,
            self.index_buffer.handle,
        );
        let objects = &self.objects;
        let mut pass = CommandCounts::default();
        self.oneshot.run(&mut self.recorder, |rec| {
            let before = rec.counts;
            let undefined = (
                vk::ImageLayout::UNDEFINED,
                vk::PipelineStageFlags2::NONE,
                vk::AccessFlags2::NONE,
            );
            rec.barrier(
                &[
                    image_barrier(
                        ids.handle,
                        ids.full_range(),
                        undefined,
                        (
                            vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL,
                            vk::PipelineStageFlags2::COLOR_ATTACHMENT_OUTPUT,
                            vk::AccessFlags2::COLOR_ATTACHMENT_WRITE,
                        ),
                    ),
                    image_barrier(
                        depth.handle,
                        depth.full_range(),
                        undefined,
                        (
                            vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL,
                            vk::PipelineStageFlags2::EARLY_FRAGMENT_TESTS
                                | vk::PipelineStageFlags2::LATE_FRAGMENT_TESTS,
                            vk::AccessFlags2::DEPTH_STENCIL_ATTACHMENT_WRITE
                                | vk::AccessFlags2::DEPTH_STENCIL_ATTACHMENT_READ,
                        ),
                    ),
                ],
                &[],
            );
            let color_att = [vk::RenderingAttachmentInfo::default()
                .image_view(ids.view)
                .image_layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)
                .load_op(vk::AttachmentLoadOp::CLEAR)
                .store_op(vk::AttachmentStoreOp::STORE)
                .clear_value(vk::ClearValue {
                    color: vk::ClearColorValue { uint32: [0; 4] },
                })];
            let depth_att = targets::depth_attachment(
                depth.view,
                vk::AttachmentLoadOp::CLEAR,
                vk::AttachmentStoreOp::DONT_CARE,
            );
            let info = vk::RenderingInfo::default()
                .render_area(vk::Rect2D {
                    offset: vk::Offset2D::default(),
                    extent,
                })
                .layer_count(1)
                .color_attachments(&color_att)
                .depth_attachment(&depth_att);
            rec.begin_rendering(&info);
            rec.set_viewport(extent);
            rec.bind_pipeline(pipeline);
            rec.bind_descriptor_set(vk::PipelineBindPoint::GRAPHICS, layout, set);
            rec.push_constants(
                layout,
                vk::ShaderStageFlags::VERTEX
                    | vk::ShaderStageFlags::FRAGMENT
                    | vk::ShaderStageFlags::COMPUTE,
                &push,
            );
            rec.bind_buffers(vb, 0, Some(ib));
            for &o in &candidates {
                let d = objects[o as usize];
                if d.index_count > 0 {
                    rec.draw_indexed(d.index_count, 1, d.first_index, d.vertex_offset, o);
                }
            }
            rec.end_rendering();
            pass.pipeline_binds = rec.counts.pipeline_binds - before.pipeline_binds;
            pass.draw_calls = rec.counts.draw_calls - before.draw_calls;
            pass.triangles = rec.counts.triangles - before.triangles;
        })?;
        // The ID pass and its readback are two submissions.
        pass.submits = 2;
        let p = &mut self.prepass_counts;
        p.pipeline_binds += pass.pipeline_binds;
        p.draw_calls += pass.draw_calls;
        p.triangles += pass.triangles;
        p.submits += pass.submits;
        let bytes = targets::read_image(
            &self.ctx,
            &self.oneshot,
            &mut self.recorder,
            ids,
            vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL,
            vk::PipelineStageFlags2::COLOR_ATTACHMENT_OUTPUT,
            vk::AccessFlags2::COLOR_ATTACHMENT_WRITE,
        )?;
        let mut seen = vec![false; self.objects.len()];
        for px in bytes.chunks_exact(4) {
            let id = u32::from_le_bytes([px[0], px[1], px[2], px[3]]);
            if id > 0 && ((id - 1) as usize) < seen.len() {
                seen[(id - 1) as usize] = true;
            }
        }
        // Keep front-to-back order for the draw.
        Ok(candidates
            .into_iter()
            .filter(|&o| seen[o as usize])
            .collect())
    }
}

impl OcclusionBackend for Renderer {
    fn draw_objects(&mut self, objects: &[u32]) -> Result<()> {
        if objects.is_empty() {
            return Ok(());
        }
        self.ensure_recording()?;
        self.use_pipeline(PipelineKind::Render);
        if self.bound != Some(Bound::Scene) {
            self.recorder.bind_buffers(
                self.vertex_buffer.handle,
                0,
                Some(self.index_buffer.handle),
            );
            self.bound = Some(Bound::Scene);
        }
        for &o in objects {
            let d = *self.objects.get(o as usize).ok_or_else(|| {
                Error::Input(format!(
                    "object {o} does not exist (scene has {})",
                    self.objects.len()
                ))
            })?;
            if d.index_count > 0 {
                self.recorder
                    .draw_indexed(d.index_count, 1, d.first_index, d.vertex_offset, o);
            }
        }
        Ok(())
    }

    fn issue_query(&mut self, boxes: &[Aabb]) -> Result<QueryId> {
        self.ensure_recording()?;
        self.use_pipeline(PipelineKind::Query);
        let id = self.occlusion.allocate()?;
        self.query_segment.push((self.segments_used - 1) as u32);
        self.query_read.push(false);
        let (pool, slot) = self.occlusion.location(id);
        self.recorder.begin_occlusion_query(pool, slot);
        let mut rest = boxes;
        while !rest.is_empty() {
            if self.box_used == BOX_CHUNK {
                self.box_chunk += 1;
                self.box_used = 0;
                if self.box_chunk == self.box_chunks.len() {
                    self.box_chunks.push(Buffer::new(
                        &self.ctx,
                        "box corners",
                        BOX_CHUNK as u64 * 8 * 12,
                        vk::BufferUsageFlags::VERTEX_BUFFER,
                        MemoryLocation::CpuToGpu,
                    )?);
                }
            }
            let n = (BOX_CHUNK - self.box_used).min(rest.len() as u32);
            let corners = upload::box_corners(&rest[..n as usize]);
            let chunk = &mut self.box_chunks[self.box_chunk];
            chunk.write(self.box_used as usize * 96, &upload::as_bytes(&corners))?;
            if self.bound != Some(Bound::Boxes(self.box_chunk)) {
                self.recorder
                    .bind_buffers(chunk.handle, 0, Some(self.box_index_buffer.handle));
                self.bound = Some(Bound::Boxes(self.box_chunk));
            }
            self.recorder
                .draw_indexed(36 * n, 1, 0, (self.box_used * 8) as i32, 0);
            self.box_used += n;
            rest = &rest[n as usize..];
        }
        self.recorder.end_query(pool, slot);
        Ok(id)
    }

    fn restore_render_state(&mut self) -> Result<()> {
        if self.recording {
            self.use_pipeline(PipelineKind::Render);
        }
        Ok(())
    }

    fn flush(&mut self) -> Result<()> {
        self.submit_segment()
    }

    fn query_result(&mut self, query: QueryId) -> Result<Option<u64>> {
        let seg = *self
            .query_segment
            .get(query as usize)
            .ok_or_else(|| Error::Input(format!("query {query} was not issued this frame")))?
            as usize;
        if self.recording && seg == self.segments_used - 1 {
            return Ok(None);
        }
        let r = self.occlusion.poll(query)?;
        if let Some(v) = r {
            if !self.query_read[query as usize] {
                self.query_read[query as usize] = true;
                self.recorder.note_query_read(v > self.visibility_threshold);
            }
        }
        Ok(r)
    }

    fn wait_query(&mut self, query: QueryId) -> Result<u64> {
        if let Some(v) = self.query_result(query)? {
            return Ok(v);
        }
        let seg = self.query_segment[query as usize] as usize;
        if self.recording && seg == self.segments_used - 1 {
            self.submit_segment()?;
        }
        let start = Instant::now();
        let fence = self.segments[seg].fence;
        // SAFETY: the segment holding the query was submitted with this fence.
        unsafe { self.ctx.device.wait_for_fences(&[fence], true, u64::MAX) }
            .vk("vkWaitForFences")?;
        let value = loop {
            if let Some(v) = self.query_result(query)? {
                break v;
            }
            std::hint::spin_loop();
        };
        self.stall += start.elapsed();
        Ok(value)
    }

    fn finish(&mut self) -> Result<()> {
        if self.segments_used == 0 {
            // Nothing was drawn: still clear the target.
            self.ensure_recording()?;
        }
        self.submit_segment()?;
        let fences: Vec<_> = self.segments[..self.segments_used]
            .iter()
            .map(|s| s.fence)
            .collect();
        // SAFETY: every used segment was submitted with its fence.
        unsafe { self.ctx.device.wait_for_fences(&fences, true, u64::MAX) }
            .vk("vkWaitForFences")?;
        Ok(())
    }
}

impl Drop for Renderer {
    fn drop(&mut self) {
        // SAFETY: after the device is idle nothing uses the fences, pools or sets.
        unsafe {
            let _ = self.ctx.device.device_wait_idle();
            for s in &self.segments {
                self.ctx.device.destroy_fence(s.fence, None);
            }
            self.ctx
                .device
                .destroy_command_pool(self.command_pool, None);
            self.ctx
                .device
                .destroy_descriptor_pool(self.descriptor_pool, None);
        }
    }
}

/// Writes RGBA8 pixels (rows bottom-up as rendered with a flipped viewport are already top-down
/// in memory) to a PNG.
pub fn save_rgba_png(path: &std::path::Path, w: u32, h: u32, pixels: Vec<u8>) -> Result<()> {
    let img = image::RgbaImage::from_raw(w, h, pixels)
        .ok_or_else(|| Error::Input("pixel buffer does not match the image size".into()))?;
    img.save(path)
        .map_err(|e| Error::Input(format!("{}: cannot write PNG: {e}", path.display())))
}
