//! Measures what multiqueries save on `parking`: queries for previously invisible nodes per
//! frame, CHC++ with and without multiqueries, on the same path (validation off). Every count
//! comes from the renderer's recorder: queries begun minus those tagged as visible-leaf
//! (v-queue) queries.
//!
//! Run: `cargo run --release --example multiquery -- [frames] [WxH]`

use anyhow::Result;
use coherent::culling::chcpp::{Chcpp, ChcppParams};
use coherent::gpu::{ContextOptions, GpuContext};
use coherent::render::Renderer;
use coherent::scene::Scene;

#[path = "common/measure.rs"]
mod measure;

use measure::median;

fn main() -> Result<()> {
    const USAGE: &str = "usage: multiquery [frames] [WxH]  (300 1280x720)";
    let Some(args) = measure::args(USAGE, 2)? else {
        return Ok(());
    };
    let frames: u32 = measure::number(&args, 0, "frames", 300)?;
    let (w, h) = measure::size(&args, 1, (1280, 720))?;
    let ctx = GpuContext::new(&ContextOptions::default())?;
    let scene = Scene::load("parking", 1.0, 4096)?;
    let bvh = scene.hierarchy(1);
    let path = scene.default_path()?.clone();
    let mut renderer = Renderer::new(&ctx, &scene, w, h)?;
    let mut with = Chcpp::new(ChcppParams::default());
    let mut without = Chcpp::new(ChcppParams {
        multiqueries: false,
        ..ChcppParams::default()
    });
    let (mut a, mut b, mut ta, mut tb, mut qa, mut qb) =
        (vec![], vec![], vec![], vec![], vec![], vec![]);
    // Multiqueries issued (recorder tags) and failed (the algorithm's own bookkeeping: only it
    // knows a query's result was "visible, re-query the group").
    let (mut multi, mut failed) = (0u64, 0u64);
    for i in 0..frames + 10 {
        let cam = renderer.camera(path.sample(i, frames + 10), &bvh);
        let ra = renderer.render_frame(&mut with, &bvh, &cam, i as u64)?;
        let rb = renderer.render_frame(&mut without, &bvh, &cam, i as u64)?;
        if i >= 10 {
            let invisible_nodes = |c: &coherent::gpu::CommandCounts| {
                (c.queries_begun - c.visible_leaf_queries) as f64
            };
            a.push(invisible_nodes(&ra.counts));
            b.push(invisible_nodes(&rb.counts));
            qa.push(ra.counts.queries_begun as f64);
            qb.push(rb.counts.queries_begun as f64);
            ta.push(ra.frame_ms);
            multi += ra.counts.multiqueries as u64;
            failed += ra.cull.failed_multiqueries as u64;
            tb.push(rb.frame_ms);
        }
    }
    let (sa, sb): (f64, f64) = (a.iter().sum(), b.iter().sum());
    println!(
        "parking, {} objects, {frames} frames, {w}x{h}, {}",
        scene.objects.len(),
        ctx.info.name
    );
    println!("                      invisible-node queries (median / total)   all queries (median)   frame ms (median)");
    println!(
        "chcpp                   {:8.1} / {:8.0}                         {:8.1}             {:8.2}",
        median(a),
        sa,
        median(qa),
        median(ta)
    );
    println!(
        "chcpp, no multiqueries  {:8.1} / {:8.0}                         {:8.1}             {:8.2}",
        median(b),
        sb,
        median(qb),
        median(tb)
    );
    println!(
        "reduction of invisible-node queries: {:.2}x (totals); {multi} multiqueries, {failed} failed",
        sb / sa.max(1.0)
    );
    Ok(())
}
