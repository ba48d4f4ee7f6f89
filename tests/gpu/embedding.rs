//! Embedding: the culler takes any camera as a view-projection matrix, an eye and a depth
//! convention (standard, reverse-Z infinite, off-axis, orthographic), and reads its queries one
//! frame late in the latency modes — one submission per frame, no waits. Under validation.

use crate::common;

use coherent::bvh::ObjectBvh;
use coherent::culling::{self, ChcppParams, Culler, Latency};
use coherent::render::Renderer;
use coherent::scene::camera::{
    frustum_rh, look_to_rh, orthographic_rh, perspective_infinite_reverse_rh,
    perspective_reverse_rh, Camera, CameraView, DepthConvention,
};
use coherent::scene::Scene;
use glam::{Mat4, Vec3};

const W: u32 = 160;
const H: u32 = 90;

/// Renders `view` with `culler` and returns the sorted objects drawn and the image.
fn drawn(
    r: &mut Renderer,
    culler: &mut dyn Culler,
    bvh: &ObjectBvh,
    view: &CameraView,
    f: u64,
) -> (Vec<u32>, Vec<u8>) {
    r.render_frame(culler, bvh, view, f).expect("frame");
    let mut d = r.drawn_objects().to_vec();
    d.sort_unstable();
    d.dedup();
    (d, r.read_color().expect("readback"))
}

/// The camera as four projections: standard, reverse-Z with the same far plane, the same
/// frustum built as an off-axis one from its near-plane rectangle, and reverse-Z infinite.
fn four_views(cam: &Camera) -> [CameraView; 4] {
    let view = cam.view();
    let eye = cam.eye.to_array();
    let h = cam.near * (cam.fov_y * 0.5).tan();
    let w = h * cam.aspect;
    let off_axis = frustum_rh(-w, w, -h, h, cam.near, cam.far) * view;
    let reverse = perspective_reverse_rh(cam.fov_y, cam.aspect, cam.near, cam.far) * view;
    let infinite = perspective_infinite_reverse_rh(cam.fov_y, cam.aspect, cam.near) * view;
    [
        CameraView::from(cam),
        CameraView::new(reverse.to_cols_array(), eye, DepthConvention::REVERSE_Z),
        CameraView::new(off_axis.to_cols_array(), eye, DepthConvention::STANDARD),
        CameraView::new(
            infinite.to_cols_array(),
            eye,
            DepthConvention::REVERSE_Z_INFINITE,
        ),
    ]
}

fn city() -> (Scene, ObjectBvh) {
    let (scene, bvh) = common::scene("city", 0.1);
    let street = Scene {
        paths: vec![scene.path("street").expect("street").clone()],
        ..scene
    };
    (street, bvh)
}

/// vfc, chcpp and chcpp@next-frame (whose decisions do not depend on when results arrive).
fn three_cullers() -> [Box<dyn Culler>; 3] {
    let p = ChcppParams::default();
    [
        culling::create("vfc", &p).expect("vfc"),
        culling::create("chcpp", &p).expect("chcpp"),
        culling::create_latency("chcpp", &p, Latency::NextFrame).expect("next-frame"),
    ]
}

