//! Moving objects: with the built-in movers and with objects moved, inserted and removed through
//! the public API between frames, every algorithm renders what vfc renders, frame after frame,
//! under the validation layer.

use crate::common;

use coherent::app::walk;
use coherent::bvh::ObjectBvh;
use coherent::culling::{
    self, CullStats, Culler, FrameInput, OcclusionBackend, QueryId, QueryPurpose,
};
use coherent::render::Renderer;
use coherent::scene::movers::Movers;
use coherent::scene::{Aabb, CameraPose, Scene};
use glam::{Mat4, Vec3};

/// A culler that records which objects its inner culler drew this frame.
struct Spy {
    inner: Box<dyn Culler>,
    drawn: Vec<u32>,
}

struct SpyBackend<'a> {
    inner: &'a mut dyn OcclusionBackend,
    drawn: &'a mut Vec<u32>,
}

impl OcclusionBackend for SpyBackend<'_> {
    fn draw_objects(&mut self, objects: &[u32]) -> coherent_cull::Result<()> {
        self.drawn.extend_from_slice(objects);
        self.inner.draw_objects(objects)
    }
    fn issue_query(&mut self, boxes: &[Aabb]) -> coherent_cull::Result<QueryId> {
        self.inner.issue_query(boxes)
    }
    fn issue_query_for(
        &mut self,
        boxes: &[Aabb],
        purpose: QueryPurpose,
    ) -> coherent_cull::Result<QueryId> {
        self.inner.issue_query_for(boxes, purpose)
    }
    fn restore_render_state(&mut self) -> coherent_cull::Result<()> {
        self.inner.restore_render_state()
    }
    fn flush(&mut self) -> coherent_cull::Result<()> {
        self.inner.flush()
    }
    fn query_result(&mut self, query: QueryId) -> coherent_cull::Result<Option<u64>> {
        self.inner.query_result(query)
    }
    fn wait_query(&mut self, query: QueryId) -> coherent_cull::Result<u64> {
        self.inner.wait_query(query)
    }
    fn finish(&mut self) -> coherent_cull::Result<()> {
        self.inner.finish()
    }
}

impl Culler for Spy {
    fn name(&self) -> &str {
        self.inner.name()
    }
    fn needs_exact_visibility(&self) -> bool {
        self.inner.needs_exact_visibility()
    }
    fn cull_frame(
        &mut self,
        input: &FrameInput,
        backend: &mut dyn OcclusionBackend,
    ) -> coherent_cull::Result<CullStats> {
        self.drawn.clear();
        let mut spy = SpyBackend {
            inner: backend,
            drawn: &mut self.drawn,
        };
        self.inner.cull_frame(input, &mut spy)
    }
    fn reset(&mut self) {
        self.inner.reset();
    }
}

/// Every exact algorithm: all of `culling::ALGORITHMS` but pvs (sampled, built for a static
/// scene; it draws movers frustum-culled only and may miss what its samples did not see). NOHC
/// gets a fixed cost model under which it both queries and skips queries.
fn spies() -> Vec<Spy> {
    let setup = common::setup(Vec::new(), (160, 90), 0.05);
    culling::ALGORITHMS
        .iter()
        .filter(|a| **a != "pvs")
        .map(|a| Spy {
            inner: culling::create_with(a, &setup).unwrap(),
            drawn: Vec::new(),
        })
        .collect()
}

fn bvh_of(s: &Scene) -> ObjectBvh {
    s.hierarchy(1)
}

/// A car of the scene's movers, copied as a scripted object: returns its id and object-space box.
fn add_car(scene: &mut Scene, template: u32) -> (u32, Aabb) {
    let mut o = scene.objects[template as usize].clone();
    let local = o.bounds.transformed(&o.transform.inverse());
    o.transform = Mat4::from_translation(Vec3::new(0.0, -100.0, 0.0));
    o.bounds = local.transformed(&o.transform);
    scene.objects.push(o);
    ((scene.objects.len() - 1) as u32, local)
}

/// A car facing along +x placed at `p` (or, for `along_z`, facing +z).
fn car_at(p: Vec3, along_z: bool) -> Mat4 {
    let yaw = if along_z {
        -std::f32::consts::FRAC_PI_2
    } else {
        0.0
    };
    Mat4::from_translation(p) * Mat4::from_rotation_y(yaw)
}

