//! Mesh prototypes for procedural scenes (boxes, cylinders, spheres, compounds) and a builder that
//! stores each prototype once in the shared buffers and instances it as objects.

use glam::{Mat4, Vec3, Vec4};

use super::{Aabb, CameraPath, Object, Scene, Vertex};

/// A mesh in its own space: vertices and triangle indices.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    /// Vertices.
    pub vertices: Vec<Vertex>,
    /// Triangle indices into `vertices`.
    pub indices: Vec<u32>,
}

impl Mesh {
    /// Appends `other` transformed by `m`.
    pub fn append(&mut self, other: &Mesh, m: Mat4) {
        let base = self.vertices.len() as u32;
        let nm = m.inverse().transpose();
        for v in &other.vertices {
            let p = m.transform_point3(Vec3::from(v.position));
            let n = nm
                .transform_vector3(Vec3::from(v.normal))
                .normalize_or(Vec3::Y);
            self.vertices.push(Vertex {
                position: p.to_array(),
                normal: n.to_array(),
            });
        }
        self.indices.extend(other.indices.iter().map(|i| i + base));
    }

    /// Bounds of the vertices.
    pub fn bounds(&self) -> Aabb {
        let mut b = Aabb::EMPTY;
        for v in &self.vertices {
            b.grow(Vec3::from(v.position));
        }
        b
    }

    /// Triangle count.
    pub fn triangles(&self) -> usize {
        self.indices.len() / 3
    }

    fn quad(&mut self, corners: [Vec3; 4], n: Vec3) {
        let base = self.vertices.len() as u32;
        for c in corners {
            self.vertices.push(Vertex {
                position: c.to_array(),
                normal: n.to_array(),
            });
        }
        self.indices
            .extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
    }

    /// A mesh of `triangles` (counter-clockwise fronts), three vertices each with the
    /// triangle's normal (the up axis for a degenerate one).
    pub fn from_triangles(triangles: &[[Vec3; 3]]) -> Mesh {
        let mut m = Mesh::default();
        for t in triangles {
            let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or(Vec3::Y);
            for p in t {
                m.indices.push(m.vertices.len() as u32);
                m.vertices.push(Vertex {
                    position: p.to_array(),
                    normal: n.to_array(),
                });
            }
        }
        m
    }

    /// The unit cube [-0.5, 0.5]³ with outward faces (counter-clockwise seen from outside).
    pub fn cube() -> Mesh {
        let mut m = Mesh::default();
        let h = 0.5;
        for axis in 0..3 {
            for sign in [-1.0f32, 1.0] {
                let n =
                    Vec3::from_array(std::array::from_fn(|i| if i == axis { sign } else { 0.0 }));
                let u = Vec3::from_array(std::array::from_fn(|i| {
                    if i == (axis + 1) % 3 {
                        1.0
                    } else {
                        0.0
                    }
                }));
                let v = n.cross(u);
                let c = n * h;
                m.quad(
                    [
                        c - u * h - v * h,
                        c + u * h - v * h,
                        c + u * h + v * h,
                        c - u * h + v * h,
                    ],
                    n,
                );
            }
        }
        m
    }

    /// A box from `min` to `max`.
    pub fn cuboid(min: Vec3, max: Vec3) -> Mesh {
        let mut m = Mesh::default();
        m.append(
            &Mesh::cube(),
            Mat4::from_translation((min + max) * 0.5) * Mat4::from_scale(max - min),
        );
        m
    }

    /// A closed cylinder along +y from y=0 to y=1, radius 1, `segments` around.
    pub fn cylinder(segments: u32) -> Mesh {
        let mut m = Mesh::default();
        let s = segments.max(3);
        let ring = |i: u32| {
            let a = i as f32 / s as f32 * std::f32::consts::TAU;
            Vec3::new(a.cos(), 0.0, -a.sin())
        };
        for i in 0..s {
            let (a, b) = (ring(i), ring(i + 1));
            let n = ((a + b) * 0.5).normalize();
            let base = m.vertices.len() as u32;
            for (p, nn) in [(a, a), (b, b), (b + Vec3::Y, b), (a + Vec3::Y, a)] {
                let _ = n;
                m.vertices.push(Vertex {
                    position: p.to_array(),
                    normal: nn.to_array(),
                });
            }
            m.indices
                .extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
            // caps
            let top = m.vertices.len() as u32;
            for p in [Vec3::Y, a + Vec3::Y, b + Vec3::Y] {
                m.vertices.push(Vertex {
                    position: p.to_array(),
                    normal: [0.0, 1.0, 0.0],
                });
            }
            m.indices.extend_from_slice(&[top, top + 1, top + 2]);
            let bot = m.vertices.len() as u32;
            for p in [Vec3::ZERO, b, a] {
                m.vertices.push(Vertex {
                    position: p.to_array(),
                    normal: [0.0, -1.0, 0.0],
                });
            }
            m.indices.extend_from_slice(&[bot, bot + 1, bot + 2]);
        }
        m
    }

