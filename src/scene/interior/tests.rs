//! Procedural levels with the failure modes of real ones: a leak to the outside, a level
//! floating above a ground plane, rooms joined by doorways and a staircase with thick walls and
//! closed voids, ceilings whose tops are flat and reachable by rays inside a sky box, a level
//! whose materials are all double-sided with the winding reversed, a roofless level (a
//! block-out), a roofless furnished house and a closed double-sided solid.

use glam::{Mat4, Vec3, Vec4};

use super::rays::TriangleScene;
use super::*;
use crate::scene::mesh::{Mesh, SceneBuilder};
use crate::scene::path_check;
use crate::scene::Material;

/// Triangles of a level under construction (counter-clockwise fronts).
#[derive(Default)]
struct Level {
    tris: Vec<[Vec3; 3]>,
}

/// A room: its horizontal extent and its floor and ceiling heights.
#[derive(Clone, Copy, Debug)]
struct Room {
    min: Vec3,
    max: Vec3,
}

impl Room {
    fn new(x0: f32, z0: f32, x1: f32, z1: f32, y0: f32, y1: f32) -> Room {
        Room {
            min: Vec3::new(x0, y0, z0),
            max: Vec3::new(x1, y1, z1),
        }
    }
    fn contains(&self, p: Vec3) -> bool {
        p.cmpge(self.min).all() && p.cmple(self.max).all()
    }
}

impl Level {
    /// A quad through `c` (in order around it) facing `n`.
    fn quad(&mut self, c: [Vec3; 4], n: Vec3) {
        let flip = (c[1] - c[0]).cross(c[2] - c[0]).dot(n) < 0.0;
        for t in [[c[0], c[1], c[2]], [c[0], c[2], c[3]]] {
            self.tris.push(if flip { [t[0], t[2], t[1]] } else { t });
        }
    }
    /// Horizontal quad at height `y`, facing up (`up`) or down.
    fn flat(&mut self, (x0, z0, x1, z1): (f32, f32, f32, f32), y: f32, up: bool) {
        let c = [
            Vec3::new(x0, y, z0),
            Vec3::new(x1, y, z0),
            Vec3::new(x1, y, z1),
            Vec3::new(x0, y, z1),
        ];
        self.quad(c, if up { Vec3::Y } else { Vec3::NEG_Y });
    }
    /// Wall in the plane `x` from `z0` to `z1`, `y0` to `y1`, facing `facing` (±1 along x).
    fn wall_x(&mut self, x: f32, (z0, z1): (f32, f32), (y0, y1): (f32, f32), facing: f32) {
        let c = [
            Vec3::new(x, y0, z0),
            Vec3::new(x, y0, z1),
            Vec3::new(x, y1, z1),
            Vec3::new(x, y1, z0),
        ];
        self.quad(c, Vec3::X * facing);
    }
    /// Wall in the plane `z` from `x0` to `x1`, facing `facing` (±1 along z).
    fn wall_z(&mut self, z: f32, (x0, x1): (f32, f32), (y0, y1): (f32, f32), facing: f32) {
        let c = [
            Vec3::new(x0, y0, z),
            Vec3::new(x1, y0, z),
            Vec3::new(x1, y1, z),
            Vec3::new(x0, y1, z),
        ];
        self.quad(c, Vec3::Z * facing);
    }
    /// A wall in the plane `x` with a door from `d0` to `d1` up to `top`.
    fn wall_x_door(
        &mut self,
        x: f32,
        (z0, z1): (f32, f32),
        (y0, y1): (f32, f32),
        facing: f32,
        (d0, d1, top): (f32, f32, f32),
    ) {
        self.wall_x(x, (z0, d0), (y0, y1), facing);
        self.wall_x(x, (d1, z1), (y0, y1), facing);
        self.wall_x(x, (d0, d1), (top, y1), facing);
    }
    /// A solid box (faces outward, a closed void inside).
    fn brush(&mut self, min: Vec3, max: Vec3) {
        let mut m = Mesh::default();
        m.append(
            &Mesh::cube(),
            Mat4::from_translation((min + max) * 0.5) * Mat4::from_scale(max - min),
        );
        for t in m.indices.chunks_exact(3) {
            self.tris
                .push([t[0], t[1], t[2]].map(|i| Vec3::from(m.vertices[i as usize].position)));
        }
    }
    /// A room's inward faces: floor, ceiling and the walls not in `skip` (−x, +x, −z, +z).
    fn room_shell(&mut self, r: Room, skip: [bool; 4]) {
        let (a, b) = (r.min, r.max);
        self.flat((a.x, a.z, b.x, b.z), a.y, true);
        self.flat((a.x, a.z, b.x, b.z), b.y, false);
        if !skip[0] {
            self.wall_x(a.x, (a.z, b.z), (a.y, b.y), 1.0);
        }
        if !skip[1] {
            self.wall_x(b.x, (a.z, b.z), (a.y, b.y), -1.0);
        }
        if !skip[2] {
            self.wall_z(a.z, (a.x, b.x), (a.y, b.y), 1.0);
        }
        if !skip[3] {
            self.wall_z(b.z, (a.x, b.x), (a.y, b.y), -1.0);
        }
    }
    fn rays(&self) -> TriangleScene {
        TriangleScene::from_triangles(&self.tris, &[]).expect("triangles")
    }
    /// Adds the level to `scene` as one more object (single-sided).
    fn add_to(&self, scene: &mut Scene) {
        let own = self.scene(false);
        let (base, first) = (scene.vertices.len() as u32, scene.indices.len() as u32);
        scene.vertices.extend_from_slice(&own.vertices);
        scene.indices.extend(own.indices.iter().copied());
        scene.objects.push(crate::scene::Object {
            first_index: first,
            vertex_offset: base,
            ..own.objects[0].clone()
        });
    }
    /// The level as a scene of one object, all double-sided when `two_sided`.
    fn scene(&self, two_sided: bool) -> Scene {
        let m = Mesh::from_triangles(&self.tris);
        let mut b = SceneBuilder::new("level");
        b.add(&m, Vec3::ONE);
        b.path("default", &[(Vec3::new(0.0, 50.0, 50.0), Vec3::ZERO); 2]);
        let mut s = b.finish();
        if two_sided {
            s.materials.push(Material {
                double_sided: true,
                ..Material::default()
            });
            s.objects[0].material = Some(0);
            s.objects[0].color = Vec4::ONE;
        }
        s
    }
}

/// Three rooms in a row along x (6 x 6, 3.5 high, floor at `y`) joined by thin walls with
/// doors; `leak`: a door in the last room's outer wall. Returns the rooms.
fn row_of_rooms(l: &mut Level, y: f32, leak: bool) -> Vec<Room> {
    let rooms: Vec<Room> = (0..3)
        .map(|i| {
            let x = i as f32 * 6.0;
            Room::new(x, 0.0, x + 6.0, 6.0, y, y + 3.5)
        })
        .collect();
    for (i, r) in rooms.iter().enumerate() {
        // Partitions are 0.1 thick: each room's wall stands 0.05 inside the shared line.
        let mut inner = *r;
        if i > 0 {
            inner.min.x += 0.05;
        }
        if i < 2 {
            inner.max.x -= 0.05;
        }
        // Floors and ceilings run under the partitions (door thresholds).
        l.flat((r.min.x, 0.0, r.max.x, 6.0), y, true);
        l.flat((r.min.x, 0.0, r.max.x, 6.0), y + 3.5, false);
        l.wall_z(0.0, (inner.min.x, inner.max.x), (y, y + 3.5), 1.0);
        l.wall_z(6.0, (inner.min.x, inner.max.x), (y, y + 3.5), -1.0);
        if i == 0 {
            l.wall_x(0.0, (0.0, 6.0), (y, y + 3.5), 1.0);
        }
        if i == 2 && !leak {
            l.wall_x(18.0, (0.0, 6.0), (y, y + 3.5), -1.0);
        }
        let door = (2.0, 4.0, y + 2.5);
        if i > 0 {
            l.wall_x_door(inner.min.x, (0.0, 6.0), (y, y + 3.5), 1.0, door);
        }
        if i < 2 || leak {
            l.wall_x_door(inner.max.x, (0.0, 6.0), (y, y + 3.5), -1.0, door);
        }
    }
    rooms
}

