//! The command recorder: the one type that records `vkCmd*` calls. It skips redundant pipeline
//! binds (dirty tracking) and counts every bind, render/query state switch, draw, triangle,
//! query and submit, so frame statistics come from what was really recorded.

use std::sync::Arc;

use ash::vk;

use super::descriptors::DescriptorSet;
use super::memory::{Buffer, Image, ImageUse};
use super::pipelines::{ComputePipeline, Pipeline, PipelineKind, PipelineLayout};
use super::queries::QueryPools;
use super::sync::Timeline;
use super::GpuContext;
use crate::error::{Error, Result, VkContext};

/// What the recorder saw.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CommandCounts {
    /// `vkCmdBindPipeline` calls.
    pub pipeline_binds: u32,
    /// Of those, binds of compute pipelines.
    pub compute_binds: u32,
    /// Switches between render and query state (a bind whose kind differs from the last one).
    pub state_changes: u32,
    /// Draw calls (object draws, query draws and any other).
    pub draw_calls: u32,
    /// Draw calls in render state (shaded objects).
    pub object_draws: u32,
    /// Draw calls inside an occlusion query (query boxes).
    pub query_draws: u32,
    /// Triangles drawn inside occlusion queries (12 per box).
    pub query_triangles: u64,
    /// Triangles submitted by draw calls (render and query geometry).
    pub triangles: u64,
    /// Triangles of render-state draws only.
    pub render_triangles: u64,
    /// `vkCmdBeginQuery` calls for occlusion queries.
    pub queries_begun: u32,
    /// Of those, queries covering several nodes (multiqueries), as the caller tagged them.
    pub multiqueries: u32,
    /// Of those, queries for previously visible leaves, as the caller tagged them.
    pub visible_leaf_queries: u32,
    /// Occlusion-query results read back.
    pub queries_read: u32,
    /// Occlusion-query results that counted more pixels than the visibility threshold.
    pub queries_visible: u32,
    /// Queue submissions.
    pub submits: u32,
    /// Descriptor-set binds.
    pub descriptor_binds: u32,
    /// Of those, binds that switch an object's material texture (scenes with materials).
    pub texture_binds: u32,
    /// Vertex/index buffer binds.
    pub buffer_binds: u32,
    /// Compute dispatches.
    pub dispatches: u32,
    /// Indirect draw calls (`vkCmdDrawIndexedIndirectCount`, and `vkCmdDrawIndexedIndirect`
    /// multi-draws of objects; also in `draw_calls`).
    pub indirect_draws: u32,
    /// Objects drawn by the GPU through indirect draws, read back from the draw counts after
    /// the frame and added by the caller that issued them (`hiz`); for reports only.
    pub indirect_objects: u32,
    /// Triangles of those objects, read back likewise.
    pub indirect_triangles: u64,
    /// Object draws of moving objects, added after the frame by whoever knows which objects
    /// move (the scene renderer's draw log, and `hiz` for its GPU-generated draws, read
    /// back); a draw under a predicate counts only where the predicate was true. For reports
    /// only.
    pub mover_draws: u32,
    /// Predicate resolves: query results copied into the predicate buffer for conditional
    /// rendering (each a pass break: end rendering, copy, barrier, resume).
    pub predicate_resolves: u32,
    /// Conditional-rendering blocks (`vkCmdBeginConditionalRenderingEXT`).
    pub conditional_blocks: u32,
    /// Queries whose boxes were drawn inside a conditional block (a block begun while a query
    /// is active; also in `queries_begun`), and box flags drawn under a predicate (also in
    /// `flag_tests`).
    pub predicated_queries: u32,
    /// Render-state draw calls recorded inside a conditional block: one per object, or one
    /// indirect multi-draw of several objects ([`Recorder::draw_objects_indirect`]); also in
    /// `object_draws`.
    pub predicated_calls: u32,
    /// Parts of split nodes decided by the renderer instead of a query (predicated mode,
    /// built-in renderer): by the depth part test, or by box flags gated by their node's
    /// (also in `flag_tests`); not in `queries_begun`.
    pub tested_parts: u32,
    /// Box tests answered by flags instead of queries (predicated mode, built-in renderer
    /// with box flags on): one flag each, their boxes drawn by instanced draws at the
    /// resolves; not in `queries_begun`.
    pub flag_tests: u32,
    /// Predicates (tested parts, or queried nodes with one predicate level) whose draws were
    /// gathered on the device into one indirect draw with a count
    /// ([`Recorder::count_gathered`]) instead of a conditional block each.
    pub gathered_parts: u32,
    /// Objects those draw calls draw when their predicate is true (an object drawn by its own
    /// draw, or by one command of a multi-draw), and the candidates of draws gathered on the
    /// device from tested parts' predicates ([`Recorder::count_gathered`]).
    pub predicated_objects: u32,
    /// Of those, objects whose predicate was true, read back from the predicate buffer after
    /// the frame (added by the scene renderer); for reports only.
    pub predicated_objects_taken: u32,
    /// Triangles of object draws under predicates that were false: submitted (counted in
    /// `render_triangles`) but not drawn; read back after the frame like
    /// `predicated_objects_taken`. For reports only.
    pub predicated_triangles_skipped: u64,
}

