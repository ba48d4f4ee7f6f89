//! Reliability: only the validation layer's messages fail a run (a second layer injected with
//! `VK_INSTANCE_LAYERS` does not), running out of memory is a typed error, device limits are
//! checked where things are created (and work beyond `maxFramebufferLayers` is split: the GI
//! shadow maps, run under a lowered limit), and a 500-frame soak of every algorithm stays at zero
//! validation messages with flat GPU memory. `COHERENT_SOAK_FRAMES=N` runs the long soak
//! (`soak_long`, ignored by default; `scripts/soak.sh`).

use crate::common;

use std::process::Command;
use std::sync::Arc;

use ash::vk;
use coherent::culling;
use coherent::gpu::{Buffer, ContextOptions, GpuContext, Image, LimitOverrides, MemoryUsage};
use coherent::render::hiz::FrameAlgorithm;
use coherent::render::Renderer;
use coherent::Error;

fn scratch(test: &str) -> coherent::testing::TempDir {
    coherent::testing::TempDir::new(&format!("rel-{test}"))
}

#[test]
fn render_passes_with_a_second_layer_injected() {
    let dir = scratch("layer");
    let out = dir.join("frame.png");
    let run = Command::new(env!("CARGO_BIN_EXE_coherent"))
        .args(["render", "--scene", "cornell", "--size", "64x48", "--out"])
        .arg(&out)
        .env("VK_INSTANCE_LAYERS", "VK_LAYER_MESA_overlay")
        .env("COHERENT_STRICT_VALIDATION", "1")
        .output()
        .expect("run coherent");
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "render failed: {stderr}");
    assert!(out.exists(), "no image written");
    // The layer really was there: the loader says it injected it, and that message was printed
    // as not counted (it is what used to fail the run).
    assert!(
        stderr.contains("not validation, not counted") && stderr.contains("VK_INSTANCE_LAYERS"),
        "the loader's message about the injected layer was not printed: {stderr}"
    );
}

#[test]
fn validation_errors_still_count() {
    let (ctx, log) = common::context();
    ctx.provoke_validation_error().expect("provoke");
    assert!(log.count() >= 1, "the provoked error was not counted");
    assert!(
        log.other_messages().is_empty(),
        "{:?}",
        log.other_messages()
    );
}

fn budget_context(bytes: u64) -> Arc<GpuContext> {
    GpuContext::new(&ContextOptions {
        validation: true,
        strict_validation: true,
        memory_budget: Some(bytes),
        ..Default::default()
    })
    .expect("context")
}

#[test]
fn out_of_device_memory_is_a_typed_error() {
    let ctx = budget_context(8 << 20);
    let log = ctx.validation_log();
    {
        let usage = vk::BufferUsageFlags::STORAGE_BUFFER;
        let loc = gpu_allocator::MemoryLocation::GpuOnly;
        let big = Buffer::new(&ctx, "too big", 16 << 20, usage, loc);
        match big {
            Err(Error::OutOfDeviceMemory { what }) => assert!(what.contains("too big"), "{what}"),
            Err(e) => panic!("expected OutOfDeviceMemory, got {e}"),
            Ok(_) => panic!("a 16 MiB buffer fit an 8 MiB budget"),
        }
        // Within the budget it works, and the failure left nothing behind.
        let small = Buffer::new(&ctx, "small", 1 << 20, usage, loc).expect("small buffer");
        assert!(ctx.memory_usage().allocated_bytes >= 1 << 20);
        drop(small);
        // A whole renderer that does not fit fails the same way, not with a panic.
        let (scene, _) = common::scene("cornell", 1.0);
        match Renderer::new(&ctx, &scene, 2048, 2048) {
            Err(e @ Error::OutOfDeviceMemory { .. }) => {
                assert!(e.to_string().starts_with("out of device memory"), "{e}")
            }
            Err(e) => panic!("expected OutOfDeviceMemory, got {e}"),
            Ok(_) => panic!("a 2048x2048 renderer fit an 8 MiB budget"),
        }
    }
    drop(ctx);
    common::assert_silent(&log);
}

