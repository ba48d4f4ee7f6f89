//! The built-in ground-level paths keep the camera out of solid objects: a walk whose eye
//! enters a building measures the inside of a box, not occlusion culling.

use coherent::scene::Scene;

/// Every quarter frame of `path`, the eye is at least `margin` metres outside every object's
/// box; returns the first offending (frame, object) pairs.
fn eye_inside_objects(scene: &Scene, path: &str, margin: f32) -> Vec<(f32, usize)> {
    let path = scene.path(path).expect("path");
    let frames = path.natural_frames() as f32;
    let boxes: Vec<_> = scene
        .objects
        .iter()
        .map(|o| o.bounds.enlarged(margin))
        .collect();
    let mut hits = Vec::new();
    let mut f = 0.0f32;
    while f <= frames {
        let eye = path.pose_at(f).eye;
        if let Some(i) = boxes.iter().position(|b| b.contains(eye)) {
            hits.push((f, i));
        }
        f += 0.25;
    }
    hits
}

#[test]
fn city_street_stays_in_the_streets() {
    let scene = Scene::load("city", 1.0, 4096).expect("city");
    let hits = eye_inside_objects(&scene, "street", 0.3);
    assert!(
        hits.is_empty(),
        "street path eye inside {} object boxes, first at frame {:?} (eye {:?})",
        hits.len(),
        hits.first(),
        hits.first()
            .map(|h| scene.path("street").expect("path").pose_at(h.0).eye)
    );
}

#[test]
fn city_street_stays_in_the_streets_at_every_scale() {
    for scale in [4.0, 16.0] {
        let scene = Scene::load("city", scale, 4096).expect("city");
        let hits = eye_inside_objects(&scene, "street", 0.3);
        assert!(hits.is_empty(), "scale {scale}: {} hits", hits.len());
    }
}

#[test]
fn parking_path_stays_out_of_the_cars() {
    let scene = Scene::load("parking", 1.0, 4096).expect("parking");
    for path in &scene.paths {
        let hits = eye_inside_objects(&scene, &path.name, 0.3);
        assert!(
            hits.is_empty(),
            "parking path {}: eye inside {} object boxes, first {:?} eye {:?} box {:?}",
            path.name,
            hits.len(),
            hits.first(),
            hits.first().map(|h| path.pose_at(h.0).eye),
            hits.first().map(|h| scene.objects[h.1].bounds)
        );
    }
}

#[test]
fn parking_walk_crosses_the_driving_lanes_and_never_follows_one() {
    // The parking's movers drive along the aisles free of pillars, out of the lot and back in.
    // A walk along such an aisle has cars drive through the eye (their roofs are 0.1 m under
    // it) for much of its length. The walk may cross a lane, as a walker does, but not travel
    // along it: within a car's box, widened by 0.3 m, the eye moves at most 3 m along x.
    use coherent::scene::movers::Movers;
    for scale in [0.25, 0.5, 1.0, 4.0] {
        let mut scene = Scene::load("parking", scale, 4096).expect("parking");
        let movers = Movers::add(&mut scene, 200);
        // Each car keeps its z and height on its aisle: its box at frame 0 gives its lane.
        let mut lanes = Vec::new();
        movers
            .for_each_at(0, |_, b, _| {
                lanes.push(b.enlarged(0.3));
                Ok(())
            })
            .expect("movers");
        let in_lane = |eye: glam::Vec3| {
            lanes
                .iter()
                .any(|b| (b.min.z..=b.max.z).contains(&eye.z) && eye.y <= b.max.y)
        };
        let path = scene.default_path().expect("path").clone();
        let frames = path.natural_frames() * 4;
        // The x where the eye entered the lane it is in, if any.
        let mut entered: Option<f32> = None;
        let mut longest = 0.0f32;
        for i in 0..=frames {
            let eye = path.sample(i, frames + 1).eye;
            if in_lane(eye) {
                let x0 = *entered.get_or_insert(eye.x);
                longest = longest.max((eye.x - x0).abs());
            } else {
                entered = None;
            }
        }
        assert!(
            longest <= 3.0,
            "x{scale}: the walk follows a driving lane for {longest:.1} m"
        );
    }
}

#[test]
fn every_builtin_path_passes_the_path_check_at_every_frame() {
    // What a command checks before it walks a path (and warns about), at every frame rather
    // than the command's 120 samples: no frame stands inside geometry or closer to it than the
    // near plane, nor looks mostly at back faces.
    use coherent::scene::interior::rays::TriangleScene;
    use coherent::scene::path_check::view_at;
    let mut bad = Vec::new();
    for name in coherent::scene::procedural::SCENES {
        let scene = Scene::load(name, 1.0, 4096).expect(name);
        let rays = TriangleScene::new(&scene).expect("triangles");
        for path in &scene.paths {
            for f in 0..=path.natural_frames() {
                let view = view_at(&rays, &path.pose_at(f as f32), f);
                if let Some(problem) = view.problem(false) {
                    bad.push(format!(
                        "{name} {} frame {f} at {}: {problem}",
                        path.name, view.eye
                    ));
                }
            }
        }
    }
    assert!(bad.is_empty(), "{bad:#?}");
}

#[test]
fn scaled_scenes_paths_pass_the_path_check() {
    // The generators draw their random props per room or block, so a larger scale puts them
    // elsewhere along the same paths. The command's own check (120 frames) at scales 2 and 4
    // (the city's two paths are checked at every scale by the box test above).
    let mut bad = Vec::new();
    for name in ["parking", "powerplant"] {
        for scale in [2.0, 4.0] {
            let scene = Scene::load(name, scale, 4096).expect(name);
            for path in &scene.paths {
                if let Some(line) = coherent::scene::path_check::check(&scene, path) {
                    bad.push(format!("{name} x{scale}: {line}"));
                }
            }
        }
    }
    assert!(bad.is_empty(), "{bad:#?}");
}