impl CommandCounts {
    /// Objects the frame drew: those of render-state draws, less the draws recorded under
    /// predicates, plus the objects of those whose predicate was true
    /// (`predicated_objects_taken`) and the objects of draws the GPU generated
    /// (`indirect_objects`). A draw under a false predicate drew nothing. Render-state draws
    /// outside predicates draw one object each (the multi-draws are all predicated).
    pub fn drawn_objects(&self) -> u32 {
        (self.object_draws + self.predicated_objects_taken + self.indirect_objects)
            .saturating_sub(self.predicated_calls)
    }

    /// Triangles the frame's object draws drew: those of render-state draws and of draws the
    /// GPU generated (`indirect_triangles`), less those under false predicates.
    pub fn drawn_triangles(&self) -> u64 {
        (self.render_triangles + self.indirect_triangles)
            .saturating_sub(self.predicated_triangles_skipped)
    }
}

/// How a buffer (or any memory) is accessed, for [`Recorder::memory_barrier`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Access {
    /// Written by a transfer (fill, copy).
    TransferWrite,
    /// Read by a transfer (copy source).
    TransferRead,
    /// Read and written by compute shaders.
    ComputeReadWrite,
    /// Read as indirect draw commands and counts.
    IndirectRead,
    /// Read by the host after the submission completed.
    HostRead,
    /// Read as a conditional-rendering predicate.
    ConditionalRead,
    /// Written by fragment shaders (storage buffers).
    FragmentWrite,
    /// Read by vertex shaders (storage buffers).
    VertexRead,
}

impl Access {
    pub(crate) fn stage_access(self) -> (vk::PipelineStageFlags2, vk::AccessFlags2) {
        use vk::AccessFlags2 as A;
        use vk::PipelineStageFlags2 as S;
        match self {
            Access::TransferWrite => (S::ALL_TRANSFER, A::TRANSFER_WRITE),
            Access::TransferRead => (S::ALL_TRANSFER, A::TRANSFER_READ),
            Access::ComputeReadWrite => (
                S::COMPUTE_SHADER,
                A::SHADER_STORAGE_READ | A::SHADER_STORAGE_WRITE | A::SHADER_SAMPLED_READ,
            ),
            Access::IndirectRead => (S::DRAW_INDIRECT, A::INDIRECT_COMMAND_READ),
            Access::HostRead => (S::HOST, A::HOST_READ),
            Access::ConditionalRead => (
                S::CONDITIONAL_RENDERING_EXT,
                A::CONDITIONAL_RENDERING_READ_EXT,
            ),
            Access::FragmentWrite => (S::FRAGMENT_SHADER, A::SHADER_STORAGE_WRITE),
            Access::VertexRead => (S::VERTEX_SHADER, A::SHADER_STORAGE_READ),
        }
    }
}

/// A command buffer handed out by a [`CommandPool`], begun and ready to record.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CommandBuffer(pub(crate) vk::CommandBuffer);

/// A command pool and the buffers allocated from it. Buffers are handed out in order by
/// [`CommandPool::begin_next`] and all recycled together by [`CommandPool::reset`].
pub struct CommandPool {
    ctx: Arc<GpuContext>,
    pool: vk::CommandPool,
    buffers: Vec<vk::CommandBuffer>,
    used: usize,
}

impl CommandPool {
    /// Creates an empty pool on the context's queue family.
    pub fn new(ctx: &Arc<GpuContext>) -> Result<CommandPool> {
        let info = vk::CommandPoolCreateInfo::default().queue_family_index(ctx.queue_family);
        // SAFETY: valid device and create info.
        let pool =
            unsafe { ctx.device.create_command_pool(&info, None) }.vk("vkCreateCommandPool")?;
        Ok(CommandPool {
            ctx: ctx.clone(),
            pool,
            buffers: Vec::new(),
            used: 0,
        })
    }

    /// The next free buffer (allocated when all are used), begun for one submission.
    pub fn begin_next(&mut self) -> Result<CommandBuffer> {
        let d = &self.ctx.device;
        if self.used == self.buffers.len() {
            let alloc = vk::CommandBufferAllocateInfo::default()
                .command_pool(self.pool)
                .level(vk::CommandBufferLevel::PRIMARY)
                .command_buffer_count(1);
            // SAFETY: valid pool; the buffer is owned by it.
            let cmd =
                unsafe { d.allocate_command_buffers(&alloc) }.vk("vkAllocateCommandBuffers")?[0];
            self.buffers.push(cmd);
        }
        let cmd = self.buffers[self.used];
        let begin = vk::CommandBufferBeginInfo::default()
            .flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
        // SAFETY: the buffer is in the initial state: new, or recycled by `reset` after its
        // submission completed.
        unsafe { d.begin_command_buffer(cmd, &begin) }.vk("vkBeginCommandBuffer")?;
        self.used += 1;
        Ok(CommandBuffer(cmd))
    }

