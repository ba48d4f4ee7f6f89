//! Base color textures in the GI's G-buffer, under validation: a glTF written here with a
//! spotlight above a floor whose texture is a red and blue checker. The image shows the
//! checker's cells in their own colors (each triangle's one albedo, the control, shows the
//! same purple everywhere), and a checker of single texels far finer than the pixels reads its
//! coarser levels: purple, not red and blue noise.

use crate::common;

use coherent::gi::geometry::WorldGeometry;
use coherent::gi::light::Spotlight;
use coherent::gi::textures::TriangleTextures;
use coherent::gi::vpl::VplSet;
use coherent::scene::camera::Camera;
use coherent::scene::gltf::testdata::GltfBuilder;
use coherent::scene::{CameraPose, Scene};
use glam::Vec3;

const W: u32 = 320;
const H: u32 = 240;

/// A `cells` x `cells` checker: red where `(i + j)` is even, blue elsewhere.
fn checker_png(cells: u32) -> Vec<u8> {
    let rgba = (0..cells * cells)
        .flat_map(|k| match (k % cells + k / cells) % 2 {
            0 => [255, 0, 0, 255],
            _ => [0, 0, 255, 255],
        })
        .collect();
    common::png(cells, cells, rgba)
}

/// Nearest magnification, trilinear minification, clamped.
const CLAMPED: &str = r#"{"magFilter":9728,"minFilter":9987,"wrapS":33071,"wrapT":33071}"#;

/// A 4 x 4 floor (x, z in -2..2) at height 0 with the checker of `cells` texels a side (u along
/// x, v along z; nearest magnification, trilinear minification, clamped), loaded.
fn floor_scene(test: &str, cells: u32) -> Scene {
    floor_with(test, &checker_png(cells), CLAMPED)
}

