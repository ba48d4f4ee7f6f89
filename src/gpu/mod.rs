//! The only module that talks to ash: context, memory, pipelines, the counting command recorder,
//! query pools, offscreen targets and embedded shaders.

pub mod commands;
pub mod context;
pub mod memory;
pub mod pipelines;
pub mod queries;
pub mod shaders;
pub mod swapchain;
pub mod targets;

use std::sync::Arc;

use ash::vk;

pub use commands::{CommandCounts, Recorder};
pub use context::{
    ContextOptions, DeviceInfo, GpuContext, Severity, ValidationLog, ValidationMessage,
};

use crate::error::{Result, VkContext};

/// A command pool with one command buffer and a fence, for one-off work (uploads, readback).
pub struct OneShot {
    ctx: Arc<GpuContext>,
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
}

impl OneShot {
    /// Creates the pool, buffer and fence.
    pub fn new(ctx: &Arc<GpuContext>) -> Result<OneShot> {
        let info = vk::CommandPoolCreateInfo::default()
            .queue_family_index(ctx.queue_family)
            .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER);
        // SAFETY: valid device.
        let pool =
            unsafe { ctx.device.create_command_pool(&info, None) }.vk("vkCreateCommandPool")?;
        let mut me = OneShot {
            ctx: ctx.clone(),
            pool,
            cmd: vk::CommandBuffer::null(),
            fence: vk::Fence::null(),
        };
        let alloc = vk::CommandBufferAllocateInfo::default()
            .command_pool(pool)
            .level(vk::CommandBufferLevel::PRIMARY)
            .command_buffer_count(1);
        // SAFETY: valid pool.
        me.cmd = unsafe { ctx.device.allocate_command_buffers(&alloc) }
            .vk("vkAllocateCommandBuffers")?[0];
        // SAFETY: valid device.
        me.fence = unsafe {
            ctx.device
                .create_fence(&vk::FenceCreateInfo::default(), None)
        }
        .vk("vkCreateFence")?;
        Ok(me)
    }

    /// Records with `f`, submits and waits. The recorder's counts are not changed.
    pub fn run(&self, recorder: &mut Recorder, f: impl FnOnce(&mut Recorder)) -> Result<()> {
        // Not in flight: every run waits for its fence.
        commands::begin_one_time(&self.ctx.device, self.cmd, true)?;
        let d = &self.ctx.device;
        let saved = recorder.counts;
        let prev = recorder.command_buffer();
        recorder.set_command_buffer(self.cmd);
        f(recorder);
        recorder.set_command_buffer(prev);
        recorder.counts = saved;
        let cmds = [self.cmd];
        let submit = vk::SubmitInfo::default().command_buffers(&cmds);
        // SAFETY: recorded above; fence unsignaled.
        unsafe {
            d.end_command_buffer(self.cmd).vk("vkEndCommandBuffer")?;
            d.queue_submit(self.ctx.queue, &[submit], self.fence)
                .vk("vkQueueSubmit")?;
            d.wait_for_fences(&[self.fence], true, u64::MAX)
                .vk("vkWaitForFences")?;
            d.reset_fences(&[self.fence]).vk("vkResetFences")?;
        }
        Ok(())
    }
}

impl Drop for OneShot {
    fn drop(&mut self) {
        // SAFETY: every run waited for completion, so nothing is in flight.
        unsafe {
            self.ctx.device.destroy_fence(self.fence, None);
            self.ctx.device.destroy_command_pool(self.pool, None);
        }
    }
}
