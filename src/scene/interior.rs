//! The automatic interior walk (`--path interior`): eye-height positions over floors found by
//! ray casting (an obvhs triangle BVH), kept a margin away from all geometry, joined into a
//! tour of the most open places along shortest grid paths. Deterministic for a given scene.

use std::collections::{BinaryHeap, HashMap};
use std::time::Duration;

use glam::{Vec3, Vec3A};
use obvhs::aabb::Aabb as BvhAabb;
use obvhs::bvh2::{builder::build_bvh2_from_tris, Bvh2};
use obvhs::ray::{Ray, RayHit};
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;

use super::{Aabb, CameraPath, CameraPose, Scene};
use crate::Error;

/// Name of the interior walk among a scene's paths.
pub const PATH_NAME: &str = "interior";

/// Settings of the interior walk; lengths in scene units, `None` = derived from the bounds.
#[derive(Clone, Debug)]
pub struct InteriorParams {
    /// Eye height over the floor (default 1.7, at most 40% of the scene's height).
    pub eye_height: Option<f32>,
    /// Least distance from the eye to any geometry (default 1% of the horizontal extent, at
    /// most a quarter of the eye height).
    pub margin: Option<f32>,
    /// Grid cells along the longer horizontal side.
    pub grid: usize,
    /// Most places of the tour.
    pub waypoints: usize,
}

impl Default for InteriorParams {
    fn default() -> Self {
        InteriorParams {
            eye_height: None,
            margin: None,
            grid: 48,
            waypoints: 6,
        }
    }
}

/// World triangles with a BVH for ray casts and distance queries.
pub struct TriangleScene {
    bvh: Bvh2,
    triangles: Vec<Triangle>,
    /// World bounds.
    pub bounds: Aabb,
}

impl TriangleScene {
    /// The scene's world-space triangles; `None` when it has none.
    pub fn new(scene: &Scene) -> Option<TriangleScene> {
        let mut triangles = Vec::new();
        let mut bounds = Aabb::EMPTY;
        for o in &scene.objects {
            let idx =
                &scene.indices[o.first_index as usize..(o.first_index + o.index_count) as usize];
            for t in idx.chunks_exact(3) {
                let p = [t[0], t[1], t[2]].map(|i| {
                    let v = scene.vertices[(o.vertex_offset + i) as usize];
                    o.transform.transform_point3(Vec3::from_array(v.position))
                });
                p.iter().for_each(|&q| bounds.grow(q));
                triangles.push(Triangle {
                    v0: p[0].into(),
                    v1: p[1].into(),
                    v2: p[2].into(),
                });
            }
        }
        if triangles.is_empty() {
            return None;
        }
        let mut time = Duration::ZERO;
        let bvh = build_bvh2_from_tris(&triangles, BvhBuildParams::fast_build(), &mut time);
        let triangles = bvh
            .primitive_indices
            .iter()
            .map(|&i| triangles[i as usize])
            .collect();
        Some(TriangleScene {
            bvh,
            triangles,
            bounds,
        })
    }

    /// Distance to the closest hit along a unit `dir` (up to `t_max`) and the hit's normal.
    pub fn cast(&self, origin: Vec3, dir: Vec3, t_max: f32) -> Option<(f32, Vec3)> {
        let ray = Ray::new(origin.into(), dir.into(), 0.0, t_max);
        let mut hit = RayHit::none();
        if !self
            .bvh
            .ray_traverse(ray, &mut hit, |r, id| self.triangles[id].intersect(r))
        {
            return None;
        }
        let n = Vec3::from(self.triangles[hit.primitive_id as usize].compute_normal());
        Some((hit.t, n))
    }

    /// Whether any triangle is closer to `p` than `r`.
    pub fn within(&self, p: Vec3, r: f32) -> bool {
        let pa = Vec3A::from(p);
        let query = BvhAabb::new(pa - Vec3A::splat(r), pa + Vec3A::splat(r));
        let mut found = false;
        self.bvh.aabb_traverse(query, |bvh, node| {
            let n = &bvh.nodes[node as usize];
            let first = n.first_index as usize;
            for t in &self.triangles[first..first + n.prim_count as usize] {
                let tri = [t.v0, t.v1, t.v2].map(Vec3::from);
                if distance_to_triangle(p, &tri) < r {
                    found = true;
                    return false;
                }
            }
            true
        });
        found
    }

