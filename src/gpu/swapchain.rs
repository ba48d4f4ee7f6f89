//! The windowed presentation path: a surface and swapchain (recreated on resize and when out of
//! date, skipped while the window is 0×0), and the final command buffer of a frame, which blits
//! the renderer's offscreen color image to the acquired image, copies overlay panels over it,
//! optionally reads it back (screenshots) and presents it.

use std::sync::Arc;

use ash::{khr, vk};
use gpu_allocator::MemoryLocation;
use raw_window_handle::{RawDisplayHandle, RawWindowHandle};

use super::commands::{image_barrier, CommandPool, Recorder};
use super::memory::{Buffer, Image, ImageUse};
use super::sync::{BinarySync, Timeline};
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
    // The timeline is declared before the pool so that it is dropped (waiting) first.
    timeline: Timeline,
    pool: CommandPool,
    staging: Option<Buffer>,
    readback: Option<Buffer>,
    needs_recreate: bool,
    /// The window size the swapchain was last made for.
    made_for: (u32, u32),
    /// Present mode in use.
    pub present_mode: vk::PresentModeKHR,
}

/// The device extensions presenting needs (pass them in
/// [`super::ContextOptions::device_extensions`]).
pub fn required_device_extensions() -> Vec<std::ffi::CString> {
    vec![khr::swapchain::NAME.to_owned()]
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
            timeline: Timeline::new(ctx)?,
            pool: CommandPool::new(ctx)?,
            staging: None,
            readback: None,
            needs_recreate: false,
            made_for: (width, height),
            present_mode: vk::PresentModeKHR::FIFO,
        };
        // SAFETY: valid device; destroyed in Drop.
        me.acquired = unsafe {
            ctx.device
                .create_semaphore(&vk::SemaphoreCreateInfo::default(), None)
        }
        .vk("vkCreateSemaphore")?;
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
        // SAFETY: valid physical device and surface.
        let caps = unsafe {
            self.surface_fn
                .get_physical_device_surface_capabilities(self.ctx.physical_device, self.surface)
        }
        .vk("vkGetPhysicalDeviceSurfaceCapabilitiesKHR")?;
        let extent = surface_extent(&caps, width, height);
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
        let chosen = self.choose_format()?;
        let swapchain = self.create_swapchain(&caps, chosen, extent);
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

    /// An 8-bit RGBA/BGRA format (UNORM preferred) that can be blitted to.
    fn choose_format(&self) -> Result<vk::SurfaceFormatKHR> {
        let pd = self.ctx.physical_device;
        // SAFETY: valid physical device and surface.
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
        Ok(chosen)
    }

    /// A swapchain replacing the current one (which the caller then destroys).
    fn create_swapchain(
        &self,
        caps: &vk::SurfaceCapabilitiesKHR,
        chosen: vk::SurfaceFormatKHR,
        extent: vk::Extent2D,
    ) -> Result<vk::SwapchainKHR> {
        let mut count = caps.min_image_count + 1;
        if caps.max_image_count > 0 {
            count = count.min(caps.max_image_count);
        }
        let mut usage = vk::ImageUsageFlags::TRANSFER_DST;
        if self.can_read {
            usage |= vk::ImageUsageFlags::TRANSFER_SRC;
        }
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
            .old_swapchain(self.swapchain);
        // SAFETY: valid surface; the old swapchain (if any) is idle (the caller waited).
        unsafe { self.swapchain_fn.create_swapchain(&info, None) }.vk("vkCreateSwapchainKHR")
    }

    fn is_bgr(&self) -> bool {
        matches!(
            self.format,
            vk::Format::B8G8R8A8_UNORM | vk::Format::B8G8R8A8_SRGB
        )
    }

    /// Shows `color` (the renderer's color image, after its frame) scaled to the window, with
    /// `panels` on top: acquire, record (blit, overlay, optional readback), submit, present,
    /// and recreate the swapchain when the window changed. The final command buffer is
    /// recorded through `recorder`, so its commands are counted. Leaves `color` in
    /// [`ImageUse::TransferSrc`]. `window_size` is the window's current inner size.
    pub fn present(
        &mut self,
        recorder: &mut Recorder,
        color: &Image,
        panels: &[Panel],
        window_size: (u32, u32),
        screenshot: bool,
    ) -> Result<Presented> {
        if !self.ready_for(window_size)? {
            return Ok(Presented::Skipped);
        }
        let Some(index) = self.acquire()? else {
            return Ok(Presented::Skipped);
        };
        let screenshot = screenshot && self.can_read;
        let copies = self.stage_panels(panels)?;
        if screenshot {
            self.ensure_readback()?;
        }
        self.pool.reset(&self.timeline)?;
        let prev = recorder.command_buffer();
        recorder.set_command_buffer(self.pool.begin_next()?);
        self.record(recorder, color, index, &copies, screenshot);
        let submitted = self.timeline.submit_with(
            recorder,
            BinarySync {
                wait: Some(self.acquired),
                signal: Some(self.finished[index as usize]),
            },
        );
        recorder.set_command_buffer(prev);
        self.timeline.wait(submitted?)?;
        self.queue_present(index)?;
        let pixels = if screenshot {
            Some(self.screenshot_pixels()?)
        } else {
            None
        };
        Ok(Presented::Shown { pixels })
    }

    /// Recreates the swapchain if it is stale; false when there is nothing to present to.
    fn ready_for(&mut self, window_size: (u32, u32)) -> Result<bool> {
        if window_size.0 == 0 || window_size.1 == 0 {
            return Ok(false);
        }
        if self.needs_recreate
            || self.swapchain == vk::SwapchainKHR::null()
            || self.made_for != window_size
        {
            self.recreate(window_size.0, window_size.1)?;
        }
        Ok(self.swapchain != vk::SwapchainKHR::null())
    }

    /// Acquires the next image; `None` when the swapchain is out of date (it is recreated
    /// before the next frame).
    fn acquire(&mut self) -> Result<Option<u32>> {
        // SAFETY: valid swapchain; the semaphore is unsignaled (the last submit waited on it).
        let acquired = unsafe {
            self.swapchain_fn.acquire_next_image(
                self.swapchain,
                u64::MAX,
                self.acquired,
                vk::Fence::null(),
            )
        };
        match acquired {
            Ok((i, suboptimal)) => {
                self.needs_recreate |= suboptimal;
                Ok(Some(i))
            }
            Err(vk::Result::ERROR_OUT_OF_DATE_KHR) => {
                self.needs_recreate = true;
                Ok(None)
            }
            Err(e) => Err(Error::Vulkan {
                call: "vkAcquireNextImageKHR",
                result: e,
            }),
        }
    }

    /// Writes the overlay panels (clipped to the image) into the staging buffer in the
    /// swapchain's byte order; returns the copies to record.
    fn stage_panels(&mut self, panels: &[Panel]) -> Result<Vec<vk::BufferImageCopy>> {
        let extent = self.extent;
        let bgr = self.is_bgr();
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
            copies.push(panel_copy(offset, p.x, p.y, w, h));
        }
        if bytes.is_empty() {
            return Ok(copies);
        }
        let big_enough = self
            .staging
            .as_ref()
            .is_some_and(|b| b.size >= bytes.len() as u64);
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
        Ok(copies)
    }

    fn read_size(&self) -> u64 {
        self.extent.width as u64 * self.extent.height as u64 * 4
    }

    fn ensure_readback(&mut self) -> Result<()> {
        let size = self.read_size();
        if self.readback.as_ref().is_none_or(|b| b.size < size) {
            self.readback = Some(Buffer::new(
                &self.ctx,
                "screenshot readback",
                size,
                vk::BufferUsageFlags::TRANSFER_DST,
                MemoryLocation::GpuToCpu,
            )?);
        }
        Ok(())
    }

    /// Records the frame's last command buffer: blit `color` to image `index`, copy the panels
    /// over it, read it back if asked, and hand it to presentation.
    fn record(
        &self,
        recorder: &mut Recorder,
        color: &Image,
        index: u32,
        copies: &[vk::BufferImageCopy],
        screenshot: bool,
    ) {
        let image = self.images[index as usize];
        let range = color_range();
        recorder.transition(color, ImageUse::TransferSrc);
        let transfer_dst = ImageUse::TransferDst.access();
        let undefined = (
            vk::ImageLayout::UNDEFINED,
            vk::PipelineStageFlags2::ALL_TRANSFER,
            vk::AccessFlags2::NONE,
        );
        recorder.barrier(&[image_barrier(image, range, undefined, transfer_dst)], &[]);
        recorder.blit_image(color.handle, image, self.blit_region(color));
        if let (Some(staging), false) = (self.staging.as_ref(), copies.is_empty()) {
            recorder.barrier(
                &[image_barrier(image, range, transfer_dst, transfer_dst)],
                &[],
            );
            recorder.copy_buffer_to_image(staging.handle, image, copies);
        }
        let mut last = transfer_dst;
        if let (true, Some(rb)) = (screenshot, self.readback.as_ref()) {
            let src = ImageUse::TransferSrc.access();
            recorder.barrier(&[image_barrier(image, range, transfer_dst, src)], &[]);
            let region = vk::BufferImageCopy::default()
                .image_subresource(color_layers())
                .image_extent(vk::Extent3D {
                    width: self.extent.width,
                    height: self.extent.height,
                    depth: 1,
                });
            recorder.copy_image_to_buffer(image, rb.handle, region);
            recorder.host_read_barrier(rb);
            last = src;
        }
        let present = ImageUse::Present.access();
        recorder.barrier(&[image_barrier(image, range, last, present)], &[]);
    }

    fn blit_region(&self, color: &Image) -> vk::ImageBlit {
        let corner = |w: u32, h: u32| vk::Offset3D {
            x: w as i32,
            y: h as i32,
            z: 1,
        };
        vk::ImageBlit {
            src_subresource: color_layers(),
            src_offsets: [
                vk::Offset3D::default(),
                corner(color.extent.width, color.extent.height),
            ],
            dst_subresource: color_layers(),
            dst_offsets: [
                vk::Offset3D::default(),
                corner(self.extent.width, self.extent.height),
            ],
        }
    }

    /// Presents image `index` once its command buffer has signalled `finished`.
    fn queue_present(&mut self, index: u32) -> Result<()> {
        let swapchains = [self.swapchain];
        let indices = [index];
        let wait = [self.finished[index as usize]];
        let info = vk::PresentInfoKHR::default()
            .wait_semaphores(&wait)
            .swapchains(&swapchains)
            .image_indices(&indices);
        // SAFETY: the image was acquired and transitioned to PRESENT_SRC by the submit before.
        match unsafe { self.swapchain_fn.queue_present(self.ctx.queue, &info) } {
            Ok(false) => Ok(()),
            Ok(true) | Err(vk::Result::ERROR_OUT_OF_DATE_KHR) => {
                self.needs_recreate = true;
                Ok(())
            }
            Err(e) => Err(Error::Vulkan {
                call: "vkQueuePresentKHR",
                result: e,
            }),
        }
    }

    /// The read-back image as RGBA8 (the submission that wrote it has completed).
    fn screenshot_pixels(&self) -> Result<(u32, u32, Vec<u8>)> {
        let rb = self
            .readback
            .as_ref()
            .ok_or_else(|| Error::Alloc("no screenshot readback buffer".into()))?;
        let data = rb
            .mapped()
            .ok_or_else(|| Error::Alloc("readback buffer is not mapped".into()))?;
        let mut px = data[..self.read_size() as usize].to_vec();
        if self.is_bgr() {
            for p in px.chunks_exact_mut(4) {
                p.swap(0, 2);
            }
        }
        Ok((self.extent.width, self.extent.height, px))
    }
}