/// Checks a walk over `rays`: every frame in one of `rooms` (or `passages`), at least `min_rooms` visited, no
/// checked frame mostly sky (over 40%) or back faces (over 10%) or inside geometry.
fn assert_walks_rooms(
    rays: &TriangleScene,
    rooms: &[Room],
    passages: &[Room],
    min_rooms: usize,
) -> InteriorWalk {
    let walk = find(rays, &InteriorParams::default()).expect("an interior walk");
    let path = &walk.path;
    let mut visited = vec![false; rooms.len()];
    for f in 0..=path.natural_frames() {
        let eye = path.pose_at(f as f32).eye;
        match rooms.iter().position(|r| r.contains(eye)) {
            Some(k) => visited[k] = true,
            None if passages.iter().any(|r| r.contains(eye)) => {}
            None => panic!(
                "frame {f}: {eye} is in no room (waypoints {:?})",
                walk.waypoints
            ),
        }
    }
    let count = visited.iter().filter(|v| **v).count();
    assert!(
        count >= min_rooms,
        "visits {count} rooms: {visited:?} (waypoints {:?}, {} of {} places)",
        walk.waypoints,
        walk.part,
        walk.places
    );
    for v in path_check::views(rays, path) {
        assert!(
            v.sky <= 0.4 && v.back <= 0.1 && v.back_around <= 0.1 && !v.clips,
            "{v:?}"
        );
        assert_eq!(v.problem(true), None);
    }
    walk
}

#[test]
fn a_leak_to_the_outside_is_not_the_inside() {
    let mut l = Level::default();
    let rooms = row_of_rooms(&mut l, 0.0, true);
    // Open ground outside the leak, far larger than the rooms.
    l.flat((18.0, -20.0, 60.0, 26.0), 0.0, true);
    assert_walks_rooms(&l.rays(), &rooms, &[], 3);
}

#[test]
fn a_level_inside_a_sky_dome_is_walked_as_without_it() {
    // An open-air level (three rooms, one with a door to the open ground beside them) and,
    // as a second object, a sky dome 2 km wide: the search leaves the dome out.
    let mut l = Level::default();
    let rooms = row_of_rooms(&mut l, 0.0, true);
    l.flat((18.0, -20.0, 60.0, 26.0), 0.0, true);
    let dome = crate::scene::backdrop::tests::dome(1000.0, 8, 24);
    let sky = Level {
        tris: (dome.iter())
            .map(|t| t.map(|p| p + Vec3::X * 20.0))
            .collect(),
    };
    let mut scene = l.scene(false);
    sky.add_to(&mut scene);
    let backdrop = crate::scene::backdrop::find(&scene).expect("the dome is the backdrop");
    assert_eq!(backdrop.sky, vec![1]);
    // With the dome, the floor grid over 2 km has a few cells over the level: no inside.
    let all = TriangleScene::of(&scene, |_| true).expect("triangles");
    assert!(find(&all, &InteriorParams::default()).is_err());
    // Without it, the walk of the level alone.
    let rays = TriangleScene::new(&scene).expect("triangles");
    assert!(rays.bounds.extent().x < 100.0, "{:?}", rays.bounds);
    assert_walks_rooms(&rays, &rooms, &[], 3);
    interior_path(&scene, &InteriorParams::default()).expect("the walk");
}

#[test]
fn a_level_on_a_ground_far_larger_than_itself_is_walked() {
    // The same rooms, one open to the outside, on a ground plate 2 km wide (a second object):
    // the plate is kept (it is the floor outside), the search keeps to the rooms' region.
    let mut l = Level::default();
    let rooms = row_of_rooms(&mut l, 0.0, true);
    let mut ground = Level::default();
    ground.flat((-1000.0, -1000.0, 1000.0, 1000.0), -0.01, true);
    let mut scene = l.scene(false);
    ground.add_to(&mut scene);
    let backdrop = crate::scene::backdrop::find(&scene).expect("the plate is a ground");
    assert_eq!((backdrop.sky.len(), backdrop.ground.clone()), (0, vec![1]));
    // Searched over the whole plate, the grid's cells are wider than the rooms: no inside.
    let all = TriangleScene::of(&scene, |_| true).expect("triangles");
    assert!(find(&all, &InteriorParams::default()).is_err());
    let rays = TriangleScene::new(&scene).expect("triangles");
    assert_eq!(rays.bounds, all.bounds);
    assert!(rays.region.extent().x < 100.0, "{:?}", rays.region);
    assert_walks_rooms(&rays, &rooms, &[], 3);
}

#[test]
fn a_level_floating_above_a_ground_plane_is_walked_inside() {
    let mut l = Level::default();
    let rooms = row_of_rooms(&mut l, 20.0, false);
    l.flat((-20.0, -20.0, 40.0, 26.0), 0.0, true);
    let walk = assert_walks_rooms(&l.rays(), &rooms, &[], 3);
    assert!(
        (walk.scale.eye_height - 1.7).abs() < 1e-3,
        "{:?}",
        walk.scale
    );
}

#[test]
fn ceiling_tops_inside_a_sky_box_are_not_floors() {
    let mut l = Level::default();
    let rooms = row_of_rooms(&mut l, 0.0, false);
    // A sky box around the level, seen from within: the space between it and the rooms is
    // the level's void, over ceilings (back faces from above) and under floors.
    let (a, b) = (Vec3::new(-1.0, -0.5, -1.0), Vec3::new(19.0, 9.0, 7.0));
    l.room_shell(Room { min: a, max: b }, [false; 4]);
    let rays = l.rays();
    let walk = assert_walks_rooms(&rays, &rooms, &[], 3);
    assert!(
        walk.waypoints.iter().all(|w| w.y < 3.5),
        "{:?}",
        walk.waypoints
    );
    // The void beside the outer walls sees their backs: no place there, walked or not.
    let floors = places::floors(&rays, walk.scale.cell);
    let (found, why) = places::places(&rays, &floors, &walk.scale);
    assert!(why.back > 0, "{why}");
    for p in &found {
        assert!(rooms.iter().any(|r| r.contains(p.eye)), "{p:?}");
    }
}

/// Rooms of solid brushes: thick walls (1 m, closed voids inside), doorways, a room raised
/// 1.2 m on a solid plinth reached by a staircase, a large solid block, single-sided
/// ceilings open to the sky above. Returns the rooms and the doorways.
fn house(l: &mut Level) -> (Vec<Room>, Vec<Room>) {
    let h = 4.5;
    let rooms = vec![
        Room::new(0.0, 0.0, 6.0, 6.0, 0.0, h),
        Room::new(7.0, 0.0, 13.0, 6.0, 0.0, h),
        Room::new(14.0, 0.0, 20.0, 6.0, 1.2, h),
        Room::new(0.0, 7.0, 6.0, 13.0, 0.0, h),
    ];
    let v = Vec3::new;
    for r in &rooms {
        l.flat((r.min.x, r.min.z, r.max.x, r.max.z), r.min.y, true);
        l.flat((r.min.x, r.min.z, r.max.x, r.max.z), h, false);
    }
    let doors = vec![
        Room::new(6.0, 2.0, 7.0, 4.0, 0.0, h),
        Room::new(13.0, 2.0, 14.0, 4.0, 1.2, h),
        Room::new(2.0, 6.0, 4.0, 7.0, 0.0, h),
    ];
    l.flat((6.0, 2.0, 7.0, 4.0), 0.0, true);
    l.flat((2.0, 6.0, 4.0, 7.0), 0.0, true);
    // The plinth under the raised room and the solid block beside the last room.
    l.brush(v(14.0, -0.01, 0.0), v(20.0, 1.2, 6.0));
    l.brush(v(6.0, 0.0, 6.0), v(21.0, h, 14.0));
    // Outer walls.
    l.brush(v(-1.0, 0.0, -1.0), v(21.0, h, 0.0));
    l.brush(v(-1.0, 0.0, 0.0), v(0.0, h, 14.0));
    l.brush(v(0.0, 0.0, 13.0), v(6.0, h, 14.0));
    l.brush(v(20.0, 0.0, 0.0), v(21.0, h, 6.0));
    // Thick walls with doors 2 m wide: x = 6..7 and x = 13..14 (the latter's door starts
    // at the raised floor), z = 6..7 between the first room and the fourth.
    for (x, sill) in [(6.0, 0.0), (13.0, 1.2)] {
        l.brush(v(x, 0.0, 0.0), v(x + 1.0, h, 2.0));
        l.brush(v(x, 0.0, 4.0), v(x + 1.0, h, 6.0));
        l.brush(v(x, sill + 2.4, 2.0), v(x + 1.0, h, 4.0));
        if sill > 0.0 {
            l.brush(v(x, 0.0, 2.0), v(x + 1.0, sill, 4.0));
        }
    }
    l.brush(v(0.0, 0.0, 6.0), v(2.0, h, 7.0));
    l.brush(v(4.0, 0.0, 6.0), v(6.0, h, 7.0));
    l.brush(v(2.0, 2.4, 6.0), v(4.0, h, 7.0));
    // Stairs up to the raised room's door: six steps of 0.2 m, 0.3 m deep.
    for k in 1..=6 {
        let x0 = 13.0 - 0.3 * (7 - k) as f32;
        l.brush(v(x0, 0.0, 2.0), v(13.0, 0.2 * k as f32, 4.0));
    }
    (rooms, doors)
}

