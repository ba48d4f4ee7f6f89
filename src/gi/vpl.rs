//! Incremental instant radiosity (Laine et al., EGSR 2007): a persistent set of
//! virtual point lights (VPLs) parameterized on the spotlight's Malley disk.
//! Each frame deletes invalid and worst-placed VPLs, adds new ones in the largest
//! empty circles, and re-weights them by their clipped Voronoi cell areas.

use std::collections::HashMap;

use glam::{DVec2, Vec2, Vec3};
use spade::{DelaunayTriangulation, HasPosition, Point2, Triangulation};

use super::light::Spotlight;
use crate::scene::raycast::RayScene;

/// Default number of VPLs (the paper's N).
pub const DEFAULT_TARGET: usize = 256;
/// Default per-frame budget of new VPLs / shadow maps (the paper's B).
pub const DEFAULT_BUDGET: usize = 8;

/// Fixed candidate points on the rim of the disk for the largest-empty-circle search.
const BOUNDARY_SAMPLES: usize = 256;
/// Radius at which rim candidates are placed (slightly inside the unit circle).
const BOUNDARY_RADIUS: f64 = 0.999;
/// Sides of the polygon approximating the unit disk when clipping Voronoi cells.
const DISK_POLYGON_SIDES: usize = 128;
/// Minimum cosine between a VPL's normal and the direction to the light.
const MIN_FACING_COS: f32 = 1e-6;
/// Golden angle in radians, for the sunflower spiral.
const GOLDEN_ANGLE: f64 = 2.399_963_229_728_653;
/// Interleave classes of the gather: a VPL is gathered by the pixels of class `layer % 16`
/// (4x4 interleaved sampling, see gi_gather.comp).
pub const INTERLEAVE_CLASSES: u32 = 16;

/// A virtual point light: a one-bounce sample of the spotlight's emission.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Vpl {
    /// Unique, monotonically increasing identifier.
    pub id: u64,
    /// World-space position on the surface.
    pub position: Vec3,
    /// Surface unit normal, facing the side the light reached it from.
    pub normal: Vec3,
    /// Diffuse albedo of the surface.
    pub albedo: Vec3,
    /// Position on the light's unit disk (Malley parameterization), updated every frame.
    pub disk_point: Vec2,
    /// Fraction of the light's power carried by this VPL (its clipped Voronoi cell's
    /// share of the disk); sums to 1 minus the fraction that escapes the scene.
    pub weight: f32,
    /// Shadow-map layer owned by this VPL, in `0..target`.
    pub layer: u32,
}

/// What one call to [`VplSet::update`] or [`VplSet::recompute_all`] changed.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct UpdateStats {
    /// VPLs deleted because they became invalid (behind the light, occluded or
    /// facing away). For [`VplSet::recompute_all`], all discarded VPLs.
    pub invalid_deleted: usize,
    /// Valid VPLs deleted to improve the distribution (shortest Delaunay edge rule).
    pub density_deleted: usize,
    /// VPLs created.
    pub added: usize,
    /// Layers of the VPLs created this frame: their shadow maps must be rendered.
    pub new_layers: Vec<u32>,
}

/// A disk direction whose ray escaped the scene. Voids occupy sample slots like
/// VPLs (so escaping regions are not re-tried every frame) but carry no light.
#[derive(Debug, Clone, Copy)]
struct Void {
    /// World-space unit direction from the light.
    direction: Vec3,
    /// Current disk point.
    disk_point: Vec2,
}

/// Triangulation vertex: a disk point tagged with its sample index.
#[derive(Debug, Clone, Copy)]
struct DiskVertex {
    pos: Point2<f64>,
    sample: usize,
}

impl HasPosition for DiskVertex {
    type Scalar = f64;
    fn position(&self) -> Point2<f64> {
        self.pos
    }
}

type DiskTriangulation = DelaunayTriangulation<DiskVertex>;

/// The incrementally maintained set of VPLs.
///
/// Samples on the disk are VPLs plus internal "voids" (rays that missed the
/// scene). Voids count towards the target `N` and take part in the Delaunay
/// bookkeeping, but own no layer; their Voronoi cells hold the light that escapes.
#[derive(Debug, Clone)]
pub struct VplSet {
    target: usize,
    budget: usize,
    vpls: Vec<Vpl>,
    voids: Vec<Void>,
    /// Free shadow-map layers, used as a stack (lowest layer on top).
    free_layers: Vec<u32>,
    next_id: u64,
}

impl Default for VplSet {
    fn default() -> Self {
        Self::new(DEFAULT_TARGET, DEFAULT_BUDGET)
    }
}

impl VplSet {
    /// Creates an empty set that maintains up to `target` (N) VPLs and creates at
    /// most `budget` (B) new ones per frame after the first.
    pub fn new(target: usize, budget: usize) -> Self {
        Self {
            target,
            budget,
            vpls: Vec::with_capacity(target),
            voids: Vec::new(),
            free_layers: (0..target as u32).rev().collect(),
            next_id: 0,
        }
    }

    /// Target number of VPLs (N), also the number of shadow-map layers.
    pub fn target(&self) -> usize {
        self.target
    }

    /// Per-frame budget of new VPLs (B).
    pub fn budget(&self) -> usize {
        self.budget
    }

    /// The current VPLs.
    pub fn vpls(&self) -> &[Vpl] {
        &self.vpls
    }