    /// Buffers handed out since the last reset.
    pub fn used(&self) -> usize {
        self.used
    }

    /// Waits until everything submitted on `timeline` has completed (the pool's buffers are
    /// only ever submitted there), then recycles every buffer.
    pub fn reset(&mut self, timeline: &Timeline) -> Result<()> {
        timeline.wait_all()?;
        // SAFETY: no buffer of this pool is pending: all were submitted on `timeline`, which
        // has completed, or never submitted.
        unsafe {
            self.ctx
                .device
                .reset_command_pool(self.pool, vk::CommandPoolResetFlags::empty())
        }
        .vk("vkResetCommandPool")?;
        self.used = 0;
        Ok(())
    }
}

impl Drop for CommandPool {
    fn drop(&mut self) {
        // SAFETY: owners drop the pool after the timeline its buffers were submitted on has
        // completed (Timeline::drop and the owners' Drop wait for it); freeing the pool frees
        // its buffers.
        unsafe {
            let _ = self.ctx.device.device_wait_idle();
            self.ctx.device.destroy_command_pool(self.pool, None);
        }
    }
}

/// What to do with an attachment's contents at the start of a rendering.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Load {
    /// Keep what is there.
    Keep,
    /// Contents are not needed.
    DontCare,
    /// Clear a float/unorm color attachment.
    ClearColor([f32; 4]),
    /// Clear an integer color attachment.
    ClearUint([u32; 4]),
    /// Clear a depth attachment.
    ClearDepth(f32),
}

/// One attachment of a rendering: the image (in [`ImageUse::ColorAttachment`] or
/// [`ImageUse::DepthAttachment`]), its load op and whether its results are stored.
#[derive(Clone, Copy)]
pub struct Attachment<'a> {
    /// The image (its view over all layers is attached).
    pub image: &'a Image,
    /// Load op.
    pub load: Load,
    /// Store the results (false: DONT_CARE).
    pub store: bool,
}

impl Attachment<'_> {
    fn info(&self, layout: vk::ImageLayout) -> vk::RenderingAttachmentInfo<'static> {
        let (load, clear) = match self.load {
            Load::Keep => (vk::AttachmentLoadOp::LOAD, vk::ClearValue::default()),
            Load::DontCare => (vk::AttachmentLoadOp::DONT_CARE, vk::ClearValue::default()),
            Load::ClearColor(c) => (
                vk::AttachmentLoadOp::CLEAR,
                vk::ClearValue {
                    color: vk::ClearColorValue { float32: c },
                },
            ),
            Load::ClearUint(c) => (
                vk::AttachmentLoadOp::CLEAR,
                vk::ClearValue {
                    color: vk::ClearColorValue { uint32: c },
                },
            ),
            Load::ClearDepth(depth) => (
                vk::AttachmentLoadOp::CLEAR,
                vk::ClearValue {
                    depth_stencil: vk::ClearDepthStencilValue { depth, stencil: 0 },
                },
            ),
        };
        let store = if self.store {
            vk::AttachmentStoreOp::STORE
        } else {
            vk::AttachmentStoreOp::DONT_CARE
        };
        vk::RenderingAttachmentInfo::default()
            .image_view(self.image.view)
            .image_layout(layout)
            .load_op(load)
            .store_op(store)
            .clear_value(clear)
    }
}

/// Most color attachments of one rendering.
const MAX_COLOR_ATTACHMENTS: usize = 4;

/// Records into one command buffer at a time and counts.
pub struct Recorder {
    device: ash::Device,
    cmd: vk::CommandBuffer,
    bound: Option<vk::Pipeline>,
    last_kind: Option<PipelineKind>,
    render_extent: vk::Extent2D,
    /// Counts since the last [`Recorder::take_counts`].
    pub counts: CommandCounts,
    /// The device's `maxComputeWorkGroupCount`, checked by every dispatch.
    max_work_group_count: [u32; 3],
    /// The predicate (query id) of the conditional block the caller has open (recorded by
    /// coherent-ash's query set; the recorder counts the draws inside it).
    in_conditional: Option<u32>,
}

impl Recorder {
    /// A recorder for `ctx`'s device (and its limits); call [`Recorder::set_command_buffer`]
    /// before recording.
    pub fn new(ctx: &GpuContext) -> Recorder {
        Recorder {
            device: ctx.device.clone(),
            cmd: vk::CommandBuffer::null(),
            bound: None,
            last_kind: None,
            render_extent: vk::Extent2D::default(),
            counts: CommandCounts::default(),
            max_work_group_count: ctx.info.max_compute_work_group_count,
            in_conditional: None,
        }
    }

    /// Marks the conditional block on query `query`'s predicate that the caller opened (or,
    /// with `None`, closed) in this command buffer: draws in render state inside it count as
    /// predicated calls.
    pub fn note_conditional(&mut self, query: Option<u32>) {
        self.in_conditional = query;
    }

