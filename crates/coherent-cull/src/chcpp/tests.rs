//! Unit tests of the traversal's steps on a small mock backend.

use super::tight::{screen_fraction, screen_split, tight_boxes};
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

impl OcclusionBackend for Mock {
    fn draw_objects(&mut self, _objects: &[u32]) -> Result<()> {
        Ok(())
    }
    fn issue_query(&mut self, boxes: &[Aabb]) -> Result<QueryId> {
        let hit = boxes
            .iter()
            .any(|b| self.visible.iter().any(|v| b.overlaps(v)));
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
            assert!(s.query_culled > s.invisible_node_queries.saturating_sub(s.visible_results));
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

/// Two clusters of boxes at opposite corners of the view, near the eye, and one box outside
/// the frustum: the root's box covers most of the screen, its children's much less.
fn corners() -> (ObjectBvh, Camera) {
    let mut boxes = Vec::new();
    for i in 0..4 {
        let d = i as f32 * 0.3;
        boxes.push(Aabb::new(
            Vec3::new(-6.0 + d, -4.0, 0.0),
            Vec3::new(-5.5 + d, -3.5, 0.5),
        ));
        boxes.push(Aabb::new(
            Vec3::new(5.5 - d, 3.5, 0.0),
            Vec3::new(6.0 - d, 4.0, 0.5),
        ));
    }
    // Behind the eye: outside the view.
    boxes.push(Aabb::new(
        Vec3::new(0.0, 0.0, 30.0),
        Vec3::new(1.0, 1.0, 31.0),
    ));
    let bvh = ObjectBvh::build(&boxes, 1);
    let pose = CameraPose {
        eye: Vec3::new(0.0, 0.0, 10.0),
        target: Vec3::new(0.0, 0.0, 0.0),
    };
    (bvh, Camera::from_pose(pose, 1.0, 500.0))
}

#[test]
fn screen_split_covers_every_object_in_view_with_less_screen() {
    let (bvh, cam) = corners();
    let view = View::new(&(&cam).into());
    let root = 0;
    let mut out = Vec::new();
    screen_split(&bvh, root, &view, 0.005, &mut out);
    assert!(out.len() > 1, "the root's box is split: {out:?}");
    let area: f32 = out.iter().map(|b| screen_fraction(&view, b)).sum();
    let root_area = screen_fraction(&view, &bvh.nodes[root as usize].bounds);
    assert!(
        area < 0.5 * root_area,
        "{area} against the root's {root_area}"
    );
    // Every object that may show lies in a box of the split; the one behind the eye in none.
    let mut in_view = 0;
    for o in 0..9u32 {
        let b = bvh.object_bounds(o).expect("an object");
        let covered = out.iter().any(|s| s.contains(b.min) && s.contains(b.max));
        if view.in_view(&b) {
            in_view += 1;
            assert!(covered, "object {o} in view is not covered");
        }
    }
    assert_eq!(in_view, 8);
    // With the whole screen as the threshold only the root's box, which reaches behind the
    // eye (no screen bound), is split: into its one child in view, the two clusters'.
    out.clear();
    screen_split(&bvh, root, &view, 1.0, &mut out);
    assert_eq!(out.len(), 1, "{out:?}");
    assert!(out[0].max.z < 1.0 && out[0].min.x <= -6.0 && out[0].max.x >= 6.0);
}
