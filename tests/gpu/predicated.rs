//! The predicated latency mode on the built-in renderer (`VK_EXT_conditional_rendering`): CHC++
//! (and NOHC) with one submission per frame and no wait draws the previously invisible nodes under their
//! queries' predicates. Its images equal vfc's pixel for pixel and it misses no visible object
//! along walks with a camera cut, a turn that brings nodes in from behind, and movers; the
//! recorder refuses predicates read without their barrier; a device without the extension gets
//! a clear error.

use coherent::app::walk;
use coherent::bvh::ObjectBvh;
use coherent::culling::{self, ChcppParams, Culler, CullerSetup};
use coherent::gpu::{ContextOptions, GpuContext};
use coherent::render::Renderer;
use coherent::scene::movers::Movers;
use coherent::scene::{CameraPose, Scene};

use crate::common;

const MODES: [&str; 2] = ["chcpp@predicated", "chcpp@predicated-k2"];

/// 60 poses: the path, a cut to a far part of it at frame 30, and from frame 45 a turn on the
/// spot through 180 degrees (what was behind the camera enters the frustum).
fn poses(scene: &Scene, path: &str) -> Vec<CameraPose> {
    let p = scene.path(path).expect("path").clone();
    let mut out: Vec<CameraPose> = (0..30).map(|f| p.pose_at(4.0 + f as f32)).collect();
    out.extend((30..45).map(|f| p.pose_at(120.0 + f as f32)));
    let last = out[44];
    let ahead = last.target - last.eye;
    out.extend((45..60).map(|f| {
        let a = (f - 44) as f32 * std::f32::consts::PI / 15.0;
        let (s, c) = a.sin_cos();
        let dir = coherent::culling::glam::Vec3::new(
            ahead.x * c - ahead.z * s,
            ahead.y,
            ahead.x * s + ahead.z * c,
        );
        CameraPose {
            eye: last.eye,
            target: last.eye + dir,
        }
    }));
    out
}

