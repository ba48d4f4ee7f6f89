//! The lecture's two missing systems and the object-level exactness check, under validation:
//! NOHC and CHC++ draw every visible object (missed_objects = 0) with images equal to VFC's;
//! the PVS of a scene with a known answer holds exactly what can be seen; PVS cache files and
//! calibrations are reused, and refused when truncated, corrupt or foreign.

use crate::common;

use coherent::app::calibrate::{self, Source};
use coherent::app::pvs_build::PvsFile;
use coherent::app::pvs_build::{self, PvsSettings};
use coherent::culling::chcpp::{Chcpp, ChcppParams};
use coherent::culling::{self, Culler, CullerSetup};
use coherent::render::Renderer;
use coherent::scene::mesh::{Mesh, SceneBuilder};
use coherent::scene::Scene;
use glam::Vec3;

const W: u32 = 160;
const H: u32 = 90;

fn temp_dir(name: &str) -> coherent::testing::TempDir {
    coherent::testing::TempDir::new(name)
}

/// NOHC with queries cheap against rendering (it queries nearly everything) or dear (it queries
/// only heavy, likely hidden nodes): both must stay exact.
fn nohc(scene: &Scene, query_ms: f64) -> Box<dyn Culler> {
    let setup = common::setup(common::triangles(scene), (W, H), query_ms);
    culling::create_with("nohc", &setup).unwrap()
}

/// `frames` consecutive frames of `path`: every algorithm's image equals VFC's and it misses no
/// object of the exact ID pass. Returns the total queries and wasted queries per algorithm.
fn exact_walk(scene_name: &str, scale: f32, path: &str, frames: u32) -> Vec<(String, u32, u32)> {
    let (ctx, log) = common::context();
    let mut totals;
    {
        let (scene, bvh) = common::scene(scene_name, scale);
        let path = scene.path(path).unwrap().clone();
        let mut r = Renderer::new(&ctx, &scene, W, H).unwrap();
        r.log_drawn_objects(true);
        let mut vfc = culling::create("vfc", &ChcppParams::default()).unwrap();
        let mut algs: Vec<(String, Box<dyn Culler>)> = vec![
            ("nohc".into(), nohc(&scene, 0.02)),
            ("nohc(dear queries)".into(), nohc(&scene, 2.0)),
            ("chcpp".into(), Box::new(Chcpp::new(ChcppParams::default()))),
            (
                "chc".into(),
                culling::create("chc", &ChcppParams::default()).unwrap(),
            ),
        ];
        totals = algs
            .iter()
            .map(|(n, _)| (n.clone(), 0, 0))
            .collect::<Vec<_>>();
        let mut owned = Vec::new();
        for f in 0..frames {
            let pose = path.sample(f, frames);
            let cam = r.camera(pose, &bvh);
            r.object_pixels(&bvh, &cam, &mut owned).unwrap();
            let (_, reference) = common::frame(&mut r, vfc.as_mut(), &bvh, pose, f as u64);
            assert_eq!(
                r.check_drawn(&owned).missed_objects,
                0,
                "vfc misses nothing"
            );
            for (i, (name, alg)) in algs.iter_mut().enumerate() {
                let (res, px) = common::frame(&mut r, alg.as_mut(), &bvh, pose, f as u64);
                let check = r.check_drawn(&owned);
                assert!(check.visible_objects > 0);
                assert_eq!(
                    check.missed_objects, 0,
                    "{scene_name} frame {f}: {name} missed {check:?}"
                );
                let d = common::diff_pixels(&reference, &px);
                assert_eq!(
                    d, 0,
                    "{scene_name} frame {f}: {name} differs from vfc in {d} pixels"
                );
                totals[i].1 += res.counts.queries_begun;
                totals[i].2 += res.counts.queries_visible;
            }
        }
    }
    drop(ctx);
    common::assert_silent(&log);
    totals
}

#[test]
fn nohc_and_chcpp_miss_nothing_on_city_street() {
    let t = exact_walk("city", 0.1, "street", 30);
    let get = |n: &str| t.iter().find(|x| x.0 == n).unwrap();
    // The cost rule asks fewer wasted queries than CHC, which tests every visible leaf.
    assert!(get("nohc").2 < get("chc").2, "{t:?}");
    // A dearer query makes NOHC query less.
    assert!(get("nohc(dear queries)").1 < get("nohc").1, "{t:?}");
}

#[test]
fn nohc_and_chcpp_miss_nothing_on_powerplant_difficult() {
    exact_walk("powerplant", 1.0, "difficult", 30);
}

