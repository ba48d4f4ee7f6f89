//! Materials under validation: a glTF written here with a checker texture (REPEAT and
//! CLAMP_TO_EDGE samplers, nearest filtering), an alpha-masked quad in front of a wall with
//! vertex colors; the render shows the texture, masked pixels show the wall, the ID pass agrees
//! with the mask. Images come from a data URI, a file next to the .gltf and a GLB buffer view.

use crate::common;

use std::path::{Path, PathBuf};

use coherent::culling;
use coherent::render::hiz::{HizCuller, HizParams};
use coherent::render::Renderer;
use coherent::scene::gltf::testdata::GltfBuilder;
use coherent::scene::{AlphaMode, CameraPose, Scene};
use glam::Vec3;

const W: u32 = 320;
const H: u32 = 240;

fn temp_dir(test: &str) -> coherent::testing::TempDir {
    coherent::testing::TempDir::new(&format!("materials-{test}"))
}

/// 8x8 checker: texel (x, y) white when x + y is even, else black.
fn checker_png() -> Vec<u8> {
    let rgba = (0..64)
        .flat_map(|i| {
            let c = if (i % 8 + i / 8) % 2 == 0 { 255 } else { 0 };
            [c, c, c, 255]
        })
        .collect();
    common::png(8, 8, rgba)
}

/// 2x1 red: the left texel transparent, the right one opaque.
fn mask_png() -> Vec<u8> {
    common::png(2, 1, vec![255, 0, 0, 0, 255, 0, 0, 255])
}

fn base64(data: &[u8]) -> String {
    coherent::scene::gltf::testdata::base64(data)
}

