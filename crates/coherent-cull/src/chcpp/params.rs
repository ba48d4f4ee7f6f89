//! CHC++'s parameters: every switch and constant of the paper, defaulted to the paper's values,
//! and the configurations that make the same traversal CHC or one part of CHC++ alone.

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
    /// Predicated mode: the same for an interior part of a split node that passed its test or
    /// its query (default 1). A part's test compares its screen rectangle with the depth drawn
    /// so far, coarser than a query, and most leaves opened two levels under a passing part
    /// failed their own query in the next frame; one level measured fewer objects and fewer
    /// queries on the city's street, overhead and x16 walks (docs/measurements.md).
    pub predicated_part_levels: u32,
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
    /// Predicated mode, on a backend that issues queries under predicates: how many levels
    /// below a queried node its parts are queried in the same frame, each under the node's
    /// predicate, so that only the parts that show are drawn (default 2; 0: one predicate
    /// level, the node's objects all drawn under its own predicate: what a GPU wants, see
    /// [`ChcppParams::for_gpu`]).
    pub predicated_refine_levels: u32,
    /// Predicated mode: a queried node is split into parts (see `predicated_refine_levels`)
    /// only while it holds more than this many objects in the frustum (default 4).
    pub predicated_refine_objects: u32,
    /// Predicated mode, on a backend that issues queries under predicates: whether the nodes
    /// of a multiquery are queried one by one under its predicate (default true). Off, a
    /// multiquery's objects are all drawn under its own predicate: fewer queries (a
    /// multiquery is grouped because its nodes are expected to stay hidden), more extra draws
    /// in the frame one of them turns visible.
    pub predicated_split_multiqueries: bool,
    /// Predicated mode: split a node (or a node of a multiquery) only when it pays in
    /// expectation, `(1 - p) · objects · ratio > parts`, with `1 - p` the chance that its
    /// query's predicate is true (from the nodes' invisibility history, as for multiqueries),
    /// `objects` its objects in the frustum, `parts` the queries splitting costs, and `ratio`
    /// this value: the cost of drawing an object over that of a query whose boxes a false
    /// predicate discards (the begin and end of every split query are recorded, and paid,
    /// whatever the predicate). The nodes of a multiquery are split all or none, by their
    /// sums. 0 (the default) splits by size alone (4 was faster in 100-frame street walks on
    /// lavapipe, not beyond the spread of the 300-frame one: docs/measurements.md). Parts that
    /// the backend decides by its own test (`predicated_tested_parts_min`) cost no query:
    /// while it does, every node the size rule picks is split.
    pub predicated_split_ratio: f32,
    /// Predicated mode: the backend's own test ([`crate::OcclusionBackend::test_part_if`],
    /// e.g. a depth test on the device) decides the parts of split nodes instead of one
    /// query each in a frame that follows one with at least this many parts (default 0:
    /// always; `u32::MAX`: never). Set it above 0 for a backend whose test has a fixed cost
    /// per frame that pays only from some number of parts on. A backend without such a test
    /// queries the parts.
    pub predicated_tested_parts_min: u32,
    /// Predicated mode: query with tight bounding volumes (when `tight_bounds` is on). Off
    /// by default: on a CPU rasterizer (lavapipe) every fragment of a query box is depth-tested,
    /// and seen along a street a node's descendants overlap on screen, so its tight boxes
    /// rasterize more than twice the fill of the own boxes; on the city street the predicated
    /// frame was about 3% faster without them (interleaved runs in both orders,
    /// docs/measurements.md). [`ChcppParams::for_gpu`] turns it on: a GPU's depth test rejects
    /// hidden box fragments cheaply.
    pub predicated_tight_bounds: bool,
    /// Predicated mode: the visible interval `n_av` (frames between two queries of a leaf
    /// assumed visible; its first re-test after a random delay in `[1, n_av]`), in place of
    /// `visible_interval`. A visible leaf is drawn whatever its query says until the result
    /// comes back, and the mode's other rules (a node found visible opens levels, hidden
    /// parts are not drawn) decide most of what is drawn, so on the street its queries cost
    /// more than they save at the paper's 5. From above, where most leaves are visible, a
    /// long interval draws hidden leaves for longer. 7 is the compromise measured on the city
    /// (docs/measurements.md): against 10, about 5% faster from above (6,284 objects a frame
    /// against 6,523) and about 2% slower on the street (137.5 queries against 117).
    pub predicated_visible_interval: u32,
    /// Predicated mode: a query box that covers more than this fraction of the screen (its
    /// screen rectangle, clipped) is replaced by the boxes of its children that may show,
    /// level by level, while their rectangles cover less than [`SCREEN_SPLIT_GAIN`] times
    /// its own (default 0.005; 0: off). On a CPU rasterizer a box test costs its fill, and
    /// a few large boxes of hidden nodes near the eye make most of it; their children, seen
    /// from the street, often cover much less. The test stays one test (one predicate) and
    /// stays exact: the children's boxes cover every object of the node that can show.
    pub predicated_screen_split: f32,
    /// Predicated mode: a previously invisible node that enters the frustum in this frame
    /// (it lay outside when last visited) and whose box covers more than this fraction of
    /// the screen (its screen rectangle, clipped) is opened unconditionally rather than
    /// queried: a leaf is drawn with the unconditional draws and queried later as a visible
    /// leaf, an interior node's children are visited as entering too (default 0.003; 0: off).
    /// When the camera turns, what enters from the side near the eye is mostly in front of
    /// what lies behind it, and drawn before the frame's tests it hides that: otherwise the
    /// frame's tests run against depth that lacks it and pass for everything behind. On the
    /// city street (docs/measurements.md) it took the slowest frame from 108 ms to 76 ms
    /// and the mean frame from 1.45x to 1.36x the oracle, the median within its spread.
    pub predicated_enter_fraction: f32,
}

