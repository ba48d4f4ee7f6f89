//! The walkthrough benchmark: several culling algorithms over the same camera path, interleaved
//! frame by frame (each with its own temporal state) so machine drift hits all of them alike.

use std::path::{Path, PathBuf};

use super::report::{self, FrameRecord, WalkSummary};
use crate::bvh::ObjectBvh;
use crate::culling;
use crate::culling::ChcppParams;
use crate::error::Result;
use crate::scene::camera::Camera;
use crate::scene::{CameraPath, Scene};

use crate::render::hiz::FrameAlgorithm;
use crate::render::Renderer;

/// What to walk.
#[derive(Clone, Debug, Default)]
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
    /// Give the cullers no pixel grid ([`Renderer::pixel_grid`] off): objects that fall
    /// between pixel centres are drawn like any other in the frustum.
    pub no_pixel_grid: bool,
    /// Test boxes with occlusion queries in the predicated mode too
    /// ([`Renderer::set_box_flags`] off).
    pub no_box_flags: bool,
    /// With box flags, decide the parts of split nodes by the depth part test instead of
    /// gated flags ([`Renderer::set_gated_parts`] off).
    pub depth_part_tests: bool,
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
    renderer.pixel_grid = !cfg.no_pixel_grid;
    renderer.log_drawn_objects(cfg.check);
    let mut owned = Vec::new();
    let repeats = cfg.repeats.max(1);
    let total = cfg.warmup + cfg.frames;
    let per_repeat = total as u64 * cfg.algorithms.len() as u64;
    let expected = u64::from(cfg.frames) * u64::from(repeats) * cfg.algorithms.len() as u64;
    let mut records = Vec::with_capacity(expected.min(1 << 20) as usize);
    for repeat in 0..repeats {
        let setup = culling::CullerSetup {
            params: cfg.params.clone(),
            nohc: cfg.nohc.clone(),
            pvs: cfg.pvs.clone(),
        };
        let mut cullers: Vec<FrameAlgorithm> = cfg
            .algorithms
            .iter()
            .map(|a| FrameAlgorithm::create(a, &setup, renderer))
            .collect::<Result<_>>()?;
        for c in cullers.iter_mut() {
            c.log_drawn_objects(renderer, cfg.check)?;
        }
        // One exact pass per pose, before its first algorithm: the check and the oracle share
        // it, and the oracle's timed frame no longer follows an ID pass of its own (which
        // slows the next frame); with the order turning a pose (`rotated`), every algorithm
        // follows the exact pass equally often.
        let needs_exact = needs_pose_exact(cfg.check, &cullers);
        for i in 0..total {
            let pose = path.sample(i, total);
            let camera = renderer.camera(pose, bvh);
            let exact = pose_exact(needs_exact, renderer, bvh, &camera, &mut owned)?;
            let n = cullers.len();
            for k in 0..n {
                // The order turns by one algorithm a pose (see `rotated`).
                let a = rotated(k, i, n);
                let (name, culler) = (&cfg.algorithms[a], &mut cullers[a]);
                let checked = cfg.check.then_some(owned.as_slice());
                let r = pose_frame(culler, renderer, bvh, &camera, i, exact.as_deref(), checked)?;
                if i >= cfg.warmup {
                    records.push(FrameRecord::from_frame(&r, name, i - cfg.warmup, repeat));
                }
                let done = repeat as u64 * per_repeat + i as u64 * cfg.algorithms.len() as u64;
                progress(done + k as u64 + 1, per_repeat * repeats as u64);
            }
        }
    }
    Ok(records)
}

