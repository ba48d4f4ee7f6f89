//! The rest of the embedding contract on the CPU mock backend: latency modes and frames in
//! flight, moving, inserted and removed objects, camera cuts and resets, the eye inside a box,
//! an empty hierarchy, NOHC, PVS, the oracle, and the errors of the factory functions.

mod common;

use std::cell::{Cell, RefCell};
use std::sync::Arc;

use coherent_cull::camera::{Camera, CameraPose, CameraView};
use coherent_cull::chcpp::{Chcpp, ChcppParams};
use coherent_cull::glam::{Mat4, Vec3};
use coherent_cull::pvs::{Pvs, ViewCell};
use coherent_cull::testing::{Completion, MockBackend, MockEvent};
use coherent_cull::{
    create, create_latency, create_named, create_with, Aabb, CostModel, Culler, CullerSetup, Error,
    FrameInput, Latency, NohcParams, ObjectBvh, ALGORITHMS, MAX_FRAMES_IN_FLIGHT,
};
use common::*;

/// Eight unit boxes in a row, all in front of the camera.
fn row() -> (Vec<Aabb>, Camera) {
    let boxes = (0..8)
        .map(|i| {
            let x = 2.0 * i as f32;
            Aabb::new(Vec3::new(x, 0.0, -10.0), Vec3::new(x + 1.0, 1.0, -9.0))
        })
        .collect();
    let pose = CameraPose {
        eye: Vec3::new(7.0, 0.5, 10.0),
        target: Vec3::new(7.0, 0.5, -10.0),
    };
    (boxes, Camera::from_pose(pose, 16.0 / 9.0, 100.0))
}

/// The error `c` refuses frame 1 with (it must refuse it).
fn first_frame_error(
    c: &mut dyn Culler,
    bvh: &ObjectBvh,
    cam: &Camera,
    backend: &mut MockBackend,
) -> Error {
    let input = FrameInput {
        bvh,
        view: cam.into(),
        frame: 1,
        exact_visible: None,
    };
    c.cull_frame(&input, backend).unwrap_err()
}

/// A visibility function: a box sees pixels when it overlaps an object whose bit is set in
/// `mask` (read at every query, so the test can change what is visible between frames).
fn masked<'a>(boxes: &'a [Aabb], mask: &'a Cell<u64>) -> impl FnMut(&Aabb) -> u64 + 'a {
    move |b| {
        let hit = boxes
            .iter()
            .enumerate()
            .any(|(i, o)| mask.get() & (1 << i) != 0 && o.overlaps(b));
        if hit {
            PIXELS
        } else {
            0
        }
    }
}

/// Objects 0..4 are visible; object 6 turns visible in frame 6. Returns the first frame that
/// draws it, after checking that every frame is one submission without waits when `late`.
fn frame_object_6_appears(culler: &mut dyn Culler, k: u32, late: bool) -> u64 {
    let (boxes, cam) = row();
    let bvh = ObjectBvh::build(&boxes, 1);
    let mask = Cell::new(0b1111);
    let mut backend = MockBackend::new(masked(&boxes, &mask)).with_frames_in_flight(k);
    for f in 1..=12 {
        if f == 6 {
            mask.set(mask.get() | 1 << 6);
        }
        let fr = run(culler, &bvh, &cam, &mut backend, f);
        if late {
            assert_eq!((fr.counts.submits, fr.counts.waits), (1, 0), "frame {f}");
            assert_eq!(fr.stats.blocking_waits, 0);
        }
        // Once the first results are in (frame 2 + k), the hidden object is culled.
        if (3 + u64::from(k)..6).contains(&f) {
            assert!(!fr.drawn.contains(&6), "hidden object drawn in frame {f}");
        }
        if f >= 6 && fr.drawn.contains(&6) {
            assert_eq!(backend.early_reads(), 0, "no result read before its time");
            return f;
        }
    }
    panic!("object 6 never drawn")
}

#[test]
fn in_frame_draws_a_newly_visible_object_at_once() {
    for name in ["chc", "chcpp"] {
        let mut c = create(name, &ChcppParams::default()).unwrap();
        assert_eq!(frame_object_6_appears(c.as_mut(), 1, false), 6, "{name}");
    }
}

#[test]
fn next_frame_submits_once_never_waits_and_draws_one_frame_late() {
    for name in ["chc", "chcpp"] {
        let mut c = create_latency(name, &ChcppParams::default(), Latency::NextFrame).unwrap();
        assert_eq!(frame_object_6_appears(c.as_mut(), 1, true), 7, "{name}");
    }
}

#[test]
fn two_frames_in_flight_read_nothing_early_and_draw_two_frames_late() {
    let mut c = Chcpp::new(ChcppParams::default())
        .with_latency(Latency::NextFrame)
        .with_frames_in_flight(2);
    assert_eq!(c.frames_in_flight(), 2);
    assert_eq!(frame_object_6_appears(&mut c, 2, true), 8);
    // The same through the factory.
    let mut c = create_named("chcpp@next-frame-k2", &CullerSetup::default()).unwrap();
    assert_eq!(frame_object_6_appears(c.as_mut(), 2, true), 8);
}

#[test]
fn frames_in_flight_need_a_backend_that_keeps_results_that_long() {
    let (boxes, cam) = row();
    let bvh = ObjectBvh::build(&boxes, 1);
    let mut c = Chcpp::new(ChcppParams::default())
        .with_latency(Latency::NextFrame)
        .with_frames_in_flight(3);
    let mut backend = MockBackend::new(|_| PIXELS).with_frames_in_flight(2);
    let err = first_frame_error(&mut c, &bvh, &cam, &mut backend);
    assert!(matches!(err, Error::Input(_)), "{err}");
}

/// Parameters that mean nothing (a zero count, a NaN or negative fraction) refuse the frame
/// with an error naming the field, before anything is recorded; every configuration the
/// crate offers passes.
#[test]
fn nonsense_parameters_refuse_the_frame_and_name_the_field() {
    let d = ChcppParams::default();
    for p in [
        d.clone(),
        ChcppParams::chc(),
        ChcppParams::for_gpu(),
        ChcppParams::only(&["batching", "interval", "multiqueries", "tight"]),
        ChcppParams::only(&[]),
    ] {
        p.validate().unwrap();
    }
    let bad = [
        (
            ChcppParams {
                batch_size: 0,
                ..d.clone()
            },
            "batch_size",
        ),
        (
            ChcppParams {
                visible_interval: 0,
                ..d.clone()
            },
            "visible_interval",
        ),
        (
            ChcppParams {
                predicated_visible_interval: 0,
                ..d.clone()
            },
            "predicated_visible_interval",
        ),
        (
            ChcppParams {
                flush_interval: 0,
                ..d.clone()
            },
            "flush_interval",
        ),
        (
            ChcppParams {
                predicated_budget: f32::NAN,
                ..d.clone()
            },
            "predicated_budget",
        ),
        (
            ChcppParams {
                predicated_split_ratio: -1.0,
                ..d.clone()
            },
            "predicated_split_ratio",
        ),
        (
            ChcppParams {
                predicated_enter_fraction: f32::INFINITY,
                ..d.clone()
            },
            "predicated_enter_fraction",
        ),
        (
            ChcppParams {
                predicated_screen_split: 1.5,
                ..d.clone()
            },
            "predicated_screen_split",
        ),
        (
            ChcppParams {
                predicated_screen_split: f32::NAN,
                ..d.clone()
            },
            "predicated_screen_split",
        ),
        (
            ChcppParams {
                tight_area_factor: 0.0,
                ..d.clone()
            },
            "tight_area_factor",
        ),
    ];
    let (boxes, cam) = row();
    let bvh = ObjectBvh::build(&boxes, 1);
    for (params, field) in bad {
        let e = params.validate().unwrap_err().to_string();
        assert!(
            e.contains(&format!("ChcppParams::{field} ")),
            "{field}: {e}"
        );
        for latency in [Latency::InFrame, Latency::Predicated] {
            let mut c = Chcpp::new(params.clone()).with_latency(latency);
            let mut backend = MockBackend::new(|_| PIXELS);
            let err = first_frame_error(&mut c, &bvh, &cam, &mut backend);
            assert!(matches!(err, Error::Input(_)), "{field}: {err}");
            assert!(err.to_string().contains(field), "{field}: {err}");
            let counts = backend.counts();
            assert_eq!(
                (counts.draw_calls, counts.queries),
                (0, 0),
                "{field}: recorded"
            );
        }
    }
}