/// The floor of [`floor_scene`] with the texture `png` and the glTF sampler `sampler`.
fn floor_with(test: &str, png: &[u8], sampler: &str) -> Scene {
    let dir = std::env::temp_dir().join(format!(
        "coherent-gi-textures-{}-{test}",
        std::process::id()
    ));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let mut b = GltfBuilder {
        materials: vec![r#"{"pbrMetallicRoughness":{"baseColorTexture":{"index":0}}}"#.into()],
        ..Default::default()
    };
    let floor = crate::materials_gi::quad(&mut b, (-2.0, -2.0, 2.0, 2.0, 0.0), 0);
    b.node(floor, [0.0, 0.0, 0.0]);
    let images = format!(
        r#""images":[{{"uri":"data:image/png;base64,{}"}}],"samplers":[{sampler}],"textures":[{{"source":0,"sampler":0}}],"#,
        coherent::scene::gltf::testdata::base64(png)
    );
    let uri = format!(
        "data:application/octet-stream;base64,{}",
        coherent::scene::gltf::testdata::base64(&b.bin)
    );
    let json = b.json(Some(&uri)).replacen('{', &format!("{{{images}"), 1);
    let path = dir.join("floor.gltf");
    std::fs::write(&path, json).expect("write");
    let (scene, warnings) = coherent::scene::gltf::load_gltf(&path).expect("load");
    std::fs::remove_dir_all(&dir).ok();
    assert!(warnings.is_empty(), "{warnings:?}");
    scene
}

fn camera() -> Camera {
    Camera::from_pose(
        CameraPose {
            eye: Vec3::new(0.0, 6.0, 1.0),
            target: Vec3::ZERO,
        },
        W as f32 / H as f32,
        40.0,
    )
}

/// The spotlight's direct light on `geometry` from [`camera`], as RGBA8.
fn direct_light(geometry: &WorldGeometry) -> Vec<u8> {
    let (ctx, log) = common::context();
    let out = {
        let rays = geometry.ray_scene();
        let mut renderer = crate::materials_gi::direct_only_renderer(&ctx, geometry, (W, H));
        let light = Spotlight::new(Vec3::new(0.0, 4.0, 0.0), Vec3::NEG_Y, Vec3::splat(200.0));
        let mut set = VplSet::new(16, 16);
        let stats = set.recompute_all(&light, &rays);
        renderer
            .frame(&light, set.vpls(), &stats.new_layers, &camera())
            .expect("frame");
        renderer.read_output().expect("readback")
    };
    drop(ctx);
    common::assert_silent(&log);
    out
}

/// Red and blue of pixel (x, y).
fn red_blue(px: &[u8], (x, y): (i32, i32)) -> (i32, i32) {
    let i = ((y as u32 * W + x as u32) * 4) as usize;
    (i32::from(px[i]), i32::from(px[i + 2]))
}

/// The pixel of floor point (x, z), if on screen.
fn pixel(x: f32, z: f32) -> Option<(i32, i32)> {
    let ndc = camera().view_proj().project_point3(Vec3::new(x, 0.0, z));
    let px = ((ndc.x * 0.5 + 0.5) * W as f32) as i32;
    let py = ((0.5 - 0.5 * ndc.y) * H as f32) as i32;
    (px >= 0 && py >= 0 && px < W as i32 && py < H as i32).then_some((px, py))
}

/// Each cell of a 4 x 4 checker seen at its centre: its own color where the G-buffer reads
/// the texture, and one purple for all where each triangle has one albedo.
#[test]
fn the_gbuffer_shows_the_texture_of_each_pixel() {
    let scene = floor_scene("cells", 4);
    let textured = WorldGeometry::from_scene(&scene);
    assert!(textured.textures.any());
    let flat = WorldGeometry {
        textures: TriangleTextures::default(),
        ..textured.clone()
    };
    let (with, without) = (direct_light(&textured), direct_light(&flat));
    let mut cells = 0;
    for i in 0..4 {
        for j in 0..4 {
            let centre = (-2.0 + i as f32 + 0.5, -2.0 + j as f32 + 0.5);
            let p = pixel(centre.0, centre.1).expect("cell on screen");
            let (r, b) = red_blue(&with, p);
            let red_cell = (i + j) % 2 == 0;
            let (own, other) = if red_cell { (r, b) } else { (b, r) };
            assert!(
                own > 40 && own > 4 * other.max(1),
                "cell ({i}, {j}) at {p:?}: red {r}, blue {b}"
            );
            // The control: both colors in every cell (the texture's mean over each triangle).
            let (r, b) = red_blue(&without, p);
            assert!(
                r > 20 && b > 20 && (r - b).abs() < 20,
                "control: cell ({i}, {j}) red {r}, blue {b}"
            );
            cells += 1;
        }
    }
    assert_eq!(cells, 16);
}

/// A checker of 512 single texels a side, two or more texels to a pixel: every pixel reads a
/// level whose texels average red and blue, as a mip-mapped sampler would.
#[test]
fn a_minified_texture_reads_its_coarser_levels() {
    let scene = floor_scene("fine", 512);
    let px = direct_light(&WorldGeometry::from_scene(&scene));
    let mut checked = 0;
    for k in 0..9 {
        let (x, z) = (-1.5 + 0.375 * k as f32, 0.3 - 0.2 * k as f32);
        let p = pixel(x, z).expect("on screen");
        let (r, b) = red_blue(&px, p);
        assert!(
            r > 20 && b > 20 && (r - b).abs() <= 12,
            "at ({x}, {z}) {p:?}: red {r}, blue {b}"
        );
        checked += 1;
    }
    assert_eq!(checked, 9);
}

/// A red and a blue texel side by side, magnified with the bilinear filter: with the sampler
/// repeating, the floor's edges at u = 0 and u = 1 mix the two (the texel beyond the edge is
/// the other end's), while clamped they keep their own; the texels' centres are their own
/// colors either way.
#[test]
fn bilinear_reads_wrap_at_the_edges_as_the_sampler_says() {
    let png = common::png(2, 1, vec![255, 0, 0, 255, 0, 0, 255, 255]);
    let linear = |wrap: u32| {
        let sampler =
            format!(r#"{{"magFilter":9729,"minFilter":9987,"wrapS":{wrap},"wrapT":{wrap}}}"#);
        let scene = floor_with(&format!("wrap{wrap}"), &png, &sampler);
        direct_light(&WorldGeometry::from_scene(&scene))
    };
    let (repeat, clamp) = (linear(10497), linear(33071));
    // u = (x + 2) / 4 along the floor; z = 0.5 keeps away from v's edges.
    let at = |px: &[u8], u: f32| red_blue(px, pixel(4.0 * u - 2.0, 0.5).expect("on screen"));
    for (u, red) in [(0.25, true), (0.75, false)] {
        for (name, px) in [("repeat", &repeat), ("clamp", &clamp)] {
            let (r, b) = at(px, u);
            let (own, other) = if red { (r, b) } else { (b, r) };
            assert!(
                own > 40 && own > 4 * other.max(1),
                "{name}: u = {u}: red {r}, blue {b}"
            );
        }
    }
    for u in [0.01, 0.99] {
        let (r, b) = at(&repeat, u);
        assert!(r > 20 && b > 20, "repeat: u = {u}: red {r}, blue {b}");
        let (r, b) = at(&clamp, u);
        let (own, other) = if u < 0.5 { (r, b) } else { (b, r) };
        assert!(own > 4 * other.max(1), "clamp: u = {u}: red {r}, blue {b}");
    }
}
