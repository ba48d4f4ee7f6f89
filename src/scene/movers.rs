//! Moving objects: those a glTF file's first animation moves ([`Scene::animation`]), and the
//! built-in ones (`--movers N`): cars that drive along the `city` streets and turn at
//! crossings, cars that drive along the `parking` aisles out of the lot and back in, fans that
//! spin in the `powerplant` (and in any other scene). Each mover's transform is a pure function
//! of the frame number, so every algorithm of a walk sees the same scene at the same frame.

use glam::{Mat4, Vec3, Vec4};

use super::animation::MeshPose;
use super::mesh::{Mesh, Rng};
use super::{Aabb, Object, Scene, Vertex};
use crate::error::Result;

/// The city's block and street widths (as `procedural::city` lays them out).
const CITY_BLOCK: f32 = 40.0;
const CITY_STREET: f32 = 14.0;
/// Distance from a street's centre line to the centre of a driving lane.
const LANE: f32 = 2.0;

/// The built-in movers of a scene.
#[derive(Clone, Debug, Default)]
pub struct Movers {
    movers: Vec<Mover>,
    /// The glTF animation that [`Route::Animated`] and [`Route::Deformed`] movers follow.
    animation: Option<std::sync::Arc<super::animation::Animation>>,
    /// The animation's deformed meshes as last posed (scratch, reused from frame to frame).
    skins: std::cell::RefCell<MeshPose>,
}

/// One mover: its object, its object-space box and its route.
#[derive(Clone, Debug)]
struct Mover {
    object: u32,
    local: Aabb,
    route: Route,
}

/// How a mover moves.
#[derive(Clone, Copy, Debug)]
enum Route {
    /// Along the city's streets from crossing to crossing, turning at random (seeded) at each.
    Street {
        seed: u64,
        start: (i32, i32),
        dir: u8,
        speed: f32,
        offset: f32,
        crossings: i32,
        pitch: f32,
    },
    /// Along a parking aisle in x, out of the lot at one end and back in at the other.
    Aisle {
        z: f32,
        from: f32,
        length: f32,
        speed: f32,
        offset: f32,
        forward: bool,
    },
    /// Spinning about a vertical axis in place.
    Spin { at: Vec3, speed: f32, phase: f32 },
    /// Object `index` of the scene's glTF animation.
    Animated { index: usize },
    /// Deformed object `index` of the scene's glTF animation (skinned or morphed): its
    /// vertices posed each frame.
    Deformed { index: usize },
    /// Back and forth between two points (a crane's trolley and hook).
    Shuttle {
        from: Vec3,
        to: Vec3,
        speed: f32,
        phase: f32,
    },
}

/// Unit steps of the four street directions: +x, +z, -x, -z.
const DIRS: [(i32, i32); 4] = [(1, 0), (0, 1), (-1, 0), (0, -1)];

