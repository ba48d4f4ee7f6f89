//! The built-in procedural scenes (`city`, `parking`, `powerplant`, `cornell`, `hall`) with their
//! walkthrough paths. Deterministic: fixed seeds, so tests and benchmarks are reproducible.

use glam::{Mat4, Quat, Vec3};

use super::mesh::{Mesh, Proto, Rng, SceneBuilder};
use super::Scene;
use crate::error::{Error, Result};

/// Names of the built-in scenes.
pub const SCENES: &[&str] = &["city", "parking", "powerplant", "cornell", "hall"];

/// One-line descriptions, for `--help` and the README.
pub fn describe(name: &str) -> &'static str {
    match name {
        "city" => "streets between tall buildings with many detailed small objects (>= 10k objects, >= 2M triangles); paths street, overhead",
        "parking" => "rows of cars, each with an engine block and interior parts hidden inside its closed body",
        "powerplant" => "a dense interior of pipes, boilers and walls: the massive-model case",
        "cornell" => "the Cornell box with two blocks, for GI smoke tests",
        "hall" => "a nave with pillars and arches, the GI test in the spirit of Sibenik",
        _ => "",
    }
}

/// Builds a built-in scene. `scale` multiplies its size (number of blocks, rows, rooms) roughly
/// linearly in object count; 1.0 is the default.
pub fn build(name: &str, scale: f32) -> Result<Scene> {
    if !(scale.is_finite() && scale > 0.0 && scale <= 64.0) {
        return Err(Error::Input(format!(
            "scale {scale} is out of range (0, 64]"
        )));
    }
    match name {
        "city" => Ok(city(scale)),
        "parking" => Ok(parking(scale)),
        "powerplant" => Ok(powerplant(scale)),
        "cornell" => Ok(cornell()),
        "hall" => Ok(hall(scale)),
        other => Err(Error::Input(format!(
            "unknown scene \"{other}\" (built-in: {}; or a path to a .gltf/.glb file)",
            SCENES.join(", ")
        ))),
    }
}

fn trs(t: Vec3, r_y: f32, s: Vec3) -> Mat4 {
    Mat4::from_scale_rotation_translation(s, Quat::from_rotation_y(r_y), t)
}

fn tree_mesh() -> Mesh {
    let mut m = Mesh::default();
    m.append(
        &Mesh::cylinder(8),
        Mat4::from_scale(Vec3::new(0.25, 2.5, 0.25)),
    );
    m.append(
        &Mesh::sphere(16, 10),
        Mat4::from_translation(Vec3::new(0.0, 3.6, 0.0)) * Mat4::from_scale(Vec3::splat(1.6)),
    );
    m
}

fn car_mesh() -> Mesh {
    let mut m = Mesh::default();
    m.append(
        &Mesh::cuboid(Vec3::new(-2.1, 0.35, -0.9), Vec3::new(2.1, 1.0, 0.9)),
        Mat4::IDENTITY,
    );
    m.append(
        &Mesh::cuboid(Vec3::new(-1.2, 1.0, -0.8), Vec3::new(1.0, 1.5, 0.8)),
        Mat4::IDENTITY,
    );
    for (x, z) in [(-1.3, -0.9), (-1.3, 0.9), (1.3, -0.9), (1.3, 0.9)] {
        let r = Mat4::from_translation(Vec3::new(x, 0.35, z))
            * Mat4::from_rotation_x(std::f32::consts::FRAC_PI_2)
            * Mat4::from_translation(Vec3::new(0.0, -0.12, 0.0))
            * Mat4::from_scale(Vec3::new(0.35, 0.24, 0.35));
        m.append(&Mesh::cylinder(12), r);
    }
    m
}

fn lamp_mesh() -> Mesh {
    let mut m = Mesh::default();
    m.append(
        &Mesh::cylinder(10),
        Mat4::from_scale(Vec3::new(0.08, 5.0, 0.08)),
    );
    m.append(
        &Mesh::sphere(12, 8),
        Mat4::from_translation(Vec3::new(0.0, 5.1, 0.0)) * Mat4::from_scale(Vec3::splat(0.3)),
    );
    m
}

fn bench_mesh() -> Mesh {
    let mut m = Mesh::default();
    m.append(
        &Mesh::cuboid(Vec3::new(-0.9, 0.4, -0.25), Vec3::new(0.9, 0.5, 0.25)),
        Mat4::IDENTITY,
    );
    m.append(
        &Mesh::cuboid(Vec3::new(-0.9, 0.5, 0.18), Vec3::new(0.9, 0.95, 0.25)),
        Mat4::IDENTITY,
    );
    for x in [-0.8, 0.8] {
        m.append(
            &Mesh::cuboid(
                Vec3::new(x - 0.05, 0.0, -0.2),
                Vec3::new(x + 0.05, 0.4, 0.2),
            ),
            Mat4::IDENTITY,
        );
    }
    m
}

fn statue_mesh() -> Mesh {
    let mut m = Mesh::default();
    m.append(
        &Mesh::cuboid(Vec3::new(-0.6, 0.0, -0.6), Vec3::new(0.6, 1.0, 0.6)),
        Mat4::IDENTITY,
    );
    m.append(
        &Mesh::sphere(24, 14),
        Mat4::from_translation(Vec3::new(0.0, 1.9, 0.0))
            * Mat4::from_scale(Vec3::new(0.5, 0.9, 0.5)),
    );
    m.append(
        &Mesh::sphere(16, 10),
        Mat4::from_translation(Vec3::new(0.0, 3.0, 0.0)) * Mat4::from_scale(Vec3::splat(0.3)),
    );
    m
}

fn roof_unit_mesh() -> Mesh {
    let mut m = Mesh::default();
    m.append(
        &Mesh::cuboid(Vec3::new(-1.0, 0.0, -0.7), Vec3::new(1.0, 1.2, 0.7)),
        Mat4::IDENTITY,
    );
    m.append(
        &Mesh::cylinder(16),
        Mat4::from_translation(Vec3::new(0.0, 1.2, 0.0))
            * Mat4::from_scale(Vec3::new(0.5, 0.3, 0.5)),
    );
    m
}

