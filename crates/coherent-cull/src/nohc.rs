//! NOHC (Guthe, Balázs, Klein 2006, "Near Optimal Hierarchical Culling"): issue an occlusion
//! query only where a cost model says it pays. A query for a node is worth it when the expected
//! saving, P(occluded) × the cost of rendering the node's subtree, exceeds the query's own cost;
//! both costs come from a [`CostModel`] measured on the device (`coherent calibrate`).
//!
//! Here NOHC is the CHC traversal (front to back, previously visible interior nodes opened
//! without a query, query results handled as they return, pull-up) with this rule deciding every
//! query instead of CHC's "query everything on the cut and every visible leaf":
//! - a node invisible last frame (or never seen) is queried only if
//!   `P_occ · render_cost(subtree) > query_cost + round_trip / flush_interval` (its result is
//!   needed within the frame, so it pays its share of a segment round trip); otherwise it is
//!   opened and rendered without a query (conservative: nothing visible is lost);
//! - a visible leaf is rendered and queried (for the next frame) only if
//!   `P_turns_occluded · render_cost(leaf) > query_cost`.
//!
//! The occlusion probability of a node comes from its history and its screen coverage:
//! `P_occ = h · (1 − c)^coverage_exponent`, where `h` is an exponential moving average of the
//! node's query outcomes (1 = occluded; `prior` before any query; `history_weight` for the newest
//! outcome) and `c` the fraction of the screen its box covers (a box filling the screen is
//! rarely occluded by what is in front of it). For a visible leaf, the chance that it turned
//! occluded grows with the frames `t` since it was last tested:
//! `P_turns_occluded = 1 − (1 − visible_turnover)^t`.

use glam::Mat4;

use crate::bvh::ObjectBvh;
use crate::Aabb;

/// Per-operation costs of the device in milliseconds, measured by `coherent calibrate`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct CostModel {
    /// One draw call (state already bound).
    pub draw_ms: f64,
    /// One triangle submitted (vertex processing and setup, little coverage).
    pub triangle_ms: f64,
    /// One shaded fragment (a pixel of a rendered object).
    pub fragment_ms: f64,
    /// One occlusion query with a small box: begin, box draw, end, result read.
    pub query_ms: f64,
    /// One pixel of query-box fill (depth test only).
    pub query_fragment_ms: f64,
    /// One segment round trip: end rendering, submit, signal, wait, read back.
    pub round_trip_ms: f64,
}

impl CostModel {
    /// Whether every figure is finite and positive (a model fit to use).
    pub fn is_valid(&self) -> bool {
        [
            self.draw_ms,
            self.triangle_ms,
            self.fragment_ms,
            self.query_ms,
            self.query_fragment_ms,
            self.round_trip_ms,
        ]
        .iter()
        .all(|v| v.is_finite() && *v > 0.0)
    }
}

/// NOHC's parameters (the cost model's constants come from calibration).
#[derive(Clone, Debug, PartialEq)]
pub struct NohcParams {
    /// The device's costs.
    pub costs: CostModel,
    /// Pixels of the render target (width, height), for screen coverage.
    pub viewport: (u32, u32),
    /// Triangles of each object (index = object id).
    pub object_triangles: Vec<u32>,
    /// Occlusion probability `h` of a node with no query history (default 0.5).
    pub prior: f32,
    /// Weight of the newest query outcome in `h` (default 0.5).
    pub history_weight: f32,
    /// Exponent of the coverage term `(1 − c)^e` (default 1).
    pub coverage_exponent: f32,
    /// Per-frame chance that a visible leaf became occluded (default 0.05).
    pub visible_turnover: f32,
    /// Queries per segment that share a round trip (the CHC flush interval, default 16).
    pub flush_interval: u32,
}

impl NohcParams {
    /// Defaults for `costs`, a `viewport` and the scene's per-object triangle counts.
    pub fn new(costs: CostModel, viewport: (u32, u32), object_triangles: Vec<u32>) -> NohcParams {
        NohcParams {
            costs,
            viewport,
            object_triangles,
            prior: 0.5,
            history_weight: 0.5,
            coverage_exponent: 1.0,
            visible_turnover: 0.05,
            flush_interval: 16,
        }
    }
}

/// The per-node state and the decisions of NOHC's cost rule. The traversal that uses it lives
/// in `chcpp/` (NOHC is the CHC traversal with this rule as its query rule, `chcpp/rules.rs`).
pub struct NohcRule {
    params: NohcParams,
    /// Per node: objects and triangles of the subtree.
    subtree: Vec<(u32, u64)>,
    /// Per node: the occlusion history `h`.
    history: Vec<f32>,
    /// Per node: the frame of the last query (0: never).
    last_test: Vec<u64>,
    view_proj: Mat4,
    /// Rule outcomes this frame: (queried, skipped).
    pub decisions: (u32, u32),
}

