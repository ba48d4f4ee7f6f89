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
//! The culler hands a tested part's objects over before the test
//! ([`coherent_cull::OcclusionBackend::test_part_if`]), as runs of the renderer's ordered draw
//! commands. Where the device has `drawIndirectCount` (and the multi-draws the ordered
//! commands need), a second dispatch after the test copies the commands of the runs whose part
//! passed, in the order they were handed over, into one list, and the renderer draws it with
//! one `vkCmdDrawIndexedIndirectCount`: no conditional block and no draw command per part (on
//! lavapipe each costs a little even when its predicate is false; at the city's x16 scale a
//! frame has about 3,600 parts). Elsewhere each part's objects are drawn in a conditional
//! block on its predicate.
//!
//! The same gathering serves frames with one predicate level (the GPU policy, which splits
//! no node): the culler hands each queried node's objects over before the frame's resolve
//! ([`coherent_cull::OcclusionBackend::gathers_predicated_draws`]), the resolve copies the
//! queries' values, and the dispatch copies the runs of the nodes whose query counted a
//! sample, with no part test. On an NVIDIA H200 that took the street's predicated frame from
//! 530 draw commands to 349.
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
    bytes_of, shaders, word_at, Access, Binding, Buffer, ComputePipeline, DescriptorSets,
    GpuContext, Image, ImageUse, PipelineLayout, Recorder, Sampler,
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
/// Bytes of one draw group (part or query, first command, commands, source) and of one
/// indexed indirect draw command.
const GROUP_BYTES: usize = 16;
const COMMAND_BYTES: usize = 20;
/// Push constants of part_draws.comp: first group, groups, unused x2.
const DRAWS_PUSH: u32 = 16;

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
    /// Draw groups (part or query, first command, commands, source), host-visible.
    groups: Buffer,
    /// The commands of the groups whose part passed, gathered on the device (indirect).
    drawn: Buffer,
    /// How many commands `drawn` holds (the indirect draw's count).
    count: Buffer,
    /// The test's descriptor set.
    sets: DescriptorSets,
    /// New since the gathering's set was made (which names them).
    fresh: bool,
    /// Room: parts, boxes, queries, groups, commands.
    room: Room,
}

/// Room of the buffers: parts, boxes, query values, draw groups, draw commands.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
struct Room {
    parts: u32,
    boxes: u32,
    queries: u32,
    groups: u32,
    commands: u32,
}

impl Room {
    fn holds(&self, need: &Room) -> bool {
        need.parts <= self.parts
            && need.boxes <= self.boxes
            && need.queries <= self.queries
            && need.groups <= self.groups
            && need.commands <= self.commands
    }
}

/// The draws of parts handed over before their test, drawn after it (see
/// [`PartTests::defer_run`] and [`PartTests::defer`]).
#[derive(Default)]
pub struct Deferred {
    /// Runs of the renderer's ordered draw commands: the part's id and the commands'
    /// positions.
    pub runs: Vec<(QueryId, std::ops::Range<u32>)>,
    /// Lists of objects: the part's id and the range of `objects` (always drawn in a
    /// conditional block).
    pub lists: Vec<(QueryId, std::ops::Range<usize>)>,
    pub objects: Vec<u32>,
    /// Whether the device gathered the commands of the runs whose part passed into the list
    /// [`PartTests::gathered`] names (else each run is drawn in a conditional block).
    pub gathered: bool,
    /// Commands in the runs (the gathered list's most).
    pub commands: u32,
}

impl Deferred {
    fn clear(&mut self) {
        self.runs.clear();
        self.lists.clear();
        self.objects.clear();
        self.gathered = false;
        self.commands = 0;
    }

    /// Whether there is nothing to draw.
    pub fn is_empty(&self) -> bool {
        self.runs.is_empty() && self.lists.is_empty()
    }
}