/// Standard, reverse-Z and off-axis give vfc the same objects and chcpp@next-frame the same
/// objects (in-frame chcpp's choices depend on when results arrive, so for it the test is its
/// image against vfc's and no missed object); reverse-Z infinite gives vfc the same objects
/// (its depth values differ, so query counts may too: image and missed objects are the test).
#[test]
fn standard_reverse_z_and_off_axis_projections_cull_the_same_objects() {
    let (ctx, log) = common::context();
    {
        let (scene, bvh) = city();
        let path = scene.default_path().expect("path").clone();
        let mut r = Renderer::new(&ctx, &scene, W, H).expect("renderer");
        r.log_drawn_objects(true);
        let mut cullers: Vec<[Box<dyn Culler>; 3]> = (0..4).map(|_| three_cullers()).collect();
        let mut some_culled = false;
        let mut pixels = Vec::new();
        for f in 0..12u32 {
            let cam = r.camera(path.pose_at(20.0 + f as f32 * 3.0), &bvh);
            let views = four_views(&cam);
            let mut sets = Vec::new();
            for (i, (v, c)) in views.iter().zip(cullers.iter_mut()).enumerate() {
                let (vfc_set, vfc_img) = drawn(&mut r, c[0].as_mut(), &bvh, v, f as u64);
                let (chcpp_set, chcpp_img) = drawn(&mut r, c[1].as_mut(), &bvh, v, f as u64);
                assert_eq!(
                    common::diff_pixels(&vfc_img, &chcpp_img),
                    0,
                    "frame {f}: chcpp's image differs from vfc's in view {i}"
                );
                r.object_pixels(&bvh, v, &mut pixels).expect("id pass");
                let (late_set, _) = drawn(&mut r, c[2].as_mut(), &bvh, v, f as u64);
                r.render_frame(c[1].as_mut(), &bvh, v, 1000 + f as u64)
                    .expect("frame");
                let check = r.check_drawn(&pixels);
                assert_eq!(
                    check.missed_objects, 0,
                    "frame {f}: chcpp missed in view {i}"
                );
                some_culled |= chcpp_set.len() < vfc_set.len();
                sets.push((vfc_set, late_set));
            }
            for (i, s) in sets.iter().enumerate().skip(1) {
                assert_eq!(
                    s.0, sets[0].0,
                    "frame {f}: vfc drew other objects in view {i}"
                );
                if i < 3 {
                    assert_eq!(
                        s.1, sets[0].1,
                        "frame {f}: chcpp@next-frame differs in view {i}"
                    );
                }
            }
        }
        assert!(
            some_culled,
            "chcpp never culled by occlusion: the test shows nothing"
        );
    }
    common::assert_silent(&log);
}

/// Runs vfc and chcpp over `views` and asserts equal images and no missed object.
fn images_equal_vfc(r: &mut Renderer, bvh: &ObjectBvh, views: &[CameraView]) -> u32 {
    let p = ChcppParams::default();
    let mut vfc = culling::create("vfc", &p).expect("vfc");
    let mut chcpp = culling::create("chcpp", &p).expect("chcpp");
    let mut pixels = Vec::new();
    let mut culled = 0;
    for (f, v) in views.iter().enumerate() {
        let (vfc_set, a) = drawn(r, vfc.as_mut(), bvh, v, f as u64);
        let (chcpp_set, b) = drawn(r, chcpp.as_mut(), bvh, v, f as u64);
        assert_eq!(common::diff_pixels(&a, &b), 0, "frame {f}: images differ");
        r.object_pixels(bvh, v, &mut pixels).expect("id pass");
        let check = r.check_drawn(&pixels);
        assert_eq!(check.missed_objects, 0, "frame {f}: chcpp missed objects");
        assert!(check.visible_objects > 0, "frame {f}: nothing visible");
        culled += (vfc_set.len() - chcpp_set.len()) as u32;
    }
    culled
}

#[test]
fn orthographic_and_shifted_off_axis_cameras_cull_correctly() {
    let (ctx, log) = common::context();
    {
        let (scene, bvh) = city();
        let path = scene.default_path().expect("path").clone();
        let mut r = Renderer::new(&ctx, &scene, W, H).expect("renderer");
        r.log_drawn_objects(true);
        let b = bvh.nodes[0].bounds;
        let (c, e) = (b.center(), b.extent());
        // Orthographic: along the street at eye height, and from above, moving.
        let mut views = Vec::new();
        for f in 0..8 {
            let pose = path.pose_at(20.0 + f as f32 * 4.0);
            let dir = (pose.target - pose.eye).normalize();
            let view = look_to_rh(pose.eye, dir, Vec3::Y);
            let ortho = orthographic_rh(-6.0, 6.0, -3.4, 3.4, 0.1, e.length() * 2.0);
            views.push(CameraView::new(
                (ortho * view).to_cols_array(),
                pose.eye.to_array(),
                DepthConvention::STANDARD,
            ));
            let above = c + Vec3::new(f as f32 * 2.0, e.y + 5.0, 0.0);
            let view = look_to_rh(above, Vec3::NEG_Y, Vec3::Z);
            let ortho = orthographic_rh(-20.0, 20.0, -11.0, 11.0, 0.1, e.y * 2.0 + 10.0);
            views.push(CameraView::new(
                (ortho * view).to_cols_array(),
                above.to_array(),
                DepthConvention::STANDARD,
            ));
        }
        let ortho_culled = images_equal_vfc(&mut r, &bvh, &views);
        assert!(ortho_culled > 0, "orthographic chcpp never culled anything");
        // A truly off-axis (shifted) frustum, as one eye of a VR headset.
        let shifted: Vec<CameraView> = (0..8)
            .map(|f| {
                let cam = r.camera(path.pose_at(20.0 + f as f32 * 4.0), &bvh);
                let h = cam.near * (cam.fov_y * 0.5).tan();
                let w = h * cam.aspect;
                let m: Mat4 = frustum_rh(-0.4 * w, 1.6 * w, -1.2 * h, 0.8 * h, cam.near, cam.far)
                    * cam.view();
                CameraView::new(
                    m.to_cols_array(),
                    cam.eye.to_array(),
                    DepthConvention::STANDARD,
                )
            })
            .collect();
        images_equal_vfc(&mut r, &bvh, &shifted);
    }
    common::assert_silent(&log);
}

