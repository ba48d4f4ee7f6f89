//! # coherent-ash
//!
//! What an [ash](https://docs.rs/ash) host needs to run a [`coherent_cull`] culler inside its own
//! frame: [`QueryBackend`], an [`OcclusionBackend`] that records into the host's command buffer
//! on the host's `ash::Device`, inside the host's depth pass (dynamic rendering or the host's
//! render pass), with `k` frames in flight. It owns the query side and nothing else:
//!
//! - one precise occlusion query pool per frame-in-flight slot, reset inside the frame that
//!   reuses the slot (`vkCmdResetQueryPool`, before the host begins rendering);
//! - the results, copied at the end of the frame with `vkCmdCopyQueryPoolResults` (value and
//!   availability) into host-visible memory and read when the host starts the slot's next
//!   frame, after it waited for the slot's fence: `vkGetQueryPoolResults` is never called (on
//!   some drivers, lavapipe among them, it waits for the whole device);
//! - the box pipeline for the host's attachment formats and depth convention (depth test
//!   *or-equal* towards the eye, a small depth bias towards the eye, no writes), its SPIR-V
//!   shipped inside this crate: no shaderc, no C++ toolchain;
//! - counts of what it recorded ([`QueryCounts`]): queries, boxes, pipeline binds, state
//!   changes, the host's draw calls.
//!
//! The host keeps its device, its frame loop, its command buffers and its draws: the culler's
//! "draw these objects" comes back to the host through a callback.
//!
//! ## A frame
//!
//! ```no_run
//! # use ash::vk;
//! # use coherent_ash::{QueryBackend, QueryBackendDesc};
//! # use coherent_cull::chcpp::{Chcpp, ChcppParams};
//! # use coherent_cull::{CameraView, Culler, DepthConvention, FrameInput, Latency, ObjectBvh};
//! # fn host(instance: &ash::Instance, physical_device: vk::PhysicalDevice, device: &ash::Device,
//! #         cmd: vk::CommandBuffer, bvh: &ObjectBvh, view_proj: [f32; 16], eye: [f32; 3],
//! #         frame: u64) -> Result<(), Box<dyn std::error::Error>> {
//! let desc = QueryBackendDesc {
//!     frames_in_flight: 2,
//!     depth_format: vk::Format::D32_SFLOAT,
//!     depth: DepthConvention::REVERSE_Z_INFINITE,
//!     ..QueryBackendDesc::default()
//! };
//! // Once, after creating the device (with `occlusionQueryPrecise` enabled).
//! let mut queries = unsafe { QueryBackend::new(instance, physical_device, device, desc)? };
//! let mut culler = Chcpp::new(ChcppParams::default())
//!     .with_latency(Latency::NextFrame)
//!     .with_frames_in_flight(2);
//!
//! // Each frame, in slot `frame % 2`, after waiting for the slot's fence, before rendering:
//! unsafe { queries.begin_frame(cmd, (frame % 2) as u32)? };
//! // ... vkCmdBeginRendering (the depth pass), viewport and scissor set ...
//! // One sample a pixel: objects between pixel centres are culled too (see `PixelGrid`).
//! let view = CameraView::new(view_proj, eye, DepthConvention::REVERSE_Z_INFINITE)
//!     .with_pixel_grid(1920, 1080);
//! let input = FrameInput { bvh, view, frame, exact_visible: None };
//! let mut backend = queries.frame(cmd, view_proj, |cmd, objects: &[u32], rebind| {
//!     // if rebind: bind the host's pipeline, descriptor sets and push constants again;
//!     // then record the draws of `objects` into `cmd`.
//!     Ok(())
//! });
//! culler.cull_frame(&input, &mut backend)?;
//! drop(backend);
//! // ... vkCmdEndRendering ...
//! unsafe { queries.end_frame(cmd)? };
//! // ... end the command buffer, one vkQueueSubmit with the slot's fence ...
//! # Ok(()) }
//! ```
//!
//! ## What the culler may ask
//!
//! A [`QueryBackend`] frame supports the latency modes of `coherent-cull` with `k` frames in
//! flight (`Latency::NextFrame`, `Latency::NextFrameConservative` or, see below,
//! `Latency::Predicated`,
//! `Chcpp::with_frames_in_flight(k)` with `k` at least 2 and at most the backend's
//! `frames_in_flight`): one submission per frame and no waits. It refuses, with
//! [`coherent_cull::Error::Unsupported`], what would need the host to submit or wait inside
//! its frame: `flush` and `wait_query` (the in-frame mode and stop-and-wait), and `finish`
//! (a culler reading its results in the same frame, `k = 1`).
//!
//! ## Predicated frames
//!
//! `Latency::Predicated` (exact, one submission per frame, no wait) draws the nodes that were
//! invisible under their queries' predicates on the device. It needs `VK_EXT_conditional_rendering`
//! with `conditionalRendering` enabled on the host's device, [`QueryBackendDesc::predicates`]
//! set, and the frame made with [`FrameBackend::with_resume`]: once or twice per frame the
//! backend ends the host's rendering, copies the results issued so far (32-bit, `WAIT`) into
//! a predicate buffer with a barrier to `CONDITIONAL_RENDERING_READ`, and calls the host's
//! resume, which begins the depth pass again with LOAD ops (so the first pass must STORE
//! depth). The draws that follow come back through the same draw callback, inside
//! `vkCmdBeginConditionalRenderingEXT` / `vkCmdEndConditionalRenderingEXT`. The second resolve
//! follows the queries of the parts of split nodes, whose boxes the backend draws inside a
//! conditional block on their node's predicate (`OcclusionBackend::issue_query_if`). Without the
//! extension [`QueryBackend::new`] refuses `predicates` with an error that names it; a frame
//! without a resume makes the culler refuse the mode. The culler also hands over its draw
//! order ([`DrawObjects::set_order`]): each subtree's objects are contiguous in it, and the
//! objects of a conditional block come as ranges of it ([`DrawObjects::draw_ranges`]), so a
//! host that keeps one indirect command per object in that order draws a range as one
//! multi-draw without looking at its objects (the built-in renderer of the `coherent` package
//! does; at the city's x16 scale about 100,000 objects a frame go under predicates). On a
//! GPU, create the culler with `ChcppParams::for_gpu()`: one resolve a frame and no split
//! nodes, since recording the parts costs a GPU host more CPU time than the few objects they
//! save (NVIDIA H100, the `coherent` city street: 2.12x the oracle's frame against 3.09x;
//! `examples/engine.rs` picks it by device type).
//!
//! ## Building blocks for a frame of your own
//!
//! [`QueryBackend`] is made of two public parts that a host with another frame structure can
//! use directly (the built-in renderer of the `coherent` package does: it submits and waits
//! inside a frame for the in-frame modes and stop-and-wait, which [`QueryBackend`] refuses):
//!
//! - [`QuerySet`]: the occlusion queries of one frame, growing (pools of
//!   [`QuerySetDesc::queries_per_pool`], reset from the host with `hostQueryReset`, or made at
//!   full size and reset by a command), the box corners they draw, the copies of their results
//!   into host memory (as often as the host submits: [`QuerySet::record_copy`] copies what was
//!   issued since the last copy), and their predicates and conditional blocks, all counted;
//! - [`BoxPipeline`]: the box pipeline for the host's formats and depth convention, on its own
//!   layout or on the host's ([`BoxPipelineDesc::layout`], sharing the host's push block), with
//!   back faces culled when the host says how its viewport winds them.
//!
//! ## Several views, multisampling
//!
//! A host that culls more than one camera in a frame (a mirror, a split screen, a shadow
//! view) makes one [`QueryBackend`] and one culler per view: each backend has its own query
//! pools, result memory and box pipeline, so the views' queries can share a command buffer
//! without their results mixing. Begin every backend's frame before the first rendering and
//! end them after the last. With multisampled attachments set [`QueryBackendDesc::samples`]:
//! the queries then count samples, not pixels.
//!
//! ## Secondary command buffers
//!
//! A host that records its depth pass in a secondary command buffer that continues the
//! primary's rendering (`VK_RENDERING_CONTENTS_SECONDARY_COMMAND_BUFFERS_BIT`, or
//! `VK_SUBPASS_CONTENTS_SECONDARY_COMMAND_BUFFERS`) passes that secondary to
//! [`QueryBackend::frame`], and the primary to [`QueryBackend::begin_frame`] and
//! [`QueryBackend::end_frame`] (outside the rendering, before and after the secondary is
//! executed). Begin the secondary with `RENDER_PASS_CONTINUE` and the inheritance of the
//! host's formats and samples (or its render pass and subpass), and set viewport and scissor
//! in it: the box pipeline uses them as dynamic state, which a secondary does not inherit.
//! The queries begin and end inside the secondary, so the device needs no `inheritedQueries`.
//! Such a secondary cannot end the rendering it continues, so the predicated mode, whose
//! resolves end and resume the rendering, needs the depth pass in a command buffer that
//! began it: a frame without [`FrameBackend::with_resume`] makes a predicated culler refuse
//! with an error that names it. The next-frame modes work in secondaries.
//!
//! ## Requirements
//!
//! `occlusionQueryPrecise` enabled on the device ([`QueryBackend::new`] checks that the
//! physical device has it and says so if not), and a depth pass recorded either with dynamic
//! rendering (Vulkan 1.3, or 1.2 with `VK_KHR_dynamic_rendering`, `dynamicRendering` enabled)
//! or in the host's `VkRenderPass` ([`QueryBackendDesc::render_pass`] and `subpass`). The
//! host's rendering must match the formats, samples and view mask of [`QueryBackendDesc`]
//! (the device must support them there, which [`QueryBackend::new`] checks), and set viewport
//! and scissor dynamically. The backend records only Vulkan 1.0 commands besides the
//! conditional blocks and, in a predicated frame with dynamic rendering, the end of the
//! rendering (`vkCmdEndRendering`, or `vkCmdEndRenderingKHR` on a 1.2 device): it needs neither
//! Vulkan 1.3 nor `synchronization2` (tested on a Vulkan 1.2 instance whose device has
//! `VK_KHR_dynamic_rendering` and `VK_EXT_conditional_rendering`).
//!
//! ## Lifetime
//!
//! Drop the backend (or call [`QueryBackend::destroy`]) after the device has finished every
//! frame that used it and before the host destroys the device.