    /// Whether the segment from `a` to `b` stays at least `r` from all geometry (sampled every
    /// `r / 2`, both ends included).
    pub fn segment_clear(&self, a: Vec3, b: Vec3, r: f32) -> bool {
        let steps = ((b - a).length() / (0.5 * r)).ceil().max(1.0) as usize;
        (0..=steps).all(|i| !self.within(a.lerp(b, i as f32 / steps as f32), r))
    }
}

/// Distance from `p` to the triangle `t` (closest point by Voronoi regions, Ericson 5.1.5).
pub fn distance_to_triangle(p: Vec3, t: &[Vec3; 3]) -> f32 {
    let [a, b, c] = *t;
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return p.distance(a);
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return p.distance(b);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return p.distance(a + ab * (d1 / (d1 - d3)));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return p.distance(c);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return p.distance(a + ac * (d2 / (d2 - d6)));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return p.distance(b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6))));
    }
    let denom = 1.0 / (va + vb + vc);
    let closest = a + ab * (vb * denom) + ac * (vc * denom);
    if closest.is_finite() {
        p.distance(closest)
    } else {
        p.distance(a).min(p.distance(b)).min(p.distance(c))
    }
}

/// Sixteen horizontal unit directions.
fn horizontal_dirs() -> impl Iterator<Item = Vec3> {
    (0..16).map(|k| {
        let a = k as f32 * std::f32::consts::TAU / 16.0;
        Vec3::new(a.cos(), 0.0, a.sin())
    })
}

/// Whether a camera at the middle of the scene would stand inside something enclosed: from
/// the bounds' center, 90% of rays in 26 directions hit geometry.
pub fn is_enclosed(rays: &TriangleScene) -> bool {
    let c = rays.bounds.center();
    let far = rays.bounds.extent().length() * 2.0 + 1.0;
    let mut hits = 0;
    let mut total = 0;
    for x in -1..=1 {
        for y in -1..=1 {
            for z in -1..=1 {
                let d = Vec3::new(x as f32, y as f32, z as f32);
                if d == Vec3::ZERO {
                    continue;
                }
                total += 1;
                hits += rays.cast(c, d.normalize(), far).is_some() as usize;
            }
        }
    }
    hits * 10 >= total * 9
}

/// One walkable place: a grid cell, the eye position over its floor and how open it is.
#[derive(Clone, Copy, Debug)]
struct Place {
    cell: (i32, i32),
    eye: Vec3,
    /// Mean horizontal free distance (the "large open spaces" measure).
    openness: f32,
}

/// Eye-height places over every floor under each grid cell center, each at least `2 *
/// margin` from geometry and, with `need_ceiling`, under a ceiling.
fn places(
    rays: &TriangleScene,
    cell: f32,
    (eye_h, margin): (f32, f32),
    need_ceiling: bool,
) -> Vec<Place> {
    let b = rays.bounds;
    let (nx, nz) = (
        (b.extent().x / cell).ceil().max(1.0) as i32,
        (b.extent().z / cell).ceil().max(1.0) as i32,
    );
    let far = b.extent().length() + 1.0;
    let mut out = Vec::new();
    for iz in 0..nz {
        for ix in 0..nx {
            let x = b.min.x + (ix as f32 + 0.5) * cell;
            let z = b.min.z + (iz as f32 + 0.5) * cell;
            let mut origin = Vec3::new(x, b.max.y + 1.0, z);
            // Every surface under the cell center, top to bottom.
            while let Some((t, n)) = rays.cast(origin, Vec3::NEG_Y, far) {
                let floor = origin - Vec3::Y * t;
                origin = floor - Vec3::Y * (1e-3 * cell);
                let eye = floor + Vec3::Y * eye_h;
                if n.normalize_or_zero().y.abs() < 0.7
                    || eye.y > b.max.y
                    || (need_ceiling && rays.cast(eye, Vec3::Y, far).is_none())
                    || rays.within(eye, 2.0 * margin)
                    || rays.cast(eye, Vec3::NEG_Y, far).map(|h| h.0) < Some(eye_h * 0.99)
                {
                    continue;
                }
                let openness = horizontal_dirs()
                    .map(|d| rays.cast(eye, d, far).map(|h| h.0).unwrap_or(far))
                    .sum::<f32>()
                    / 16.0;
                out.push(Place {
                    cell: (ix, iz),
                    eye,
                    openness,
                });
            }
        }
    }
    out
}

