//! Frame orchestration: the forward renderer that implements [`OcclusionBackend`]. A frame is a
//! chain of segments (command buffers): when a culler needs query results the current segment is
//! submitted and recording goes on in the next one, which resumes rendering with LOAD ops.

pub mod box_flags;
mod box_oracle;
mod draw_log;
pub mod frame;
pub mod hiz;
mod ordered;
pub mod part_tests;
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
use crate::gpu::targets::{self, Target, COLOR_FORMAT, DEPTH_FORMAT, ID_FORMAT};
use crate::gpu::{
    bytes_of, Access, Attachment, Binding, Buffer, CommandCounts, CommandPool, DescriptorSets,
    GpuContext, Image, ImageUse, Load, OneShot, PipelineKind, Recorder, Timeline,
};
use crate::scene::camera::{Camera, CameraView};
use crate::scene::{Aabb, Scene};
use passes::{ScenePipelines, PUSH_SIZE};

pub use frame::{Check, FrameResult};

/// Boxes per box-vertex buffer of the query set (8 corners each).
const BOX_CHUNK: u32 = 16384;
/// Occlusion queries per query pool of the query set (it grows by pools).
const QUERY_CHUNK: u32 = 1024;
/// Indexed indirect draw commands per command chunk (predicated multi-draws).
const DRAW_CHUNK: u32 = 4096;
/// Bytes of one `VkDrawIndexedIndirectCommand`.
const DRAW_BYTES: usize = 20;
/// Sky color the first segment of a frame clears to.
const SKY: [f32; 4] = [0.62, 0.74, 0.86, 1.0];

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Bound {
    Scene,
    /// The query set's box buffers (and the box pipeline).
    Boxes,
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
    /// The occlusion queries: coherent-ash's query set (pools, box corners, result copies,
    /// predicates), the query side hosts of coherent-ash use too.
    queries: coherent_ash::QuerySet,
    /// coherent-ash's box pipeline, on the scene's pipeline layout (it shares the push block,
    /// whose first 64 bytes are the view-projection).
    box_pipeline: coherent_ash::BoxPipeline,
    /// The frame's view-projection (column-major).
    view_proj: [f32; 16],
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
    /// Bytes of one vertex in `vertex_buffer` (position and normal first).
    vertex_stride: usize,
    index_buffer: Buffer,
    /// Per-object data (the descriptor set points at it); host-visible, rewritten between
    /// frames for objects that move.
    object_buffer: Buffer,
    /// Object slots the per-object buffer holds.
    object_slots: usize,
    target: Target,
    id_image: Option<Image>,
    timestamps: QueryPools,
    /// Diagnostic phase marks (COHERENT_PHASES): timestamp index and name.
    phase_marks: Vec<(u32, &'static str)>,
    phases_on: bool,
    query_segment: Vec<u32>,
    query_read: Vec<bool>,
    recorder: Recorder,
    oneshot: OneShot,
    push: [u8; PUSH_SIZE as usize],
    bound: Option<Bound>,
    stall: Duration,
    /// When the frame's last submission was handed to the queue (the CPU's part of the frame
    /// ends there; `FrameResult::cpu_ms`), and how long the frame had waited by then.
    last_submit: Option<(Instant, Duration)>,
    prepass_counts: CommandCounts,
    /// Pixel count above which a query result means visible (for counting wasted queries).
    pub visibility_threshold: u64,
    /// Whether the culler's view carries the target's pixel grid
    /// ([`CameraView::with_pixel_grid`]: objects that fall between pixel centres are culled
    /// with those outside the frustum). On by default; the renderer draws one sample a pixel.
    pub pixel_grid: bool,
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
    /// Scratch of a draw of order ranges the commands do not follow: its objects.
    range_objects: Vec<u32>,
    /// Scratch of one ordered draw: its pieces and its scattered objects.
    pieces: Vec<ordered::Piece>,
    scattered: Vec<u32>,
    /// The predicated mode's depth part tests ([`part_tests`]), made on first use.
    part_tests: Option<part_tests::PartTests>,
    /// Why the device cannot run the part tests (its parts are then queried).
    part_tests_unsupported: Option<String>,
    /// The box oracle's pass ([`Renderer::box_visible`]), made on first use.
    box_oracle: Option<box_oracle::BoxOracle>,
    /// Box tests answered by flags instead of queries ([`Renderer::set_box_flags`]), made on
    /// first use; whether they were asked for, and whether this frame uses them.
    box_flags: Option<box_flags::BoxFlags>,
    box_flags_on: bool,
    flags_frame: bool,
    /// Why the device cannot use box flags (its tests are then queries).
    box_flags_unsupported: Option<String>,
    /// Leaves out the barrier after the flags' draw (the test that shows it is refused).
    skip_flag_barrier: bool,
    /// Parts of split nodes tested by gated box flags (on by default; see
    /// [`Renderer::set_gated_parts`]).
    gated_parts: bool,
    /// Objects handed over under gated flags before their resolve, drawn after it
    /// ([`Renderer::record_flag_lists`]): each flag's range of `flag_list_objects`.
    flag_lists: Vec<(QueryId, std::ops::Range<usize>)>,
    flag_list_objects: Vec<u32>,
    /// The scene's blended objects ([`Scene::is_blended`]): no culler draws them (they are not
    /// in [`Scene::hierarchy`]); every frame draws those in its view after the culled pass.
    blended: Vec<u32>,
    /// Scratch of a frame's blended draws: (squared distance of the box centre, object).
    blend_order: Vec<(f32, u32)>,
    /// Scratch: the predicate of each of `blend_order` (`None`: drawn without a test).
    blend_predicates: Vec<Option<QueryId>>,
    /// The view of the frame being recorded.
    frame_view: Option<CameraView>,
    /// Whether this frame's blended objects were drawn (once a frame, however often the
    /// culler finishes).
    blended_drawn: bool,
    /// Which blended objects in view a frame tests against the opaque depth (one occlusion
    /// query each, one predicate resolve) and draws under their predicates: those of at least
    /// this many triangles, when they hold at least `.1` together
    /// ([`Renderer::set_blended_tests`]).
    blended_tests: (u32, u64),
    /// This frame's queries of blended objects' boxes, with the object's index in `blended`
    /// (read back after the frame into `blended_seen`).
    blended_queries: Vec<(usize, QueryId)>,
    /// Per object of `blended`: whether its last test found it visible (it is then drawn
    /// without one, and tested again every [`BLENDED_RETEST`] frames).
    blended_seen: Vec<bool>,
    /// Frames begun (staggers the re-tests of visible blended objects).
    frames_begun: u64,
}

/// A blended object its last test found visible is drawn without a test, and tested again in
/// every this many frames (staggered by object), as CHC++ re-tests visible leaves.
pub const BLENDED_RETEST: u64 = 8;

/// Default of [`Renderer::set_blended_tests`]: a blended object is tested when it has at least
/// this many triangles (on lavapipe at 1280x720 a query costs about what drawing 200 triangles
/// of a hidden object does)...
pub const BLENDED_TEST_TRIANGLES: u32 = 256;
/// ... and the tested ones hold at least this many together (the resolve's pass break).
pub const BLENDED_TEST_TOTAL: u64 = 8192;

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
        let blended: Vec<u32> = (0..scene.objects.len())
            .filter(|&i| scene.is_blended(i))
            .map(|i| i as u32)
            .collect();
        if !blended.is_empty() {
            pipelines.add_blended(ctx)?;
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
        let (queries, box_pipeline) = query_side(ctx, &pipelines)?;
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
            queries,
            box_pipeline,
            view_proj: [0.0; 16],
            segments: CommandPool::new(ctx)?,
            segment_values: Vec::new(),
            recording: false,
            pipelines,
            descriptors,
            materials,
            bound_set: 0,
            vertex_buffer: uploaded.vertices,
            vertex_stride: if scene.has_materials() {
                passes::MATERIAL_VERTEX_STRIDE as usize
            } else {
                std::mem::size_of::<crate::scene::Vertex>()
            },
            index_buffer: uploaded.indices,
            object_buffer: uploaded.objects,
            object_slots: (scene.objects.len() + spare).max(1),
            target,
            id_image: None,
            timestamps: QueryPools::new(ctx, vk::QueryType::TIMESTAMP, 256)?,
            phase_marks: Vec::new(),
            phases_on: std::env::var_os("COHERENT_PHASES").is_some(),
            query_segment: Vec::new(),
            query_read: Vec::new(),
            recorder,
            oneshot,
            push: initial_push(scene),
            bound: None,
            stall: Duration::ZERO,
            last_submit: None,
            prepass_counts: CommandCounts::default(),
            visibility_threshold: 0,
            pixel_grid: true,
            bounds_version: 0,
            draw_chunks: Vec::new(),
            draw_chunk: 0,
            draw_used: 0,
            draw_bytes: Vec::new(),
            draw_objects: Vec::new(),
            log: draw_log::DrawLog::default(),
            ordered: ordered::OrderedDraws::default(),
            range_objects: Vec::new(),
            pieces: Vec::new(),
            scattered: Vec::new(),
            part_tests: None,
            part_tests_unsupported: None,
            box_oracle: None,
            box_flags: None,
            box_flags_on: true,
            flags_frame: false,
            box_flags_unsupported: None,
            skip_flag_barrier: false,
            gated_parts: true,
            flag_lists: Vec::new(),
            flag_list_objects: Vec::new(),
            blended,
            blend_order: Vec::new(),
            blend_predicates: Vec::new(),
            frame_view: None,
            blended_drawn: false,
            blended_tests: (BLENDED_TEST_TRIANGLES, BLENDED_TEST_TOTAL),
            blended_queries: Vec::new(),
            blended_seen: Vec::new(),
            frames_begun: 0,
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
        let data = upload::object_data(transform, glam::Vec4::ZERO, false);
        self.object_buffer.write(offset, bytes_of(&data[..32]))
    }

    /// Rewrites the positions and normals of the scene's vertices from `first_vertex` on (a
    /// deformed mesh posed anew, [`Movers::for_each_deformed`]); their other attributes stay.
    /// Call between frames, as [`Renderer::set_object_transform`].
    ///
    /// [`Movers::for_each_deformed`]: crate::scene::movers::Movers::for_each_deformed
    pub fn set_vertices(
        &mut self,
        first_vertex: u32,
        vertices: &[crate::scene::Vertex],
    ) -> Result<()> {
        let stride = self.vertex_stride;
        let start = first_vertex as usize * stride;
        let end = start + vertices.len() * stride;
        let Some(mapped) = self.vertex_buffer.mapped_mut() else {
            return Err(Error::Alloc("the vertex buffer is not host-visible".into()));
        };
        let Some(range) = mapped.get_mut(start..end) else {
            return Err(Error::Input(format!(
                "vertices {first_vertex}..{} are past the scene's {}",
                first_vertex as usize + vertices.len(),
                mapped.len() / stride
            )));
        };
        for (dst, v) in range.chunks_exact_mut(stride).zip(vertices) {
            dst[..24].copy_from_slice(bytemuck::bytes_of(v));
        }
        Ok(())
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
        // The template's color and parameters (the floats after the two matrices).
        let mut color = [0u8; 32];
        if let Some(m) = self.object_buffer.mapped() {
            color.copy_from_slice(&m[t * stride + 128..t * stride + 160]);
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
    /// ([`Renderer::exact_visible`], the oracle's, with the untimed frame that follows it in
    /// [`Renderer::render_frame_given`]) since the last call. They are not in
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
        self.queries.capacity()
    }

    /// A camera with this target's aspect ratio for `pose`, with a far plane that covers `bvh`.
    pub fn camera(&self, pose: crate::scene::CameraPose, bvh: &ObjectBvh) -> Camera {
        let b = bvh.nodes[0].bounds;
        let far = (b.extent().length() * 2.0 + (pose.eye - b.center()).length()).max(10.0);
        let (w, h) = self.size();
        Camera::from_pose(pose, w as f32 / h as f32, far)
    }

    /// Renders one frame with `culler` and reports it. A culler that needs the exact visible
    /// set (the oracle) gets it from an ID pass run just before its frame, and one that needs
    /// the objects whose own box shows (the box oracle) from a box pass; an untimed frame that
    /// draws that set follows the pass, so that the timed frame follows a frame and not the
    /// pass ([`Renderer::render_frame_given`]).
    pub fn render_frame(
        &mut self,
        culler: &mut dyn Culler,
        bvh: &ObjectBvh,
        camera: impl Into<CameraView>,
        frame: u64,
    ) -> Result<FrameResult> {
        self.render_frame_given(culler, bvh, camera, frame, None)
    }

    /// [`Renderer::render_frame`] with the exact visible set of this camera already known
    /// (from [`Renderer::exact_pass`]): a culler that needs it uses `exact` instead of an ID
    /// pass of its own. `walk` runs one exact pass per pose before the pose's first algorithm,
    /// so that the oracle's timed frame does not follow its own ID pass, which slows the frame
    /// after it (on lavapipe by about 2.7 ms on the street at 1280x720). Where the pass runs
    /// here instead (`exact` is `None`, or the culler needs the box pass), an untimed frame
    /// that draws the set it found comes between the pass and the timed frame: the culler is
    /// not called for it.
    pub fn render_frame_given(
        &mut self,
        culler: &mut dyn Culler,
        bvh: &ObjectBvh,
        camera: impl Into<CameraView>,
        frame: u64,
        exact: Option<&[u32]>,
    ) -> Result<FrameResult> {
        let mut view: CameraView = camera.into();
        let extent = self.target.extent;
        view.pixel_grid = self.pixel_grid.then_some(coherent_cull::PixelGrid {
            width: extent.width,
            height: extent.height,
        });
        let owned = if culler.needs_box_visibility() {
            Some(self.box_visible(bvh, view)?)
        } else if culler.needs_exact_visibility() && exact.is_none() {
            Some(self.exact_visible(bvh, view)?)
        } else {
            None
        };
        if let Some(set) = owned.as_deref() {
            self.settle_after_pass(&view, set)?;
        }
        let exact = match owned.as_deref() {
            Some(set) => Some(set),
            None if culler.needs_exact_visibility() => exact,
            None => None,
        };
        self.begin_frame(&view)?;
        self.begin_box_flags(culler.reads_tests_after_frame())?;
        let start = Instant::now();
        let input = FrameInput {
            bvh,
            view,
            frame,
            exact_visible: exact,
        };
        let cull = culler.cull_frame(&input, self);
        let finished = self.finish();
        let frame_time = start.elapsed();
        let cull: CullStats = cull?;
        finished?;
        self.read_blended_tests()?;
        let gpu_ms = self.gpu_time_ms()?;
        let mut counts: CommandCounts = self.recorder.take_counts();
        add_query_counts(&mut counts, &self.queries.counts());
        if let Some(f) = self.frame_flags() {
            let c = f.counts();
            counts.flag_tests += c.tests;
            counts.predicated_queries += c.predicated;
            counts.tested_parts += c.gated;
        }
        self.read_predicates(&mut counts)?;
        let unread = self.query_read.iter().filter(|r| !**r).count()
            + self.part_tests.as_ref().map_or(0, |p| p.unread());
        if unread > 0 {
            return Err(Error::Input(format!(
                "{}: {unread} occlusion queries were issued but never read back",
                culler.name()
            )));
        }
        if !self.flag_lists.is_empty() {
            return Err(Error::Input(format!(
                "{}: objects were drawn under {} tested parts whose resolve never came                  (OcclusionBackend::resolve_predicates after test_part_if)",
                culler.name(),
                self.flag_lists.len()
            )));
        }
        Ok(FrameResult {
            frame_ms: frame_time.as_secs_f64() * 1e3,
            gpu_ms,
            stall_ms: self.stall.as_secs_f64() * 1e3,
            cpu_ms: self.cpu_ms(start, frame_time),
            counts,
            cull,
            check: None,
        })
    }

    /// An untimed frame that draws `objects`, between an untimed pre-pass (the ID pass or
    /// the box pass) and the timed frame that uses what the pass found: on lavapipe a frame
    /// right after the ID pass is slower (about 2.7 ms on the street at 1280x720), which
    /// would be charged to the oracle. Its binds, draws, triangles and submits count as the
    /// pre-pass's ([`Renderer::take_prepass_counts`]); its draw log is dropped by the next
    /// [`Renderer::begin_frame`].
    fn settle_after_pass(&mut self, view: &CameraView, objects: &[u32]) -> Result<()> {
        self.begin_frame(view)?;
        let drawn = OcclusionBackend::draw_objects(self, objects);
        let finished = self.finish();
        let counts = self.recorder.take_counts();
        add_prepass(&mut self.prepass_counts, &counts);
        drawn?;
        Ok(finished?)
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
        // SAFETY: every segment of the previous frame has completed (finish() waited).
        unsafe { self.queries.reset_from_host()? };
        self.timestamps.reset();
        self.phase_marks.clear();
        self.query_segment.clear();
        self.query_read.clear();
        if let Some(parts) = self.part_tests.as_mut() {
            parts.begin_frame(view.pixel_grid.is_some());
        }
        self.stall = Duration::ZERO;
        self.last_submit = None;
        self.recorder.take_counts();
        self.log.begin_frame();
        self.draw_chunk = 0;
        self.draw_used = 0;
        self.ordered.begin_frame();
        self.flag_lists.clear();
        self.flag_list_objects.clear();
        self.frame_view = Some(*view);
        self.blended_drawn = false;
        self.blended_queries.clear();
        self.blended_seen.resize(self.blended.len(), false);
        self.frames_begun += 1;
        // Tests are queries unless the frame's culler takes flags (`begin_box_flags`).
        self.flags_frame = false;
        let vp = raster_matrix(view);
        self.view_proj = vp.to_cols_array();
        self.push[..64].copy_from_slice(bytes_of(&self.view_proj));
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
        // SAFETY: outside rendering, after the segment's queries.
        unsafe { self.queries.record_copy(self.recorder.command_buffer().0) };
        let ts = self.timestamps.allocate()?;
        self.recorder.write_timestamp(&self.timestamps, ts);
        self.recording = false;
        self.submit_recorded()
    }

    /// Submits what the recorder holds as one of this frame's segments, noting when.
    fn submit_recorded(&mut self) -> Result<()> {
        let value = self.timeline.submit(&mut self.recorder)?;
        self.last_submit = Some((Instant::now(), self.stall));
        self.segment_values.push(value);
        Ok(())
    }

    /// The CPU's part of a frame that began at `start` and took `frame_time`: until its last
    /// submission, less the time blocked on query results before it (a wait after the last
    /// submission, for the results read at the end of the frame, is not inside that span).
    pub(crate) fn cpu_ms(&self, start: Instant, frame_time: Duration) -> f64 {
        let (until_submit, waited) = self
            .last_submit
            .map(|(t, waited)| (t.saturating_duration_since(start), waited))
            .unwrap_or((frame_time, self.stall));
        until_submit.saturating_sub(waited).as_secs_f64() * 1e3
    }

    /// Diagnostic: a timestamp named `name` (COHERENT_PHASES set).
    pub(crate) fn phase(&mut self, name: &'static str) -> Result<()> {
        if self.phases_on {
            let ts = self.timestamps.allocate()?;
            self.recorder.write_timestamp(&self.timestamps, ts);
            self.phase_marks.push((ts, name));
        }
        Ok(())
    }

    fn gpu_time_ms(&self) -> Result<f64> {
        let mut total = 0u64;
        let n = self.timestamps.used();
        // The segments' timestamps in pairs (start, end), the phase marks between them left out.
        let marked = |i: u32| self.phase_marks.iter().any(|m| m.0 == i);
        let mut start = None;
        for i in (0..n).filter(|&i| !marked(i)) {
            let t = self.timestamps.poll(i)?;
            match start.take() {
                None => start = Some(t.unwrap_or(0)),
                Some(a) => total += t.unwrap_or(a).saturating_sub(a),
            }
        }
        if self.phases_on && n > 0 {
            let tick = self.ctx.info.timestamp_period_ns as f64 * 1e-6;
            let mut prev = self.timestamps.poll(0)?.unwrap_or(0);
            let mut line = String::from("PHASES");
            for &(ts, name) in &self.phase_marks {
                let t = self.timestamps.poll(ts)?.unwrap_or(prev);
                line += &format!(" {name}={:.3}", t.saturating_sub(prev) as f64 * tick);
                prev = t;
            }
            let end = self.timestamps.poll(n - 1)?.unwrap_or(prev);
            line += &format!(" end={:.3}", end.saturating_sub(prev) as f64 * tick);
            eprintln!("{line}");
        }
        Ok(total as f64 * self.ctx.info.timestamp_period_ns as f64 * 1e-6)
    }

    /// Binds the render pipeline (render state).
    fn use_render_pipeline(&mut self) {
        self.recorder.bind_pipeline(&self.pipelines.render);
    }

    /// Enters query state: the query set binds the box pipeline and its buffers unless they
    /// are bound (the recorder counts the bind).
    fn use_box_pipeline(&mut self) {
        let handle = self.box_pipeline.handle();
        if self.recorder.bound_pipeline() == Some(handle) && self.bound == Some(Bound::Boxes) {
            return;
        }
        let cmd = self.recorder.command_buffer().0;
        // SAFETY: recording inside the target's rendering, which the box pipeline was made
        // for; the set and pipeline live as long as the renderer.
        unsafe { self.queries.bind(cmd, &self.box_pipeline, &self.view_proj) };
        self.recorder.note_bind(handle, PipelineKind::Query);
        self.bound = Some(Bound::Boxes);
    }

    /// Finds the objects that cover at least one pixel: renders the frustum's objects into an
    /// object-ID image and reads it back. Not part of any frame's time or counts.
    pub fn exact_visible(
        &mut self,
        bvh: &ObjectBvh,
        camera: impl Into<CameraView>,
    ) -> Result<Vec<u32>> {
        self.exact_pass(bvh, camera, &mut Vec::new())
    }

    /// The exact ID pass of `camera`, as [`Renderer::object_pixels`] (`pixels[o]` becomes the
    /// number of pixels object `o` owns), returning the visible objects front to back, as
    /// [`Renderer::exact_visible`] does: both from one pass. Not part of any frame's time or
    /// counts.
    pub fn exact_pass(
        &mut self,
        bvh: &ObjectBvh,
        camera: impl Into<CameraView>,
        pixels: &mut Vec<u32>,
    ) -> Result<Vec<u32>> {
        let candidates = self.id_pass(bvh, &camera.into(), pixels)?;
        // Keep front-to-back order for the draw.
        Ok(candidates
            .into_iter()
            .filter(|&o| pixels[o as usize] > 0)
            .collect())
    }

    /// Finds the objects whose own bounding box shows against the exact depth (the box oracle,
    /// `oracle-box`): the ID pass, then the frustum's boxes tested against its depth as query
    /// boxes are. Not part of any frame's time or counts. Needs `fragmentStoresAndAtomics`.
    pub fn box_visible(
        &mut self,
        bvh: &ObjectBvh,
        camera: impl Into<CameraView>,
    ) -> Result<Vec<u32>> {
        let view = camera.into();
        let candidates = frustum_candidates(bvh, &view);
        let n = self.objects.len();
        let mut oracle = match self.box_oracle.take() {
            Some(b) if b.objects() == n => b,
            // Nothing is in flight: every pass that used an older one was waited for.
            _ => box_oracle::BoxOracle::new(&self.ctx, n)?,
        };
        oracle.write_boxes(&candidates, &self.objects)?;
        let visible = self
            .render_ids(&view, &candidates, Some(&oracle))
            .and_then(|()| oracle.passed_objects(&candidates));
        self.box_oracle = Some(oracle);
        visible
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
        Renderer::check_split(self.log.drawn(), self.log.unconditional(), pixels)
    }

    /// [`Renderer::check_drawn`] for a list of drawn objects from elsewhere (the GPU-generated
    /// draws of `hiz`, read back), all drawn unconditionally.
    pub fn check_objects(drawn_objects: &[u32], pixels: &[u32]) -> Check {
        Renderer::check_split(drawn_objects, drawn_objects.len(), pixels)
    }

    /// The check of `drawn_objects`, of which the first `unconditional` were drawn
    /// unconditionally and the rest under true predicates.
    fn check_split(drawn_objects: &[u32], unconditional: usize, pixels: &[u32]) -> Check {
        // 0: not drawn, 1: drawn only under predicates, 2: drawn unconditionally.
        let mut drawn = vec![0u8; pixels.len()];
        for (i, &o) in drawn_objects.iter().enumerate() {
            if let Some(d) = drawn.get_mut(o as usize) {
                *d = (*d).max(if i < unconditional { 2 } else { 1 });
            }
        }
        let mut check = Check::default();
        for (&p, &d) in pixels.iter().zip(&drawn) {
            if p > 0 {
                check.visible_objects += 1;
                if d == 0 {
                    check.missed_objects += 1;
                    check.missed_pixels += u64::from(p);
                }
            } else if d > 0 {
                check.extra_objects += 1;
                if d == 1 {
                    check.extra_predicated_objects += 1;
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
        self.render_ids(view, &candidates, None)?;
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

    /// Draws `candidates` seen from `view` into the object-ID image (ID = object + 1; 0 is
    /// background) and adds what the pass recorded to the pre-pass counts; the pass and its
    /// readback are two submissions. With `boxes`, the box oracle's pass follows the draws in
    /// the same rendering (its boxes written beforehand) and its flags are ready to read when
    /// this returns.
    fn render_ids(
        &mut self,
        view: &CameraView,
        candidates: &[u32],
        boxes: Option<&box_oracle::BoxOracle>,
    ) -> Result<()> {
        let mut push = self.push;
        push[..64].copy_from_slice(bytes_of(&raster_matrix(view).to_cols_array()));
        let push = &push[..];
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
            return Ok(());
        };
        let depth = &self.target.depth;
        let (pipelines, set) = (&self.pipelines, self.descriptors.get(0));
        let sets = &self.descriptors;
        let (vb, ib, objects) = (&self.vertex_buffer, &self.index_buffer, &self.objects);
        let mut pass = CommandCounts::default();
        self.oneshot.run(&mut self.recorder, |rec| {
            let before = rec.counts;
            if let Some(b) = boxes {
                rec.fill_buffer(b.flags(), 0, vk::WHOLE_SIZE, 0);
                rec.memory_barrier(Access::TransferWrite, Access::FragmentWrite);
            }
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
            if let Some(b) = boxes {
                b.record(rec, &push[..64]);
            }
            rec.end_rendering();
            if boxes.is_some() {
                rec.memory_barrier(Access::FragmentWrite, Access::HostRead);
            }
            pass.pipeline_binds = rec.counts.pipeline_binds - before.pipeline_binds;
            pass.draw_calls = rec.counts.draw_calls - before.draw_calls;
            pass.triangles = rec.counts.triangles - before.triangles;
            Ok(())
        })?;
        pass.submits = 2;
        add_prepass(&mut self.prepass_counts, &pass);
        Ok(())
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

/// The query set and box pipeline of a renderer with `pipelines` (the set grows by pools of
/// [`QUERY_CHUNK`] queries and buffers of [`BOX_CHUNK`] boxes, reset from the host).
fn query_side(
    ctx: &Arc<GpuContext>,
    pipelines: &ScenePipelines,
) -> Result<(coherent_ash::QuerySet, coherent_ash::BoxPipeline)> {
    let desc = coherent_ash::BoxPipelineDesc {
        depth_format: DEPTH_FORMAT,
        color_formats: vec![COLOR_FORMAT],
        samples: vk::SampleCountFlags::TYPE_1,
        view_mask: 0,
        depth: crate::culling::DepthConvention::STANDARD,
        // Front faces suffice: the camera is never inside a queried box (the culler draws a
        // node whose box, enlarged by the near-plane corner distance, holds the eye), so every
        // visible point of a box is covered by a front face at most as deep. Halves the fill.
        // Counter-clockwise, as the scene pipelines' front faces (gpu/pipelines.rs).
        cull_back_faces: Some(vk::FrontFace::COUNTER_CLOCKWISE),
        layout: Some(pipelines.layout.handle),
        ..coherent_ash::BoxPipelineDesc::default()
    };
    let sets = coherent_ash::QuerySetDesc {
        queries_per_pool: QUERY_CHUNK,
        max_queries: 1 << 24,
        boxes_per_buffer: BOX_CHUNK,
        max_boxes: 1 << 26,
        predicates: ctx.info.optional.conditional_rendering,
        host_query_reset: true,
    };
    // SAFETY: the context's device was made from its physical device with precise occlusion
    // queries and host query resets enabled (and conditional rendering when the info says
    // so), with dynamic rendering; it outlives the renderer, which drops these first.
    unsafe {
        let pipeline = coherent_ash::BoxPipeline::new(&ctx.device, &desc)?;
        let set =
            coherent_ash::QuerySet::new(&ctx.instance, ctx.physical_device, &ctx.device, sets)?;
        Ok((set, pipeline))
    }
}

/// Adds what the query set recorded in the frame to the recorder's counts: its box draws,
/// queries, predicate resolves, conditional blocks and buffer binds (its pipeline binds were
/// counted when the renderer entered query state).
fn add_query_counts(c: &mut CommandCounts, q: &coherent_ash::QueryCounts) {
    c.draw_calls += q.box_draws;
    c.query_draws += q.box_draws;
    let triangles = 12 * u64::from(q.query_boxes);
    c.triangles += triangles;
    c.query_triangles += triangles;
    c.queries_begun += q.queries;
    c.predicate_resolves += q.resolves;
    c.conditional_blocks += q.conditional_blocks;
    c.predicated_queries += q.predicated_queries;
    c.buffer_binds += q.buffer_binds;
}

impl Renderer {
    /// Records draws of `objects` in render state (inside the conditional block on
    /// `predicate` when one is given and open).
    fn record_objects(&mut self, objects: &[u32], predicate: Option<QueryId>) -> Result<()> {
        self.use_render_pipeline();
        self.bind_scene_buffers();
        for &o in objects {
            let d = self.object_draw(o)?;
            if d.index_count > 0 {
                if self.pipelines.materials {
                    self.bind_material(&d);
                }
                self.recorder
                    .draw_indexed(d.index_count, 1, d.first_index, d.vertex_offset, o);
                self.log.drew(&[o], predicate, u64::from(d.index_count / 3));
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

    /// Records an occlusion query of `boxes` through the query set; with `predicate`, its
    /// boxes are drawn inside a conditional block on that query's predicate (the query itself
    /// begins and ends unconditionally: a predicate does not affect them, so under a false one
    /// it counts no sample).
    fn record_query(&mut self, boxes: &[Aabb], predicate: Option<QueryId>) -> Result<QueryId> {
        self.ensure_recording()?;
        self.use_box_pipeline();
        let cmd = self.recorder.command_buffer().0;
        // SAFETY: recording inside rendering with the set bound and nothing bound since; the
        // set was reset for this frame; it checks the predicate.
        let id = unsafe { self.queries.record_query(cmd, boxes, predicate)? };
        self.query_segment.push(self.current_segment() as u32);
        self.query_read.push(false);
        Ok(id)
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
        self.use_render_pipeline();
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
            self.log.drew(&self.draw_objects, predicate, triangles);
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
                // The run's objects are the order's from `position` on.
                result = self.record_order_range(position, p.len as u32, predicate);
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

    /// Whether the box tests of the predicated mode are answered with flags instead of
    /// occlusion queries ([`box_flags`]: one instanced draw of a resolve's boxes, the flags
    /// the predicates). On by default. They apply to the frames of a culler that reads its
    /// tests after the frame ([`Culler::reads_tests_after_frame`]: the predicated mode; with
    /// `k` frames in flight through `FramesInFlight`, which reads them right after the frame),
    /// where the device can (`fragmentStoresAndAtomics`, conditional
    /// rendering) and the visibility threshold is 0; elsewhere the tests stay queries
    /// ([`Renderer::box_flags_unsupported`] says why a device cannot).
    pub fn set_box_flags(&mut self, on: bool) {
        self.box_flags_on = on;
    }

    /// Why box flags cannot be used here (`None` when they can, or were not tried).
    pub fn box_flags_unsupported(&self) -> Option<&str> {
        self.box_flags_unsupported.as_deref()
    }

    /// Whether, with box flags, the parts of split nodes are tested by box flags gated by
    /// their node's flag (on by default): the parts' boxes go into the resolve's instanced
    /// draw, and its vertex shader draws a part's boxes only where its node's flag is 1, so
    /// no conditional block is needed; the parts that pass have their objects gathered into
    /// one indirect draw. Exact on a query's terms, as the node's test. Off: the depth part
    /// test ([`part_tests`]: the parts' screen rectangles against the depth texels, a compute
    /// dispatch; coarser). Needs the gathering (`drawIndirectCount`), else parts stay depth
    /// part tests.
    pub fn set_gated_parts(&mut self, on: bool) {
        self.gated_parts = on;
    }

    /// Leaves out the barrier between the flags' draw and their readers (for the test that
    /// shows such a frame is refused).
    #[doc(hidden)]
    pub fn skip_flag_barrier(&mut self, skip: bool) {
        self.skip_flag_barrier = skip;
    }

    /// After [`Renderer::begin_frame`]: decides whether this frame's tests are flags (its
    /// culler `reads_after_frame`, [`Culler::reads_tests_after_frame`]), making them on first
    /// use.
    fn begin_box_flags(&mut self, reads_after_frame: bool) -> Result<()> {
        let wanted = self.box_flags_on && reads_after_frame;
        if !wanted || self.visibility_threshold != 0 || !self.supports_predicates() {
            return Ok(());
        }
        if self.box_flags.is_none() && self.box_flags_unsupported.is_none() {
            match box_flags::BoxFlags::new(&self.ctx) {
                Ok(f) => self.box_flags = Some(f),
                Err(Error::Unsupported { feature }) => self.box_flags_unsupported = Some(feature),
                Err(e) => return Err(e),
            }
        }
        if let Some(f) = self.box_flags.as_mut() {
            f.begin_frame()?;
            self.flags_frame = true;
        }
        Ok(())
    }

    /// This frame's flags, when its tests are flags.
    fn frame_flags(&self) -> Option<&box_flags::BoxFlags> {
        self.box_flags.as_ref().filter(|_| self.flags_frame)
    }

    /// This frame's flags.
    fn flags_mut(&mut self) -> Result<&mut box_flags::BoxFlags> {
        self.box_flags
            .as_mut()
            .filter(|_| self.flags_frame)
            .ok_or_else(|| Error::Input("this frame has no box flags".into()))
    }

    /// The predicate of flag `query`: its buffer and byte offset.
    fn flag_predicate(&self, query: QueryId) -> Result<(vk::Buffer, u64)> {
        match self.frame_flags() {
            Some(f) => f.predicate_at(query),
            None => Err(Error::Input(format!(
                "{query:#x} is a box flag, and this frame has none"
            ))),
        }
    }

    /// Draws the pending box flags (inside rendering); whether there were any.
    fn record_box_flags(&mut self) -> Result<bool> {
        let pending = self.box_flags.as_ref().is_some_and(|f| f.pending());
        if !self.flags_frame || !pending {
            return Ok(false);
        }
        let Some(mut flags) = self.box_flags.take() else {
            return Ok(false);
        };
        let matrix = self.view_proj;
        let (queries, cmd) = (&mut self.queries, self.recorder.command_buffer().0);
        let drawn = flags.record(&mut self.recorder, bytes_of(&matrix), |rec, at| {
            match at {
                // SAFETY: inside rendering; the predicate's writer and its barrier came before.
                Some((b, o)) => unsafe { queries.begin_block_at(cmd, b, o)? },
                // SAFETY: the block begun just before is open in this rendering.
                None => unsafe { queries.end_block(cmd) },
            }
            rec.note_conditional(at.map(|_| FLAG_BLOCK));
            Ok(())
        });
        self.box_flags = Some(flags);
        // The flag pipeline bound its own set and layout: rebind the scene's state.
        self.bound = None;
        drawn.map(|()| true)
    }

    /// Refuses a predicate that is not a resolved query (or a tested part) of this frame.
    fn check_predicate(&self, query: QueryId) -> Result<()> {
        if box_flags::BoxFlags::is_flag(query) {
            return self.flag_predicate(query).map(|_| ());
        }
        if query & part_tests::PART_BIT != 0 {
            let tested = self.part_tests.as_ref().is_some_and(|p| p.is_tested(query));
            if !tested {
                return Err(Error::Input(format!(
                    "part {} is not a tested predicate of this frame",
                    query & !part_tests::PART_BIT
                )));
            }
        } else if query >= self.queries.resolved() {
            return Err(Error::Input(format!(
                "query {query} is not a resolved predicate of this frame"
            )));
        }
        Ok(())
    }

    /// Where the predicate of a flag or a tested part lies: its buffer and byte offset (the
    /// value was written and made visible to conditional rendering, else an error); `None`
    /// for a query, whose predicate the query set keeps.
    fn predicate_buffer(&self, query: QueryId) -> Result<Option<(vk::Buffer, u64)>> {
        if box_flags::BoxFlags::is_flag(query) {
            return self.flag_predicate(query).map(Some);
        }
        let part = query & part_tests::PART_BIT != 0;
        match self.part_tests.as_ref().filter(|_| part) {
            Some(parts) => parts.predicate_at(query).map(Some),
            None => Ok(None),
        }
    }

    /// Begins a conditional block on `query` (checked by [`Renderer::check_predicate`]).
    fn begin_predicated(&mut self, query: QueryId) -> Result<()> {
        self.ensure_recording()?;
        let cmd = self.recorder.command_buffer().0;
        match self.predicate_buffer(query)? {
            // SAFETY: recording inside rendering, after what wrote the predicate (the flags'
            // draw and copy, or the part test) and its barrier to conditional rendering, in
            // this command buffer; the set checks that no block is open.
            Some((buffer, offset)) => unsafe { self.queries.begin_block_at(cmd, buffer, offset)? },
            // SAFETY: recording inside rendering, after the resolve in this command buffer;
            // the set checks the predicate, its barrier and that no block is open.
            None => unsafe { self.queries.begin_block(cmd, query)? },
        }
        self.recorder.note_conditional(Some(query));
        Ok(())
    }

    /// Ends the block [`Renderer::begin_predicated`] began.
    fn end_predicated(&mut self) {
        let cmd = self.recorder.command_buffer().0;
        // SAFETY: the block begun by `begin_predicated` is open in this rendering instance.
        unsafe { self.queries.end_block(cmd) };
        self.recorder.note_conditional(None);
    }

    /// Records the objects of `ranges` of `order`, the order of the ordered commands: a
    /// range of at least [`ordered::MIN_RUN`] objects as multi-draws of those commands, the
    /// short ones between them gathered into multi-draws written for this frame (as
    /// [`Renderer::record_objects_ordered`] does with runs).
    fn record_order_ranges(
        &mut self,
        order: &[u32],
        ranges: &[std::ops::Range<u32>],
        predicate: Option<QueryId>,
    ) -> Result<()> {
        let mut scattered = std::mem::take(&mut self.scattered);
        scattered.clear();
        let mut drawn = Ok(());
        for r in ranges {
            if r.len() < ordered::MIN_RUN {
                scattered.extend_from_slice(&order[r.start as usize..r.end as usize]);
                continue;
            }
            if !scattered.is_empty() {
                drawn = self.record_objects_indirect(&scattered, predicate);
                scattered.clear();
            }
            if drawn.is_ok() {
                drawn = self.record_order_run(r.clone(), predicate);
            }
            if drawn.is_err() {
                break;
            }
        }
        if drawn.is_ok() && !scattered.is_empty() {
            drawn = self.record_objects_indirect(&scattered, predicate);
        }
        self.scattered = scattered;
        drawn
    }

    /// The ordered commands of `run` as multi-draws of at most `maxDrawIndirectCount` each.
    fn record_order_run(
        &mut self,
        run: std::ops::Range<u32>,
        predicate: Option<QueryId>,
    ) -> Result<()> {
        let max = self.ctx.info.max_draw_indirect_count.max(1);
        let mut start = run.start;
        while start < run.end {
            let len = (run.end - start).min(max);
            self.record_order_range(start, len, predicate)?;
            start += len;
        }
        Ok(())
    }

    /// One multi-draw of the ordered commands `position..position + len` (at most
    /// `maxDrawIndirectCount`).
    fn record_order_range(
        &mut self,
        position: u32,
        len: u32,
        predicate: Option<QueryId>,
    ) -> Result<()> {
        self.use_render_pipeline();
        self.bind_scene_buffers();
        let triangles = self.ordered.run_triangles(position, len as usize);
        if let Some(buffer) = self.ordered.buffer() {
            let offset = u64::from(position) * DRAW_BYTES as u64;
            self.recorder
                .draw_objects_indirect(buffer, offset, len, triangles);
            let run = &self.ordered.order()[position as usize..(position + len) as usize];
            self.log.drew(run, predicate, triangles);
        }
        Ok(())
    }

    /// After the frame: reads the predicates back, so objects drawn under a false predicate
    /// do not count as drawn (`walk --check`) and `counts.predicated_objects_taken` says how
    /// many were; adds the mover draws.
    fn read_predicates(&mut self, counts: &mut CommandCounts) -> Result<()> {
        let (queries, parts) = (&self.queries, self.part_tests.as_ref());
        // Field by field: the log is borrowed mutably below.
        let flags = self.box_flags.as_ref().filter(|_| self.flags_frame);
        let predicate = |q: QueryId| match (parts, flags) {
            (_, Some(f)) if box_flags::BoxFlags::is_flag(q) => f.predicate(q),
            (Some(p), _) if q & part_tests::PART_BIT != 0 => p.predicate(q),
            _ => queries.predicate(q),
        };
        self.log
            .end_frame(counts, |q| predicate(q).is_some_and(|v| v != 0));
        counts.tested_parts += self.part_tests.as_ref().map_or(0, |p| p.tested());
        Ok(())
    }

    /// Leaves out the barrier between the predicate copy and the conditional blocks (for the
    /// test that shows such a frame is refused).
    #[doc(hidden)]
    pub fn skip_predicate_barrier(&mut self, skip: bool) {
        self.queries.skip_resolve_barrier(skip);
    }

    /// Why the predicated mode's depth part test cannot run on this device (`None` when it can
    /// or was not tried yet); its parts are then queried.
    pub fn part_test_unsupported(&self) -> Option<&str> {
        self.part_tests_unsupported.as_deref()
    }

    /// Leaves out the barrier between the depth part test and the conditional blocks on its
    /// predicates (for the test that shows such a frame is refused).
    #[doc(hidden)]
    pub fn skip_part_barrier(&mut self, skip: bool) -> Result<()> {
        if let Some(p) = self.target_part_tests()? {
            p.skip_barrier = skip;
            return Ok(());
        }
        Err(Error::Unsupported {
            feature: self.part_tests_unsupported.clone().unwrap_or_default(),
        })
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
        self.queries.desc().predicates
    }

    fn resolve_predicates(&mut self) -> coherent_cull::Result<()> {
        if !self.supports_predicates() {
            return Err(coherent_cull::predicates_unsupported());
        }
        self.ensure_recording()?;
        self.phase("draws")?;
        let flagged = self.record_box_flags()?;
        // A pass break: the copy runs outside rendering, which resumes with LOAD ops.
        self.recorder.end_rendering();
        self.phase("flags")?;
        if let Some(f) = self.box_flags.as_mut().filter(|_| flagged) {
            // The flags are copied (into the predicates here, into the part tests' node values
            // below) and, after the frame, read by the host.
            self.recorder
                .memory_barrier(Access::FragmentWrite, Access::TransferRead);
            self.recorder
                .memory_barrier(Access::FragmentWrite, Access::HostRead);
            // The predicates of an earlier resolve of this frame were read (as predicates and
            // as gates) and written before.
            self.recorder
                .memory_barrier(Access::ConditionalRead, Access::TransferWrite);
            self.recorder
                .memory_barrier(Access::VertexRead, Access::TransferWrite);
            self.recorder
                .memory_barrier(Access::TransferWrite, Access::TransferWrite);
            f.record_copy(&mut self.recorder);
            if !self.skip_flag_barrier {
                self.recorder
                    .memory_barrier(Access::TransferWrite, Access::ConditionalRead);
                // Gated tests of later resolves read them in the vertex shader.
                self.recorder
                    .memory_barrier(Access::TransferWrite, Access::VertexRead);
                f.barrier_recorded();
            }
        }
        // SAFETY: outside rendering, after the queries it copies.
        unsafe {
            self.queries
                .record_resolve(self.recorder.command_buffer().0)?
        };
        let mut tested = false;
        let multi_draws = self.multi_draws();
        if let Some(parts) = self.part_tests.as_mut().filter(|p| p.pending()) {
            let segment = self.segments.used().saturating_sub(1) as u32;
            // Field by field: the part tests are borrowed mutably.
            let flags = self.box_flags.as_ref().filter(|_| self.flags_frame);
            parts.record(
                &mut self.recorder,
                &self.target.depth,
                &mut self.queries,
                flags.map(|f| f.flags()),
                &self.view_proj,
                segment,
                self.ordered.buffer_generation().filter(|_| multi_draws),
                self.ctx.info.max_draw_indirect_count,
            )?;
            tested = true;
        }
        self.phase("resolve")?;
        if flagged {
            // Later flags of this frame are written after these copies read the flags.
            self.recorder
                .memory_barrier(Access::TransferRead, Access::FragmentWrite);
        }
        self.begin_target_rendering(false)?;
        if tested {
            self.record_part_draws()?;
        }
        self.phase("partdraws")?;
        self.record_flag_lists()?;
        self.phase("flaglists")?;
        Ok(())
    }

    fn draw_objects_if(&mut self, query: QueryId, objects: &[u32]) -> coherent_cull::Result<()> {
        if self.awaits_part_test(query) {
            return Ok(self.defer_part_draw(query, objects)?);
        }
        if self
            .frame_flags()
            .is_some_and(|f| f.gated_awaits_draw(query))
        {
            return Ok(self.defer_flag_draw(query, objects)?);
        }
        self.check_predicate(query)?;
        if objects.is_empty() {
            return Ok(());
        }
        self.begin_predicated(query)?;
        let drawn = if self.multi_draws() {
            self.record_objects_ordered(objects, Some(query))
        } else {
            self.record_objects(objects, Some(query))
        };
        self.end_predicated();
        Ok(drawn?)
    }

    fn draw_order_ranges_if(
        &mut self,
        query: QueryId,
        order: &[u32],
        ranges: &[std::ops::Range<u32>],
    ) -> coherent_cull::Result<()> {
        let objects = coherent_cull::order_ranges_len(order, ranges)?;
        let held = self.multi_draws() && self.ordered.holds(order);
        let awaits_test = self.awaits_part_test(query);
        if held && awaits_test {
            // A tested part's runs of the ordered commands, drawn after its test.
            let parts = self.part_tests.as_mut().expect("the part awaits its test");
            for r in ranges.iter().filter(|r| !r.is_empty()) {
                parts.defer_run(query, r.clone())?;
            }
            return Ok(());
        }
        if held && self.awaits_resolve(query) {
            // A queried node's runs before its resolve: gathered there with the others whose
            // query counted a sample.
            let parts = self.part_tests.as_mut().expect("gathering checked");
            for r in ranges.iter().filter(|r| !r.is_empty()) {
                parts.defer_node_run(query, r.clone())?;
            }
            return Ok(());
        }
        if !held || awaits_test {
            // Not the order of the commands held: the objects one by one.
            let mut list = std::mem::take(&mut self.range_objects);
            list.clear();
            let drawn = coherent_cull::extend_order_objects(&mut list, order, ranges)
                .and_then(|()| self.draw_objects_if(query, &list));
            self.range_objects = list;
            return drawn;
        }
        self.check_predicate(query)?;
        if objects == 0 {
            return Ok(());
        }
        self.begin_predicated(query)?;
        let drawn = self.record_order_ranges(order, ranges, Some(query));
        self.end_predicated();
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

    fn gathers_predicated_draws(&mut self) -> bool {
        if self.visibility_threshold != 0 || !self.supports_predicates() || !self.multi_draws() {
            return false;
        }
        matches!(self.target_part_tests(), Ok(Some(p)) if p.can_gather())
    }

    fn issue_query_if(
        &mut self,
        predicate: QueryId,
        boxes: &[Aabb],
        purpose: QueryPurpose,
    ) -> coherent_cull::Result<QueryId> {
        if self.flags_frame {
            self.check_predicate(predicate)?;
            let Some(at) = self.predicate_buffer(predicate)? else {
                return Err(Error::Input(format!(
                    "a box flag under query {predicate}: a frame with box flags has no queries"
                ))
                .into());
            };
            let id = self.flags_mut()?.add(Some(at), boxes)?;
            self.tag_query(purpose);
            return Ok(id);
        }
        let id = self.record_query(boxes, Some(predicate))?;
        self.tag_query(purpose);
        Ok(id)
    }

    fn test_part_if(
        &mut self,
        predicate: QueryId,
        boxes: &[Aabb],
    ) -> coherent_cull::Result<Option<QueryId>> {
        Ok(self.add_tested_part(predicate, boxes)?)
    }

    fn issue_query(&mut self, boxes: &[Aabb]) -> coherent_cull::Result<QueryId> {
        if self.flags_frame {
            return Ok(self.flags_mut()?.add(None, boxes)?);
        }
        Ok(self.record_query(boxes, None)?)
    }

    fn issue_query_for(
        &mut self,
        boxes: &[Aabb],
        purpose: QueryPurpose,
    ) -> coherent_cull::Result<QueryId> {
        if self.flags_frame {
            let id = self.flags_mut()?.add(None, boxes)?;
            self.tag_query(purpose);
            return Ok(id);
        }
        let id = self.record_query(boxes, None)?;
        self.tag_query(purpose);
        Ok(id)
    }

    fn restore_render_state(&mut self) -> coherent_cull::Result<()> {
        if self.recording {
            self.use_render_pipeline();
        }
        Ok(())
    }

    fn flush(&mut self) -> coherent_cull::Result<()> {
        if self.flags_frame {
            return Err(flags_read_in_frame().into());
        }
        Ok(self.submit_segment()?)
    }

    fn query_result(&mut self, query: QueryId) -> coherent_cull::Result<Option<u64>> {
        if box_flags::BoxFlags::is_flag(query) {
            let r = self.frame_flags().and_then(|f| f.result(query));
            if let Some(v) = r {
                self.recorder.note_query_read(v > self.visibility_threshold);
            }
            return Ok(r);
        }
        // Only a completed segment's queries are read: on some drivers (lavapipe) reading a
        // query of a pending submission waits for the whole device, so that read would be a
        // hidden, uncounted stall.
        if !self.segment_complete(self.segment_of(query)?)? {
            return Ok(None);
        }
        if query & part_tests::PART_BIT != 0 {
            return Ok(self.part_result(query));
        }
        // The segment copied its results into host memory (never vkGetQueryPoolResults).
        let r = self.queries.copied_result(query).map(u64::from);
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
        if box_flags::BoxFlags::is_flag(query) {
            return Err(flags_read_in_frame().into());
        }
        let seg = self.segment_of(query)?;
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
        let flags_pending = self.box_flags.as_ref().is_some_and(|f| f.pending());
        if self.flags_frame && flags_pending {
            // Tests handed over with no resolve after them: drawn now.
            self.resolve_predicates()?;
        }
        if self.part_tests.as_ref().is_some_and(|p| p.pending()) {
            // Parts (and draws of theirs) handed over with no resolve after them: tested now.
            self.resolve_predicates()?;
        }
        self.order_blended();
        if self.segments.used() == 0 || !self.blend_order.is_empty() {
            // Nothing was drawn (still clear the target), or blended objects are drawn now.
            self.ensure_recording()?;
        }
        let test = self.supports_predicates();
        self.draw_blended_order(test)?;
        self.submit_segment()?;
        self.timeline.wait_all()?;
        if let Some(f) = self.box_flags.as_mut() {
            f.set_complete();
        }
        Ok(())
    }
}

/// What the recorder notes as the open block while flags are drawn under a predicate (no
/// render-state draw happens inside it).
const FLAG_BLOCK: QueryId = box_flags::FLAG_BIT;

/// Why a box flag cannot be read inside its frame.
fn flags_read_in_frame() -> Error {
    Error::Input(
        "box flags are read after their frame (the predicated mode); this culler reads a \
         test inside its frame: use queries (Renderer::set_box_flags(false))"
            .into(),
    )
}

impl Renderer {
    /// A part of a split node under `predicate`, as a depth part test ([`part_tests`]) when it
    /// can be: the visibility threshold is 0 (the test says visible or not, not how many
    /// pixels), the device has conditional rendering, and this frame has room; `None` when
    /// it is to be queried.
    fn add_tested_part(&mut self, predicate: QueryId, boxes: &[Aabb]) -> Result<Option<QueryId>> {
        if box_flags::BoxFlags::is_flag(predicate) && self.gated_parts && self.multi_draws() {
            // A box flag gated by the node's: its objects are gathered at the next resolve
            // with the other runs whose flag is 1.
            self.flag_predicate(predicate)?;
            if self.target_part_tests()?.is_some_and(|p| p.can_gather()) {
                return self.flags_mut()?.add_gated(predicate, boxes).map(Some);
            }
        }
        if box_flags::BoxFlags::is_flag(predicate) {
            // The node's flag, copied into the test's node values at its slot.
            let (_, at) = self.flag_predicate(predicate)?;
            let slot = (at / 4) as QueryId;
            return match self.target_part_tests()? {
                Some(parts) if parts.fits(boxes.len(), slot) => parts.add(slot, boxes).map(Some),
                _ => Ok(None),
            };
        }
        if self.visibility_threshold != 0
            || !self.supports_predicates()
            || predicate & part_tests::PART_BIT != 0
        {
            return Ok(None);
        }
        if predicate >= self.queries.resolved() {
            return Err(Error::Input(format!(
                "query {predicate} is not a resolved predicate of this frame"
            )));
        }
        match self.target_part_tests()? {
            Some(parts) if parts.fits(boxes.len(), predicate) => {
                parts.add(predicate, boxes).map(Some)
            }
            _ => Ok(None),
        }
    }

    /// Whether `query` is a query of this frame not resolved yet whose draws can be gathered
    /// at its resolve ([`OcclusionBackend::gathers_predicated_draws`]).
    fn awaits_resolve(&self, query: QueryId) -> bool {
        if box_flags::BoxFlags::is_flag(query) {
            return self.frame_flags().is_some_and(|f| f.awaits_draw(query))
                && self.part_tests.as_ref().is_some_and(|p| p.can_gather());
        }
        query & part_tests::PART_BIT == 0
            && query >= self.queries.resolved()
            && query < self.queries.issued()
            && self.part_tests.as_ref().is_some_and(|p| p.can_gather())
    }

    /// Whether `query` is a part added in this frame and not tested yet: draws under it wait
    /// for its test ([`Renderer::defer_part_draw`]).
    fn awaits_part_test(&self, query: QueryId) -> bool {
        self.part_tests
            .as_ref()
            .is_some_and(|p| p.awaits_test(query))
    }

    /// Draws the objects handed over under gated flags before their resolve
    /// ([`Renderer::defer_flag_draw`]), each list in a block on its flag, which the resolve
    /// just drew and made visible to conditional rendering.
    fn record_flag_lists(&mut self) -> Result<()> {
        let lists = std::mem::take(&mut self.flag_lists);
        let objects = std::mem::take(&mut self.flag_list_objects);
        let drawn = lists.iter().try_for_each(|(query, range)| {
            self.begin_predicated(*query)?;
            let r = self.record_objects(&objects[range.clone()], Some(*query));
            self.end_predicated();
            r
        });
        // The emptied vectors back, their room kept for the next frame.
        self.flag_lists = lists;
        self.flag_lists.clear();
        self.flag_list_objects = objects;
        self.flag_list_objects.clear();
        drawn
    }

    /// Fails when `objects` names an object the scene does not have.
    fn check_object_ids(&self, objects: &[u32]) -> Result<()> {
        match objects.iter().find(|&&o| o as usize >= self.objects.len()) {
            Some(&o) => Err(Error::Input(format!(
                "draw names object {o} (scene has {})",
                self.objects.len()
            ))),
            None => Ok(()),
        }
    }

    /// Keeps `objects` of a part tested by a gated flag, handed over before the flag's
    /// resolve, to be drawn after it ([`Renderer::record_flag_lists`]).
    fn defer_flag_draw(&mut self, part: QueryId, objects: &[u32]) -> Result<()> {
        self.check_object_ids(objects)?;
        let first = self.flag_list_objects.len();
        self.flag_list_objects.extend_from_slice(objects);
        self.flag_lists
            .push((part, first..self.flag_list_objects.len()));
        Ok(())
    }

    /// Keeps `objects` of a part that waits for its test, to be drawn after it
    /// ([`Renderer::record_part_draws`]).
    fn defer_part_draw(&mut self, part: QueryId, objects: &[u32]) -> Result<()> {
        if objects.is_empty() {
            return Ok(());
        }
        self.check_object_ids(objects)?;
        match self.part_tests.as_mut() {
            Some(parts) => parts.defer(part, objects),
            None => Err(Error::Input(format!(
                "{part:#x} is not a part of this frame"
            ))),
        }
    }

    /// Records the draws handed over for the parts that the last dispatch tested, inside
    /// rendering after it: where the device gathered the passed parts' runs of the ordered
    /// commands, one indirect draw with a count (no conditional block per part); the rest in
    /// a conditional block on each part's predicate.
    fn record_part_draws(&mut self) -> Result<()> {
        let Some(parts) = self.part_tests.as_mut() else {
            return Ok(());
        };
        let d = parts.take_recorded_draws();
        let drawn = if d.is_empty() {
            Ok(())
        } else {
            self.record_deferred(&d)
        };
        if let Some(parts) = self.part_tests.as_mut() {
            parts.restore_deferred(d);
        }
        drawn
    }

    /// [`Renderer::record_part_draws`] of `d`. The log (`walk --check`) takes each part's
    /// objects under its predicate either way.
    fn record_deferred(&mut self, d: &part_tests::Deferred) -> Result<()> {
        if d.gathered {
            self.use_render_pipeline();
            self.bind_scene_buffers();
            let parts = self
                .part_tests
                .as_ref()
                .expect("part tests recorded the draws");
            let (drawn, count) = parts.gathered()?;
            self.recorder
                .draw_indexed_indirect_count(drawn, 0, count, 0, d.commands);
            let (mut triangles, mut parts, mut last) = (0, 0, None);
            for (part, run) in &d.runs {
                parts += u32::from(last != Some(*part));
                last = Some(*part);
                let run_triangles = self.ordered.run_triangles(run.start, run.len());
                triangles += run_triangles;
                let objects = &self.ordered.order()[run.start as usize..run.end as usize];
                self.log.drew(objects, Some(*part), run_triangles);
            }
            self.recorder.count_gathered(parts, d.commands, triangles);
        } else {
            for (part, run) in &d.runs {
                self.begin_predicated(*part)?;
                let drawn = self.record_order_run(run.clone(), Some(*part));
                self.end_predicated();
                drawn?;
            }
        }
        for (part, range) in &d.lists {
            let objects = &d.objects[range.clone()];
            self.begin_predicated(*part)?;
            let drawn = if self.multi_draws() {
                self.record_objects_ordered(objects, Some(*part))
            } else {
                self.record_objects(objects, Some(*part))
            };
            self.end_predicated();
            drawn?;
        }
        Ok(())
    }

    /// The segment that recorded query `query`, or the dispatch that tested part `query`.
    fn segment_of(&self, query: QueryId) -> Result<usize> {
        let seg = match query & part_tests::PART_BIT {
            0 => self
                .query_segment
                .get(query as usize)
                .copied()
                .ok_or_else(|| Error::Input(format!("query {query} was not issued this frame")))?,
            _ => self
                .part_tests
                .as_ref()
                .and_then(|p| p.segment_of(query))
                .ok_or_else(|| Error::Input(format!("part {query:#x} was not tested")))?,
        };
        Ok(seg as usize)
    }

    /// Whether segment `seg` was submitted and has completed on the device.
    fn segment_complete(&self, seg: usize) -> Result<bool> {
        match self.segment_values.get(seg) {
            Some(&value) => self.timeline.is_complete(value),
            None => Ok(false), // still being recorded
        }
    }

    /// The result of a tested part (1 or 0), its segment completed.
    fn part_result(&mut self, part: QueryId) -> Option<u64> {
        let parts = self.part_tests.as_mut()?;
        let r = parts.predicate(part).map(u64::from);
        if r.is_some() {
            parts.mark_read(part);
        }
        r
    }

    /// The part tests for the target, made on first use (again when the target's size
    /// changed); `None` on a device that cannot run them (see
    /// [`Renderer::part_test_unsupported`]).
    fn target_part_tests(&mut self) -> Result<Option<&mut part_tests::PartTests>> {
        let size = self.size();
        if self.part_tests.as_ref().is_none_or(|p| p.size() != size) {
            if self.part_tests_unsupported.is_some() {
                return Ok(None);
            }
            let gather = self.multi_draws() && self.ctx.info.optional.draw_indirect_count;
            let grid = self.frame_view.is_some_and(|v| v.pixel_grid.is_some());
            match part_tests::PartTests::new(&self.ctx, &self.target.depth, gather, grid) {
                Ok(p) => self.part_tests = Some(p),
                Err(Error::Unsupported { feature }) => {
                    self.part_tests_unsupported = Some(feature);
                    return Ok(None);
                }
                Err(e) => return Err(e),
            }
        }
        Ok(self.part_tests.as_mut())
    }
}

/// One object as GPU-driven culling uploads it: its world bounds, its indexed draw range and
/// what its draw binds.
#[derive(Clone, Copy, Debug)]
pub(crate) struct DrawRange {
    pub bounds: Aabb,
    pub first_index: u32,
    pub index_count: u32,
    pub vertex_offset: i32,
    pub class: DrawClass,
}

/// What an object's draw binds in a scene with materials: its texture set, its alpha cutoff
/// (masked) and whether it is two-sided. Objects of one class can share an indirect draw; a
/// scene without materials has one class.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub(crate) struct DrawClass {
    set: u32,
    cutoff_bits: Option<u32>,
    double_sided: bool,
}

/// What a GPU-driven frame (`hiz`) records with: the scene's draw ranges, one command buffer
/// per frame on the renderer's timeline, its recorder, timestamps and target. The frame
/// orchestration (culling dispatches, indirect draws) stays with the caller.
impl Renderer {
    /// Every object's bounds and draw range, by object index. A blended object has an empty
    /// range: GPU-driven culling skips it, and
    /// [`Renderer::record_blended`] draws it after the culled pass.
    pub(crate) fn draw_ranges(&self) -> impl ExactSizeIterator<Item = DrawRange> + '_ {
        self.objects.iter().enumerate().map(|(i, o)| DrawRange {
            bounds: o.bounds,
            first_index: o.first_index,
            index_count: if self.blended.binary_search(&(i as u32)).is_ok() {
                0
            } else {
                o.index_count
            },
            vertex_offset: o.vertex_offset,
            class: DrawClass {
                set: o.set,
                cutoff_bits: o.mask.map(f32::to_bits),
                double_sided: o.double_sided,
            },
        })
    }

    /// Records, inside the target's rendering, the blended objects whose boxes meet the
    /// frame's view frustum, farthest box centre first (ties by id, so every algorithm blends
    /// them in the same order), each blended over what is drawn, without writing depth. They
    /// come after everything the culler drew, so they hide nothing from its queries and
    /// nothing drawn after them; every algorithm draws the same ones (the tests below, or
    /// none: a hidden one fails the depth test and changes no pixel), so every algorithm's
    /// image has the same blended pixels.
    ///
    /// The heavy ones are tested first ([`Renderer::set_blended_tests`]; on a device with
    /// conditional rendering) when their last test found them hidden (or
    /// they have none), and the others every [`BLENDED_RETEST`] frames: each of their boxes
    /// (unless the eye is inside it or the near plane cuts it) gets an occlusion query against
    /// the opaque depth, one resolve turns the results into predicates, and each is drawn
    /// under its own. Exact as the culled pass is: a box that shows no sample hides every
    /// fragment of its object, and an object drawn without a test is drawn.
    ///
    /// [`OcclusionBackend::finish`] does so after every culler's frame. `hiz` calls this
    /// inside the rendering its phase 2 began in a command buffer of its own (the resolve
    /// ends that rendering and begins it again), then [`Renderer::copy_blended_tests`] once
    /// rendering has ended and [`Renderer::read_blended_tests`] once the frame has completed.
    pub(crate) fn record_blended(&mut self) -> Result<()> {
        self.order_blended();
        let own = std::mem::replace(&mut self.recording, true);
        let test = self.supports_predicates();
        let drawn = self.draw_blended_order(test);
        self.recording = own;
        drawn
    }

    /// Records the copy of this frame's query results into host memory (outside rendering),
    /// for a pass that does not end with [`OcclusionBackend::finish`].
    pub(crate) fn copy_blended_tests(&mut self) {
        if !self.blended_queries.is_empty() {
            // SAFETY: outside rendering, after the queries it copies.
            unsafe { self.queries.record_copy(self.recorder.command_buffer().0) };
        }
    }

    /// Adds a completed frame's query counts and what its predicates let draw to `counts`
    /// (for a pass that does not go through [`Renderer::render_frame`]: `hiz`).
    pub(crate) fn add_frame_query_counts(&mut self, counts: &mut CommandCounts) -> Result<()> {
        add_query_counts(counts, &self.queries.counts());
        self.read_predicates(counts)
    }

    /// After the frame has completed: what each blended object's test found decides its next
    /// tests ([`Renderer::record_blended`]); the queries count as read.
    pub(crate) fn read_blended_tests(&mut self) -> Result<()> {
        for k in 0..self.blended_queries.len() {
            let (i, q) = self.blended_queries[k];
            let samples = self.query_result(q)?.unwrap_or(1);
            self.blended_seen[i] = samples > 0;
        }
        // Cleared, not dropped: its room serves the next frame.
        self.blended_queries.clear();
        Ok(())
    }

    /// Which blended objects in a frame's view are tested before they are drawn: those of at
    /// least `triangles` triangles, when they hold at least `total` together (defaults
    /// [`BLENDED_TEST_TRIANGLES`] and [`BLENDED_TEST_TOTAL`]; `(0, 0)`: every one, `u64::MAX`
    /// total: none). The others are drawn without a test: a light object costs less to draw
    /// than its query, and a few, less than the resolve's pass break.
    pub fn set_blended_tests(&mut self, triangles: u32, total: u64) {
        self.blended_tests = (triangles, total);
    }

    /// Fills `blend_order` with the blended objects in the frame's view, back to front.
    fn order_blended(&mut self) {
        self.blend_order.clear();
        let Some(view) = self.frame_view.filter(|_| !self.blended.is_empty()) else {
            return;
        };
        if std::mem::replace(&mut self.blended_drawn, true) {
            return;
        }
        let frustum = view.frustum();
        let eye = view.order_point();
        for &o in &self.blended {
            let d = &self.objects[o as usize];
            if d.index_count > 0 && frustum.intersects(&d.bounds) {
                self.blend_order
                    .push((d.bounds.center().distance_squared(eye), o));
            }
        }
        self.blend_order
            .sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    }

    /// Draws `blend_order` (see [`Renderer::record_blended`]), each under the predicate of a
    /// query of its box when `test` (and the object is due a test).
    fn draw_blended_order(&mut self, test: bool) -> Result<()> {
        // Scratch kept by the renderer: nothing allocates once they have grown.
        let order = std::mem::take(&mut self.blend_order);
        let mut predicates = std::mem::take(&mut self.blend_predicates);
        predicates.clear();
        let drawn = match self.frame_view.filter(|_| test) {
            Some(view) => self.test_blended(&order, &view, &mut predicates),
            None => Ok(()),
        }
        .and_then(|()| self.draw_blended(&order, &predicates));
        self.blend_order = order;
        self.blend_predicates = predicates;
        drawn
    }

    /// Queries the boxes of the objects of `order` that are due a test (heavy enough, last
    /// found hidden or due a re-test, the eye outside), when they hold enough triangles
    /// together, and resolves them: `predicates` gets each object's query, `None` for one
    /// drawn without a test.
    fn test_blended(
        &mut self,
        order: &[(f32, u32)],
        view: &CameraView,
        predicates: &mut Vec<Option<QueryId>>,
    ) -> Result<()> {
        let view = coherent_cull::View::new(view);
        let (heavy, total) = self.blended_tests;
        let frame = self.frames_begun;
        // Object `o`'s index in `blended`, when it is tested this frame.
        let due = |r: &Renderer, o: u32| {
            let d = &r.objects[o as usize];
            let i = r.blended.binary_search(&o).ok()?;
            let again = !r.blended_seen[i] || (frame + i as u64).is_multiple_of(BLENDED_RETEST);
            (again && d.index_count / 3 >= heavy && !view.eye_inside(&d.bounds)).then_some(i)
        };
        let sum: u64 = order
            .iter()
            .filter(|&&(_, o)| due(self, o).is_some())
            .map(|&(_, o)| u64::from(self.objects[o as usize].index_count / 3))
            .sum();
        if sum < total || total == u64::MAX {
            return Ok(());
        }
        for &(_, o) in order {
            let q = match due(self, o) {
                Some(i) => {
                    let q = self.record_query(&[self.objects[o as usize].bounds], None)?;
                    self.blended_queries.push((i, q));
                    Some(q)
                }
                None => None,
            };
            predicates.push(q);
        }
        if !self.blended_queries.is_empty() {
            OcclusionBackend::resolve_predicates(self)?;
        }
        Ok(())
    }

    /// Draws the objects of `order`, blended, each in a conditional block on its entry of
    /// `predicates` when it has one.
    fn draw_blended(&mut self, order: &[(f32, u32)], predicates: &[Option<QueryId>]) -> Result<()> {
        if !order.is_empty() {
            self.bind_scene_buffers();
        }
        for (k, &(_, o)) in order.iter().enumerate() {
            let d = self.objects[o as usize];
            let predicate = predicates.get(k).copied().flatten();
            self.recorder
                .bind_pipeline(self.pipelines.blended_pipeline(d.double_sided));
            if self.pipelines.materials && d.set != self.bound_set {
                self.recorder
                    .bind_texture_set(&self.pipelines.layout, self.descriptors.get(d.set as usize));
                self.bound_set = d.set;
            }
            if let Some(q) = predicate {
                self.begin_predicated(q)?;
            }
            self.recorder
                .draw_indexed(d.index_count, 1, d.first_index, d.vertex_offset, o);
            self.log.drew(&[o], predicate, u64::from(d.index_count / 3));
            if predicate.is_some() {
                self.end_predicated();
            }
        }
        Ok(())
    }

    /// Binds what the draws of `object`'s [`DrawClass`] need, after
    /// [`Renderer::bind_scene_geometry`]: in a scene with materials its (masked, two-sided)
    /// pipeline, texture set and cutoff; nothing in a scene without.
    pub(crate) fn bind_draw_class_of(&mut self, object: u32) -> Result<()> {
        if self.pipelines.materials {
            let d = self.object_draw(object)?;
            self.bind_material(&d);
        }
        Ok(())
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
        self.submit_recorded()?;
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

#[cfg(test)]
mod tests {
    use super::{Check, Renderer};

    #[test]
    fn the_check_counts_missed_and_extra_objects_once_each() {
        // Objects 0..5 own 3, 0, 7, 0 and 1 pixels; 1, 2 and 3 were drawn (2 twice), and an
        // id past the scene's objects is ignored.
        let pixels = [3, 0, 7, 0, 1];
        let check = Renderer::check_objects(&[2, 1, 2, 3, 99], &pixels);
        assert_eq!(
            check,
            Check {
                visible_objects: 3,
                missed_objects: 2,
                missed_pixels: 4,
                extra_objects: 2,
                extra_predicated_objects: 0,
            }
        );
        assert_eq!(Renderer::check_objects(&[], &[]), Check::default());
    }

    #[test]
    fn the_check_tells_extra_objects_drawn_only_under_predicates() {
        // Objects 0..6 own 0, 5, 0, 0, 2 and 0 pixels. Drawn unconditionally: 0 and 1; under
        // true predicates: 0 again (drawn unconditionally too), 2, 3, 4 and 3 again.
        let pixels = [0, 5, 0, 0, 2, 0];
        let check = Renderer::check_split(&[0, 1, 0, 2, 3, 4, 3], 2, &pixels);
        assert_eq!(
            check,
            Check {
                visible_objects: 2,
                missed_objects: 0,
                missed_pixels: 0,
                extra_objects: 3,
                extra_predicated_objects: 2,
            }
        );
        // Nothing under predicates: none of the extra objects counts there.
        let all = Renderer::check_split(&[0, 2, 3], 3, &pixels);
        assert_eq!((all.extra_objects, all.extra_predicated_objects), (3, 0));
        assert_eq!(all.missed_objects, 2);
    }
}
