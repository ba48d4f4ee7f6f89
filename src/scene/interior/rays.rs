//! The scene's world triangles in a BVH (obvhs) for the interior walk and the path check: ray
//! casts that say which side of a surface they hit, and distance queries.
//!
//! A ray hits the *front* of a triangle when it comes from the side its counter-clockwise
//! winding faces (glTF's front face); triangles of a `doubleSided` material are front from both
//! sides, and their hit normal is turned towards the ray, except those of a closed solid: an
//! object whose triangles close around a volume and face out of it is seen from outside only
//! (a point inside it is inside geometry), double-sided or not.

use std::time::Duration;

use glam::{Mat4, Vec3, Vec3A};
use obvhs::aabb::Aabb as BvhAabb;
use obvhs::bvh2::{builder::build_bvh2_from_tris, Bvh2};
use obvhs::ray::{Ray, RayHit};
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;

use crate::scene::gltf::DEFAULT_SUN;
use crate::scene::{Aabb, Object, Scene};

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
    /// The colour the built-in renderer gives the side that was hit when it is one flat colour
    /// (see [`flat_colour`]), `None` when the colour varies over the triangle (a texture,
    /// vertex colours or normals that differ between its corners).
    pub colour: Option<[u8; 3]>,
    /// The triangle hit (an index of this scene's own order).
    pub triangle: u32,
}

/// World triangles, whether each is double-sided, and their flat colours (empty when not
/// gathered), in the scene's order.
type Gathered = (Vec<[Vec3; 3]>, Vec<bool>, Vec<Option<[[u8; 3]; 2]>>);

/// Triangles above which the ray scene's BVH is built for speed rather than quality.
const LARGE_SCENE_TRIANGLES: usize = 4_000_000;

/// World triangles with a BVH for ray casts and distance queries.
pub struct TriangleScene {
    bvh: Bvh2,
    triangles: Vec<Triangle>,
    /// Per triangle (in `triangles`' order): whether its material is double-sided.
    two_sided: Vec<bool>,
    /// Per triangle (in `triangles`' order): the colours of its front and back sides when the
    /// built-in renderer draws each in one colour, `None` when its colour varies over it.
    /// Empty for a [`shape`](Self::shape) scene.
    colours: Vec<Option<[[u8; 3]; 2]>>,
    /// World bounds.
    pub bounds: Aabb,
}

impl TriangleScene {
    /// The scene's world-space triangles (those of double-sided materials marked so, unless
    /// their object is a [`closed_solid`]); `None` when it has none with finite corners.
    pub fn new(scene: &Scene) -> Option<TriangleScene> {
        TriangleScene::of_objects(scene, |_| true)
    }

    /// As [`new`](Self::new), with the triangles of the objects whose bounds meet `region`
    /// only.
    pub fn near(scene: &Scene, region: &Aabb) -> Option<TriangleScene> {
        TriangleScene::of_objects(scene, |o| o.bounds.overlaps(region))
    }

    /// The scene's shape only, for the path check's few thousand rays: as [`new`](Self::new)
    /// (or [`near`](Self::near) `region`), without the flat colours (hits have none, so
    /// [`one_colour_share`](Self::one_colour_share) counts only the sky) and with the quickest
    /// BVH build. Several times quicker to build.
    pub fn shape(scene: &Scene, region: Option<&Aabb>) -> Option<TriangleScene> {
        let keep = |o: &Object| region.is_none_or(|r| o.bounds.overlaps(r));
        let (triangles, two_sided, _) = TriangleScene::gather(scene, keep, false);
        TriangleScene::build_with(
            &triangles,
            &two_sided,
            None,
            BvhBuildParams::fastest_build(),
        )
    }

    fn of_objects(scene: &Scene, keep: impl Fn(&Object) -> bool) -> Option<TriangleScene> {
        let (triangles, two_sided, sides) = TriangleScene::gather(scene, keep, true);
        TriangleScene::build(&triangles, &two_sided, &sides)
    }