impl Movers {
    /// Adds the objects of the scene's glTF animation (taken out of `scene.animation`), then
    /// `count` built-in movers, to `scene` (new objects after the scene's own, at their frame-0
    /// places): cars on the `city` streets, cars in the `parking` aisles, spinning fans
    /// elsewhere. Their ids are `scene.objects.len()` before the call, onwards.
    pub fn add(scene: &mut Scene, count: usize) -> Movers {
        let mut movers = Movers::default();
        if let Some(animation) = scene.animation.take() {
            for (index, a) in animation.objects.iter().enumerate() {
                movers.movers.push(Mover {
                    object: scene.objects.len() as u32,
                    local: a.local,
                    route: Route::Animated { index },
                });
                let mut object = a.object.clone();
                object.material = object.material.map(|m| unblended(scene, m));
                scene.objects.push(object);
            }
            let mut pose = MeshPose::default();
            animation.pose_meshes(0, &mut pose);
            // The scene's vertices start in the pose of frame 0, each mesh once.
            for mesh in 0..animation.deformed_meshes() {
                let first = animation.deformed_first_vertex(mesh) as usize;
                let posed = pose.mesh(mesh);
                if let Some(range) = scene.vertices.get_mut(first..first + posed.len()) {
                    range.copy_from_slice(posed);
                }
            }
            for (index, a) in animation.deformed.iter().enumerate() {
                let mesh = a.mesh;
                let mut object = a.object.clone();
                object.transform = animation.deformed_transform(index, 0);
                object.bounds = pose.bounds(mesh).transformed(&object.transform);
                object.material = object.material.map(|m| unblended(scene, m));
                movers.movers.push(Mover {
                    object: scene.objects.len() as u32,
                    local: pose.bounds(mesh),
                    route: Route::Deformed { index },
                });
                scene.objects.push(object);
            }
            movers.skins = std::cell::RefCell::new(pose);
            movers.animation = Some(animation);
        }
        let mut rng = Rng::new(0x00D1_7A11 ^ count as u64);
        let ground = scene.objects.first().map(|o| o.bounds);
        let world = scene.bounds();
        let (mesh, color) = match scene.name.as_str() {
            "city" | "parking" => (car_mesh(), Vec3::new(0.85, 0.75, 0.1)),
            _ => (fan_mesh(), Vec3::new(0.75, 0.2, 0.15)),
        };
        let local = mesh.bounds();
        let first = append_mesh(scene, &mesh);
        let crane = if scene.name == "powerplant" {
            append_mesh(scene, &crane_mesh())
        } else {
            first.clone()
        };
        for i in 0..count {
            let route = match (scene.name.as_str(), ground) {
                ("city", Some(g)) => street_route(&mut rng, g),
                ("parking", Some(g)) => aisle_route(&mut rng, g),
                ("powerplant", _) if i % 8 == 0 => crane_route(&mut rng, &world),
                _ => spin_route(&mut rng, &world),
            };
            let (local, first) = if matches!(route, Route::Shuttle { .. }) {
                (crane.bounds, &crane)
            } else {
                (local, &first)
            };
            let tint = 0.6 + 0.4 * rng.f32();
            let object = scene.objects.len() as u32;
            let mover = Mover {
                object,
                local,
                route,
            };
            let transform = movers.transform_of(&mover, 0);
            scene.objects.push(Object {
                transform,
                color: Vec4::from((color * tint, 1.0)),
                bounds: local.transformed(&transform),
                ..first.clone()
            });
            movers.movers.push(mover);
        }
        movers
    }

    /// Number of movers.
    pub fn len(&self) -> usize {
        self.movers.len()
    }

    /// The movers' object ids, one contiguous range (empty when there are none).
    pub fn objects(&self) -> std::ops::Range<u32> {
        match (self.movers.first(), self.movers.last()) {
            (Some(a), Some(b)) => a.object..b.object + 1,
            _ => 0..0,
        }
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.movers.is_empty()
    }

    /// The object id of mover `i`.
    pub fn object(&self, i: usize) -> u32 {
        self.movers[i].object
    }

    /// Mover `i`'s transform at `frame`.
    pub fn transform_at(&self, i: usize, frame: u64) -> Mat4 {
        self.transform_of(&self.movers[i], frame)
    }

    fn transform_of(&self, m: &Mover, frame: u64) -> Mat4 {
        match (m.route, &self.animation) {
            (Route::Animated { index }, Some(a)) => a.transform_at(index, frame),
            (Route::Deformed { index }, Some(a)) => a.deformed_transform(index, frame),
            _ => m.transform_at(frame),
        }
    }

    /// The glTF animation with its deformed meshes posed at `frame` (posed once per frame,
    /// into the movers' scratch); `None` without deformed meshes.
    fn posed(
        &self,
        frame: u64,
    ) -> Option<(
        &super::animation::Animation,
        std::cell::RefMut<'_, MeshPose>,
    )> {
        let a = self
            .animation
            .as_deref()
            .filter(|a| a.deformed_meshes() > 0)?;
        let mut pose = self.skins.borrow_mut();
        a.pose_meshes(frame, &mut pose);
        Some((a, pose))
    }

