//! coherent-ash's `QueryBackend` on a real device under strict validation (core,
//! synchronization, best practices): a culler in next-frame mode with two frames in flight,
//! queries recorded into a host command buffer inside a depth pass, results copied and read two
//! frames later; its building blocks (`QuerySet`, `BoxPipeline`) on their own, growing and
//! copying across pools; and the shipped SPIR-V of its box shader equals what the workspace's
//! GLSL compiles to.

use ash::vk;
use coherent::gpu::memory::Image;
use coherent::gpu::shaders::QUERY_BOX_VERT;
use coherent_ash::{QueryBackend, QueryBackendDesc};
use coherent_cull::camera::{Camera, CameraPose};
use coherent_cull::chcpp::{Chcpp, ChcppParams};
use coherent_cull::glam::Vec3;
use coherent_cull::{CameraView, Culler, DepthConvention, FrameInput, Latency, ObjectBvh};

use crate::common;

/// The words coherent-ash ships must be what `shaders/query_box.vert` compiles to now: change
/// the GLSL without regenerating them and this fails. Regenerate with
/// `COHERENT_BLESS_SPIRV=1 cargo test --test gpu shipped_box_shader`.
#[test]
fn shipped_box_shader_is_current() {
    let shipped = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("crates/coherent-ash/spirv/query_box.vert.spv");
    if std::env::var_os("COHERENT_BLESS_SPIRV").is_some() {
        std::fs::write(&shipped, QUERY_BOX_VERT).expect("write the shipped SPIR-V");
    }
    let on_disk = std::fs::read(&shipped).expect("crates/coherent-ash/spirv/query_box.vert.spv");
    assert!(
        on_disk == QUERY_BOX_VERT && coherent_ash::QUERY_BOX_VERT_SPV == QUERY_BOX_VERT,
        "coherent-ash's shipped SPIR-V is stale: regenerate it with \
         COHERENT_BLESS_SPIRV=1 cargo test --test gpu shipped_box_shader"
    );
}

const W: u32 = 64;
const H: u32 = 64;

/// 16 unit boxes in a row along -z in front of the camera, at depths 5 to 35.
fn row() -> (ObjectBvh, Camera) {
    let boxes = (0..16).map(|i| {
        let z = -5.0 - 2.0 * i as f32;
        [[-0.5, -0.5, z - 1.0], [0.5, 0.5, z]]
    });
    let bvh = ObjectBvh::from_boxes(boxes, 1);
    let pose = CameraPose {
        eye: Vec3::new(0.0, 0.0, 0.0),
        target: Vec3::new(0.0, 0.0, -10.0),
    };
    (bvh, Camera::from_pose(pose, 1.0, 100.0))
}

/// A `W`x`H` D32 depth attachment.
fn depth_image(ctx: &std::sync::Arc<coherent::gpu::GpuContext>) -> Image {
    Image::new(
        ctx,
        "query test depth",
        vk::Format::D32_SFLOAT,
        (W, H),
        1,
        vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT,
    )
    .expect("depth image")
}

/// Depth (standard convention) of a point `d` in front of the camera.
fn depth_at(cam: &Camera, d: f32) -> f32 {
    let p = cam.view_proj() * coherent_cull::glam::Vec4::new(0.0, 0.0, -d, 1.0);
    p.z / p.w
}