#[test]
fn next_frame_submits_once_never_waits_and_misses_nothing_on_a_static_camera() {
    let (ctx, log) = common::context();
    {
        let (scene, bvh) = city();
        let path = scene.default_path().expect("path").clone();
        let mut r = Renderer::new(&ctx, &scene, W, H).expect("renderer");
        r.log_drawn_objects(true);
        let p = ChcppParams::default();
        let mut pixels = Vec::new();
        for latency in [Latency::NextFrame, Latency::NextFrameConservative] {
            for name in ["chcpp", "chc"] {
                let mut c = culling::create_latency(name, &p, latency).expect("culler");
                let mut moving_queries = 0;
                // A moving camera, then a static one.
                for f in 0..16u32 {
                    let t = 20.0 + f.min(8) as f32 * 4.0;
                    let cam = r.camera(path.pose_at(t), &bvh);
                    let res = r
                        .render_frame(c.as_mut(), &bvh, &cam, f as u64)
                        .expect("frame");
                    let tag = format!("{name}@{} frame {f}", latency.name());
                    assert_eq!(res.counts.submits, 1, "{tag}: submits");
                    assert_eq!(res.stall_ms, 0.0, "{tag}: waited inside the frame");
                    assert_eq!(res.counts.queries_read, res.counts.queries_begun, "{tag}");
                    moving_queries += res.counts.queries_begun;
                    if f >= 9 {
                        // Static since frame 8: its results decide frame 9.
                        r.object_pixels(&bvh, &cam, &mut pixels).expect("id pass");
                        let check = r.check_drawn(&pixels);
                        assert_eq!(check.missed_objects, 0, "{tag}: missed on a static camera");
                    }
                }
                assert!(moving_queries > 0, "{name}: no queries at all");
            }
        }
    }
    common::assert_silent(&log);
}