/// Facade colors of the city's buildings.
const BUILDING_PALETTE: [Vec3; 6] = [
    Vec3::new(0.75, 0.70, 0.62),
    Vec3::new(0.62, 0.55, 0.50),
    Vec3::new(0.55, 0.60, 0.68),
    Vec3::new(0.80, 0.78, 0.72),
    Vec3::new(0.58, 0.42, 0.35),
    Vec3::new(0.45, 0.50, 0.55),
];

/// Paint colors of the city's parked cars.
const CITY_CAR_COLORS: [Vec3; 6] = [
    Vec3::new(0.8, 0.1, 0.1),
    Vec3::new(0.1, 0.2, 0.7),
    Vec3::new(0.9, 0.9, 0.9),
    Vec3::new(0.1, 0.1, 0.1),
    Vec3::new(0.9, 0.7, 0.1),
    Vec3::new(0.2, 0.5, 0.3),
];

/// The city's layout: `blocks` x `blocks` square blocks of side `block`, `street` apart.
struct CityGrid {
    blocks: i32,
    block: f32,
    street: f32,
    /// Block plus street: the distance between block corners.
    pitch: f32,
}

impl CityGrid {
    fn new(scale: f32) -> CityGrid {
        let block = 40.0f32;
        let street = 14.0f32;
        CityGrid {
            blocks: ((14.0 * scale.sqrt()).round() as i32).max(2),
            block,
            street,
            pitch: block + street,
        }
    }

    /// The paths are laid out on the default-size city (14 blocks), so that larger scales grow
    /// the city around the same walk (for scaling measurements).
    fn path_blocks(&self) -> i32 {
        self.blocks.min(14)
    }
}

/// The city's prototypes, each stored once and instanced everywhere.
struct CityProtos {
    cube: Proto,
    tree: Proto,
    car: Proto,
    lamp: Proto,
    bench: Proto,
    statue: Proto,
    roof_unit: Proto,
}

impl CityProtos {
    fn new(b: &mut SceneBuilder) -> CityProtos {
        CityProtos {
            cube: b.proto(&Mesh::cube()),
            tree: b.proto(&tree_mesh()),
            car: b.proto(&car_mesh()),
            lamp: b.proto(&lamp_mesh()),
            bench: b.proto(&bench_mesh()),
            statue: b.proto(&statue_mesh()),
            roof_unit: b.proto(&roof_unit_mesh()),
        }
    }
}

/// `city`: a grid of blocks with tall buildings (the occluders), trees, cars, lamps, benches,
/// statues on the streets and machinery on the roofs.
pub fn city(scale: f32) -> Scene {
    let mut b = SceneBuilder::new("city");
    let mut rng = Rng::new(0xC17E);
    let grid = CityGrid::new(scale);
    let extent = grid.blocks as f32 * grid.pitch;
    let ground = Mesh::cuboid(
        Vec3::new(-grid.street, -0.5, -grid.street),
        Vec3::new(extent, 0.0, extent),
    );
    b.add(&ground, Vec3::new(0.32, 0.32, 0.34));
    let protos = CityProtos::new(&mut b);
    for bx in 0..grid.blocks {
        for bz in 0..grid.blocks {
            let x0 = bx as f32 * grid.pitch;
            let z0 = bz as f32 * grid.pitch;
            city_block(&mut b, &mut rng, &protos, grid.block, x0, z0);
        }
    }
    city_street_path(&mut b, &grid);
    city_overhead_path(&mut b, &grid);
    b.finish()
}

/// One block with its corner at (`x0`, `z0`): sidewalk, four buildings, street furniture and
/// parked cars along its four sides, statues at its corners.
fn city_block(b: &mut SceneBuilder, rng: &mut Rng, p: &CityProtos, block: f32, x0: f32, z0: f32) {
    // sidewalk slab
    b.instance(
        p.cube,
        trs(
            Vec3::new(x0 + block / 2.0, 0.1, z0 + block / 2.0),
            0.0,
            Vec3::new(block + 4.0, 0.2, block + 4.0),
        ),
        Vec3::new(0.55, 0.55, 0.53),
    );
    // 2x2 lots with buildings
    for lx in 0..2 {
        for lz in 0..2 {
            let cx = x0 + 10.0 + lx as f32 * 20.0;
            let cz = z0 + 10.0 + lz as f32 * 20.0;
            city_building(b, rng, p, cx, cz);
        }
    }
    // trees and lamps along the block edges, cars in the streets
    for side in 0..4 {
        let side = BlockSide {
            x0,
            z0,
            block,
            side,
        };
        street_trees(b, rng, p.tree, &side);
        lamps_and_benches(b, p, &side);
        parked_cars(b, rng, p.car, &side);
    }
    corner_statues(b, rng, p.statue, block, x0, z0);
}

/// A building on the lot centred at (`cx`, `cz`) with three machinery units on its roof.
fn city_building(b: &mut SceneBuilder, rng: &mut Rng, p: &CityProtos, cx: f32, cz: f32) {
    let w = rng.range(14.0, 18.5);
    let d = rng.range(14.0, 18.5);
    let h = rng.range(18.0, 70.0);
    let color = BUILDING_PALETTE[rng.below(BUILDING_PALETTE.len() as u32) as usize];
    b.instance(
        p.cube,
        trs(Vec3::new(cx, 0.2 + h / 2.0, cz), 0.0, Vec3::new(w, h, d)),
        color,
    );
    for _ in 0..3 {
        let ux = cx + rng.range(-w / 2.0 + 1.5, w / 2.0 - 1.5);
        let uz = cz + rng.range(-d / 2.0 + 1.5, d / 2.0 - 1.5);
        b.instance(
            p.roof_unit,
            trs(Vec3::new(ux, 0.2 + h, uz), rng.range(0.0, 3.0), Vec3::ONE),
            Vec3::new(0.6, 0.6, 0.62),
        );
    }
}

