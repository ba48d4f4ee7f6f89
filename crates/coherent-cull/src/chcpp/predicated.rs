//! The predicated latency mode of CHC, CHC++ and NOHC ([`Latency::Predicated`]): exact culling
//! with one submission per frame and no CPU wait, through predicates the device evaluates
//! itself (on Vulkan, `VK_EXT_conditional_rendering`). NOHC runs the same traversal with its
//! cost rule deciding which nodes are queried; a node the rule does not query is opened as if
//! visible (case (a) below for its leaves), and the rule learns from the results when they are
//! read, `k` frames later.
//!
//! # A frame
//!
//! 1. The traversal runs on the hierarchy's state as of the newest results the CPU has (those
//!    of frame N-k, read at the start of frame N). Previously visible leaves are drawn
//!    unconditionally and, when their query is due, queried for later frames (the v-queue;
//!    every [`ChcppParams::predicated_visible_interval`] frames, 7 by default, where the
//!    other modes keep the paper's 5: here those queries save fewer draws).
//!    Previously invisible nodes go into the i-queue; no batch goes out during the traversal.
//!    A node whose box holds the eye (or reaches the near plane where the view is) is opened
//!    unconditionally, as in every mode, and so is a node that enters the frustum in this
//!    frame with a box over [`ChcppParams::predicated_enter_fraction`] of the screen (its
//!    children enter with it): what comes into view near the eye as the camera turns is
//!    drawn before the tests and hides what lies behind it.
//! 2. When the traversal is done, the render queue is drawn, then the i-queue is queried in one
//!    batch (multiqueries; the nodes' own boxes, or with `predicated_tight_bounds` their
//!    tight volumes; a box over [`ChcppParams::predicated_screen_split`] of the screen gives
//!    way to its children's in view where theirs cover less) together with the v-queue.
//! 3. The backend resolves the predicates ([`OcclusionBackend::resolve_predicates`]: on Vulkan
//!    one pass break, a copy and a barrier), and the objects under each i-queue query's nodes
//!    that lie in the frustum are drawn under that query's predicate, handed over as ranges of
//!    the subtree order ([`OcclusionBackend::draw_order_ranges_if`]: a subtree wholly in the
//!    frustum is one range). A backend that keeps such draws until the resolve
//!    ([`OcclusionBackend::gathers_predicated_draws`]: the built-in renderer gathers the passed
//!    ones on the device into one indirect draw) gets them before it when no node is split.
//! 4. On a backend that can issue queries under a predicate
//!    ([`OcclusionBackend::supports_predicated_queries`]), a queried node with more than
//!    `predicated_refine_objects` objects in the frustum, and every node of a multiquery
//!    (unless `predicated_split_multiqueries` is off), is split instead: its parts
//!    (descendants down to `predicated_refine_levels` levels, fewer where a part is a leaf or
//!    small) are queried under the node's predicate
//!    ([`OcclusionBackend::issue_query_if`]: when the node's query counted nothing, the parts'
//!    boxes are not drawn and their queries count nothing), against the depth of everything
//!    drawn so far. A second resolve follows, and each part's objects are drawn under the
//!    part's own predicate: a node that turns visible draws the parts that show, not its
//!    whole subtree. Blocks do not nest, and none has to: a part's query lies in its node's
//!    block, its draws in its own. With `predicated_split_ratio` R > 0 a node is
//!    split only when it pays in expectation, `(1 - p) · objects · R > parts`, `1 - p` the
//!    chance that its query's predicate is true (the multiqueries' estimate from the nodes'
//!    history): a split query costs its begin and end even when a false predicate discards
//!    its boxes (a part decided by the backend's test, below, costs no query, so while the
//!    backend tests parts the rule is off).
//!    A backend with a test of its own ([`OcclusionBackend::test_part_if`]; the built-in
//!    renderer's box flags gated by the node's flag, all parts in one instanced draw at the
//!    second resolve, or with queries its test of the parts' screen rectangles against the
//!    depth drawn so far, one compute dispatch) decides the parts instead of queries (in a
//!    frame after one that split at least `predicated_tested_parts_min` parts, by default
//!    always): no query per part, a test as fine as a query's or coarser. A tested part's objects are handed over
//!    as soon as the part is, before the resolve that tests it; the backend draws them after
//!    the test (the built-in renderer: the draws of the parts that passed, gathered on the
//!    device into one indirect draw, with no conditional block per part).
//! 5. The results are read `k` frames later only to update the hierarchy: a queried node that
//!    came back visible is opened `predicated_levels` levels deep, a part that passed
//!    `predicated_part_levels` (the nodes below are queried, and drawn under their own
//!    predicates, from then on), a failed multiquery's nodes lose their invisibility history
//!    (queried one by one next time), a visible leaf that came back hidden is queried (and
//!    drawn under a predicate) from the next frame on.
//!
//! # Why nothing visible is culled
//!
//! A node outside the frustum, or (with the view's [`crate::PixelGrid`]) whose box holds no
//! pixel centre, holds no object that can own a pixel. Every other object in the frustum lies
//! below exactly one node where the traversal stopped: (a) a leaf opened unconditionally,
//! whose objects are drawn; (b) a node opened unconditionally (its box holds the eye, or it
//! enters the view large), whose children are visited; or (c) an i-queue node. In case (c)
//! the node's query draws boxes that cover the object (its own box, its tight volume or its
//! children's boxes in view: this frame's boxes, so movers are covered where they are now)
//! against the depth of the frame's unconditional draws, which is depth written by real
//! geometry of this frame and only gets nearer as the frame goes on. If the query counted no
//! sample, every sample of the object's surface lies behind that depth and owns no pixel of
//! the final image; if it counted any, the object is drawn. A multiquery's
//! predicate covers all its nodes: they are drawn when any of them is visible. Nodes that enter
//! the frustum or the hierarchy have no visible history and are case (c). The boxes must be
//! rasterized conservatively (a depth bias towards the eye and a compare that passes on equal
//! depth): that is the backend's part. A split node's objects lie under its parts (the parts
//! cover the subtree's objects in the frustum); a part's query draws its boxes when the node's
//! predicate is true, against depth that is still only real geometry of this frame, so the
//! same argument holds for the part; when the node's predicate is false, the node's boxes,
//! which cover every object of its parts, were hidden already. A part decided by the backend's
//! own test is exact on the same terms: the test must pass every box that owns a pixel
//! against that depth (the built-in renderer's is conservative: a box fails only when every
//! depth texel under its screen rectangle lies nearer than the box's nearest point), and a
//! part of a node whose query counted nothing fails. The CPU's results only steer which nodes
//! land in which case, so however old they are, the image is exact; they decide the cost.
//!
//! # What it costs
//!
//! One pass break per frame (two when nodes are split), and extra draws: an object under a
//! true predicate is drawn even when only another object of its node or part is visible, until
//! the results come back and the node is opened (`k` frames). [`CullStats::predicated_objects`] counts the objects sent under
//! predicates; the built-in renderer reads the predicates back after the frame to count those
//! the device really drew.
//!
//! Which split pays depends on the device: on a CPU rasterizer (lavapipe) every object drawn
//! costs rasterization, so nodes are split into parts (the defaults); on a GPU the extra
//! objects cost little and recording the parts' queries, tight boxes and conditional blocks is
//! the frame's cost, so [`ChcppParams::for_gpu`] keeps one predicate level (each queried
//! node's objects under its own predicate, one pass break).

