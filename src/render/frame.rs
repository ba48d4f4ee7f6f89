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
}

impl FrameResult {
    /// Converts to a report row (`repeat`: which run of a repeated walk).
    pub fn record(&self, algorithm: &str, frame: u32, repeat: u32) -> crate::report::FrameRecord {
        crate::report::FrameRecord {
            algorithm: algorithm.to_string(),
            frame,
            repeat,
            frame_ms: self.frame_ms,
            gpu_ms: self.gpu_ms,
            stall_ms: self.stall_ms,
            queries: self.counts.queries_begun,
            wasted_queries: self.counts.queries_visible,
            state_changes: self.counts.state_changes,
            pipeline_binds: self.counts.pipeline_binds,
            draw_calls: self.counts.draw_calls,
            object_draws: self.counts.object_draws + self.counts.indirect_objects,
            query_draws: self.counts.query_draws,
            triangles: self.counts.render_triangles + self.counts.indirect_triangles,
            // Objects really drawn: a draw under a false predicate drew nothing.
            objects: self.counts.object_draws - self.counts.predicated_calls
                + self.counts.predicated_objects_taken
                + self.counts.indirect_objects,
            submits: self.counts.submits,
            missed_objects: self.check.map(|c| c.missed_objects),
            missed_pixels: self.check.map(|c| c.missed_pixels),
            mover_draws: None,
            predicated_draws: self.counts.predicated_objects,
            predicated_taken: self.counts.predicated_objects_taken,
            predicate_resolves: self.counts.predicate_resolves,
        }
    }
}
