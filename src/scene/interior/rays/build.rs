//! Building a [`TriangleScene`]: the objects of shared meshes placed by their transforms, the
//! others' triangles gathered into one world-space mesh, and the BVHs over both.

use std::collections::HashMap;
use std::time::Duration;

use glam::{Mat4, Vec3};
use obvhs::aabb::Aabb as BvhAabb;
use obvhs::bvh2::builder::{build_bvh2, build_bvh2_from_tris};
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;

use super::{
    closed_solid, flat_colour, flat_sides, placed_corners, Corner, Instance, Placement, RayMesh,
    TriangleScene,
};
use crate::scene::gltf::DEFAULT_SUN;
use crate::scene::{Aabb, Object, Scene};

/// World triangles, whether each is double-sided, and their flat colours (empty when not
/// gathered), in the scene's order.
type Gathered = (Vec<[Vec3; 3]>, Vec<bool>, Vec<Option<[[u8; 3]; 2]>>);

/// Triangles above which the ray scene's BVH is built for speed rather than quality.
const LARGE_SCENE_TRIANGLES: usize = 4_000_000;

/// Relative margin by which the boxes of an instanced mesh's BVH and of the instances are
/// grown, so that a ray taken into a mesh's own space (with its rounding) still finds every
/// triangle its world-space test would hit.
const PLACED_BOX_MARGIN: f32 = 1e-4;

/// How a BVH over `n` primitives is built: for quality, and above
/// [`LARGE_SCENE_TRIANGLES`] for speed (a scaled-up city is only path-checked, a few thousand
/// rays: a quick build without reinsertion is several times faster there and ample for that).
fn params_for(n: usize) -> BvhBuildParams {
    if n > LARGE_SCENE_TRIANGLES {
        BvhBuildParams::fastest_build()
    } else {
        BvhBuildParams::fast_build()
    }
}

/// The scene of `triangles`, all in the world mesh (see [`TriangleScene::build`]).
pub(super) fn of_triangles(
    triangles: &[[Vec3; 3]],
    two_sided: &[bool],
    colours: &[Option<[[u8; 3]; 2]>],
) -> Option<TriangleScene> {
    let params = params_for(triangles.len());
    let world = RayMesh::world(triangles, two_sided, Some(colours), params);
    Parts::new(world).finish(DEFAULT_SUN.normalize(), params)
}

/// Triangles from which a mesh shared by several objects is kept once and placed; smaller
/// ones (a box, a quad) cost less as world-space copies, where a ray meets them without
/// going through a placement.
const PLACED_MESH_TRIANGLES: usize = 64;

/// What makes two objects share a mesh: their index range and vertex offset.
type MeshKey = (u32, u32, u32);