    /// One frame of incremental instant radiosity:
    /// 1. re-project every VPL to the light's disk and delete the invalid ones
    ///    (behind the hemisphere, occluded from the light, or facing away);
    /// 2. if the set was full and fewer than B samples were deleted, delete the
    ///    worst-placed ones (endpoint of the shortest Delaunay edge with the
    ///    smaller mean incident edge length) until B are deleted in total, as long
    ///    as a replacement improves the spacing (see `replacement_improves`);
    /// 3. add up to B VPLs at the centres of the largest empty circles in the disk
    ///    (an empty set is instead refilled at once with a sunflower spiral);
    /// 4. recompute weights from Voronoi cell areas.
    pub fn update(&mut self, light: &Spotlight, scene: &RayScene) -> UpdateStats {
        let mut stats = UpdateStats::default();
        let was_full = self.vpls.len() + self.voids.len() >= self.target;

        // (1) Re-projection and validation.
        let mut kept = Vec::with_capacity(self.vpls.len());
        for mut vpl in std::mem::take(&mut self.vpls) {
            match self.revalidate(&vpl, light, scene) {
                Some(disk_point) => {
                    vpl.disk_point = disk_point;
                    kept.push(vpl);
                }
                None => {
                    self.free_layers.push(vpl.layer);
                    stats.invalid_deleted += 1;
                }
            }
        }
        self.vpls = kept;
        let mut deleted_samples = stats.invalid_deleted;
        let voids_before = self.voids.len();
        self.voids.retain_mut(|v| {
            let Some(p) = light.direction_to_disk(light.position + v.direction) else {
                return false;
            };
            v.disk_point = p;
            scene
                .intersect(light.position, v.direction, f32::INFINITY)
                .is_none()
        });
        deleted_samples += voids_before - self.voids.len();

        if self.vpls.is_empty() && self.voids.is_empty() {
            self.fill_spiral(light, scene, &mut stats);
            self.compute_weights();
            return stats;
        }

        // (2) Density deletions.
        let mut tri = self.triangulate();
        if was_full && deleted_samples < self.budget {
            let mut deleted = vec![false; self.vpls.len() + self.voids.len()];
            let mut remaining = self.budget - deleted_samples;
            while remaining > 0 && replacement_improves(&tri) {
                let Some(victim) = worst_placed(&tri) else {
                    break;
                };
                let sample = tri.vertex(victim).data().sample;
                tri.remove(victim);
                deleted[sample] = true;
                remaining -= 1;
            }
            let n_vpls = self.vpls.len();
            let mut index = 0;
            let free_layers = &mut self.free_layers;
            let density_deleted = &mut stats.density_deleted;
            self.vpls.retain(|vpl| {
                let keep = !deleted[index];
                index += 1;
                if !keep {
                    free_layers.push(vpl.layer);
                    *density_deleted += 1;
                }
                keep
            });
            let mut index = n_vpls;
            self.voids.retain(|_| {
                index += 1;
                !deleted[index - 1]
            });
        }

        // (3) Additions at the largest empty circles.
        self.add_largest_empty_circles(&mut tri, light, scene, &mut stats);

        // (4) Weights.
        self.compute_weights();
        stats
    }

    /// Deletes the VPLs for which `gone` holds (those on an object that moved) and frees their
    /// layers; the next [`VplSet::update`] fills their places within its budget. Returns how
    /// many were deleted.
    pub fn remove_where(&mut self, mut gone: impl FnMut(&Vpl) -> bool) -> usize {
        let before = self.vpls.len();
        let free_layers = &mut self.free_layers;
        self.vpls.retain(|v| {
            let keep = !gone(v);
            if !keep {
                free_layers.push(v.layer);
            }
            keep
        });
        before - self.vpls.len()
    }

    /// Keller's full recompute: discard all VPLs and create up to N new ones from
    /// a sunflower spiral on the disk (rays that miss create no VPL).
    pub fn recompute_all(&mut self, light: &Spotlight, scene: &RayScene) -> UpdateStats {
        let mut stats = UpdateStats {
            invalid_deleted: self.vpls.len(),
            ..Default::default()
        };
        self.vpls.clear();
        self.voids.clear();
        self.free_layers = (0..self.target as u32).rev().collect();
        self.fill_spiral(light, scene, &mut stats);
        self.compute_weights();
        stats
    }

    /// Uniformity of the VPL disk points: the shortest distance between two disk
    /// points (which is always the shortest Delaunay edge) divided by the ideal
    /// spacing `sqrt(pi / n)` for the current count `n`. Larger is better; a
    /// hexagonal packing scores about 1.07. Returns 0 for fewer than two VPLs.
    pub fn uniformity(&self) -> f32 {
        let n = self.vpls.len();
        if n < 2 {
            return 0.0;
        }
        let mut min2 = f32::INFINITY;
        for (i, a) in self.vpls.iter().enumerate() {
            for b in &self.vpls[i + 1..] {
                min2 = min2.min(a.disk_point.distance_squared(b.disk_point));
            }
        }
        min2.sqrt() / (std::f32::consts::PI / n as f32).sqrt()
    }

    /// Current disk point if `vpl` is still valid for `light`.
    fn revalidate(&self, vpl: &Vpl, light: &Spotlight, scene: &RayScene) -> Option<Vec2> {
        let disk_point = light.direction_to_disk(vpl.position)?;
        let to_light = (light.position - vpl.position).normalize();
        if vpl.normal.dot(to_light) <= MIN_FACING_COS
            || scene.occluded(light.position, vpl.position)
        {
            return None;
        }
        Some(disk_point)
    }

