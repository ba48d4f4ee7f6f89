//! Scenes as users bring them: path files, glTF cameras and lights, compressed glTF, the
//! automatic interior walk.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use coherent::scene::paths::{self, PathKey};
use coherent::scene::Scene;
use glam::Vec3;

fn temp_dir(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("coherent_scenes_{}_{test}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
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
    let out = Command::new(env!("CARGO_BIN_EXE_coherent"))
        .args(["render", "--scene", "cornell", "--size", "64x64", "--path"])
        .arg(&file)
        .arg("--out")
        .arg(dir.join("x.png"))
        .env("COHERENT_DEVICE", "llvmpipe")
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