/// With `--check` data in `records`: `missed_pixels.png`, the pixels of missed objects per
/// frame (the pop of the latency modes), and `extra_objects.png`, the drawn objects that own
/// no pixel, one line per algorithm each.
fn plot_exactness(
    dir: &Path,
    title: &str,
    records: &[FrameRecord],
    algorithms: &[String],
) -> Result<Vec<PathBuf>> {
    if !records.iter().any(|r| r.missed_pixels.is_some()) {
        return Ok(Vec::new());
    }
    let series = first_repeat_series(records, algorithms, |r| {
        (r.frame, r.missed_pixels.unwrap_or(0) as f64)
    });
    let missed = dir.join("missed_pixels.png");
    report::plot_missed_pixels(&missed, &format!("Missed pixels: {title}"), &series)?;
    let series = first_repeat_series(records, algorithms, |r| {
        (r.frame, f64::from(r.extra_objects.unwrap_or(0)))
    });
    let extra = dir.join("extra_objects.png");
    report::plot_extra_objects(
        &extra,
        &format!("Drawn objects that own no pixel: {title}"),
        &series,
    )?;
    Ok(vec![missed, extra])
}

/// One plot series per algorithm: `point` of each of its rows of the first repeat, in order.
fn first_repeat_series<T>(
    records: &[FrameRecord],
    algorithms: &[String],
    point: impl Fn(&FrameRecord) -> T,
) -> Vec<(String, Vec<T>)> {
    algorithms
        .iter()
        .map(|a| {
            let rows = records
                .iter()
                .filter(|r| &r.algorithm == a && r.repeat == 0);
            (a.clone(), rows.map(&point).collect())
        })
        .collect()
}

/// A walk's report as [`write_report`] wrote it.
pub struct WrittenReport {
    /// The walk's summary, as written to `summary.json`.
    pub summary: WalkSummary,
    /// The files written, in the order written.
    pub files: Vec<PathBuf>,
}

/// Writes `frames.csv`, `summary.json`, `frametime.png` and `counts.png` into `dir`, and with
/// `--check` records (a missed-pixel count in them) `missed_pixels.png` and `extra_objects.png`.
pub fn write_report(
    dir: &Path,
    scene: &Scene,
    path_name: &str,
    device: &str,
    size: (u32, u32),
    records: &[FrameRecord],
    algorithms: &[String],
) -> Result<WrittenReport> {
    std::fs::create_dir_all(dir)?;
    let mut files = vec![dir.join("frames.csv")];
    report::write_frames_csv(&files[0], records)?;
    let summary = report::summarize(
        &scene.name,
        scene.objects.len(),
        scene.triangle_count(),
        device,
        size,
        records,
        algorithms,
    );
    files.push(dir.join("summary.json"));
    summary.write_json(&files[1])?;
    let title = format!(
        "{} ({} objects, {:.2}M triangles), path {path_name}, {}x{}, {device}",
        scene.name,
        scene.objects.len(),
        scene.triangle_count() as f64 / 1e6,
        size.0,
        size.1
    );
    let series = first_repeat_series(records, algorithms, |r| (r.frame, r.frame_ms));
    files.push(dir.join("frametime.png"));
    report::plot_frametime(&files[2], &format!("Frame time: {title}"), &series)?;
    let counts: Vec<report::CountSeries> = first_repeat_series(records, algorithms, |r| {
        let (q, w) = (r.queries as f64, r.wasted_queries as f64);
        (r.frame, q, w, r.state_changes as f64)
    });
    files.push(dir.join("counts.png"));
    report::plot_counts(
        &files[3],
        &format!("Queries, wasted queries, state changes: {title}"),
        &counts,
    )?;
    files.extend(plot_exactness(dir, &title, records, algorithms)?);
    Ok(WrittenReport { summary, files })
}

/// Movers in a walk: the scene's built-in movers, and a copy of the scene without them on which
/// some algorithms run too, interleaved in the same walk, for comparison.
pub struct MoverWalk<'a> {
    /// The movers (objects of the walked scene).
    pub movers: &'a crate::scene::movers::Movers,
    /// The scene without movers, its renderer and hierarchy, for the baseline algorithms.
    pub baseline: Option<(&'a mut Renderer, &'a ObjectBvh)>,
    /// Algorithms that also run on the baseline (reported as `NAME-static`).
    pub baseline_algorithms: Vec<String>,
}