/// Two rooms joined by a door: room A (x 0..10, z 0..10) is closed but for a door (z 4..6)
/// in its wall at x = 10. Objects: 0 floor, 1..=6 walls, 7 and 8 in room A, 9 in room B in
/// line with the door, 10 in room B behind the wall, 11 outside room A behind its x = 0 wall.
fn two_rooms() -> Scene {
    let mut b = SceneBuilder::new("two-rooms");
    let grey = Vec3::splat(0.6);
    let c = |min: Vec3, max: Vec3| Mesh::cuboid(min, max);
    b.add(
        &c(Vec3::new(-5.0, -0.1, -1.0), Vec3::new(20.0, 0.0, 11.0)),
        grey,
    );
    b.add(
        &c(Vec3::new(-0.2, 0.0, -0.2), Vec3::new(0.2, 4.0, 10.2)),
        grey,
    );
    b.add(
        &c(Vec3::new(0.0, 0.0, -0.2), Vec3::new(10.0, 4.0, 0.2)),
        grey,
    );
    b.add(
        &c(Vec3::new(0.0, 0.0, 9.8), Vec3::new(10.0, 4.0, 10.2)),
        grey,
    );
    b.add(
        &c(Vec3::new(9.8, 0.0, -0.2), Vec3::new(10.2, 4.0, 4.0)),
        grey,
    );
    b.add(
        &c(Vec3::new(9.8, 0.0, 6.0), Vec3::new(10.2, 4.0, 10.2)),
        grey,
    );
    b.add(
        &c(Vec3::new(9.8, 4.0, -0.2), Vec3::new(10.2, 4.2, 10.2)),
        grey,
    );
    let cube = |x: f32, z: f32| {
        c(
            Vec3::new(x - 0.5, 0.0, z - 0.5),
            Vec3::new(x + 0.5, 1.0, z + 0.5),
        )
    };
    b.add(&cube(5.0, 2.0), Vec3::X);
    b.add(&cube(7.0, 8.0), Vec3::Y);
    b.add(&cube(12.5, 5.0), Vec3::Z);
    b.add(&cube(11.0, 1.0), Vec3::ONE);
    b.add(&cube(-3.0, 5.0), Vec3::ONE);
    b.path(
        "default",
        &[
            (Vec3::new(3.0, 1.7, 7.0), Vec3::new(10.0, 1.7, 5.0)),
            (Vec3::new(3.2, 1.7, 7.2), Vec3::new(10.0, 1.7, 5.0)),
        ],
    );
    b.finish()
}

#[test]
fn pvs_of_two_rooms_is_what_can_be_seen_and_its_cache_is_checked() {
    let (ctx, log) = common::context();
    {
        let scene = two_rooms();
        let bvh = common::bvh_of(&scene);
        let path = scene.default_path().unwrap().clone();
        let settings = PvsSettings {
            cell_size: 2.0,
            samples: 6,
            face_size: 64,
            refine: 4,
            margin: 0,
            enlarge: 0.0,
            raster: false,
            border: true,
        };
        let dir = temp_dir("pvs");
        let build = |ctx| {
            pvs_build::load_or_build(
                ctx,
                &dir,
                "two-rooms",
                1.0,
                &scene,
                &bvh,
                &path,
                &settings,
                |_, _| {},
            )
            .unwrap()
        };
        let first = build(&ctx);
        assert!(!first.from_cache);
        let pvs = &first.pvs;
        assert!(
            !pvs.cells.is_empty() && pvs.cells.len() <= 2,
            "{} cells",
            pvs.cells.len()
        );
        for cell in &pvs.cells {
            for seen in [0, 7, 8, 9] {
                assert!(
                    cell.objects.contains(&seen),
                    "object {seen} is visible: {:?}",
                    cell.objects
                );
            }
            for hidden in [10, 11] {
                assert!(
                    !cell.objects.contains(&hidden),
                    "object {hidden} is hidden: {:?}",
                    cell.objects
                );
            }
        }
        let eye = path.keys[0].eye;
        assert!(pvs.cell_at(eye).is_some());
        // Reused from the cache, identical.
        let again = build(&ctx);
        assert!(again.from_cache);
        assert_eq!(*again.pvs, **pvs);
        // A truncated file is rebuilt, never trusted.
        let bytes = std::fs::read(&first.file).unwrap();
        std::fs::write(&first.file, &bytes[..bytes.len() / 2]).unwrap();
        let rebuilt = build(&ctx);
        assert!(!rebuilt.from_cache);
        assert_eq!(*rebuilt.pvs, **pvs);
        // A foreign file (another scene's sets at this path) is rebuilt too.
        let foreign = coherent::culling::Pvs::new("scene=other".into(), 3, Vec3::ZERO, 1.0, vec![]);
        foreign.save(&first.file).unwrap();
        let rebuilt = build(&ctx);
        assert!(!rebuilt.from_cache);
        assert_eq!(*rebuilt.pvs, **pvs);
        // At run time: the cell's set, frustum-culled; hidden objects are never drawn.
        let mut r = Renderer::new(&ctx, &scene, W, H).unwrap();
        r.log_drawn_objects(true);
        let setup = CullerSetup {
            pvs: Some(pvs.clone()),
            ..CullerSetup::default()
        };
        let mut culler = culling::create_with("pvs", &setup).unwrap();
        let cam = r.camera(path.keys[0], &bvh);
        let mut owned = Vec::new();
        r.object_pixels(&bvh, &cam, &mut owned).unwrap();
        let res = r.render_frame(culler.as_mut(), &bvh, &cam, 0).unwrap();
        assert_eq!(res.counts.queries_begun, 0);
        assert_eq!(r.check_drawn(&owned).missed_objects, 0);
    }
    drop(ctx);
    common::assert_silent(&log);
}