#![deny(missing_docs)]

mod pipeline;
mod set;
mod slots;

use std::ops::Range;

use ash::vk;
use coherent_cull::{
    Aabb, DepthConvention, Error, OcclusionBackend, QueryId, QueryPurpose, Result,
};

pub use coherent_cull;
pub use pipeline::{BoxPipeline, BoxPipelineDesc};
pub use set::{QuerySet, QuerySetDesc};

/// SPIR-V of the box vertex shader (compiled from the workspace's `shaders/query_box.vert`).
pub const QUERY_BOX_VERT_SPV: &[u8] = include_bytes!("../spirv/query_box.vert.spv");

/// How the host renders, and how much the backend may record per frame.
#[derive(Clone, Debug)]
pub struct QueryBackendDesc {
    /// Frames in flight: one query pool and result buffer per slot (at least 2, at most
    /// [`coherent_cull::MAX_FRAMES_IN_FLIGHT`]; a host with one frame in flight still uses 2,
    /// and its culler reads results two frames late).
    pub frames_in_flight: u32,
    /// Most queries one frame may issue. A frame that needs more fails `cull_frame` with an
    /// error that says to raise it (`CullStats::queries` tells how many a frame used); the
    /// culler's later frames stay exact.
    pub max_queries: u32,
    /// Most query boxes one frame may draw (a multiquery or a tight volume has several).
    pub max_boxes: u32,
    /// Depth attachment format of the host's depth pass.
    pub depth_format: vk::Format,
    /// Color attachment formats of the host's depth pass (the box pipeline writes none).
    pub color_formats: Vec<vk::Format>,
    /// Rasterization samples of the host's attachments: one count, which the device must
    /// support on them ([`QueryBackend::new`] checks `framebufferDepthSampleCounts` and, with
    /// color formats, `framebufferColorSampleCounts`). With several samples a query counts
    /// samples, not pixels: a culler's pixel threshold (`ChcppParams::pixel_threshold`, 0 by
    /// default) is then in samples.
    pub samples: vk::SampleCountFlags,
    /// View mask of the host's rendering (0 without multiview; otherwise the device must have
    /// `multiview` and enough views, which [`QueryBackend::new`] checks).
    pub view_mask: u32,
    /// The host's depth convention: which depth compare and bias face the eye.
    pub depth: DepthConvention,
    /// Cull the boxes' back faces, given the winding a box face seen from outside has in the
    /// host's viewport ([`BoxPipelineDesc::cull_back_faces`]); `None` (the default) draws both.
    pub cull_back_faces: Option<vk::FrontFace>,
    /// Predicated draws for `Latency::Predicated` (see [Predicated frames](crate#predicated-frames)):
    /// the device needs `VK_EXT_conditional_rendering` with `conditionalRendering` enabled.
    pub predicates: bool,
    /// The host's render pass and subpass, for a depth pass recorded in a `VkRenderPass`
    /// instead of with dynamic rendering ([`BoxPipelineDesc::render_pass`]); null (the
    /// default): dynamic rendering. A predicate resolve then ends the render pass instance
    /// (`vkCmdEndRenderPass`), and the host's resume begins one again whose attachments LOAD.
    pub render_pass: vk::RenderPass,
    /// The subpass of `render_pass` the host's depth pass (and the boxes) are drawn in.
    pub subpass: u32,
}