#[test]
fn rooms_doorways_stairs_and_thick_walls() {
    let mut l = Level::default();
    let (rooms, doors) = house(&mut l);
    let walk = assert_walks_rooms(&l.rays(), &rooms, &doors, 3);
    // Only doorways join the rooms: the walk crosses the thick walls through them.
    // The raised room is reached over the stairs.
    assert!(
        walk.waypoints.iter().any(|w| rooms[2].contains(*w)),
        "{:?}",
        walk.waypoints
    );
}

#[test]
fn double_sided_materials_count_from_either_side() {
    let mut l = Level::default();
    let rooms = row_of_rooms(&mut l, 0.0, false);
    // Every face turned the wrong way: single-sided, the rooms show only back faces.
    for t in &mut l.tris {
        t.swap(1, 2);
    }
    let mut scene = l.scene(true);
    let path = interior_path(&scene, &InteriorParams::default()).expect("walk");
    let eye = path.pose_at(0.0).eye;
    assert!(rooms.iter().any(|r| r.contains(eye)), "{eye}");
    default_if_enclosed(&mut scene);
    assert_eq!(scene.paths[0].name, PATH_NAME);
    assert!(scene.path(LIGHT_PATH_NAME).is_ok());
    // The same level single-sided has no inside: the orbit stays the default.
    let mut scene = l.scene(false);
    let err = interior_path(&scene, &InteriorParams::default()).expect_err("no inside");
    assert!(err.to_string().contains("back faces"), "{err}");
    default_if_enclosed(&mut scene);
    assert_eq!(scene.paths[0].name, "default");
}

#[test]
fn a_small_model_without_an_inside_is_told_about_the_scale() {
    // Rooms turned inside out have no inside at any size; at 1/32 of life size the reason also
    // says how high the eye would stand and that --scale magnifies a glTF file.
    let mut l = Level::default();
    row_of_rooms(&mut l, 0.0, false);
    for t in &mut l.tris {
        t.swap(1, 2);
    }
    let mut scene = l.scene(false);
    let err = interior_path(&scene, &InteriorParams::default()).expect_err("no inside");
    assert!(!err.to_string().contains("--scale"), "{err}");
    scene.magnify(1.0 / 32.0);
    let err = interior_path(&scene, &InteriorParams::default()).expect_err("no inside");
    let text = err.to_string();
    assert!(
        text.contains("back faces") && text.contains("--scale N"),
        "{text}"
    );
    // A small solid (a prop, not a level) at the same size is not told about the scale.
    let mut l = Level::default();
    l.brush(Vec3::ZERO, Vec3::new(12.0, 5.0, 12.0));
    let mut scene = l.scene(true);
    scene.magnify(1.0 / 32.0);
    let err = interior_path(&scene, &InteriorParams::default()).expect_err("no inside");
    assert!(!err.to_string().contains("--scale"), "{err}");
}

#[test]
fn a_small_level_is_told_the_scale_that_finds_its_inside() {
    // The house at 1/32 of life size has no inside at the eye height its storeys give; the
    // reason names a --scale, and the house magnified by it has one.
    let mut l = Level::default();
    house(&mut l);
    let mut scene = l.scene(false);
    scene.magnify(1.0 / 32.0);
    let err = interior_path(&scene, &InteriorParams::default()).expect_err("no inside");
    let text = err.to_string();
    let n: f32 = text
        .split("--scale ")
        .nth(1)
        .and_then(|t| t.split(' ').next())
        .and_then(|t| t.parse().ok())
        .unwrap_or_else(|| panic!("no scale named: {text}"));
    assert!(n > 1.0 && n <= 1000.0, "{text}");
    scene.magnify(n);
    interior_path(&scene, &InteriorParams::default())
        .unwrap_or_else(|e| panic!("at --scale {n}: {e}"));
}

#[test]
fn the_light_path_is_inside_above_the_eye_and_lights_the_floor() {
    let mut l = Level::default();
    let (rooms, doors) = house(&mut l);
    let rays = l.rays();
    let walk = find(&rays, &InteriorParams::default()).expect("walk");
    let light = light_path(&rays, &walk.path, &walk.scale);
    assert_eq!(light.keys.len(), walk.path.keys.len());
    let mut floors = 0;
    for (i, (k, c)) in light.keys.iter().zip(&walk.path.keys).enumerate() {
        let inside = rooms.iter().chain(&doors).any(|r| r.contains(k.eye));
        assert!(inside, "key {i}: {k:?}");
        assert!(
            k.eye.y > c.eye.y - 1e-3,
            "key {i}: {k:?} under the eye {c:?}"
        );
        let dir = (k.target - k.eye).normalize();
        let hit = rays.hit(k.eye, dir, 100.0).expect("lights something");
        assert!(hit.front, "key {i}: lights a back face {hit:?}");
        floors += usize::from(hit.normal.y > 0.7);
    }
    // Mostly the floor ahead (near a wall the axis may meet the wall first).
    assert!(
        floors * 5 >= light.keys.len() * 4,
        "{floors} of {}",
        light.keys.len()
    );
}

#[test]
fn bad_paths_are_reported_with_frame_and_position() {
    let mut l = Level::default();
    row_of_rooms(&mut l, 0.0, false);
    let rays = l.rays();
    let pose = |eye: Vec3, target: Vec3| crate::scene::CameraPose { eye, target };
    // Above the roof looking at it: back faces (ceilings seen from above) and sky.
    let over = CameraPath {
        name: PATH_NAME.into(),
        keys: vec![
            pose(Vec3::new(3.0, 8.0, 3.0), Vec3::new(3.0, 0.0, 3.5)),
            pose(Vec3::new(9.0, 8.0, 3.0), Vec3::new(9.0, 0.0, 3.5)),
        ],
    };
    let views = path_check::views(&rays, &over);
    let line = path_check::report(&over, &views, true).expect("reported");
    assert!(
        line.contains("frame") && line.contains("back faces"),
        "{line}"
    );
    assert!(!line.contains('\n'));
    // Looking up from over the roof: sky, reported only for an interior.
    let up = CameraPath {
        name: PATH_NAME.into(),
        keys: vec![pose(Vec3::new(9.0, 8.0, 3.0), Vec3::new(9.0, 20.0, 3.2))],
    };
    let v = path_check::views(&rays, &up);
    assert!(path_check::report(&up, &v, true).is_some_and(|l| l.contains("sky")));
    assert_eq!(path_check::report(&up, &v, false), None);
    // Inside a solid brush.
    let mut solid = Level::default();
    solid.brush(Vec3::ZERO, Vec3::splat(10.0));
    let inside = CameraPath {
        name: "file".into(),
        keys: vec![pose(Vec3::splat(5.0), Vec3::new(6.0, 5.0, 5.0))],
    };
    let v = path_check::views(&solid.rays(), &inside);
    let line = path_check::report(&inside, &v, false).expect("reported");
    assert!(
        line.contains("inside geometry") && line.contains("(5.00, 5.00, 5.00)"),
        "{line}"
    );
    // A good path is not reported.
    let walk = find(&rays, &InteriorParams::default()).expect("walk");
    let v = path_check::views(&rays, &walk.path);
    assert_eq!(path_check::report(&walk.path, &v, true), None);
}