    /// The vertices of each mesh that the glTF animation deforms (skins, morph weights),
    /// posed at `frame`:
    /// `deform(first_vertex, vertices)`, for the host to write into its vertex buffer from
    /// the scene's vertex `first_vertex` on (positions and normals; the other attributes do not
    /// change). Nothing without such meshes. Allocates nothing once the first frame is posed.
    pub fn for_each_deformed(
        &self,
        frame: u64,
        mut deform: impl FnMut(u32, &[Vertex]) -> Result<()>,
    ) -> Result<()> {
        let Some((a, pose)) = self.posed(frame) else {
            return Ok(());
        };
        (0..a.deformed_meshes()).try_for_each(|i| deform(a.deformed_first_vertex(i), pose.mesh(i)))
    }

    /// For a mover whose mesh the glTF animation deforms (skin, morph weights): the
    /// scene's vertex where that mesh starts, the `first_vertex` that
    /// [`Movers::for_each_deformed`] passes with its posed vertices. `None` for the others.
    pub fn deformed_first_vertex(&self, i: usize) -> Option<u32> {
        match (self.movers.get(i)?.route, &self.animation) {
            (Route::Deformed { index }, Some(a)) => {
                let mesh = a.deformed.get(index)?.mesh;
                (mesh < a.deformed_meshes()).then(|| a.deformed_first_vertex(mesh))
            }
            _ => None,
        }
    }

    /// Which of the glTF file's animations the movers play (`1 "Walk"`; see
    /// [`Animation::label`](super::animation::Animation::label)); `None` without one.
    pub fn animation_label(&self) -> Option<&str> {
        self.animation
            .as_deref()
            .map(|a| a.label())
            .filter(|l| !l.is_empty())
    }

    /// The meshes the glTF animation deforms (skins, morph weights), posed every frame.
    pub fn deformed_meshes(&self) -> usize {
        self.animation.as_ref().map_or(0, |a| a.deformed_meshes())
    }

    /// Each mover's place at `frame`: `place(object, world box, transform)`, for the host to
    /// put the box into the hierarchy (`ObjectBvh::set_bounds`, then `update`) and the
    /// transform into its per-object transform buffer. Allocates nothing.
    pub fn for_each_at(
        &self,
        frame: u64,
        mut place: impl FnMut(u32, Aabb, &Mat4) -> Result<()>,
    ) -> Result<()> {
        let posed = self.posed(frame);
        for m in &self.movers {
            let t = self.transform_of(m, frame);
            let bounds = match (m.route, &posed) {
                (Route::Deformed { index }, Some((a, pose))) => {
                    pose.bounds(a.deformed[index].mesh).transformed(&t)
                }
                _ => m.local.transformed(&t),
            };
            place(m.object, bounds, &t)?;
        }
        Ok(())
    }
}

impl Mover {
    fn transform_at(&self, frame: u64) -> Mat4 {
        match self.route {
            Route::Street { .. } => street_transform(&self.route, frame),
            Route::Aisle {
                z,
                from,
                length,
                speed,
                offset,
                forward,
            } => {
                let s = (offset + speed * frame as f32).rem_euclid(length);
                let (x, yaw, lane) = if forward {
                    (from + s, 0.0, 1.2)
                } else {
                    (from + length - s, std::f32::consts::PI, -1.2)
                };
                Mat4::from_translation(Vec3::new(x, 0.0, z + lane)) * Mat4::from_rotation_y(yaw)
            }
            Route::Spin { at, speed, phase } => {
                Mat4::from_translation(at) * Mat4::from_rotation_y(phase + speed * frame as f32)
            }
            // Placed by `Movers::transform_of`, which holds the animation.
            Route::Animated { .. } | Route::Deformed { .. } => Mat4::IDENTITY,
            Route::Shuttle {
                from,
                to,
                speed,
                phase,
            } => {
                // Smooth back and forth: 0 at `from`, 1 at `to`.
                let t = 0.5 - 0.5 * (phase + speed * frame as f32).cos();
                Mat4::from_translation(from.lerp(to, t))
            }
        }
    }
}