    /// Counts a pipeline bind the caller recorded itself (coherent-ash's box pipeline): the
    /// recorder's bound pipeline and kind follow it, so its next bind of another is recorded.
    pub fn note_bind(&mut self, pipeline: vk::Pipeline, kind: PipelineKind) {
        self.bound = Some(pipeline);
        self.counts.pipeline_binds += 1;
        if self.last_kind.is_some() && self.last_kind != Some(kind) {
            self.counts.state_changes += 1;
        }
        self.last_kind = Some(kind);
    }

    /// The pipeline bound last in this command buffer, as far as the recorder knows.
    pub fn bound_pipeline(&self) -> Option<vk::Pipeline> {
        self.bound
    }

    /// Starts recording into a new command buffer (already begun): bound state is forgotten.
    pub fn set_command_buffer(&mut self, cmd: CommandBuffer) {
        self.cmd = cmd.0;
        self.bound = None;
        self.in_conditional = None;
    }

    /// The current command buffer.
    pub fn command_buffer(&self) -> CommandBuffer {
        CommandBuffer(self.cmd)
    }

    /// Returns the counts and starts a new frame (no kind is current).
    pub fn take_counts(&mut self) -> CommandCounts {
        self.last_kind = None;
        std::mem::take(&mut self.counts)
    }

    /// The kind of the last bound pipeline.
    pub fn current_kind(&self) -> Option<PipelineKind> {
        self.last_kind
    }

    /// Binds `p` unless it is bound already; returns whether a bind was recorded.
    pub fn bind_pipeline(&mut self, p: &Pipeline) -> bool {
        if self.bound == Some(p.handle) {
            return false;
        }
        // SAFETY: recording command buffer and valid pipeline.
        unsafe {
            self.device
                .cmd_bind_pipeline(self.cmd, vk::PipelineBindPoint::GRAPHICS, p.handle)
        };
        self.note_bind(p.handle, p.kind);
        true
    }

    /// Binds a compute pipeline.
    pub fn bind_compute_pipeline(&mut self, p: &ComputePipeline) {
        // SAFETY: recording command buffer and valid pipeline.
        unsafe {
            self.device
                .cmd_bind_pipeline(self.cmd, vk::PipelineBindPoint::COMPUTE, p.handle)
        };
        self.counts.pipeline_binds += 1;
        self.counts.compute_binds += 1;
    }

    /// Binds `set` as set 0 of `layout` for graphics pipelines.
    pub fn bind_graphics_set(&mut self, layout: &PipelineLayout, set: DescriptorSet) {
        self.bind_set(vk::PipelineBindPoint::GRAPHICS, layout, set);
    }

    /// Binds `set` (a material's texture set) as set 0 of `layout` for graphics pipelines;
    /// counted as a descriptor bind and a texture bind.
    pub fn bind_texture_set(&mut self, layout: &PipelineLayout, set: DescriptorSet) {
        self.bind_set(vk::PipelineBindPoint::GRAPHICS, layout, set);
        self.counts.texture_binds += 1;
    }

    /// Binds `set` as set 0 of `layout` for compute pipelines.
    pub fn bind_compute_set(&mut self, layout: &PipelineLayout, set: DescriptorSet) {
        self.bind_set(vk::PipelineBindPoint::COMPUTE, layout, set);
    }

    fn bind_set(
        &mut self,
        point: vk::PipelineBindPoint,
        layout: &PipelineLayout,
        set: DescriptorSet,
    ) {
        // SAFETY: recording command buffer; the set was allocated for this layout's set 0.
        unsafe {
            self.device
                .cmd_bind_descriptor_sets(self.cmd, point, layout.handle, 0, &[set.0], &[])
        };
        self.counts.descriptor_binds += 1;
    }

    /// Binds vertex buffer 0 at `vertex_offset` and, if given, a u32 index buffer.
    pub fn bind_buffers(
        &mut self,
        vertices: &Buffer,
        vertex_offset: u64,
        indices: Option<&Buffer>,
    ) {
        // SAFETY: recording command buffer and valid buffers.
        unsafe {
            self.device
                .cmd_bind_vertex_buffers(self.cmd, 0, &[vertices.handle], &[vertex_offset]);
            if let Some(ib) = indices {
                self.device
                    .cmd_bind_index_buffer(self.cmd, ib.handle, 0, vk::IndexType::UINT32);
            }
        }
        self.counts.buffer_binds += 1;
    }

