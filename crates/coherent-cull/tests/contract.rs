//! The culling contract on the CPU mock backend: what each traversal draws (vfc exactly the
//! objects in the frustum; stop-and-wait, CHC and CHC++ every object the visibility function
//! calls visible, on random scenes along a walk), and what CHC++'s four parts do to the queries
//! (multiqueries, tight bounds, randomized intervals, batching).

mod common;

use coherent_cull::chcpp::{Chcpp, ChcppParams};
use coherent_cull::testing::{Completion, MockBackend};
use coherent_cull::{create, Culler, ObjectBvh, QueryPurpose};
use common::*;

const FRAMES: u64 = 30;

/// Runs `culler` along the walk with the fog model and checks that nothing visible is missing;
/// returns every frame.
fn walk_exactly(
    culler: &mut dyn Culler,
    bvh: &ObjectBvh,
    completion: Completion,
    range: f32,
) -> Vec<Frame> {
    let mut backend = MockBackend::new(|_| 0).with_completion(completion);
    let mut frames = Vec::new();
    for f in 1..=FRAMES {
        let cam = walk(f);
        let fog = Fog::new(&cam, range);
        let want = fog.visible_objects(bvh);
        backend.set_visibility(move |b| fog.pixels(b));
        let fr = run(culler, bvh, &cam, &mut backend, f);
        let lost = missing(&want, &fr.drawn);
        assert!(
            lost.is_empty(),
            "{} ({completion:?}) frame {f}: visible objects {lost:?} not drawn",
            culler.name()
        );
        // The culler's own counts agree with what the backend saw.
        assert_eq!(fr.stats.queries, fr.counts.queries, "{}", culler.name());
        assert_eq!(fr.stats.objects_drawn, fr.counts.objects_drawn);
        frames.push(fr);
    }
    frames
}

#[test]
fn vfc_draws_exactly_the_objects_in_the_frustum() {
    let bvh = ObjectBvh::build(&random_boxes(600, 1), 1);
    let mut vfc = create("vfc", &ChcppParams::default()).unwrap();
    let mut backend = MockBackend::new(|_| PIXELS);
    let mut culled_some = false;
    for f in 1..=FRAMES {
        let cam = walk(f);
        let fr = run(vfc.as_mut(), &bvh, &cam, &mut backend, f);
        let want = in_frustum(&bvh, &cam);
        assert_eq!(fr.drawn, want, "frame {f}");
        assert_eq!(fr.counts.queries, 0);
        assert_eq!(fr.counts.draw_calls, 1, "one batch");
        culled_some |= want.len() < 600;
    }
    assert!(culled_some, "the walk leaves objects outside the frustum");
}

/// A culler made by name is `Send`: a host that picks the algorithm from its settings moves it
/// to the thread that records its frames, where it stays exact.
#[test]
fn cullers_made_by_name_move_to_another_thread() {
    let bvh = std::sync::Arc::new(ObjectBvh::build(&random_boxes(300, 7), 2));
    let setup = coherent_cull::CullerSetup::default();
    for name in [
        "chcpp",
        "chcpp@predicated",
        "chcpp@next-frame-k2",
        "stop-and-wait",
    ] {
        let mut culler = coherent_cull::create_named(name, &setup).unwrap();
        let bvh = std::sync::Arc::clone(&bvh);
        let lost = std::thread::spawn(move || {
            let mut backend = MockBackend::new(|_| 0).with_frames_in_flight(2);
            let mut lost = Vec::new();
            for f in 1..=FRAMES {
                let cam = walk(f);
                let fog = Fog::new(&cam, 40.0);
                let want = fog.visible_objects(&bvh);
                backend.set_visibility(move |b| fog.pixels(b));
                let fr = run(culler.as_mut(), &bvh, &cam, &mut backend, f);
                lost.extend(missing(&want, &fr.drawn));
            }
            (culler.name().to_string(), lost)
        })
        .join()
        .expect("the culler's thread");
        // Next-frame modes draw late by design; the exact ones miss nothing.
        if !name.contains("next-frame") {
            assert!(lost.1.is_empty(), "{}: missed {:?}", lost.0, lost.1);
        }
    }
}

#[test]
fn stop_and_wait_draws_the_visible_objects_and_only_those() {
    let bvh = ObjectBvh::build(&random_boxes(400, 2), 1);
    for completion in [Completion::AfterSubmit, Completion::OnWait] {
        let mut s = create("stop-and-wait", &ChcppParams::default()).unwrap();
        let frames = walk_exactly(s.as_mut(), &bvh, completion, 35.0);
        for (i, fr) in frames.iter().enumerate() {
            let cam = walk(i as u64 + 1);
            let fog = Fog::new(&cam, 35.0);
            let want = fog.visible_objects(&bvh);
            // Anything more is only what the eye is inside of (drawn without a query).
            for o in missing(&fr.drawn, &want) {
                let b = bvh.object_bounds(o).unwrap();
                assert!(
                    coherent_cull::eye_inside(&b, &(&cam).into()),
                    "frame {}: object {o} drawn but not visible",
                    i + 1
                );
            }
            // Every query is waited for.
            assert_eq!(fr.counts.waits, fr.counts.queries);
        }
    }
}