#[test]
fn conservative_mode_draws_nodes_without_a_recent_result() {
    let (boxes, cam) = row();
    let bvh = ObjectBvh::build(&boxes, 1);
    let params = ChcppParams::default();
    let mut plain = create_latency("chcpp", &params, Latency::NextFrame).unwrap();
    let mut conservative =
        create_latency("chcpp", &params, Latency::NextFrameConservative).unwrap();
    let mask = Cell::new(0b1111);
    let mut a = MockBackend::new(masked(&boxes, &mask));
    let mut b = MockBackend::new(masked(&boxes, &mask));
    for f in 1..=6 {
        let p = run(plain.as_mut(), &bvh, &cam, &mut a, f);
        let c = run(conservative.as_mut(), &bvh, &cam, &mut b, f);
        for fr in [&p, &c] {
            assert_eq!((fr.counts.submits, fr.counts.waits), (1, 0));
        }
        if f == 1 {
            // Nothing has a result yet: the plain mode draws nothing (it pops in a frame
            // later), the conservative one draws everything in view.
            assert!(p.drawn.is_empty());
            assert_eq!(c.drawn, (0..8).collect::<Vec<u32>>());
        }
        if f >= 4 {
            // Every node has fresh results: both draw the visible objects only.
            assert_eq!(c.drawn, vec![0, 1, 2, 3], "frame {f}");
            assert_eq!(p.drawn, vec![0, 1, 2, 3], "frame {f}");
        }
    }
}

/// The forward point `d` in front of the camera, as a small box.
fn box_ahead(cam: &Camera, d: f32) -> Aabb {
    let p = cam.eye + (cam.target - cam.eye).normalize() * d;
    Aabb::new(p - Vec3::splat(0.5), p + Vec3::splat(0.5))
}

#[test]
fn a_hidden_object_moved_into_view_is_drawn_the_same_frame() {
    for name in ["chc", "chcpp", "stop-and-wait"] {
        let mut bvh = ObjectBvh::build(&random_boxes(400, 9), 1);
        let cam = walk(0);
        let fog = Fog::new(&cam, 30.0);
        let visible = fog.visible_objects(&bvh);
        let mut c = create(name, &ChcppParams::default()).unwrap();
        let f2 = fog.clone();
        let mut backend = MockBackend::new(move |b| f2.pixels(b));
        let hidden = *in_frustum(&bvh, &cam)
            .iter()
            .find(|o| !visible.contains(o))
            .unwrap();
        for f in 1..=4 {
            let fr = run(c.as_mut(), &bvh, &cam, &mut backend, f);
            assert!(!fr.drawn.contains(&hidden));
        }
        bvh.set_bounds(hidden, box_ahead(&cam, 12.0)).unwrap();
        bvh.update();
        let fr = run(c.as_mut(), &bvh, &cam, &mut backend, 5);
        assert!(fr.drawn.contains(&hidden), "{name}: the mover is drawn");
        assert!(missing(&fog.visible_objects(&bvh), &fr.drawn).is_empty());
        // And moved behind the camera, it is frustum-culled at once.
        let behind = Aabb::new(
            cam.eye * 2.0 - cam.target,
            cam.eye * 2.0 - cam.target + Vec3::ONE,
        );
        bvh.set_bounds(hidden, behind).unwrap();
        bvh.update();
        let fr = run(c.as_mut(), &bvh, &cam, &mut backend, 6);
        assert!(!fr.drawn.contains(&hidden), "{name}");
    }
}

#[test]
fn inserted_objects_are_drawn_and_removed_ones_never() {
    let mut bvh = ObjectBvh::build(&random_boxes(300, 10), 1);
    let cam = walk(0);
    let fog = Fog::new(&cam, 30.0);
    let mut c = Chcpp::new(ChcppParams::default());
    let f2 = fog.clone();
    let mut backend = MockBackend::new(move |b| f2.pixels(b));
    for f in 1..=3 {
        run(&mut c, &bvh, &cam, &mut backend, f);
    }
    let new = bvh.insert(box_ahead(&cam, 10.0));
    let gone = fog.visible_objects(&bvh)[0];
    bvh.remove(gone).unwrap();
    assert!(!bvh.update().rebuilt);
    for f in 4..=6 {
        let fr = run(&mut c, &bvh, &cam, &mut backend, f);
        assert!(
            fr.drawn.contains(&new),
            "frame {f}: the inserted object is drawn"
        );
        assert!(
            !fr.drawn.contains(&gone),
            "frame {f}: the removed one is not"
        );
        assert!(missing(&fog.visible_objects(&bvh), &fr.drawn).is_empty());
    }
    // Many inserts rebuild the tree (new node ids); the culler stays exact through it.
    let ids: Vec<u32> = (0..120)
        .map(|i| bvh.insert(box_ahead(&cam, 14.0 + i as f32 * 0.5)))
        .collect();
    assert_eq!(ids[0], gone, "the removed id is handed out again");
    assert!(bvh.update().rebuilt);
    bvh.validate().unwrap();
    for f in 7..=9 {
        let fr = run(&mut c, &bvh, &cam, &mut backend, f);
        assert!(missing(&fog.visible_objects(&bvh), &fr.drawn).is_empty());
    }
}

#[test]
fn a_camera_cut_stays_exact_and_a_reset_starts_afresh() {
    let bvh = ObjectBvh::build(&random_boxes(500, 11), 1);
    let mut c = Chcpp::new(ChcppParams::default());
    let mut backend = MockBackend::new(|_| 0);
    for f in 1..=10 {
        let cam = walk(f);
        let fog = Fog::new(&cam, 35.0);
        backend.set_visibility(move |b| fog.pixels(b));
        run(&mut c, &bvh, &cam, &mut backend, f);
    }
    // Cut to the overview: nothing seen there is missing, though nothing is known of it.
    let cam = overview();
    let fog = Fog::new(&cam, 330.0);
    let want = fog.visible_objects(&bvh);
    assert!(!want.is_empty() && want.len() < in_frustum(&bvh, &cam).len());
    let f2 = fog.clone();
    backend.set_visibility(move |b| f2.pixels(b));
    let cut = run(&mut c, &bvh, &cam, &mut backend, 11);
    assert!(missing(&want, &cut.drawn).is_empty());
    // After a reset the culler behaves as a new one (same seed, same decisions).
    c.reset();
    let after_reset = run(&mut c, &bvh, &cam, &mut backend, 12);
    let mut fresh = Chcpp::new(ChcppParams::default());
    let mut fresh_backend = MockBackend::new(move |b| fog.pixels(b));
    let first = run(&mut fresh, &bvh, &cam, &mut fresh_backend, 1);
    assert_eq!(after_reset.stats, first.stats);
    assert_eq!(after_reset.counts, first.counts);
    assert_eq!(after_reset.drawn, first.drawn);
    assert!(missing(&want, &first.drawn).is_empty());
}

