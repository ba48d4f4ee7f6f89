//! GI with moving objects, on the GPU under the validation layer: a moved occluder changes the
//! shadow map of the VPL that sees it and not the map of one that does not (incremental renders
//! only the first again and gives the image of a fresh render of every map), and `gi --movers`
//! runs all three modes with the incremental mode re-rendering the maps the movers touch.

use crate::common;

use coherent::app::gi_run::{self, GiMode, GiRunOptions, GiSetup};
use coherent::gi::geometry::WorldGeometry;
use coherent::gi::light::Spotlight;
use coherent::gi::movers::{stale_layers, Move};
use coherent::gi::vpl::Vpl;
use coherent::gi::{GiOptions, GiRenderer, IsmOptions, OutputMode};
use coherent::scene::camera::Camera;
use coherent::scene::{Aabb, CameraPose, Scene};
use glam::{Mat4, Vec2, Vec3};

const SIZE: (u32, u32) = (96, 72);

fn push_quad(g: &mut WorldGeometry, c: [Vec3; 4], n: Vec3, albedo: f32) {
    for t in [[c[0], c[1], c[2]], [c[0], c[2], c[3]]] {
        for p in t {
            g.bounds.grow(p);
        }
        g.triangles.push(t);
        g.normals.push([n; 3]);
        g.albedo.push(Vec3::splat(albedo));
    }
}

/// A 4 x 4 floor at y = 0 in 0.25 cells.
fn floor() -> WorldGeometry {
    let mut g = WorldGeometry::empty();
    let s = 0.25;
    for i in 0..16 {
        for j in 0..16 {
            let (x, z) = (-2.0 + i as f32 * s, -2.0 + j as f32 * s);
            let c = [
                Vec3::new(x, 0.0, z),
                Vec3::new(x, 0.0, z + s),
                Vec3::new(x + s, 0.0, z + s),
                Vec3::new(x + s, 0.0, z),
            ];
            push_quad(&mut g, c, Vec3::Y, 0.8);
        }
    }
    g
}

/// The occluder: a 1 x 1 horizontal quad at height 1 (both sides), moved by `t`; split into
/// pieces shorter than the renderer's longest edge, so it keeps its triangles.
fn occluder(t: &Mat4) -> WorldGeometry {
    let mut g = WorldGeometry::empty();
    let c = [
        Vec3::new(-0.5, 1.0, -0.5),
        Vec3::new(-0.5, 1.0, 0.5),
        Vec3::new(0.5, 1.0, 0.5),
        Vec3::new(0.5, 1.0, -0.5),
    ];
    push_quad(&mut g, c, Vec3::NEG_Y, 0.5);
    g.tessellated(0.2).placed(t)
}

fn vpl(position: Vec3, normal: Vec3, layer: u32) -> Vpl {
    Vpl {
        id: u64::from(layer),
        position,
        normal: normal.normalize(),
        albedo: Vec3::ONE,
        disk_point: Vec2::ZERO,
        weight: 0.5,
        layer,
    }
}

/// A: high above the floor looking down, the occluder between it and the floor. B: low at the
/// floor's near edge, tilted away: the occluder is behind its base plane, the strip of floor at
/// z < -1.56 in front of it.
fn two_vpls() -> [Vpl; 2] {
    [
        vpl(Vec3::new(0.0, 2.0, 0.0), Vec3::NEG_Y, 0),
        vpl(Vec3::new(0.0, 0.2, -1.5), Vec3::new(0.0, 0.3, -1.0), 1),
    ]
}

fn camera() -> Camera {
    Camera::from_pose(
        CameraPose {
            eye: Vec3::new(0.0, 4.0, -3.5),
            target: Vec3::new(0.0, 0.0, -0.3),
        },
        SIZE.0 as f32 / SIZE.1 as f32,
        20.0,
    )
}

