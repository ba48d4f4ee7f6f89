//! The predicated mode's part tests: the parts of split nodes decided by a depth test on the
//! device instead of one occlusion query each.
//!
//! In the predicated mode a queried node that may turn visible is split into parts, each
//! queried under the node's predicate so that only the parts that show are drawn
//! ([`coherent_cull::OcclusionBackend::issue_query_if`]). On a tiled rasterizer every query is
//! begun and ended in every tile even when a false predicate discards its boxes (lavapipe:
//! about 4 us a query at 1280x720), and a split frame issues hundreds of them (thousands in
//! larger scenes). Here the renderer answers those part queries itself: at the resolve that
//! follows them it ends rendering, copies the node queries' values, and runs one compute
//! dispatch that writes each part's predicate: 1 when its node's query counted a sample and
//! one of its boxes may be visible against the depth drawn so far, else 0. The part's objects
//! are drawn under that predicate, and the culler reads it `k` frames later as the part's
//! result (1 or 0).
//!
//! The depth test reads the depth buffer itself, texel by texel over the box's screen
//! rectangle, and only for parts whose node's query counted a sample: most queried nodes stay
//! hidden, and their parts cost one read of the node's value. A box whose rectangle covers
//! more than [`MOST_PIXELS`] pixels passes unread, which bounds a dispatch's cost. No pyramid
//! is built: on lavapipe the `hiz` pyramid of a frame's depth costs as much as 1,500-2,000
//! part queries.
//!
//! Exact: a box passes when it reaches the near plane, and fails only when every depth texel
//! under its screen rectangle lies nearer than its nearest depth less a margin. The depth is
//! of real geometry of this frame, which later draws only make nearer; and a node whose query
//! counted nothing hides every part. It is coarser than a query (a rectangle at the box's
//! nearest depth instead of the box's faces per pixel), so a part may pass that a query would
//! have failed: more objects drawn, never fewer.

use std::sync::Arc;

use ash::vk;
use coherent_cull::{Aabb, QueryId};
use gpu_allocator::MemoryLocation;

use crate::error::{Error, Result};
use crate::gpu::{
    bytes_of, shaders, Access, Binding, Buffer, ComputePipeline, DescriptorSets, GpuContext, Image,
    ImageUse, PipelineLayout, Recorder, Sampler,
};

/// Part ids carry this bit, so that they never collide with the query set's ids.
pub const PART_BIT: QueryId = 1 << 31;
/// Invocations per workgroup of part_test.comp.
const GROUP: u32 = 64;
/// Push constants of part_test.comp: view_proj, info, screen.
const PUSH: u32 = 96;
/// Most pixels read for one box: a box whose screen rectangle covers more passes unread
/// (256x256: at 1280x720, a part that covers a fifteenth of the image).
pub const MOST_PIXELS: u32 = 256 * 256;
/// Depth margin of the test (as `hiz`).
const DEPTH_MARGIN: f32 = 1e-6;
/// Bytes of one part record and of one box in their buffers.
const PART_BYTES: usize = 16;
const BOX_BYTES: usize = 32;

/// The buffers of the tests and the descriptor set that names them; replaced by larger ones
/// when a frame needs more room.
struct Buffers {
    /// Part records (first box, boxes, node query, unused), host-visible.
    parts: Buffer,
    /// Box corners (min, max as two vec4), host-visible.
    boxes: Buffer,
    /// The frame's query values, 4 bytes per query id (copied on the device).
    node_values: Buffer,
    /// One 32-bit predicate per part, written by the test; host-visible (results, checks).
    predicates: Buffer,
    sets: DescriptorSets,
    /// Room: parts, boxes, queries.
    room: (u32, u32, u32),
}

/// The part tests of one renderer (its target's size and depth image).
pub struct PartTests {
    ctx: Arc<GpuContext>,
    pipeline: ComputePipeline,
    layout: PipelineLayout,
    /// Nearest sampler for the depth texel fetches.
    sampler: Sampler,
    size: (u32, u32),
    buffers: Buffers,
    /// Buffers replaced during a frame, kept until the frame has completed.
    retired: Vec<Buffers>,
    /// This frame's parts: (first box, boxes, node query) and boxes.
    parts: Vec<[u32; 4]>,
    boxes: Vec<[f32; 8]>,
    /// Parts tested by a recorded dispatch (the rest wait for the next one).
    tested: u32,
    /// The command-buffer segment of each dispatched part's dispatch.
    segment: Vec<u32>,
    /// Whether each part's result was read.
    read: Vec<bool>,
    /// Leave out the barrier from the test to conditional rendering (for the test that shows
    /// such predicates are refused), and whether the last test was recorded without it.
    pub skip_barrier: bool,
    unguarded: bool,
}

