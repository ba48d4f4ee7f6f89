//! Alpha masks in the GI, under validation: a glTF written here with a spotlight above a
//! horizontal white quad whose texture is a checker of holes (alpha mode MASK), over a green
//! floor. The spotlight's shadow map (the same layered pipeline as the VPLs') lets light
//! through the holes only, the G-buffer shows the floor through them, the ray caster places
//! VPLs on the floor under the holes and none on the quad's holes, and the imperfect shadow
//! maps' points avoid the holes. The same file with the mask off is
//! the control: every check fails for it.

use crate::common;

use std::path::PathBuf;

use coherent::gi::geometry::WorldGeometry;
use coherent::gi::light::Spotlight;
use coherent::gi::vpl::VplSet;
use coherent::gi::{GiOptions, GiRenderer, OutputMode};
use coherent::scene::camera::Camera;
use coherent::scene::gltf::testdata::GltfBuilder;
use coherent::scene::{AlphaMode, CameraPose, Scene};
use glam::{Mat4, Vec3};

/// Height of the light and of the masked quad (x, z in -2..2); the floor is at 0.
const LIGHT_Y: f32 = 4.0;
const QUAD_Y: f32 = 2.0;
/// Texels along each side of the checker (one unit of the quad each).
const CELLS: u32 = 4;
const W: u32 = 320;
const H: u32 = 240;

/// Whether checker texel (i, j) (i along u = x, j along v = z) is a hole.
fn hole(i: i32, j: i32) -> bool {
    (i + j) % 2 != 0
}

/// 4x4 white checker whose odd texels are transparent.
fn holes_png() -> Vec<u8> {
    let n = CELLS as i32;
    let rgba = (0..n * n)
        .flat_map(|k| [255, 255, 255, if hole(k % n, k / n) { 0 } else { 255 }])
        .collect();
    common::png(CELLS, CELLS, rgba)
}

/// A horizontal quad at height `y` from (x0, z0) to (x1, z1), facing +Y, with texture
/// coordinates u = 0..1 along x and v = 0..1 along z; returns the mesh index.
pub(crate) fn quad(
    b: &mut GltfBuilder,
    (x0, z0, x1, z1, y): (f32, f32, f32, f32, f32),
    material: usize,
) -> usize {
    let pos = b.vec3(&[[x0, y, z0], [x0, y, z1], [x1, y, z1], [x1, y, z0]]);
    let nrm = b.vec3(&[[0.0, 1.0, 0.0]; 4]);
    let uv: Vec<u8> = [[0.0f32, 0.0], [0.0, 1.0], [1.0, 1.0], [1.0, 0.0]]
        .iter()
        .flatten()
        .flat_map(|f| f.to_le_bytes())
        .collect();
    let uv_view = b.view(&uv);
    let uv = b.accessor(uv_view, 5126, "VEC2", 4);
    let idx = b.indices_u16(&[0, 1, 2, 0, 2, 3]);
    b.meshes.push(format!(
        r#"{{"primitives":[{{"attributes":{{"POSITION":{pos},"NORMAL":{nrm},"TEXCOORD_0":{uv}}},"indices":{idx},"material":{material}}}]}}"#
    ));
    b.meshes.len() - 1
}

/// Writes the scene: a 12 x 12 floor (object 0) and the masked quad (object 1, cutoff 0.5,
/// nearest filtering, clamped) at `QUAD_Y`, into a directory of its own for `test` (the tests
/// run in parallel, and each removes its directory after loading).
fn write_scene(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "coherent-materials-gi-{}-{test}",
        std::process::id()
    ));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let mut b = GltfBuilder {
        materials: vec![
            r#"{"pbrMetallicRoughness":{"baseColorFactor":[0.1,0.8,0.1,1]}}"#.to_string(),
            r#"{"pbrMetallicRoughness":{"baseColorTexture":{"index":0}},"alphaMode":"MASK","alphaCutoff":0.5}"#.to_string(),
        ],
        ..Default::default()
    };
    let floor = quad(&mut b, (-6.0, -6.0, 6.0, 6.0, 0.0), 0);
    let masked = quad(&mut b, (-2.0, -2.0, 2.0, 2.0, QUAD_Y), 1);
    for m in [floor, masked] {
        b.node(m, [0.0, 0.0, 0.0]);
    }
    let images = format!(
        r#""images":[{{"uri":"data:image/png;base64,{}"}}],"samplers":[{{"magFilter":9728,"minFilter":9728,"wrapS":33071,"wrapT":33071}}],"textures":[{{"source":0,"sampler":0}}],"#,
        coherent::scene::gltf::testdata::base64(&holes_png())
    );
    let uri = format!(
        "data:application/octet-stream;base64,{}",
        coherent::scene::gltf::testdata::base64(&b.bin)
    );
    let json = b.json(Some(&uri)).replacen('{', &format!("{{{images}"), 1);
    let path = dir.join("masked_gi.gltf");
    std::fs::write(&path, json).expect("write");
    path
}