/// Moves a scripted object: its box into the hierarchy, its transform into the renderer.
fn place(bvh: &mut ObjectBvh, r: &mut Renderer, (id, local): (u32, Aabb), m: Mat4) {
    bvh.set_bounds(id, local.transformed(&m)).unwrap();
    r.set_object_transform(id, &m).unwrap();
}

/// Renders frame `f` with every culler and checks that each drew every object of the exact
/// visible set (`missed_objects` = 0) and that its image equals vfc's (the first). Returns
/// the exact visible set.
fn frame_all(
    r: &mut Renderer,
    cullers: &mut [Spy],
    bvh: &ObjectBvh,
    pose: CameraPose,
    f: u64,
) -> Vec<u32> {
    let cam = r.camera(pose, bvh);
    let exact = r.exact_visible(bvh, &cam).unwrap();
    let mut reference: Option<Vec<u8>> = None;
    for c in cullers.iter_mut() {
        r.render_frame(c, bvh, &cam, f).unwrap();
        // Exactness at object level: every object that owns a pixel was drawn.
        let missed: Vec<&u32> = exact.iter().filter(|o| !c.drawn.contains(o)).collect();
        assert!(
            missed.is_empty(),
            "frame {f}: {} missed visible objects {missed:?}",
            c.name()
        );
        let px = r.read_color().unwrap();
        match &reference {
            None => reference = Some(px),
            Some(v) => {
                let d = common::diff_pixels(v, &px);
                assert_eq!(
                    d,
                    0,
                    "frame {f}: {} differs from vfc in {d} pixels",
                    c.name()
                );
            }
        }
    }
    exact
}

/// City with built-in movers and two scripted cars: one drives along a cross street out from
/// behind a block of buildings into full view, one drives from behind the camera into the
/// frustum. 60 frames, every algorithm misses no visible object and its image equals vfc's.
#[test]
fn city_movers_every_algorithm_matches_vfc_for_60_frames() {
    let (ctx, log) = common::context();
    {
        let mut scene = Scene::load("city", 0.05, 4096).unwrap();
        let movers = Movers::add(&mut scene, 30);
        let template = movers.object(0);
        let out_of_hiding = add_car(&mut scene, template);
        let from_behind = add_car(&mut scene, template);
        let mut bvh = bvh_of(&scene);
        let mut r = Renderer::new(&ctx, &scene, 160, 90).unwrap();
        let mut cullers = spies();
        // The camera stands in the first street (x = 47) looking down it (+z); the cross street
        // runs along z = 47, behind the first block's buildings (x in [0, 40]).
        let (mut hidden, mut seen, mut behind, mut entered) = (false, false, false, false);
        for f in 0..60u64 {
            let z = 2.0 + f as f32 * 0.1;
            let pose = CameraPose {
                eye: Vec3::new(47.0, 1.7, z),
                target: Vec3::new(47.0, 1.7, z + 40.0),
            };
            walk::place_movers(&movers, f, &mut bvh, &mut r).unwrap();
            let a = car_at(Vec3::new(5.0 + f as f32 * 0.9, 0.0, 49.0), false);
            place(&mut bvh, &mut r, out_of_hiding, a);
            let b = car_at(Vec3::new(49.0, 0.0, -25.0 + f as f32 * 1.2), true);
            place(&mut bvh, &mut r, from_behind, b);
            bvh.update();
            bvh.validate().unwrap();
            let exact = frame_all(&mut r, &mut cullers, &bvh, pose, f);
            let visible = |o: (u32, Aabb)| exact.contains(&o.0);
            if f < 20 {
                hidden |= !visible(out_of_hiding);
            }
            seen |= hidden && visible(out_of_hiding);
            behind |= f < 10 && !visible(from_behind);
            entered |= behind && visible(from_behind);
            for c in &cullers {
                for o in [out_of_hiding, from_behind] {
                    assert!(
                        !visible(o) || c.drawn.contains(&o.0),
                        "frame {f}: {} missed the visible car {}",
                        c.name(),
                        o.0
                    );
                }
            }
        }
        assert!(hidden && seen, "the car came out from behind the buildings");
        assert!(
            behind && entered,
            "the car entered the view from behind the camera"
        );
    }
    common::assert_silent(&log);
}