impl PartTests {
    /// The pipeline and first buffers for a target whose depth image is `depth`.
    /// [`Error::Unsupported`] names what the device lacks (sampled depth, workgroups of 64):
    /// the renderer then queries the parts.
    pub fn new(ctx: &Arc<GpuContext>, depth: &Image) -> Result<PartTests> {
        let i = &ctx.info;
        let mut missing = Vec::new();
        if !i.optional.depth_sampled {
            missing.push("SAMPLED_IMAGE on D32_SFLOAT");
        }
        if i.max_compute_work_group_size[0] < GROUP || i.max_compute_work_group_invocations < GROUP
        {
            missing.push("compute workgroups of 64");
        }
        if !missing.is_empty() {
            return Err(Error::Unsupported {
                feature: format!("depth part test: {}", missing.join(", ")),
            });
        }
        let layout = PipelineLayout::new(
            ctx,
            &[
                vk::DescriptorType::STORAGE_BUFFER,
                vk::DescriptorType::STORAGE_BUFFER,
                vk::DescriptorType::STORAGE_BUFFER,
                vk::DescriptorType::STORAGE_BUFFER,
                vk::DescriptorType::COMBINED_IMAGE_SAMPLER,
            ],
            PUSH,
        )?;
        let pipeline = ComputePipeline::new(ctx, &layout, "part test", shaders::PART_TEST_COMP)?;
        let sampler = Sampler::nearest_clamp(ctx)?;
        let buffers = Buffers::new(ctx, &layout, depth, &sampler, (1024, 2048, 4096))?;
        Ok(PartTests {
            ctx: ctx.clone(),
            pipeline,
            layout,
            sampler,
            size: depth.size(),
            buffers,
            retired: Vec::new(),
            parts: Vec::new(),
            boxes: Vec::new(),
            tested: 0,
            segment: Vec::new(),
            read: Vec::new(),
            skip_barrier: false,
            unguarded: false,
        })
    }

    /// The target size the tests were made for.
    pub fn size(&self) -> (u32, u32) {
        self.size
    }

    /// Starts a frame: every earlier frame has completed (replaced buffers go), no parts.
    pub fn begin_frame(&mut self) {
        self.retired.clear();
        self.parts.clear();
        self.boxes.clear();
        self.tested = 0;
        self.segment.clear();
        self.read.clear();
        self.unguarded = false;
    }

    /// Adds a part under `node_query`'s predicate with `boxes`; returns its id (with
    /// [`PART_BIT`]). Tested at the next [`PartTests::record`].
    pub fn add(&mut self, node_query: QueryId, boxes: &[Aabb]) -> Result<QueryId> {
        if node_query & PART_BIT != 0 {
            return Err(Error::Input(format!(
                "a part's predicate must be a query, not part {}",
                node_query & !PART_BIT
            )));
        }
        let index = self.parts.len() as u32;
        if index >= PART_BIT {
            return Err(Error::Input("too many parts in one frame".into()));
        }
        self.parts
            .push([self.boxes.len() as u32, boxes.len() as u32, node_query, 0]);
        self.boxes.extend(boxes.iter().map(|b| {
            [
                b.min.x, b.min.y, b.min.z, 0.0, b.max.x, b.max.y, b.max.z, 0.0,
            ]
        }));
        Ok(PART_BIT | index)
    }

