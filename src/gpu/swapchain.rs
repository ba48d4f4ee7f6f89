//! The windowed presentation path: a surface and swapchain (recreated on resize and when out of
//! date, skipped while the window is 0×0), and the final command buffer of a frame, which blits
//! the renderer's offscreen color image to the acquired image, copies overlay panels over it,
//! optionally reads it back (screenshots) and presents it.

use std::sync::Arc;

use ash::{khr, vk};
use gpu_allocator::MemoryLocation;
use raw_window_handle::{RawDisplayHandle, RawWindowHandle};

use super::commands::{self, image_barrier, Recorder};
use super::memory::{Buffer, Image};
use super::GpuContext;
use crate::error::{Error, Result, VkContext};

/// An opaque rectangle of RGBA8 pixels (top row first) drawn over the presented image.
pub struct Panel {
    /// Left edge in pixels.
    pub x: u32,
    /// Top edge in pixels.
    pub y: u32,
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// `width * height * 4` bytes, RGBA.
    pub rgba: Vec<u8>,
}

/// What [`Swapchain::present`] did.
pub enum Presented {
    /// The frame was shown; `pixels` holds the composited image (RGBA8, `width`×`height`) when a
    /// screenshot was asked for.
    Shown {
        /// Screenshot pixels, if requested.
        pixels: Option<(u32, u32, Vec<u8>)>,
    },
    /// Nothing was shown (0×0 window, or the swapchain was out of date and was recreated).
    Skipped,
}

/// A window surface with its swapchain and the per-frame present machinery.
pub struct Swapchain {
    ctx: Arc<GpuContext>,
    surface_fn: khr::surface::Instance,
    swapchain_fn: khr::swapchain::Device,
    surface: vk::SurfaceKHR,
    swapchain: vk::SwapchainKHR,
    images: Vec<vk::Image>,
    format: vk::Format,
    extent: vk::Extent2D,
    can_read: bool,
    acquired: vk::Semaphore,
    finished: Vec<vk::Semaphore>,
    fence: vk::Fence,
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    staging: Option<Buffer>,
    readback: Option<Buffer>,
    needs_recreate: bool,
    /// The window size the swapchain was last made for.
    made_for: (u32, u32),
    /// Present mode in use.
    pub present_mode: vk::PresentModeKHR,
}

/// The instance extensions a surface for this display needs (pass them in
/// [`super::ContextOptions::instance_extensions`]).
pub fn required_instance_extensions(display: RawDisplayHandle) -> Result<Vec<std::ffi::CString>> {
    let names = ash_window::enumerate_required_extensions(display).vk("surface extensions")?;
    Ok(names
        .iter()
        // SAFETY: ash-window returns pointers to static null-terminated extension names.
        .map(|&p| unsafe { std::ffi::CStr::from_ptr(p) }.to_owned())
        .collect())
}

