//! GI on the GPU under the validation layer: color bleeding in the indirect-only image, and
//! shadow-map counts of incremental vs full recompute taken from the command recorder.

use coherent::app::gi_run::{default_camera, LightPath};
use coherent::gi::geometry::WorldGeometry;
use coherent::gi::light::Spotlight;
use coherent::gi::vpl::VplSet;
use coherent::gi::{GiOptions, GiRenderer, OutputMode};
use coherent::gpu::GpuContext;
use coherent::scene::camera::Camera;
use coherent::scene::{CameraPose, Scene};
use glam::Vec3;

/// Mean R/G over the pixels in a 7x7 window around the projection of `p`.
fn red_green_ratio(pixels: &[u8], w: u32, h: u32, view_proj: glam::Mat4, p: Vec3) -> f64 {
    let ndc = view_proj.project_point3(p);
    let cx = ((ndc.x * 0.5 + 0.5) * w as f32) as i32;
    let cy = ((0.5 - 0.5 * ndc.y) * h as f32) as i32;
    let (mut r, mut g) = (0.0, 0.0);
    for y in cy - 3..=cy + 3 {
        for x in cx - 3..=cx + 3 {
            if x < 0 || y < 0 || x >= w as i32 || y >= h as i32 {
                continue;
            }
            let i = ((y as u32 * w + x as u32) * 4) as usize;
            r += pixels[i] as f64;
            g += pixels[i + 1] as f64;
        }
    }
    assert!(r + g > 0.0, "no indirect light around {p}");
    r / g.max(1.0)
}

#[test]
fn cornell_indirect_light_bleeds_wall_colors() {
    let ctx = GpuContext::headless().expect("context");
    let log = ctx.validation_log();
    {
        let scene = Scene::load("cornell", 1.0, 0).expect("scene");
        let geometry = WorldGeometry::from_scene(&scene);
        let rays = geometry.ray_scene();
        let light = LightPath::for_scene("cornell", &geometry, &rays).at(0.5);
        let (w, h) = (128, 96);
        let camera = default_camera(&scene, &geometry, w as f32 / h as f32);
        let mut renderer = GiRenderer::new(
            &ctx,
            &geometry,
            GiOptions {
                width: w,
                height: h,
                vpl_layers: 64,
                max_vpls: 64,
                shadow_size: 128,
            },
        )
        .expect("renderer");
        renderer.output = OutputMode::IndirectOnly;
        let mut set = VplSet::new(64, 64);
        let stats = set.recompute_all(&light, &rays);
        renderer
            .frame(&light, set.vpls(), &stats.new_layers, &camera)
            .expect("frame");
        let pixels = renderer.read_output().expect("readback");
        let vp = camera.view_proj();
        let near_red = red_green_ratio(&pixels, w, h, vp, Vec3::new(0.4, 0.0, 4.8));
        let near_green = red_green_ratio(&pixels, w, h, vp, Vec3::new(5.1, 0.0, 4.8));
        eprintln!("floor R/G: near red wall {near_red:.3}, near green wall {near_green:.3}");
        assert!(
            near_red > near_green * 1.1,
            "floor R/G near the red wall {near_red:.3} should exceed that near the green wall {near_green:.3}"
        );
    }
    drop(ctx);
    assert_eq!(log.count(), 0, "validation messages: {:?}", log.messages());
}

#[test]
fn incremental_renders_at_most_budget_shadow_maps_full_renders_all() {
    let ctx = GpuContext::headless().expect("context");
    let log = ctx.validation_log();
    {
        let scene = Scene::load("cornell", 1.0, 0).expect("scene");
        let geometry = WorldGeometry::from_scene(&scene);
        let rays = geometry.ray_scene();
        let path = LightPath::for_scene("cornell", &geometry, &rays);
        let (w, h) = (64, 48);
        let camera = default_camera(&scene, &geometry, w as f32 / h as f32);
        let (n, b) = (32usize, 4usize);
        let options = GiOptions {
            width: w,
            height: h,
            vpl_layers: n as u32,
            max_vpls: n as u32,
            shadow_size: 64,
        };
        let frames = 8;
        let mut incremental = GiRenderer::new(&ctx, &geometry, options).expect("renderer");
        let mut set = VplSet::new(n, b);
        for f in 0..frames {
            let light = path.at(f as f32 / (frames - 1) as f32);
            let before: std::collections::HashSet<u64> = set.vpls().iter().map(|v| v.id).collect();
            let stats = set.update(&light, &rays);
            let frame = incremental
                .frame(&light, set.vpls(), &stats.new_layers, &camera)
                .expect("frame");
            // The maps the recorder saw drawn are those of the VPLs that did not exist before.
            let created = set
                .vpls()
                .iter()
                .filter(|v| !before.contains(&v.id))
                .count();
            assert_eq!(frame.shadow_maps_rendered as usize, created);
            if f == 0 {
                assert_eq!(frame.shadow_maps_rendered as usize, set.vpls().len());
            } else {
                assert!(
                    frame.shadow_maps_rendered as usize <= b,
                    "frame {f}: {} maps",
                    frame.shadow_maps_rendered
                );
            }
        }
        drop(incremental);
        let mut full = GiRenderer::new(&ctx, &geometry, options).expect("renderer");
        let mut set = VplSet::new(n, b);
        for f in 0..3 {
            let light = path.at(f as f32 / 2.0);
            let stats = set.recompute_all(&light, &rays);
            let frame = full
                .frame(&light, set.vpls(), &stats.new_layers, &camera)
                .expect("frame");
            assert!(
                set.vpls().len() > n / 2,
                "most of the {n} rays should hit the box"
            );
            assert_eq!(frame.shadow_maps_rendered as usize, set.vpls().len());
        }
        drop(full);
        // The chunked path (VPL layers beyond the array) renders every map of every chunk.
        let mut chunked = GiRenderer::new(
            &ctx,
            &geometry,
            GiOptions {
                width: w,
                height: h,
                vpl_layers: 8,
                max_vpls: n as u32,
                shadow_size: 64,
            },
        )
        .expect("renderer");
        let light = path.at(0.5);
        let stats = set.recompute_all(&light, &rays);
        let frame = chunked
            .frame(&light, set.vpls(), &stats.new_layers, &camera)
            .expect("frame");
        assert!(frame.chunks > 1);
        assert_eq!(frame.shadow_maps_rendered as usize, set.vpls().len());
    }
    drop(ctx);
    assert_eq!(log.count(), 0, "validation messages: {:?}", log.messages());
}

