//! CHC++ (Mattausch, Bittner, Wimmer 2008): coherent hierarchical culling with query batching
//! (i-queue, v-queue, render queue), randomized query intervals for visible leaves, multiqueries
//! and tight bounding volumes. Each part is a switch ([`ChcppParams`]); with all of them off and
//! a batch size of 1 the same traversal is the original CHC (Bittner et al. 2004), see `chc.rs`.
//!
//! This file is the paper's Algorithm 1 ([`Chcpp::cull_frame`]) followed by its steps in the
//! order they run. What differs between the algorithms and modes that share the traversal is
//! handed to it as two policies, which it consults at its decision points:
//! - the *query rule* (`rules.rs`) says which nodes get a query: CHC++'s rules (every node on
//!   the invisible cut; a visible leaf when its query interval is due), or NOHC's cost model;
//! - the *latency mode* (`latency.rs`, one policy per [`Latency`](crate::Latency)) says when
//!   results are read and how they are applied: in the frame as they return (the paper), after
//!   the frame (next-frame, conservative, with `k` frames in flight: `in_flight.rs`), or by the
//!   device under predicates (`predicated.rs`, with the argument why nothing visible is culled).
//!
//! The parts of CHC++: `queues.rs` (i-queue, v-queue, render queue, batches), `multiquery.rs`,
//! `tight.rs`, and `state.rs` (per-node state that follows the hierarchy through refits and
//! rebuilds); the parameters are in `params.rs`.

use std::collections::VecDeque;

use super::{CullStats, Culler, FrameInput, OcclusionBackend, QueryId, View};
use crate::bvh::{DistanceQueue, ObjectBvh};
use crate::error::Result;
use crate::rng::Rng;
use crate::Aabb;

mod in_flight;
mod latency;
mod multiquery;
mod params;
mod predicated;
mod queues;
mod rules;
mod state;
mod tight;

use latency::LatencyMode;
pub use params::{ChcppParams, SCREEN_SPLIT_GAIN};
use rules::QueryRule;

impl Culler for Chcpp {
    fn name(&self) -> &str {
        self.name
    }

    fn reads_tests_after_frame(&self) -> bool {
        self.mode.latency() == crate::Latency::Predicated
    }

    /// Algorithm 1 of the paper: while the traversal queue or the query queue is not empty,
    /// first handle the queries that have returned, then take the next node from the traversal
    /// queue; when the traversal queue runs dry, issue what the queues hold. A latency mode
    /// that reads its results after the frame leaves the query queue to the frame's end.
    fn cull_frame(
        &mut self,
        input: &FrameInput,
        backend: &mut dyn OcclusionBackend,
    ) -> Result<CullStats> {
        self.params.validate()?;
        let bvh = input.bvh;
        let view = View::new(&input.view);
        let eye = view.eye;
        self.frame_view = Some(view.clone());
        let mut stats = CullStats::default();
        self.mode.check_backend(backend)?;
        // With k frames in flight, a latency mode reads the queries of frame N-k first.
        self.read_frames_in_flight(bvh, backend, &mut stats)?;
        self.begin_frame(bvh, eye);
        self.eye = eye;
        self.rule.begin_frame(bvh, input.view.view_proj);
        // In a latency mode queries are read after the frame: only the traversal drives it.
        let in_frame = self.mode.reads_in_frame();
        while !self.traversal.is_empty() || (in_frame && !self.query_queue.is_empty()) {
            // 1. Process finished occlusion queries.
            if in_frame {
                self.process_finished_queries(bvh, eye, backend, &mut stats)?;
            }
            // 2. Hierarchical traversal.
            if let Some(node) = self.traversal.pop() {
                self.visit_node(input, &view, node, backend, &mut stats)?;
            }
            // 3. The traversal ran dry: issue what the queues hold.
            if self.traversal.is_empty() {
                let mode = self.mode;
                mode.issue_remaining_queries(self, bvh, &view, backend, &mut stats)?;
            }
        }
        self.end_frame(bvh, eye, backend, &mut stats)?;
        Ok(stats)
    }

