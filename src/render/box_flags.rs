//! Box flags: the predicated mode's box tests answered by one instanced draw of a batch's
//! boxes instead of one occlusion query each ([`Renderer::set_box_flags`](super::Renderer)).
//!
//! A query is at least one draw, and on lavapipe a draw's fixed cost (a few microseconds in a
//! street frame, about 7 us for a query's box draw at the city's x16 scale) outweighs the
//! boxes it draws (about 0.1-0.3 us a box when 1,024 boxes share one draw): docs/measurements.md,
//! "What a draw costs lavapipe". Here the boxes of all tests issued before a predicate resolve
//! are drawn at the resolve, one instanced draw for the unconditional ones
//! (`shaders/box_visible.vert`, the box oracle's shaders: front faces, an indexed draw of the
//! boxes' 8 corners, the query boxes' depth bias toward the eye, no writes but the flag), and a
//! fragment that passes the depth test
//! (early fragment tests, so the shader runs only for those) writes 1 into its test's 32-bit
//! flag. A copy of the flags is the predicate buffer, the flags themselves the part tests' node
//! values (copied again) and, once the frame completed, the results the culler reads (1 or 0).
//!
//! Why a copy: a conditional block reads its predicate when the device reaches it, and the
//! barrier from the flags' fragment writes to that read is all Vulkan asks for. Lavapipe
//! (Mesa 22.3) does not wait for the rasterizer at such a barrier, and reads a predicate the
//! rasterizer may still be writing: without the copy a test of this module's saw objects go
//! missing. A buffer copy waits there for the writes of the buffer it reads, as the copy of
//! query results does; on any device it is one small transfer a resolve.
//!
//! Exact on the same terms as a query: a box that owns a sample in front of the depth drawn so
//! far passes the same depth test with the same bias, so its flag is 1. The depth a resolve
//! tests against holds every draw recorded before it, real geometry of this frame that only
//! gets nearer. What a flag gives up is the pixel count: the visibility threshold must be 0.
//!
//! A flag names its frame: a result asked for after the next frame began is `None` (dropped,
//! as a result not back), so the culler must read them after the frame; with `k` frames in
//! flight the built-in renderer's cullers are wrapped in `FramesInFlight`, which does and
//! keeps them.
//!
//! The parts of split nodes ([`coherent_cull::OcclusionBackend::test_part_if`] under a node's
//! flag) are *gated* flags (`BoxFlags::add_gated`): their records name the node's flag, and
//! the vertex shader reads it from the predicates and draws the part's boxes only where it is
//! 1, so they join the resolve's one instanced draw with no conditional block; a part whose node
//! was hidden reads 0, as a query in a block on the node's predicate would. Other tests drawn
//! under a predicate (parts queried under their node's) get a conditional block each, as
//! queries do.

use std::sync::Arc;

use ash::vk;
use coherent_cull::{Aabb, QueryId};
use gpu_allocator::MemoryLocation;

use crate::error::{Error, Result};
use crate::gpu::targets::COLOR_FORMAT;
use crate::gpu::{
    word_at, Binding, Buffer, DescriptorSets, GpuContext, Pipeline, PipelineKind, PipelineLayout,
    Recorder,
};

/// Flag ids carry this bit (query ids never do; part ids carry [`super::part_tests::PART_BIT`]).
pub const FLAG_BIT: QueryId = 1 << 30;
/// Bits of a flag id that hold its slot in the frame's flag buffer...
const SLOT_BITS: u32 = 16;
/// ... and above them, up to `FLAG_BIT`, the frame it belongs to (wrapping).
const FRAME_MASK: u32 = (FLAG_BIT >> SLOT_BITS) - 1;
/// Most flags (tests) in one frame, and most boxes.
pub const MAX_FLAGS: u32 = 1 << SLOT_BITS;
const MAX_BOXES: u32 = 1 << 18;
/// Bytes of one box record (`box_visible.vert` `ObjectBox`: two vec4, the flag slot in lo.w).
const BOX_BYTES: usize = 32;

/// Where the value of node test `id` (a query, or a flag: its slot) lies in the part tests'
/// node values.
pub fn node_index(id: QueryId) -> u32 {
    if BoxFlags::is_flag(id) {
        id & (MAX_FLAGS - 1)
    } else {
        id
    }
}