/// Runs `frames` frames of chcpp in next-frame mode with `k` frames in flight through a
/// QueryBackend (one command pool, command buffer and fence per slot); the depth pass draws
/// nothing but is cleared to the depth of a wall `wall` units away, so boxes behind it are
/// hidden. Returns the objects drawn in each frame and the backend's counts of the last frame.
fn run_frames(frames: u64, wall: f32, k: u32) -> (Vec<Vec<u32>>, coherent_ash::QueryCounts) {
    let (ctx, log) = common::context();
    let result;
    {
        let (bvh, cam) = row();
        let d = &ctx.device;
        let depth = depth_image(&ctx);
        let desc = QueryBackendDesc {
            frames_in_flight: k,
            depth_format: vk::Format::D32_SFLOAT,
            depth: DepthConvention::STANDARD,
            max_queries: 256,
            max_boxes: 1024,
            ..QueryBackendDesc::default()
        };
        // SAFETY: the context's device has dynamic rendering and precise queries, and outlives
        // the backend (dropped at the end of this block after the device went idle).
        let mut queries = unsafe {
            QueryBackend::new(&ctx.instance, ctx.physical_device, d, desc).expect("backend")
        };
        // SAFETY: valid device; everything below is destroyed before the block ends.
        // One command pool per slot, reset whole when the slot is reused.
        let (pools, cmds, fences) = unsafe {
            let pools: Vec<vk::CommandPool> = (0..k)
                .map(|_| {
                    d.create_command_pool(
                        &vk::CommandPoolCreateInfo::default().queue_family_index(ctx.queue_family),
                        None,
                    )
                    .expect("pool")
                })
                .collect();
            let cmds: Vec<vk::CommandBuffer> = pools
                .iter()
                .map(|&pool| {
                    d.allocate_command_buffers(
                        &vk::CommandBufferAllocateInfo::default()
                            .command_pool(pool)
                            .command_buffer_count(1),
                    )
                    .expect("command buffer")[0]
                })
                .collect();
            let fences: Vec<vk::Fence> = (0..k)
                .map(|_| {
                    d.create_fence(
                        &vk::FenceCreateInfo::default().flags(vk::FenceCreateFlags::SIGNALED),
                        None,
                    )
                    .expect("fence")
                })
                .collect();
            (pools, cmds, fences)
        };
        let mut culler = Chcpp::new(ChcppParams::default())
            .with_latency(Latency::NextFrame)
            .with_frames_in_flight(k);
        let clear = depth_at(&cam, wall);
        let view: CameraView = (&cam).into();
        let view_proj = view.view_proj.to_cols_array();
        let mut drawn = Vec::new();
        for frame in 0..frames {
            let slot = (frame % u64::from(k)) as usize;
            let cmd = cmds[slot];
            let mut objects: Vec<u32> = Vec::new();
            // SAFETY: the slot's fence is waited for before its command buffer and queries are
            // reused; recording follows the backend's contract (begin outside rendering, frame
            // inside, end outside).
            unsafe {
                d.wait_for_fences(&[fences[slot]], true, u64::MAX)
                    .expect("wait");
                d.reset_fences(&[fences[slot]]).expect("reset fence");
                d.reset_command_pool(pools[slot], vk::CommandPoolResetFlags::empty())
                    .expect("reset");
                begin_depth_pass(d, cmd, &depth, clear, |cmd| {
                    queries.begin_frame(cmd, slot as u32).expect("begin_frame")
                });
            }
            let input = FrameInput {
                bvh: &bvh,
                view,
                frame,
                exact_visible: None,
            };
            let draw = |_: vk::CommandBuffer, o: &[u32], _rebind: bool| {
                objects.extend_from_slice(o);
                Ok(())
            };
            culler
                .cull_frame(&input, &mut queries.frame(cmd, view_proj, draw))
                .expect("cull_frame");
            // SAFETY: as above.
            unsafe {
                d.cmd_end_rendering(cmd);
                queries.end_frame(cmd).expect("end_frame");
                d.end_command_buffer(cmd).expect("end");
                d.queue_submit(
                    ctx.queue,
                    &[vk::SubmitInfo::default().command_buffers(&[cmd])],
                    fences[slot],
                )
                .expect("submit");
            }
            objects.sort_unstable();
            objects.dedup();
            drawn.push(objects);
        }
        result = (drawn, queries.counts());
        // SAFETY: the device is idle before anything is destroyed.
        unsafe {
            d.device_wait_idle().expect("idle");
            drop(queries);
            for f in fences {
                d.destroy_fence(f, None);
            }
            for p in pools {
                d.destroy_command_pool(p, None);
            }
        }
    }
    common::assert_silent(&log);
    result
}