    /// Casts a ray through `disk_point`; a hit becomes a VPL taking a free layer,
    /// a miss becomes a void.
    /// With `stratify`, the layer is chosen to keep interleave classes spread (see
    /// `take_stratified_layer`); else it is the last freed one (the spiral's order).
    fn shoot(
        &mut self,
        disk_point: Vec2,
        light: &Spotlight,
        scene: &RayScene,
        stats: &mut UpdateStats,
        stratify: bool,
    ) {
        let dir = light.disk_to_direction(disk_point);
        match scene.intersect(light.position, dir, f32::INFINITY) {
            Some(hit) => {
                let layer = match stratify {
                    true => self.take_stratified_layer(disk_point),
                    false => self.free_layers.pop(),
                };
                let Some(layer) = layer else {
                    return;
                };
                self.vpls.push(Vpl {
                    id: self.next_id,
                    position: hit.position,
                    normal: hit.normal,
                    albedo: hit.albedo,
                    disk_point,
                    weight: 0.0,
                    layer,
                });
                self.next_id += 1;
                stats.added += 1;
                stats.new_layers.push(layer);
            }
            None => self.voids.push(Void {
                direction: dir,
                disk_point,
            }),
        }
    }

    /// Fills the (empty) set with up to N samples on a sunflower spiral.
    fn fill_spiral(&mut self, light: &Spotlight, scene: &RayScene, stats: &mut UpdateStats) {
        let n = self.target;
        for i in 0..n {
            let r = ((i as f64 + 0.5) / n as f64).sqrt();
            let angle = i as f64 * GOLDEN_ANGLE;
            let p = Vec2::new((r * angle.cos()) as f32, (r * angle.sin()) as f32);
            self.shoot(p, light, scene, stats, false);
        }
    }

    /// Delaunay triangulation of all current samples (VPLs first, then voids).
    fn triangulate(&self) -> DiskTriangulation {
        let points = self
            .vpls
            .iter()
            .map(|v| v.disk_point)
            .chain(self.voids.iter().map(|v| v.disk_point));
        let mut tri = DiskTriangulation::new();
        for (sample, p) in points.enumerate() {
            // Exact duplicates replace the earlier vertex; the earlier sample then
            // has no vertex and will not be chosen for density deletion.
            let _ = tri.insert(DiskVertex {
                pos: to_point(p),
                sample,
            });
        }
        tri
    }

    /// Step (3): repeatedly shoot a ray through the centre of the largest empty
    /// circle whose centre lies in the disk. Candidates are Delaunay circumcentres
    /// inside the disk and fixed rim samples at radius 0.999 (radius = distance to
    /// the nearest sample). Misses become voids that block their region.
    fn add_largest_empty_circles(
        &mut self,
        tri: &mut DiskTriangulation,
        light: &Spotlight,
        scene: &RayScene,
        stats: &mut UpdateStats,
    ) {
        let max_attempts = 2 * self.budget;
        let mut rim = rim_candidates(tri);
        let mut attempts = 0;
        while stats.added < self.budget
            && attempts < max_attempts
            && self.vpls.len() + self.voids.len() < self.target
        {
            attempts += 1;
            let best = largest_empty_circle(tri, &rim);
            let centre = if best.1.is_finite() && best.1 >= 0.0 {
                best.0
            } else {
                DVec2::ZERO
            };
            for (p, r2) in &mut rim {
                *r2 = r2.min(p.distance_squared(centre));
            }
            let sample = self.vpls.len() + self.voids.len();
            let disk_point = centre.as_vec2();
            if tri
                .insert(DiskVertex {
                    pos: to_point(disk_point),
                    sample,
                })
                .is_err()
            {
                break;
            }
            self.shoot(disk_point, light, scene, stats, true);
        }
    }

    /// The free layer for a new VPL at `disk_point`, chosen so that each interleave class stays
    /// spread over the disk: the free layer whose class's nearest VPL is farthest from it.
    /// (Taking whichever layer was freed last would give the new VPL the class of one that
    /// died elsewhere, and over a moving light each class would drift into clumps: every
    /// 4x4 block then gathers unrepresentative subsets and the blur leaves the pattern.)
    /// Ties go to the most recently freed layer.
    fn take_stratified_layer(&mut self, disk_point: Vec2) -> Option<u32> {
        let mut nearest = [f32::INFINITY; INTERLEAVE_CLASSES as usize];
        for v in &self.vpls {
            let c = (v.layer % INTERLEAVE_CLASSES) as usize;
            nearest[c] = nearest[c].min(v.disk_point.distance_squared(disk_point));
        }
        let gap = |layer: u32| nearest[(layer % INTERLEAVE_CLASSES) as usize];
        let mut best = self.free_layers.len().checked_sub(1)?;
        for (i, &layer) in self.free_layers.iter().enumerate().rev() {
            if gap(layer) > gap(self.free_layers[best]) {
                best = i;
            }
        }
        Some(self.free_layers.remove(best))
    }

    /// Step (4): each VPL's weight is the area of its Voronoi cell (over all
    /// samples, voids included) clipped exactly against a 128-gon approximating
    /// the unit disk, divided by the area of that 128-gon. Malley's map sends
    /// cosine-weighted directions uniformly onto the disk, so this is the fraction
    /// of the light's power leaving through the cell. The cells of voids (rays that
    /// escaped the scene) keep their share: their light is lost, not put back onto
    /// the VPLs, so the weights sum to 1 only when no ray escapes.
    fn compute_weights(&mut self) {
        if self.vpls.is_empty() {
            return;
        }
        let points: Vec<Vec2> = self
            .vpls
            .iter()
            .map(|v| v.disk_point)
            .chain(self.voids.iter().map(|v| v.disk_point))
            .collect();
        let areas = voronoi_disk_areas(&points);
        let disk_area = polygon_area(&disk_polygon());
        for (vpl, area) in self.vpls.iter_mut().zip(&areas) {
            vpl.weight = (area / disk_area) as f32;
        }
    }

