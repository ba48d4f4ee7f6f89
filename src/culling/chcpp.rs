//! CHC++ (Mattausch, Bittner, Wimmer 2008): coherent hierarchical culling with query batching
//! (i-queue, v-queue, render queue), randomized query intervals for visible leaves, multiqueries
//! and tight bounding volumes. Each part is a switch; with all of them off and a batch size of 1
//! the same traversal is the original CHC (Bittner et al. 2004), see `chc.rs`.

use std::collections::VecDeque;

use super::{eye_inside, CullStats, Culler, FrameInput, OcclusionBackend, QueryId, View};
use crate::bvh::{DistanceQueue, ObjectBvh};
use crate::error::Result;
use crate::scene::mesh::Rng;
use crate::scene::Aabb;

/// The parameters of CHC++ (defaults from the paper).
#[derive(Clone, Debug, PartialEq)]
pub struct ChcppParams {
    /// Batch previously invisible nodes in an i-queue and visible leaves in a v-queue.
    pub batching: bool,
    /// Nodes per i-queue batch (`b`, default 50).
    pub batch_size: usize,
    /// Test visible leaves every `n_av` frames, first after a random delay in `[1, n_av]`.
    pub randomized_interval: bool,
    /// The assumed-visible interval `n_av` (default 5).
    pub visible_interval: u32,
    /// Group previously invisible nodes into multiqueries by the cost/benefit rule.
    pub multiqueries: bool,
    /// Query nodes with the boxes of their descendants instead of their own box.
    pub tight_bounds: bool,
    /// Descendant depth for tight bounding volumes (default 3).
    pub tight_depth: u32,
    /// Use the tight boxes only if their total surface area is at most this times the node's
    /// (default 1.4).
    pub tight_area_factor: f32,
    /// A query counting more than this many pixels means visible (default 0).
    pub pixel_threshold: u64,
    /// Submit after this many queries have been recorded without a submit (for the
    /// unbatched CHC; batches are always submitted as a whole).
    pub flush_interval: usize,
    /// Seed of the randomized interval.
    pub seed: u64,
}

impl Default for ChcppParams {
    fn default() -> Self {
        ChcppParams {
            batching: true,
            batch_size: 50,
            randomized_interval: true,
            visible_interval: 5,
            multiqueries: true,
            tight_bounds: true,
            tight_depth: 3,
            tight_area_factor: 1.4,
            pixel_threshold: 0,
            flush_interval: 16,
            seed: 0x00C0_FFEE,
        }
    }
}

impl ChcppParams {
    /// The original CHC as a configuration of the same traversal: no batching (each query is
    /// issued at once, so one state change per query), every visible leaf queried every frame,
    /// single queries with the node's own box.
    pub fn chc() -> ChcppParams {
        ChcppParams {
            batching: false,
            batch_size: 1,
            randomized_interval: false,
            visible_interval: 1,
            multiqueries: false,
            tight_bounds: false,
            ..ChcppParams::default()
        }
    }

    /// CHC++ with only the named parts on (for measuring each part alone): any of `batching`,
    /// `interval`, `multiqueries`, `tight`. Multiqueries group the i-queue, so `multiqueries`
    /// turns batching on too.
    pub fn only(parts: &[&str]) -> ChcppParams {
        let mut p = ChcppParams::chc();
        for part in parts {
            match *part {
                "batching" => {
                    p.batching = true;
                    p.batch_size = 50;
                }
                "interval" => {
                    p.randomized_interval = true;
                    p.visible_interval = 5;
                }
                // Multiqueries group the i-queue, so they need it.
                "multiqueries" => {
                    p.multiqueries = true;
                    p.batching = true;
                }
                "tight" => p.tight_bounds = true,
                _ => {}
            }
        }
        p
    }
}

/// Per-node temporal state, kept beside the hierarchy.
#[derive(Clone, Copy, Debug, Default)]
struct NodeState {
    visible: bool,
    last_visited: u64,
    /// Frame at which a visible leaf is queried next.
    next_query: u64,
    /// Frames the node has been invisible in a row (for the multiquery probability).
    invisible_frames: u32,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum QueryKind {
    /// For previously invisible nodes: the result decides traversal in this frame.
    Invisible,
    /// For previously visible leaves: the result matters next frame.
    Visible,
}

struct Pending {
    id: QueryId,
    nodes: Vec<u32>,
    kind: QueryKind,
}

/// CHC++ (or, configured with [`ChcppParams::chc`], CHC).
pub struct Chcpp {
    name: &'static str,
    params: ChcppParams,
    state: Vec<NodeState>,
    tight: Vec<Option<Vec<Aabb>>>,
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
}

impl Chcpp {
    /// CHC++ with `params`.
    pub fn new(params: ChcppParams) -> Chcpp {
        Chcpp::named("chcpp", params)
    }