#[test]
fn a_roofless_level_is_inside_between_its_walls() {
    let mut l = Level::default();
    let rooms = row_of_rooms(&mut l, 0.0, true);
    // No ceilings (a block-out), a leak in the last room's outer wall, open ground outside.
    l.tris.retain(|t| !t.iter().all(|p| p.y == 3.5));
    l.flat((18.0, -20.0, 60.0, 26.0), 0.0, true);
    assert_tours_every_room(&l.rays(), &rooms, |_, _| {});
}

/// Finds the walk over `rays` and checks that every frame stands in one of `rooms` (and
/// passes `each(frame, eye)`), every room is visited and no view has a problem.
fn assert_tours_every_room(
    rays: &TriangleScene,
    rooms: &[Room],
    each: impl Fn(u32, Vec3),
) -> InteriorWalk {
    let walk = find(rays, &InteriorParams::default()).expect("an interior walk");
    let path = &walk.path;
    let mut visited = vec![false; rooms.len()];
    for f in 0..=path.natural_frames() {
        let eye = path.pose_at(f as f32).eye;
        let k = rooms.iter().position(|r| r.contains(eye));
        let k = k.unwrap_or_else(|| panic!("frame {f}: {eye} is outside the rooms"));
        visited[k] = true;
        each(f, eye);
    }
    assert!(visited.iter().all(|v| *v), "waypoints {:?}", walk.waypoints);
    for v in path_check::views(rays, path) {
        assert_eq!(v.problem(true), None, "{v:?}");
    }
    walk
}

#[test]
fn a_roofless_furnished_house_is_walked_at_eye_height_on_its_floors() {
    let mut l = Level::default();
    let rooms = row_of_rooms(&mut l, 0.0, false);
    l.tris.retain(|t| !t.iter().all(|p| p.y == 3.5));
    // Furniture: in every room a table (a top 0.7 m up: its underside is the only ceiling
    // in the house) and a sofa against a wall; in the middle room a bed between the doors.
    for r in &rooms {
        let x = r.min.x;
        l.brush(Vec3::new(x + 0.8, 0.7, 0.8), Vec3::new(x + 2.0, 0.75, 1.6));
        l.brush(Vec3::new(x + 4.2, 0.7, 4.4), Vec3::new(x + 5.4, 0.75, 5.2));
        l.brush(Vec3::new(x + 1.0, 0.0, 5.2), Vec3::new(x + 3.0, 0.45, 5.9));
    }
    l.brush(Vec3::new(8.0, 0.0, 2.2), Vec3::new(10.0, 0.5, 3.8));
    // On the floor, never on a table, the sofas or the bed.
    let walk = assert_tours_every_room(&l.rays(), &rooms, |f, eye| {
        assert!(
            (eye.y - 1.7).abs() < 0.05,
            "frame {f}: eye {eye} is not at eye height over the floor"
        );
    });
    // The storey comes from the walls, not from the tables' undersides.
    assert!(
        (walk.scale.eye_height - 1.7).abs() < 1e-3,
        "{:?}",
        walk.scale
    );
}

#[test]
fn furniture_tops_are_told_from_stairs_and_floors() {
    // The house with its stairs and raised room, a bed in the first room and a table in
    // the fourth: the places on the bed are furniture, no other place is.
    let mut l = Level::default();
    let (rooms, _) = house(&mut l);
    let bed = Room::new(2.0, 2.0, 4.0, 3.6, 0.0, 0.5);
    let table = Room::new(2.0, 9.0, 3.5, 10.0, 0.7, 0.75);
    for b in [bed, table] {
        l.brush(b.min, b.max);
    }
    let rays = l.rays();
    let s = places::scale(&rays, None, None, 256);
    let (found, _) = places::places(&rays, &places::floors(&rays, s.cell), &s);
    let adj = walk::neighbours(&rays, &found, &s);
    let top = walk::on_furniture(&found, &adj, &s);
    let on = |r: &Room, p: &Place| {
        (p.floor.y - r.max.y).abs() < 1e-3
            && (r.min.x..=r.max.x).contains(&p.floor.x)
            && (r.min.z..=r.max.z).contains(&p.floor.z)
    };
    // The table stands higher than a step: its top is joined to no floor (not walked to), and
    // left as it is.
    let mut tops = 0;
    for (p, t) in found.iter().zip(&top) {
        assert_eq!(*t, on(&bed, p), "{p:?}");
        tops += usize::from(*t);
    }
    assert!(tops > 0, "no place on the bed");
    assert!(found.iter().any(|p| on(&table, p)), "no place on the table");
    // The raised room and the stairs have places, none of them furniture.
    assert!(found.iter().any(|p| rooms[2].contains(p.eye)));
    assert!(found
        .iter()
        .any(|p| p.floor.x > 11.0 && p.floor.x < 13.0 && p.floor.y > 0.1));
}

#[test]
fn the_tour_walks_around_a_bed_rather_than_over_it() {
    // A bed between two places: two steps over it, or four around it on the floor.
    let place = |x: f32, z: f32, y: f32| Place {
        cell: (x as i32, z as i32),
        floor: Vec3::new(x, y, z),
        eye: Vec3::new(x, y + 1.7, z),
        openness: 5.0,
        nearest: 2.0,
    };
    let found = [
        place(0.0, 0.0, 0.0),
        place(1.0, 0.0, 0.5),
        place(2.0, 0.0, 0.0),
        place(0.0, 1.0, 0.0),
        place(1.0, 1.0, 0.0),
        place(2.0, 1.0, 0.0),
    ];
    // 0 - 1 (bed) - 2, and 0 - 3 - 4 - 5 - 2 around it.
    let edges = [(0, 1), (1, 2), (0, 3), (3, 4), (4, 5), (5, 2)];
    let mut adj = vec![Vec::new(); found.len()];
    for (a, b) in edges {
        adj[a].push(b);
        adj[b].push(a);
    }
    let (over, _) = walk::dijkstra(&found, &adj, &[0], 1.7, 0.0);
    assert_eq!(
        over[2], 1,
        "without a cost for climbing the shortest way is over the bed"
    );
    let (around, _) = walk::dijkstra(&found, &adj, &[0], 1.7, walk::CLIMB_COST);
    assert_eq!(around[2], 5, "the tour steps around the bed");
}

#[test]
fn gi_walks_the_interior_path_with_its_light_a_key_ahead() {
    use crate::app::gi_run::{walking_path, GiSetup};
    let mut l = Level::default();
    let _ = row_of_rooms(&mut l, 0.0, false);
    let mut scene = l.scene(false);
    default_if_enclosed(&mut scene);
    let walk = walking_path(&scene, &GiSetup::default()).expect("the camera walks");
    assert_eq!(walk.name, PATH_NAME);
    assert!(walk.keys.len() >= 3, "{} keys", walk.keys.len());
    let light = scene.path(LIGHT_PATH_NAME).expect("a light path").clone();
    assert_eq!(light.keys.len(), walk.keys.len());
    for (lamp, eye) in light.keys.iter().zip(walk.keys.iter().skip(1)) {
        let ahead = (lamp.eye - eye.eye).with_y(0.0).length();
        assert!(ahead < 1e-4 && lamp.eye.y > eye.eye.y, "{lamp:?} {eye:?}");
    }
    // The user's camera or light: the camera stands.
    let camera = GiSetup {
        camera: Some(walk.keys[0]),
        ..GiSetup::default()
    };
    assert!(walking_path(&scene, &camera).is_none());
    let lamp = GiSetup {
        light_keys: Some(light),
        ..GiSetup::default()
    };
    assert!(walking_path(&scene, &lamp).is_none());
}

#[test]
fn a_closed_double_sided_solid_is_not_a_room() {
    // A large block whose material is double-sided: its inside sees front faces only, but it
    // is a solid (closed, facing out), so it has no inside.
    let mut l = Level::default();
    l.brush(Vec3::ZERO, Vec3::new(12.0, 5.0, 12.0));
    let scene = l.scene(true);
    let err = interior_path(&scene, &InteriorParams::default()).expect_err("no inside");
    assert!(err.to_string().contains("no inside"), "{err}");
    let rays = TriangleScene::new(&scene).expect("triangles");
    let inside = rays.hit(Vec3::splat(3.0), Vec3::X, 100.0).expect("a wall");
    assert!(!inside.front, "{inside:?}");
    // The same block turned inside out is a room (a closed shell seen from within).
    for t in &mut l.tris {
        t.swap(1, 2);
    }
    let walk = find(
        &TriangleScene::new(&l.scene(true)).expect("triangles"),
        &InteriorParams::default(),
    );
    assert!(walk.is_ok(), "{:?}", walk.err());
}

