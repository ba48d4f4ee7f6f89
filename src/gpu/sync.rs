//! The one submit path: every queue submission of the crate (renderer segments, GI frames,
//! one-shot uploads and readbacks, the swapchain's present buffer) goes through
//! [`Timeline::submit`], which signals a timeline semaphore so completion can be polled
//! ([`Timeline::is_complete`], never blocks) or waited for ([`Timeline::wait`], blocks).

use std::cell::Cell;
use std::sync::Arc;

use ash::vk;

use super::commands::Recorder;
use super::GpuContext;
use crate::error::{Result, VkContext};

/// A timeline semaphore and the last value submitted on it.
pub struct Timeline {
    ctx: Arc<GpuContext>,
    semaphore: vk::Semaphore,
    last: u64,
    /// The highest value seen completed. A timeline's value never decreases, so a value at or
    /// below it is complete without asking the driver (on lavapipe each
    /// `vkGetSemaphoreCounterValue` takes a lock and wakes the queue thread).
    completed: Cell<u64>,
}

/// Binary semaphores a submission waits on and signals (swapchain acquire and present).
#[derive(Clone, Copy, Default)]
pub(crate) struct BinarySync {
    pub wait: Option<vk::Semaphore>,
    pub signal: Option<vk::Semaphore>,
}

impl Timeline {
    /// Creates the semaphore at value 0.
    pub fn new(ctx: &Arc<GpuContext>) -> Result<Timeline> {
        let mut ty = vk::SemaphoreTypeCreateInfo::default()
            .semaphore_type(vk::SemaphoreType::TIMELINE)
            .initial_value(0);
        let info = vk::SemaphoreCreateInfo::default().push_next(&mut ty);
        // SAFETY: valid device with the timelineSemaphore feature enabled.
        let semaphore =
            unsafe { ctx.device.create_semaphore(&info, None) }.vk("vkCreateSemaphore")?;
        Ok(Timeline {
            ctx: ctx.clone(),
            semaphore,
            last: 0,
            completed: Cell::new(0),
        })
    }

    /// Ends the recorder's current command buffer, submits it signalling the next timeline
    /// value, counts the submission in the recorder and returns the value.
    pub fn submit(&mut self, recorder: &mut Recorder) -> Result<u64> {
        self.submit_with(recorder, BinarySync::default())
    }

    /// [`Timeline::submit`] that also waits on and signals binary semaphores.
    pub(crate) fn submit_with(&mut self, recorder: &mut Recorder, sync: BinarySync) -> Result<u64> {
        let cmd = recorder.command_buffer().0;
        let value = self.last + 1;
        // vkQueueSubmit with a chained timeline info rather than vkQueueSubmit2: layers that
        // count commands per submission (Mesa's overlay, used by the tests) only see the former.
        let signals = [self.semaphore, sync.signal.unwrap_or_default()];
        let signals = &signals[..1 + sync.signal.is_some() as usize];
        // Binary semaphores ignore their value; the array only has to be as long.
        let signal_values = [value, 0];
        let waits = [sync.wait.unwrap_or_default()];
        let waits = &waits[..sync.wait.is_some() as usize];
        let wait_values = [0];
        let wait_stages = [vk::PipelineStageFlags::ALL_COMMANDS];
        let mut timeline = vk::TimelineSemaphoreSubmitInfo::default()
            .signal_semaphore_values(&signal_values[..signals.len()]);
        let cmds = [cmd];
        let mut submit = vk::SubmitInfo::default()
            .command_buffers(&cmds)
            .signal_semaphores(signals);
        // Wait arrays only when there is a wait (best practices flags a set pointer with a
        // zero count).
        if !waits.is_empty() {
            timeline = timeline.wait_semaphore_values(&wait_values[..waits.len()]);
            submit = submit
                .wait_semaphores(waits)
                .wait_dst_stage_mask(&wait_stages[..waits.len()]);
        }
        let submit = submit.push_next(&mut timeline);
        let d = &self.ctx.device;
        // SAFETY: the buffer was begun by its pool and recorded through the recorder; the
        // timeline value grows strictly; the queue is used from this thread only.
        unsafe {
            d.end_command_buffer(cmd).vk("vkEndCommandBuffer")?;
            d.queue_submit(self.ctx.queue, &[submit], vk::Fence::null())
                .vk("vkQueueSubmit")?;
        }
        self.last = value;
        recorder.note_submit();
        Ok(value)
    }

    /// The value of the last submission (0 before any).
    pub fn last_submitted(&self) -> u64 {
        self.last
    }

    /// Whether the submission that signals `value` has completed; never blocks.
    pub fn is_complete(&self, value: u64) -> Result<bool> {
        if value <= self.completed.get() {
            return Ok(true);
        }
        // SAFETY: valid timeline semaphore.
        let now = unsafe { self.ctx.device.get_semaphore_counter_value(self.semaphore) }
            .vk("vkGetSemaphoreCounterValue")?;
        self.completed.set(self.completed.get().max(now));
        Ok(now >= value)
    }

    /// Blocks until the submission that signals `value` has completed.
    pub fn wait(&self, value: u64) -> Result<()> {
        let semaphores = [self.semaphore];
        let values = [value];
        let info = vk::SemaphoreWaitInfo::default()
            .semaphores(&semaphores)
            .values(&values);
        // SAFETY: valid timeline semaphore; `value` was (or will be) signalled by a submission.
        unsafe { self.ctx.device.wait_semaphores(&info, u64::MAX) }.vk("vkWaitSemaphores")?;
        self.completed.set(self.completed.get().max(value));
        Ok(())
    }

    /// Blocks until everything submitted on this timeline has completed.
    pub fn wait_all(&self) -> Result<()> {
        self.wait(self.last)
    }
}

impl Drop for Timeline {
    fn drop(&mut self) {
        // SAFETY: waits for every submission that signals it before destroying it.
        unsafe {
            let _ = self.wait_all();
            self.ctx.device.destroy_semaphore(self.semaphore, None);
        }
    }
}
