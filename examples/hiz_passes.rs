//! Where a Hi-Z frame's device time goes: median time of each pass (phase-1 cull, phase-1
//! draw, pyramid, phase-2 cull, phase-2 draw) along a path, from timestamps between the passes,
//! with the objects each phase drew (validation off). On lavapipe the "device" is the CPU:
//! compute passes and rasterization share the same cores.
//!
//! Run: `cargo run --release --example hiz_passes -- [scene] [path] [frames] [WxH]`

use anyhow::Result;
use coherent::gpu::{ContextOptions, GpuContext};
use coherent::render::hiz::{HizCuller, HizParams, PASSES};
use coherent::render::Renderer;
use coherent::scene::Scene;

#[path = "common/measure.rs"]
mod measure;

use measure::median;

fn main() -> Result<()> {
    const USAGE: &str =
        "usage: hiz_passes [scene] [path] [frames] [WxH]  (city, its first path, 60, 640x360)";
    let Some(args) = measure::args(USAGE, 4)? else {
        return Ok(());
    };
    let scene_name = args.first().map(String::as_str).unwrap_or("city");
    let frames: u32 = measure::number(&args, 2, "frames", 60)?;
    let (w, h) = measure::size(&args, 3, (640, 360))?;
    let ctx = GpuContext::new(&ContextOptions::default())?;
    let scene = Scene::load(scene_name, 1.0, 4096)?;
    let bvh = scene.hierarchy(1);
    let path = match args.get(1) {
        Some(p) => scene.path(p)?.clone(),
        None => scene.default_path()?.clone(),
    };
    let mut renderer = Renderer::new(&ctx, &scene, w, h)?;
    let mut hiz = HizCuller::new(&renderer, HizParams::default())?;
    let mut passes: Vec<Vec<f64>> = vec![Vec::new(); PASSES.len()];
    let (mut total, mut phase1, mut phase2) = (Vec::new(), Vec::new(), Vec::new());
    for f in 0..frames {
        let cam = renderer.camera(path.sample(f, frames), &bvh);
        let r = hiz.render_frame(&mut renderer, &cam)?;
        for (k, ms) in hiz.last_pass_ms().iter().enumerate() {
            passes[k].push(*ms);
        }
        total.push(r.gpu_ms);
        phase1.push(hiz.last_phase_objects()[0] as f64);
        phase2.push(hiz.last_phase_objects()[1] as f64);
    }
    println!(
        "{scene_name} {}, {frames} frames, {w}x{h}, {}: medians",
        path.name, ctx.info.name
    );
    for (name, v) in PASSES.iter().zip(passes) {
        println!("  {name:<14} {:8.2} ms", median(v));
    }
    println!("  {:<14} {:8.2} ms", "frame (device)", median(total));
    println!(
        "  objects drawn: phase 1 {}, phase 2 {}",
        median(phase1),
        median(phase2)
    );
    Ok(())
}