use super::latency::LatencyMode;
use super::{Chcpp, ChcppParams, Pending, QueryKind};
use crate::bvh::ObjectBvh;
use crate::error::Result;
use crate::{CullStats, Latency, OcclusionBackend, SubtreeOrder, View};
use std::ops::Range;

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
            Err(crate::Error::Unsupported {
                feature: "predicated draws (Latency::Predicated needs a backend whose \
                          supports_predicates() is true: on Vulkan VK_EXT_conditional_rendering, \
                          with coherent-ash also QueryBackendDesc::predicates and a frame made \
                          with FrameBackend::with_resume)"
                    .into(),
            })
        }
    }

    /// The objects below each node, kept in the order handed to the backend.
    fn begin_frame(&self, c: &mut Chcpp, bvh: &ObjectBvh) {
        if c.predicated.order.update(bvh) {
            c.predicated.order_sent = false;
        }
        let p = &mut c.predicated;
        p.parts_last_frame = std::mem::take(&mut p.parts_this_frame);
        p.tested_last_frame = std::mem::take(&mut p.tested_this_frame);
    }

    /// A node held open: its children are visited. A node entering the view near the eye:
    /// opened unconditionally.
    fn opens_previously_invisible(
        &self,
        c: &mut Chcpp,
        bvh: &ObjectBvh,
        node: u32,
        eye: glam::Vec3,
        stats: &mut CullStats,
    ) -> bool {
        if c.held_open(bvh, node) {
            c.traverse_held_open(bvh, node, eye, stats);
            true
        } else if c.enters_large(bvh, node) {
            c.open_entering(bvh, node, eye, stats);
            true
        } else {
            false
        }
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
    /// The objects of one conditional draw: ranges of `order`, adjacent ones merged.
    ranges: Vec<Range<u32>>,
    /// A subtree walk: nodes, or nodes with their depth below the opened node.
    stack: Vec<(u32, u32)>,
    /// Nodes held open whose hold runs out: probed in this frame's query batch.
    pub(super) probes: Vec<u32>,
    /// Split nodes of this frame, with the query whose predicate decides their parts.
    split: Vec<(crate::QueryId, u32)>,
    /// The parts of one split node.
    parts: Vec<u32>,
    /// Where the frame's queried parts (not decided by the backend's test) lie in the query
    /// queue: drawn after the second resolve.
    queried: Vec<usize>,
    /// The hierarchy's objects with every subtree contiguous (how many lie below a node).
    order: SubtreeOrder,
    /// Whether the backend has `order` ([`OcclusionBackend::set_draw_order`]).
    order_sent: bool,
    /// Parts split in the last frame and in this one (`predicated_tested_parts_min`).
    parts_last_frame: u32,
    parts_this_frame: u32,
    /// Whether the backend decided parts by its own test in the last frame and in this one
    /// (`predicated_split_ratio` applies only to parts that cost a query).
    tested_last_frame: bool,
    tested_this_frame: bool,
}