/// One side of a block (0: -z, 1: +z, 2: -x, 3: +x), for placing things along it.
struct BlockSide {
    x0: f32,
    z0: f32,
    block: f32,
    side: i32,
}

impl BlockSide {
    /// The point `t` along the side, just off the sidewalk, and the rotation that faces along it.
    fn along(&self, t: f32) -> (Vec3, f32) {
        let (x0, z0, block) = (self.x0, self.z0, self.block);
        match self.side {
            0 => (Vec3::new(x0 + t, 0.0, z0 - 1.0), 0.0),
            1 => (Vec3::new(x0 + t, 0.0, z0 + block + 1.0), 0.0),
            2 => (
                Vec3::new(x0 - 1.0, 0.0, z0 + t),
                std::f32::consts::FRAC_PI_2,
            ),
            _ => (
                Vec3::new(x0 + block + 1.0, 0.0, z0 + t),
                std::f32::consts::FRAC_PI_2,
            ),
        }
    }

    /// Offset from the side into the parking lane next to it.
    fn lane(&self) -> Vec3 {
        match self.side {
            0 => Vec3::new(0.0, 0.0, -3.0),
            1 => Vec3::new(0.0, 0.0, 3.0),
            2 => Vec3::new(-3.0, 0.0, 0.0),
            _ => Vec3::new(3.0, 0.0, 0.0),
        }
    }
}

/// Five trees along a block side, each turned, scaled and tinted at random.
fn street_trees(b: &mut SceneBuilder, rng: &mut Rng, tree: Proto, side: &BlockSide) {
    for k in 0..5 {
        let (p, _) = side.along(4.0 + k as f32 * 8.0);
        b.instance(
            tree,
            trs(
                p + Vec3::Y * 0.2,
                rng.range(0.0, 6.0),
                Vec3::splat(rng.range(0.8, 1.2)),
            ),
            Vec3::new(0.2, rng.range(0.4, 0.6), 0.15),
        );
    }
}

/// Two lamps and two benches along a block side.
fn lamps_and_benches(b: &mut SceneBuilder, protos: &CityProtos, side: &BlockSide) {
    for k in 0..2 {
        let (p, r) = side.along(8.0 + k as f32 * 24.0);
        b.instance(
            protos.lamp,
            trs(p + Vec3::Y * 0.2, r, Vec3::ONE),
            Vec3::new(0.2, 0.2, 0.22),
        );
        let (p, r) = side.along(12.0 + k as f32 * 16.0);
        b.instance(
            protos.bench,
            trs(p + Vec3::Y * 0.2, r, Vec3::ONE),
            Vec3::new(0.45, 0.3, 0.2),
        );
    }
}

/// Three cars parked in the lane next to a block side.
fn parked_cars(b: &mut SceneBuilder, rng: &mut Rng, car: Proto, side: &BlockSide) {
    let lane = side.lane();
    for k in 0..3 {
        let (p, r) = side.along(6.0 + k as f32 * 13.0 + rng.range(-1.0, 1.0));
        let c = CITY_CAR_COLORS[rng.below(CITY_CAR_COLORS.len() as u32) as usize];
        b.instance(car, trs(p + lane, r, Vec3::ONE), c);
    }
}

/// Statues at the four corners of the block at (`x0`, `z0`).
fn corner_statues(
    b: &mut SceneBuilder,
    rng: &mut Rng,
    statue: Proto,
    block: f32,
    x0: f32,
    z0: f32,
) {
    for (sx, sz) in [
        (-2.0, -2.0),
        (block + 2.0, -2.0),
        (-2.0, block + 2.0),
        (block + 2.0, block + 2.0),
    ] {
        b.instance(
            statue,
            trs(
                Vec3::new(x0 + sx, 0.2, z0 + sz),
                rng.range(0.0, 6.0),
                Vec3::ONE,
            ),
            Vec3::new(0.7, 0.68, 0.6),
        );
    }
}

/// Path `street`: along the centre lines of the streets at eye height 1.7 m, three turns at
/// crossings. Each turn has a key a few metres before and after the crossing, so that the
/// Catmull-Rom spline between keys stays in the street instead of cutting the corner through a
/// building or a parked car (`tests/gpu/builtin_paths.rs` checks every quarter frame).
fn city_street_path(b: &mut SceneBuilder, grid: &CityGrid) {
    let (block, street, pitch) = (grid.block, grid.street, grid.pitch);
    let path_blocks = grid.path_blocks();
    // Centre line of the street after block `k` (x or z).
    let line = |k: i32| k as f32 * pitch + block + street / 2.0;
    let (l0, l6, l10) = (
        line(0),
        line(path_blocks / 2 - 1),
        line(path_blocks * 5 / 7),
    );
    let e = 1.7;
    let at = |x: f32, z: f32| Vec3::new(x, e, z);
    let (px, pz, nx) = (Vec3::X, Vec3::Z, -Vec3::X);
    let mut keys = vec![
        (at(l0, 2.0), at(l0, 42.0)),
        (at(l0, l6 * 0.5), at(l0 + 2.0, l6 * 0.5 + 40.0)),
    ];
    keys.extend(turn(at(l0, l6), pz, px, 8.0));
    keys.push((at(l6, l6), at(l6 + 40.0, l6 + 5.0)));
    keys.extend(turn(at(l10, l6), px, pz, 8.0));
    keys.extend(turn(at(l10, l10), pz, nx, 8.0));
    keys.push((at(l6, l10), at(l6 - 40.0, l10)));
    b.path("street", &keys);
}

/// Three path keys turning at `c` from direction `from` to direction `to`, `approach` metres
/// before and after it: the spline between them strays at most about 0.074 `approach` from the
/// two straight lines (its sideways offset is `approach` t^2 (1 - t) / 2 at most).
fn turn(c: Vec3, from: Vec3, to: Vec3, approach: f32) -> [(Vec3, Vec3); 3] {
    [
        (c - from * approach, c + from * 40.0),
        (c, c + (from + to) * 20.0),
        (c + to * approach, c + to * 40.0),
    ]
}