/// Walks `poses` with vfc and the predicated modes `names` (created from `setup`; the checks
/// below read the part policy of `setup.params`): every frame of a
/// predicated mode is one submission with no wait and two pass breaks at most (the second
/// decides the parts of split nodes under their predicates: by the renderer's depth part
/// test, or with `predicated_tested_parts_min` at its maximum by queries; with one
/// predicate level there is one, where the queried nodes' draws are gathered), draws every object
/// that owns a pixel of the exact ID pass (predicates read back: a draw under a false predicate did not draw),
/// and its image equals vfc's but for at most `tie_pixels` pixels where surfaces tie in depth
/// and draw order decides. Returns the objects drawn under true predicates in all.
fn matches_vfc(
    r: &mut Renderer,
    triangles: &[u64],
    scene_bvh: &mut ObjectBvh,
    poses: &[CameraPose],
    movers: Option<&Movers>,
    tie_pixels: usize,
    (setup, names): (&CullerSetup, &[&str]),
) -> u32 {
    let params = &setup.params;
    let mut vfc = culling::create("vfc", &ChcppParams::default()).unwrap();
    let mut modes: Vec<Box<dyn Culler>> = names
        .iter()
        .map(|m| culling::create_named(m, setup).expect(m))
        .collect();
    r.log_drawn_objects(true);
    if let Some(m) = movers {
        r.count_mover_draws(m.objects());
    }
    let (mut pixels, mut taken, mut split_queries, mut tested_parts) = (Vec::new(), 0, 0, 0);
    let mut gathered = 0;
    for (f, &pose) in poses.iter().enumerate() {
        let f = f as u64;
        if let Some(m) = movers {
            walk::place_movers(m, f, scene_bvh, r).unwrap();
        }
        let bvh = &*scene_bvh;
        let cam = r.camera(pose, bvh);
        r.render_frame(vfc.as_mut(), bvh, &cam, f).unwrap();
        let reference = r.read_color().unwrap();
        for (name, c) in names.iter().zip(modes.iter_mut()) {
            let res = r.render_frame(c.as_mut(), bvh, &cam, f).unwrap();
            let tag = format!("{name} frame {f}");
            assert_eq!(res.counts.submits, 1, "{tag}: submissions");
            assert_eq!(res.stall_ms, 0.0, "{tag}: waited");
            assert_eq!(res.cull.blocking_waits, 0, "{tag}");

            assert!(res.counts.predicate_resolves <= 2, "{tag}: pass breaks");
            // Every query goes out after the traversal, in one batch, whatever the
            // algorithm's batching in the other modes: a switch into the query state and
            // one back (CHC's unbatched queries made two per query).
            assert!(
                res.counts.state_changes <= 4,
                "{tag}: {} state changes",
                res.counts.state_changes
            );
            // Every draw under a predicate is a block, except those of tested parts that the
            // device gathered into one indirect draw.
            assert_eq!(
                res.counts.conditional_blocks + res.counts.gathered_parts,
                res.cull.predicated_draws + res.cull.predicated_queries,
                "{tag}"
            );
            assert_eq!(
                res.counts.predicated_queries, res.cull.predicated_queries,
                "{tag}: queries under predicates"
            );
            split_queries += res.cull.predicated_queries;
            tested_parts += res.counts.tested_parts;
            gathered += res.counts.gathered_parts;
            assert_eq!(
                res.counts.predicated_objects, res.cull.predicated_objects,
                "{tag}: objects under predicates"
            );
            taken += res.counts.predicated_objects_taken;
            // Triangles (and mover draws) under a false predicate did not draw: the counts are
            // the log's.
            let logged: u64 = r
                .drawn_objects()
                .iter()
                .map(|&o| triangles[o as usize])
                .sum();
            assert_eq!(
                res.counts.drawn_triangles(),
                logged,
                "{tag}: triangles drawn"
            );
            assert_eq!(
                res.counts.drawn_objects() as usize,
                r.drawn_objects().len(),
                "{tag}: objects drawn"
            );
            if let Some(m) = movers {
                let logged = r.drawn_objects().iter();
                let logged = logged.filter(|o| m.objects().contains(o)).count();
                assert_eq!(
                    res.counts.mover_draws as usize, logged,
                    "{tag}: mover draws"
                );
            }
            let px = r.read_color().unwrap();
            r.object_pixels(bvh, &cam, &mut pixels).unwrap();
            let check = r.check_drawn(&pixels);
            assert_eq!(check.missed_objects, 0, "{tag}: missed visible objects");
            // The extra objects drawn only under true predicates are among the extra objects
            // and among the objects the true predicates drew.
            assert!(
                check.extra_predicated_objects <= check.extra_objects
                    && check.extra_predicated_objects <= res.counts.predicated_objects_taken,
                "{tag}: {} extra objects under predicates, {} extra, {} drawn under predicates",
                check.extra_predicated_objects,
                check.extra_objects,
                res.counts.predicated_objects_taken
            );
            let d = common::diff_pixels(&reference, &px);
            assert!(d <= tie_pixels, "{tag}: differs from vfc in {d} pixels");
        }
    }
    let o = &r.context().info.optional;
    let can_gather =
        o.draw_indirect_count && o.multi_draw_indirect && o.draw_indirect_first_instance;
    if params.predicated_refine_levels == 0 {
        // One predicate level: the queried nodes' draws are handed over before the resolve
        // and gathered there where the device can.
        assert_eq!(split_queries + tested_parts, 0, "one level splits nothing");
        if can_gather {
            assert!(gathered > 0, "no queried node's draws were gathered");
        }
    } else if params.predicated_tested_parts_min == 0 {
        assert!(tested_parts > 0, "no part was decided by the depth test");
        // Where the device can (lavapipe can), the passed parts' draws are gathered on the
        // device into one indirect draw with a count, not drawn in a block each.
        if can_gather {
            assert!(gathered > 0, "no tested part's draws were gathered");
        }
    } else {
        assert!(
            split_queries > 0 && tested_parts == 0,
            "no node was split into parts queried under its predicate"
        );
    }
    taken
}

/// What the predicated modes of chcpp need: its parameters.
fn with_params(params: ChcppParams) -> CullerSetup {
    CullerSetup {
        params,
        ..CullerSetup::default()
    }
}

