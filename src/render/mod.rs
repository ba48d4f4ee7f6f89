//! Frame orchestration: the forward renderer that implements [`OcclusionBackend`]. A frame is a
//! chain of segments (command buffers): when a culler needs query results the current segment is
//! submitted and recording goes on in the next one, which resumes rendering with LOAD ops.

mod draw_log;
pub mod frame;
pub mod hiz;
mod ordered;
pub mod passes;
pub mod upload;

use std::sync::Arc;
use std::time::{Duration, Instant};

use ash::vk;
use gpu_allocator::MemoryLocation;

use crate::bvh::ObjectBvh;
use crate::culling::{CullStats, Culler, FrameInput, OcclusionBackend, QueryId, QueryPurpose};
use crate::error::{Error, Result};
use crate::gpu::queries::QueryPools;
use crate::gpu::targets::{self, Target, ID_FORMAT};
use crate::gpu::{
    bytes_of, Attachment, Binding, Buffer, CommandCounts, CommandPool, DescriptorSets, GpuContext,
    Image, ImageUse, Load, OneShot, PipelineKind, Recorder, Timeline,
};
use crate::scene::camera::{Camera, CameraView};
use crate::scene::{Aabb, Scene};
use passes::{ScenePipelines, PUSH_SIZE};

pub use frame::{Check, FrameResult};

/// Boxes per box-vertex chunk (8 corners each).
const BOX_CHUNK: u32 = 16384;
/// Bytes of one box's corners in a chunk.
const BOX_BYTES: usize = 8 * 12;
/// Indexed indirect draw commands per command chunk (predicated multi-draws).
const DRAW_CHUNK: u32 = 4096;
/// Bytes of one `VkDrawIndexedIndirectCommand`.
const DRAW_BYTES: usize = 20;
/// Sky color the first segment of a frame clears to.
const SKY: [f32; 4] = [0.62, 0.74, 0.86, 1.0];

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Bound {
    Scene,
    Boxes(usize),
}

#[derive(Clone, Copy, Debug)]
struct ObjectDraw {
    first_index: u32,
    index_count: u32,
    vertex_offset: i32,
    /// World-space bounds (GPU-driven culling reads them).
    bounds: Aabb,
    /// Descriptor set of its material's texture (0: none; scenes with materials).
    set: u32,
    /// Alpha cutoff of a masked material.
    mask: Option<f32>,
    /// Whether its material is `doubleSided` (drawn without back-face culling).
    double_sided: bool,
}

/// The forward renderer: scene geometry on the GPU, the render/query/ID pipelines, an offscreen
/// target, and the segment machinery that lets a culler read query results within a frame.
pub struct Renderer {
    ctx: Arc<GpuContext>,
    objects: Vec<ObjectDraw>,
    /// Bumped whenever an object's bounds change (GPU-driven culling re-uploads them).
    bounds_version: u64,
    triangles: u64,
    // The timeline is dropped first: it waits for every submitted segment.
    timeline: Timeline,
    segments: CommandPool,
    /// Timeline value of each segment of this frame submitted so far.
    segment_values: Vec<u64>,
    recording: bool,
    pipelines: ScenePipelines,
    descriptors: DescriptorSets,
    /// Textures and samplers of a scene with materials.
    materials: Option<upload::SceneMaterials>,
    /// The descriptor set bound in the segment being recorded.
    bound_set: u32,
    vertex_buffer: Buffer,
    index_buffer: Buffer,
    /// Per-object data (the descriptor set points at it); host-visible, rewritten between
    /// frames for objects that move.
    object_buffer: Buffer,
    /// Object slots the per-object buffer holds.
    object_slots: usize,
    box_index_buffer: Buffer,
    box_chunks: Vec<Buffer>,
    box_chunk: usize,
    box_used: u32,
    target: Target,
    id_image: Option<Image>,
    occlusion: QueryPools,
    timestamps: QueryPools,
    query_segment: Vec<u32>,
    query_read: Vec<bool>,
    /// Occlusion results read from the driver this frame (a segment's copy was missing).
    driver_reads: u32,
    /// Id of the first occlusion query of the segment being recorded: the segment copies the
    /// results of its queries into host memory at its end.
    segment_first_query: u32,
    recorder: Recorder,
    oneshot: OneShot,
    push: [u8; PUSH_SIZE as usize],
    bound: Option<Bound>,
    /// Scratch for query-box corners (reused, so queries do not allocate).
    corners: Vec<[f32; 3]>,
    stall: Duration,
    prepass_counts: CommandCounts,
    /// Pixel count above which a query result means visible (for counting wasted queries).
    pub visibility_threshold: u64,
    /// Predicates for conditional rendering: 4 bytes per occlusion query, one host-visible
    /// buffer per query pool (read back after the frame to count what was really drawn).
    predicates: Vec<Buffer>,
    /// Occlusion queries of this frame whose results are predicates already.
    predicates_resolved: u32,
    /// Leave out the barrier between the predicate copy and the conditional blocks (tests:
    /// the recorder must refuse).
    skip_predicate_barrier: bool,
    /// Host-visible chunks of indexed indirect draw commands: the objects of one predicate are
    /// drawn by one multi-draw (scenes without materials, on devices with `multiDrawIndirect`
    /// and `drawIndirectFirstInstance`).
    draw_chunks: Vec<Buffer>,
    /// The chunk being filled and the commands in it (this frame).
    draw_chunk: usize,
    draw_used: u32,
    /// Scratch for one multi-draw: its command bytes and its objects.
    draw_bytes: Vec<u8>,
    draw_objects: Vec<u32>,
    /// What the object draws drew (`walk --check`) and the mover draws.
    log: draw_log::DrawLog,
    /// One command per object in the culler's subtree order (`set_draw_order`): a run of a
    /// predicate's objects that is a run of the order is one multi-draw of these.
    ordered: ordered::OrderedDraws,
    /// Scratch of one ordered draw: its pieces and its scattered objects.
    pieces: Vec<ordered::Piece>,
    scattered: Vec<u32>,
}

impl Renderer {
    /// Uploads `scene` and creates pipelines and a `width`x`height` target.
    pub fn new(ctx: &Arc<GpuContext>, scene: &Scene, width: u32, height: u32) -> Result<Renderer> {
        Renderer::with_spare_objects(ctx, scene, width, height, 0)
    }