/// Path `overhead`: a bird's-eye flight around the city (mostly visible: CHC's worst case).
fn city_overhead_path(b: &mut SceneBuilder, grid: &CityGrid) {
    let extent = grid.path_blocks() as f32 * grid.pitch;
    let h = extent * 0.45 + 60.0;
    b.path(
        "overhead",
        &[
            (
                Vec3::new(-30.0, h, -30.0),
                Vec3::new(extent * 0.4, 0.0, extent * 0.4),
            ),
            (
                Vec3::new(extent * 0.5, h, -40.0),
                Vec3::new(extent * 0.5, 0.0, extent * 0.45),
            ),
            (
                Vec3::new(extent + 30.0, h, extent * 0.3),
                Vec3::new(extent * 0.55, 0.0, extent * 0.5),
            ),
            (
                Vec3::new(extent + 30.0, h, extent + 30.0),
                Vec3::new(extent * 0.6, 0.0, extent * 0.6),
            ),
            (
                Vec3::new(extent * 0.4, h * 0.8, extent + 40.0),
                Vec3::new(extent * 0.45, 0.0, extent * 0.55),
            ),
            (
                Vec3::new(-30.0, h, extent * 0.6),
                Vec3::new(extent * 0.4, 0.0, extent * 0.5),
            ),
        ],
    );
}

/// Paint colors of the parking lot's cars.
const PARKING_CAR_COLORS: [Vec3; 5] = [
    Vec3::new(0.7, 0.1, 0.1),
    Vec3::new(0.1, 0.3, 0.7),
    Vec3::new(0.85, 0.85, 0.85),
    Vec3::new(0.15, 0.15, 0.15),
    Vec3::new(0.8, 0.6, 0.1),
];

/// The parking lot's layout: `rows` rows of `per_row` bays, `dx` wide and `dz` apart.
struct ParkingLot {
    rows: i32,
    per_row: i32,
    dx: f32,
    dz: f32,
}

impl ParkingLot {
    fn new(scale: f32) -> ParkingLot {
        ParkingLot {
            rows: ((8.0 * scale.sqrt()).round() as i32).max(1),
            per_row: ((20.0 * scale.sqrt()).round() as i32).max(2),
            dx: 3.0,
            dz: 9.0,
        }
    }

    /// Width of the rows.
    fn width(&self) -> f32 {
        self.per_row as f32 * self.dx
    }

    /// Depth of all rows together.
    fn depth(&self) -> f32 {
        self.rows as f32 * self.dz
    }
}

/// The parking lot's prototypes: a car is a closed body with parts hidden inside it.
struct ParkingProtos {
    body: Proto,
    engine: Proto,
    seat: Proto,
    wheel: Proto,
    pillar: Proto,
}

/// `parking`: rows of cars with engine blocks, seats and steering wheels inside closed bodies.
pub fn parking(scale: f32) -> Scene {
    let mut b = SceneBuilder::new("parking");
    let mut rng = Rng::new(0xCA75);
    let lot = ParkingLot::new(scale);
    let (w, d) = (lot.width(), lot.depth());
    b.add(
        &Mesh::cuboid(
            Vec3::new(-8.0, -0.3, -8.0),
            Vec3::new(w + 8.0, 0.0, d + 8.0),
        ),
        Vec3::new(0.35, 0.35, 0.37),
    );
    let protos = ParkingProtos {
        body: b.proto(&car_body_mesh()),
        engine: b.proto(&engine_mesh()),
        seat: b.proto(&seat_mesh()),
        wheel: b.proto(&Mesh::sphere(16, 8)),
        pillar: b.proto(&Mesh::cube()),
    };
    for r in 0..lot.rows {
        parking_row(&mut b, &mut rng, &protos, &lot, r);
    }
    parking_path(&mut b, &lot);
    b.finish()
}

/// Row `r`: a car in each bay (about one bay in eight stays empty), facing the aisle; every
/// second row has pillars in front of it.
fn parking_row(b: &mut SceneBuilder, rng: &mut Rng, p: &ParkingProtos, lot: &ParkingLot, r: i32) {
    let (dx, dz) = (lot.dx, lot.dz);
    for c in 0..lot.per_row {
        if rng.f32() < 0.12 {
            continue;
        }
        let pos = Vec3::new(c as f32 * dx + 1.5, 0.0, r as f32 * dz + 2.5);
        let rot = if r % 2 == 0 {
            0.0
        } else {
            std::f32::consts::PI
        };
        let color = PARKING_CAR_COLORS[rng.below(PARKING_CAR_COLORS.len() as u32) as usize];
        parked_car(b, p, trs(pos, rot, Vec3::ONE), color);
    }
    if r % 2 == 1 {
        for c in (0..lot.per_row).step_by(4) {
            b.instance(
                p.pillar,
                trs(
                    Vec3::new(c as f32 * dx, 2.0, r as f32 * dz - 1.8),
                    0.0,
                    Vec3::new(0.6, 4.0, 0.6),
                ),
                Vec3::new(0.6, 0.6, 0.58),
            );
        }
    }
}

/// One car placed by `t`: its body, and inside it an engine, two seats and a steering wheel.
fn parked_car(b: &mut SceneBuilder, p: &ParkingProtos, t: Mat4, color: Vec3) {
    b.instance(p.body, t, color);
    b.instance(
        p.engine,
        t * Mat4::from_translation(Vec3::new(0.0, 0.0, -1.5)),
        Vec3::new(0.3, 0.3, 0.3),
    );
    b.instance(
        p.seat,
        t * Mat4::from_translation(Vec3::new(-0.45, 0.0, 0.1)),
        Vec3::new(0.2, 0.15, 0.1),
    );
    b.instance(
        p.seat,
        t * Mat4::from_translation(Vec3::new(0.45, 0.0, 0.1)),
        Vec3::new(0.2, 0.15, 0.1),
    );
    b.instance(
        p.wheel,
        t * Mat4::from_translation(Vec3::new(-0.45, 0.9, -0.5))
            * Mat4::from_scale(Vec3::new(0.2, 0.2, 0.04)),
        Vec3::new(0.1, 0.1, 0.1),
    );
}