impl NohcRule {
    /// A rule with `params`; per-node state is sized on the first frame.
    pub fn new(params: NohcParams) -> NohcRule {
        NohcRule {
            params,
            subtree: Vec::new(),
            history: Vec::new(),
            last_test: Vec::new(),
            view_proj: Mat4::IDENTITY,
            decisions: (0, 0),
        }
    }

    /// The parameters.
    pub fn params(&self) -> &NohcParams {
        &self.params
    }

    /// Sizes the per-node state for `bvh` (when it changed) and takes the frame's camera.
    pub fn begin_frame(&mut self, bvh: &ObjectBvh, view_proj: Mat4) {
        if self.subtree.len() != bvh.nodes.len() {
            self.subtree = subtree_sums(bvh, &self.params.object_triangles);
            self.history = vec![self.params.prior; bvh.nodes.len()];
            self.last_test = vec![0; bvh.nodes.len()];
        }
        self.view_proj = view_proj;
        self.decisions = (0, 0);
    }

    /// Forgets the history.
    pub fn reset(&mut self) {
        self.subtree.clear();
        self.history.clear();
        self.last_test.clear();
    }

    /// Whether a node that was invisible last frame (or is new) is worth a query in `frame`;
    /// if not, the traversal opens it without one.
    pub fn query_invisible(&mut self, bvh: &ObjectBvh, node: u32, frame: u64) -> bool {
        let c = &self.params.costs;
        let pixels = self.screen_pixels(&bvh.nodes[node as usize].bounds);
        let p = self.occluded(node, pixels);
        let saving = p as f64 * self.render_cost(node, pixels);
        let cost = self.query_cost(pixels)
            + c.round_trip_ms / f64::from(self.params.flush_interval.max(1));
        self.decide(saving > cost, node, frame)
    }

    /// Whether a visible leaf rendered in `frame` is worth a query for the next frame.
    pub fn query_visible_leaf(&mut self, bvh: &ObjectBvh, node: u32, frame: u64) -> bool {
        let pixels = self.screen_pixels(&bvh.nodes[node as usize].bounds);
        let t = frame
            .saturating_sub(self.last_test[node as usize])
            .min(1 << 20) as i32;
        let p = 1.0 - (1.0 - self.params.visible_turnover.clamp(0.0, 1.0)).powi(t);
        let saving = p as f64 * self.render_cost(node, pixels);
        self.decide(saving > self.query_cost(pixels), node, frame)
    }

    /// A query result for `node`: updates its history.
    pub fn record(&mut self, node: u32, occluded: bool) {
        if let Some(h) = self.history.get_mut(node as usize) {
            let w = self.params.history_weight.clamp(0.0, 1.0);
            *h = (1.0 - w) * *h + w * if occluded { 1.0 } else { 0.0 };
        }
    }

    fn decide(&mut self, query: bool, node: u32, frame: u64) -> bool {
        if query {
            self.decisions.0 += 1;
            self.last_test[node as usize] = frame;
        } else {
            self.decisions.1 += 1;
        }
        query
    }

    /// `P_occ = h · (1 − c)^e`.
    fn occluded(&self, node: u32, pixels: f64) -> f32 {
        let (w, h) = self.params.viewport;
        let screen = (f64::from(w) * f64::from(h)).max(1.0);
        let coverage = (pixels / screen).clamp(0.0, 1.0) as f32;
        self.history[node as usize] * (1.0 - coverage).powf(self.params.coverage_exponent)
    }

    /// Cost of rendering the node's subtree: its draws, triangles and the fragments of its
    /// screen footprint.
    fn render_cost(&self, node: u32, pixels: f64) -> f64 {
        let c = &self.params.costs;
        let (objects, triangles) = self.subtree[node as usize];
        f64::from(objects) * c.draw_ms + triangles as f64 * c.triangle_ms + pixels * c.fragment_ms
    }

    /// Cost of one query whose box covers `pixels`.
    fn query_cost(&self, pixels: f64) -> f64 {
        let c = &self.params.costs;
        c.query_ms + pixels * c.query_fragment_ms
    }

    /// Screen pixels covered by the bounding rectangle of the projected box (the whole screen
    /// when the box reaches behind the eye).
    fn screen_pixels(&self, b: &Aabb) -> f64 {
        let (w, h) = self.params.viewport;
        let (w, h) = (f64::from(w), f64::from(h));
        let Some((lo, hi)) = crate::camera::projected_rect(&self.view_proj, b) else {
            return w * h;
        };
        let lo = lo.clamp(glam::Vec2::splat(-1.0), glam::Vec2::splat(1.0));
        let hi = hi.clamp(glam::Vec2::splat(-1.0), glam::Vec2::splat(1.0));
        let size = (hi - lo).max(glam::Vec2::ZERO) * 0.5;
        f64::from(size.x) * w * f64::from(size.y) * h
    }
}