impl Scratch {
    /// The objects below `node`.
    pub(super) fn objects_below(&self, node: u32) -> u32 {
        self.order.count_below(node)
    }

    /// Appends the objects of `node`'s subtree whose leaves lie in the frustum to `ranges`.
    fn collect(&mut self, bvh: &ObjectBvh, node: u32, view: &View) {
        let (order, ranges) = (&self.order, &mut self.ranges);
        walk_in_frustum(bvh, order, &mut self.stack, node, view, |r| {
            match ranges.last_mut() {
                Some(last) if last.end == r.start => last.end = r.end,
                _ => ranges.push(r),
            }
        });
    }

    /// How many objects of `node`'s subtree lie in leaves in the frustum.
    fn count_in_frustum(&mut self, bvh: &ObjectBvh, node: u32, view: &View) -> u32 {
        let mut count = 0;
        walk_in_frustum(bvh, &self.order, &mut self.stack, node, view, |r| {
            count += r.len() as u32
        });
        count
    }

    /// How many objects `ranges` holds.
    fn objects(&self) -> u32 {
        crate::ranges_len(&self.ranges) as u32
    }
}

/// Hands `found` the ranges of `order` of the leaves below `node` that lie in the frustum, in
/// walk order: a subtree wholly in the frustum as its one range. A child is tested only
/// against the planes that cut its parent (a node's box holds its children's).
fn walk_in_frustum(
    bvh: &ObjectBvh,
    order: &SubtreeOrder,
    stack: &mut Vec<(u32, u32)>,
    node: u32,
    view: &View,
    mut found: impl FnMut(Range<u32>),
) {
    stack.clear();
    stack.push((node, u32::from(crate::Frustum::ALL_PLANES)));
    while let Some((n, planes)) = stack.pop() {
        let b = &bvh.nodes[n as usize];
        if !b.bounds.is_valid() {
            continue;
        }
        let Some(cut) = view.frustum.cut_planes(&b.bounds, planes as u8) else {
            continue;
        };
        if b.is_leaf() || cut == 0 {
            let r = order.range(n);
            if !r.is_empty() {
                found(r);
            }
        } else {
            stack.extend(b.children.iter().map(|&c| (c, u32::from(cut))));
        }
    }
}

