//! Draw commands in the culler's subtree order ([`coherent_cull::SubtreeOrder`]): one indexed
//! indirect command per object, written when the order changes, so that the objects of a
//! subtree drawn under one predicate cost one recorded multi-draw, not a command written per
//! object per frame.

use std::sync::Arc;

use ash::vk;
use gpu_allocator::MemoryLocation;

use super::{ObjectDraw, DRAW_BYTES};
use crate::error::Result;
use crate::gpu::{Buffer, GpuContext};

/// Runs shorter than this go with the frame's other scattered objects into one multi-draw
/// written for the frame.
pub(super) const MIN_RUN: usize = 4;

/// The commands, the order they are in, and where each object's command lies.
#[derive(Default)]
pub(super) struct OrderedDraws {
    /// Objects in command order.
    order: Vec<u32>,
    /// Per object id: its command's index (`u32::MAX`: none).
    position: Vec<u32>,
    /// One `VkDrawIndexedIndirectCommand` per entry of `order` (host-visible).
    buffer: Option<Buffer>,
    /// Buffers replaced in this frame, freed when the next frame starts (every frame has
    /// completed on the device by then).
    retired: Vec<Buffer>,
}

/// A piece of a conditional draw: `len` objects from `objects[start..]` whose commands lie at
/// `position..position + len` of the buffer, or (`position` None) one object to write.
pub(super) struct Piece {
    pub start: usize,
    pub len: usize,
    pub position: Option<u32>,
}

/// The command that draws `draw` as object `object` (its index as `first_instance`).
pub(super) fn command_bytes(object: u32, draw: &ObjectDraw) -> [u8; DRAW_BYTES] {
    let words = [
        draw.index_count,
        1,
        draw.first_index,
        draw.vertex_offset as u32,
        object,
    ];
    let mut out = [0; DRAW_BYTES];
    for (bytes, word) in out.chunks_exact_mut(4).zip(words) {
        bytes.copy_from_slice(&word.to_ne_bytes());
    }
    out
}

impl OrderedDraws {
    /// The command buffer (None until an order was set).
    pub(super) fn buffer(&self) -> Option<&Buffer> {
        self.buffer.as_ref()
    }

    /// Keeps the commands of `order` (object ids into `draws`); nothing to do when it is the
    /// order already held. Ids the renderer has no object for are refused.
    pub(super) fn set(
        &mut self,
        ctx: &Arc<GpuContext>,
        order: &[u32],
        draws: &[ObjectDraw],
    ) -> Result<()> {
        if self.buffer.is_some() && order == self.order.as_slice() {
            return Ok(());
        }
        let mut bytes = Vec::with_capacity(order.len() * DRAW_BYTES);
        let mut position = vec![u32::MAX; draws.len()];
        for (p, &o) in order.iter().enumerate() {
            let draw = draws.get(o as usize).ok_or_else(|| {
                crate::error::Error::Input(format!(
                    "draw order names object {o} (scene has {})",
                    draws.len()
                ))
            })?;
            bytes.extend_from_slice(&command_bytes(o, draw));
            position[o as usize] = p as u32;
        }
        let size = (bytes.len().max(DRAW_BYTES)) as u64;
        let mut buffer = Buffer::new(
            ctx,
            "ordered draws",
            size,
            vk::BufferUsageFlags::INDIRECT_BUFFER,
            MemoryLocation::CpuToGpu,
        )?;
        buffer.write(0, &bytes)?;
        if let Some(old) = self.buffer.replace(buffer) {
            self.retired.push(old);
        }
        self.order = order.to_vec();
        self.position = position;
        Ok(())
    }

    /// Object `object` now draws `draw` (between frames): rewrites its command.
    pub(super) fn update(&mut self, object: u32, draw: &ObjectDraw) -> Result<()> {
        let Some(&p) = self.position.get(object as usize) else {
            return Ok(());
        };
        let Some(buffer) = self.buffer.as_mut() else {
            return Ok(());
        };
        if p == u32::MAX {
            return Ok(());
        }
        buffer.write(p as usize * DRAW_BYTES, &command_bytes(object, draw))
    }

    /// A new frame: the buffers replaced before it are no longer used.
    pub(super) fn begin_frame(&mut self) {
        self.retired.clear();
    }

    /// Cuts `objects` into runs of consecutive commands (at least [`MIN_RUN`] long, at most
    /// `max_count`) and single objects, in order, into `out`.
    pub(super) fn pieces(&self, objects: &[u32], max_count: usize, out: &mut Vec<Piece>) {
        out.clear();
        let pos = |o: u32| self.position.get(o as usize).copied().unwrap_or(u32::MAX);
        let mut i = 0;
        while i < objects.len() {
            let first = pos(objects[i]);
            let mut j = i + 1;
            if first != u32::MAX && self.buffer.is_some() {
                while j < objects.len()
                    && j - i < max_count
                    && pos(objects[j]) == first + (j - i) as u32
                {
                    j += 1;
                }
            }
            if j - i >= MIN_RUN {
                out.push(Piece {
                    start: i,
                    len: j - i,
                    position: Some(first),
                });
            } else {
                for k in i..j {
                    out.push(Piece {
                        start: k,
                        len: 1,
                        position: None,
                    });
                }
            }
            i = j;
        }
    }
}
