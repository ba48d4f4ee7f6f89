//! PVS preprocessing: view cells over the region the camera can occupy and, per cell, the union
//! of the objects that own a pixel in ID buffers taken from sample points inside the cell in six
//! directions (a cube map of 90° views). By default the ID buffers are ray cast on the CPU, one
//! ray through each pixel centre against a triangle BVH of the scene (obvhs, as the GI's ray
//! caster): the same pixels a rasterized ID pass owns, and on lavapipe, where rasterizing a 3M
//! triangle city six times per sample costs about a second, several times faster. `raster`
//! uses the renderer's exact ID pass (the oracle's) instead.
//!
//! A view of 128 pixels over 90° is about eight times coarser than a 1280x720 camera's, so
//! objects far down a street, a few screen pixels wide, fall between its rays: on the city's
//! street they were most of what the PVS missed (80 objects in the median frame). Where a ray-cast
//! view has a far edge (a pixel whose neighbours hit another object, or nothing, and reach beyond
//! [`FAR_EDGE_CELLS`] cells) it casts `refine` x `refine` more rays over that pixel. Nearer than
//! that, an object thinner than the views' ray spacing (a lamp pole between a tree and a wall)
//! can still fall between the rays: each object within that distance of the cell that no view
//! found is aimed at from every sample point, along the longest axis of its box.
//!
//! The region: a grid of cubic cells of `cell_size` around the walked camera path — every cell
//! the path passes through plus `margin` cells to each side horizontally (the streets along a
//! `city` path, the rooms and corridors a `powerplant` path goes through, the path's
//! surroundings in a glTF scene). Sample points are stratified (Halton) over the cell enlarged
//! by `enlarge` of its size on each side: a conservative setting samples more points over a
//! larger box, at a cost proportional to `samples` × (1 + 2·enlarge)² in coverage. With
//! `border` (the default) eight points on the cell's border are sampled too, its four corners
//! and the midpoints of its four sides, at the middle of its sampled heights; the cells that
//! meet at such a point share its views, so on a path they cost about four samples a cell. A
//! camera at the side of a cell, next to a doorway, sees through it what the Halton points
//! deeper in the cell do not.
//! A sample point inside a solid (a building, a boiler) sees only that object's inside: the
//! next Halton points are tried instead (a border point moves towards the cell's centre). A
//! cell that a wall crosses still sees only what its samples on either side see (a
//! cell-and-portal subdivision would split such cells at the wall).

use std::collections::hash_map::{Entry, HashMap};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use glam::Vec3;

use crate::bvh::ObjectBvh;
use crate::culling::pvs::{fnv1a, Pvs, ViewCell};
use crate::error::{Error, Result};
use crate::gpu::GpuContext;
use crate::render::Renderer;
use crate::scene::camera::Camera;
use crate::scene::{CameraPath, Scene};

/// How the PVS is built.
#[derive(Clone, Debug, PartialEq)]
pub struct PvsSettings {
    /// Edge length of a view cell in scene units (default 6).
    pub cell_size: f32,
    /// Sample points per cell (default 8).
    pub samples: u32,
    /// Pixels per side of each of the six ID renders (default 128).
    pub face_size: u32,
    /// Ray-cast ID views: rays per pixel side in the pixels of far edges (default 4; 1 casts
    /// one ray per pixel everywhere). A far edge is a pixel whose neighbourhood holds more
    /// than one object and reaches beyond [`FAR_EDGE_CELLS`] cells (or into nothing): there
    /// objects far down a street are thinner than a pixel of the view.
    pub refine: u32,
    /// Cells added to each side of the path horizontally (default 0: the cells the path
    /// passes through).
    pub margin: u32,
    /// Samples spread over the cell enlarged by this fraction of its size per side (default 0).
    pub enlarge: f32,
    /// Rasterize the ID buffers with the renderer's ID pass instead of ray casting them.
    pub raster: bool,
    /// Also sample eight points on each cell's border, its corners and the midpoints of its
    /// sides (at the middle of its sampled heights), shared with the cells that meet there
    /// (default on). A camera near a cell's side sees through a doorway there what no point
    /// inside the cell sees.
    pub border: bool,
}

impl Default for PvsSettings {
    fn default() -> Self {
        PvsSettings {
            cell_size: 6.0,
            samples: 8,
            face_size: 128,
            refine: 4,
            margin: 0,
            enlarge: 0.0,
            raster: false,
            border: true,
        }
    }
}

impl PvsSettings {
    /// Rays per pixel side that the far edges of the ID views get: [`PvsSettings::refine`]
    /// (at least 1) for ray-cast views, 1 for rasterized ones (which cast no rays).
    pub fn far_edge_rays(&self) -> u32 {
        if self.raster {
            1
        } else {
            self.refine.max(1)
        }
    }
}

