//! The windowed viewer as a library call: `cargo run --example viewer -- city` (needs a display;
//! under Xvfb: `xvfb-run -a cargo run --example viewer -- city`). Keys: WASD/QE fly, mouse drag
//! look, P path playback, 1-6 algorithms (vfc, stop-and-wait, chc, chcpp, oracle, hiz), L latency
//! mode, B/I/M/T CHC++ parts, V query map, R record the camera, F12 screenshot.

use anyhow::Result;
use coherent::app::viewer::{self, ViewerConfig};
use coherent::culling::ChcppParams;
use coherent::scene::Scene;

fn main() -> Result<()> {
    let name = std::env::args().nth(1).unwrap_or_else(|| "city".into());
    if name == "--help" || name == "-h" {
        println!(
            "usage: viewer [scene]  (a built-in scene, city by default, or a .gltf/.glb file)\n\
             keys: WASD/QE fly, mouse drag look, P path playback, 1-6 algorithms (vfc, \
             stop-and-wait, chc, chcpp, oracle, hiz), L latency mode, B/I/M/T CHC++ parts, \
             V query map, R record the camera, F12 screenshot"
        );
        return Ok(());
    }
    let scene = Scene::load(&name, 1.0, 4096)?;
    let path = scene.default_path()?.clone();
    let bvh = scene.hierarchy(1);
    viewer::run(ViewerConfig {
        scene,
        bvh,
        path,
        width: 1280,
        height: 720,
        algorithm: "chcpp".into(),
        params: ChcppParams::default(),
        gpu_params: Some(ChcppParams::for_gpu()),
        frames: None,
        screenshot: None,
        stats: None,
        validation: false,
        vsync: true,
        visualize: false,
        resize_at: None,
    })?;
    Ok(())
}
