//! The scene's world triangles in a BVH (obvhs) for the interior walk and the path check: ray
//! casts that say which side of a surface they hit, and distance queries.
//!
//! A ray hits the *front* of a triangle when it comes from the side its counter-clockwise
//! winding faces (glTF's front face); triangles of a `doubleSided` material are front from both
//! sides, and their hit normal is turned towards the ray, except those of a closed solid: an
//! object whose triangles close around a volume and face out of it is seen from outside only
//! (a point inside it is inside geometry), double-sided or not.

use std::time::Duration;

use glam::{Vec3, Vec3A};
use obvhs::aabb::Aabb as BvhAabb;
use obvhs::bvh2::{builder::build_bvh2_from_tris, Bvh2};
use obvhs::ray::{Ray, RayHit};
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;

use crate::scene::{Aabb, Scene};

/// One ray hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance along the (unit) ray.
    pub t: f32,
    /// Unit normal of the side that was hit: the front normal for a front hit, the back normal
    /// (facing the ray) for a back hit.
    pub normal: Vec3,
    /// Whether the ray hit a side that is meant to be seen (the front, or either side of a
    /// double-sided triangle).
    pub front: bool,
}

/// World triangles with a BVH for ray casts and distance queries.
pub struct TriangleScene {
    bvh: Bvh2,
    triangles: Vec<Triangle>,
    /// Per triangle (in `triangles`' order): whether its material is double-sided.
    two_sided: Vec<bool>,
    /// World bounds.
    pub bounds: Aabb,
}

impl TriangleScene {
    /// The scene's world-space triangles (those of double-sided materials marked so, unless
    /// their object is a [`closed_solid`]); `None` when it has none with finite corners.
    pub fn new(scene: &Scene) -> Option<TriangleScene> {
        let mut triangles = Vec::new();
        let mut two_sided = Vec::new();
        for (i, o) in scene.objects.iter().enumerate() {
            let first = o.first_index as usize;
            let Some(idx) = scene
                .indices
                .get(first..first.saturating_add(o.index_count as usize))
            else {
                continue;
            };
            let start = triangles.len();
            for t in idx.chunks_exact(3) {
                let corner = |i: u32| {
                    let v = scene
                        .vertices
                        .get(o.vertex_offset.saturating_add(i) as usize)?;
                    Some(o.transform.transform_point3(Vec3::from_array(v.position)))
                };
                if let (Some(a), Some(b), Some(c)) = (corner(t[0]), corner(t[1]), corner(t[2])) {
                    triangles.push([a, b, c]);
                }
            }
            let both = scene.object_material(i).is_some_and(|m| m.double_sided)
                && !closed_solid(&triangles[start..]);
            two_sided.resize(triangles.len(), both);
        }
        TriangleScene::from_triangles(&triangles, &two_sided)
    }

    /// A scene of `triangles` (counter-clockwise fronts), `two_sided[i]` marking double-sided
    /// ones (missing entries: single-sided); `None` when none has finite corners.
    pub fn from_triangles(triangles: &[[Vec3; 3]], two_sided: &[bool]) -> Option<TriangleScene> {
        let mut bounds = Aabb::EMPTY;
        let mut tris = Vec::new();
        let mut sides = Vec::new();
        for (i, t) in triangles.iter().enumerate() {
            if !t.iter().all(|p| p.is_finite()) {
                continue;
            }
            t.iter().for_each(|&p| bounds.grow(p));
            tris.push(Triangle {
                v0: t[0].into(),
                v1: t[1].into(),
                v2: t[2].into(),
            });
            sides.push(two_sided.get(i).copied().unwrap_or(false));
        }
        if tris.is_empty() {
            return None;
        }
        let mut time = Duration::ZERO;
        let bvh = build_bvh2_from_tris(&tris, BvhBuildParams::fast_build(), &mut time);
        let (triangles, two_sided) = bvh
            .primitive_indices
            .iter()
            .map(|&i| (tris[i as usize], sides[i as usize]))
            .unzip();
        Some(TriangleScene {
            bvh,
            triangles,
            two_sided,
            bounds,
        })
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.triangles.len()
    }

    /// Whether there are no triangles (never true for a built scene).
    pub fn is_empty(&self) -> bool {
        self.triangles.is_empty()
    }

    /// The closest hit along a unit `dir` up to `t_max`, with the side it hit.
    pub fn hit(&self, origin: Vec3, dir: Vec3, t_max: f32) -> Option<Hit> {
        let ray = Ray::new(origin.into(), dir.into(), 0.0, t_max);
        let mut hit = RayHit::none();
        if !self
            .bvh
            .ray_traverse(ray, &mut hit, |r, id| self.triangles[id].intersect(r))
        {
            return None;
        }
        let id = hit.primitive_id as usize;
        let n = Vec3::from(self.triangles[id].compute_normal());
        let facing = n.dot(dir) < 0.0;
        Some(Hit {
            t: hit.t,
            normal: if facing { n } else { -n },
            front: facing || self.two_sided[id],
        })
    }