    /// [`Renderer::new`] with room for `spare` objects beyond the scene's, added later with
    /// [`Renderer::set_object`] (for objects a host inserts).
    pub fn with_spare_objects(
        ctx: &Arc<GpuContext>,
        scene: &Scene,
        width: u32,
        height: u32,
        spare: usize,
    ) -> Result<Renderer> {
        let target = Target::new(ctx, width, height)?;
        let uploaded = upload::upload_scene_with_spare(ctx, scene, spare)?;
        let mut pipelines = ScenePipelines::for_scene(ctx, scene.has_materials())?;
        if scene.materials.iter().any(|m| m.double_sided) {
            pipelines.add_two_sided(ctx)?;
        }
        let mut oneshot = OneShot::new(ctx)?;
        let mut recorder = Recorder::new(ctx);
        let (descriptors, materials) = scene_descriptors(
            ctx,
            scene,
            &pipelines,
            &uploaded.objects,
            (&mut oneshot, &mut recorder),
        )?;
        let box_index_buffer = Buffer::with_data(
            ctx,
            "box indices",
            &upload::as_bytes(&upload::box_indices(BOX_CHUNK)),
            vk::BufferUsageFlags::INDEX_BUFFER,
        )?;
        Ok(Renderer {
            ctx: ctx.clone(),
            objects: scene
                .objects
                .iter()
                .enumerate()
                .map(|(i, o)| ObjectDraw {
                    first_index: o.first_index,
                    index_count: o.index_count,
                    vertex_offset: o.vertex_offset as i32,
                    bounds: o.bounds,
                    set: object_set(scene, i),
                    mask: object_mask(scene, i),
                    double_sided: scene.object_material(i).is_some_and(|m| m.double_sided),
                })
                .collect(),
            triangles: scene.objects.iter().map(|o| o.triangle_count()).sum(),
            timeline: Timeline::new(ctx)?,
            segments: CommandPool::new(ctx)?,
            segment_values: Vec::new(),
            recording: false,
            pipelines,
            descriptors,
            materials,
            bound_set: 0,
            vertex_buffer: uploaded.vertices,
            index_buffer: uploaded.indices,
            object_buffer: uploaded.objects,
            object_slots: (scene.objects.len() + spare).max(1),
            box_index_buffer,
            box_chunks: vec![box_chunk(ctx)?],
            box_chunk: 0,
            box_used: 0,
            target,
            id_image: None,
            occlusion: QueryPools::with_readback(ctx, vk::QueryType::OCCLUSION, 1024)?,
            timestamps: QueryPools::new(ctx, vk::QueryType::TIMESTAMP, 256)?,
            query_segment: Vec::new(),
            query_read: Vec::new(),
            segment_first_query: 0,
            driver_reads: 0,
            recorder,
            oneshot,
            push: initial_push(scene),
            bound: None,
            corners: Vec::with_capacity(8 * 64),
            stall: Duration::ZERO,
            prepass_counts: CommandCounts::default(),
            visibility_threshold: 0,
            bounds_version: 0,
            predicates: Vec::new(),
            predicates_resolved: 0,
            skip_predicate_barrier: false,
            draw_chunks: Vec::new(),
            draw_chunk: 0,
            draw_used: 0,
            draw_bytes: Vec::new(),
            draw_objects: Vec::new(),
            log: draw_log::DrawLog::default(),
            ordered: ordered::OrderedDraws::default(),
            pieces: Vec::new(),
            scattered: Vec::new(),
        })
    }

    /// Moves object `object`: its model matrix (and normal matrix) from the next frame on. Call
    /// between frames (a frame has completed on the device when `render_frame` returns).
    pub fn set_object_transform(&mut self, object: u32, transform: &glam::Mat4) -> Result<()> {
        if object as usize >= self.objects.len() {
            return Err(Error::Input(format!(
                "object {object} does not exist (renderer has {})",
                self.objects.len()
            )));
        }
        let offset = object as usize * upload::OBJECT_FLOATS * 4;
        let data = upload::object_data(transform, glam::Vec4::ZERO);
        self.object_buffer.write(offset, bytes_of(&data[..32]))
    }

    /// Sets the world-space bounds of `object` (after it moved), for GPU-driven culling, which
    /// tests bounds on the GPU (`hiz`); the CPU traversals take them from the hierarchy.
    pub fn set_object_bounds(&mut self, object: u32, bounds: Aabb) -> Result<()> {
        let n = self.objects.len();
        let o = self.objects.get_mut(object as usize).ok_or_else(|| {
            Error::Input(format!("object {object} does not exist (renderer has {n})"))
        })?;
        o.bounds = bounds;
        self.bounds_version += 1;
        Ok(())
    }

    /// Makes object slot `object` draw the mesh and color of object `template` with
    /// `transform` (for an object a host inserts: use the id the hierarchy's `insert` gave). A
    /// new slot must be the next one; the renderer holds as many as it was created with.
    pub fn set_object(&mut self, object: u32, template: u32, transform: &glam::Mat4) -> Result<()> {
        let (slot, t) = (object as usize, template as usize);
        if t >= self.objects.len() || slot > self.objects.len() || slot >= self.object_slots {
            return Err(Error::Input(format!(
                "cannot make object {object} a copy of {template} ({} objects, room for {})",
                self.objects.len(),
                self.object_slots
            )));
        }
        let stride = upload::OBJECT_FLOATS * 4;
        let mut color = [0u8; 16];
        if let Some(m) = self.object_buffer.mapped() {
            color.copy_from_slice(&m[t * stride + 128..t * stride + 144]);
        }
        let draw = self.objects[t];
        if slot == self.objects.len() {
            self.objects.push(draw);
        } else {
            self.objects[slot] = draw;
        }
        self.ordered.update(object, &draw)?;
        self.object_buffer.write(slot * stride + 128, &color)?;
        self.set_object_transform(object, transform)
    }

    /// The context.
    pub fn context(&self) -> &Arc<GpuContext> {
        &self.ctx
    }

