//! The predicated latency mode of CHC and CHC++ ([`Latency::Predicated`]): exact culling with
//! one submission per frame and no CPU wait, through predicates the device evaluates itself
//! (on Vulkan, `VK_EXT_conditional_rendering`).
//!
//! # A frame
//!
//! 1. The traversal runs on the hierarchy's state as of the newest results the CPU has (those
//!    of frame N-k, read at the start of frame N). Previously visible leaves are drawn
//!    unconditionally and, when their query is due, queried for later frames (the v-queue).
//!    Previously invisible nodes go into the i-queue; no batch goes out during the traversal.
//!    A node whose box holds the eye (or reaches the near plane where the view is) is opened
//!    unconditionally, as in every mode.
//! 2. When the traversal is done, the render queue is drawn, then the i-queue is queried in one
//!    batch (multiqueries, tight bounds) together with the v-queue.
//! 3. The backend resolves the predicates ([`OcclusionBackend::resolve_predicates`]: on Vulkan
//!    one pass break, a copy and a barrier), and the objects under each i-queue query's nodes
//!    that lie in the frustum are drawn under that query's predicate
//!    ([`OcclusionBackend::draw_objects_if`]).
//! 4. The results are read `k` frames later only to update the hierarchy: a queried node that
//!    came back visible is opened `predicated_levels` levels deep (the nodes below are queried,
//!    and drawn under their own predicates, from then on), a failed multiquery's nodes lose their
//!    invisibility history (queried one by one next time), a visible leaf that came back hidden
//!    is queried (and drawn under a predicate) from the next frame on.
//!
//! # Why nothing visible is culled
//!
//! Every object in the frustum lies below exactly one node where the traversal stopped: (a) a
//! leaf opened unconditionally, whose objects are drawn; (b) a node whose box holds the eye,
//! opened unconditionally; or (c) an i-queue node. In case (c) the node's query draws boxes that
//! cover the object (its own box or its tight volume: this frame's boxes, so movers are covered
//! where they are now) against the depth of the frame's unconditional draws, which is depth
//! written by real geometry of this frame and only gets nearer as the frame goes on. If the
//! query counted no sample, every sample of the object's surface lies behind that depth and
//! owns no pixel of the final image; if it counted any, the object is drawn. A multiquery's
//! predicate covers all its nodes: they are drawn when any of them is visible. Nodes that enter
//! the frustum or the hierarchy have no visible history and are case (c). The boxes must be
//! rasterized conservatively (a depth bias towards the eye and a compare that passes on equal
//! depth): that is the backend's part. The CPU's results only steer which nodes land in which
//! case, so however old they are, the image is exact; they decide the cost.
//!
//! # What it costs
//!
//! One pass break per frame, and extra draws: an object under a true predicate is drawn even
//! when only another part of its node is visible, until the results come back and the node is
//! opened (`k` frames). [`CullStats::predicated_objects`] counts the objects sent under
//! predicates; the built-in renderer reads the predicates back after the frame to count those
//! the device really drew.

use super::latency::LatencyMode;
use super::{Chcpp, ChcppParams, Pending, QueryKind};
use crate::bvh::ObjectBvh;
use crate::error::Result;
use crate::{CullStats, Latency, OcclusionBackend, View};

/// The predicated mode's policy: the traversal's decision points as the steps above say.
pub(super) struct Predicated;

impl LatencyMode for Predicated {
    fn latency(&self) -> Latency {
        Latency::Predicated
    }

    fn check_backend(&self, backend: &dyn OcclusionBackend) -> Result<()> {
        if backend.supports_predicates() {
            Ok(())
        } else {
            Err(crate::predicates_unsupported())
        }
    }

    fn fit(&self, c: &mut Chcpp, bvh: &ObjectBvh) {
        c.predicated.count_objects(bvh);
    }

    /// A node held open: its children are visited.
    fn opens_previously_invisible(
        &self,
        c: &mut Chcpp,
        bvh: &ObjectBvh,
        node: u32,
        eye: glam::Vec3,
        stats: &mut CullStats,
    ) -> bool {
        let held = c.held_open(bvh, node);
        if held {
            c.traverse_held_open(bvh, node, eye, stats);
        }
        held
    }

    fn opens_instead_of_query(&self, c: &Chcpp, bvh: &ObjectBvh, node: u32) -> bool {
        c.over_predicate_budget(bvh, node)
    }

    /// Step 2: the i-queue goes out in one batch after the traversal.
    fn issues_after_traversal(&self) -> bool {
        true
    }