/// CHC++ in the predicated mode with its part policies, and NOHC in it (with one and two
/// frames in flight and the suite's fixed cost model; the nodes its rule does not query are
/// drawn unconditionally, and that rule at work is tested in coherent-cull's `modes.rs`), on
/// the street and in the powerplant.
#[test]
fn predicated_images_equal_vfc_on_the_street_and_in_the_powerplant() {
    let (ctx, log) = common::context();
    {
        for (name, scale, path) in [("city", 0.1, "street"), ("powerplant", 0.5, "difficult")] {
            let (scene, mut bvh) = common::scene(name, scale);
            let mut r = Renderer::new(&ctx, &scene, 160, 90).unwrap();
            let tris: Vec<u64> = scene.objects.iter().map(|o| o.triangle_count()).collect();
            let poses = poses(&scene, path);
            // The parts of split nodes decided by the depth part test from the first frame on,
            // then queried.
            let taken = [0, u32::MAX].map(|tested_parts_min| {
                let params = ChcppParams {
                    predicated_tested_parts_min: tested_parts_min,
                    ..ChcppParams::default()
                };
                let setup = with_params(params);
                let taken = matches_vfc(&mut r, &tris, &mut bvh, &poses, None, 0, (&setup, &MODES));
                assert!(
                    taken > 0,
                    "{name}: something was drawn under a true predicate"
                );
                taken
            });
            // One predicate level (the GPU policy): each queried node's objects under its
            // own predicate, gathered on the device where it can.
            let gpu = with_params(ChcppParams::for_gpu());
            let one_level = matches_vfc(&mut r, &tris, &mut bvh, &poses, None, 0, (&gpu, &MODES));
            assert!(
                one_level > 0,
                "{name}: one level drew under a true predicate"
            );
            let nohc = common::setup(common::triangles(&scene), (160, 90), 0.05);
            let modes = ["nohc@predicated", "nohc@predicated-k2", "chc@predicated"];
            matches_vfc(&mut r, &tris, &mut bvh, &poses, None, 0, (&nohc, &modes));
            // The test is coarser than a query but still hides parts: within a quarter of the
            // queries' objects under true predicates (city 4,730 against 4,695, powerplant
            // 1,839 against 1,904; a test that passes every part draws 1.8x).
            assert!(
                taken[0] * 4 <= taken[1] * 5,
                "{name}: tested parts drew {} objects under true predicates, queried {}",
                taken[0],
                taken[1]
            );
        }
    }
    common::assert_silent(&log);
}

#[test]
fn predicated_images_equal_vfc_in_the_parking_with_100_movers() {
    let (ctx, log) = common::context();
    {
        let mut scene = Scene::load("parking", 0.5, 4096).unwrap();
        let movers = Movers::add(&mut scene, 100);
        let mut bvh = common::bvh_of(&scene);
        let mut r = Renderer::new(&ctx, &scene, 160, 90).unwrap();
        let poses = poses(&scene, &scene.default_path().unwrap().name.clone());
        // The parking's rows of cars hold faces flush with each other: where surfaces tie in
        // depth the first drawn wins, and the predicated draws come after the unconditional
        // ones (seen after the cut: the same colour, shaded by another face's normal; at most
        // 1% of the image; missed objects stay 0).
        let tris: Vec<u64> = scene.objects.iter().map(|o| o.triangle_count()).collect();
        matches_vfc(
            &mut r,
            &tris,
            &mut bvh,
            &poses,
            Some(&movers),
            144,
            (
                &with_params(ChcppParams {
                    predicated_tested_parts_min: 0,
                    ..ChcppParams::default()
                }),
                &MODES,
            ),
        );
    }
    common::assert_silent(&log);
}

