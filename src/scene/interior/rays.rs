//! The scene's world triangles in a BVH (obvhs) for the interior walk and the path check: ray
//! casts that say which side of a surface they hit, and distance queries.
//!
//! A ray hits the *front* of a triangle when it comes from the side its counter-clockwise
//! winding faces (glTF's front face); triangles of a `doubleSided` material are front from both
//! sides, and their hit normal is turned towards the ray, except those of a closed solid: an
//! object whose triangles close around a volume and face out of it is seen from outside only
//! (a point inside it is inside geometry), double-sided or not.

use glam::{Mat4, Vec3, Vec3A};
use obvhs::aabb::Aabb as BvhAabb;
use obvhs::bvh2::Bvh2;
use obvhs::ray::{Ray, RayHit};
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;

use crate::scene::{Aabb, Object, Scene};

mod build;

use build::{bvh_box, padded, triangle};

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

/// Whether a hit at distance `t` (and whether it faces the ray) beats the hit `so_far`: it
/// is nearer, or it faces the ray where the other does not at the same distance (to
/// [`SAME_DISTANCE`]).
fn beats((t, facing): (f32, bool), so_far: Option<(f32, bool)>) -> bool {
    match so_far {
        None => true,
        Some((best, best_facing)) if (t - best).abs() <= SAME_DISTANCE * best => {
            if facing == best_facing {
                t < best
            } else {
                facing
            }
        }
        Some((best, _)) => t < best,
    }
}

/// Relative difference of distance under which two hits are on coincident surfaces (one
/// that faces the ray is then preferred; see [`TriangleScene::hit`]).
const SAME_DISTANCE: f32 = 1e-5;

/// The distances around a hit at `t` within which another hit is its coplanar twin (see
/// [`TriangleScene::hit_and_twin`]).
fn twin_window(t: f32) -> (f32, f32) {
    let eps = 1e-4 * t.max(1.0);
    (t - eps, t + eps)
}

/// The ray from `origin` along `dir` up to `t_max`; none for one that is not finite (it
/// meets nothing).
fn cast(origin: Vec3, dir: Vec3, t_max: f32) -> Option<Ray> {
    let finite = origin.is_finite() && dir.is_finite() && !t_max.is_nan();
    finite.then(|| Ray::new(origin.into(), dir.into(), 0.0, t_max))
}

/// A hit met along a ray.
#[derive(Clone, Copy, Debug)]
struct Candidate {
    t: f32,
    /// Whether its triangle faces the ray.
    facing: bool,
    /// Instance, and triangle in the instance's mesh.
    at: (usize, usize),
    /// Its id in [`Hit::triangle`]'s numbering.
    triangle: u32,
}

/// What a traversal keeps of the hits it meets, and how far it still has to look.
trait Keep {
    /// A hit at distance `t`, facing the ray or not, on triangle `at` (`triangle` as
    /// [`Hit::triangle`] numbers it).
    fn offer(&mut self, t: f32, facing: bool, at: (usize, usize), triangle: u32);
    /// The distance beyond which no hit matters any more.
    fn bound(&self) -> f32;
}

/// Keeps the closest hit (see [`beats`]), other than on one triangle.
struct Closest {
    best: Option<Candidate>,
    skip: Option<u32>,
}

impl Keep for Closest {
    fn offer(&mut self, t: f32, facing: bool, at: (usize, usize), triangle: u32) {
        if Some(triangle) != self.skip && beats((t, facing), self.best.map(|b| (b.t, b.facing))) {
            self.best = Some(Candidate {
                t,
                facing,
                at,
                triangle,
            });
        }
    }

    /// A little beyond the closest hit, where a coincident surface may still win.
    fn bound(&self) -> f32 {
        self.best
            .map_or(f32::INFINITY, |b| b.t * (1.0 + SAME_DISTANCE))
    }
}

/// Keeps the closest hit, as [`Closest`] does, and the hits met within [`twin_window`] of
/// the closest one so far (which may be closer, when they lost to a hit facing the ray).
#[derive(Default)]
struct NearClosest {
    best: Option<Candidate>,
    near: Vec<Candidate>,
}

