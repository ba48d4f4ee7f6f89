//! CPU ray casting against the static scene: the GI places VPLs and tests light-to-VPL
//! visibility with it, the PVS build samples visibility with it. Wraps an obvhs `Bvh2` built over
//! world-space triangles, each carrying one diffuse albedo.

use std::time::Duration;

use glam::{Vec3, Vec3A};

use super::mask::TriangleMasks;
use obvhs::{
    bvh2::{builder::build_bvh2_from_tris, Bvh2},
    ray::{Ray, RayHit},
    triangle::Triangle,
    BvhBuildParams,
};

/// Relative part of the epsilon used by [`RayScene::occluded`] at both ends.
const OCCLUSION_EPS_REL: f32 = 1e-4;
/// Absolute part of the epsilon used by [`RayScene::occluded`] at both ends.
const OCCLUSION_EPS_ABS: f32 = 1e-5;

/// Closest intersection of a ray with the scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Ray parameter of the hit (distance when the direction is unit length).
    pub t: f32,
    /// World-space hit position.
    pub position: Vec3,
    /// Geometric unit normal of the hit triangle, flipped to face against the ray direction.
    pub normal: Vec3,
    /// Whether the ray met the triangle's front (counter-clockwise) side; a ray from inside a
    /// closed solid meets back sides.
    pub front: bool,
    /// Diffuse albedo of the hit triangle.
    pub albedo: Vec3,
    /// Index of the hit triangle in the list given to [`RayScene::new`].
    pub triangle: u32,
}

/// A static triangle scene with a BVH for closest-hit and occlusion queries.
pub struct RayScene {
    /// `None` for an empty scene.
    bvh: Option<Bvh2>,
    /// Triangles reordered to BVH primitive order.
    triangles: Vec<Triangle>,
    /// Original triangle index of each reordered triangle (a boxed slice: `RayScene` stays
    /// as small as it was before the movers' field).
    original: Box<[u32]>,
    /// Albedo per original triangle index (a boxed slice, as `original`: `RayScene` stays as
    /// small as it was before the masks' field).
    albedo: Box<[Vec3]>,
    /// Moving objects' triangles at their current places (see [`RayScene::set_movers`]),
    /// rebuilt when they move; their hits' triangle indices follow the static ones.
    movers: Option<Box<RayScene>>,
    /// Alpha masks by original triangle index: rays pass through masked-out texels (see
    /// [`RayScene::with_masks`]); `None` for scenes without masks.
    masks: Option<Box<TriangleMasks>>,
}

impl RayScene {
    /// Builds the scene from world-space triangles and one albedo per triangle.
    ///
    /// Missing albedos (if `albedo` is shorter than `triangles`) default to 0.5 grey.
    pub fn new(triangles: Vec<[Vec3; 3]>, albedo: Vec<Vec3>) -> Self {
        Self::built(triangles, albedo, BvhBuildParams::fast_build())
    }

    /// [`RayScene::new`] with the hierarchy built by `params`.
    fn built(triangles: Vec<[Vec3; 3]>, mut albedo: Vec<Vec3>, params: BvhBuildParams) -> Self {
        albedo.resize(triangles.len(), Vec3::splat(0.5));
        if triangles.is_empty() {
            return Self {
                bvh: None,
                triangles: Vec::new(),
                original: Box::default(),
                albedo: albedo.into(),
                movers: None,
                masks: None,
            };
        }
        let tris: Vec<Triangle> = triangles
            .iter()
            .map(|t| Triangle {
                v0: t[0].into(),
                v1: t[1].into(),
                v2: t[2].into(),
            })
            .collect();
        let mut build_time = Duration::ZERO;
        let bvh = build_bvh2_from_tris(&tris, params, &mut build_time);
        let original: Box<[u32]> = bvh.primitive_indices.clone().into();
        let reordered = original.iter().map(|&i| tris[i as usize]).collect();
        Self {
            bvh: Some(bvh),
            triangles: reordered,
            original,
            albedo: albedo.into(),
            movers: None,
            masks: None,
        }
    }