#[test]
fn the_box_the_eye_is_in_is_drawn_without_a_query() {
    // A 5 × 5 grid of boxes; the eye is in the middle one, and no query ever sees a pixel.
    let boxes: Vec<Aabb> = (0..25)
        .map(|i| {
            let p = Vec3::new((i % 5) as f32 * 5.0, 0.0, (i / 5) as f32 * 5.0);
            Aabb::new(p, p + Vec3::splat(2.0))
        })
        .collect();
    let bvh = ObjectBvh::build(&boxes, 1);
    let eye = boxes[12].center();
    let cam = Camera::from_pose(
        CameraPose {
            eye,
            target: eye + Vec3::new(1.0, 0.0, 0.3),
        },
        1.5,
        100.0,
    );
    for name in ["stop-and-wait", "chc", "chcpp"] {
        let queried = RefCell::new(Vec::new());
        let mut backend = MockBackend::new(|b: &Aabb| {
            queried.borrow_mut().push(*b);
            0
        })
        .with_completion(Completion::OnWait);
        let mut c = create(name, &ChcppParams::default()).unwrap();
        for f in 1..=3 {
            let fr = run(c.as_mut(), &bvh, &cam, &mut backend, f);
            assert_eq!(fr.drawn, vec![12], "{name} frame {f}");
        }
        let queried = queried.borrow();
        assert!(!queried.is_empty(), "{name}: the other boxes are queried");
        assert!(
            queried.iter().all(|b| !b.contains(eye)),
            "{name}: nothing around the eye is queried"
        );
    }
}

#[test]
fn an_empty_hierarchy_draws_nothing_then_what_is_inserted() {
    let (_, cam) = row();
    let names = [
        "vfc",
        "stop-and-wait",
        "chc",
        "chcpp",
        "chcpp@next-frame",
        "chcpp@next-frame-conservative",
    ];
    for name in names {
        let mut bvh = ObjectBvh::build(&[], 1);
        let mut c = create_named(name, &CullerSetup::default()).unwrap();
        let mut backend = MockBackend::new(|_| PIXELS);
        for f in 1..=3 {
            let fr = run(c.as_mut(), &bvh, &cam, &mut backend, f);
            assert!(fr.drawn.is_empty(), "{name}");
            assert_eq!(fr.stats.objects_drawn, 0);
        }
        let id = bvh.insert([[6.0, 0.0, -10.0], [7.0, 1.0, -9.0]]);
        bvh.update();
        let drawn_by = (4..=6)
            .find(|&f| run(c.as_mut(), &bvh, &cam, &mut backend, f).drawn == vec![id])
            .unwrap_or_else(|| panic!("{name}: the inserted object is never drawn"));
        if !name.contains('@') {
            assert_eq!(drawn_by, 4, "{name}: in-frame, at once");
        }
    }
}

fn costs() -> CostModel {
    CostModel {
        draw_ms: 0.06,
        triangle_ms: 2e-5,
        fragment_ms: 2e-6,
        query_ms: 0.1,
        query_fragment_ms: 1e-6,
        round_trip_ms: 0.3,
    }
}

/// NOHC through the factory for objects of `triangles` each.
fn nohc(objects: usize, triangles: u32) -> Box<dyn Culler> {
    let setup = CullerSetup {
        nohc: Some(NohcParams::new(
            costs(),
            (640, 360),
            vec![triangles; objects],
        )),
        ..CullerSetup::default()
    };
    create_with("nohc", &setup).unwrap()
}

/// Queries of `culler` along the walk; checks it misses nothing.
fn walk_queries(culler: &mut dyn Culler, bvh: &ObjectBvh) -> u32 {
    let mut backend = MockBackend::new(|_| 0);
    let mut queries = 0;
    for f in 1..=20 {
        let cam = walk(f);
        let fog = Fog::new(&cam, 35.0);
        let want = fog.visible_objects(bvh);
        backend.set_visibility(move |b| fog.pixels(b));
        let fr = run(culler, bvh, &cam, &mut backend, f);
        assert!(missing(&want, &fr.drawn).is_empty(), "frame {f}");
        queries += fr.counts.queries;
    }
    queries
}

#[test]
fn nohc_misses_nothing_and_queries_where_the_cost_model_says_it_pays() {
    let bvh = ObjectBvh::build(&random_boxes(400, 12), 1);
    let heavy = walk_queries(nohc(400, 200_000).as_mut(), &bvh);
    let cheap = walk_queries(nohc(400, 12).as_mut(), &bvh);
    let chc = walk_queries(
        create("chc", &ChcppParams::default()).unwrap().as_mut(),
        &bvh,
    );
    assert!(heavy > 0, "heavy objects are worth queries");
    assert!(cheap < heavy, "cheap objects are drawn rather than queried");
    assert!(cheap < chc, "NOHC {cheap} queries, CHC {chc}");
}

#[test]
fn the_pvs_culler_draws_its_cells_set_in_the_frustum() {
    let bvh = ObjectBvh::build(&random_boxes(300, 13), 1);
    let cam_at = |eye: Vec3| {
        Camera::from_pose(
            CameraPose {
                eye,
                target: Vec3::new(100.0, 0.0, 100.0),
            },
            1.0,
            1000.0,
        )
    };
    // Two cells of 50 at the ground's corner: the first sees objects 0..100, the second none.
    let cells = vec![
        ViewCell {
            coord: [0, 0, 0],
            objects: (0..100).collect(),
        },
        ViewCell {
            coord: [1, 0, 0],
            objects: vec![],
        },
    ];
    let pvs = Arc::new(Pvs::new("test".into(), 300, Vec3::ZERO, 50.0, cells));
    let setup = CullerSetup {
        pvs: Some(pvs),
        ..CullerSetup::default()
    };
    let mut c = create_with("pvs", &setup).unwrap();
    let mut backend = MockBackend::new(|_| 0);
    let in_cell = cam_at(Vec3::new(20.0, 10.0, 20.0));
    let fr = run(c.as_mut(), &bvh, &in_cell, &mut backend, 1);
    let want: Vec<u32> = in_frustum(&bvh, &in_cell)
        .into_iter()
        .filter(|&o| o < 100)
        .collect();
    assert!(!want.is_empty());
    assert_eq!(fr.drawn, want);
    assert_eq!(fr.counts.queries, 0);
    let empty_cell = cam_at(Vec3::new(70.0, 10.0, 20.0));
    assert!(run(c.as_mut(), &bvh, &empty_cell, &mut backend, 2)
        .drawn
        .is_empty());
    // Outside every cell: frustum culling only.
    let outside = cam_at(Vec3::new(20.0, 60.0, 20.0));
    let fr = run(c.as_mut(), &bvh, &outside, &mut backend, 3);
    assert_eq!(fr.drawn, in_frustum(&bvh, &outside));
}

#[test]
fn the_oracle_draws_exactly_the_visible_set() {
    let bvh = ObjectBvh::build(&random_boxes(100, 14), 1);
    let mut c = create("oracle", &ChcppParams::default()).unwrap();
    assert!(c.needs_exact_visibility());
    let mut backend = MockBackend::new(|_| PIXELS);
    let cam = walk(0);
    let exact = [3, 17, 42, 99];
    let fr = run_with(c.as_mut(), &bvh, &cam, &mut backend, 1, Some(&exact));
    assert_eq!(fr.drawn, exact);
    assert_eq!((fr.counts.queries, fr.counts.submits), (0, 1));
    let input = FrameInput {
        bvh: &bvh,
        view: (&cam).into(),
        frame: 2,
        exact_visible: None,
    };
    assert!(
        c.cull_frame(&input, &mut backend).is_err(),
        "no visible set"
    );
}

#[test]
fn the_box_oracle_asks_for_the_box_visible_set_and_draws_it() {
    let bvh = ObjectBvh::build(&random_boxes(100, 14), 1);
    let mut c = create("oracle-box", &ChcppParams::default()).unwrap();
    assert_eq!(c.name(), "oracle-box");
    assert!(c.needs_exact_visibility() && c.needs_box_visibility());
    assert!(!create("oracle", &ChcppParams::default())
        .unwrap()
        .needs_box_visibility());
    let mut backend = MockBackend::new(|_| PIXELS);
    let boxes = [3, 5, 17, 42, 99];
    let fr = run_with(c.as_mut(), &bvh, &walk(0), &mut backend, 1, Some(&boxes));
    assert_eq!(fr.drawn, boxes);
    assert_eq!((fr.counts.queries, fr.counts.submits), (0, 1));
}