impl Keep for NearClosest {
    fn offer(&mut self, t: f32, facing: bool, at: (usize, usize), triangle: u32) {
        let c = Candidate {
            t,
            facing,
            at,
            triangle,
        };
        if beats((t, facing), self.best.map(|b| (b.t, b.facing))) {
            self.best = Some(c);
            let (lo, hi) = twin_window(t);
            self.near.retain(|n| n.t >= lo && n.t <= hi);
        }
        if t <= self.bound() {
            self.near.push(c);
        }
    }

    /// The end of the window around the closest hit.
    fn bound(&self) -> f32 {
        self.best.map_or(f32::INFINITY, |b| twin_window(b.t).1)
    }
}

/// World triangles with a BVH for ray casts and distance queries.
///
/// In a large scene (over 4 million triangles) and for the path check, objects that share
/// one mesh of 64 triangles or more (the same index range and vertex offset, as the built-in
/// scenes' and glTF files' instanced meshes do) keep its triangles once, in the mesh's own
/// space, with a BVH of their own; a BVH over the objects' boxes leads rays to them (two
/// levels). The other objects' triangles make one world-space mesh. A placed triangle is
/// tested in world space, its corners transformed exactly as a world-space copy would be, so
/// every hit and distance is the one a single world-space BVH gives. On the city at
/// `--scale 16`, `render` peaks at 0.34 GB with the path check's first run instead of 3.5 GB,
/// and at 0.49 GB with the interior walk's search instead of 15 GB. A placed mesh's rays cost
/// more, so a scene that fits keeps all its triangles in world space for that search.
pub struct TriangleScene {
    /// Over the instances' world boxes (`instances` in its order).
    top: Bvh2,
    instances: Vec<Instance>,
    meshes: Vec<RayMesh>,
    /// Triangles in all, every placement counted.
    triangle_count: usize,
    /// The sun of the scene's flat colours (see [`flat_colour`]).
    sun: Vec3,
    /// World bounds.
    pub bounds: Aabb,
    /// Where the interior walk looks for floors: the bounds, or around the rest of a scene
    /// that stands on a ground far larger than itself
    /// ([`Backdrop::search_region`](crate::scene::backdrop::Backdrop::search_region)).
    pub region: Aabb,
}

/// One mesh of a [`TriangleScene`]: its triangles and their BVH.
struct RayMesh {
    bvh: Bvh2,
    /// Corners in the BVH's order: world space for the world mesh, the mesh's own space for
    /// an instanced one.
    triangles: Vec<Triangle>,
    /// World mesh: per triangle, whether its material is double-sided (an instance says it
    /// for all of its triangles).
    two_sided: Vec<bool>,
    /// World mesh: per triangle, the colours of its front and back sides when the built-in
    /// renderer draws each in one colour, `None` when its colour varies over it. Empty when
    /// not gathered.
    colours: Vec<Option<[[u8; 3]; 2]>>,
    /// Instanced mesh, colours gathered: per triangle, its corners' normals and vertex
    /// colours (`None` where a corner's data is missing), from which each placement's flat
    /// colours follow.
    corners: Vec<Option<[Corner; 3]>>,
}

/// What a corner's flat colour is made of, in the mesh's own space.
#[derive(Clone, Copy, Debug)]
struct Corner {
    normal: Vec3,
    /// The vertex colour; `None` when the scene has none at all.
    tint: Option<[u8; 4]>,
}

/// A mesh placed in the world.
struct Instance {
    mesh: u32,
    /// `None`: the world mesh, already in world space.
    place: Option<Placement>,
    /// Id of the first triangle: a hit names the triangle `first` plus its place in the
    /// mesh's BVH order.
    first: u32,
}

/// Where an instanced mesh stands and how its triangles look there.
struct Placement {
    to_world: Mat4,
    to_local: Mat4,
    two_sided: bool,
    /// The normal matrix and base colour of the object's flat colours, and whether its
    /// material is unlit; `None` when its hits have none (a textured object, or colours not
    /// gathered).
    shade: Option<(Mat4, Vec3, bool)>,
}

impl TriangleScene {
    /// The scene's world-space triangles (those of double-sided materials marked so, unless
    /// their object is a [`closed_solid`]) less those of its backdrop's sky (a sky dome or box
    /// far larger than the rest, [`backdrop`](crate::scene::backdrop)), its
    /// [`region`](Self::region) the rest's when it has a backdrop: what the interior walk
    /// searches. `None` when it has none with finite corners.
    pub fn new(scene: &Scene) -> Option<TriangleScene> {
        let Some(b) = crate::scene::backdrop::find(scene) else {
            return TriangleScene::of(scene, |_| true);
        };
        let mut rays = TriangleScene::of(scene, |i| !b.is_sky(i))?;
        rays.region = b.search_region(&rays.bounds);
        Some(rays)
    }