impl Default for QueryBackendDesc {
    fn default() -> Self {
        QueryBackendDesc {
            frames_in_flight: 2,
            max_queries: 4096,
            max_boxes: 32768,
            depth_format: vk::Format::D32_SFLOAT,
            color_formats: Vec::new(),
            samples: vk::SampleCountFlags::TYPE_1,
            view_mask: 0,
            depth: DepthConvention::REVERSE_Z_INFINITE,
            cull_back_faces: None,
            predicates: false,
            render_pass: vk::RenderPass::null(),
            subpass: 0,
        }
    }
}

/// What the backend recorded in the current frame (since [`QueryBackend::begin_frame`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct QueryCounts {
    /// Occlusion queries begun (`vkCmdBeginQuery`).
    pub queries: u32,
    /// Of those, multiqueries (several nodes in one query).
    pub multiqueries: u32,
    /// Of those, queries of previously visible leaves (for a later frame).
    pub visible_leaf_queries: u32,
    /// Boxes drawn inside queries.
    pub query_boxes: u32,
    /// Box draws (`vkCmdDrawIndexed`, one per query).
    pub box_draws: u32,
    /// Binds of the box pipeline (`vkCmdBindPipeline`).
    pub pipeline_binds: u32,
    /// Binds of the box vertex and index buffers (one per bind call of either or both).
    pub buffer_binds: u32,
    /// Switches between the host's render state and the query state, either way.
    pub state_changes: u32,
    /// Calls of the host's draw callback ([`DrawObjects::draw`], or [`DrawObjects::draw_ranges`]
    /// for one conditional block) with at least one object.
    pub object_draw_calls: u32,
    /// Objects handed to the host's draw callback.
    pub objects_drawn: u32,
    /// Query pool resets recorded (`vkCmdResetQueryPool`).
    pub resets: u32,
    /// Result copies recorded (`vkCmdCopyQueryPoolResults`).
    pub result_copies: u32,
    /// Query results read from the host-visible copy at the start of the frame.
    pub results_read: u32,
    /// Predicate resolves (pass breaks: end rendering, copy, barrier, the host's resume).
    pub resolves: u32,
    /// Conditional blocks recorded (`vkCmdBeginConditionalRenderingEXT`).
    pub conditional_blocks: u32,
    /// Objects handed to the host's draw callback inside conditional blocks (also in
    /// `objects_drawn`; the device draws those whose predicate is true).
    pub predicated_objects: u32,
    /// Queries whose boxes were drawn inside a conditional block on another query's
    /// predicate (the predicated mode's parts of a split node; also in `queries`).
    pub predicated_queries: u32,
}

/// The host's draw callback: record draws of `objects` into the command buffer; `rebind` is
/// true when the box pipeline was bound since the host's last draw (bind the host's pipeline,
/// descriptor sets and push constants again).
pub trait DrawObjects {
    /// Records the draws (see the trait docs).
    fn draw(&mut self, cmd: vk::CommandBuffer, objects: &[u32], rebind: bool) -> Result<()>;

    /// The culler's draw order (`Latency::Predicated`; see
    /// [`coherent_cull::OcclusionBackend::set_draw_order`]): every object once, each subtree
    /// of the hierarchy contiguous. The objects of a draw under a predicate come mostly in
    /// runs of it, so a host that keeps one indexed indirect command per object in this order
    /// can record a run as one `vkCmdDrawIndexedIndirect`. Sent again when the hierarchy's
    /// leaves change. Default: ignored.
    fn set_order(&mut self, order: &[u32]) -> Result<()> {
        let _ = order;
        Ok(())
    }

