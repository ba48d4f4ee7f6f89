//! The commands and flags of what some algorithms need before they can run: NOHC's device
//! calibration (`coherent calibrate`) and the PVS preprocessing (`coherent pvs`), both cached
//! in the user's cache directory and built automatically by `walk` on first use.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{bail, Result};
use clap::Args;

use coherent::app::calibrate::{self, Calibration, Source};
use coherent::app::pvs_build::{self, PvsBuild, PvsSettings};
use coherent::app::report::PreprocessSummary;
use coherent::bvh::ObjectBvh;
use coherent::culling::{NohcParams, Pvs};
use coherent::gpu::GpuContext;
use coherent::scene::{CameraPath, Scene};

use crate::cli_common::{self, SceneArgs};

/// Where calibration and PVS files live, and NOHC's parameters (its costs come from the
/// calibration).
#[derive(Args, Clone, Debug)]
pub struct CacheArgs {
    /// Cache directory of the calibration, the PVS files and glTF files' interior walks
    /// (default: $XDG_CACHE_HOME/coherent, else ~/.cache/coherent).
    #[arg(long)]
    pub cache_dir: Option<PathBuf>,
    /// Measure the device again instead of using the stored calibration.
    #[arg(long)]
    pub recalibrate: bool,
    /// NOHC: occlusion probability of a node with no query history.
    #[arg(long, default_value_t = 0.5)]
    pub nohc_prior: f32,
    /// NOHC: weight of the newest query outcome in a node's occlusion history.
    #[arg(long, default_value_t = 0.5)]
    pub nohc_history_weight: f32,
    /// NOHC: exponent of the screen-coverage term (1 - coverage)^e.
    #[arg(long, default_value_t = 1.0)]
    pub nohc_coverage_exponent: f32,
    /// NOHC: per-frame chance that a visible leaf became occluded.
    #[arg(long, default_value_t = 0.05)]
    pub nohc_turnover: f32,
}

impl CacheArgs {
    /// The cache directory: `--cache-dir`, else the user's.
    pub fn dir(&self) -> PathBuf {
        self.cache_dir
            .clone()
            .unwrap_or_else(calibrate::default_cache_dir)
    }
}

/// PVS settings on the command line.
#[derive(Args, Clone, Debug)]
pub struct PvsArgs {
    /// PVS view-cell edge length in scene units [default: 6, or a quarter of the scene's
    /// diagonal when that is less (a small model)].
    #[arg(long)]
    pub cell_size: Option<f32>,
    /// PVS sample points per view cell (each renders six ID views).
    #[arg(long, default_value_t = 8)]
    pub samples: u32,
    /// Pixels per side of each PVS ID view.
    #[arg(long, default_value_t = 128)]
    pub face_size: u32,
    /// Rays per pixel side where a ray-cast PVS ID view has a far edge (1: one ray per pixel).
    #[arg(long, default_value_t = 4)]
    pub face_refine: u32,
    /// View cells added to each side of the path (0: the cells the path passes through).
    #[arg(long, default_value_t = 0)]
    pub cell_margin: u32,
    /// Spread PVS samples over the cell enlarged by this fraction per side (conservative).
    #[arg(long, default_value_t = 0.0)]
    pub cell_enlarge: f32,
    /// Build the PVS again even if a cache file exists.
    #[arg(long)]
    pub rebuild_pvs: bool,
    /// Rasterize the PVS ID buffers (the oracle's ID pass) instead of ray casting them.
    #[arg(long)]
    pub pvs_raster: bool,
    /// Sample only the Halton points of each view cell, not also its corners and the
    /// midpoints of its sides.
    #[arg(long)]
    pub no_cell_border: bool,
}