impl Chcpp {
    /// The traversal is done: draws the render queue, queries the i-queue (with the v-queue)
    /// in one batch, resolves the predicates and draws each queried node's objects under its
    /// query's predicate. On a backend that queries under predicates, large nodes and the
    /// nodes of multiqueries are split instead: their parts are queried under the node's
    /// predicate, a second resolve follows, and each part's objects are drawn under its own.
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
        if !self.predicated.order_sent {
            backend.set_draw_order(self.predicated.order.objects())?;
            self.predicated.order_sent = true;
        }
        let split =
            backend.supports_predicated_queries() && self.params.predicated_refine_levels > 0;
        // With one predicate level a backend that keeps draws until the resolve gets them
        // before it (it gathers the passed ones on the device): still one resolve.
        let draws_first = !split && backend.gathers_predicated_draws();
        if !draws_first {
            backend.resolve_predicates()?;
            stats.predicate_resolves += 1;
        }
        let mut scratch = std::mem::take(&mut self.predicated);
        let result =
            self.draw_under_predicates(bvh, view, first, split, &mut scratch, backend, stats);
        self.predicated = scratch;
        result?;
        if draws_first {
            backend.resolve_predicates()?;
            stats.predicate_resolves += 1;
        }
        Ok(())
    }

    /// Draws the objects of the i-queue queries from `first` on under their predicates; with
    /// `split`, queries the parts of the nodes that [`Chcpp::split_node`] picks under their
    /// query's predicate and, after a second resolve, draws each part's objects under its own.
    #[allow(clippy::too_many_arguments)]
    fn draw_under_predicates(
        &mut self,
        bvh: &ObjectBvh,
        view: &View,
        first: usize,
        split: bool,
        scratch: &mut Scratch,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        let last = self.query_queue.len();
        scratch.split.clear();
        for i in first..last {
            let q: Pending = self.query_queue[i];
            if q.kind != QueryKind::Invisible {
                continue;
            }
            scratch.ranges.clear();
            let nodes = q.first as usize..(q.first + q.count) as usize;
            let multiquery = q.count > 1;
            let p_true = if self.params.predicated_split_ratio > 0.0 {
                1.0 - self.query_nodes[nodes.clone()]
                    .iter()
                    .map(|&n| self.stays_invisible(n).clamp(0.0, 1.0))
                    .product::<f32>()
            } else {
                1.0
            };
            // A multiquery is split as a whole or not at all, so that its result is handled
            // one way for all its nodes (a split query's nodes wait for their parts' results;
            // an unsplit one's are queried one by one after it failed).
            let split_group = split
                && multiquery
                && self.params.predicated_split_multiqueries
                && self.split_pays(bvh, &self.query_nodes[nodes.clone()], view, p_true, scratch);
            for &n in &self.query_nodes[nodes] {
                if split_group
                    || (split
                        && !multiquery
                        && self.split_node(bvh, n, view, scratch)
                        && self.split_pays(bvh, &[n], view, p_true, scratch))
                {
                    scratch.split.push((q.id, n));
                    self.query_queue[i].split = true;
                } else {
                    scratch.collect(bvh, n, view);
                }
            }
            self.draw_if(q.id, scratch, backend, stats)?;
        }
        if scratch.split.is_empty() {
            return Ok(());
        }
        // The parts, queried against the depth drawn so far (the unconditional draws and the
        // objects drawn under the first predicates).
        // A part decided by the backend's test has its objects handed over at once (the
        // backend draws them after the test, at the resolve); a queried part's after the
        // resolve, under its query's predicate.
        let tested = scratch.parts_last_frame >= self.params.predicated_tested_parts_min;
        scratch.queried.clear();
        for s in 0..scratch.split.len() {
            let (predicate, node) = scratch.split[s];
            scratch.parts.clear();
            self.parts_of(bvh, node, view, scratch);
            for p in 0..scratch.parts.len() {
                let part = scratch.parts[p];
                let decided = self.issue_part(bvh, predicate, part, tested, backend, stats)?;
                scratch.tested_this_frame |= decided;
                scratch.parts_this_frame += 1;
                let issued = self.query_queue.len() - 1;
                if decided {
                    scratch.ranges.clear();
                    scratch.collect(bvh, part, view);
                    self.draw_if(self.query_queue[issued].id, scratch, backend, stats)?;
                } else {
                    scratch.queried.push(issued);
                }
            }
        }
        backend.resolve_predicates()?;
        stats.predicate_resolves += 1;
        for k in 0..scratch.queried.len() {
            let q: Pending = self.query_queue[scratch.queried[k]];
            scratch.ranges.clear();
            scratch.collect(bvh, self.query_nodes[q.first as usize], view);
            self.draw_if(q.id, scratch, backend, stats)?;
        }
        Ok(())
    }

    /// Draws the objects of `scratch.ranges` under `query`'s predicate (nothing when there
    /// are none).
    fn draw_if(
        &self,
        query: crate::QueryId,
        scratch: &Scratch,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        if scratch.ranges.is_empty() {
            return Ok(());
        }
        stats.predicated_draws += 1;
        stats.predicated_objects += scratch.objects();
        backend.draw_order_ranges_if(query, scratch.order.objects(), &scratch.ranges)
    }

    /// Whether a queried node is split into parts: an interior node with more than
    /// `predicated_refine_objects` objects in the frustum.
    fn split_node(&self, bvh: &ObjectBvh, node: u32, view: &View, scratch: &mut Scratch) -> bool {
        if bvh.nodes[node as usize].is_leaf()
            || scratch.objects_below(node) <= self.params.predicated_refine_objects
        {
            return false;
        }
        scratch.count_in_frustum(bvh, node, view) > self.params.predicated_refine_objects
    }

    /// Whether splitting `nodes` (one node, or the nodes of a multiquery), queried under a
    /// predicate that is true with probability `p_true`, pays in expectation
    /// (`predicated_split_ratio`; always with a ratio of 0, and while the backend decides
    /// parts by its own test, which costs no query per part).
    fn split_pays(
        &self,
        bvh: &ObjectBvh,
        nodes: &[u32],
        view: &View,
        p_true: f32,
        scratch: &mut Scratch,
    ) -> bool {
        let ratio = self.params.predicated_split_ratio;
        if ratio <= 0.0 || scratch.tested_last_frame {
            return true;
        }
        let (mut objects, mut parts) = (0, 0);
        for &node in nodes {
            objects += scratch.count_in_frustum(bvh, node, view);
            scratch.parts.clear();
            self.parts_of(bvh, node, view, scratch);
            parts += scratch.parts.len();
        }
        scratch.parts.clear();
        p_true * objects as f32 * ratio > parts as f32
    }

    /// The parts of a split node in the frustum, into `scratch.parts`: its descendants down to
    /// `predicated_refine_levels` levels, stopping early at leaves and at nodes with at most
    /// `predicated_refine_objects` objects (a node of a multiquery that is small is its own
    /// part).
    fn parts_of(&self, bvh: &ObjectBvh, node: u32, view: &View, scratch: &mut Scratch) {
        scratch.stack.clear();
        scratch.stack.push((node, 0));
        while let Some((n, depth)) = scratch.stack.pop() {
            let b = &bvh.nodes[n as usize];
            if !b.bounds.is_valid() || !view.frustum.intersects(&b.bounds) {
                continue;
            }
            let small = scratch.objects_below(n) <= self.params.predicated_refine_objects;
            if b.is_leaf() || small || depth == self.params.predicated_refine_levels {
                scratch.parts.push(n);
            } else {
                scratch
                    .stack
                    .extend(b.children.iter().map(|&c| (c, depth + 1)));
            }
        }
    }

    /// Queries `part` under `predicate`'s predicate (with `tested`, has the backend decide it
    /// by its own test where it offers one). Returns whether the backend's test decided it.
    fn issue_part(
        &mut self,
        bvh: &ObjectBvh,
        predicate: crate::QueryId,
        part: u32,
        tested: bool,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<bool> {
        let mut boxes = std::mem::take(&mut self.boxes);
        boxes.clear();
        self.query_boxes(bvh, part, &mut boxes);
        let decided = match tested {
            true => backend.test_part_if(predicate, &boxes),
            false => Ok(None),
        };
        let mut decided_here = false;
        let id = decided.and_then(|id| match id {
            Some(id) => {
                decided_here = true;
                Ok(id)
            }
            None => {
                stats.queries += 1;
                stats.predicated_queries += 1;
                backend.issue_query_if(predicate, &boxes, crate::QueryPurpose::Node)
            }
        });
        self.boxes = boxes;
        let id = id?;
        let first = self.query_nodes.len() as u32;
        self.query_nodes.push(part);
        self.query_queue.push_back(Pending {
            id,
            first,
            count: 1,
            kind: QueryKind::Part,
            split: false,
        });
        Ok(decided_here)
    }

    /// A result of the predicated mode, read `k` frames after its frame: it only steers the
    /// traversal of the frames to come (see the module docs, step 5).
    fn handle_predicated_result(
        &mut self,
        bvh: &ObjectBvh,
        q: Pending,
        visible: bool,
        stats: &mut CullStats,
    ) {
        let nodes = q.first as usize..(q.first + q.count) as usize;
        if q.kind == QueryKind::Part {
            // A part of a split node: visible parts open as a queried node would (their
            // ancestors, the split node among them, turn visible by the pull-up); hidden ones
            // are queried as previously invisible nodes.
            let node = self.query_nodes[q.first as usize];
            if !visible {
                self.state[node as usize].visible = false;
            } else {
                self.pull_up_visibility(bvh, node);
                if bvh.nodes[node as usize].is_leaf() {
                    self.start_interval(node);
                } else {
                    self.open_levels(bvh, node, self.params.predicated_part_levels);
                }
            }
            return;
        }
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
            QueryKind::Invisible if q.split => {
                // Its parts' results say what shows; its interior nodes are held open, so the
                // traversal reaches the parts rather than querying (and splitting) a box that
                // shows while its contents may be hidden.
                if q.count > 1 {
                    stats.failed_multiqueries += 1;
                }
                let hold = self.frame + 1 + u64::from(self.params.predicated_hold);
                for i in nodes {
                    let node = self.query_nodes[i];
                    if !bvh.nodes[node as usize].is_leaf() {
                        self.state[node as usize].open_until = hold;
                    }
                }
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
            QueryKind::Invisible | QueryKind::Part => {
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

    /// Whether `node` enters the view in this frame with a box over
    /// `predicated_enter_fraction` of the screen (see [`ChcppParams::predicated_enter_fraction`]).
    fn enters_large(&self, bvh: &ObjectBvh, node: u32) -> bool {
        let fraction = self.params.predicated_enter_fraction;
        if fraction <= 0.0 || !self.state[node as usize].entering {
            return false;
        }
        self.frame_view.as_ref().is_some_and(|view| {
            super::tight::screen_fraction(view, &bvh.nodes[node as usize].bounds) > fraction
        })
    }

    /// Opens an entering node unconditionally (a leaf is drawn and queried later as a visible
    /// leaf); its children enter with it.
    fn open_entering(
        &mut self,
        bvh: &ObjectBvh,
        node: u32,
        eye: glam::Vec3,
        stats: &mut CullStats,
    ) {
        let n = &bvh.nodes[node as usize];
        if !n.is_leaf() {
            for &child in &n.children {
                self.state[child as usize].entering = true;
            }
        }
        self.state[node as usize].tested = true;
        self.traverse_unqueryable(bvh, node, eye, stats);
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