    /// Records the draws of the objects `order[r]` of each range `r` of `ranges`, in that
    /// order: `order` is the draw order last given to [`DrawObjects::set_order`] (see
    /// [`coherent_cull::OcclusionBackend::draw_order_ranges_if`]). A host that keeps one
    /// indexed indirect command per object in that order records each range as one
    /// `vkCmdDrawIndexedIndirect` (at most `maxDrawIndirectCount` commands each) without
    /// looking at its objects. `rebind` as in [`DrawObjects::draw`]. Default: each range's
    /// objects through [`DrawObjects::draw`].
    fn draw_ranges(
        &mut self,
        cmd: vk::CommandBuffer,
        order: &[u32],
        ranges: &[Range<u32>],
        rebind: bool,
    ) -> Result<()> {
        let mut rebind = rebind;
        for r in ranges {
            let objects = coherent_cull::order_slice(order, r)?;
            if !objects.is_empty() {
                self.draw(cmd, objects, std::mem::take(&mut rebind))?;
            }
        }
        Ok(())
    }
}

impl<F> DrawObjects for F
where
    F: FnMut(vk::CommandBuffer, &[u32], bool) -> Result<()>,
{
    fn draw(&mut self, cmd: vk::CommandBuffer, objects: &[u32], rebind: bool) -> Result<()> {
        self(cmd, objects, rebind)
    }
}

/// Occlusion queries for a culler, recorded into the host's command buffers (see the crate
/// docs).
pub struct QueryBackend {
    device: ash::Device,
    desc: QueryBackendDesc,
    /// One query set per frame-in-flight slot (dropped before the pipeline).
    slots: Vec<QuerySet>,
    /// The results each slot's previous frame copied, read at `begin_frame`.
    read: Vec<Vec<Option<u64>>>,
    /// The box pipeline (`None` once destroyed).
    pipeline: Option<BoxPipeline>,
    /// The slot of the frame being recorded (`None` outside begin/end).
    current: Option<u32>,
    /// The slot of the last frame begun (whose counts [`QueryBackend::counts`] returns).
    last: Option<u32>,
    /// `vkCmdEndRendering` or `vkCmdEndRenderingKHR`, for the predicate resolves of a host
    /// with dynamic rendering (`None` with a render pass or without predicates).
    end_rendering: Option<vk::PFN_vkCmdEndRendering>,
}

/// The 8 corners of `b`, corner `c` = x | y << 1 | z << 2 (the layout of [`BOX_FACES`]).
pub fn box_corners(b: &Aabb) -> [[f32; 3]; 8] {
    std::array::from_fn(|c| {
        [
            if c & 1 == 0 { b.min.x } else { b.max.x },
            if c & 2 == 0 { b.min.y } else { b.max.y },
            if c & 4 == 0 { b.min.z } else { b.max.z },
        ]
    })
}

/// Corner indices of one box's 12 triangles (corner `c` = x | y << 1 | z << 2), the layout the
/// built-in renderer of the `coherent` package uses for its query boxes too.
pub const BOX_FACES: [u32; 36] = [
    0, 2, 1, 1, 2, 3, // -z
    4, 5, 6, 5, 7, 6, // +z
    0, 1, 4, 1, 5, 4, // -y
    2, 6, 3, 3, 6, 7, // +y
    0, 4, 2, 2, 4, 6, // -x
    1, 3, 5, 3, 7, 5, // +x
];

impl QueryBackend {
    /// Creates the query pools, result and box buffers (host-visible memory) and the box
    /// pipeline on the host's device.
    ///
    /// # Safety
    /// `device` must have been created from `physical_device` of `instance`, with
    /// `occlusionQueryPrecise` enabled (and `dynamicRendering`, unless `desc.render_pass` names
    /// the host's render pass, made on it and outliving the backend), and must outlive the
    /// backend.
    pub unsafe fn new(
        instance: &ash::Instance,
        physical_device: vk::PhysicalDevice,
        device: &ash::Device,
        desc: QueryBackendDesc,
    ) -> Result<QueryBackend> {
        check_desc(&desc)?;
        // SAFETY: the caller guarantees that the handles belong together.
        let features = unsafe { instance.get_physical_device_features(physical_device) };
        if features.occlusion_query_precise == vk::FALSE {
            return Err(Error::Unsupported {
                feature: "occlusionQueryPrecise (precise occlusion queries)".into(),
            });
        }
        // SAFETY: as above.
        unsafe { check_device_limits(instance, physical_device, &desc)? };
        // (Without VK_EXT_conditional_rendering, QuerySet::new refuses `predicates`.)
        let pipeline_desc = BoxPipelineDesc {
            depth_format: desc.depth_format,
            color_formats: desc.color_formats.clone(),
            samples: desc.samples,
            view_mask: desc.view_mask,
            depth: desc.depth,
            cull_back_faces: desc.cull_back_faces,
            layout: None,
            render_pass: desc.render_pass,
            subpass: desc.subpass,
        };
        let end_rendering = if desc.predicates && desc.render_pass == vk::RenderPass::null() {
            // SAFETY: the caller guarantees that the handles belong together.
            Some(unsafe { end_rendering_fn(instance, device)? })
        } else {
            None
        };
        // SAFETY: the caller's guarantees.
        let pipeline = unsafe { BoxPipeline::new(device, &pipeline_desc)? };
        let set_desc = QuerySetDesc {
            queries_per_pool: desc.max_queries,
            max_queries: desc.max_queries,
            boxes_per_buffer: desc.max_boxes,
            max_boxes: desc.max_boxes,
            predicates: desc.predicates,
            host_query_reset: false,
        };
        let mut slots = Vec::new();
        for _ in 0..desc.frames_in_flight {
            // SAFETY: the caller's guarantees; on an error the sets made so far are dropped.
            slots.push(unsafe {
                QuerySet::new(instance, physical_device, device, set_desc.clone())?
            });
        }
        Ok(QueryBackend {
            device: device.clone(),
            read: vec![Vec::new(); slots.len()],
            slots,
            pipeline: Some(pipeline),
            current: None,
            last: None,
            end_rendering,
            desc,
        })
    }