/// How far, in view cells, an edge of a ray-cast ID view must reach to be refined
/// ([`PvsSettings::refine`]). On the city's street (cells of 6, 4 rays per pixel side, 60
/// frames) 4 cells took the build from 20 s to 48 s, 10 cells to 38 s and 20 cells to 31 s;
/// the objects missed in the median frame were 17.5, 17.5 and 20.
pub const FAR_EDGE_CELLS: f32 = 10.0;

/// Edge length of the view cells of the command line's PVS when `--cell-size` is not given:
/// [`PvsSettings::default`]'s 6 scene units, or a quarter of the diagonal of the scene's objects'
/// boxes when that is less. Around a small model (a 12 cm can) cells of 6 units put the samples
/// metres away from a camera that stands centimetres off it, where the parts it sees up close
/// are a pixel or none.
pub fn default_cell_size(scene: &Scene) -> f32 {
    let quarter = 0.25 * scene.bounds().extent().length();
    if quarter.is_finite() && quarter > 0.0 {
        quarter.min(PvsSettings::default().cell_size)
    } else {
        PvsSettings::default().cell_size
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
    /// The settings it was built with (part of the cache key).
    pub settings: PvsSettings,
}

/// The cache key: scene, scale, path, settings and object count. Its version changes with
/// what a build finds for the same settings (v6: the view rays traced in bundles from the
/// sample point itself, starting 5 cm out along the ray; v7: near objects that no view found
/// aimed at).
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
        "v7;scene={scene_id};scale={scale};objects={};triangles={};path={}#{:016x};cell={};samples={};border={};face={};refine={};margin={};enlarge={};raster={}",
        scene.objects.len(),
        scene.triangle_count(),
        path.name,
        fnv1a(keys.join(";").as_bytes()),
        s.cell_size,
        s.samples,
        s.border,
        s.face_size,
        s.refine,
        s.margin,
        s.enlarge,
        s.raster
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
    match Pvs::load_for_scene(&file, &key, scene.objects.len()) {
        Ok(Some(pvs)) => {
            let file_bytes = std::fs::metadata(&file).map(|m| m.len()).unwrap_or(0);
            return Ok(PvsBuild {
                pvs: Arc::new(pvs),
                file,
                file_bytes,
                seconds: 0.0,
                from_cache: true,
                settings: s.clone(),
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
        settings: s.clone(),
    })
}

/// Builds the sets: for every view cell, `samples` points, six ID buffers each.
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
    let far = (bvh.nodes[0].bounds.extent().length() * 2.0).max(10.0);
    let mut ids = if s.raster {
        IdBuffers::Raster(Box::new(Renderer::new(ctx, scene, face, face)?), Vec::new())
    } else {
        IdBuffers::Rays(ObjectRays::new(scene))
    };
    let mut seen = vec![false; scene.objects.len()];
    let mut cells = Vec::with_capacity(coords.len());
    let samples = s.samples.max(1);
    let refine = FarEdges {
        rays: s.far_edge_rays(),
        beyond: FAR_EDGE_CELLS * s.cell_size,
    };
    let per_cell = samples + if s.border { BORDER_POINTS } else { 0 };
    let total = coords.len() as u64 * u64::from(per_cell);
    let heights = eye_heights(path);
    // What each shared border point sees (the objects), by its lattice point.
    let mut shared_sets: HashMap<[i32; 3], Vec<u32>> = HashMap::new();
    let mut shared_seen = vec![false; scene.objects.len()];
    for (ci, &coord) in coords.iter().enumerate() {
        seen.fill(false);
        let cell = sampled_region(Pvs::cell_bounds(origin, s.cell_size, coord), heights);
        let points = match &ids {
            IdBuffers::Rays(rays) => {
                let solid = |p: Vec3| rays.rays.inside_solid(p, far);
                cell_sample_points(scene, bvh, &cell, coord, s, Some(&solid))
            }
            IdBuffers::Raster(..) => cell_sample_points(scene, bvh, &cell, coord, s, None),
        };
        for (k, sample) in points.iter().enumerate() {
            match sample.shared {
                None => ids.mark_visible(bvh, sample.point, face, far, refine, &mut seen)?,
                Some(lattice) => {
                    let set = match shared_sets.entry(lattice) {
                        Entry::Occupied(e) => e.into_mut(),
                        Entry::Vacant(e) => {
                            shared_seen.fill(false);
                            ids.mark_visible(
                                bvh,
                                sample.point,
                                face,
                                far,
                                refine,
                                &mut shared_seen,
                            )?;
                            e.insert(
                                (0..shared_seen.len() as u32)
                                    .filter(|&o| shared_seen[o as usize])
                                    .collect(),
                            )
                        }
                    };
                    for &o in set.iter() {
                        seen[o as usize] = true;
                    }
                }
            }
            progress(ci as u64 * u64::from(per_cell) + k as u64 + 1, total);
        }
        if let IdBuffers::Rays(rays) = &ids {
            // Objects near the cell that no view found, aimed at from every point.
            let reach = cell.enlarged(refine.beyond);
            let unseen: Vec<u32> = (0..scene.objects.len() as u32)
                .filter(|&o| !seen[o as usize] && scene.objects[o as usize].bounds.overlaps(&reach))
                .collect();
            let from: Vec<Vec3> = points.iter().map(|p| p.point).collect();
            for o in rays.aimed(scene, &from, &unseen, far) {
                seen[o as usize] = true;
            }
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

/// How ID buffers are made: rasterized by the renderer, or ray cast.
enum IdBuffers {
    Raster(Box<Renderer>, Vec<u32>),
    Rays(ObjectRays),
}

impl IdBuffers {
    /// Marks in `seen` every object that owns a pixel of one of the six `face`-sized views
    /// from `p` (ray cast: or that a ray of `refine` hits).
    fn mark_visible(
        &mut self,
        bvh: &ObjectBvh,
        p: Vec3,
        face: u32,
        far: f32,
        refine: FarEdges,
        seen: &mut [bool],
    ) -> Result<()> {
        match self {
            IdBuffers::Raster(renderer, pixels) => {
                for dir in DIRECTIONS {
                    let camera = Camera {
                        eye: p,
                        target: p + dir,
                        fov_y: std::f32::consts::FRAC_PI_2,
                        aspect: 1.0,
                        near: 0.05,
                        far,
                    };
                    renderer.object_pixels(bvh, &camera, pixels)?;
                    for (o, &n) in pixels.iter().enumerate() {
                        seen[o] |= n > 0;
                    }
                }
            }
            IdBuffers::Rays(rays) => rays.mark_visible(p, face, far, refine, seen),
        }
        Ok(())
    }
}

/// The scene's triangles in a ray-casting BVH, with the object of each triangle.
struct ObjectRays {
    rays: crate::scene::raycast::RayScene,
    /// First triangle of each object (object `o` owns `first[o]..first[o + 1]`).
    first: Vec<u32>,
}

impl ObjectRays {
    fn new(scene: &Scene) -> ObjectRays {
        let mut triangles = Vec::with_capacity(scene.triangle_count() as usize);
        let mut first = Vec::with_capacity(scene.objects.len() + 1);
        for o in &scene.objects {
            first.push(triangles.len() as u32);
            let range = o.first_index as usize..(o.first_index + o.index_count) as usize;
            for tri in scene.indices[range].chunks_exact(3) {
                let corner = |k: usize| {
                    let v = &scene.vertices[(o.vertex_offset + tri[k]) as usize];
                    o.transform.transform_point3(Vec3::from(v.position))
                };
                triangles.push([corner(0), corner(1), corner(2)]);
            }
        }
        first.push(triangles.len() as u32);
        ObjectRays {
            rays: crate::scene::raycast::RayScene::for_many_rays(triangles, Vec::new()),
            first,
        }
    }

    /// The object of triangle `t`.
    fn object_of(&self, t: u32) -> usize {
        self.first.partition_point(|&f| f <= t) - 1
    }

    /// One ray per pixel centre of six 90° views, split over the machine's cores, and
    /// `refine` x `refine` more in the pixels of a far edge (see [`ObjectRays::cast_face`]).
    fn mark_visible(&self, p: Vec3, face: u32, far: f32, refine: FarEdges, seen: &mut [bool]) {
        let found = crate::parallel::map(DIRECTIONS.len(), |d| {
            let mut hits = Vec::new();
            self.cast_face(p, DIRECTIONS[d], face, far, refine, &mut hits);
            hits
        });
        for o in found.into_iter().flatten() {
            seen[o as usize] = true;
        }
    }

    /// Those of `objects` that a ray from one of `points` aimed at them hits first: each
    /// object is aimed at in [`AIMS`] points along the longest axis of its box. A view's rays
    /// are about 0.7° apart (128 pixels over 90°), so an object thinner than that seen from
    /// nearby (a pole between a tree and a wall) can fall between them; a ray aimed at it
    /// finds it wherever its axis shows.
    fn aimed(&self, scene: &Scene, points: &[Vec3], objects: &[u32], far: f32) -> Vec<u32> {
        let found = crate::parallel::map(objects.len(), |k| {
            let o = objects[k];
            let b = scene.objects[o as usize].bounds;
            let e = b.extent();
            let axis = if e.x >= e.y && e.x >= e.z {
                Vec3::X * e.x
            } else if e.y >= e.z {
                Vec3::Y * e.y
            } else {
                Vec3::Z * e.z
            };
            let sees = |p: Vec3, at: Vec3| {
                let d = (at - p).normalize_or_zero();
                d != Vec3::ZERO
                    && self
                        .rays
                        .intersect(p + d * RAY_START, d, far)
                        .is_some_and(|h| self.object_of(h.triangle) == o as usize)
            };
            let aims = AIMS.map(|f| b.center() + axis * f);
            let seen = aims.iter().any(|&at| points.iter().any(|&p| sees(p, at)));
            seen.then_some(o)
        });
        found.into_iter().flatten().collect()
    }

    /// The objects hit through the pixel centres of a `face` x `face` 90° view along `dir`,
    /// and through `refine.rays` x `refine.rays` points spread over each pixel whose 3x3
    /// neighbourhood holds more than one object (or an object and nothing) and reaches
    /// farther than `refine.beyond` (or hits nothing): where an object too thin for one ray
    /// per pixel can show between others, far away.
    fn cast_face(
        &self,
        p: Vec3,
        dir: Vec3,
        face: u32,
        far: f32,
        refine: FarEdges,
        hits: &mut Vec<u32>,
    ) {
        let up = if dir.cross(Vec3::Y).length_squared() < 1e-6 {
            Vec3::Z
        } else {
            Vec3::Y
        };
        let right = dir.cross(up).normalize();
        let up = right.cross(dir);
        let n = face as f32;
        // The direction through the point (u, v) of the face, in pixels from its top left
        // corner.
        let through = |u: f32, v: f32| {
            (dir + (2.0 * u / n - 1.0) * right + (1.0 - 2.0 * v / n) * up).normalize()
        };
        // The objects and distances (from 5 cm out, as far as `far`) along `dirs`, traced
        // together: rays through one tile of the face share most of the hierarchy.
        let mut found = Vec::with_capacity(BUNDLE_SIDE * BUNDLE_SIDE);
        let mut cast = |dirs: &[Vec3], into: &mut Vec<(u32, f32)>| {
            self.rays
                .closest_from(p, dirs, RAY_START, far + RAY_START, &mut found);
            into.extend(found.iter().map(|h| match h {
                Some((triangle, t)) => (self.object_of(*triangle) as u32, t - RAY_START),
                None => (NOTHING, f32::INFINITY),
            }));
        };
        let f = face as usize;
        let mut centres = vec![(NOTHING, f32::INFINITY); f * f];
        let mut dirs = Vec::with_capacity(BUNDLE_SIDE * BUNDLE_SIDE);
        let mut tile = Vec::with_capacity(BUNDLE_SIDE * BUNDLE_SIDE);
        let mut pixel = Vec::with_capacity(BUNDLE_SIDE * BUNDLE_SIDE);
        for j0 in (0..f).step_by(BUNDLE_SIDE) {
            for i0 in (0..f).step_by(BUNDLE_SIDE) {
                dirs.clear();
                pixel.clear();
                for j in j0..(j0 + BUNDLE_SIDE).min(f) {
                    for i in i0..(i0 + BUNDLE_SIDE).min(f) {
                        dirs.push(through(i as f32 + 0.5, j as f32 + 0.5));
                        pixel.push(j * f + i);
                    }
                }
                tile.clear();
                cast(&dirs, &mut tile);
                for (&k, &c) in pixel.iter().zip(&tile) {
                    centres[k] = c;
                }
            }
        }
        hits.extend(centres.iter().map(|c| c.0).filter(|&o| o != NOTHING));
        if refine.rays > 1 {
            // Every far edge's rays, cast together: four pixels' rays make a bundle.
            let r = refine.rays;
            dirs.clear();
            for j in 0..f {
                for i in 0..f {
                    let around = || {
                        (j.saturating_sub(1)..(j + 2).min(f)).flat_map(move |jj| {
                            (i.saturating_sub(1)..(i + 2).min(f)).map(move |ii| jj * f + ii)
                        })
                    };
                    let own = centres[j * f + i].0;
                    let edge = around().any(|k| centres[k].0 != own);
                    if !edge || around().all(|k| centres[k].1 <= refine.beyond) {
                        continue;
                    }
                    for b in 0..r {
                        for a in 0..r {
                            let u = i as f32 + (a as f32 + 0.5) / r as f32;
                            let v = j as f32 + (b as f32 + 0.5) / r as f32;
                            dirs.push(through(u, v));
                        }
                    }
                }
            }
            let mut spread = Vec::with_capacity(dirs.len());
            cast(&dirs, &mut spread);
            hits.extend(spread.iter().map(|c| c.0).filter(|&o| o != NOTHING));
        }
        hits.sort_unstable();
        hits.dedup();
    }
}

/// No object hit by a ray.
const NOTHING: u32 = u32::MAX;

/// Where [`ObjectRays::aimed`] aims along an object box's longest axis, as fractions of its
/// length from the centre.
const AIMS: [f32; 5] = [0.0, -0.4, 0.4, -0.2, 0.2];

/// Pixels on a side of the tiles of a ray-cast view whose rays are traced together (64 rays,
/// [`crate::scene::raycast::BUNDLE`]).
const BUNDLE_SIDE: usize = 8;

/// How far from the sample point the rays of a ray-cast view start (5 cm), so that a point
/// on a surface does not see only that surface.
const RAY_START: f32 = 0.05;

/// Where the ray-cast ID views cast more rays than one per pixel (see
/// [`ObjectRays::cast_face`]).
#[derive(Clone, Copy, Debug)]
struct FarEdges {
    /// Rays per pixel side there (1: none more).
    rays: u32,
    /// Distance beyond which an edge counts as far.
    beyond: f32,
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

/// Points on a view cell's border that [`PvsSettings::border`] samples: 4 corners and 4 side
/// midpoints.
pub const BORDER_POINTS: u32 = 8;

/// A sample point of a view cell.
#[derive(Clone, Copy, Debug, PartialEq)]
struct CellSample {
    point: Vec3,
    /// A border point that stands where the lattice puts it (in half cells), so that the
    /// cells meeting there share its views.
    shared: Option<[i32; 3]>,
}

/// The sample points of the view cell at `coord`, whose sampled region is `cell`: `samples`
/// Halton points and, with [`PvsSettings::border`], the cell's four corners and the midpoints
/// of its four sides, at the middle of its heights. A border point inside a solid moves
/// towards the cell's centre until it is out (and is then the cell's own). On the
/// powerplant's `difficult` path, the camera passes a doorway at the side of a cell whose
/// Halton points stand 1.5 units or more from that side and see through the doorway only in
/// a narrow wedge: with four Halton points a frame there missed 69,939 pixels, with the
/// border points added none (the walk's worst frame: 3,797).
fn cell_sample_points(
    scene: &Scene,
    bvh: &ObjectBvh,
    cell: &crate::scene::Aabb,
    coord: [i32; 3],
    s: &PvsSettings,
    solid: Option<&dyn Fn(Vec3) -> bool>,
) -> Vec<CellSample> {
    let samples = s.samples.max(1);
    let mut points: Vec<CellSample> = (0..samples)
        .map(|k| CellSample {
            point: free_sample_point(scene, bvh, cell, k, samples, s.enlarge, solid),
            shared: None,
        })
        .collect();
    if !s.border {
        return points;
    }
    let centre = cell.center();
    // In half cells: the corners, then the midpoints of the sides.
    let halves = [
        (0, 0),
        (2, 0),
        (0, 2),
        (2, 2),
        (1, 0),
        (1, 2),
        (0, 1),
        (2, 1),
    ];
    for (hx, hz) in halves {
        let on_border = Vec3::new(
            cell.min.x + (cell.max.x - cell.min.x) * 0.5 * hx as f32,
            centre.y,
            cell.min.z + (cell.max.z - cell.min.z) * 0.5 * hz as f32,
        );
        let lattice = [2 * coord[0] + hx, coord[1], 2 * coord[2] + hz];
        let mut sample = CellSample {
            point: on_border,
            shared: Some(lattice),
        };
        // Towards the centre in tenths of the way, the last at nine tenths.
        for t in 1..10 {
            if !in_solid(scene, bvh, solid, sample.point) {
                break;
            }
            sample = CellSample {
                point: on_border.lerp(centre, 0.1 * t as f32),
                shared: None,
            };
        }
        points.push(sample);
    }
    points
}

/// Sample `k` of `samples` in a cell, outside solid objects where possible: a point inside a
/// solid (a building, a boiler, a pillar) sees only that object's inside, so the next Halton
/// points (`k + samples`, `k + 2 samples`, ...) are tried, up to 16 in all. With `solid` (the
/// ray-cast views) a point is inside a solid when `solid` says so; without it, when it lies
/// in some object's box. The box rule fails in a level split into chunks, whose boxes span
/// its rooms: there the only points outside every box lie outside the building, and on the
/// Sibenik cathedral two view cells saw its outer walls only.
fn free_sample_point(
    scene: &Scene,
    bvh: &ObjectBvh,
    cell: &crate::scene::Aabb,
    k: u32,
    samples: u32,
    enlarge: f32,
    solid: Option<&dyn Fn(Vec3) -> bool>,
) -> Vec3 {
    let mut p = sample_point(cell, k, enlarge);
    for t in 1..16 {
        if !in_solid(scene, bvh, solid, p) {
            break;
        }
        p = sample_point(cell, k + t * samples, enlarge);
    }
    p
}

/// Whether a sample point at `p` stands in a solid: as `solid` says (the ray-cast views),
/// else when it lies in some object's box.
fn in_solid(scene: &Scene, bvh: &ObjectBvh, solid: Option<&dyn Fn(Vec3) -> bool>, p: Vec3) -> bool {
    match solid {
        Some(solid) => solid(p),
        None => inside_object(scene, bvh, p),
    }
}

/// Whether `p` lies inside the box of some object.
fn inside_object(scene: &Scene, bvh: &ObjectBvh, p: Vec3) -> bool {
    let mut stack = vec![0u32];
    while let Some(id) = stack.pop() {
        let node = &bvh.nodes[id as usize];
        if !node.bounds.contains(p) {
            continue;
        }
        if node.is_leaf() {
            let objects = bvh.objects(id);
            if objects.iter().any(|&o| {
                scene
                    .objects
                    .get(o as usize)
                    .is_some_and(|x| x.bounds.contains(p))
            }) {
                return true;
            }
        } else {
            stack.extend_from_slice(&node.children);
        }
    }
    false
}

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

/// The PVS cache file: [`Pvs`] is data in `coherent-cull` (bytes in, bytes out); reading and
/// writing its file is the application's.
pub trait PvsFile: Sized {
    /// Writes the cache file (through a temporary file, so a crash leaves no half file).
    fn save(&self, path: &Path) -> Result<()>;
    /// Reads a cache file made for `key`: `Ok(None)` if there is none, `Err` with the reason
    /// when it exists but cannot be trusted.
    fn load(path: &Path, key: &str) -> Result<Option<Self>>;
    /// [`PvsFile::load`] for a scene of `objects` objects: a file whose object count differs
    /// is refused too.
    fn load_for_scene(path: &Path, key: &str, objects: usize) -> Result<Option<Self>>;
}

impl PvsFile for Pvs {
    /// Writes the cache file.
    fn save(&self, path: &Path) -> Result<()> {
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir)?;
        }
        let tmp = path.with_extension("tmp");
        std::fs::write(&tmp, self.to_bytes())?;
        std::fs::rename(&tmp, path)?;
        Ok(())
    }

    /// Reads a cache file made for `key`: `Ok(None)` if there is none, `Err` with the reason
    /// when it exists but cannot be trusted.
    fn load(path: &Path, key: &str) -> Result<Option<Pvs>> {
        let bytes = match std::fs::read(path) {
            Ok(b) => b,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(e.into()),
        };
        Pvs::from_bytes(&bytes, key)
            .map(Some)
            .map_err(|why| Error::Input(format!("{}: {why}", path.display())))
    }

    /// [`Pvs::load`] for a scene of `objects` objects: a file whose object count differs is
    /// refused too (its ids are only checked against its own count, and the culler sizes
    /// its per-object state by it: a damaged file claiming 4 billion objects would cost
    /// gigabytes).
    fn load_for_scene(path: &Path, key: &str, objects: usize) -> Result<Option<Pvs>> {
        match <Pvs as PvsFile>::load(path, key)? {
            Some(p) if p.objects as usize != objects => Err(Error::Input(format!(
                "{}: made for {} objects, the scene has {objects}",
                path.display(),
                p.objects
            ))),
            other => Ok(other),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_cell_is_a_quarter_of_a_small_scene_and_six_units_at_most() {
        let city = crate::scene::procedural::city(1.0);
        assert_eq!(default_cell_size(&city), 6.0);
        // The Cornell box is about 5.5 units across: its cells are a quarter of its diagonal.
        let mut cornell = crate::scene::procedural::cornell();
        let small = default_cell_size(&cornell);
        assert!(small > 1.0 && small < 6.0, "{small}");
        // A tenth of the size, a tenth of the cell.
        cornell.magnify(0.1);
        let tenth = default_cell_size(&cornell);
        assert!(
            (tenth - 0.1 * small).abs() < 1e-3 * small,
            "{tenth} against {small}"
        );
        cornell.objects.clear();
        assert_eq!(default_cell_size(&cornell), 6.0, "no objects: the default");
    }

    /// A view of 16 pixels from the origin along -Z: a wall over the left half 100 units away,
    /// a pole half a unit wide just right of the wall's edge, between two pixel centres (6.25
    /// units apart there), and a backdrop 150 units away behind both (objects 0, 1 and 2).
    fn wall_and_pole() -> (ObjectRays, u32) {
        use crate::scene::mesh::{Mesh, SceneBuilder};
        let mut b = SceneBuilder::new("wall-and-pole");
        let grey = Vec3::splat(0.5);
        b.add(
            &Mesh::cuboid(
                Vec3::new(-60.0, -60.0, -101.0),
                Vec3::new(0.0, 60.0, -100.0),
            ),
            grey,
        );
        let pole = b.add(
            &Mesh::cuboid(Vec3::new(4.5, -60.0, -101.0), Vec3::new(5.0, 60.0, -100.0)),
            grey,
        );
        b.add(
            &Mesh::cuboid(
                Vec3::new(-200.0, -200.0, -151.0),
                Vec3::new(200.0, 200.0, -150.0),
            ),
            grey,
        );
        (ObjectRays::new(&b.finish()), pole)
    }

    #[test]
    fn far_edges_are_refined_and_find_what_falls_between_pixel_centres() {
        let (rays, pole) = wall_and_pole();
        let seen = |refine: FarEdges| {
            let mut hits = Vec::new();
            rays.cast_face(Vec3::ZERO, Vec3::NEG_Z, 16, 1000.0, refine, &mut hits);
            hits
        };
        let one = FarEdges {
            rays: 1,
            beyond: 50.0,
        };
        assert_eq!(seen(one), vec![0, 2], "one ray per pixel misses the pole");
        let four = FarEdges { rays: 4, ..one };
        assert_eq!(
            seen(four),
            vec![0, pole, 2],
            "the wall's far edge is refined"
        );
        // The same edge nearer than `beyond` is not.
        let near = FarEdges {
            beyond: 200.0,
            ..four
        };
        assert_eq!(seen(near), vec![0, 2]);
    }

    #[test]
    fn aimed_rays_find_a_thin_pole_that_falls_between_view_rays() {
        use crate::scene::mesh::{Mesh, SceneBuilder};
        let v = Vec3::new;
        let grey = Vec3::splat(0.5);
        let mut b = SceneBuilder::new("poles");
        // 0: a wall behind; 1: a pole 5 cm thick, 10 units away; 2: a crate; 3: a pole as
        // thin right behind the crate.
        b.add(
            &Mesh::cuboid(v(-50.0, -5.0, -21.0), v(50.0, 9.0, -20.0)),
            grey,
        );
        b.add(
            &Mesh::cuboid(v(0.3, 0.0, -10.05), v(0.35, 4.0, -10.0)),
            grey,
        );
        b.add(&Mesh::cuboid(v(2.0, 0.0, -7.0), v(4.0, 4.0, -6.0)), grey);
        b.add(
            &Mesh::cuboid(v(5.8, 0.0, -12.05), v(5.85, 4.0, -12.0)),
            grey,
        );
        let scene = b.finish();
        let rays = ObjectRays::new(&scene);
        let p = v(0.0, 2.0, 0.0);
        let mut seen = vec![false; 4];
        let one = FarEdges {
            rays: 1,
            beyond: f32::MAX,
        };
        rays.mark_visible(p, 16, 100.0, one, &mut seen);
        assert_eq!(
            seen,
            [true, false, true, false],
            "16-pixel views miss the poles"
        );
        assert_eq!(
            rays.aimed(&scene, &[p], &[1, 3], 100.0),
            vec![1],
            "aimed at, the pole in the open is found, the one behind the crate is not"
        );
    }

    /// A room of 13 x 4 x 13 units as one object (floor, ceiling and four walls 0.2 thick),
    /// like a level's chunk: its box holds the whole room.
    fn room() -> Scene {
        use crate::scene::mesh::{Mesh, SceneBuilder};
        let mut m = Mesh::default();
        let v = Vec3::new;
        for (min, max) in [
            (v(-5.2, -0.2, -5.2), v(8.2, 0.0, 8.2)),
            (v(-5.2, 4.0, -5.2), v(8.2, 4.2, 8.2)),
            (v(-5.2, 0.0, -5.2), v(-5.0, 4.0, 8.2)),
            (v(8.0, 0.0, -5.2), v(8.2, 4.0, 8.2)),
            (v(-5.0, 0.0, -5.2), v(8.0, 4.0, -5.0)),
            (v(-5.0, 0.0, 8.0), v(8.0, 4.0, 8.2)),
        ] {
            m.append(&Mesh::cuboid(min, max), glam::Mat4::IDENTITY);
        }
        let mut b = SceneBuilder::new("room");
        b.add(&m, Vec3::splat(0.5));
        b.finish()
    }

    /// A wall 0.2 thick at z = 6.2 with a doorway from x = 5 to 7, a crate behind it to the
    /// north-west (x 1.5..3, z 8..9) and a pillar around the origin (objects 0 and 1 the wall,
    /// 2 the crate, 3 the pillar).
    fn doorway() -> Scene {
        use crate::scene::mesh::{Mesh, SceneBuilder};
        let v = Vec3::new;
        let mut b = SceneBuilder::new("doorway");
        let grey = Vec3::splat(0.5);
        b.add(&Mesh::cuboid(v(-50.0, -5.0, 6.2), v(5.0, 5.0, 6.4)), grey);
        b.add(&Mesh::cuboid(v(7.0, -5.0, 6.2), v(50.0, 5.0, 6.4)), grey);
        b.add(&Mesh::cuboid(v(1.5, -5.0, 8.0), v(3.0, 5.0, 9.0)), grey);
        b.add(&Mesh::cuboid(v(-0.5, -5.0, -0.5), v(0.5, 5.0, 0.5)), grey);
        b.finish()
    }

    #[test]
    fn cell_borders_see_through_a_doorway_at_the_cells_side() {
        let scene = doorway();
        let bvh = scene.hierarchy(1);
        let rays = ObjectRays::new(&scene);
        let solid = |p: Vec3| rays.rays.inside_solid(p, 100.0);
        // The cell below the doorway: its corner (6, 6) stands under the doorway's west half.
        let cell = crate::scene::Aabb::new(Vec3::new(0.0, 1.0, 0.0), Vec3::new(6.0, 2.0, 6.0));
        let seen_from = |points: &[CellSample]| {
            let mut seen = vec![false; scene.objects.len()];
            let one = FarEdges {
                rays: 1,
                beyond: f32::MAX,
            };
            for s in points {
                rays.mark_visible(s.point, 64, 100.0, one, &mut seen);
            }
            seen
        };
        // Four Halton points, as the default was when the border points came in.
        let four = PvsSettings {
            samples: 4,
            ..PvsSettings::default()
        };
        let halton = PvsSettings {
            border: false,
            ..four.clone()
        };
        let points = cell_sample_points(&scene, &bvh, &cell, [0, 0, 0], &halton, Some(&solid));
        assert_eq!(points.len(), 4);
        let seen = seen_from(&points);
        assert!(seen[0] && seen[1], "the wall: {seen:?}");
        assert!(
            !seen[2],
            "no Halton point sees the crate through the doorway"
        );
        let points = cell_sample_points(&scene, &bvh, &cell, [0, 0, 0], &four, Some(&solid));
        assert_eq!(points.len(), 4 + BORDER_POINTS as usize);
        assert!(
            seen_from(&points)[2],
            "the corner under the doorway sees the crate"
        );
        let others: Vec<CellSample> = (0..points.len())
            .filter(|&i| i != 7)
            .map(|i| points[i])
            .collect();
        assert!(!seen_from(&others)[2], "only that corner sees it");
        assert_eq!(
            points[7],
            CellSample {
                point: Vec3::new(6.0, 1.5, 6.0),
                shared: Some([2, 0, 2]),
            },
            "a free corner is shared by its lattice point (in half cells)"
        );
        assert_eq!(
            points[8],
            CellSample {
                point: Vec3::new(3.0, 1.5, 0.0),
                shared: Some([1, 0, 0]),
            },
            "so is the midpoint of a side"
        );
        // The corner in the pillar moves two tenths of the way to the centre, and is the
        // cell's own.
        assert_eq!(points[4].shared, None);
        assert!((points[4].point - Vec3::new(0.6, 1.5, 0.6)).length() < 1e-5);
    }

    #[test]
    fn samples_stand_in_the_room_not_in_its_walls_nor_outside_its_box() {
        let scene = room();
        let bvh = scene.hierarchy(1);
        let rays = ObjectRays::new(&scene);
        assert!(
            rays.rays.inside_solid(Vec3::new(8.1, 2.0, 0.0), 100.0),
            "in a wall"
        );
        assert!(
            !rays.rays.inside_solid(Vec3::new(1.5, 2.0, 1.5), 100.0),
            "in the room"
        );
        assert!(
            !rays.rays.inside_solid(Vec3::new(20.0, 2.0, 20.0), 100.0),
            "outside"
        );
        // A cell across the wall at z = 8: its first Halton point (5, 1.5, 2) is in the room,
        // its third (z = 8.4) outside.
        let cell = crate::scene::Aabb::new(Vec3::new(0.0, 0.5, 0.0), Vec3::new(10.0, 3.5, 10.0));
        let solid = |p: Vec3| rays.rays.inside_solid(p, 100.0);
        let p = free_sample_point(&scene, &bvh, &cell, 0, 4, 0.0, Some(&solid));
        assert_eq!(p, Vec3::new(5.0, 1.5, 2.0));
        // The box rule leaves the room's box, and so the building.
        let p = free_sample_point(&scene, &bvh, &cell, 0, 4, 0.0, None);
        assert!(!scene.objects[0].bounds.contains(p), "{p}");
    }
}
