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
    /// CHC++ parameters (their pixel threshold also sets the renderer's).
    pub params: ChcppParams,
    /// How many times to run the whole interleaved walk (each with fresh temporal state), so
    /// that ratios come with their spread (at least 1).
    pub repeats: u32,
    /// Render the exact ID pass at every pose and report each algorithm's missed objects
    /// and pixels (objects that own a pixel but were not drawn).
    pub check: bool,
    /// NOHC's parameters (needed when `nohc` is walked).
    pub nohc: Option<crate::culling::NohcParams>,
    /// The scene's PVS (needed when `pvs` is walked).
    pub pvs: Option<std::sync::Arc<crate::culling::Pvs>>,
}

/// Runs the walk `repeats` times: `warmup + frames` poses spread over the whole path; every
/// algorithm renders every pose in turn. `progress(done, total)` is called after each rendered
/// frame.
pub fn run(
    renderer: &mut Renderer,
    bvh: &ObjectBvh,
    path: &CameraPath,
    cfg: &WalkConfig,
    mut progress: impl FnMut(u64, u64),
) -> Result<Vec<FrameRecord>> {
    renderer.visibility_threshold = cfg.params.pixel_threshold;
    renderer.log_drawn_objects(cfg.check);
    let mut owned = Vec::new();
    let repeats = cfg.repeats.max(1);
    let total = cfg.warmup + cfg.frames;
    let per_repeat = total as u64 * cfg.algorithms.len() as u64;
    let mut records = Vec::with_capacity((cfg.frames * repeats) as usize * cfg.algorithms.len());
    for repeat in 0..repeats {
        let setup = culling::CullerSetup {
            params: cfg.params.clone(),
            nohc: cfg.nohc.clone(),
            pvs: cfg.pvs.clone(),
        };
        let mut cullers: Vec<Box<dyn Culler>> = cfg
            .algorithms
            .iter()
            .map(|a| culling::create_named(a, &setup))
            .collect::<Result<_>>()?;
        for i in 0..total {
            let pose = path.sample(i, total);
            let camera = renderer.camera(pose, bvh);
            if cfg.check {
                renderer.object_pixels(bvh, &camera, &mut owned)?;
            }
            for (k, (name, culler)) in cfg.algorithms.iter().zip(cullers.iter_mut()).enumerate() {
                let mut r = renderer.render_frame(culler.as_mut(), bvh, &camera, i as u64)?;
                if cfg.check {
                    r.check = Some(renderer.check_drawn(&owned));
                }
                if i >= cfg.warmup {
                    records.push(r.record(name, i - cfg.warmup, repeat));
                }
                let done = repeat as u64 * per_repeat + i as u64 * cfg.algorithms.len() as u64;
                progress(done + k as u64 + 1, per_repeat * repeats as u64);
            }
        }
    }
    Ok(records)
}

/// With `--check` data in `records`: `missed_pixels.png`, the pixels of missed objects per
/// frame (the pop of the latency modes), one line per algorithm.
fn plot_missed(
    dir: &Path,
    title: &str,
    records: &[FrameRecord],
    algorithms: &[String],
) -> Result<()> {
    if !records.iter().any(|r| r.missed_pixels.is_some()) {
        return Ok(());
    }
    let series: Vec<(String, Vec<(u32, f64)>)> = algorithms
        .iter()
        .map(|a| {
            let pts = records
                .iter()
                .filter(|r| &r.algorithm == a && r.repeat == 0)
                .map(|r| (r.frame, r.missed_pixels.unwrap_or(0) as f64))
                .collect();
            (a.clone(), pts)
        })
        .collect();
    report::plot_missed_pixels(
        &dir.join("missed_pixels.png"),
        &format!("Missed pixels: {title}"),
        &series,
    )?;
    Ok(())
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
                    .filter(|r| &r.algorithm == a && r.repeat == 0)
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
                    .filter(|r| &r.algorithm == a && r.repeat == 0)
                    .map(|r| {
                        let (q, w) = (r.queries as f64, r.wasted_queries as f64);
                        (r.frame, q, w, r.state_changes as f64)
                    })
                    .collect(),
            )
        })
        .collect();
    report::plot_counts(
        &dir.join("counts.png"),
        &format!("Queries, wasted queries, state changes: {title}"),
        &counts,
    )?;
    plot_missed(dir, &title, records, algorithms)?;
    Ok(summary)
}