    /// As [`new`](Self::new), with the triangles of the objects `keep` accepts (by their
    /// index in `Scene::objects`), backdrop or not.
    pub fn of(scene: &Scene, keep: impl Fn(usize) -> bool) -> Option<TriangleScene> {
        build::of_objects(scene, |i, _| keep(i), true, None, None)
    }

    /// As [`of`](Self::of), with the triangles of the objects whose bounds meet `region`
    /// only.
    pub fn near(scene: &Scene, region: &Aabb) -> Option<TriangleScene> {
        build::of_objects(scene, |_, o| o.bounds.overlaps(region), true, None, None)
    }

    /// The scene's shape only, for the path check's few thousand rays: as [`new`](Self::new)
    /// (or [`near`](Self::near) `region`), without the flat colours (hits have none, so
    /// [`one_colour_share`](Self::one_colour_share) counts only the sky), with the quickest
    /// BVH build and every mesh shared by several objects placed (see [`TriangleScene`]),
    /// whatever the scene's size. Several times quicker to build, for slower rays.
    pub fn shape(scene: &Scene, region: Option<&Aabb>) -> Option<TriangleScene> {
        let keep = |_, o: &Object| region.is_none_or(|r| o.bounds.overlaps(r));
        let quickest = Some(BvhBuildParams::fastest_build());
        build::of_objects(scene, keep, false, quickest, Some(true))
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
        build::of_triangles(triangles, two_sided, colours)
    }

    /// Number of triangles, every placement of a shared mesh counted.
    pub fn len(&self) -> usize {
        self.triangle_count
    }

    /// Whether there are no triangles (never true for a built scene).
    pub fn is_empty(&self) -> bool {
        self.triangle_count == 0
    }

    /// The world-space triangle `id` of instance `inst` (in the mesh's BVH order).
    fn world_triangle(&self, inst: &Instance, id: usize) -> Triangle {
        let t = &self.meshes[inst.mesh as usize].triangles[id];
        match &inst.place {
            None => *t,
            Some(p) => triangle(placed_corners(t, p.to_world)),
        }
    }

    /// Offers `keep` the hits of `ray` (world space) on instance `i`'s triangles, met in the
    /// order of the mesh's BVH, which prunes beyond [`Keep::bound`].
    fn instance_hits(&self, i: usize, ray: &Ray, keep: &mut impl Keep) {
        let inst = &self.instances[i];
        let mesh = &self.meshes[inst.mesh as usize];
        let mut consider = |r: &Ray, id: usize, tri: Triangle| {
            let t = tri.intersect(r);
            if t.is_finite() {
                let facing = Vec3::from(tri.compute_normal()).dot(Vec3::from(ray.direction)) < 0.0;
                keep.offer(t, facing, (i, id), inst.first.saturating_add(id as u32));
            }
            keep.bound()
        };
        let mut hit = RayHit::none();
        match &inst.place {
            None => {
                mesh.bvh
                    .ray_traverse(*ray, &mut hit, |r, id| consider(r, id, mesh.triangles[id]));
            }
            Some(p) => {
                // The boxes are tested in the mesh's space, the triangles in world space; the
                // parameter along the ray is the same in both.
                let o = p.to_local.transform_point3(Vec3::from(ray.origin));
                let d = p.to_local.transform_vector3(Vec3::from(ray.direction));
                if !(o.is_finite() && d.is_finite()) {
                    return;
                }
                let local = Ray::new(o.into(), d.into(), ray.tmin, ray.tmax);
                mesh.bvh.ray_traverse(local, &mut hit, |r, id| {
                    let tri = self.world_triangle(inst, id);
                    // The world ray, with the local ray's distance so far.
                    let world = Ray {
                        tmax: r.tmax,
                        ..*ray
                    };
                    consider(&world, id, tri)
                });
            }
        }
    }

    /// Offers `keep` the hits along `ray`, instance by instance in the order of the top BVH.
    fn hits_along(&self, ray: Ray, keep: &mut impl Keep) {
        let mut hit = RayHit::none();
        self.top.ray_traverse(ray, &mut hit, |r, i| {
            self.instance_hits(i, r, keep);
            keep.bound()
        });
    }