/// Objects and triangles below every node (children come after parents, so one backward
/// pass sums them).
fn subtree_sums(bvh: &ObjectBvh, object_triangles: &[u32]) -> Vec<(u32, u64)> {
    let mut sums = vec![(0u32, 0u64); bvh.nodes.len()];
    for id in (0..bvh.nodes.len()).rev() {
        let n = &bvh.nodes[id];
        if n.is_leaf() {
            let objects = bvh.objects(id as u32);
            let tris: u64 = objects
                .iter()
                .map(|&o| u64::from(object_triangles.get(o as usize).copied().unwrap_or(0)))
                .sum();
            sums[id] = (objects.len() as u32, tris);
        } else {
            let [a, b] = n.children;
            let (sa, sb) = (sums[a as usize], sums[b as usize]);
            sums[id] = (sa.0 + sb.0, sa.1 + sb.1);
        }
    }
    sums
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;
    use crate::camera::CameraPose;
    use glam::Vec3;

    fn costs() -> CostModel {
        CostModel {
            draw_ms: 0.05,
            triangle_ms: 1e-5,
            fragment_ms: 1e-6,
            query_ms: 0.1,
            query_fragment_ms: 5e-7,
            round_trip_ms: 0.3,
        }
    }

    fn setup(triangles: u32) -> (ObjectBvh, NohcRule) {
        let bounds = vec![
            Aabb::new(Vec3::new(-1.0, -1.0, -11.0), Vec3::new(1.0, 1.0, -9.0)),
            Aabb::new(Vec3::new(4.0, -1.0, -31.0), Vec3::new(6.0, 1.0, -29.0)),
        ];
        let bvh = ObjectBvh::build(&bounds, 1);
        let params = NohcParams::new(costs(), (640, 360), vec![triangles; 2]);
        let mut rule = NohcRule::new(params);
        let cam = Camera::from_pose(
            CameraPose {
                eye: Vec3::ZERO,
                target: Vec3::new(0.0, 0.0, -1.0),
            },
            640.0 / 360.0,
            100.0,
        );
        rule.begin_frame(&bvh, cam.view_proj());
        (bvh, rule)
    }

    fn leaf(bvh: &ObjectBvh) -> u32 {
        (0..bvh.nodes.len() as u32)
            .find(|&n| bvh.nodes[n as usize].is_leaf())
            .unwrap()
    }

    #[test]
    fn heavy_nodes_are_queried_and_cheap_ones_are_not() {
        let (bvh, mut heavy) = setup(200_000);
        let n = leaf(&bvh);
        assert!(heavy.query_invisible(&bvh, n, 1));
        let (bvh, mut cheap) = setup(12);
        assert!(!cheap.query_invisible(&bvh, leaf(&bvh), 1));
    }

    #[test]
    fn history_of_visible_results_stops_queries() {
        let (bvh, mut rule) = setup(20_000);
        let n = leaf(&bvh);
        assert!(rule.query_invisible(&bvh, n, 1));
        for _ in 0..8 {
            rule.record(n, false);
        }
        assert!(!rule.query_invisible(&bvh, n, 2), "a node seen every time");
    }

    #[test]
    fn visible_leaves_are_retested_later_the_cheaper_they_are() {
        let (bvh, mut rule) = setup(20_000);
        let n = leaf(&bvh);
        // Tested a frame ago: not worth testing again at once, but after some frames it is.
        rule.last_test[n as usize] = 100;
        assert!(!rule.query_visible_leaf(&bvh, n, 101));
        assert!(rule.query_visible_leaf(&bvh, n, 200));
    }

    #[test]
    fn coverage_and_subtree_sums() {
        let (bvh, rule) = setup(100);
        assert_eq!(rule.subtree[0], (2, 200));
        let near = rule.screen_pixels(&bvh.nodes[leaf(&bvh) as usize].bounds);
        assert!(near > 0.0 && near <= 640.0 * 360.0);
        let behind = Aabb::new(Vec3::new(-1.0, -1.0, -1.0), Vec3::new(1.0, 1.0, 1.0));
        assert_eq!(rule.screen_pixels(&behind), 640.0 * 360.0);
        assert!(costs().is_valid());
        let bad = CostModel {
            draw_ms: f64::NAN,
            ..costs()
        };
        assert!(!bad.is_valid());
    }
}
