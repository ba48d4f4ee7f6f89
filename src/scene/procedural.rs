//! The built-in procedural scenes (`city`, `parking`, `powerplant`, `cornell`, `hall`) with their
//! walkthrough paths. Deterministic: fixed seeds, so tests and benchmarks are reproducible.

use glam::{Mat4, Quat, Vec3};

use super::mesh::{Mesh, Rng, SceneBuilder};
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

/// `city`: a grid of blocks with tall buildings (the occluders), trees, cars, lamps, benches,
/// statues on the streets and machinery on the roofs.
pub fn city(scale: f32) -> Scene {
    let mut b = SceneBuilder::new("city");
    let mut rng = Rng::new(0xC17E);
    let blocks = ((14.0 * scale.sqrt()).round() as i32).max(2);
    let block = 40.0f32;
    let street = 14.0f32;
    let pitch = block + street;
    let extent = blocks as f32 * pitch;
    let ground = Mesh::cuboid(
        Vec3::new(-street, -0.5, -street),
        Vec3::new(extent, 0.0, extent),
    );
    b.add(&ground, Vec3::new(0.32, 0.32, 0.34));
    let cube = b.proto(&Mesh::cube());
    let tree = b.proto(&tree_mesh());
    let car = b.proto(&car_mesh());
    let lamp = b.proto(&lamp_mesh());
    let bench = b.proto(&bench_mesh());
    let statue = b.proto(&statue_mesh());
    let roof_unit = b.proto(&roof_unit_mesh());
    let palette = [
        Vec3::new(0.75, 0.70, 0.62),
        Vec3::new(0.62, 0.55, 0.50),
        Vec3::new(0.55, 0.60, 0.68),
        Vec3::new(0.80, 0.78, 0.72),
        Vec3::new(0.58, 0.42, 0.35),
        Vec3::new(0.45, 0.50, 0.55),
    ];
    let car_colors = [
        Vec3::new(0.8, 0.1, 0.1),
        Vec3::new(0.1, 0.2, 0.7),
        Vec3::new(0.9, 0.9, 0.9),
        Vec3::new(0.1, 0.1, 0.1),
        Vec3::new(0.9, 0.7, 0.1),
        Vec3::new(0.2, 0.5, 0.3),
    ];
    for bx in 0..blocks {
        for bz in 0..blocks {
            let x0 = bx as f32 * pitch;
            let z0 = bz as f32 * pitch;
            // sidewalk slab
            b.instance(
                cube,
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
                    let w = rng.range(14.0, 18.5);
                    let d = rng.range(14.0, 18.5);
                    let h = rng.range(18.0, 70.0);
                    let cx = x0 + 10.0 + lx as f32 * 20.0;
                    let cz = z0 + 10.0 + lz as f32 * 20.0;
                    let color = palette[rng.below(palette.len() as u32) as usize];
                    b.instance(
                        cube,
                        trs(Vec3::new(cx, 0.2 + h / 2.0, cz), 0.0, Vec3::new(w, h, d)),
                        color,
                    );
                    for _ in 0..3 {
                        let ux = cx + rng.range(-w / 2.0 + 1.5, w / 2.0 - 1.5);
                        let uz = cz + rng.range(-d / 2.0 + 1.5, d / 2.0 - 1.5);
                        b.instance(
                            roof_unit,
                            trs(Vec3::new(ux, 0.2 + h, uz), rng.range(0.0, 3.0), Vec3::ONE),
                            Vec3::new(0.6, 0.6, 0.62),
                        );
                    }
                }
            }
            // trees and lamps along the block edges, cars in the streets
            for side in 0..4 {
                let along = |t: f32| -> (Vec3, f32) {
                    match side {
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
                };
                for k in 0..5 {
                    let (p, _) = along(4.0 + k as f32 * 8.0);
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
                for k in 0..2 {
                    let (p, r) = along(8.0 + k as f32 * 24.0);
                    b.instance(
                        lamp,
                        trs(p + Vec3::Y * 0.2, r, Vec3::ONE),
                        Vec3::new(0.2, 0.2, 0.22),
                    );
                    let (p, r) = along(12.0 + k as f32 * 16.0);
                    b.instance(
                        bench,
                        trs(p + Vec3::Y * 0.2, r, Vec3::ONE),
                        Vec3::new(0.45, 0.3, 0.2),
                    );
                }
                // parked cars in the lane next to this side
                let lane = match side {
                    0 => Vec3::new(0.0, 0.0, -3.0),
                    1 => Vec3::new(0.0, 0.0, 3.0),
                    2 => Vec3::new(-3.0, 0.0, 0.0),
                    _ => Vec3::new(3.0, 0.0, 0.0),
                };
                for k in 0..3 {
                    let (p, r) = along(6.0 + k as f32 * 13.0 + rng.range(-1.0, 1.0));
                    let c = car_colors[rng.below(car_colors.len() as u32) as usize];
                    b.instance(car, trs(p + lane, r, Vec3::ONE), c);
                }
            }
            // statues at the block corners
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
    }
    // street: walk along a street, turn, walk another; eye height 1.7 m.
    let s0 = block + street / 2.0; // centre line of the first street
                                   // The paths are laid out on the default-size city (14 blocks), so that larger scales grow
                                   // the city around the same walk (for scaling measurements).
    let path_blocks = blocks.min(14);
    let path_extent = path_blocks as f32 * pitch;
    let mid = (path_blocks / 2) as f32 * pitch - street / 2.0;
    let far = path_extent - street;
    let e = 1.7;
    b.path(
        "street",
        &[
            (Vec3::new(s0, e, 2.0), Vec3::new(s0, e, 40.0)),
            (
                Vec3::new(s0, e, mid * 0.5),
                Vec3::new(s0 + 2.0, e, mid * 0.5 + 40.0),
            ),
            (Vec3::new(s0, e, mid), Vec3::new(s0 + 20.0, e, mid + 20.0)),
            (
                Vec3::new(s0 + pitch, e, mid),
                Vec3::new(s0 + pitch + 40.0, e, mid),
            ),
            (Vec3::new(mid, e, mid), Vec3::new(mid + 40.0, e, mid + 5.0)),
            (
                Vec3::new(far * 0.75, e, mid),
                Vec3::new(far * 0.75 + 20.0, e, mid + 30.0),
            ),
            (
                Vec3::new(far * 0.75, e, mid + pitch),
                Vec3::new(far * 0.75, e, mid + pitch + 40.0),
            ),
            (
                Vec3::new(far * 0.75, e, far * 0.8),
                Vec3::new(far * 0.75 - 30.0, e, far * 0.8 + 20.0),
            ),
            (
                Vec3::new(far * 0.5, e, far * 0.8),
                Vec3::new(far * 0.5 - 40.0, e, far * 0.8),
            ),
            (
                Vec3::new(s0, e, far * 0.8),
                Vec3::new(s0, e, far * 0.8 - 40.0),
            ),
            (
                Vec3::new(s0, e, far * 0.5),
                Vec3::new(s0, e, far * 0.5 - 40.0),
            ),
        ],
    );
    let extent = path_extent;
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
    b.finish()
}

/// `parking`: rows of cars with engine blocks, seats and steering wheels inside closed bodies.
pub fn parking(scale: f32) -> Scene {
    let mut b = SceneBuilder::new("parking");
    let mut rng = Rng::new(0xCA75);
    let rows = ((8.0 * scale.sqrt()).round() as i32).max(1);
    let per_row = ((20.0 * scale.sqrt()).round() as i32).max(2);
    let dx = 3.0f32;
    let dz = 9.0f32;
    let w = per_row as f32 * dx;
    let d = rows as f32 * dz;
    b.add(
        &Mesh::cuboid(
            Vec3::new(-8.0, -0.3, -8.0),
            Vec3::new(w + 8.0, 0.0, d + 8.0),
        ),
        Vec3::new(0.35, 0.35, 0.37),
    );
    let body = b.proto(&{
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
    });
    let engine = b.proto(&{
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
    });
    let seat = b.proto(&{
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
    });
    let wheel = b.proto(&Mesh::sphere(16, 8));
    let pillar = b.proto(&Mesh::cube());
    let colors = [
        Vec3::new(0.7, 0.1, 0.1),
        Vec3::new(0.1, 0.3, 0.7),
        Vec3::new(0.85, 0.85, 0.85),
        Vec3::new(0.15, 0.15, 0.15),
        Vec3::new(0.8, 0.6, 0.1),
    ];
    for r in 0..rows {
        for c in 0..per_row {
            if rng.f32() < 0.12 {
                continue;
            }
            let p = Vec3::new(c as f32 * dx + 1.5, 0.0, r as f32 * dz + 2.5);
            let rot = if r % 2 == 0 {
                0.0
            } else {
                std::f32::consts::PI
            };
            let t = trs(p, rot, Vec3::ONE);
            b.instance(body, t, colors[rng.below(colors.len() as u32) as usize]);
            b.instance(
                engine,
                t * Mat4::from_translation(Vec3::new(0.0, 0.0, -1.5)),
                Vec3::new(0.3, 0.3, 0.3),
            );
            b.instance(
                seat,
                t * Mat4::from_translation(Vec3::new(-0.45, 0.0, 0.1)),
                Vec3::new(0.2, 0.15, 0.1),
            );
            b.instance(
                seat,
                t * Mat4::from_translation(Vec3::new(0.45, 0.0, 0.1)),
                Vec3::new(0.2, 0.15, 0.1),
            );
            b.instance(
                wheel,
                t * Mat4::from_translation(Vec3::new(-0.45, 0.9, -0.5))
                    * Mat4::from_scale(Vec3::new(0.2, 0.2, 0.04)),
                Vec3::new(0.1, 0.1, 0.1),
            );
        }
        if r % 2 == 1 {
            for c in (0..per_row).step_by(4) {
                b.instance(
                    pillar,
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
    let e = 1.7;
    let aisle = |r: i32| r as f32 * dz + 6.9;
    b.path(
        "default",
        &[
            (Vec3::new(-4.0, e, aisle(0)), Vec3::new(10.0, e, aisle(0))),
            (
                Vec3::new(w * 0.5, e, aisle(0)),
                Vec3::new(w * 0.5 + 10.0, e, aisle(0) + 2.0),
            ),
            (
                Vec3::new(w + 3.0, e, aisle(0) + 1.0),
                Vec3::new(w + 3.0, e, aisle(0) + 10.0),
            ),
            (
                Vec3::new(w + 3.0, e, aisle((rows - 1).max(0) / 2)),
                Vec3::new(w - 5.0, e, aisle((rows - 1).max(0) / 2)),
            ),
            (
                Vec3::new(w * 0.5, e, aisle((rows - 1).max(0) / 2)),
                Vec3::new(w * 0.5 - 10.0, e, aisle((rows - 1).max(0) / 2) + 1.0),
            ),
            (
                Vec3::new(-3.0, e + 2.0, d),
                Vec3::new(w * 0.5, 0.0, d * 0.5),
            ),
        ],
    );
    b.finish()
}

/// `powerplant`: rooms in a grid separated by walls with doorways, filled with boilers, pipe
/// runs and tanks.
pub fn powerplant(scale: f32) -> Scene {
    let mut b = SceneBuilder::new("powerplant");
    let mut rng = Rng::new(0x90E7);
    let rooms = ((4.0 * scale.sqrt()).round() as i32).max(1);
    let size = 24.0f32;
    let height = 12.0f32;
    let total = rooms as f32 * size;
    b.add(
        &Mesh::cuboid(
            Vec3::new(-1.0, -0.5, -1.0),
            Vec3::new(total + 1.0, 0.0, total + 1.0),
        ),
        Vec3::new(0.4, 0.4, 0.42),
    );
    let cube = b.proto(&Mesh::cube());
    let pipe = b.proto(&Mesh::cylinder(20));
    let boiler = b.proto(&{
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
    });
    let valve = b.proto(&Mesh::sphere(14, 8));
    for rx in 0..rooms {
        for rz in 0..rooms {
            let x0 = rx as f32 * size;
            let z0 = rz as f32 * size;
            // walls on the -x and -z sides with a doorway in the middle
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
            for k in 0..2 {
                let p = Vec3::new(x0 + 7.0 + k as f32 * 10.0, 0.0, z0 + rng.range(6.0, 9.0));
                b.instance(
                    boiler,
                    Mat4::from_translation(p),
                    Vec3::new(0.6, 0.25, 0.15),
                );
                for v in 0..4 {
                    b.instance(
                        valve,
                        Mat4::from_translation(p + Vec3::new(2.3, 1.0 + v as f32 * 1.5, 0.0))
                            * Mat4::from_scale(Vec3::splat(0.35)),
                        Vec3::new(0.8, 0.7, 0.1),
                    );
                }
            }
            // pipe runs along x and z at several heights
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
            // vertical pipes
            for _ in 0..8 {
                let p = Vec3::new(
                    x0 + rng.range(2.0, size - 2.0),
                    0.0,
                    z0 + rng.range(12.0, size - 2.0),
                );
                b.instance(
                    pipe,
                    Mat4::from_translation(p) * Mat4::from_scale(Vec3::new(0.25, height, 0.25)),
                    Vec3::new(0.55, 0.55, 0.6),
                );
            }
        }
    }
    let e = 1.7;
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
    b.finish()
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

/// `hall`: a nave with two rows of pillars, arches between them, side walls, a vaulted roof.
pub fn hall(scale: f32) -> Scene {
    let mut b = SceneBuilder::new("hall");
    let bays = ((8.0 * scale.sqrt()).round() as i32).max(2);
    let bay = 6.0f32;
    let len = bays as f32 * bay;
    let width = 16.0f32;
    let wall_h = 12.0f32;
    let stone = Vec3::new(0.75, 0.7, 0.62);
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
        stone,
    );
    // vault: a half cylinder over the nave made of many segments (the bulk of the triangles)
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
    b.add(&vault, stone);
    let pillar = b.proto(&{
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
    });
    let arch = b.proto(&{
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
    });
    for i in 0..=bays {
        let z = i as f32 * bay;
        for x in [-width / 2.0, width / 2.0] {
            b.instance(pillar, Mat4::from_translation(Vec3::new(x, 0.0, z)), stone);
            if i < bays {
                b.instance(
                    arch,
                    Mat4::from_translation(Vec3::new(x, wall_h - 0.6, z + bay / 2.0)),
                    stone * 0.95,
                );
            }
        }
    }
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
    b.sun(Vec3::new(0.3, 1.0, -0.4));
    b.finish()
}

/// Default path name of a scene.
pub fn default_path(scene: &Scene) -> &str {
    scene
        .paths
        .first()
        .map(|p| p.name.as_str())
        .unwrap_or("default")
}
