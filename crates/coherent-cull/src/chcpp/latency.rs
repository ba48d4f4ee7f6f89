//! The latency modes ([`Latency`]) as policies handed to the traversal: each mode is one object
//! that Algorithm 1 asks, at its decision points, when results are read and how they are
//! applied. The paper's mode ([`Latency::InFrame`]) reads them in the frame as they return;
//! [`Latency::NextFrame`] and [`Latency::NextFrameConservative`] issue the queries as CHC++ does
//! but read them after the frame (`k` frames later with frames in flight, `in_flight.rs`), and
//! their results decide the frames to come; [`Latency::Predicated`] is in `predicated.rs`.

use super::predicated::Predicated;
use super::{Chcpp, ChcppParams, Pending, QueryKind};
use crate::bvh::ObjectBvh;
use crate::error::Result;
use crate::{CullStats, Latency, OcclusionBackend, View};

/// The policy of `latency`.
pub(super) fn mode(latency: Latency) -> &'static dyn LatencyMode {
    match latency {
        Latency::InFrame => &InFrame,
        Latency::NextFrame => &NextFrame,
        Latency::NextFrameConservative => &NextFrameConservative,
        Latency::Predicated => &Predicated,
    }
}

/// When the traversal's query results are read and how they are applied: asked by the
/// traversal at its decision points. The defaults are those of a mode that reads the results
/// after the frame and opens nothing by itself.
pub(super) trait LatencyMode: Sync {
    /// The mode's name in the public API.
    fn latency(&self) -> Latency;

    /// Whether results are read inside the frame: Algorithm 1 runs until the query queue is
    /// empty too, handles results as they return, waits when it has nothing else to do, and
    /// submits every batch so that its results can come back. Otherwise the frame is one
    /// submission and its results are read after it.
    fn reads_in_frame(&self) -> bool {
        false
    }

    /// Refuses a backend the mode cannot run on.
    fn check_backend(&self, _backend: &dyn OcclusionBackend) -> Result<()> {
        Ok(())
    }

    /// A frame starts (the per-node state fits the hierarchy): fits the mode's own data to it.
    fn begin_frame(&self, _c: &mut Chcpp, _bvh: &ObjectBvh) {}

    /// A node in the frustum that was not visible last frame: whether the mode opens it itself
    /// (draws it, or visits its children) instead of leaving it to the query rule.
    fn opens_previously_invisible(
        &self,
        _c: &mut Chcpp,
        _bvh: &ObjectBvh,
        _node: u32,
        _eye: glam::Vec3,
        _stats: &mut CullStats,
    ) -> bool {
        false
    }

    /// A previously invisible node about to be queried: whether it is opened instead (its
    /// children queried), because a visible answer would cost too much.
    fn opens_instead_of_query(&self, _c: &Chcpp, _bvh: &ObjectBvh, _node: u32) -> bool {
        false
    }

    /// Whether the i-queue goes out once, after the traversal, so that queries always wait
    /// in the queues (batching or not).
    fn issues_after_traversal(&self) -> bool {
        false
    }

    /// The most objects a multiquery may put at stake in expectation, if the mode limits it.
    fn multiquery_objects(&self, _params: &ChcppParams) -> Option<f32> {
        None
    }

    /// The traversal queue ran dry: issues what the queues hold.
    fn issue_remaining_queries(
        &self,
        c: &mut Chcpp,
        bvh: &ObjectBvh,
        _view: &View,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        c.issue_remaining_queries(bvh, backend, stats)
    }

    /// Applies the result of `q` (`visible`: it counted more than the pixel threshold).
    #[allow(clippy::too_many_arguments)]
    fn apply_result(
        &self,
        c: &mut Chcpp,
        bvh: &ObjectBvh,
        q: Pending,
        visible: bool,
        _eye: glam::Vec3,
        _backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        c.handle_late_result(bvh, q, visible, stats);
        Ok(())
    }

    /// The end of the frame, its last queries issued: submits it and reads back (or keeps for
    /// a later frame) its queries.
    fn read_back(
        &self,
        c: &mut Chcpp,
        bvh: &ObjectBvh,
        eye: glam::Vec3,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        c.read_after_frame(bvh, eye, backend, stats)
    }
}

/// The paper's mode: a frame is a chain of submissions, results are read as they return and
/// a previously invisible node is traversed in the same frame once its query says visible.
struct InFrame;

impl LatencyMode for InFrame {
    fn latency(&self) -> Latency {
        Latency::InFrame
    }

    fn reads_in_frame(&self) -> bool {
        true
    }

    fn apply_result(
        &self,
        c: &mut Chcpp,
        bvh: &ObjectBvh,
        q: Pending,
        visible: bool,
        eye: glam::Vec3,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        c.apply_result_in_frame(bvh, q, visible, eye, backend, stats)
    }