#[test]
fn vulkan_results_map_to_typed_errors() {
    let lost = Error::from_vk("vkQueueSubmit", vk::Result::ERROR_DEVICE_LOST);
    assert!(
        matches!(
            lost,
            Error::DeviceLost {
                call: "vkQueueSubmit"
            }
        ),
        "{lost}"
    );
    assert!(lost.to_string().contains("device was lost"), "{lost}");
    let dev = Error::from_vk("vkAllocateMemory", vk::Result::ERROR_OUT_OF_DEVICE_MEMORY);
    assert!(matches!(dev, Error::OutOfDeviceMemory { .. }), "{dev}");
    let host = Error::from_vk("vkCreateBuffer", vk::Result::ERROR_OUT_OF_HOST_MEMORY);
    assert!(matches!(host, Error::OutOfHostMemory { .. }), "{host}");
    let other = Error::from_vk("vkCreateBuffer", vk::Result::ERROR_UNKNOWN);
    assert!(matches!(other, Error::Vulkan { .. }), "{other}");
}

fn expect_limit(r: coherent::Result<()>, name: &str) {
    match r {
        Err(Error::Limit { limit, .. }) if limit == name => {}
        other => panic!("expected the {name} limit error, got {other:?}"),
    }
}

#[test]
fn limits_are_checked_against_the_device() {
    let (ctx, log) = common::context();
    // Fake small limits: each check fires at its limit + 1 and passes at the limit.
    let mut small = ctx.info.clone();
    small.max_image_dimension_2d = 64;
    small.max_image_array_layers = 4;
    small.max_framebuffer_layers = 2;
    small.max_framebuffer_size = (48, 32);
    small.max_storage_buffer_range = 1024;
    small.max_push_constants_size = 128;
    small.max_compute_work_group_size = [16, 16, 1];
    small.max_compute_work_group_invocations = 128;
    small.max_compute_work_group_count = [100, 100, 1];
    small
        .check_image("t", (64, 8), 4, false)
        .expect("at the limits");
    expect_limit(
        small.check_image("t", (65, 8), 1, false),
        "maxImageDimension2D",
    );
    expect_limit(
        small.check_image("t", (8, 8), 5, false),
        "maxImageArrayLayers",
    );
    expect_limit(
        small.check_image("t", (49, 8), 1, true),
        "maxFramebufferWidth",
    );
    expect_limit(
        small.check_image("t", (8, 33), 1, true),
        "maxFramebufferHeight",
    );
    small
        .check_framebuffer_layers("t", 2)
        .expect("at the limit");
    expect_limit(
        small.check_framebuffer_layers("t", 3),
        "maxFramebufferLayers",
    );
    small.check_storage_buffer("t", 1024).expect("at the limit");
    expect_limit(
        small.check_storage_buffer("t", 1025),
        "maxStorageBufferRange",
    );
    small.check_push_constants("t", 128).expect("at the limit");
    expect_limit(small.check_push_constants("t", 132), "maxPushConstantsSize");
    small
        .check_workgroup("t", [8, 16, 1])
        .expect("128 invocations");
    expect_limit(
        small.check_workgroup("t", [17, 1, 1]),
        "maxComputeWorkGroupSize[0]",
    );
    expect_limit(
        small.check_workgroup("t", [16, 16, 1]),
        "maxComputeWorkGroupInvocations",
    );
    expect_limit(
        small.check_dispatch("t", [100, 101, 1]),
        "maxComputeWorkGroupCount[1]",
    );
    // The real device: an image past maxImageDimension2D is refused before Vulkan sees it.
    let too_wide = ctx.info.max_image_dimension_2d + 1;
    let img = Image::new(
        &ctx,
        "too wide",
        vk::Format::R8G8B8A8_UNORM,
        (too_wide, 1),
        1,
        vk::ImageUsageFlags::SAMPLED,
    );
    assert!(
        matches!(
            img,
            Err(Error::Limit {
                limit: "maxImageDimension2D",
                ..
            })
        ),
        "{:?}",
        img.err()
    );
    drop(ctx);
    common::assert_silent(&log);
}

/// A strictly validated context whose limits are lowered by `lower` (the device's otherwise).
fn lowered_context(lower: LimitOverrides) -> Arc<GpuContext> {
    GpuContext::new(&ContextOptions {
        validation: true,
        strict_validation: true,
        lower_limits: lower,
        ..Default::default()
    })
    .expect("context")
}

/// GI frames of cornell on `ctx` (64x48, 32 VPL layers, 4 new VPLs a frame): three
/// incremental frames and one full recompute. The images read back after each, and what each
/// frame reported (the recorder's counts among it).
fn gi_frames(
    ctx: &Arc<GpuContext>,
) -> coherent::Result<(Vec<Vec<u8>>, Vec<coherent::gi::GiFrame>)> {
    gi_frames_with(ctx, None)
}

