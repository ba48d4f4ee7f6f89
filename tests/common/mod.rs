//! Shared helpers of the integration tests: validation-checked contexts, scenes, image compare.
#![allow(dead_code)]

use std::sync::Arc;

use coherent::bvh::ObjectBvh;
use coherent::culling::Culler;
use coherent::gpu::{GpuContext, ValidationLog};
use coherent::render::{FrameResult, Renderer};
use coherent::scene::{CameraPath, CameraPose, Scene};

/// A context with validation on, and its log (kept to check teardown messages too).
pub fn context() -> (Arc<GpuContext>, Arc<ValidationLog>) {
    let ctx = GpuContext::headless().expect("a Vulkan 1.3 device with the validation layer");
    let log = ctx.validation_log();
    (ctx, log)
}

/// Fails the test if the log holds any warning or error.
pub fn assert_silent(log: &ValidationLog) {
    let msgs = log.messages();
    if !msgs.is_empty() {
        for m in &msgs {
            eprintln!("{:?} {}: {}", m.severity, m.id, m.text);
        }
        panic!("{} validation messages", msgs.len());
    }
}

/// A scene and its BVH.
pub fn scene(name: &str, scale: f32) -> (Scene, ObjectBvh) {
    let s = Scene::load(name, scale, 4096).expect("scene");
    let bvh = bvh_of(&s);
    (s, bvh)
}

/// The object BVH of a scene.
pub fn bvh_of(s: &Scene) -> ObjectBvh {
    s.hierarchy(1)
}

/// Renders one frame and returns it with the pixels.
pub fn frame(
    r: &mut Renderer,
    c: &mut dyn Culler,
    bvh: &ObjectBvh,
    pose: CameraPose,
    f: u64,
) -> (FrameResult, Vec<u8>) {
    let cam = r.camera(pose, bvh);
    let res = r.render_frame(c, bvh, &cam, f).expect("frame");
    let px = r.read_color().expect("readback");
    (res, px)
}

/// Number of pixels that differ.
pub fn diff_pixels(a: &[u8], b: &[u8]) -> usize {
    a.chunks_exact(4)
        .zip(b.chunks_exact(4))
        .filter(|(x, y)| x != y)
        .count()
}

/// A path's pose at frame `f`.
pub fn pose(p: &CameraPath, f: u32) -> CameraPose {
    p.pose_at(f as f32)
}

/// A fixed device cost model for NOHC in tests (a calibration is measured in its own test):
/// `query_ms` sets how dear a query is against rendering.
pub fn cost_model(query_ms: f64) -> coherent::culling::CostModel {
    coherent::culling::CostModel {
        draw_ms: 0.06,
        triangle_ms: 2e-5,
        fragment_ms: 2e-6,
        query_ms,
        query_fragment_ms: 1e-6,
        round_trip_ms: 0.3,
    }
}

/// Triangles per object of `scene` (what NOHC's render cost counts).
pub fn triangles(scene: &Scene) -> Vec<u32> {
    scene
        .objects
        .iter()
        .map(|o| o.triangle_count() as u32)
        .collect()
}

/// What every algorithm but pvs needs for a scene with `tris` triangles per object rendered at
/// `size`: nohc gets [`cost_model`] with `query_ms`.
pub fn setup(tris: Vec<u32>, size: (u32, u32), query_ms: f64) -> coherent::culling::CullerSetup {
    coherent::culling::CullerSetup {
        nohc: Some(coherent::culling::NohcParams::new(
            cost_model(query_ms),
            size,
            tris,
        )),
        ..Default::default()
    }
}

/// `rgba` (`w` x `h` RGBA8) encoded as a PNG file's bytes (textures of the glTF files tests
/// write).
pub fn png(w: u32, h: u32, rgba: Vec<u8>) -> Vec<u8> {
    let img = image::RgbaImage::from_raw(w, h, rgba).expect("image");
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)
        .expect("png");
    out.into_inner()
}

/// Makes a child process (the CLI, an example) run on lavapipe unless the caller's
/// `COHERENT_DEVICE` names another device (the child inherits it then).
pub fn on_test_device(cmd: &mut std::process::Command) -> &mut std::process::Command {
    if std::env::var_os("COHERENT_DEVICE").is_none() {
        cmd.env("COHERENT_DEVICE", "llvmpipe");
    }
    cmd
}