    /// Waits for the device and reads back every query.
    fn read_back(
        &self,
        c: &mut Chcpp,
        bvh: &ObjectBvh,
        eye: glam::Vec3,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        backend.finish()?;
        while let Some(q) = c.query_queue.pop_front() {
            let pixels = backend.wait_query(q.id)?;
            c.handle_returned_query(bvh, q, pixels, eye, backend, stats)?;
        }
        Ok(())
    }
}

/// One submission per frame, results read after it: nodes use their last known visibility.
struct NextFrame;

impl LatencyMode for NextFrame {
    fn latency(&self) -> Latency {
        Latency::NextFrame
    }
}

/// As [`NextFrame`], but a node without a recent result is drawn rather than assumed
/// invisible.
struct NextFrameConservative;

impl LatencyMode for NextFrameConservative {
    fn latency(&self) -> Latency {
        Latency::NextFrameConservative
    }

    fn opens_previously_invisible(
        &self,
        c: &mut Chcpp,
        bvh: &ObjectBvh,
        node: u32,
        eye: glam::Vec3,
        stats: &mut CullStats,
    ) -> bool {
        let stale = c.stale(node);
        if stale {
            c.traverse_conservatively(bvh, node, eye, stats);
        }
        stale
    }
}

/// What the modes that read results after the frame share.
impl Chcpp {
    /// The frame's end when results are read after it: with `k > 1` frames in flight, submits
    /// without waiting and keeps the queries for frame N+k; else finishes the frame and reads
    /// every result that is back, never waiting (a result not back yet leaves the last known
    /// state).
    pub(super) fn read_after_frame(
        &mut self,
        bvh: &ObjectBvh,
        eye: glam::Vec3,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        if self.reads_frames_later() {
            return self.submit_frame_in_flight(bvh, backend);
        }
        backend.finish()?;
        while let Some(q) = self.query_queue.pop_front() {
            if let Some(pixels) = backend.query_result(q.id)? {
                self.handle_returned_query(bvh, q, pixels, eye, backend, stats)?;
            }
        }
        Ok(())
    }

    /// In the conservative mode, whether a node's last known state is too old to trust (no
    /// query result for it last frame: it entered the frustum, or its parent was closed).
    fn stale(&mut self, node: u32) -> bool {
        if self.result_frame.len() != self.state.len() {
            self.result_frame = vec![0; self.state.len()];
        }
        let r = self.result_frame[node as usize];
        r == 0 || r + 1 < self.frame
    }

    /// Conservative mode: a node without a recent result is drawn rather than assumed
    /// invisible; a leaf is queried at once (through the v-queue) so its state is fresh next
    /// frame.
    fn traverse_conservatively(
        &mut self,
        bvh: &ObjectBvh,
        node: u32,
        eye: glam::Vec3,
        stats: &mut CullStats,
    ) {
        self.traverse_node(bvh, node, eye, stats);
        let interval = self.visible_interval();
        let s = &mut self.state[node as usize];
        s.last_visited = self.frame;
        s.tested = true;
        if bvh.nodes[node as usize].is_leaf() {
            s.next_query = self.frame + interval;
            self.v_queue.push(node);
        }
    }

    /// A result read after the frame: visible opens the node's whole subtree next frame (its
    /// descendants have no state of their own yet; a failed multiquery opens every node of
    /// it), invisible closes the node.
    fn handle_late_result(
        &mut self,
        bvh: &ObjectBvh,
        q: Pending,
        visible: bool,
        stats: &mut CullStats,
    ) {
        if self.result_frame.len() != self.state.len() {
            self.result_frame = vec![0; self.state.len()];
        }
        let nodes = q.first as usize..(q.first + q.count) as usize;
        for i in nodes {
            let node = self.query_nodes[i];
            self.result_frame[node as usize] = self.frame;
            if !visible {
                self.state[node as usize].visible = false;
                if q.kind == QueryKind::Invisible {
                    stats.query_culled += 1;
                }
            } else if q.kind == QueryKind::Invisible {
                // Pull up first: it stops at a node already visible in this frame.
                self.pull_up_visibility(bvh, node);
                self.open_subtree(bvh, node);
            } else {
                self.pull_up_visibility(bvh, node);
            }
        }
        if visible && q.count > 1 {
            stats.failed_multiqueries += 1;
        }
    }

    /// Marks `node` and its descendants visible in this frame, so the next frame opens them
    /// all; their leaves are re-tested in that next frame (their results close the hidden ones
    /// one frame later), so opening a large subtree costs its draws for two frames only.
    fn open_subtree(&mut self, bvh: &ObjectBvh, node: u32) {
        let mut stack = vec![node];
        while let Some(n) = stack.pop() {
            let s = &mut self.state[n as usize];
            s.visible = true;
            s.last_visited = self.frame;
            s.last_visible = self.frame;
            s.tested = true;
            let b = &bvh.nodes[n as usize];
            if b.is_leaf() {
                s.next_query = self.frame + 1;
            } else {
                stack.extend_from_slice(&b.children);
            }
        }
    }
}
