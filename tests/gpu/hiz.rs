//! Two-phase Hi-Z GPU culling: the depth pyramid holds the farthest depth of its 2x2 blocks,
//! frames equal VFC's pixel for pixel (first frame and camera cuts included, odd sizes too),
//! and its counts come from the recorder — all under validation.

use crate::common;

use coherent::app::walk::{self, WalkConfig};
use coherent::culling::{self, ChcppParams};
use coherent::render::hiz::{FrameAlgorithm, HizCuller, HizParams};
use coherent::render::{FrameResult, Renderer};

/// Frames of `path` in `scene` (scaled) at `size`, rendered with VFC and Hi-Z in turn: the
/// images must be equal. `frames` are path frame numbers in order (a jump is a camera cut).
/// Returns Hi-Z's and VFC's results.
fn exactness(
    scene_name: &str,
    scale: f32,
    path: &str,
    size: (u32, u32),
    frames: &[u32],
) -> Vec<(FrameResult, FrameResult)> {
    let (ctx, log) = common::context();
    let mut out = Vec::new();
    {
        let (scene, bvh) = common::scene(scene_name, scale);
        let path = if path.is_empty() {
            scene.default_path().unwrap().clone()
        } else {
            scene.path(path).unwrap().clone()
        };
        let mut r = Renderer::new(&ctx, &scene, size.0, size.1).unwrap();
        let mut vfc = culling::create("vfc", &ChcppParams::default()).unwrap();
        let mut hiz = HizCuller::new(&r, HizParams::default()).unwrap();
        for &f in frames {
            let pose = path.pose_at(f as f32);
            let (v, reference) = common::frame(&mut r, vfc.as_mut(), &bvh, pose, f as u64);
            let cam = r.camera(pose, &bvh);
            let h = hiz.render_frame(&mut r, &cam).unwrap();
            let px = r.read_color().unwrap();
            let d = common::diff_pixels(&reference, &px);
            assert_eq!(
                d, 0,
                "{scene_name} frame {f}: hiz differs from vfc in {d} pixels"
            );
            out.push((h, v));
        }
    }
    drop(ctx);
    common::assert_silent(&log);
    out
}

/// 15 consecutive frames from `start`, then a cut to 15 frames from `cut`.
fn with_cut(start: u32, cut: u32) -> Vec<u32> {
    (start..start + 15).chain(cut..cut + 15).collect()
}

/// Checks what the recorder counted for one Hi-Z frame.
fn check_counts(h: &FrameResult, levels: u32) {
    let c = &h.counts;
    assert_eq!(
        c.dispatches,
        2 + levels,
        "two culling passes and one per level"
    );
    assert_eq!(c.indirect_draws, 2);
    assert_eq!(c.draw_calls, 2);
    assert_eq!(c.queries_begun, 0);
    assert_eq!(c.submits, 1, "one submission, no readback inside the frame");
    assert_eq!(c.indirect_objects, h.cull.objects_drawn);
}

#[test]
fn city_street_images_equal_vfc_with_first_frame_and_cut() {
    let results = exactness("city", 0.1, "street", (160, 90), &with_cut(20, 150));
    // 160x90: level 0 holds 80x45 valid texels in a 128x64 image.
    let levels = coherent::gpu::pyramid::mip_sizes((128, 64)).len() as u32;
    for (h, v) in &results {
        check_counts(h, levels);
        // Never more than the frustum's objects.
        assert!(h.counts.indirect_objects <= v.counts.object_draws);
    }
    // Occlusion culling actually culls on the street.
    assert!(results
        .iter()
        .any(|(h, v)| h.counts.indirect_objects < v.counts.object_draws));
}

#[test]
fn parking_images_equal_vfc_with_first_frame_and_cut() {
    exactness("parking", 0.3, "", (160, 90), &with_cut(0, 90));
}

#[test]
fn powerplant_images_equal_vfc_with_first_frame_and_cut() {
    exactness("powerplant", 0.25, "", (160, 90), &with_cut(0, 90));
}

#[test]
fn odd_size_1277x719_stays_exact() {
    exactness("city", 0.1, "street", (1277, 719), &[20, 21, 22, 150, 151]);
}

