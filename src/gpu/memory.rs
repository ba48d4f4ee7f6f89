//! GPU memory: buffers and images allocated through gpu-allocator. Each owns an `Arc` to the
//! context and frees itself on drop (callers make sure the GPU is done with it first).

use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::Arc;

use ash::vk;
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme};
use gpu_allocator::MemoryLocation;

use super::GpuContext;
use crate::error::{Error, Result, VkContext};

/// Allocates memory for `name` within the context's memory budget (if it has one): running
/// out of memory, in the driver, in the allocator or in the budget, is
/// [`Error::OutOfDeviceMemory`].
fn allocate(
    ctx: &GpuContext,
    name: &str,
    requirements: vk::MemoryRequirements,
    location: MemoryLocation,
    linear: bool,
) -> Result<Allocation> {
    let mut allocator = ctx.allocator();
    if let Some(budget) = ctx.memory_budget() {
        let used = allocator.generate_report().total_allocated_bytes;
        if used.saturating_add(requirements.size) > budget {
            return Err(Error::OutOfDeviceMemory {
                what: format!(
                    "{name}: {} bytes requested, {used} of the context's budget of {budget} bytes in use",
                    requirements.size
                ),
            });
        }
    }
    allocator
        .allocate(&AllocationCreateDesc {
            name,
            requirements,
            location,
            linear,
            allocation_scheme: AllocationScheme::GpuAllocatorManaged,
        })
        .map_err(|e| Error::from_alloc(name, e))
}

/// A buffer and its memory.
pub struct Buffer {
    ctx: Arc<GpuContext>,
    /// The Vulkan handle.
    pub handle: vk::Buffer,
    /// Size in bytes.
    pub size: u64,
    allocation: Option<Allocation>,
}

impl Buffer {
    /// A host-visible storage buffer holding `bytes` (at least 16 bytes long), after checking
    /// that they fit the device's `maxStorageBufferRange`; `name` says what it holds.
    pub fn storage_with(ctx: &Arc<GpuContext>, name: &str, bytes: &[u8]) -> Result<Buffer> {
        ctx.info.check_storage_buffer(name, bytes.len() as u64)?;
        let mut b = Buffer::new(
            ctx,
            name,
            bytes.len().max(16) as u64,
            vk::BufferUsageFlags::STORAGE_BUFFER,
            MemoryLocation::CpuToGpu,
        )?;
        b.write(0, bytes)?;
        Ok(b)
    }

    /// Creates a buffer in `location` (CpuToGpu/GpuToCpu buffers are mapped).
    pub fn new(
        ctx: &Arc<GpuContext>,
        name: &str,
        size: u64,
        usage: vk::BufferUsageFlags,
        location: MemoryLocation,
    ) -> Result<Buffer> {
        let size = size.max(4);
        let info = vk::BufferCreateInfo::default()
            .size(size)
            .usage(usage)
            .sharing_mode(vk::SharingMode::EXCLUSIVE);
        // SAFETY: valid device and create info.
        let handle = unsafe { ctx.device.create_buffer(&info, None) }.vk("vkCreateBuffer")?;
        // SAFETY: handle is a buffer of this device.
        let requirements = unsafe { ctx.device.get_buffer_memory_requirements(handle) };
        let allocation = match allocate(ctx, name, requirements, location, true) {
            Ok(a) => a,
            Err(e) => {
                // SAFETY: unused buffer created above.
                unsafe { ctx.device.destroy_buffer(handle, None) };
                return Err(e);
            }
        };
        // SAFETY: the allocation satisfies the buffer's requirements.
        let bound = unsafe {
            ctx.device
                .bind_buffer_memory(handle, allocation.memory(), allocation.offset())
        };
        let buffer = Buffer {
            ctx: ctx.clone(),
            handle,
            size,
            allocation: Some(allocation),
        };
        bound.vk("vkBindBufferMemory")?;
        Ok(buffer)
    }

    /// A device-local buffer filled with `data` through a host-visible buffer (GpuOnly memory on
    /// lavapipe is host-visible too, but we don't rely on that).
    pub fn with_data(
        ctx: &Arc<GpuContext>,
        name: &str,
        data: &[u8],
        usage: vk::BufferUsageFlags,
    ) -> Result<Buffer> {
        let mut b = Buffer::new(
            ctx,
            name,
            data.len() as u64,
            usage,
            MemoryLocation::CpuToGpu,
        )?;
        b.write(0, data)?;
        Ok(b)
    }