/// A closed car body: lower box and cabin.
fn car_body_mesh() -> Mesh {
    let mut m = Mesh::default();
    m.append(
        &Mesh::cuboid(Vec3::new(-1.0, 0.3, -2.2), Vec3::new(1.0, 1.1, 2.2)),
        Mat4::IDENTITY,
    );
    m.append(
        &Mesh::cuboid(Vec3::new(-0.9, 1.1, -1.2), Vec3::new(0.9, 1.6, 1.0)),
        Mat4::IDENTITY,
    );
    m
}

/// An engine block with four cylinder heads.
fn engine_mesh() -> Mesh {
    let mut m = Mesh::default();
    m.append(
        &Mesh::cuboid(Vec3::new(-0.5, 0.45, -0.45), Vec3::new(0.5, 0.95, 0.45)),
        Mat4::IDENTITY,
    );
    for i in 0..4 {
        m.append(
            &Mesh::cylinder(16),
            Mat4::from_translation(Vec3::new(-0.3 + i as f32 * 0.2, 0.95, 0.0))
                * Mat4::from_scale(Vec3::new(0.07, 0.1, 0.07)),
        );
    }
    m
}

/// A seat with backrest and headrest.
fn seat_mesh() -> Mesh {
    let mut m = Mesh::default();
    m.append(
        &Mesh::cuboid(Vec3::new(-0.3, 0.4, -0.3), Vec3::new(0.3, 0.6, 0.3)),
        Mat4::IDENTITY,
    );
    m.append(
        &Mesh::cuboid(Vec3::new(-0.3, 0.6, 0.2), Vec3::new(0.3, 1.3, 0.3)),
        Mat4::IDENTITY,
    );
    m.append(
        &Mesh::sphere(10, 6),
        Mat4::from_translation(Vec3::new(0.0, 1.4, 0.25)) * Mat4::from_scale(Vec3::splat(0.12)),
    );
    m
}

/// The walk: along the first aisle, round the end of the rows, back along a middle aisle, out
/// past the first bays and a look over the lot from its far edge. Turns have keys just before and
/// after them so that the spline stays in the aisles (`tests/gpu/builtin_paths.rs`). Both aisles
/// walked along are in front of pillars: the movers drive along the other aisles (`movers.rs`),
/// which the walk only crosses.
fn parking_path(b: &mut SceneBuilder, lot: &ParkingLot) {
    let (rows, dz) = (lot.rows, lot.dz);
    let (w, d) = (lot.width(), lot.depth());
    let e = 1.7;
    // Between the cars of row `r` (up to z = r dz + 4.7) and the pillars in front of row r + 1
    // (from z = r dz + 6.9): the eye keeps more than 1 m from both.
    // Only even rows have pillar-lined aisles behind them (the odd ones are the movers' lanes).
    let aisle = |r: i32| r as f32 * dz + 5.8;
    let middle = (rows - 1).max(0) / 2;
    let (a0, am) = (aisle(0), aisle(middle + (middle & 1)));
    let at = |x: f32, z: f32| Vec3::new(x, e, z);
    let mut keys = vec![
        (at(-4.0, a0), at(10.0, a0)),
        (at(w * 0.5, a0), at(w * 0.5 + 10.0, a0 + 2.0)),
    ];
    keys.extend(turn(at(w + 3.0, a0), Vec3::X, Vec3::Z, 5.0));
    keys.extend(turn(at(w + 3.0, am), Vec3::Z, -Vec3::X, 5.0));
    keys.push((at(w * 0.5, am), at(w * 0.5 - 10.0, am + 1.0)));
    keys.extend(turn(at(-3.0, am), -Vec3::X, Vec3::Z, 5.0));
    keys.push((
        Vec3::new(-3.0, e + 2.0, d),
        Vec3::new(w * 0.5, 0.0, d * 0.5),
    ));
    b.path("default", &keys);
}

/// Side of a powerplant room.
const ROOM_SIZE: f32 = 24.0;
/// Height of a powerplant room's walls.
const ROOM_HEIGHT: f32 = 12.0;
/// Half the width of the powerplant's walkways (the rooms' middle lines) that vertical pipes
/// keep clear of.
const WALKWAY: f32 = 1.5;

/// The powerplant's prototypes.
struct PlantProtos {
    cube: Proto,
    pipe: Proto,
    boiler: Proto,
    valve: Proto,
}

/// `powerplant`: rooms in a grid separated by walls with doorways, filled with boilers, pipe
/// runs and tanks.
pub fn powerplant(scale: f32) -> Scene {
    let mut b = SceneBuilder::new("powerplant");
    let mut rng = Rng::new(0x90E7);
    let rooms = ((4.0 * scale.sqrt()).round() as i32).max(1);
    let total = rooms as f32 * ROOM_SIZE;
    b.add(
        &Mesh::cuboid(
            Vec3::new(-1.0, -0.5, -1.0),
            Vec3::new(total + 1.0, 0.0, total + 1.0),
        ),
        Vec3::new(0.4, 0.4, 0.42),
    );
    let protos = PlantProtos {
        cube: b.proto(&Mesh::cube()),
        pipe: b.proto(&Mesh::cylinder(20)),
        boiler: b.proto(&boiler_mesh()),
        valve: b.proto(&Mesh::sphere(14, 8)),
    };
    for rx in 0..rooms {
        for rz in 0..rooms {
            let x0 = rx as f32 * ROOM_SIZE;
            let z0 = rz as f32 * ROOM_SIZE;
            room_walls(&mut b, protos.cube, x0, z0);
            room_boilers(&mut b, &mut rng, &protos, x0, z0);
            room_pipe_runs(&mut b, &mut rng, protos.pipe, x0, z0);
            room_vertical_pipes(&mut b, &mut rng, protos.pipe, x0, z0);
        }
    }
    powerplant_path(&mut b);
    if rooms >= 3 {
        powerplant_difficult_path(&mut b);
    }
    b.finish()
}