    /// Whether a part of `boxes` boxes under `node_query` can be added: always before the
    /// frame's first dispatch (the buffers grow), afterwards only within their room.
    pub fn fits(&self, boxes: usize, node_query: QueryId) -> bool {
        // The device's limits on one dispatch and one storage buffer.
        let i = &self.ctx.info;
        let parts = self.parts.len() as u64 + 1;
        let boxes_after = (self.boxes.len() + boxes) as u64;
        let range = u64::from(i.max_storage_buffer_range);
        if parts.div_ceil(u64::from(GROUP)) > u64::from(i.max_compute_work_group_count[0])
            || (parts * PART_BYTES as u64).next_power_of_two() > range
            || (boxes_after * BOX_BYTES as u64).next_power_of_two() > range
        {
            return false;
        }
        if self.tested == 0 {
            return true;
        }
        let (p, b, q) = self.buffers.room;
        self.parts.len() < p as usize && self.boxes.len() + boxes <= b as usize && node_query < q
    }

    /// Whether parts wait for a dispatch.
    pub fn pending(&self) -> bool {
        (self.tested as usize) < self.parts.len()
    }

    /// Whether `part` (an id from [`PartTests::add`]) has its predicate recorded.
    pub fn is_tested(&self, part: QueryId) -> bool {
        (part & !PART_BIT) < self.tested
    }

    /// The predicate buffer and byte offset of a tested `part`, for a conditional block;
    /// refused when the test's barrier to conditional rendering is missing (the validation
    /// layers do not track predicate reads).
    pub fn predicate_at(&self, part: QueryId) -> Result<(vk::Buffer, u64)> {
        if part & PART_BIT == 0 || !self.is_tested(part) {
            return Err(Error::Input(format!(
                "{part:#x} is not a tested part of this frame"
            )));
        }
        if self.unguarded {
            return Err(Error::Input(
                "a conditional block reads part predicates that no barrier made visible after \
                 their test"
                    .into(),
            ));
        }
        Ok((
            self.buffers.predicates.handle,
            u64::from(part & !PART_BIT) * 4,
        ))
    }