/// [`gi_frames`] with imperfect shadow maps when `ism` is given.
fn gi_frames_with(
    ctx: &Arc<GpuContext>,
    ism: Option<coherent::gi::ism::IsmOptions>,
) -> coherent::Result<(Vec<Vec<u8>>, Vec<coherent::gi::GiFrame>)> {
    use coherent::app::gi_run::{default_camera, LightPath};
    use coherent::gi::geometry::WorldGeometry;
    use coherent::gi::vpl::VplSet;
    use coherent::gi::{GiOptions, GiRenderer};
    let scene = coherent::scene::Scene::load("cornell", 1.0, 0)?;
    let geometry = WorldGeometry::from_scene(&scene);
    let rays = geometry.ray_scene();
    let path = LightPath::for_scene("cornell", &geometry, &rays);
    let (w, h) = (64, 48);
    let camera = default_camera(&scene, &geometry, w as f32 / h as f32);
    let options = GiOptions {
        width: w,
        height: h,
        vpl_layers: 32,
        max_vpls: 32,
        shadow_size: 32,
    };
    let mut renderer = match ism {
        Some(ism) => GiRenderer::with_ism(ctx, &geometry, options, ism)?,
        None => GiRenderer::new(ctx, &geometry, options)?,
    };
    let mut set = VplSet::new(32, 4);
    let (mut images, mut counts) = (Vec::new(), Vec::new());
    for f in 0..4 {
        let light = path.at(f as f32 / 3.0);
        let stats = if f < 3 {
            set.update(&light, &rays)
        } else {
            set.recompute_all(&light, &rays)
        };
        counts.push(renderer.frame(&light, set.vpls(), &stats.new_layers, &camera)?);
        images.push(renderer.read_output()?);
    }
    Ok((images, counts))
}

#[test]
fn gi_refuses_a_scene_too_large_for_one_storage_buffer_in_one_line() {
    // Every world-space vertex of a GI scene is pulled from one storage buffer; on a device
    // whose maxStorageBufferRange is smaller than that, gi says so before it allocates.
    let low = lowered_context(LimitOverrides {
        max_storage_buffer_range: Some(4096),
        ..Default::default()
    });
    let low_log = low.validation_log();
    assert_eq!(low.info.max_storage_buffer_range, 4096);
    let err = gi_frames(&low).expect_err("the cornell box needs more than 4 KiB");
    let text = err.to_string();
    assert!(
        matches!(
            err,
            Error::Limit {
                limit: "maxStorageBufferRange",
                ..
            }
        ) && text.starts_with("gi: ")
            && text.contains("world-space triangles")
            && !text.contains('\n'),
        "{text}"
    );
    drop(low);
    common::assert_silent(&low_log);
}

#[test]
fn gi_shadow_maps_split_at_max_framebuffer_layers() {
    // 32 VPL layers + the spotlight's: one 33-layer rendering on lavapipe (2048 allowed);
    // with maxFramebufferLayers lowered to 6, chunks of 5 VPL maps through the staging image.
    let (ctx, log) = common::context();
    assert!(
        ctx.info.max_framebuffer_layers >= 33,
        "{}",
        ctx.info.max_framebuffer_layers
    );
    let (whole, whole_counts) = gi_frames(&ctx).expect("unsplit frames");
    drop(ctx);
    common::assert_silent(&log);
    let low = lowered_context(LimitOverrides {
        max_framebuffer_layers: Some(6),
        ..Default::default()
    });
    let low_log = low.validation_log();
    assert_eq!(low.info.max_framebuffer_layers, 6);
    let (split, split_counts) = gi_frames(&low).expect("split frames");
    drop(low);
    common::assert_silent(&low_log);
    for (f, (a, b)) in whole.iter().zip(&split).enumerate() {
        assert_eq!(common::diff_pixels(a, b), 0, "frame {f}: images differ");
    }
    // Frames 0 and 3 render every VPL's map (most of 32): unsplit in one draw, split in
    // chunks of 5 (one draw each); frames 1 and 2 render at most 4 maps, staged either way.
    for (f, (a, b)) in whole_counts.iter().zip(&split_counts).enumerate() {
        let maps = a.shadow_maps_rendered;
        assert_eq!(maps, b.shadow_maps_rendered, "frame {f}");
        let extra = b.counts.draw_calls - a.counts.draw_calls;
        if f == 0 || f == 3 {
            assert!(maps > 16, "frame {f}: {maps} maps");
            assert_eq!(extra, maps.div_ceil(5) - 1, "frame {f}: {maps} maps");
        } else {
            assert!(maps <= 4, "frame {f}: {maps} maps");
            assert_eq!(extra, 0, "frame {f}");
        }
    }
    // A device whose array cannot hold the VPLs' maps: an honest error, no Vulkan call.
    let tiny = lowered_context(LimitOverrides {
        max_image_array_layers: Some(16),
        ..Default::default()
    });
    let tiny_log = tiny.validation_log();
    let err = gi_frames(&tiny).expect_err("33 layers in a 16-layer array");
    assert!(err.to_string().contains("array layers"), "{err}");
    drop(tiny);
    common::assert_silent(&tiny_log);
}