#[test]
fn empty_geometry_renders_dark_frames_in_every_shadow_variant() {
    let ctx = GpuContext::headless().expect("context");
    let log = ctx.validation_log();
    {
        let options = GiOptions {
            width: 64,
            height: 48,
            vpl_layers: 4,
            max_vpls: 4,
            shadow_size: 32,
        };
        let mut r = GiRenderer::new(&ctx, &WorldGeometry::empty(), options).expect("renderer");
        let pose = CameraPose {
            eye: Vec3::new(0.0, 1.0, -3.0),
            target: Vec3::ZERO,
        };
        let camera = Camera::from_pose(pose, 64.0 / 48.0, 20.0);
        let light = Spotlight::new(Vec3::new(0.0, 2.0, 0.0), Vec3::NEG_Y, Vec3::ONE);
        for exact in [false, true] {
            if exact {
                r.use_exact_shadow_clipping().expect("exact pipelines");
            }
            let frame = r.frame(&light, &[], &[], &camera).expect("frame");
            assert_eq!(frame.shadow_maps_rendered, 0);
            let px = r.read_output().expect("readback");
            assert!(
                px.chunks_exact(4).all(|p| p[..3] == [0, 0, 0]),
                "nothing lit"
            );
        }
    }
    drop(ctx);
    assert_eq!(log.count(), 0, "validation messages: {:?}", log.messages());
}

/// The Cornell box inside a sky dome 200 times its size (a glTF level's backdrop) lights and
/// renders as the box alone: gi leaves the sky out. Left in, the dome's size set the shadow
/// maps' range and the splitting of long triangles, and the frames came out nearly black.
#[test]
fn a_sky_dome_around_the_scene_changes_nothing_in_gi() {
    use coherent::app::gi_run::{self, GiMode, GiRunOptions};
    use coherent::gi::IsmOptions;
    use coherent::scene::mesh::Mesh;
    use coherent::scene::Object;
    use glam::Mat4;

    let (ctx, log) = crate::common::context();
    let plain = Scene::load("cornell", 1.0, 0).expect("scene");
    let mut domed = plain.clone();
    let b = plain.bounds();
    let dome = Mesh::sphere(24, 12);
    let transform = Mat4::from_translation(b.center())
        * Mat4::from_scale(Vec3::splat(200.0 * b.extent().length()));
    let (vertex_offset, first_index) = (domed.vertices.len() as u32, domed.indices.len() as u32);
    domed.vertices.extend_from_slice(&dome.vertices);
    domed.indices.extend_from_slice(&dome.indices);
    domed.objects.push(Object {
        first_index,
        index_count: dome.indices.len() as u32,
        vertex_offset,
        vertex_count: dome.vertices.len() as u32,
        transform,
        color: glam::Vec4::ONE,
        bounds: dome.bounds().transformed(&transform),
        material: None,
    });
    let sky = coherent::scene::backdrop::find(&domed).expect("the dome is a backdrop");
    assert_eq!(sky.sky, vec![plain.objects.len()]);
    let opts = GiRunOptions {
        vpls: 16,
        budget: 4,
        frames: 3,
        width: 64,
        height: 48,
        modes: vec![GiMode::Incremental],
        shadow_size: 64,
        sample_frames: 1,
        ism: IsmOptions {
            map_size: 16,
            points_per_vpl: 256,
        },
    };
    let image = |scene: &Scene, name: &str| {
        let dir = coherent::testing::TempDir::new(&format!("gi-dome-{name}"));
        gi_run::run(&ctx, scene, &opts, Some(dir.path())).expect("gi run");
        let png = image::open(dir.path().join("incremental.png")).expect("png");
        png.to_rgba8().into_raw()
    };
    let (want, got) = (image(&plain, "plain"), image(&domed, "domed"));
    let lit = (want.chunks_exact(4))
        .filter(|p| p[..3].iter().any(|&c| c > 40))
        .count();
    assert!(
        lit > want.len() / 4 / 8,
        "the box alone is lit: {lit} pixels"
    );
    assert!(want == got, "the dome changed the image");
    drop(ctx);
    crate::common::assert_silent(&log);
}