    pub(crate) fn named(name: &'static str, params: ChcppParams) -> Chcpp {
        let rng = Rng::new(params.seed);
        Chcpp {
            name,
            params,
            state: Vec::new(),
            tight: Vec::new(),
            frame: 0,
            rng,
            traversal: DistanceQueue::default(),
            query_queue: VecDeque::new(),
            i_queue: Vec::new(),
            requery: Vec::new(),
            v_queue: Vec::new(),
            render_queue: Vec::new(),
            unsubmitted: 0,
            boxes: Vec::new(),
        }
    }

    /// The parameters.
    pub fn params(&self) -> &ChcppParams {
        &self.params
    }

    fn prepare(&mut self, bvh: &ObjectBvh) {
        if self.state.len() != bvh.nodes.len() {
            self.state = vec![NodeState::default(); bvh.nodes.len()];
            self.tight = vec![None; bvh.nodes.len()];
            self.frame = 0;
            if self.params.tight_bounds {
                for id in 0..bvh.nodes.len() as u32 {
                    self.tight[id as usize] = tight_boxes(bvh, id, &self.params);
                }
            }
        }
    }

    fn was_visible(&self, node: u32) -> bool {
        let s = &self.state[node as usize];
        s.visible && s.last_visited + 1 == self.frame
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
            if !s.visible {
                s.invisible_frames = 0;
            }
            s.visible = true;
            s.last_visited = self.frame;
            let parent = bvh.nodes[node as usize].parent;
            if parent == u32::MAX {
                break;
            }
            node = parent;
        }
    }

    fn query_boxes(&self, bvh: &ObjectBvh, node: u32, out: &mut Vec<Aabb>) {
        match &self.tight[node as usize] {
            Some(b) if self.params.tight_bounds => out.extend_from_slice(b),
            _ => out.push(bvh.nodes[node as usize].bounds),
        }
    }

    fn flush_render_queue(&mut self, backend: &mut dyn OcclusionBackend) -> Result<()> {
        if !self.render_queue.is_empty() {
            backend.draw_objects(&self.render_queue)?;
            self.render_queue.clear();
        }
        Ok(())
    }

    fn issue(
        &mut self,
        bvh: &ObjectBvh,
        nodes: Vec<u32>,
        kind: QueryKind,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        let mut boxes = std::mem::take(&mut self.boxes);
        boxes.clear();
        for &n in &nodes {
            self.query_boxes(bvh, n, &mut boxes);
        }
        let id = backend.issue_query(&boxes)?;
        self.boxes = boxes;
        stats.queries += 1;
        match kind {
            QueryKind::Invisible => stats.invisible_node_queries += 1,
            QueryKind::Visible => stats.visible_leaf_queries += 1,
        }
        if nodes.len() > 1 {
            stats.multiqueries += 1;
        }
        self.query_queue.push_back(Pending { id, nodes, kind });
        self.unsubmitted += 1;
        if !self.params.batching {
            backend.restore_render_state()?;
        }
        if !self.params.batching && self.unsubmitted >= self.params.flush_interval {
            backend.flush()?;
            self.unsubmitted = 0;
        }
        Ok(())
    }

    /// Issues the i-queue as one batch: render queue first, one switch into query state,
    /// multiqueries grouped by the cost/benefit rule, then submit.
    fn issue_i_queue(
        &mut self,
        bvh: &ObjectBvh,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        if self.i_queue.is_empty() && self.requery.is_empty() {
            return Ok(());
        }
        self.flush_render_queue(backend)?;
        stats.query_batches += 1;
        for n in std::mem::take(&mut self.requery) {
            self.issue(bvh, vec![n], QueryKind::Invisible, backend, stats)?;
        }
        let nodes = std::mem::take(&mut self.i_queue);
        if self.params.multiqueries && nodes.len() > 1 {
            self.issue_multiqueries(bvh, nodes, backend, stats)?;
        } else {
            for n in nodes {
                self.issue(bvh, vec![n], QueryKind::Invisible, backend, stats)?;
            }
        }
        // Due visible-leaf queries ride along while we are in query state anyway: no extra
        // state change for them.
        for n in std::mem::take(&mut self.v_queue) {
            self.issue(bvh, vec![n], QueryKind::Visible, backend, stats)?;
        }
        backend.flush()?;
        self.unsubmitted = 0;
        Ok(())
    }

