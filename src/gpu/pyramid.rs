//! Mip-mapped storage images (the Hi-Z depth pyramid): one image with a view per mip level
//! (written by compute shaders as storage images, read as sampled images) and a view of all
//! levels. The image lives in GENERAL layout once initialized; barriers between passes are
//! recorded through [`Recorder::mip_barrier`], and any level can be read back for tests.

use std::sync::Arc;

use ash::vk;
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme};
use gpu_allocator::MemoryLocation;

use super::commands::{Access, Recorder};
use super::memory::{destroy_image, Buffer};
use super::{GpuContext, OneShot};
use crate::error::{Error, Result, VkContext};

/// Create info of an optimal-tiling, exclusive 2D image of `size` with `levels` mips.
pub(super) fn mip_image_info(
    format: vk::Format,
    size: (u32, u32),
    levels: u32,
    usage: vk::ImageUsageFlags,
) -> vk::ImageCreateInfo<'static> {
    vk::ImageCreateInfo::default()
        .image_type(vk::ImageType::TYPE_2D)
        .format(format)
        .extent(vk::Extent3D {
            width: size.0,
            height: size.1,
            depth: 1,
        })
        .mip_levels(levels)
        .array_layers(1)
        .samples(vk::SampleCountFlags::TYPE_1)
        .tiling(vk::ImageTiling::OPTIMAL)
        .usage(usage)
        .sharing_mode(vk::SharingMode::EXCLUSIVE)
        .initial_layout(vk::ImageLayout::UNDEFINED)
}

/// Allocates GPU-only memory for image `handle` (outside the context's memory budget) and
/// binds it. The allocation goes into `slot` even when binding fails, so the owner frees it.
pub(super) fn bind_gpu_only_memory(
    ctx: &GpuContext,
    handle: vk::Image,
    name: &str,
    slot: &mut Option<Allocation>,
) -> Result<()> {
    // SAFETY: handle is an image of this device.
    let requirements = unsafe { ctx.device.get_image_memory_requirements(handle) };
    let allocation = ctx
        .allocator()
        .allocate(&AllocationCreateDesc {
            name,
            requirements,
            location: MemoryLocation::GpuOnly,
            linear: false,
            allocation_scheme: AllocationScheme::GpuAllocatorManaged,
        })
        .map_err(|e| Error::Alloc(format!("{name}: {e}")))?;
    // SAFETY: the allocation satisfies the image's requirements; the memory handle is only
    // used to bind this image.
    let bound = unsafe {
        ctx.device
            .bind_image_memory(handle, allocation.memory(), allocation.offset())
    };
    *slot = Some(allocation);
    bound.vk("vkBindImageMemory")
}

/// A 2D image with `levels` mips, a view per level and one over all levels.
pub struct MipImage {
    ctx: Arc<GpuContext>,
    pub(crate) handle: vk::Image,
    /// View of all levels (sampled reads with an explicit level).
    pub(crate) all_levels: vk::ImageView,
    /// One view per level (storage writes, sampled reads of one level).
    pub(crate) level_views: Vec<vk::ImageView>,
    /// Size of each level.
    sizes: Vec<(u32, u32)>,
    /// Pixel format.
    pub format: vk::Format,
    /// Whether the image is in GENERAL layout (false until the first barrier).
    initialized: bool,
    allocation: Option<Allocation>,
}

impl MipImage {
    /// Creates an image of `size` with its full mip chain (each level half the last, rounded
    /// down, at least 1, to 1x1). Usage: storage, sampled, transfer source.
    pub fn new(
        ctx: &Arc<GpuContext>,
        name: &str,
        format: vk::Format,
        size: (u32, u32),
    ) -> Result<MipImage> {
        let max = ctx.info.max_image_dimension_2d;
        if size.0 == 0 || size.1 == 0 || size.0 > max || size.1 > max {
            return Err(Error::Input(format!(
                "{name}: size {}x{} is outside 1..={max} (maxImageDimension2D)",
                size.0, size.1
            )));
        }
        let sizes = mip_sizes(size);
        let info = mip_image_info(
            format,
            size,
            sizes.len() as u32,
            vk::ImageUsageFlags::STORAGE
                | vk::ImageUsageFlags::SAMPLED
                | vk::ImageUsageFlags::TRANSFER_SRC,
        );
        // SAFETY: valid device and create info.
        let handle = unsafe { ctx.device.create_image(&info, None) }.vk("vkCreateImage")?;
        let mut image = MipImage {
            ctx: ctx.clone(),
            handle,
            all_levels: vk::ImageView::null(),
            level_views: Vec::new(),
            sizes,
            format,
            initialized: false,
            allocation: None,
        };
        image.allocate(name)?;
        image.create_views()?;
        Ok(image)
    }

    fn allocate(&mut self, name: &str) -> Result<()> {
        bind_gpu_only_memory(&self.ctx, self.handle, name, &mut self.allocation)
    }

    fn create_views(&mut self) -> Result<()> {
        self.all_levels = self.view(0, self.levels())?;
        for level in 0..self.levels() {
            let v = self.view(level, 1)?;
            self.level_views.push(v);
        }
        Ok(())
    }