/// k = 2 frames in flight on the built-in renderer (through `FramesInFlight`, which keeps each
/// frame's GPU results in one of two slots and hides them until two frames later): one
/// submission per frame, no stall, every query read exactly once and never early, nothing
/// missed once the camera has been static for k frames.
#[test]
fn two_frames_in_flight_read_two_frames_late_and_miss_nothing_on_a_static_camera() {
    use coherent::culling::latency::{create_with_frames_in_flight, FramesInFlight};
    let (ctx, log) = common::context();
    {
        let (scene, bvh) = city();
        let path = scene.default_path().expect("path").clone();
        let mut r = Renderer::new(&ctx, &scene, W, H).expect("renderer");
        r.log_drawn_objects(true);
        let p = ChcppParams::default();
        let mut pixels = Vec::new();
        for latency in [Latency::NextFrame, Latency::NextFrameConservative] {
            let inner = create_with_frames_in_flight("chcpp", &p, latency, 2).expect("culler");
            let mut c = FramesInFlight::new(inner, 2);
            let (mut begun, mut read, mut missed_moving) = (0, 0, 0);
            for f in 0..16u32 {
                let t = 20.0 + f.min(8) as f32 * 4.0;
                let cam = r.camera(path.pose_at(t), &bvh);
                let res = r.render_frame(&mut c, &bvh, &cam, f as u64).expect("frame");
                let tag = format!("chcpp@{} k=2 frame {f}", latency.name());
                assert_eq!(res.counts.submits, 1, "{tag}: submits");
                assert_eq!(res.stall_ms, 0.0, "{tag}: waited inside the frame");
                begun += res.counts.queries_begun;
                read += res.cull.visible_results;
                r.object_pixels(&bvh, &cam, &mut pixels).expect("id pass");
                let check = r.check_drawn(&pixels);
                if f >= 10 {
                    // Static since frame 8: its results are read in frame 10.
                    assert_eq!(check.missed_objects, 0, "{tag}: missed on a static camera");
                } else {
                    missed_moving += check.missed_objects;
                }
            }
            assert!(begun > 0 && read > 0, "{latency:?}: no queries read at all");
            assert_eq!(
                c.early_reads(),
                0,
                "{latency:?}: a query was read before k frames"
            );
            eprintln!("{latency:?} k=2: {missed_moving} objects missed while moving");
        }
    }
    common::assert_silent(&log);
}

/// A culler reading k = 2 frames late refuses a backend that keeps results for one frame
/// (the built-in renderer without `FramesInFlight`), instead of reading the wrong queries.
#[test]
fn two_frames_in_flight_need_a_backend_that_keeps_two_frames() {
    let (ctx, log) = common::context();
    {
        let (scene, bvh) = city();
        let path = scene.default_path().expect("path").clone();
        let mut r = Renderer::new(&ctx, &scene, W, H).expect("renderer");
        let p = ChcppParams::default();
        let mut c = coherent::culling::latency::create_with_frames_in_flight(
            "chcpp",
            &p,
            Latency::NextFrame,
            2,
        )
        .expect("culler");
        let cam = r.camera(path.pose_at(20.0), &bvh);
        let err = r.render_frame(c.as_mut(), &bvh, &cam, 0).err();
        let err = err.map(|e| e.to_string()).unwrap_or_default();
        assert!(err.contains("frames_in_flight"), "no clear error: {err:?}");
    }
    common::assert_silent(&log);
}

/// The binary of example `name`, built by cargo for this test's profile (or, where there is
/// no cargo, the one already built beside the test binary).
fn example_binary(name: &str) -> std::path::PathBuf {
    let exe = std::env::current_exe().expect("test binary");
    let profile_dir = exe.parent().and_then(|d| d.parent()).expect("target dir");
    let mut build = std::process::Command::new(env!("CARGO"));
    build.args(["build", "--example", name]);
    if profile_dir.ends_with("release") {
        build.arg("--release");
    }
    let exe = profile_dir.join("examples").join(name);
    match build.status() {
        Ok(status) => assert!(status.success(), "building example {name} failed"),
        // No cargo where the suite runs (test binaries copied to a machine without a Rust
        // toolchain): the example built beside them is used.
        Err(e) => assert!(exe.exists(), "cargo build --example {name}: {e}"),
    }
    exe
}

/// `examples/engine.rs` (its own device, two frames in flight, one submit per frame,
/// reverse-Z infinite matrices, chcpp in the predicated mode with k = 2, next-frame on a
/// device without conditional rendering) runs a few frames, submits once per frame, never
/// waits, reads results from frame 2 on and has no validation message.
/// Runs the engine example with `args` on the suite's device; it must succeed without a
/// validation message. Returns its output and its frame rows: frame, cull ms, pace ms, draws,
/// predicated, breaks, queries, multi, binds, switches, visible, submits, waits.
fn run_engine(args: &[&str]) -> (String, Vec<Vec<f64>>) {
    let mut cmd = std::process::Command::new(example_binary("engine"));
    cmd.args(args);
    common::on_test_device(&mut cmd);
    let out = cmd.output().expect("run the engine example");
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "engine failed:\n{text}\n{err}");
    assert!(text.contains("validation: no messages"), "{text}");
    let rows = text
        .lines()
        .filter_map(|l| l.split_whitespace().map(|w| w.parse().ok()).collect())
        .filter(|r: &Vec<f64>| r.len() == 13)
        .collect();
    (text, rows)
}