    /// Groups i-queue nodes greedily into multiqueries, highest probability of staying
    /// invisible first, and issues one query per group.
    fn issue_multiqueries(
        &mut self,
        bvh: &ObjectBvh,
        mut nodes: Vec<u32>,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        nodes.sort_by(|a, b| {
            stays_invisible(&self.state[*b as usize])
                .total_cmp(&stays_invisible(&self.state[*a as usize]))
                .then(a.cmp(b))
        });
        let mut i = 0;
        while i < nodes.len() {
            let j = self.multiquery_group_end(&nodes, i);
            let group = nodes[i..j].to_vec();
            self.issue(bvh, group, QueryKind::Invisible, backend, stats)?;
            i = j;
        }
        Ok(())
    }

    /// The end of the multiquery group that starts at `nodes[i]`: a group M costs
    /// `1 + (1 - Π p) · |M|` queries in expectation; it grows while `|M| / cost` does not
    /// decrease.
    fn multiquery_group_end(&self, nodes: &[u32], i: usize) -> usize {
        let mut prod = 1.0f32;
        let mut best_value = 0.0f32;
        let mut j = i;
        while j < nodes.len() {
            let pj = stays_invisible(&self.state[nodes[j] as usize]).max(0.0);
            let size = (j - i + 1) as f32;
            let cost = 1.0 + (1.0 - prod * pj) * size;
            let value = size / cost;
            if j > i && value < best_value {
                break;
            }
            best_value = value;
            prod *= pj;
            j += 1;
        }
        j
    }

    /// Issues up to `limit` v-queue queries as one batch.
    fn issue_v_queue(
        &mut self,
        bvh: &ObjectBvh,
        limit: usize,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        if self.v_queue.is_empty() {
            return Ok(());
        }
        self.flush_render_queue(backend)?;
        stats.query_batches += 1;
        let n = limit.min(self.v_queue.len());
        let batch: Vec<u32> = self.v_queue.drain(..n).collect();
        for node in batch {
            self.issue(bvh, vec![node], QueryKind::Visible, backend, stats)?;
        }
        backend.flush()?;
        self.unsubmitted = 0;
        Ok(())
    }

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
        if visible && q.nodes.len() > 1 {
            // A failed multiquery: each node is queried on its own in the next batch.
            stats.failed_multiqueries += 1;
            self.requery.extend_from_slice(&q.nodes);
            if self.requery.len() + self.i_queue.len() >= self.params.batch_size.max(1) {
                self.issue_i_queue(bvh, backend, stats)?;
            }
            return Ok(());
        }
        let node = q.nodes[0];
        if visible {
            if q.kind == QueryKind::Invisible {
                self.traverse_node(bvh, node, eye, stats);
                self.start_interval(node);
            }
            self.pull_up_visibility(bvh, node);
        } else {
            let s = &mut self.state[node as usize];
            s.visible = false;
            s.invisible_frames += 1;
            if q.kind == QueryKind::Invisible {
                stats.query_culled += 1;
            }
        }
        Ok(())
    }

    /// A node that just turned visible gets its first re-test after a random delay.
    fn start_interval(&mut self, node: u32) {
        let n = self.params.visible_interval.max(1) as u64;
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
}

/// The steps of [`Chcpp::cull_frame`], in the order the paper's pseudocode runs them.
impl Chcpp {
    /// Starts a frame: empty queues, the root in the traversal queue.
    fn begin_frame(&mut self, bvh: &ObjectBvh, eye: glam::Vec3) {
        self.prepare(bvh);
        self.frame += 1;
        self.traversal.clear();
        self.query_queue.clear();
        self.i_queue.clear();
        self.requery.clear();
        self.v_queue.clear();
        self.render_queue.clear();
        self.unsubmitted = 0;
        self.traversal
            .push(0, bvh.nodes[0].bounds.distance_squared(eye));
    }

    /// Nodes per i-queue batch (`b`; 1 without batching).
    fn i_queue_batch_size(&self) -> usize {
        if self.params.batching {
            self.params.batch_size.max(1)
        } else {
            1
        }
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
        if !view.frustum.intersects(bounds) {
            self.frustum_cull(node, stats);
        } else if eye_inside(bounds, input.camera) {
            self.traverse_unqueryable(bvh, node, view.eye, stats);
        } else if !self.was_visible(node) {
            self.query_previously_invisible(bvh, node, backend, stats)?;
        } else {
            self.traverse_previously_visible(bvh, node, view.eye, backend, stats)?;
        }
        Ok(())
    }