/// The validation layers do not track conditional-rendering reads, so the recorder does: a
/// frame whose predicates were copied without the barrier to `CONDITIONAL_RENDERING_READ` is
/// refused, and the next one with the barrier renders.
#[test]
fn predicates_without_their_barrier_are_refused() {
    let (ctx, log) = common::context();
    {
        let (scene, bvh) = common::scene("city", 0.1);
        let mut r = Renderer::new(&ctx, &scene, 160, 90).unwrap();
        let pose = scene.path("street").unwrap().pose_at(10.0);
        let cam = r.camera(pose, &bvh);
        let setup = CullerSetup::default();
        let mut c = culling::create_named("chcpp@predicated", &setup).unwrap();
        // Queries' predicates first (box flags off), the flags' own barrier below.
        r.set_box_flags(false);
        r.skip_predicate_barrier(true);
        let err = r.render_frame(c.as_mut(), &bvh, &cam, 0).unwrap_err();
        assert!(err.to_string().contains("barrier"), "{err}");
        r.skip_predicate_barrier(false);
        c.reset();
        let res = r.render_frame(c.as_mut(), &bvh, &cam, 1).unwrap();
        assert!(res.counts.conditional_blocks > 0);
        // The same for the predicates of the depth part test: a walk that splits nodes reads
        // them, and without their barrier it is refused (the first frames may split none).
        let tested = CullerSetup {
            params: ChcppParams {
                predicated_tested_parts_min: 0,
                ..ChcppParams::default()
            },
            ..CullerSetup::default()
        };
        let mut c = culling::create_named("chcpp@predicated", &tested).unwrap();
        r.skip_part_barrier(true).unwrap();
        let path = scene.path("street").unwrap().clone();
        let refused = (0..30).find_map(|f| {
            let cam = r.camera(path.pose_at(f as f32), &bvh);
            r.render_frame(c.as_mut(), &bvh, &cam, 2 + f).err()
        });
        let err = refused.expect("a frame with part predicates and no barrier was refused");
        assert!(err.to_string().contains("barrier"), "{err}");
        r.skip_part_barrier(false).unwrap();
        c.reset();
        let res = r.render_frame(c.as_mut(), &bvh, &cam, 40).unwrap();
        assert!(res.counts.conditional_blocks > 0);
        // Box flags: without the barrier after their draw, a block on one is refused.
        r.set_box_flags(true);
        r.skip_flag_barrier(true);
        c.reset();
        let err = r.render_frame(c.as_mut(), &bvh, &cam, 41).unwrap_err();
        assert!(err.to_string().contains("barrier"), "{err}");
        r.skip_flag_barrier(false);
        c.reset();
        let res = r.render_frame(c.as_mut(), &bvh, &cam, 42).unwrap();
        assert!(res.counts.flag_tests > 0 && res.counts.queries_begun == 0);
        assert!(res.counts.conditional_blocks > 0);
    }
    common::assert_silent(&log);
}

/// Box flags answer the predicated mode's tests as its queries do (the visibility threshold is
/// 0): along the street with a cut and a turn, CHC++ with flags draws the same objects frame
/// by frame as with queries, with no occlusion query, one instanced draw of boxes per resolve
/// at most beside the blocks of tests under predicates, and fewer draw calls; its images
/// equal vfc's (the walks of `matches_vfc`, where `chcpp@predicated` uses flags by default).
/// A culler that reads its tests inside the frame keeps its queries.
#[test]
fn box_flags_decide_as_queries_do() {
    let (ctx, log) = common::context();
    {
        let (scene, bvh) = common::scene("city", 0.1);
        let mut r = Renderer::new(&ctx, &scene, 160, 90).unwrap();
        let poses = poses(&scene, "street");
        let setup = CullerSetup::default();
        r.log_drawn_objects(true);
        let mut drawn: [Vec<Vec<u32>>; 2] = [Vec::new(), Vec::new()];
        let mut calls = [0u32; 2];
        // Parts by the depth part test either way (gated flags would test them as queries
        // do, not as that test does).
        r.set_gated_parts(false);
        for (i, flags) in [true, false].into_iter().enumerate() {
            r.set_box_flags(flags);
            let mut c = culling::create_named("chcpp@predicated", &setup).unwrap();
            for (f, &pose) in poses.iter().enumerate() {
                let cam = r.camera(pose, &bvh);
                let res = r.render_frame(c.as_mut(), &bvh, &cam, f as u64).unwrap();
                let tag = format!("flags {flags}, frame {f}");
                if flags {
                    assert_eq!(res.counts.queries_begun, 0, "{tag}: queries");
                    assert!(res.counts.flag_tests > 0, "{tag}: no flag test");
                } else {
                    assert_eq!(res.counts.flag_tests, 0, "{tag}: flags");
                }
                assert_eq!(res.counts.submits, 1, "{tag}");
                assert!(res.counts.state_changes <= 4, "{tag}");
                calls[i] += res.counts.draw_calls;
                let mut objects = r.drawn_objects().to_vec();
                objects.sort_unstable();
                drawn[i].push(objects);
            }
        }
        for (f, (a, b)) in drawn[0].iter().zip(&drawn[1]).enumerate() {
            assert_eq!(a, b, "frame {f}: flags and queries drew different objects");
        }
        assert!(
            calls[0] < calls[1],
            "flags made {} draw calls, queries {}",
            calls[0],
            calls[1]
        );
        // Parts tested by gated flags: some tests lie under a node's flag, in no block.
        r.set_gated_parts(true);
        r.set_box_flags(true);
        let mut c = culling::create_named("chcpp@predicated", &setup).unwrap();
        let mut gated = 0;
        for (f, &pose) in poses.iter().enumerate() {
            let cam = r.camera(pose, &bvh);
            let res = r.render_frame(c.as_mut(), &bvh, &cam, f as u64).unwrap();
            assert_eq!(res.counts.submits, 1);
            gated += res.counts.tested_parts;
        }
        assert!(gated > 0, "no part was tested under its node's flag");
        // In-frame CHC++ reads its queries inside the frame: they stay queries.
        let mut c = culling::create_named("chcpp", &setup).unwrap();
        let cam = r.camera(poses[0], &bvh);
        let res = r.render_frame(c.as_mut(), &bvh, &cam, 0).unwrap();
        assert!(res.counts.queries_begun > 0 && res.counts.flag_tests == 0);
    }
    common::assert_silent(&log);
}

