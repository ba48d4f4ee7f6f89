//! The glTF loader never panics: every file in `tests/fuzz_corpus/` (inputs the fuzzer found,
//! minimized; see `scripts/fuzz.sh`) and the known upstream panics load or give a one-line
//! error naming the file. A panic hook counts panics on the loading thread, so a panic that the
//! loader contains still fails these tests. `COHERENT_FUZZ_SEEDS=DIR` also writes the fuzzer's
//! seed corpus (built from the loader's test builders) into DIR.

use std::cell::Cell;
use std::path::{Path, PathBuf};
use std::sync::Once;

use coherent::scene::gltf::testdata::{
    cube_grid_glb, morphed_column, skinned_column, skinned_triangles, GltfBuilder,
};
use coherent::scene::Scene;

thread_local! {
    static PANICS: Cell<usize> = const { Cell::new(0) };
}

/// Loads `bytes` as a file named `name` in `dir`; fails the test on a panic (even a contained
/// one) or an error that is not one line naming the file. Returns whether it loaded.
fn load_never_panics(dir: &Path, name: &str, bytes: &[u8]) -> Result<Scene, String> {
    static HOOK: Once = Once::new();
    HOOK.call_once(|| {
        let default = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            PANICS.with(|p| p.set(p.get() + 1));
            default(info);
        }));
    });
    let path = dir.join(name);
    std::fs::write(&path, bytes).expect("write test file");
    let text = path.to_string_lossy().into_owned();
    let before = PANICS.with(Cell::get);
    let result = Scene::load(&text, 1.0, 4096);
    assert_eq!(
        PANICS.with(Cell::get),
        before,
        "{name}: the loader panicked"
    );
    result.map_err(|e| {
        let msg = e.to_string();
        assert!(!msg.contains('\n'), "{name}: error is not one line: {msg}");
        assert!(
            msg.contains(&text),
            "{name}: error does not name the file: {msg}"
        );
        msg
    })
}

fn scratch(test: &str) -> coherent::testing::TempDir {
    coherent::testing::TempDir::new(&format!("fuzzreg-{test}"))
}

/// A cube whose mesh JSON is replaced by `mesh` (with `{pos}`, `{nrm}`, `{idx}` filled in).
fn cube_with_mesh(mesh: &str) -> GltfBuilder {
    let mut b = GltfBuilder::default();
    b.cube_mesh([0.5, 0.5, 0.5, 1.0]);
    b.meshes[0] = mesh
        .replace("{pos}", "0")
        .replace("{nrm}", "1")
        .replace("{idx}", "2");
    b.node(0, [0.0, 0.0, 0.0]);
    b.scene_nodes = Some(vec![0]);
    b
}

#[test]
fn out_of_range_attribute_accessor_is_a_one_line_error() {
    let dir = scratch("attr");
    let cases = [
        (
            "position.glb",
            r#"{"primitives":[{"attributes":{"POSITION":2147483647,"NORMAL":{nrm}},"indices":{idx}}]}"#,
            "attribute accessor 2147483647 out of range",
        ),
        (
            "normal.glb",
            r#"{"primitives":[{"attributes":{"POSITION":{pos},"NORMAL":4000000000},"indices":{idx}}]}"#,
            "attribute accessor 4000000000 out of range",
        ),
        (
            "target.glb",
            r#"{"primitives":[{"attributes":{"POSITION":{pos}},"indices":{idx},"targets":[{"POSITION":99}]}]}"#,
            "attribute accessor 99 out of range",
        ),
    ];
    for (name, mesh, needle) in cases {
        let glb = cube_with_mesh(mesh).glb();
        let err = load_never_panics(&dir, name, &glb).expect_err(name);
        assert!(err.contains(needle), "{name}: {err}");
    }
    // The same file with valid indices loads, so the errors above are about the index alone.
    let ok = cube_with_mesh(
        r#"{"primitives":[{"attributes":{"POSITION":{pos},"NORMAL":{nrm}},"indices":{idx}}]}"#,
    );
    load_never_panics(&dir, "valid.glb", &ok.glb()).expect("valid cube loads");
}