    /// The world triangles of the objects `keep` accepts, which of them are double-sided, and
    /// (when `colours`) their flat colours.
    fn gather(scene: &Scene, keep: impl Fn(&Object) -> bool, colours: bool) -> Gathered {
        let mut triangles = Vec::new();
        let mut two_sided = Vec::new();
        let mut sides = Vec::new();
        for (i, o) in scene.objects.iter().enumerate() {
            if !keep(o) {
                continue;
            }
            // A textured object is never one flat colour.
            let textured = scene
                .object_material(i)
                .is_some_and(|m| m.base_color_texture.is_some());
            let normal_matrix = (colours && !textured).then(|| o.transform.inverse().transpose());
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
                    if colours {
                        sides.push(normal_matrix.and_then(|m| flat_sides(scene, o, m, t)));
                    }
                }
            }
            let both = scene.object_material(i).is_some_and(|m| m.double_sided)
                && !closed_solid(&triangles[start..]);
            two_sided.resize(triangles.len(), both);
        }
        (triangles, two_sided, sides)
    }

    /// A scene of `triangles` (counter-clockwise fronts), `two_sided[i]` marking double-sided
    /// ones (missing entries: single-sided), all of one grey lit as glTF scenes are (from
    /// (0.4, 1, 0.3)); `None` when none has finite corners.
    pub fn from_triangles(triangles: &[[Vec3; 3]], two_sided: &[bool]) -> Option<TriangleScene> {
        TriangleScene::build(triangles, two_sided, &[])
    }

    /// A scene of `triangles` and their sides (as [`from_triangles`](Self::from_triangles))
    /// with the colours of their front and back sides where each is one flat colour (missing
    /// entries: grey by the face normal, lit as glTF scenes are).
    pub fn build(
        triangles: &[[Vec3; 3]],
        two_sided: &[bool],
        colours: &[Option<[[u8; 3]; 2]>],
    ) -> Option<TriangleScene> {
        // A large scene (a scaled-up city) is only path-checked, a few thousand rays: a quick
        // build without reinsertion is several times faster there and ample for that.
        let params = if triangles.len() > LARGE_SCENE_TRIANGLES {
            BvhBuildParams::fastest_build()
        } else {
            BvhBuildParams::fast_build()
        };
        TriangleScene::build_with(triangles, two_sided, Some(colours), params)
    }

    /// [`build`](Self::build) with the BVH built by `params`; `colours` `None`: no colours
    /// at all (hits have none).
    fn build_with(
        triangles: &[[Vec3; 3]],
        two_sided: &[bool],
        colours: Option<&[Option<[[u8; 3]; 2]>]>,
        params: BvhBuildParams,
    ) -> Option<TriangleScene> {
        let mut bounds = Aabb::EMPTY;
        let mut tris = Vec::new();
        let mut sides = Vec::new();
        let mut flat = Vec::new();
        let sun = DEFAULT_SUN.normalize();
        let grey = |n: Vec3| flat_colour(Vec3::splat(0.8), n, sun);
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
            if let Some(colours) = colours {
                flat.push(colours.get(i).copied().unwrap_or_else(|| {
                    let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero();
                    Some([grey(n), grey(-n)])
                }));
            }
        }
        if tris.is_empty() {
            return None;
        }
        let mut time = Duration::ZERO;
        let bvh = build_bvh2_from_tris(&tris, params, &mut time);
        let order = &bvh.primitive_indices;
        let triangles = order.iter().map(|&i| tris[i as usize]).collect();
        drop(tris);
        let two_sided = order.iter().map(|&i| sides[i as usize]).collect();
        drop(sides);
        let colours = if flat.is_empty() {
            Vec::new()
        } else {
            order.iter().map(|&i| flat[i as usize]).collect()
        };
        Some(TriangleScene {
            bvh,
            triangles,
            two_sided,
            colours,
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

    /// The closest hit along a unit `dir` up to `t_max`, with the side it hit; none for a ray
    /// that is not finite.
    pub fn hit(&self, origin: Vec3, dir: Vec3, t_max: f32) -> Option<Hit> {
        if !(origin.is_finite() && dir.is_finite()) || t_max.is_nan() {
            return None;
        }
        let ray = Ray::new(origin.into(), dir.into(), 0.0, t_max);
        let mut hit = RayHit::none();
        if !self
            .bvh
            .ray_traverse(ray, &mut hit, |r, id| self.triangles[id].intersect(r))
        {
            return None;
        }
        Some(self.side(hit.primitive_id as usize, dir, hit.t))
    }

    /// The hit on triangle `id` at distance `t` along the unit `dir`: the side it meets, whether
    /// that side is meant to be seen, and its flat colour.
    fn side(&self, id: usize, dir: Vec3, t: f32) -> Hit {
        let n = Vec3::from(self.triangles[id].compute_normal());
        let facing = n.dot(dir) < 0.0;
        let front = facing || self.two_sided[id];
        Hit {
            t,
            normal: if facing { n } else { -n },
            front,
            colour: self
                .colours
                .get(id)
                .copied()
                .flatten()
                .filter(|_| front)
                .map(|c| c[usize::from(!facing)]),
            triangle: id as u32,
        }
    }

    /// The colour of a second, coplanar side that `hit` (along the unit `dir` from `origin`)
    /// shares its distance with, when it differs: which of two coincident surfaces the
    /// renderer shows depends on draw order and depth precision, so both count.
    fn coplanar_colour(&self, origin: Vec3, dir: Vec3, hit: &Hit) -> Option<[u8; 3]> {
        let eps = 1e-4 * hit.t.max(1.0);
        let ray = Ray::new(origin.into(), dir.into(), hit.t - eps, hit.t + eps);
        let mut other = RayHit::none();
        let first = hit.triangle as usize;
        let found = self.bvh.ray_traverse(ray, &mut other, |r, id| {
            if id == first {
                f32::INFINITY
            } else {
                self.triangles[id].intersect(r)
            }
        });
        let id = other.primitive_id as usize;
        if !found || id == first {
            return None;
        }
        self.side(id, dir, other.t)
            .colour
            .filter(|&c| Some(c) != hit.colour)
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

/// The colours of the front and the back of triangle `t` (indices relative to the object's
/// vertex offset) of the untextured object `o`, whose normals `normal_matrix` takes to world
/// space, when the built-in renderer draws each side in one colour: the same colour at its
/// three corners from their vertex colours and normals (see [`flat_colour`]).
fn flat_sides(scene: &Scene, o: &Object, normal_matrix: Mat4, t: &[u32]) -> Option<[[u8; 3]; 2]> {
    let mut sides: Option<[[u8; 3]; 2]> = None;
    for &i in t {
        let at = o.vertex_offset.saturating_add(i) as usize;
        let mut base = o.color.truncate();
        if !scene.attributes.is_empty() {
            let c = scene.attributes.get(at)?.color;
            base *= Vec3::new(c[0].into(), c[1].into(), c[2].into()) / 255.0;
        }
        let n = normal_matrix
            .transform_vector3(Vec3::from_array(scene.vertices.get(at)?.normal))
            .try_normalize()?;
        let corner = [
            flat_colour(base, n, scene.sun_dir),
            flat_colour(base, -n, scene.sun_dir),
        ];
        if sides.is_some_and(|s| s != corner) {
            return None;
        }
        sides = Some(corner);
    }
    sides
}

/// The 8-bit colour the built-in renderer's forward pass (`shaders/scene.frag`,
/// `scene_mat.frag`) gives a flat `base` colour on a side with unit `normal`: Lambert from the
/// light towards `sun` plus a sky term, gamma 2.2.
pub fn flat_colour(base: Vec3, normal: Vec3, sun: Vec3) -> [u8; 3] {
    let lambert = normal.dot(sun).max(0.0);
    let sky = 0.5 + 0.5 * normal.y;
    let c = base * (0.75 * lambert + 0.25 * sky + 0.05);
    c.clamp(Vec3::ZERO, Vec3::ONE)
        .powf(1.0 / 2.2)
        .to_array()
        .map(|x| (x * 255.0).round() as u8)
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

    /// Share of the rays from `p` along `dirs` (up to `far`) that see the most common colour:
    /// the sky (rays that escape), or one flat colour of the built-in renderer's (see
    /// [`Hit::colour`]; a ray whose hit has a coplanar twin of another colour counts for both).
    pub fn one_colour_share(&self, p: Vec3, dirs: &[Vec3], far: f32) -> f32 {
        self.one_colour_and_back(p, dirs, far).0
    }

    /// [`TriangleScene::one_colour_share`] and the share of the rays that hit a back face,
    /// from one cast of the rays.
    pub fn one_colour_and_back(&self, p: Vec3, dirs: &[Vec3], far: f32) -> (f32, f32) {
        let mut colours: std::collections::HashMap<[u8; 3], usize> = Default::default();
        let (mut escaped, mut back) = (0, 0);
        for &d in dirs {
            match self.hit(p, d, far) {
                None => escaped += 1,
                Some(h) if h.front => {
                    let second = self.coplanar_colour(p, d, &h);
                    for c in h.colour.into_iter().chain(second) {
                        *colours.entry(c).or_default() += 1;
                    }
                }
                Some(_) => back += 1,
            }
        }
        let most = colours.into_values().max().unwrap_or(0).max(escaped);
        let rays = dirs.len().max(1) as f32;
        (most as f32 / rays, back as f32 / rays)
    }
}