/// Parking with built-in movers (cars driving along the aisles, out of the lot and back in):
/// 60 frames of the default path, every algorithm misses no visible object and its image
/// equals vfc's.
#[test]
fn parking_movers_every_algorithm_matches_vfc_for_60_frames() {
    let (ctx, log) = common::context();
    {
        let mut scene = Scene::load("parking", 0.5, 4096).unwrap();
        let movers = Movers::add(&mut scene, 30);
        let path = scene.default_path().unwrap().clone();
        let mut bvh = bvh_of(&scene);
        let mut r = Renderer::new(&ctx, &scene, 160, 90).unwrap();
        let mut cullers = spies();
        let mut movers_seen = 0;
        for f in 0..60u64 {
            walk::place_movers(&movers, f, &mut bvh, &mut r).unwrap();
            let exact = frame_all(&mut r, &mut cullers, &bvh, path.pose_at(f as f32), f);
            movers_seen += (0..movers.len())
                .filter(|&i| exact.contains(&movers.object(i)))
                .count();
        }
        assert!(movers_seen > 0, "movers were in view");
    }
    common::assert_silent(&log);
}

/// A glTF file whose first animation drives a cube behind a wall (x from -10 to 10 and back
/// over 2 s, 3 m behind it): its cube is a mover. 60 frames from a fixed camera: the cube is
/// seen, hidden behind the wall and seen again, every algorithm misses no visible object and
/// its image equals vfc's.
#[test]
fn gltf_animated_objects_are_movers_every_algorithm_matches_vfc() {
    use coherent::scene::gltf::testdata::GltfBuilder;
    let dir = coherent::testing::TempDir::new("animated");
    let mut b = GltfBuilder::default();
    let cube = b.cube_mesh([0.8, 0.8, 0.8, 1.0]);
    b.nodes.push(format!(
        r#"{{"mesh":{cube},"translation":[0,1.5,0],"scale":[6,3,0.5]}}"#
    ));
    b.node(cube, [0.0, 1.5, -3.0]);
    b.scene_nodes = Some(vec![0, 1]);
    let times = b.key_times(&[0.0, 1.0, 2.0]);
    let moved = b.vec3(&[[-10.0, 1.5, -3.0], [10.0, 1.5, -3.0], [-10.0, 1.5, -3.0]]);
    b.head = format!(
        r#""animations":[{{"samplers":[{{"input":{times},"output":{moved}}}],"channels":[{{"sampler":0,"target":{{"node":1,"path":"translation"}}}}]}}],"#
    );
    let path = dir.join("animated.gltf");
    std::fs::write(&path, b.gltf_embedded()).unwrap();

    let (ctx, log) = common::context();
    {
        let mut scene = Scene::load(path.to_str().unwrap(), 1.0, 4096).unwrap();
        assert_eq!(scene.objects.len(), 1, "the wall stands still");
        let movers = Movers::add(&mut scene, 0);
        assert_eq!(movers.len(), 1, "the cube is a mover");
        let cube = movers.object(0);
        let mut bvh = bvh_of(&scene);
        let mut r = Renderer::new(&ctx, &scene, 160, 90).unwrap();
        let mut cullers = spies();
        let pose = CameraPose {
            eye: Vec3::new(0.0, 1.5, 8.0),
            target: Vec3::new(0.0, 1.5, -3.0),
        };
        let (mut seen, mut hidden, mut seen_again) = (false, false, false);
        for f in 0..60u64 {
            walk::place_movers(&movers, f, &mut bvh, &mut r).unwrap();
            bvh.update();
            let exact = frame_all(&mut r, &mut cullers, &bvh, pose, f);
            let visible = exact.contains(&cube);
            seen |= visible;
            hidden |= seen && !visible;
            seen_again |= hidden && visible;
        }
        assert!(
            seen && hidden && seen_again,
            "the cube went behind the wall and came out"
        );
    }
    common::assert_silent(&log);
}