#[test]
fn bad_buffer_uris_are_one_line_errors() {
    let dir = scratch("uri");
    // Invalid UTF-8 after percent-decoding: the gltf crate unwraps the decoding and panics.
    let mut b =
        cube_with_mesh(r#"{"primitives":[{"attributes":{"POSITION":{pos}},"indices":{idx}}]}"#);
    let json = b.json(Some("bad%FFname.bin"));
    let err = load_never_panics(&dir, "percent.gltf", json.as_bytes()).expect_err("percent");
    assert!(err.contains("percent-encoding"), "{err}");
    // A buffer naming a directory (or a device) is refused before it is read.
    std::fs::create_dir_all(dir.join("sub")).expect("subdir");
    b.buffer_length_override = Some(16);
    let json = b.json(Some("sub"));
    let err = load_never_panics(&dir, "directory.gltf", json.as_bytes()).expect_err("dir");
    assert!(err.contains("not a regular file"), "{err}");
}

/// Valid files covering the loader's paths: GLB and embedded glTF, u16/u32 and no indices,
/// instancing (nodes and `EXT_mesh_gpu_instancing`), a hierarchy without scenes, a non-triangle
/// mode, strips and fans, a sparse accessor, a WebP texture of a specular-glossiness
/// material, a Draco-compressed triangle, a skin and a morph target, a KTX2 texture and an animation.
fn seeds() -> Vec<(&'static str, Vec<u8>)> {
    let mut out = vec![("grid4.glb", cube_grid_glb(4))];
    let mut b = GltfBuilder::default();
    let cube = b.cube_mesh([1.0, 0.0, 0.0, 1.0]);
    let pos = b.vec3(&[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    let idx = b.indices_u32(&[0, 1, 2]);
    b.meshes.push(format!(
        r#"{{"primitives":[{{"attributes":{{"POSITION":{pos}}},"indices":{idx}}},{{"attributes":{{"POSITION":{pos}}},"mode":1}}]}}"#
    ));
    b.meshes.push(format!(
        r#"{{"primitives":[{{"attributes":{{"POSITION":{pos}}}}}]}}"#
    ));
    b.node(cube, [-2.0, 0.0, 0.0]);
    b.node(1, [2.0, 0.0, 0.0]);
    b.nodes
        .push(r#"{"children":[0,1],"scale":[2,2,2]}"#.to_string());
    b.node(2, [0.0, 3.0, 0.0]);
    b.scene_nodes = Some(vec![2, 3]);
    out.push(("mixed.gltf", b.gltf_embedded().into_bytes()));
    out.push(("mixed.glb", b.glb()));
    b.scene_nodes = None;
    out.push(("noscene.glb", b.glb()));

    // BLEND materials: one translucent cube, one whose alpha is one (drawn opaque).
    let mut b = GltfBuilder::default();
    let glass = b.cube_mesh([1.0, 1.0, 1.0, 0.5]);
    let solid = b.cube_mesh([0.2, 0.2, 0.2, 1.0]);
    for m in &mut b.materials {
        *m = m.replacen('{', r#"{"alphaMode":"BLEND","#, 1);
    }
    b.node(glass, [0.0, 0.0, 0.0]);
    b.node(solid, [0.0, 0.0, -3.0]);
    out.push(("blend.gltf", b.gltf_embedded().into_bytes()));
    // A skinned column whose animation lifts one of its joints: posed every frame.
    out.push((
        "skinned_anim.gltf",
        skinned_column(4.0).gltf_embedded().into_bytes(),
    ));
    // A column whose animation plays a morph target's weight.
    out.push((
        "morphed_anim.gltf",
        morphed_column(4.0).gltf_embedded().into_bytes(),
    ));

    // A node whose mesh EXT_mesh_gpu_instancing places twice.
    let mut b = GltfBuilder::default();
    let cube = b.cube_mesh([0.0, 1.0, 0.0, 1.0]);
    let t = b.vec3(&[[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]]);
    let s = b.vec3(&[[1.0, 1.0, 1.0], [0.5, 0.5, 0.5]]);
    b.nodes.push(format!(
        r#"{{"mesh":{cube},"extensions":{{"EXT_mesh_gpu_instancing":{{"attributes":{{"TRANSLATION":{t},"SCALE":{s}}}}}}}}}"#
    ));
    b.scene_nodes = Some(vec![0]);
    out.push(("instanced.glb", b.glb()));

    // A strip, an indexed fan and a triangle whose positions are a sparse accessor over zeros.
    let mut b = GltfBuilder::default();
    let pos = b.vec3(&[
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0],
    ]);
    let idx = b.indices_u16(&[0, 1, 3, 2]);
    let sparse_idx = b.view(&[1, 0, 2, 0]);
    let values: Vec<u8> = [2.0f32, 0.0, 0.0, 0.0, 2.0, 0.0]
        .iter()
        .flat_map(|f| f.to_le_bytes())
        .collect();
    let sparse_val = b.view(&values);
    b.accessors.push(format!(
        r#"{{"componentType":5126,"type":"VEC3","count":3,"sparse":{{"count":2,"indices":{{"bufferView":{sparse_idx},"componentType":5123}},"values":{{"bufferView":{sparse_val}}}}}}}"#
    ));
    let sparse = b.accessors.len() - 1;
    b.meshes.push(format!(
        r#"{{"primitives":[{{"attributes":{{"POSITION":{pos}}},"mode":5}},{{"attributes":{{"POSITION":{pos}}},"indices":{idx},"mode":6}},{{"attributes":{{"POSITION":{sparse}}}}}]}}"#
    ));
    b.node(0, [0.0; 3]);
    b.scene_nodes = Some(vec![0]);
    out.push(("strips_sparse.glb", b.glb()));

    // A cube whose spec-gloss material reads a 2x2 WebP texture through EXT_texture_webp.
    let mut webp = Vec::new();
    image::codecs::webp::WebPEncoder::new_lossless(&mut webp)
        .encode(&[255; 16], 2, 2, image::ExtendedColorType::Rgba8)
        .expect("webp");
    let mut b = GltfBuilder::default();
    let cube = b.cube_mesh([1.0; 4]);
    b.materials[0] =
        r#"{"extensions":{"KHR_materials_pbrSpecularGlossiness":{"diffuseTexture":{"index":0}}}}"#
            .to_string();
    b.node(cube, [0.0; 3]);
    b.scene_nodes = Some(vec![0]);
    let head = format!(
        r#"{{"extensionsUsed":["EXT_texture_webp","KHR_materials_pbrSpecularGlossiness"],"extensionsRequired":["EXT_texture_webp"],"images":[{{"uri":"data:image/webp;base64,{}"}}],"textures":[{{"extensions":{{"EXT_texture_webp":{{"source":0}}}}}}],"#,
        coherent::scene::gltf::testdata::base64(&webp)
    );
    out.push((
        "webp.gltf",
        b.gltf_embedded().replacen('{', &head, 1).into_bytes(),
    ));
    out.push(("draco.glb", draco_triangle_glb()));
    // The cube textured by a KTX2 Basis Universal (ETC1S) image through KHR_texture_basisu.
    let head = format!(
        r#"{{"extensionsUsed":["KHR_texture_basisu"],"extensionsRequired":["KHR_texture_basisu"],"images":[{{"uri":"data:image/ktx2;base64,{}"}}],"textures":[{{"extensions":{{"KHR_texture_basisu":{{"source":0}}}}}}],"#,
        coherent::scene::gltf::testdata::base64(include_bytes!("data/checker_etc1s.ktx2"))
    );
    let mut b = GltfBuilder::default();
    let cube = b.cube_mesh([1.0; 4]);
    b.materials[0] = r#"{"pbrMetallicRoughness":{"baseColorTexture":{"index":0}}}"#.to_string();
    b.node(cube, [0.0; 3]);
    b.scene_nodes = Some(vec![0]);
    out.push((
        "ktx2.gltf",
        b.gltf_embedded().replacen('{', &head, 1).into_bytes(),
    ));

    // A skinned mesh (two joints, one of them mirrored) and, on a second node, a triangle
    // with a morph target and weights of its own.
    let mut joints = [0u8; 36];
    joints[4 * 3] = 1;
    joints[4 * 6 + 1] = 1;
    let mut b = skinned_triangles(&joints);
    b.nodes[0] = b.nodes[0].replace("[2,2,2]", "[-2,2,2]");
    let pos = b.vec3(&[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    let moved = b.vec3(&[[0.0, 0.0, 1.0]; 3]);
    b.meshes.push(format!(
        r#"{{"weights":[0.5],"primitives":[{{"attributes":{{"POSITION":{pos}}},"targets":[{{"POSITION":{moved}}}]}}]}}"#
    ));
    b.nodes.push(r#"{"mesh":1,"weights":[1.5]}"#.to_string());
    b.scene_nodes = Some(vec![0, 2, 3]);
    out.push(("skin_morph.glb", b.glb()));

    // Two cubes, one of them moved by a LINEAR translation and a STEP rotation.
    let mut b = GltfBuilder::default();
    let cube = b.cube_mesh([0.5; 4]);
    b.node(cube, [0.0; 3]);
    b.node(cube, [3.0, 0.0, 0.0]);
    b.scene_nodes = Some(vec![0, 1]);
    let times = b.key_times(&[0.0, 1.0]);
    let moved = b.vec3(&[[3.0, 0.0, 0.0], [3.0, 2.0, 0.0]]);
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let turns: Vec<u8> = [0.0f32, 0.0, 0.0, 1.0, 0.0, h, 0.0, h]
        .iter()
        .flat_map(|t| t.to_le_bytes())
        .collect();
    let view = b.view(&turns);
    let turns = b.accessor(view, 5126, "VEC4", 2);
    b.head = format!(
        r#""animations":[{{"samplers":[{{"input":{times},"output":{moved}}},{{"input":{times},"output":{turns},"interpolation":"STEP"}}],"channels":[{{"sampler":0,"target":{{"node":1,"path":"translation"}}}},{{"sampler":1,"target":{{"node":1,"path":"rotation"}}}}]}}],"#
    );
    out.push(("animated.glb", b.glb()));
    out
}

/// A triangle whose positions and faces are a Draco stream (KHR_draco_mesh_compression
/// required; its accessors have no buffer views).
fn draco_triangle_glb() -> Vec<u8> {
    use draco_core::{
        DataType, EncoderBuffer, EncoderOptions, FaceIndex, GeometryAttributeType, Mesh,
        MeshEncoder, PointAttribute, PointIndex,
    };
    let mut mesh = Mesh::new();
    mesh.set_num_points(3);
    let mut position = PointAttribute::new();
    position.init(
        GeometryAttributeType::Position,
        3,
        DataType::Float32,
        false,
        3,
    );
    let bytes: Vec<u8> = [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]
        .iter()
        .flat_map(|f| f.to_le_bytes())
        .collect();
    position.buffer_mut().write(0, &bytes);
    let id = mesh.add_attribute(position);
    let unique = mesh.attribute(id).unique_id();
    mesh.set_num_faces(1);
    mesh.set_face(FaceIndex(0), [PointIndex(0), PointIndex(1), PointIndex(2)]);
    let mut encoder = MeshEncoder::new();
    encoder.set_mesh(mesh);
    let mut stream = EncoderBuffer::new();
    encoder
        .encode(&EncoderOptions::new(), &mut stream)
        .expect("encode");
    let mut b = GltfBuilder::default();
    let view = b.view(stream.data());
    b.accessors = vec![
        r#"{"componentType":5125,"type":"SCALAR","count":3}"#.to_string(),
        r#"{"componentType":5126,"type":"VEC3","count":3}"#.to_string(),
    ];
    b.meshes.push(format!(
        r#"{{"primitives":[{{"attributes":{{"POSITION":1}},"indices":0,"extensions":{{"KHR_draco_mesh_compression":{{"bufferView":{view},"attributes":{{"POSITION":{unique}}}}}}}}}]}}"#
    ));
    b.node(0, [0.0; 3]);
    b.scene_nodes = Some(vec![0]);
    b.head = r#""extensionsUsed":["KHR_draco_mesh_compression"],"extensionsRequired":["KHR_draco_mesh_compression"],"#.to_string();
    b.glb()
}

#[test]
fn seed_corpus_loads() {
    let dir = scratch("seeds");
    let out = std::env::var_os("COHERENT_FUZZ_SEEDS").map(PathBuf::from);
    for (name, bytes) in seeds() {
        let scene = load_never_panics(&dir, name, &bytes).expect(name);
        assert!(!scene.objects.is_empty(), "{name}: no objects");
        if name == "webp.gltf" || name == "ktx2.gltf" {
            assert_eq!(
                scene.images.len(),
                1,
                "{name}: the seed's texture is not read"
            );
        }
        if name == "blend.gltf" {
            let blended: Vec<bool> = (0..2).map(|o| scene.is_blended(o)).collect();
            assert_eq!(blended, [true, false], "the BLEND seed");
        }
        if name == "skinned_anim.gltf" || name == "morphed_anim.gltf" {
            let skinned = scene.animation.as_ref().map_or(0, |a| a.deformed.len());
            assert_eq!(skinned, 1, "{name} deforms nothing");
        }
        if name == "animated.glb" {
            assert!(scene.animation.is_some(), "the animated seed moves nothing");
        }
        if let Some(out) = &out {
            std::fs::create_dir_all(out).expect("seed dir");
            std::fs::write(out.join(name), &bytes).expect("write seed");
        }
    }
}

#[test]
fn corpus_replays_without_panic() {
    let corpus = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fuzz_corpus");
    let dir = scratch("corpus");
    let mut files: Vec<_> = std::fs::read_dir(&corpus)
        .expect("tests/fuzz_corpus")
        .map(|e| e.expect("corpus entry").path())
        .filter(|p| p.is_file() && p.extension().is_none_or(|e| e != "md"))
        .collect();
    files.sort();
    assert!(!files.is_empty(), "tests/fuzz_corpus is empty");
    for file in files {
        let bytes = std::fs::read(&file).expect("read corpus file");
        let ext = if bytes.starts_with(b"glTF") {
            "glb"
        } else {
            "gltf"
        };
        let stem = file.file_name().map(|n| n.to_string_lossy().into_owned());
        let name = format!("{}.{ext}", stem.unwrap_or_default());
        // Ok or a one-line error are both fine; a panic fails inside. A loaded scene's GI
        // geometry has one finite albedo per triangle.
        if let Ok(scene) = load_never_panics(&dir, &name, &bytes) {
            let world = coherent::gi::geometry::WorldGeometry::from_scene(&scene);
            assert_eq!(world.albedo.len(), world.triangles.len(), "{name}");
            assert!(
                world.albedo.iter().all(|a| a.is_finite()),
                "{name}: an albedo is not finite"
            );
        }
    }
}

// ---- Path files, PVS, calibration and interior walk cache files (fuzz target `cache_files`) ----

#[path = "../../fuzz/cache_input.rs"]
mod cache_input;

use cache_input::Kind;

/// Valid inputs of each kind (the `cache_files` fuzzer's seeds); each must be accepted.
fn cache_seeds() -> Vec<(&'static str, Vec<u8>)> {
    use coherent::app::calibrate::Calibration;
    use coherent::culling::nohc::CostModel;
    use coherent::culling::pvs::{Pvs, ViewCell};
    use coherent::scene::paths::{keys_to_json, PathKey};
    use coherent::scene::{interior, path_check, CameraPath, CameraPose};
    use glam::Vec3;
    let key = |t: f32, x: f32| PathKey {
        time: t,
        position: Vec3::new(x, 1.0, 10.0),
        target: Vec3::new(x, 1.0, 0.0),
    };
    let even = keys_to_json(&[key(0.0, -3.0), key(1.0, 0.0), key(2.0, 3.0)]);
    let uneven = keys_to_json(&[key(0.0, -3.0), key(0.5, 0.0), key(2.0, 3.0), key(2.1, 4.0)]);
    let oriented = r#"{"keys":[
        {"time":0,"position":[0,0,9],"orientation":[0,0,0,1]},
        {"time":1,"position":[1,0,9],"orientation":[0,0.70710677,0,0.70710677]}]}"#;
    let cells = (0..8)
        .map(|i| ViewCell {
            coord: [i % 2, i / 2 % 2, i / 4],
            objects: (0..cache_input::OBJECTS)
                .filter(|o| (o + i as u32).is_multiple_of(3))
                .collect(),
        })
        .collect();
    let pvs = Pvs::new(
        cache_input::PVS_KEY.into(),
        cache_input::OBJECTS,
        Vec3::splat(-4.0),
        4.0,
        cells,
    )
    .to_bytes();
    let body = pvs[..pvs.len() - 8].to_vec();
    let [device, driver, api_version] = cache_input::DEVICE.map(String::from);
    let cal = Calibration {
        format: "coherent-calibration".into(),
        version: 1,
        device,
        driver,
        api_version,
        costs: CostModel {
            draw_ms: 0.004,
            triangle_ms: 2e-6,
            fragment_ms: 1e-6,
            query_ms: 0.02,
            query_fragment_ms: 5e-7,
            round_trip_ms: 0.1,
        },
        unmeasurable: vec!["triangle".into()],
    };
    let cal = serde_json::to_string_pretty(&cal).expect("calibration json");
    let pose = |x: f32| CameraPose {
        eye: Vec3::new(x, 1.0, 10.0),
        target: Vec3::new(x, 0.5, 0.0),
    };
    let path = |name: &str| CameraPath {
        name: name.into(),
        keys: vec![pose(-3.0), pose(0.0), pose(3.0)],
    };
    let walk = interior::Outcome::Walk {
        camera: path(interior::PATH_NAME),
        light: path(interior::LIGHT_PATH_NAME),
    };
    let walk = interior::cache::to_json(&walk, cache_input::INTERIOR_KEY);
    let no_inside = interior::Outcome::NoInside("no place is inside".into());
    let no_inside = interior::cache::to_json(&no_inside, cache_input::INTERIOR_KEY);
    let good_path = path_check::verdict_json(cache_input::PATH_CHECK_KEY, None);
    let bad_path = path_check::verdict_json(
        cache_input::PATH_CHECK_KEY,
        Some("path \"street\": 3 of 120 checked frames look wrong; frame 30 at (1.00, 2.00, 3.00) sees 60% back faces"),
    );
    vec![
        ("path-even", cache_input::join(Kind::Path, even.as_bytes())),
        (
            "path-uneven",
            cache_input::join(Kind::Path, uneven.as_bytes()),
        ),
        (
            "path-oriented",
            cache_input::join(Kind::Path, oriented.as_bytes()),
        ),
        ("pvs", cache_input::join(Kind::Pvs, &pvs)),
        ("pvs-body", cache_input::join(Kind::PvsBody, &body)),
        (
            "calibration",
            cache_input::join(Kind::Calibration, cal.as_bytes()),
        ),
        (
            "interior",
            cache_input::join(Kind::Interior, walk.as_bytes()),
        ),
        (
            "interior-no-inside",
            cache_input::join(Kind::Interior, no_inside.as_bytes()),
        ),
        (
            "path-check-good",
            cache_input::join(Kind::PathCheck, good_path.as_bytes()),
        ),
        (
            "path-check-bad",
            cache_input::join(Kind::PathCheck, bad_path.as_bytes()),
        ),
    ]
}

#[test]
fn cache_seed_corpus_loads() {
    let dir = scratch("cache-seeds");
    let out = std::env::var_os("COHERENT_FUZZ_SEEDS").map(PathBuf::from);
    for (name, bytes) in cache_seeds() {
        let accepted = cache_input::run(&dir, &bytes).expect(name);
        assert!(accepted, "{name}: a valid file was refused");
        if let Some(out) = &out {
            std::fs::create_dir_all(out).expect("seed dir");
            std::fs::write(out.join(name), &bytes).expect("write seed");
        }
    }
}

#[test]
fn cache_files_refuse_damage_with_one_line_errors() {
    let dir = scratch("cache-damage");
    for (name, bytes) in cache_seeds() {
        // Cut short, and one byte flipped in the middle: refused (the PVS checksum, JSON
        // syntax or a field) or still valid, never a panic (run asserts the error's shape).
        let cut = &bytes[..bytes.len() / 2];
        let refused = !cache_input::run(&dir, cut).expect(name);
        assert!(refused, "{name}: half a file was accepted");
        let mut flipped = bytes.clone();
        let mid = flipped.len() / 2;
        flipped[mid] ^= 0x5a;
        cache_input::run(&dir, &flipped).expect(name);
    }
}

#[test]
fn cache_corpus_replays_without_panic() {
    let corpus = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fuzz_corpus/cache_files");
    let dir = scratch("cache-corpus");
    let mut files: Vec<_> = std::fs::read_dir(&corpus)
        .expect("tests/fuzz_corpus/cache_files")
        .map(|e| e.expect("corpus entry").path())
        .filter(|p| p.is_file() && p.extension().is_none_or(|e| e != "md"))
        .collect();
    files.sort();
    assert!(!files.is_empty(), "tests/fuzz_corpus/cache_files is empty");
    for file in files {
        let bytes = std::fs::read(&file).expect("read corpus file");
        // Accepted or refused with a one-line error naming the file; a panic fails.
        let start = std::time::Instant::now();
        let accepted =
            cache_input::run(&dir, &bytes).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        let name = file.file_name().unwrap_or_default().to_string_lossy();
        let ms = start.elapsed().as_secs_f64() * 1e3;
        println!("{name}: accepted {accepted}, {ms:.1} ms");
    }
}
