//! What the renderer's object draws drew: the log `walk --check` compares with the exact ID
//! pass, and the draws of moving objects. Kept beside the recorder, which records and counts
//! commands and knows nothing of objects.

use std::ops::Range;

use crate::gpu::CommandCounts;

/// One object draw call under a predicate, counted once the predicate is read back.
#[derive(Clone, Copy)]
struct PredicatedCall {
    /// The query whose predicate the call is under.
    query: u32,
    /// Objects it drew (with the log on, the next that many of [`DrawLog::predicated`]).
    objects: u32,
    /// How many of those are movers.
    movers: u32,
    /// Their triangles.
    triangles: u64,
}

/// The objects one frame's object draws drew (with the log on), and its mover draws.
#[derive(Default)]
pub(super) struct DrawLog {
    /// Whether draws are logged (`walk --check`).
    on: bool,
    /// Objects drawn unconditionally this frame, in draw order (with repeats).
    drawn: Vec<u32>,
    /// With the log on: objects drawn under a predicate this frame, call by call; they join
    /// `drawn` once the predicates are read back, if theirs was true.
    predicated: Vec<u32>,
    /// The calls under a predicate this frame (log on or off).
    predicated_calls: Vec<PredicatedCall>,
    /// Objects whose draws count as mover draws.
    movers: Range<u32>,
    /// Unconditional draws of those this frame (draws under a predicate count once it is
    /// read back, if it was true).
    mover_draws: u32,
    /// Where the objects drawn under true predicates begin in `drawn`, once
    /// [`DrawLog::end_frame`] added them (`None`: all of `drawn` was drawn unconditionally).
    predicated_from: Option<usize>,
}

impl DrawLog {
    /// Turns the log on or off (and forgets it).
    pub(super) fn set_logging(&mut self, on: bool) {
        self.on = on;
        self.begin_frame();
    }

    /// Counts draws of `objects` as mover draws from now on.
    pub(super) fn set_movers(&mut self, objects: Range<u32>) {
        self.movers = objects;
    }

    /// The objects counted as movers.
    pub(super) fn movers(&self) -> Range<u32> {
        self.movers.clone()
    }

    /// A new frame: forgets the last one (keeps the capacity).
    pub(super) fn begin_frame(&mut self) {
        self.drawn.clear();
        self.predicated.clear();
        self.predicated_calls.clear();
        self.mover_draws = 0;
        self.predicated_from = None;
    }

    /// `objects` (`triangles` in all) were drawn in render state, under `predicate`'s query
    /// if given.
    pub(super) fn drew(&mut self, objects: &[u32], predicate: Option<u32>, triangles: u64) {
        let movers = if self.movers.is_empty() {
            0
        } else {
            objects.iter().filter(|o| self.movers.contains(o)).count() as u32
        };
        match predicate {
            Some(query) => {
                self.predicated_calls.push(PredicatedCall {
                    query,
                    objects: objects.len() as u32,
                    movers,
                    triangles,
                });
                if self.on {
                    self.predicated.extend_from_slice(objects);
                }
            }
            None => {
                self.mover_draws += movers;
                if self.on {
                    self.drawn.extend_from_slice(objects);
                }
            }
        }
    }

    /// After the frame, with the predicates read back (`taken(query)`): adds the mover draws
    /// (those under a predicate only where it was true: a draw a predicate skipped did not
    /// draw), the objects drawn under true predicates and the triangles of the draws under
    /// false ones to `counts`, and the objects drawn to the log.
    pub(super) fn end_frame(&mut self, counts: &mut CommandCounts, taken: impl Fn(u32) -> bool) {
        counts.mover_draws += self.mover_draws;
        self.mover_draws = 0;
        if self.on && !self.predicated_calls.is_empty() {
            self.predicated_from.get_or_insert(self.drawn.len());
        }
        let mut first = 0;
        for c in &self.predicated_calls {
            let call = first..first + c.objects as usize;
            first = call.end;
            if !taken(c.query) {
                counts.predicated_triangles_skipped += c.triangles;
                continue;
            }
            counts.predicated_objects_taken += c.objects;
            counts.mover_draws += c.movers;
            if self.on {
                self.drawn.extend_from_slice(&self.predicated[call]);
            }
        }
        self.predicated.clear();
        self.predicated_calls.clear();
    }

    /// The objects drawn (with the log on), in draw order; those under predicates follow the
    /// unconditional ones once [`DrawLog::end_frame`] read their predicates.
    pub(super) fn drawn(&self) -> &[u32] {
        &self.drawn
    }

    /// How many of [`DrawLog::drawn`]'s entries, from the start, were drawn unconditionally
    /// (the rest under true predicates).
    pub(super) fn unconditional(&self) -> usize {
        self.predicated_from
            .unwrap_or(self.drawn.len())
            .min(self.drawn.len())
    }
}