#[test]
fn pyramid_texels_are_the_farthest_of_the_four_below() {
    let (ctx, log) = common::context();
    {
        let (scene, bvh) = common::scene("city", 0.1);
        let path = scene.path("street").unwrap().clone();
        let (w, h) = (37u32, 23u32);
        let mut r = Renderer::new(&ctx, &scene, w, h).unwrap();
        let mut vfc = culling::create("vfc", &ChcppParams::default()).unwrap();
        common::frame(&mut r, vfc.as_mut(), &bvh, path.pose_at(20.0), 20);
        let mut hiz = HizCuller::new(&r, HizParams::default()).unwrap();
        hiz.build_pyramid(&mut r).unwrap();
        let depth = r.read_depth().unwrap();
        assert!(depth.iter().any(|&d| d < 1.0) && depth.contains(&1.0));
        let mut below = (depth, (w, h));
        assert_eq!(hiz.pyramid_level_size(0), (19, 12));
        for level in 0..hiz.pyramid_levels() {
            let size = hiz.pyramid_level_size(level);
            let texels = hiz.read_pyramid_level(&mut r, level).unwrap();
            let (src, (sw, sh)) = &below;
            for y in 0..size.1 {
                for x in 0..size.0 {
                    let mut far = 0.0f32;
                    for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let (sx, sy) = ((2 * x + dx).min(sw - 1), (2 * y + dy).min(sh - 1));
                        far = far.max(src[(sy * sw + sx) as usize]);
                    }
                    let got = texels[(y * size.0 + x) as usize];
                    assert_eq!(got, far, "level {level} texel ({x}, {y})");
                }
            }
            below = (texels, size);
        }
        assert_eq!(below.1, (1, 1), "the chain ends at 1x1");
    }
    drop(ctx);
    common::assert_silent(&log);
}

#[test]
fn walk_runs_hiz_beside_the_query_algorithms() {
    let (ctx, log) = common::context();
    {
        let (scene, bvh) = common::scene("city", 0.1);
        let path = scene.path("street").unwrap().clone();
        let mut r = Renderer::new(&ctx, &scene, 96, 64).unwrap();
        let cfg = WalkConfig {
            algorithms: vec!["vfc".into(), "chcpp".into(), "hiz".into()],
            frames: 4,
            warmup: 1,
            params: ChcppParams::default(),
            repeats: 1,
            ..Default::default()
        };
        let records = walk::run(&mut r, &bvh, &path, &cfg, |_, _| {}).unwrap();
        let hiz: Vec<_> = records.iter().filter(|x| x.algorithm == "hiz").collect();
        assert_eq!(hiz.len(), 4);
        for x in hiz {
            assert_eq!((x.draw_calls, x.queries, x.submits), (2, 0, 1));
            assert!(x.objects > 0 && x.triangles > 0);
        }
        assert!(FrameAlgorithm::create("nope", &Default::default(), &r).is_err());
    }
    drop(ctx);
    common::assert_silent(&log);
}

/// `walk --check` for hiz: its GPU-generated draws are read back, and over 30 consecutive
/// frames of each scene (including the first) it misses no object of the exact ID pass, nor
/// does vfc; the check would see a miss (a frame whose draws are not logged misses everything).
#[test]
fn hiz_misses_no_object_under_walk_check() {
    let (ctx, log) = common::context();
    {
        for (name, scale, path) in [("city", 0.1, "street"), ("powerplant", 1.0, "difficult")] {
            let (scene, bvh) = common::scene(name, scale);
            let path = scene.path(path).unwrap().clone();
            let mut r = Renderer::new(&ctx, &scene, 160, 90).unwrap();
            let cfg = WalkConfig {
                algorithms: vec!["vfc".into(), "hiz".into()],
                frames: 30,
                warmup: 0,
                check: true,
                ..Default::default()
            };
            let records = walk::run(&mut r, &bvh, &path, &cfg, |_, _| {}).unwrap();
            assert_eq!(records.len(), 60);
            for x in &records {
                assert_eq!(
                    x.missed_objects,
                    Some(0),
                    "{name} {} frame {}",
                    x.algorithm,
                    x.frame
                );
            }
            // Without the log the same check reports the visible objects as missed.
            let mut hiz = FrameAlgorithm::create("hiz", &Default::default(), &r).unwrap();
            let mut owned = Vec::new();
            let cam = r.camera(path.pose_at(0.0), &bvh);
            r.object_pixels(&bvh, &cam, &mut owned).unwrap();
            hiz.render_frame(&mut r, &bvh, &cam, 0).unwrap();
            assert!(hiz.check(&r, &owned).missed_objects > 0);
        }
    }
    drop(ctx);
    common::assert_silent(&log);
}

/// hiz with moving objects: the culler re-uploads the boxes of objects that moved, so over 40
/// frames of city with 40 cars driving it misses no object (walk --check), like vfc.
#[test]
fn hiz_follows_movers() {
    let (ctx, log) = common::context();
    {
        let mut scene = coherent::scene::Scene::load("city", 0.1, 4096).unwrap();
        let movers = coherent::scene::movers::Movers::add(&mut scene, 40);
        let mut bvh = common::bvh_of(&scene);
        let path = scene.path("street").unwrap().clone();
        let mut r = Renderer::new(&ctx, &scene, 160, 90).unwrap();
        let cfg = WalkConfig {
            algorithms: vec!["vfc".into(), "hiz".into()],
            frames: 40,
            warmup: 0,
            check: true,
            ..Default::default()
        };
        let mut mw = walk::MoverWalk {
            movers: &movers,
            baseline: None,
            baseline_algorithms: Vec::new(),
        };
        let (records, _) =
            walk::run_with_movers(&mut r, &mut bvh, &path, &cfg, &mut mw, |_, _| {}).unwrap();
        assert_eq!(records.len(), 80);
        for x in &records {
            assert_eq!(
                x.missed_objects,
                Some(0),
                "{} frame {}",
                x.algorithm,
                x.frame
            );
        }
    }
    drop(ctx);
    common::assert_silent(&log);
}

