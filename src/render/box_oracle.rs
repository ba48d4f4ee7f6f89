//! The box oracle (`oracle-box`): the objects whose own bounding box shows against the exact
//! depth, what an ideal culler that tests boxes would draw.
//!
//! A culler that tests bounding boxes (CHC, CHC++ in any latency mode, stop-and-wait, NOHC,
//! two-phase Hi-Z) tests them against the depth drawn so far, which is never nearer than the
//! frame's final depth, and mostly tests boxes larger than one object's (a node's, a
//! multiquery's, a tight bound's). The box oracle tests each object's own box against the final
//! depth: after the untimed ID pass (which leaves the final depth of the frustum's objects), one
//! instanced draw of the candidates' boxes (`shaders/box_visible.vert`: front faces, as the
//! query boxes; the same depth test, with the same bias toward the eye; no writes) marks, in the
//! fragment shader, each object a box fragment of which passed (`shaders/box_visible.frag`,
//! early fragment tests). Its frame then draws those objects and nothing else: the time of the
//! draws an ideal box culler cannot avoid, with no query and no pass break. Where it lies above
//! the `oracle` (the objects that own a pixel) is the price of testing boxes rather than the
//! objects themselves; where a culler lies above it is the price of its hierarchy, its
//! history and its queries. (It is not a strict floor for every culler: the depth bias
//! depends on a face's slope, so in a few objects a frame a larger box's face can fail where
//! the object's own passed.)
//!
//! Needs `fragmentStoresAndAtomics`; a device without it gets [`Error::Unsupported`].

use std::sync::Arc;

use ash::vk;
use gpu_allocator::MemoryLocation;

use crate::error::{Error, Result};
use crate::gpu::targets::{DEPTH_FORMAT, ID_FORMAT};
use crate::gpu::{
    as_bytes, shaders, word_at, Binding, Buffer, DescriptorSets, GpuContext, Pipeline,
    PipelineDesc, PipelineKind, PipelineLayout,
};

use super::ObjectDraw;

/// Bytes of one box record (`box_visible.vert` `ObjectBox`: two vec4).
const BOX_BYTES: u64 = 32;
/// Push constants of [`marking_pipeline`]: the world-to-clip matrix.
const PUSH: u32 = 64;
/// The 12 triangles of a box as indices of its corners (x | y << 1 | z << 2), counter-clockwise
/// seen from outside: coherent-ash's query boxes' [`coherent_ash::BOX_FACES`], so these boxes
/// cover the pixels its query boxes do. `box_visible.vert` makes the corner from the index.
pub(super) const BOX_INDICES: [u32; 36] = coherent_ash::BOX_FACES;

/// The index buffer of [`BOX_INDICES`], for a marking pass's indexed instanced draw.
pub(super) fn box_index_buffer(ctx: &Arc<GpuContext>, name: &str) -> Result<Buffer> {
    Buffer::with_data(
        ctx,
        name,
        crate::gpu::bytes_of(&BOX_INDICES),
        vk::BufferUsageFlags::INDEX_BUFFER,
    )
}

/// The pipeline of a pass that marks boxes (`shaders/box_visible.vert` and `.frag`): one
/// instance per record of its storage buffer (binding 0, [`box_record`]) draws the box's
/// front faces (an indexed draw of [`BOX_INDICES`]) with coherent-ash's query boxes' depth
/// test and bias, writes no color or depth,
/// and a fragment that passes (early fragment tests) writes 1 into the word of the storage
/// buffer at binding 1 that the record names. A record may name a gate, a word of the storage
/// buffer at binding 2: its box is drawn only where that word is non-zero. The box oracle
/// marks objects with it, the box flags tests. Push constants: the world-to-clip matrix.
pub(super) fn marking_pipeline(
    ctx: &Arc<GpuContext>,
    name: &'static str,
    color_format: vk::Format,
    kind: PipelineKind,
) -> Result<(PipelineLayout, Pipeline)> {
    let layout = PipelineLayout::new(
        ctx,
        &[
            vk::DescriptorType::STORAGE_BUFFER,
            vk::DescriptorType::STORAGE_BUFFER,
            vk::DescriptorType::STORAGE_BUFFER,
        ],
        PUSH,
    )?;
    let desc = PipelineDesc {
        name,
        vert: shaders::BOX_VISIBLE_VERT,
        frag: Some(shaders::BOX_VISIBLE_FRAG),
        vertex_stride: 0,
        attributes: &[],
        color_formats: &[color_format],
        color_write: false,
        depth_format: DEPTH_FORMAT,
        depth_compare: vk::CompareOp::LESS_OR_EQUAL,
        depth_write: false,
        // Front faces only, as the query boxes: the box of an object the eye is inside
        // (or that reaches the near plane) may then show nothing, and exact cullers draw
        // such objects without a test anyway.
        cull: vk::CullModeFlags::BACK,
        kind,
        // As coherent-ash's query boxes: toward the eye, so a face lying on the surface
        // it bounds passes.
        depth_bias: (-4.0, -1.0),
        blend: false,
    };
    let pipeline = Pipeline::graphics(ctx, &layout, &desc)?;
    Ok((layout, pipeline))
}

/// A box record's gate for a box drawn whatever the gates hold.
pub(super) const NO_GATE: u32 = u32::MAX;