#[test]
fn latency_names_parse_and_bad_ones_are_refused() {
    let ok = [
        ("in-frame", Latency::InFrame, 1),
        ("next-frame", Latency::NextFrame, 1),
        ("next-frame-k2", Latency::NextFrame, 2),
        (
            "next-frame-conservative-k3",
            Latency::NextFrameConservative,
            3,
        ),
        ("predicated-k16", Latency::Predicated, MAX_FRAMES_IN_FLIGHT),
    ];
    for (name, latency, k) in ok {
        assert_eq!(
            Latency::parse_in_flight(name).unwrap(),
            (latency, k),
            "{name}"
        );
    }
    for bad in [
        "",
        "bogus",
        "next-frame-k0",
        "in-frame-k2",
        "next-frame-kx",
        "next-frame-k-1",
        // More slots than a host keeps: refused, not allocated (four billion slots took
        // 256 GB and aborted the walk).
        "predicated-k17",
        "next-frame-k4000000000",
    ] {
        let err = Latency::parse_in_flight(bad).unwrap_err();
        assert!(matches!(err, Error::Input(_)), "{bad}: {err}");
        let named = create_named(&format!("chcpp@{bad}"), &CullerSetup::default());
        assert!(named.is_err(), "{bad}");
    }
    // The builders cannot fail: they clamp.
    let k = Chcpp::new(ChcppParams::default()).with_frames_in_flight(u32::MAX);
    assert_eq!(k.frames_in_flight(), MAX_FRAMES_IN_FLIGHT);
    assert_eq!(
        Chcpp::new(ChcppParams::default())
            .with_frames_in_flight(0)
            .frames_in_flight(),
        1
    );
    assert_eq!(Latency::parse("next-frame-k4").unwrap(), Latency::NextFrame);
    for l in Latency::ALL {
        assert_eq!(Latency::parse(l.name()).unwrap(), l);
    }
}

#[test]
fn unknown_names_are_errors_not_panics() {
    let params = ChcppParams::default();
    let setup = CullerSetup::default();
    let unknown = create("bogus", &params).err().expect("unknown algorithm");
    assert!(
        unknown.to_string().contains("chcpp"),
        "lists the known ones"
    );
    assert!(create_with("bogus", &setup).is_err());
    assert!(create_named("bogus@next-frame", &setup).is_err());
    assert!(create_named("chcpp@bogus", &setup).is_err());
    assert!(create_latency("vfc", &params, Latency::NextFrame).is_err());
    assert!(coherent_cull::check_name("bogus").is_err());
    // nohc and pvs need their data: an error saying so, through either function.
    for name in ["nohc", "pvs"] {
        assert!(create(name, &params).is_err(), "{name}");
        assert!(create_with(name, &setup).is_err(), "{name}");
    }
    // Every known name is created with what it needs.
    let full = CullerSetup {
        nohc: Some(NohcParams::new(costs(), (64, 64), vec![])),
        pvs: Some(Arc::new(Pvs::new("k".into(), 0, Vec3::ZERO, 1.0, vec![]))),
        ..CullerSetup::default()
    };
    for name in ALGORITHMS {
        coherent_cull::check_name(name).unwrap();
        assert_eq!(create_with(name, &full).unwrap().name(), *name);
    }
}

/// `name` (chc or chcpp) in the predicated mode with `k` frames in flight.
fn predicated(name: &str, k: u32) -> Chcpp {
    let c = match name {
        "chc" => Chcpp::new(ChcppParams::chc()),
        _ => Chcpp::new(ChcppParams::default()),
    };
    c.with_latency(Latency::Predicated).with_frames_in_flight(k)
}

#[test]
fn predicated_draws_a_newly_visible_object_at_once_with_one_submission() {
    for name in ["chc", "chcpp"] {
        for k in [1, 2] {
            let mut c = predicated(name, k);
            assert_eq!(frame_object_6_appears(&mut c, k, true), 6, "{name} k={k}");
        }
    }
    // The factory names it too.
    let c = create_named("chcpp@predicated-k2", &CullerSetup::default()).unwrap();
    assert_eq!(c.name(), "chcpp");
}

#[test]
fn predicated_misses_nothing_along_a_walk_and_converges_to_the_visible_set() {
    let bvh = ObjectBvh::build(&random_boxes(600, 3), 1);
    for (name, k, split) in modes_with_split() {
        {
            let name = format!("{name}{}", if split { " split" } else { "" });
            let mut c = predicated(name.split(' ').next().unwrap(), k);
            let mut backend = MockBackend::new(|_| 0).with_frames_in_flight(k);
            if !split {
                backend = backend.without_predicated_queries();
            }
            let (mut drawn, mut in_view, mut sent, mut parts) = (0, 0, 0, 0);
            let (mut extra, mut steady) = (0, 0);
            for f in 1..=50 {
                // A walk, then the camera stands still for twenty frames.
                let cam = walk(f.min(30));
                let fog = Fog::new(&cam, 35.0);
                let want = fog.visible_objects(&bvh);
                backend.set_visibility(move |b| fog.pixels(b));
                let fr = run(&mut c, &bvh, &cam, &mut backend, f);
                let lost = missing(&want, &fr.drawn);
                assert!(lost.is_empty(), "{name} k={k} frame {f}: {lost:?} missed");
                assert_eq!((fr.counts.submits, fr.counts.waits), (1, 0), "frame {f}");
                assert!(fr.counts.resolves <= 2);
                assert_eq!(fr.stats.blocking_waits, 0);
                assert_eq!(fr.stats.predicated_objects, fr.counts.predicated_objects);
                assert_eq!(fr.stats.objects_drawn, fr.counts.objects_drawn);
                drawn += fr.drawn.len();
                in_view += in_frustum(&bvh, &cam).len();
                sent += fr.stats.predicated_objects as usize;
                parts += fr.counts.predicated_queries;
                assert_eq!(fr.stats.predicated_queries, fr.counts.predicated_queries);
                if f > 40 {
                    // Standing still, the extra draws die out: nodes whose boxes show while
                    // their contents are hidden are held open and queried child by child.
                    extra += fr.drawn.len() - want.len();
                    steady += want.len();
                }
            }
            eprintln!("{name} k={k}: {extra} extra objects drawn while standing, {steady} visible");
            assert!(
                extra * 10 < steady,
                "{name} k={k}: {extra} extra of {steady}"
            );
            assert_eq!(backend.early_reads(), 0);
            assert!(drawn * 2 < in_view, "{name} k={k}: it culls");
            assert!(sent > 0, "{name} k={k}: draws under predicates");
            assert_eq!(
                parts > 0,
                split,
                "{name} k={k}: parts queried under predicates"
            );
        }
    }
}

/// A backend with a part test of its own gets the parts of split nodes in the frames after one
/// with at least `predicated_tested_parts_min` parts, queries before; where its test answers as
/// its queries would, the culler decides the same either way (and misses nothing).
#[test]
fn parts_go_to_the_backends_test_after_a_frame_with_enough_of_them() {
    let bvh = ObjectBvh::build(&random_boxes(600, 3), 1);
    let with_min = |min| {
        // Splitting by size alone, so that tested and queried parts come from the same
        // splits (a split ratio holds back only queried ones).
        let params = ChcppParams {
            predicated_tested_parts_min: min,
            predicated_split_ratio: 0.0,
            ..ChcppParams::default()
        };
        Chcpp::new(params).with_latency(Latency::Predicated)
    };
    for min in [0, 40, u32::MAX] {
        let (mut tested, mut queried) = (with_min(min), with_min(u32::MAX));
        let mut a = MockBackend::new(|_| 0).with_part_test();
        let mut b = MockBackend::new(|_| 0).with_part_test();
        let (mut previous, mut frames_tested) = (0, 0);
        for f in 1..=30 {
            let cam = walk(f);
            let fog = Fog::new(&cam, 35.0);
            let want = fog.visible_objects(&bvh);
            let f2 = fog.clone();
            a.set_visibility(move |x| fog.pixels(x));
            b.set_visibility(move |x| f2.pixels(x));
            let t = run(&mut tested, &bvh, &cam, &mut a, f);
            let q = run(&mut queried, &bvh, &cam, &mut b, f);
            let tag = format!("min {min} frame {f}");
            assert!(missing(&want, &t.drawn).is_empty(), "{tag}: missed");
            assert_eq!(t.drawn, q.drawn, "{tag}: the same objects drawn");
            let parts = t.counts.tested_parts + t.counts.predicated_queries;
            assert_eq!(parts, q.counts.predicated_queries, "{tag}: the same parts");
            assert_eq!(q.counts.tested_parts, 0, "{tag}");
            if previous >= min {
                assert_eq!(t.counts.predicated_queries, 0, "{tag}: parts tested");
                frames_tested += u32::from(parts > 0);
            } else {
                assert_eq!(t.counts.tested_parts, 0, "{tag}: parts queried");
            }
            previous = parts;
        }
        match min {
            u32::MAX => assert_eq!(frames_tested, 0),
            _ => assert!(frames_tested > 0, "min {min}: no frame tested its parts"),
        }
    }
}