    fn reset(&mut self) {
        self.state.clear();
        self.tight.clear();
        self.forget_frames_in_flight();
        self.rule.reset();
        self.structure = u64::MAX;
        self.rng = Rng::new(self.params.seed);
    }
}

/// The steps of [`Chcpp::cull_frame`], in the order the paper's pseudocode runs them.
impl Chcpp {
    /// Starts a frame: empty queues, the root in the traversal queue.
    fn begin_frame(&mut self, bvh: &ObjectBvh, eye: glam::Vec3) {
        self.prepare(bvh);
        let mode = self.mode;
        mode.begin_frame(self, bvh);
        self.frame += 1;
        self.traversal.clear();
        self.query_queue.clear();
        self.i_queue.clear();
        self.requery.clear();
        self.v_queue.clear();
        self.predicated.probes.clear();
        self.render_queue.clear();
        self.query_nodes.clear();
        self.unsubmitted = 0;
        self.traversal
            .push(0, bvh.nodes[0].bounds.distance_squared(eye));
    }

    /// Handles returned queries in order. While the traversal has work, stops at the first
    /// query that is not ready; when it has none, fills the wait with the v-queue's queries,
    /// and only then blocks on the query.
    fn process_finished_queries(
        &mut self,
        bvh: &ObjectBvh,
        eye: glam::Vec3,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        while let Some(front) = self.query_queue.front() {
            let id = front.id;
            let pixels = match backend.query_result(id)? {
                Some(p) => p,
                None if !self.traversal.is_empty() => break,
                None if !self.v_queue.is_empty() => {
                    let all = self.v_queue.len();
                    self.issue_v_queue(bvh, all, backend, stats)?;
                    continue;
                }
                None => {
                    self.flush_render_queue(backend)?;
                    stats.blocking_waits += 1;
                    backend.wait_query(id)?
                }
            };
            if let Some(q) = self.query_queue.pop_front() {
                self.handle_returned_query(bvh, q, pixels, eye, backend, stats)?;
            }
        }
        Ok(())
    }

    /// One node from the traversal queue: frustum test, then by its visibility last frame.
    fn visit_node(
        &mut self,
        input: &FrameInput,
        view: &View,
        node: u32,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        let bvh = input.bvh;
        stats.nodes_visited += 1;
        let bounds = &bvh.nodes[node as usize].bounds;
        let in_view = view.in_view(bounds);
        if !in_view {
            self.frustum_cull(node, stats);
        } else if view.eye_inside(bounds) {
            self.traverse_unqueryable(bvh, node, view.eye, stats);
        } else if !self.was_visible(node) {
            // The latency mode may open it itself (draw it, or visit its children).
            let mode = self.mode;
            if !mode.opens_previously_invisible(self, bvh, node, view.eye, stats) {
                self.query_previously_invisible(bvh, node, backend, stats)?;
            }
        } else {
            self.traverse_previously_visible(bvh, node, view.eye, backend, stats)?;
        }
        let s = &mut self.state[node as usize];
        if in_view {
            // Seen in the frustum: it enters no more (frustum_cull sets it otherwise).
            s.entering = false;
        }
        s.seen_epoch = bvh.epoch();
        Ok(())
    }

    /// A node outside the view frustum: invisible. Once it has been tested in the frustum it
    /// keeps ageing (`k` counts frames since it was last visible), so when it re-enters the
    /// frustum it is grouped by how long it has really been unseen; a node never tested yet
    /// has no evidence of occlusion and does not age.
    fn frustum_cull(&mut self, node: u32, stats: &mut CullStats) {
        stats.frustum_culled += 1;
        let s = &mut self.state[node as usize];
        s.visible = false;
        s.entering = true;
        s.last_visited = self.frame;
        if !s.tested {
            s.last_visible = self.frame;
        }
    }