/// See [`ChcppParams::predicated_screen_split`]: children replace a box only when their
/// screen rectangles add up to less than this fraction of its own.
pub const SCREEN_SPLIT_GAIN: f32 = 0.8;

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
            predicated_part_levels: 1,
            predicated_hold: 10,
            predicated_budget: 8.0,
            predicated_refine_levels: 2,
            predicated_refine_objects: 4,
            predicated_split_multiqueries: true,
            predicated_split_ratio: 0.0,
            predicated_tested_parts_min: 0,
            predicated_tight_bounds: false,
            predicated_visible_interval: 7,
            predicated_screen_split: 0.005,
            predicated_enter_fraction: 0.003,
        }
    }
}

impl ChcppParams {
    /// Checks that every count is at least 1 where a count of 0 means nothing (the batch
    /// size, the visible intervals, the flush interval) and that every fraction, factor and
    /// budget is a finite number in its range. [`Chcpp`](super::Chcpp) checks its
    /// parameters at the start of every frame and refuses the frame with this error, which
    /// names the field, rather than quietly reading a NaN as "off" or a 0 as 1.
    pub fn validate(&self) -> crate::Result<()> {
        let fail = |field: &str, value: String, rule: &str| {
            Err(crate::Error::Input(format!(
                "ChcppParams::{field} is {value}: it must be {rule}"
            )))
        };
        for (field, value) in [
            ("batch_size", self.batch_size as u64),
            ("visible_interval", u64::from(self.visible_interval)),
            (
                "predicated_visible_interval",
                u64::from(self.predicated_visible_interval),
            ),
            ("flush_interval", self.flush_interval as u64),
        ] {
            if value == 0 {
                return fail(field, value.to_string(), "at least 1");
            }
        }
        let at_least_zero = [
            ("predicated_budget", self.predicated_budget),
            ("predicated_split_ratio", self.predicated_split_ratio),
            ("predicated_enter_fraction", self.predicated_enter_fraction),
        ];
        for (field, value) in at_least_zero {
            if !(value >= 0.0 && value.is_finite()) {
                return fail(field, value.to_string(), "a finite number at least 0");
            }
        }
        if !(0.0..=1.0).contains(&self.predicated_screen_split) {
            return fail(
                "predicated_screen_split",
                self.predicated_screen_split.to_string(),
                "a fraction of the screen from 0 (off) to 1",
            );
        }
        if !(self.tight_area_factor > 0.0 && self.tight_area_factor.is_finite()) {
            return fail(
                "tight_area_factor",
                self.tight_area_factor.to_string(),
                "a finite number above 0",
            );
        }
        Ok(())
    }

    /// The original CHC as a configuration of the same traversal: no batching (each query is
    /// issued at once, so one state change per query), every visible leaf queried every frame,
    /// single queries with the node's own box.
    pub fn chc() -> ChcppParams {
        ChcppParams {
            batching: false,
            batch_size: 1,
            randomized_interval: false,
            visible_interval: 1,
            predicated_visible_interval: 1,
            multiqueries: false,
            tight_bounds: false,
            ..ChcppParams::default()
        }
    }

    /// CHC++ for a hardware GPU, where recording a frame's commands costs more than
    /// rasterizing a few extra objects: the defaults, but the predicated mode draws a queried
    /// node's objects all under its own predicate (`predicated_refine_levels` 0: no parts, one
    /// predicate resolve a frame) and queries with tight bounding volumes, as the other
    /// modes do. The defaults split nodes into parts because on a CPU rasterizer (lavapipe)
    /// every object drawn is rasterized on the CPU; on a GPU the parts'
    /// queries, tight boxes and conditional blocks are CPU time that the device does not give
    /// back. Measured on an NVIDIA H100 (docs/measurements.md): the city street at 1280x720,
    /// 2.12x the oracle against 3.09x with the defaults (in-frame CHC++ 2.06x).
    pub fn for_gpu() -> ChcppParams {
        ChcppParams {
            predicated_refine_levels: 0,
            predicated_tight_bounds: true,
            ..ChcppParams::default()
        }
    }

    /// CHC++ with only the named parts on (for measuring each part alone): any of `batching`,
    /// `interval`, `multiqueries`, `tight`. Multiqueries group the i-queue, so `multiqueries`
    /// turns batching on too.
    pub fn only(parts: &[&str]) -> ChcppParams {
        let mut p = ChcppParams::chc();
        let d = ChcppParams::default();
        for part in parts {
            match *part {
                "batching" => {
                    p.batching = true;
                    p.batch_size = d.batch_size;
                }
                "interval" => {
                    p.randomized_interval = true;
                    p.visible_interval = d.visible_interval;
                    p.predicated_visible_interval = d.predicated_visible_interval;
                }
                // Multiqueries group the i-queue, so they need it.
                "multiqueries" => {
                    p.multiqueries = true;
                    p.batching = true;
                    p.batch_size = d.batch_size;
                }
                "tight" => p.tight_bounds = true,
                _ => {}
            }
        }
        p
    }
}
