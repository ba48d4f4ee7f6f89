//! The command recorder: the one type that records `vkCmd*` calls. It skips redundant pipeline
//! binds (dirty tracking) and counts every bind, render/query state switch, draw, triangle,
//! query and submit, so frame statistics come from what was really recorded.

use ash::vk;

use super::pipelines::{Pipeline, PipelineKind};

/// What the recorder saw.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CommandCounts {
    /// `vkCmdBindPipeline` calls.
    pub pipeline_binds: u32,
    /// Switches between render and query state (a bind whose kind differs from the last one).
    pub state_changes: u32,
    /// Draw calls.
    pub draw_calls: u32,
    /// Triangles submitted by draw calls (render and query geometry).
    pub triangles: u64,
    /// Triangles of render-state draws only.
    pub render_triangles: u64,
    /// `vkCmdBeginQuery` calls for occlusion queries.
    pub queries_begun: u32,
    /// Occlusion-query results read back.
    pub queries_read: u32,
    /// Occlusion-query results that counted more pixels than the visibility threshold.
    pub queries_visible: u32,
    /// Queue submissions.
    pub submits: u32,
    /// Descriptor-set binds.
    pub descriptor_binds: u32,
    /// Vertex/index buffer binds.
    pub buffer_binds: u32,
}

/// Records into one command buffer at a time and counts.
pub struct Recorder {
    device: ash::Device,
    cmd: vk::CommandBuffer,
    bound: Option<vk::Pipeline>,
    last_kind: Option<PipelineKind>,
    /// Counts since the last [`Recorder::take_counts`].
    pub counts: CommandCounts,
}

impl Recorder {
    /// A recorder for `device`; call [`Recorder::set_command_buffer`] before recording.
    pub fn new(device: ash::Device) -> Recorder {
        Recorder {
            device,
            cmd: vk::CommandBuffer::null(),
            bound: None,
            last_kind: None,
            counts: CommandCounts::default(),
        }
    }

    /// Starts recording into a new command buffer (already begun): bound state is forgotten.
    pub fn set_command_buffer(&mut self, cmd: vk::CommandBuffer) {
        self.cmd = cmd;
        self.bound = None;
    }

    /// The current command buffer.
    pub fn command_buffer(&self) -> vk::CommandBuffer {
        self.cmd
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
        self.bound = Some(p.handle);
        self.counts.pipeline_binds += 1;
        if self.last_kind.is_some() && self.last_kind != Some(p.kind) {
            self.counts.state_changes += 1;
        }
        self.last_kind = Some(p.kind);
        true
    }

    /// Binds a compute pipeline.
    pub fn bind_compute_pipeline(&mut self, p: vk::Pipeline) {
        // SAFETY: recording command buffer and valid pipeline.
        unsafe {
            self.device
                .cmd_bind_pipeline(self.cmd, vk::PipelineBindPoint::COMPUTE, p)
        };
        self.counts.pipeline_binds += 1;
    }

    /// Binds descriptor set 0.
    pub fn bind_descriptor_set(
        &mut self,
        bind_point: vk::PipelineBindPoint,
        layout: vk::PipelineLayout,
        set: vk::DescriptorSet,
    ) {
        // SAFETY: recording command buffer; set compatible with layout.
        unsafe {
            self.device
                .cmd_bind_descriptor_sets(self.cmd, bind_point, layout, 0, &[set], &[])
        };
        self.counts.descriptor_binds += 1;
    }

    /// Binds vertex buffer 0 and, if given, a u32 index buffer.
    pub fn bind_buffers(
        &mut self,
        vertices: vk::Buffer,
        vertex_offset: u64,
        indices: Option<vk::Buffer>,
    ) {
        // SAFETY: recording command buffer and valid buffers.
        unsafe {
            self.device
                .cmd_bind_vertex_buffers(self.cmd, 0, &[vertices], &[vertex_offset]);
            if let Some(ib) = indices {
                self.device
                    .cmd_bind_index_buffer(self.cmd, ib, 0, vk::IndexType::UINT32);
            }
        }
        self.counts.buffer_binds += 1;
    }