/// The scene of the objects `keep` accepts, with their flat colours when `colours`; the
/// objects of meshes shared by several placed by their transforms when `instancing` says so,
/// or (`None`) when the objects have more than [`LARGE_SCENE_TRIANGLES`] triangles in all:
/// a placed mesh saves memory and building time but costs each ray that meets it, so a
/// scene that fits keeps every triangle in the world mesh. `params`: how its BVHs are
/// built, `None` for [`params_for`] their sizes.
pub(super) fn of_objects(
    scene: &Scene,
    keep: impl Fn(usize, &Object) -> bool,
    colours: bool,
    params: Option<BvhBuildParams>,
    instancing: Option<bool>,
) -> Option<TriangleScene> {
    let key = |o: &Object| (o.first_index, o.index_count, o.vertex_offset);
    let mut uses: HashMap<MeshKey, usize> = Default::default();
    let instancing = instancing.unwrap_or_else(|| {
        let triangles: u64 = (scene.objects.iter().enumerate())
            .filter(|(i, o)| keep(*i, o))
            .map(|(_, o)| o.triangle_count())
            .sum();
        triangles > LARGE_SCENE_TRIANGLES as u64
    });
    if instancing {
        for (_, o) in scene
            .objects
            .iter()
            .enumerate()
            .filter(|(i, o)| keep(*i, o))
        {
            *uses.entry(key(o)).or_default() += 1;
        }
    }
    let mut meshes: HashMap<MeshKey, Option<LocalMesh>> = Default::default();
    let mut placed = Vec::new();
    let mut world = Vec::new();
    for (i, o) in scene.objects.iter().enumerate() {
        if !keep(i, o) {
            continue;
        }
        let k = key(o);
        let shared = uses.get(&k).is_some_and(|&n| n >= 2)
            && o.index_count as usize >= 3 * PLACED_MESH_TRIANGLES;
        let mesh = shared
            .then(|| {
                meshes
                    .entry(k)
                    .or_insert_with(|| LocalMesh::gather(scene, o, colours))
                    .as_ref()
            })
            .flatten();
        // An object whose corners do not all exist, or do not all land on finite points,
        // goes into the world mesh, which skips such triangles one by one.
        match mesh.and_then(|m| m.placed_bounds(o.transform)) {
            Some(b) => placed.push((i, b)),
            None => world.push(i),
        }
    }
    let (triangles, two_sided, sides) = gather_objects(scene, world.iter().copied(), colours);
    let world_params = params.unwrap_or_else(|| params_for(triangles.len()));
    let world_mesh = RayMesh::world(
        &triangles,
        &two_sided,
        colours.then_some(&sides[..]),
        world_params,
    );
    let params = params.unwrap_or_else(BvhBuildParams::fast_build);
    drop((triangles, two_sided, sides));
    let mut parts = Parts::new(world_mesh);
    let mut index: HashMap<MeshKey, u32> = Default::default();
    for &(i, b) in &placed {
        let o = &scene.objects[i];
        let k = key(o);
        let mesh = match index.get(&k) {
            Some(&m) => m,
            None => {
                let Some(local) = meshes.get_mut(&k).and_then(Option::take) else {
                    continue;
                };
                let m = parts.meshes.len() as u32;
                parts.meshes.push(local.build(params));
                index.insert(k, m);
                m
            }
        };
        let two_sided = scene.object_material(i).is_some_and(|m| m.double_sided)
            && !closed_solid(&parts.meshes[mesh as usize].placed_in_order(o.transform));
        let to_local = o.transform.inverse();
        let shade = flat_coloured(scene, i, colours)
            .then(|| (to_local.transpose(), o.color.truncate(), scene.is_unlit(i)));
        let place = Placement {
            to_world: o.transform,
            to_local,
            two_sided,
            shade,
        };
        parts.place(mesh, Some(place), b);
    }
    let top = params_for(parts.instances.len());
    parts.finish(scene.sun_dir, top)
}

/// The world triangles of the objects `objects` (indices, ascending), which of them are
/// double-sided, and (when `colours`) their flat colours.
fn gather_objects(scene: &Scene, objects: impl Iterator<Item = usize>, colours: bool) -> Gathered {
    let mut triangles = Vec::new();
    let mut two_sided = Vec::new();
    let mut sides = Vec::new();
    for i in objects {
        let o = &scene.objects[i];
        let normal_matrix =
            flat_coloured(scene, i, colours).then(|| o.transform.inverse().transpose());
        let light = (!scene.is_unlit(i)).then_some(scene.sun_dir);
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
                    sides.push(normal_matrix.and_then(|m| {
                        flat_sides(
                            scene_corners(scene, o.vertex_offset, t),
                            m,
                            o.color.truncate(),
                            light,
                        )
                    }));
                }
            }
        }
        let both = scene.object_material(i).is_some_and(|m| m.double_sided)
            && !closed_solid(&triangles[start..]);
        two_sided.resize(triangles.len(), both);
    }
    (triangles, two_sided, sides)
}

/// The meshes and instances of a [`TriangleScene`] being built.
struct Parts {
    meshes: Vec<RayMesh>,
    instances: Vec<Instance>,
    /// The instances' world boxes, in their order.
    boxes: Vec<BvhAabb>,
    bounds: Aabb,
    triangle_count: usize,
}