#[test]
fn calibration_is_measured_once_and_replaced_when_foreign() {
    let (ctx, log) = common::context();
    {
        let dir = temp_dir("calibration");
        let (cal, source) = calibrate::load_or_calibrate(&ctx, &dir, false).unwrap();
        assert_eq!(source, Source::Measured { replaced: None });
        assert!(cal.costs.is_valid(), "{cal:?}");
        assert!(cal.table().contains("draw call"));
        let (again, source) = calibrate::load_or_calibrate(&ctx, &dir, false).unwrap();
        assert_eq!(source, Source::Cache);
        // The same figures (JSON keeps them to the last bit or one ulp).
        let close = |a: f64, b: f64| (a - b).abs() <= a.abs() * 1e-12;
        assert!(close(again.costs.draw_ms, cal.costs.draw_ms));
        assert!(close(
            again.costs.query_fragment_ms,
            cal.costs.query_fragment_ms
        ));
        assert_eq!(again.device, cal.device);
        // Another driver version: not trusted, measured again.
        let file = calibrate::cache_file(&dir, &ctx);
        let text = std::fs::read_to_string(&file).unwrap();
        let foreign = text.replace(&ctx.info.driver, "some other driver 1.0");
        assert_ne!(foreign, text);
        std::fs::write(&file, foreign).unwrap();
        let (_, source) = calibrate::load_or_calibrate(&ctx, &dir, false).unwrap();
        assert!(
            matches!(source, Source::Measured { replaced: Some(_) }),
            "{source:?}"
        );
        // A corrupt file: the same.
        std::fs::write(&file, "{ not json").unwrap();
        let (fixed, source) = calibrate::load_or_calibrate(&ctx, &dir, false).unwrap();
        assert!(matches!(source, Source::Measured { replaced: Some(_) }));
        assert!(fixed.costs.is_valid());
    }
    drop(ctx);
    common::assert_silent(&log);
}

#[test]
fn walk_check_reports_no_missed_objects_for_exact_algorithms() {
    let out = temp_dir("walk-check");
    let exe = env!("CARGO_BIN_EXE_coherent");
    let status = common::on_test_device(&mut std::process::Command::new(exe))
        .args([
            "walk",
            "--scene",
            "city",
            "--scale",
            "0.1",
            "--path",
            "street",
            "--frames",
            "6",
            "--warmup",
            "1",
            "--size",
            "160x90",
            "--check",
            "--validation",
            "--algorithms",
            "vfc,pvs,nohc,chcpp,oracle",
            "--cell-size",
            "12",
            "--samples",
            "1",
            "--face-size",
            "32",
        ])
        .arg("--out")
        .arg(&out)
        .arg("--cache-dir")
        .arg(out.join("cache"))
        .status()
        .unwrap();
    assert!(status.success());
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let algs = &json["algorithms"];
    for exact in ["vfc", "nohc", "chcpp", "oracle"] {
        assert_eq!(algs[exact]["missed_objects_max"], 0, "{exact}: {algs}");
        assert_eq!(algs[exact]["missed_pixels_max"], 0, "{exact}");
    }
    for plot in ["missed_pixels.png", "extra_objects.png"] {
        let bytes = std::fs::metadata(out.join(plot)).map(|m| m.len());
        assert!(bytes.is_ok_and(|b| b > 1024), "--check writes {plot}");
    }
    // The oracle draws only objects that own a pixel; vfc draws the whole frustum.
    assert_eq!(algs["oracle"]["extra_objects_median"], 0.0, "{algs}");
    assert!(
        algs["vfc"]["extra_objects_median"].as_f64().unwrap() > 0.0,
        "{algs}"
    );
    let pvs = &algs["pvs"];
    assert!(pvs["missed_objects_max"].is_u64(), "{pvs}");
    assert!(pvs["cells"].as_u64().unwrap() > 0);
    assert_eq!(pvs["cell_size"].as_f64(), Some(12.0), "--cell-size: {pvs}");
    assert_eq!(pvs["samples"].as_u64(), Some(1), "--samples: {pvs}");
    assert_eq!(pvs["face_size"].as_u64(), Some(32), "--face-size: {pvs}");
    assert_eq!(pvs["face_refine"].as_u64(), Some(4), "the default: {pvs}");
    assert_eq!(pvs["border"].as_bool(), Some(true), "the default: {pvs}");
    assert!(pvs["pvs_objects_mean"].as_f64().unwrap() > 0.0);
    assert!(pvs["preprocess_s"].as_f64().unwrap() > 0.0);
    let csv = std::fs::read_to_string(out.join("frames.csv")).unwrap();
    assert!(csv
        .lines()
        .next()
        .unwrap()
        .ends_with("missed_objects,missed_pixels,extra_objects,extra_predicated_objects,mover_draws,predicated_draws,predicated_taken,predicate_resolves,multiqueries,visible_leaf_queries,predicated_queries,tested_parts,flag_tests,cpu_ms"));
}