#[test]
fn chc_and_chcpp_miss_nothing_along_a_walk() {
    for leaf_size in [1, 4] {
        let bvh = ObjectBvh::build(&random_boxes(600, 3), leaf_size);
        let in_view: usize = (1..=FRAMES).map(|f| in_frustum(&bvh, &walk(f)).len()).sum();
        for name in ["chc", "chcpp"] {
            for completion in [Completion::AfterSubmit, Completion::OnWait] {
                let mut c = create(name, &ChcppParams::default()).unwrap();
                let frames = walk_exactly(c.as_mut(), &bvh, completion, 35.0);
                let drawn: usize = frames.iter().map(|f| f.drawn.len()).sum();
                assert!(
                    drawn * 2 < in_view,
                    "{name}: {drawn} objects drawn of {in_view} in view: it culls"
                );
                if completion == Completion::OnWait {
                    assert!(frames.iter().any(|f| f.stats.blocking_waits > 0));
                }
            }
        }
    }
}

#[test]
fn each_part_of_chcpp_alone_misses_nothing() {
    let bvh = ObjectBvh::build(&random_boxes(500, 4), 1);
    for part in ["batching", "interval", "multiqueries", "tight"] {
        let mut c = Chcpp::new(ChcppParams::only(&[part]));
        walk_exactly(&mut c, &bvh, Completion::OnWait, 30.0);
    }
}

/// A static view of the walk's first frame with the fog model: most of the view is hidden.
fn static_fog_frames(
    c: &mut dyn Culler,
    bvh: &ObjectBvh,
    backend: &mut MockBackend,
    frames: std::ops::Range<u64>,
) -> Vec<Frame> {
    let cam = walk(0);
    let fog = Fog::new(&cam, 30.0);
    backend.set_visibility(move |b| fog.pixels(b));
    frames.map(|f| run(c, bvh, &cam, backend, f)).collect()
}

#[test]
fn multiqueries_group_invisible_nodes_and_a_failed_one_requeries_them() {
    let bvh = ObjectBvh::build(&random_boxes(600, 5), 1);
    let mut c = Chcpp::new(ChcppParams::default());
    let mut backend = MockBackend::new(|_| 0);
    let frames = static_fog_frames(&mut c, &bvh, &mut backend, 1..12);
    // The hidden cut has been invisible for frames: its nodes share queries.
    let last = frames.last().unwrap();
    assert!(last.stats.multiqueries > 0);
    assert!(last
        .queries()
        .iter()
        .any(|q| q.0 == QueryPurpose::Multiquery && q.1 > 1));
    let tested: u32 = frames[5..]
        .iter()
        .map(|f| f.stats.invisible_nodes_tested)
        .sum();
    let queried: u32 = frames[5..]
        .iter()
        .map(|f| f.stats.invisible_node_queries)
        .sum();
    assert!(
        tested > 2 * queried,
        "{tested} invisible nodes in {queried} queries"
    );
    // Everything turns visible: the multiqueries fail, each of their nodes is queried on its
    // own in the same frame, and every object in view is drawn.
    backend.set_visibility(|_| PIXELS);
    let fr = run(&mut c, &bvh, &walk(0), &mut backend, 12);
    assert!(fr.stats.failed_multiqueries > 0);
    assert!(fr.stats.requeried >= 2 * fr.stats.failed_multiqueries);
    let failed = fr
        .queries()
        .iter()
        .filter(|q| q.0 == QueryPurpose::Multiquery && q.2)
        .count();
    assert_eq!(failed as u32, fr.stats.failed_multiqueries);
    assert!(fr.queries_for(QueryPurpose::Node) as u32 >= fr.stats.requeried);
    assert_eq!(fr.drawn, in_frustum(&bvh, &walk(0)));
}