/// A glTF column 3 m behind a wall whose first animation stretches it 4 m up and back over
/// 2 s, once skinned (its top joint lifted) and once morphed (a morph target's weight
/// animated), so that it rises out of the wall's shadow while its default shape (and box)
/// stays hidden. 60 frames from a fixed camera each: the column is hidden, seen (only through
/// its posed vertices and box) and hidden again; every algorithm misses no visible object and
/// its image equals vfc's; the lifted column's red shows.
#[test]
fn gltf_deformed_objects_are_posed_each_frame_every_algorithm_matches_vfc() {
    use coherent::scene::gltf::testdata::{morphed_column, skinned_column};
    let dir = coherent::testing::TempDir::new("deformed");
    let (ctx, log) = common::context();
    for (name, b) in [
        ("skinned", skinned_column(4.0)),
        ("morphed", morphed_column(4.0)),
    ] {
        let path = dir.join(format!("{name}.gltf"));
        std::fs::write(&path, b.gltf_embedded()).unwrap();
        let mut scene = Scene::load(path.to_str().unwrap(), 1.0, 4096).unwrap();
        let movers = Movers::add(&mut scene, 0);
        assert_eq!(
            movers.deformed_meshes(),
            1,
            "{name}: the column is posed each frame"
        );
        let column = movers.object(0);
        let mut bvh = bvh_of(&scene);
        let (w, h) = (160, 90);
        let mut r = Renderer::new(&ctx, &scene, w, h).unwrap();
        let mut cullers = spies();
        let pose = CameraPose {
            eye: Vec3::new(0.0, 1.5, 8.0),
            target: Vec3::new(0.0, 1.5, -3.0),
        };
        let (mut hidden, mut seen, mut hidden_again) = (false, false, false);
        let mut red = [0usize; 2];
        for f in 0..60u64 {
            walk::place_movers(&movers, f, &mut bvh, &mut r).unwrap();
            let exact = frame_all(&mut r, &mut cullers, &bvh, pose, f);
            let visible = exact.contains(&column);
            hidden |= f == 0 && !visible;
            seen |= hidden && visible;
            hidden_again |= seen && !visible;
            if f == 0 || f == 30 {
                let px = r.read_color().unwrap();
                red[(f / 30) as usize] = px
                    .chunks_exact(4)
                    .filter(|p| u16::from(p[0]) > u16::from(p[1].max(p[2])) + 40)
                    .count();
            }
        }
        assert!(
            hidden && seen && hidden_again,
            "{name}: the column rose above the wall and sank back"
        );
        assert_eq!(
            red[0], 0,
            "{name}: the column hides behind the wall at frame 0"
        );
        assert!(
            red[1] > 20,
            "{name}: the lifted column shows red pixels at frame 30: {red:?}"
        );
    }
    common::assert_silent(&log);
}

