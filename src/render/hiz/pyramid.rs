//! The Hi-Z depth pyramid: a mip chain of the farthest depth, built by one compute dispatch per
//! level from the frame's depth buffer. Texel (x, y) of level k covers the 2^(k+1) x 2^(k+1)
//! pixels from (x, y) * 2^(k+1), clipped to the image, so the culling test addresses texels
//! with shifts. Level k must then hold ceil(size / 2^(k+1)) texels (its *valid* region) while
//! Vulkan mips halve rounding down: the image is padded to powers of two (level 0 is the next
//! power of two of half the depth buffer) and only the valid region is computed and read, each
//! 2x2 block clamped to the valid region of the level below. No pixel is lost at odd sizes.

use std::sync::Arc;

use ash::vk;

use crate::error::{Error, Result};
use crate::gpu::{
    bytes_of, shaders, Access, Binding, ComputePipeline, DescriptorSets, GpuContext, Image,
    ImageUse, MipImage, PipelineLayout, Recorder, Sampler,
};

/// Workgroup edge of the reduction shader (hiz_reduce.comp: 8x8).
const GROUP: u32 = 8;

/// The pyramid image, its reduction pipeline and one descriptor set per level.
pub struct DepthPyramid {
    pipeline: ComputePipeline,
    layout: PipelineLayout,
    sets: DescriptorSets,
    /// Nearest sampler for texel fetches (no filtering: the reduction is done by hand, which
    /// needs no optional feature and stays exact at odd sizes).
    pub sampler: Sampler,
    /// The pyramid (R32_SFLOAT, GENERAL layout once built).
    pub image: MipImage,
    /// The valid region of each level (the rest is padding, never written or read).
    pub valid: Vec<(u32, u32)>,
    /// Size of the depth buffer.
    depth_size: (u32, u32),
}

impl DepthPyramid {
    /// A pyramid for `depth` (a sampled depth image).
    pub fn new(ctx: &Arc<GpuContext>, depth: &Image) -> Result<DepthPyramid> {
        let (w, h) = depth.size();
        let valid = valid_sizes((w, h));
        let size = (
            valid[0].0.next_power_of_two(),
            valid[0].1.next_power_of_two(),
        );
        check_dispatch(ctx, valid[0])?;
        let image = MipImage::new(ctx, "hi-z pyramid", vk::Format::R32_SFLOAT, size)?;
        let sampler = Sampler::nearest_clamp(ctx)?;
        let layout = PipelineLayout::new(
            ctx,
            &[
                vk::DescriptorType::COMBINED_IMAGE_SAMPLER,
                vk::DescriptorType::STORAGE_IMAGE,
            ],
            16,
        )?;
        let pipeline = ComputePipeline::new(ctx, &layout, "hiz reduce", shaders::HIZ_REDUCE_COMP)?;
        let bindings: Vec<[Binding; 2]> = (0..image.levels())
            .map(|level| {
                let src = match level {
                    0 => Binding::Sampled(depth, &sampler),
                    l => Binding::SampledMips(&image, Some(l - 1), &sampler),
                };
                [src, Binding::StorageMip(&image, level)]
            })
            .collect();
        let sets: Vec<(&PipelineLayout, &[Binding])> =
            bindings.iter().map(|b| (&layout, &b[..])).collect();
        let sets = DescriptorSets::new(ctx, &sets)?;
        Ok(DepthPyramid {
            pipeline,
            layout,
            sets,
            sampler,
            valid: valid[..image.levels() as usize].to_vec(),
            image,
            depth_size: (w, h),
        })
    }

    /// Records the reduction of `depth` (the image this pyramid was made for) into every
    /// level. Leaves `depth` sampled by compute (the caller moves it back to an attachment)
    /// and the pyramid readable by compute shaders.
    pub fn record_build(&mut self, rec: &mut Recorder, depth: &Image) -> Result<()> {
        rec.transition(depth, ImageUse::SampledByCompute);
        rec.mip_barrier(
            &mut self.image,
            Access::ComputeReadWrite,
            Access::ComputeReadWrite,
        );
        rec.bind_compute_pipeline(&self.pipeline);
        for level in 0..self.image.levels() {
            if level > 0 {
                rec.memory_barrier(Access::ComputeReadWrite, Access::ComputeReadWrite);
            }
            rec.bind_compute_set(&self.layout, self.sets.get(level as usize));
            let src = match level {
                0 => self.depth_size,
                l => self.valid[l as usize - 1],
            };
            let dst = self.valid[level as usize];
            rec.push_constants(&self.layout, bytes_of(&[src.0, src.1, dst.0, dst.1]));
            rec.dispatch(
                "depth pyramid level",
                dst.0.div_ceil(GROUP),
                dst.1.div_ceil(GROUP),
                1,
            )?;
        }
        rec.memory_barrier(Access::ComputeReadWrite, Access::ComputeReadWrite);
        Ok(())
    }
}

/// Valid region of each level for a depth buffer of `size`: halve rounding up, to 1x1, and
/// then 1x1 for any further level of the padded image.
pub fn valid_sizes(size: (u32, u32)) -> Vec<(u32, u32)> {
    let mut sizes = Vec::new();
    let mut s = size;
    while s != (1, 1) || sizes.is_empty() {
        s = (s.0.div_ceil(2), s.1.div_ceil(2));
        sizes.push(s);
    }
    // The padded image may have more levels (its sides are powers of two >= the valid ones).
    sizes.resize(sizes.len() + 32, (1, 1));
    sizes
}

/// Checks the device limits the reduction relies on for a level 0 of `size`.
fn check_dispatch(ctx: &GpuContext, size: (u32, u32)) -> Result<()> {
    let i = &ctx.info;
    let groups = [size.0.div_ceil(GROUP), size.1.div_ceil(GROUP)];
    let fits = i.max_compute_work_group_size[0] >= GROUP
        && i.max_compute_work_group_size[1] >= GROUP
        && i.max_compute_work_group_invocations >= GROUP * GROUP
        && groups[0] <= i.max_compute_work_group_count[0]
        && groups[1] <= i.max_compute_work_group_count[1];
    if fits {
        Ok(())
    } else {
        Err(Error::Unsupported {
            feature: format!(
                "a {}x{} depth pyramid needs {}x{} workgroups of {GROUP}x{GROUP} \
                 (device: maxComputeWorkGroupCount {:?}, maxComputeWorkGroupSize {:?})",
                size.0,
                size.1,
                groups[0],
                groups[1],
                i.max_compute_work_group_count,
                i.max_compute_work_group_size
            ),
        })
    }
}
