//! Foundation: context lifetime, validation capture, built-in scenes, glTF loading and its
//! errors, all under the validation layer with zero messages and no leaks at teardown.

use crate::common;

use coherent::culling::{self, ChcppParams};
use coherent::gpu::Severity;
use coherent::render::Renderer;
use coherent::scene::gltf::testdata::cube_grid_glb;
use coherent::scene::Scene;

#[test]
fn context_create_and_destroy_is_silent() {
    let (ctx, log) = common::context();
    // Vulkan 1.3 or newer (lavapipe reports 1.3, current NVIDIA drivers 1.4).
    let version: Vec<u32> = ctx
        .info
        .api_version
        .split('.')
        .map(|p| p.parse().expect("numeric version"))
        .collect();
    assert!(
        version.len() == 3 && (version[0], version[1]) >= (1, 3),
        "Vulkan 1.3 or newer, got {}",
        ctx.info.api_version
    );
    // Lavapipe is a CPU device (the predicated mode keeps its split policy there); a GPU not.
    assert_eq!(
        ctx.info.is_cpu(),
        ctx.info.name.contains("llvmpipe"),
        "{} ({})",
        ctx.info.name,
        ctx.info.device_type
    );
    drop(ctx);
    common::assert_silent(&log);
}

#[test]
fn validation_capture_is_per_context() {
    let (a, log_a) = common::context();
    let (b, log_b) = common::context();
    a.provoke_validation_error().unwrap();
    let msgs = log_a.messages();
    assert!(
        msgs.iter()
            .any(|m| m.severity == Severity::Error && m.id.contains("VkBufferCreateInfo-usage")),
        "the deliberate error was captured: {msgs:?}"
    );
    drop(a);
    drop(b);
    // The other context saw nothing.
    common::assert_silent(&log_b);
}

#[test]
fn leaked_objects_are_reported_at_teardown() {
    // Proves the teardown check can fail: a buffer created behind the library's back and never
    // destroyed is reported by the object tracker when the device is destroyed.
    let (ctx, log) = common::context();
    let info = ash::vk::BufferCreateInfo::default()
        .size(64)
        .usage(ash::vk::BufferUsageFlags::VERTEX_BUFFER)
        .sharing_mode(ash::vk::SharingMode::EXCLUSIVE);
    // SAFETY: valid device; the leak is the point of the test.
    let _leaked = unsafe { ctx.device.create_buffer(&info, None) }.unwrap();
    assert_eq!(log.count(), 0);
    drop(ctx);
    let msgs = log.messages();
    assert!(
        msgs.iter()
            .any(|m| m.text.contains("has not been destroyed")
                || m.id.contains("vkDestroyDevice-device")),
        "leak reported at teardown: {msgs:?}"
    );
}

#[test]
fn built_in_scenes_render_distinct_images() {
    let (ctx, log) = common::context();
    let mut images = Vec::new();
    for (name, scale) in [
        ("city", 0.05),
        ("parking", 0.25),
        ("powerplant", 0.25),
        ("cornell", 1.0),
        ("hall", 0.25),
    ] {
        let (scene, bvh) = common::scene(name, scale);
        assert!(!scene.objects.is_empty());
        let mut r = Renderer::new(&ctx, &scene, 96, 64).unwrap();
        let mut vfc = culling::create("vfc", &ChcppParams::default()).unwrap();
        let path = scene.default_path().unwrap().clone();
        let (res, px) = common::frame(&mut r, vfc.as_mut(), &bvh, common::pose(&path, 10), 0);
        assert!(res.counts.draw_calls > 0, "{name}: something drawn");
        let background = [px[0], px[1], px[2], px[3]];
        let non_bg = px.chunks_exact(4).filter(|p| *p != background).count();
        let distinct: std::collections::HashSet<_> = px.chunks_exact(4).collect();
        assert!(
            distinct.len() > 8,
            "{name}: image has structure ({} colors)",
            distinct.len()
        );
        assert!(non_bg > 0 || name == "cornell", "{name}: not empty");
        images.push((name, px));
    }
    for i in 0..images.len() {
        for j in i + 1..images.len() {
            assert!(
                common::diff_pixels(&images[i].1, &images[j].1) > 500,
                "{} and {} differ",
                images[i].0,
                images[j].0
            );
        }
    }
    drop(ctx);
    common::assert_silent(&log);
}

#[test]
fn city_default_size_meets_the_spec() {
    let s = Scene::load("city", 1.0, 4096).unwrap();
    assert!(s.objects.len() >= 10_000, "{} objects", s.objects.len());
    assert!(
        s.triangle_count() >= 2_000_000,
        "{} triangles",
        s.triangle_count()
    );
    assert!(s.path("street").is_ok() && s.path("overhead").is_ok());
    // Deterministic.
    let t = Scene::load("city", 1.0, 4096).unwrap();
    assert_eq!(s.objects.len(), t.objects.len());
    assert_eq!(s.vertices, t.vertices);
}

