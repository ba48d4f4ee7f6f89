//! The query rule handed to the traversal: which nodes get an occlusion query. CHC and CHC++
//! query every node on the invisible cut and a visible leaf when its query interval is due
//! ([`PaperRule`]); NOHC asks its cost model ([`NohcRule`], see `nohc.rs`) at the same two
//! decision points, and learns from the results read in the frame.

use glam::Mat4;

use crate::bvh::ObjectBvh;
use crate::nohc::NohcRule;

/// Which nodes the traversal queries. The defaults are the paper's rules.
pub(super) trait QueryRule: Send + Sync {
    /// Start of a frame seen through `view_proj`.
    fn begin_frame(&mut self, _bvh: &ObjectBvh, _view_proj: Mat4) {}

    /// Whether a node in the frustum that was invisible last frame (or is new) is queried in
    /// `frame`; if not, the traversal opens it as if it were visible (conservative).
    fn query_invisible(&mut self, _bvh: &ObjectBvh, _node: u32, _frame: u64) -> bool {
        true
    }

    /// Whether a visible leaf drawn in `frame` is queried for the frames to come;
    /// `interval_due`: its query interval (CHC++'s randomized one) has run out.
    fn query_visible_leaf(
        &mut self,
        _bvh: &ObjectBvh,
        _node: u32,
        _frame: u64,
        interval_due: bool,
    ) -> bool {
        interval_due
    }

    /// A result of `node` read in the frame.
    fn record(&mut self, _node: u32, _occluded: bool) {}

    /// Forgets what was learnt.
    fn reset(&mut self) {}

    /// The NOHC rule, when this is it.
    fn nohc(&self) -> Option<&NohcRule> {
        None
    }
}

/// CHC's and CHC++'s rule: query the invisible cut, and visible leaves when due.
pub(super) struct PaperRule;

impl QueryRule for PaperRule {}

/// NOHC: query where the cost model says the query pays.
impl QueryRule for NohcRule {
    fn begin_frame(&mut self, bvh: &ObjectBvh, view_proj: Mat4) {
        NohcRule::begin_frame(self, bvh, view_proj);
    }

    fn query_invisible(&mut self, bvh: &ObjectBvh, node: u32, frame: u64) -> bool {
        NohcRule::query_invisible(self, bvh, node, frame)
    }

    fn query_visible_leaf(
        &mut self,
        bvh: &ObjectBvh,
        node: u32,
        frame: u64,
        _interval_due: bool,
    ) -> bool {
        NohcRule::query_visible_leaf(self, bvh, node, frame)
    }

    fn record(&mut self, node: u32, occluded: bool) {
        NohcRule::record(self, node, occluded);
    }

    fn reset(&mut self) {
        NohcRule::reset(self);
    }

    fn nohc(&self) -> Option<&NohcRule> {
        Some(self)
    }
}
