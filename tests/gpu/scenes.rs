//! Scenes as users bring them: path files, glTF cameras and lights, compressed glTF, the
//! automatic interior walk.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::Command;

use coherent::scene::paths::{self, PathKey};
use coherent::scene::Scene;
use glam::Vec3;

fn temp_dir(test: &str) -> coherent::testing::TempDir {
    coherent::testing::TempDir::new(&format!("scenes-{test}"))
}

fn write(dir: &Path, name: &str, bytes: impl AsRef<[u8]>) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).expect("write");
    p
}

#[test]
fn path_file_round_trip() {
    let dir = temp_dir("roundtrip");
    let scene = Scene::load("cornell", 1.0, 4096).expect("cornell");
    let original = scene.default_path().expect("path").clone();
    let file = dir.join("cornell_path.json");
    paths::write_path_file(&file, &paths::path_to_keys(&original)).expect("write");
    let back = scene
        .resolve_path(Some(file.to_str().expect("utf-8")))
        .expect("read back");
    assert_eq!(back.name, "cornell_path");
    assert_eq!(back.keys, original.keys);
    // Written again, the file is the same.
    let again = dir.join("again.json");
    paths::write_path_file(&again, &paths::path_to_keys(&back)).expect("write");
    assert_eq!(
        std::fs::read_to_string(&file).expect("read"),
        std::fs::read_to_string(&again).expect("read")
    );
    for f in [0.0, 13.0, 45.5, back.natural_frames() as f32] {
        assert_eq!(back.pose_at(f), original.pose_at(f));
    }
}

#[test]
fn path_file_orientation_and_uneven_times() {
    let dir = temp_dir("orientation");
    // Quarter turn about +Y per key: -Z, -X, +Z. Times 0, 1, 3: resampled to 4 uniform keys.
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let file = write(
        &dir,
        "turn.json",
        format!(
            r#"{{"keys":[
            {{"time":0,"position":[0,1,0],"orientation":[0,0,0,1]}},
            {{"time":1,"position":[1,1,0],"orientation":[0,{h},0,{h}]}},
            {{"time":3,"position":[3,1,0],"look_at":[3,1,5]}}]}}"#
        ),
    );
    let keys = paths::read_path_file(&file).expect("read");
    assert!((keys[0].target - Vec3::new(0.0, 1.0, -1.0)).length() < 1e-5);
    assert!((keys[1].target - Vec3::new(0.0, 1.0, 0.0)).length() < 1e-5);
    let path = paths::read_camera_path(&file).expect("path");
    assert_eq!(path.keys.len(), 4);
    assert_eq!(path.keys[0].eye, Vec3::new(0.0, 1.0, 0.0));
    assert_eq!(path.keys[3].eye, Vec3::new(3.0, 1.0, 0.0));
    // The key at t = 2 s lies between the last two keys.
    assert!(path.keys[2].eye.x > 1.5 && path.keys[2].eye.x < 2.5);
}

/// Writes `text` as a path file and checks that reading it fails with one line naming the
/// file and containing `needle`.
fn assert_path_error(dir: &Path, name: &str, text: &str, needle: &str) {
    let file = write(dir, name, text);
    let msg = match paths::read_path_file(&file) {
        Ok(k) => panic!("{name} was accepted: {k:?}"),
        Err(e) => e.to_string(),
    };
    assert!(msg.contains(name), "{msg:?} does not name the file");
    assert!(msg.contains(needle), "{msg:?} lacks {needle:?}");
    assert!(!msg.contains('\n'), "{msg:?} is not one line");
}