/// Boxes drawn together: consecutive unconditional tests, or one test under a predicate.
struct Group {
    predicate: Option<(vk::Buffer, u64)>,
    first: u32,
    count: u32,
}

/// What a frame's flags recorded, for the frame's counts.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FlagCounts {
    /// Tests issued (each one flag).
    pub tests: u32,
    /// Of those, tests drawn under another predicate in a conditional block.
    pub predicated: u32,
    /// Of those, tests gated by another flag (`BoxFlags::add_gated`: parts of split nodes).
    pub gated: u32,
    /// Instanced draws of boxes.
    pub draws: u32,
    /// Boxes drawn.
    pub boxes: u32,
}

/// The flag pipeline, this frame's boxes and flags, and their descriptor set.
pub(super) struct BoxFlags {
    // The pipeline and the set go before the layout and the buffers they use.
    pipeline: Pipeline,
    sets: DescriptorSets,
    layout: PipelineLayout,
    /// This frame's box records (host-visible, written as tests are issued).
    boxes: Buffer,
    /// One word per test: written by the device, zeroed by the host between frames.
    flags: Buffer,
    /// The drawn flags copied at each resolve: the buffer conditional blocks read.
    predicates: Buffer,
    pending: Vec<Group>,
    /// The boxes' triangles as corner indices (`box_oracle::BOX_INDICES`).
    indices: Buffer,
    /// Scratch: one test's box records.
    words: Vec<u32>,
    /// Per slot of this frame: whether its test is gated ([`BoxFlags::add_gated`]).
    gated: Vec<bool>,
    boxes_used: u32,
    flags_used: u32,
    /// Flags whose boxes were drawn and made visible to predicates by a barrier.
    resolved: u32,
    /// Flags whose boxes were drawn (a barrier must follow before they are read).
    drawn: u32,
    frame: u32,
    /// Whether this frame completed, so its flags are final.
    complete: bool,
    counts: FlagCounts,
}

impl BoxFlags {
    /// The flags for the built-in renderer's target; needs `fragmentStoresAndAtomics`.
    pub(super) fn new(ctx: &Arc<GpuContext>) -> Result<BoxFlags> {
        if !ctx.info.optional.fragment_stores {
            return Err(Error::Unsupported {
                feature: "fragmentStoresAndAtomics (box flags are written by the fragment \
                          shader)"
                    .into(),
            });
        }
        let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
        let boxes = Buffer::new(
            ctx,
            "box flag boxes",
            u64::from(MAX_BOXES) * BOX_BYTES as u64,
            storage,
            MemoryLocation::CpuToGpu,
        )?;
        let flags = Buffer::new(
            ctx,
            "box flags",
            u64::from(MAX_FLAGS) * 4,
            storage
                | vk::BufferUsageFlags::CONDITIONAL_RENDERING_EXT
                | vk::BufferUsageFlags::TRANSFER_SRC,
            MemoryLocation::CpuToGpu,
        )?;
        let predicates = Buffer::new(
            ctx,
            "box flag predicates",
            u64::from(MAX_FLAGS) * 4,
            vk::BufferUsageFlags::CONDITIONAL_RENDERING_EXT
                | vk::BufferUsageFlags::TRANSFER_DST
                | storage,
            MemoryLocation::GpuOnly,
        )?;
        let (layout, pipeline) = super::box_oracle::marking_pipeline(
            ctx,
            "box flags",
            COLOR_FORMAT,
            PipelineKind::Query,
        )?;
        // The predicates are the gates of gated tests (BoxFlags::add_gated).
        let bindings = [
            Binding::StorageBuffer(&boxes),
            Binding::StorageBuffer(&flags),
            Binding::StorageBuffer(&predicates),
        ];
        let sets = DescriptorSets::new(ctx, &[(&layout, &bindings[..])])?;
        let mut f = BoxFlags {
            pipeline,
            sets,
            layout,
            boxes,
            flags,
            predicates,
            pending: Vec::new(),
            words: Vec::new(),
            indices: super::box_oracle::box_index_buffer(ctx, "box flag indices")?,
            gated: Vec::new(),
            boxes_used: 0,
            // Zeroes the whole buffer before the first frame.
            flags_used: MAX_FLAGS,
            resolved: 0,
            drawn: 0,
            frame: 0,
            complete: false,
            counts: FlagCounts::default(),
        };
        f.begin_frame()?;
        Ok(f)
    }