    /// The closest hit along `ray` other than on triangle `skip` (an id of [`Hit::triangle`]):
    /// its distance, instance and triangle in the instance's mesh. Of two triangles met at the
    /// same distance (to [`SAME_DISTANCE`]: coincident surfaces), one that faces the ray wins
    /// over one that does not, as the renderer shows the front of such a pair.
    fn closest(&self, ray: Ray, skip: Option<u32>) -> Option<(f32, usize, usize)> {
        let mut keep = Closest { best: None, skip };
        self.hits_along(ray, &mut keep);
        keep.best.map(|b| (b.t, b.at.0, b.at.1))
    }

    /// The closest hit along a unit `dir` up to `t_max`, with the side it hit; none for a ray
    /// that is not finite. Of two coincident surfaces (hits at the same distance, to a
    /// relative 1e-5), the one that faces the ray, as the renderer shows it.
    pub fn hit(&self, origin: Vec3, dir: Vec3, t_max: f32) -> Option<Hit> {
        let (t, i, id) = self.closest(cast(origin, dir, t_max)?, None)?;
        Some(self.side(i, id, dir, t))
    }

    /// The colour of the side of triangle `id` of instance `i`, hit at `t` along `dir`, when
    /// it has one and it differs from `hit`'s: the second colour of a coplanar pair.
    fn other_colour(
        &self,
        hit: &Hit,
        (t, i, id): (f32, usize, usize),
        dir: Vec3,
    ) -> Option<[u8; 3]> {
        self.side(i, id, dir, t)
            .colour
            .filter(|&c| Some(c) != hit.colour)
    }

    /// The hit on triangle `id` of instance `i` at distance `t` along the unit `dir`: the side
    /// it meets, whether that side is meant to be seen, and its flat colour.
    fn side(&self, i: usize, id: usize, dir: Vec3, t: f32) -> Hit {
        let inst = &self.instances[i];
        let mesh = &self.meshes[inst.mesh as usize];
        let n = Vec3::from(self.world_triangle(inst, id).compute_normal());
        let facing = n.dot(dir) < 0.0;
        let (two_sided, colours) = match &inst.place {
            None => (mesh.two_sided[id], mesh.colours.get(id).copied().flatten()),
            Some(p) => (
                p.two_sided,
                p.shade.and_then(|(m, base, unlit)| {
                    let light = (!unlit).then_some(self.sun);
                    flat_sides(mesh.corners.get(id).copied().flatten(), m, base, light)
                }),
            ),
        };
        let front = facing || two_sided;
        Hit {
            t,
            normal: if facing { n } else { -n },
            front,
            colour: colours.filter(|_| front).map(|c| c[usize::from(!facing)]),
            triangle: inst.first.saturating_add(id as u32),
        }
    }

    /// [`hit`](Self::hit), and the colour of a second, coplanar side that the hit shares its
    /// distance with (within a relative 1e-4), when it differs: which of two coincident
    /// surfaces the renderer shows depends on draw order and depth precision, so both count.
    /// One traversal finds both: it keeps the hits within that distance of the closest so far.
    pub(crate) fn hit_and_twin(
        &self,
        origin: Vec3,
        dir: Vec3,
        t_max: f32,
    ) -> Option<(Hit, Option<[u8; 3]>)> {
        let mut keep = NearClosest::default();
        self.hits_along(cast(origin, dir, t_max)?, &mut keep);
        let best = keep.best?;
        let hit = self.side(best.at.0, best.at.1, dir, best.t);
        // The second side: the closest of the other hits in the window, offered in the order
        // they were met, as `closest` over the window would meet them.
        let (lo, hi) = twin_window(best.t);
        let mut twin = Closest {
            best: None,
            skip: Some(hit.triangle),
        };
        for c in keep.near.iter().filter(|c| c.t >= lo && c.t <= hi) {
            twin.offer(c.t, c.facing, c.at, c.triangle);
        }
        let colour = twin
            .best
            .and_then(|c| self.other_colour(&hit, (c.t, c.at.0, c.at.1), dir));
        Some((hit, colour))
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
        self.top.aabb_traverse(query, |top, node| {
            let n = &top.nodes[node as usize];
            let first = n.first_index as usize;
            for inst in &self.instances[first..first + n.prim_count as usize] {
                if self.instance_within(inst, &query, p, r) {
                    found = true;
                    return false;
                }
            }
            true
        });
        found
    }