    /// Distance to the closest hit along a unit `dir` (up to `t_max`) and the triangle's front
    /// normal, whichever side was hit.
    pub fn cast(&self, origin: Vec3, dir: Vec3, t_max: f32) -> Option<(f32, Vec3)> {
        self.hit(origin, dir, t_max).map(|h| {
            let front = if h.normal.dot(dir) < 0.0 {
                h.normal
            } else {
                -h.normal
            };
            (h.t, front)
        })
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
        let steps = ((b - a).length() / (0.5 * r)).ceil().clamp(1.0, 4096.0) as usize;
        (0..=steps).all(|i| !self.within(a.lerp(b, i as f32 / steps as f32), r))
    }
}

/// Whether `tris` close around a volume and face out of it: every edge (corners matched by
/// position) is shared by an even number of triangles and the signed volume is positive, a
/// thousandth of the bounding box's at least. Such an object is a solid (a wall, a pillar, a
/// prop): its inside is never a place, even when its material is double-sided.
pub fn closed_solid(tris: &[[Vec3; 3]]) -> bool {
    let mut bounds = Aabb::EMPTY;
    tris.iter().flatten().for_each(|&p| bounds.grow(p));
    let e = bounds.extent();
    if tris.len() < 4 || !e.is_finite() || e.min_element() <= 0.0 {
        return false;
    }
    let q = 1e-5 * e.max_element();
    let key = |p: Vec3| ((p - bounds.min) / q).round().as_ivec3().to_array();
    let mut edges: std::collections::HashMap<_, u32> = std::collections::HashMap::new();
    let mut volume = 0.0f64;
    for t in tris {
        let k = t.map(key);
        for (a, b) in [(k[0], k[1]), (k[1], k[2]), (k[2], k[0])] {
            if a != b {
                *edges
                    .entry(if a < b { (a, b) } else { (b, a) })
                    .or_default() += 1;
            }
        }
        let [a, b, c] = t.map(|p| (p - bounds.center()).as_dvec3());
        volume += a.dot(b.cross(c)) / 6.0;
    }
    edges.values().all(|n| n % 2 == 0)
        && volume > 1e-3 * f64::from(e.x) * f64::from(e.y) * f64::from(e.z)
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

/// `n` unit directions spread evenly over the sphere (a Fibonacci lattice), deterministic.
pub fn sphere_dirs(n: usize) -> Vec<Vec3> {
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    (0..n)
        .map(|i| {
            let y = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
            let r = (1.0 - y * y).max(0.0).sqrt();
            let a = golden * i as f32;
            Vec3::new(r * a.cos(), y, r * a.sin())
        })
        .collect()
}

/// `n` unit directions around the vertical axis, level or slightly up: azimuths evenly spaced,
/// elevations alternating between 2° and 12° (what a person looking around at eye height sees
/// of the walls, even where the level has no ceiling). Deterministic.
pub fn ring_dirs(n: usize) -> Vec<Vec3> {
    (0..n)
        .map(|i| {
            let a = std::f32::consts::TAU * i as f32 / n.max(1) as f32;
            let e = if i % 2 == 0 { 2f32 } else { 12f32 }.to_radians();
            Vec3::new(e.cos() * a.cos(), e.sin(), e.cos() * a.sin())
        })
        .collect()
}

/// What rays in many directions from one point see.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Probe {
    /// Rays cast.
    pub rays: usize,
    /// Rays that left the model without hitting anything (sky).
    pub escaped: usize,
    /// Rays whose first hit is a back face.
    pub back: usize,
    /// Mean distance of the rays that hit a front face (0 when none did).
    pub mean_front_distance: f32,
    /// Distance of the nearest hit, front or back (infinite when every ray escaped).
    pub nearest: f32,
}

impl Probe {
    /// Share of rays that escaped.
    pub fn escaped_share(&self) -> f32 {
        self.escaped as f32 / self.rays.max(1) as f32
    }

    /// Share of rays that hit a back face.
    pub fn back_share(&self) -> f32 {
        self.back as f32 / self.rays.max(1) as f32
    }
}

impl TriangleScene {
    /// Casts a ray from `p` along each of `dirs` (up to `far`) and counts what they see.
    pub fn probe(&self, p: Vec3, dirs: &[Vec3], far: f32) -> Probe {
        let mut probe = Probe {
            rays: dirs.len(),
            nearest: f32::INFINITY,
            ..Probe::default()
        };
        let (mut sum, mut fronts) = (0.0, 0usize);
        for &d in dirs {
            let hit = self.hit(p, d, far);
            if let Some(h) = hit {
                probe.nearest = probe.nearest.min(h.t);
            }
            match hit {
                None => probe.escaped += 1,
                Some(h) if !h.front => probe.back += 1,
                Some(h) => {
                    sum += h.t;
                    fronts += 1;
                }
            }
        }
        if fronts > 0 {
            probe.mean_front_distance = sum / fronts as f32;
        }
        probe
    }
}