    /// Start of a frame, once the previous one completed (nothing reads the flags): every
    /// flag of the last frame back to 0, and a new frame number for the ids.
    pub(super) fn begin_frame(&mut self) -> Result<()> {
        if self.flags_used > 0 {
            let used = self.flags_used as usize * 4;
            let bytes = self
                .flags
                .mapped_mut()
                .ok_or_else(|| Error::Alloc("box flags are not mapped".into()))?;
            bytes[..used].fill(0);
        }
        self.pending.clear();
        self.gated.clear();
        self.boxes_used = 0;
        self.flags_used = 0;
        self.resolved = 0;
        self.drawn = 0;
        self.frame = (self.frame + 1) & FRAME_MASK;
        self.complete = false;
        self.counts = FlagCounts::default();
        Ok(())
    }

    /// A test of `boxes`, drawn at the next resolve; with `predicate` (a predicate buffer and
    /// byte offset: a resolved flag's or a tested part's) inside a conditional block on it.
    /// Returns the test's id.
    pub(super) fn add(
        &mut self,
        predicate: Option<(vk::Buffer, u64)>,
        boxes: &[Aabb],
    ) -> Result<QueryId> {
        self.add_test(predicate, super::box_oracle::NO_GATE, boxes)
    }

    /// A test of `boxes` whose boxes are drawn only where resolved flag `gate` of this frame
    /// is 1 (else the test reads 0): in the draw of the unconditional tests, with no
    /// conditional block. The shader reads the gate from the predicates, so a barrier from
    /// their copy to vertex-shader reads must lie between the gate's resolve and this test's
    /// draw, and one from those reads to the next copy after it (the renderer's resolve).
    pub(super) fn add_gated(&mut self, gate: QueryId, boxes: &[Aabb]) -> Result<QueryId> {
        let slot = self.resolved_slot(gate).ok_or_else(|| {
            Error::Input(format!(
                "{gate:#x} is not a resolved box flag of this frame: a gate must be"
            ))
        })?;
        let id = self.add_test(None, slot, boxes)?;
        self.counts.gated += 1;
        Ok(id)
    }

    fn add_test(
        &mut self,
        predicate: Option<(vk::Buffer, u64)>,
        gate: u32,
        boxes: &[Aabb],
    ) -> Result<QueryId> {
        let n = boxes.len() as u32;
        if n == 0 {
            return Err(Error::Input("a box test of no boxes".into()));
        }
        if self.flags_used >= MAX_FLAGS || self.boxes_used + n > MAX_BOXES {
            return Err(Error::Input(format!(
                "more than {MAX_FLAGS} box tests or {MAX_BOXES} boxes in one frame"
            )));
        }
        let slot = self.flags_used;
        self.words.clear();
        for b in boxes {
            self.words
                .extend(super::box_oracle::box_record(b, slot, gate));
        }
        let at = self.boxes_used as usize * BOX_BYTES;
        self.boxes.write(at, crate::gpu::bytes_of(&self.words))?;
        match self.pending.last_mut() {
            Some(g) if predicate.is_none() && g.predicate.is_none() => g.count += n,
            _ => self.pending.push(Group {
                predicate,
                first: self.boxes_used,
                count: n,
            }),
        }
        self.boxes_used += n;
        self.flags_used += 1;
        self.gated.push(gate != super::box_oracle::NO_GATE);
        self.counts.tests += 1;
        self.counts.predicated += u32::from(predicate.is_some());
        Ok(FLAG_BIT | (self.frame << SLOT_BITS) | slot)
    }

    /// Whether tests wait for their draw.
    pub(super) fn pending(&self) -> bool {
        !self.pending.is_empty()
    }

    /// Whether `id` is a flag id (of any frame).
    pub(super) fn is_flag(id: QueryId) -> bool {
        id & (FLAG_BIT | super::part_tests::PART_BIT) == FLAG_BIT
    }

    /// The slot of `id` when it is a flag of this frame.
    fn slot(&self, id: QueryId) -> Option<u32> {
        let this_frame = Self::is_flag(id) && (id & !FLAG_BIT) >> SLOT_BITS == self.frame;
        let slot = id & (MAX_FLAGS - 1);
        (this_frame && slot < self.flags_used).then_some(slot)
    }