/// What maintaining the hierarchy cost in a walk with movers.
#[derive(Clone, Debug, Default)]
pub struct MoverStats {
    /// Number of movers.
    pub movers: usize,
    /// Per recorded frame: milliseconds to put the movers' boxes into the hierarchy and
    /// update it (refit, and rebuild when one was due).
    pub refit_ms: Vec<f64>,
    /// Full rebuilds during the walk.
    pub rebuilds: u32,
    /// Per recorded frame: milliseconds to pose the deformed meshes of a glTF animation and
    /// write their vertices (0 without them).
    pub pose_ms: Vec<f64>,
}

/// What [`place_movers`] spent.
#[derive(Clone, Copy, Debug, Default)]
pub struct Placed {
    /// Milliseconds on the hierarchy (set_bounds and update).
    pub hierarchy_ms: f64,
    /// Milliseconds posing deformed meshes (skins, morph weights) and writing their vertices.
    pub pose_ms: f64,
}

/// [`run`] with movers: before each pose, every mover goes to its place for that frame (its
/// box into `bvh`, which is then updated, its transform into the renderer's object buffer);
/// then every algorithm renders the pose, and the baseline algorithms render it on the scene
/// without movers.
pub fn run_with_movers(
    renderer: &mut Renderer,
    bvh: &mut ObjectBvh,
    path: &CameraPath,
    cfg: &WalkConfig,
    walk: &mut MoverWalk,
    mut progress: impl FnMut(u64, u64),
) -> Result<(Vec<FrameRecord>, MoverStats)> {
    renderer.visibility_threshold = cfg.params.pixel_threshold;
    renderer.pixel_grid = !cfg.no_pixel_grid;
    renderer.set_box_flags(!cfg.no_box_flags);
    renderer.set_gated_parts(!cfg.depth_part_tests);
    if let Some((base, _)) = walk.baseline.as_mut() {
        base.visibility_threshold = cfg.params.pixel_threshold;
        base.pixel_grid = !cfg.no_pixel_grid;
        base.set_box_flags(!cfg.no_box_flags);
        base.set_gated_parts(!cfg.depth_part_tests);
    }
    let total = cfg.warmup + cfg.frames;
    let runs = cfg.algorithms.len() + walk.baseline_algorithms.len();
    let per_repeat = total as u64 * runs as u64;
    let mut records = Vec::new();
    let mut stats = MoverStats {
        movers: walk.movers.len(),
        ..MoverStats::default()
    };
    let rebuilds_before = bvh.rebuilds();
    renderer.log_drawn_objects(cfg.check);
    let mut owned = Vec::new();
    for repeat in 0..cfg.repeats.max(1) {
        let mut cullers = create_all(&cfg.algorithms, cfg, renderer)?;
        for c in cullers.iter_mut() {
            c.log_drawn_objects(renderer, cfg.check)?;
            c.count_mover_draws(renderer, walk.movers.objects())?;
        }
        // As in `run`: one exact pass per pose, shared by the check and the oracle.
        let needs_exact = needs_pose_exact(cfg.check, &cullers);
        let mut base_cullers = match walk.baseline.as_mut() {
            Some((base, _)) => create_all(&walk.baseline_algorithms, cfg, base)?,
            None => Vec::new(),
        };
        for i in 0..total {
            let placed = place_movers(walk.movers, i as u64, bvh, renderer)?;
            if i >= cfg.warmup {
                stats.refit_ms.push(placed.hierarchy_ms);
                stats.pose_ms.push(placed.pose_ms);
            }
            let pose = path.sample(i, total);
            let camera = renderer.camera(pose, bvh);
            let exact = pose_exact(needs_exact, renderer, bvh, &camera, &mut owned)?;
            let mut k = 0u64;
            let n = cullers.len();
            for step in 0..n {
                let a = rotated(step, i, n);
                let (name, culler) = (&cfg.algorithms[a], &mut cullers[a]);
                let checked = cfg.check.then_some(owned.as_slice());
                let r = pose_frame(culler, renderer, bvh, &camera, i, exact.as_deref(), checked)?;
                if i >= cfg.warmup {
                    records.push(mover_record(&r, name, i - cfg.warmup, repeat));
                }
                k += 1;
                progress(
                    repeat as u64 * per_repeat + i as u64 * runs as u64 + k,
                    per_repeat * cfg.repeats.max(1) as u64,
                );
            }
            if let Some((base, base_bvh)) = walk.baseline.as_mut() {
                for (name, culler) in walk.baseline_algorithms.iter().zip(base_cullers.iter_mut()) {
                    let r = culler.render_frame(base, base_bvh, &camera, i as u64)?;
                    if i >= cfg.warmup {
                        let name = format!("{name}-static");
                        records.push(mover_record(&r, &name, i - cfg.warmup, repeat));
                    }
                    k += 1;
                    progress(
                        repeat as u64 * per_repeat + i as u64 * runs as u64 + k,
                        per_repeat * cfg.repeats.max(1) as u64,
                    );
                }
            }
        }
    }
    stats.rebuilds = bvh.rebuilds() - rebuilds_before;
    Ok((records, stats))
}