/// A boiler: a tall cylinder with a domed top.
fn boiler_mesh() -> Mesh {
    let mut m = Mesh::default();
    m.append(
        &Mesh::cylinder(40),
        Mat4::from_scale(Vec3::new(2.2, 7.0, 2.2)),
    );
    m.append(
        &Mesh::sphere(40, 16),
        Mat4::from_translation(Vec3::new(0.0, 7.0, 0.0))
            * Mat4::from_scale(Vec3::new(2.2, 1.2, 2.2)),
    );
    m
}

/// Walls on the room's -x and -z sides, with a doorway in the middle of each.
fn room_walls(b: &mut SceneBuilder, cube: Proto, x0: f32, z0: f32) {
    let (size, height) = (ROOM_SIZE, ROOM_HEIGHT);
    let wall = Vec3::new(0.76, 0.74, 0.7);
    for (a, bb) in [(0.0, size * 0.4), (size * 0.6, size)] {
        b.instance(
            cube,
            Mat4::from_translation(Vec3::new(x0 + 0.2, height / 2.0, z0 + (a + bb) / 2.0))
                * Mat4::from_scale(Vec3::new(0.4, height, bb - a)),
            wall,
        );
        b.instance(
            cube,
            Mat4::from_translation(Vec3::new(x0 + (a + bb) / 2.0, height / 2.0, z0 + 0.2))
                * Mat4::from_scale(Vec3::new(bb - a, height, 0.4)),
            wall,
        );
    }
}

/// Two boilers, each with four valves on its side.
fn room_boilers(b: &mut SceneBuilder, rng: &mut Rng, protos: &PlantProtos, x0: f32, z0: f32) {
    for k in 0..2 {
        let p = Vec3::new(x0 + 7.0 + k as f32 * 10.0, 0.0, z0 + rng.range(6.0, 9.0));
        b.instance(
            protos.boiler,
            Mat4::from_translation(p),
            Vec3::new(0.6, 0.25, 0.15),
        );
        for v in 0..4 {
            b.instance(
                protos.valve,
                Mat4::from_translation(p + Vec3::new(2.3, 1.0 + v as f32 * 1.5, 0.0))
                    * Mat4::from_scale(Vec3::splat(0.35)),
                Vec3::new(0.8, 0.7, 0.1),
            );
        }
    }
}

/// Pipe runs along x and z at six heights.
fn room_pipe_runs(b: &mut SceneBuilder, rng: &mut Rng, pipe: Proto, x0: f32, z0: f32) {
    let size = ROOM_SIZE;
    for level in 0..6 {
        let y = 2.0 + level as f32 * 1.6;
        let z = z0 + 14.0 + rng.range(0.0, 8.0);
        let c = [
            Vec3::new(0.2, 0.4, 0.7),
            Vec3::new(0.7, 0.7, 0.2),
            Vec3::new(0.3, 0.6, 0.3),
        ][level % 3];
        b.instance(
            pipe,
            Mat4::from_translation(Vec3::new(x0 + 1.0, y, z))
                * Mat4::from_rotation_z(-std::f32::consts::FRAC_PI_2)
                * Mat4::from_scale(Vec3::new(0.3, size - 2.0, 0.3)),
            c,
        );
        let x = x0 + 2.0 + rng.range(0.0, 20.0);
        b.instance(
            pipe,
            Mat4::from_translation(Vec3::new(x, y + 0.7, z0 + 1.0))
                * Mat4::from_rotation_x(std::f32::consts::FRAC_PI_2)
                * Mat4::from_scale(Vec3::new(0.2, size - 2.0, 0.2)),
            c * 0.8,
        );
    }
}

/// Eight floor-to-ceiling pipes at random places in the back half of the room, clear of the
/// walkways through its doorways (the room's middle lines), where the built-in paths go.
fn room_vertical_pipes(b: &mut SceneBuilder, rng: &mut Rng, pipe: Proto, x0: f32, z0: f32) {
    let (size, height) = (ROOM_SIZE, ROOM_HEIGHT);
    let (mid_x, mid_z) = (x0 + 0.5 * size, z0 + 0.5 * size);
    let clear = |p: Vec3| (p.x - mid_x).abs() >= WALKWAY && (p.z - mid_z).abs() >= WALKWAY;
    for _ in 0..8 {
        let Some(p) = (0..64).find_map(|_| {
            let p = Vec3::new(
                x0 + rng.range(2.0, size - 2.0),
                0.0,
                z0 + rng.range(12.0, size - 2.0),
            );
            clear(p).then_some(p)
        }) else {
            continue;
        };
        b.instance(
            pipe,
            Mat4::from_translation(p) * Mat4::from_scale(Vec3::new(0.25, height, 0.25)),
            Vec3::new(0.55, 0.55, 0.6),
        );
    }
}

/// The walk through the doorways of the first rooms.
fn powerplant_path(b: &mut SceneBuilder) {
    let size = ROOM_SIZE;
    // Eye height 1.5 m on both walks: the lowest pipe runs hang from 1.7 m to 2.3 m.
    let e = 1.5;
    let door = size * 0.5;
    b.path(
        "default",
        &[
            (Vec3::new(door, e, 3.0), Vec3::new(door, e, 20.0)),
            (
                Vec3::new(door, e, size * 0.5),
                Vec3::new(door + 10.0, e, size * 0.5 + 3.0),
            ),
            (
                Vec3::new(size + 2.0, e, door),
                Vec3::new(size + 15.0, e, door + 2.0),
            ),
            (
                Vec3::new(size * 1.5, e, door + 1.0),
                Vec3::new(size * 1.5, e + 3.0, door + 15.0),
            ),
            (
                Vec3::new(size * 1.5, e, size + 3.0),
                Vec3::new(size * 1.5 + 2.0, e, size + 15.0),
            ),
            (
                Vec3::new(size * 1.5, e, size * 1.5),
                Vec3::new(size * 1.5 - 15.0, e, size * 1.5),
            ),
        ],
    );
}