/// `ChcppParams::for_gpu` is the defaults with one predicate level and tight bounds in the
/// predicated mode: on a backend that could query parts under predicates it queries none,
/// resolves once a frame and misses nothing, where the defaults split.
#[test]
fn the_gpu_parameters_keep_one_predicate_level_and_stay_exact() {
    let gpu = ChcppParams::for_gpu();
    let defaults = ChcppParams::default();
    assert_eq!(
        ChcppParams {
            predicated_refine_levels: defaults.predicated_refine_levels,
            predicated_tight_bounds: defaults.predicated_tight_bounds,
            ..gpu.clone()
        },
        defaults,
        "only the split policy and the predicated mode's tight bounds differ"
    );
    assert!(gpu.predicated_tight_bounds && !defaults.predicated_tight_bounds);
    let bvh = ObjectBvh::build(&random_boxes(600, 3), 1);
    let mut parts = [0, 0];
    for (i, params) in [gpu, ChcppParams::default()].into_iter().enumerate() {
        let mut c = Chcpp::new(params).with_latency(Latency::Predicated);
        let mut backend = MockBackend::new(|_| 0);
        for f in 1..=30 {
            let cam = walk(f);
            let fog = Fog::new(&cam, 35.0);
            let want = fog.visible_objects(&bvh);
            backend.set_visibility(move |b| fog.pixels(b));
            let fr = run(&mut c, &bvh, &cam, &mut backend, f);
            assert!(
                missing(&want, &fr.drawn).is_empty(),
                "params {i} frame {f}: missed"
            );
            assert_eq!((fr.counts.submits, fr.counts.waits), (1, 0));
            if i == 0 {
                assert!(fr.counts.resolves <= 1, "frame {f}: one predicate level");
            }
            parts[i] += fr.counts.predicated_queries;
        }
    }
    assert_eq!(parts[0], 0, "for_gpu queries no parts");
    assert!(parts[1] > 0, "the defaults split nodes on this walk");
}

/// On a backend that keeps draws until the resolve (`gathers_predicated_draws`), one
/// predicate level hands each frame's draws over before its one resolve, and draws what the
/// same culler draws on a backend that takes them after it; with split nodes (the defaults)
/// nothing changes.
#[test]
fn one_level_hands_its_draws_over_before_the_resolve_where_the_backend_gathers() {
    let bvh = ObjectBvh::build(&random_boxes(600, 5), 1);
    for (i, params) in [ChcppParams::for_gpu(), ChcppParams::default()]
        .into_iter()
        .enumerate()
    {
        let mut a = Chcpp::new(params.clone()).with_latency(Latency::Predicated);
        let mut b = Chcpp::new(params).with_latency(Latency::Predicated);
        let mut gathering = MockBackend::new(|_| 0).with_gathering();
        let mut plain = MockBackend::new(|_| 0);
        let mut early = 0;
        for f in 1..=30 {
            let cam = walk(f);
            let fog = Fog::new(&cam, 35.0);
            let want = fog.visible_objects(&bvh);
            let f2 = fog.clone();
            gathering.set_visibility(move |x| fog.pixels(x));
            plain.set_visibility(move |x| f2.pixels(x));
            let g = run(&mut a, &bvh, &cam, &mut gathering, f);
            let p = run(&mut b, &bvh, &cam, &mut plain, f);
            let tag = format!("params {i} frame {f}");
            assert!(missing(&want, &g.drawn).is_empty(), "{tag}: missed");
            assert_eq!(g.drawn, p.drawn, "{tag}: the same objects drawn");
            assert_eq!(g.counts.resolves, p.counts.resolves, "{tag}: resolves");
            // Where the first conditional draw lies against the frame's first resolve.
            let first_draw = g
                .events
                .iter()
                .position(|e| matches!(e, MockEvent::DrawIf { .. }));
            let first_resolve = g
                .events
                .iter()
                .position(|e| matches!(e, MockEvent::Resolve));
            if let (Some(d), Some(r)) = (first_draw, first_resolve) {
                early += u32::from(d < r);
                if i == 1 {
                    assert!(r < d, "{tag}: split frames draw after the resolve");
                }
            }
        }
        match i {
            0 => assert!(early > 0, "one level: no frame handed its draws over early"),
            _ => assert_eq!(early, 0),
        }
    }
}

/// chc and chcpp, one and two frames in flight, on a backend with and without queries under
/// predicates (nodes split into parts, or one predicate level).
fn modes_with_split() -> Vec<(&'static str, u32, bool)> {
    let mut out = Vec::new();
    for name in ["chc", "chcpp"] {
        for k in [1, 2] {
            for split in [false, true] {
                out.push((name, k, split));
            }
        }
    }
    out
}

#[test]
fn predicated_stays_exact_with_movers_and_a_camera_cut() {
    let mut bvh = ObjectBvh::build(&random_boxes(400, 9), 1);
    let cam = walk(0);
    let fog = Fog::new(&cam, 30.0);
    let visible = fog.visible_objects(&bvh);
    let mut c = predicated("chcpp", 2);
    let f2 = fog.clone();
    let mut backend = MockBackend::new(move |b| f2.pixels(b)).with_frames_in_flight(2);
    let hidden = *in_frustum(&bvh, &cam)
        .iter()
        .find(|o| !visible.contains(o))
        .unwrap();
    for f in 1..=6 {
        let fr = run(&mut c, &bvh, &cam, &mut backend, f);
        assert!(missing(&visible, &fr.drawn).is_empty());
    }
    bvh.set_bounds(hidden, box_ahead(&cam, 12.0)).unwrap();
    bvh.update();
    let fr = run(&mut c, &bvh, &cam, &mut backend, 7);
    assert!(
        fr.drawn.contains(&hidden),
        "the mover is drawn the same frame"
    );
    assert!(missing(&fog.visible_objects(&bvh), &fr.drawn).is_empty());
    // A cut to the overview, whose view shares nothing with the walk's.
    let cam = overview();
    let fog = Fog::new(&cam, 330.0);
    let want = fog.visible_objects(&bvh);
    backend.set_visibility(move |b| fog.pixels(b));
    for f in 8..=12 {
        let fr = run(&mut c, &bvh, &cam, &mut backend, f);
        assert!(missing(&want, &fr.drawn).is_empty(), "frame {f}");
        assert_eq!((fr.counts.submits, fr.counts.waits), (1, 0));
    }
}

#[test]
fn predicated_refuses_a_backend_without_predicates() {
    let (boxes, cam) = row();
    let bvh = ObjectBvh::build(&boxes, 1);
    let mut c = predicated("chcpp", 1);
    let mut backend = MockBackend::new(|_| PIXELS).without_predicates();
    let err = first_frame_error(&mut c, &bvh, &cam, &mut backend);
    assert!(matches!(err, Error::Unsupported { .. }), "{err}");
    assert!(
        err.to_string().contains("VK_EXT_conditional_rendering"),
        "{err}"
    );
    // Only chc and chcpp have the mode.
    assert!(create_latency("vfc", &ChcppParams::default(), Latency::Predicated).is_err());
}