fn renderer(ctx: &std::sync::Arc<coherent::gpu::GpuContext>, g: &WorldGeometry) -> GiRenderer {
    let mut r = GiRenderer::new(
        ctx,
        g,
        GiOptions {
            width: SIZE.0,
            height: SIZE.1,
            vpl_layers: 2,
            max_vpls: 2,
            shadow_size: 128,
        },
    )
    .expect("renderer");
    r.output = OutputMode::IndirectOnly;
    r
}

#[test]
fn a_moved_occluder_changes_only_the_map_of_the_vpl_that_sees_it() {
    let (ctx, log) = common::context();
    {
        let light = Spotlight::new(Vec3::new(0.0, 3.0, 0.0), Vec3::NEG_Y, Vec3::splat(40.0));
        let vpls = two_vpls();
        let (before, after) = (Mat4::IDENTITY, Mat4::from_translation(Vec3::X));
        let mut scene = floor();
        let first = scene.triangles.len() as u32;
        scene.append(&occluder(&before));
        let cam = camera();
        let mut r = renderer(&ctx, &scene);
        assert_eq!(r.triangle_count() as usize, scene.triangles.len());
        r.frame(&light, &vpls, &[0, 1], &cam).expect("frame");
        let at_rest = r.read_output().expect("readback");

        // Move the occluder by one unit in x.
        let moved = occluder(&after);
        r.move_triangles(first, &moved).expect("move");
        let moves = [Move {
            old: occluder(&before).bounds,
            new: moved.bounds,
        }];
        let stale = stale_layers(&vpls, &moves, &[], 1e-4);
        assert_eq!(stale, vec![0], "only A sees the occluder's old or new box");
        // Kept maps for both (nothing invalidated), then A's map rendered again.
        r.frame(&light, &vpls, &[], &cam).expect("frame");
        let kept = r.read_output().expect("readback");
        r.frame(&light, &vpls, &stale, &cam).expect("frame");
        let invalidated = r.read_output().expect("readback");

        // Every map rendered afresh with the occluder at its new place.
        let mut fresh_scene = floor();
        fresh_scene.append(&moved);
        let mut fresh = renderer(&ctx, &fresh_scene);
        fresh.frame(&light, &vpls, &[0, 1], &cam).expect("frame");
        let expected = fresh.read_output().expect("readback");

        let moved_shadow = common::diff_pixels(&at_rest, &expected);
        let stale_pixels = common::diff_pixels(&kept, &expected);
        let wrong = common::diff_pixels(&invalidated, &expected);
        eprintln!(
            "pixels changed by the move {moved_shadow}, wrong with kept maps {stale_pixels}, \
             wrong after re-rendering A's map {wrong}"
        );
        assert!(moved_shadow > 50, "the move changes the indirect light");
        assert!(stale_pixels > 50, "A's old map is wrong after the move");
        assert_eq!(
            wrong, 0,
            "A's new map and B's kept map give the fresh image"
        );
    }
    drop(ctx);
    common::assert_silent(&log);
}

#[test]
fn a_mover_merged_with_a_static_twin_is_drawn_where_it_moved() {
    let (ctx, log) = common::context();
    {
        let light = Spotlight::new(Vec3::new(0.0, 3.0, 0.0), Vec3::NEG_Y, Vec3::splat(40.0));
        let vpls = two_vpls();
        // A static copy of the occluder, then the mover at the same place: every vertex of the
        // mover is bit-identical to one of the static copy's, so the indexed passes point the
        // mover's corners at the static ones until they are merged again after the move.
        let mut scene = floor();
        scene.append(&occluder(&Mat4::IDENTITY));
        let first = scene.triangles.len() as u32;
        scene.append(&occluder(&Mat4::IDENTITY));
        let moved = occluder(&Mat4::from_translation(Vec3::new(1.0, 0.0, 0.5)));
        let cam = camera();
        let mut r = renderer(&ctx, &scene);
        r.frame(&light, &vpls, &[0, 1], &cam).expect("frame");
        r.move_triangles(first, &moved).expect("move");
        r.frame(&light, &vpls, &[0, 1], &cam).expect("frame");
        let after_move = r.read_output().expect("readback");

        let mut fresh_scene = floor();
        fresh_scene.append(&occluder(&Mat4::IDENTITY));
        fresh_scene.append(&moved);
        let mut fresh = renderer(&ctx, &fresh_scene);
        fresh.frame(&light, &vpls, &[0, 1], &cam).expect("frame");
        let expected = fresh.read_output().expect("readback");
        let mut unmoved = renderer(&ctx, &scene);
        unmoved.frame(&light, &vpls, &[0, 1], &cam).expect("frame");
        let at_rest = unmoved.read_output().expect("readback");

        assert!(
            common::diff_pixels(&at_rest, &expected) > 50,
            "the move changes the indirect light"
        );
        assert_eq!(
            common::diff_pixels(&after_move, &expected),
            0,
            "the moved copy is drawn where it moved"
        );
    }
    drop(ctx);
    common::assert_silent(&log);
}