/// The part tests of one renderer (its target's size and depth image).
pub struct PartTests {
    ctx: Arc<GpuContext>,
    pipeline: ComputePipeline,
    layout: PipelineLayout,
    /// The gathering of the passed parts' draws (part_draws.comp), when the renderer draws
    /// them by one indirect draw with a count.
    gather: Option<(ComputePipeline, PipelineLayout)>,
    /// The gathering's descriptor set, made for the renderer's ordered commands it names
    /// (their buffer's generation) and these buffers.
    gather_set: Option<(u64, DescriptorSets)>,
    /// The groups' words as written (kept so that steady frames do not allocate).
    group_words: Vec<u32>,
    /// Nearest sampler for the depth texel fetches.
    sampler: Sampler,
    size: (u32, u32),
    buffers: Buffers,
    /// Buffers and gathering sets replaced during a frame, kept until the frame has
    /// completed.
    retired: Vec<Buffers>,
    retired_sets: Vec<DescriptorSets>,
    /// This frame's parts: (first box, boxes, node query) and boxes.
    parts: Vec<[u32; 4]>,
    boxes: Vec<[f32; 8]>,
    /// Draws of parts not tested yet, and those of the last dispatch, to be recorded.
    deferred: Deferred,
    /// Parts tested by a recorded dispatch (the rest wait for the next one).
    tested: u32,
    /// Whether draws under queried nodes wait for the frame's first dispatch
    /// ([`PartTests::defer_node_run`]).
    node_runs: bool,
    /// Whether this frame recorded a dispatch (its buffers and gathered list are in use).
    dispatched: bool,
    /// The command-buffer segment of each dispatched part's dispatch.
    segment: Vec<u32>,
    /// Whether each part's result was read.
    read: Vec<bool>,
    /// Leave out the barrier from the test to conditional rendering (for the test that shows
    /// such predicates are refused), and whether the last test was recorded without it.
    pub skip_barrier: bool,
    unguarded: bool,
    /// Whether a box that holds no pixel centre is decided hidden without reading depth: the
    /// frame's view has a pixel grid ([`PartTests::begin_frame`]).
    pixel_grid: bool,
}