#[test]
fn a_shell_narrower_than_the_near_plane_has_no_inside() {
    // The room of a closed shell (above) at the size of a can: its eye would stand closer to
    // the walls than the camera's near plane, which would cut them away, so it is no inside.
    let mut l = Level::default();
    l.brush(Vec3::ZERO, Vec3::new(12.0, 5.0, 12.0));
    for t in &mut l.tris {
        t.swap(1, 2);
    }
    let mut scene = l.scene(true);
    scene.magnify(0.012);
    let err = interior_path(&scene, &InteriorParams::default()).expect_err("no inside");
    assert!(err.to_string().contains("too close to geometry"), "{err}");
    // Ten times larger (a box 1.4 wide) it is a room again.
    scene.magnify(10.0);
    interior_path(&scene, &InteriorParams::default()).expect("a room");
}

/// Summary of the interior walk of each glTF file in `COHERENT_LEVELS` (colon-separated):
/// `COHERENT_LEVELS=a.glb:b.gltf cargo test --release --lib interior::tests::levels -- --ignored --nocapture`.
#[test]
#[ignore = "needs glTF files named in COHERENT_LEVELS"]
fn levels() {
    let list = std::env::var("COHERENT_LEVELS").unwrap_or_default();
    for file in list.split(':').filter(|f| !f.is_empty()) {
        let (scene, _) = crate::scene::gltf::load_gltf(std::path::Path::new(file)).expect("load");
        let rays = TriangleScene::new(&scene).expect("triangles");
        let t = std::time::Instant::now();
        let walk = find(&rays, &InteriorParams::default());
        match &walk {
            Ok(w) => {
                let views = path_check::views(&rays, &w.path);
                let worst = views.iter().map(|v| v.sky).fold(0.0f32, f32::max);
                let one = views.iter().map(|v| v.one_colour).fold(0.0f32, f32::max);
                let keys: Vec<String> = w
                    .path
                    .keys
                    .iter()
                    .enumerate()
                    .map(|(k, p)| (k, path_check::view_at(&rays, p, 30 * k as u32).one_colour))
                    .filter(|(_, s)| *s > 0.4)
                    .map(|(k, s)| format!("{k}:{s:.2}"))
                    .collect();
                let frames: Vec<String> = views
                    .iter()
                    .filter(|v| v.one_colour > 0.4)
                    .map(|v| format!("{}:{:.2}", v.frame, v.one_colour))
                    .collect();
                println!("  keys over 40% one colour: {keys:?}; frames: {frames:?}");
                println!(
                    "{file}: {} tris, bounds {:?}, {:?}, {} places, part {}, {} keys, {} frames, \
                     waypoints {:?}, worst sky {worst:.2}, most one colour {one:.2}, check {:?} \
                     ({:.1} s)",
                    rays.len(),
                    rays.bounds,
                    w.scale,
                    w.places,
                    w.part,
                    w.path.keys.len(),
                    w.path.natural_frames(),
                    w.waypoints,
                    path_check::report(&w.path, &views, true),
                    t.elapsed().as_secs_f32()
                );
            }
            Err(why) => println!("{file}: no inside: {why}"),
        }
        let Ok(w) = walk else { continue };
        {
            // Every frame of the walk, on the path check's grid of rays.
            let n = w.path.natural_frames() as usize;
            let shares = crate::parallel::map(n + 1, |f| {
                path_check::one_colour_at(&rays, &w.path.pose_at(f as f32), path_check::VIEW_RAYS)
            });
            let over = shares.iter().filter(|&&s| s > 0.4).count();
            let most = shares.iter().cloned().fold(0.0f32, f32::max);
            println!(
                "  every frame: {over} of {} over 40% one colour, most {most:.2}",
                n + 1
            );
        }
        {
            let n = w.path.natural_frames();
            for k in 0..6 {
                let pose = w.path.pose_at((n * k / 5) as f32);
                let d = (pose.target - pose.eye).normalize();
                let hit = rays.hit(pose.eye, d, 1e4);
                let view = path_check::view_at(&rays, &pose, n * k / 5);
                println!(
                    "  frame {}: eye {:.2} dir {:.2} ahead {:?} one colour {:.2}",
                    n * k / 5,
                    pose.eye,
                    d,
                    hit.map(|h| (h.t, h.front)),
                    view.one_colour
                );
            }
        }
    }
}

#[test]
fn one_colour_counts_flat_sides_the_sky_and_both_of_coplanar_surfaces() {
    // Seen from 2 above, straight down: a 4 x 4 floor (blue) under a 60° field of view covers
    // the whole view; its west half has a red twin in the same plane, its south-east quarter
    // is textured (no flat colour).
    let quad = |x0: f32, z0: f32, x1: f32, z1: f32| {
        let c = [(x0, z0), (x1, z0), (x1, z1), (x0, z1)].map(|(x, z)| Vec3::new(x, 0.0, z));
        [[c[0], c[2], c[1]], [c[0], c[3], c[2]]]
    };
    let (blue, red) = (Vec3::new(0.2, 0.3, 0.9), Vec3::new(0.9, 0.1, 0.1));
    let sun = crate::scene::gltf::DEFAULT_SUN.normalize();
    let flat = |c: Vec3| {
        Some([
            rays::flat_colour(c, Vec3::Y, sun),
            rays::flat_colour(c, Vec3::NEG_Y, sun),
        ])
    };
    let mut tris = Vec::new();
    let mut colours = Vec::new();
    for (t, c) in [
        (quad(-20.0, -20.0, 0.0, 20.0), flat(blue)),
        (quad(0.0, -20.0, 20.0, 0.0), flat(blue)),
        (quad(0.0, 0.0, 20.0, 20.0), None),
        (quad(-20.0, -20.0, 0.0, 20.0), flat(red)),
    ] {
        assert!((t[0][1] - t[0][0]).cross(t[0][2] - t[0][0]).y > 0.0);
        tris.extend(t);
        colours.extend([c, c]);
    }
    let rays = TriangleScene::build(&tris, &[], &colours).expect("triangles");
    let eye = Vec3::new(0.0, 2.0, 0.0);
    let dirs: Vec<Vec3> = (0..16)
        .flat_map(|j| (0..16).map(move |i| (i, j)))
        .map(|(i, j)| Vec3::new(i as f32 - 7.5, -20.0, j as f32 - 7.5).normalize())
        .collect();
    // Blue: the west half (under its red twin) and the north-east quarter, 3/4 of the rays.
    assert_eq!(rays.one_colour_share(eye, &dirs, 100.0), 192.0 / 256.0);
    // Without the north-east blue quarter: the west half in blue and in red, 1/2 each.
    let rays = TriangleScene::build(
        &[&tris[..2], &tris[4..]].concat(),
        &[],
        &[&colours[..2], &colours[4..]].concat(),
    )
    .expect("triangles");
    assert_eq!(rays.one_colour_share(eye, &dirs, 100.0), 128.0 / 256.0);
    // Looking up: every ray sees the sky, one colour.
    let up: Vec<Vec3> = dirs.iter().map(|&d| -d).collect();
    assert_eq!(rays.one_colour_share(eye, &up, 100.0), 1.0);
    // From below the single-sided floor: back faces are no colour; the sky past its edges is.
    let under = Vec3::new(0.0, -1.0, 0.0);
    let below = rays.probe(under, &up, 100.0);
    assert!(below.back > 0 && below.escaped > 0, "{below:?}");
    assert_eq!(
        rays.one_colour_share(under, &up, 100.0),
        below.escaped as f32 / 256.0
    );
}

