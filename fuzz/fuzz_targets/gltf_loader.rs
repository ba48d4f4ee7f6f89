//! Fuzzes the glTF/GLB loader: any bytes, written to a file named `.glb` or `.gltf` (by the
//! GLB magic), must load or give a one-line error naming the file, never panic.
#![no_main]

use std::path::PathBuf;
use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;

/// A private directory per fuzzing process (external buffer URIs resolve inside it).
fn dir() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("coherent-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&d).expect("fuzz temp dir");
        d
    })
}

fuzz_target!(|data: &[u8]| {
    let name = if data.starts_with(b"glTF") {
        "input.glb"
    } else {
        "input.gltf"
    };
    let path = dir().join(name);
    std::fs::write(&path, data).expect("write fuzz input");
    let path_text = path.to_string_lossy().into_owned();
    // The animation played: the first, none, the second by index, or one by name.
    use coherent::scene::gltf::AnimationChoice;
    let choice = match data.len() % 4 {
        0 => AnimationChoice::First,
        1 => AnimationChoice::Nothing,
        2 => AnimationChoice::Index(1),
        _ => AnimationChoice::Name("Walk".to_string()),
    };
    match coherent::scene::Scene::load_with(&path_text, 1.0, 4096, None, &choice) {
        Ok(mut scene) => {
            // The objects its animation moves: placed at a few frames, boxes finite.
            let movers = coherent::scene::movers::Movers::add(&mut scene, 0);
            // The culling hierarchy leaves out exactly the blended objects (no mover blends).
            let bvh = scene.hierarchy(1);
            bvh.validate().expect("a valid hierarchy");
            let blended = (0..scene.objects.len()).filter(|&o| scene.is_blended(o)).count();
            assert_eq!(bvh.live_objects() + blended, scene.objects.len());
            assert!(movers.objects().all(|o| !scene.is_blended(o as usize)));
            for i in 0..movers.len() {
                for frame in [0, 7, 1000] {
                    let m = movers.transform_at(i, frame);
                    assert!(m.is_finite(), "mover {i} at frame {frame}: {m}");
                }
            }
            // Skinned meshes posed at a few frames: finite vertices inside the scene's, finite
            // boxes.
            for frame in [0, 7, 1000] {
                movers
                    .for_each_deformed(frame, |first, vertices| {
                        let end = first as usize + vertices.len();
                        assert!(end <= scene.vertices.len(), "posed vertices past the scene's");
                        assert!(vertices
                            .iter()
                            .all(|v| v.position.iter().chain(&v.normal).all(|c| c.is_finite())));
                        Ok(())
                    })
                    .expect("posed");
                movers
                    .for_each_at(frame, |_, bounds, _| {
                        assert!(bounds.min.is_finite() && bounds.max.is_finite());
                        Ok(())
                    })
                    .expect("placed");
            }
            // GI's movers: the deformed ones keep their pieces from pose to pose.
            let diagonal = scene.bounds().extent().length();
            let mut gi = coherent::gi::movers::GiMovers::new(&scene, movers, diagonal.max(1e-3));
            let pieces = gi.geometry().triangles.len();
            for frame in [0, 7, 1000] {
                gi.advance(frame).expect("advanced");
                assert_eq!(gi.geometry().triangles.len(), pieces);
            }
            // GI's static geometry: one finite albedo per triangle (its texture averaged over
            // it at a mip level of its footprint).
            let world = coherent::gi::geometry::WorldGeometry::from_scene(&scene);
            assert_eq!(world.albedo.len(), world.triangles.len());
            assert!(world.albedo.iter().all(|a| a.is_finite()), "an albedo is not finite");
        }
        Err(e) => {
            let text = e.to_string();
            assert!(!text.contains('\n'), "error is not one line: {text}");
            assert!(
                text.contains(&path_text),
                "error does not name the file: {text}"
            );
        }
    }
});