/// One box record of [`marking_pipeline`]'s storage buffer: the corners, in the minimum's w
/// the index of the word a passing fragment marks, and in the maximum's w the index of the
/// word at binding 2 that must be non-zero for the box to be drawn ([`NO_GATE`]: none).
pub(super) fn box_record(b: &coherent_cull::Aabb, index: u32, gate: u32) -> [u32; 8] {
    let (lo, hi) = (b.min, b.max);
    [
        lo.x.to_bits(),
        lo.y.to_bits(),
        lo.z.to_bits(),
        index,
        hi.x.to_bits(),
        hi.y.to_bits(),
        hi.z.to_bits(),
        gate,
    ]
}

/// The box pass's pipeline, its buffers and their descriptor set.
pub(super) struct BoxOracle {
    // The pipeline and the set go before the layout and the buffers they use.
    pipeline: Pipeline,
    sets: DescriptorSets,
    layout: PipelineLayout,
    /// One record per candidate of the pass (host-visible, written before it).
    boxes: Buffer,
    /// One word per object: 1 where a fragment of its box passed (read by the host after it).
    visible: Buffer,
    /// The gates' binding (unused: no box has a gate).
    _gates: Buffer,
    /// [`BOX_INDICES`].
    indices: Buffer,
    /// Objects the buffers are sized for.
    objects: usize,
    /// Candidates in the box buffer now.
    count: u32,
}

impl BoxOracle {
    /// The pass for a scene of `objects` objects.
    pub(super) fn new(ctx: &Arc<GpuContext>, objects: usize) -> Result<BoxOracle> {
        if !ctx.info.optional.fragment_stores {
            return Err(Error::Unsupported {
                feature: "fragmentStoresAndAtomics (oracle-box marks visible boxes from the \
                          fragment shader)"
                    .into(),
            });
        }
        let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
        let n = objects.max(1) as u64;
        let boxes = Buffer::new(
            ctx,
            "oracle-box boxes",
            n * BOX_BYTES,
            storage,
            MemoryLocation::CpuToGpu,
        )?;
        let visible = Buffer::new(
            ctx,
            "oracle-box visible",
            n * 4,
            storage | vk::BufferUsageFlags::TRANSFER_DST,
            MemoryLocation::GpuToCpu,
        )?;
        // No box of the oracle has a gate: a word the shader never reads.
        let gates = Buffer::new(ctx, "oracle-box gates", 4, storage, MemoryLocation::GpuOnly)?;
        let (layout, pipeline) =
            marking_pipeline(ctx, "oracle-box", ID_FORMAT, PipelineKind::Other)?;
        let bindings = [
            Binding::StorageBuffer(&boxes),
            Binding::StorageBuffer(&visible),
            Binding::StorageBuffer(&gates),
        ];
        let sets = DescriptorSets::new(ctx, &[(&layout, &bindings[..])])?;
        Ok(BoxOracle {
            pipeline,
            sets,
            layout,
            boxes,
            visible,
            _gates: gates,
            indices: box_index_buffer(ctx, "oracle-box indices")?,
            objects,
            count: 0,
        })
    }

    /// Objects the buffers hold.
    pub(super) fn objects(&self) -> usize {
        self.objects
    }

    /// Writes the boxes of `candidates` (current bounds from `draws`) for the next pass.
    pub(super) fn write_boxes(&mut self, candidates: &[u32], draws: &[ObjectDraw]) -> Result<()> {
        let mut words = Vec::with_capacity(candidates.len() * 8);
        for &o in candidates {
            let b = draws
                .get(o as usize)
                .ok_or_else(|| Error::Input(format!("oracle-box: no object {o}")))?
                .bounds;
            words.extend(box_record(&b, o, NO_GATE));
        }
        self.boxes.write(0, &as_bytes(&words))?;
        self.count = candidates.len() as u32;
        Ok(())
    }

    /// Records the pass inside the ID pass's rendering, after its draws: one instanced draw of
    /// the boxes written by [`BoxOracle::write_boxes`]; `matrix` the world-to-clip matrix.
    pub(super) fn record(&self, rec: &mut crate::gpu::Recorder, matrix: &[u8]) {
        if self.count == 0 {
            return;
        }
        rec.bind_pipeline(&self.pipeline);
        rec.bind_graphics_set(&self.layout, self.sets.get(0));
        rec.push_constants(&self.layout, matrix);
        rec.bind_index_buffer(&self.indices);
        rec.draw_indexed_instanced(BOX_INDICES.len() as u32, self.count, 0);
    }

    /// The visible flags buffer, cleared before the pass and read after it.
    pub(super) fn flags(&self) -> &Buffer {
        &self.visible
    }

    /// The objects of `candidates` whose box passed in the last pass, in their order (after
    /// its submission completed).
    pub(super) fn passed_objects(&self, candidates: &[u32]) -> Result<Vec<u32>> {
        let bytes = self
            .visible
            .mapped()
            .ok_or_else(|| Error::Alloc("oracle-box flags are not mapped".into()))?;
        let passed = |o: u32| word_at(bytes, o as usize).is_some_and(|w| w != 0);
        Ok(candidates.iter().copied().filter(|&o| passed(o)).collect())
    }
}