    /// A UV sphere of radius 1 around the origin.
    pub fn sphere(lon: u32, lat: u32) -> Mesh {
        let mut m = Mesh::default();
        let (lon, lat) = (lon.max(3), lat.max(2));
        for j in 0..=lat {
            let t = j as f32 / lat as f32 * std::f32::consts::PI;
            for i in 0..=lon {
                let p = i as f32 / lon as f32 * std::f32::consts::TAU;
                let n = Vec3::new(t.sin() * p.cos(), t.cos(), -t.sin() * p.sin());
                m.vertices.push(Vertex {
                    position: n.to_array(),
                    normal: n.to_array(),
                });
            }
        }
        for j in 0..lat {
            for i in 0..lon {
                let a = j * (lon + 1) + i;
                let b = a + lon + 1;
                if j != 0 {
                    m.indices.extend_from_slice(&[a, b, a + 1]);
                }
                if j != lat - 1 {
                    m.indices.extend_from_slice(&[a + 1, b, b + 1]);
                }
            }
        }
        m
    }
}

/// A prototype stored once in the shared buffers.
#[derive(Clone, Copy, Debug)]
pub struct Proto {
    first_index: u32,
    index_count: u32,
    vertex_offset: u32,
    vertex_count: u32,
    bounds: Aabb,
}

/// Builds a [`Scene`] from instanced prototypes.
pub struct SceneBuilder {
    scene: Scene,
}

impl SceneBuilder {
    /// An empty scene named `name`.
    pub fn new(name: &str) -> SceneBuilder {
        SceneBuilder {
            scene: Scene {
                name: name.to_string(),
                vertices: Vec::new(),
                indices: Vec::new(),
                objects: Vec::new(),
                paths: Vec::new(),
                sun_dir: Vec3::new(0.45, 1.0, 0.3).normalize(),
                attributes: Vec::new(),
                materials: Vec::new(),
                images: Vec::new(),
                textures: Vec::new(),
                animation: None,
            },
        }
    }

    /// Stores a mesh once; instance it with [`SceneBuilder::instance`].
    pub fn proto(&mut self, mesh: &Mesh) -> Proto {
        let p = Proto {
            first_index: self.scene.indices.len() as u32,
            index_count: mesh.indices.len() as u32,
            vertex_offset: self.scene.vertices.len() as u32,
            vertex_count: mesh.vertices.len() as u32,
            bounds: mesh.bounds(),
        };
        self.scene.vertices.extend_from_slice(&mesh.vertices);
        self.scene.indices.extend_from_slice(&mesh.indices);
        p
    }

    /// Adds an object: prototype `p` placed by `transform`, with `color` (linear RGB).
    pub fn instance(&mut self, p: Proto, transform: Mat4, color: Vec3) -> u32 {
        self.scene.objects.push(Object {
            first_index: p.first_index,
            index_count: p.index_count,
            vertex_offset: p.vertex_offset,
            vertex_count: p.vertex_count,
            transform,
            color: Vec4::from((color, 1.0)),
            bounds: p.bounds.transformed(&transform),
            material: None,
        });
        self.scene.objects.len() as u32 - 1
    }

    /// Adds a one-off mesh as an object.
    pub fn add(&mut self, mesh: &Mesh, color: Vec3) -> u32 {
        let p = self.proto(mesh);
        self.instance(p, Mat4::IDENTITY, color)
    }

    /// Adds a walkthrough path.
    pub fn path(&mut self, name: &str, keys: &[(Vec3, Vec3)]) {
        self.scene.paths.push(CameraPath {
            name: name.to_string(),
            keys: keys
                .iter()
                .map(|&(eye, target)| super::CameraPose { eye, target })
                .collect(),
        });
    }

    /// Sets the direction towards the sun.
    pub fn sun(&mut self, dir: Vec3) {
        self.scene.sun_dir = dir.normalize_or(Vec3::Y);
    }

    /// The finished scene.
    pub fn finish(self) -> Scene {
        self.scene
    }
}

/// A small deterministic PRNG (xorshift64*), so procedural scenes are reproducible.
pub use coherent_cull::rng::Rng;
