//! Where a CHC++ frame goes on a walk: per frame, the recorder's counts (object draws, query
//! draws, state changes, submits), the stall, and the algorithm's own split of its queries
//! (previously invisible nodes tested, i-queue queries, v-queue leaves, multiqueries and how
//! many failed, query batches, those issued because the i-queue held `b` nodes, nodes
//! re-queried after a failed multiquery, and the round trips: times the traversal ran dry and
//! blocked on a result), next to the oracle's object draws at the same pose. Validation off; one line per frame on stdout
//! (tab separated, with a header), medians at the end.
//!
//! Run: `cargo run --release --example chcpp_profile -- [scene] [path] [frames] [WxH] [scale]
//! [no-oracle]` (`no-oracle` skips the oracle, whose exact ID pass dominates large scales; its column is
//! then NaN)

use anyhow::Result;
use coherent::culling::chcpp::{Chcpp, ChcppParams};
use coherent::culling::create;
use coherent::gpu::{ContextOptions, GpuContext};
use coherent::render::Renderer;
use coherent::scene::Scene;

#[path = "common/measure.rs"]
mod measure;

use measure::median;

fn main() -> Result<()> {
    const USAGE: &str =
        "usage: chcpp_profile [scene] [path] [frames] [WxH] [scale] [no-oracle]  (city street 100 640x360 1)";
    let Some(args) = measure::args(USAGE, 6)? else {
        return Ok(());
    };
    let scene_name = args.first().map(String::as_str).unwrap_or("city");
    let path_name = args.get(1).map(String::as_str).unwrap_or("street");
    let frames: u32 = measure::number(&args, 2, "frames", 100)?;
    let (w, h) = measure::size(&args, 3, (640, 360))?;
    let scale: f32 = measure::number(&args, 4, "scale", 1.0)?;
    let with_oracle = match args.get(5).map(String::as_str) {
        None => true,
        Some("no-oracle") => false,
        Some(other) => anyhow::bail!("{other:?}: the last argument can only be no-oracle; {USAGE}"),
    };
    let ctx = GpuContext::new(&ContextOptions::default())?;
    let scene = Scene::load(scene_name, scale, 4096)?;
    let bvh = scene.hierarchy(1);
    let path = scene.path(path_name)?.clone();
    let mut renderer = Renderer::new(&ctx, &scene, w, h)?;
    let mut chcpp = Chcpp::new(ChcppParams::default());
    let mut oracle = create("oracle", &ChcppParams::default())?;
    let columns = [
        "frame",
        "frame_ms",
        "stall_ms",
        "object_draws",
        "oracle_draws",
        "query_draws",
        "queries",
        "i_nodes",
        "i_queries",
        "v_queries",
        "multi",
        "failed",
        "visible_results",
        "query_culled",
        "batches",
        "full_batches",
        "requeried",
        "waits",
        "state_changes",
        "submits",
    ];
    println!("{}", columns.join("\t"));
    let mut rows: Vec<Vec<f64>> = Vec::new();
    let warmup = 10;
    for i in 0..frames + warmup {
        let cam = renderer.camera(path.sample(i, frames + warmup), &bvh);
        let r = renderer.render_frame(&mut chcpp, &bvh, &cam, i as u64)?;
        let oracle_draws = if with_oracle {
            let o = renderer.render_frame(oracle.as_mut(), &bvh, &cam, i as u64)?;
            o.counts.object_draws as f64
        } else {
            f64::NAN
        };
        if i < warmup {
            continue;
        }
        let row = vec![
            i as f64,
            r.frame_ms,
            r.stall_ms,
            r.counts.object_draws as f64,
            oracle_draws,
            r.counts.query_draws as f64,
            r.counts.queries_begun as f64,
            r.cull.invisible_nodes_tested as f64,
            r.cull.invisible_node_queries as f64,
            r.cull.visible_leaf_queries as f64,
            r.cull.multiqueries as f64,
            r.cull.failed_multiqueries as f64,
            r.cull.visible_results as f64,
            r.cull.query_culled as f64,
            r.cull.query_batches as f64,
            r.cull.full_batches as f64,
            r.cull.requeried as f64,
            r.cull.blocking_waits as f64,
            r.counts.state_changes as f64,
            r.counts.submits as f64,
        ];
        let text: Vec<String> = row.iter().map(|v| format!("{v:.1}")).collect();
        println!("{}", text.join("\t"));
        rows.push(row);
    }
    let medians: Vec<String> = (0..columns.len())
        .map(|c| format!("{:.1}", median(rows.iter().map(|r| r[c]).collect())))
        .collect();
    println!("median\t{}", medians[1..].join("\t"));
    Ok(())
}