    /// The description the backend was made with.
    pub fn desc(&self) -> &QueryBackendDesc {
        &self.desc
    }

    /// Starts the frame that uses frame-in-flight `slot`: reads the results of the slot's
    /// previous frame from host memory and records the reset of the queries it used into
    /// `cmd` (so call it before the host begins rendering).
    ///
    /// # Safety
    /// `cmd` is in the recording state, outside a render pass instance; the slot's previous
    /// frame has completed on the device (the host waited for its fence).
    pub unsafe fn begin_frame(&mut self, cmd: vk::CommandBuffer, slot: u32) -> Result<()> {
        if slot >= self.desc.frames_in_flight {
            return Err(Error::Input(format!(
                "frame-in-flight slot {slot} out of range (the backend has {})",
                self.desc.frames_in_flight
            )));
        }
        if let Some(open) = self.current {
            return Err(Error::Input(format!(
                "begin_frame({slot}) while the frame in slot {open} was not ended (end_frame)"
            )));
        }
        let s = &mut self.slots[slot as usize];
        let read = &mut self.read[slot as usize];
        read.clear();
        read.extend((0..s.copied()).map(|i| s.copied_result(i).map(u64::from)));
        // SAFETY: the caller guarantees the recording state outside rendering, and that the
        // slot's previous frame has completed.
        unsafe { s.record_reset(cmd) };
        s.counts_mut().results_read = read.len() as u32;
        self.current = Some(slot);
        self.last = Some(slot);
        Ok(())
    }

    /// This frame as an [`OcclusionBackend`] for `cull_frame`: draws go to `draw`, queries are
    /// recorded into `cmd` inside the host's depth pass, with `view_proj` (column-major
    /// world-to-clip, the matrix of the frame's `CameraView`) for the boxes.
    ///
    /// Call it between [`QueryBackend::begin_frame`] and [`QueryBackend::end_frame`], with
    /// `cmd` inside the host's rendering.
    pub fn frame<D: DrawObjects>(
        &mut self,
        cmd: vk::CommandBuffer,
        view_proj: [f32; 16],
        draw: D,
    ) -> FrameBackend<'_, D> {
        FrameBackend {
            backend: self,
            cmd,
            view_proj,
            draw,
            in_query_state: false,
            box_bound_since_draw: false,
            resume: None,
        }
    }

    /// Ends the frame: records the copy of its query results (value and availability) into
    /// the slot's host-visible buffer and a barrier that makes them visible to the host. Call
    /// it after the host ended rendering; the results are read by the `begin_frame` that
    /// reuses the slot.
    ///
    /// # Safety
    /// `cmd` is the command buffer of `begin_frame`, recording, outside a render pass instance.
    pub unsafe fn end_frame(&mut self, cmd: vk::CommandBuffer) -> Result<()> {
        let slot = self
            .current
            .take()
            .ok_or_else(|| Error::Input("end_frame without begin_frame".into()))?;
        // SAFETY: the caller guarantees the recording state outside rendering, after the
        // frame's queries.
        unsafe { self.slots[slot as usize].record_copy(cmd) };
        Ok(())
    }

    /// What was recorded since the last [`QueryBackend::begin_frame`].
    pub fn counts(&self) -> QueryCounts {
        self.last
            .map(|s| self.slots[s as usize].counts())
            .unwrap_or_default()
    }

    /// Destroys every Vulkan object of the backend (also done on drop).
    ///
    /// # Safety
    /// The device has finished every command buffer that used the backend.
    pub unsafe fn destroy(&mut self) {
        for s in &mut self.slots {
            // SAFETY: the caller (or drop) guarantees the device is done with them.
            unsafe { s.destroy() };
        }
        self.slots.clear();
        self.pipeline = None;
    }

    fn slot_of(&self, id: QueryId) -> (u32, u32) {
        let k = self.desc.frames_in_flight;
        (id % k, id / k)
    }
}

/// One frame of a [`QueryBackend`] as the culler's [`OcclusionBackend`] (from
/// [`QueryBackend::frame`]).
pub struct FrameBackend<'a, D: DrawObjects> {
    backend: &'a mut QueryBackend,
    cmd: vk::CommandBuffer,
    view_proj: [f32; 16],
    draw: D,
    in_query_state: bool,
    box_bound_since_draw: bool,
    /// The host's resume of its depth pass after a predicate resolve.
    resume: Option<Resume<'a>>,
}

/// The host's "resume rendering" callback of a predicated frame.
type Resume<'a> = Box<dyn FnMut(vk::CommandBuffer) -> Result<()> + 'a>;

impl<'a, D: DrawObjects> FrameBackend<'a, D> {
    /// Predicated frames: `resume(cmd)` begins the host's depth pass again after a predicate
    /// resolve ended it (`vkCmdBeginRendering` with LOAD ops on the same attachments, after
    /// a barrier from the attachment writes before; viewport and scissor as before). With
    /// it, and [`QueryBackendDesc::predicates`], the frame supports `Latency::Predicated`.
    pub fn with_resume(mut self, resume: impl FnMut(vk::CommandBuffer) -> Result<()> + 'a) -> Self {
        self.resume = Some(Box::new(resume));
        self
    }
}