/// A part tested by a gated box flag (`test_part_if` under a node's flag) reads 1 only where its
/// node's flag is 1: with nothing drawn, a box ahead of the eye shows wherever it is tested,
/// and its test gated by a flag that read 0 (a box behind the eye) reads 0. Without the gate
/// in the vertex shader it would read 1.
#[test]
fn gated_box_flags_follow_their_gate() {
    use coherent::culling::{CullStats, FrameInput, OcclusionBackend, QueryId};
    use coherent::scene::Aabb;
    struct Gated {
        ids: Vec<QueryId>,
    }
    impl Culler for Gated {
        fn name(&self) -> &str {
            "gated"
        }
        fn reads_tests_after_frame(&self) -> bool {
            true
        }
        fn cull_frame(
            &mut self,
            input: &FrameInput,
            backend: &mut dyn OcclusionBackend,
        ) -> culling::Result<CullStats> {
            let (eye, forward) = (input.view.eye, input.view.forward());
            let ahead = Aabb::new(eye + forward * 5.0 - 0.5, eye + forward * 5.0 + 0.5);
            let behind = Aabb::new(eye - forward * 5.0 - 0.5, eye - forward * 5.0 + 0.5);
            let shown = backend.issue_query(&[ahead])?;
            let hidden = backend.issue_query(&[behind])?;
            backend.resolve_predicates()?;
            let under_shown = backend.test_part_if(shown, &[ahead])?;
            let under_hidden = backend.test_part_if(hidden, &[ahead])?;
            // Objects handed over under the parts before their resolve: drawn after it, under
            // each part's flag.
            if let (Some(a), Some(b)) = (under_shown, under_hidden) {
                backend.draw_objects_if(a, &[0])?;
                backend.draw_objects_if(b, &[1])?;
            }
            backend.resolve_predicates()?;
            self.ids = [Some(shown), Some(hidden), under_shown, under_hidden]
                .into_iter()
                .map(|id| id.expect("the renderer tests parts under box flags"))
                .collect();
            Ok(CullStats::default())
        }
        fn reset(&mut self) {}
    }
    let (ctx, log) = common::context();
    {
        let (scene, bvh) = common::scene("city", 0.1);
        let mut r = Renderer::new(&ctx, &scene, 160, 90).unwrap();
        let pose = scene.path("street").unwrap().pose_at(10.0);
        let cam = r.camera(pose, &bvh);
        let mut c = Gated { ids: Vec::new() };
        r.log_drawn_objects(true);
        let res = r.render_frame(&mut c, &bvh, &cam, 0).unwrap();
        assert_eq!(r.drawn_objects(), [0], "drawn under the parts' flags");
        assert_eq!(res.counts.conditional_blocks, 2);
        assert_eq!(res.counts.queries_begun, 0);
        assert_eq!(res.counts.flag_tests, 4);
        assert_eq!(res.counts.tested_parts, 2);
        let values: Vec<Option<u64>> = c
            .ids
            .iter()
            .map(|&id| r.query_result(id).unwrap())
            .collect();
        assert_eq!(
            values,
            [Some(1), Some(0), Some(1), Some(0)],
            "shown, hidden, under each"
        );
    }
    common::assert_silent(&log);
}