/// The street route of a city car: a random crossing, direction, speed and start offset.
fn street_route(rng: &mut Rng, ground: Aabb) -> Route {
    let pitch = CITY_BLOCK + CITY_STREET;
    // The ground spans [-street, blocks * pitch] in x and z; streets run at k * pitch - street/2.
    let crossings = ((ground.max.x / pitch).round() as i32).max(1);
    let start = (
        rng.below(crossings as u32 + 1) as i32,
        rng.below(crossings as u32 + 1) as i32,
    );
    let mut dir = rng.below(4) as u8;
    let (dx, dz) = DIRS[dir as usize];
    if !on_grid(start.0 + dx, start.1 + dz, crossings) {
        dir = (dir + 2) % 4;
    }
    Route::Street {
        seed: rng.next_u64(),
        start,
        dir,
        speed: rng.range(0.25, 0.5),
        offset: rng.range(0.0, pitch),
        crossings,
        pitch,
    }
}

fn on_grid(i: i32, j: i32, crossings: i32) -> bool {
    (0..=crossings).contains(&i) && (0..=crossings).contains(&j)
}

/// Where a city car is at `frame`: it drives `speed` metres a frame; at every crossing it goes
/// straight, left or right (never back, unless the grid ends), chosen by its seed.
fn street_transform(route: &Route, frame: u64) -> Mat4 {
    let Route::Street {
        seed,
        start,
        dir,
        speed,
        offset,
        crossings,
        pitch,
    } = *route
    else {
        return Mat4::IDENTITY;
    };
    let s = offset + speed * frame as f32;
    let segments = (s / pitch).floor() as u64;
    let t = s - segments as f32 * pitch;
    let (mut at, mut d) = (start, dir);
    for k in 0..segments {
        let (dx, dz) = DIRS[d as usize];
        at = (at.0 + dx, at.1 + dz);
        d = turn(seed, k, at, d, crossings);
    }
    let (dx, dz) = DIRS[d as usize];
    let centre = |k: i32| k as f32 * pitch - CITY_STREET / 2.0;
    let dirv = Vec3::new(dx as f32, 0.0, dz as f32);
    let right = Vec3::new(-dirv.z, 0.0, dirv.x);
    let p = Vec3::new(centre(at.0), 0.0, centre(at.1)) + dirv * t + right * LANE;
    let yaw = (-dirv.z).atan2(dirv.x);
    Mat4::from_translation(p) * Mat4::from_rotation_y(yaw)
}