    /// The same scene whose rays pass through the masked-out texels of `masks` (parallel to
    /// the triangles given to [`RayScene::new`]): a candidate hit is tested against its
    /// triangle's mask before it counts. Scenes without masks never pay for the test.
    pub fn with_masks(mut self, masks: TriangleMasks) -> RayScene {
        self.masks = masks.any().then(|| Box::new(masks));
        self
    }

    /// The hit distance of reordered triangle `id` for a masked scene: infinity when the ray
    /// meets it on a masked-out texel.
    #[inline(always)]
    fn masked_hit(&self, masks: &TriangleMasks, id: usize, ray: &Ray) -> f32 {
        let (t, a, b) = intersect_triangle_uv(&self.triangles[id], ray);
        if t.is_finite() && !masks.keeps(self.original[id] as usize, a, b) {
            f32::INFINITY
        } else {
            t
        }
    }

    /// Replaces the moving objects' triangles (world space, one albedo each): rays see them
    /// beside the static triangles, and their hits' triangle indices are numbered after the
    /// static ones. A small separate hierarchy, rebuilt here (quickly, without the reinsertion
    /// pass: it is rebuilt whenever a mover moves), so the static one is kept.
    pub fn set_movers(&mut self, triangles: Vec<[Vec3; 3]>, albedo: Vec<Vec3>) {
        self.movers = (!triangles.is_empty()).then(|| {
            Box::new(RayScene::built(
                triangles,
                albedo,
                BvhBuildParams::very_fast_build(),
            ))
        });
    }

    /// Number of triangles in the scene.
    pub fn triangle_count(&self) -> usize {
        self.albedo.len()
    }

    /// Whether `p` lies inside a closed solid: most of 14 rays from it (the axes and the
    /// diagonals) meet the back sides of triangles within `reach`. A point in a room meets its
    /// walls' front sides, one in the open escapes.
    pub fn inside_solid(&self, p: Vec3, reach: f32) -> bool {
        let mut dirs: Vec<Vec3> = [Vec3::X, Vec3::Y, Vec3::Z]
            .into_iter()
            .flat_map(|a| [a, -a])
            .collect();
        for x in [-1.0, 1.0] {
            for y in [-1.0, 1.0] {
                for z in [-1.0, 1.0] {
                    dirs.push(Vec3::new(x, y, z).normalize());
                }
            }
        }
        let backs = dirs
            .iter()
            .filter(|&&d| self.intersect(p, d, reach).is_some_and(|h| !h.front))
            .count();
        2 * backs > dirs.len()
    }

    /// Closest hit along `origin + t * dir` for `t` in `(0, t_max]`; `None` on a miss.
    pub fn intersect(&self, origin: Vec3, dir: Vec3, t_max: f32) -> Option<Hit> {
        let own = self.intersect_static(origin, dir, t_max);
        let Some(movers) = &self.movers else {
            return own;
        };
        let limit = own.map_or(t_max, |h| h.t);
        match movers.intersect_static(origin, dir, limit) {
            Some(hit) => Some(Hit {
                triangle: hit.triangle + self.albedo.len() as u32,
                ..hit
            }),
            None => own,
        }
    }

