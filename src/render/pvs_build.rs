//! PVS preprocessing: view cells over the region the camera can occupy and, per cell, the union
//! of the objects that own a pixel in ID-buffer renders (the oracle's exact ID pass) from sample
//! points inside the cell, in six directions (a cube map of 90° views).
//!
//! The region: a grid of cubic cells of `cell_size` around the walked camera path — every cell
//! the path passes through plus `margin` cells to each side horizontally (the streets along a
//! `city` path, the rooms and corridors a `powerplant` path goes through, the path's
//! surroundings in a glTF scene). Sample points are stratified (Halton) over the cell enlarged
//! by `enlarge` of its size on each side: a conservative setting samples more points over a
//! larger box, at a cost proportional to `samples` × (1 + 2·enlarge)² in coverage.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use glam::Vec3;

use super::Renderer;
use crate::bvh::ObjectBvh;
use crate::culling::pvs::{fnv1a, Pvs, ViewCell};
use crate::error::Result;
use crate::gpu::GpuContext;
use crate::scene::camera::Camera;
use crate::scene::{CameraPath, Scene};

/// How the PVS is built.
#[derive(Clone, Debug, PartialEq)]
pub struct PvsSettings {
    /// Edge length of a view cell in scene units (default 6).
    pub cell_size: f32,
    /// Sample points per cell (default 4).
    pub samples: u32,
    /// Pixels per side of each of the six ID renders (default 128).
    pub face_size: u32,
    /// Cells added to each side of the path horizontally (default 1).
    pub margin: u32,
    /// Samples spread over the cell enlarged by this fraction of its size per side (default 0).
    pub enlarge: f32,
}

impl Default for PvsSettings {
    fn default() -> Self {
        PvsSettings {
            cell_size: 6.0,
            samples: 4,
            face_size: 128,
            margin: 1,
            enlarge: 0.0,
        }
    }
}

/// What preprocessing produced.
pub struct PvsBuild {
    /// The sets.
    pub pvs: Arc<Pvs>,
    /// The cache file.
    pub file: PathBuf,
    /// Its size in bytes.
    pub file_bytes: u64,
    /// Seconds spent building (0 when loaded).
    pub seconds: f64,
    /// Whether it was loaded from the cache.
    pub from_cache: bool,
}

/// The cache key: scene, scale, path, settings and object count.
pub fn key(
    scene_id: &str,
    scale: f32,
    scene: &Scene,
    path: &CameraPath,
    s: &PvsSettings,
) -> String {
    let keys: Vec<String> = path
        .keys
        .iter()
        .map(|k| format!("{:?}{:?}", k.eye.to_array(), k.target.to_array()))
        .collect();
    format!(
        "scene={scene_id};scale={scale};objects={};triangles={};path={}#{:016x};cell={};samples={};face={};margin={};enlarge={}",
        scene.objects.len(),
        scene.triangle_count(),
        path.name,
        fnv1a(keys.join(";").as_bytes()),
        s.cell_size,
        s.samples,
        s.face_size,
        s.margin,
        s.enlarge
    )
}

/// The view cells of `path` on a grid at `origin` (sorted, no repeats).
pub fn view_cells(path: &CameraPath, origin: Vec3, s: &PvsSettings) -> Vec<[i32; 3]> {
    let frames = path.natural_frames().max(1);
    let steps = frames * 4;
    let m = s.margin as i32;
    let mut cells = Vec::new();
    for i in 0..=steps {
        let eye = path.pose_at(i as f32 * frames as f32 / steps as f32).eye;
        if !eye.is_finite() {
            continue;
        }
        let c = Pvs::coord_of(origin, s.cell_size, eye);
        for dx in -m..=m {
            for dz in -m..=m {
                cells.push([c[0] + dx, c[1], c[2] + dz]);
            }
        }
    }
    cells.sort_unstable();
    cells.dedup();
    cells
}

/// Loads the PVS from `dir` when a file for this key exists and can be trusted; otherwise
/// builds it (printing why an existing file was not used) and stores it there.
#[allow(clippy::too_many_arguments)]
pub fn load_or_build(
    ctx: &Arc<GpuContext>,
    dir: &Path,
    scene_id: &str,
    scale: f32,
    scene: &Scene,
    bvh: &ObjectBvh,
    path: &CameraPath,
    s: &PvsSettings,
    progress: impl FnMut(u64, u64),
) -> Result<PvsBuild> {
    let key = key(scene_id, scale, scene, path, s);
    let file = dir.join(format!("pvs-{:016x}.bin", fnv1a(key.as_bytes())));
    match Pvs::load(&file, &key) {
        Ok(Some(pvs)) => {
            let file_bytes = std::fs::metadata(&file).map(|m| m.len()).unwrap_or(0);
            return Ok(PvsBuild {
                pvs: Arc::new(pvs),
                file,
                file_bytes,
                seconds: 0.0,
                from_cache: true,
            });
        }
        Ok(None) => {}
        Err(e) => eprintln!("pvs: {e}: rebuilding it"),
    }
    let start = Instant::now();
    let pvs = build(ctx, &key, scene, bvh, path, s, progress)?;
    let seconds = start.elapsed().as_secs_f64();
    pvs.save(&file)?;
    let file_bytes = std::fs::metadata(&file).map(|m| m.len()).unwrap_or(0);
    Ok(PvsBuild {
        pvs: Arc::new(pvs),
        file,
        file_bytes,
        seconds,
        from_cache: false,
    })
}