    /// A node outside the view frustum: invisible, and its count of occluded frames restarts.
    fn frustum_cull(&mut self, node: u32, stats: &mut CullStats) {
        stats.frustum_culled += 1;
        let s = &mut self.state[node as usize];
        s.visible = false;
        s.last_visited = self.frame;
        s.invisible_frames = 0;
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
        self.state[node as usize].last_visited = self.frame;
        if self.params.batching {
            self.i_queue.push(node);
            if self.i_queue.len() + self.requery.len() >= self.i_queue_batch_size() {
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
        let due = self.query_reasonable(node);
        self.pull_up_visibility(bvh, node);
        if due {
            self.state[node as usize].next_query =
                self.frame + self.params.visible_interval.max(1) as u64;
            if self.params.batching {
                self.v_queue.push(node);
            } else {
                self.issue_unbatched(bvh, node, QueryKind::Visible, backend, stats)?;
            }
        }
        Ok(())
    }

    /// Unbatched (CHC): render what is queued, then issue this node's query on its own.
    fn issue_unbatched(
        &mut self,
        bvh: &ObjectBvh,
        node: u32,
        kind: QueryKind,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        self.flush_render_queue(backend)?;
        stats.query_batches += 1;
        self.issue(bvh, vec![node], kind, backend, stats)
    }

    /// The traversal queue ran dry: issue the i-queue (unbatched: submit what was recorded).
    fn issue_remaining_queries(
        &mut self,
        bvh: &ObjectBvh,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        self.issue_i_queue(bvh, backend, stats)?;
        if !self.params.batching && self.unsubmitted > 0 {
            self.flush_render_queue(backend)?;
            backend.flush()?;
            self.unsubmitted = 0;
        }
        Ok(())
    }

    /// Ends a frame: render what is left, issue the leftover visible-leaf queries (their
    /// results are for the next frame), wait for the device and read back every query.
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
        backend.finish()?;
        while let Some(q) = self.query_queue.pop_front() {
            let pixels = backend.wait_query(q.id)?;
            self.handle_returned_query(bvh, q, pixels, eye, backend, stats)?;
        }
        Ok(())
    }
}

/// `p(k) = 0.99 - 0.7 e^(-k)`: the probability that a node invisible for `k` frames stays
/// invisible (fitted by the paper's authors).
fn stays_invisible(s: &NodeState) -> f32 {
    0.99 - 0.7 * (-(s.invisible_frames as f32)).exp()
}

/// The boxes of `node`'s descendants down to `tight_depth` levels (leaves above that depth count
/// themselves), if their total surface area is at most `tight_area_factor` times the node's.
fn tight_boxes(bvh: &ObjectBvh, node: u32, params: &ChcppParams) -> Option<Vec<Aabb>> {
    let root = &bvh.nodes[node as usize];
    if root.is_leaf() {
        return None;
    }
    let mut out = Vec::new();
    let mut stack = vec![(node, 0u32)];
    while let Some((n, d)) = stack.pop() {
        let nn = &bvh.nodes[n as usize];
        if nn.is_leaf() || d == params.tight_depth {
            out.push(nn.bounds);
        } else {
            stack.push((nn.children[0], d + 1));
            stack.push((nn.children[1], d + 1));
        }
    }
    let area: f32 = out.iter().map(|b| b.surface_area()).sum();
    (area <= params.tight_area_factor * root.bounds.surface_area()).then_some(out)
}

impl Culler for Chcpp {
    fn name(&self) -> &str {
        self.name
    }

    /// The main loop of the paper's pseudocode: while the traversal queue or the query queue is
    /// not empty, first handle the queries that have returned, then take the next node from the
    /// traversal queue; when the traversal queue runs dry, issue what the i-queue holds.
    fn cull_frame(
        &mut self,
        input: &FrameInput,
        backend: &mut dyn OcclusionBackend,
    ) -> Result<CullStats> {
        let bvh = input.bvh;
        let view = View::new(input.camera);
        let eye = view.eye;
        let mut stats = CullStats::default();
        self.begin_frame(bvh, eye);
        while !self.traversal.is_empty() || !self.query_queue.is_empty() {
            // 1. Process finished occlusion queries.
            self.process_finished_queries(bvh, eye, backend, &mut stats)?;
            // 2. Hierarchical traversal.
            if let Some(node) = self.traversal.pop() {
                self.visit_node(input, &view, node, backend, &mut stats)?;
            }
            if self.traversal.is_empty() {
                self.issue_remaining_queries(bvh, backend, &mut stats)?;
            }
        }
        self.end_frame(bvh, eye, backend, &mut stats)?;
        Ok(stats)
    }

    fn reset(&mut self) {
        self.state.clear();
        self.tight.clear();
        self.rng = Rng::new(self.params.seed);
    }
}