    fn multiquery_objects(&self, params: &ChcppParams) -> Option<f32> {
        Some(params.predicated_budget)
    }

    fn issue_remaining_queries(
        &self,
        c: &mut Chcpp,
        bvh: &ObjectBvh,
        view: &View,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        c.issue_predicated(bvh, view, backend, stats)
    }

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
        c.handle_predicated_result(bvh, q, visible, stats);
        Ok(())
    }
}

/// Scratch of the predicated mode, kept so that steady frames do not allocate.
#[derive(Default)]
pub(super) struct Scratch {
    /// The objects of one conditional draw.
    objects: Vec<u32>,
    /// A subtree walk: nodes, or nodes with their depth below the opened node.
    stack: Vec<(u32, u32)>,
    /// Nodes held open whose hold runs out: probed in this frame's query batch.
    pub(super) probes: Vec<u32>,
    /// Objects below each node.
    objects_below: Vec<u32>,
}

impl Scratch {
    /// The objects below `node` (0 before [`Scratch::count_objects`]).
    pub(super) fn objects_below(&self, node: u32) -> u32 {
        self.objects_below.get(node as usize).copied().unwrap_or(0)
    }

    /// Counts the objects below each node of `bvh` (after a change of its structure).
    pub(super) fn count_objects(&mut self, bvh: &ObjectBvh) {
        let mut order: Vec<u32> = (0..bvh.nodes.len() as u32).collect();
        order.sort_unstable_by_key(|&n| std::cmp::Reverse(bvh.nodes[n as usize].depth));
        self.objects_below = vec![0; bvh.nodes.len()];
        for n in order {
            let b = &bvh.nodes[n as usize];
            self.objects_below[n as usize] = if b.is_leaf() {
                b.object_count
            } else {
                b.children
                    .iter()
                    .map(|&c| self.objects_below.get(c as usize).copied().unwrap_or(0))
                    .sum()
            };
        }
    }

    /// Appends the objects of `node`'s subtree whose leaves lie in the frustum.
    fn collect(&mut self, bvh: &ObjectBvh, node: u32, view: &View) {
        self.stack.clear();
        self.stack.push((node, 0));
        while let Some((n, _)) = self.stack.pop() {
            let b = &bvh.nodes[n as usize];
            if !b.bounds.is_valid() || !view.frustum.intersects(&b.bounds) {
                continue;
            }
            if b.is_leaf() {
                self.objects.extend_from_slice(bvh.objects(n));
            } else {
                self.stack.extend(b.children.iter().map(|&c| (c, 0)));
            }
        }
    }
}

impl Chcpp {
    /// The traversal is done: draws the render queue, queries the i-queue (with the v-queue)
    /// in one batch, resolves the predicates and draws each queried node's objects under its
    /// query's predicate.
    fn issue_predicated(
        &mut self,
        bvh: &ObjectBvh,
        view: &View,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        if self.i_queue.is_empty() && self.requery.is_empty() {
            // Nothing to predicate: the v-queue goes out at the end of the frame.
            return Ok(());
        }
        let first = self.query_queue.len();
        self.issue_i_queue(bvh, backend, stats)?;
        backend.resolve_predicates()?;
        stats.predicate_resolves += 1;
        let mut scratch = std::mem::take(&mut self.predicated);
        let mut result = Ok(());
        for i in first..self.query_queue.len() {
            let q: Pending = self.query_queue[i];
            if q.kind != QueryKind::Invisible {
                continue;
            }
            scratch.objects.clear();
            for &n in &self.query_nodes[q.first as usize..(q.first + q.count) as usize] {
                scratch.collect(bvh, n, view);
            }
            if scratch.objects.is_empty() {
                continue;
            }
            stats.predicated_draws += 1;
            stats.predicated_objects += scratch.objects.len() as u32;
            result = backend.draw_objects_if(q.id, &scratch.objects);
            if result.is_err() {
                break;
            }
        }
        self.predicated = scratch;
        result
    }

