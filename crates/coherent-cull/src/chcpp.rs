//! CHC++ (Mattausch, Bittner, Wimmer 2008): coherent hierarchical culling with query batching
//! (i-queue, v-queue, render queue), randomized query intervals for visible leaves, multiqueries
//! and tight bounding volumes. Each part is a switch; with all of them off and a batch size of 1
//! the same traversal is the original CHC (Bittner et al. 2004), see `chc.rs`.

use std::collections::VecDeque;

use super::nohc::{NohcParams, NohcRule};
use super::{
    CullStats, Culler, FrameInput, Latency, OcclusionBackend, QueryId, QueryPurpose, View,
};
use crate::bvh::{DistanceQueue, ObjectBvh};
use crate::error::Result;
use crate::rng::Rng;
use crate::Aabb;

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
    /// Predicated mode: when a queried interior node comes back visible, the levels of its
    /// subtree opened at once (default 2): the nodes that many levels down are queried, and
    /// drawn under their own predicates, in the next frame (`u32::MAX`: open the whole subtree,
    /// as the next-frame modes do).
    pub predicated_levels: u32,
    /// Predicated mode: frames an interior node whose own query came back visible stays open
    /// (its children queried one by one) before it is queried as a whole again (default 10). A
    /// box that shows while its contents are hidden would otherwise draw its whole subtree
    /// under a true predicate every other frame.
    pub predicated_hold: u32,
    /// Predicated mode: the most objects a previously invisible node may put under one
    /// predicate in expectation, `(1 - p) · objects` with `p` its probability of staying
    /// invisible (default 8). A node above it is opened and its children are queried, each
    /// under its own predicate: more queries, fewer extra draws when a node turns visible.
    pub predicated_budget: f32,
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
            predicated_levels: 2,
            predicated_hold: 10,
            predicated_budget: 8.0,
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
                    p.batch_size = 50;
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
}

/// An issued query: its nodes are `query_nodes[first..first + count]`.
#[derive(Clone, Copy)]
struct Pending {
    id: QueryId,
    first: u32,
    count: u32,
    kind: QueryKind,
}