/// `difficult`: through six doorways with a sharp turn right behind each, along the pipe
/// runs, where temporal coherence breaks (what was hidden a moment ago fills the view).
fn powerplant_difficult_path(b: &mut SceneBuilder) {
    let s = ROOM_SIZE;
    let e = 1.5;
    let z = 0.49 * s; // a walkway between the boilers and the pipe runs
    let keys = [
        (Vec3::new(0.5 * s, e, 3.0), Vec3::new(0.5 * s, e, 20.0)),
        (Vec3::new(0.5 * s, e, z), Vec3::new(s, e, z)),
        (Vec3::new(s - 1.5, e, z), Vec3::new(s + 10.0, e, z)),
        (Vec3::new(s + 1.5, e, z), Vec3::new(s + 1.5, e, s)),
        (
            Vec3::new(s + 3.0, e, z),
            Vec3::new(2.0 * s, e + 2.0, z + 1.0),
        ),
        (Vec3::new(1.5 * s, e, z), Vec3::new(1.5 * s, e, s)),
        (
            Vec3::new(1.5 * s, e, s - 1.5),
            Vec3::new(1.5 * s, e, s + 10.0),
        ),
        (Vec3::new(1.5 * s, e, s + 1.5), Vec3::new(s, e, s + 1.5)),
        // South past the boiler by the doorway, then west behind it.
        (Vec3::new(1.5 * s, e, s + z), Vec3::new(s, e, s + z)),
        (Vec3::new(1.2 * s, e, s + z), Vec3::new(0.5 * s, e, s + z)),
        (Vec3::new(s + 1.5, e, s + z), Vec3::new(s - 10.0, e, s + z)),
        (Vec3::new(s - 1.5, e, s + z), Vec3::new(s - 1.5, e, 2.0 * s)),
        (Vec3::new(0.5 * s, e, s + z), Vec3::new(0.5 * s, e, 2.5 * s)),
        (
            Vec3::new(0.5 * s, e, 2.0 * s - 1.5),
            Vec3::new(0.5 * s, e, 2.0 * s + 10.0),
        ),
        (
            Vec3::new(0.5 * s, e, 2.0 * s + 1.5),
            Vec3::new(0.5 * s + 10.0, e + 4.0, 2.0 * s + 14.0),
        ),
    ];
    b.path("difficult", &keys);
}

/// `cornell`: the Cornell box (5.5 m) with a tall and a short block; red left, green right.
pub fn cornell() -> Scene {
    let mut b = SceneBuilder::new("cornell");
    let s = 5.5f32;
    let t = 0.2f32;
    let white = Vec3::new(0.73, 0.73, 0.73);
    b.add(
        &Mesh::cuboid(Vec3::new(0.0, -t, 0.0), Vec3::new(s, 0.0, s)),
        white,
    ); // floor
    b.add(
        &Mesh::cuboid(Vec3::new(0.0, s, 0.0), Vec3::new(s, s + t, s)),
        white,
    ); // ceiling
    b.add(
        &Mesh::cuboid(Vec3::new(0.0, 0.0, -t), Vec3::new(s, s, 0.0)),
        white,
    ); // back
    b.add(
        &Mesh::cuboid(Vec3::new(-t, 0.0, 0.0), Vec3::new(0.0, s, s)),
        Vec3::new(0.65, 0.05, 0.05),
    ); // left red
    b.add(
        &Mesh::cuboid(Vec3::new(s, 0.0, 0.0), Vec3::new(s + t, s, s)),
        Vec3::new(0.12, 0.45, 0.15),
    ); // right green
    let mut tall = Mesh::default();
    tall.append(
        &Mesh::cube(),
        trs(Vec3::new(1.8, 1.65, 1.9), 0.3, Vec3::new(1.65, 3.3, 1.65)),
    );
    b.add(&tall, white);
    let mut short = Mesh::default();
    short.append(
        &Mesh::cube(),
        trs(
            Vec3::new(3.7, 0.825, 3.4),
            -0.3,
            Vec3::new(1.65, 1.65, 1.65),
        ),
    );
    b.add(&short, white);
    let c = Vec3::new(s / 2.0, s / 2.0, 0.0);
    b.path(
        "default",
        &[
            (Vec3::new(s / 2.0, s / 2.0, s + 8.0), c + Vec3::Z * 2.0),
            (
                Vec3::new(s / 2.0 + 1.0, s / 2.0 + 0.3, s + 7.0),
                c + Vec3::Z * 2.0,
            ),
            (
                Vec3::new(s / 2.0 - 1.0, s / 2.0 - 0.3, s + 7.5),
                c + Vec3::Z * 2.0,
            ),
        ],
    );
    b.sun(Vec3::new(0.2, 1.0, 0.6));
    b.finish()
}

/// Length of one bay of the hall (pillar to pillar).
const HALL_BAY: f32 = 6.0;
/// Width of the nave between the pillar rows.
const HALL_WIDTH: f32 = 16.0;
/// Height of the side walls, where the vault starts.
const HALL_WALL_HEIGHT: f32 = 12.0;
/// The hall's stone color.
const STONE: Vec3 = Vec3::new(0.75, 0.7, 0.62);

/// `hall`: a nave with two rows of pillars, arches between them, side walls, a vaulted roof.
pub fn hall(scale: f32) -> Scene {
    let mut b = SceneBuilder::new("hall");
    let bays = ((8.0 * scale.sqrt()).round() as i32).max(2);
    let len = bays as f32 * HALL_BAY;
    hall_floor_and_walls(&mut b, len);
    b.add(&vault_mesh(len), STONE);
    let pillar = b.proto(&pillar_mesh());
    let arch = b.proto(&arch_mesh());
    for i in 0..=bays {
        let z = i as f32 * HALL_BAY;
        for x in [-HALL_WIDTH / 2.0, HALL_WIDTH / 2.0] {
            b.instance(pillar, Mat4::from_translation(Vec3::new(x, 0.0, z)), STONE);
            if i < bays {
                b.instance(
                    arch,
                    Mat4::from_translation(Vec3::new(
                        x,
                        HALL_WALL_HEIGHT - 0.6,
                        z + HALL_BAY / 2.0,
                    )),
                    STONE * 0.95,
                );
            }
        }
    }
    hall_path(&mut b, len);
    b.sun(Vec3::new(0.3, 1.0, -0.4));
    b.finish()
}