#[test]
fn phase_one_draws_last_frames_visible_and_phase_two_the_rest() {
    let (ctx, log) = common::context();
    {
        let (scene, bvh) = common::scene("city", 0.1);
        let path = scene.path("street").unwrap().clone();
        let mut r = Renderer::new(&ctx, &scene, 160, 90).unwrap();
        let mut hiz = HizCuller::new(&r, HizParams::default()).unwrap();
        let mut phases = Vec::new();
        for f in 20..26 {
            let cam = r.camera(path.pose_at(f as f32), &bvh);
            let res = hiz.render_frame(&mut r, &cam).unwrap();
            let p = hiz.last_phase_objects();
            assert_eq!(p[0] + p[1], res.counts.indirect_objects);
            // Timestamps between the passes add up to the frame's device time.
            let passes: f64 = hiz.last_pass_ms().iter().sum();
            assert!(passes > 0.0 && (passes - res.gpu_ms).abs() < 1e-6);
            phases.push(p);
        }
        // First frame: nothing was visible before, phase 2 draws everything.
        assert_eq!(phases[0][0], 0);
        assert!(phases[0][1] > 0);
        // Then coherence: most objects come from phase 1.
        for p in &phases[1..] {
            assert!(p[0] > p[1], "phase 1 {} vs phase 2 {}", p[0], p[1]);
        }
        // A reset forgets visibility: phase 1 is empty again.
        hiz.reset().unwrap();
        let cam = r.camera(path.pose_at(26.0), &bvh);
        hiz.render_frame(&mut r, &cam).unwrap();
        assert_eq!(hiz.last_phase_objects()[0], 0);
    }
    drop(ctx);
    common::assert_silent(&log);
}

/// The image comparison catches a culler that is not conservative: a depth margin that culls
/// boxes up to 0.01 in depth in front of the pyramid hides visible objects.
#[test]
fn a_non_conservative_test_is_caught() {
    let (ctx, log) = common::context();
    {
        let (scene, bvh) = common::scene("city", 0.1);
        let path = scene.path("street").unwrap().clone();
        let mut r = Renderer::new(&ctx, &scene, 160, 90).unwrap();
        let mut vfc = culling::create("vfc", &ChcppParams::default()).unwrap();
        let params = HizParams {
            depth_margin: -0.01,
            ..HizParams::default()
        };
        let mut hiz = HizCuller::new(&r, params).unwrap();
        let mut differing = 0;
        for f in 20..25 {
            let pose = path.pose_at(f as f32);
            let (_, reference) = common::frame(&mut r, vfc.as_mut(), &bvh, pose, f as u64);
            let cam = r.camera(pose, &bvh);
            hiz.render_frame(&mut r, &cam).unwrap();
            differing += common::diff_pixels(&reference, &r.read_color().unwrap());
        }
        assert!(differing > 0);
    }
    drop(ctx);
    common::assert_silent(&log);
}

/// `render` and `walk` accept `hiz` (validation on; `view` in the viewer tests, which run one
/// Xvfb at a time).
#[test]
fn cli_render_and_walk_accept_hiz() {
    use std::process::Command;
    let exe = env!("CARGO_BIN_EXE_coherent");
    let dir = coherent::testing::TempDir::new("hiz-cli");
    let run = |cmd: &mut Command| {
        common::on_test_device(cmd);
        let out = cmd.output().expect("run coherent");
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(out.status.success(), "{text}");
        assert!(!text.contains("validation"), "{text}");
        text
    };
    let png = dir.join("hiz.png");
    let scene = ["--scene", "city", "--scale", "0.1"];
    run(Command::new(exe)
        .arg("render")
        .args(scene)
        .args(["--size", "160x90", "--algorithm", "hiz", "--frame", "3"])
        .arg("--out")
        .arg(&png));
    assert!(png.exists());
    let walk_dir = dir.join("walk");
    run(Command::new(exe)
        .arg("walk")
        .args(scene)
        .args(["--size", "96x64", "--frames", "3", "--warmup", "1"])
        .args(["--algorithms", "vfc,hiz", "--validation", "--out"])
        .arg(&walk_dir));
    let summary = std::fs::read_to_string(walk_dir.join("summary.json")).unwrap();
    assert!(summary.contains("\"hiz\""));
}