/// The scene, and the same scene with its mask turned off (the control).
fn scenes(test: &str) -> (Scene, Scene) {
    let path = write_scene(test);
    let (scene, warnings) = coherent::scene::gltf::load_gltf(&path).expect("load");
    assert!(warnings.is_empty(), "{warnings:?}");
    std::fs::remove_dir_all(path.parent().expect("dir")).ok();
    assert!(matches!(scene.materials[0].alpha, AlphaMode::Mask(_)));
    let mut opaque = scene.clone();
    for m in &mut opaque.materials {
        m.alpha = AlphaMode::Opaque;
    }
    (scene, opaque)
}

fn light() -> Spotlight {
    Spotlight::new(
        Vec3::new(0.0, LIGHT_Y, 0.0),
        Vec3::NEG_Y,
        Vec3::splat(200.0),
    )
}

/// The checker texel of a point of the quad's plane, or `None` within `margin` of a texel
/// edge or outside the quad.
fn texel_at(x: f32, z: f32, margin: f32) -> Option<(i32, i32)> {
    let (u, v) = (x + 2.0, z + 2.0);
    let n = CELLS as f32;
    if !(0.0..n).contains(&u) || !(0.0..n).contains(&v) {
        return None;
    }
    let near_edge = |t: f32| (t - t.round()).abs() < margin;
    if near_edge(u) || near_edge(v) {
        return None;
    }
    Some((u as i32, v as i32))
}

/// The point where the line from the light through `p` crosses the plane y = `y`.
fn along_light(p: Vec3, y: f32) -> Vec3 {
    let l = light().position;
    l + (p - l) * ((l.y - y) / (l.y - p.y))
}

#[test]
fn ray_cast_vpls_and_ism_points_skip_the_holes() {
    let (scene, opaque) = scenes("ray_cast");
    // (VPLs on the floor under the quad, of them under a hole, VPLs on the quad on a hole)
    let count = |s: &Scene| {
        let geometry = WorldGeometry::from_scene(s);
        let rays = geometry.ray_scene();
        let mut set = VplSet::new(256, 256);
        set.recompute_all(&light(), &rays);
        let (mut under, mut under_hole, mut on_hole) = (0, 0, 0);
        for v in set.vpls() {
            let p = v.position;
            if p.y.abs() < 1e-3 {
                let q = along_light(p, QUAD_Y);
                if q.x.abs() < 2.0 && q.z.abs() < 2.0 {
                    under += 1;
                    under_hole += texel_at(q.x, q.z, 0.01).is_some_and(|(i, j)| hole(i, j)) as u32;
                }
            } else if (p.y - QUAD_Y).abs() < 1e-3 {
                on_hole += texel_at(p.x, p.z, 0.01).is_some_and(|(i, j)| hole(i, j)) as u32;
            }
        }
        (geometry, under, under_hole, on_hole)
    };
    let (geometry, under, under_hole, on_hole) = count(&scene);
    assert!(under >= 20, "{under} VPLs through the holes");
    assert!(
        under_hole * 10 >= under * 9,
        "{under_hole} of {under} under holes"
    );
    assert_eq!(on_hole, 0, "VPLs on the quad's holes");
    let (opaque_geometry, under, _, on_hole) = count(&opaque);
    assert_eq!(under, 0, "the opaque quad lets VPLs through");
    assert!(
        on_hole >= 20,
        "{on_hole}: the opaque quad has VPLs all over"
    );

    // ISM points: none on a hole; the control has about half of the quad's there.
    let on_holes = |g: &WorldGeometry| {
        let points = coherent::gi::ism::sample_surface_points(g, 20_000, 7);
        assert_eq!(points.len(), 20_000);
        let quad: Vec<_> = points
            .iter()
            .filter(|p| (p[1] - QUAD_Y).abs() < 1e-3)
            .collect();
        let holes = quad
            .iter()
            .filter(|p| texel_at(p[0], p[2], 1e-3).is_some_and(|(i, j)| hole(i, j)))
            .count();
        (quad.len(), holes)
    };
    let (on_quad, holes) = on_holes(&geometry);
    assert!(on_quad > 500, "{on_quad} points on the quad");
    assert_eq!(holes, 0, "ISM points on holes");
    let (on_quad, holes) = on_holes(&opaque_geometry);
    assert!(
        holes * 3 > on_quad,
        "control: {holes} of {on_quad} on holes"
    );
}