#[test]
fn predicated_hands_over_subtrees_in_the_draw_order_it_set() {
    // Directly, and through the wrapper that keeps k frames' query ids (which must pass the
    // order on: the mock refuses ranges of an order it was not given).
    let setup = CullerSetup::default();
    for name in ["chcpp@predicated", "chcpp@predicated-k2"] {
        let mut bvh = ObjectBvh::build(&random_boxes(600, 3), 1);
        let mut c = create_named(name, &setup).unwrap();
        let mut backend = MockBackend::new(|_| 0).without_predicated_queries();
        let (mut objects, mut runs, mut ranges, mut range_draws) = (0, 0, 0, 0);
        for f in 1..=30 {
            let cam = walk(f);
            let fog = Fog::new(&cam, 35.0);
            backend.set_visibility(move |b| fog.pixels(b));
            let fr = run(c.as_mut(), &bvh, &cam, &mut backend, f);
            let mut position = vec![usize::MAX; 600];
            for (p, &o) in backend.draw_order().iter().enumerate() {
                position[o as usize] = p;
            }
            for e in &fr.events {
                if let MockEvent::DrawIf { objects: o, .. } = e {
                    objects += o.len();
                    // A run ends where the next object is not the next one of the order.
                    runs += 1 + o
                        .windows(2)
                        .filter(|w| {
                            position[w[1] as usize] != position[w[0] as usize].wrapping_add(1)
                        })
                        .count();
                }
            }
            // Every draw under a predicate came as ranges, as many as the draw has runs.
            assert_eq!(
                fr.counts.order_range_draws, fr.counts.predicated_draws,
                "{name}"
            );
            ranges += fr.counts.order_ranges as usize;
            range_draws += fr.counts.order_range_draws;
        }
        assert!(range_draws > 0, "{name}");
        assert_eq!(ranges, runs, "{name}: adjacent ranges merged");
        // Set once for a hierarchy whose leaves do not change, holding every object once.
        assert_eq!(backend.draw_orders_set(), 1, "{name}");
        let mut all = backend.draw_order().to_vec();
        all.sort_unstable();
        assert_eq!(all, (0..600).collect::<Vec<_>>());
        // Whole subtrees come as runs of the order (only the frustum's edge cuts them).
        eprintln!("{name}: {objects} objects under predicates in {runs} runs of the draw order");
        assert!(
            objects > 0 && runs * 4 < objects,
            "{name}: {objects} objects in {runs} runs"
        );
        // A removed object leaves the order, which is set again.
        bvh.remove(7).unwrap();
        bvh.update();
        run(c.as_mut(), &bvh, &walk(31), &mut backend, 31);
        assert_eq!(backend.draw_orders_set(), 2, "{name}");
        assert_eq!(backend.draw_order().len(), 599);
        assert!(!backend.draw_order().contains(&7));
    }
}

/// The predicated walk of the split-ratio tests with `params` and `k` frames in flight: `moving`
/// frames along the walk, then standing still until frame `frames` (nodes stay hidden, and
/// their history says they will). Every frame must draw every visible object; returns the
/// frames after `keep_after` with the objects visible in each.
fn split_walk(
    bvh: &ObjectBvh,
    params: ChcppParams,
    k: u32,
    backend: &mut MockBackend,
    (moving, frames, keep_after): (u64, u64, u64),
) -> Vec<(Frame, usize)> {
    let ratio = params.predicated_split_ratio;
    let mut c = Chcpp::new(params)
        .with_latency(Latency::Predicated)
        .with_frames_in_flight(k);
    let mut late = Vec::new();
    for f in 1..=frames {
        let cam = walk(f.min(moving));
        let fog = Fog::new(&cam, 35.0);
        let want = fog.visible_objects(bvh);
        backend.set_visibility(move |b| fog.pixels(b));
        let fr = run(&mut c, bvh, &cam, backend, f);
        let lost = missing(&want, &fr.drawn);
        assert!(
            lost.is_empty(),
            "ratio {ratio} k={k} frame {f}: {lost:?} missed"
        );
        if f > keep_after {
            late.push((fr, want.len()));
        }
    }
    late
}

/// Parts that the backend decides by its own test cost no query, so the split ratio (a query's
/// cost against the objects a split saves) does not hold them back: with the test, ratio 4
/// splits as many parts as the size rule.
#[test]
fn a_split_ratio_leaves_parts_alone_that_the_backend_tests() {
    let bvh = ObjectBvh::build(&random_boxes(600, 3), 1);
    let mut tested_by_ratio = Vec::new();
    for ratio in [0.0, 4.0] {
        let params = ChcppParams {
            predicated_split_ratio: ratio,
            predicated_tested_parts_min: 0,
            ..ChcppParams::default()
        };
        let mut backend = MockBackend::new(|_| 0).with_part_test();
        let late = split_walk(&bvh, params, 1, &mut backend, (20, 40, 25));
        assert!(late.iter().all(|(fr, _)| fr.counts.predicated_queries == 0));
        tested_by_ratio.push(
            late.iter()
                .map(|(fr, _)| fr.counts.tested_parts)
                .sum::<u32>(),
        );
    }
    assert!(tested_by_ratio[0] > 0, "{tested_by_ratio:?}");
    assert_eq!(
        tested_by_ratio[0], tested_by_ratio[1],
        "{tested_by_ratio:?}"
    );
}

#[test]
fn a_split_ratio_queries_fewer_parts_of_long_hidden_nodes_and_stays_exact() {
    let bvh = ObjectBvh::build(&random_boxes(600, 3), 1);
    let mut parts_by_ratio = Vec::new();
    for ratio in [0.0, 4.0, 1e9, 1e-9] {
        let params = ChcppParams {
            predicated_split_ratio: ratio,
            ..ChcppParams::default()
        };
        let mut backend = MockBackend::new(|_| 0);
        let late = split_walk(&bvh, params, 1, &mut backend, (20, 40, 25));
        let parts: u32 = late
            .iter()
            .map(|(fr, _)| fr.counts.predicated_queries)
            .sum();
        let sent: u32 = late.iter().map(|(fr, _)| fr.stats.predicated_objects).sum();
        eprintln!("ratio {ratio}: {parts} parts queried, {sent} objects under predicates");
        parts_by_ratio.push(parts);
    }
    assert!(parts_by_ratio[0] > 0, "the size rule splits nodes");
    assert!(
        parts_by_ratio[1] * 5 < parts_by_ratio[0] * 4,
        "long-hidden nodes are not worth their parts: {parts_by_ratio:?}"
    );
    // The rule only filters the size rule's splits: nearly all of them when every split
    // with an object in the frustum pays, none when none does.
    assert!(
        parts_by_ratio[2] <= parts_by_ratio[0] && parts_by_ratio[2] > parts_by_ratio[1],
        "{parts_by_ratio:?}"
    );
    assert_eq!(parts_by_ratio[3], 0, "{parts_by_ratio:?}");
}

/// With a split ratio some nodes of a frame are split and others not; standing still, the
/// extra draws still die out (a multiquery is split as a whole or not at all, so a node drawn
/// under a failed multiquery's predicate is queried on its own afterwards).
#[test]
fn a_split_ratio_converges_while_standing() {
    let bvh = ObjectBvh::build(&random_boxes(600, 3), 1);
    for k in [1, 2] {
        let params = ChcppParams {
            predicated_split_ratio: 4.0,
            ..ChcppParams::default()
        };
        let mut backend = MockBackend::new(|_| 0).with_frames_in_flight(k);
        let all = split_walk(&bvh, params, k, &mut backend, (30, 50, 0));
        let parts: u32 = all.iter().map(|(fr, _)| fr.counts.predicated_queries).sum();
        assert!(parts > 0, "k={k}: some nodes split");
        let standing = &all[40..];
        let extra: usize = standing
            .iter()
            .map(|(fr, want)| fr.drawn.len() - want)
            .sum();
        let steady: usize = standing.iter().map(|(_, want)| want).sum();
        assert!(extra * 10 < steady, "k={k}: {extra} extra of {steady}");
    }
}