    /// The slot of `id` when it is a flag of this frame whose boxes were drawn and made
    /// visible to predicates.
    pub(super) fn resolved_slot(&self, id: QueryId) -> Option<u32> {
        self.slot(id).filter(|&s| s < self.resolved)
    }

    /// Whether `id` is a gated flag of this frame ([`BoxFlags::add_gated`]) whose boxes wait
    /// for their draw: draws under it may be handed over before its resolve.
    pub(super) fn gated_awaits_draw(&self, id: QueryId) -> bool {
        self.awaits_draw(id)
            && self
                .slot(id)
                .is_some_and(|s| self.gated.get(s as usize) == Some(&true))
    }

    /// Whether `id` is a flag of this frame whose boxes wait for their draw.
    pub(super) fn awaits_draw(&self, id: QueryId) -> bool {
        self.slot(id).is_some_and(|s| s >= self.drawn)
    }

    /// The buffer and byte offset of a resolved flag, for a conditional block.
    pub(super) fn predicate_at(&self, id: QueryId) -> Result<(vk::Buffer, u64)> {
        let slot = self.resolved_slot(id).ok_or_else(|| {
            Error::Input(format!(
                "{id:#x} is not a resolved box flag of this frame (its boxes drawn, and a \
                 barrier after them)"
            ))
        })?;
        Ok((self.predicates.handle, u64::from(slot) * 4))
    }

    /// Records the pending tests' boxes inside rendering: one instanced draw for each run of
    /// unconditional tests, one in a conditional block for each test under a predicate
    /// (`block` opens it with `Some`, closes it with `None`). A barrier must follow outside
    /// rendering ([`BoxFlags::barrier_recorded`]) before the flags are read.
    pub(super) fn record(
        &mut self,
        rec: &mut Recorder,
        matrix: &[u8],
        mut block: impl FnMut(&mut Recorder, Option<(vk::Buffer, u64)>) -> Result<()>,
    ) -> Result<()> {
        rec.bind_pipeline(&self.pipeline);
        rec.bind_graphics_set(&self.layout, self.sets.get(0));
        rec.push_constants(&self.layout, matrix);
        for g in &self.pending {
            if g.predicate.is_some() {
                block(rec, g.predicate)?;
            }
            rec.bind_index_buffer(&self.indices);
            let indices = super::box_oracle::BOX_INDICES.len() as u32;
            rec.draw_indexed_instanced(indices, g.count, g.first);
            if g.predicate.is_some() {
                block(rec, None)?;
            }
            self.counts.draws += 1;
            self.counts.boxes += g.count;
        }
        self.pending.clear();
        self.drawn = self.flags_used;
        Ok(())
    }

    /// Outside rendering, after [`BoxFlags::record`] and a barrier from its fragment writes to
    /// transfer reads: copies the drawn flags into the predicate buffer. A barrier from that
    /// copy to conditional rendering must follow ([`BoxFlags::barrier_recorded`]).
    pub(super) fn record_copy(&self, rec: &mut Recorder) {
        rec.copy_buffer(
            &self.flags,
            &self.predicates,
            u64::from(self.drawn.max(1)) * 4,
        );
    }

    /// The barrier after [`BoxFlags::record_copy`] was recorded: the drawn flags may be read
    /// as predicates.
    pub(super) fn barrier_recorded(&mut self) {
        self.resolved = self.drawn;
    }

    /// The flag buffer (the part tests copy their node values from it).
    pub(super) fn flags(&self) -> &Buffer {
        &self.flags
    }

    /// The frame completed: its flags are final.
    pub(super) fn set_complete(&mut self) {
        self.complete = true;
    }

    /// The result of `id` (1 or 0) once its frame completed; `None` before, and for a flag of
    /// another frame.
    pub(super) fn result(&self, id: QueryId) -> Option<u64> {
        let slot = self.resolved_slot(id).filter(|_| self.complete)?;
        word_at(self.flags.mapped()?, slot as usize).map(u64::from)
    }

    /// The value a conditional block on `id` read, after the frame (for the draw log).
    pub(super) fn predicate(&self, id: QueryId) -> Option<u32> {
        let slot = self.resolved_slot(id)?;
        word_at(self.flags.mapped()?, slot as usize)
    }

    /// What this frame recorded.
    pub(super) fn counts(&self) -> FlagCounts {
        self.counts
    }
}