/// With a wall between the 3rd and 4th box, the culler learns from results read two frames
/// late to draw the boxes in front of it and none far behind it. The box right behind the wall
/// may stay drawn: the box pipeline draws both faces with a depth bias of one pixel's depth
/// slope towards the eye (conservative: a query may see more pixels, never fewer), and the
/// edge-on side faces of a box straight ahead have a steep slope.
#[test]
fn query_backend_culls_what_the_depth_hides_two_frames_late() {
    let (drawn, counts) = run_frames(12, 10.5, 2);
    let last = drawn.last().expect("frames");
    assert!(
        [0, 1, 2].iter().all(|o| last.contains(o)),
        "a box in front of the wall is missing: {drawn:?}"
    );
    assert!(
        last.iter().all(|&o| o <= 3),
        "a box far behind the wall is still drawn: {drawn:?}"
    );
    // The first two frames have no results yet (read two frames late).
    assert!(drawn[..2].iter().all(|d| d.is_empty()), "{drawn:?}");
    assert!(counts.queries > 0, "{counts:?}");
    assert!(counts.results_read > 0, "{counts:?}");
    assert_eq!(counts.resets, 1, "{counts:?}");
    assert_eq!(counts.result_copies, 1, "{counts:?}");
    assert!(counts.pipeline_binds <= counts.queries, "{counts:?}");
}

/// Three frames in flight (triple buffering): results are read three frames late, and the
/// culler ends where it does with two.
#[test]
fn query_backend_with_three_frames_in_flight_reads_three_frames_late() {
    let (drawn, counts) = run_frames(14, 10.5, 3);
    assert!(drawn[..3].iter().all(|d| d.is_empty()), "{drawn:?}");
    assert!(
        !drawn[3].is_empty(),
        "nothing drawn once results came back: {drawn:?}"
    );
    let last = drawn.last().expect("frames");
    assert!([0, 1, 2].iter().all(|o| last.contains(o)), "{drawn:?}");
    assert!(last.iter().all(|&o| o <= 3), "{drawn:?}");
    assert_eq!(
        drawn.last(),
        run_frames(14, 10.5, 2).0.last(),
        "k = 3 against k = 2"
    );
    assert!(counts.results_read > 0, "{counts:?}");
}

/// Without the wall every box is seen, and every one ends up drawn.
#[test]
fn query_backend_draws_everything_that_is_visible() {
    let (drawn, _) = run_frames(10, 1000.0, 2);
    assert_eq!(
        drawn.last().expect("frames"),
        &(0..16).collect::<Vec<u32>>(),
        "drawn per frame: {drawn:?}"
    );
}

/// Begins `cmd`, records what `before` records outside rendering (a query reset), and begins a
/// depth-only rendering into `depth` (cleared to `clear`, after the writes of earlier frames),
/// viewport and scissor set; returns what `before` returned.
///
/// # Safety
/// `cmd` is in the initial state; `depth` is a `W`x`H` depth attachment of its device; `before`
/// records only commands valid outside rendering.
unsafe fn begin_depth_pass<T>(
    d: &ash::Device,
    cmd: vk::CommandBuffer,
    depth: &Image,
    clear: f32,
    before: impl FnOnce(vk::CommandBuffer) -> T,
) -> T {
    let range = vk::ImageSubresourceRange::default()
        .aspect_mask(vk::ImageAspectFlags::DEPTH)
        .level_count(1)
        .layer_count(1);
    let tests = vk::PipelineStageFlags2::EARLY_FRAGMENT_TESTS
        | vk::PipelineStageFlags2::LATE_FRAGMENT_TESTS;
    let to_attachment = vk::ImageMemoryBarrier2::default()
        .image(depth.handle)
        .subresource_range(range)
        .old_layout(vk::ImageLayout::UNDEFINED)
        .new_layout(vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL)
        .src_stage_mask(tests)
        .src_access_mask(vk::AccessFlags2::DEPTH_STENCIL_ATTACHMENT_WRITE)
        .dst_stage_mask(tests)
        .dst_access_mask(
            vk::AccessFlags2::DEPTH_STENCIL_ATTACHMENT_READ
                | vk::AccessFlags2::DEPTH_STENCIL_ATTACHMENT_WRITE,
        );
    let attachment = vk::RenderingAttachmentInfo::default()
        .image_view(depth.view)
        .image_layout(vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL)
        .load_op(vk::AttachmentLoadOp::CLEAR)
        .store_op(vk::AttachmentStoreOp::DONT_CARE)
        .clear_value(vk::ClearValue {
            depth_stencil: vk::ClearDepthStencilValue {
                depth: clear,
                stencil: 0,
            },
        });
    let extent = vk::Extent2D {
        width: W,
        height: H,
    };
    // SAFETY: per the caller.
    unsafe {
        d.begin_command_buffer(cmd, &vk::CommandBufferBeginInfo::default())
            .expect("begin");
        let out = before(cmd);
        d.cmd_pipeline_barrier2(
            cmd,
            &vk::DependencyInfo::default().image_memory_barriers(&[to_attachment]),
        );
        d.cmd_begin_rendering(
            cmd,
            &vk::RenderingInfo::default()
                .render_area(extent.into())
                .layer_count(1)
                .depth_attachment(&attachment),
        );
        d.cmd_set_viewport(
            cmd,
            0,
            &[vk::Viewport {
                x: 0.0,
                y: 0.0,
                width: W as f32,
                height: H as f32,
                min_depth: 0.0,
                max_depth: 1.0,
            }],
        );
        d.cmd_set_scissor(cmd, 0, &[extent.into()]);
        out
    }
}