/// Whether a walk runs the exact pass at each pose: for `--check`, or for a culler that draws
/// the exact set (the oracle). The box oracle finds its set with a pass of its own, so it
/// needs none.
fn needs_pose_exact(check: bool, cullers: &[FrameAlgorithm]) -> bool {
    check
        || cullers
            .iter()
            .any(|c| c.needs_exact_visibility() && !c.needs_box_visibility())
}

/// The pose's exact pass when the walk needs one (`--check` or the oracle): `owned` gets each
/// object's pixels, and the visible objects come back front to back.
fn pose_exact(
    needs: bool,
    renderer: &mut Renderer,
    bvh: &ObjectBvh,
    camera: &Camera,
    owned: &mut Vec<u32>,
) -> Result<Option<Vec<u32>>> {
    if needs {
        renderer.exact_pass(bvh, camera, owned).map(Some)
    } else {
        Ok(None)
    }
}

/// `culler`'s frame of pose `pose`, with the pose's exact visible set where known, checked
/// against the pose's pixels (`--check`) when given.
fn pose_frame(
    culler: &mut FrameAlgorithm,
    renderer: &mut Renderer,
    bvh: &ObjectBvh,
    camera: &Camera,
    pose: u32,
    exact: Option<&[u32]>,
    checked: Option<&[u32]>,
) -> Result<crate::render::FrameResult> {
    let mut r = culler.render_frame_given(renderer, bvh, camera, u64::from(pose), exact)?;
    if let Some(pixels) = checked {
        r.check = Some(culler.check(renderer, pixels));
    }
    Ok(r)
}

/// The algorithm that runs `step`-th at pose `pose` of `n`: the order turns by one algorithm
/// a pose, so that each runs first (just after the pose's exact pass) and after each other
/// algorithm equally often. On lavapipe a frame is slower after the exact pass, and slower or
/// faster after some algorithms than after others; a fixed order gave those effects to the
/// same algorithms in every pose.
fn rotated(step: usize, pose: u32, n: usize) -> usize {
    (step + pose as usize) % n.max(1)
}

/// A frame's record in a walk with movers: with the recorder's count of mover draws (0 on the
/// scene without movers).
fn mover_record(
    r: &crate::render::FrameResult,
    name: &str,
    frame: u32,
    repeat: u32,
) -> FrameRecord {
    let mut record = FrameRecord::from_frame(r, name, frame, repeat);
    record.mover_draws = Some(r.counts.mover_draws);
    record
}