#[test]
fn bad_path_files_are_one_line_errors() {
    let dir = temp_dir("bad");
    let key = r#"{"time":0,"position":[0,0,0],"look_at":[0,0,-1]}"#;
    let key1 = r#"{"time":1,"position":[1,0,0],"look_at":[1,0,-1]}"#;
    let cases = [
        (
            "nokeys.json",
            r#"{"frames":[]}"#.to_string(),
            "missing \"keys\"",
        ),
        (
            "one.json",
            format!(r#"{{"keys":[{key}]}}"#),
            "at least 2 keys",
        ),
        (
            "nan.json",
            format!(r#"{{"keys":[{key},{{"time":NaN,"position":[0,0,0],"look_at":[1,1,1]}}]}}"#),
            "invalid JSON",
        ),
        (
            "huge.json",
            format!(r#"{{"keys":[{key},{{"time":1e39,"position":[0,0,0],"look_at":[1,1,1]}}]}}"#),
            "not a finite",
        ),
        (
            "notime.json",
            format!(r#"{{"keys":[{key},{{"position":[0,0,0],"look_at":[1,1,1]}}]}}"#),
            "key 1: missing \"time\"",
        ),
        (
            "nopos.json",
            format!(r#"{{"keys":[{key},{{"time":1,"look_at":[1,1,1]}}]}}"#),
            "key 1: missing \"position\"",
        ),
        (
            "nolook.json",
            format!(r#"{{"keys":[{key},{{"time":1,"position":[0,0,0]}}]}}"#),
            "needs \"look_at\" or \"orientation\"",
        ),
        (
            "strpos.json",
            format!(r#"{{"keys":[{key},{{"time":1,"position":"here","look_at":[1,1,1]}}]}}"#),
            "\"position\" is not an array of 3 numbers",
        ),
        (
            "short.json",
            format!(r#"{{"keys":[{key},{{"time":1,"position":[0,0],"look_at":[1,1,1]}}]}}"#),
            "\"position\" is not an array of 3 numbers",
        ),
        (
            "strtime.json",
            format!(r#"{{"keys":[{key},{{"time":"1","position":[0,0,0],"look_at":[1,1,1]}}]}}"#),
            "\"time\" is not a number",
        ),
        (
            "quat.json",
            format!(
                r#"{{"keys":[{key},{{"time":1,"position":[0,0,0],"orientation":[0,0,0,2]}}]}}"#
            ),
            "not a unit quaternion",
        ),
        (
            "order.json",
            format!(r#"{{"keys":[{key1},{key}]}}"#),
            "key 1: time 0 is not after",
        ),
        (
            "keysobj.json",
            r#"{"keys":{"a":1}}"#.to_string(),
            "\"keys\" is not an array",
        ),
        ("text.json", "camera goes here".to_string(), "invalid JSON"),
    ];
    for (name, text, needle) in &cases {
        assert_path_error(&dir, name, text, needle);
    }
    let missing = dir.join("absent.json");
    let msg = paths::read_path_file(&missing)
        .expect_err("missing")
        .to_string();
    assert!(msg.contains("absent.json") && msg.contains("cannot read path file"));
}

#[test]
fn cli_reports_bad_path_file_in_one_line() {
    let dir = temp_dir("cli");
    let file = write(&dir, "broken_path.json", r#"{"keys":[]}"#);
    let out = common::on_test_device(&mut Command::new(env!("CARGO_BIN_EXE_coherent")))
        .args(["render", "--scene", "cornell", "--size", "64x64", "--path"])
        .arg(&file)
        .arg("--out")
        .arg(dir.join("x.png"))
        .output()
        .expect("run coherent");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(lines[0].contains("broken_path.json") && lines[0].contains("at least 2 keys"));
}

#[test]
fn render_follows_a_path_file() {
    // The frame rendered from a path file's first key equals the frame of the scene path it
    // was written from (validation on, zero messages).
    let dir = temp_dir("render");
    let (ctx, log) = common::context();
    let (scene, bvh) = common::scene("cornell", 1.0);
    let original = scene.default_path().expect("path").clone();
    let mut keys: Vec<PathKey> = paths::path_to_keys(&original);
    keys.reverse();
    for (i, k) in keys.iter_mut().enumerate() {
        k.time = i as f32 * 0.5;
    }
    let file = dir.join("reversed.json");
    paths::write_path_file(&file, &keys).expect("write");
    let reversed = scene
        .resolve_path(Some(file.to_str().expect("utf-8")))
        .expect("path file");
    {
        let mut r = coherent::render::Renderer::new(&ctx, &scene, 96, 64).expect("renderer");
        let mut vfc = coherent::culling::create("vfc", &Default::default()).expect("vfc");
        let last = original.keys.len() - 1;
        let (_, a) = common::frame(&mut r, vfc.as_mut(), &bvh, original.keys[last], 0);
        let (_, b) = common::frame(&mut r, vfc.as_mut(), &bvh, reversed.pose_at(0.0), 1);
        let (_, c) = common::frame(&mut r, vfc.as_mut(), &bvh, original.keys[0], 2);
        assert_eq!(common::diff_pixels(&a, &b), 0);
        assert!(
            common::diff_pixels(&a, &c) > 0,
            "the path's ends look alike"
        );
    }
    drop(ctx);
    common::assert_silent(&log);
}

use coherent::scene::gltf::testdata::GltfBuilder;

/// `json` with `extra` (`"key":value,` pairs) added at the top level.
fn with_top(json: &str, extra: &str) -> String {
    format!("{{{extra},{}", &json[1..])
}

/// A `.glb` of a JSON document and its binary chunk.
fn glb_from(json: &str, bin: &[u8]) -> Vec<u8> {
    let mut json = json.as_bytes().to_vec();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let mut bin = bin.to_vec();
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let mut out = Vec::new();
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&((28 + json.len() + bin.len()) as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    out
}

/// A triangle rotated so its smallest corner comes first (same winding): meshopt's index
/// codec may rotate a triangle's corners.
fn canonical(t: [Vec3; 3]) -> [Vec3; 3] {
    let key = |v: Vec3| (v.x, v.y, v.z);
    let first = (0..3)
        .min_by(|&a, &b| key(t[a]).partial_cmp(&key(t[b])).expect("finite"))
        .unwrap_or(0);
    [t[first], t[(first + 1) % 3], t[(first + 2) % 3]]
}

/// World-space triangles of every object, in order.
fn world_triangles(scene: &Scene) -> Vec<[Vec3; 3]> {
    let mut out = Vec::new();
    for o in &scene.objects {
        let idx = &scene.indices[o.first_index as usize..(o.first_index + o.index_count) as usize];
        for t in idx.chunks_exact(3) {
            out.push([t[0], t[1], t[2]].map(|i| {
                let v = scene.vertices[(o.vertex_offset + i) as usize];
                o.transform.transform_point3(Vec3::from_array(v.position))
            }));
        }
    }
    out
}

fn scene_bounds(scene: &Scene) -> coherent::scene::Aabb {
    scene
        .objects
        .iter()
        .fold(coherent::scene::Aabb::EMPTY, |b, o| b.union(&o.bounds))
}

/// Node translations of the compression tests: a row of cubes.
const CUBES: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [2.0, 0.5, 0.0], [4.0, 0.0, -1.0]];

fn bytes_of<T: Copy, const N: usize>(v: &[[T; N]], f: impl Fn(T) -> Vec<u8>) -> Vec<u8> {
    v.iter().flatten().flat_map(|&x| f(x)).collect()
}

/// The uncompressed original: unit cubes (float positions and normals, u16 indices).
fn original_cubes() -> GltfBuilder {
    let mut b = GltfBuilder::default();
    let mesh = b.cube_mesh([0.7, 0.6, 0.5, 1.0]);
    for t in CUBES {
        b.node(mesh, t);
    }
    b.scene_nodes = Some((0..CUBES.len()).collect());
    b
}

/// The same cubes with KHR_mesh_quantization: i16 positions (x2, stride 8) under a node
/// scale of 0.5, i8 normalized normals (stride 4).
fn quantized_cubes() -> String {
    let (pos, nrm, idx) = coherent::scene::gltf::testdata::cube();
    let mut b = GltfBuilder::default();
    let qpos: Vec<[i16; 4]> = pos
        .iter()
        .map(|p| {
            [
                (p[0] * 2.0) as i16,
                (p[1] * 2.0) as i16,
                (p[2] * 2.0) as i16,
                0,
            ]
        })
        .collect();
    let qnrm: Vec<[i8; 4]> = nrm
        .iter()
        .map(|n| {
            [
                (n[0] * 127.0) as i8,
                (n[1] * 127.0) as i8,
                (n[2] * 127.0) as i8,
                0,
            ]
        })
        .collect();
    let v = b.view(&bytes_of(&qpos, |x: i16| x.to_le_bytes().to_vec()));
    b.views[v] = b.views[v].replace('}', r#","byteStride":8}"#);
    let p = b.accessor(v, 5122, "VEC3", qpos.len());
    let v = b.view(&bytes_of(&qnrm, |x: i8| vec![x as u8]));
    b.views[v] = b.views[v].replace('}', r#","byteStride":4}"#);
    let n = b.accessor(v, 5120, "VEC3", qnrm.len());
    b.accessors[n] = b.accessors[n].replace('}', r#","normalized":true}"#);
    let i = b.indices_u16(&idx);
    b.meshes.push(format!(
        r#"{{"primitives":[{{"attributes":{{"POSITION":{p},"NORMAL":{n}}},"indices":{i}}}]}}"#
    ));
    for t in CUBES {
        b.nodes.push(format!(
            r#"{{"mesh":0,"translation":[{},{},{}],"scale":[0.5,0.5,0.5]}}"#,
            t[0], t[1], t[2]
        ));
    }
    b.scene_nodes = Some((0..CUBES.len()).collect());
    with_top(
        &b.gltf_embedded(),
        r#""extensionsUsed":["KHR_mesh_quantization"],"extensionsRequired":["KHR_mesh_quantization"]"#,
    )
}

/// Adds a view of `data` compressed with meshopt into buffer 0, decoding into `length` bytes
/// at `offset` of the fallback buffer 1; returns the view index.
fn meshopt_view(
    b: &mut GltfBuilder,
    data: &[u8],
    (offset, length, stride, count): (usize, usize, usize, usize),
    mode_filter: (&str, &str),
) -> usize {
    while !b.bin.len().is_multiple_of(4) {
        b.bin.push(0);
    }
    let at = b.bin.len();
    b.bin.extend_from_slice(data);
    let (mode, filter) = mode_filter;
    b.views.push(format!(
        r#"{{"buffer":1,"byteOffset":{offset},"byteLength":{length}{},"extensions":{{"EXT_meshopt_compression":{{"buffer":0,"byteOffset":{at},"byteLength":{},"byteStride":{stride},"count":{count},"mode":"{mode}","filter":"{filter}"}}}}}}"#,
        if mode == "ATTRIBUTES" { format!(r#","byteStride":{stride}"#) } else { String::new() },
        data.len()
    ));
    b.views.len() - 1
}

/// The same cubes compressed with meshopt's encoder (float positions, octahedral-filtered i8
/// normals, triangle-coded u16 indices) into a fallback buffer, as gltfpack writes them.
fn meshopt_cubes() -> Vec<u8> {
    let (pos, nrm, idx) = coherent::scene::gltf::testdata::cube();
    let mut b = GltfBuilder::default();
    let n = pos.len();
    let enc_pos = meshopt::encode_vertex_buffer(&pos).expect("encode positions");
    let v = meshopt_view(&mut b, &enc_pos, (0, 12 * n, 12, n), ("ATTRIBUTES", "NONE"));
    let p = b.accessor(v, 5126, "VEC3", n);
    let n4: Vec<[f32; 4]> = nrm.iter().map(|v| [v[0], v[1], v[2], 0.0]).collect();
    let oct: Vec<[i8; 4]> = meshopt::encode_filter_oct(&n4, 8);
    let enc_nrm = meshopt::encode_vertex_buffer(&oct).expect("encode normals");
    let v = meshopt_view(
        &mut b,
        &enc_nrm,
        (12 * n, 4 * n, 4, n),
        ("ATTRIBUTES", "OCTAHEDRAL"),
    );
    let nacc = b.accessor(v, 5120, "VEC3", n);
    b.accessors[nacc] = b.accessors[nacc].replace('}', r#","normalized":true}"#);
    let idx32: Vec<u32> = idx.iter().map(|&i| i as u32).collect();
    let enc_idx = meshopt::encode_index_buffer(&idx32, n).expect("encode indices");
    let v = meshopt_view(
        &mut b,
        &enc_idx,
        (16 * n, 2 * idx.len(), 2, idx.len()),
        ("TRIANGLES", "NONE"),
    );
    let i = b.accessor(v, 5123, "SCALAR", idx.len());
    b.meshes.push(format!(
        r#"{{"primitives":[{{"attributes":{{"POSITION":{p},"NORMAL":{nacc}}},"indices":{i}}}]}}"#
    ));
    for t in CUBES {
        b.node(0, t);
    }
    b.scene_nodes = Some((0..CUBES.len()).collect());
    let fallback = 16 * n + 2 * idx.len();
    let json = b.json(None);
    let json = format!(
        r#"{},{{"byteLength":{fallback},"extensions":{{"EXT_meshopt_compression":{{"fallback":true}}}}}}]}}"#,
        json.strip_suffix("]}").expect("buffers last")
    );
    let exts = r#""EXT_meshopt_compression","KHR_mesh_quantization""#;
    let json = with_top(
        &json,
        &format!(r#""extensionsUsed":[{exts}],"extensionsRequired":[{exts}]"#),
    );
    glb_from(&json, &b.bin)
}

#[test]
fn meshopt_and_quantized_files_load_like_the_original() {
    let dir = temp_dir("compressed");
    let original = write(&dir, "original.glb", original_cubes().glb());
    let quantized = write(&dir, "quantized.gltf", quantized_cubes());
    let compressed = write(&dir, "meshopt.glb", meshopt_cubes());
    let (a, wa) = coherent::scene::gltf::load_gltf(&original).expect("original");
    assert!(wa.is_empty(), "{wa:?}");
    let ta = world_triangles(&a);
    assert_eq!(ta.len(), 36);
    for file in [&quantized, &compressed] {
        let (b, wb) = coherent::scene::gltf::load_gltf(file).expect("compressed file loads");
        assert!(wb.is_empty(), "{}: {wb:?}", file.display());
        let canon = |s: &Scene| -> Vec<[Vec3; 3]> {
            world_triangles(s).into_iter().map(canonical).collect()
        };
        assert_eq!(canon(&b), canon(&a), "{}", file.display());
        assert_eq!(scene_bounds(&b), scene_bounds(&a), "{}", file.display());
        for (x, y) in a.vertices.iter().zip(&b.vertices) {
            let (nx, ny) = (Vec3::from_array(x.normal), Vec3::from_array(y.normal));
            assert!((nx - ny).length() < 0.02, "{nx} vs {ny}");
        }
    }
    // The compressed file really is compressed: no plain float positions in it.
    let bytes = std::fs::read(&compressed).expect("read");
    let plain: Vec<u8> = 0.5f32.to_le_bytes().repeat(3);
    assert!(!bytes.windows(12).any(|w| w == plain.as_slice()));
}

#[test]
fn unsupported_extensions_warn_or_fail_in_one_line() {
    let dir = temp_dir("extensions");
    let json = original_cubes().gltf_embedded();
    let used = write(
        &dir,
        "avif.gltf",
        with_top(&json, r#""extensionsUsed":["EXT_texture_avif"]"#),
    );
    let (_, warnings) = coherent::scene::gltf::load_gltf(&used).expect("loads");
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    assert!(warnings[0].contains("EXT_texture_avif") && !warnings[0].contains('\n'));
    let required = write(
        &dir,
        "metadata.gltf",
        with_top(
            &json,
            r#""extensionsUsed":["EXT_structural_metadata"],"extensionsRequired":["EXT_structural_metadata"]"#,
        ),
    );
    let msg = coherent::scene::gltf::load_gltf(&required)
        .expect_err("the extension is required")
        .to_string();
    assert!(
        msg.contains("metadata.gltf") && msg.contains("EXT_structural_metadata"),
        "{msg}"
    );
    assert!(!msg.contains('\n'));
}

/// Cubes with two cameras (one under a translated parent, turned 90° about +Y) and a spot
/// light; with `animated`, a translation animation moves the light along +X.
fn cameras_and_light(animated: bool) -> String {
    let mut b = original_cubes();
    let h = std::f32::consts::FRAC_1_SQRT_2;
    b.nodes.push(r#"{"camera":0,"translation":[0,1,8]}"#.into()); // 3
    b.nodes
        .push(r#"{"translation":[10,0,0],"children":[5]}"#.into()); // 4
    b.nodes.push(format!(
        r#"{{"camera":0,"translation":[0,1,0],"rotation":[0,{h},0,{h}]}}"#
    )); // 5
    b.nodes.push(format!(
        r#"{{"translation":[2,4,0],"rotation":[{},0,0,{}],"extensions":{{"KHR_lights_punctual":{{"light":0}}}}}}"#,
        -h, h
    )); // 6: looks down -Y
    b.scene_nodes = Some(vec![0, 1, 2, 3, 4, 6]);
    let mut extra = String::from(
        r#""cameras":[{"type":"perspective","perspective":{"yfov":1.0,"znear":0.1}}],"extensionsUsed":["KHR_lights_punctual"],"extensions":{"KHR_lights_punctual":{"lights":[{"type":"spot","spot":{}}]}}"#,
    );
    if animated {
        let input = b.key_times(&[0.0, 1.0, 2.0]);
        let output = b.vec3(&[[2.0, 4.0, 0.0], [3.0, 4.0, 0.0], [4.0, 4.0, 0.0]]);
        extra += &format!(
            r#","animations":[{{"channels":[{{"sampler":0,"target":{{"node":6,"path":"translation"}}}}],"samplers":[{{"input":{input},"output":{output}}}]}}]"#
        );
    }
    with_top(&b.gltf_embedded(), &extra)
}

#[test]
fn gltf_cameras_and_spot_light_become_paths() {
    let dir = temp_dir("cameras");
    let file = write(&dir, "rig.gltf", cameras_and_light(false));
    let scene = Scene::load(file.to_str().expect("utf-8"), 1.0, 4096).expect("load");
    let cams = scene
        .resolve_path(Some("gltf-cameras"))
        .expect("camera path");
    assert_eq!(cams.keys.len(), 2);
    assert!((cams.keys[0].eye - Vec3::new(0.0, 1.0, 8.0)).length() < 1e-5);
    assert!((cams.keys[0].target - Vec3::new(0.0, 1.0, 7.0)).length() < 1e-5);
    assert!((cams.keys[1].eye - Vec3::new(10.0, 1.0, 0.0)).length() < 1e-5);
    assert!((cams.keys[1].target - Vec3::new(9.0, 1.0, 0.0)).length() < 1e-5);
    // A static spot light: a sweep of three keys at its position around its direction.
    let light = scene.path("gltf-light").expect("light path");
    assert_eq!(light.keys.len(), 3);
    for k in &light.keys {
        assert!((k.eye - Vec3::new(2.0, 4.0, 0.0)).length() < 1e-5);
        let d = (k.target - k.eye).normalize();
        assert!(d.y < -0.9, "{d}");
    }
    assert!((light.keys[1].target - Vec3::new(2.0, 3.0, 0.0)).length() < 1e-5);
    assert!(light.keys[0].target != light.keys[2].target);

    let file = write(&dir, "animated.gltf", cameras_and_light(true));
    let scene = Scene::load(file.to_str().expect("utf-8"), 1.0, 4096).expect("load");
    let light = scene.path("gltf-light").expect("light path");
    assert_eq!(light.keys.len(), 3);
    for (i, k) in light.keys.iter().enumerate() {
        assert!(
            (k.eye - Vec3::new(2.0 + i as f32, 4.0, 0.0)).length() < 1e-5,
            "{k:?}"
        );
        assert!((k.target - k.eye - Vec3::NEG_Y).length() < 1e-5, "{k:?}");
    }
    // Without cameras or lights the paths are not there, and asking names the ones there are.
    let plain = write(&dir, "plain.glb", original_cubes().glb());
    let scene = Scene::load(plain.to_str().expect("utf-8"), 1.0, 4096).expect("load");
    let msg = scene
        .resolve_path(Some("gltf-cameras"))
        .expect_err("none")
        .to_string();
    assert!(msg.contains("no path \"gltf-cameras\""), "{msg}");
}

/// A closed box room (20 x 4 x 12 inside, walls 0.2 thick) with eight pillars.
fn room_with_pillars() -> Vec<u8> {
    let mut b = GltfBuilder::default();
    let cube = b.cube_mesh([0.8, 0.8, 0.8, 1.0]);
    let mut boxes: Vec<([f32; 3], [f32; 3])> = vec![
        ([0.0, -0.1, 0.0], [20.4, 0.2, 12.4]),
        ([0.0, 4.1, 0.0], [20.4, 0.2, 12.4]),
        ([-10.1, 2.0, 0.0], [0.2, 4.0, 12.0]),
        ([10.1, 2.0, 0.0], [0.2, 4.0, 12.0]),
        ([0.0, 2.0, -6.1], [20.0, 4.0, 0.2]),
        ([0.0, 2.0, 6.1], [20.0, 4.0, 0.2]),
    ];
    for x in [-6.0, -3.0, 3.0, 6.0] {
        for z in [-3.0, 3.0] {
            boxes.push(([x, 2.0, z], [0.6, 4.0, 0.6]));
        }
    }
    for (t, s) in &boxes {
        b.nodes.push(format!(
            r#"{{"mesh":{cube},"translation":[{},{},{}],"scale":[{},{},{}]}}"#,
            t[0], t[1], t[2], s[0], s[1], s[2]
        ));
    }
    b.scene_nodes = Some((0..boxes.len()).collect());
    b.glb()
}

#[test]
fn interior_walk_stays_inside_and_clear() {
    use coherent::scene::interior::{self, InteriorParams};
    let dir = temp_dir("interior");
    let file = write(&dir, "room.glb", room_with_pillars());
    let scene = Scene::load(file.to_str().expect("utf-8"), 1.0, 4096).expect("load");
    // Enclosed: the interior walk is the default path, the orbit is still there.
    assert_eq!(scene.paths[0].name, "interior");
    assert!(scene.path("default").is_ok());
    let margin = 0.3;
    let params = InteriorParams {
        margin: Some(margin),
        ..Default::default()
    };
    let path = interior::interior_path(&scene, &params).expect("walk");
    let again = interior::interior_path(&scene, &params).expect("walk");
    assert_eq!(path.keys, again.keys, "not deterministic");
    assert!(path.keys.len() >= 4, "{} keys", path.keys.len());
    let triangles = world_triangles(&scene);
    let frames = path.natural_frames();
    let mut xs = (f32::INFINITY, f32::NEG_INFINITY);
    for f in 0..=frames {
        let eye = path.pose_at(f as f32).eye;
        assert!(
            eye.x > -10.0 && eye.x < 10.0 && eye.y > 0.0 && eye.y < 4.0,
            "frame {f}: {eye} outside the room"
        );
        assert!(
            eye.z > -6.0 && eye.z < 6.0,
            "frame {f}: {eye} outside the room"
        );
        let d = triangles
            .iter()
            .map(|t| interior::distance_to_triangle(eye, t))
            .fold(f32::INFINITY, f32::min);
        assert!(d >= margin, "frame {f}: {eye} is {d} from geometry");
        assert!(
            (eye.y - 1.6).abs() < 0.15,
            "frame {f}: eye height {}",
            eye.y
        );
        xs = (xs.0.min(eye.x), xs.1.max(eye.x));
    }
    // It walks through the room, not around one spot.
    assert!(xs.1 - xs.0 > 8.0, "x range {xs:?}");
    // A scene that is not enclosed keeps the orbit as its default.
    let open = write(
        &dir,
        "grid.glb",
        coherent::scene::gltf::testdata::cube_grid_glb(9),
    );
    let scene = Scene::load(open.to_str().expect("utf-8"), 1.0, 4096).expect("load");
    assert_eq!(scene.paths[0].name, "default");
}

#[test]
fn recorded_camera_plays_back() {
    use coherent::scene::paths::PathRecorder;
    use coherent::scene::CameraPose;
    let dir = temp_dir("record");
    let mut rec = PathRecorder::new(0.1);
    let file = dir.join("flown.json");
    assert!(rec.finish(&file).is_err(), "an empty recording was written");
    // Frames every 1/60 s while flying along +X: one key per 0.1 s is kept.
    for i in 0..=120 {
        let t = i as f32 / 60.0;
        let eye = Vec3::new(t * 3.0, 1.7, 0.0);
        rec.push(
            t,
            CameraPose {
                eye,
                target: eye + Vec3::X,
            },
        );
    }
    assert!(
        (20..=21).contains(&rec.keys().len()),
        "{}",
        rec.keys().len()
    );
    rec.finish(&file).expect("write");
    let scene = Scene::load("cornell", 1.0, 4096).expect("scene");
    let path = scene
        .resolve_path(Some(file.to_str().expect("utf-8")))
        .expect("play back");
    let end = path.pose_at(path.natural_frames() as f32);
    assert!((end.eye - rec.keys().last().expect("key").position).length() < 1e-4);
    assert!((path.pose_at(0.0).eye - Vec3::new(0.0, 1.7, 0.0)).length() < 1e-5);
}

/// A `.glb` room seen from inside: a 12 x 3 x 12 box with its faces turned in, and two
/// pillars.
fn room_glb() -> Vec<u8> {
    use coherent::scene::gltf::testdata::{cube, GltfBuilder};
    let (positions, normals, indices) = cube();
    let mut b = GltfBuilder::default();
    let walls: Vec<[f32; 3]> = positions
        .iter()
        .map(|p| [p[0] * 12.0, p[1] * 3.0 + 1.5, p[2] * 12.0])
        .collect();
    let inward: Vec<[f32; 3]> = normals.iter().map(|n| n.map(|c| -c)).collect();
    let turned: Vec<u16> = indices
        .chunks_exact(3)
        .flat_map(|t| [t[0], t[2], t[1]])
        .collect();
    let (pos, nrm, idx) = (b.vec3(&walls), b.vec3(&inward), b.indices_u16(&turned));
    b.materials
        .push(r#"{"pbrMetallicRoughness":{"baseColorFactor":[0.8,0.7,0.6,1]}}"#.into());
    b.meshes.push(format!(
        r#"{{"name":"room","primitives":[{{"attributes":{{"POSITION":{pos},"NORMAL":{nrm}}},"indices":{idx},"material":0}}]}}"#
    ));
    let room = b.node(0, [0.0, 0.0, 0.0]);
    let pillar = b.cube_mesh([0.3, 0.4, 0.8, 1.0]);
    let pillars = [
        b.node(pillar, [-3.0, 0.5, 2.0]),
        b.node(pillar, [3.0, 0.5, -2.0]),
    ];
    b.scene_nodes = Some(vec![room, pillars[0], pillars[1]]);
    b.glb()
}

#[test]
fn render_keeps_the_interior_walk_in_the_cache_directory() {
    // The first render finds the walk and says where it kept it; the second reads it from
    // there, says nothing about it and renders the same image.
    let dir = temp_dir("interior_cache");
    let file = write(&dir, "room.glb", room_glb());
    let cache = dir.join("cache");
    let render = |png: &str| {
        let out = common::on_test_device(&mut Command::new(env!("CARGO_BIN_EXE_coherent")))
            .args(["render", "--size", "96x54", "--scene"])
            .arg(&file)
            .arg("--cache-dir")
            .arg(&cache)
            .arg("--out")
            .arg(dir.join(png))
            .output()
            .expect("run coherent");
        let err = String::from_utf8_lossy(&out.stderr).to_string();
        assert!(out.status.success(), "{err}");
        assert!(
            String::from_utf8_lossy(&out.stdout).contains("room: interior frame 0"),
            "{err}"
        );
        err
    };
    let first = render("first.png");
    assert!(first.contains("interior walk found in"), "{first}");
    let mut kept: Vec<_> = std::fs::read_dir(&cache)
        .expect("cache directory")
        .map(|e| e.expect("entry").file_name().to_string_lossy().to_string())
        .collect();
    kept.sort();
    // The walk, and the path check's verdict on it (no warning: a good walk).
    assert!(
        kept.len() == 2
            && kept[0].starts_with("interior-")
            && first.contains(&kept[0])
            && kept[1].starts_with("pathcheck-"),
        "{kept:?} {first}"
    );
    assert!(!first.contains("warning"), "{first}");
    let second = render("second.png");
    assert!(!second.contains("interior walk"), "{second}");
    let image = |png: &str| std::fs::read(dir.join(png)).expect("png");
    assert!(image("first.png") == image("second.png"));
}