    /// The eye is inside the node's box, so a query can't be trusted: treat it as visible.
    fn traverse_unqueryable(
        &mut self,
        bvh: &ObjectBvh,
        node: u32,
        eye: glam::Vec3,
        stats: &mut CullStats,
    ) {
        let was = self.was_visible(node);
        self.traverse_node(bvh, node, eye, stats);
        if bvh.nodes[node as usize].is_leaf() {
            if !was {
                self.start_interval(node);
            }
            self.pull_up_visibility(bvh, node);
        } else {
            self.state[node as usize].last_visited = self.frame;
        }
    }

    /// A previously invisible node goes to the i-queue, issued as a batch once it holds `b`
    /// nodes (unbatched: queried at once). It is traversed only when its query says visible.
    fn query_previously_invisible(
        &mut self,
        bvh: &ObjectBvh,
        node: u32,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        if !self.rule.query_invisible(bvh, node, self.frame) {
            // Not worth a query (NOHC): open it as if it were visible (conservative).
            self.state[node as usize].tested = true;
            let eye = self.eye;
            self.traverse_unqueryable(bvh, node, eye, stats);
            return Ok(());
        }
        let grown = bvh.grown_since(node, self.state[node as usize].seen_epoch);
        let s = &mut self.state[node as usize];
        if s.last_visited + 1 < self.frame || grown {
            s.watched_since = self.frame;
        }
        s.last_visited = self.frame;
        s.tested = true;
        if self.mode.opens_instead_of_query(self, bvh, node) {
            // The latency mode opens it (predicated: too many objects would wait on one
            // predicate); its children are queried instead.
            let eye = self.eye;
            self.traverse_node(bvh, node, eye, stats);
            return Ok(());
        }
        stats.invisible_nodes_tested += 1;
        if self.queues_queries() {
            self.i_queue.push(node);
            if self.i_queue_full() {
                self.issue_i_queue(bvh, backend, stats)?;
            }
            Ok(())
        } else {
            self.issue_unbatched(bvh, node, QueryKind::Invisible, backend, stats)
        }
    }

    /// A previously visible node is traversed without waiting; a leaf is rendered now and, if
    /// its query is due, queried for next frame (through the v-queue when batching).
    fn traverse_previously_visible(
        &mut self,
        bvh: &ObjectBvh,
        node: u32,
        eye: glam::Vec3,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        self.traverse_node(bvh, node, eye, stats);
        if !bvh.nodes[node as usize].is_leaf() {
            self.state[node as usize].last_visited = self.frame;
            return Ok(());
        }
        let interval_due = self.query_reasonable(node);
        let due = self
            .rule
            .query_visible_leaf(bvh, node, self.frame, interval_due);
        self.pull_up_visibility(bvh, node);
        if due {
            self.state[node as usize].next_query = self.frame + self.visible_interval();
            if self.queues_queries() {
                self.v_queue.push(node);
            } else {
                self.issue_unbatched(bvh, node, QueryKind::Visible, backend, stats)?;
            }
        }
        Ok(())
    }

    /// Opens a node: a leaf goes to the render queue, an interior node's children to the
    /// traversal queue. Its visibility is re-derived this frame (pull-up from its leaves).
    fn traverse_node(
        &mut self,
        bvh: &ObjectBvh,
        node: u32,
        eye: glam::Vec3,
        stats: &mut CullStats,
    ) {
        let n = &bvh.nodes[node as usize];
        if n.is_leaf() {
            let objects = bvh.objects(node);
            stats.objects_drawn += objects.len() as u32;
            self.render_queue.extend_from_slice(objects);
            for &o in objects {
                self.drawn[o as usize] = self.frame;
            }
        } else {
            self.state[node as usize].visible = false;
            for c in n.children {
                self.traversal
                    .push(c, bvh.nodes[c as usize].bounds.distance_squared(eye));
            }
        }
    }

    fn pull_up_visibility(&mut self, bvh: &ObjectBvh, mut node: u32) {
        loop {
            let s = &mut self.state[node as usize];
            if s.visible && s.last_visited == self.frame {
                break;
            }
            s.visible = true;
            s.last_visited = self.frame;
            s.last_visible = self.frame;
            let parent = bvh.nodes[node as usize].parent;
            if parent == u32::MAX {
                break;
            }
            node = parent;
        }
    }