    /// The mapped bytes, if host-visible.
    pub fn mapped(&self) -> Option<&[u8]> {
        self.allocation.as_ref().and_then(|a| a.mapped_slice())
    }

    /// The mapped bytes for writing, if host-visible.
    pub fn mapped_mut(&mut self) -> Option<&mut [u8]> {
        self.allocation.as_mut().and_then(|a| a.mapped_slice_mut())
    }

    /// Writes `data` at `offset` into a host-visible buffer.
    pub fn write(&mut self, offset: usize, data: &[u8]) -> Result<()> {
        let slice = self
            .allocation
            .as_mut()
            .and_then(|a| a.mapped_slice_mut())
            .ok_or_else(|| Error::Alloc("buffer is not host-visible".into()))?;
        let end = offset
            .checked_add(data.len())
            .filter(|&e| e <= slice.len())
            .ok_or_else(|| {
                Error::Input(format!(
                    "write of {} bytes at {offset} past buffer end {}",
                    data.len(),
                    slice.len()
                ))
            })?;
        slice[offset..end].copy_from_slice(data);
        Ok(())
    }
}

impl Drop for Buffer {
    fn drop(&mut self) {
        if let Some(a) = self.allocation.take() {
            let _ = self.ctx.allocator().free(a);
        }
        // SAFETY: the owner guarantees the GPU no longer uses the buffer.
        unsafe { self.ctx.device.destroy_buffer(self.handle, None) };
    }
}

/// An image, its memory and one view of all its layers.
pub struct Image {
    ctx: Arc<GpuContext>,
    /// The Vulkan image.
    pub handle: vk::Image,
    /// A view of all layers (2D or 2D array).
    pub view: vk::ImageView,
    /// Pixel format.
    pub format: vk::Format,
    /// Size.
    pub extent: vk::Extent2D,
    /// Array layers.
    pub layers: u32,
    /// How the last recorded command used it ([`ImageUse`] as u8), for layout transitions.
    state: AtomicU8,
    allocation: Option<Allocation>,
}

impl Image {
    /// Creates a 2D (array) image with a view over all layers.
    pub fn new(
        ctx: &Arc<GpuContext>,
        name: &str,
        format: vk::Format,
        size: (u32, u32),
        layers: u32,
        usage: vk::ImageUsageFlags,
    ) -> Result<Image> {
        Image::new_multisampled(
            ctx,
            name,
            format,
            size,
            layers,
            vk::SampleCountFlags::TYPE_1,
            usage,
        )
    }

    /// [`Image::new`] with `samples` per texel (an attachment for multisampled rendering);
    /// the caller checks that the device supports the count for the format and usage.
    pub fn new_multisampled(
        ctx: &Arc<GpuContext>,
        name: &str,
        format: vk::Format,
        (width, height): (u32, u32),
        layers: u32,
        samples: vk::SampleCountFlags,
        usage: vk::ImageUsageFlags,
    ) -> Result<Image> {
        let extent = vk::Extent2D { width, height };
        if extent.width == 0 || extent.height == 0 || layers == 0 {
            return Err(Error::Input(format!(
                "{name}: image size {}x{}x{layers} is empty",
                extent.width, extent.height
            )));
        }
        let attachment = usage.intersects(
            vk::ImageUsageFlags::COLOR_ATTACHMENT | vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT,
        );
        ctx.info
            .check_image(name, (width, height), layers, attachment)?;
        let info = vk::ImageCreateInfo::default()
            .image_type(vk::ImageType::TYPE_2D)
            .format(format)
            .extent(vk::Extent3D {
                width: extent.width,
                height: extent.height,
                depth: 1,
            })
            .mip_levels(1)
            .array_layers(layers)
            .samples(samples)
            .tiling(vk::ImageTiling::OPTIMAL)
            .usage(usage)
            .sharing_mode(vk::SharingMode::EXCLUSIVE)
            .initial_layout(vk::ImageLayout::UNDEFINED);
        // SAFETY: valid device and create info.
        let handle = unsafe { ctx.device.create_image(&info, None) }.vk("vkCreateImage")?;
        // SAFETY: handle is an image of this device.
        let requirements = unsafe { ctx.device.get_image_memory_requirements(handle) };
        let allocation = match allocate(ctx, name, requirements, MemoryLocation::GpuOnly, false) {
            Ok(a) => a,
            Err(e) => {
                // SAFETY: unused image created above.
                unsafe { ctx.device.destroy_image(handle, None) };
                return Err(e);
            }
        };
        let mut image = Image {
            ctx: ctx.clone(),
            handle,
            view: vk::ImageView::null(),
            format,
            extent,
            layers,
            state: AtomicU8::new(ImageUse::Undefined as u8),
            allocation: Some(allocation),
        };
        image.bind_and_view()?;
        Ok(image)
    }