/// Boxes an engine might hand over by mistake: NaN, infinite, inverted, empty, huge.
fn bad_boxes() -> Vec<Aabb> {
    let n = f32::NAN;
    let i = f32::INFINITY;
    let mut boxes = random_boxes(200, 31);
    boxes.extend([
        Aabb::new(Vec3::splat(n), Vec3::splat(n)),
        Aabb::new(Vec3::new(1.0, n, 1.0), Vec3::new(2.0, 2.0, 2.0)),
        Aabb::new(Vec3::splat(-i), Vec3::splat(i)),
        Aabb::new(Vec3::new(5.0, 0.0, 5.0), Vec3::new(4.0, 1.0, 6.0)),
        Aabb::EMPTY,
        Aabb::new(Vec3::splat(-1e30), Vec3::splat(1e30)),
        Aabb::new(Vec3::splat(50.0), Vec3::splat(50.0)),
    ]);
    boxes
}

/// Views an engine might hand over by mistake: NaN and zero matrices, the eye at the target, a
/// NaN eye.
fn bad_views(f: u64) -> CameraView {
    let good: CameraView = (&walk(f)).into();
    match f % 5 {
        1 => CameraView {
            view_proj: Mat4::from_cols_array(&[f32::NAN; 16]),
            ..good
        },
        2 => CameraView {
            view_proj: Mat4::ZERO,
            ..good
        },
        3 => (&Camera::from_pose(
            CameraPose {
                eye: Vec3::splat(50.0),
                target: Vec3::splat(50.0),
            },
            1.0,
            100.0,
        ))
            .into(),
        4 => CameraView {
            eye: Vec3::splat(f32::NAN),
            ..good
        },
        _ => good,
    }
}

/// Every culler and mode, with a latency where it has one: no panic on the boxes and views
/// above, and a frame with a good view after bad ones draws every valid box in the frustum
/// again where the mode is exact (the mock shows every valid box); a NaN view draws nothing
/// (but in the oracles, which draw the set they are given).
#[test]
fn bad_boxes_and_bad_views_neither_panic_nor_break_the_frames_after() {
    let boxes = bad_boxes();
    let mut cullers: Vec<(&str, Latency, Box<dyn Culler>)> =
        vec![("nohc", Latency::InFrame, nohc(boxes.len() + 1, 100))];
    // Every algorithm of the factory but the two that need more than parameters (nohc above;
    // pvs needs a scene's sets).
    for &name in ALGORITHMS.iter().filter(|&&n| n != "nohc" && n != "pvs") {
        for latency in Latency::ALL {
            if let Ok(c) = create_latency(name, &ChcppParams::default(), latency) {
                cullers.push((name, latency, c));
            }
        }
    }
    assert_eq!(cullers.len(), 1 + 4 + 2 * 4);
    for (name, latency, mut culler) in cullers {
        let mut bvh = ObjectBvh::build(&boxes, 1);
        let mut backend = MockBackend::new(|b: &Aabb| if b.is_valid() { PIXELS } else { 0 });
        for f in 0..30u64 {
            if f == 10 {
                // A mover that turns NaN and an insert at infinity.
                bvh.set_bounds(3, Aabb::new(Vec3::splat(f32::NAN), Vec3::ONE))
                    .unwrap();
                bvh.insert(Aabb::new(Vec3::splat(f32::INFINITY), Vec3::ONE));
                bvh.update();
            }
            let all = live_objects(&bvh);
            let input = FrameInput {
                bvh: &bvh,
                view: bad_views(f),
                frame: f,
                exact_visible: Some(&all),
            };
            let r = culler.cull_frame(&input, &mut backend);
            if f % 5 == 1 && !name.starts_with("oracle") {
                let drawn = backend.drawn_last_frame();
                assert!(
                    drawn.is_empty(),
                    "{name} {latency:?}: a NaN view drew {drawn:?}"
                );
            }
            let exact = matches!(latency, Latency::InFrame | Latency::Predicated);
            if f % 5 == 0 && f > 0 && exact {
                assert!(r.is_ok(), "{name} {latency:?} frame {f}: {r:?}");
                let want: Vec<u32> = in_frustum(&bvh, &walk(f))
                    .into_iter()
                    .filter(|&o| bvh.object_bounds(o).is_some_and(|b| b.is_valid()))
                    .collect();
                assert!(!want.is_empty());
                let missed = missing(&want, &backend.drawn_last_frame());
                assert!(
                    missed.is_empty(),
                    "{name} {latency:?} frame {f}: missed {missed:?}"
                );
            }
            backend.end_frame();
        }
    }
}

/// NOHC in the predicated mode with `k` frames in flight, for up to 2,000 objects of 100
/// triangles.
fn nohc_predicated(k: u32) -> Chcpp {
    let params = NohcParams::new(costs(), (640, 360), vec![100; 2000]);
    Chcpp::nohc(params)
        .with_latency(Latency::Predicated)
        .with_frames_in_flight(k)
}

/// The exact modes with their frames in flight: chc, chcpp and nohc predicated with 1 to
/// `max_k` frames in flight, and stop-and-wait, chc, chcpp and nohc in-frame.
fn exact_modes(max_k: u32) -> Vec<(String, Box<dyn Culler>, u32)> {
    let mut modes: Vec<(String, Box<dyn Culler>, u32)> = Vec::new();
    for k in 1..=max_k {
        for name in ["chc", "chcpp"] {
            modes.push((
                format!("{name}@predicated k={k}"),
                Box::new(predicated(name, k)),
                k,
            ));
        }
        modes.push((
            format!("nohc@predicated k={k}"),
            Box::new(nohc_predicated(k)),
            k,
        ));
    }
    for name in ["stop-and-wait", "chc", "chcpp"] {
        modes.push((
            format!("{name} in-frame"),
            create(name, &ChcppParams::default()).unwrap(),
            1,
        ));
    }
    modes.push(("nohc in-frame".into(), nohc(2000, 100), 1));
    modes
}

/// NOHC in the predicated mode: one submission and no wait a frame, nothing visible missed,
/// and its cost rule at work (some nodes queried, some opened without a query because the rule
/// says the query would not pay: drawn unconditionally, which stays exact); its history learns
/// from the results read frames later. By name (`nohc@predicated`, `nohc@predicated-k2`) it
/// takes its cost model from the setup; without one, and through `create_latency`, which has
/// no cost model, it is refused with errors that say so.
#[test]
fn nohc_in_the_predicated_mode_is_exact_and_follows_its_cost_rule() {
    let bvh = ObjectBvh::build(&random_boxes(600, 3), 1);
    for k in [1, 2] {
        let mut c = nohc_predicated(k);
        let mut backend = MockBackend::new(|_| 0).with_frames_in_flight(k);
        let (mut queried, mut skipped) = (0, 0);
        for f in 1..=40 {
            let cam = walk(f);
            let fog = Fog::new(&cam, 35.0);
            let want = fog.visible_objects(&bvh);
            backend.set_visibility(move |b| fog.pixels(b));
            let fr = run(&mut c, &bvh, &cam, &mut backend, f);
            let lost = missing(&want, &fr.drawn);
            assert!(lost.is_empty(), "k={k} frame {f}: {lost:?} missed");
            assert_eq!((fr.counts.submits, fr.counts.waits), (1, 0), "frame {f}");
            assert_eq!(fr.stats.blocking_waits, 0);
            let (q, s) = c.nohc_rule().expect("nohc").decisions;
            queried += q;
            skipped += s;
        }
        assert!(
            queried > 0 && skipped > 0,
            "k={k}: {queried} queried, {skipped} skipped"
        );
    }
    let setup = CullerSetup {
        nohc: Some(NohcParams::new(costs(), (640, 360), vec![100; 600])),
        ..CullerSetup::default()
    };
    for name in ["nohc@predicated", "nohc@predicated-k2", "nohc@next-frame"] {
        let c = create_named(name, &setup).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(c.name(), "nohc", "{name}");
    }
    let refused = create_named("nohc@predicated", &CullerSetup::default()).err();
    assert!(
        refused.is_some_and(|e| e.to_string().contains("cost model")),
        "nohc@predicated without a cost model"
    );
    let refused = create_latency("nohc", &ChcppParams::default(), Latency::Predicated).err();
    assert!(
        refused.is_some_and(|e| e.to_string().contains("create_named")),
        "create_latency says where nohc's modes come from"
    );
}