impl PvsArgs {
    pub(crate) fn settings(&self, scene: &Scene) -> Result<PvsSettings> {
        let cell_size = match self.cell_size {
            Some(c) if c.is_finite() && c > 0.0 => c,
            Some(_) => bail!("--cell-size must be a positive number"),
            None => pvs_build::default_cell_size(scene),
        };
        if self.samples == 0 || self.face_size < 8 || self.face_size > 4096 {
            bail!("--samples must be at least 1 and --face-size between 8 and 4096");
        }
        if !(1..=16).contains(&self.face_refine) {
            bail!("--face-refine must be 1 to 16");
        }
        if !(self.cell_enlarge.is_finite() && (0.0..=4.0).contains(&self.cell_enlarge)) {
            bail!("--cell-enlarge must be between 0 and 4");
        }
        Ok(PvsSettings {
            cell_size,
            samples: self.samples,
            face_size: self.face_size,
            refine: self.face_refine,
            margin: self.cell_margin,
            enlarge: self.cell_enlarge,
            raster: self.pvs_raster,
            border: !self.no_cell_border,
        })
    }
}

/// `coherent calibrate`.
#[derive(Args, Debug)]
pub struct CalibrateArgs {
    #[command(flatten)]
    pub cache: CacheArgs,
}

/// `coherent pvs`.
#[derive(Args, Debug)]
pub struct PvsCommandArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Camera path whose surroundings get view cells (default: the scene's first path).
    #[arg(long)]
    pub path: Option<String>,
    #[command(flatten)]
    pub pvs: PvsArgs,
    #[command(flatten)]
    pub cache: CacheArgs,
}

/// `coherent calibrate`: measures (or reads) the device's costs and prints them.
pub fn calibrate_command(a: &CalibrateArgs) -> Result<()> {
    let ctx = cli_common::context(false)?;
    let cal = calibration(&ctx, &a.cache)?;
    print!("{}", cal.table());
    Ok(())
}

/// The device's calibration (measured on first use, then read from the cache).
pub fn calibration(ctx: &Arc<GpuContext>, cache: &CacheArgs) -> Result<Calibration> {
    let dir = cache.dir();
    let (cal, source) = calibrate::load_or_calibrate(ctx, &dir, cache.recalibrate)?;
    match source {
        Source::Cache => eprintln!(
            "calibration: {}",
            calibrate::cache_file(&dir, ctx).display()
        ),
        Source::Measured { .. } => eprintln!(
            "calibration: measured and stored in {}",
            calibrate::cache_file(&dir, ctx).display()
        ),
    }
    Ok(cal)
}

/// NOHC's parameters for a scene rendered at `size`.
pub fn nohc_params(
    ctx: &Arc<GpuContext>,
    cache: &CacheArgs,
    scene: &Scene,
    size: (u32, u32),
) -> Result<NohcParams> {
    let cal = calibration(ctx, cache)?;
    for (name, v) in [
        ("--nohc-prior", cache.nohc_prior),
        ("--nohc-history-weight", cache.nohc_history_weight),
        ("--nohc-turnover", cache.nohc_turnover),
    ] {
        if !(0.0..=1.0).contains(&v) {
            bail!("{name} must be between 0 and 1");
        }
    }
    if !(cache.nohc_coverage_exponent.is_finite() && cache.nohc_coverage_exponent >= 0.0) {
        bail!("--nohc-coverage-exponent must be a number >= 0");
    }
    let triangles = scene
        .objects
        .iter()
        .map(|o| o.triangle_count().min(u64::from(u32::MAX)) as u32)
        .collect();
    let mut p = NohcParams::new(cal.costs, size, triangles);
    p.prior = cache.nohc_prior;
    p.history_weight = cache.nohc_history_weight;
    p.coverage_exponent = cache.nohc_coverage_exponent;
    p.visible_turnover = cache.nohc_turnover;
    Ok(p)
}