#[test]
fn without_multiqueries_every_query_is_for_one_node() {
    let bvh = ObjectBvh::build(&random_boxes(600, 5), 1);
    let params = ChcppParams {
        multiqueries: false,
        ..ChcppParams::default()
    };
    let mut c = Chcpp::new(params);
    let mut backend = MockBackend::new(|_| 0);
    let frames = static_fog_frames(&mut c, &bvh, &mut backend, 1..12);
    for fr in &frames {
        assert_eq!(fr.stats.multiqueries, 0);
        assert_eq!(fr.queries_for(QueryPurpose::Multiquery), 0);
    }
    // The same frames with multiqueries issue fewer queries.
    let mut with = Chcpp::new(ChcppParams::default());
    let mut backend = MockBackend::new(|_| 0);
    let grouped = static_fog_frames(&mut with, &bvh, &mut backend, 1..12);
    let count = |fs: &[Frame]| fs.iter().map(|f| f.counts.queries).sum::<u32>();
    assert!(count(&grouped) < count(&frames));
}

#[test]
fn tight_bounds_query_several_boxes_and_plain_ones_one() {
    let bvh = ObjectBvh::build(&random_boxes(600, 6), 1);
    for tight in [true, false] {
        let params = ChcppParams {
            tight_bounds: tight,
            multiqueries: false,
            ..ChcppParams::default()
        };
        let mut c = Chcpp::new(params);
        let frames = walk_exactly(&mut c, &bvh, Completion::AfterSubmit, 35.0);
        let most = frames
            .iter()
            .flat_map(|f| f.queries())
            .map(|q| q.1)
            .max()
            .unwrap();
        let boxes: u32 = frames.iter().map(|f| f.counts.query_boxes).sum();
        let queries: u32 = frames.iter().map(|f| f.counts.queries).sum();
        if tight {
            assert!(
                most > 1 && boxes > queries,
                "tight volumes of several boxes"
            );
        } else {
            assert_eq!((most, boxes), (1, queries), "one box per query");
        }
    }
}

/// Visible-leaf queries per frame from an overview where everything is visible.
fn visible_leaf_queries(params: ChcppParams, frames: u64) -> (Vec<usize>, usize) {
    let bvh = ObjectBvh::build(&random_boxes(300, 7), 1);
    let cam = overview();
    assert_eq!(in_frustum(&bvh, &cam).len(), 300);
    let mut c = Chcpp::new(params);
    let mut backend = MockBackend::new(|_| PIXELS);
    let per_frame = (1..=frames)
        .map(|f| {
            let fr = run(&mut c, &bvh, &cam, &mut backend, f);
            assert_eq!(fr.drawn.len(), 300, "frame {f}");
            fr.queries_for(QueryPurpose::VisibleLeaf)
        })
        .collect();
    (per_frame, bvh.leaf_count())
}

#[test]
fn randomized_intervals_spread_visible_leaf_queries_over_frames() {
    let (per_frame, leaves) = visible_leaf_queries(ChcppParams::default(), 25);
    // n_av = 5: after the first frames each leaf is tested once in every 5 frames, ...
    for w in per_frame[7..].windows(5) {
        assert_eq!(w.iter().sum::<usize>(), leaves, "{per_frame:?}");
    }
    // ... and not all in the same frame.
    for &n in &per_frame[1..] {
        assert!(n > 0 && n < leaves / 2, "{per_frame:?}");
    }
}

#[test]
fn with_an_interval_of_one_every_visible_leaf_is_tested_every_frame() {
    let params = ChcppParams {
        visible_interval: 1,
        ..ChcppParams::default()
    };
    let (per_frame, leaves) = visible_leaf_queries(params, 8);
    assert_eq!(per_frame[0], 0, "the first frame knows nothing visible yet");
    assert!(per_frame[1..].iter().all(|&n| n == leaves), "{per_frame:?}");
}

#[test]
fn chcpp_batches_queries_into_few_state_changes() {
    let bvh = ObjectBvh::build(&random_boxes(600, 8), 1);
    let mut c = Chcpp::new(ChcppParams::default());
    let frames = walk_exactly(&mut c, &bvh, Completion::AfterSubmit, 35.0);
    let (mut changes, mut queries) = (0, 0);
    for fr in &frames {
        assert!(
            fr.counts.state_changes <= 2 * fr.stats.query_batches,
            "{fr:?}"
        );
        changes += fr.counts.state_changes;
        queries += fr.counts.queries;
    }
    assert!(
        changes * 5 < queries,
        "{changes} state changes for {queries} queries"
    );
}

#[test]
fn chc_changes_state_twice_per_query() {
    let bvh = ObjectBvh::build(&random_boxes(400, 8), 1);
    let mut c = create("chc", &ChcppParams::default()).unwrap();
    let frames = walk_exactly(c.as_mut(), &bvh, Completion::AfterSubmit, 35.0);
    for fr in &frames {
        assert!(fr.counts.queries > 0);
        assert_eq!(fr.counts.state_changes, 2 * fr.counts.queries);
        assert_eq!(
            fr.stats.query_batches, fr.stats.queries,
            "a batch per query"
        );
    }
}