impl Parts {
    /// Parts with the world mesh, if it has triangles, as the first instance (its triangles'
    /// ids start at 0).
    fn new(world: Option<(RayMesh, Aabb)>) -> Parts {
        let mut parts = Parts {
            meshes: Vec::new(),
            instances: Vec::new(),
            boxes: Vec::new(),
            bounds: Aabb::EMPTY,
            triangle_count: 0,
        };
        if let Some((w, bounds)) = world {
            parts.meshes.push(w);
            parts.place(0, None, bounds);
        }
        parts
    }

    /// Places mesh `mesh` (`place` `None`: the world mesh) with world bounds `bounds`.
    fn place(&mut self, mesh: u32, place: Option<Placement>, bounds: Aabb) {
        self.bounds = self.bounds.union(&bounds);
        let b = if place.is_some() {
            padded(bounds)
        } else {
            bounds
        };
        self.boxes.push(bvh_box(b));
        self.instances.push(Instance {
            mesh,
            place,
            first: u32::try_from(self.triangle_count).unwrap_or(u32::MAX),
        });
        self.triangle_count += self.meshes[mesh as usize].triangles.len();
    }

    /// The scene, its instances under one BVH; `None` when it has no triangle.
    fn finish(self, sun: Vec3, params: BvhBuildParams) -> Option<TriangleScene> {
        if self.instances.is_empty() {
            return None;
        }
        let mut time = Duration::ZERO;
        let top = build_bvh2(&self.boxes, params, &mut time);
        let mut slots: Vec<Option<Instance>> = self.instances.into_iter().map(Some).collect();
        let instances = top
            .primitive_indices
            .iter()
            .filter_map(|&i| slots.get_mut(i as usize).and_then(Option::take))
            .collect();
        Some(TriangleScene {
            top,
            instances,
            meshes: self.meshes,
            triangle_count: self.triangle_count,
            sun,
            bounds: self.bounds,
            region: self.bounds,
        })
    }
}

impl RayMesh {
    /// This instanced mesh's triangles placed by `transform`, in the order they were
    /// gathered (the index buffer's).
    fn placed_in_order(&self, transform: Mat4) -> Vec<[Vec3; 3]> {
        let mut order: Vec<(u32, usize)> = (self.bvh.primitive_indices.iter().copied())
            .zip(0..)
            .collect();
        order.sort_unstable();
        order
            .iter()
            .map(|&(_, at)| placed_corners(&self.triangles[at], transform))
            .collect()
    }

    /// The world mesh of `triangles` (those with finite corners), `two_sided` and (when
    /// `colours` is given) their flat colours (missing entries: grey by the face normal, lit
    /// as glTF scenes are), and their bounds; `None` when no triangle has finite corners.
    fn world(
        triangles: &[[Vec3; 3]],
        two_sided: &[bool],
        colours: Option<&[Option<[[u8; 3]; 2]>]>,
        params: BvhBuildParams,
    ) -> Option<(RayMesh, Aabb)> {
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
            tris.push(triangle(*t));
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
        let colours = if flat.is_empty() {
            Vec::new()
        } else {
            order.iter().map(|&i| flat[i as usize]).collect()
        };
        let mesh = RayMesh {
            bvh,
            triangles,
            two_sided,
            colours,
            corners: Vec::new(),
        };
        Some((mesh, bounds))
    }
}

/// A shared mesh gathered in its own space, before its BVH is built.
struct LocalMesh {
    triangles: Vec<[Vec3; 3]>,
    /// Its corners' positions, each vertex once (for a placement's exact bounds).
    points: Vec<Vec3>,
    corners: Vec<Option<[Corner; 3]>>,
}