#[test]
fn an_unlit_material_is_its_colour_on_either_side() {
    // Two floor slabs of one colour side by side, the east one unlit: seen from above, the
    // west one is lit as the forward pass lights it, the east one is its colour, gamma 2.2.
    let mut b = SceneBuilder::new("unlit");
    let colour = Vec3::new(0.5, 0.25, 0.1);
    b.add(
        &Mesh::cuboid(Vec3::new(-4.0, -0.1, -2.0), Vec3::new(0.0, 0.0, 2.0)),
        colour,
    );
    b.add(
        &Mesh::cuboid(Vec3::new(0.0, -0.1, -2.0), Vec3::new(4.0, 0.0, 2.0)),
        colour,
    );
    let mut scene = b.finish();
    scene.materials.push(Material {
        unlit: true,
        ..Material::default()
    });
    scene.objects[1].material = Some(0);
    let rays = TriangleScene::new(&scene).expect("triangles");
    let down = |x: f32| {
        rays.hit(Vec3::new(x, 3.0, 0.3), Vec3::NEG_Y, 10.0)
            .expect("a hit")
    };
    let gamma = colour
        .powf(1.0 / 2.2)
        .to_array()
        .map(|c| (c * 255.0).round() as u8);
    assert_eq!(down(2.0).colour, Some(gamma));
    let lit = rays::flat_colour(colour, Vec3::Y, scene.sun_dir);
    assert_eq!(down(-2.0).colour, Some(lit));
    assert_ne!(lit, gamma);
}

#[test]
fn the_walk_looks_away_from_views_of_one_colour() {
    // Untextured grey rooms: floors, ceilings and the walls facing one way are each one flat
    // colour, so many views are mostly one colour. The walk's views (from the path check's
    // rays) fill more than 40% of the image with one colour in less than a third as many
    // sampled frames as with the rule turned off.
    let over = |l: &Level, most: f32| {
        let rays = l.rays();
        let params = InteriorParams {
            one_colour_most: most,
            ..Default::default()
        };
        let w = find(&rays, &params).expect("walk");
        let views = path_check::views(&rays, &w.path);
        views.iter().filter(|v| v.one_colour > 0.4).count()
    };
    let mut house_level = Level::default();
    let _ = house(&mut house_level);
    let mut rooms = Level::default();
    let _ = row_of_rooms(&mut rooms, 0.0, false);
    for l in [&house_level, &rooms] {
        let (with, without) = (
            over(l, InteriorParams::default().one_colour_most),
            over(l, 1.0),
        );
        assert!(
            3 * with < without,
            "{with} frames over 40% one colour, {without} without the rule"
        );
    }
}

/// On a large scene the path check builds its rays from the objects near the path only: the
/// ray scene then holds exactly the triangles of the objects whose bounds meet the region,
/// and the region holds every eye of the path.
#[test]
fn the_ray_scene_near_a_region_holds_the_objects_that_meet_it() {
    let scene = Scene::load("city", 0.1, 4096).expect("city");
    let all = TriangleScene::new(&scene).expect("triangles");
    let region = scene.objects[0].bounds.enlarged(1.0);
    let kept: u64 = scene
        .objects
        .iter()
        .filter(|o| o.bounds.overlaps(&region))
        .map(|o| o.triangle_count())
        .sum();
    let near = TriangleScene::near(&scene, &region).expect("triangles");
    assert_eq!(near.len() as u64, kept);
    assert!(near.len() < all.len(), "{} of {}", near.len(), all.len());
    let path = scene.path("street").expect("street");
    let local = path_check::local_region(path);
    assert!(path.keys.iter().all(|k| local.contains(k.eye)));
}

#[test]
fn turns_are_judged_every_few_frames_and_mended() {
    // Untextured grey rooms (see above): judged every third frame rather than at the keys and
    // a few frames between, the worst view of the walk shows at most 60% of one colour (0.92
    // in the house and 0.84 in the row of rooms when turns are not mended: the camera sweeps
    // past a wall close ahead while it turns).
    let mut house_level = Level::default();
    let _ = house(&mut house_level);
    let mut rooms = Level::default();
    let _ = row_of_rooms(&mut rooms, 0.0, false);
    for l in [&house_level, &rooms] {
        let rays = l.rays();
        let w = find(&rays, &InteriorParams::default()).expect("walk");
        let worst = (0..=w.path.natural_frames())
            .step_by(3)
            .map(|f| {
                let pose = w.path.pose_at(f as f32);
                (
                    path_check::one_colour_at(&rays, &pose, path_check::VIEW_RAYS),
                    f,
                )
            })
            .fold((0.0f32, 0), |a, b| if b.0 > a.0 { b } else { a });
        assert!(
            worst.0 <= 0.6,
            "frame {} is {:.2} one colour",
            worst.1,
            worst.0
        );
    }
}

