//! Imperfect shadow maps on the GPU under the validation layer: every VPL gets its own map, built
//! every frame from the surface points, and an occluder between a VPL and a surface darkens it.

use crate::common;

use coherent::gi::geometry::WorldGeometry;
use coherent::gi::light::Spotlight;
use coherent::gi::vpl::Vpl;
use coherent::gi::{GiOptions, GiRenderer, IsmOptions, OutputMode};
use coherent::scene::camera::Camera;
use coherent::scene::CameraPose;
use glam::{Mat4, Vec2, Vec3};

fn push_quad(g: &mut WorldGeometry, c: Vec3, u: Vec3, v: Vec3) {
    let (p0, p1, p2, p3) = (c - u - v, c + u - v, c + u + v, c - u + v);
    let n = u.cross(v).normalize();
    for t in [[p0, p1, p2], [p0, p2, p3]] {
        for p in t {
            g.bounds.grow(p);
        }
        g.triangles.push(t);
        g.normals.push([n; 3]);
        g.albedo.push(Vec3::splat(0.7));
    }
}

/// A 6 x 6 floor at y = 0 made of 0.5-wide quads, and, with `occluder`, a 1 x 1 plate at
/// y = 0.5 under the first VPL.
fn scene(occluder: bool) -> WorldGeometry {
    let mut g = WorldGeometry::empty();
    for i in 0..12 {
        for j in 0..12 {
            let c = Vec3::new(-2.75 + 0.5 * i as f32, 0.0, -2.75 + 0.5 * j as f32);
            push_quad(&mut g, c, Vec3::Z * 0.25, Vec3::X * 0.25);
        }
    }
    if occluder {
        push_quad(
            &mut g,
            Vec3::new(-1.5, 0.5, 0.0),
            Vec3::Z * 0.5,
            Vec3::X * 0.5,
        );
    }
    g
}

/// Two VPLs one unit above the floor, facing down, at x = -1.5 and x = +1.5.
fn vpls() -> Vec<Vpl> {
    [-1.5f32, 1.5]
        .iter()
        .enumerate()
        .map(|(i, &x)| Vpl {
            id: i as u64,
            position: Vec3::new(x, 1.0, 0.0),
            normal: Vec3::NEG_Y,
            albedo: Vec3::ONE,
            disk_point: Vec2::ZERO,
            weight: 0.5,
            layer: i as u32,
        })
        .collect()
}

/// Mean red value in a 7x7 window around the projection of `p`.
fn mean_at(px: &[u8], size: (u32, u32), vp: Mat4, p: Vec3) -> f64 {
    let ndc = vp.project_point3(p);
    let cx = ((ndc.x * 0.5 + 0.5) * size.0 as f32) as i32;
    let cy = ((0.5 - 0.5 * ndc.y) * size.1 as f32) as i32;
    let mut sum = 0.0;
    for y in cy - 3..=cy + 3 {
        for x in cx - 3..=cx + 3 {
            sum += f64::from(px[((y as u32 * size.0 + x as u32) * 4) as usize]);
        }
    }
    sum / 49.0
}

/// Renders the two VPLs' indirect light on the floor; returns the brightness under each VPL
/// and the number of imperfect maps built.
fn render(occluder: bool) -> ([f64; 2], u32) {
    let (ctx, log) = common::context();
    let out;
    {
        let geometry = scene(occluder);
        let size = (192, 144);
        let camera = Camera::from_pose(
            CameraPose {
                eye: Vec3::new(0.0, 4.0, -3.5),
                target: Vec3::ZERO,
            },
            size.0 as f32 / size.1 as f32,
            20.0,
        );
        let options = GiOptions {
            width: size.0,
            height: size.1,
            vpl_layers: 8,
            max_vpls: 8,
            shadow_size: 64,
        };
        let ism = IsmOptions {
            map_size: 32,
            points_per_vpl: 8192,
        };
        let mut r = GiRenderer::with_ism(&ctx, &geometry, options, ism).expect("renderer");
        r.output = OutputMode::IndirectOnly;
        r.exposure = 2.0;
        // The spotlight only sets the VPLs' flux; its own light is not in the image.
        let light = Spotlight::new(Vec3::new(0.0, 3.0, 0.0), Vec3::NEG_Y, Vec3::splat(20.0));
        let frame = r.frame(&light, &vpls(), &[], &camera).expect("frame");
        assert_eq!(
            frame.shadow_maps_rendered, 0,
            "no triangle maps in ism mode"
        );
        let px = r.read_output().expect("readback");
        let vp = camera.view_proj();
        // In the plate's shadow from the first VPL (which reaches z = -1), yet not behind the
        // plate as the camera sees it.
        let under = [Vec3::new(-1.5, 0.0, -0.7), Vec3::new(1.5, 0.0, -0.7)];
        out = (
            [
                mean_at(&px, size, vp, under[0]),
                mean_at(&px, size, vp, under[1]),
            ],
            frame.ism_maps,
        );
    }
    drop(ctx);
    common::assert_silent(&log);
    out
}

#[test]
fn each_vpl_has_its_own_map_and_an_occluder_darkens_what_it_hides() {
    let (open, maps) = render(false);
    let (blocked, maps_blocked) = render(true);
    eprintln!("under the VPLs: open {open:?}, with the plate under the first {blocked:?}");
    assert_eq!((maps, maps_blocked), (2, 2), "one map per VPL");
    assert!(
        open[0] > 40.0 && open[1] > 40.0,
        "the floor under both VPLs is lit"
    );
    // The plate hides the floor below the first VPL from it; the second VPL is far off to the
    // side and sees that floor only at a grazing angle, so the spot goes nearly dark.
    assert!(
        blocked[0] < 0.5 * open[0],
        "the occluder should darken the floor under the first VPL: {} vs {}",
        blocked[0],
        open[0]
    );
    // Under the second VPL nothing changed but the first VPL's far-off contribution.
    assert!((blocked[1] - open[1]).abs() < 0.15 * open[1]);
}