/// The median shadow maps rendered a frame by `mode` in `s`.
fn maps_median(s: &gi_run::GiSummary, mode: &str) -> f64 {
    s.algorithms
        .iter()
        .find(|(name, _)| name == mode)
        .map(|(_, m)| m.shadow_maps_rendered_median)
        .expect("mode")
}

#[test]
fn gi_with_movers_runs_all_modes_and_incremental_renders_the_touched_maps() {
    let (ctx, log) = common::context();
    {
        let scene = Scene::load("cornell", 1.0, 0).expect("scene");
        let opts = GiRunOptions {
            vpls: 32,
            budget: 2,
            frames: 4,
            width: 64,
            height: 48,
            modes: vec![GiMode::Incremental, GiMode::Full, GiMode::Ism],
            shadow_size: 64,
            sample_frames: 1,
            ism: IsmOptions {
                map_size: 16,
                points_per_vpl: 256,
            },
        };
        let run = |movers| {
            let setup = GiSetup {
                movers,
                ..GiSetup::default()
            };
            let mut reports = Vec::new();
            let summary = gi_run::run_reporting(&ctx, &scene, &opts, None, &setup, |d, t| {
                reports.push((d, t))
            })
            .expect("gi run");
            // One report per rendered frame: the reference's sampled frames, then each
            // mode's frames, counted up to the total.
            let total = summary.rmse_frames.len() as u64 + 3 * u64::from(opts.frames);
            let expected: Vec<(u64, u64)> = (1..=total).map(|d| (d, total)).collect();
            assert_eq!(reports, expected);
            summary
        };
        let still = run(0);
        let moving = run(3);
        eprintln!("{}{}", still.table(), moving.table());
        assert_eq!(moving.movers, 3);
        assert!(maps_median(&still, "incremental") <= 2.0);
        assert!(
            maps_median(&moving, "incremental") > maps_median(&still, "incremental"),
            "spinning fans in the box make incremental render more maps"
        );
        assert_eq!(maps_median(&moving, "full"), maps_median(&still, "full"));
        for (name, m) in &moving.algorithms {
            assert!(m.rmse_vs_reference.is_some_and(f64::is_finite), "{name}");
        }
    }
    drop(ctx);
    common::assert_silent(&log);
}

/// A run of `frames` frames at 64x48 with `vpls` VPLs (2 new a frame), 64x64 shadow maps,
/// one sample frame.
fn small_run(vpls: usize, frames: u32, modes: Vec<GiMode>) -> GiRunOptions {
    GiRunOptions {
        vpls,
        budget: 2,
        frames,
        width: 64,
        height: 48,
        modes,
        shadow_size: 64,
        sample_frames: 1,
        ism: IsmOptions::default(),
    }
}

