//! What one rendered frame reports.

use crate::culling::CullStats;
use crate::gpu::CommandCounts;

/// The measured result of one frame.
#[derive(Clone, Debug, Default)]
pub struct FrameResult {
    /// Wall clock from the start of traversal until the last submission completed.
    pub frame_ms: f64,
    /// Sum of the segments' GPU time (timestamps).
    pub gpu_ms: f64,
    /// Time spent blocked on query results inside the frame (every wait for a segment; the
    /// final wait for the frame's completion is not included).
    pub stall_ms: f64,
    /// The CPU's part of the frame: traversal, recording and submission, from the start of
    /// traversal until the last submission, less `stall_ms`. What an engine's render thread
    /// would spend on the frame; on a CPU driver recording competes with rendering for cores.
    pub cpu_ms: f64,
    /// What the recorder counted.
    pub counts: CommandCounts,
    /// The algorithm's own bookkeeping.
    pub cull: CullStats,
    /// What the exactness check found, when it ran (`walk --check`).
    pub check: Option<Check>,
}

/// Exactness at object level: what an algorithm drew, against the exact ID pass of the same
/// camera. An object *owns a pixel* when the ID pass shows it there; it is *missed* when it
/// owns a pixel and the frame did not draw it (the recorder's log of object draws).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Check {
    /// Objects that own at least one pixel.
    pub visible_objects: u32,
    /// Visible objects that were not drawn.
    pub missed_objects: u32,
    /// Pixels owned by missed objects.
    pub missed_pixels: u64,
    /// Drawn objects that own no pixel (hidden, or outside the view): the draws an exact
    /// visibility oracle would have saved.
    pub extra_objects: u32,
    /// Of `extra_objects`, those drawn only under true predicates (the predicated mode's
    /// objects under a node or part whose test passed), none of their draws unconditional:
    /// `extra_objects` less this are the unconditional draws that own no pixel (leaves last
    /// seen visible, or opened without a test).
    pub extra_predicated_objects: u32,
}