    /// Whether a triangle of instance `inst` is closer to `p` than `r` (`query`: the world box
    /// of that ball).
    fn instance_within(&self, inst: &Instance, query: &BvhAabb, p: Vec3, r: f32) -> bool {
        let mesh = &self.meshes[inst.mesh as usize];
        let local = match &inst.place {
            None => *query,
            Some(pl) => {
                let world = Aabb::new(query.min.into(), query.max.into());
                bvh_box(padded(world.transformed(&pl.to_local)))
            }
        };
        let mut found = false;
        mesh.bvh.aabb_traverse(local, |bvh, node| {
            let n = &bvh.nodes[node as usize];
            let first = n.first_index as usize;
            for id in first..first + n.prim_count as usize {
                let t = self.world_triangle(inst, id);
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

/// The world corners of the mesh-space triangle `t` placed by `transform`, computed as the
/// world mesh computes its own (so that both give the same hits).
fn placed_corners(t: &Triangle, transform: Mat4) -> [Vec3; 3] {
    [t.v0, t.v1, t.v2].map(|p| transform.transform_point3(Vec3::from(p)))
}

/// The colours of the front and the back of a triangle with `corners`, of an untextured
/// object of colour `base` whose normals `normal_matrix` takes to world space, lit by the
/// light towards `sun` (`None`: an unlit material), when the built-in renderer draws each
/// side in one colour: the same colour at its three corners from their vertex colours and
/// normals (see [`flat_colour`]).
fn flat_sides(
    corners: Option<[Corner; 3]>,
    normal_matrix: Mat4,
    base: Vec3,
    sun: Option<Vec3>,
) -> Option<[[u8; 3]; 2]> {
    let mut sides: Option<[[u8; 3]; 2]> = None;
    for c in corners? {
        let mut base = base;
        if let Some(t) = c.tint {
            base *= Vec3::new(t[0].into(), t[1].into(), t[2].into()) / 255.0;
        }
        let n = normal_matrix.transform_vector3(c.normal).try_normalize()?;
        let corner = match sun {
            Some(sun) => [flat_colour(base, n, sun), flat_colour(base, -n, sun)],
            None => [gamma_bytes(base); 2],
        };
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
    gamma_bytes(base * (0.75 * lambert + 0.25 * sky + 0.05))
}

/// A linear colour as the forward pass writes it: clamped, gamma 2.2, 8 bits (an unlit
/// material's flat colour is its base colour so written).
fn gamma_bytes(c: Vec3) -> [u8; 3] {
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
            match self.hit_and_twin(p, d, far) {
                None => escaped += 1,
                Some((h, second)) if h.front => {
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

#[cfg(test)]
impl TriangleScene {
    /// As [`new`](Self::new) with the meshes shared by several objects placed, whatever the
    /// scene's size.
    pub(crate) fn placing(scene: &Scene) -> Option<TriangleScene> {
        build::of_objects(scene, |_, _| true, true, None, Some(true))
    }

    /// As [`new`](Self::new) with every triangle in the world mesh (no placed meshes): the
    /// reference the placed meshes are compared with.
    pub(crate) fn world_only(scene: &Scene) -> Option<TriangleScene> {
        build::of_objects(scene, |_, _| true, true, None, Some(false))
    }

    /// The twin colour of [`hit_and_twin`](Self::hit_and_twin) found by a second cast: the
    /// closest hit other than `hit`'s triangle within [`twin_window`] of it, along the same
    /// ray (the reference the one-traversal search is compared with).
    pub(crate) fn twin_by_second_cast(
        &self,
        origin: Vec3,
        dir: Vec3,
        hit: &Hit,
    ) -> Option<[u8; 3]> {
        let (lo, hi) = twin_window(hit.t);
        let ray = Ray::new(origin.into(), dir.into(), lo, hi);
        let twin = self.closest(ray, Some(hit.triangle))?;
        self.other_colour(hit, twin, dir)
    }

    /// Number of placed instances (objects of shared meshes).
    pub(crate) fn placed(&self) -> usize {
        self.instances.iter().filter(|i| i.place.is_some()).count()
    }
}