/// Neighbour lists: places in adjacent cells (8-neighbourhood) at similar height joined by a
/// segment that keeps `margin`.
fn neighbours(rays: &TriangleScene, places: &[Place], eye_h: f32, margin: f32) -> Vec<Vec<usize>> {
    let mut by_cell: HashMap<(i32, i32), Vec<usize>> = HashMap::new();
    for (i, p) in places.iter().enumerate() {
        by_cell.entry(p.cell).or_default().push(i);
    }
    let mut adj = vec![Vec::new(); places.len()];
    for (i, p) in places.iter().enumerate() {
        for dz in -1..=1 {
            for dx in -1..=1 {
                let Some(js) = by_cell.get(&(p.cell.0 + dx, p.cell.1 + dz)) else {
                    continue;
                };
                for &j in js {
                    let q = &places[j];
                    if j != i
                        && (q.eye.y - p.eye.y).abs() < 0.5 * eye_h
                        && rays.segment_clear(p.eye, q.eye, margin)
                    {
                        adj[i].push(j);
                    }
                }
            }
        }
    }
    adj
}

/// Shortest paths from `start` (cost: length, more near walls via the openness), returning
/// each place's predecessor and distance.
fn dijkstra(places: &[Place], adj: &[Vec<usize>], start: usize) -> (Vec<usize>, Vec<f32>) {
    #[derive(PartialEq)]
    struct Item(f32, usize);
    impl Eq for Item {}
    impl PartialOrd for Item {
        fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
            Some(self.cmp(o))
        }
    }
    impl Ord for Item {
        fn cmp(&self, o: &Self) -> std::cmp::Ordering {
            o.0.total_cmp(&self.0).then(o.1.cmp(&self.1))
        }
    }
    let mut dist = vec![f32::INFINITY; places.len()];
    let mut prev = vec![usize::MAX; places.len()];
    let mut heap = BinaryHeap::new();
    dist[start] = 0.0;
    heap.push(Item(0.0, start));
    while let Some(Item(d, i)) = heap.pop() {
        if d > dist[i] {
            continue;
        }
        for &j in &adj[i] {
            let len = places[i].eye.distance(places[j].eye);
            let nd = d + len * (1.0 + 1.0 / places[j].openness.max(1e-3));
            if nd < dist[j] {
                dist[j] = nd;
                prev[j] = i;
                heap.push(Item(nd, j));
            }
        }
    }
    (prev, dist)
}

/// The tour's place indices: the most open place first, then greedily the nearest (by path)
/// of the other chosen open places, joined by shortest paths.
fn tour(places: &[Place], adj: &[Vec<usize>], params: &InteriorParams, spread: f32) -> Vec<usize> {
    let mut order: Vec<usize> = (0..places.len()).collect();
    order.sort_by(|&a, &b| {
        places[b]
            .openness
            .total_cmp(&places[a].openness)
            .then(a.cmp(&b))
    });
    let start = order[0];
    let (_, reach) = dijkstra(places, adj, start);
    let mut chosen = vec![start];
    for &i in &order {
        if chosen.len() >= params.waypoints.max(2) {
            break;
        }
        if reach[i].is_finite()
            && chosen
                .iter()
                .all(|&c| places[c].eye.distance(places[i].eye) >= spread)
        {
            chosen.push(i);
        }
    }
    let mut route = vec![start];
    let mut current = start;
    let mut left: Vec<usize> = chosen[1..].to_vec();
    while !left.is_empty() {
        let (prev, dist) = dijkstra(places, adj, current);
        let k = (0..left.len())
            .min_by(|&a, &b| dist[left[a]].total_cmp(&dist[left[b]]))
            .unwrap_or(0);
        let goal = left.remove(k);
        let mut leg = vec![goal];
        while let Some(&p) = leg.last().map(|&l| &prev[l]) {
            if p == usize::MAX || p == current {
                break;
            }
            leg.push(p);
        }
        leg.reverse();
        route.extend(leg);
        current = goal;
    }
    route
}