#[test]
fn gltf_written_by_the_test_loads_and_renders() {
    let dir = tempdir("gltf_ok");
    let path = dir.join("grid.glb");
    std::fs::write(&path, cube_grid_glb(7)).unwrap();
    let scene = Scene::load(path.to_str().unwrap(), 1.0, 4096).unwrap();
    assert_eq!(scene.objects.len(), 7);
    assert_eq!(scene.triangle_count(), 7 * 12);
    let (ctx, log) = common::context();
    {
        let bvh = common::bvh_of(&scene);
        let mut r = Renderer::new(&ctx, &scene, 64, 48).unwrap();
        let mut vfc = culling::create("vfc", &ChcppParams::default()).unwrap();
        let path = scene.default_path().unwrap().clone();
        let (res, _) = common::frame(&mut r, vfc.as_mut(), &bvh, common::pose(&path, 0), 0);
        assert!(res.counts.draw_calls > 0);
    }
    drop(ctx);
    common::assert_silent(&log);
}

#[test]
fn bad_gltf_inputs_give_errors_not_panics() {
    let dir = tempdir("gltf_bad");
    let good = cube_grid_glb(3);
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("truncated.glb", good[..good.len() / 2].to_vec()),
        ("garbage.glb", b"not a glb at all".to_vec()),
        ("empty.glb", cube_grid_glb(0)),
        (
            "bad.gltf",
            b"{ \"asset\": { \"version\": \"2.0\" }, \"meshes\": [ {".to_vec(),
        ),
    ];
    for (name, bytes) in cases {
        let p = dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        let err = Scene::load(p.to_str().unwrap(), 1.0, 4096)
            .expect_err(name)
            .to_string();
        assert!(err.contains(name), "{name}: error names the file: {err}");
        assert!(!err.contains('\n'), "{name}: one line: {err}");
    }
    let missing = dir.join("missing.glb");
    let err = Scene::load(missing.to_str().unwrap(), 1.0, 4096)
        .unwrap_err()
        .to_string();
    assert!(err.contains("missing.glb"), "{err}");
}

#[test]
fn cli_reports_truncated_glb_in_one_line() {
    let dir = tempdir("cli_bad");
    let good = cube_grid_glb(3);
    let p = dir.join("truncated.glb");
    std::fs::write(&p, &good[..good.len() / 2]).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_coherent"))
        .args([
            "render",
            "--scene",
            p.to_str().unwrap(),
            "--out",
            dir.join("x.png").to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.trim().lines().count(), 1, "one line: {err}");
    assert!(
        err.contains("truncated.glb") && !err.contains("panicked"),
        "{err}"
    );
}

#[test]
fn cli_rejects_bad_flags_cleanly() {
    for line in [
        "render --scene nowhere --out /tmp/x.png",
        "render --scene city --size 0x10 --out /tmp/x.png",
        "render --scene cornell --algorithm magic --out /tmp/x.png",
        "render --scene cornell --latency predicated --out /tmp/x.png",
        "render --scene cornell --algorithm chcpp --latency sideways --out /tmp/x.png",
        "pvs --scene cornell --face-refine 0",
        // A walk's frame past its frames, a warm-up without a walk, a frame past any walk.
        "render --scene cornell --walk-frames 10 --frame 10 --out /tmp/x.png",
        "render --scene cornell --warmup 5 --out /tmp/x.png",
        "render --scene cornell --frame 100001 --out /tmp/x.png",
        // The output's name is checked before the scene is loaded (or a window opened).
        "render --scene cornell --out /tmp/x",
        "view --scene cornell --screenshot /tmp/x.jpg",
    ] {
        let args: Vec<&str> = line.split_whitespace().collect();
        let named = args.contains(&"/tmp/x") || args.contains(&"/tmp/x.jpg");
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_coherent"))
            .args(&args)
            .output()
            .unwrap();
        assert!(!out.status.success(), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.starts_with("error:") && err.trim().lines().count() == 1,
            "{args:?}: {err}"
        );
        assert!(
            !named || err.contains("must end in .png"),
            "{args:?}: {err}"
        );
    }
}

/// `render --walk-frames F --frame N` takes the camera of a walk's frame N (after its
/// warm-up): on the powerplant's `difficult` path (14 segments of 30 path frames), a walk of
/// 411 frames and 10 warm-up frames (421 poses over 420 path frames) steps one path frame a
/// walk frame, so its frame 5 is path frame 15.
#[test]
fn render_takes_the_camera_of_a_walks_frame() {
    let dir = tempdir("walk-frame");
    let render = |extra: &[&str], out: &str| {
        let out = dir.path().join(out);
        let status = std::process::Command::new(env!("CARGO_BIN_EXE_coherent"))
            .args([
                "render",
                "--scene",
                "powerplant",
                "--path",
                "difficult",
                "--size",
                "96x54",
                "--cache-dir",
            ])
            .arg(dir.path())
            .args(extra)
            .arg("--out")
            .arg(&out)
            .status()
            .unwrap();
        assert!(status.success(), "{extra:?}");
        std::fs::read(out).unwrap()
    };
    let path_frame = render(&["--frame", "15"], "path15.png");
    let walk_frame = render(&["--walk-frames", "411", "--frame", "5"], "walk5.png");
    assert!(path_frame == walk_frame, "walk frame 5 is path frame 15");
    let other = render(&["--walk-frames", "411", "--frame", "6"], "walk6.png");
    assert!(path_frame != other, "the next walk frame has moved on");
    // One warm-up frame less and one walk frame more: the same 420 steps, the same pose.
    let warm = render(
        &["--walk-frames", "412", "--warmup", "9", "--frame", "6"],
        "warm9.png",
    );
    assert!(path_frame == warm, "walk frame 6 after 9 warm-up frames");
}

fn tempdir(name: &str) -> coherent::testing::TempDir {
    coherent::testing::TempDir::new(&format!("test-{name}"))
}