    /// A result of the predicated mode, read `k` frames after its frame: it only steers the
    /// traversal of the frames to come (see the module docs, step 4).
    fn handle_predicated_result(
        &mut self,
        bvh: &ObjectBvh,
        q: Pending,
        visible: bool,
        stats: &mut CullStats,
    ) {
        let nodes = q.first as usize..(q.first + q.count) as usize;
        if !visible && q.kind == QueryKind::Probe {
            // Its box is hidden now: it closes and is queried as a whole again.
            self.state[self.query_nodes[q.first as usize] as usize].open_until = 0;
            return;
        }
        if !visible {
            for i in nodes {
                let node = self.query_nodes[i];
                self.state[node as usize].visible = false;
                if q.kind == QueryKind::Invisible {
                    stats.query_culled += 1;
                }
            }
            return;
        }
        match q.kind {
            QueryKind::Visible => {
                let node = self.query_nodes[q.first as usize];
                self.pull_up_visibility(bvh, node);
            }
            QueryKind::Probe => {
                // Still showing: held open for another while.
                let node = self.query_nodes[q.first as usize];
                self.state[node as usize].open_until =
                    self.frame + 1 + u64::from(self.params.predicated_hold);
            }
            QueryKind::Invisible if q.count > 1 => {
                // A failed multiquery: its nodes are queried one by one next time (no
                // invisibility history, p = 0.29), each under its own predicate.
                stats.failed_multiqueries += 1;
                for i in nodes {
                    let node = self.query_nodes[i];
                    self.state[node as usize].last_visible = self.frame;
                }
            }
            QueryKind::Invisible => {
                let node = self.query_nodes[q.first as usize];
                self.pull_up_visibility(bvh, node);
                if bvh.nodes[node as usize].is_leaf() {
                    self.start_interval(node);
                } else {
                    self.open_levels(bvh, node, self.params.predicated_levels);
                }
            }
        }
    }

    /// Whether a previously invisible interior node would put more objects under its predicate
    /// than the budget allows in expectation, `(1 - p) · objects > predicated_budget`: it is
    /// opened instead (predicated mode).
    fn over_predicate_budget(&self, bvh: &ObjectBvh, node: u32) -> bool {
        if bvh.nodes[node as usize].is_leaf() {
            return false;
        }
        let objects = self.predicated.objects_below(node) as f32;
        let expected = (1.0 - self.stays_invisible(node)) * objects;
        expected > self.params.predicated_budget
    }

    /// Whether `node` is an interior node held open in the predicated mode: its own query said
    /// visible less than `predicated_hold` frames ago, so its children are queried rather
    /// than its box (which shows) with its whole subtree under the predicate.
    fn held_open(&self, bvh: &ObjectBvh, node: u32) -> bool {
        self.frame < self.state[node as usize].open_until && !bvh.nodes[node as usize].is_leaf()
    }

    /// Opens a node held open (its children are visited). When its hold runs out it is
    /// probed: its box is queried with the frame's batch, nothing drawn under it, and it stays
    /// open until the result is read (and longer if its box still shows).
    fn traverse_held_open(
        &mut self,
        bvh: &ObjectBvh,
        node: u32,
        eye: glam::Vec3,
        stats: &mut CullStats,
    ) {
        let s = &mut self.state[node as usize];
        s.last_visited = self.frame;
        if self.frame + 1 >= s.open_until {
            s.open_until = self.frame + 2 + u64::from(self.frames_in_flight);
            self.predicated.probes.push(node);
        }
        self.traverse_node(bvh, node, eye, stats);
    }

    /// Issues the probes of nodes held open (see [`Chcpp::traverse_held_open`]).
    pub(super) fn issue_probes(
        &mut self,
        bvh: &ObjectBvh,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        if self.predicated.probes.is_empty() {
            return Ok(());
        }
        self.batch.clear();
        self.batch.append(&mut self.predicated.probes);
        self.issue_batch_singly(bvh, QueryKind::Probe, backend, stats)
    }

    /// Marks the nodes of `node`'s subtree down to `levels` levels below it visible in this
    /// frame, so the next frame opens them, and holds its interior nodes open for
    /// `predicated_hold` frames; the interior nodes `levels` down keep no visible state and are
    /// queried then. Leaves reached are drawn and re-tested in the next frame.
    fn open_levels(&mut self, bvh: &ObjectBvh, node: u32, levels: u32) {
        let hold = self.frame + 1 + u64::from(self.params.predicated_hold);
        let mut stack = std::mem::take(&mut self.predicated.stack);
        stack.clear();
        stack.push((node, 0));
        while let Some((n, depth)) = stack.pop() {
            let b = &bvh.nodes[n as usize];
            if depth >= levels && !b.is_leaf() {
                continue;
            }
            let s = &mut self.state[n as usize];
            s.visible = true;
            s.last_visited = self.frame;
            s.last_visible = self.frame;
            s.tested = true;
            if b.is_leaf() {
                s.next_query = self.frame + 1;
            } else {
                s.open_until = hold;
                stack.extend(b.children.iter().map(|&c| (c, depth + 1)));
            }
        }
        self.predicated.stack = stack;
    }
}