impl<D: DrawObjects> FrameBackend<'_, D> {
    fn slot(&self) -> Result<u32> {
        self.backend
            .current
            .ok_or_else(|| Error::Input("a culler frame outside begin_frame/end_frame".into()))
    }

    /// The query set of the frame being recorded.
    fn set(&mut self) -> Result<&mut QuerySet> {
        let slot = self.slot()?;
        Ok(&mut self.backend.slots[slot as usize])
    }

    fn enter_query_state(&mut self) -> Result<()> {
        if self.in_query_state {
            return Ok(());
        }
        self.in_query_state = true;
        self.box_bound_since_draw = true;
        let (cmd, view_proj) = (self.cmd, self.view_proj);
        let slot = self.slot()?;
        let b = &mut *self.backend;
        let pipeline = b
            .pipeline
            .as_ref()
            .ok_or_else(|| Error::Input("the backend was destroyed".into()))?;
        let set = &mut b.slots[slot as usize];
        set.counts_mut().state_changes += 1;
        // SAFETY: `cmd` is recording inside the host's rendering (the `frame` contract); the
        // pipeline and the set live as long as the backend.
        unsafe { set.bind(cmd, pipeline, &view_proj) };
        Ok(())
    }

    /// Records an occlusion query of `boxes`; with `predicate` (the index of a resolved
    /// query of this slot), its box draws lie inside a conditional block on that predicate.
    fn record_query(
        &mut self,
        boxes: &[Aabb],
        purpose: QueryPurpose,
        predicate: Option<u32>,
    ) -> Result<QueryId> {
        let slot = self.slot()?;
        self.enter_query_state()?;
        let cmd = self.cmd;
        let set = self.set()?;
        // SAFETY: recording inside the host's rendering with the box pipeline bound by
        // `enter_query_state` and nothing of the host's since; the set was reset in this
        // frame's begin_frame; a predicate is checked by the set.
        let index = unsafe { set.record_query(cmd, boxes, predicate)? };
        let c = set.counts_mut();
        match purpose {
            QueryPurpose::Multiquery => c.multiqueries += 1,
            QueryPurpose::VisibleLeaf => c.visible_leaf_queries += 1,
            QueryPurpose::Node => {}
        }
        Ok(slot + self.backend.desc.frames_in_flight * index)
    }

    /// Back to render state before the host's draws: counts the state change, and returns
    /// whether the host must bind its state again (the box pipeline was bound since).
    fn enter_render_state(&mut self) -> Result<bool> {
        if std::mem::take(&mut self.in_query_state) {
            self.set()?.counts_mut().state_changes += 1;
        }
        Ok(std::mem::take(&mut self.box_bound_since_draw))
    }

    /// Counts one draw call of the culler's with `objects` objects.
    fn count_draw(&mut self, objects: usize) -> Result<()> {
        let c = self.set()?.counts_mut();
        c.object_draw_calls += 1;
        c.objects_drawn += objects as u32;
        Ok(())
    }

    /// Records `draw` (the host's draws of `objects` objects) inside a conditional block on
    /// `query`'s predicate, and counts the objects as predicated; nothing for no objects.
    fn draw_in_block(
        &mut self,
        query: QueryId,
        objects: usize,
        draw: impl FnOnce(&mut Self) -> Result<()>,
    ) -> Result<()> {
        let index = self.resolved_predicate(query)?;
        if objects == 0 {
            return Ok(());
        }
        let cmd = self.cmd;
        // SAFETY: recording inside the host's rendering, after the resolve in this command
        // buffer; the set checks the predicate and that no block is open.
        unsafe { self.set()?.begin_block(cmd, index)? };
        let drawn = draw(self);
        // SAFETY: the block begun above is open in this rendering instance.
        unsafe { self.set()?.end_block(cmd) };
        drawn?;
        self.set()?.counts_mut().predicated_objects += objects as u32;
        Ok(())
    }

    /// The index in this frame's slot of `query`, a resolved predicate of this frame.
    fn resolved_predicate(&self, query: QueryId) -> Result<u32> {
        let current = self.slot()?;
        let (slot, index) = self.backend.slot_of(query);
        if slot != current || index >= self.backend.slots[slot as usize].resolved() {
            return Err(Error::Input(format!(
                "query {query} is not a resolved predicate of this frame"
            )));
        }
        if !self.backend.desc.predicates {
            return Err(coherent_cull::predicates_unsupported());
        }
        Ok(index)
    }
}