    /// Push constants at offset 0 for every stage of `layout` (at most its push size).
    pub fn push_constants(&mut self, layout: &PipelineLayout, bytes: &[u8]) {
        let len = bytes.len().min(layout.push_size as usize);
        // SAFETY: recording command buffer; the range lies in the layout's push range.
        unsafe {
            self.device.cmd_push_constants(
                self.cmd,
                layout.handle,
                PipelineLayout::STAGES,
                0,
                &bytes[..len],
            )
        };
    }
    /// Indexed draw; counts the draw and its triangles.
    pub fn draw_indexed(
        &mut self,
        index_count: u32,
        instances: u32,
        first_index: u32,
        vertex_offset: i32,
        first_instance: u32,
    ) {
        // SAFETY: recording inside rendering with a bound pipeline and buffers.
        unsafe {
            self.device.cmd_draw_indexed(
                self.cmd,
                index_count,
                instances,
                first_index,
                vertex_offset,
                first_instance,
            )
        };
        let tris = (index_count / 3) as u64 * instances as u64;
        self.count_draw(tris);
        if self.last_kind == Some(PipelineKind::Render) && self.in_conditional.is_some() {
            // Drawn only if the predicate holds.
            self.counts.predicated_calls += 1;
            self.counts.predicated_objects += 1;
        }
    }

    /// Non-indexed draw.
    pub fn draw(&mut self, vertex_count: u32, instances: u32) {
        // SAFETY: recording inside rendering with a bound pipeline.
        unsafe {
            self.device
                .cmd_draw(self.cmd, vertex_count, instances, 0, 0)
        };
        self.count_draw((vertex_count / 3) as u64 * instances as u64);
    }

    /// Binds `indices` (32-bit) as the index buffer.
    pub fn bind_index_buffer(&mut self, indices: &Buffer) {
        // SAFETY: recording command buffer and a valid buffer.
        unsafe {
            self.device
                .cmd_bind_index_buffer(self.cmd, indices.handle, 0, vk::IndexType::UINT32)
        };
    }

    /// Indexed instanced draw of `index_count` indices from instance `first_instance` on.
    pub fn draw_indexed_instanced(
        &mut self,
        index_count: u32,
        instances: u32,
        first_instance: u32,
    ) {
        // SAFETY: recording inside rendering with a bound pipeline and index buffer.
        unsafe {
            self.device
                .cmd_draw_indexed(self.cmd, index_count, instances, 0, 0, first_instance)
        };
        self.count_draw((index_count / 3) as u64 * instances as u64);
    }

    /// Counts a draw of `tris` triangles and, in render state, as an object draw (query boxes
    /// are drawn and counted by coherent-ash's query set, and added to these counts by the
    /// scene renderer after the frame).
    fn count_draw(&mut self, tris: u64) {
        self.counts.draw_calls += 1;
        self.counts.triangles += tris;
        if self.last_kind == Some(PipelineKind::Render) {
            self.counts.object_draws += 1;
            self.counts.render_triangles += tris;
        }
    }

    /// Counts the draw commands the device gathered for one
    /// [`Recorder::draw_indexed_indirect_count`] from the draws of `parts` predicates (tested
    /// parts or queried nodes): `objects` candidates of `tris` triangles in all, each drawn
    /// only where its predicate is true, counted as objects and triangles sent under
    /// predicates.
    pub fn count_gathered(&mut self, parts: u32, objects: u32, tris: u64) {
        self.counts.gathered_parts += parts;
        self.counts.triangles += tris;
        self.counts.render_triangles += tris;
        self.counts.predicated_objects += objects;
    }

    /// Tags the query begun last: a multiquery and/or a visible-leaf query (so queries can be
    /// counted by purpose where they are recorded).
    pub fn tag_query(&mut self, multiquery: bool, visible_leaf: bool) {
        self.counts.multiqueries += multiquery as u32;
        self.counts.visible_leaf_queries += visible_leaf as u32;
    }

    /// Writes timestamp `id` of `pools` after all previous work (BOTTOM_OF_PIPE: for a
    /// timestamp the same point as ALL_COMMANDS, without best practices' warning about it).
    pub fn write_timestamp(&mut self, pools: &QueryPools, id: u32) {
        let (pool, index) = pools.location(id);
        // SAFETY: the query was reset.
        unsafe {
            self.device.cmd_write_timestamp2(
                self.cmd,
                vk::PipelineStageFlags2::BOTTOM_OF_PIPE,
                pool,
                index,
            )
        };
    }