#[test]
fn imperfect_shadow_maps_split_at_max_framebuffer_layers() {
    // 32 ISM layers: one layered splat on lavapipe; with maxFramebufferLayers lowered to 6,
    // six splats of at most 6 layers through the staging image, copied into the array.
    let ism = coherent::gi::ism::IsmOptions {
        map_size: 16,
        points_per_vpl: 256,
    };
    let (ctx, log) = common::context();
    let (whole, whole_counts) = gi_frames_with(&ctx, Some(ism)).expect("unsplit ism frames");
    drop(ctx);
    common::assert_silent(&log);
    let low = lowered_context(LimitOverrides {
        max_framebuffer_layers: Some(6),
        ..Default::default()
    });
    let low_log = low.validation_log();
    let (split, split_counts) = gi_frames_with(&low, Some(ism)).expect("split ism frames");
    drop(low);
    common::assert_silent(&low_log);
    for (f, (a, b)) in whole.iter().zip(&split).enumerate() {
        assert_eq!(common::diff_pixels(a, b), 0, "frame {f}: images differ");
        let (a, b) = (&whole_counts[f], &split_counts[f]);
        assert_eq!(a.ism_maps, b.ism_maps, "frame {f}");
        assert!(a.ism_maps > 0, "frame {f}: no imperfect shadow maps");
        // One splat draw per chunk instead of one.
        assert_eq!(
            b.counts.draw_calls - a.counts.draw_calls,
            32u32.div_ceil(6) - 1,
            "frame {f}"
        );
    }
}

#[test]
fn every_dispatch_checks_max_compute_work_group_count() {
    // The GI frame dispatches 8x6 groups at full resolution (64x48) and 4x3 at half: at the
    // lowered limit it runs, one group below it is refused through the recorder.
    let exact = lowered_context(LimitOverrides {
        max_compute_work_group_count: Some([8, 6, 1]),
        ..Default::default()
    });
    let log = exact.validation_log();
    let (_, counts) = gi_frames(&exact).expect("dispatches at the limit");
    assert!(counts.iter().all(|c| c.counts.dispatches > 0));
    drop(exact);
    common::assert_silent(&log);
    for (lower, limit) in [
        ([7, 6, 1], "maxComputeWorkGroupCount[0]"),
        ([8, 5, 1], "maxComputeWorkGroupCount[1]"),
    ] {
        let ctx = lowered_context(LimitOverrides {
            max_compute_work_group_count: Some(lower),
            ..Default::default()
        });
        let log = ctx.validation_log();
        match gi_frames(&ctx) {
            Err(Error::Limit { limit: l, what, .. }) if l == limit => {
                assert!(what.contains("gi full-resolution pass"), "{what}")
            }
            other => panic!("expected the {limit} error, got {:?}", other.err()),
        }
        drop(ctx);
        common::assert_silent(&log);
    }
    // A limit is only lowered, never raised above the device's.
    let raised = lowered_context(LimitOverrides {
        max_framebuffer_layers: Some(u32::MAX),
        ..Default::default()
    });
    let real = GpuContext::headless().expect("context");
    assert_eq!(
        raised.info.max_framebuffer_layers,
        real.info.max_framebuffer_layers
    );
}

/// Resident set size of this process, kB (Linux).
fn rss_kb() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap_or(0)
}

/// What a soak saw.
struct Soak {
    frames: u32,
    messages: usize,
    rss_kb: Vec<(u32, u64)>,
    memory: (MemoryUsage, MemoryUsage),
    seconds: f64,
}

/// The algorithms a soak runs: every algorithm that needs no preprocessing (pvs needs its
/// cells built; its per-frame work is vfc's over a smaller set), and CHC++ in the predicated
/// mode (one and two frames in flight) and the next-frame mode with two frames in flight.
const SOAKED: [&str; 10] = [
    "vfc",
    "stop-and-wait",
    "chc",
    "chcpp",
    "oracle",
    "nohc",
    "hiz",
    "chcpp@predicated",
    "chcpp@predicated-k2",
    "chcpp@next-frame-k2",
];