/// A scene that churns while results are in flight: each frame some objects move (some into
/// view, some out), some are inserted and some removed, and every seventh frame the hierarchy is
/// rebuilt (node ids change under queries not yet read). Every exact mode with one to three
/// frames in flight draws every visible object in every frame, and never an object that was
/// removed; the rebuilds do happen.
#[test]
fn exact_modes_stay_exact_while_the_scene_churns_under_queries_in_flight() {
    use coherent_cull::rng::Rng;
    for (name, mut culler, k) in exact_modes(3) {
        let mut rng = Rng::new(41);
        let mut bvh = ObjectBvh::build(&random_boxes(500, 17), 1);
        let mut backend = MockBackend::new(|_| 0).with_frames_in_flight(k);
        let mut removed: Vec<u32> = Vec::new();
        for f in 1..=60u64 {
            let cam = walk(f);
            if f > 3 {
                let live = live_objects(&bvh);
                for _ in 0..12 {
                    let o = live[rng.below(live.len() as u32) as usize];
                    if removed.contains(&o) {
                        continue;
                    }
                    // Half of the moves land close ahead of the camera, the others anywhere.
                    let b = if rng.below(2) == 0 {
                        box_ahead(&cam, rng.range(6.0, 30.0))
                    } else {
                        random_boxes(1, rng.next_u64())[0]
                    };
                    bvh.set_bounds(o, b).unwrap();
                }
                for _ in 0..3 {
                    let id = bvh.insert(box_ahead(&cam, rng.range(6.0, 40.0)));
                    removed.retain(|&r| r != id);
                }
                for _ in 0..3 {
                    let live = live_objects(&bvh);
                    let o = live[rng.below(live.len() as u32) as usize];
                    bvh.remove(o).unwrap();
                    removed.push(o);
                }
                if f % 7 == 0 {
                    bvh.rebuild();
                } else {
                    bvh.update();
                }
                bvh.validate().unwrap();
            }
            let fog = Fog::new(&cam, 35.0);
            let want = fog.visible_objects(&bvh);
            backend.set_visibility(move |b| fog.pixels(b));
            let fr = run(culler.as_mut(), &bvh, &cam, &mut backend, f);
            let lost = missing(&want, &fr.drawn);
            assert!(lost.is_empty(), "{name} frame {f}: {lost:?} missed");
            let gone: Vec<u32> = fr
                .drawn
                .iter()
                .copied()
                .filter(|o| removed.contains(o))
                .collect();
            assert!(gone.is_empty(), "{name} frame {f}: removed {gone:?} drawn");
        }
        assert!(bvh.rebuilds() >= 8, "{name}: {} rebuilds", bvh.rebuilds());
    }
}

/// A frame whose backend refuses a query (out of room: the mock's query limit) fails
/// `cull_frame` with that error, and the frames after it, with room again, are exact again:
/// one failed frame does not poison the culler's state, with or without `reset`, in every
/// exact mode and with frames in flight.
#[test]
fn a_frame_that_ran_out_of_queries_fails_and_the_next_ones_are_exact() {
    let bvh = ObjectBvh::build(&random_boxes(600, 5), 1);
    for reset in [false, true] {
        let mut modes = exact_modes(2);
        // The factory's frames-in-flight wrapper.
        let named = create_named("chcpp@predicated-k2", &CullerSetup::default()).unwrap();
        modes.push(("chcpp@predicated-k2 by name".into(), named, 2));
        for (name, mut culler, k) in modes {
            let mut backend = MockBackend::new(|_| 0).with_frames_in_flight(k);
            let mut failed = 0;
            for f in 1..=30u64 {
                let cam = walk(f);
                let fog = Fog::new(&cam, 35.0);
                let want = fog.visible_objects(&bvh);
                backend.set_visibility(move |b| fog.pixels(b));
                // Frames 8 and 9 have room for three queries only.
                let limited = (8..=9).contains(&f);
                backend.set_query_limit(limited.then_some(3));
                let input = FrameInput {
                    bvh: &bvh,
                    view: (&cam).into(),
                    frame: f,
                    exact_visible: None,
                };
                let r = culler.cull_frame(&input, &mut backend);
                let drawn = backend.drawn_last_frame();
                backend.end_frame();
                if limited {
                    let e = r.expect_err(&format!("{name} frame {f}: ran out of queries"));
                    assert!(e.to_string().contains("queries in a frame"), "{name}: {e}");
                    failed += 1;
                    if reset {
                        culler.reset();
                    }
                    continue;
                }
                r.unwrap_or_else(|e| panic!("{name} frame {f}: {e}"));
                let lost = missing(&want, &drawn);
                assert!(
                    lost.is_empty(),
                    "{name} (reset {reset}) frame {f}: {lost:?} missed"
                );
            }
            assert_eq!(failed, 2, "{name}");
        }
    }
}

/// A wall near the eye to the left, a small box far behind it and the row ahead: looking
/// ahead, neither is in view; then the camera turns left and both enter. Returns the frame
/// the camera turned in: the objects drawn, those drawn unconditionally and its queries.
fn turn_towards_a_wall(params: ChcppParams) -> (Vec<u32>, Vec<u32>, usize) {
    let (mut boxes, cam) = row();
    // Object 8: a wall 4 units left of the eye, 10 wide and 6 high, facing it.
    boxes.push(Aabb::new(
        Vec3::new(-4.0, -3.0, 5.0),
        Vec3::new(-3.0, 3.0, 15.0),
    ));
    // Object 9: a small box far behind the wall.
    boxes.push(Aabb::new(
        Vec3::new(-40.0, 0.0, 9.5),
        Vec3::new(-39.0, 1.0, 10.5),
    ));
    let bvh = ObjectBvh::build(&boxes, 1);
    let left = Camera::from_pose(
        CameraPose {
            eye: cam.eye,
            target: cam.eye + Vec3::new(-20.0, 0.0, 0.0),
        },
        16.0 / 9.0,
        100.0,
    );
    // Everything shows but object 9 (hidden behind the wall).
    let wall = boxes[8];
    let mut backend =
        MockBackend::new(move |b: &Aabb| if b.max.x < wall.min.x { 0 } else { PIXELS });
    let mut c = Chcpp::new(params).with_latency(Latency::Predicated);
    for f in 1..=6 {
        let fr = run(&mut c, &bvh, &cam, &mut backend, f);
        assert!(
            !fr.drawn.contains(&8) && !fr.drawn.contains(&9),
            "frame {f}"
        );
    }
    let fr = run(&mut c, &bvh, &left, &mut backend, 7);
    assert!(fr.drawn.contains(&8), "the wall that entered is drawn");
    let unconditional = fr
        .events
        .iter()
        .filter_map(|e| match e {
            MockEvent::Draw(objects) => Some(objects.clone()),
            _ => None,
        })
        .flatten()
        .collect();
    let queried = fr
        .events
        .iter()
        .filter(|e| matches!(e, MockEvent::Query { .. }))
        .count();
    (fr.drawn, unconditional, queried)
}

#[test]
fn a_large_node_entering_the_view_is_drawn_before_the_tests() {
    // By default the wall, entering large, is drawn with the unconditional draws (and hides
    // what lies behind it from the frame's tests); the small box far behind it is queried.
    let (all, drawn, _) = turn_towards_a_wall(ChcppParams::default());
    assert!(drawn.contains(&8), "unconditional draws: {drawn:?}");
    assert!(!all.contains(&9), "drawn: {all:?}");
    // Off, the wall is queried like any node entering the view and drawn under a predicate.
    let off = ChcppParams {
        predicated_enter_fraction: 0.0,
        ..ChcppParams::default()
    };
    let (_, drawn, queried) = turn_towards_a_wall(off);
    assert!(!drawn.contains(&8), "unconditional draws: {drawn:?}");
    assert!(queried > 0);
}