/// Insert and remove through the public API between frames: an inserted car is drawn by every
/// algorithm the first frame it is visible; a removed one is never drawn again (its id is not
/// reused here: no insert follows the removal).
#[test]
fn inserted_objects_are_drawn_and_removed_ones_never_again() {
    let (ctx, log) = common::context();
    {
        let mut scene = Scene::load("city", 0.1, 4096).unwrap();
        let movers = Movers::add(&mut scene, 1);
        let template = movers.object(0);
        let local = scene.objects[template as usize]
            .bounds
            .transformed(&scene.objects[template as usize].transform.inverse());
        let mut bvh = bvh_of(&scene);
        let mut r = Renderer::with_spare_objects(&ctx, &scene, 160, 90, 4).unwrap();
        let mut cullers = spies();
        let pose = CameraPose {
            eye: Vec3::new(47.0, 1.7, 2.0),
            target: Vec3::new(47.0, 1.7, 42.0),
        };
        // The mover stands in view for the first frames, so it is drawn, then it is removed.
        let in_view = car_at(Vec3::new(49.0, 0.0, 20.0), true);
        place(&mut bvh, &mut r, (template, local), in_view);
        bvh.update();
        let mut inserted = None;
        for f in 0..24u64 {
            if f == 8 {
                bvh.remove(template).unwrap();
            }
            if f == 4 {
                // A new car right in front of the camera.
                let m = car_at(Vec3::new(45.0, 0.0, 15.0), true);
                let id = bvh.insert(local.transformed(&m));
                assert_eq!(id as usize, scene.objects.len(), "a fresh id");
                r.set_object(id, template, &m).unwrap();
                inserted = Some(id);
            }
            if f == 18 {
                // Drive it further away: still visible, its box refitted.
                let id = inserted.unwrap();
                let m = car_at(Vec3::new(45.0, 0.0, 30.0), true);
                bvh.set_bounds(id, local.transformed(&m)).unwrap();
                r.set_object_transform(id, &m).unwrap();
            }
            bvh.update();
            bvh.validate().unwrap();
            let exact = frame_all(&mut r, &mut cullers, &bvh, pose, f);
            for c in &cullers {
                if f < 8 {
                    assert!(c.drawn.contains(&template), "{} drew the car", c.name());
                } else {
                    assert!(
                        !c.drawn.contains(&template),
                        "{} drew a removed object",
                        c.name()
                    );
                }
                if let Some(id) = inserted {
                    assert!(exact.contains(&id), "the inserted car is visible");
                    assert!(
                        c.drawn.contains(&id),
                        "frame {f}: {} missed the inserted car",
                        c.name()
                    );
                }
            }
        }
    }
    common::assert_silent(&log);
}

/// `coherent walk --movers N` (validation on): every algorithm plus chcpp on the scene without
/// movers, and the movers' figures in `summary.json`.
#[test]
fn walk_with_movers_reports_refit_and_rebuilds() {
    let dir = coherent::testing::TempDir::new("movers");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_coherent"))
        .args([
            "walk",
            "--scene",
            "parking",
            "--scale",
            "0.25",
            "--movers",
            "20",
            "--algorithms",
            "vfc,stop-and-wait,chc,chcpp,oracle",
        ])
        .args([
            "--frames",
            "4",
            "--warmup",
            "1",
            "--size",
            "96x64",
            "--validation",
        ])
        .args(["--out", dir.to_str().unwrap()])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
    for a in [
        "vfc",
        "stop-and-wait",
        "chc",
        "chcpp",
        "oracle",
        "chcpp-static",
    ] {
        assert!(json["algorithms"][a]["frame_ms_median"].is_number(), "{a}");
    }
    for a in ["vfc", "chcpp", "oracle"] {
        assert!(
            json["algorithms"][a]["mover_draws_median"].is_number(),
            "{a}"
        );
    }
    assert_eq!(
        json["algorithms"]["chcpp-static"]["mover_draws_median"],
        0.0
    );
    let csv = std::fs::read_to_string(dir.join("frames.csv")).unwrap();
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let col = header.iter().position(|h| *h == "mover_draws").unwrap();
    let vfc_movers: u32 = csv
        .lines()
        .filter(|l| l.starts_with("vfc,"))
        .map(|l| l.split(',').nth(col).unwrap().parse::<u32>().unwrap())
        .sum();
    assert!(vfc_movers > 0, "vfc drew movers");
    let m = &json["movers"];
    assert_eq!(m["movers"], 20);
    assert!(m["refit_ms_median"].as_f64().unwrap() > 0.0);
    assert!(m["rebuilds"].is_number());
    assert!(m["vs_static"]["chcpp"]["median"].as_f64().unwrap() > 0.0);
}