    /// Target size.
    pub fn size(&self) -> (u32, u32) {
        self.target.color.size()
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

    /// Occlusion results of the last frame that had to be read through
    /// `vkGetQueryPoolResults` because the segment's copy of them was missing. Every segment
    /// copies its queries' results into host memory when it ends, so this is 0; a read through
    /// the driver may wait for the whole device (lavapipe does).
    pub fn driver_query_reads(&self) -> u32 {
        self.driver_reads
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
        camera: impl Into<CameraView>,
        frame: u64,
    ) -> Result<FrameResult> {
        let view: CameraView = camera.into();
        let exact = if culler.needs_exact_visibility() {
            Some(self.exact_visible(bvh, view)?)
        } else {
            None
        };
        self.begin_frame(&view)?;
        let start = Instant::now();
        let input = FrameInput {
            bvh,
            view,
            frame,
            exact_visible: exact.as_deref(),
        };
        let cull = culler.cull_frame(&input, self);
        let finished = self.finish();
        let frame_time = start.elapsed();
        let cull: CullStats = cull?;
        finished?;
        let gpu_ms = self.gpu_time_ms()?;
        let mut counts: CommandCounts = self.recorder.take_counts();
        self.read_predicates(&mut counts)?;
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
            check: None,
        })
    }

    /// Reads the color target back as RGBA8 rows (bottom row last).
    pub fn read_color(&mut self) -> Result<Vec<u8>> {
        targets::read_image(
            &self.ctx,
            &mut self.oneshot,
            &mut self.recorder,
            &self.target.color,
        )
    }

    /// Reads the depth target back (one f32 per pixel, row by row).
    pub fn read_depth(&mut self) -> Result<Vec<f32>> {
        let bytes = targets::read_image(
            &self.ctx,
            &mut self.oneshot,
            &mut self.recorder,
            &self.target.depth,
        )?;
        Ok(bytes
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect())
    }

    /// Saves the color target as a PNG.
    pub fn save_png(&mut self, path: &std::path::Path) -> Result<()> {
        let (w, h) = self.size();
        let pixels = self.read_color()?;
        crate::image_io::save_rgba_png(path, w, h, pixels)
    }

    /// Starts a frame: forgets the last frame's segments, queries, timestamps and counts, and
    /// pushes `view`'s matrix.
    pub(crate) fn begin_frame(&mut self, view: &CameraView) -> Result<()> {
        // Every segment of the previous frame has completed: finish() waited for them.
        self.segments.reset(&self.timeline)?;
        self.segment_values.clear();
        self.recording = false;
        self.occlusion.reset();
        self.timestamps.reset();
        self.query_segment.clear();
        self.query_read.clear();
        self.driver_reads = 0;
        self.box_chunk = 0;
        self.box_used = 0;
        self.stall = Duration::ZERO;
        self.recorder.take_counts();
        self.log.begin_frame();
        self.predicates_resolved = 0;
        self.draw_chunk = 0;
        self.draw_used = 0;
        self.ordered.begin_frame();
        let vp = raster_matrix(view);
        self.push[..64].copy_from_slice(bytes_of(&vp.to_cols_array()));
        Ok(())
    }

    /// Index of the segment being recorded or, when none is, of the last one.
    fn current_segment(&self) -> usize {
        self.segments.used().saturating_sub(1)
    }

    /// Starts a new segment unless one is being recorded: a command buffer that resumes
    /// rendering into the target (the frame's first segment clears it).
    fn ensure_recording(&mut self) -> Result<()> {
        if self.recording {
            return Ok(());
        }
        let first = self.segments.used() == 0;
        self.begin_segment()?;
        self.segment_first_query = self.occlusion.used();
        self.write_timestamp()?;
        self.begin_target_rendering(first)?;
        self.recording = true;
        Ok(())
    }

    /// Begins rendering into the target, clearing it when `clear` (a frame's first pass) and
    /// otherwise resuming with LOAD ops, and binds the scene's descriptor set and push block.
    pub(crate) fn begin_target_rendering(&mut self, clear: bool) -> Result<()> {
        let (color, depth) = (&self.target.color, &self.target.depth);
        let (color_load, depth_load) = if clear {
            self.recorder.discard(color, ImageUse::ColorAttachment);
            self.recorder.discard(depth, ImageUse::DepthAttachment);
            (Load::ClearColor(SKY), Load::ClearDepth(1.0))
        } else {
            self.recorder.transition(color, ImageUse::ColorAttachment);
            self.recorder.transition(depth, ImageUse::DepthAttachment);
            (Load::Keep, Load::Keep)
        };
        self.recorder.begin_rendering(
            &[Attachment {
                image: color,
                load: color_load,
                store: true,
            }],
            Some(Attachment {
                image: depth,
                load: depth_load,
                store: true,
            }),
            1,
        )?;
        let layout = &self.pipelines.layout;
        self.recorder
            .bind_graphics_set(layout, self.descriptors.get(0));
        self.bound_set = 0;
        self.recorder.push_constants(layout, &self.push);
        Ok(())
    }

    /// Ends rendering and submits the segment being recorded, if any.
    fn submit_segment(&mut self) -> Result<()> {
        if !self.recording {
            return Ok(());
        }
        self.recorder.end_rendering();
        let first = self.segment_first_query;
        self.recorder
            .copy_query_results(&self.occlusion, first, self.occlusion.used() - first);
        let ts = self.timestamps.allocate()?;
        self.recorder.write_timestamp(&self.timestamps, ts);
        self.recording = false;
        let value = self.timeline.submit(&mut self.recorder)?;
        self.segment_values.push(value);
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
            &self.pipelines.query
        } else {
            &self.pipelines.render
        };
        self.recorder.bind_pipeline(p);
    }

    /// Finds the objects that cover at least one pixel: renders the frustum's objects into an
    /// object-ID image and reads it back. Not part of any frame's time or counts.
    pub fn exact_visible(
        &mut self,
        bvh: &ObjectBvh,
        camera: impl Into<CameraView>,
    ) -> Result<Vec<u32>> {
        let mut pixels = Vec::new();
        let candidates = self.id_pass(bvh, &camera.into(), &mut pixels)?;
        // Keep front-to-back order for the draw.
        Ok(candidates
            .into_iter()
            .filter(|&o| pixels[o as usize] > 0)
            .collect())
    }

    /// The exact ID pass of `camera`: `pixels[o]` becomes the number of pixels object `o` owns
    /// (0 for hidden or culled objects). Not part of any frame's time or counts.
    pub fn object_pixels(
        &mut self,
        bvh: &ObjectBvh,
        camera: impl Into<CameraView>,
        pixels: &mut Vec<u32>,
    ) -> Result<()> {
        self.id_pass(bvh, &camera.into(), pixels).map(|_| ())
    }

    /// Turns the log of drawn objects on or off (`walk --check` needs it; it costs a push per
    /// object draw).
    pub fn log_drawn_objects(&mut self, on: bool) {
        self.log.set_logging(on);
    }

    /// Counts the draws of the objects in `movers` (the scene's moving objects) as the frame's
    /// `mover_draws` too (an empty range counts none).
    pub fn count_mover_draws(&mut self, movers: std::ops::Range<u32>) {
        self.log.set_movers(movers);
    }

    /// The objects whose draws count as mover draws ([`Renderer::count_mover_draws`]).
    pub fn mover_objects(&self) -> std::ops::Range<u32> {
        self.log.movers()
    }

    /// Objects the last frame drew, in draw order (with [`Renderer::log_drawn_objects`] on).
    pub fn drawn_objects(&self) -> &[u32] {
        self.log.drawn()
    }

    /// Compares what the last frame drew (the draw log, see
    /// [`Renderer::log_drawn_objects`]) with `pixels` from [`Renderer::object_pixels`] for the
    /// same camera.
    pub fn check_drawn(&self, pixels: &[u32]) -> Check {
        Renderer::check_objects(self.log.drawn(), pixels)
    }

    /// [`Renderer::check_drawn`] for a list of drawn objects from elsewhere (the GPU-generated
    /// draws of `hiz`, read back).
    pub fn check_objects(drawn_objects: &[u32], pixels: &[u32]) -> Check {
        let mut drawn = vec![false; pixels.len()];
        for &o in drawn_objects {
            if let Some(d) = drawn.get_mut(o as usize) {
                *d = true;
            }
        }
        let mut check = Check::default();
        for (&p, &d) in pixels.iter().zip(&drawn) {
            if p > 0 {
                check.visible_objects += 1;
                if !d {
                    check.missed_objects += 1;
                    check.missed_pixels += u64::from(p);
                }
            }
        }
        check
    }

    /// Renders the frustum's objects into the ID image, counts each object's pixels into
    /// `pixels` and returns the candidates (front to back).
    fn id_pass(
        &mut self,
        bvh: &ObjectBvh,
        view: &CameraView,
        pixels: &mut Vec<u32>,
    ) -> Result<Vec<u32>> {
        let candidates = frustum_candidates(bvh, view);
        let mut push = self.push;
        push[..64].copy_from_slice(bytes_of(&raster_matrix(view).to_cols_array()));
        let pass = self.render_ids(&candidates, &push)?;
        add_prepass(&mut self.prepass_counts, &pass);
        pixels.clear();
        pixels.resize(self.objects.len(), 0);
        let Some(ids) = self.id_image.as_ref() else {
            return Ok(candidates);
        };
        let bytes = targets::read_image(&self.ctx, &mut self.oneshot, &mut self.recorder, ids)?;
        for px in bytes.chunks_exact(4) {
            let id = u32::from_le_bytes([px[0], px[1], px[2], px[3]]);
            if id > 0 && ((id - 1) as usize) < pixels.len() {
                pixels[(id - 1) as usize] += 1;
            }
        }
        Ok(candidates)
    }

    /// Draws `candidates` into the object-ID image (ID = object + 1; 0 is background) and
    /// returns what the pass recorded; the pass and its readback are two submissions.
    fn render_ids(&mut self, candidates: &[u32], push: &[u8]) -> Result<CommandCounts> {
        if self.id_image.is_none() {
            self.id_image = Some(Image::new(
                &self.ctx,
                "object ids",
                ID_FORMAT,
                self.target.color.size(),
                1,
                vk::ImageUsageFlags::COLOR_ATTACHMENT | vk::ImageUsageFlags::TRANSFER_SRC,
            )?);
        }
        let Some(ids) = self.id_image.as_ref() else {
            return Ok(CommandCounts::default());
        };
        let depth = &self.target.depth;
        let (pipelines, set) = (&self.pipelines, self.descriptors.get(0));
        let sets = &self.descriptors;
        let (vb, ib, objects) = (&self.vertex_buffer, &self.index_buffer, &self.objects);
        let mut pass = CommandCounts::default();
        self.oneshot.run(&mut self.recorder, |rec| {
            let before = rec.counts;
            rec.discard(ids, ImageUse::ColorAttachment);
            rec.discard(depth, ImageUse::DepthAttachment);
            rec.begin_rendering(
                &[Attachment {
                    image: ids,
                    load: Load::ClearUint([0; 4]),
                    store: true,
                }],
                Some(Attachment {
                    image: depth,
                    load: Load::ClearDepth(1.0),
                    store: false,
                }),
                1,
            )?;
            rec.bind_pipeline(&pipelines.id);
            rec.bind_graphics_set(&pipelines.layout, set);
            rec.push_constants(&pipelines.layout, push);
            rec.bind_buffers(vb, 0, Some(ib));
            let mut state = MaterialState::new(push);
            for &o in candidates {
                let d = objects[o as usize];
                if d.index_count > 0 {
                    if pipelines.materials {
                        state.bind(rec, pipelines, sets, &d, true);
                    }
                    rec.draw_indexed(d.index_count, 1, d.first_index, d.vertex_offset, o);
                }
            }
            rec.end_rendering();
            pass.pipeline_binds = rec.counts.pipeline_binds - before.pipeline_binds;
            pass.draw_calls = rec.counts.draw_calls - before.draw_calls;
            pass.triangles = rec.counts.triangles - before.triangles;
            Ok(())
        })?;
        pass.submits = 2;
        Ok(pass)
    }
}

