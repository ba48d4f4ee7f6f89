//! The culler's state and how it follows the hierarchy: construction, and the per-node state
//! fitted to the [`ObjectBvh`] each frame (kept through refits, carried over rebuilds through the
//! objects drawn last frame), with every queue sized so that steady frames do not allocate.

use std::collections::VecDeque;

use super::rules::PaperRule;
use super::tight::tight_boxes;
use super::{latency, Chcpp, ChcppParams, NodeState};
use crate::bvh::{DistanceQueue, ObjectBvh};
use crate::nohc::{NohcParams, NohcRule};
use crate::rng::Rng;
use crate::Latency;

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
            batch_order: Vec::new(),
            rule: Box::new(PaperRule),
            eye: glam::Vec3::ZERO,
            frame_view: None,
            mode: latency::mode(Latency::InFrame),
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
        c.rule = Box::new(NohcRule::new(params));
        c
    }

    /// Sets the visibility threshold in pixels.
    pub fn set_pixel_threshold(&mut self, pixels: u64) {
        self.params.pixel_threshold = pixels;
    }

    /// The NOHC rule, when this traversal is NOHC.
    pub fn nohc_rule(&self) -> Option<&NohcRule> {
        self.rule.nohc()
    }

    /// The parameters.
    pub fn params(&self) -> &ChcppParams {
        &self.params
    }

    /// The same culler reading its query results in `latency` mode.
    pub fn with_latency(mut self, latency: Latency) -> Chcpp {
        self.mode = latency::mode(latency);
        // Whether tight volumes are used depends on the mode: fit them again at the next frame.
        self.structure = u64::MAX;
        self
    }

    /// The latency mode.
    pub fn latency(&self) -> Latency {
        self.mode.latency()
    }

    /// Fits the per-node state to the hierarchy. Refits keep it as it is (node ids are
    /// stable); inserted nodes start unknown; after a rebuild (new node ids) a leaf counts as
    /// visible last frame if one of its objects was drawn then, and that pulls up.
    pub(super) fn prepare(&mut self, bvh: &ObjectBvh) {
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
        if self.uses_tight_bounds() {
            for id in 0..bvh.nodes.len() as u32 {
                self.tight[id as usize] = tight_boxes(bvh, id, &self.params);
            }
        }
        self.structure = bvh.structure();
        self.rebuilds = bvh.rebuilds();
        self.reserve(bvh);
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
}