/// A device without `VK_EXT_conditional_rendering` (the extension left off): the predicated mode
/// refuses with an error that names it; the other modes run.
#[test]
fn without_conditional_rendering_the_predicated_mode_names_the_extension() {
    let ctx = GpuContext::new(&ContextOptions {
        validation: true,
        strict_validation: true,
        without_conditional_rendering: true,
        ..Default::default()
    })
    .unwrap();
    let log = ctx.validation_log();
    {
        assert!(!ctx.info.optional.conditional_rendering);
        let (scene, bvh) = common::scene("city", 0.05);
        let mut r = Renderer::new(&ctx, &scene, 160, 90).unwrap();
        let cam = r.camera(scene.path("street").unwrap().pose_at(10.0), &bvh);
        let setup = CullerSetup::default();
        let mut c = culling::create_named("chcpp@predicated", &setup).unwrap();
        let err = r.render_frame(c.as_mut(), &bvh, &cam, 0).unwrap_err();
        assert!(
            err.to_string().contains("VK_EXT_conditional_rendering"),
            "{err}"
        );
        let mut next = culling::create_named("chcpp@next-frame", &setup).unwrap();
        r.render_frame(next.as_mut(), &bvh, &cam, 1).unwrap();
    }
    common::assert_silent(&log);
}

/// `render --latency predicated` renders the frame with one submission and says how many objects
/// went under predicates; its image equals vfc's.
#[test]
fn render_takes_the_predicated_latency() {
    let dir = coherent::testing::TempDir::new("render-pred");
    let render = |algorithm: &str, latency: &str, png: &str| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_coherent"))
            .args([
                "render", "--scene", "city", "--scale", "0.1", "--size", "320x180",
            ])
            .args([
                "--frame",
                "12",
                "--algorithm",
                algorithm,
                "--latency",
                latency,
            ])
            .arg("--out")
            .arg(dir.join(png))
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stdout).to_string();
        assert!(
            out.status.success(),
            "{text}{}",
            String::from_utf8_lossy(&out.stderr)
        );
        text
    };
    let text = render("chcpp", "predicated", "p.png");
    assert!(
        text.contains("chcpp@predicated")
            && text.contains(" 1 submits")
            && text.contains("under predicates"),
        "{text}"
    );
    render("vfc", "in-frame", "v.png");
    let read = |png: &str| image::open(dir.join(png)).unwrap().to_rgba8().into_raw();
    assert_eq!(common::diff_pixels(&read("v.png"), &read("p.png")), 0);
}

/// Ranges of the draw order that do not lie in it, and predicates that are not resolved
/// queries of the frame, are refused with an error, not a panic or a draw.
#[test]
fn draw_order_ranges_outside_the_order_are_refused() {
    use coherent::culling::OcclusionBackend;
    let (ctx, log) = common::context();
    {
        let (scene, _) = common::scene("city", 0.05);
        let mut r = Renderer::new(&ctx, &scene, 160, 90).unwrap();
        let order: Vec<u32> = (0..scene.objects.len() as u32).collect();
        r.set_draw_order(&order).unwrap();
        let n = order.len() as u32;
        // Past the end, reversed, starting at the end.
        for (start, end) in [(n - 1, n + 1), (3, 2), (n, u32::MAX)] {
            let err = r
                .draw_order_ranges_if(0, &order, std::slice::from_ref(&(start..end)))
                .unwrap_err();
            assert!(err.to_string().contains("outside the order"), "{err}");
        }
        let err = r
            .draw_order_ranges_if(0, &order, std::slice::from_ref(&(0..4)))
            .unwrap_err();
        assert!(
            err.to_string().contains("not a resolved predicate"),
            "{err}"
        );
    }
    common::assert_silent(&log);
}