/// Descriptor sets of the scene pipelines: set 0 points at the per-object buffer (and, for a
/// scene with materials, the white texture); a scene with materials gets one more per texture.
fn scene_descriptors(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    pipelines: &ScenePipelines,
    objects: &Buffer,
    (oneshot, recorder): (&mut OneShot, &mut Recorder),
) -> Result<(DescriptorSets, Option<upload::SceneMaterials>)> {
    if !pipelines.materials {
        let sets = DescriptorSets::new(
            ctx,
            &[(&pipelines.layout, &[Binding::StorageBuffer(objects)])],
        )?;
        return Ok((sets, None));
    }
    let materials = upload::SceneMaterials::upload(ctx, oneshot, recorder, scene)?;
    let bindings: Vec<[Binding; 2]> = materials
        .set_textures(scene)
        .into_iter()
        .map(|(t, s)| [Binding::StorageBuffer(objects), Binding::Texture(t, s)])
        .collect();
    let sets: Vec<(&crate::gpu::PipelineLayout, &[Binding])> = bindings
        .iter()
        .map(|b| (&pipelines.layout, &b[..]))
        .collect();
    let sets = DescriptorSets::new(ctx, &sets)?;
    Ok((sets, Some(materials)))
}

/// The descriptor set of an object's material texture (0: none).
fn object_set(scene: &Scene, object: usize) -> u32 {
    scene
        .object_material(object)
        .and_then(|m| m.base_color_texture)
        .filter(|&t| (t as usize) < scene.textures.len())
        .map_or(0, |t| t + 1)
}