impl PartTests {
    /// The pipeline and first buffers for a target whose depth image is `depth`.
    /// [`Error::Unsupported`] names what the device lacks (sampled depth, workgroups of 64):
    /// the renderer then queries the parts.
    /// With `gather`, the draws of the parts that pass are gathered on the device into one
    /// indirect draw with a count (the renderer checked `drawIndirectCount`, multi-draws and
    /// `drawIndirectFirstInstance`). `pixel_grid`: the current frame's view has one (as
    /// [`PartTests::begin_frame`] says for each later frame).
    pub fn new(
        ctx: &Arc<GpuContext>,
        depth: &Image,
        gather: bool,
        pixel_grid: bool,
    ) -> Result<PartTests> {
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
        let gather = match gather {
            true => {
                let storage = vk::DescriptorType::STORAGE_BUFFER;
                let layout = PipelineLayout::new(ctx, &[storage; 6], DRAWS_PUSH)?;
                let pipeline =
                    ComputePipeline::new(ctx, &layout, "part draws", shaders::PART_DRAWS_COMP)?;
                Some((pipeline, layout))
            }
            false => None,
        };
        let sampler = Sampler::nearest_clamp(ctx)?;
        let room = Room {
            parts: 1024,
            boxes: 2048,
            queries: 4096,
            groups: 1024,
            commands: 4096,
        };
        let buffers = Buffers::new(ctx, &layout, gather.as_ref(), depth, &sampler, room)?;
        Ok(PartTests {
            ctx: ctx.clone(),
            pipeline,
            layout,
            gather,
            gather_set: None,
            group_words: Vec::new(),
            sampler,
            pixel_grid,
            size: depth.size(),
            buffers,
            retired: Vec::new(),
            retired_sets: Vec::new(),
            parts: Vec::new(),
            boxes: Vec::new(),
            deferred: Deferred::default(),
            tested: 0,
            node_runs: false,
            dispatched: false,
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

    /// Starts a frame: every earlier frame has completed (replaced buffers go), no parts;
    /// `pixel_grid`: the frame's view has one (boxes between pixel centres are hidden).
    pub fn begin_frame(&mut self, pixel_grid: bool) {
        self.pixel_grid = pixel_grid;
        self.retired.clear();
        self.retired_sets.clear();
        self.parts.clear();
        self.boxes.clear();
        self.deferred.clear();
        self.tested = 0;
        self.node_runs = false;
        self.dispatched = false;
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
        if !self.dispatched {
            return true;
        }
        let room = self.buffers.room;
        self.parts.len() < room.parts as usize
            && self.boxes.len() + boxes <= room.boxes as usize
            && node_query < room.queries
    }

    /// Whether `part` was added and waits for its test.
    pub fn awaits_test(&self, part: QueryId) -> bool {
        let i = part & !PART_BIT;
        part & PART_BIT != 0 && i >= self.tested && (i as usize) < self.parts.len()
    }

    /// Hands over the objects of `part` (added, not tested yet) whose commands lie at
    /// `positions` of the renderer's ordered draw commands, to be drawn after its test:
    /// gathered with the other passed parts' runs into one indirect draw where the device
    /// can, else in a conditional block on the part's predicate.
    pub fn defer_run(&mut self, part: QueryId, positions: std::ops::Range<u32>) -> Result<()> {
        self.check_awaits(part)?;
        self.deferred.commands += positions.len() as u32;
        self.deferred.runs.push((part, positions));
        Ok(())
    }

    /// Whether draws under queried nodes can still be handed over to be gathered
    /// ([`PartTests::defer_node_run`]): the device can gather and the frame's first dispatch
    /// is still to come.
    pub fn can_gather(&self) -> bool {
        self.gather.is_some() && !self.dispatched
    }

    /// Hands over the objects of queried node `query` (a query of this frame, not resolved
    /// yet) whose commands lie at `positions` of the renderer's ordered draw commands, to be
    /// gathered at the next dispatch with the other runs whose predicate holds: the query's
    /// value, copied there, decides as a conditional block on it would.
    pub fn defer_node_run(
        &mut self,
        query: QueryId,
        positions: std::ops::Range<u32>,
    ) -> Result<()> {
        if query & PART_BIT != 0 || !self.can_gather() {
            return Err(Error::Input(format!(
                "draws under query {query:#x} cannot be gathered (not a query, or no gathering \
                 after this frame's first dispatch)"
            )));
        }
        self.node_runs = true;
        self.deferred.commands += positions.len() as u32;
        self.deferred.runs.push((query, positions));
        Ok(())
    }

    /// Hands over `objects` of `part` (added, not tested yet), to be drawn after its test in
    /// a conditional block on its predicate.
    pub fn defer(&mut self, part: QueryId, objects: &[u32]) -> Result<()> {
        self.check_awaits(part)?;
        let d = &mut self.deferred;
        let first = d.objects.len();
        d.objects.extend_from_slice(objects);
        d.lists.push((part, first..d.objects.len()));
        Ok(())
    }

    fn check_awaits(&self, part: QueryId) -> Result<()> {
        if !self.awaits_test(part) {
            return Err(Error::Input(format!(
                "{part:#x} is not a part of this frame waiting for its test"
            )));
        }
        Ok(())
    }

    /// The draws of the last dispatch's parts, for the renderer to record after it (taken:
    /// the next call returns the next dispatch's). Give the lists back with
    /// [`PartTests::restore_deferred`] to keep their capacity.
    pub fn take_recorded_draws(&mut self) -> Deferred {
        std::mem::take(&mut self.deferred)
    }

    /// Gives back the lists of [`PartTests::take_recorded_draws`], emptied.
    pub fn restore_deferred(&mut self, mut d: Deferred) {
        d.clear();
        if self.deferred.is_empty() {
            self.deferred = d;
        }
    }

    /// The gathered commands and their count for the indirect draw; refused when the
    /// gathering's barrier to indirect reads is missing.
    pub fn gathered(&self) -> Result<(&Buffer, &Buffer)> {
        if self.unguarded {
            return Err(Error::Input(
                "an indirect draw reads part draws that no barrier made visible after their \
                 gathering"
                    .into(),
            ));
        }
        Ok((&self.buffers.drawn, &self.buffers.count))
    }

    /// Whether parts, or draws under queried nodes, wait for a dispatch.
    pub fn pending(&self) -> bool {
        (self.tested as usize) < self.parts.len() || self.node_runs
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
        word_at(
            self.buffers.predicates.mapped()?,
            (part & !PART_BIT) as usize,
        )
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
    /// dispatch, and the barriers to conditional rendering and the host. With gathering, a
    /// second dispatch copies the runs handed over for these parts
    /// ([`PartTests::defer_run`]) and for queried nodes ([`PartTests::defer_node_run`]; with
    /// no parts, it is the only dispatch) whose predicate holds from `ordered` (the
    /// renderer's ordered draw commands, with their buffer's generation) into one list, with
    /// a barrier to indirect reads; the renderer then records the draws
    /// ([`PartTests::take_recorded_draws`]). Leaves `depth` sampled by compute when parts were
    /// tested (the caller moves it back to an attachment). `segment` is the segment being
    /// recorded.
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &mut self,
        rec: &mut Recorder,
        depth: &Image,
        queries: &mut coherent_ash::QuerySet,
        flags: Option<&Buffer>,
        view_proj: &[f32; 16],
        segment: u32,
        ordered: Option<(&Buffer, u64)>,
        max_draw_count: u32,
    ) -> Result<()> {
        let (first, n) = (self.tested, self.parts.len() as u32 - self.tested);
        if n == 0 && !self.node_runs {
            return Ok(());
        }
        // The values of the queries up to the last one a part or a node's draws name.
        let node_runs = self
            .deferred
            .runs
            .iter()
            .filter(|(id, _)| id & PART_BIT == 0);
        let issued = (self.parts.iter().map(|p| p[2] + 1))
            .chain(node_runs.map(|(id, _)| super::box_flags::node_index(*id) + 1))
            .max()
            .unwrap_or(0);
        let groups = self.deferred.runs.len() as u32;
        let commands = self.deferred.commands;
        let need = Room {
            parts: self.parts.len() as u32,
            boxes: self.boxes.len() as u32,
            queries: issued,
            groups: if self.gather.is_some() { groups } else { 0 },
            commands: if self.gather.is_some() { commands } else { 0 },
        };
        let ordered = ordered.filter(|_| self.gather.is_some());
        if !self.dispatched {
            self.make_room(depth, need)?;
        }
        // Gathered on the device at the frame's first dispatch (later ones would overwrite the
        // list an earlier draw reads), when one indirect draw may draw them all.
        let gather =
            ordered.is_some() && !self.dispatched && groups > 0 && commands <= max_draw_count;
        self.deferred.gathered = gather;
        let b = &mut self.buffers;
        if n > 0 {
            let parts = &self.parts[first as usize..];
            let first_box = parts[0][0] as usize;
            b.parts
                .write(first as usize * PART_BYTES, bytes_of(parts))?;
            b.boxes
                .write(first_box * BOX_BYTES, bytes_of(&self.boxes[first_box..]))?;
        }
        if let (Some(f), true) = (flags, issued > 0) {
            rec.copy_buffer(f, &b.node_values, u64::from(issued) * 4);
        } else if issued > 0 {
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
        if n > 0 {
            rec.transition(depth, ImageUse::SampledByCompute);
            rec.bind_compute_pipeline(&self.pipeline);
            rec.bind_compute_set(&self.layout, b.sets.get(0));
            let (w, h) = self.size;
            let info = [n, first, MOST_PIXELS, 0];
            let screen = [
                w as f32,
                h as f32,
                DEPTH_MARGIN,
                centre_margin(self.pixel_grid),
            ];
            let mut push = [0u8; PUSH as usize];
            push[..64].copy_from_slice(bytes_of(view_proj));
            push[64..80].copy_from_slice(bytes_of(&info));
            push[80..96].copy_from_slice(bytes_of(&screen));
            rec.push_constants(&self.layout, &push);
            rec.dispatch("part test", n.div_ceil(GROUP), 1, 1)?;
        }
        self.node_runs = false;
        if let Some((ordered, generation)) = ordered.filter(|_| gather) {
            self.record_gathering(rec, ordered, generation)?;
        }
        if self.skip_barrier {
            self.unguarded = true;
        } else {
            rec.memory_barrier(Access::ComputeReadWrite, Access::ConditionalRead);
            if gather {
                rec.memory_barrier(Access::ComputeReadWrite, Access::IndirectRead);
            }
        }
        rec.memory_barrier(Access::ComputeReadWrite, Access::HostRead);
        self.tested = self.parts.len() as u32;
        self.dispatched = true;
        self.segment.resize(self.parts.len(), segment);
        self.read.resize(self.parts.len(), false);
        Ok(())
    }

    /// Writes the deferred runs as groups and records their gathering after the test: only
    /// the commands of the runs whose part passed are copied from `ordered`, in run order,
    /// and their number written as the count.
    fn record_gathering(
        &mut self,
        rec: &mut Recorder,
        ordered: &Buffer,
        generation: u64,
    ) -> Result<()> {
        let Some((pipeline, layout)) = self.gather.as_ref() else {
            return Ok(());
        };
        let d = &self.deferred;
        let words = &mut self.group_words;
        words.clear();
        for (id, run) in &d.runs {
            // Source 0: a part's predicate; 1: a queried node's value.
            let node = id & PART_BIT == 0;
            let index = if node {
                super::box_flags::node_index(*id)
            } else {
                id & !PART_BIT
            };
            words.extend_from_slice(&[index, run.start, run.len() as u32, u32::from(node)]);
        }
        let b = &mut self.buffers;
        b.groups.write(0, bytes_of(&words[..]))?;
        // The set names the ordered commands and this frame's buffers: made again when
        // either changed (the old one is kept until the frame has completed).
        if self.gather_set.as_ref().map(|(g, _)| *g) != Some(generation) || b.fresh {
            let bindings = [
                Binding::StorageBuffer(&b.groups),
                Binding::StorageBuffer(&b.predicates),
                Binding::StorageBuffer(ordered),
                Binding::StorageBuffer(&b.drawn),
                Binding::StorageBuffer(&b.count),
                Binding::StorageBuffer(&b.node_values),
            ];
            let set = DescriptorSets::new(&self.ctx, &[(layout, &bindings[..])])?;
            if let Some((_, old)) = self.gather_set.replace((generation, set)) {
                self.retired_sets.push(old);
            }
            b.fresh = false;
        }
        let set = self.gather_set.as_ref().expect("made above").1.get(0);
        rec.memory_barrier(Access::ComputeReadWrite, Access::ComputeReadWrite);
        rec.bind_compute_pipeline(pipeline);
        rec.bind_compute_set(layout, set);
        let info = [0, d.runs.len() as u32, 0, 0];
        rec.push_constants(layout, bytes_of(&info));
        rec.dispatch("part draws", 1, 1, 1)?;
        Ok(())
    }

    /// Makes room for `need`: buffers too small are replaced by larger ones (the old ones
    /// kept until the frame has completed). Only before the frame's first dispatch, which
    /// names the buffers: later, a part that does not fit is refused by [`PartTests::fits`]
    /// and queried instead, and draws that do not fit are drawn in conditional blocks.
    fn make_room(&mut self, depth: &Image, need: Room) -> Result<()> {
        let have = self.buffers.room;
        if have.holds(&need) {
            return Ok(());
        }
        if self.dispatched {
            return Err(Error::Input(format!(
                "part tests: a second test in one frame needs room for {need:?} (there is \
                 room for {have:?})"
            )));
        }
        let grow = |need: u32, have: u32| need.max(have).next_power_of_two();
        let room = Room {
            parts: grow(need.parts, have.parts),
            boxes: grow(need.boxes, have.boxes),
            queries: grow(need.queries, have.queries),
            groups: grow(need.groups, have.groups),
            commands: grow(need.commands, have.commands),
        };
        let new = Buffers::new(
            &self.ctx,
            &self.layout,
            self.gather.as_ref(),
            depth,
            &self.sampler,
            room,
        )?;
        let old = std::mem::replace(&mut self.buffers, new);
        self.retired.push(old);
        Ok(())
    }
}

impl Buffers {
    fn new(
        ctx: &Arc<GpuContext>,
        layout: &PipelineLayout,
        gather: Option<&(ComputePipeline, PipelineLayout)>,
        depth: &Image,
        sampler: &Sampler,
        room: Room,
    ) -> Result<Buffers> {
        let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
        let indirect = vk::BufferUsageFlags::INDIRECT_BUFFER;
        let host = MemoryLocation::CpuToGpu;
        let sized = |n: u32, bytes: usize| u64::from(n.max(1)) * bytes as u64;
        let parts = Buffer::new(
            ctx,
            "part records",
            sized(room.parts, PART_BYTES),
            storage,
            host,
        )?;
        let boxes = Buffer::new(
            ctx,
            "part boxes",
            sized(room.boxes, BOX_BYTES),
            storage,
            host,
        )?;
        let node_values = Buffer::new(
            ctx,
            "part node values",
            sized(room.queries, 4),
            storage | vk::BufferUsageFlags::TRANSFER_DST,
            MemoryLocation::GpuOnly,
        )?;
        let predicates = Buffer::new(
            ctx,
            "part predicates",
            sized(room.parts, 4),
            storage | vk::BufferUsageFlags::CONDITIONAL_RENDERING_EXT,
            MemoryLocation::GpuToCpu,
        )?;
        // Without a gathering these stay minimal (one entry each).
        let (groups_room, commands_room) = match gather {
            Some(_) => (room.groups, room.commands),
            None => (1, 1),
        };
        let groups = Buffer::new(
            ctx,
            "part draw groups",
            sized(groups_room, GROUP_BYTES),
            storage,
            host,
        )?;
        let drawn = Buffer::new(
            ctx,
            "part draws gathered",
            sized(commands_room, COMMAND_BYTES),
            storage | indirect,
            MemoryLocation::GpuOnly,
        )?;
        let count = Buffer::new(
            ctx,
            "part draw count",
            4,
            storage | indirect,
            MemoryLocation::GpuOnly,
        )?;
        let test = [
            Binding::StorageBuffer(&parts),
            Binding::StorageBuffer(&boxes),
            Binding::StorageBuffer(&node_values),
            Binding::StorageBuffer(&predicates),
            Binding::Sampled(depth, sampler),
        ];
        let sets = DescriptorSets::new(ctx, &[(layout, &test[..])])?;
        Ok(Buffers {
            parts,
            boxes,
            node_values,
            predicates,
            groups,
            drawn,
            count,
            sets,
            fresh: true,
            room: Room {
                groups: groups_room,
                commands: commands_room,
                ..room
            },
        })
    }
}

/// The pixel-centre margin box_project.glsl takes (pixels): [`coherent_cull::PixelGrid`]'s, or
/// negative for no pixel-centre test.
pub(crate) fn centre_margin(pixel_grid: bool) -> f32 {
    if pixel_grid {
        coherent_cull::PixelGrid::MARGIN
    } else {
        -1.0
    }
}