    /// A query's result, applied as the latency mode says (in the frame: see
    /// [`Chcpp::apply_result_in_frame`]).
    fn handle_returned_query(
        &mut self,
        bvh: &ObjectBvh,
        q: Pending,
        pixels: u64,
        eye: glam::Vec3,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        let visible = pixels > self.params.pixel_threshold;
        if visible {
            stats.visible_results += 1;
        }
        // The query rule learns from every result, whenever the mode reads it (NOHC's history).
        for &n in &self.query_nodes[q.first as usize..(q.first + q.count) as usize] {
            self.rule.record(n, !visible);
        }
        let mode = self.mode;
        mode.apply_result(self, bvh, q, visible, eye, backend, stats)
    }

    /// A result read in the frame: a visible multiquery re-queues its nodes for single
    /// queries; a visible single query opens its node (previously invisible) and pulls
    /// visibility up; an invisible result marks every node of the query invisible.
    fn apply_result_in_frame(
        &mut self,
        bvh: &ObjectBvh,
        q: Pending,
        visible: bool,
        eye: glam::Vec3,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        let nodes = q.first as usize..(q.first + q.count) as usize;
        if visible && q.count > 1 {
            // A failed multiquery: each node is queried on its own in the next batch.
            stats.failed_multiqueries += 1;
            stats.requeried += q.count;
            self.requery.extend_from_slice(&self.query_nodes[nodes]);
            if self.i_queue_full() {
                self.issue_i_queue(bvh, backend, stats)?;
            }
            return Ok(());
        }
        if visible {
            let node = self.query_nodes[q.first as usize];
            if q.kind == QueryKind::Invisible {
                self.traverse_node(bvh, node, eye, stats);
                self.start_interval(node);
            }
            self.pull_up_visibility(bvh, node);
            return Ok(());
        }
        for &node in &self.query_nodes[nodes] {
            self.state[node as usize].visible = false;
        }
        if q.kind == QueryKind::Invisible {
            stats.query_culled += q.count;
        }
        Ok(())
    }

    /// The visible interval `n_av` of this culler's latency mode (at least 1).
    pub(super) fn visible_interval(&self) -> u64 {
        let n = match self.mode.latency() {
            crate::Latency::Predicated => self.params.predicated_visible_interval,
            _ => self.params.visible_interval,
        };
        n.max(1) as u64
    }

    /// A node that just turned visible gets its first re-test after a random delay.
    fn start_interval(&mut self, node: u32) {
        let n = self.visible_interval();
        let delay = if self.params.randomized_interval && n > 1 {
            1 + self.rng.below(n as u32) as u64
        } else {
            1
        };
        self.state[node as usize].next_query = self.frame + delay;
    }

    fn query_reasonable(&self, node: u32) -> bool {
        self.frame >= self.state[node as usize].next_query
    }

    fn was_visible(&self, node: u32) -> bool {
        let s = &self.state[node as usize];
        s.visible && s.last_visited + 1 == self.frame
    }

    /// Ends a frame: render what is left, issue the leftover visible-leaf queries (their
    /// results are for the next frame), then submit and read back as the latency mode says
    /// (in the frame: wait for the device and read back every query).
    fn end_frame(
        &mut self,
        bvh: &ObjectBvh,
        eye: glam::Vec3,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        self.flush_render_queue(backend)?;
        let rest = self.v_queue.len();
        self.issue_v_queue(bvh, rest, backend, stats)?;
        let mode = self.mode;
        mode.read_back(self, bvh, eye, backend, stats)
    }
}