    /// Binds the memory and creates the view over all layers.
    fn bind_and_view(&mut self) -> Result<()> {
        let d = &self.ctx.device;
        // SAFETY: the memory handle is only used to bind this image.
        let (memory, offset) = self
            .allocation
            .as_ref()
            .map(|a| (unsafe { a.memory() }, a.offset()))
            .unwrap_or_default();
        // SAFETY: the allocation satisfies the image's requirements.
        unsafe { d.bind_image_memory(self.handle, memory, offset) }.vk("vkBindImageMemory")?;
        let view_info = vk::ImageViewCreateInfo::default()
            .image(self.handle)
            .view_type(if self.layers > 1 {
                vk::ImageViewType::TYPE_2D_ARRAY
            } else {
                vk::ImageViewType::TYPE_2D
            })
            .format(self.format)
            .subresource_range(self.full_range());
        // SAFETY: valid image with bound memory.
        self.view = unsafe { d.create_image_view(&view_info, None) }.vk("vkCreateImageView")?;
        Ok(())
    }

    /// Width and height.
    pub fn size(&self) -> (u32, u32) {
        (self.extent.width, self.extent.height)
    }

    /// How the last recorded command used the image (its layout after that command).
    pub fn state(&self) -> ImageUse {
        ImageUse::from_u8(self.state.load(Ordering::Relaxed))
    }

    /// Records that the image is now used as `state` (the recorder calls this with each
    /// transition it records; recording order is submission order within the crate).
    pub(crate) fn set_state(&self, state: ImageUse) {
        self.state.store(state as u8, Ordering::Relaxed);
    }

    /// The aspect of this image's format.
    pub fn aspect(&self) -> vk::ImageAspectFlags {
        aspect_of(self.format)
    }

    /// All mips and layers.
    pub fn full_range(&self) -> vk::ImageSubresourceRange {
        vk::ImageSubresourceRange {
            aspect_mask: self.aspect(),
            base_mip_level: 0,
            level_count: 1,
            base_array_layer: 0,
            layer_count: self.layers,
        }
    }
}

/// How an image is used: each use implies a layout and the stages and accesses that touch it.
/// [`super::Recorder::transition`] moves an image from its current use to another.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum ImageUse {
    /// Contents undefined (new image, or discarded).
    Undefined,
    /// Color attachment of a rendering (read and written).
    ColorAttachment,
    /// Depth attachment of a rendering (tested and written).
    DepthAttachment,
    /// Storage image read and written by compute shaders (GENERAL).
    ComputeReadWrite,
    /// Storage image only read by compute shaders (GENERAL).
    ComputeRead,
    /// Sampled by compute shaders (SHADER_READ_ONLY_OPTIMAL).
    SampledByCompute,
    /// Source of copies and blits.
    TransferSrc,
    /// Destination of copies and blits.
    TransferDst,
    /// Handed to the presentation engine.
    Present,
}

impl ImageUse {
    const ALL: [ImageUse; 9] = [
        ImageUse::Undefined,
        ImageUse::ColorAttachment,
        ImageUse::DepthAttachment,
        ImageUse::ComputeReadWrite,
        ImageUse::ComputeRead,
        ImageUse::SampledByCompute,
        ImageUse::TransferSrc,
        ImageUse::TransferDst,
        ImageUse::Present,
    ];

    fn from_u8(v: u8) -> ImageUse {
        Self::ALL
            .get(v as usize)
            .copied()
            .unwrap_or(ImageUse::Undefined)
    }