    /// [`RayScene::intersect`] against the static triangles only.
    fn intersect_static(&self, origin: Vec3, dir: Vec3, t_max: f32) -> Option<Hit> {
        let bvh = self.bvh.as_ref()?;
        if !(origin.is_finite() && dir.is_finite()) || dir.length_squared() == 0.0 {
            return None;
        }
        let ray = Ray::new(Vec3A::from(origin), Vec3A::from(dir), 0.0, t_max);
        let mut hit = RayHit::none();
        let found = match &self.masks {
            None => bvh.ray_traverse(ray, &mut hit, |r, id| {
                intersect_triangle(&self.triangles[id], r)
            }),
            Some(m) => bvh.ray_traverse(ray, &mut hit, |r, id| self.masked_hit(m, id, r)),
        };
        if !found {
            return None;
        }
        let tri = &self.triangles[hit.primitive_id as usize];
        let original = self.original[hit.primitive_id as usize];
        let mut normal = Vec3::from(tri.compute_normal());
        let front = normal.dot(dir) < 0.0;
        if normal == Vec3::ZERO {
            normal = -dir.normalize();
        } else if normal.dot(dir) > 0.0 {
            normal = -normal;
        }
        Some(Hit {
            t: hit.t,
            position: origin + dir * hit.t,
            normal,
            front,
            albedo: self.albedo[original as usize],
            triangle: original,
        })
    }

    /// True when any triangle lies strictly between `from` and `to`, ignoring a
    /// small (relative) epsilon at both ends so surfaces at the endpoints do not count.
    pub fn occluded(&self, from: Vec3, to: Vec3) -> bool {
        self.occluded_static(from, to) || self.movers.as_ref().is_some_and(|m| m.occluded(from, to))
    }

    /// [`RayScene::occluded`] against the static triangles only.
    fn occluded_static(&self, from: Vec3, to: Vec3) -> bool {
        let Some(bvh) = self.bvh.as_ref() else {
            return false;
        };
        let delta = to - from;
        let dist = delta.length();
        let eps = OCCLUSION_EPS_REL * dist + OCCLUSION_EPS_ABS;
        if !dist.is_finite() || dist <= 2.0 * eps {
            return false;
        }
        let dir = delta / dist;
        let ray = Ray::new(Vec3A::from(from), Vec3A::from(dir), eps, dist - eps);
        match &self.masks {
            None => !bvh.ray_traverse_miss(ray, |r, id| intersect_triangle(&self.triangles[id], r)),
            Some(m) => !bvh.ray_traverse_miss(ray, |r, id| self.masked_hit(m, id, r)),
        }
    }
}

/// Möller–Trumbore ray/triangle test with a tiny barycentric tolerance so rays
/// through shared edges (e.g. a quad's diagonal) do not leak. Returns the hit `t`
/// within `[ray.tmin, ray.tmax]`, or infinity on a miss.
#[inline(always)]
fn intersect_triangle(tri: &Triangle, ray: &Ray) -> f32 {
    intersect_triangle_uv(tri, ray).0
}