    /// Fraction of the light's power that leaves through the voids (rays that
    /// escaped the scene): 1 minus the sum of the VPL weights.
    pub fn escaped_fraction(&self) -> f32 {
        if self.vpls.is_empty() {
            return if self.voids.is_empty() { 0.0 } else { 1.0 };
        }
        (1.0 - self.vpls.iter().map(|v| f64::from(v.weight)).sum::<f64>()).max(0.0) as f32
    }

    /// Number of voids (samples whose ray escaped the scene).
    pub fn void_count(&self) -> usize {
        self.voids.len()
    }
}

/// The fixed rim candidates at radius 0.999, each with its squared distance to the
/// nearest sample (infinite for an empty triangulation).
fn rim_candidates(tri: &DiskTriangulation) -> Vec<(DVec2, f64)> {
    (0..BOUNDARY_SAMPLES)
        .map(|k| {
            let a = (k as f64 + 0.5) * std::f64::consts::TAU / BOUNDARY_SAMPLES as f64;
            let p = DVec2::new(a.cos(), a.sin()) * BOUNDARY_RADIUS;
            let r2 = tri
                .vertices()
                .map(|v| to_dvec(v.position()).distance_squared(p))
                .fold(f64::INFINITY, f64::min);
            (p, r2)
        })
        .collect()
}

/// Centre and squared radius of the largest empty circle whose centre lies in the
/// disk: the largest Delaunay circumcircle centred inside, or a rim candidate.
/// `(0, -1)` when there is no candidate.
fn largest_empty_circle(tri: &DiskTriangulation, rim: &[(DVec2, f64)]) -> (DVec2, f64) {
    let mut best = (DVec2::ZERO, -1.0);
    for face in tri.inner_faces() {
        let (c, r2) = face.circumcircle();
        let c = to_dvec(c);
        if r2 > best.1 && c.length_squared() < BOUNDARY_RADIUS * BOUNDARY_RADIUS {
            best = (c, r2);
        }
    }
    for &(p, r2) in rim {
        if r2 > best.1 {
            best = (p, r2);
        }
    }
    best
}

/// Whether replacing the worst-placed sample can improve the distribution: the
/// largest empty circle is wider (in radius) than the shortest Delaunay edge, so a
/// sample placed at its centre ends up farther from its neighbours than the
/// deleted endpoint of that edge was. Under a static light this stops the density
/// deletions once the samples are evenly spread (a hexagonal packing's largest
/// empty circle is 0.58 of its spacing), so such frames replace nothing.
fn replacement_improves(tri: &DiskTriangulation) -> bool {
    let Some(shortest) = tri
        .undirected_edges()
        .map(|e| e.length_2())
        .min_by(f64::total_cmp)
    else {
        return false;
    };
    let (_, r2) = largest_empty_circle(tri, &rim_candidates(tri));
    r2 > shortest
}

/// Step (2) selection: the endpoint of the shortest Delaunay edge whose incident
/// edges have the smaller mean length (the denser neighbourhood).
fn worst_placed(tri: &DiskTriangulation) -> Option<spade::handles::FixedVertexHandle> {
    let shortest = tri
        .undirected_edges()
        .min_by(|a, b| a.length_2().total_cmp(&b.length_2()))?;
    let mean_len = |v: spade::handles::VertexHandle<DiskVertex>| {
        let (sum, count) = v
            .out_edges()
            .fold((0.0, 0), |(s, c), e| (s + e.length_2().sqrt(), c + 1));
        sum / f64::from(count.max(1))
    };
    let [a, b] = shortest.vertices();
    let victim = if mean_len(b) < mean_len(a) { b } else { a };
    Some(victim.fix())
}

/// Area of the Voronoi cell of each point, clipped to a 128-gon approximating the
/// unit disk. Exact duplicates share their cell equally. Works for 0, 1, 2 and
/// collinear points (cells are the disk clipped by the bisectors to Delaunay
/// neighbours, which exist for collinear input too).
fn voronoi_disk_areas(points: &[Vec2]) -> Vec<f64> {
    if points.is_empty() {
        return Vec::new();
    }
    let disk = disk_polygon();
    let disk_inradius = (std::f64::consts::PI / DISK_POLYGON_SIDES as f64).cos();
    let (tri, owner) = triangulate_distinct(points);
    let mut cell = Vec::with_capacity(2 * DISK_POLYGON_SIDES);
    let mut scratch = Vec::with_capacity(2 * DISK_POLYGON_SIDES);
    let mut cell_area = vec![0.0; points.len()];
    for v in tri.vertices() {
        clipped_voronoi_cell(v, &disk, disk_inradius, &mut cell, &mut scratch);
        cell_area[v.data().sample] = polygon_area(&cell);
    }
    share_among_duplicates(&owner, &cell_area)
}

/// The `DISK_POLYGON_SIDES`-gon inscribed in the unit circle.
fn disk_polygon() -> Vec<DVec2> {
    (0..DISK_POLYGON_SIDES)
        .map(|k| {
            let a = k as f64 * std::f64::consts::TAU / DISK_POLYGON_SIDES as f64;
            DVec2::new(a.cos(), a.sin())
        })
        .collect()
}