/// The alpha cutoff of an object's masked material.
fn object_mask(scene: &Scene, object: usize) -> Option<f32> {
    match scene.object_material(object)?.alpha {
        crate::scene::AlphaMode::Mask(cutoff) => Some(cutoff),
        crate::scene::AlphaMode::Opaque => None,
    }
}

/// What a pass over a scene with materials has bound: the pipeline (opaque or masked), the
/// texture set and the alpha cutoff in the push block (`sun_dir.w`).
struct MaterialState {
    push: [u8; PUSH_SIZE as usize],
    set: u32,
}

impl MaterialState {
    /// The state after a pass bound set 0 and pushed `push`.
    fn new(push: &[u8]) -> MaterialState {
        let mut p = [0u8; PUSH_SIZE as usize];
        p.copy_from_slice(&push[..PUSH_SIZE as usize]);
        MaterialState { push: p, set: 0 }
    }

    /// Binds what object `d` needs that is not bound: the (masked, two-sided) render or ID pipeline, its
    /// texture set, its cutoff. Every bind goes through the recorder, which counts it.
    fn bind(
        &mut self,
        rec: &mut Recorder,
        pipelines: &ScenePipelines,
        sets: &DescriptorSets,
        d: &ObjectDraw,
        ids: bool,
    ) {
        rec.bind_pipeline(pipelines.material_pipeline(d.mask.is_some(), d.double_sided, ids));
        if d.set != self.set {
            rec.bind_texture_set(&pipelines.layout, sets.get(d.set as usize));
            self.set = d.set;
        }
        if let Some(cutoff) = d.mask {
            let bytes = cutoff.to_le_bytes();
            if self.push[76..80] != bytes {
                self.push[76..80].copy_from_slice(&bytes);
                rec.push_constants(&pipelines.layout, &self.push);
            }
        }
    }
}

impl Renderer {
    /// For a scene with materials, whether the texture mips were blitted on the device
    /// (`Some(false)`: made on the CPU, the device cannot blit the texture format linearly).
    pub fn texture_mips_blitted(&self) -> Option<bool> {
        self.materials.as_ref().map(|m| m.blitted_mips)
    }

    /// [`MaterialState::bind`] for the forward pass, keeping the renderer's push block and
    /// bound set in step.
    fn bind_material(&mut self, d: &ObjectDraw) {
        let mut state = MaterialState {
            push: self.push,
            set: self.bound_set,
        };
        state.bind(
            &mut self.recorder,
            &self.pipelines,
            &self.descriptors,
            d,
            false,
        );
        self.push = state.push;
        self.bound_set = state.set;
    }
}

/// Objects of the BVH nodes the frustum touches, front to back.
fn frustum_candidates(bvh: &ObjectBvh, view: &CameraView) -> Vec<u32> {
    let frustum = view.frustum();
    let mut candidates = Vec::new();
    bvh.front_to_back(view.order_point(), |id, node| {
        if !frustum.intersects(&node.bounds) {
            return false;
        }
        candidates.extend_from_slice(bvh.objects(id));
        true
    });
    candidates
}

/// The matrix the built-in renderer rasterizes with: its depth test is the standard one (near 0,
/// LESS), so a reverse-Z view is mapped to standard depth (z' = w - z); clip x, y and the
/// frustum are unchanged, so the image is the same up to depth precision.
fn raster_matrix(view: &CameraView) -> glam::Mat4 {
    if !view.depth.reverse_z {
        return view.view_proj;
    }
    let flip = glam::Mat4::from_cols(
        glam::Vec4::X,
        glam::Vec4::Y,
        glam::Vec4::new(0.0, 0.0, -1.0, 0.0),
        glam::Vec4::new(0.0, 0.0, 1.0, 1.0),
    );
    flip * view.view_proj
}

/// Adds an exact-visibility pass's binds, draws, triangles and submits to the running totals.
fn add_prepass(total: &mut CommandCounts, pass: &CommandCounts) {
    total.pipeline_binds += pass.pipeline_binds;
    total.draw_calls += pass.draw_calls;
    total.triangles += pass.triangles;
    total.submits += pass.submits;
}

/// The push block before the first frame: no view yet, the scene's sun direction.
fn initial_push(scene: &Scene) -> [u8; PUSH_SIZE as usize] {
    let sun = scene.sun_dir.normalize_or(glam::Vec3::Y).to_array();
    let mut push = [0u8; PUSH_SIZE as usize];
    push[64..76].copy_from_slice(bytes_of(&sun));
    push
}

/// A host-visible buffer for the corners of [`BOX_CHUNK`] query boxes.
fn box_chunk(ctx: &Arc<GpuContext>) -> Result<Buffer> {
    Buffer::new(
        ctx,
        "box corners",
        BOX_CHUNK as u64 * BOX_BYTES as u64,
        vk::BufferUsageFlags::VERTEX_BUFFER,
        MemoryLocation::CpuToGpu,
    )
}

impl Renderer {
    /// Records draws of `objects` in render state (inside the conditional block on
    /// `predicate` when one is given and open).
    fn record_objects(&mut self, objects: &[u32], predicate: Option<QueryId>) -> Result<()> {
        self.use_pipeline(PipelineKind::Render);
        self.bind_scene_buffers();
        for &o in objects {
            let d = self.object_draw(o)?;
            if d.index_count > 0 {
                if self.pipelines.materials {
                    self.bind_material(&d);
                }
                self.recorder
                    .draw_indexed(d.index_count, 1, d.first_index, d.vertex_offset, o);
                self.log.drew(&[o], predicate);
            }
        }
        Ok(())
    }

    /// How object `o` is drawn (an error names an object the scene does not have).
    fn object_draw(&self, o: u32) -> Result<ObjectDraw> {
        self.objects.get(o as usize).copied().ok_or_else(|| {
            Error::Input(format!(
                "object {o} does not exist (scene has {})",
                self.objects.len()
            ))
        })
    }