impl<D: DrawObjects> OcclusionBackend for FrameBackend<'_, D> {
    fn draw_objects(&mut self, objects: &[u32]) -> Result<()> {
        if objects.is_empty() {
            return Ok(());
        }
        let rebind = self.enter_render_state()?;
        self.draw.draw(self.cmd, objects, rebind)?;
        self.count_draw(objects.len())
    }

    fn issue_query(&mut self, boxes: &[Aabb]) -> Result<QueryId> {
        self.issue_query_for(boxes, QueryPurpose::Node)
    }

    fn issue_query_for(&mut self, boxes: &[Aabb], purpose: QueryPurpose) -> Result<QueryId> {
        self.record_query(boxes, purpose, None)
    }

    fn supports_predicated_queries(&self) -> bool {
        self.supports_predicates()
    }

    fn issue_query_if(
        &mut self,
        predicate: QueryId,
        boxes: &[Aabb],
        purpose: QueryPurpose,
    ) -> Result<QueryId> {
        let index = self.resolved_predicate(predicate)?;
        self.record_query(boxes, purpose, Some(index))
    }

    fn restore_render_state(&mut self) -> Result<()> {
        if std::mem::take(&mut self.in_query_state) {
            self.set()?.counts_mut().state_changes += 1;
        }
        Ok(())
    }

    fn flush(&mut self) -> Result<()> {
        Err(Error::Unsupported {
            feature: "submissions inside a frame (coherent-ash records into the host's one \
                      command buffer per frame: use a latency mode with frames in flight)"
                .into(),
        })
    }

    fn query_result(&mut self, query: QueryId) -> Result<Option<u64>> {
        let current = self.slot()?;
        let (slot, index) = self.backend.slot_of(query);
        if slot != current || self.backend.slots[slot as usize].issued() > 0 {
            // Another slot's frame has not been waited for, or this slot was reused already.
            return Ok(None);
        }
        Ok(self.backend.read[slot as usize]
            .get(index as usize)
            .copied()
            .flatten())
    }

    fn wait_query(&mut self, query: QueryId) -> Result<u64> {
        Err(Error::Unsupported {
            feature: format!(
                "waiting for query {query} inside a frame (coherent-ash never waits: use a \
                 latency mode with frames in flight)"
            ),
        })
    }

    fn finish(&mut self) -> Result<()> {
        Err(Error::Unsupported {
            feature: "finishing the frame inside cull_frame (the host submits; configure the \
                      culler with with_frames_in_flight(k), k >= 2)"
                .into(),
        })
    }

    fn frames_in_flight(&self) -> u32 {
        self.backend.desc.frames_in_flight
    }

    fn submit_frame(&mut self) -> Result<()> {
        // The host ends rendering, calls end_frame and submits.
        Ok(())
    }

    fn supports_predicates(&self) -> bool {
        self.backend.desc.predicates && self.resume.is_some()
    }

    fn resolve_predicates(&mut self) -> Result<()> {
        let slot = self.slot()?;
        let (true, Some(resume)) = (self.backend.desc.predicates, self.resume.as_mut()) else {
            return Err(Error::Unsupported {
                feature: "predicated draws (QueryBackendDesc::predicates with \
                          VK_EXT_conditional_rendering, and FrameBackend::with_resume)"
                    .into(),
            });
        };
        let (cmd, b) = (self.cmd, &mut *self.backend);
        // SAFETY: `cmd` is recording inside the host's rendering (the `frame` contract): it is
        // ended here, the copy and barrier recorded outside it, and the host resumes it.
        unsafe {
            match b.end_rendering {
                Some(end_rendering) => end_rendering(cmd),
                None => b.device.cmd_end_render_pass(cmd),
            }
            b.slots[slot as usize].record_resolve(cmd)?;
        }
        resume(cmd)?;
        // The host binds its own state while resuming: back in render state.
        if std::mem::take(&mut self.in_query_state) {
            self.set()?.counts_mut().state_changes += 1;
        }
        self.box_bound_since_draw = false;
        Ok(())
    }

    fn set_draw_order(&mut self, order: &[u32]) -> Result<()> {
        self.draw.set_order(order)
    }

    fn draw_objects_if(&mut self, query: QueryId, objects: &[u32]) -> Result<()> {
        self.draw_in_block(query, objects.len(), |b| b.draw_objects(objects))
    }

    fn draw_order_ranges_if(
        &mut self,
        query: QueryId,
        order: &[u32],
        ranges: &[Range<u32>],
    ) -> Result<()> {
        let objects = coherent_cull::order_ranges_len(order, ranges)?;
        self.draw_in_block(query, objects, |b| {
            let rebind = b.enter_render_state()?;
            b.draw.draw_ranges(b.cmd, order, ranges, rebind)?;
            b.count_draw(objects)
        })
    }
}

/// `vkCmdEndRendering` of a Vulkan 1.3 device, or `vkCmdEndRenderingKHR` of a device with
/// `VK_KHR_dynamic_rendering` (a Vulkan 1.2 host); an error naming both without either.
///
/// # Safety
/// `device` was created from `instance`.
unsafe fn end_rendering_fn(
    instance: &ash::Instance,
    device: &ash::Device,
) -> Result<vk::PFN_vkCmdEndRendering> {
    for name in [c"vkCmdEndRendering", c"vkCmdEndRenderingKHR"] {
        // SAFETY: per the caller; the name is a valid C string.
        if let Some(f) = unsafe { instance.get_device_proc_addr(device.handle(), name.as_ptr()) } {
            // SAFETY: both names have the signature of PFN_vkCmdEndRendering.
            return Ok(unsafe {
                std::mem::transmute::<unsafe extern "system" fn(), vk::PFN_vkCmdEndRendering>(f)
            });
        }
    }
    Err(Error::Unsupported {
        feature: "ending dynamic rendering for the predicate resolves: vkCmdEndRendering \
                  (Vulkan 1.3) or vkCmdEndRenderingKHR (VK_KHR_dynamic_rendering enabled on \
                  the device)"
            .into(),
    })
}

/// Whether the physical device has `VK_EXT_conditional_rendering` with `conditionalRendering`.
///
/// # Safety
/// `physical_device` belongs to `instance`.
unsafe fn has_conditional_rendering(
    instance: &ash::Instance,
    physical_device: vk::PhysicalDevice,
) -> bool {
    let name = ash::ext::conditional_rendering::NAME;
    // SAFETY: per the caller.
    let listed = unsafe { instance.enumerate_device_extension_properties(physical_device) }
        .unwrap_or_default()
        .iter()
        .any(|e| e.extension_name_as_c_str() == Ok(name));
    if !listed {
        return false;
    }
    let mut cr = vk::PhysicalDeviceConditionalRenderingFeaturesEXT::default();
    let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut cr);
    // SAFETY: per the caller; the chain outlives the call.
    unsafe { instance.get_physical_device_features2(physical_device, &mut f2) };
    cr.conditional_rendering != 0
}