/// The floor, the two colored side walls and the end wall of a hall `len` long.
fn hall_floor_and_walls(b: &mut SceneBuilder, len: f32) {
    let (width, wall_h) = (HALL_WIDTH, HALL_WALL_HEIGHT);
    b.add(
        &Mesh::cuboid(
            Vec3::new(-width / 2.0 - 4.0, -0.3, -2.0),
            Vec3::new(width / 2.0 + 4.0, 0.0, len + 2.0),
        ),
        Vec3::new(0.6, 0.55, 0.5),
    );
    b.add(
        &Mesh::cuboid(
            Vec3::new(-width / 2.0 - 4.5, 0.0, -2.0),
            Vec3::new(-width / 2.0 - 4.0, wall_h, len + 2.0),
        ),
        Vec3::new(0.7, 0.3, 0.2),
    );
    b.add(
        &Mesh::cuboid(
            Vec3::new(width / 2.0 + 4.0, 0.0, -2.0),
            Vec3::new(width / 2.0 + 4.5, wall_h, len + 2.0),
        ),
        Vec3::new(0.25, 0.4, 0.65),
    );
    b.add(
        &Mesh::cuboid(
            Vec3::new(-width / 2.0 - 4.5, 0.0, len + 2.0),
            Vec3::new(width / 2.0 + 4.5, wall_h + 6.0, len + 2.5),
        ),
        STONE,
    );
}

/// The vault: a half cylinder over the nave made of many segments (the bulk of the
/// triangles).
fn vault_mesh(len: f32) -> Mesh {
    let (width, wall_h) = (HALL_WIDTH, HALL_WALL_HEIGHT);
    let mut vault = Mesh::default();
    let segs = 48;
    for i in 0..segs {
        let a0 = i as f32 / segs as f32 * std::f32::consts::PI;
        let a1 = (i + 1) as f32 / segs as f32 * std::f32::consts::PI;
        let r = width / 2.0 + 4.5;
        let p0 = Vec3::new(r * a0.cos(), wall_h + r * 0.5 * a0.sin(), 0.0);
        let p1 = Vec3::new(r * a1.cos(), wall_h + r * 0.5 * a1.sin(), 0.0);
        let mid = (p0 + p1) * 0.5;
        let along = p1 - p0;
        let rot = Mat4::from_rotation_z(along.y.atan2(along.x));
        vault.append(
            &Mesh::cuboid(
                Vec3::new(-along.length() / 2.0 - 0.02, 0.0, -2.0),
                Vec3::new(along.length() / 2.0 + 0.02, 0.3, len + 2.5),
            ),
            Mat4::from_translation(mid) * rot,
        );
    }
    vault
}

/// A pillar: base, round shaft, capital block and a flattened sphere under the capital.
fn pillar_mesh() -> Mesh {
    let wall_h = HALL_WALL_HEIGHT;
    let mut m = Mesh::default();
    m.append(
        &Mesh::cuboid(Vec3::new(-0.8, 0.0, -0.8), Vec3::new(0.8, 0.6, 0.8)),
        Mat4::IDENTITY,
    );
    m.append(
        &Mesh::cylinder(64),
        Mat4::from_translation(Vec3::new(0.0, 0.6, 0.0))
            * Mat4::from_scale(Vec3::new(0.55, wall_h - 1.8, 0.55)),
    );
    m.append(
        &Mesh::cuboid(
            Vec3::new(-0.8, wall_h - 1.2, -0.8),
            Vec3::new(0.8, wall_h - 0.6, 0.8),
        ),
        Mat4::IDENTITY,
    );
    m.append(
        &Mesh::sphere(48, 24),
        Mat4::from_translation(Vec3::new(0.0, wall_h - 1.2, 0.0))
            * Mat4::from_scale(Vec3::new(0.75, 0.3, 0.75)),
    );
    m
}

/// An arch spanning one bay, made of short straight segments.
fn arch_mesh() -> Mesh {
    let bay = HALL_BAY;
    let mut m = Mesh::default();
    let n = 24;
    for i in 0..n {
        let a0 = i as f32 / n as f32 * std::f32::consts::PI;
        let a1 = (i + 1) as f32 / n as f32 * std::f32::consts::PI;
        let r = bay / 2.0;
        let p0 = Vec3::new(0.0, r * a0.sin(), r * a0.cos());
        let p1 = Vec3::new(0.0, r * a1.sin(), r * a1.cos());
        let mid = (p0 + p1) * 0.5;
        let along = p1 - p0;
        let rot = Mat4::from_rotation_x(-(along.y.atan2(along.z)));
        m.append(
            &Mesh::cuboid(
                Vec3::new(-0.4, -0.2, -along.length() / 2.0 - 0.03),
                Vec3::new(0.4, 0.4, along.length() / 2.0 + 0.03),
            ),
            Mat4::from_translation(mid) * rot,
        );
    }
    m
}

/// The walk up the nave.
fn hall_path(b: &mut SceneBuilder, len: f32) {
    let e = 1.7;
    b.path(
        "default",
        &[
            (
                Vec3::new(0.0, e + 1.0, -1.0),
                Vec3::new(0.0, e + 2.0, len * 0.5),
            ),
            (
                Vec3::new(-3.0, e + 1.0, len * 0.3),
                Vec3::new(2.0, e + 3.0, len * 0.8),
            ),
            (
                Vec3::new(3.0, e + 1.0, len * 0.6),
                Vec3::new(-4.0, e + 2.0, len),
            ),
        ],
    );
}

/// Default path name of a scene.
pub fn default_path(scene: &Scene) -> &str {
    scene
        .paths
        .first()
        .map(|p| p.name.as_str())
        .unwrap_or("default")
}