    /// Push constants for vertex+fragment(+compute) stages.
    pub fn push_constants(
        &mut self,
        layout: vk::PipelineLayout,
        stages: vk::ShaderStageFlags,
        bytes: &[u8],
    ) {
        // SAFETY: recording command buffer; range declared in the layout.
        unsafe {
            self.device
                .cmd_push_constants(self.cmd, layout, stages, 0, bytes)
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
        self.counts.draw_calls += 1;
        self.counts.triangles += tris;
        if self.last_kind == Some(PipelineKind::Render) {
            self.counts.render_triangles += tris;
        }
    }

    /// Non-indexed draw.
    pub fn draw(&mut self, vertex_count: u32, instances: u32) {
        // SAFETY: recording inside rendering with a bound pipeline.
        unsafe {
            self.device
                .cmd_draw(self.cmd, vertex_count, instances, 0, 0)
        };
        self.counts.draw_calls += 1;
        self.counts.triangles += (vertex_count / 3) as u64 * instances as u64;
    }

    /// Begins a precise occlusion query.
    pub fn begin_occlusion_query(&mut self, pool: vk::QueryPool, index: u32) {
        // SAFETY: the query was reset and is not active.
        unsafe {
            self.device
                .cmd_begin_query(self.cmd, pool, index, vk::QueryControlFlags::PRECISE)
        };
        self.counts.queries_begun += 1;
    }

    /// Ends a query.
    pub fn end_query(&mut self, pool: vk::QueryPool, index: u32) {
        // SAFETY: the query is active in this command buffer.
        unsafe { self.device.cmd_end_query(self.cmd, pool, index) };
    }

    /// Writes a timestamp after all previous work.
    pub fn write_timestamp(&mut self, pool: vk::QueryPool, index: u32) {
        // SAFETY: the query was reset.
        unsafe {
            self.device.cmd_write_timestamp2(
                self.cmd,
                vk::PipelineStageFlags2::ALL_COMMANDS,
                pool,
                index,
            )
        };
    }

    /// Begins dynamic rendering.
    pub fn begin_rendering(&mut self, info: &vk::RenderingInfo) {
        // SAFETY: recording outside rendering; attachments in the right layouts.
        unsafe { self.device.cmd_begin_rendering(self.cmd, info) };
    }

    /// Ends dynamic rendering.
    pub fn end_rendering(&mut self) {
        // SAFETY: inside rendering.
        unsafe { self.device.cmd_end_rendering(self.cmd) };
    }

    /// Clears regions (and array layers) of the current rendering's attachments.
    pub fn clear_attachments(
        &mut self,
        attachments: &[vk::ClearAttachment],
        rects: &[vk::ClearRect],
    ) {
        if attachments.is_empty() || rects.is_empty() {
            return;
        }
        // SAFETY: inside rendering; the rects lie within the render area and its layers.
        unsafe {
            self.device
                .cmd_clear_attachments(self.cmd, attachments, rects)
        };
    }

    /// Viewport (flipped so +y is up, GL style) and scissor covering `extent`.
    pub fn set_viewport(&mut self, extent: vk::Extent2D) {
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

    /// A synchronization2 barrier.
    pub fn barrier(
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

    /// Copies an image layer to a buffer.
    pub fn copy_image_to_buffer(
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
    pub fn blit_image(&mut self, src: vk::Image, dst: vk::Image, region: vk::ImageBlit) {
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
    pub fn copy_buffer_to_image(
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

    /// Dispatches a compute shader.
    pub fn dispatch(&mut self, x: u32, y: u32, z: u32) {
        // SAFETY: compute pipeline bound.
        unsafe { self.device.cmd_dispatch(self.cmd, x, y, z) };
    }

    /// Counts a queue submission made by the owner of this recorder.
    pub fn note_submit(&mut self) {
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

/// Resets `cmd` (when `reset`; buffers from a pool reset as a whole pass `false`) and begins it
/// for one submission. The caller guarantees the buffer is not in flight.
pub fn begin_one_time(
    device: &ash::Device,
    cmd: vk::CommandBuffer,
    reset: bool,
) -> crate::Result<()> {
    use crate::error::VkContext;
    // SAFETY: the caller guarantees `cmd` is not pending execution.
    unsafe {
        if reset {
            device
                .reset_command_buffer(cmd, vk::CommandBufferResetFlags::empty())
                .vk("vkResetCommandBuffer")?;
        }
        device
            .begin_command_buffer(
                cmd,
                &vk::CommandBufferBeginInfo::default()
                    .flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT),
            )
            .vk("vkBeginCommandBuffer")
    }
}

/// Layout-transition barrier for a whole image.
pub fn image_barrier(
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