    /// Where the predicate of query `query` lies: its buffer (index into the predicate
    /// buffers) and byte offset; an error unless it was resolved in this frame.
    fn predicate_slot(&self, query: QueryId) -> Result<(usize, u64)> {
        if query >= self.predicates_resolved {
            return Err(Error::Input(format!(
                "query {query} is not a resolved predicate of this frame"
            )));
        }
        let chunk = self.occlusion.chunk();
        Ok(((query / chunk) as usize, u64::from(query % chunk) * 4))
    }

    /// Records an occlusion query of `boxes`; with `predicate`, its boxes are drawn inside a
    /// conditional block on that query's predicate (the query itself begins and ends
    /// unconditionally: a predicate does not affect them, so under a false one it counts no
    /// sample).
    fn record_query(&mut self, boxes: &[Aabb], predicate: Option<QueryId>) -> Result<QueryId> {
        let block = match predicate {
            Some(p) => Some((p, self.predicate_slot(p)?)),
            None => None,
        };
        self.ensure_recording()?;
        self.use_pipeline(PipelineKind::Query);
        let id = self.occlusion.allocate()?;
        self.query_segment.push(self.current_segment() as u32);
        self.query_read.push(false);
        self.recorder.begin_occlusion_query(&self.occlusion, id);
        let mut drawn = match block {
            Some((p, (buffer, offset))) => {
                self.recorder
                    .begin_conditional(&self.predicates[buffer], offset, p)
            }
            None => Ok(()),
        };
        let mut rest = boxes;
        while drawn.is_ok() && !rest.is_empty() {
            match self.draw_boxes(rest) {
                Ok(r) => rest = r,
                Err(e) => drawn = Err(e),
            }
        }
        if block.is_some() {
            self.recorder.end_conditional();
        }
        self.recorder.end_query(&self.occlusion, id);
        drawn.map(|()| id)
    }

    /// Tags the last query with what the culler said it is for.
    fn tag_query(&mut self, purpose: QueryPurpose) {
        self.recorder.tag_query(
            purpose == QueryPurpose::Multiquery,
            purpose == QueryPurpose::VisibleLeaf,
        );
    }

    /// Binds the scene's vertex and index buffers unless they are bound.
    fn bind_scene_buffers(&mut self) {
        if self.bound != Some(Bound::Scene) {
            self.recorder
                .bind_buffers(&self.vertex_buffer, 0, Some(&self.index_buffer));
            self.bound = Some(Bound::Scene);
        }
    }

    /// Whether the objects of one predicate are drawn by one indexed indirect multi-draw
    /// (one command for lavapipe to skip on a false predicate instead of one per object): the
    /// device has `multiDrawIndirect` and `drawIndirectFirstInstance`, and the scene has no
    /// materials (whose objects bind their own textures and pipelines).
    fn multi_draws(&self) -> bool {
        let optional = &self.ctx.info.optional;
        optional.multi_draw_indirect
            && optional.draw_indirect_first_instance
            && self.ctx.info.max_draw_indirect_count > 1
            && !self.pipelines.materials
    }

    /// Records `objects` in render state as indexed indirect multi-draws, each command drawing
    /// one object (its index as `first_instance`, as [`Renderer::record_objects`] does), from
    /// this frame's command chunks.
    fn record_objects_indirect(
        &mut self,
        objects: &[u32],
        predicate: Option<QueryId>,
    ) -> Result<()> {
        self.use_pipeline(PipelineKind::Render);
        self.bind_scene_buffers();
        let per_chunk = DRAW_CHUNK.min(self.ctx.info.max_draw_indirect_count);
        let mut rest = objects;
        while !rest.is_empty() {
            if self.draw_used == per_chunk || self.draw_chunks.is_empty() {
                if !self.draw_chunks.is_empty() {
                    self.draw_chunk += 1;
                }
                self.draw_used = 0;
                if self.draw_chunk == self.draw_chunks.len() {
                    self.draw_chunks.push(Buffer::new(
                        &self.ctx,
                        "predicated draws",
                        u64::from(per_chunk) * DRAW_BYTES as u64,
                        vk::BufferUsageFlags::INDIRECT_BUFFER,
                        MemoryLocation::CpuToGpu,
                    )?);
                }
            }
            let room = (per_chunk - self.draw_used) as usize;
            self.draw_bytes.clear();
            self.draw_objects.clear();
            let (mut used, mut triangles) = (0, 0);
            for &o in rest {
                if self.draw_objects.len() == room {
                    break;
                }
                used += 1;
                let d = self.object_draw(o)?;
                if d.index_count == 0 {
                    continue;
                }
                self.draw_bytes
                    .extend_from_slice(&ordered::command_bytes(o, &d));
                self.draw_objects.push(o);
                triangles += u64::from(d.index_count / 3);
            }
            rest = &rest[used..];
            if self.draw_objects.is_empty() {
                continue;
            }
            let offset = self.draw_used as usize * DRAW_BYTES;
            let chunk = &mut self.draw_chunks[self.draw_chunk];
            chunk.write(offset, &self.draw_bytes)?;
            let count = self.draw_objects.len() as u32;
            self.recorder
                .draw_objects_indirect(chunk, offset as u64, count, triangles);
            self.log.drew(&self.draw_objects, predicate);
            self.draw_used += count;
        }
        Ok(())
    }

    /// Records `objects` in render state as indexed indirect multi-draws: each run of them
    /// that is a run of the culler's subtree order (at least [`ordered::MIN_RUN`] long) as one
    /// multi-draw of the ordered commands, the objects between runs as multi-draws written
    /// for this frame ([`Renderer::record_objects_indirect`]), in the order given.
    fn record_objects_ordered(
        &mut self,
        objects: &[u32],
        predicate: Option<QueryId>,
    ) -> Result<()> {
        if self.ordered.buffer().is_none() {
            return self.record_objects_indirect(objects, predicate);
        }
        let max = self.ctx.info.max_draw_indirect_count.max(1) as usize;
        let mut pieces = std::mem::take(&mut self.pieces);
        let mut scattered = std::mem::take(&mut self.scattered);
        self.ordered.pieces(objects, max, &mut pieces);
        scattered.clear();
        let mut result = Ok(());
        for p in &pieces {
            let Some(position) = p.position else {
                scattered.push(objects[p.start]);
                continue;
            };
            if !scattered.is_empty() {
                result = self.record_objects_indirect(&scattered, predicate);
                scattered.clear();
            }
            if result.is_ok() {
                let run = &objects[p.start..p.start + p.len];
                result = self.record_run(run, position, predicate);
            }
            if result.is_err() {
                break;
            }
        }
        if result.is_ok() && !scattered.is_empty() {
            result = self.record_objects_indirect(&scattered, predicate);
        }
        self.pieces = pieces;
        self.scattered = scattered;
        result
    }

