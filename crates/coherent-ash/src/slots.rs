//! The host-visible buffers the query side is made of, and the allocation they share.

use ash::vk;
use coherent_cull::{Error, Result};

use crate::vk_err;

/// A buffer in host-visible, host-coherent memory, mapped for its whole life: created unbound
/// by [`HostBuffer::create`], bound into the backend's one [`Arena`].
pub(crate) struct HostBuffer {
    pub buffer: vk::Buffer,
    requirements: vk::MemoryRequirements,
    mapped: *mut u8,
    size: u64,
}

impl HostBuffer {
    /// A buffer that owns nothing yet (destroying it does nothing).
    pub fn null() -> HostBuffer {
        HostBuffer {
            buffer: vk::Buffer::null(),
            requirements: vk::MemoryRequirements::default(),
            mapped: std::ptr::null_mut(),
            size: 0,
        }
    }

    /// Creates a buffer of `size` bytes, not yet bound to memory.
    ///
    /// # Safety
    /// `device` is valid.
    pub unsafe fn create(
        device: &ash::Device,
        size: u64,
        usage: vk::BufferUsageFlags,
    ) -> Result<HostBuffer> {
        let info = vk::BufferCreateInfo::default()
            .size(size.max(16))
            .usage(usage)
            .sharing_mode(vk::SharingMode::EXCLUSIVE);
        // SAFETY: valid device and create info.
        let buffer =
            unsafe { device.create_buffer(&info, None) }.map_err(vk_err("vkCreateBuffer"))?;
        // SAFETY: the buffer was just created.
        let requirements = unsafe { device.get_buffer_memory_requirements(buffer) };
        Ok(HostBuffer {
            buffer,
            requirements,
            mapped: std::ptr::null_mut(),
            size,
        })
    }

    /// Copies `bytes` to `offset` (bounds checked).
    pub fn write(&mut self, offset: u64, bytes: &[u8]) {
        let end = offset + bytes.len() as u64;
        assert!(end <= self.size, "write past the end of a host buffer");
        // SAFETY: the mapping covers `size` bytes and the range was checked; the device does
        // not read this range now (the slot's previous frame has completed).
        unsafe {
            std::ptr::copy_nonoverlapping(
                bytes.as_ptr(),
                self.mapped.add(offset as usize),
                bytes.len(),
            )
        };
    }

    /// Reads the `i`-th little-endian `u32`.
    pub fn read_u32(&self, i: u64) -> u32 {
        assert!(
            4 * (i + 1) <= self.size,
            "read past the end of a host buffer"
        );
        // SAFETY: in range; coherent memory written by a completed copy (barrier to HOST_READ).
        unsafe { std::ptr::read_unaligned(self.mapped.add(4 * i as usize).cast::<u32>()) }
    }

    /// Destroys the buffer (its memory belongs to the arena).
    ///
    /// # Safety
    /// The device no longer uses the buffer.
    pub unsafe fn destroy(&mut self, device: &ash::Device) {
        if self.buffer != vk::Buffer::null() {
            // SAFETY: per the caller.
            unsafe { device.destroy_buffer(self.buffer, None) };
        }
        *self = HostBuffer::null();
    }
}

/// The one host-visible, host-coherent allocation every buffer of the backend lives in (one
/// allocation instead of one per buffer: drivers and the best-practices layer prefer it).
pub(crate) struct Arena {
    memory: vk::DeviceMemory,
}

impl Arena {
    /// Owns nothing yet.
    pub fn null() -> Arena {
        Arena {
            memory: vk::DeviceMemory::null(),
        }
    }

    /// Allocates one block for `buffers` (at least `min_size` bytes), binds each at its
    /// aligned offset and maps it.
    ///
    /// # Safety
    /// `device` is valid, `memory` its physical device's properties; the buffers were
    /// created by [`HostBuffer::create`] on it and are not bound yet.
    pub unsafe fn new(
        device: &ash::Device,
        memory: &vk::PhysicalDeviceMemoryProperties,
        buffers: &mut [&mut HostBuffer],
        min_size: u64,
    ) -> Result<Arena> {
        let mut offsets = Vec::with_capacity(buffers.len());
        let (mut size, mut type_bits) = (0u64, u32::MAX);
        for b in buffers.iter() {
            let align = b.requirements.alignment.max(1);
            size = size.div_ceil(align) * align;
            offsets.push(size);
            size += b.requirements.size;
            type_bits &= b.requirements.memory_type_bits;
        }
        let wanted = vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT;
        let kind = (0..memory.memory_type_count)
            .find(|&i| {
                type_bits & (1 << i) != 0
                    && memory.memory_types[i as usize]
                        .property_flags
                        .contains(wanted)
            })
            .ok_or_else(|| Error::Unsupported {
                feature: "host-visible, host-coherent memory for query buffers".into(),
            })?;
        let alloc = vk::MemoryAllocateInfo::default()
            .allocation_size(size.max(min_size).max(1))
            .memory_type_index(kind);
        let mut arena = Arena::null();
        // SAFETY: valid device and allocate info; on error the memory is freed by the caller's
        // destroy of the arena.
        unsafe {
            arena.memory = device
                .allocate_memory(&alloc, None)
                .map_err(vk_err("vkAllocateMemory"))?;
            let bound = buffers.iter().zip(&offsets).try_for_each(|(b, &offset)| {
                device
                    .bind_buffer_memory(b.buffer, arena.memory, offset)
                    .map_err(vk_err("vkBindBufferMemory"))
            });
            let mapped = bound.and_then(|()| {
                device
                    .map_memory(arena.memory, 0, vk::WHOLE_SIZE, vk::MemoryMapFlags::empty())
                    .map_err(vk_err("vkMapMemory"))
            });
            match mapped {
                Ok(base) => {
                    for (b, &offset) in buffers.iter_mut().zip(&offsets) {
                        b.mapped = base.cast::<u8>().add(offset as usize);
                    }
                }
                Err(e) => {
                    device.free_memory(arena.memory, None);
                    return Err(e);
                }
            }
        }
        Ok(arena)
    }

    /// Frees the block (implicitly unmapped).
    ///
    /// # Safety
    /// The device no longer uses it; its buffers are destroyed.
    pub unsafe fn destroy(&mut self, device: &ash::Device) {
        if self.memory != vk::DeviceMemory::null() {
            // SAFETY: per the caller.
            unsafe { device.free_memory(self.memory, None) };
        }
        self.memory = vk::DeviceMemory::null();
    }
}

// SAFETY: the mapping is plain memory owned by the buffer; moving it to another thread is
// sound (Vulkan objects are not tied to a thread).
unsafe impl Send for HostBuffer {}