/// The camera low beside the floor (below the quad: it sees the floor under it), and the one
/// beside the light, looking down through the quad.
fn cameras() -> [Camera; 2] {
    let camera =
        |eye, target| Camera::from_pose(CameraPose { eye, target }, W as f32 / H as f32, 40.0);
    [
        camera(Vec3::new(0.0, 1.8, 6.5), Vec3::ZERO),
        Camera {
            // Wide enough to see the whole quad from just beside the light.
            fov_y: 110f32.to_radians(),
            ..camera(Vec3::new(0.0, LIGHT_Y, 0.3), Vec3::ZERO)
        },
    ]
}

/// The spotlight's direct light only (its shadow map is drawn by the same layered pipeline as
/// the VPLs'), as RGBA8, from each of [`cameras`].
/// The direct-light images from both cameras; with `exact`, the shadow maps clip in the vertex
/// shader (the variant of devices without `shaderClipDistance`).
fn direct_light_with(scene: &Scene, exact: bool) -> Vec<Vec<u8>> {
    let (ctx, log) = common::context();
    let out = {
        let geometry = WorldGeometry::from_scene(scene);
        let rays = geometry.ray_scene();
        let mut renderer = direct_only_renderer(&ctx, &geometry, (W, H));
        if exact {
            renderer
                .use_exact_shadow_clipping()
                .expect("exact pipelines");
        }
        let mut set = VplSet::new(16, 16);
        let stats = set.recompute_all(&light(), &rays);
        let mut images = Vec::new();
        for (i, camera) in cameras().iter().enumerate() {
            let new_layers = if i == 0 { &stats.new_layers[..] } else { &[] };
            let frame = renderer
                .frame(&light(), set.vpls(), new_layers, camera)
                .expect("frame");
            assert_eq!(frame.shadow_maps_rendered as usize, new_layers.len());
            images.push(renderer.read_output().expect("readback"));
        }
        images
    };
    drop(ctx);
    common::assert_silent(&log);
    out
}

/// A GI renderer of `size` that outputs the spotlight's direct light only (16 VPL layers,
/// 256 x 256 shadow maps).
pub(crate) fn direct_only_renderer(
    ctx: &std::sync::Arc<coherent::gpu::GpuContext>,
    geometry: &WorldGeometry,
    (width, height): (u32, u32),
) -> GiRenderer {
    let options = GiOptions {
        width,
        height,
        vpl_layers: 16,
        max_vpls: 16,
        shadow_size: 256,
    };
    let mut renderer = GiRenderer::new(ctx, geometry, options).expect("renderer");
    renderer.output = OutputMode::DirectOnly;
    renderer
}

fn direct_light(scene: &Scene) -> Vec<Vec<u8>> {
    direct_light_with(scene, false)
}

/// Mean brightness of a 3x3 window around pixel (x, y).
fn brightness(px: &[u8], x: i32, y: i32) -> f32 {
    let mut sum = 0.0;
    for dy in -1..=1 {
        for dx in -1..=1 {
            let i = (((y + dy) as u32 * W + (x + dx) as u32) * 4) as usize;
            sum += f32::from(px[i]) + f32::from(px[i + 1]) + f32::from(px[i + 2]);
        }
    }
    sum / 27.0
}