    /// Layout, stages and accesses of this use.
    pub(crate) fn access(self) -> (vk::ImageLayout, vk::PipelineStageFlags2, vk::AccessFlags2) {
        use vk::AccessFlags2 as A;
        use vk::PipelineStageFlags2 as S;
        let fragment_tests = S::EARLY_FRAGMENT_TESTS | S::LATE_FRAGMENT_TESTS;
        match self {
            ImageUse::Undefined => (vk::ImageLayout::UNDEFINED, S::NONE, A::NONE),
            ImageUse::ColorAttachment => (
                vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL,
                S::COLOR_ATTACHMENT_OUTPUT,
                A::COLOR_ATTACHMENT_WRITE | A::COLOR_ATTACHMENT_READ,
            ),
            ImageUse::DepthAttachment => (
                vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL,
                fragment_tests,
                A::DEPTH_STENCIL_ATTACHMENT_WRITE | A::DEPTH_STENCIL_ATTACHMENT_READ,
            ),
            ImageUse::ComputeReadWrite => (
                vk::ImageLayout::GENERAL,
                S::COMPUTE_SHADER,
                A::SHADER_STORAGE_READ | A::SHADER_STORAGE_WRITE,
            ),
            ImageUse::ComputeRead => (
                vk::ImageLayout::GENERAL,
                S::COMPUTE_SHADER,
                A::SHADER_STORAGE_READ,
            ),
            // SHADER_READ (which includes SHADER_SAMPLED_READ): best practices of layer 1.3.239
            // expects it for SHADER_READ_ONLY_OPTIMAL and does not know the sync2 bit.
            ImageUse::SampledByCompute => (
                vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL,
                S::COMPUTE_SHADER,
                A::SHADER_READ,
            ),
            ImageUse::TransferSrc => (
                vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                S::ALL_TRANSFER,
                A::TRANSFER_READ,
            ),
            ImageUse::TransferDst => (
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                S::ALL_TRANSFER,
                A::TRANSFER_WRITE,
            ),
            ImageUse::Present => (vk::ImageLayout::PRESENT_SRC_KHR, S::NONE, A::NONE),
        }
    }
}

/// Plain data whose bytes may be viewed and uploaded (`bytemuck::Pod`: no padding, any bit
/// pattern valid), so [`as_bytes`] needs no `unsafe` from its callers.
pub use bytemuck::Pod;

/// The bytes of a slice of plain data, borrowed (no copy).
pub fn bytes_of<T: Pod>(data: &[T]) -> &[u8] {
    bytemuck::cast_slice(data)
}

/// The little-endian 32-bit word at index `i` of `bytes` (mapped buffer memory the device
/// wrote: counters, flags, predicates); `None` past the end.
pub fn word_at(bytes: &[u8], i: usize) -> Option<u32> {
    let w = bytes.get(i.checked_mul(4)?..)?.get(..4)?;
    Some(u32::from_le_bytes([w[0], w[1], w[2], w[3]]))
}

/// The bytes of a slice of plain data, copied.
pub fn as_bytes<T: Pod>(data: &[T]) -> Vec<u8> {
    bytemuck::cast_slice(data).to_vec()
}

/// The aspect mask for a format.
pub fn aspect_of(format: vk::Format) -> vk::ImageAspectFlags {
    match format {
        vk::Format::D32_SFLOAT | vk::Format::D16_UNORM => vk::ImageAspectFlags::DEPTH,
        vk::Format::D24_UNORM_S8_UINT | vk::Format::D32_SFLOAT_S8_UINT => {
            vk::ImageAspectFlags::DEPTH | vk::ImageAspectFlags::STENCIL
        }
        _ => vk::ImageAspectFlags::COLOR,
    }
}

/// Destroys `view` (unless null) and `image`, and frees `allocation`: the drop of an image
/// that owns its memory ([`Image`], `Texture`, the pyramids' `MipImage`).
///
/// # Safety
/// The handles belong to `ctx`'s device, which no longer uses them.
pub(crate) unsafe fn destroy_image(
    ctx: &GpuContext,
    image: vk::Image,
    view: vk::ImageView,
    allocation: &mut Option<Allocation>,
) {
    // SAFETY: per the caller.
    unsafe {
        if view != vk::ImageView::null() {
            ctx.device.destroy_image_view(view, None);
        }
        ctx.device.destroy_image(image, None);
    }
    if let Some(a) = allocation.take() {
        let _ = ctx.allocator().free(a);
    }
}

impl Drop for Image {
    fn drop(&mut self) {
        // SAFETY: the owner guarantees the GPU no longer uses the image.
        unsafe { destroy_image(&self.ctx, self.handle, self.view, &mut self.allocation) };
    }
}

#[cfg(test)]
mod tests {
    use super::word_at;

    #[test]
    fn word_at_reads_little_endian_words_and_stops_at_the_end() {
        let bytes = [1, 0, 0, 0, 0x78, 0x56, 0x34, 0x12, 9, 9];
        assert_eq!(word_at(&bytes, 0), Some(1));
        assert_eq!(word_at(&bytes, 1), Some(0x1234_5678));
        assert_eq!(word_at(&bytes, 2), None);
        assert_eq!(word_at(&bytes, usize::MAX), None);
    }
}
