//! The only module that talks to ash. It owns every Vulkan object and every queue submission:
//! the context, memory (buffers, images with tracked layouts), pipelines (graphics and compute),
//! descriptor sets and samplers, command pools and the counting recorder, the timeline that every
//! submission goes through, query pools, offscreen targets and the swapchain. `render/` and
//! `gi/` compose these types and never call ash themselves.

pub mod commands;
pub mod context;
pub mod descriptors;
pub mod memory;
pub mod pipelines;
pub mod pyramid;
pub mod queries;
pub mod shaders;
pub mod swapchain;
pub mod sync;
pub mod targets;
pub mod texture;

use std::sync::Arc;

pub use commands::{Access, Attachment, CommandBuffer, CommandCounts, CommandPool, Load, Recorder};
pub use context::{
    ContextOptions, DeviceInfo, GpuContext, LimitOverrides, MemoryUsage, OptionalFeatures,
    Severity, ValidationLog, ValidationMessage,
};
pub use descriptors::{Binding, DescriptorSet, DescriptorSets, Sampler};
pub use memory::{as_bytes, bytes_of, word_at, Buffer, Image, ImageUse, Pod};
pub use pipelines::{ComputePipeline, Pipeline, PipelineDesc, PipelineKind, PipelineLayout};
pub use pyramid::MipImage;
pub use sync::Timeline;
pub use texture::{AddressMode, Mips, SamplerModes, Texture};

use crate::error::Result;

/// A command pool and a timeline for one-off work (uploads, readback): record, submit, wait.
pub struct OneShot {
    // The timeline is declared first so that it is dropped (waiting for its work) before the pool.
    timeline: Timeline,
    pool: CommandPool,
}

impl OneShot {
    /// Creates the pool and the timeline.
    pub fn new(ctx: &Arc<GpuContext>) -> Result<OneShot> {
        Ok(OneShot {
            timeline: Timeline::new(ctx)?,
            pool: CommandPool::new(ctx)?,
        })
    }

    /// Records with `f` into a fresh command buffer, submits it and waits. The recorder's
    /// counts and command buffer are as they were before. Nothing is submitted if `f` fails.
    pub fn run(
        &mut self,
        recorder: &mut Recorder,
        f: impl FnOnce(&mut Recorder) -> Result<()>,
    ) -> Result<()> {
        self.pool.reset(&self.timeline)?;
        let cmd = self.pool.begin_next()?;
        let saved = recorder.counts;
        let prev = recorder.command_buffer();
        recorder.set_command_buffer(cmd);
        let submitted = f(recorder).and_then(|()| self.timeline.submit(recorder));
        recorder.set_command_buffer(prev);
        recorder.counts = saved;
        self.timeline.wait(submitted?)
    }
}