/// Computes the interior walk of `scene`; an error when no walkable place is found.
pub fn interior_path(scene: &Scene, params: &InteriorParams) -> Result<CameraPath, Error> {
    let none = || {
        Error::Input(format!(
            "scene \"{}\": no place for an interior walk (no floor with room to stand)",
            scene.name
        ))
    };
    let rays = TriangleScene::new(scene).ok_or_else(none)?;
    let e = rays.bounds.extent();
    let side = e.x.max(e.z).max(1e-3);
    let eye_h = params.eye_height.unwrap_or(1.7).min(0.4 * e.y.max(1e-3));
    // Places keep two margins of clearance, which must fit between the floor and the eye.
    let margin = params.margin.unwrap_or(0.01 * side).min(0.25 * eye_h);
    let cell = side / params.grid.max(4) as f32;
    // Under a roof where there is one (interiors), else anywhere (roofless rooms).
    let mut places = places(&rays, cell, (eye_h, margin), true);
    if places.is_empty() {
        places = self::places(&rays, cell, (eye_h, margin), false);
    }
    if places.is_empty() {
        return Err(none());
    }
    let adj = neighbours(&rays, &places, eye_h, margin);
    let route = tour(&places, &adj, params, 0.25 * side);
    let eyes: Vec<Vec3> = route.iter().map(|&i| places[i].eye).collect();
    Ok(path_through(&rays, &eyes, margin, cell))
}

/// Keys along `eyes` about every three cells, each looking ahead along the route; a
/// stretch whose spline would come closer than `margin` to geometry keeps every eye.
fn path_through(rays: &TriangleScene, eyes: &[Vec3], margin: f32, cell: f32) -> CameraPath {
    let mut keys: Vec<Vec3> = Vec::new();
    for &e in eyes {
        if keys.last().is_none_or(|l| l.distance(e) >= 2.5 * cell) || keys.len() == 1 {
            keys.push(e);
        }
    }
    if let (Some(&last), Some(&k)) = (eyes.last(), keys.last()) {
        if k != last {
            keys.push(last);
        }
    }
    let sparse = poses_of(&keys);
    let path = CameraPath {
        name: PATH_NAME.to_string(),
        keys: sparse,
    };
    let frames = path.natural_frames();
    let clear = (0..=frames).all(|f| !rays.within(path.pose_at(f as f32).eye, margin));
    if clear {
        return path;
    }
    CameraPath {
        name: PATH_NAME.to_string(),
        keys: poses_of(eyes),
    }
}

/// Poses through `eyes`, each looking towards the eyes after it (at its own height).
fn poses_of(eyes: &[Vec3]) -> Vec<CameraPose> {
    let n = eyes.len();
    (0..n)
        .map(|i| {
            let ahead = eyes[(i + 2).min(n - 1)] - eyes[i.saturating_sub(1)];
            let dir = Vec3::new(ahead.x, 0.0, ahead.z)
                .try_normalize()
                .unwrap_or(Vec3::NEG_Z);
            CameraPose {
                eye: eyes[i],
                target: eyes[i] + dir,
            }
        })
        .collect()
}

/// Makes the interior walk a glTF scene's first (default) path when the middle of its bounds
/// is enclosed; the orbit stays available as `default`. Nothing changes when no walk is found.
pub fn default_if_enclosed(scene: &mut Scene) {
    let enclosed = TriangleScene::new(scene).is_some_and(|r| is_enclosed(&r));
    if !enclosed {
        return;
    }
    match interior_path(scene, &InteriorParams::default()) {
        Ok(path) => scene.paths.insert(0, path),
        Err(e) => eprintln!("warning: {e}; the default path stays the orbit"),
    }
}
