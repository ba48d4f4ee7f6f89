//! The walkthrough benchmark: several culling algorithms over the same camera path, interleaved
//! frame by frame (each with its own temporal state) so machine drift hits all of them alike.

use std::path::Path;

use crate::bvh::ObjectBvh;
use crate::culling::{self, ChcppParams, Culler};
use crate::error::Result;
use crate::report::{self, FrameRecord, WalkSummary};
use crate::scene::{CameraPath, Scene};

use super::Renderer;

/// What to walk.
#[derive(Clone, Debug)]
pub struct WalkConfig {
    /// Algorithms by name, in report order.
    pub algorithms: Vec<String>,
    /// Recorded frames.
    pub frames: u32,
    /// Frames rendered first and left out of the records.
    pub warmup: u32,
    /// CHC++ parameters.
    pub params: ChcppParams,
}

/// Runs the walk: `warmup + frames` poses spread over the whole path; every algorithm renders
/// every pose in turn. `progress(done, total)` is called after each rendered frame.
pub fn run(
    renderer: &mut Renderer,
    bvh: &ObjectBvh,
    path: &CameraPath,
    cfg: &WalkConfig,
    mut progress: impl FnMut(u64, u64),
) -> Result<Vec<FrameRecord>> {
    let mut cullers: Vec<Box<dyn Culler>> = cfg
        .algorithms
        .iter()
        .map(|a| culling::create(a, &cfg.params))
        .collect::<Result<_>>()?;
    let total = cfg.warmup + cfg.frames;
    let mut records = Vec::with_capacity((cfg.frames as usize) * cullers.len());
    let steps = total as u64 * cullers.len() as u64;
    let mut done = 0;
    for i in 0..total {
        let pose = path.sample(i, total);
        let camera = renderer.camera(pose, bvh);
        for (name, culler) in cfg.algorithms.iter().zip(cullers.iter_mut()) {
            let r = renderer.render_frame(culler.as_mut(), bvh, &camera, i as u64)?;
            if i >= cfg.warmup {
                records.push(r.record(name, i - cfg.warmup));
            }
            done += 1;
            progress(done, steps);
        }
    }
    Ok(records)
}

/// Writes `frames.csv`, `summary.json`, `frametime.png` and `counts.png` into `dir`.
pub fn write_report(
    dir: &Path,
    scene: &Scene,
    path_name: &str,
    device: &str,
    size: (u32, u32),
    records: &[FrameRecord],
    algorithms: &[String],
) -> Result<WalkSummary> {
    std::fs::create_dir_all(dir)?;
    report::write_frames_csv(&dir.join("frames.csv"), records)?;
    let summary = report::summarize(
        &scene.name,
        scene.objects.len(),
        scene.triangle_count(),
        device,
        size,
        records,
        algorithms,
    );
    summary.write_json(&dir.join("summary.json"))?;
    let title = format!(
        "{} ({} objects, {:.2}M triangles), path {path_name}, {}x{}, {device}",
        scene.name,
        scene.objects.len(),
        scene.triangle_count() as f64 / 1e6,
        size.0,
        size.1
    );
    let series: Vec<(String, Vec<(u32, f64)>)> = algorithms
        .iter()
        .map(|a| {
            (
                a.clone(),
                records
                    .iter()
                    .filter(|r| &r.algorithm == a)
                    .map(|r| (r.frame, r.frame_ms))
                    .collect(),
            )
        })
        .collect();
    report::plot_frametime(
        &dir.join("frametime.png"),
        &format!("Frame time: {title}"),
        &series,
    )?;
    let counts: Vec<report::CountSeries> = algorithms
        .iter()
        .map(|a| {
            (
                a.clone(),
                records
                    .iter()
                    .filter(|r| &r.algorithm == a)
                    .map(|r| (r.frame, r.queries as f64, r.state_changes as f64))
                    .collect(),
            )
        })
        .collect();
    report::plot_counts(
        &dir.join("counts.png"),
        &format!("Queries and state changes: {title}"),
        &counts,
    )?;
    Ok(summary)
}