    /// Begins dynamic rendering into `colors` and `depth` over `layers` array layers, with a
    /// viewport and scissor covering the attachments (flipped so +y is up, GL style). The
    /// attachments must be in their attachment use (see [`Recorder::transition`]), of one size,
    /// and have at least `layers` layers (checked here: lavapipe crashes instead of reporting it).
    pub fn begin_rendering(
        &mut self,
        colors: &[Attachment],
        depth: Option<Attachment>,
        layers: u32,
    ) -> Result<()> {
        let first = colors
            .first()
            .or(depth.as_ref())
            .ok_or_else(|| Error::Input("a rendering needs an attachment".into()))?;
        let extent = first.image.extent;
        if colors.len() > MAX_COLOR_ATTACHMENTS {
            return Err(Error::Input(format!(
                "{} color attachments (at most {MAX_COLOR_ATTACHMENTS})",
                colors.len()
            )));
        }
        for a in colors.iter().chain(depth.as_ref()) {
            if a.image.extent != extent || a.image.layers < layers.max(1) {
                return Err(Error::Input(format!(
                    "rendering of {}x{}x{layers}: an attachment is {}x{}x{}",
                    extent.width,
                    extent.height,
                    a.image.extent.width,
                    a.image.extent.height,
                    a.image.layers
                )));
            }
        }
        let mut color_infos = [vk::RenderingAttachmentInfo::default(); MAX_COLOR_ATTACHMENTS];
        for (info, a) in color_infos.iter_mut().zip(colors) {
            *info = a.info(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL);
        }
        let depth_info = depth.map(|d| d.info(vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL));
        let mut info = vk::RenderingInfo::default()
            .render_area(vk::Rect2D {
                offset: vk::Offset2D::default(),
                extent,
            })
            .layer_count(layers.max(1))
            .color_attachments(&color_infos[..colors.len()]);
        if let Some(d) = depth_info.as_ref() {
            info = info.depth_attachment(d);
        }
        // SAFETY: recording outside rendering; attachments checked above, in attachment layouts.
        unsafe { self.device.cmd_begin_rendering(self.cmd, &info) };
        self.render_extent = extent;
        self.set_viewport(extent);
        Ok(())
    }

    /// Ends dynamic rendering.
    pub fn end_rendering(&mut self) {
        // SAFETY: inside rendering.
        unsafe { self.device.cmd_end_rendering(self.cmd) };
    }

    /// Clears the depth attachment of the current rendering to `depth` in each of `layers`
    /// (whole render area). Layers must lie within the rendering's layer count.
    pub fn clear_depth_layers(&mut self, layers: impl Iterator<Item = u32>, depth: f32) {
        let clear = [vk::ClearAttachment {
            aspect_mask: vk::ImageAspectFlags::DEPTH,
            color_attachment: 0,
            clear_value: vk::ClearValue {
                depth_stencil: vk::ClearDepthStencilValue { depth, stencil: 0 },
            },
        }];
        let rect = vk::Rect2D {
            offset: vk::Offset2D::default(),
            extent: self.render_extent,
        };
        for layer in layers {
            let rects = [vk::ClearRect {
                rect,
                base_array_layer: layer,
                layer_count: 1,
            }];
            // SAFETY: inside rendering; the rect is the render area; the caller keeps the layer
            // within the rendering's layers.
            unsafe { self.device.cmd_clear_attachments(self.cmd, &clear, &rects) };
        }
    }

    fn set_viewport(&mut self, extent: vk::Extent2D) {
        let vp = vk::Viewport {
            x: 0.0,
            y: extent.height as f32,
            width: extent.width as f32,
            height: -(extent.height as f32),
            min_depth: 0.0,
            max_depth: 1.0,
        };
        let sc = vk::Rect2D {
            offset: vk::Offset2D::default(),
            extent,
        };
        // SAFETY: recording command buffer; dynamic viewport/scissor declared in pipelines.
        unsafe {
            self.device.cmd_set_viewport(self.cmd, 0, &[vp]);
            self.device.cmd_set_scissor(self.cmd, 0, &[sc]);
        }
    }

    /// Moves `image` from its current use to `to` (layout transition and memory dependency;
    /// recorded even when the use does not change, e.g. between two segments of one frame).
    pub fn transition(&mut self, image: &Image, to: ImageUse) {
        let from = image.state().access();
        self.image_barrier(image, from, to);
    }

    /// Like [`Recorder::transition`], but the old contents are discarded (old layout
    /// UNDEFINED; earlier accesses are still waited for).
    pub fn discard(&mut self, image: &Image, to: ImageUse) {
        let (_, stage, _) = image.state().access();
        let from = (vk::ImageLayout::UNDEFINED, stage, vk::AccessFlags2::NONE);
        self.image_barrier(image, from, to);
    }

    fn image_barrier(
        &mut self,
        image: &Image,
        from: (vk::ImageLayout, vk::PipelineStageFlags2, vk::AccessFlags2),
        to: ImageUse,
    ) {
        let b = image_barrier(image.handle, image.full_range(), from, to.access());
        self.barrier(&[b], &[]);
        image.set_state(to);
    }

    /// A synchronization2 barrier.
    pub(crate) fn barrier(
        &mut self,
        images: &[vk::ImageMemoryBarrier2],
        buffers: &[vk::BufferMemoryBarrier2],
    ) {
        let dep = vk::DependencyInfo::default()
            .image_memory_barriers(images)
            .buffer_memory_barriers(buffers);
        // SAFETY: recording outside rendering.
        unsafe { self.device.cmd_pipeline_barrier2(self.cmd, &dep) };
    }

