//! The scene flattened to world-space triangles for GI: one list feeds the CPU ray caster
//! ([`RayScene`]) and, expanded to non-indexed vertices, the GPU passes (vertex pulling).

use glam::{Mat3, Mat4, Vec3};

use super::raycast::RayScene;
use crate::scene::{Aabb, Object, Scene};

/// Floats per GPU vertex: position (vec4), normal (vec4), albedo (vec4), std430 layout.
pub const VERTEX_FLOATS: usize = 12;

/// World-space triangles of a scene with one albedo each.
#[derive(Clone, Debug)]
pub struct WorldGeometry {
    /// Triangle corners in world space.
    pub triangles: Vec<[Vec3; 3]>,
    /// Per-vertex normals in world space, parallel to `triangles`.
    pub normals: Vec<[Vec3; 3]>,
    /// Diffuse albedo per triangle.
    pub albedo: Vec<Vec3>,
    /// World bounds.
    pub bounds: Aabb,
}

impl WorldGeometry {
    /// Applies every object's transform to its triangles.
    pub fn from_scene(scene: &Scene) -> WorldGeometry {
        Self::from_objects(scene, 0..scene.objects.len())
    }

    /// [`WorldGeometry::from_scene`] for the objects in `objects` only, in order.
    pub fn from_objects(scene: &Scene, objects: std::ops::Range<usize>) -> WorldGeometry {
        let mut out = WorldGeometry::empty();
        for o in &scene.objects[objects] {
            out.push_object(scene, o, &o.transform);
        }
        out
    }

    /// Object `index` of `scene` in its own space (its transform not applied).
    pub fn object_local(scene: &Scene, index: usize) -> WorldGeometry {
        let mut out = WorldGeometry::empty();
        out.push_object(scene, &scene.objects[index], &Mat4::IDENTITY);
        out
    }

    /// No triangles.
    pub fn empty() -> WorldGeometry {
        WorldGeometry {
            triangles: Vec::new(),
            normals: Vec::new(),
            albedo: Vec::new(),
            bounds: Aabb::EMPTY,
        }
    }

    /// Appends the triangles of object `o` of `scene`, placed by `transform`.
    fn push_object(&mut self, scene: &Scene, o: &Object, transform: &Mat4) {
        let normal_matrix = Mat3::from_mat4(transform.inverse().transpose());
        let color = o.color.truncate();
        let indices =
            &scene.indices[o.first_index as usize..(o.first_index + o.index_count) as usize];
        for tri in indices.chunks_exact(3) {
            let mut p = [Vec3::ZERO; 3];
            let mut n = [Vec3::ZERO; 3];
            for k in 0..3 {
                let v = &scene.vertices[(o.vertex_offset + tri[k]) as usize];
                p[k] = transform.transform_point3(Vec3::from(v.position));
                n[k] = (normal_matrix * Vec3::from(v.normal)).normalize_or_zero();
                self.bounds.grow(p[k]);
            }
            self.triangles.push(p);
            self.normals.push(n);
            self.albedo.push(color);
        }
    }

    /// A copy whose triangles have no edge longer than `max_edge` (longest-edge bisection, at
    /// most 2^12 pieces per triangle). The paraboloid shadow maps interpolate straight edges in a
    /// non-linear projection, so long triangles cast visibly wrong shadows; short ones don't.
    pub fn tessellated(&self, max_edge: f32) -> WorldGeometry {
        let mut out = WorldGeometry {
            triangles: Vec::with_capacity(self.triangles.len()),
            normals: Vec::with_capacity(self.triangles.len()),
            albedo: Vec::with_capacity(self.triangles.len()),
            bounds: self.bounds,
        };
        let max2 = max_edge * max_edge;
        let mut stack = Vec::new();
        for ((t, n), a) in self.triangles.iter().zip(&self.normals).zip(&self.albedo) {
            stack.push((*t, *n, 0u32));
            while let Some((p, m, depth)) = stack.pop() {
                let lens = [
                    p[0].distance_squared(p[1]),
                    p[1].distance_squared(p[2]),
                    p[2].distance_squared(p[0]),
                ];
                let (k, longest) =
                    lens.iter()
                        .copied()
                        .enumerate()
                        .fold(
                            (0, 0.0),
                            |best, (i, l)| if l > best.1 { (i, l) } else { best },
                        );
                if longest <= max2 || depth >= 12 || !longest.is_finite() {
                    out.triangles.push(p);
                    out.normals.push(m);
                    out.albedo.push(*a);
                    continue;
                }
                // Split edge (k, k+1) at its midpoint; the opposite corner is k+2.
                let (i, j) = (k, (k + 1) % 3);
                let mid = (p[i] + p[j]) * 0.5;
                let mid_n = (m[i] + m[j]).normalize_or(m[i]);
                let mut first = (p, m, depth + 1);
                first.0[j] = mid;
                first.1[j] = mid_n;
                let mut second = (p, m, depth + 1);
                second.0[i] = mid;
                second.1[i] = mid_n;
                stack.push(first);
                stack.push(second);
            }
        }
        out
    }

    /// Appends `other`'s triangles after this one's and grows the bounds.
    pub fn append(&mut self, other: &WorldGeometry) {
        self.triangles.extend_from_slice(&other.triangles);
        self.normals.extend_from_slice(&other.normals);
        self.albedo.extend_from_slice(&other.albedo);
        self.bounds = self.bounds.union(&other.bounds);
    }

    /// The CPU ray-casting scene (BVH over the same triangles).
    pub fn ray_scene(&self) -> RayScene {
        RayScene::new(self.triangles.clone(), self.albedo.clone())
    }

    /// Non-indexed GPU vertices, [`VERTEX_FLOATS`] floats each.
    pub fn gpu_vertices(&self) -> Vec<f32> {
        let mut out = Vec::with_capacity(self.triangles.len() * 3 * VERTEX_FLOATS);
        for ((t, n), a) in self.triangles.iter().zip(&self.normals).zip(&self.albedo) {
            for k in 0..3 {
                out.extend_from_slice(&[t[k].x, t[k].y, t[k].z, 1.0]);
                out.extend_from_slice(&[n[k].x, n[k].y, n[k].z, 0.0]);
                out.extend_from_slice(&[a.x, a.y, a.z, 1.0]);
            }
        }
        out
    }

    /// Length of the bounds' diagonal (the scene's scale), at least 1e-3.
    pub fn diagonal(&self) -> f32 {
        if self.bounds.is_valid() {
            self.bounds.extent().length().max(1e-3)
        } else {
            1.0
        }
    }
}