/// The direction a car takes at crossing `at` (its `k`-th), arriving in direction `d`.
fn turn(seed: u64, k: u64, at: (i32, i32), d: u8, crossings: i32) -> u8 {
    let mut options = [0u8; 3];
    let mut n = 0;
    for choice in [d, (d + 1) % 4, (d + 3) % 4] {
        let (dx, dz) = DIRS[choice as usize];
        if on_grid(at.0 + dx, at.1 + dz, crossings) {
            options[n] = choice;
            n += 1;
        }
    }
    if n == 0 {
        return (d + 2) % 4;
    }
    let mut r = Rng::new(seed ^ (k + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    options[r.below(n as u32) as usize]
}

/// A parking car: along an aisle free of pillars (the one in front of the lot, or one behind
/// an odd row), from 25 m before the lot to 25 m past it.
fn aisle_route(rng: &mut Rng, ground: Aabb) -> Route {
    let width = ground.max.x - 8.0;
    let depth = ground.max.z - 8.0;
    let rows = ((depth / 9.0).round() as i32).max(1);
    let aisles = 1 + rows / 2;
    let a = rng.below(aisles as u32) as i32;
    let z = if a == 0 {
        -3.0
    } else {
        (2 * a - 1) as f32 * 9.0 + 7.0
    };
    let length = width + 50.0;
    Route::Aisle {
        z,
        from: -25.0,
        length,
        speed: rng.range(0.15, 0.35),
        offset: rng.range(0.0, length),
        forward: rng.below(2) == 0,
    }
}

/// A fan spinning somewhere in the middle third of the scene's height.
fn spin_route(rng: &mut Rng, world: &Aabb) -> Route {
    let (lo, hi) = if world.is_valid() {
        (world.min, world.max)
    } else {
        (Vec3::splat(-10.0), Vec3::splat(10.0))
    };
    let at = Vec3::new(
        rng.range(lo.x, hi.x),
        lo.y + (hi.y - lo.y) * rng.range(0.33, 0.66),
        rng.range(lo.z, hi.z),
    );
    Route::Spin {
        at,
        speed: rng.range(0.05, 0.2),
        phase: rng.range(0.0, 6.3),
    }
}

/// A crane in the powerplant: its trolley runs 15 m along x below the ceiling (12 m walls).
fn crane_route(rng: &mut Rng, world: &Aabb) -> Route {
    let (lo, hi) = if world.is_valid() {
        (world.min, world.max)
    } else {
        (Vec3::splat(-10.0), Vec3::splat(10.0))
    };
    let from = Vec3::new(
        rng.range(lo.x, (hi.x - 15.0).max(lo.x)),
        10.5,
        rng.range(lo.z, hi.z),
    );
    Route::Shuttle {
        from,
        to: from + Vec3::new(15.0, 0.0, 0.0),
        speed: rng.range(0.01, 0.03),
        phase: rng.range(0.0, 6.3),
    }
}

/// Material `m`, or a copy of it that does not blend when it does: a moving object is drawn
/// by the culler in the culled pass, so a blended one is alpha-tested there, as its other
/// passes draw it (the copy is made once per material).
fn unblended(scene: &mut Scene, m: u32) -> u32 {
    let Some(&material) = scene.materials.get(m as usize) else {
        return m;
    };
    if !material.blend {
        return m;
    }
    let copy = crate::scene::Material {
        blend: false,
        ..material
    };
    match scene.materials.iter().position(|x| *x == copy) {
        Some(i) => i as u32,
        None => {
            scene.materials.push(copy);
            scene.materials.len() as u32 - 1
        }
    }
}

/// Stores `mesh` in the scene's buffers once; the returned object draws it (transform and
/// bounds still to be set).
fn append_mesh(scene: &mut Scene, mesh: &Mesh) -> Object {
    let o = Object {
        first_index: scene.indices.len() as u32,
        index_count: mesh.indices.len() as u32,
        vertex_offset: scene.vertices.len() as u32,
        vertex_count: mesh.vertices.len() as u32,
        transform: Mat4::IDENTITY,
        color: Vec4::ONE,
        bounds: mesh.bounds(),
        material: None,
    };
    scene.vertices.extend_from_slice(&mesh.vertices);
    scene.indices.extend_from_slice(&mesh.indices);
    o
}

/// A car facing +x: body, cabin, four wheels.
fn car_mesh() -> Mesh {
    let mut m = Mesh::default();
    m.append(
        &Mesh::cuboid(Vec3::new(-2.2, 0.35, -0.95), Vec3::new(2.2, 1.05, 0.95)),
        Mat4::IDENTITY,
    );
    m.append(
        &Mesh::cuboid(Vec3::new(-1.1, 1.05, -0.85), Vec3::new(1.0, 1.6, 0.85)),
        Mat4::IDENTITY,
    );
    for (x, z) in [(-1.4, -0.95), (-1.4, 0.95), (1.4, -0.95), (1.4, 0.95)] {
        let wheel = Mat4::from_translation(Vec3::new(x, 0.35, z))
            * Mat4::from_rotation_x(std::f32::consts::FRAC_PI_2)
            * Mat4::from_translation(Vec3::new(0.0, -0.12, 0.0))
            * Mat4::from_scale(Vec3::new(0.35, 0.24, 0.35));
        m.append(&Mesh::cylinder(10), wheel);
    }
    m
}

/// A crane's trolley with a cable and a hook block hanging 4 m below it.
fn crane_mesh() -> Mesh {
    let mut m = Mesh::default();
    m.append(
        &Mesh::cuboid(Vec3::new(-1.0, -0.4, -1.0), Vec3::new(1.0, 0.4, 1.0)),
        Mat4::IDENTITY,
    );
    m.append(
        &Mesh::cuboid(Vec3::new(-0.05, -4.0, -0.05), Vec3::new(0.05, -0.4, 0.05)),
        Mat4::IDENTITY,
    );
    m.append(
        &Mesh::cuboid(Vec3::new(-0.4, -4.6, -0.4), Vec3::new(0.4, -4.0, 0.4)),
        Mat4::IDENTITY,
    );
    m
}

/// A fan: a hub and four blades in the xz plane.
fn fan_mesh() -> Mesh {
    let mut m = Mesh::default();
    m.append(
        &Mesh::cuboid(Vec3::new(-0.3, -0.3, -0.3), Vec3::new(0.3, 0.3, 0.3)),
        Mat4::IDENTITY,
    );
    for k in 0..4 {
        let r = Mat4::from_rotation_y(k as f32 * std::f32::consts::FRAC_PI_2);
        m.append(
            &Mesh::cuboid(Vec3::new(0.3, -0.05, -0.25), Vec3::new(2.0, 0.05, 0.25)),
            r,
        );
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn powerplant_fans_spin_and_cranes_run() {
        let mut scene = crate::scene::procedural::build("powerplant", 1.0).unwrap();
        let movers = Movers::add(&mut scene, 16);
        let (mut cranes, mut fans) = (0, 0);
        for i in 0..movers.len() {
            let (a, b) = (movers.transform_at(i, 0), movers.transform_at(i, 40));
            let moved = a.transform_point3(Vec3::ZERO) != b.transform_point3(Vec3::ZERO);
            let turned = a.transform_vector3(Vec3::X) != b.transform_vector3(Vec3::X);
            match movers.movers[i].route {
                Route::Shuttle { .. } => {
                    assert!(moved && !turned);
                    cranes += 1;
                }
                _ => {
                    assert!(turned && !moved);
                    fans += 1;
                }
            }
        }
        assert_eq!((cranes, fans), (2, 14));
    }

    #[test]
    fn city_cars_stay_on_the_streets_and_turn() {
        let mut scene = crate::scene::procedural::build("city", 0.1).unwrap();
        let statics = scene.objects.len();
        let movers = Movers::add(&mut scene, 50);
        assert_eq!(scene.objects.len(), statics + 50);
        let pitch = CITY_BLOCK + CITY_STREET;
        let mut turned = 0;
        for i in 0..movers.len() {
            let mut last_dir = None;
            for f in (0..2000).step_by(7) {
                let t = movers.transform_at(i, f);
                let p = t.transform_point3(Vec3::ZERO);
                // On a street: x or z within the street of some centre line.
                let off = |v: f32| {
                    ((v + CITY_STREET / 2.0).rem_euclid(pitch))
                        .min(pitch - (v + CITY_STREET / 2.0).rem_euclid(pitch))
                };
                assert!(
                    off(p.x) <= CITY_STREET / 2.0 || off(p.z) <= CITY_STREET / 2.0,
                    "{p}"
                );
                let dir = t.transform_vector3(Vec3::X).round();
                if last_dir.is_some_and(|d: Vec3| d != dir) {
                    turned += 1;
                }
                last_dir = Some(dir);
            }
            // Deterministic.
            assert_eq!(movers.transform_at(i, 999), movers.transform_at(i, 999));
        }
        assert!(turned > 20, "cars turn at crossings ({turned})");
    }
}