/// The recorder counts the movers' draws (`mover_draws`): in a walk with movers every algorithm
/// reports them, pvs (whose sets know only the static scene) draws the movers frustum-culled
/// only, so exactly as many as vfc in every frame, and the exact algorithms (hiz included) miss
/// no object. Here the PVS's one cell holds no static object, so pvs draws movers and nothing
/// else. The count agrees with the recorder's log of drawn objects.
#[test]
fn mover_draws_are_counted_and_pvs_draws_movers_frustum_culled() {
    use coherent::culling::pvs::ViewCell;
    use coherent::culling::Pvs;
    let (ctx, log) = common::context();
    {
        let fixed = Scene::load("parking", 0.5, 4096).unwrap();
        let mut scene = fixed.clone();
        let movers = Movers::add(&mut scene, 30);
        assert_eq!(
            movers.objects(),
            fixed.objects.len() as u32..scene.objects.len() as u32
        );
        let path = scene.default_path().unwrap().clone();
        let (mut bvh, fixed_bvh) = (bvh_of(&scene), bvh_of(&fixed));
        let pvs = Pvs::new(
            "test: one cell, no static object".into(),
            fixed.objects.len() as u32,
            Vec3::splat(-1.0e4),
            2.0e4,
            vec![ViewCell {
                coord: [0, 0, 0],
                objects: Vec::new(),
            }],
        );
        let size = (160, 90);
        let exact = [
            "vfc",
            "stop-and-wait",
            "chc",
            "chcpp",
            "oracle",
            "nohc",
            "hiz",
        ];
        let mut algorithms: Vec<String> = exact.iter().map(|a| a.to_string()).collect();
        algorithms.push("pvs".into());
        let setup = common::setup(common::triangles(&scene), size, 0.05);
        let cfg = walk::WalkConfig {
            algorithms,
            frames: 30,
            warmup: 0,
            repeats: 1,
            check: true,
            nohc: setup.nohc,
            pvs: Some(std::sync::Arc::new(pvs)),
            ..Default::default()
        };
        let mut r = Renderer::new(&ctx, &scene, size.0, size.1).unwrap();
        let mut fixed_r = Renderer::new(&ctx, &fixed, size.0, size.1).unwrap();
        let mut mw = walk::MoverWalk {
            movers: &movers,
            baseline: Some((&mut fixed_r, &fixed_bvh)),
            baseline_algorithms: vec!["chcpp".into()],
        };
        let (records, _) =
            walk::run_with_movers(&mut r, &mut bvh, &path, &cfg, &mut mw, |_, _| {}).unwrap();
        let at = |a: &str, f: u32| {
            records
                .iter()
                .find(|x| x.algorithm == a && x.frame == f)
                .unwrap()
        };
        let mut in_view = 0;
        for f in 0..cfg.frames {
            let vfc = at("vfc", f).mover_draws.unwrap();
            let pvs = at("pvs", f);
            assert_eq!(pvs.mover_draws, Some(vfc), "frame {f}: pvs draws as vfc");
            assert_eq!(pvs.object_draws, vfc, "frame {f}: pvs drew only movers");
            // Every exact algorithm drew every object that owns a pixel, so its draws less
            // those that own none are the same count for all of them; the oracle draws no
            // object that owns none.
            let owners =
                |x: &coherent::app::report::FrameRecord| x.objects - x.extra_objects.unwrap();
            let visible = owners(at("vfc", f));
            assert_eq!(at("oracle", f).extra_objects, Some(0), "frame {f}: oracle");
            for a in exact {
                let x = at(a, f);
                assert_eq!(x.missed_objects, Some(0), "frame {f}: {a} missed objects");
                assert_eq!(
                    owners(x),
                    visible,
                    "frame {f}: {a} drew objects owning no pixel"
                );
                assert!(x.mover_draws.unwrap() <= vfc, "frame {f}: {a} drew movers");
            }
            assert_eq!(at("chcpp-static", f).mover_draws, Some(0));
            in_view += vfc;
        }
        assert!(in_view > 0, "movers were in the frustum");
        // The recorder's count against its own log of drawn objects.
        r.log_drawn_objects(true);
        r.count_mover_draws(movers.objects());
        let mut vfc = culling::create_with("vfc", &culling::CullerSetup::default()).unwrap();
        let mut counted = 0;
        for f in 0..10u64 {
            walk::place_movers(&movers, f, &mut bvh, &mut r).unwrap();
            let cam = r.camera(path.pose_at(f as f32), &bvh);
            let res = r.render_frame(vfc.as_mut(), &bvh, &cam, f).unwrap();
            let logged = r
                .drawn_objects()
                .iter()
                .filter(|o| movers.objects().contains(o))
                .count();
            assert_eq!(res.counts.mover_draws as usize, logged, "frame {f}");
            counted += logged;
        }
        assert!(counted > 0, "movers were drawn");
    }
    common::assert_silent(&log);
}