/// `coherent pvs`: builds (or loads) the PVS of a scene's path and reports it.
pub fn pvs_command(a: &PvsCommandArgs) -> Result<()> {
    let scale = cli_common::single_scale(&a.scene)?;
    let cache_dir = a.cache.dir();
    let scene = cli_common::load_scene(&a.scene, scale, &cache_dir)?;
    let path = scene.resolve_path_cached(a.path.as_deref(), &cache_dir)?;
    let bvh = scene.hierarchy(a.scene.leaf_size);
    let ctx = cli_common::context(false)?;
    let built = pvs(&ctx, &a.scene, scale, &scene, &bvh, &path, &a.pvs, &a.cache)?;
    let s = preprocess_summary(&built, 0);
    println!(
        "pvs: {} path {}: {}, {:.1} objects per cell (max {} of {}), {:.1} s{}, {} KiB: {}",
        scene.name,
        path.name,
        s.sampling(),
        s.pvs_objects_mean,
        s.pvs_objects_max,
        scene.objects.len(),
        s.preprocess_s,
        if s.from_cache { " (cached)" } else { "" },
        s.file_bytes / 1024,
        built.file.display()
    );
    Ok(())
}

/// The PVS of `path` (built with a progress bar on first use, then read from the cache).
#[allow(clippy::too_many_arguments)]
pub fn pvs(
    ctx: &Arc<GpuContext>,
    scene_args: &SceneArgs,
    scale: f32,
    scene: &Scene,
    bvh: &ObjectBvh,
    path: &CameraPath,
    args: &PvsArgs,
    cache: &CacheArgs,
) -> Result<PvsBuild> {
    let settings = args.settings(scene)?;
    let dir = cache.dir();
    let id = scene_id(scene_args);
    if args.rebuild_pvs {
        let key = pvs_build::key(&id, scale, scene, path, &settings);
        let file = dir.join(format!(
            "pvs-{:016x}.bin",
            coherent::culling::pvs::fnv1a(key.as_bytes())
        ));
        let _ = std::fs::remove_file(file);
    }
    eprintln!(
        "pvs: preprocessing view cells along path {} (cached after the first run)",
        path.name
    );
    let bar = cli_common::progress_bar_named("samples");
    let built = pvs_build::load_or_build(
        ctx,
        &dir,
        &id,
        scale,
        scene,
        bvh,
        path,
        &settings,
        |d, t| bar.tick(d, t),
    )?;
    bar.finish();
    Ok(built)
}

/// A built-in scene's name, or a glTF file's canonical path with its size and modification
/// time (so an edited file gets a new PVS).
fn scene_id(a: &SceneArgs) -> String {
    let p = std::path::Path::new(&a.scene);
    match std::fs::metadata(p) {
        Ok(m) if m.is_file() => {
            let canon = p.canonicalize().unwrap_or_else(|_| p.to_path_buf());
            let mtime = m
                .modified()
                .ok()
                .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
                .map(|d| d.as_secs())
                .unwrap_or(0);
            let animation = match &a.animation {
                None => String::new(),
                Some(choice) => format!(":{choice:?}"),
            };
            format!(
                "{}:{}:{mtime}:{}{animation}",
                canon.display(),
                m.len(),
                a.chunk_triangles
            )
        }
        _ => a.scene.clone(),
    }
}

/// The report's preprocessing figures of a PVS.
pub fn preprocess_summary(b: &PvsBuild, frames_outside_cells: usize) -> PreprocessSummary {
    let (mean, max) = b.pvs.set_sizes();
    PreprocessSummary {
        preprocess_s: b.seconds,
        from_cache: b.from_cache,
        cells: b.pvs.cells.len(),
        cell_size: b.pvs.cell_size,
        samples: b.settings.samples,
        border: b.settings.border,
        face_size: b.settings.face_size,
        face_refine: b.settings.far_edge_rays(),
        pvs_objects_mean: mean,
        pvs_objects_max: max,
        file_bytes: b.file_bytes,
        frames_outside_cells,
    }
}

/// Frames of a walk whose eye is in no view cell of `pvs`.
pub fn frames_outside(pvs: &Pvs, path: &CameraPath, frames: u32, warmup: u32) -> usize {
    let total = warmup + frames;
    (warmup..total)
        .filter(|&i| pvs.cell_at(path.sample(i, total).eye).is_none())
        .count()
}
