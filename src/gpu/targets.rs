//! Offscreen render targets (color, depth, optional object-ID) and their readback to the host.

use std::sync::Arc;

use ash::vk;
use gpu_allocator::MemoryLocation;

use super::commands::Recorder;
use super::memory::{Buffer, Image, ImageUse};
use super::{GpuContext, OneShot};
use crate::error::{Error, Result};

/// Color format of offscreen targets.
pub const COLOR_FORMAT: vk::Format = vk::Format::R8G8B8A8_UNORM;
/// Depth format.
pub const DEPTH_FORMAT: vk::Format = vk::Format::D32_SFLOAT;
/// Object-ID format (oracle pass).
pub const ID_FORMAT: vk::Format = vk::Format::R32_UINT;

/// A color + depth target of one size.
pub struct Target {
    /// Color image (RGBA8).
    pub color: Image,
    /// Depth image (D32).
    pub depth: Image,
    /// Size.
    pub extent: vk::Extent2D,
}

impl Target {
    /// Creates a target of `width`x`height` (both 1..=16384).
    pub fn new(ctx: &Arc<GpuContext>, width: u32, height: u32) -> Result<Target> {
        if width == 0 || height == 0 || width > 16384 || height > 16384 {
            return Err(Error::Input(format!(
                "image size {width}x{height} is out of range (1..16384)"
            )));
        }
        let extent = vk::Extent2D { width, height };
        let size = (width, height);
        let color = Image::new(
            ctx,
            "color target",
            COLOR_FORMAT,
            size,
            1,
            vk::ImageUsageFlags::COLOR_ATTACHMENT | vk::ImageUsageFlags::TRANSFER_SRC,
        )?;
        let depth = Image::new(
            ctx,
            "depth target",
            DEPTH_FORMAT,
            size,
            1,
            vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT
                | vk::ImageUsageFlags::SAMPLED
                | vk::ImageUsageFlags::TRANSFER_SRC,
        )?;
        Ok(Target {
            color,
            depth,
            extent,
        })
    }
}

/// Copies layer 0 of `image` (4 bytes per pixel) to host memory with a one-shot command
/// buffer, after whatever last used it. Leaves the image in [`ImageUse::TransferSrc`], so any
/// number of reads may follow each other.
pub fn read_image(
    ctx: &Arc<GpuContext>,
    oneshot: &mut OneShot,
    recorder: &mut Recorder,
    image: &Image,
) -> Result<Vec<u8>> {
    let size = image.extent.width as u64 * image.extent.height as u64 * 4;
    let buffer = Buffer::new(
        ctx,
        "readback",
        size,
        vk::BufferUsageFlags::TRANSFER_DST,
        MemoryLocation::GpuToCpu,
    )?;
    oneshot.run(recorder, |rec| {
        rec.transition(image, ImageUse::TransferSrc);
        let region = vk::BufferImageCopy::default()
            .image_subresource(vk::ImageSubresourceLayers {
                aspect_mask: image.aspect(),
                mip_level: 0,
                base_array_layer: 0,
                layer_count: 1,
            })
            .image_extent(vk::Extent3D {
                width: image.extent.width,
                height: image.extent.height,
                depth: 1,
            });
        rec.copy_image_to_buffer(image.handle, buffer.handle, region);
        rec.host_read_barrier(&buffer);
        Ok(())
    })?;
    let bytes = buffer
        .mapped()
        .ok_or_else(|| Error::Alloc("readback buffer is not mapped".into()))?;
    Ok(bytes[..size as usize].to_vec())
}