/// CHC++ (or, configured with [`ChcppParams::chc`], CHC).
pub struct Chcpp {
    name: &'static str,
    params: ChcppParams,
    state: Vec<NodeState>,
    /// Tight bounding volume of each node as descendant node ids (their current boxes are
    /// queried, so refits keep it covering the subtree; recomputed when nodes are added).
    tight: Vec<Option<Vec<u32>>>,
    /// The hierarchy's structure and rebuild count that `state` and `tight` were made for.
    structure: u64,
    rebuilds: u32,
    /// Per object id: the last frame it was drawn (carries visibility across rebuilds).
    drawn: Vec<u64>,
    frame: u64,
    rng: Rng,
    traversal: DistanceQueue,
    query_queue: VecDeque<Pending>,
    i_queue: Vec<u32>,
    /// Nodes of failed multiqueries, queried one by one in the next i-queue batch.
    requery: Vec<u32>,
    v_queue: Vec<u32>,
    render_queue: Vec<u32>,
    unsubmitted: usize,
    boxes: Vec<Aabb>,
    /// The nodes of this frame's queries, in issue order (a query's nodes are contiguous).
    query_nodes: Vec<u32>,
    /// A batch being issued (taken out of the queues so they can refill meanwhile).
    batch: Vec<u32>,
    /// A batch's nodes with their probability of staying invisible, for sorting it.
    batch_order: Vec<(f32, u32)>,
    /// Which nodes are queried: CHC++'s rules, or NOHC's cost rule (`rules.rs`).
    rule: Box<dyn QueryRule>,
    /// The eye of the current frame.
    eye: glam::Vec3,
    /// The view of the current frame (the screen split of query boxes).
    frame_view: Option<View>,
    /// When query results are read and how they are applied: the latency mode's policy
    /// (`latency.rs`, see [`Latency`](crate::Latency)).
    mode: &'static dyn LatencyMode,
    /// Per node, the last frame a query result gave its state (for the conservative mode).
    result_frame: Vec<u64>,
    /// Latency modes: the frames between issuing a query and reading it (`k`, default 1).
    frames_in_flight: u32,
    /// Latency modes with `k > 1`: the queries of the frames still in flight, oldest first.
    in_flight: in_flight::InFlightQueries,
    /// Predicated mode: scratch for the objects of one conditional draw and a subtree walk.
    predicated: predicated::Scratch,
}

/// Per-node temporal state, kept beside the hierarchy.
#[derive(Clone, Copy, Debug, Default)]
struct NodeState {
    visible: bool,
    last_visited: u64,
    /// Frame at which a visible leaf is queried next.
    next_query: u64,
    /// The last frame the node was visible (0: never). `k`, the frames it has been invisible
    /// (for the multiquery probability), counts from here, frustum-culled frames included.
    last_visible: u64,
    /// The first frame of the node's current unbroken run of visits: a node not visited in
    /// the previous frame (its parent was closed: culled by a query, or just opened now) or
    /// whose box grew starts a new run, since nothing is known of its visibility in between.
    /// `k` never counts frames before it, so a node first seen invisible a frame ago is one
    /// frame old, not as old as its last visibility (or the walk, if it never was visible).
    watched_since: u64,
    /// The node has been tested inside the frustum at least once. Until then, frames outside
    /// the frustum are no evidence of occlusion and do not age it.
    tested: bool,
    /// The hierarchy's epoch when the node was last visited: if its box has grown since, what
    /// was learnt about it then is about other space (see the motion rule in `culling`).
    seen_epoch: u64,
    /// Predicated mode: an interior node whose own query said visible stays open until this
    /// frame.
    open_until: u64,
    /// The node lay outside the frustum when last visited, or it is the child of a node
    /// opened as entering in this frame: it enters the view now (predicated mode).
    entering: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum QueryKind {
    /// For previously invisible nodes: the result decides traversal in this frame.
    Invisible,
    /// For previously visible leaves: the result matters next frame.
    Visible,
    /// Predicated mode: whether a node held open still shows (it stays open) or not (it
    /// closes); nothing is drawn under it.
    Probe,
    /// Predicated mode: a part of a queried node, queried under the node's predicate; its
    /// objects are drawn under its own.
    Part,
}

/// An issued query: its nodes are `query_nodes[first..first + count]`.
#[derive(Clone, Copy)]
struct Pending {
    id: QueryId,
    first: u32,
    count: u32,
    kind: QueryKind,
    /// Predicated mode: the query's nodes were split into parts queried under its predicate
    /// (their results, not this one's, say which parts are visible).
    split: bool,
}

#[cfg(test)]
mod tests;
