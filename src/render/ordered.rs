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
    /// Triangles drawn by each command (for the counts).
    triangles: RunTriangles,
    /// One `VkDrawIndexedIndirectCommand` per entry of `order` (host-visible).
    buffer: Option<Buffer>,
    /// Buffers replaced in this frame, freed when the next frame starts (every frame has
    /// completed on the device by then).
    retired: Vec<Buffer>,
    /// Counts the buffers made, so that a descriptor set naming one can tell it is current
    /// (a handle may be reused after its buffer was freed).
    generation: u64,
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

    /// The command buffer with its generation (which changes whenever the buffer does).
    pub(super) fn buffer_generation(&self) -> Option<(&Buffer, u64)> {
        self.buffer.as_ref().map(|b| (b, self.generation))
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
        let mut triangles = Vec::with_capacity(order.len());
        for (p, &o) in order.iter().enumerate() {
            let draw = draws.get(o as usize).ok_or_else(|| {
                crate::error::Error::Input(format!(
                    "draw order names object {o} (scene has {})",
                    draws.len()
                ))
            })?;
            bytes.extend_from_slice(&command_bytes(o, draw));
            position[o as usize] = p as u32;
            triangles.push(draw.index_count / 3);
        }
        let size = (bytes.len().max(DRAW_BYTES)) as u64;
        let mut buffer = Buffer::new(
            ctx,
            "ordered draws",
            size,
            // Storage: the predicated mode's part draws are gathered from it on the device.
            vk::BufferUsageFlags::INDIRECT_BUFFER | vk::BufferUsageFlags::STORAGE_BUFFER,
            MemoryLocation::CpuToGpu,
        )?;
        buffer.write(0, &bytes)?;
        if let Some(old) = self.buffer.replace(buffer) {
            self.retired.push(old);
        }
        self.generation += 1;
        self.order = order.to_vec();
        self.position = position;
        self.triangles.set(triangles);
        Ok(())
    }

    /// The objects in command order.
    pub(super) fn order(&self) -> &[u32] {
        &self.order
    }

    /// Whether the commands follow `order` (checked by length: a draw order handed back
    /// with ranges is the one last set, so a different length means another order).
    pub(super) fn holds(&self, order: &[u32]) -> bool {
        self.buffer.is_some() && order.len() == self.order.len()
    }

    /// Triangles drawn by the commands `position..position + len`.
    pub(super) fn run_triangles(&mut self, position: u32, len: usize) -> u64 {
        self.triangles.sum(position as usize, len)
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
        self.triangles.update(p as usize, draw.index_count / 3);
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

/// Triangles per command in command order, summed over a run of commands with two reads (the
/// objects of a run are not looked up one by one: at x16 the city draws 100,000 objects a
/// frame under predicates).
#[derive(Default)]
struct RunTriangles {
    per_command: Vec<u32>,
    /// Triangles of the commands before each index (`per_command.len() + 1` entries).
    prefix: Vec<u64>,
    /// Whether `prefix` must be rebuilt (after `set`, or an update that changed a count).
    stale: bool,
}

impl RunTriangles {
    fn set(&mut self, per_command: Vec<u32>) {
        self.per_command = per_command;
        self.stale = true;
    }

    fn update(&mut self, position: usize, triangles: u32) {
        if let Some(t) = self.per_command.get_mut(position) {
            if *t != triangles {
                *t = triangles;
                self.stale = true;
            }
        }
    }

    /// Triangles of the commands `position..position + len` (clipped to the commands).
    fn sum(&mut self, position: usize, len: usize) -> u64 {
        if self.stale || self.prefix.is_empty() {
            self.prefix.clear();
            self.prefix.push(0);
            let mut sum = 0;
            for &t in &self.per_command {
                sum += u64::from(t);
                self.prefix.push(sum);
            }
            self.stale = false;
        }
        let start = position.min(self.per_command.len());
        let end = start.saturating_add(len).min(self.per_command.len());
        self.prefix[end] - self.prefix[start]
    }
}

#[cfg(test)]
mod tests {
    use super::RunTriangles;

    #[test]
    fn run_triangles_sum_runs_and_follow_updates() {
        let mut t = RunTriangles::default();
        assert_eq!(t.sum(0, 3), 0);
        t.set(vec![1, 2, 3, 4]);
        assert_eq!(t.sum(0, 4), 10);
        assert_eq!(t.sum(1, 2), 5);
        assert_eq!(t.sum(3, 9), 4, "clipped to the commands");
        t.update(1, 20);
        assert_eq!(t.sum(0, 2), 21);
        t.update(9, 5);
        assert_eq!(t.sum(0, 4), 28, "an update past the end changes nothing");
    }
}