/// [`intersect_triangle`] with the hit's barycentric weights of corners 1 and 2.
#[inline(always)]
fn intersect_triangle_uv(tri: &Triangle, ray: &Ray) -> (f32, f32, f32) {
    const BARY_EPS: f32 = 1e-6;
    let e1 = tri.v1 - tri.v0;
    let e2 = tri.v2 - tri.v0;
    let p = ray.direction.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 || !det.is_finite() {
        return (f32::INFINITY, 0.0, 0.0);
    }
    let inv_det = 1.0 / det;
    let s = ray.origin - tri.v0;
    let u = s.dot(p) * inv_det;
    let q = s.cross(e1);
    let v = ray.direction.dot(q) * inv_det;
    if u < -BARY_EPS || v < -BARY_EPS || u + v > 1.0 + BARY_EPS {
        return (f32::INFINITY, u, v);
    }
    let t = e2.dot(q) * inv_det;
    if t >= ray.tmin && t <= ray.tmax {
        (t, u, v)
    } else {
        (f32::INFINITY, u, v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad(c: Vec3, u: Vec3, v: Vec3) -> [[Vec3; 3]; 2] {
        let (a, b, cc, d) = (c - u - v, c + u - v, c + u + v, c - u + v);
        [[a, b, cc], [a, cc, d]]
    }

    fn two_planes() -> RayScene {
        let mut tris = Vec::new();
        tris.extend(quad(Vec3::new(0.0, 0.0, 1.0), Vec3::X, Vec3::Y));
        tris.extend(quad(Vec3::new(0.0, 0.0, 2.0), Vec3::X, Vec3::Y));
        let albedo = vec![Vec3::X, Vec3::X, Vec3::Y, Vec3::Y];
        RayScene::new(tris, albedo)
    }

    #[test]
    fn nearest_of_two_parallel_quads() {
        let scene = two_planes();
        let hit = scene.intersect(Vec3::ZERO, Vec3::Z, f32::INFINITY).unwrap();
        assert!((hit.t - 1.0).abs() < 1e-5);
        assert_eq!(hit.albedo, Vec3::X);
        assert!(hit.triangle < 2);
        assert!((hit.normal - Vec3::NEG_Z).length() < 1e-5);
        // From behind both planes the far one (first along the ray) is hit.
        let hit = scene
            .intersect(Vec3::new(0.2, 0.1, 3.0), Vec3::NEG_Z, f32::INFINITY)
            .unwrap();
        assert!((hit.t - 1.0).abs() < 1e-5);
        assert_eq!(hit.albedo, Vec3::Y);
        assert!((hit.normal - Vec3::Z).length() < 1e-5);
        assert!(scene.intersect(Vec3::ZERO, Vec3::Z, 0.5).is_none());
        assert!(scene.intersect(Vec3::ZERO, Vec3::NEG_Z, 10.0).is_none());
    }

    #[test]
    fn occlusion() {
        let scene = two_planes();
        assert!(scene.occluded(Vec3::ZERO, Vec3::new(0.0, 0.0, 1.5)));
        assert!(!scene.occluded(Vec3::ZERO, Vec3::new(0.0, 0.0, 0.9)));
        // Endpoint exactly on a surface is not occluded by that surface.
        assert!(!scene.occluded(Vec3::ZERO, Vec3::new(0.3, 0.2, 1.0)));
        assert!(!scene.occluded(Vec3::new(0.0, 0.0, 1.0), Vec3::new(0.0, 0.0, 2.0)));
        assert!(!scene.occluded(Vec3::new(5.0, 0.0, 0.0), Vec3::new(5.0, 0.0, 3.0)));
    }

    #[test]
    fn movers_block_and_are_hit() {
        let mut scene = two_planes();
        let mover = quad(Vec3::new(0.0, 0.0, 0.5), Vec3::X, Vec3::Y).to_vec();
        scene.set_movers(mover, vec![Vec3::Z; 2]);
        let hit = scene.intersect(Vec3::ZERO, Vec3::Z, f32::INFINITY).unwrap();
        assert!((hit.t - 0.5).abs() < 1e-5);
        assert_eq!(hit.albedo, Vec3::Z);
        assert!(hit.triangle >= 4);
        assert!(scene.occluded(Vec3::ZERO, Vec3::new(0.0, 0.0, 0.9)));
        // Moved out of the way: the static planes again.
        scene.set_movers(
            quad(Vec3::new(5.0, 0.0, 0.5), Vec3::X, Vec3::Y).to_vec(),
            vec![Vec3::Z; 2],
        );
        assert!(!scene.occluded(Vec3::ZERO, Vec3::new(0.0, 0.0, 0.9)));
        let hit = scene.intersect(Vec3::ZERO, Vec3::Z, f32::INFINITY).unwrap();
        assert!((hit.t - 1.0).abs() < 1e-5 && hit.triangle < 4);
    }

    #[test]
    fn empty_scene() {
        let scene = RayScene::new(Vec::new(), Vec::new());
        assert!(scene
            .intersect(Vec3::ZERO, Vec3::Z, f32::INFINITY)
            .is_none());
        assert!(!scene.occluded(Vec3::ZERO, Vec3::ONE));
        assert_eq!(scene.triangle_count(), 0);
    }
}