    /// The predicate the device wrote for `part` (only meaningful once the frame completed);
    /// `None` for a part that was not tested.
    pub fn predicate(&self, part: QueryId) -> Option<u32> {
        if part & PART_BIT == 0 || !self.is_tested(part) {
            return None;
        }
        let at = (part & !PART_BIT) as usize * 4;
        let bytes = self.buffers.predicates.mapped()?.get(at..at + 4)?;
        Some(u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]))
    }

    /// The segment whose dispatch tested `part`.
    pub fn segment_of(&self, part: QueryId) -> Option<u32> {
        self.segment.get((part & !PART_BIT) as usize).copied()
    }

    /// Marks `part`'s result read.
    pub fn mark_read(&mut self, part: QueryId) {
        if let Some(r) = self.read.get_mut((part & !PART_BIT) as usize) {
            *r = true;
        }
    }

    /// Parts whose result was never read.
    pub fn unread(&self) -> usize {
        self.read.iter().filter(|r| !**r).count()
    }

    /// Parts tested in this frame.
    pub fn tested(&self) -> u32 {
        self.tested
    }

    /// Records the tests of the parts added since the last call, outside rendering, after the
    /// queries they name: the copy of the query values, `depth` made readable by compute, the
    /// dispatch, and the barriers to conditional rendering and the host. Leaves `depth`
    /// sampled by compute (the caller moves it back to an attachment). `segment` is the
    /// segment being recorded.
    pub fn record(
        &mut self,
        rec: &mut Recorder,
        depth: &Image,
        queries: &mut coherent_ash::QuerySet,
        view_proj: &[f32; 16],
        segment: u32,
    ) -> Result<()> {
        let (first, n) = (self.tested, self.parts.len() as u32 - self.tested);
        if n == 0 {
            return Ok(());
        }
        // The values of the queries up to the last one a part names.
        let issued = self.parts.iter().map(|p| p[2] + 1).max().unwrap_or(0);
        self.make_room(
            depth,
            self.parts.len() as u32,
            self.boxes.len() as u32,
            issued,
        )?;
        let b = &mut self.buffers;
        let parts = &self.parts[first as usize..];
        let first_box = parts[0][0] as usize;
        b.parts
            .write(first as usize * PART_BYTES, bytes_of(parts))?;
        b.boxes
            .write(first_box * BOX_BYTES, bytes_of(&self.boxes[first_box..]))?;
        if issued > 0 {
            // SAFETY: outside rendering, after the queries named (the set checks that they were
            // issued); the buffer has room
            // for `issued` values and TRANSFER_DST usage.
            unsafe {
                queries.record_copy_values(
                    rec.command_buffer().0,
                    b.node_values.handle,
                    0,
                    issued,
                )?
            };
        }
        rec.memory_barrier(Access::TransferWrite, Access::ComputeReadWrite);
        rec.transition(depth, ImageUse::SampledByCompute);
        rec.bind_compute_pipeline(&self.pipeline);
        rec.bind_compute_set(&self.layout, b.sets.get(0));
        let (w, h) = self.size;
        let info = [n, first, MOST_PIXELS, 0];
        let screen = [w as f32, h as f32, DEPTH_MARGIN, 0.0];
        let mut push = [0u8; PUSH as usize];
        push[..64].copy_from_slice(bytes_of(view_proj));
        push[64..80].copy_from_slice(bytes_of(&info));
        push[80..96].copy_from_slice(bytes_of(&screen));
        rec.push_constants(&self.layout, &push);
        rec.dispatch("part test", n.div_ceil(GROUP), 1, 1)?;
        if self.skip_barrier {
            self.unguarded = true;
        } else {
            rec.memory_barrier(Access::ComputeReadWrite, Access::ConditionalRead);
        }
        rec.memory_barrier(Access::ComputeReadWrite, Access::HostRead);
        self.tested = self.parts.len() as u32;
        self.segment.resize(self.parts.len(), segment);
        self.read.resize(self.parts.len(), false);
        Ok(())
    }

    /// Makes room for `parts` parts, `boxes` boxes and `queries` query values: buffers too
    /// small are replaced by larger ones (the old ones kept until the frame has completed).
    /// Only before the frame's first dispatch, which names the buffers: later, a part that
    /// does not fit is refused by [`PartTests::fits`] and queried instead.
    fn make_room(&mut self, depth: &Image, parts: u32, boxes: u32, queries: u32) -> Result<()> {
        let (p, b, q) = self.buffers.room;
        if parts <= p && boxes <= b && queries <= q {
            return Ok(());
        }
        if self.tested > 0 {
            return Err(Error::Input(format!(
                "part tests: a second test in one frame needs room for {parts} parts, \
                 {boxes} boxes and {queries} queries (there is room for {p}, {b}, {q})"
            )));
        }
        let grow = |need: u32, have: u32| need.max(have).next_power_of_two();
        let room = (grow(parts, p), grow(boxes, b), grow(queries, q));
        let new = Buffers::new(&self.ctx, &self.layout, depth, &self.sampler, room)?;
        let old = std::mem::replace(&mut self.buffers, new);
        self.retired.push(old);
        Ok(())
    }
}

impl Buffers {
    fn new(
        ctx: &Arc<GpuContext>,
        layout: &PipelineLayout,
        depth: &Image,
        sampler: &Sampler,
        room: (u32, u32, u32),
    ) -> Result<Buffers> {
        let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
        let host = MemoryLocation::CpuToGpu;
        let parts = Buffer::new(
            ctx,
            "part records",
            u64::from(room.0) * PART_BYTES as u64,
            storage,
            host,
        )?;
        let boxes = Buffer::new(
            ctx,
            "part boxes",
            u64::from(room.1) * BOX_BYTES as u64,
            storage,
            host,
        )?;
        let node_values = Buffer::new(
            ctx,
            "part node values",
            u64::from(room.2) * 4,
            storage | vk::BufferUsageFlags::TRANSFER_DST,
            MemoryLocation::GpuOnly,
        )?;
        let predicates = Buffer::new(
            ctx,
            "part predicates",
            u64::from(room.0) * 4,
            storage | vk::BufferUsageFlags::CONDITIONAL_RENDERING_EXT,
            MemoryLocation::GpuToCpu,
        )?;
        let bindings = [
            Binding::StorageBuffer(&parts),
            Binding::StorageBuffer(&boxes),
            Binding::StorageBuffer(&node_values),
            Binding::StorageBuffer(&predicates),
            Binding::Sampled(depth, sampler),
        ];
        let sets = DescriptorSets::new(ctx, &[(layout, &bindings[..])])?;
        Ok(Buffers {
            parts,
            boxes,
            node_values,
            predicates,
            sets,
            room,
        })
    }
}