    fn view(&self, base: u32, count: u32) -> Result<vk::ImageView> {
        let info = vk::ImageViewCreateInfo::default()
            .image(self.handle)
            .view_type(vk::ImageViewType::TYPE_2D)
            .format(self.format)
            .subresource_range(range(base, count));
        // SAFETY: valid image with bound memory; the range lies within its levels.
        unsafe { self.ctx.device.create_image_view(&info, None) }.vk("vkCreateImageView")
    }

    /// Number of mip levels.
    pub fn levels(&self) -> u32 {
        self.sizes.len() as u32
    }

    /// Width and height of `level`.
    pub fn level_size(&self, level: u32) -> (u32, u32) {
        self.sizes[level as usize]
    }

    /// Reads `level` back as f32 texels, row by row (the image must hold 4-byte texels). Runs
    /// its own submission and waits; the image stays in GENERAL layout.
    pub fn read_level(
        &mut self,
        oneshot: &mut OneShot,
        recorder: &mut Recorder,
        level: u32,
    ) -> Result<Vec<f32>> {
        let (w, h) = *self
            .sizes
            .get(level as usize)
            .ok_or_else(|| Error::Input(format!("mip level {level} does not exist")))?;
        let buffer = Buffer::new(
            &self.ctx,
            "mip readback",
            w as u64 * h as u64 * 4,
            vk::BufferUsageFlags::TRANSFER_DST,
            MemoryLocation::GpuToCpu,
        )?;
        let handle = self.handle;
        let initialized = self.initialized;
        oneshot.run(recorder, |rec| {
            let from = if initialized {
                vk::ImageLayout::GENERAL
            } else {
                vk::ImageLayout::UNDEFINED
            };
            let src = vk::ImageLayout::TRANSFER_SRC_OPTIMAL;
            rec.layout_barrier(
                handle,
                (from, src),
                Access::ComputeReadWrite,
                Access::TransferRead,
            );
            let region = vk::BufferImageCopy::default()
                .image_subresource(vk::ImageSubresourceLayers {
                    aspect_mask: vk::ImageAspectFlags::COLOR,
                    mip_level: level,
                    base_array_layer: 0,
                    layer_count: 1,
                })
                .image_extent(vk::Extent3D {
                    width: w,
                    height: h,
                    depth: 1,
                });
            rec.copy_image_to_buffer(handle, buffer.handle, region);
            let back = (src, vk::ImageLayout::GENERAL);
            rec.layout_barrier(handle, back, Access::TransferRead, Access::ComputeReadWrite);
            rec.memory_barrier(Access::TransferWrite, Access::HostRead);
            Ok(())
        })?;
        self.initialized = true;
        let bytes = buffer
            .mapped()
            .ok_or_else(|| Error::Alloc("readback buffer is not mapped".into()))?;
        Ok(bytes[..(w * h * 4) as usize]
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect())
    }
}

impl Recorder {
    /// Orders accesses to `image` (all levels): `from` before `to`. The first barrier moves it
    /// from UNDEFINED (contents discarded) to GENERAL, where it stays.
    pub fn mip_barrier(&mut self, image: &mut MipImage, from: Access, to: Access) {
        let old = if image.initialized {
            vk::ImageLayout::GENERAL
        } else {
            vk::ImageLayout::UNDEFINED
        };
        self.layout_barrier(image.handle, (old, vk::ImageLayout::GENERAL), from, to);
        image.initialized = true;
    }

    fn layout_barrier(
        &mut self,
        image: vk::Image,
        (old, new): (vk::ImageLayout, vk::ImageLayout),
        from: Access,
        to: Access,
    ) {
        let (src_stage, src_access) = from.stage_access();
        let (dst_stage, dst_access) = to.stage_access();
        let b = vk::ImageMemoryBarrier2::default()
            .image(image)
            .subresource_range(range(0, vk::REMAINING_MIP_LEVELS))
            .old_layout(old)
            .new_layout(new)
            .src_stage_mask(src_stage)
            .src_access_mask(src_access)
            .dst_stage_mask(dst_stage)
            .dst_access_mask(dst_access);
        self.barrier(&[b], &[]);
    }
}

/// Sizes of the full mip chain of `size` (Vulkan's: halve rounding down, at least 1, to 1x1).
pub fn mip_sizes(size: (u32, u32)) -> Vec<(u32, u32)> {
    let mut sizes = vec![size];
    let mut s = size;
    while s != (1, 1) {
        s = ((s.0 / 2).max(1), (s.1 / 2).max(1));
        sizes.push(s);
    }
    sizes
}

fn range(base: u32, count: u32) -> vk::ImageSubresourceRange {
    vk::ImageSubresourceRange {
        aspect_mask: vk::ImageAspectFlags::COLOR,
        base_mip_level: base,
        level_count: count,
        base_array_layer: 0,
        layer_count: 1,
    }
}

impl Drop for MipImage {
    fn drop(&mut self) {
        // SAFETY: the owner guarantees the GPU no longer uses the image or its views.
        unsafe {
            for v in self.level_views.drain(..) {
                if v != vk::ImageView::null() {
                    self.ctx.device.destroy_image_view(v, None);
                }
            }
            destroy_image(
                &self.ctx,
                self.handle,
                self.all_levels,
                &mut self.allocation,
            );
        }
    }
}
