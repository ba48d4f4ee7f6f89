//! Offscreen render targets (color, depth, optional object-ID) and their readback to the host.

use std::sync::Arc;

use ash::vk;
use gpu_allocator::MemoryLocation;

use super::commands::{image_barrier, Recorder};
use super::memory::{Buffer, Image};
use super::{GpuContext, OneShot};
use crate::error::{Error, Result};

/// Color format of offscreen targets.
pub const COLOR_FORMAT: vk::Format = vk::Format::R8G8B8A8_UNORM;
/// Depth format.
pub const DEPTH_FORMAT: vk::Format = vk::Format::D32_SFLOAT;
/// Object-ID format (oracle pass).
pub const ID_FORMAT: vk::Format = vk::Format::R32_UINT;

/// A depth attachment for dynamic rendering that clears to 1.0 when `load` is CLEAR.
pub fn depth_attachment(
    view: vk::ImageView,
    load: vk::AttachmentLoadOp,
    store: vk::AttachmentStoreOp,
) -> vk::RenderingAttachmentInfo<'static> {
    vk::RenderingAttachmentInfo::default()
        .image_view(view)
        .image_layout(vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL)
        .load_op(load)
        .store_op(store)
        .clear_value(vk::ClearValue {
            depth_stencil: vk::ClearDepthStencilValue {
                depth: 1.0,
                stencil: 0,
            },
        })
}

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
        let color = Image::new(
            ctx,
            "color target",
            COLOR_FORMAT,
            extent,
            1,
            vk::ImageUsageFlags::COLOR_ATTACHMENT | vk::ImageUsageFlags::TRANSFER_SRC,
        )?;
        let depth = Image::new(
            ctx,
            "depth target",
            DEPTH_FORMAT,
            extent,
            1,
            vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT | vk::ImageUsageFlags::SAMPLED,
        )?;
        Ok(Target {
            color,
            depth,
            extent,
        })
    }
}

/// Copies layer 0 of `image` (4 bytes per pixel, currently in `layout` after `stage`) to host
/// memory with a one-shot command buffer. Leaves the image in TRANSFER_SRC_OPTIMAL.
pub fn read_image(
    ctx: &Arc<GpuContext>,
    oneshot: &OneShot,
    recorder: &mut Recorder,
    image: &Image,
    layout: vk::ImageLayout,
    stage: vk::PipelineStageFlags2,
    access: vk::AccessFlags2,
) -> Result<Vec<u8>> {
    let size = image.extent.width as u64 * image.extent.height as u64 * 4;
    let buffer = Buffer::new(
        ctx,
        "readback",
        size,
        vk::BufferUsageFlags::TRANSFER_DST,
        MemoryLocation::GpuToCpu,
    )?;
    let range = vk::ImageSubresourceRange {
        layer_count: 1,
        ..image.full_range()
    };
    oneshot.run(recorder, |rec| {
        rec.barrier(
            &[image_barrier(
                image.handle,
                range,
                (layout, stage, access),
                (
                    vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                    vk::PipelineStageFlags2::COPY,
                    vk::AccessFlags2::TRANSFER_READ,
                ),
            )],
            &[],
        );
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
        rec.barrier(
            &[],
            &[vk::BufferMemoryBarrier2::default()
                .buffer(buffer.handle)
                .size(vk::WHOLE_SIZE)
                .src_stage_mask(vk::PipelineStageFlags2::COPY)
                .src_access_mask(vk::AccessFlags2::TRANSFER_WRITE)
                .dst_stage_mask(vk::PipelineStageFlags2::HOST)
                .dst_access_mask(vk::AccessFlags2::HOST_READ)],
        );
    })?;
    let bytes = buffer
        .mapped()
        .ok_or_else(|| Error::Alloc("readback buffer is not mapped".into()))?;
    Ok(bytes[..size as usize].to_vec())
}