/// Builds the sets: for every view cell, `samples` points, six ID renders each.
pub fn build(
    ctx: &Arc<GpuContext>,
    key: &str,
    scene: &Scene,
    bvh: &ObjectBvh,
    path: &CameraPath,
    s: &PvsSettings,
    mut progress: impl FnMut(u64, u64),
) -> Result<Pvs> {
    let origin = bvh.nodes[0].bounds.min;
    let coords = view_cells(path, origin, s);
    let face = s.face_size.max(8);
    let mut renderer = Renderer::new(ctx, scene, face, face)?;
    let far = (bvh.nodes[0].bounds.extent().length() * 2.0).max(10.0);
    let mut pixels = Vec::new();
    let mut seen = vec![false; scene.objects.len()];
    let mut cells = Vec::with_capacity(coords.len());
    let total = coords.len() as u64 * u64::from(s.samples.max(1));
    let heights = eye_heights(path);
    for (ci, &coord) in coords.iter().enumerate() {
        seen.fill(false);
        let cell = sampled_region(Pvs::cell_bounds(origin, s.cell_size, coord), heights);
        for k in 0..s.samples.max(1) {
            let p = sample_point(&cell, k, s.enlarge);
            for dir in DIRECTIONS {
                let camera = Camera {
                    eye: p,
                    target: p + dir,
                    fov_y: std::f32::consts::FRAC_PI_2,
                    aspect: 1.0,
                    near: 0.05,
                    far,
                };
                renderer.object_pixels(bvh, &camera, &mut pixels)?;
                for (o, &n) in pixels.iter().enumerate() {
                    seen[o] |= n > 0;
                }
            }
            progress(
                ci as u64 * u64::from(s.samples.max(1)) + u64::from(k) + 1,
                total,
            );
        }
        let objects = (0..seen.len() as u32)
            .filter(|&o| seen[o as usize])
            .collect();
        cells.push(ViewCell { coord, objects });
    }
    Ok(Pvs::new(
        key.to_owned(),
        scene.objects.len() as u32,
        origin,
        s.cell_size,
        cells,
    ))
}

/// The lowest and highest eye of the path (the camera's heights).
fn eye_heights(path: &CameraPath) -> (f32, f32) {
    let frames = path.natural_frames().max(1);
    (0..=frames * 4)
        .map(|i| path.pose_at(i as f32 / 4.0).eye.y)
        .filter(|y| y.is_finite())
        .fold((f32::MAX, f32::MIN), |(lo, hi), y| (lo.min(y), hi.max(y)))
}

/// The part of a cell the camera can be in: its heights limited to the path's eye heights
/// (half a unit of slack), unless the two do not overlap.
fn sampled_region(cell: crate::scene::Aabb, (lo, hi): (f32, f32)) -> crate::scene::Aabb {
    let (y0, y1) = (cell.min.y.max(lo - 0.5), cell.max.y.min(hi + 0.5));
    if y0 > y1 {
        return cell;
    }
    let mut c = cell;
    c.min.y = y0;
    c.max.y = y1;
    c
}

/// The six axis directions of a cube map.
const DIRECTIONS: [Vec3; 6] = [
    Vec3::X,
    Vec3::NEG_X,
    Vec3::Y,
    Vec3::NEG_Y,
    Vec3::Z,
    Vec3::NEG_Z,
];

/// Sample `k` of a cell: a Halton point (bases 2, 3, 5) in the cell enlarged by `enlarge`.
fn sample_point(cell: &crate::scene::Aabb, k: u32, enlarge: f32) -> Vec3 {
    let grow = cell.extent() * enlarge.max(0.0);
    let (min, size) = (cell.min - grow, cell.extent() + 2.0 * grow);
    let u = Vec3::new(halton(k + 1, 2), halton(k + 1, 3), halton(k + 1, 5));
    min + u * size
}

fn halton(mut i: u32, base: u32) -> f32 {
    let (mut f, mut r) = (1.0f32, 0.0f32);
    while i > 0 {
        f /= base as f32;
        r += f * (i % base) as f32;
        i /= base;
    }
    r
}