/// A glTF column that its skin's joint lifts (its transform never changes): GI poses it each
/// frame, so the incremental mode renders again the maps of the VPLs that see it, which it
/// would not do for a column that stands still; every mode still matches the reference.
#[test]
fn gi_poses_skinned_meshes_and_incremental_renders_the_maps_they_touch() {
    use coherent::scene::gltf::testdata::skinned_column;
    let dir = coherent::testing::TempDir::new("gi_skinned");
    let (ctx, log) = common::context();
    {
        let opts = small_run(32, 6, vec![GiMode::Incremental, GiMode::Full]);
        let run = |lift: f32| {
            let path = dir.join(format!("column_{lift}.gltf"));
            std::fs::write(&path, skinned_column(lift).gltf_embedded()).unwrap();
            let scene = Scene::load(path.to_str().unwrap(), 1.0, 0).expect("scene");
            gi_run::run_with(&ctx, &scene, &opts, None, &GiSetup::default()).expect("gi run")
        };
        let still = run(0.0);
        let lifted = run(4.0);
        eprintln!("{}{}", still.table(), lifted.table());
        assert_eq!((lifted.movers, lifted.objects), (1, 2));
        assert_eq!(
            lifted.animation.as_deref(),
            Some("0"),
            "an animation without a name"
        );
        assert!(
            maps_median(&lifted, "incremental") > maps_median(&still, "incremental"),
            "the posed column makes incremental render more maps"
        );
        for (name, m) in &lifted.algorithms {
            assert!(m.rmse_vs_reference.is_some_and(f64::is_finite), "{name}");
        }
    }
    drop(ctx);
    common::assert_silent(&log);
}

/// A cube 20 times its mesh's size (its node scaled, as exporters scale a model in other
/// units) that an animation moves over a floor: its triangles are split where they are
/// placed, not in the mesh's units (before, the renderer found them too long and split them
/// again, and the run stopped with an error).
#[test]
fn gi_splits_a_scaled_mover_where_it_is_placed() {
    use coherent::scene::gltf::testdata::GltfBuilder;
    let dir = coherent::testing::TempDir::new("gi_scaled_mover");
    let (ctx, log) = common::context();
    {
        let opts = small_run(16, 3, vec![GiMode::Incremental]);
        let mut b = GltfBuilder::default();
        let cube = b.cube_mesh([0.8, 0.8, 0.8, 1.0]);
        b.nodes.push(format!(
            r#"{{"mesh":{cube},"translation":[0,-1,0],"scale":[40,0.1,40]}}"#
        ));
        b.nodes.push(format!(
            r#"{{"mesh":{cube},"translation":[0,12,0],"scale":[20,20,20]}}"#
        ));
        let times = b.key_times(&[0.0, 1.0]);
        let places = b.vec3(&[[0.0, 12.0, 0.0], [5.0, 12.0, 0.0]]);
        b.head = format!(
            r#""animations":[{{"samplers":[{{"input":{times},"output":{places}}}],"channels":[{{"sampler":0,"target":{{"node":1,"path":"translation"}}}}]}}],"#
        );
        let path = dir.join("scaled.gltf");
        std::fs::write(&path, b.gltf_embedded()).unwrap();
        let scene = Scene::load(path.to_str().unwrap(), 1.0, 0).expect("scene");
        let run = gi_run::run_with(&ctx, &scene, &opts, None, &GiSetup::default())
            .expect("gi runs the scaled mover");
        assert_eq!(run.movers, 1);
        for (name, m) in &run.algorithms {
            assert!(m.rmse_vs_reference.is_some_and(f64::is_finite), "{name}");
        }
    }
    drop(ctx);
    common::assert_silent(&log);
}

#[test]
fn movers_geometry_follows_the_transform() {
    let g = occluder(&Mat4::IDENTITY);
    let moved = g.placed(&Mat4::from_translation(Vec3::new(0.0, 2.0, 0.0)));
    assert_eq!(moved.triangles.len(), g.triangles.len());
    let b: Aabb = moved.bounds;
    assert!((b.min.y - 3.0).abs() < 1e-6 && (b.max.y - 3.0).abs() < 1e-6);
}