/// Pixel of world point `p`, if it lies well inside the image.
fn pixel(vp: Mat4, p: Vec3) -> Option<(i32, i32)> {
    let ndc = vp.project_point3(p);
    let x = ((ndc.x * 0.5 + 0.5) * W as f32) as i32;
    let y = ((0.5 - 0.5 * ndc.y) * H as f32) as i32;
    (x >= 2 && y >= 2 && x < W as i32 - 2 && y < H as i32 - 2).then_some((x, y))
}

/// Under the spotlight, every hole cell of the quad that is big enough on screen lights its
/// floor cell in `masked_px` and every opaque cell leaves its floor cell dark; `opaque_px` (the
/// same scene without the mask) is dark under every cell.
fn check_hole_shadows(masked_px: &[u8], opaque_px: &[u8]) {
    let vp = cameras()[0].view_proj();
    let (mut lit_holes, mut dark_cells, mut checked_holes) = (0, 0, 0);
    for i in 0..CELLS as i32 {
        for j in 0..CELLS as i32 {
            // The centre of texel (i, j) on the quad, and its shadow on the floor.
            let c = Vec3::new(-2.0 + i as f32 + 0.5, QUAD_Y, -2.0 + j as f32 + 0.5);
            let floor = along_light(c, 0.0);
            // Only cells big enough on screen: the floor cell's corners a quarter cell away.
            let corners = [(-0.25, -0.25), (0.25, 0.25)]
                .map(|(dx, dz)| pixel(vp, along_light(c + Vec3::new(dx, 0.0, dz), 0.0)));
            let (Some((x, y)), [Some(a), Some(b)]) = (pixel(vp, floor), corners) else {
                continue;
            };
            if (a.0 - b.0).abs() < 4 || (a.1 - b.1).abs() < 4 {
                continue;
            }
            let (m, o) = (brightness(masked_px, x, y), brightness(opaque_px, x, y));
            assert!(
                o < 5.0,
                "control: cell ({i}, {j}) lit ({o}) under the opaque quad"
            );
            if hole(i, j) {
                checked_holes += 1;
                lit_holes += (m > 40.0) as u32;
            } else {
                dark_cells += (m < 5.0) as u32;
                assert!(m < 5.0, "cell ({i}, {j}) lit ({m}) under an opaque texel");
            }
        }
    }
    assert!(
        checked_holes >= 3,
        "only {checked_holes} hole cells on screen"
    );
    assert_eq!(lit_holes, checked_holes, "hole cells lit");
    assert!(dark_cells >= 3, "{dark_cells} opaque cells checked");
}

#[test]
fn the_shadow_maps_let_light_through_the_holes_only() {
    let (scene, opaque) = scenes("shadow_maps");
    let masked = direct_light(&scene);
    let opaque_images = direct_light(&opaque);
    // The masked pass with the in-shader clipping (devices without shaderClipDistance) must
    // let the same light through: the holes' cells below are checked in its image too.
    let exact = direct_light_with(&scene, true);
    for masked_px in [&masked[0], &exact[0]] {
        check_hole_shadows(masked_px, &opaque_images[0]);
    }

    // From beside the light: the G-buffer shows the lit green floor through every hole and the
    // white quad elsewhere; with the mask off, the quad everywhere.
    let vp = cameras()[1].view_proj();
    let green = |px: &[u8], (x, y): (i32, i32)| {
        let i = ((y as u32 * W + x as u32) * 4) as usize;
        let (r, g) = (u32::from(px[i]), u32::from(px[i + 1]));
        g > 60 && g > r + 40
    };
    let white = |px: &[u8], (x, y): (i32, i32)| {
        let i = ((y as u32 * W + x as u32) * 4) as usize;
        px[i] > 30 && px[i].abs_diff(px[i + 1]) < 10
    };
    for i in 0..CELLS as i32 {
        for j in 0..CELLS as i32 {
            let c = Vec3::new(-2.0 + i as f32 + 0.5, QUAD_Y, -2.0 + j as f32 + 0.5);
            let p = pixel(vp, c).expect("cell on screen");
            let shows = if hole(i, j) { green } else { white };
            let at = ((p.1 as u32 * W + p.0 as u32) * 4) as usize;
            assert!(
                shows(&masked[1], p),
                "cell ({i}, {j}) from above: {:?} at {p:?}",
                &masked[1][at..at + 4]
            );
            assert!(
                white(&opaque_images[1], p),
                "control: cell ({i}, {j}) from above"
            );
        }
    }
}