/// The Delaunay triangulation of the distinct points, and for each point the index of the
/// first point at the same position (its owner; `usize::MAX` if spade refused it).
fn triangulate_distinct(points: &[Vec2]) -> (DiskTriangulation, Vec<usize>) {
    let mut tri = DiskTriangulation::new();
    let mut first_at: HashMap<(u32, u32), usize> = HashMap::new();
    let mut owner = vec![usize::MAX; points.len()];
    for (i, p) in points.iter().enumerate() {
        let key = (p.x.to_bits(), p.y.to_bits());
        if let Some(&first) = first_at.get(&key) {
            owner[i] = first;
            continue;
        }
        if tri
            .insert(DiskVertex {
                pos: to_point(*p),
                sample: i,
            })
            .is_ok()
        {
            first_at.insert(key, i);
            owner[i] = i;
        }
    }
    (tri, owner)
}

/// Writes into `cell` the Voronoi cell of `v` clipped to the `disk` polygon: the disk (or a
/// smaller box around `v` known to hold the cell) clipped by the bisector to each neighbour.
fn clipped_voronoi_cell(
    v: spade::handles::VertexHandle<DiskVertex>,
    disk: &[DVec2],
    disk_inradius: f64,
    cell: &mut Vec<DVec2>,
    scratch: &mut Vec<DVec2>,
) {
    let p = to_dvec(v.position());
    cell.clear();
    // An interior vertex's cell lies within its largest incident circumradius;
    // if that box is inside the disk polygon, start from the box (much cheaper).
    let mut reach: Option<f64> = Some(0.0);
    for e in v.out_edges() {
        reach = match (reach, e.face().as_inner()) {
            (Some(r), Some(face)) => Some(r.max(face.circumcircle().1.sqrt())),
            _ => None,
        };
    }
    match reach {
        Some(h) if h > 0.0 && p.length() + h * std::f64::consts::SQRT_2 < disk_inradius => {
            cell.extend([
                p + DVec2::new(-h, -h),
                p + DVec2::new(h, -h),
                p + DVec2::new(h, h),
                p + DVec2::new(-h, h),
            ]);
        }
        _ => cell.extend_from_slice(disk),
    }
    for e in v.out_edges() {
        let q = to_dvec(e.to().position());
        clip_half_plane(cell, scratch, (p + q) * 0.5, q - p);
        std::mem::swap(cell, scratch);
        if cell.is_empty() {
            break;
        }
    }
}

/// Each point's area: its owner's cell area, split equally among the points at the same
/// position (0 for points the triangulation refused).
fn share_among_duplicates(owner: &[usize], cell_area: &[f64]) -> Vec<f64> {
    let mut areas = vec![0.0; owner.len()];
    let mut share = vec![0usize; owner.len()];
    for &o in owner {
        if o != usize::MAX {
            share[o] += 1;
        }
    }
    for (area, &o) in areas.iter_mut().zip(owner) {
        if o != usize::MAX {
            *area = cell_area[o] / share[o] as f64;
        }
    }
    areas
}

/// Sutherland–Hodgman: keeps the part of `poly` with `(x - m) · n <= 0`.
fn clip_half_plane(poly: &[DVec2], out: &mut Vec<DVec2>, m: DVec2, n: DVec2) {
    out.clear();
    let Some(&last) = poly.last() else {
        return;
    };
    let mut prev = last;
    let mut prev_d = (prev - m).dot(n);
    for &cur in poly {
        let cur_d = (cur - m).dot(n);
        if (prev_d <= 0.0) != (cur_d <= 0.0) {
            let t = prev_d / (prev_d - cur_d);
            out.push(prev + (cur - prev) * t);
        }
        if cur_d <= 0.0 {
            out.push(cur);
        }
        prev = cur;
        prev_d = cur_d;
    }
}

/// Absolute area of a simple polygon (shoelace formula).
fn polygon_area(poly: &[DVec2]) -> f64 {
    let Some(&last) = poly.last() else {
        return 0.0;
    };
    let mut prev = last;
    let mut twice = 0.0;
    for &cur in poly {
        twice += prev.perp_dot(cur);
        prev = cur;
    }
    0.5 * twice.abs()
}

fn to_point(p: Vec2) -> Point2<f64> {
    spade::mitigate_underflow(Point2::new(f64::from(p.x), f64::from(p.y)))
}