/// A quad in the plane z = `z` from (x0, y0) to (x1, y1), facing +Z, with texture coordinates
/// (0, v) .. (`u1`, ...) and optional per-vertex colors (normalized u8 RGBA, left two vertices
/// then right two); returns the mesh index.
fn quad(
    b: &mut GltfBuilder,
    (x0, y0, x1, y1, z): (f32, f32, f32, f32, f32),
    u1: f32,
    colors: Option<([u8; 4], [u8; 4])>,
    material: usize,
) -> usize {
    let pos = b.vec3(&[[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]]);
    let nrm = b.vec3(&[[0.0, 0.0, 1.0]; 4]);
    let uv: Vec<u8> = [[0.0, 1.0], [u1, 1.0], [u1, 0.0], [0.0, 0.0]]
        .iter()
        .flatten()
        .flat_map(|f: &f32| f.to_le_bytes())
        .collect();
    let uv_view = b.view(&uv);
    let uv = b.accessor(uv_view, 5126, "VEC2", 4);
    let idx = b.indices_u16(&[0, 1, 2, 0, 2, 3]);
    let mut attributes = format!(r#""POSITION":{pos},"NORMAL":{nrm},"TEXCOORD_0":{uv}"#);
    if let Some((left, right)) = colors {
        let bytes: Vec<u8> = [left, right, right, left].concat();
        let view = b.view(&bytes);
        b.accessors.push(format!(
            r#"{{"bufferView":{view},"componentType":5121,"normalized":true,"type":"VEC4","count":4}}"#
        ));
        attributes += &format!(r#","COLOR_0":{}"#, b.accessors.len() - 1);
    }
    b.meshes.push(format!(
        r#"{{"primitives":[{{"attributes":{{{attributes}}},"indices":{idx},"material":{material}}}]}}"#
    ));
    b.meshes.len() - 1
}

/// The test document: materials 0 (wall, vertex colors), 1 (checker, REPEAT), 2 (checker,
/// CLAMP_TO_EDGE), 3 (red, alpha mask 0.5); images `checker` and `mask` as JSON objects.
fn document(b: &mut GltfBuilder) {
    b.materials = vec![
        r#"{"pbrMetallicRoughness":{"baseColorFactor":[1,1,1,1]}}"#.to_string(),
        r#"{"pbrMetallicRoughness":{"baseColorTexture":{"index":0}}}"#.to_string(),
        r#"{"pbrMetallicRoughness":{"baseColorTexture":{"index":1}}}"#.to_string(),
        r#"{"pbrMetallicRoughness":{"baseColorTexture":{"index":2}},"alphaMode":"MASK","alphaCutoff":0.5}"#.to_string(),
    ];
    let blue = [0, 0, 255, 255];
    let cyan = [0, 255, 255, 255];
    let wall = quad(b, (-6.0, -4.0, 6.0, 4.0, -1.0), 1.0, Some((blue, cyan)), 0);
    let repeat = quad(b, (-2.0, 0.2, -0.2, 1.8, 0.0), 2.0, None, 1);
    let clamp = quad(b, (-2.0, -1.8, -0.2, -0.2, 0.0), 2.0, None, 2);
    let masked = quad(b, (0.2, -1.0, 2.0, 1.0, 0.5), 1.0, None, 3);
    for m in [wall, repeat, clamp, masked] {
        b.node(m, [0.0, 0.0, 0.0]);
    }
}

const SAMPLERS: &str = r#""samplers":[{"magFilter":9728,"minFilter":9728,"wrapS":10497,"wrapT":10497},{"magFilter":9728,"minFilter":9728,"wrapS":33071,"wrapT":33071}],"textures":[{"source":0,"sampler":0},{"source":0,"sampler":1},{"source":1,"sampler":1}]"#;

/// Writes the document as .gltf (checker as a data URI, mask as `mask.png` next to it).
fn write_gltf(dir: &Path) -> PathBuf {
    let mut b = GltfBuilder::default();
    document(&mut b);
    std::fs::write(dir.join("mask.png"), mask_png()).expect("write");
    let images = format!(
        r#""images":[{{"uri":"data:image/png;base64,{}"}},{{"uri":"mask.png"}}],{SAMPLERS},"#,
        base64(&checker_png())
    );
    let uri = format!("data:application/octet-stream;base64,{}", base64(&b.bin));
    let json = b.json(Some(&uri)).replacen('{', &format!("{{{images}"), 1);
    let path = dir.join("materials.gltf");
    std::fs::write(&path, json).expect("write");
    path
}

/// The same document as .glb with both images in buffer views.
fn write_glb(dir: &Path, checker: &[u8], checker_mime: &str) -> PathBuf {
    let mut b = GltfBuilder::default();
    document(&mut b);
    let c = b.view(checker);
    let m = b.view(&mask_png());
    let images = format!(
        r#""images":[{{"bufferView":{c},"mimeType":"{checker_mime}"}},{{"bufferView":{m},"mimeType":"image/png"}}],{SAMPLERS},"#
    );
    while b.bin.len() % 4 != 0 {
        b.bin.push(0);
    }
    let mut json = b.json(None).replacen('{', &format!("{{{images}"), 1);
    while json.len() % 4 != 0 {
        json.push(' ');
    }
    let mut glb = Vec::new();
    let total = 12 + 8 + json.len() + 8 + b.bin.len();
    for w in [
        0x4654_6C67u32,
        2,
        total as u32,
        json.len() as u32,
        0x4E4F_534A,
    ] {
        glb.extend_from_slice(&w.to_le_bytes());
    }
    glb.extend_from_slice(json.as_bytes());
    for w in [b.bin.len() as u32, 0x004E_4942] {
        glb.extend_from_slice(&w.to_le_bytes());
    }
    glb.extend_from_slice(&b.bin);
    let path = dir.join("materials.glb");
    std::fs::write(&path, glb).expect("write");
    path
}

fn pose() -> CameraPose {
    CameraPose {
        eye: Vec3::new(0.0, 0.0, 5.0),
        target: Vec3::ZERO,
    }
}

/// Renders `scene` with vfc; returns the pixels and the ID pass's pixels per object.
fn render(scene: &Scene) -> (Vec<u8>, Vec<u32>) {
    let (ctx, log) = common::context();
    let out = {
        let bvh = common::bvh_of(scene);
        let mut r = Renderer::new(&ctx, scene, W, H).expect("renderer");
        let mut vfc = culling::create("vfc", &Default::default()).expect("vfc");
        let (res, px) = common::frame(&mut r, vfc.as_mut(), &bvh, pose(), 0);
        assert!(res.counts.texture_binds >= 1, "{:?}", res.counts);
        let cam = r.camera(pose(), &bvh);
        let mut ids = Vec::new();
        r.object_pixels(&bvh, &cam, &mut ids).expect("ids");
        (px, ids)
    };
    drop(ctx);
    common::assert_silent(&log);
    out
}

fn px(pixels: &[u8], x: u32, y: u32) -> [u8; 4] {
    let i = ((y * W + x) * 4) as usize;
    [pixels[i], pixels[i + 1], pixels[i + 2], pixels[i + 3]]
}

fn is_red(p: [u8; 4]) -> bool {
    p[0] > 100 && p[1] < 40 && p[2] < 40
}

fn is_wall(p: [u8; 4]) -> bool {
    p[0] < 40 && p[2] > 100
}

/// Dark/grey transitions along row `y` of the left half (the checker quads).
fn checker_transitions(pixels: &[u8], y: u32) -> usize {
    let mut last = None;
    let mut n = 0;
    for x in 0..W / 2 {
        let p = px(pixels, x, y);
        let state = if p[..3].iter().all(|&c| c < 40) {
            Some(false)
        } else if p[..3].iter().all(|&c| c > 100) && p[0].abs_diff(p[2]) < 10 {
            Some(true)
        } else {
            None
        };
        if let Some(s) = state {
            if last.is_some_and(|l| l != s) {
                n += 1;
            }
            last = Some(s);
        }
    }
    n
}

#[test]
fn textures_masks_and_vertex_colors_render_as_authored() {
    let dir = temp_dir("render");
    let path = write_gltf(&dir);
    let (scene, warnings) = coherent::scene::gltf::load_gltf(&path).expect("load");
    assert!(warnings.is_empty(), "{warnings:?}");
    assert_eq!(scene.images.len(), 2);
    assert_eq!(scene.textures.len(), 3);
    assert!(scene.has_materials());
    let (pixels, ids) = render(&scene);

    // The checker: REPEAT over u in 0..2 shows 16 cells along a row (15 transitions),
    // CLAMP_TO_EDGE shows 8 and then its edge texel (7).
    let upper = checker_transitions(&pixels, H / 2 - H / 8);
    let lower = checker_transitions(&pixels, H / 2 + H / 8);
    assert!((13..=17).contains(&upper), "repeat: {upper} transitions");
    assert!((5..=9).contains(&lower), "clamp: {lower} transitions");

    // Vertex colors: the wall is blue at its left, cyan at its right.
    let left = px(&pixels, 2, H / 2).map(u32::from);
    let right = px(&pixels, W - 3, H / 2).map(u32::from);
    assert!(left[2] > 100 && left[2] > 2 * left[1], "left {left:?}");
    assert!(
        right[2] > 100 && right[1] * 5 > right[2] * 4,
        "right {right:?}"
    );

    // The masked quad: only its right half is drawn; its left half shows the wall. With the
    // mask off, the whole quad is red.
    let mut opaque = scene.clone();
    for m in &mut opaque.materials {
        m.alpha = AlphaMode::Opaque;
    }
    let (opaque_pixels, opaque_ids) = render(&opaque);
    let count = |p: &[u8], f: fn([u8; 4]) -> bool| {
        p.chunks_exact(4)
            .filter(|c| f([c[0], c[1], c[2], c[3]]))
            .count()
    };
    let (red, red_opaque) = (count(&pixels, is_red), count(&opaque_pixels, is_red));
    assert!(red > 100, "{red} red pixels");
    let half = red as f64 / red_opaque as f64;
    assert!(
        (0.4..0.6).contains(&half),
        "masked/opaque red {red}/{red_opaque}"
    );
    let mut behind = 0;
    for (a, b) in pixels.chunks_exact(4).zip(opaque_pixels.chunks_exact(4)) {
        let (a, b) = ([a[0], a[1], a[2], a[3]], [b[0], b[1], b[2], b[3]]);
        if is_red(b) && !is_red(a) {
            assert!(is_wall(a), "a masked pixel shows {a:?}, not the wall");
            behind += 1;
        }
    }
    assert!(behind > 100, "{behind}");

    // The ID pass respects the mask: the quad (object 3) owns exactly its drawn pixels, and
    // the wall (object 0) owns those it shows through the holes.
    assert_eq!(ids[3] as usize, red, "masked quad ID pixels");
    assert_eq!(opaque_ids[3] as usize, red_opaque, "opaque quad ID pixels");
    assert_eq!(
        ids[0] as usize,
        opaque_ids[0] as usize + behind,
        "wall ID pixels"
    );
}

/// Blended quads in front of a wall and of an opaque red quad: material 0 the wall (white), 1
/// the red quad, 2 and 3 BLEND at alpha one half (white, then green nearer the eye). Objects:
/// 0 wall, 1 red quad, 2 white glass, 3 green glass.
fn write_blended(dir: &Path) -> PathBuf {
    let mut b = GltfBuilder {
        materials: vec![
            r#"{"pbrMetallicRoughness":{"baseColorFactor":[0.2,0.3,1,1]}}"#.to_string(),
            r#"{"pbrMetallicRoughness":{"baseColorFactor":[1,0,0,1]}}"#.to_string(),
            r#"{"pbrMetallicRoughness":{"baseColorFactor":[1,1,1,0.5]},"alphaMode":"BLEND"}"#
                .to_string(),
            r#"{"pbrMetallicRoughness":{"baseColorFactor":[0,1,0,0.5]},"alphaMode":"BLEND"}"#
                .to_string(),
        ],
        ..GltfBuilder::default()
    };
    let wall = quad(&mut b, (-6.0, -4.0, 6.0, 4.0, -1.0), 1.0, None, 0);
    let red = quad(&mut b, (-1.5, -0.5, -0.5, 0.5, -0.5), 1.0, None, 1);
    let white = quad(&mut b, (-2.0, -1.0, 1.0, 1.0, 0.5), 1.0, None, 2);
    let green = quad(&mut b, (0.0, -1.0, 2.0, 1.0, 1.0), 1.0, None, 3);
    for m in [wall, red, white, green] {
        b.node(m, [0.0, 0.0, 0.0]);
    }
    let uri = format!("data:application/octet-stream;base64,{}", base64(&b.bin));
    let path = dir.join("blended.gltf");
    std::fs::write(&path, b.json(Some(&uri))).expect("write");
    path
}

/// Pixel (x, y) of the image at the world point `p` on the plane the camera of [`pose`] looks
/// at (found by projecting it).
fn pixel_of(r: &Renderer, bvh: &coherent::bvh::ObjectBvh, p: Vec3) -> (u32, u32) {
    let cam = r.camera(pose(), bvh);
    let ndc = cam.view_proj().project_point3(p);
    let x = ((ndc.x * 0.5 + 0.5) * W as f32) as u32;
    let y = ((ndc.y * 0.5 + 0.5) * H as f32) as u32;
    (x.min(W - 1), y.min(H - 1))
}

/// glTF BLEND is blended: the two glass quads are drawn over the wall and over the red quad,
/// farthest first, hide nothing (the red quad behind the glass is drawn and owns its pixels in
/// the ID pass), and stay out of the culling hierarchy. Every algorithm's image equals vfc's.
/// Drawn alpha-tested at 0.5 (as before), the white glass hid the red quad.
#[test]
fn blend_materials_are_blended_back_to_front_and_hide_nothing() {
    let dir = temp_dir("blend");
    let (scene, warnings) =
        coherent::scene::gltf::load_gltf(&write_blended(&dir)).expect("blended");
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    assert!(
        warnings[0].starts_with("materials 2 and 3: alpha mode BLEND, blended after the opaque"),
        "{warnings:?}"
    );
    let blended: Vec<bool> = (0..4).map(|o| scene.is_blended(o)).collect();
    assert_eq!(blended, [false, false, true, true]);
    assert!(matches!(
        scene.object_material(2).map(|m| m.alpha),
        Some(AlphaMode::Mask(_))
    ));
    let bvh = common::bvh_of(&scene);
    assert_eq!(
        bvh.live_objects(),
        2,
        "the blended quads are not in the hierarchy"
    );

    let (ctx, log) = common::context();
    {
        let mut r = Renderer::new(&ctx, &scene, W, H).expect("renderer");
        let mut vfc = culling::create("vfc", &Default::default()).expect("vfc");
        let (res, reference) = common::frame(&mut r, vfc.as_mut(), &bvh, pose(), 0);
        assert_eq!(res.counts.draw_calls, 4, "{:?}", res.counts);
        let at = |p: Vec3| {
            let (x, y) = pixel_of(&r, &bvh, p);
            px(&reference, x, y)
        };
        let wall = at(Vec3::new(-4.0, 2.5, -1.0));
        let red_behind_white = at(Vec3::new(-1.0, 0.0, -0.5));
        let white_over_wall = at(Vec3::new(-1.8, 0.8, 0.5));
        let green_over_wall = at(Vec3::new(1.6, 0.8, 1.0));
        let green_over_white = at(Vec3::new(0.5, 0.8, 1.0));
        // The red quad shows through the white glass: half red, half white.
        let [r0, g0, b0, _] = red_behind_white;
        assert!(
            r0 >= g0.saturating_add(50) && g0 >= 40 && (g0 as i32 - b0 as i32).abs() < 8,
            "red behind white glass: {red_behind_white:?}"
        );
        // Blending is linear in the stored values: the glass colours come out of the pixels
        // over the wall, and the green glass, nearer, is blended last.
        let f = |c: [u8; 4]| c.map(f32::from);
        let (w, a, g) = (f(wall), f(white_over_wall), f(green_over_wall));
        let want: Vec<f32> = (0..3)
            .map(|i| 0.5 * (2.0 * g[i] - w[i]) + 0.5 * a[i])
            .collect();
        let wrong: Vec<f32> = (0..3)
            .map(|i| 0.5 * (2.0 * a[i] - w[i]) + 0.5 * g[i])
            .collect();
        let got = f(green_over_white);
        for i in 0..3 {
            assert!(
                (got[i] - want[i]).abs() <= 3.0,
                "green over white over wall {green_over_white:?}: want {want:?} (the other order \
                 gives {wrong:?})"
            );
        }
        // The ID pass sees the red quad (the glass hides nothing) and no glass.
        let cam = r.camera(pose(), &bvh);
        let mut ids = Vec::new();
        r.object_pixels(&bvh, &cam, &mut ids).expect("ids");
        assert!(ids[1] > 0 && ids[2] == 0 && ids[3] == 0, "ID pass: {ids:?}");

        // NOHC with queries cheap against rendering: it queries the red quad.
        let setup = common::setup(common::triangles(&scene), (W, H), 1e-4);
        for name in ["chc", "chcpp", "nohc", "oracle", "chcpp@predicated"] {
            let mut c = culling::create_named(name, &setup).expect(name);
            for f in 0..3 {
                let (res, pixels) = common::frame(&mut r, c.as_mut(), &bvh, pose(), f);
                let d = common::diff_pixels(&reference, &pixels);
                assert_eq!(d, 0, "{name} frame {f}: {d} pixels differ from vfc");
                assert!(res.counts.draw_calls >= 3, "{name}: {:?}", res.counts);
            }
        }
        let mut hiz = HizCuller::new(&r, HizParams::default()).expect("hiz");
        for f in 0..2 {
            let cam = r.camera(pose(), &bvh);
            hiz.render_frame(&mut r, &cam).expect("hiz frame");
            let pixels = r.read_color().expect("read");
            let d = common::diff_pixels(&reference, &pixels);
            assert_eq!(d, 0, "hiz frame {f}: {d} pixels differ from vfc");
        }
    }
    drop(ctx);
    common::assert_silent(&log);
}

/// Blended quads (BLEND, white, alpha one half): ten behind an opaque wall on the left, six
/// in view on the right; and a blended cube around the eye (its box holds the eye; from inside
/// only back faces, so it draws nothing).
fn write_many_blended(dir: &Path) -> PathBuf {
    let mut b = GltfBuilder {
        materials: vec![
            r#"{"pbrMetallicRoughness":{"baseColorFactor":[0.2,0.3,1,1]}}"#.to_string(),
            r#"{"pbrMetallicRoughness":{"baseColorFactor":[1,1,1,0.5]},"alphaMode":"BLEND"}"#
                .to_string(),
        ],
        ..GltfBuilder::default()
    };
    let wall = quad(&mut b, (-6.0, -4.0, 0.0, 4.0, 0.0), 1.0, None, 0);
    b.node(wall, [0.0, 0.0, 0.0]);
    for i in 0..16 {
        let x = if i < 10 {
            -3.5 + 0.3 * i as f32
        } else {
            0.3 + 0.35 * (i - 10) as f32
        };
        let glass = quad(&mut b, (x, -1.0, x + 0.25, 1.0, -1.0), 1.0, None, 1);
        b.node(glass, [0.0, 0.0, 0.0]);
    }
    let cube = b.cube_mesh([1.0, 1.0, 1.0, 0.5]);
    b.materials[2] = b.materials[2].replacen('{', r#"{"alphaMode":"BLEND","#, 1);
    b.node(cube, [0.0, 0.0, 5.0]);
    let uri = format!("data:application/octet-stream;base64,{}", base64(&b.bin));
    let path = dir.join("many_blended.gltf");
    std::fs::write(&path, b.json(Some(&uri))).expect("write");
    path
}

/// With `Renderer::set_blended_tests(0, 0)` every blended object in view has its box
/// queried against the opaque depth and the object drawn under its predicate: the ten behind
/// the wall are skipped by their predicates, the image is the one drawn without the test, and
/// the cube whose box holds the eye is drawn without a query.
#[test]
fn many_blended_objects_are_tested_against_the_opaque_depth() {
    let dir = temp_dir("many-blended");
    let (scene, _) = coherent::scene::gltf::load_gltf(&write_many_blended(&dir)).expect("load");
    assert_eq!(scene.objects.len(), 18);
    assert_eq!((1..18).filter(|&o| scene.is_blended(o)).count(), 17);
    let bvh = common::bvh_of(&scene);
    let (ctx, log) = common::context();
    {
        let setup = culling::CullerSetup::default();
        for name in ["vfc", "chcpp", "chcpp@predicated"] {
            let mut r = Renderer::new(&ctx, &scene, W, H).expect("renderer");
            // Two cullers with the same history, one frame each: all drawn, then tested.
            let off_then_on = |r: &mut Renderer| {
                let mut c = culling::create_named(name, &setup).expect(name);
                r.set_blended_tests(0, u64::MAX);
                let (all, reference) = common::frame(r, c.as_mut(), &bvh, pose(), 0);
                let mut c = culling::create_named(name, &setup).expect(name);
                r.set_blended_tests(0, 0);
                let (tested, pixels) = common::frame(r, c.as_mut(), &bvh, pose(), 0);
                (all, reference, tested, pixels)
            };
            let (all, reference, tested, pixels) = off_then_on(&mut r);
            let d = common::diff_pixels(&reference, &pixels);
            assert_eq!(
                d, 0,
                "{name}: {d} pixels differ with the blended objects tested"
            );
            let (a, t) = (&all.counts, &tested.counts);
            assert_eq!(
                (
                    t.conditional_blocks - a.conditional_blocks,
                    t.predicated_objects_taken - a.predicated_objects_taken,
                    t.queries_begun - a.queries_begun,
                ),
                (16, 6, 16),
                "{name}: {a:?} against {t:?}"
            );
            assert!(t.predicate_resolves > a.predicate_resolves, "{name}: {t:?}");
            assert_eq!(t.object_draws, a.object_draws, "{name}");
            // The next frames test the ten found hidden, and the six found visible only when
            // their turn to be tested again comes: fewer queries, the same image.
            let mut blended_queries = Vec::new();
            for f in 1..=8 {
                let (all, _, t, px) = off_then_on(&mut r);
                assert_eq!(common::diff_pixels(&reference, &px), 0, "{name} frame {f}");
                blended_queries.push(t.counts.queries_begun - all.counts.queries_begun);
            }
            assert!(
                blended_queries.iter().all(|&q| (10..16).contains(&q)),
                "{name}: blended queries a frame {blended_queries:?}"
            );
            assert!(
                blended_queries.iter().sum::<u32>() >= 8 * 10 + 6,
                "{name}: the visible ones are tested again: {blended_queries:?}"
            );
        }
        // hiz tests them inside its phase 2's rendering: the same image, and 16 queries in
        // its first frame on a fresh renderer.
        let mut r = Renderer::new(&ctx, &scene, W, H).expect("renderer");
        let mut vfc = culling::create("vfc", &Default::default()).expect("vfc");
        r.set_blended_tests(0, u64::MAX);
        let (_, reference) = common::frame(&mut r, vfc.as_mut(), &bvh, pose(), 0);
        r.set_blended_tests(0, 0);
        let mut hiz = HizCuller::new(&r, HizParams::default()).expect("hiz");
        for f in 0..3 {
            let cam = r.camera(pose(), &bvh);
            let h = hiz.render_frame(&mut r, &cam).expect("hiz frame");
            let px = r.read_color().expect("read");
            let d = common::diff_pixels(&reference, &px);
            assert_eq!(d, 0, "hiz frame {f}: {d} pixels differ");
            if f == 0 {
                let c = &h.counts;
                assert_eq!(
                    (
                        c.queries_begun,
                        c.conditional_blocks,
                        c.predicated_objects_taken
                    ),
                    (16, 16, 6),
                    "hiz: {c:?}"
                );
            }
        }
    }
    drop(ctx);
    common::assert_silent(&log);
}

/// A BLEND material is blended where its texture has alpha under one (the mask), drawn
/// opaque where it has none (the checker).
#[test]
fn blend_materials_blend_only_where_their_texture_has_alpha() {
    let dir = temp_dir("blend-textures");
    let path = write_gltf(&dir);
    let json = std::fs::read_to_string(&path).expect("read");
    let checker = r#"{"pbrMetallicRoughness":{"baseColorTexture":{"index":0}}}"#;
    let mask = r#""alphaMode":"MASK","alphaCutoff":0.5"#;
    assert_eq!(
        (json.matches(checker).count(), json.matches(mask).count()),
        (1, 1)
    );
    let json = json.replace(mask, r#""alphaMode":"BLEND""#).replace(
        checker,
        &checker.replacen('{', r#"{"alphaMode":"BLEND","#, 1),
    );
    std::fs::write(&path, json).expect("write");
    let (scene, warnings) = coherent::scene::gltf::load_gltf(&path).expect("load");
    // Objects: wall, repeat checker (BLEND, opaque texels), clamp checker, masked quad.
    let blended: Vec<bool> = (0..4).map(|o| scene.is_blended(o)).collect();
    assert_eq!(blended, [false, false, false, true], "{warnings:?}");
    assert!(
        warnings
            .iter()
            .any(|w| w.starts_with("material 1: alpha mode BLEND with no alpha under one")),
        "{warnings:?}"
    );
}

/// One checker quad (REPEAT, nearest) whose texture coordinates reach u = `u1`, its material's
/// texture under `transform` (a KHR_texture_transform object, or none), as a .gltf in `dir`.
fn write_checker_quad(dir: &Path, name: &str, u1: f32, transform: Option<&str>) -> PathBuf {
    let used = if transform.is_some() {
        r#""extensionsUsed":["KHR_texture_transform"],"#
    } else {
        ""
    };
    let head = format!(
        r#"{used}"images":[{{"uri":"data:image/png;base64,{}"}}],"textures":[{{"source":0,"sampler":0}}],"#,
        base64(&checker_png())
    );
    write_quad(dir, name, u1, transform, &head)
}

/// A quad as [`write_checker_quad`] writes it, with `head` (the images, textures and extension
/// lists) in place of its checker PNG.
fn write_quad(dir: &Path, name: &str, u1: f32, transform: Option<&str>, head: &str) -> PathBuf {
    let mut b = GltfBuilder::default();
    let ext = transform
        .map(|t| format!(r#","extensions":{{"KHR_texture_transform":{t}}}"#))
        .unwrap_or_default();
    b.materials = vec![format!(
        r#"{{"pbrMetallicRoughness":{{"baseColorTexture":{{"index":0{ext}}}}}}}"#
    )];
    let q = quad(&mut b, (-2.0, -1.0, 2.0, 1.0, 0.0), u1, None, 0);
    b.node(q, [0.0, 0.0, 0.0]);
    let head = format!(r#"{head}"samplers":[{{"magFilter":9728,"minFilter":9728}}],"#);
    let uri = format!("data:application/octet-stream;base64,{}", base64(&b.bin));
    let json = b.json(Some(&uri)).replacen('{', &format!("{{{head}"), 1);
    let path = dir.join(name);
    std::fs::write(&path, json).expect("write");
    path
}

/// `EXT_texture_webp` (what `gltf-transform optimize --texture-compress webp` writes) and
/// `KHR_texture_basisu` (KTX2 Basis Universal, what `gltf-transform etc1s`/`uastc` and
/// `gltfpack -tc` write): a texture whose only image is a WebP or KTX2 one, the extension
/// required, draws as the same texture in PNG does. A KTX2 image that cannot be transcoded and
/// an AVIF-only texture leave the file loaded and drawn without them, with warnings that say so.
#[test]
fn webp_and_ktx2_textures_draw_as_png_ones() {
    let dir = temp_dir("webp");
    let rgba: Vec<u8> = (0..64)
        .flat_map(|i| {
            let c = if (i % 8 + i / 8) % 2 == 0 { 255 } else { 0 };
            [c, c, c, 255]
        })
        .collect();
    let mut webp = Vec::new();
    image::codecs::webp::WebPEncoder::new_lossless(&mut webp)
        .encode(&rgba, 8, 8, image::ExtendedColorType::Rgba8)
        .expect("webp");
    let plain = write_checker_quad(&dir, "png.gltf", 2.0, None);
    let only_image = |ext: &str, mime: &str, bytes: &[u8]| {
        format!(
            r#""extensionsUsed":["{ext}"],"extensionsRequired":["{ext}"],"images":[{{"uri":"data:{mime};base64,{}"}}],"textures":[{{"sampler":0,"extensions":{{"{ext}":{{"source":0}}}}}}],"#,
            base64(bytes)
        )
    };
    let (want, _) = coherent::scene::gltf::load_gltf(&plain).expect("png");
    let want_pixels = render(&want).0;
    // The same 8x8 checker as the PNG, encoded by the Basis Universal encoder (see
    // tests/gpu/data/README.md): ETC1S, and UASTC with zstd supercompression.
    for (name, ext, mime, bytes) in [
        ("webp", "EXT_texture_webp", "image/webp", webp.as_slice()),
        (
            "etc1s",
            "KHR_texture_basisu",
            "image/ktx2",
            include_bytes!("data/checker_etc1s.ktx2").as_slice(),
        ),
        (
            "uastc",
            "KHR_texture_basisu",
            "image/ktx2",
            include_bytes!("data/checker_uastc_zstd.ktx2").as_slice(),
        ),
    ] {
        let path = write_quad(
            &dir,
            &format!("{name}.gltf"),
            2.0,
            None,
            &only_image(ext, mime, bytes),
        );
        let (scene, warnings) = coherent::scene::gltf::load_gltf(&path).expect(name);
        assert!(warnings.is_empty(), "{name}: {warnings:?}");
        assert_eq!(
            scene.images, want.images,
            "{name}: the decoded texels differ"
        );
        let (pixels, _) = render(&scene);
        assert!(checker_transitions(&pixels, H / 2) >= 6, "{name}");
        assert!(pixels == want_pixels, "the {name} quad's pixels differ");
    }

    let ktx2_magic = [
        0xAB, b'K', b'T', b'X', b' ', b'2', b'0', 0xBB, b'\r', b'\n', 0x1A, b'\n',
    ];
    let head = only_image("KHR_texture_basisu", "image/ktx2", &ktx2_magic);
    let path = write_quad(&dir, "ktx2_cut.gltf", 2.0, None, &head);
    let (scene, warnings) = coherent::scene::gltf::load_gltf(&path).expect("cut ktx2");
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    assert!(
        warnings[0].starts_with("image 0: cannot transcode its KTX2 Basis data")
            && warnings[0].ends_with("; drawn without this texture"),
        "{warnings:?}"
    );
    assert!(scene.images.is_empty() && scene.textures.is_empty());
    assert_eq!(scene.objects.len(), 1);

    let head = only_image("EXT_texture_avif", "image/avif", b"not decoded");
    let path = write_quad(&dir, "avif.gltf", 2.0, None, &head);
    let (scene, warnings) = coherent::scene::gltf::load_gltf(&path).expect("avif only");
    assert_eq!(
        warnings,
        [
            "extension EXT_texture_avif is not supported, ignored",
            "texture 0: its only image is given by EXT_texture_avif, which is not supported; \
             drawn without it"
        ]
    );
    assert!(scene.images.is_empty() && scene.textures.is_empty());
    assert_eq!(scene.objects.len(), 1);
}

/// `KHR_materials_pbrSpecularGlossiness` (older files, often with a plain metallic-roughness
/// fallback): its diffuse texture and factor are the base color, so the quad draws the checker
/// as the metallic-roughness one does, not its red fallback.
#[test]
fn specular_glossiness_materials_draw_their_diffuse_texture() {
    let dir = temp_dir("specgloss");
    let plain = write_checker_quad(&dir, "plain.gltf", 2.0, None);
    let text = std::fs::read_to_string(&plain).expect("read");
    let metallic = r#"{"pbrMetallicRoughness":{"baseColorTexture":{"index":0}}}"#;
    assert!(text.contains(metallic));
    let text = text.replacen(
        metallic,
        r#"{"pbrMetallicRoughness":{"baseColorFactor":[1,0,0,1]},"extensions":{"KHR_materials_pbrSpecularGlossiness":{"diffuseTexture":{"index":0},"diffuseFactor":[1,1,1,1],"glossinessFactor":0.5}}}"#,
        1,
    );
    let text = text.replacen(
        '{',
        r#"{"extensionsUsed":["KHR_materials_pbrSpecularGlossiness"],"#,
        1,
    );
    let path = dir.join("specgloss.gltf");
    std::fs::write(&path, text).expect("write");
    let (want, _) = coherent::scene::gltf::load_gltf(&plain).expect("plain");
    let (scene, warnings) = coherent::scene::gltf::load_gltf(&path).expect("spec-gloss");
    assert!(warnings.is_empty(), "{warnings:?}");
    assert_eq!(scene.objects[0].color, want.objects[0].color);
    assert!(
        render(&scene).0 == render(&want).0,
        "the spec-gloss quad's pixels differ"
    );
}

/// KHR_texture_transform on the base color texture: texture coordinates to u = 1 scaled by 2
/// draw what coordinates to u = 2 draw (16 checker cells across), with no warning; gltfpack
/// writes such a transform for every textured material it quantizes.
#[test]
fn texture_transforms_scale_the_coordinates() {
    let dir = temp_dir("transform");
    let plain = write_checker_quad(&dir, "plain.gltf", 2.0, None);
    let scaled = write_checker_quad(&dir, "scaled.gltf", 1.0, Some(r#"{"scale":[2,1]}"#));
    let (want, _) = coherent::scene::gltf::load_gltf(&plain).expect("plain");
    let (scene, warnings) = coherent::scene::gltf::load_gltf(&scaled).expect("scaled");
    assert!(warnings.is_empty(), "{warnings:?}");
    assert_eq!(scene.attributes, want.attributes);
    let (pixels, _) = render(&scene);
    let (want_pixels, _) = render(&want);
    // The left half of the image holds the quad's left half: 8 cells (4 untransformed).
    let cells = checker_transitions(&pixels, H / 2);
    assert!((6..=9).contains(&cells), "{cells} transitions");
    assert!(
        pixels == want_pixels,
        "the transformed quad's pixels differ"
    );
}

#[test]
fn glb_views_jpeg_and_unsupported_images() {
    let dir = temp_dir("glb");
    // PNG in buffer views: the same images as the .gltf's data URI and file.
    let gltf = coherent::scene::gltf::load_gltf(&write_gltf(&dir))
        .expect("gltf")
        .0;
    let glb = coherent::scene::gltf::load_gltf(&write_glb(&dir, &checker_png(), "image/png"))
        .expect("glb")
        .0;
    assert_eq!(gltf.images, glb.images);
    assert_eq!(gltf.attributes, glb.attributes);

    // JPEG decodes (lossy: the size and the mean are checked).
    let img = image::RgbImage::from_fn(8, 8, |x, y| {
        let c = if (x + y) % 2 == 0 { 255 } else { 0 };
        image::Rgb([c, c, c])
    });
    let mut jpeg = std::io::Cursor::new(Vec::new());
    img.write_to(&mut jpeg, image::ImageFormat::Jpeg)
        .expect("jpeg");
    let (scene, warnings) =
        coherent::scene::gltf::load_gltf(&write_glb(&dir, &jpeg.into_inner(), "image/jpeg"))
            .expect("jpeg glb");
    assert!(warnings.is_empty(), "{warnings:?}");
    assert_eq!((scene.images[0].width, scene.images[0].height), (8, 8));

    // A KTX2 Basis image in a buffer view decodes to the PNG's texels; one cut after its
    // identifier is one warning naming the image, the material drawn untextured.
    let path = write_glb(
        &dir,
        include_bytes!("data/checker_etc1s.ktx2"),
        "image/ktx2",
    );
    let (basis, warnings) = coherent::scene::gltf::load_gltf(&path).expect("ktx2 glb");
    assert!(warnings.is_empty(), "{warnings:?}");
    assert_eq!(basis.images, glb.images);
    let ktx2 = [
        0xAB, b'K', b'T', b'X', b' ', b'2', b'0', 0xBB, b'\r', b'\n', 0x1A, b'\n',
    ];
    let path = write_glb(&dir, &ktx2, "image/ktx2");
    let (scene, warnings) = coherent::scene::gltf::load_gltf(&path).expect("cut ktx2 glb");
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    assert!(
        warnings[0].contains("image 0") && warnings[0].contains("cannot transcode its KTX2"),
        "{warnings:?}"
    );
    assert_eq!(scene.images.len(), 1);

    // Bytes that are not the PNG their view declares: a warning that says so.
    let (_, warnings) = coherent::scene::gltf::load_gltf(&write_glb(&dir, b"ERR", "image/png"))
        .expect("broken png glb");
    assert_eq!(
        warnings,
        ["image 0: its 3 bytes are not the PNG image it declares; drawn without this texture"]
    );
    let (pixels, _) = render(&scene);
    assert!(pixels
        .chunks_exact(4)
        .any(|p| is_red([p[0], p[1], p[2], p[3]])));
}

/// Two quads facing +Z: object 0 red and `doubleSided`, object 1 green and single-sided
/// (the glTF default), side by side.
fn two_sided_scene() -> Scene {
    two_quads(
        "two_sided",
        [
            r#"{"pbrMetallicRoughness":{"baseColorFactor":[1,0,0,1]},"doubleSided":true}"#
                .to_string(),
            r#"{"pbrMetallicRoughness":{"baseColorFactor":[0,1,0,1]}}"#.to_string(),
        ],
        "",
    )
}

/// Two 1.8 x 2 quads facing +Z side by side, left of x = 0 with material 0 and right of it
/// with material 1 (JSON objects), with `head` (say, `extensionsUsed`) in the document,
/// written as `name.gltf` and loaded without a warning.
fn two_quads(name: &str, materials: [String; 2], head: &str) -> Scene {
    let mut b = GltfBuilder {
        materials: materials.to_vec(),
        head: head.to_string(),
        ..Default::default()
    };
    let left = quad(&mut b, (-2.0, -1.0, -0.2, 1.0, 0.0), 1.0, None, 0);
    let right = quad(&mut b, (0.2, -1.0, 2.0, 1.0, 0.0), 1.0, None, 1);
    for m in [left, right] {
        b.node(m, [0.0, 0.0, 0.0]);
    }
    let dir = temp_dir(name);
    let path = dir.join(format!("{name}.gltf"));
    std::fs::write(&path, b.gltf_embedded()).expect("write");
    let (scene, warnings) = coherent::scene::gltf::load_gltf(&path).expect("load");
    assert!(warnings.is_empty(), "{warnings:?}");
    scene
}

/// Renders `scene` with vfc from `eye` (looking at the origin); returns the pixels, the ID
/// pass's pixels per object and the frame's pipeline binds.
fn render_from(scene: &Scene, eye: Vec3) -> (Vec<u8>, Vec<u32>, u32) {
    let (ctx, log) = common::context();
    let pose = CameraPose {
        eye,
        target: Vec3::ZERO,
    };
    let out = {
        let bvh = common::bvh_of(scene);
        let mut r = Renderer::new(&ctx, scene, W, H).expect("renderer");
        let mut vfc = culling::create("vfc", &Default::default()).expect("vfc");
        let (res, px) = common::frame(&mut r, vfc.as_mut(), &bvh, pose, 0);
        let cam = r.camera(pose, &bvh);
        let mut ids = Vec::new();
        r.object_pixels(&bvh, &cam, &mut ids).expect("ids");
        (px, ids, res.counts.pipeline_binds)
    };
    drop(ctx);
    common::assert_silent(&log);
    out
}

/// `KHR_materials_unlit` (lighting baked into the colors, as exporters of scanned and baked
/// levels write it): the unlit quad shows its base color as it is (gamma 2.2) whatever the
/// light, the lit one beside it with the same color changes with the light; the extension
/// gets no warning.
#[test]
fn unlit_materials_draw_their_color_without_the_light() {
    let color = r#""baseColorFactor":[0.5,0.25,0.1,1]"#;
    let mut scene = two_quads(
        "unlit",
        [
            format!(r#"{{"pbrMetallicRoughness":{{{color}}}}}"#),
            format!(
                r#"{{"pbrMetallicRoughness":{{{color}}},"extensions":{{"KHR_materials_unlit":{{}}}}}}"#
            ),
        ],
        r#""extensionsUsed":["KHR_materials_unlit"],"#,
    );
    assert!(!scene.is_unlit(0) && scene.is_unlit(1));
    let want = [0.5f32, 0.25, 0.1].map(|c| (c.powf(1.0 / 2.2) * 255.0).round() as i32);
    let eye = Vec3::new(0.0, 0.0, 5.0);
    let mut lit_pixels = Vec::new();
    for sun in [Vec3::new(0.0, 0.3, 1.0), Vec3::new(0.9, 0.3, -0.2)] {
        scene.sun_dir = sun.normalize();
        let (px_, ids, _) = render_from(&scene, eye);
        assert!(ids[0] > 1000 && ids[1] > 1000, "{ids:?}");
        let p = px(&px_, W * 3 / 4, H / 2);
        for k in 0..3 {
            assert!(
                (i32::from(p[k]) - want[k]).abs() <= 1,
                "unlit pixel {p:?}, want {want:?} (sun {sun})"
            );
        }
        lit_pixels.push(px(&px_, W / 4, H / 2));
    }
    assert_ne!(
        lit_pixels[0], lit_pixels[1],
        "the lit quad does not follow the light"
    );
}

#[test]
fn double_sided_quads_are_seen_from_behind() {
    let scene = two_sided_scene();
    assert!(scene.materials.iter().any(|m| m.double_sided));
    let dominant = |p: [u8; 4], c: usize| {
        let p = p.map(u32::from);
        p[c] > 60 && (0..3).all(|k| k == c || p[c] > 2 * p[k])
    };
    let is_green = |p: [u8; 4]| dominant(p, 1);
    let is_red = |p: [u8; 4]| dominant(p, 0);
    let count = |px: &[u8], f: &dyn Fn([u8; 4]) -> bool| {
        px.chunks_exact(4)
            .filter(|c| f([c[0], c[1], c[2], c[3]]))
            .count()
    };
    // From the front both quads are drawn.
    let (front, front_ids, _) = render_from(&scene, Vec3::new(0.0, 0.0, 5.0));
    let (red, green) = (count(&front, &is_red), count(&front, &is_green));
    assert!(
        red > 1000 && green > 1000,
        "front: red {red}, green {green}"
    );
    assert_eq!(front_ids[1] as usize, green, "ID pixels of the green quad");
    // From behind only the double-sided one, with the same pixels in the ID pass; the
    // switch between the two-sided and the culling pipeline is a counted bind.
    let (back, back_ids, binds) = render_from(&scene, Vec3::new(0.0, 0.0, -5.0));
    let (red, green) = (count(&back, &is_red), count(&back, &is_green));
    assert!(red > 1000, "behind: red {red}");
    assert_eq!(green, 0, "behind: the single-sided quad is drawn");
    assert_eq!(
        back_ids[0] as usize, red,
        "ID pixels of the double-sided quad"
    );
    assert_eq!(back_ids[1], 0, "ID pixels of the culled quad");
    assert!(binds >= 2, "{binds} pipeline binds");
    // Without doubleSided, both are culled from behind.
    let mut single = scene.clone();
    for m in &mut single.materials {
        m.double_sided = false;
    }
    let (back, back_ids, _) = render_from(&single, Vec3::new(0.0, 0.0, -5.0));
    assert_eq!(
        count(&back, &is_red),
        0,
        "single-sided red drawn from behind"
    );
    assert_eq!(back_ids[0], 0);
}

#[test]
fn hiz_draws_textures_masks_and_two_sided_faces_as_vfc_does() {
    // Hi-Z's indirect draws bind what each object binds in the forward pass, one draw per
    // group of objects that bind the same: its images equal vfc's, and the masked quad's holes
    // show the wall behind it (they are holes in the depth it culls against, too).
    let dir = temp_dir("hiz-materials");
    let path = write_glb(&dir, &checker_png(), "image/png");
    let (textured, _) = coherent::scene::gltf::load_gltf(&path).expect("load");
    let views = [
        (
            "materials",
            textured,
            [Vec3::new(0.0, 0.0, 5.0), Vec3::new(1.5, 0.5, 4.0)],
        ),
        (
            "two-sided",
            two_sided_scene(),
            [Vec3::new(0.0, 0.0, 5.0), Vec3::new(0.5, 0.0, -5.0)],
        ),
    ];
    for (name, scene, eyes) in views {
        let (ctx, log) = common::context();
        {
            let bvh = common::bvh_of(&scene);
            let mut r = Renderer::new(&ctx, &scene, W, H).expect("renderer");
            let mut vfc = culling::create("vfc", &Default::default()).expect("vfc");
            let mut hiz = HizCuller::new(&r, HizParams::default()).expect("hiz");
            for (f, eye) in eyes.into_iter().enumerate() {
                let pose = CameraPose {
                    eye,
                    target: Vec3::ZERO,
                };
                // Twice: the second frame draws the first's visible objects in phase 1.
                for _ in 0..2 {
                    let (_, reference) = common::frame(&mut r, vfc.as_mut(), &bvh, pose, f as u64);
                    let cam = r.camera(pose, &bvh);
                    let h = hiz.render_frame(&mut r, &cam).expect("hiz frame");
                    let px = r.read_color().expect("read");
                    let d = common::diff_pixels(&reference, &px);
                    assert_eq!(
                        d, 0,
                        "{name} from {eye}: hiz differs from vfc in {d} pixels"
                    );
                    assert!(h.counts.texture_binds >= 1 || name == "two-sided");
                }
            }
        }
        drop(ctx);
        common::assert_silent(&log);
    }
}