fn panel_copy(offset: u64, x: u32, y: u32, w: u32, h: u32) -> vk::BufferImageCopy {
    vk::BufferImageCopy::default()
        .buffer_offset(offset)
        .buffer_row_length(w)
        .image_subresource(color_layers())
        .image_offset(vk::Offset3D {
            x: x as i32,
            y: y as i32,
            z: 0,
        })
        .image_extent(vk::Extent3D {
            width: w,
            height: h,
            depth: 1,
        })
}

fn color_range() -> vk::ImageSubresourceRange {
    vk::ImageSubresourceRange {
        aspect_mask: vk::ImageAspectFlags::COLOR,
        base_mip_level: 0,
        level_count: 1,
        base_array_layer: 0,
        layer_count: 1,
    }
}

/// The surface's size, or the window's clamped to what the surface allows.
fn surface_extent(caps: &vk::SurfaceCapabilitiesKHR, width: u32, height: u32) -> vk::Extent2D {
    if caps.current_extent.width != u32::MAX {
        caps.current_extent
    } else {
        vk::Extent2D {
            width: width.clamp(caps.min_image_extent.width, caps.max_image_extent.width),
            height: height.clamp(caps.min_image_extent.height, caps.max_image_extent.height),
        }
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
            self.ctx.device.destroy_semaphore(self.acquired, None);
            self.surface_fn.destroy_surface(self.surface, None);
        }
    }
}