fn to_dvec(p: Point2<f64>) -> DVec2 {
    DVec2::new(p.x, p.y)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashSet;

    const N: usize = 256;
    const B: usize = 8;

    fn quad(tris: &mut Vec<[Vec3; 3]>, albedo: &mut Vec<Vec3>, c: Vec3, u: Vec3, v: Vec3, a: Vec3) {
        let (p0, p1, p2, p3) = (c - u - v, c + u - v, c + u + v, c - u + v);
        tris.push([p0, p1, p2]);
        tris.push([p0, p2, p3]);
        albedo.extend([a, a]);
    }

    /// Closed Cornell-like box [-1,1] x [0,2] x [-1,1] with a short block inside.
    fn cornell() -> RayScene {
        let (mut t, mut a) = (Vec::new(), Vec::new());
        let w = Vec3::splat(0.75);
        quad(&mut t, &mut a, Vec3::ZERO, Vec3::X, Vec3::Z, w);
        quad(
            &mut t,
            &mut a,
            Vec3::new(0.0, 2.0, 0.0),
            Vec3::X,
            Vec3::Z,
            w,
        );
        quad(
            &mut t,
            &mut a,
            Vec3::new(0.0, 1.0, -1.0),
            Vec3::X,
            Vec3::Y,
            w,
        );
        quad(
            &mut t,
            &mut a,
            Vec3::new(0.0, 1.0, 1.0),
            Vec3::X,
            Vec3::Y,
            w,
        );
        quad(
            &mut t,
            &mut a,
            Vec3::new(-1.0, 1.0, 0.0),
            Vec3::Y,
            Vec3::Z,
            Vec3::new(0.7, 0.1, 0.1),
        );
        quad(
            &mut t,
            &mut a,
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::Y,
            Vec3::Z,
            Vec3::new(0.1, 0.7, 0.1),
        );
        // Short block centred at (0.4, 0.3, 0.3), half size 0.3.
        let c = Vec3::new(0.4, 0.3, 0.3);
        let h = 0.3;
        quad(&mut t, &mut a, c + Vec3::Y * h, Vec3::X * h, Vec3::Z * h, w);
        quad(&mut t, &mut a, c + Vec3::X * h, Vec3::Y * h, Vec3::Z * h, w);
        quad(&mut t, &mut a, c - Vec3::X * h, Vec3::Y * h, Vec3::Z * h, w);
        quad(&mut t, &mut a, c + Vec3::Z * h, Vec3::X * h, Vec3::Y * h, w);
        quad(&mut t, &mut a, c - Vec3::Z * h, Vec3::X * h, Vec3::Y * h, w);
        RayScene::new(t, a)
    }

    fn ceiling_light() -> Spotlight {
        Spotlight::new(Vec3::new(0.0, 1.9, 0.0), Vec3::NEG_Y, Vec3::splat(10.0))
    }

    /// Light moving around near the ceiling, slightly swaying.
    fn moving_light(frame: usize) -> Spotlight {
        let a = frame as f32 * 0.05;
        Spotlight::new(
            Vec3::new(0.5 * a.cos(), 1.85, 0.5 * a.sin()),
            Vec3::new(0.3 * a.sin(), -1.0, 0.2 * a.cos()),
            Vec3::ONE,
        )
    }

    fn is_valid(vpl: &Vpl, light: &Spotlight, scene: &RayScene) -> bool {
        light.direction_to_disk(vpl.position).is_some()
            && vpl.normal.dot((light.position - vpl.position).normalize()) > MIN_FACING_COS
            && !scene.occluded(light.position, vpl.position)
    }

    fn check_invariants(set: &VplSet) {
        let sum: f32 = set.vpls().iter().map(|v| v.weight).sum();
        if !set.vpls().is_empty() && set.void_count() == 0 {
            assert!((sum - 1.0).abs() < 1e-4, "weights sum to {sum}");
        }
        assert!(sum <= 1.0 + 1e-4, "weights sum to {sum}");
        if !set.vpls().is_empty() || set.void_count() > 0 {
            assert!((sum + set.escaped_fraction() - 1.0).abs() < 1e-4);
        }
        let layers: HashSet<u32> = set.vpls().iter().map(|v| v.layer).collect();
        assert_eq!(layers.len(), set.vpls().len(), "layers must be unique");
        assert!(layers.iter().all(|&l| (l as usize) < set.target()));
        assert!(set.vpls().len() <= set.target());
    }

    #[test]
    fn weights_sum_to_one_with_moving_light() {
        let scene = cornell();
        let mut set = VplSet::new(N, B);
        for frame in 0..30 {
            set.update(&moving_light(frame), &scene);
            check_invariants(&set);
            assert!(set.vpls().iter().all(|v| v.weight > 0.0));
        }
    }

    #[test]
    fn uniformity_improves_on_static_light_until_the_set_rests() {
        let scene = cornell();
        let mut set = VplSet::new(N, B);
        let first = set.update(&moving_light(0), &scene);
        assert_eq!(first.added, N);
        // A moving light distorts the distribution on the disk.
        for frame in 1..20 {
            set.update(&moving_light(frame), &scene);
        }
        let light = moving_light(20);
        set.update(&light, &scene);
        let mut before = set.uniformity();
        let (mut replaced, mut rest) = (0, None);
        for frame in 0..4 * N / B {
            let stats = set.update(&light, &scene);
            assert_eq!(stats.invalid_deleted, 0);
            assert!(stats.density_deleted <= B);
            assert_eq!(stats.added, stats.density_deleted);
            let after = set.uniformity();
            assert!(after >= before - 1e-4, "uniformity {before} -> {after}");
            before = after;
            replaced += stats.added;
            if stats.density_deleted == 0 {
                rest = Some(frame);
                break;
            }
        }
        assert!(replaced > 0, "the distorted set should be improved");
        assert!(rest.is_some(), "the set never came to rest");
        for _ in 0..3 {
            let stats = set.update(&light, &scene);
            assert_eq!(
                stats.added + stats.density_deleted + stats.invalid_deleted,
                0
            );
        }
    }

    #[test]
    fn a_new_vpl_takes_the_free_class_whose_nearest_member_is_farthest() {
        let vpl = |layer: u32, x: f32| Vpl {
            id: layer as u64,
            position: Vec3::ZERO,
            normal: Vec3::Y,
            albedo: Vec3::ONE,
            disk_point: Vec2::new(x, 0.0),
            weight: 0.0,
            layer,
        };
        let mut set = VplSet::new(N, B);
        // Class 0 sits at x = 0.5, class 1 at x = -0.5; layers 16 and 17 (classes 0, 1) free.
        set.vpls = vec![vpl(0, 0.5), vpl(1, -0.5)];
        set.free_layers = vec![16, 17];
        assert_eq!(set.take_stratified_layer(Vec2::new(0.5, 0.1)), Some(17));
        set.free_layers = vec![17, 16];
        assert_eq!(set.take_stratified_layer(Vec2::new(-0.5, 0.1)), Some(16));
        assert_eq!(set.free_layers, [17]);
        // A tie (no VPL of either class) goes to the most recently freed layer.
        set.vpls.clear();
        set.free_layers = vec![16, 17];
        assert_eq!(set.take_stratified_layer(Vec2::ZERO), Some(17));
        set.free_layers.clear();
        assert_eq!(set.take_stratified_layer(Vec2::ZERO), None);
    }

    #[test]
    fn invalid_vpls_are_deleted_first() {
        let scene = cornell();
        let mut set = VplSet::new(N, B);
        set.update(&ceiling_light(), &scene);
        assert_eq!(set.vpls().len(), N);
        // Find a small tilt that invalidates between 1 and B-1 VPLs.
        let (light, k) = (1..200)
            .map(|i| {
                let angle = i as f32 * 0.002;
                let dir = Vec3::new(angle.sin(), -angle.cos(), 0.0);
                Spotlight::new(Vec3::new(0.0, 1.9, 0.0), dir, Vec3::ONE)
            })
            .map(|l| {
                let k = set
                    .vpls()
                    .iter()
                    .filter(|v| !is_valid(v, &l, &scene))
                    .count();
                (l, k)
            })
            .find(|&(_, k)| k > 0 && k < B)
            .expect("some tilt invalidates fewer than B VPLs");
        let stats = set.update(&light, &scene);
        assert_eq!(stats.invalid_deleted, k);
        assert_eq!(stats.density_deleted, B - k);
        assert!(stats.added <= B);
        assert!(set.vpls().iter().all(|v| is_valid(v, &light, &scene)));
        check_invariants(&set);
    }

    #[test]
    fn at_most_budget_new_vpls_per_frame() {
        let scene = cornell();
        let mut set = VplSet::new(N, B);
        let first = set.update(&moving_light(0), &scene);
        assert_eq!(first.new_layers.len(), first.added);
        for frame in 1..50 {
            let before: HashSet<u64> = set.vpls().iter().map(|v| v.id).collect();
            let stats = set.update(&moving_light(frame), &scene);
            assert!(stats.added <= B, "frame {frame}: {} added", stats.added);
            assert_eq!(stats.new_layers.len(), stats.added);
            let new: Vec<&Vpl> = set
                .vpls()
                .iter()
                .filter(|v| !before.contains(&v.id))
                .collect();
            assert_eq!(new.len(), stats.added);
            let new_layers: HashSet<u32> = new.iter().map(|v| v.layer).collect();
            assert_eq!(new_layers, stats.new_layers.iter().copied().collect());
            check_invariants(&set);
        }
    }

    #[test]
    fn light_turning_away_invalidates_unreached_vpls() {
        let scene = cornell();
        let mut set = VplSet::new(N, B);
        set.update(&ceiling_light(), &scene);
        // Quarter turn: the light now points at the front wall (+Z).
        let turned = Spotlight::new(Vec3::new(0.0, 1.9, 0.0), Vec3::Z, Vec3::ONE);
        let doomed: HashSet<u64> = set
            .vpls()
            .iter()
            .filter(|v| !is_valid(v, &turned, &scene))
            .map(|v| v.id)
            .collect();
        assert!(!doomed.is_empty());
        let stats = set.update(&turned, &scene);
        assert_eq!(stats.invalid_deleted, doomed.len());
        assert!(set.vpls().iter().all(|v| !doomed.contains(&v.id)));
        assert!(set.vpls().iter().all(|v| is_valid(v, &turned, &scene)));
        check_invariants(&set);
        // Half turn: everything below the light is now behind it.
        let up = Spotlight::new(Vec3::new(0.0, 1.9, 0.0), Vec3::Y, Vec3::ONE);
        let old: HashSet<u64> = set.vpls().iter().map(|v| v.id).collect();
        let stats = set.update(&up, &scene);
        assert!(stats.invalid_deleted > 0);
        assert!(set.vpls().iter().all(|v| is_valid(v, &up, &scene)));
        assert!(set.vpls().iter().all(|v| v.position.y > 1.9 - 1e-4));
        assert!(set
            .vpls()
            .iter()
            .all(|v| !old.contains(&v.id) || v.position.y > 1.9));
        check_invariants(&set);
    }

    #[test]
    fn full_recompute_creates_n_vpls() {
        let scene = cornell();
        let mut set = VplSet::new(N, B);
        set.update(&ceiling_light(), &scene);
        let stats = set.recompute_all(&moving_light(7), &scene);
        assert_eq!(stats.invalid_deleted, N);
        assert_eq!(stats.added, N);
        assert_eq!(stats.new_layers.len(), N);
        let layers: HashSet<u32> = stats.new_layers.iter().copied().collect();
        assert_eq!(layers, (0..N as u32).collect());
        check_invariants(&set);
    }

    #[test]
    fn open_scene_creates_as_many_as_hit() {
        // A single floor quad below the light: the rim of the disk misses.
        let (mut t, mut a) = (Vec::new(), Vec::new());
        quad(&mut t, &mut a, Vec3::ZERO, Vec3::X, Vec3::Z, Vec3::ONE);
        let scene = RayScene::new(t, a);
        let mut set = VplSet::new(N, B);
        let stats = set.recompute_all(&ceiling_light(), &scene);
        assert!(stats.added > 0 && stats.added < N);
        assert_eq!(stats.new_layers.len(), stats.added);
        check_invariants(&set);
        for _ in 0..10 {
            let s = set.update(&ceiling_light(), &scene);
            assert!(s.added <= B);
            check_invariants(&set);
        }
    }

    #[test]
    fn degenerate_sets_do_not_panic() {
        let scene = cornell();
        for target in [0, 1, 2, 3] {
            let mut set = VplSet::new(target, 1);
            for frame in 0..5 {
                set.update(&moving_light(frame), &scene);
                check_invariants(&set);
                assert_eq!(set.vpls().len(), target);
            }
            if target == 1 {
                assert_eq!(set.vpls()[0].weight, 1.0);
            }
        }
        let empty = RayScene::new(Vec::new(), Vec::new());
        let mut set = VplSet::default();
        assert_eq!(set.update(&ceiling_light(), &empty).added, 0);
        assert_eq!(set.recompute_all(&ceiling_light(), &empty).added, 0);
        assert_eq!(set.uniformity(), 0.0);
    }

    #[test]
    fn voronoi_areas_degenerate_inputs() {
        let disk_area = polygon_area(
            &(0..DISK_POLYGON_SIDES)
                .map(|k| {
                    let a = k as f64 * std::f64::consts::TAU / DISK_POLYGON_SIDES as f64;
                    DVec2::new(a.cos(), a.sin())
                })
                .collect::<Vec<_>>(),
        );
        assert!(voronoi_disk_areas(&[]).is_empty());
        let one = voronoi_disk_areas(&[Vec2::new(0.2, 0.1)]);
        assert!((one[0] - disk_area).abs() < 1e-9);
        let two = voronoi_disk_areas(&[Vec2::new(-0.5, 0.0), Vec2::new(0.5, 0.0)]);
        assert!((two[0] - two[1]).abs() < 1e-9 && (two[0] + two[1] - disk_area).abs() < 1e-9);
        let line: Vec<Vec2> = (0..5)
            .map(|i| Vec2::new(i as f32 * 0.2 - 0.4, 0.1))
            .collect();
        let areas = voronoi_disk_areas(&line);
        assert!((areas.iter().sum::<f64>() - disk_area).abs() < 1e-9);
        let dup = voronoi_disk_areas(&[Vec2::ZERO, Vec2::ZERO, Vec2::new(0.5, 0.5)]);
        assert!((dup[0] - dup[1]).abs() < 1e-12);
        assert!((dup.iter().sum::<f64>() - disk_area).abs() < 1e-9);
        let spiral: Vec<Vec2> = (0..256)
            .map(|i| {
                let r = ((i as f64 + 0.5) / 256.0).sqrt();
                let a = i as f64 * GOLDEN_ANGLE;
                Vec2::new((r * a.cos()) as f32, (r * a.sin()) as f32)
            })
            .collect();
        let areas = voronoi_disk_areas(&spiral);
        assert!(areas.iter().all(|&a| a > 0.0));
        assert!((areas.iter().sum::<f64>() - disk_area).abs() < 1e-9);
    }

    /// Release-mode timing on a ~50k-triangle scene:
    /// `cargo test --release -- --ignored --nocapture update_timing`.
    #[test]
    #[ignore]
    fn update_timing() {
        let (mut t, mut a) = (Vec::new(), Vec::new());
        // Finely tessellated box walls: 6 faces x 2 x 64 x 64 = 49k triangles.
        let n = 64;
        let faces = [
            (Vec3::ZERO, Vec3::X, Vec3::Z),
            (Vec3::new(0.0, 2.0, 0.0), Vec3::X, Vec3::Z),
            (Vec3::new(0.0, 1.0, -1.0), Vec3::X, Vec3::Y),
            (Vec3::new(0.0, 1.0, 1.0), Vec3::X, Vec3::Y),
            (Vec3::new(-1.0, 1.0, 0.0), Vec3::Y, Vec3::Z),
            (Vec3::new(1.0, 1.0, 0.0), Vec3::Y, Vec3::Z),
        ];
        for (c, u, v) in faces {
            for i in 0..n {
                for j in 0..n {
                    let s = (i as f32 + 0.5) / n as f32 * 2.0 - 1.0;
                    let r = (j as f32 + 0.5) / n as f32 * 2.0 - 1.0;
                    let cc = c + u * s + v * r;
                    quad(
                        &mut t,
                        &mut a,
                        cc,
                        u / n as f32,
                        v / n as f32,
                        Vec3::splat(0.7),
                    );
                }
            }
        }
        let scene = RayScene::new(t, a);
        let mut set = VplSet::new(N, B);
        set.update(&moving_light(0), &scene);
        let start = std::time::Instant::now();
        let frames = 100;
        for frame in 1..=frames {
            set.update(&moving_light(frame), &scene);
        }
        let per_frame = start.elapsed().as_secs_f64() * 1e3 / frames as f64;
        println!(
            "{} triangles: {per_frame:.3} ms per update",
            scene.triangle_count()
        );
        let start = std::time::Instant::now();
        for _ in 0..frames {
            set.update(&ceiling_light(), &scene);
        }
        let per_frame = start.elapsed().as_secs_f64() * 1e3 / frames as f64;
        println!("static light: {per_frame:.3} ms per update");
        let light = ceiling_light();
        let start = std::time::Instant::now();
        for v in set.vpls() {
            std::hint::black_box(scene.occluded(light.position, v.position));
        }
        println!("occlusion rays: {:?}", start.elapsed());
    }
}