/// What the soaked algorithms need: nohc a cost model (a fixed one: the soak is about leaks and
/// messages, not about which nodes are worth a query).
fn setup(scene: &coherent::scene::Scene) -> culling::CullerSetup {
    common::setup(common::triangles(scene), (160, 90), 0.05)
}

/// Cars moving on the soaked city's streets (their boxes and transforms updated every pose).
const SOAK_MOVERS: usize = 40;

/// Renders `frames` frames along the city's street path at 160x90 (scale 0.1) with
/// [`SOAK_MOVERS`] moving cars: each pose is rendered by every algorithm in turn (frames / 10
/// poses, forward and back along the path), under strict validation. Start figures are taken
/// after a warm-up of 10 poses; RSS is also sampled at ten checkpoints.
fn soak(frames: u32) -> Soak {
    let (warmup, poses) = (10u32, (frames / SOAKED.len() as u32).max(1));
    let (ctx, log) = common::context();
    let mut report = {
        let (mut scene, _) = common::scene("city", 0.1);
        let movers = coherent::scene::movers::Movers::add(&mut scene, SOAK_MOVERS);
        let mut bvh = common::bvh_of(&scene);
        let path = scene.path("street").expect("street path").clone();
        let mut r = Renderer::new(&ctx, &scene, 160, 90).expect("renderer");
        let mut algs: Vec<_> = SOAKED
            .iter()
            .map(|a| FrameAlgorithm::create(a, &setup(&scene), &r).expect("algorithm"))
            .collect();
        let mut start = (MemoryUsage::default(), std::time::Instant::now());
        let mut rss = Vec::new();
        for p in 0..warmup + poses {
            if p == warmup {
                start = (ctx.memory_usage(), std::time::Instant::now());
            }
            if p >= warmup && (p - warmup) % (poses / 10).max(1) == 0 {
                rss.push(((p - warmup) * SOAKED.len() as u32, rss_kb()));
            }
            let (period, k) = (2 * 600, p % 1200);
            coherent::app::walk::place_movers(&movers, p.into(), &mut bvh, &mut r).expect("movers");
            let cam = r.camera(path.sample(k.min(period - k), 601), &bvh);
            for alg in algs.iter_mut() {
                alg.render_frame(&mut r, &bvh, &cam, p as u64)
                    .expect("frame");
            }
        }
        rss.push((poses * SOAKED.len() as u32, rss_kb()));
        Soak {
            frames: poses * SOAKED.len() as u32,
            messages: 0,
            rss_kb: rss,
            memory: (start.0, ctx.memory_usage()),
            seconds: start.1.elapsed().as_secs_f64(),
        }
    };
    drop(ctx);
    report.messages = log.count();
    common::assert_silent(&log);
    report
}

fn print_and_check(s: &Soak) {
    let (m0, m1) = s.memory;
    let rss: Vec<String> = s.rss_kb.iter().map(|(f, kb)| format!("{f}:{kb}")).collect();
    println!(
        "soak: {} frames ({} poses x {} algorithms) in {:.1} s; validation messages {}; \
         RSS kB at frame {}; GPU allocator {} B in {} allocations ({} B in {} blocks) -> \
         {} B in {} allocations ({} B in {} blocks)",
        s.frames,
        s.frames / SOAKED.len() as u32,
        SOAKED.len(),
        s.seconds,
        s.messages,
        rss.join(" "),
        m0.allocated_bytes,
        m0.allocations,
        m0.capacity_bytes,
        m0.blocks,
        m1.allocated_bytes,
        m1.allocations,
        m1.capacity_bytes,
        m1.blocks
    );
    assert_eq!(s.messages, 0);
    let flat = |a: u64, b: u64| b.abs_diff(a) as f64 <= 0.01 * a as f64;
    assert!(
        flat(m0.allocated_bytes, m1.allocated_bytes),
        "GPU memory not flat"
    );
    assert!(
        flat(m0.capacity_bytes, m1.capacity_bytes),
        "GPU memory blocks not flat"
    );
}

#[test]
fn soak_500_frames() {
    let s = soak(500);
    print_and_check(&s);
}

#[test]
#[ignore = "long; scripts/soak.sh runs it with COHERENT_SOAK_FRAMES"]
fn soak_long() {
    let frames = std::env::var("COHERENT_SOAK_FRAMES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10_000);
    let s = soak(frames);
    print_and_check(&s);
}