/// Ends `cmd`, submits it and waits until the queue is idle.
///
/// # Safety
/// `cmd` is recording, outside rendering, on `ctx`'s device.
unsafe fn submit_and_wait(ctx: &coherent::gpu::GpuContext, cmd: vk::CommandBuffer) {
    let d = &ctx.device;
    // SAFETY: per the caller.
    unsafe {
        d.end_command_buffer(cmd).expect("end");
        d.queue_submit(
            ctx.queue,
            &[vk::SubmitInfo::default().command_buffers(&[cmd])],
            vk::Fence::null(),
        )
        .expect("submit");
        d.queue_wait_idle(ctx.queue).expect("wait");
    }
}

/// coherent-ash's building blocks on their own, as a host with its own frame uses them: a
/// `QuerySet` that grows by pools of 4 queries and buffers of 8 boxes while one command buffer
/// is recorded (reset from the host), drawn with a `BoxPipeline` on its own layout; one copy of
/// every result across the pool boundaries, read once the submission completed. Boxes in front
/// of a wall count samples, boxes far behind it none, a query whose boxes span several box
/// buffers sees its visible box; a set made at full size refuses a query past `max_queries`
/// and a query before its pipeline is bound, with errors that say so.
#[test]
fn query_set_grows_copies_across_pools_and_refuses_clearly() {
    use coherent_ash::{BoxPipeline, BoxPipelineDesc, QuerySet, QuerySetDesc};
    use coherent_cull::Aabb;
    let (ctx, log) = common::context();
    {
        let d = &ctx.device;
        let (bvh, cam) = row();
        let boxes: Vec<Aabb> = (0..16)
            .map(|o| bvh.object_bounds(o).expect("object"))
            .collect();
        let depth = depth_image(&ctx);
        let view: CameraView = (&cam).into();
        let view_proj = view.view_proj.to_cols_array();
        let growing = QuerySetDesc {
            queries_per_pool: 4,
            max_queries: 64,
            boxes_per_buffer: 8,
            max_boxes: 256,
            predicates: false,
            host_query_reset: true,
        };
        let full_size = QuerySetDesc {
            max_queries: 4,
            host_query_reset: false,
            ..growing.clone()
        };
        let pipeline_desc = BoxPipelineDesc {
            depth: DepthConvention::STANDARD,
            ..BoxPipelineDesc::default()
        };
        // SAFETY: the context's device has dynamic rendering, precise queries and host query
        // resets; everything is dropped after the device went idle, before the context.
        unsafe {
            let pipeline = BoxPipeline::new(d, &pipeline_desc).expect("box pipeline");
            let mut set =
                QuerySet::new(&ctx.instance, ctx.physical_device, d, growing).expect("query set");
            let mut small = QuerySet::new(&ctx.instance, ctx.physical_device, d, full_size)
                .expect("full-size query set");
            assert_eq!(set.capacity(), 4);
            assert_eq!(small.capacity(), 4);
            let pool = d
                .create_command_pool(
                    &vk::CommandPoolCreateInfo::default().queue_family_index(ctx.queue_family),
                    None,
                )
                .expect("pool");
            let cmd = d
                .allocate_command_buffers(
                    &vk::CommandBufferAllocateInfo::default()
                        .command_pool(pool)
                        .command_buffer_count(1),
                )
                .expect("command buffer")[0];
            set.reset_from_host().expect("host reset");
            let refused_reset = small.reset_from_host().expect_err("no host resets");
            assert!(
                refused_reset.to_string().contains("host_query_reset"),
                "{refused_reset}"
            );
            begin_depth_pass(d, cmd, &depth, depth_at(&cam, 10.5), |_| ());
            let unbound = set
                .record_query(cmd, &boxes[..1], None)
                .expect_err("a query before bind");
            assert!(unbound.to_string().contains("bind"), "{unbound}");
            set.bind(cmd, &pipeline, &view_proj);
            // One query per box (4 pools), then one of 12 boxes: the far ones first, so that
            // the visible box 0 is drawn from the fourth box buffer.
            for b in &boxes {
                set.record_query(cmd, std::slice::from_ref(b), None)
                    .expect("query");
            }
            let mut far_then_near: Vec<Aabb> = boxes[5..16].to_vec();
            far_then_near.push(boxes[0]);
            let spanning = set.record_query(cmd, &far_then_near, None).expect("query");
            let far_only = set.record_query(cmd, &boxes[6..16], None).expect("query");
            d.cmd_end_rendering(cmd);
            assert_eq!(set.record_copy(cmd), 18);
            assert_eq!(set.record_copy(cmd), 0, "a second copy has nothing new");
            submit_and_wait(&ctx, cmd);
            assert!(set.capacity() >= 18, "capacity {}", set.capacity());
            let results: Vec<Option<u32>> = (0..16).map(|q| set.copied_result(q)).collect();
            assert!(
                results[..3].iter().all(|r| r.is_some_and(|v| v > 0)),
                "boxes in front of the wall: {results:?}"
            );
            assert!(
                results[5..].iter().all(|r| *r == Some(0)),
                "boxes far behind the wall: {results:?}"
            );
            assert!(set.copied_result(spanning).is_some_and(|v| v > 0));
            assert_eq!(set.copied_result(far_only), Some(0));
            assert_eq!(set.copied_result(18), None, "never issued");
            let c = set.counts();
            assert_eq!((c.queries, c.query_boxes), (18, 16 + 12 + 10));
            assert!(c.box_draws > 18, "a query spanning box buffers: {c:?}");
            assert_eq!(c.result_copies, 5, "one copy per pool: {c:?}");

            // The full-size set: four queries, then a clear refusal.
            d.reset_command_pool(pool, vk::CommandPoolResetFlags::empty())
                .expect("reset pool");
            let resets = begin_depth_pass(d, cmd, &depth, 1.0, |cmd| small.record_reset(cmd));
            assert_eq!(resets, 1);
            small.bind(cmd, &pipeline, &view_proj);
            for b in &boxes[..4] {
                small
                    .record_query(cmd, std::slice::from_ref(b), None)
                    .expect("query");
            }
            let full = small
                .record_query(cmd, &boxes[..1], None)
                .expect_err("past max_queries");
            assert!(full.to_string().contains("max_queries"), "{full}");
            d.cmd_end_rendering(cmd);
            small.record_copy(cmd);
            submit_and_wait(&ctx, cmd);
            assert!((0..4).all(|q| small.copied_result(q).is_some_and(|v| v > 0)));
            drop(set);
            drop(small);
            drop(pipeline);
            d.destroy_command_pool(pool, None);
        }
    }
    drop(ctx);
    common::assert_silent(&log);
}