/// The named algorithms for `renderer`, with what `cfg` holds for nohc and pvs.
fn create_all(
    names: &[String],
    cfg: &WalkConfig,
    renderer: &Renderer,
) -> Result<Vec<FrameAlgorithm>> {
    let setup = culling::CullerSetup {
        params: cfg.params.clone(),
        nohc: cfg.nohc.clone(),
        pvs: cfg.pvs.clone(),
    };
    names
        .iter()
        .map(|a| FrameAlgorithm::create(a, &setup, renderer))
        .collect()
}

/// Puts every mover at its place for `frame` (deformed vertices and transform into the
/// renderer, box into `bvh`), updates `bvh`, and returns what that took.
pub fn place_movers(
    movers: &crate::scene::movers::Movers,
    frame: u64,
    bvh: &mut ObjectBvh,
    renderer: &mut Renderer,
) -> Result<Placed> {
    let mut hierarchy = std::time::Duration::ZERO;
    let t = std::time::Instant::now();
    movers.for_each_deformed(frame, |first, vertices| {
        renderer.set_vertices(first, vertices)
    })?;
    let pose = t.elapsed();
    movers.for_each_at(frame, |object, bounds, transform| {
        let t = std::time::Instant::now();
        bvh.set_bounds(object, bounds)?;
        hierarchy += t.elapsed();
        renderer.set_object_bounds(object, bounds)?;
        renderer.set_object_transform(object, transform)
    })?;
    let t = std::time::Instant::now();
    bvh.update();
    hierarchy += t.elapsed();
    Ok(Placed {
        hierarchy_ms: hierarchy.as_secs_f64() * 1e3,
        pose_ms: pose.as_secs_f64() * 1e3,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::culling::CullerSetup;

    fn algorithms(names: &[&str]) -> Vec<FrameAlgorithm> {
        let setup = CullerSetup::default();
        let culler = |n: &&str| FrameAlgorithm::Culler(culling::create_named(n, &setup).unwrap());
        names.iter().map(culler).collect()
    }

    #[test]
    fn the_pose_exact_pass_runs_for_the_check_and_the_oracle_only() {
        assert!(!needs_pose_exact(false, &algorithms(&["vfc", "chcpp"])));
        assert!(needs_pose_exact(true, &algorithms(&["vfc", "chcpp"])));
        assert!(needs_pose_exact(false, &algorithms(&["vfc", "oracle"])));
        // The box oracle runs its own pass (`Renderer::box_visible`).
        assert!(!needs_pose_exact(
            false,
            &algorithms(&["chcpp", "oracle-box"])
        ));
        assert!(needs_pose_exact(
            false,
            &algorithms(&["oracle-box", "oracle"])
        ));
    }

    /// The files [`write_report`] names are the files it wrote, with `--check` records and
    /// without them.
    #[test]
    fn the_report_names_the_files_it_wrote() {
        let scene = crate::scene::procedural::cornell();
        let names = vec!["vfc".to_string(), "oracle".to_string()];
        for checked in [false, true] {
            let dir = crate::testing::TempDir::new(&format!("report-files-{checked}"));
            let records: Vec<FrameRecord> = (0..4)
                .flat_map(|frame| {
                    names.iter().map(move |a| FrameRecord {
                        algorithm: a.clone(),
                        frame,
                        frame_ms: 1.0 + f64::from(frame),
                        missed_pixels: checked.then_some(0),
                        extra_objects: checked.then_some(frame),
                        ..FrameRecord::default()
                    })
                })
                .collect();
            let out = write_report(&dir, &scene, "test", "none", (8, 8), &records, &names)
                .expect("write the report");
            let mut named = out.files.clone();
            let mut found: Vec<_> = std::fs::read_dir(dir.path())
                .unwrap()
                .map(|e| e.unwrap().path())
                .collect();
            named.sort();
            found.sort();
            assert_eq!(named, found);
            assert_eq!(out.files.len(), if checked { 6 } else { 4 });
        }
    }
}