// k frames in flight for the latency modes (a child module: it reads the culler's state).
#[path = "latency_chcpp.rs"]
mod latency_chcpp;
// The predicated mode: conditional draws under the i-queue's queries.
#[path = "predicated.rs"]
mod predicated;

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
    /// NOHC's cost rule, when it decides the queries instead of CHC's rules (`nohc`).
    nohc: Option<NohcRule>,
    /// The eye of the current frame.
    eye: glam::Vec3,
    /// When query results are read (see [`Latency`]).
    latency: Latency,
    /// Per node, the last frame a query result gave its state (for the conservative mode).
    result_frame: Vec<u64>,
    /// Latency modes: the frames between issuing a query and reading it (`k`, default 1).
    frames_in_flight: u32,
    /// Latency modes with `k > 1`: the queries of the frames still in flight, oldest first.
    in_flight: latency_chcpp::InFlightQueries,
    /// Predicated mode: scratch for the objects of one conditional draw and a subtree walk.
    predicated: predicated::Scratch,
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
            structure: u64::MAX,
            rebuilds: 0,
            drawn: Vec::new(),
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
            query_nodes: Vec::new(),
            batch: Vec::new(),
            nohc: None,
            eye: glam::Vec3::ZERO,
            latency: Latency::InFrame,
            result_frame: Vec::new(),
            frames_in_flight: 1,
            in_flight: Default::default(),
            predicated: Default::default(),
        }
    }

    /// NOHC (Guthe et al. 2006): the CHC traversal (no batching, multiqueries or tight
    /// bounds) with the cost rule of [`NohcRule`] deciding which nodes are queried. See
    /// `nohc.rs`.
    pub fn nohc(params: NohcParams) -> Chcpp {
        let flush_interval = params.flush_interval.max(1) as usize;
        let mut c = Chcpp::named(
            "nohc",
            ChcppParams {
                flush_interval,
                ..ChcppParams::chc()
            },
        );
        c.nohc = Some(NohcRule::new(params));
        c
    }

    /// Sets the visibility threshold in pixels.
    pub fn set_pixel_threshold(&mut self, pixels: u64) {
        self.params.pixel_threshold = pixels;
    }

    /// The NOHC rule, when this traversal is NOHC.
    pub fn nohc_rule(&self) -> Option<&NohcRule> {
        self.nohc.as_ref()
    }

    /// The parameters.
    pub fn params(&self) -> &ChcppParams {
        &self.params
    }

    /// Fits the per-node state to the hierarchy. Refits keep it as it is (node ids are
    /// stable); inserted nodes start unknown; after a rebuild (new node ids) a leaf counts as
    /// visible last frame if one of its objects was drawn then, and that pulls up.
    fn prepare(&mut self, bvh: &ObjectBvh) {
        if self.drawn.len() < bvh.object_capacity() {
            self.drawn.resize(bvh.object_capacity(), 0);
        }
        if self.structure == bvh.structure() && self.state.len() == bvh.nodes.len() {
            return;
        }
        let renumbered = self.rebuilds != bvh.rebuilds() || self.state.len() > bvh.nodes.len();
        if self.state.is_empty() {
            self.frame = 0;
        }
        if renumbered {
            self.state.clear();
        }
        self.state.resize(bvh.nodes.len(), NodeState::default());
        if renumbered && self.frame > 0 {
            self.carry_visibility(bvh);
        }
        self.tight = vec![None; bvh.nodes.len()];
        if self.params.tight_bounds {
            for id in 0..bvh.nodes.len() as u32 {
                self.tight[id as usize] = tight_boxes(bvh, id, &self.params);
            }
        }
        self.structure = bvh.structure();
        self.rebuilds = bvh.rebuilds();
        self.reserve(bvh);
        if self.latency == Latency::Predicated {
            self.predicated.count_objects(bvh);
        }
    }

    /// After a rebuild: leaves with an object drawn last frame were visible last frame.
    fn carry_visibility(&mut self, bvh: &ObjectBvh) {
        for id in 0..bvh.nodes.len() as u32 {
            let n = &bvh.nodes[id as usize];
            let seen = bvh
                .objects(id)
                .iter()
                .any(|&o| self.drawn[o as usize] == self.frame);
            if n.is_leaf() && seen {
                self.pull_up_visibility(bvh, id);
                let s = &mut self.state[id as usize];
                s.next_query = self.frame + 1;
                s.tested = true;
            }
        }
    }

    /// Sizes every per-frame queue for the worst case of this hierarchy, so that steady
    /// frames never allocate: a frame visits each node at most once and queries each node at
    /// most twice (a failed multiquery re-queries its nodes one by one).
    fn reserve(&mut self, bvh: &ObjectBvh) {
        let nodes = bvh.nodes.len();
        let most_boxes = self.tight.iter().flatten().map(Vec::len).max().unwrap_or(1);
        self.drawn.reserve(bvh.object_capacity());
        let batch = self.params.batch_size.max(1);
        self.traversal.reserve(nodes);
        self.query_queue.reserve(2 * nodes);
        self.query_nodes.reserve(2 * nodes);
        self.i_queue.reserve(nodes);
        self.requery.reserve(nodes);
        self.v_queue.reserve(nodes);
        self.batch.reserve(nodes);
        self.render_queue.reserve(bvh.leaf_objects.len());
        self.boxes.reserve(batch * most_boxes);
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

    /// The boxes a node is queried with: its tight volume's current boxes (empty leaves left
    /// by removals skipped), or its own box.
    fn query_boxes(&self, bvh: &ObjectBvh, node: u32, out: &mut Vec<Aabb>) {
        match &self.tight[node as usize] {
            Some(t) if self.params.tight_bounds => out.extend(
                t.iter()
                    .map(|&d| bvh.nodes[d as usize].bounds)
                    .filter(Aabb::is_valid),
            ),
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

    /// Issues one query for `nodes` (a multiquery when several) with their boxes.
    fn issue(
        &mut self,
        bvh: &ObjectBvh,
        nodes: &[u32],
        kind: QueryKind,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        let mut boxes = std::mem::take(&mut self.boxes);
        boxes.clear();
        for &n in nodes {
            self.query_boxes(bvh, n, &mut boxes);
        }
        let purpose = match kind {
            QueryKind::Visible => QueryPurpose::VisibleLeaf,
            QueryKind::Invisible if nodes.len() > 1 => QueryPurpose::Multiquery,
            QueryKind::Invisible | QueryKind::Probe => QueryPurpose::Node,
        };
        let id = backend.issue_query_for(&boxes, purpose);
        self.boxes = boxes;
        let id = id?;
        stats.queries += 1;
        match kind {
            QueryKind::Invisible => stats.invisible_node_queries += 1,
            QueryKind::Visible => stats.visible_leaf_queries += 1,
            QueryKind::Probe => {}
        }
        if nodes.len() > 1 {
            stats.multiqueries += 1;
        }
        let first = self.query_nodes.len() as u32;
        self.query_nodes.extend_from_slice(nodes);
        self.query_queue.push_back(Pending {
            id,
            first,
            count: nodes.len() as u32,
            kind,
        });
        self.unsubmitted += 1;
        if !self.params.batching {
            backend.restore_render_state()?;
        }
        if !self.params.batching && self.unsubmitted >= self.params.flush_interval {
            self.submit(backend)?;
            self.unsubmitted = 0;
        }
        Ok(())
    }

    /// Issues each node of `self.batch` with its own query.
    fn issue_batch_singly(
        &mut self,
        bvh: &ObjectBvh,
        kind: QueryKind,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        let batch = std::mem::take(&mut self.batch);
        let result = batch
            .iter()
            .try_for_each(|&n| self.issue(bvh, &[n], kind, backend, stats));
        self.batch = batch;
        result
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
        // Issued before the traversal ran dry only once it holds `b` nodes; at the end of the
        // traversal it holds fewer.
        if self.i_queue_full() {
            stats.full_batches += 1;
        }
        self.flush_render_queue(backend)?;
        stats.query_batches += 1;
        // Nodes of failed multiqueries: one query each.
        self.batch.clear();
        self.batch.append(&mut self.requery);
        self.issue_batch_singly(bvh, QueryKind::Invisible, backend, stats)?;
        self.batch.clear();
        self.batch.append(&mut self.i_queue);
        if self.params.multiqueries && self.batch.len() > 1 {
            self.issue_multiqueries(bvh, backend, stats)?;
        } else {
            self.issue_batch_singly(bvh, QueryKind::Invisible, backend, stats)?;
        }
        // Due visible-leaf queries ride along while we are in query state anyway: no extra
        // state change for them.
        self.batch.clear();
        self.batch.append(&mut self.v_queue);
        self.issue_batch_singly(bvh, QueryKind::Visible, backend, stats)?;
        self.issue_probes(bvh, backend, stats)?;
        self.submit(backend)?;
        self.unsubmitted = 0;
        Ok(())
    }

    /// Groups the batch (i-queue nodes) greedily into multiqueries, highest probability of
    /// staying invisible first, and issues one query per group.
    fn issue_multiqueries(
        &mut self,
        bvh: &ObjectBvh,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        let mut nodes = std::mem::take(&mut self.batch);
        nodes.sort_by(|a, b| {
            self.stays_invisible(*b)
                .total_cmp(&self.stays_invisible(*a))
                .then(a.cmp(b))
        });
        let mut i = 0;
        let mut result = Ok(());
        while i < nodes.len() && result.is_ok() {
            let j = self.multiquery_group_end(&nodes, i);
            result = self.issue(bvh, &nodes[i..j], QueryKind::Invisible, backend, stats);
            i = j;
        }
        self.batch = nodes;
        result
    }

    /// The end of the multiquery group that starts at `nodes[i]` (sorted by `p`, highest
    /// first). A group M of several nodes costs `1 + (1 - Π p) · |M|` queries in expectation
    /// (the multiquery, plus one per node if it fails); a single query costs 1. The group grows
    /// while its benefit per cost, `|M| / cost(M)`, does not decrease; a single node is worth 1,
    /// so a pair is only formed when `p₁·p₂ > 1/2`.
    fn multiquery_group_end(&self, nodes: &[u32], i: usize) -> usize {
        let mut prod = 1.0f32;
        let mut best_value = 0.0f32;
        let mut objects = 0.0f32;
        let mut j = i;
        while j < nodes.len() {
            let pj = self.stays_invisible(nodes[j]).max(0.0);
            let size = (j - i + 1) as f32;
            if self.latency == Latency::Predicated {
                // A failed multiquery draws every node's objects under its predicate: the
                // group stays within the expected extra draws a predicate may cost.
                objects += self.predicated.objects_below(nodes[j]) as f32;
                if j > i && (1.0 - prod * pj) * objects > self.params.predicated_budget {
                    break;
                }
            }
            let cost = if j == i {
                1.0
            } else {
                1.0 + (1.0 - prod * pj) * size
            };
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

    /// `p(k) = 0.99 - 0.7 e^(-k)`: the probability that a node invisible for `k` frames stays
    /// invisible (fitted by the paper's authors); `k` counts the frames since it was last
    /// visible, not counting this one, frustum-culled frames included, but only within its
    /// current run of visits (`watched_since`). A node that was not visited last frame (it lay
    /// below a closed node, e.g. a car whose parent was just opened) has no recent history:
    /// k = 0, then 1, 2, ... as it is seen invisible frame after frame, however long ago it
    /// was last visible. Counting from its last visibility instead (frame 0 for a node never
    /// visible) made a node seen invisible once look like p = 0.99, and on `parking` and
    /// `city` half of all multiqueries failed.
    fn stays_invisible(&self, node: u32) -> f32 {
        let s = &self.state[node as usize];
        let k = self
            .frame
            .saturating_sub((s.last_visible + 1).max(s.watched_since));
        0.99 - 0.7 * (-(k as f32)).exp()
    }

    /// Issues up to `limit` v-queue queries as one batch.
    fn issue_v_queue(
        &mut self,
        bvh: &ObjectBvh,
        limit: usize,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        if self.v_queue.is_empty() && self.predicated.probes.is_empty() {
            return Ok(());
        }
        self.flush_render_queue(backend)?;
        stats.query_batches += 1;
        let n = limit.min(self.v_queue.len());
        self.batch.clear();
        self.batch.extend(self.v_queue.drain(..n));
        self.issue_batch_singly(bvh, QueryKind::Visible, backend, stats)?;
        self.issue_probes(bvh, backend, stats)?;
        self.submit(backend)?;
        self.unsubmitted = 0;
        Ok(())
    }

    /// A query's result: a visible multiquery re-queues its nodes for single queries; a
    /// visible single query opens its node (previously invisible) and pulls visibility up; an
    /// invisible result marks every node of the query invisible.
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
        if self.latency != Latency::InFrame {
            self.handle_late_result(bvh, q, visible, stats);
            return Ok(());
        }
        if let Some(rule) = self.nohc.as_mut() {
            for &n in &self.query_nodes[q.first as usize..(q.first + q.count) as usize] {
                rule.record(n, !visible);
            }
        }
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
        self.predicated.probes.clear();
        self.render_queue.clear();
        self.query_nodes.clear();
        self.unsubmitted = 0;
        self.traversal
            .push(0, bvh.nodes[0].bounds.distance_squared(eye));
    }

    /// Whether queries wait in the i- and v-queues (batching; always in the predicated mode,
    /// whose predicates need the queries before the conditional draws).
    fn queues_queries(&self) -> bool {
        self.params.batching || self.latency == Latency::Predicated
    }

    /// Nodes per i-queue batch (`b`; 1 without batching).
    fn i_queue_batch_size(&self) -> usize {
        if self.params.batching {
            self.params.batch_size.max(1)
        } else {
            1
        }
    }

    /// Whether the i-queue (with the nodes of failed multiqueries) holds a full batch. Never
    /// in the predicated mode: its i-queue goes out once, after the traversal.
    fn i_queue_full(&self) -> bool {
        self.latency != Latency::Predicated
            && self.i_queue.len() + self.requery.len() >= self.i_queue_batch_size()
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
        if self.latency != Latency::InFrame {
            // Results are read after the frame (for the next one).
            return Ok(());
        }
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
        if !view.frustum.intersects(bounds) {
            self.frustum_cull(node, stats);
        } else if view.eye_inside(bounds) {
            self.traverse_unqueryable(bvh, node, view.eye, stats);
        } else if !self.was_visible(node) && self.stale_in_latency_mode(node) {
            self.traverse_conservatively(bvh, node, view.eye, stats);
        } else if !self.was_visible(node) && self.held_open(bvh, node) {
            self.traverse_held_open(bvh, node, view.eye, stats);
        } else if !self.was_visible(node) {
            self.query_previously_invisible(bvh, node, backend, stats)?;
        } else {
            self.traverse_previously_visible(bvh, node, view.eye, backend, stats)?;
        }
        self.state[node as usize].seen_epoch = bvh.epoch();
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
        if let Some(rule) = self.nohc.as_mut() {
            if !rule.query_invisible(bvh, node, self.frame) {
                // Not worth a query: open it as if it were visible (conservative).
                self.state[node as usize].tested = true;
                let eye = self.eye;
                self.traverse_unqueryable(bvh, node, eye, stats);
                return Ok(());
            }
        }
        let grown = bvh.grown_since(node, self.state[node as usize].seen_epoch);
        let s = &mut self.state[node as usize];
        if s.last_visited + 1 < self.frame || grown {
            s.watched_since = self.frame;
        }
        s.last_visited = self.frame;
        s.tested = true;
        if self.over_predicate_budget(bvh, node) {
            // Predicated: too many objects would wait on one predicate; its children are
            // queried instead.
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
        let due = match self.nohc.as_mut() {
            Some(rule) => rule.query_visible_leaf(bvh, node, self.frame),
            None => self.query_reasonable(node),
        };
        self.pull_up_visibility(bvh, node);
        if due {
            self.state[node as usize].next_query =
                self.frame + self.params.visible_interval.max(1) as u64;
            if self.queues_queries() {
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
        self.issue(bvh, &[node], kind, backend, stats)
    }

    /// The traversal queue ran dry: issue the i-queue (unbatched: submit what was recorded).
    fn issue_remaining_queries(
        &mut self,
        bvh: &ObjectBvh,
        view: &View,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        if self.latency == Latency::Predicated {
            return self.issue_predicated(bvh, view, backend, stats);
        }
        self.issue_i_queue(bvh, backend, stats)?;
        if !self.params.batching && self.unsubmitted > 0 {
            self.flush_render_queue(backend)?;
            self.submit(backend)?;
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
        if self.reads_frames_later() {
            return self.submit_frame_in_flight(bvh, backend);
        }
        backend.finish()?;
        while let Some(q) = self.query_queue.pop_front() {
            let pixels = if self.latency == Latency::InFrame {
                backend.wait_query(q.id)?
            } else {
                // Never waits: a result not back yet leaves the last known state.
                match backend.query_result(q.id)? {
                    Some(p) => p,
                    None => continue,
                }
            };
            self.handle_returned_query(bvh, q, pixels, eye, backend, stats)?;
        }
        Ok(())
    }
}

/// Tight bounding volume of `node`: the boxes of its descendants one level further down at a
/// time (leaves stand for themselves), as long as their total surface area stays within
/// `tight_area_factor` times the node's, up to `tight_depth` levels; the deepest level that
/// passes wins. `None` when already the first level fails (query the node's own box).
fn tight_boxes(bvh: &ObjectBvh, node: u32, params: &ChcppParams) -> Option<Vec<u32>> {
    let root = &bvh.nodes[node as usize];
    if root.is_leaf() {
        return None;
    }
    let limit = params.tight_area_factor * root.bounds.surface_area();
    let mut level = vec![node];
    let mut best = None;
    for _ in 0..params.tight_depth {
        let mut next = Vec::with_capacity(level.len() * 2);
        for &n in &level {
            let nn = &bvh.nodes[n as usize];
            if nn.is_leaf() {
                next.push(n);
            } else {
                next.extend_from_slice(&nn.children);
            }
        }
        if next == level {
            break; // only leaves left
        }
        let area: f32 = next
            .iter()
            .map(|&n| bvh.nodes[n as usize].bounds.surface_area())
            .sum();
        if area > limit {
            break;
        }
        best = Some(next.clone());
        level = next;
    }
    best
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
        let view = View::new(&input.view);
        let eye = view.eye;
        let mut stats = CullStats::default();
        if self.latency == Latency::Predicated && !backend.supports_predicates() {
            return Err(crate::predicates_unsupported());
        }
        self.read_frames_in_flight(bvh, backend, &mut stats)?;
        self.begin_frame(bvh, eye);
        self.eye = eye;
        if let Some(rule) = self.nohc.as_mut() {
            rule.begin_frame(bvh, input.view.view_proj);
        }
        // In a latency mode queries are read after the frame: only the traversal drives it.
        let in_frame = self.latency == Latency::InFrame;
        while !self.traversal.is_empty() || (in_frame && !self.query_queue.is_empty()) {
            // 1. Process finished occlusion queries.
            self.process_finished_queries(bvh, eye, backend, &mut stats)?;
            // 2. Hierarchical traversal.
            if let Some(node) = self.traversal.pop() {
                self.visit_node(input, &view, node, backend, &mut stats)?;
            }
            if self.traversal.is_empty() {
                self.issue_remaining_queries(bvh, &view, backend, &mut stats)?;
            }
        }
        self.end_frame(bvh, eye, backend, &mut stats)?;
        Ok(stats)
    }

    fn reset(&mut self) {
        self.state.clear();
        self.tight.clear();
        self.forget_frames_in_flight();
        if let Some(rule) = self.nohc.as_mut() {
            rule.reset();
        }
        self.structure = u64::MAX;
        self.rng = Rng::new(self.params.seed);
    }
}

/// The latency modes ([`Latency::NextFrame`], [`Latency::NextFrameConservative`]): queries are
/// issued as in CHC++ but never read inside the frame; their results, read after it, decide the
/// next frame.
impl Chcpp {
    /// The same culler reading its query results in `latency` mode.
    pub fn with_latency(mut self, latency: Latency) -> Chcpp {
        self.latency = latency;
        self
    }

    /// The latency mode.
    pub fn latency(&self) -> Latency {
        self.latency
    }

    /// Submits recorded work so its queries can complete; in a latency mode nothing is
    /// submitted before the frame's end (one submission per frame).
    fn submit(&mut self, backend: &mut dyn OcclusionBackend) -> Result<()> {
        if self.latency == Latency::InFrame {
            backend.flush()?;
        }
        Ok(())
    }

    /// In the conservative mode, whether a node's last known state is too old to trust (no
    /// query result for it last frame: it entered the frustum, or its parent was closed).
    fn stale_in_latency_mode(&mut self, node: u32) -> bool {
        if self.latency != Latency::NextFrameConservative {
            return false;
        }
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
        let s = &mut self.state[node as usize];
        s.last_visited = self.frame;
        s.tested = true;
        if bvh.nodes[node as usize].is_leaf() {
            s.next_query = self.frame + self.params.visible_interval.max(1) as u64;
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
        if self.latency == Latency::Predicated {
            self.handle_predicated_result(bvh, q, visible, stats);
            return;
        }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;
    use crate::camera::CameraPose;
    use glam::Vec3;

    /// A backend without a GPU: a query sees pixels when one of its boxes touches a region
    /// marked visible. Results are ready at once, or with `hold` only after a wait, which
    /// completes everything issued so far (a device that runs in order). It logs every
    /// query's box count.
    #[derive(Default)]
    struct Mock {
        visible: Vec<Aabb>,
        results: Vec<u64>,
        boxes_per_query: Vec<usize>,
        hold: bool,
        completed: usize,
    }

    fn touches(a: &Aabb, b: &Aabb) -> bool {
        a.min.cmple(b.max).all() && b.min.cmple(a.max).all()
    }

    impl OcclusionBackend for Mock {
        fn draw_objects(&mut self, _objects: &[u32]) -> Result<()> {
            Ok(())
        }
        fn issue_query(&mut self, boxes: &[Aabb]) -> Result<QueryId> {
            let hit = boxes
                .iter()
                .any(|b| self.visible.iter().any(|v| touches(b, v)));
            self.results.push(if hit { 100 } else { 0 });
            self.boxes_per_query.push(boxes.len());
            Ok(self.results.len() as u32 - 1)
        }
        fn flush(&mut self) -> Result<()> {
            Ok(())
        }
        fn query_result(&mut self, query: QueryId) -> Result<Option<u64>> {
            if self.hold && query as usize >= self.completed {
                return Ok(None);
            }
            Ok(self.results.get(query as usize).copied())
        }
        fn wait_query(&mut self, query: QueryId) -> Result<u64> {
            self.completed = self.results.len();
            Ok(self.results[query as usize])
        }
        fn finish(&mut self) -> Result<()> {
            Ok(())
        }
    }

    /// 16 unit boxes in a row along x, seen from the front.
    fn row() -> (ObjectBvh, Camera) {
        let boxes: Vec<Aabb> = (0..16)
            .map(|i| {
                let x = i as f32 * 2.0;
                Aabb::new(Vec3::new(x, 0.0, 0.0), Vec3::new(x + 1.0, 1.0, 1.0))
            })
            .collect();
        let bvh = ObjectBvh::build(&boxes, 1);
        let pose = CameraPose {
            eye: Vec3::new(15.0, 0.5, 60.0),
            target: Vec3::new(15.0, 0.5, 0.0),
        };
        (bvh, Camera::from_pose(pose, 1.0, 500.0))
    }

    fn frame(c: &mut Chcpp, bvh: &ObjectBvh, cam: &Camera, m: &mut Mock, f: u64) -> CullStats {
        m.results.clear();
        m.boxes_per_query.clear();
        m.completed = 0;
        let input = FrameInput {
            bvh,
            view: cam.into(),
            frame: f,
            exact_visible: None,
        };
        c.cull_frame(&input, m).unwrap()
    }

    fn leaves(bvh: &ObjectBvh) -> Vec<u32> {
        (0..bvh.nodes.len() as u32)
            .filter(|&n| bvh.nodes[n as usize].is_leaf())
            .collect()
    }

    #[test]
    fn multiqueries_update_every_node_and_failed_ones_requery() {
        let (bvh, cam) = row();
        let params = ChcppParams {
            tight_bounds: false,
            ..ChcppParams::default()
        };
        let mut c = Chcpp::new(params);
        // Only the first box is visible: the rest of the hierarchy becomes the invisible cut.
        let mut m = Mock {
            visible: vec![Aabb::new(
                Vec3::new(0.2, 0.2, 0.2),
                Vec3::new(0.8, 0.8, 0.8),
            )],
            ..Mock::default()
        };
        let mut saw_invisible_multiquery = false;
        for f in 1..12 {
            let s = frame(&mut c, &bvh, &cam, &mut m, f);
            if s.multiqueries > 0 && s.failed_multiqueries == 0 {
                saw_invisible_multiquery = true;
                // Every node of a multiquery got the invisible result in this frame.
                assert!(
                    s.query_culled > s.invisible_node_queries.saturating_sub(s.visible_results)
                );
                for n in 0..bvh.nodes.len() {
                    let st = &c.state[n];
                    if st.last_visited == c.frame && !st.visible {
                        assert_ne!(st.last_visible, c.frame);
                    }
                }
            }
        }
        assert!(saw_invisible_multiquery, "the invisible cut was grouped");
        // Now everything is visible: the multiqueries fail and their nodes are re-queried
        // one by one in the same frame.
        m.visible = vec![Aabb::new(Vec3::splat(-100.0), Vec3::splat(100.0))];
        let s = frame(&mut c, &bvh, &cam, &mut m, 12);
        assert!(s.failed_multiqueries > 0);
        assert!(s.queries > s.multiqueries + s.failed_multiqueries);
        // Each failed multiquery held at least two nodes, and each of them got a query.
        assert!(s.requeried >= 2 * s.failed_multiqueries);
        assert!(s.invisible_node_queries >= s.multiqueries + s.requeried);
        for l in leaves(&bvh) {
            assert!(c.state[l as usize].visible, "leaf {l} found visible again");
        }
    }

    #[test]
    fn round_trips_and_full_batches_are_counted() {
        let (bvh, cam) = row();
        let params = ChcppParams {
            batch_size: 2,
            multiqueries: false,
            tight_bounds: false,
            ..ChcppParams::default()
        };
        let mut c = Chcpp::new(params.clone());
        let mut m = Mock {
            visible: vec![Aabb::new(Vec3::splat(-100.0), Vec3::splat(100.0))],
            hold: true,
            ..Mock::default()
        };
        // First frame: nothing is known, everything is visible, so the hierarchy is opened one
        // level per round trip: the traversal runs dry and waits once per level.
        let levels = bvh.nodes.iter().map(|n| n.depth).max().unwrap() + 1;
        let s = frame(&mut c, &bvh, &cam, &mut m, 1);
        assert_eq!(s.blocking_waits, levels);
        // Every node was tested once, each with its own query.
        assert_eq!(s.invisible_nodes_tested as usize, bvh.nodes.len());
        assert_eq!(s.invisible_node_queries, s.invisible_nodes_tested);
        // The root went out alone when the traversal ran dry; wider levels fill batches of 2.
        assert!(s.full_batches > 0 && s.full_batches < s.query_batches);
        // Results ready at once: nothing waits.
        let mut c = Chcpp::new(params);
        m.hold = false;
        let s = frame(&mut c, &bvh, &cam, &mut m, 1);
        assert_eq!(s.blocking_waits, 0);
    }

    #[test]
    fn visibility_survives_refits_and_rebuilds() {
        let (mut bvh, cam) = row();
        let mut c = Chcpp::new(ChcppParams::default());
        let mut m = Mock {
            visible: vec![Aabb::new(Vec3::splat(-100.0), Vec3::splat(100.0))],
            ..Mock::default()
        };
        for f in 1..4 {
            frame(&mut c, &bvh, &cam, &mut m, f);
        }
        // A refit (one box moved): node ids and their history stay; nothing visible last
        // frame is queried as invisible.
        let moved = Aabb::new(Vec3::new(0.0, 0.5, 0.0), Vec3::new(1.0, 1.5, 1.0));
        bvh.set_bounds(0, moved).unwrap();
        assert!(!bvh.update().rebuilt);
        let s = frame(&mut c, &bvh, &cam, &mut m, 4);
        assert_eq!(s.invisible_node_queries, 0);
        assert_eq!(s.objects_drawn, 16);
        // A rebuild renumbers the nodes: visibility is carried over through the objects
        // drawn last frame, so again nothing is queried as invisible.
        bvh.rebuild();
        let s = frame(&mut c, &bvh, &cam, &mut m, 5);
        assert_eq!(s.invisible_node_queries, 0);
        assert_eq!(s.objects_drawn, 16);
        // Without that history (a fresh culler), the root is queried first.
        let mut fresh = Chcpp::new(ChcppParams::default());
        let s = frame(&mut fresh, &bvh, &cam, &mut m, 1);
        assert!(s.invisible_node_queries > 0);
    }

    #[test]
    fn frustum_culled_nodes_keep_their_age() {
        let (bvh, cam) = row();
        let mut c = Chcpp::new(ChcppParams::default());
        let mut m = Mock::default();
        frame(&mut c, &bvh, &cam, &mut m, 1);
        let node = leaves(&bvh)[3];
        let mut stats = CullStats::default();
        c.frame = 7;
        c.state[node as usize].last_visible = 2;
        c.state[node as usize].tested = true;
        let before = c.stays_invisible(node);
        c.frustum_cull(node, &mut stats);
        assert_eq!(c.state[node as usize].last_visible, 2);
        c.frame = 8;
        assert!(
            c.stays_invisible(node) > before,
            "k grows while out of the frustum"
        );
    }

    #[test]
    fn age_counts_from_the_first_visit_of_a_run() {
        let (bvh, _) = row();
        let mut c = Chcpp::new(ChcppParams::default());
        c.prepare(&bvh);
        let node = leaves(&bvh)[3];
        let (mut m, mut stats) = (Mock::default(), CullStats::default());
        // Never visible, last visited at frame 10 (then below a closed node), visited again
        // at frame 50: nothing is known of frames 11-49, so it is 0 frames old, not 49.
        c.state[node as usize].last_visited = 10;
        c.frame = 50;
        c.query_previously_invisible(&bvh, node, &mut m, &mut stats)
            .unwrap();
        let p = |k: f32| 0.99 - 0.7 * (-k).exp();
        assert!((c.stays_invisible(node) - p(0.0)).abs() < 1e-6);
        // Seen invisible in the next frames, it ages one frame per frame.
        for f in 51..54 {
            c.frame = f;
            c.query_previously_invisible(&bvh, node, &mut m, &mut stats)
                .unwrap();
            assert!((c.stays_invisible(node) - p((f - 50) as f32)).abs() < 1e-6);
        }
        assert_eq!(
            stats.queries, 0,
            "below the batch size nothing is issued yet"
        );
    }

    #[test]
    fn a_single_query_costs_one() {
        let (bvh, _) = row();
        let mut c = Chcpp::new(ChcppParams::default());
        c.prepare(&bvh);
        c.frame = 1;
        // Two nodes seen a frame ago: p(0) = 0.29 each, far from paying off as a pair.
        let nodes = leaves(&bvh);
        for &n in &nodes[..2] {
            c.state[n as usize].last_visible = 1;
        }
        assert_eq!(c.multiquery_group_end(&nodes[..2], 0), 1);
        // Long invisible (p close to 0.99): grouped.
        c.frame = 50;
        assert!(c.multiquery_group_end(&nodes, 0) > 4);
    }

    /// The nodes `levels` below `node` (leaves stand for themselves).
    fn frontier(bvh: &ObjectBvh, node: u32, levels: u32) -> Vec<u32> {
        let mut level = vec![node];
        for _ in 0..levels {
            level = level
                .iter()
                .flat_map(|&n| {
                    let nn = &bvh.nodes[n as usize];
                    if nn.is_leaf() {
                        vec![n]
                    } else {
                        nn.children.to_vec()
                    }
                })
                .collect();
        }
        level
    }

    #[test]
    fn tight_bounds_descend_level_by_level() {
        // Overlapping boxes: each level down covers more total area than the one above.
        let boxes: Vec<Aabb> = (0..16)
            .map(|i| {
                let o = Vec3::new(i as f32 * 0.3, (i % 3) as f32 * 0.2, (i % 5) as f32 * 0.1);
                Aabb::new(o, o + Vec3::splat(2.0))
            })
            .collect();
        let bvh = ObjectBvh::build(&boxes, 1);
        let root_area = bvh.nodes[0].bounds.surface_area();
        let ratio = |levels| {
            let area: f32 = frontier(&bvh, 0, levels)
                .iter()
                .map(|&n| bvh.nodes[n as usize].bounds.surface_area())
                .sum();
            area / root_area
        };
        let (r1, r2, r3) = (ratio(1), ratio(2), ratio(3));
        assert!(r1 < r3 && r2 < r3, "areas grow with depth: {r1} {r2} {r3}");
        // A factor that the first level passes and the third fails.
        let factor = (r1.max(r2) + r3) / 2.0;
        let params = ChcppParams {
            tight_area_factor: factor,
            tight_depth: 3,
            ..ChcppParams::default()
        };
        let tight = tight_boxes(&bvh, 0, &params).expect("level 1 passes");
        let expected = if r2 <= factor { 2 } else { 1 };
        assert_eq!(tight.len(), frontier(&bvh, 0, expected).len());
        // The old all-or-nothing rule at depth 3 would have given nothing here; a factor
        // that level 1 fails gives nothing too.
        let strict = ChcppParams {
            tight_area_factor: r1 * 0.9,
            ..params
        };
        assert!(tight_boxes(&bvh, 0, &strict).is_none());
    }
}