    /// One multi-draw of the ordered commands `position..` that draw `run`.
    fn record_run(&mut self, run: &[u32], position: u32, predicate: Option<QueryId>) -> Result<()> {
        self.use_pipeline(PipelineKind::Render);
        self.bind_scene_buffers();
        let mut triangles = 0;
        for &o in run {
            triangles += u64::from(self.object_draw(o)?.index_count / 3);
        }
        if let Some(buffer) = self.ordered.buffer() {
            let offset = u64::from(position) * DRAW_BYTES as u64;
            self.recorder
                .draw_objects_indirect(buffer, offset, run.len() as u32, triangles);
            self.log.drew(run, predicate);
        }
        Ok(())
    }

    /// After the frame: reads the predicates back, so objects drawn under a false predicate
    /// do not count as drawn (`walk --check`) and `counts.predicated_objects_taken` says how
    /// many were; adds the mover draws.
    fn read_predicates(&mut self, counts: &mut CommandCounts) -> Result<()> {
        let chunk = self.occlusion.chunk();
        let buffers = &self.predicates;
        let value = |q: u32| -> Option<u32> {
            let bytes = buffers.get((q / chunk) as usize)?.mapped()?;
            let at = (q % chunk) as usize * 4;
            Some(u32::from_ne_bytes(bytes.get(at..at + 4)?.try_into().ok()?))
        };
        self.log
            .end_frame(counts, |q| value(q).is_some_and(|v| v != 0));
        Ok(())
    }

    /// Leaves out the barrier between the predicate copy and the conditional blocks (for the
    /// test that shows the recorder refuses such a frame).
    #[doc(hidden)]
    pub fn skip_predicate_barrier(&mut self, skip: bool) {
        self.skip_predicate_barrier = skip;
    }
}

impl OcclusionBackend for Renderer {
    fn draw_objects(&mut self, objects: &[u32]) -> coherent_cull::Result<()> {
        if objects.is_empty() {
            return Ok(());
        }
        self.ensure_recording()?;
        Ok(self.record_objects(objects, None)?)
    }

    fn supports_predicates(&self) -> bool {
        self.ctx.info.optional.conditional_rendering
    }

    fn resolve_predicates(&mut self) -> coherent_cull::Result<()> {
        if !self.supports_predicates() {
            return Err(coherent_cull::predicates_unsupported());
        }
        self.ensure_recording()?;
        let (first, used) = (self.predicates_resolved, self.occlusion.used());
        while self.predicates.len() < used.div_ceil(self.occlusion.chunk()) as usize {
            self.predicates.push(Buffer::new(
                &self.ctx,
                "predicates",
                u64::from(self.occlusion.chunk()) * 4,
                vk::BufferUsageFlags::CONDITIONAL_RENDERING_EXT
                    | vk::BufferUsageFlags::TRANSFER_DST,
                MemoryLocation::GpuToCpu,
            )?);
        }
        // A pass break: the copy runs outside rendering, which resumes with LOAD ops.
        self.recorder.end_rendering();
        self.recorder.copy_predicates(
            &self.occlusion,
            first,
            used - first,
            &self.predicates,
            !self.skip_predicate_barrier,
        )?;
        self.begin_target_rendering(false)?;
        self.predicates_resolved = used;
        Ok(())
    }

    fn draw_objects_if(&mut self, query: QueryId, objects: &[u32]) -> coherent_cull::Result<()> {
        let (buffer, offset) = self.predicate_slot(query)?;
        if objects.is_empty() {
            return Ok(());
        }
        self.ensure_recording()?;
        self.recorder
            .begin_conditional(&self.predicates[buffer], offset, query)?;
        let drawn = if self.multi_draws() {
            self.record_objects_ordered(objects, Some(query))
        } else {
            self.record_objects(objects, Some(query))
        };
        self.recorder.end_conditional();
        Ok(drawn?)
    }

    fn set_draw_order(&mut self, order: &[u32]) -> coherent_cull::Result<()> {
        if self.multi_draws() {
            self.ordered.set(&self.ctx, order, &self.objects)?;
        }
        Ok(())
    }

    fn supports_predicated_queries(&self) -> bool {
        self.supports_predicates()
    }

    fn issue_query_if(
        &mut self,
        predicate: QueryId,
        boxes: &[Aabb],
        purpose: QueryPurpose,
    ) -> coherent_cull::Result<QueryId> {
        let id = self.record_query(boxes, Some(predicate))?;
        self.tag_query(purpose);
        Ok(id)
    }

    fn issue_query(&mut self, boxes: &[Aabb]) -> coherent_cull::Result<QueryId> {
        Ok(self.record_query(boxes, None)?)
    }

    fn issue_query_for(
        &mut self,
        boxes: &[Aabb],
        purpose: QueryPurpose,
    ) -> coherent_cull::Result<QueryId> {
        let id = self.record_query(boxes, None)?;
        self.tag_query(purpose);
        Ok(id)
    }

    fn restore_render_state(&mut self) -> coherent_cull::Result<()> {
        if self.recording {
            self.use_pipeline(PipelineKind::Render);
        }
        Ok(())
    }

    fn flush(&mut self) -> coherent_cull::Result<()> {
        Ok(self.submit_segment()?)
    }

    fn query_result(&mut self, query: QueryId) -> coherent_cull::Result<Option<u64>> {
        let seg = *self
            .query_segment
            .get(query as usize)
            .ok_or_else(|| Error::Input(format!("query {query} was not issued this frame")))?
            as usize;
        // Only a completed segment's queries are read: on some drivers (lavapipe) reading a
        // query of a pending submission waits for the whole device, so that read would be a
        // hidden, uncounted stall.
        let Some(&value) = self.segment_values.get(seg) else {
            return Ok(None); // still being recorded
        };
        if !self.timeline.is_complete(value)? {
            return Ok(None);
        }
        // The segment copied its results into host memory; asking the driver is the fallback.
        let r = match self.occlusion.copied(query) {
            Some(v) => Some(v),
            None => {
                self.driver_reads += 1;
                self.occlusion.poll(query)?
            }
        };
        if let Some(v) = r {
            if !self.query_read[query as usize] {
                self.query_read[query as usize] = true;
                self.recorder.note_query_read(v > self.visibility_threshold);
            }
        }
        Ok(r)
    }