/// Checks the sample count and view mask of `desc` against what the physical device can
/// render: a box pipeline the device cannot use would be undefined behaviour, not an error.
///
/// # Safety
/// `physical_device` belongs to `instance`.
unsafe fn check_device_limits(
    instance: &ash::Instance,
    physical_device: vk::PhysicalDevice,
    desc: &QueryBackendDesc,
) -> Result<()> {
    let samples = desc.samples;
    if samples.as_raw().count_ones() != 1 {
        return Err(Error::Input(format!(
            "samples {samples:?}: name exactly one sample count"
        )));
    }
    // SAFETY: per the caller.
    let limits = unsafe { instance.get_physical_device_properties(physical_device) }.limits;
    if desc.depth_format != vk::Format::UNDEFINED
        && !limits.framebuffer_depth_sample_counts.contains(samples)
    {
        return Err(Error::Unsupported {
            feature: format!(
                "{samples:?} samples on a depth attachment (framebufferDepthSampleCounts: {:?})",
                limits.framebuffer_depth_sample_counts
            ),
        });
    }
    if !desc.color_formats.is_empty() && !limits.framebuffer_color_sample_counts.contains(samples) {
        return Err(Error::Unsupported {
            feature: format!(
                "{samples:?} samples on a color attachment (framebufferColorSampleCounts: {:?})",
                limits.framebuffer_color_sample_counts
            ),
        });
    }
    if desc.view_mask != 0 {
        let mut features = vk::PhysicalDeviceMultiviewFeatures::default();
        let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut features);
        // SAFETY: per the caller; the chain outlives the call.
        unsafe { instance.get_physical_device_features2(physical_device, &mut f2) };
        if features.multiview == vk::FALSE {
            return Err(Error::Unsupported {
                feature: format!("multiview (view_mask {:#x})", desc.view_mask),
            });
        }
        let mut props = vk::PhysicalDeviceMultiviewProperties::default();
        let mut p2 = vk::PhysicalDeviceProperties2::default().push_next(&mut props);
        // SAFETY: per the caller; the chain outlives the call.
        unsafe { instance.get_physical_device_properties2(physical_device, &mut p2) };
        let views = 32 - desc.view_mask.leading_zeros();
        if views > props.max_multiview_view_count {
            return Err(Error::Unsupported {
                feature: format!(
                    "view {} of view_mask {:#x} (maxMultiviewViewCount: {})",
                    views - 1,
                    desc.view_mask,
                    props.max_multiview_view_count
                ),
            });
        }
    }
    Ok(())
}

fn check_desc(desc: &QueryBackendDesc) -> Result<()> {
    if desc.frames_in_flight < 2 {
        return Err(Error::Input(format!(
            "frames_in_flight {} (at least 2: the culler reads a frame's results when its slot \
             is reused)",
            desc.frames_in_flight
        )));
    }
    if desc.frames_in_flight > coherent_cull::MAX_FRAMES_IN_FLIGHT {
        return Err(Error::Input(format!(
            "frames_in_flight {} (at most {}, as many as a culler reads late)",
            desc.frames_in_flight,
            coherent_cull::MAX_FRAMES_IN_FLIGHT
        )));
    }
    if desc.max_queries == 0 || desc.max_boxes == 0 {
        return Err(Error::Input(
            "max_queries and max_boxes must be at least 1".into(),
        ));
    }
    if u64::from(desc.max_boxes) * 36 > u64::from(u32::MAX) {
        return Err(Error::Input(format!(
            "max_boxes {} is too large for 32-bit indices",
            desc.max_boxes
        )));
    }
    Ok(())
}

fn as_bytes(words: &[u32]) -> &[u8] {
    // SAFETY: u32 has no padding and any byte pattern of it is a valid u8 sequence.
    unsafe { std::slice::from_raw_parts(words.as_ptr().cast::<u8>(), std::mem::size_of_val(words)) }
}

fn vk_err(call: &'static str) -> impl Fn(vk::Result) -> Error {
    move |r| Error::backend(VkError { call, result: r })
}

/// A failed Vulkan call of the backend (inside [`coherent_cull::Error::Backend`]).
#[derive(Debug)]
pub struct VkError {
    /// The call.
    pub call: &'static str,
    /// What it returned.
    pub result: vk::Result,
}

impl std::fmt::Display for VkError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Vulkan call {} failed: {}", self.call, self.result)
    }
}

impl std::error::Error for VkError {}

#[cfg(test)]
mod tests {
    use super::{check_desc, QueryBackendDesc};

    /// Descriptions a backend cannot honour are refused before any Vulkan object is made:
    /// too few or too many frames in flight (a slot is a query pool and buffers each),
    /// no room for queries, boxes past 32-bit indices.
    #[test]
    fn descriptions_out_of_range_are_refused() {
        let desc = |f: &dyn Fn(&mut QueryBackendDesc)| {
            let mut d = QueryBackendDesc::default();
            f(&mut d);
            d
        };
        assert!(check_desc(&QueryBackendDesc::default()).is_ok());
        let most = coherent_cull::MAX_FRAMES_IN_FLIGHT;
        assert!(check_desc(&desc(&|d| d.frames_in_flight = most)).is_ok());
        for (bad, why) in [
            (desc(&|d| d.frames_in_flight = 1), "at least 2"),
            (desc(&|d| d.frames_in_flight = most + 1), "at most 16"),
            (desc(&|d| d.frames_in_flight = u32::MAX), "at most 16"),
            (desc(&|d| d.max_queries = 0), "at least 1"),
            (desc(&|d| d.max_boxes = 0), "at least 1"),
            (desc(&|d| d.max_boxes = u32::MAX / 8), "32-bit indices"),
        ] {
            let e = check_desc(&bad).expect_err(why).to_string();
            assert!(e.contains(why), "{e}");
        }
    }
}