/// A fresh directory in the system's temp directory for one test.
fn temp_dir(test: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("coherent_interior_{}_{test}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

#[test]
fn the_walk_is_kept_in_the_cache_and_read_back_unchanged() {
    let mut l = Level::default();
    row_of_rooms(&mut l, 0.0, false);
    let fresh = l.scene(false);
    let mut found = fresh.clone();
    default_if_enclosed(&mut found);
    assert_eq!(found.paths[0].name, PATH_NAME);
    let dir = temp_dir("kept");
    let mut first = fresh.clone();
    let file = match default_if_enclosed_cached(&mut first, &dir) {
        Some(cache::Source::Found(Some(file))) => file,
        other => panic!("{other:?}"),
    };
    assert_eq!(first.paths, found.paths);
    let mut second = fresh.clone();
    let source = default_if_enclosed_cached(&mut second, &dir);
    assert_eq!(source, Some(cache::Source::Cached(file.clone())));
    assert_eq!(second.paths, found.paths);
    // Another scene (one room wall moved) has another key and finds its own walk.
    let mut moved = fresh.clone();
    moved.vertices[0].position[0] += 0.5;
    let source = default_if_enclosed_cached(&mut moved, &dir);
    assert!(
        matches!(source, Some(cache::Source::Found(Some(ref f))) if *f != file),
        "{source:?}"
    );
    // So do other parameters.
    let params = InteriorParams {
        waypoints: 3,
        ..InteriorParams::default()
    };
    assert_ne!(
        cache::key(&fresh, &params),
        cache::key(&fresh, &InteriorParams::default())
    );
    std::fs::remove_dir_all(&dir).expect("clean up");
}

#[test]
fn a_scene_without_an_inside_is_kept_too() {
    let mut l = Level::default();
    row_of_rooms(&mut l, 0.0, false);
    for t in &mut l.tris {
        t.swap(1, 2);
    }
    let fresh = l.scene(false);
    let dir = temp_dir("no_inside");
    for expect_cached in [false, true] {
        let mut scene = fresh.clone();
        let source = default_if_enclosed_cached(&mut scene, &dir).expect("triangles");
        assert_eq!(matches!(source, cache::Source::Cached(_)), expect_cached);
        assert_eq!(scene.paths[0].name, "default");
        assert!(scene.path(LIGHT_PATH_NAME).is_err());
    }
    std::fs::remove_dir_all(&dir).expect("clean up");
}

#[test]
fn a_damaged_cache_file_is_replaced_and_an_unwritable_cache_costs_only_time() {
    let mut l = Level::default();
    row_of_rooms(&mut l, 0.0, false);
    let fresh = l.scene(false);
    let mut found = fresh.clone();
    default_if_enclosed(&mut found);
    let dir = temp_dir("damaged");
    let key = cache::key(&fresh, &InteriorParams::default());
    let file = cache::file(&dir, &key);
    let mut scene = fresh.clone();
    default_if_enclosed_cached(&mut scene, &dir);
    let good = std::fs::read_to_string(&file).expect("cache file");
    let nan = good.replacen("[[", "[[NaN,", 1);
    let damaged = [
        (good[..good.len() / 2].to_string(), "not JSON"),
        (good.replace(&key, "interior v0"), "another scene"),
        (good.replacen("[[", "[[1e39,", 1), "six finite numbers"),
        (nan, "not JSON"),
        (good.replace("\"light\"", "\"lamp\""), "no \"light\" array"),
        ("{\"key\":\"K\"}".replace('K', &key), "no \"camera\" array"),
    ];
    for (text, why) in damaged {
        let err = cache::parse(&text, &key).expect_err(why);
        assert!(err.contains(why), "{err}");
        std::fs::write(&file, &text).expect("damage");
        let mut scene = fresh.clone();
        let source = default_if_enclosed_cached(&mut scene, &dir);
        assert_eq!(
            source,
            Some(cache::Source::Found(Some(file.clone()))),
            "{why}"
        );
        assert_eq!(scene.paths, found.paths, "{why}");
        assert_eq!(std::fs::read_to_string(&file).expect("rewritten"), good);
    }
    // A file where the directory should be: nothing is kept, the walk is found all the same.
    std::fs::remove_dir_all(&dir).expect("clean up");
    std::fs::write(&dir, b"not a directory").expect("file");
    let mut scene = fresh.clone();
    let source = default_if_enclosed_cached(&mut scene, &dir);
    assert_eq!(source, Some(cache::Source::Found(None)));
    assert_eq!(scene.paths, found.paths);
    std::fs::remove_file(&dir).expect("clean up");
}

#[test]
fn the_interior_path_a_scene_lacks_is_read_from_the_same_cache() {
    // `--path interior` on a scene without the walk (a built-in one) goes through the cache
    // that a glTF file's default walk uses: the first resolve finds and keeps it, later ones
    // read the file.
    let mut l = Level::default();
    row_of_rooms(&mut l, 0.0, false);
    let scene = l.scene(false);
    assert!(scene.path(PATH_NAME).is_err());
    let dir = temp_dir("resolve");
    let direct = scene.resolve_path(Some(PATH_NAME)).expect("walk");
    let first = scene
        .resolve_path_cached(Some(PATH_NAME), &dir)
        .expect("walk");
    assert_eq!(first, direct);
    let key = cache::key(&scene, &InteriorParams::default());
    let file = cache::file(&dir, &key);
    let Ok(Some(Outcome::Walk { camera, light })) = cache::load(&file, &key) else {
        panic!("no walk kept in {}", file.display());
    };
    assert_eq!(camera, direct);
    // What the file holds is what a later resolve returns, and what the default walk is.
    let reversed = CameraPath {
        keys: camera.keys.iter().rev().copied().collect(),
        ..camera
    };
    let outcome = Outcome::Walk {
        camera: reversed.clone(),
        light,
    };
    cache::save(&file, &key, &outcome).expect("save");
    let again = scene
        .resolve_path_cached(Some(PATH_NAME), &dir)
        .expect("walk");
    assert_eq!(again, reversed);
    let mut with_default = scene.clone();
    let source = default_if_enclosed_cached(&mut with_default, &dir);
    assert_eq!(source, Some(cache::Source::Cached(file)));
    assert_eq!(with_default.paths[0], reversed);
    std::fs::remove_dir_all(&dir).expect("clean up");
}

#[test]
fn the_path_checks_verdict_is_kept_in_the_cache_and_said_again() {
    let mut l = Level::default();
    row_of_rooms(&mut l, 0.0, false);
    let scene = l.scene(false);
    let pose = |eye: Vec3, target: Vec3| crate::scene::CameraPose { eye, target };
    // A bad path (above the roof, looking down at the ceilings' backs) and a good one.
    let over = CameraPath {
        name: "over".into(),
        keys: vec![
            pose(Vec3::new(3.0, 8.0, 3.0), Vec3::new(3.0, 0.0, 3.5)),
            pose(Vec3::new(9.0, 8.0, 3.0), Vec3::new(9.0, 0.0, 3.5)),
        ],
    };
    let walk = interior_path(&scene, &InteriorParams::default()).expect("walk");
    let dir = temp_dir("path_check");
    for (path, bad) in [(&over, true), (&walk, false)] {
        let expected = path_check::check(&scene, path);
        assert_eq!(expected.is_some(), bad, "{expected:?}");
        let key = path_check::cache_key(&scene, path);
        let file = path_check::cache_file(&dir, &key);
        let first = path_check::warn_if_bad_cached(&scene, path, &dir);
        assert_eq!(first, cache::Source::Found(Some(file.clone())));
        // The file holds the verdict, the report's line itself for a bad path.
        let kept = path_check::load_verdict(&file, &key).expect("readable");
        assert_eq!(kept, Some(expected.clone()));
        let second = path_check::warn_if_bad_cached(&scene, path, &dir);
        assert_eq!(second, cache::Source::Cached(file.clone()));
    }
    // Another path, or the same path on a scene with one vertex moved, has another key.
    let mut moved = scene.clone();
    moved.vertices[0].position[0] += 0.5;
    let mut later = over.clone();
    later.keys[1].eye.y += 0.25;
    let key = path_check::cache_key(&scene, &over);
    assert_ne!(key, path_check::cache_key(&moved, &over));
    assert_ne!(key, path_check::cache_key(&scene, &later));
    assert_ne!(key, path_check::cache_key(&scene, &walk));
    // The commands' way in: resolving a path with a cache directory keeps its verdict.
    let resolved = scene
        .resolve_path_cached(Some(PATH_NAME), &dir)
        .expect("walk");
    let file = path_check::cache_file(&dir, &path_check::cache_key(&scene, &resolved));
    let kept = path_check::load_verdict(&file, &path_check::cache_key(&scene, &resolved));
    assert!(matches!(kept, Ok(Some(None))), "{kept:?}");
    // A file that cannot be trusted is refused with its reason, checked again and rewritten.
    let key = path_check::cache_key(&scene, &over);
    let file = path_check::cache_file(&dir, &key);
    let good = std::fs::read_to_string(&file).expect("cache file");
    let damaged = [
        (good[..good.len() / 2].to_string(), "not JSON"),
        (good.replace(&key, "path check v0"), "another scene"),
        (
            format!("{{\"key\":\"{key}\",\"report\":5}}"),
            "neither null",
        ),
        (
            format!("{{\"key\":\"{key}\",\"report\":\"a\\nb\"}}"),
            "one short line",
        ),
        (format!("{{\"key\":\"{key}\"}}"), "no \"report\""),
    ];
    for (text, why) in damaged {
        let err = path_check::parse_verdict(&text, &key).expect_err(why);
        assert!(err.contains(why), "{err}");
        std::fs::write(&file, &text).expect("damage");
        let source = path_check::warn_if_bad_cached(&scene, &over, &dir);
        assert_eq!(source, cache::Source::Found(Some(file.clone())), "{why}");
        assert_eq!(std::fs::read_to_string(&file).expect("rewritten"), good);
    }
    // A file where the directory should be: nothing is kept, the path is checked all the same.
    std::fs::remove_dir_all(&dir).expect("clean up");
    std::fs::write(&dir, b"not a directory").expect("file");
    let source = path_check::warn_if_bad_cached(&scene, &over, &dir);
    assert_eq!(source, cache::Source::Found(None));
    std::fs::remove_file(&dir).expect("clean up");
}

/// One traversal finds a hit's coplanar twin as a second cast over the window around the
/// hit does: on triangles of random sizes and colours, half of them with a twin in their
/// plane (the same corners in another order, or shifted along the normal by less than the
/// window), some of another colour and some facing away, seen along rays all around.
#[test]
fn the_twin_of_one_traversal_is_that_of_a_second_cast() {
    let mut rng = coherent_cull::rng::Rng::new(11);
    let mut v = |r: f32| Vec3::new(rng.range(-r, r), rng.range(-r, r), rng.range(-r, r));
    let palette = [[200, 40, 40], [40, 200, 40], [40, 40, 200], [90, 90, 90]];
    let (mut tris, mut colours) = (Vec::new(), Vec::new());
    for k in 0..1200usize {
        let c = v(20.0);
        let t = [c + v(2.0), c + v(2.0), c + v(2.0)];
        let colour = |j: usize| {
            let (a, b) = (palette[j % 4], palette[(j + 1) % 4]);
            (j % 5 != 4).then_some([a, b])
        };
        tris.push(t);
        colours.push(colour(k));
        let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero();
        match k % 4 {
            // The same plane, the same colour or another, wound the same way.
            0 => {
                tris.push([t[1], t[2], t[0]]);
                colours.push(colour(k / 4));
            }
            // Facing away.
            1 => {
                tris.push([t[0], t[2], t[1]]);
                colours.push(colour(k + 1));
            }
            // Shifted along the normal, inside the window or just outside it.
            2 => {
                let d = n * if k % 8 == 2 { 1e-5 } else { 0.05 };
                tris.push(t.map(|p| p + d));
                colours.push(colour(k + 2));
            }
            _ => {}
        }
    }
    let rays = TriangleScene::build(&tris, &[], &colours).expect("triangles");
    let (mut hits, mut twins) = (0, 0);
    for _ in 0..30 {
        let eye = v(24.0);
        for d in rays::sphere_dirs(400) {
            let one = rays.hit_and_twin(eye, d, 100.0);
            let hit = rays.hit(eye, d, 100.0);
            assert_eq!(one.map(|o| o.0), hit, "from {eye} along {d}");
            if let (Some((h, twin)), Some(_)) = (one, hit) {
                assert_eq!(
                    twin,
                    rays.twin_by_second_cast(eye, d, &h),
                    "from {eye} along {d}"
                );
                hits += 1;
                twins += usize::from(twin.is_some());
            }
        }
    }
    // Enough of both to mean something.
    assert!(
        hits > 2000 && twins > 100,
        "{hits} hits, {twins} with a twin of another colour"
    );
}

/// What [`same_rays`] counted.
struct SameRays {
    hits: usize,
    back: usize,
    near: usize,
}

/// Asserts that `placed` and `world` give the same hit (all but the triangle's id, which
/// each numbers its own way) along every one of `dirs` from every one of `points` (up to
/// `far`), and the same answer to whether geometry lies within each of `radii` of each
/// point. Counts the hits, those on back faces, and the points within a radius.
fn same_rays(
    name: &str,
    placed: &TriangleScene,
    world: &TriangleScene,
    points: &[Vec3],
    dirs: &[Vec3],
    far: f32,
    radii: &[f32],
) -> SameRays {
    let strip = |h: Option<rays::Hit>| h.map(|h| rays::Hit { triangle: 0, ..h });
    let mut same = SameRays {
        hits: 0,
        back: 0,
        near: 0,
    };
    for &p in points {
        for &d in dirs {
            let w = strip(world.hit(p, d, far));
            assert_eq!(
                strip(placed.hit(p, d, far)),
                w,
                "{name}: from {p} along {d}"
            );
            same.hits += usize::from(w.is_some());
            same.back += usize::from(w.is_some_and(|h| !h.front));
        }
        for &r in radii {
            let inside = world.within(p, r);
            assert_eq!(placed.within(p, r), inside, "{name}: {p} within {r}");
            same.near += usize::from(inside);
        }
    }
    same
}

/// Objects that share a mesh keep it once and are placed by their transforms: every hit (its
/// distance, side, normal and flat colour), every distance query and the bounds are those of
/// one world-space BVH over all the triangles, on each built-in scene that shares meshes.
/// Rays from points inside solids meet coincident surfaces (a box's bottom on the ground):
/// there the one that faces the ray wins in both, whichever the BVH meets first.
#[test]
fn placed_meshes_give_the_hits_of_world_space_triangles() {
    for (name, scale) in [("city", 0.3), ("parking", 0.3), ("powerplant", 0.3)] {
        let scene = Scene::load(name, scale, 4096).expect(name);
        let placed = TriangleScene::placing(&scene).expect("triangles");
        let world = TriangleScene::world_only(&scene).expect("triangles");
        assert!(
            placed.placed() > scene.objects.len() / 2,
            "{name}: {}",
            placed.placed()
        );
        assert_eq!(world.placed(), 0);
        assert_eq!(placed.len(), world.len(), "{name}");
        assert_eq!(placed.bounds, world.bounds, "{name}");
        // Eyes along the scene's paths and points spread through its bounds, some inside
        // solids.
        let b = world.bounds;
        let mut points: Vec<Vec3> = scene
            .paths
            .iter()
            .flat_map(|p| p.keys.iter().map(|k| k.eye))
            .collect();
        let mut seed = 0x9e37_79b9_u32;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            seed as f32 / u32::MAX as f32
        };
        for _ in 0..150 {
            let f = Vec3::new(next(), next() * 0.3, next());
            points.push(b.min + f * b.extent());
        }
        let dirs = rays::sphere_dirs(96);
        let far = b.extent().length() * 2.0;
        let same = same_rays(
            name,
            &placed,
            &world,
            &points,
            &dirs,
            far,
            &[0.05, 0.3, 1.5],
        );
        for &p in &points {
            assert_eq!(
                placed.one_colour_and_back(p, &dirs, far),
                world.one_colour_and_back(p, &dirs, far),
                "{name}: from {p}"
            );
        }
        let (hits, near) = (same.hits, same.near);
        assert!(hits > points.len() * dirs.len() / 2, "{name}: {hits} hits");
        assert!(near > 0, "{name}: no point near geometry");
    }
}

/// Placed meshes under every kind of transform a glTF node may carry (turned, stretched,
/// mirrored, which turns the winding over), with single- and double-sided materials: every
/// hit and distance query equals the all-world-space scene's, and a mirrored closed solid is
/// still seen from outside only.
#[test]
fn placed_meshes_under_mirrors_and_stretches_hit_as_in_world_space() {
    use glam::Quat;
    let mut b = SceneBuilder::new("placed");
    let sphere = b.proto(&Mesh::sphere(16, 8));
    let pipe = b.proto(&Mesh::cylinder(32));
    b.add(
        &Mesh::cuboid(Vec3::new(-30.0, -0.1, -30.0), Vec3::new(30.0, 0.0, 30.0)),
        Vec3::ONE,
    );
    let transforms = [
        Mat4::from_translation(Vec3::new(-8.0, 1.0, 0.0)),
        Mat4::from_scale_rotation_translation(
            Vec3::new(3.0, 1.0, 0.5),
            Quat::from_rotation_y(0.7),
            Vec3::new(0.0, 2.0, 6.0),
        ),
        Mat4::from_translation(Vec3::new(6.0, 1.5, -5.0))
            * Mat4::from_scale(Vec3::new(-2.0, 1.5, 2.0)),
        Mat4::from_rotation_translation(Quat::from_rotation_z(1.2), Vec3::new(10.0, 3.0, 8.0))
            * Mat4::from_scale(Vec3::new(1.0, -1.0, 4.0)),
    ];
    for (i, &t) in transforms.iter().enumerate() {
        b.instance(sphere, t, Vec3::new(0.8, 0.3, 0.2));
        b.instance(
            pipe,
            Mat4::from_translation(Vec3::new(0.0, 0.0, -12.0 + i as f32)) * t,
            Vec3::ONE,
        );
    }
    b.path("default", &[(Vec3::new(0.0, 5.0, 20.0), Vec3::ZERO); 2]);
    let mut scene = b.finish();
    scene.materials.push(Material {
        double_sided: true,
        ..Material::default()
    });
    // Every other object double-sided: the spheres and pipes are closed solids, so they stay
    // one-sided from outside; the ground slab too.
    for o in scene.objects.iter_mut().skip(1).step_by(2) {
        o.material = Some(0);
    }
    // Every other pipe unlit: its flat colours, placed or in world space, are its colour.
    scene.materials.push(Material {
        unlit: true,
        ..Material::default()
    });
    for o in scene.objects.iter_mut().skip(2).step_by(4) {
        o.material = Some(1);
    }
    let placed = TriangleScene::placing(&scene).expect("triangles");
    let world = TriangleScene::world_only(&scene).expect("triangles");
    assert_eq!(placed.placed(), transforms.len() * 2);
    assert_eq!(placed.len(), world.len());
    assert_eq!(placed.bounds, world.bounds);
    let dirs = rays::sphere_dirs(128);
    let mut points = Vec::new();
    for x in -6..=6 {
        for z in -6..=6 {
            for y in [0.5f32, 1.5, 3.0] {
                // Off the meshes' planes of symmetry: a ray in the plane of a box's face
                // may miss it in either BVH.
                points.push(Vec3::new(x as f32 * 2.1 + 0.013, y, z as f32 * 2.1 + 0.029));
            }
        }
    }
    points.extend(
        transforms
            .iter()
            .map(|t| t.transform_point3(Vec3::new(0.011, 0.007, 0.013))),
    );
    let same = same_rays(
        "placed",
        &placed,
        &world,
        &points,
        &dirs,
        200.0,
        &[0.1, 0.6, 2.0],
    );
    let (hits, back) = (same.hits, same.back);
    assert!(hits > points.len() * dirs.len() / 2, "{hits} hits");
    // The solids' centres look out at their insides' back faces, mirrored or not.
    assert!(
        back >= transforms.len() * dirs.len() / 2,
        "{back} back hits"
    );
}
