//! coherent-ash's `QueryBackend` on a real device under strict validation (core,
//! synchronization, best practices): a culler in next-frame mode with two frames in flight,
//! queries recorded into a host command buffer inside a depth pass, results copied and read two
//! frames later, also with 4 samples, with two views in one command buffer and in a host's
//! `VkRenderPass` (next-frame and predicated), and in secondary command buffers (next-frame;
//! a frame without a resume refuses the predicated mode); the sample counts and view masks it refuses;
//! its building blocks (`QuerySet`, `BoxPipeline`) on their own, growing and copying across
//! pools; and the shipped SPIR-V of its box shader equals what the workspace's GLSL compiles
//! to.

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
/// The attachments' size, `W`x`H`.
pub(crate) const EXTENT: vk::Extent2D = vk::Extent2D {
    width: W,
    height: H,
};

/// 16 unit boxes in a row along -z in front of the camera, at depths 5 to 35.
pub(crate) fn row() -> (ObjectBvh, Camera) {
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

/// A `W`x`H` D32 depth attachment with `samples` samples.
fn depth_image(
    ctx: &std::sync::Arc<coherent::gpu::GpuContext>,
    samples: vk::SampleCountFlags,
) -> Image {
    Image::new_multisampled(
        ctx,
        "query test depth",
        vk::Format::D32_SFLOAT,
        (W, H),
        1,
        samples,
        vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT,
    )
    .expect("depth image")
}

/// Depth (standard convention) of a point `d` in front of the camera.
pub(crate) fn depth_at(cam: &Camera, d: f32) -> f32 {
    let p = cam.view_proj() * coherent_cull::glam::Vec4::new(0.0, 0.0, -d, 1.0);
    p.z / p.w
}

/// One view of a host frame in [`run_views`]: its own depth pass, cleared to the depth of a
/// wall `wall` units away (boxes behind it are hidden), with `samples` samples, and its own
/// `QueryBackend` and culler. `render_pass`: the depth pass is a `VkRenderPass` instance
/// instead of dynamic rendering; `predicated` (only with a render pass): the culler runs the
/// predicated mode, and the resume begins a second render pass whose depth LOADs;
/// `secondary`: the view's culler records into a secondary command buffer that continues the
/// primary's rendering (executed by it), as an engine that records its passes on several
/// threads.
#[derive(Clone, Copy)]
struct ViewSetup {
    wall: f32,
    samples: vk::SampleCountFlags,
    render_pass: bool,
    predicated: bool,
    secondary: bool,
}

impl ViewSetup {
    fn new(wall: f32) -> ViewSetup {
        ViewSetup {
            wall,
            samples: vk::SampleCountFlags::TYPE_1,
            render_pass: false,
            predicated: false,
            secondary: false,
        }
    }
}

/// A depth-only render pass for a view's pass: the depth CLEARs (or LOADs, for the resume
/// after a predicate resolve) and is stored only where `store` (a resume follows); the
/// dependency orders the depth writes of one frame's instance before the next.
///
/// # Safety
/// Valid device.
unsafe fn depth_render_pass(
    d: &ash::Device,
    samples: vk::SampleCountFlags,
    load: vk::AttachmentLoadOp,
    store: bool,
) -> vk::RenderPass {
    let layout = vk::ImageLayout::DEPTH_STENCIL_ATTACHMENT_OPTIMAL;
    let attachment = vk::AttachmentDescription::default()
        .format(vk::Format::D32_SFLOAT)
        .samples(samples)
        .load_op(load)
        .store_op(if store {
            vk::AttachmentStoreOp::STORE
        } else {
            vk::AttachmentStoreOp::DONT_CARE
        })
        .stencil_load_op(vk::AttachmentLoadOp::DONT_CARE)
        .stencil_store_op(vk::AttachmentStoreOp::DONT_CARE)
        .initial_layout(if load == vk::AttachmentLoadOp::LOAD {
            layout
        } else {
            vk::ImageLayout::UNDEFINED
        })
        .final_layout(layout);
    let depth_ref = vk::AttachmentReference::default()
        .attachment(0)
        .layout(layout);
    let subpass = vk::SubpassDescription::default()
        .pipeline_bind_point(vk::PipelineBindPoint::GRAPHICS)
        .depth_stencil_attachment(&depth_ref);
    let tests =
        vk::PipelineStageFlags::EARLY_FRAGMENT_TESTS | vk::PipelineStageFlags::LATE_FRAGMENT_TESTS;
    let depth_access = vk::AccessFlags::DEPTH_STENCIL_ATTACHMENT_READ
        | vk::AccessFlags::DEPTH_STENCIL_ATTACHMENT_WRITE;
    let dependency = vk::SubpassDependency::default()
        .src_subpass(vk::SUBPASS_EXTERNAL)
        .dst_subpass(0)
        .src_stage_mask(tests)
        .src_access_mask(vk::AccessFlags::DEPTH_STENCIL_ATTACHMENT_WRITE)
        .dst_stage_mask(tests)
        .dst_access_mask(depth_access);
    // SAFETY: per the caller.
    unsafe {
        d.create_render_pass(
            &vk::RenderPassCreateInfo::default()
                .attachments(std::slice::from_ref(&attachment))
                .subpasses(std::slice::from_ref(&subpass))
                .dependencies(std::slice::from_ref(&dependency)),
            None,
        )
    }
    .expect("render pass")
}

/// Begins `pass` on `framebuffer` (depth cleared to `clear`, or loaded where `clear` is
/// `None`) with `contents`; with `INLINE` contents, viewport and scissor set.
///
/// # Safety
/// `cmd` is recording outside rendering; the handles belong to `d`.
unsafe fn begin_render_pass(
    d: &ash::Device,
    cmd: vk::CommandBuffer,
    pass: vk::RenderPass,
    framebuffer: vk::Framebuffer,
    clear: Option<f32>,
    contents: vk::SubpassContents,
) {
    let clear: Vec<vk::ClearValue> = clear
        .map(|depth| vk::ClearValue {
            depth_stencil: vk::ClearDepthStencilValue { depth, stencil: 0 },
        })
        .into_iter()
        .collect();
    // SAFETY: per the caller.
    unsafe {
        d.cmd_begin_render_pass(
            cmd,
            &vk::RenderPassBeginInfo::default()
                .render_pass(pass)
                .framebuffer(framebuffer)
                .render_area(EXTENT.into())
                .clear_values(&clear),
            contents,
        );
        if contents == vk::SubpassContents::INLINE {
            set_viewport(d, cmd);
        }
    }
}

/// Sets the `W`x`H` viewport and scissor.
///
/// # Safety
/// `cmd` is recording on `d`.
pub(crate) unsafe fn set_viewport(d: &ash::Device, cmd: vk::CommandBuffer) {
    // SAFETY: per the caller.
    unsafe {
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
        d.cmd_set_scissor(cmd, 0, &[EXTENT.into()]);
    }
}

/// Runs `frames` frames of chcpp in next-frame mode with `k` frames in flight through a
/// QueryBackend (one command pool, command buffer and fence per slot); the depth pass draws
/// nothing but is cleared to the depth of a wall `wall` units away, so boxes behind it are
/// hidden. Returns the objects drawn in each frame and the backend's counts of the last frame.
fn run_frames(frames: u64, wall: f32, k: u32) -> (Vec<Vec<u32>>, coherent_ash::QueryCounts) {
    let view = ViewSetup::new(wall);
    let (mut drawn, mut counts) = run_views(frames, k, &[view]);
    (drawn.remove(0), counts.remove(0))
}

/// [`run_frames`] with several views in each host frame, as a host that culls a second camera
/// (a mirror, a split screen) in the same command buffer: each view has its own backend and
/// culler, every backend's frame begins before the first depth pass and ends after the last.
/// Returns, per view, the objects drawn in each frame and the counts of the last frame.
fn run_views(
    frames: u64,
    k: u32,
    views: &[ViewSetup],
) -> (Vec<Vec<Vec<u32>>>, Vec<coherent_ash::QueryCounts>) {
    let (ctx, log) = common::context();
    let result;
    {
        let (bvh, cam) = row();
        let d = &ctx.device;
        let depths: Vec<Image> = views.iter().map(|v| depth_image(&ctx, v.samples)).collect();
        // Per view with a render pass: the clearing pass, the loading pass of the resume (in the
        // predicated mode), and the framebuffer (both passes are compatible with it).
        let passes: Vec<Option<(vk::RenderPass, vk::RenderPass, vk::Framebuffer)>> = views
            .iter()
            .zip(&depths)
            .map(|(v, depth)| {
                assert!(
                    v.render_pass || !v.predicated,
                    "predicated needs a render pass here"
                );
                assert!(
                    !(v.secondary && v.predicated),
                    "a secondary that continues the rendering cannot end it for a resolve"
                );
                v.render_pass.then(|| {
                    // SAFETY: valid device; destroyed after the device went idle.
                    unsafe {
                        let (c, l) = (vk::AttachmentLoadOp::CLEAR, vk::AttachmentLoadOp::LOAD);
                        let clear = depth_render_pass(d, v.samples, c, v.predicated);
                        // (Null, which destroys as nothing, without a resume.)
                        let load = if v.predicated {
                            depth_render_pass(d, v.samples, l, true)
                        } else {
                            vk::RenderPass::null()
                        };
                        let framebuffer = d
                            .create_framebuffer(
                                &vk::FramebufferCreateInfo::default()
                                    .render_pass(clear)
                                    .attachments(&[depth.view])
                                    .width(W)
                                    .height(H)
                                    .layers(1),
                                None,
                            )
                            .expect("framebuffer");
                        (clear, load, framebuffer)
                    }
                })
            })
            .collect();
        let mut backends: Vec<QueryBackend> = views
            .iter()
            .zip(&passes)
            .map(|(v, pass)| {
                let desc = QueryBackendDesc {
                    frames_in_flight: k,
                    depth_format: vk::Format::D32_SFLOAT,
                    samples: v.samples,
                    render_pass: pass.map_or(vk::RenderPass::null(), |p| p.0),
                    predicates: v.predicated,
                    depth: DepthConvention::STANDARD,
                    max_queries: 256,
                    max_boxes: 1024,
                    ..QueryBackendDesc::default()
                };
                // SAFETY: the context's device has dynamic rendering and precise queries, and
                // outlives the backend (dropped at the end of this block after the device went
                // idle).
                unsafe {
                    QueryBackend::new(&ctx.instance, ctx.physical_device, d, desc).expect("backend")
                }
            })
            .collect();
        // SAFETY: valid device; everything below is destroyed before the block ends.
        let (slots, secondaries) = unsafe {
            let slots = FrameSlots::new(d, ctx.queue_family, k);
            // Per slot, one secondary command buffer per view (used by views with `secondary`).
            let secondaries: Vec<Vec<vk::CommandBuffer>> = slots
                .0
                .iter()
                .map(|&(pool, _, _)| {
                    d.allocate_command_buffers(
                        &vk::CommandBufferAllocateInfo::default()
                            .command_pool(pool)
                            .level(vk::CommandBufferLevel::SECONDARY)
                            .command_buffer_count(views.len() as u32),
                    )
                    .expect("secondary command buffers")
                })
                .collect();
            (slots, secondaries)
        };
        let mut cullers: Vec<Chcpp> = views
            .iter()
            .map(|v| {
                let latency = if v.predicated {
                    Latency::Predicated
                } else {
                    Latency::NextFrame
                };
                Chcpp::new(ChcppParams::default())
                    .with_latency(latency)
                    .with_frames_in_flight(k)
            })
            .collect();
        let view: CameraView = (&cam).into();
        let view_proj = view.view_proj.to_cols_array();
        let mut drawn: Vec<Vec<Vec<u32>>> = vec![Vec::new(); views.len()];
        for frame in 0..frames {
            let slot = (frame % u64::from(k)) as usize;
            // SAFETY: the slot's fence is waited for before its command buffer and queries are
            // reused; recording follows the backend's contract (begin outside rendering, frame
            // inside, end outside).
            let cmd = unsafe { slots.begin(d, slot) };
            // SAFETY: as above.
            unsafe {
                for queries in &mut backends {
                    queries.begin_frame(cmd, slot as u32).expect("begin_frame");
                }
            }
            for (i, setup) in views.iter().enumerate() {
                let mut objects: Vec<u32> = Vec::new();
                // Beyond the far plane: cleared to the far plane.
                let clear = depth_at(&cam, setup.wall).min(1.0);
                // SAFETY: as above; the depth image and passes belong to the device. A
                // secondary continues the primary's rendering: begun with the inheritance of
                // its pass (or its formats), it sets its own viewport and scissor.
                let cmd = unsafe {
                    let (contents, flags) = if setup.secondary {
                        (
                            vk::SubpassContents::SECONDARY_COMMAND_BUFFERS,
                            vk::RenderingFlags::CONTENTS_SECONDARY_COMMAND_BUFFERS,
                        )
                    } else {
                        (vk::SubpassContents::INLINE, vk::RenderingFlags::empty())
                    };
                    match passes[i] {
                        Some((pass, _, framebuffer)) => {
                            begin_render_pass(d, cmd, pass, framebuffer, Some(clear), contents)
                        }
                        None => depth_pass(d, cmd, &depths[i], clear, flags),
                    }
                    if setup.secondary {
                        let secondary = secondaries[slot][i];
                        let formats = [vk::Format::UNDEFINED; 0];
                        let mut rendering = vk::CommandBufferInheritanceRenderingInfo::default()
                            .color_attachment_formats(&formats)
                            .depth_attachment_format(vk::Format::D32_SFLOAT)
                            .rasterization_samples(setup.samples);
                        let mut inheritance = vk::CommandBufferInheritanceInfo::default();
                        inheritance = match passes[i] {
                            Some((pass, _, framebuffer)) => inheritance
                                .render_pass(pass)
                                .subpass(0)
                                .framebuffer(framebuffer),
                            None => inheritance.push_next(&mut rendering),
                        };
                        d.begin_command_buffer(
                            secondary,
                            &vk::CommandBufferBeginInfo::default()
                                .flags(
                                    vk::CommandBufferUsageFlags::RENDER_PASS_CONTINUE
                                        | vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT,
                                )
                                .inheritance_info(&inheritance),
                        )
                        .expect("begin secondary");
                        set_viewport(d, secondary);
                        secondary
                    } else {
                        cmd
                    }
                };
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
                let mut frame = backends[i].frame(cmd, view_proj, draw);
                if let Some((_, load, framebuffer)) = passes[i].filter(|_| setup.predicated) {
                    frame = frame.with_resume(move |cmd| {
                        // SAFETY: the backend ended the pass; the loading pass resumes it.
                        unsafe {
                            let inline = vk::SubpassContents::INLINE;
                            begin_render_pass(d, cmd, load, framebuffer, None, inline)
                        };
                        Ok(())
                    });
                }
                cullers[i]
                    .cull_frame(&input, &mut frame)
                    .expect("cull_frame");
                drop(frame);
                // SAFETY: inside the rendering begun above (or resumed); a secondary is ended
                // and executed inside the primary's rendering.
                unsafe {
                    let cmd = slots.0[slot].1;
                    if setup.secondary {
                        d.end_command_buffer(secondaries[slot][i])
                            .expect("end secondary");
                        d.cmd_execute_commands(cmd, &[secondaries[slot][i]]);
                    }
                    if passes[i].is_some() {
                        d.cmd_end_render_pass(cmd);
                    } else {
                        d.cmd_end_rendering(cmd);
                    }
                };
                objects.sort_unstable();
                objects.dedup();
                drawn[i].push(objects);
            }
            // SAFETY: as above.
            unsafe {
                for queries in &mut backends {
                    queries.end_frame(cmd).expect("end_frame");
                }
                slots.submit(d, ctx.queue, slot);
            }
        }
        result = (drawn, backends.iter().map(|b| b.counts()).collect());
        // SAFETY: the device is idle before anything is destroyed.
        unsafe {
            d.device_wait_idle().expect("idle");
            drop(backends);
            slots.destroy(d);
            for (clear, load, framebuffer) in passes.into_iter().flatten() {
                d.destroy_framebuffer(framebuffer, None);
                d.destroy_render_pass(clear, None);
                d.destroy_render_pass(load, None);
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
    assert_walled(&drawn, 3);
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
    assert_walled(&drawn, 3);
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
    assert_all_drawn(&drawn);
}

/// The last of a view's `frames` (objects drawn per frame) has the three boxes in front of the
/// wall 10.5 units away and no box past `last_box`.
pub(crate) fn assert_walled(frames: &[Vec<u32>], last_box: u32) {
    let last = frames.last().expect("frames");
    assert!(
        [0, 1, 2].iter().all(|o| last.contains(o)),
        "a box in front of the wall is missing: {frames:?}"
    );
    assert!(
        last.iter().all(|&o| o <= last_box),
        "a box far behind the wall is still drawn: {frames:?}"
    );
}

/// Every one of a predicated view's `frames` hands over the three boxes in front of the wall
/// (drawn, or under a predicate).
pub(crate) fn assert_front_in_every_frame(frames: &[Vec<u32>]) {
    for (f, objects) in frames.iter().enumerate() {
        assert!(
            [0, 1, 2].iter().all(|o| objects.contains(o)),
            "frame {f}: {frames:?}"
        );
    }
}

/// The last of a view's `frames` draws all 16 boxes.
fn assert_all_drawn(frames: &[Vec<u32>]) {
    assert_eq!(
        frames.last().expect("frames"),
        &(0..16).collect::<Vec<u32>>(),
        "drawn per frame: {frames:?}"
    );
}

/// Two views in one host frame, each with its own backend and culler (a wall close in front of
/// the first, none in front of the second): their queries share a command buffer and their
/// results stay apart. Each view ends where it ends alone.
#[test]
fn query_backend_keeps_two_views_of_one_frame_apart() {
    let views = [ViewSetup::new(10.5), ViewSetup::new(1000.0)];
    let (drawn, counts) = run_views(12, 2, &views);
    assert_walled(&drawn[0], 3);
    assert_all_drawn(&drawn[1]);
    assert_eq!(drawn[0].last(), run_frames(12, 10.5, 2).0.last());
    // (In the last frame only the walled view has hidden boxes left to query.)
    assert!(
        counts[0].queries > 0 && counts[0].results_read > 0,
        "{counts:?}"
    );
}

/// Runs `views` (12 frames, two in flight) beside an inline view with dynamic rendering and a
/// wall 10.5 units away in the same command buffer: each view with a wall that close ends as
/// the inline view ends (boxes behind the wall culled, from results it read), each view
/// without one draws every box.
fn assert_views_end_as_inline(views: &[ViewSetup]) {
    let mut all = views.to_vec();
    all.push(ViewSetup::new(10.5));
    let (drawn, counts) = run_views(12, 2, &all);
    let inline = drawn.last().expect("the inline view");
    assert_walled(inline, 3);
    for (i, v) in views.iter().enumerate() {
        if v.wall < 100.0 {
            assert_eq!(drawn[i].last(), inline.last(), "view {i}: {drawn:?}");
            assert!(
                counts[i].queries > 0 && counts[i].results_read > 0,
                "view {i}: {counts:?}"
            );
        } else {
            assert_all_drawn(&drawn[i]);
        }
    }
}

/// A host that records its depth pass in a `VkRenderPass` (no dynamic rendering): the box
/// pipeline is made for its subpass, and the culler ends where it ends with dynamic rendering,
/// with 1 and 4 samples, beside a view with dynamic rendering in the same command buffer.
#[test]
fn query_backend_draws_inside_a_host_render_pass() {
    let pass = |wall, samples| ViewSetup {
        samples,
        render_pass: true,
        ..ViewSetup::new(wall)
    };
    assert_views_end_as_inline(&[
        pass(10.5, vk::SampleCountFlags::TYPE_1),
        pass(1000.0, vk::SampleCountFlags::TYPE_4),
    ]);
}

/// A host that records its depth pass in secondary command buffers continuing the primary's
/// rendering (dynamic rendering with `CONTENTS_SECONDARY_COMMAND_BUFFERS`, or a render pass
/// with `SECONDARY_COMMAND_BUFFERS` contents): the backend's queries and box draws go into the
/// secondary, its reset and copy into the primary. Each view ends where it ends inline.
#[test]
fn query_backend_records_into_the_hosts_secondary_command_buffers() {
    let secondary = |wall, render_pass| ViewSetup {
        secondary: true,
        render_pass,
        ..ViewSetup::new(wall)
    };
    assert_views_end_as_inline(&[
        secondary(10.5, false),
        secondary(10.5, true),
        secondary(1000.0, false),
        secondary(1000.0, true),
    ]);
}

/// A predicated culler on a frame made without `with_resume` (as a host whose depth pass is a
/// secondary command buffer continuing the primary's rendering must make it: the backend
/// cannot end that rendering for a resolve) is refused with an error that names what is
/// missing, before anything is recorded; the same backend then runs a next-frame culler.
#[test]
fn query_backend_without_a_resume_refuses_the_predicated_mode() {
    let (ctx, log) = common::context();
    {
        let d = &ctx.device;
        let (bvh, cam) = row();
        let depth = depth_image(&ctx, vk::SampleCountFlags::TYPE_1);
        let view: CameraView = (&cam).into();
        let view_proj = view.view_proj.to_cols_array();
        let desc = QueryBackendDesc {
            predicates: true,
            depth: DepthConvention::STANDARD,
            max_queries: 64,
            ..QueryBackendDesc::default()
        };
        // SAFETY: the context's device has dynamic rendering, precise queries and conditional
        // rendering; everything is dropped after the device went idle, before the context.
        unsafe {
            let mut queries = QueryBackend::new(&ctx.instance, ctx.physical_device, d, desc)
                .expect("backend with predicates");
            let (pool, cmd) = command_buffer(d, ctx.queue_family);
            begin_depth_pass(d, cmd, &depth, 1.0, |cmd| {
                queries.begin_frame(cmd, 0).expect("begin_frame")
            });
            let input = FrameInput {
                bvh: &bvh,
                view,
                frame: 0,
                exact_visible: None,
            };
            let mut drawn = 0;
            let mut draw = |_: vk::CommandBuffer, o: &[u32], _: bool| {
                drawn += o.len();
                Ok(())
            };
            let mut predicated = Chcpp::new(ChcppParams::default())
                .with_latency(Latency::Predicated)
                .with_frames_in_flight(2);
            let mut frame = queries.frame(cmd, view_proj, &mut draw);
            let err = predicated
                .cull_frame(&input, &mut frame)
                .expect_err("no resume");
            assert!(
                err.to_string().contains("FrameBackend::with_resume"),
                "{err}"
            );
            drop(frame);
            assert_eq!(queries.counts().queries, 0, "recorded before the refusal");
            let mut next = Chcpp::new(ChcppParams::default())
                .with_latency(Latency::NextFrame)
                .with_frames_in_flight(2);
            let mut frame = queries.frame(cmd, view_proj, &mut draw);
            next.cull_frame(&input, &mut frame).expect("next-frame");
            drop(frame);
            d.cmd_end_rendering(cmd);
            queries.end_frame(cmd).expect("end_frame");
            submit_and_wait(&ctx, cmd);
            assert!(queries.counts().queries > 0, "{:?}", queries.counts());
            assert_eq!(drawn, 0, "nothing drawn before results arrive");
            d.destroy_command_pool(pool, None);
        }
    }
    common::assert_silent(&log);
}

/// The predicated mode in a host render pass: each predicate resolve ends the render pass
/// instance (`vkCmdEndRenderPass`) and the host's resume begins one that LOADs the depth; one
/// submission a frame, strict validation silent. Exact from the first frame: the boxes in front
/// of the wall are handed over in every frame (drawn or under a predicate).
#[test]
fn query_backend_resolves_predicates_inside_a_host_render_pass() {
    let view = ViewSetup {
        render_pass: true,
        predicated: true,
        ..ViewSetup::new(10.5)
    };
    let (drawn, counts) = run_views(10, 2, &[view]);
    assert_front_in_every_frame(&drawn[0]);
    assert!(counts[0].resolves > 0, "{counts:?}");
    assert!(counts[0].queries > 0, "{counts:?}");
}

/// With 4 samples (every device has them on depth attachments) the box pipeline and the
/// queries run under strict validation and cull what the depth hides. Behind the wall they may
/// keep one box more drawn than with one sample: the box pipeline's conservative depth bias
/// (above) on the edge-on side faces meets more sample positions. Without the wall every box
/// is drawn, as with one sample.
#[test]
fn query_backend_with_four_samples_culls_what_the_depth_hides() {
    let four = |wall| {
        let (drawn, counts) = run_views(
            12,
            2,
            &[ViewSetup {
                samples: vk::SampleCountFlags::TYPE_4,
                ..ViewSetup::new(wall)
            }],
        );
        (drawn.into_iter().next().expect("one view"), counts[0])
    };
    let (drawn, counts) = four(10.5);
    assert!(counts.results_read > 0, "{counts:?}");
    assert_walled(&drawn, 4);
    let (drawn, _) = four(1000.0);
    assert_all_drawn(&drawn);
}

/// A sample count that is not one count, or that the device cannot render depth with, and a
/// view mask beyond the device's views are refused by `QueryBackend::new` with errors that
/// name them, before any pipeline is made.
#[test]
fn query_backend_refuses_samples_and_views_the_device_lacks() {
    let (ctx, log) = common::context();
    let make = |samples: vk::SampleCountFlags, view_mask: u32| {
        let desc = QueryBackendDesc {
            depth_format: vk::Format::D32_SFLOAT,
            samples,
            view_mask,
            ..QueryBackendDesc::default()
        };
        // SAFETY: the context's handles belong together; a backend made is dropped at once.
        unsafe { QueryBackend::new(&ctx.instance, ctx.physical_device, &ctx.device, desc) }
            .err()
            .map(|e| e.to_string())
    };
    let two = make(
        vk::SampleCountFlags::TYPE_1 | vk::SampleCountFlags::TYPE_4,
        0,
    );
    assert!(
        two.as_deref()
            .is_some_and(|e| e.contains("exactly one sample count")),
        "{two:?}"
    );
    assert!(make(vk::SampleCountFlags::empty(), 0).is_some());
    // SAFETY: the context's handles.
    let limits = unsafe {
        ctx.instance
            .get_physical_device_properties(ctx.physical_device)
    }
    .limits;
    let lacking = [2u32, 8, 16, 32, 64]
        .map(vk::SampleCountFlags::from_raw)
        .into_iter()
        .find(|&s| !limits.framebuffer_depth_sample_counts.contains(s));
    if let Some(s) = lacking {
        let e = make(s, 0);
        assert!(
            e.as_deref()
                .is_some_and(|e| e.contains("framebufferDepthSampleCounts")),
            "{s:?}: {e:?}"
        );
    }
    // A view the device lacks: the first past maxMultiviewViewCount (a 32-bit mask cannot pass
    // a device with 32 views, such as NVIDIA's, so there only multiview itself is checked).
    let mut multiview = vk::PhysicalDeviceMultiviewProperties::default();
    let mut p2 = vk::PhysicalDeviceProperties2::default().push_next(&mut multiview);
    // SAFETY: the context's handles; the chain outlives the call.
    unsafe {
        ctx.instance
            .get_physical_device_properties2(ctx.physical_device, &mut p2)
    };
    let max_views = multiview.max_multiview_view_count;
    if max_views < 32 {
        let views = make(vk::SampleCountFlags::TYPE_1, 1 << max_views);
        assert!(
            views
                .as_deref()
                .is_some_and(|e| e.contains("multiview") || e.contains("maxMultiviewViewCount")),
            "{views:?}"
        );
    }
    assert_eq!(make(vk::SampleCountFlags::TYPE_1, 0), None);
    assert_eq!(make(vk::SampleCountFlags::TYPE_4, 0), None);
    common::assert_silent(&log);
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
    // SAFETY: per the caller.
    unsafe {
        d.begin_command_buffer(cmd, &vk::CommandBufferBeginInfo::default())
            .expect("begin");
        let out = before(cmd);
        depth_pass(d, cmd, depth, clear, vk::RenderingFlags::empty());
        out
    }
}

/// Records into `cmd` (recording, outside rendering) a depth-only rendering into `depth`
/// (cleared to `clear`, after the writes of earlier frames) with `flags`; without
/// `CONTENTS_SECONDARY_COMMAND_BUFFERS`, viewport and scissor set.
///
/// # Safety
/// `cmd` is recording outside rendering; `depth` is a `W`x`H` depth attachment of its device.
unsafe fn depth_pass(
    d: &ash::Device,
    cmd: vk::CommandBuffer,
    depth: &Image,
    clear: f32,
    flags: vk::RenderingFlags,
) {
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
    // SAFETY: per the caller.
    unsafe {
        d.cmd_pipeline_barrier2(
            cmd,
            &vk::DependencyInfo::default().image_memory_barriers(&[to_attachment]),
        );
        d.cmd_begin_rendering(
            cmd,
            &vk::RenderingInfo::default()
                .flags(flags)
                .render_area(EXTENT.into())
                .layer_count(1)
                .depth_attachment(&attachment),
        );
        if !flags.contains(vk::RenderingFlags::CONTENTS_SECONDARY_COMMAND_BUFFERS) {
            set_viewport(d, cmd);
        }
    }
}

/// A command pool on queue family `family` of `d` and one primary command buffer of it
/// (destroy the pool when done).
///
/// # Safety
/// Valid device and family.
pub(crate) unsafe fn command_buffer(
    d: &ash::Device,
    family: u32,
) -> (vk::CommandPool, vk::CommandBuffer) {
    // SAFETY: per the caller.
    unsafe {
        let pool = d
            .create_command_pool(
                &vk::CommandPoolCreateInfo::default().queue_family_index(family),
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
        (pool, cmd)
    }
}

/// What a host keeps per frame-in-flight slot: a command pool (reset whole when the slot is
/// reused), its primary command buffer, and a fence (created signaled).
pub(crate) struct FrameSlots(pub(crate) Vec<(vk::CommandPool, vk::CommandBuffer, vk::Fence)>);

impl FrameSlots {
    /// `k` slots on queue family `family` of `d`.
    ///
    /// # Safety
    /// Valid device and family; [`FrameSlots::destroy`] before the device.
    pub(crate) unsafe fn new(d: &ash::Device, family: u32, k: u32) -> FrameSlots {
        // SAFETY: per the caller.
        FrameSlots(
            (0..k)
                .map(|_| unsafe {
                    let (pool, cmd) = command_buffer(d, family);
                    let fence = d
                        .create_fence(
                            &vk::FenceCreateInfo::default().flags(vk::FenceCreateFlags::SIGNALED),
                            None,
                        )
                        .expect("fence");
                    (pool, cmd, fence)
                })
                .collect(),
        )
    }

    /// Waits for `slot`'s previous frame, resets its fence and pool, and begins and returns its
    /// command buffer.
    ///
    /// # Safety
    /// The slots' device is `d`.
    pub(crate) unsafe fn begin(&self, d: &ash::Device, slot: usize) -> vk::CommandBuffer {
        let (pool, cmd, fence) = self.0[slot];
        // SAFETY: per the caller; the fence guards the pool's reuse.
        unsafe {
            d.wait_for_fences(&[fence], true, u64::MAX).expect("wait");
            d.reset_fences(&[fence]).expect("reset fence");
            d.reset_command_pool(pool, vk::CommandPoolResetFlags::empty())
                .expect("reset pool");
            d.begin_command_buffer(cmd, &vk::CommandBufferBeginInfo::default())
                .expect("begin");
        }
        cmd
    }

    /// Ends `slot`'s command buffer and submits it to `queue` with the slot's fence.
    ///
    /// # Safety
    /// The slot's command buffer is recording outside rendering on `d`.
    pub(crate) unsafe fn submit(&self, d: &ash::Device, queue: vk::Queue, slot: usize) {
        let (_, cmd, fence) = self.0[slot];
        // SAFETY: per the caller.
        unsafe {
            d.end_command_buffer(cmd).expect("end");
            d.queue_submit(
                queue,
                &[vk::SubmitInfo::default().command_buffers(&[cmd])],
                fence,
            )
            .expect("submit");
        }
    }

    /// Destroys the fences and pools.
    ///
    /// # Safety
    /// The device is done with them.
    pub(crate) unsafe fn destroy(self, d: &ash::Device) {
        for (pool, _, fence) in self.0 {
            // SAFETY: per the caller.
            unsafe {
                d.destroy_fence(fence, None);
                d.destroy_command_pool(pool, None);
            }
        }
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
        let depth = depth_image(&ctx, vk::SampleCountFlags::TYPE_1);
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
            let (pool, cmd) = command_buffer(d, ctx.queue_family);
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