    /// Makes transfer writes to `buffer` visible to host reads.
    pub(crate) fn host_read_barrier(&mut self, buffer: &Buffer) {
        let b = vk::BufferMemoryBarrier2::default()
            .buffer(buffer.handle)
            .size(vk::WHOLE_SIZE)
            .src_stage_mask(vk::PipelineStageFlags2::ALL_TRANSFER)
            .src_access_mask(vk::AccessFlags2::TRANSFER_WRITE)
            .dst_stage_mask(vk::PipelineStageFlags2::HOST)
            .dst_access_mask(vk::AccessFlags2::HOST_READ);
        self.barrier(&[], &[b]);
    }

    /// Copies whole layers of `src` (in [`ImageUse::TransferSrc`]) to layers of `dst` (in
    /// [`ImageUse::TransferDst`]): each pair is (source layer, destination layer). The images
    /// must have the same format and extent, and the layers must exist (checked here).
    pub fn copy_layers(&mut self, src: &Image, dst: &Image, pairs: &[(u32, u32)]) -> Result<()> {
        if src.format != dst.format || src.extent != dst.extent {
            return Err(Error::Input(
                "layer copy between images of different format or size".into(),
            ));
        }
        if let Some(&(s, d)) = pairs
            .iter()
            .find(|&&(s, d)| s >= src.layers || d >= dst.layers)
        {
            return Err(Error::Input(format!(
                "layer copy {s} -> {d} outside {} / {} layers",
                src.layers, dst.layers
            )));
        }
        let layer = |l: u32| vk::ImageSubresourceLayers {
            aspect_mask: src.aspect(),
            mip_level: 0,
            base_array_layer: l,
            layer_count: 1,
        };
        let extent = vk::Extent3D {
            width: src.extent.width,
            height: src.extent.height,
            depth: 1,
        };
        let regions: Vec<vk::ImageCopy> = pairs
            .iter()
            .map(|&(s, d)| vk::ImageCopy {
                src_subresource: layer(s),
                src_offset: vk::Offset3D::default(),
                dst_subresource: layer(d),
                dst_offset: vk::Offset3D::default(),
                extent,
            })
            .collect();
        if regions.is_empty() {
            return Ok(());
        }
        // SAFETY: recording outside rendering; the images are in the transfer layouts named
        // above (the caller's transitions), same format and extent, layers checked.
        unsafe {
            self.device.cmd_copy_image(
                self.cmd,
                src.handle,
                vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                dst.handle,
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                &regions,
            )
        };
        Ok(())
    }

    /// Copies an image layer to a buffer.
    pub(crate) fn copy_image_to_buffer(
        &mut self,
        image: vk::Image,
        buffer: vk::Buffer,
        region: vk::BufferImageCopy,
    ) {
        // SAFETY: image in TRANSFER_SRC_OPTIMAL; buffer large enough (checked by caller).
        unsafe {
            self.device.cmd_copy_image_to_buffer(
                self.cmd,
                image,
                vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                buffer,
                &[region],
            )
        };
    }

    /// Blits layer 0 of `src` (TRANSFER_SRC_OPTIMAL) to `dst` (TRANSFER_DST_OPTIMAL), scaling
    /// with nearest filtering (viewer presentation).
    pub(crate) fn blit_image(&mut self, src: vk::Image, dst: vk::Image, region: vk::ImageBlit) {
        // SAFETY: recording outside rendering; images in the stated layouts with blit usage.
        unsafe {
            self.device.cmd_blit_image(
                self.cmd,
                src,
                vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                dst,
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                &[region],
                vk::Filter::NEAREST,
            )
        };
    }

    /// Copies buffer regions into `image` (TRANSFER_DST_OPTIMAL) (viewer overlay).
    pub(crate) fn copy_buffer_to_image(
        &mut self,
        buffer: vk::Buffer,
        image: vk::Image,
        regions: &[vk::BufferImageCopy],
    ) {
        // SAFETY: recording outside rendering; regions inside both (checked by the caller).
        unsafe {
            self.device.cmd_copy_buffer_to_image(
                self.cmd,
                buffer,
                image,
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                regions,
            )
        };
    }

    /// Dispatches the bound compute pipeline (`what` names it in errors); counts the dispatch.
    /// A workgroup count above the device's `maxComputeWorkGroupCount` is [`Error::Limit`]
    /// and nothing is recorded.
    pub fn dispatch(&mut self, what: &str, x: u32, y: u32, z: u32) -> Result<()> {
        super::DeviceInfo::check_group_count(what, [x, y, z], self.max_work_group_count)?;
        // SAFETY: compute pipeline bound; the counts are within the device's limits.
        unsafe { self.device.cmd_dispatch(self.cmd, x, y, z) };
        self.counts.dispatches += 1;
        Ok(())
    }

