//! The windowed viewer under Xvfb on lavapipe: the non-interactive mode with validation on
//! (screenshot pixels: scene, stats overlay, query map), and its per-frame counts cross-checked
//! against Mesa's overlay layer (`VK_LAYER_MESA_overlay`), a counter that is not ours.

use std::collections::HashMap;
use std::path::Path;
use std::process::{Command, Output};

use crate::common;

/// `xvfb-run -a` picks a free display number racily: one viewer at a time, in this process
/// and in the others of the suite (scripts/run_tests.sh runs each test in its own process).
/// The lock is the returned file's (released when it is closed).
fn xvfb_lock() -> std::fs::File {
    let path = std::env::temp_dir().join("coherent-tests-xvfb.lock");
    let file = std::fs::File::create(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    file.lock()
        .unwrap_or_else(|e| panic!("lock {}: {e}", path.display()));
    file
}

fn scratch(name: &str) -> coherent::testing::TempDir {
    coherent::testing::TempDir::new(&format!("viewer-{name}"))
}

fn run_viewer(args: &[&str], env: &[(&str, &str)]) -> Output {
    let _guard = xvfb_lock();
    let mut cmd = Command::new("xvfb-run");
    cmd.args([
        "-a",
        "-s",
        "-screen 0 640x480x24",
        env!("CARGO_BIN_EXE_coherent"),
        "view",
    ])
    .args(args);
    common::on_test_device(&mut cmd);
    for (k, v) in env {
        cmd.env(k, v);
    }
    let out = cmd
        .output()
        .expect("xvfb-run must be installed (scripts/setup.sh installs xvfb)");
    eprintln!(
        "viewer stdout:\n{}\nviewer stderr:\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// `view` of the city at scale 0.1 with validation on and `args` after: asserts that it ran
/// and printed no validation message.
fn view_city_silently(args: &[&str]) {
    let mut all = vec!["--scene", "city", "--scale", "0.1", "--validation"];
    all.extend_from_slice(args);
    let out = run_viewer(&all, &[]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "viewer failed: {:?}\n{stderr}",
        out.status
    );
    assert!(
        !stderr.contains("validation"),
        "validation messages were printed:\n{stderr}"
    );
}

/// Rows of a CSV with a header, as maps from column name to value.
fn read_csv(path: &Path, sep: char) -> Vec<HashMap<String, String>> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = text.lines().filter(|l| !l.trim().is_empty());
    let header: Vec<String> = lines
        .next()
        .expect("header")
        .split(sep)
        .map(|s| s.trim().to_string())
        .collect();
    lines
        .map(|l| {
            header
                .iter()
                .cloned()
                .zip(l.split(sep).map(|s| s.trim().to_string()))
                .collect()
        })
        .collect()
}

fn num(row: &HashMap<String, String>, col: &str) -> u64 {
    row.get(col)
        .unwrap_or_else(|| panic!("column {col} missing in {row:?}"))
        .parse()
        .unwrap_or_else(|e| panic!("column {col}: {e}"))
}

#[test]
fn non_interactive_view_under_xvfb_with_validation() {
    let dir = scratch("shot");
    let shot = dir.join("v.png");
    let stats = dir.join("stats.csv");
    view_city_silently(&[
        "--size",
        "320x240",
        "--frames",
        "20",
        "--visualize",
        "--screenshot",
        shot.to_str().expect("utf-8 path"),
        "--stats",
        stats.to_str().expect("utf-8 path"),
    ]);

    let img = image::open(&shot).expect("screenshot PNG").to_rgba8();
    assert_eq!(img.dimensions(), (320, 240));
    let px = |x: u32, y: u32| img.get_pixel(x, y).0;

    // The stats panel in the top-left corner: white text on black.
    let (mut white, mut black) = (0, 0);
    for y in 4..40 {
        for x in 4..120 {
            match px(x, y) {
                [255, 255, 255, _] => white += 1,
                [0, 0, 0, _] => black += 1,
                _ => {}
            }
        }
    }
    assert!(
        white > 300,
        "too few text pixels in the stats panel: {white}"
    );
    assert!(black > 1000, "too few panel background pixels: {black}");

    // The scene: the middle band (below the panel, left of the map) has many colors, sky and more.
    let mut colors = std::collections::HashSet::new();
    for y in 60..230 {
        for x in 0..200 {
            colors.insert(px(x, y));
        }
    }
    assert!(
        colors.len() > 50,
        "the scene looks flat: {} colors",
        colors.len()
    );
    let sky = [158u8, 189, 219];
    let skyish = (0..320)
        .flat_map(|x| (40..120).map(move |y| (x, y)))
        .filter(|&(x, y)| {
            let p = px(x, y);
            (0..3).all(|i| (p[i] as i32 - sky[i] as i32).abs() < 12)
        })
        .count();
    assert!(skyish > 0, "no sky visible");

    // The query map in the bottom-right corner shows rendered (green) boxes.
    let side = 240 / 3;
    let green = (320 - side - 4..316)
        .flat_map(|x| (240 - side - 4..236).map(move |y| (x, y)))
        .filter(|&(x, y)| px(x, y) == [40, 210, 60, 255])
        .count();
    assert!(green > 20, "no rendered boxes on the query map");

    let rows = read_csv(&stats, ',');
    assert_eq!(rows.len(), 20, "one stats row per presented frame");
    for (i, r) in rows.iter().enumerate() {
        assert_eq!(num(r, "frame"), i as u64);
        assert!(num(r, "draws") > 0);
        assert!(num(r, "pipeline_binds") > 0);
    }
}

/// Mesa's overlay layer counts, per sampling period, the frames presented and the pipeline binds
/// and draws of every command buffer submitted between presents. It does not flush its last
/// period, so compare the sums over the periods it wrote with our first rows. Its `draw` counts
/// `vkCmdDraw`, `draw_indexed` `vkCmdDrawIndexed` and `draw_indexed_indirect`
/// `vkCmdDrawIndexedIndirect` (predicated CHC++ draws the objects of one predicate with one);
/// our `draws` counts them all.
/// `view` accepts `hiz` (validation on) and writes its screenshot.
#[test]
fn view_accepts_hiz() {
    let dir = scratch("hiz");
    let shot = dir.join("view.png");
    view_city_silently(&[
        "--size",
        "160x120",
        "--frames",
        "8",
        "--algorithm",
        "hiz",
        "--screenshot",
        shot.to_str().expect("utf-8 path"),
    ]);
    assert!(shot.exists(), "no screenshot");
}

#[test]
fn stats_match_mesa_overlay_layer() {
    for algorithm in [
        "vfc",
        "stop-and-wait",
        "chc",
        "chcpp",
        "oracle",
        "chcpp@predicated",
    ] {
        overlay_cross_check(algorithm);
    }
}

fn overlay_cross_check(algorithm: &str) {
    let dir = scratch(&format!("overlay-{algorithm}"));
    let overlay = dir.join("overlay.csv");
    let stats = dir.join("stats.csv");
    let config = format!(
        "output_file={},fps_sampling_period=50,pipeline_graphics,draw,draw_indexed,draw_indexed_indirect,draw_indexed_indirect_count,frame,no_display",
        overlay.display()
    );
    let out = run_viewer(
        &[
            "--scene",
            "city",
            "--scale",
            "0.1",
            "--size",
            "320x240",
            "--frames",
            "30",
            "--algorithm",
            algorithm,
            "--stats",
            stats.to_str().expect("utf-8 path"),
        ],
        &[
            ("VK_INSTANCE_LAYERS", "VK_LAYER_MESA_overlay"),
            ("VK_LAYER_MESA_OVERLAY_CONFIG", &config),
        ],
    );
    assert!(
        out.status.success(),
        "{algorithm}: viewer failed: {:?}",
        out.status
    );
    let periods = read_csv(&overlay, ',');
    assert!(
        !periods.is_empty(),
        "{algorithm}: the overlay layer wrote no sampling period (is mesa-vulkan-drivers installed?)"
    );
    let (mut frames, mut binds, mut draws) = (0, 0, 0);
    for p in &periods {
        frames += num(p, "frame");
        binds += num(p, "pipeline_graphics");
        draws += num(p, "draw")
            + num(p, "draw_indexed")
            + num(p, "draw_indexed_indirect")
            + num(p, "draw_indexed_indirect_count");
    }
    let rows = read_csv(&stats, ',');
    assert_eq!(rows.len(), 30);
    assert!(
        frames > 0 && frames <= 30,
        "{algorithm}: overlay saw {frames} frames"
    );
    let ours = &rows[..frames as usize];
    // The overlay counts graphics pipeline binds; ours include compute binds (the predicated
    // mode's depth part test).
    let our_binds: u64 = ours
        .iter()
        .map(|r| num(r, "pipeline_binds") - num(r, "compute_binds"))
        .sum();
    let our_draws: u64 = ours.iter().map(|r| num(r, "draws")).sum();
    assert_eq!(
        (our_binds, our_draws),
        (binds, draws),
        "{algorithm}: pipeline binds and draws of the first {frames} frames: ours vs Mesa's overlay layer"
    );
}

/// A resize in the middle of the run recreates the swapchain without validation messages, and
/// the last frame is presented at the new size.
#[test]
fn resize_recreates_the_swapchain_under_validation() {
    let dir = scratch("resize");
    let shot = dir.join("r.png");
    view_city_silently(&[
        "--size",
        "320x240",
        "--frames",
        "16",
        "--resize-at",
        "6:200x150",
        "--screenshot",
        shot.to_str().expect("utf-8 path"),
    ]);
    let img = image::open(&shot).expect("screenshot PNG").to_rgba8();
    assert_eq!(img.dimensions(), (200, 150));
}