impl LocalMesh {
    /// The mesh of object `o` in its own space; `None` when a corner's vertex is missing or
    /// not finite, or it has no triangle.
    fn gather(scene: &Scene, o: &Object, colours: bool) -> Option<LocalMesh> {
        let first = o.first_index as usize;
        let idx = scene
            .indices
            .get(first..first.saturating_add(o.index_count as usize))?;
        let mut seen = std::collections::HashSet::new();
        let mut points = Vec::new();
        let mut triangles = Vec::new();
        let mut corners = Vec::new();
        for t in idx.chunks_exact(3) {
            let mut tri = [Vec3::ZERO; 3];
            for (k, &i) in t.iter().enumerate() {
                let v = scene
                    .vertices
                    .get(o.vertex_offset.checked_add(i)? as usize)?;
                tri[k] = Vec3::from_array(v.position);
                if !tri[k].is_finite() {
                    return None;
                }
                if seen.insert(i) {
                    points.push(tri[k]);
                }
            }
            triangles.push(tri);
            if colours {
                corners.push(scene_corners(scene, o.vertex_offset, t));
            }
        }
        (!triangles.is_empty()).then_some(LocalMesh {
            triangles,
            points,
            corners,
        })
    }

    /// The exact world bounds of the mesh placed by `transform`; `None` when a corner lands
    /// on a point that is not finite.
    fn placed_bounds(&self, transform: Mat4) -> Option<Aabb> {
        let mut b = Aabb::EMPTY;
        for &p in &self.points {
            let w = transform.transform_point3(p);
            if !w.is_finite() {
                return None;
            }
            b.grow(w);
        }
        Some(b)
    }

    /// The mesh with its BVH (over its triangles' boxes, grown a little: see
    /// [`PLACED_BOX_MARGIN`]), in the BVH's order.
    fn build(self, params: BvhBuildParams) -> RayMesh {
        let boxes: Vec<BvhAabb> = self
            .triangles
            .iter()
            .map(|t| {
                let mut b = Aabb::EMPTY;
                t.iter().for_each(|&p| b.grow(p));
                bvh_box(padded(b))
            })
            .collect();
        let mut time = Duration::ZERO;
        let bvh = build_bvh2(&boxes, params, &mut time);
        let order = &bvh.primitive_indices;
        let triangles = order
            .iter()
            .map(|&i| triangle(self.triangles[i as usize]))
            .collect();
        let corners = if self.corners.is_empty() {
            Vec::new()
        } else {
            order.iter().map(|&i| self.corners[i as usize]).collect()
        };
        RayMesh {
            bvh,
            triangles,
            two_sided: Vec::new(),
            colours: Vec::new(),
            corners,
        }
    }
}

/// `b` grown by [`PLACED_BOX_MARGIN`] of its largest extent (and a little more, for boxes
/// that are flat or far from the origin).
pub(super) fn padded(b: Aabb) -> Aabb {
    let size = b.extent().max_element().max(0.0);
    let far = b.min.abs().max(b.max.abs()).max_element();
    b.enlarged(PLACED_BOX_MARGIN * size + 1e-6 * far + 1e-6)
}

/// `b` as the BVH builder's box.
pub(super) fn bvh_box(b: Aabb) -> BvhAabb {
    BvhAabb::new(b.min.into(), b.max.into())
}

/// The BVH's triangle of `corners`.
pub(super) fn triangle([a, b, c]: [Vec3; 3]) -> Triangle {
    Triangle {
        v0: a.into(),
        v1: b.into(),
        v2: c.into(),
    }
}

/// Whether object `i`'s hits get flat colours, when `colours` are gathered at all: a
/// textured object is never one flat colour.
fn flat_coloured(scene: &Scene, i: usize, colours: bool) -> bool {
    colours
        && scene
            .object_material(i)
            .is_none_or(|m| m.base_color_texture.is_none())
}

/// The data of the corners of triangle `t` (indices relative to `vertex_offset`) that their
/// flat colours are made of; `None` when a corner's vertex (or vertex colour) is missing.
fn scene_corners(scene: &Scene, vertex_offset: u32, t: &[u32]) -> Option<[Corner; 3]> {
    let mut out = [Corner {
        normal: Vec3::ZERO,
        tint: None,
    }; 3];
    for (k, &i) in t.iter().enumerate().take(3) {
        let at = vertex_offset.saturating_add(i) as usize;
        let tint = if scene.attributes.is_empty() {
            None
        } else {
            Some(scene.attributes.get(at)?.color)
        };
        out[k] = Corner {
            normal: Vec3::from_array(scene.vertices.get(at)?.normal),
            tint,
        };
    }
    Some(out)
}