impl Swapchain {
    /// Creates a surface for the window and a swapchain of `width`×`height` (the surface's own
    /// size wins where it has one). Errors clearly if the context's queue cannot present.
    pub fn new(
        ctx: &Arc<GpuContext>,
        display: RawDisplayHandle,
        window: RawWindowHandle,
        width: u32,
        height: u32,
        vsync: bool,
    ) -> Result<Swapchain> {
        // SAFETY: the handles come from a live window that outlives this swapchain (the viewer
        // drops the swapchain first); the instance has the surface extensions enabled.
        let surface =
            unsafe { ash_window::create_surface(&ctx.entry, &ctx.instance, display, window, None) }
                .vk("vkCreate*SurfaceKHR")?;
        let surface_fn = khr::surface::Instance::new(&ctx.entry, &ctx.instance);
        // SAFETY: valid physical device, family and surface.
        let supported = unsafe {
            surface_fn.get_physical_device_surface_support(
                ctx.physical_device,
                ctx.queue_family,
                surface,
            )
        };
        if !matches!(supported, Ok(true)) {
            // SAFETY: created above, unused.
            unsafe { surface_fn.destroy_surface(surface, None) };
            return Err(Error::Unsupported {
                feature: format!(
                    "presenting to this window from queue family {} of {}",
                    ctx.queue_family, ctx.info.name
                ),
            });
        }
        let swapchain_fn = khr::swapchain::Device::new(&ctx.instance, &ctx.device);
        let mut me = Swapchain {
            ctx: ctx.clone(),
            surface_fn,
            swapchain_fn,
            surface,
            swapchain: vk::SwapchainKHR::null(),
            images: Vec::new(),
            format: vk::Format::UNDEFINED,
            extent: vk::Extent2D::default(),
            can_read: false,
            acquired: vk::Semaphore::null(),
            finished: Vec::new(),
            fence: vk::Fence::null(),
            pool: vk::CommandPool::null(),
            cmd: vk::CommandBuffer::null(),
            staging: None,
            readback: None,
            needs_recreate: false,
            made_for: (width, height),
            present_mode: vk::PresentModeKHR::FIFO,
        };
        let d = &ctx.device;
        // SAFETY: valid device; every object is destroyed in Drop (null handles are ignored).
        unsafe {
            me.acquired = d
                .create_semaphore(&vk::SemaphoreCreateInfo::default(), None)
                .vk("vkCreateSemaphore")?;
            me.fence = d
                .create_fence(&vk::FenceCreateInfo::default(), None)
                .vk("vkCreateFence")?;
            me.pool = d
                .create_command_pool(
                    &vk::CommandPoolCreateInfo::default()
                        .queue_family_index(ctx.queue_family)
                        .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER),
                    None,
                )
                .vk("vkCreateCommandPool")?;
            me.cmd = d
                .allocate_command_buffers(
                    &vk::CommandBufferAllocateInfo::default()
                        .command_pool(me.pool)
                        .level(vk::CommandBufferLevel::PRIMARY)
                        .command_buffer_count(1),
                )
                .vk("vkAllocateCommandBuffers")?[0];
        }
        // SAFETY: valid physical device and surface.
        let modes = unsafe {
            me.surface_fn
                .get_physical_device_surface_present_modes(ctx.physical_device, surface)
        }
        .vk("vkGetPhysicalDeviceSurfacePresentModesKHR")?;
        if !vsync {
            for m in [vk::PresentModeKHR::MAILBOX, vk::PresentModeKHR::IMMEDIATE] {
                if modes.contains(&m) {
                    me.present_mode = m;
                    break;
                }
            }
        }
        me.recreate(width, height)?;
        Ok(me)
    }

    /// Size of the swapchain images (0×0 while the window is minimized).
    pub fn extent(&self) -> (u32, u32) {
        (self.extent.width, self.extent.height)
    }

    /// Asks for a new swapchain before the next frame (call on window resize).
    pub fn invalidate(&mut self) {
        self.needs_recreate = true;
    }

    fn destroy_swapchain(&mut self) {
        // SAFETY: callers wait for the device to be idle first; the handles belong to us.
        unsafe {
            for s in self.finished.drain(..) {
                self.ctx.device.destroy_semaphore(s, None);
            }
            if self.swapchain != vk::SwapchainKHR::null() {
                self.swapchain_fn.destroy_swapchain(self.swapchain, None);
            }
        }
        self.swapchain = vk::SwapchainKHR::null();
        self.images.clear();
    }

    /// (Re)creates the swapchain for a window of `width`×`height`; leaves it empty (0×0) when
    /// the surface has no area.
    fn recreate(&mut self, width: u32, height: u32) -> Result<()> {
        self.ctx.wait_idle()?;
        self.made_for = (width, height);
        let pd = self.ctx.physical_device;
        // SAFETY: valid physical device and surface.
        let caps = unsafe {
            self.surface_fn
                .get_physical_device_surface_capabilities(pd, self.surface)
        }
        .vk("vkGetPhysicalDeviceSurfaceCapabilitiesKHR")?;
        let extent = if caps.current_extent.width != u32::MAX {
            caps.current_extent
        } else {
            vk::Extent2D {
                width: width.clamp(caps.min_image_extent.width, caps.max_image_extent.width),
                height: height.clamp(caps.min_image_extent.height, caps.max_image_extent.height),
            }
        };
        self.needs_recreate = false;
        if extent.width == 0 || extent.height == 0 {
            self.destroy_swapchain();
            self.extent = vk::Extent2D::default();
            return Ok(());
        }
        if !caps
            .supported_usage_flags
            .contains(vk::ImageUsageFlags::TRANSFER_DST)
        {
            return Err(Error::Unsupported {
                feature: "swapchain images usable as transfer destinations".into(),
            });
        }
        self.can_read = caps
            .supported_usage_flags
            .contains(vk::ImageUsageFlags::TRANSFER_SRC);
        // SAFETY: as above.
        let formats = unsafe {
            self.surface_fn
                .get_physical_device_surface_formats(pd, self.surface)
        }
        .vk("vkGetPhysicalDeviceSurfaceFormatsKHR")?;
        let chosen = [vk::Format::B8G8R8A8_UNORM, vk::Format::R8G8B8A8_UNORM]
            .iter()
            .find_map(|f| formats.iter().find(|s| s.format == *f))
            .or_else(|| {
                formats.iter().find(|s| {
                    matches!(
                        s.format,
                        vk::Format::B8G8R8A8_SRGB | vk::Format::R8G8B8A8_SRGB
                    )
                })
            })
            .copied()
            .ok_or_else(|| Error::Unsupported {
                feature: "an 8-bit RGBA/BGRA swapchain format".into(),
            })?;
        // SAFETY: valid physical device.
        let props = unsafe {
            self.ctx
                .instance
                .get_physical_device_format_properties(pd, chosen.format)
        };
        if !props
            .optimal_tiling_features
            .contains(vk::FormatFeatureFlags::BLIT_DST)
        {
            return Err(Error::Unsupported {
                feature: format!("blitting to swapchain format {:?}", chosen.format),
            });
        }
        let mut count = caps.min_image_count + 1;
        if caps.max_image_count > 0 {
            count = count.min(caps.max_image_count);
        }
        let mut usage = vk::ImageUsageFlags::TRANSFER_DST;
        if self.can_read {
            usage |= vk::ImageUsageFlags::TRANSFER_SRC;
        }
        let old = self.swapchain;
        let info = vk::SwapchainCreateInfoKHR::default()
            .surface(self.surface)
            .min_image_count(count)
            .image_format(chosen.format)
            .image_color_space(chosen.color_space)
            .image_extent(extent)
            .image_array_layers(1)
            .image_usage(usage)
            .image_sharing_mode(vk::SharingMode::EXCLUSIVE)
            .pre_transform(caps.current_transform)
            .composite_alpha(vk::CompositeAlphaFlagsKHR::OPAQUE)
            .present_mode(self.present_mode)
            .clipped(true)
            .old_swapchain(old);
        // SAFETY: valid surface; the old swapchain (if any) is idle (waited above).
        let swapchain =
            unsafe { self.swapchain_fn.create_swapchain(&info, None) }.vk("vkCreateSwapchainKHR");
        self.destroy_swapchain();
        self.swapchain = swapchain?;
        // SAFETY: created above.
        self.images = unsafe { self.swapchain_fn.get_swapchain_images(self.swapchain) }
            .vk("vkGetSwapchainImagesKHR")?;
        for _ in 0..self.images.len() {
            // SAFETY: valid device; destroyed with the swapchain.
            let s = unsafe {
                self.ctx
                    .device
                    .create_semaphore(&vk::SemaphoreCreateInfo::default(), None)
            }
            .vk("vkCreateSemaphore")?;
            self.finished.push(s);
        }
        self.format = chosen.format;
        self.extent = extent;
        Ok(())
    }

    fn is_bgr(&self) -> bool {
        matches!(
            self.format,
            vk::Format::B8G8R8A8_UNORM | vk::Format::B8G8R8A8_SRGB
        )
    }

    /// Shows `color` (the renderer's color image, in COLOR_ATTACHMENT_OPTIMAL after its frame;
    /// left in TRANSFER_SRC_OPTIMAL) scaled to the window, with `panels` on top. Records the
    /// final command buffer through `recorder` (so its commands are counted), submits it, waits
    /// for it and presents. `window_size` is the window's current inner size.
    pub fn present(
        &mut self,
        recorder: &mut Recorder,
        color: &Image,
        panels: &[Panel],
        window_size: (u32, u32),
        screenshot: bool,
    ) -> Result<Presented> {
        if window_size.0 == 0 || window_size.1 == 0 {
            return Ok(Presented::Skipped);
        }
        if self.needs_recreate
            || self.swapchain == vk::SwapchainKHR::null()
            || self.made_for != window_size
        {
            self.recreate(window_size.0, window_size.1)?;
            if self.swapchain == vk::SwapchainKHR::null() {
                return Ok(Presented::Skipped);
            }
        }
        // SAFETY: valid swapchain; the semaphore is unsignaled (the last submit waited on it).
        let acquired = unsafe {
            self.swapchain_fn.acquire_next_image(
                self.swapchain,
                u64::MAX,
                self.acquired,
                vk::Fence::null(),
            )
        };
        let index = match acquired {
            Ok((i, suboptimal)) => {
                if suboptimal {
                    self.needs_recreate = true;
                }
                i
            }
            Err(vk::Result::ERROR_OUT_OF_DATE_KHR) => {
                self.needs_recreate = true;
                return Ok(Presented::Skipped);
            }
            Err(e) => {
                return Err(Error::Vulkan {
                    call: "vkAcquireNextImageKHR",
                    result: e,
                })
            }
        };
        let image = self.images[index as usize];
        let extent = self.extent;
        let bgr = self.is_bgr();
        let screenshot = screenshot && self.can_read;

        // Stage the overlay panels (clipped to the image) in the swapchain's byte order.
        let mut bytes = Vec::new();
        let mut copies = Vec::new();
        for p in panels {
            if p.x >= extent.width
                || p.y >= extent.height
                || p.rgba.len() < (p.width * p.height * 4) as usize
            {
                continue;
            }
            let w = p.width.min(extent.width - p.x);
            let h = p.height.min(extent.height - p.y);
            if w == 0 || h == 0 {
                continue;
            }
            let offset = bytes.len() as u64;
            for row in 0..h {
                let start = (row * p.width * 4) as usize;
                for px in p.rgba[start..start + (w * 4) as usize].chunks_exact(4) {
                    if bgr {
                        bytes.extend_from_slice(&[px[2], px[1], px[0], px[3]]);
                    } else {
                        bytes.extend_from_slice(px);
                    }
                }
            }
            copies.push(
                vk::BufferImageCopy::default()
                    .buffer_offset(offset)
                    .buffer_row_length(w)
                    .image_subresource(color_layers())
                    .image_offset(vk::Offset3D {
                        x: p.x as i32,
                        y: p.y as i32,
                        z: 0,
                    })
                    .image_extent(vk::Extent3D {
                        width: w,
                        height: h,
                        depth: 1,
                    }),
            );
        }
        if !bytes.is_empty() {
            let big_enough = self
                .staging
                .as_ref()
                .map(|b| b.size >= bytes.len() as u64)
                .unwrap_or(false);
            if !big_enough {
                self.staging = Some(Buffer::new(
                    &self.ctx,
                    "overlay staging",
                    bytes.len() as u64 * 2,
                    vk::BufferUsageFlags::TRANSFER_SRC,
                    MemoryLocation::CpuToGpu,
                )?);
            }
            if let Some(s) = self.staging.as_mut() {
                s.write(0, &bytes)?;
            }
        }
        let read_size = extent.width as u64 * extent.height as u64 * 4;
        if screenshot {
            let big_enough = self
                .readback
                .as_ref()
                .map(|b| b.size >= read_size)
                .unwrap_or(false);
            if !big_enough {
                self.readback = Some(Buffer::new(
                    &self.ctx,
                    "screenshot readback",
                    read_size,
                    vk::BufferUsageFlags::TRANSFER_DST,
                    MemoryLocation::GpuToCpu,
                )?);
            }
        }

        // Not in flight: every present waits for its fence.
        commands::begin_one_time(&self.ctx.device, self.cmd, true)?;
        let d = &self.ctx.device;
        let prev = recorder.command_buffer();
        recorder.set_command_buffer(self.cmd);
        let range = vk::ImageSubresourceRange {
            aspect_mask: vk::ImageAspectFlags::COLOR,
            base_mip_level: 0,
            level_count: 1,
            base_array_layer: 0,
            layer_count: 1,
        };
        let transfer_dst = (
            vk::ImageLayout::TRANSFER_DST_OPTIMAL,
            vk::PipelineStageFlags2::ALL_TRANSFER,
            vk::AccessFlags2::TRANSFER_WRITE,
        );
        recorder.barrier(
            &[
                image_barrier(
                    color.handle,
                    range,
                    (
                        vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL,
                        vk::PipelineStageFlags2::COLOR_ATTACHMENT_OUTPUT,
                        vk::AccessFlags2::COLOR_ATTACHMENT_WRITE,
                    ),
                    (
                        vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                        vk::PipelineStageFlags2::BLIT,
                        vk::AccessFlags2::TRANSFER_READ,
                    ),
                ),
                image_barrier(
                    image,
                    range,
                    (
                        vk::ImageLayout::UNDEFINED,
                        vk::PipelineStageFlags2::ALL_TRANSFER,
                        vk::AccessFlags2::NONE,
                    ),
                    transfer_dst,
                ),
            ],
            &[],
        );
        let blit = vk::ImageBlit {
            src_subresource: color_layers(),
            src_offsets: [
                vk::Offset3D::default(),
                vk::Offset3D {
                    x: color.extent.width as i32,
                    y: color.extent.height as i32,
                    z: 1,
                },
            ],
            dst_subresource: color_layers(),
            dst_offsets: [
                vk::Offset3D::default(),
                vk::Offset3D {
                    x: extent.width as i32,
                    y: extent.height as i32,
                    z: 1,
                },
            ],
        };
        recorder.blit_image(color.handle, image, blit);
        if let (Some(staging), false) = (self.staging.as_ref(), copies.is_empty()) {
            recorder.barrier(
                &[image_barrier(image, range, transfer_dst, transfer_dst)],
                &[],
            );
            recorder.copy_buffer_to_image(staging.handle, image, &copies);
        }
        let mut last = transfer_dst;
        if let (true, Some(rb)) = (screenshot, self.readback.as_ref()) {
            let src = (
                vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                vk::PipelineStageFlags2::ALL_TRANSFER,
                vk::AccessFlags2::TRANSFER_READ,
            );
            recorder.barrier(&[image_barrier(image, range, transfer_dst, src)], &[]);
            recorder.copy_image_to_buffer(
                image,
                rb.handle,
                vk::BufferImageCopy::default()
                    .image_subresource(color_layers())
                    .image_extent(vk::Extent3D {
                        width: extent.width,
                        height: extent.height,
                        depth: 1,
                    }),
            );
            recorder.barrier(
                &[],
                &[vk::BufferMemoryBarrier2::default()
                    .buffer(rb.handle)
                    .size(vk::WHOLE_SIZE)
                    .src_stage_mask(vk::PipelineStageFlags2::ALL_TRANSFER)
                    .src_access_mask(vk::AccessFlags2::TRANSFER_WRITE)
                    .dst_stage_mask(vk::PipelineStageFlags2::HOST)
                    .dst_access_mask(vk::AccessFlags2::HOST_READ)],
            );
            last = src;
        }
        recorder.barrier(
            &[image_barrier(
                image,
                range,
                last,
                (
                    vk::ImageLayout::PRESENT_SRC_KHR,
                    vk::PipelineStageFlags2::NONE,
                    vk::AccessFlags2::NONE,
                ),
            )],
            &[],
        );
        recorder.set_command_buffer(prev);
        let finished = self.finished[index as usize];
        let waits = [vk::SemaphoreSubmitInfo::default()
            .semaphore(self.acquired)
            .stage_mask(vk::PipelineStageFlags2::ALL_COMMANDS)];
        let signals = [vk::SemaphoreSubmitInfo::default()
            .semaphore(finished)
            .stage_mask(vk::PipelineStageFlags2::ALL_COMMANDS)];
        let cmds = [vk::CommandBufferSubmitInfo::default().command_buffer(self.cmd)];
        let submit = vk::SubmitInfo2::default()
            .wait_semaphore_infos(&waits)
            .command_buffer_infos(&cmds)
            .signal_semaphore_infos(&signals);
        // SAFETY: recorded above; the fence is unsignaled (reset after every wait).
        unsafe {
            d.end_command_buffer(self.cmd).vk("vkEndCommandBuffer")?;
            d.queue_submit2(self.ctx.queue, &[submit], self.fence)
                .vk("vkQueueSubmit2")?;
        }
        recorder.note_submit();
        // SAFETY: submitted above with this fence.
        unsafe {
            d.wait_for_fences(&[self.fence], true, u64::MAX)
                .vk("vkWaitForFences")?;
            d.reset_fences(&[self.fence]).vk("vkResetFences")?;
        }
        let swapchains = [self.swapchain];
        let indices = [index];
        let wait = [finished];
        let info = vk::PresentInfoKHR::default()
            .wait_semaphores(&wait)
            .swapchains(&swapchains)
            .image_indices(&indices);
        // SAFETY: the image was acquired and transitioned to PRESENT_SRC by the submit above.
        match unsafe { self.swapchain_fn.queue_present(self.ctx.queue, &info) } {
            Ok(false) => {}
            Ok(true) | Err(vk::Result::ERROR_OUT_OF_DATE_KHR) => self.needs_recreate = true,
            Err(e) => {
                return Err(Error::Vulkan {
                    call: "vkQueuePresentKHR",
                    result: e,
                })
            }
        }
        let pixels = match (screenshot, self.readback.as_ref()) {
            (true, Some(rb)) => {
                let data = rb
                    .mapped()
                    .ok_or_else(|| Error::Alloc("readback buffer is not mapped".into()))?;
                let mut px = data[..read_size as usize].to_vec();
                if bgr {
                    for p in px.chunks_exact_mut(4) {
                        p.swap(0, 2);
                    }
                }
                Some((extent.width, extent.height, px))
            }
            _ => None,
        };
        Ok(Presented::Shown { pixels })
    }
}

fn color_layers() -> vk::ImageSubresourceLayers {
    vk::ImageSubresourceLayers {
        aspect_mask: vk::ImageAspectFlags::COLOR,
        mip_level: 0,
        base_array_layer: 0,
        layer_count: 1,
    }
}

impl Drop for Swapchain {
    fn drop(&mut self) {
        let _ = self.ctx.wait_idle();
        self.destroy_swapchain();
        self.staging = None;
        self.readback = None;
        // SAFETY: the device is idle; these objects belong to us; the surface goes last, before
        // the context (which we hold an Arc to) destroys the instance.
        unsafe {
            let d = &self.ctx.device;
            d.destroy_command_pool(self.pool, None);
            d.destroy_fence(self.fence, None);
            d.destroy_semaphore(self.acquired, None);
            self.surface_fn.destroy_surface(self.surface, None);
        }
    }
}