#[test]
fn engine_example_runs_with_two_frames_in_flight() {
    let (text, rows) = run_engine(&["--frames", "8"]);
    assert!(text.contains("predicated mode"), "runs predicated: {text}");
    // The culler's subtree order reaches the engine's draw callback once (the leaves of the
    // engine's hierarchy never change).
    assert!(text.contains("draw order received 1 time(s)"), "{text}");
    // The predicated columns are checked, then dropped.
    let rows: Vec<Vec<f64>> = rows
        .into_iter()
        .map(|mut r: Vec<f64>| {
            assert!(
                r[5] <= 2.0 && r[4] <= r[3],
                "two pass breaks at most, predicated ⊆ draws: {text}"
            );
            r.drain(4..6);
            r
        })
        .collect();
    assert_eq!(rows.len(), 8, "{text}");
    for r in &rows {
        assert_eq!((r[9], r[10]), (1.0, 0.0), "submits, waits: {text}");
        // coherent-ash binds its box pipeline once per query batch: a switch into the query
        // state and one back (or a resume of the pass) per batch at most.
        assert!(r[7] <= 2.0 * r[6], "switches vs binds: {text}");
    }
    // Nothing is known before the first results come back, two frames after frame 0.
    assert!(
        rows[..2].iter().all(|r| r[8] == 0.0),
        "read before k frames: {text}"
    );
    assert!(rows[..2].iter().all(|r| r[4] > 0.0), "no queries: {text}");
    assert!(
        rows[2..].iter().any(|r| r[8] > 0.0),
        "no result read: {text}"
    );
    assert!(
        rows[2..].iter().all(|r| r[3] > 0.0),
        "nothing drawn: {text}"
    );
}

/// The engine example with the GPU policy (`--policy gpu`: `ChcppParams::for_gpu`, one
/// predicate level, no split nodes) on whatever device the suite runs on: coherent-ash's path
/// of a GPU host, run under validation here too. At most one pass break a frame, one
/// submission, no wait, no validation message; `--policy` refuses other values.
#[test]
fn engine_example_runs_the_gpu_policy_on_any_device() {
    let (text, rows) = run_engine(&["--frames", "8", "--policy", "gpu"]);
    assert!(text.contains("one predicate level (GPU policy)"), "{text}");
    assert_eq!(rows.len(), 8, "{text}");
    for r in &rows {
        assert!(r[5] <= 1.0, "one pass break at most: {text}");
        assert_eq!((r[11], r[12]), (1.0, 0.0), "submits, waits: {text}");
    }
    let mut bad = std::process::Command::new(example_binary("engine"));
    bad.args(["--policy", "fast"]);
    common::on_test_device(&mut bad);
    let out = bad.output().expect("run the engine example");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--policy needs cpu or gpu"));
}

/// `walk --latency next-frame-k2` runs chcpp with two frames in flight on the built-in
/// renderer and reports it as `chcpp@next-frame-k2`; a bad suffix is a clear error.
#[test]
fn walk_reports_frames_in_flight_as_a_latency_suffix() {
    use std::process::Command;
    let dir = coherent::testing::TempDir::new("walk-k2");
    let walk = |latency: &str| {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_coherent"));
        cmd.args([
            "walk", "--scene", "city", "--scale", "0.1", "--size", "96x64",
        ])
        .args(["--frames", "4", "--warmup", "1", "--algorithms", "chcpp"])
        .args(["--check", "--validation", "--latency", latency, "--out"])
        .arg(&dir);
        common::on_test_device(&mut cmd);
        cmd.output().expect("run coherent")
    };
    let out = walk("in-frame,next-frame-k2");
    let text = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{text}");
    assert!(!text.contains("validation"), "{text}");
    let summary = std::fs::read_to_string(dir.join("summary.json")).expect("summary");
    assert!(summary.contains("\"chcpp@next-frame-k2\""), "{summary}");
    let bad = walk("in-frame-k2");
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("frames in flight"));
}