    fn wait_query(&mut self, query: QueryId) -> coherent_cull::Result<u64> {
        if let Some(v) = self.query_result(query)? {
            return Ok(v);
        }
        let seg = self.query_segment[query as usize] as usize;
        if seg >= self.segment_values.len() {
            self.submit_segment()?;
        }
        let start = Instant::now();
        self.timeline.wait(self.segment_values[seg])?;
        let value = loop {
            if let Some(v) = self.query_result(query)? {
                break v;
            }
            std::hint::spin_loop();
        };
        self.stall += start.elapsed();
        Ok(value)
    }

    fn finish(&mut self) -> coherent_cull::Result<()> {
        if self.segments.used() == 0 {
            // Nothing was drawn: still clear the target.
            self.ensure_recording()?;
        }
        self.submit_segment()?;
        Ok(self.timeline.wait_all()?)
    }
}

impl Renderer {
    /// Writes as many of `boxes` as fit into the current box chunk (starting a new chunk when
    /// it is full), draws them inside the active query and returns the rest.
    fn draw_boxes<'b>(&mut self, boxes: &'b [Aabb]) -> Result<&'b [Aabb]> {
        if self.box_used == BOX_CHUNK {
            self.box_chunk += 1;
            self.box_used = 0;
            if self.box_chunk == self.box_chunks.len() {
                self.box_chunks.push(box_chunk(&self.ctx)?);
            }
        }
        let n = (BOX_CHUNK - self.box_used).min(boxes.len() as u32);
        self.corners.clear();
        upload::box_corners_into(&boxes[..n as usize], &mut self.corners);
        let chunk = &mut self.box_chunks[self.box_chunk];
        chunk.write(self.box_used as usize * BOX_BYTES, bytes_of(&self.corners))?;
        if self.bound != Some(Bound::Boxes(self.box_chunk)) {
            self.recorder
                .bind_buffers(chunk, 0, Some(&self.box_index_buffer));
            self.bound = Some(Bound::Boxes(self.box_chunk));
        }
        self.recorder
            .draw_indexed(36 * n, 1, 0, (self.box_used * 8) as i32, 0);
        self.box_used += n;
        Ok(&boxes[n as usize..])
    }
}

/// One object as GPU-driven culling uploads it: its world bounds and its indexed draw range.
#[derive(Clone, Copy, Debug)]
pub(crate) struct DrawRange {
    pub bounds: Aabb,
    pub first_index: u32,
    pub index_count: u32,
    pub vertex_offset: i32,
}

/// What a GPU-driven frame (`hiz`) records with: the scene's draw ranges, one command buffer
/// per frame on the renderer's timeline, its recorder, timestamps and target. The frame
/// orchestration (culling dispatches, indirect draws) stays with the caller.
impl Renderer {
    /// Every object's bounds and draw range, by object index.
    pub(crate) fn draw_ranges(&self) -> impl ExactSizeIterator<Item = DrawRange> + '_ {
        self.objects.iter().map(|o| DrawRange {
            bounds: o.bounds,
            first_index: o.first_index,
            index_count: o.index_count,
            vertex_offset: o.vertex_offset,
        })
    }

    /// Bumped whenever an object's bounds change (uploaded bounds are stale when it differs).
    pub(crate) fn bounds_version(&self) -> u64 {
        self.bounds_version
    }

    /// The target's depth image.
    pub(crate) fn depth_target(&self) -> &Image {
        &self.target.depth
    }

    /// Begins the frame's next command buffer (after [`Renderer::begin_frame`]): bound state is
    /// forgotten, nothing is recorded yet.
    pub(crate) fn begin_segment(&mut self) -> Result<()> {
        let cmd = self.segments.begin_next()?;
        self.recorder.set_command_buffer(cmd);
        self.bound = None;
        Ok(())
    }

    /// The recorder of the command buffer being recorded.
    pub(crate) fn recorder_mut(&mut self) -> &mut Recorder {
        &mut self.recorder
    }

    /// The recorder with the target's depth image (a pass that reads the depth just drawn).
    pub(crate) fn recorder_and_depth(&mut self) -> (&mut Recorder, &Image) {
        (&mut self.recorder, &self.target.depth)
    }

    /// Writes the frame's next timestamp after everything recorded so far.
    pub(crate) fn write_timestamp(&mut self) -> Result<()> {
        let ts = self.timestamps.allocate()?;
        self.recorder.write_timestamp(&self.timestamps, ts);
        Ok(())
    }

    /// Timestamp `i` of the frame (in ticks), once its command buffer has completed.
    pub(crate) fn timestamp(&self, i: u32) -> Result<Option<u64>> {
        self.timestamps.poll(i)
    }

    /// Binds the forward pipeline and the scene's vertex and index buffers, for draws whose
    /// commands the GPU wrote (always recorded: the bound state of other passes is not known).
    pub(crate) fn bind_scene_geometry(&mut self) {
        self.recorder.bind_pipeline(&self.pipelines.render);
        self.recorder
            .bind_buffers(&self.vertex_buffer, 0, Some(&self.index_buffer));
    }

    /// Submits the command buffer being recorded on the timeline and waits until everything
    /// submitted has completed.
    pub(crate) fn submit_and_wait(&mut self) -> Result<()> {
        let value = self.timeline.submit(&mut self.recorder)?;
        self.segment_values.push(value);
        self.timeline.wait_all()
    }

    /// Records `f` (given the target's depth image) into a one-shot command buffer, submits
    /// it and waits (outside frames: tests and inspection).
    pub(crate) fn run_one_shot(
        &mut self,
        f: impl FnOnce(&mut Recorder, &Image) -> Result<()>,
    ) -> Result<()> {
        let depth = &self.target.depth;
        self.oneshot.run(&mut self.recorder, |rec| f(rec, depth))
    }

    /// The one-shot submitter with the recorder (reads back outside frames).
    pub(crate) fn one_shot_parts(&mut self) -> (&mut OneShot, &mut Recorder) {
        (&mut self.oneshot, &mut self.recorder)
    }
}

impl Drop for Renderer {
    fn drop(&mut self) {
        // Nothing may be in flight when the fields (pools, sets, buffers) are destroyed.
        let _ = self.ctx.wait_idle();
    }
}