    /// `vkCmdDrawIndexedIndirectCount`: up to `max_draws` indexed draw commands of 20 bytes
    /// each from `commands` at `offset`, as many as the u32 in `count` at `count_offset` says.
    /// Counts one draw call and one indirect draw (the objects it draws are only known after
    /// the frame, when the caller reads them back). The device must have `drawIndirectCount`
    /// (checked by the caller through [`super::DeviceInfo::optional`]).
    pub fn draw_indexed_indirect_count(
        &mut self,
        commands: &Buffer,
        offset: u64,
        count: &Buffer,
        count_offset: u64,
        max_draws: u32,
    ) {
        // SAFETY: recording inside rendering with a bound pipeline and index buffer; the
        // buffers have INDIRECT_BUFFER usage and hold `max_draws` commands and the count.
        unsafe {
            self.device.cmd_draw_indexed_indirect_count(
                self.cmd,
                commands.handle,
                offset,
                count.handle,
                count_offset,
                max_draws,
                std::mem::size_of::<vk::DrawIndexedIndirectCommand>() as u32,
            )
        };
        self.counts.draw_calls += 1;
        self.counts.indirect_draws += 1;
    }

    /// `vkCmdDrawIndexedIndirect` of `count` commands of 20 bytes from `commands` at
    /// `offset`, which the caller wrote as the draws of `count` objects of `triangles`
    /// triangles in all. One draw call and one indirect draw; in render state it is one object
    /// draw, and inside a conditional block it counts as one predicated call of `count`
    /// objects. More than one command needs the device's `multiDrawIndirect` and at most
    /// `maxDrawIndirectCount` of them, and an object index other than 0 as `first_instance`
    /// needs `drawIndirectFirstInstance` (checked by the caller).
    pub fn draw_objects_indirect(
        &mut self,
        commands: &Buffer,
        offset: u64,
        count: u32,
        triangles: u64,
    ) {
        if count == 0 {
            return;
        }
        // SAFETY: recording inside rendering with a bound pipeline and index buffer; the
        // buffer has INDIRECT_BUFFER usage and holds the commands at `offset`; the caller
        // checked the features and the count limit.
        unsafe {
            self.device.cmd_draw_indexed_indirect(
                self.cmd,
                commands.handle,
                offset,
                count,
                std::mem::size_of::<vk::DrawIndexedIndirectCommand>() as u32,
            )
        };
        self.count_draw(triangles);
        self.counts.indirect_draws += 1;
        if self.last_kind == Some(PipelineKind::Render) && self.in_conditional.is_some() {
            self.counts.predicated_calls += 1;
            self.counts.predicated_objects += count;
        }
    }

    /// Fills `size` bytes of `buffer` at `offset` with the u32 `value` (outside rendering).
    pub fn fill_buffer(&mut self, buffer: &Buffer, offset: u64, size: u64, value: u32) {
        // SAFETY: recording outside rendering; the buffer has TRANSFER_DST usage and the range
        // lies inside it (multiples of 4, checked by the caller).
        unsafe {
            self.device
                .cmd_fill_buffer(self.cmd, buffer.handle, offset, size, value)
        };
    }

    /// Copies `size` bytes from the start of `src` to the start of `dst` (outside rendering).
    pub fn copy_buffer(&mut self, src: &Buffer, dst: &Buffer, size: u64) {
        let region = [vk::BufferCopy::default().size(size)];
        // SAFETY: recording outside rendering; `src` has TRANSFER_SRC and `dst` TRANSFER_DST
        // usage and both hold at least `size` bytes (the caller's invariant).
        unsafe {
            self.device
                .cmd_copy_buffer(self.cmd, src.handle, dst.handle, &region)
        };
    }

    /// A global memory barrier: accesses `from` happen before accesses `to`.
    pub fn memory_barrier(&mut self, from: Access, to: Access) {
        let (src_stage, src_access) = from.stage_access();
        let (dst_stage, dst_access) = to.stage_access();
        let b = [vk::MemoryBarrier2::default()
            .src_stage_mask(src_stage)
            .src_access_mask(src_access)
            .dst_stage_mask(dst_stage)
            .dst_access_mask(dst_access)];
        let dep = vk::DependencyInfo::default().memory_barriers(&b);
        // SAFETY: recording outside rendering.
        unsafe { self.device.cmd_pipeline_barrier2(self.cmd, &dep) };
    }

    /// Counts a queue submission made by the owner of this recorder.
    pub(crate) fn note_submit(&mut self) {
        self.counts.submits += 1;
    }

    /// Counts an occlusion-query result read back, and whether it was visible.
    pub fn note_query_read(&mut self, visible: bool) {
        self.counts.queries_read += 1;
        if visible {
            self.counts.queries_visible += 1;
        }
    }
}

/// Layout-transition barrier for a whole image (or the given range).
pub(crate) fn image_barrier(
    image: vk::Image,
    range: vk::ImageSubresourceRange,
    from: (vk::ImageLayout, vk::PipelineStageFlags2, vk::AccessFlags2),
    to: (vk::ImageLayout, vk::PipelineStageFlags2, vk::AccessFlags2),
) -> vk::ImageMemoryBarrier2<'static> {
    vk::ImageMemoryBarrier2::default()
        .image(image)
        .subresource_range(range)
        .old_layout(from.0)
        .src_stage_mask(from.1)
        .src_access_mask(from.2)
        .new_layout(to.0)
        .dst_stage_mask(to.1)
        .dst_access_mask(to.2)
}
