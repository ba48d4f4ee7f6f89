//! One frame-in-flight slot: its query pool, the host-visible copy of its results, the box
//! corners of its queries; and the small host-visible buffer type they are made of.

use ash::vk;
use coherent_cull::{Aabb, Error, Result};

use crate::{vk_err, QueryBackendDesc};

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
    fn read_u32(&self, i: u64) -> u32 {
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

    /// Allocates one block for `buffers`, binds each at its aligned offset and maps it.
    ///
    /// # Safety
    /// `device` is valid, `memory` its physical device's properties; the buffers were
    /// created by [`HostBuffer::create`] on it and are not bound yet.
    pub unsafe fn new(
        device: &ash::Device,
        memory: &vk::PhysicalDeviceMemoryProperties,
        buffers: &mut [&mut HostBuffer],
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
            .allocation_size(size.max(1))
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

/// One frame-in-flight slot.
pub(crate) struct Slot {
    pub pool: vk::QueryPool,
    /// World-space corners of this frame's query boxes (8 per box).
    pub vertices: HostBuffer,
    /// The copied results: (value, availability) as two `u32` per query.
    results: HostBuffer,
    /// Queries issued in the slot's current frame.
    pub issued: u32,
    /// Boxes drawn in the slot's current frame.
    pub boxes_used: u32,
    /// Queries that need a reset before they are used again (all of them at first).
    dirty: u32,
    /// Queries whose results the last `end_frame` copied (not yet read).
    copied: u32,
    /// The results of the slot's previous frame, read at `begin_frame`.
    read: Vec<Option<u64>>,
    /// Predicated mode: the frame's results as 32-bit predicates for conditional rendering
    /// (null without predicates).
    pub predicates: HostBuffer,
    /// Queries of the current frame whose results are predicates already.
    pub resolved: u32,
}

impl Slot {
    /// Creates the slot's query pool and (unbound) buffers.
    ///
    /// # Safety
    /// `device` is valid.
    pub unsafe fn new(device: &ash::Device, desc: &QueryBackendDesc) -> Result<Slot> {
        let mut slot = Slot {
            pool: vk::QueryPool::null(),
            vertices: HostBuffer::null(),
            results: HostBuffer::null(),
            issued: 0,
            boxes_used: 0,
            dirty: desc.max_queries,
            copied: 0,
            read: Vec::with_capacity(desc.max_queries as usize),
            predicates: HostBuffer::null(),
            resolved: 0,
        };
        let info = vk::QueryPoolCreateInfo::default()
            .query_type(vk::QueryType::OCCLUSION)
            .query_count(desc.max_queries);
        // SAFETY: valid device and create infos; on error what exists is destroyed.
        let made = unsafe {
            device
                .create_query_pool(&info, None)
                .map_err(vk_err("vkCreateQueryPool"))
                .and_then(|pool| {
                    slot.pool = pool;
                    slot.vertices = HostBuffer::create(
                        device,
                        u64::from(desc.max_boxes) * 8 * 12,
                        vk::BufferUsageFlags::VERTEX_BUFFER,
                    )?;
                    slot.results = HostBuffer::create(
                        device,
                        u64::from(desc.max_queries) * 8,
                        vk::BufferUsageFlags::TRANSFER_DST,
                    )?;
                    if desc.predicates {
                        slot.predicates = HostBuffer::create(
                            device,
                            u64::from(desc.max_queries) * 4,
                            vk::BufferUsageFlags::TRANSFER_DST
                                | vk::BufferUsageFlags::CONDITIONAL_RENDERING_EXT,
                        )?;
                    }
                    Ok(())
                })
        };
        match made {
            Ok(()) => Ok(slot),
            Err(e) => {
                // SAFETY: nothing of the slot was used by the device.
                unsafe { slot.destroy(device) };
                Err(e)
            }
        }
    }

    /// Reads the results the slot's last frame copied, and starts a new frame in the slot.
    /// Returns how many results were read.
    pub fn read_results(&mut self) -> u32 {
        self.dirty = self.dirty.max(self.issued);
        self.read.clear();
        for i in 0..u64::from(self.copied) {
            let (value, available) = (
                self.results.read_u32(2 * i),
                self.results.read_u32(2 * i + 1),
            );
            self.read.push((available != 0).then_some(u64::from(value)));
        }
        let n = self.copied;
        self.copied = 0;
        self.issued = 0;
        self.resolved = 0;
        self.boxes_used = 0;
        n
    }

    /// The result of query `index` of the slot's previous frame, if it was copied and available.
    pub fn result(&self, index: u32) -> Option<u64> {
        self.read.get(index as usize).copied().flatten()
    }

    /// Records the reset of the queries used since the last reset; whether there were any.
    ///
    /// # Safety
    /// `cmd` is recording, outside a render pass instance.
    pub unsafe fn record_reset(&mut self, device: &ash::Device, cmd: vk::CommandBuffer) -> bool {
        if self.dirty == 0 {
            return false;
        }
        // SAFETY: per the caller; the range lies in the pool.
        unsafe { device.cmd_reset_query_pool(cmd, self.pool, 0, self.dirty) };
        self.dirty = 0;
        true
    }

    /// Records the copy of this frame's results and the barrier to the host; whether there
    /// were any.
    ///
    /// # Safety
    /// `cmd` is recording, outside a render pass instance, after every query of the frame.
    pub unsafe fn record_copy(&mut self, device: &ash::Device, cmd: vk::CommandBuffer) -> bool {
        self.dirty = self.dirty.max(self.issued);
        if self.issued == 0 {
            return false;
        }
        // SAFETY: per the caller; queries 0..issued were reset and ended in this command
        // buffer; the buffer holds 8 bytes per query.
        unsafe {
            device.cmd_copy_query_pool_results(
                cmd,
                self.pool,
                0,
                self.issued,
                self.results.buffer,
                0,
                8,
                vk::QueryResultFlags::WAIT | vk::QueryResultFlags::WITH_AVAILABILITY,
            );
            let barrier = vk::MemoryBarrier::default()
                .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
                .dst_access_mask(vk::AccessFlags::HOST_READ);
            device.cmd_pipeline_barrier(
                cmd,
                vk::PipelineStageFlags::TRANSFER,
                vk::PipelineStageFlags::HOST,
                vk::DependencyFlags::empty(),
                &[barrier],
                &[],
                &[],
            );
        }
        self.copied = self.issued;
        true
    }

    /// Writes the corners of `boxes` from box `first` on (8 per box, corner c = x | y << 1 |
    /// z << 2).
    pub fn write_corners(&mut self, first: u32, boxes: &[Aabb]) {
        for (i, b) in boxes.iter().enumerate() {
            let corners = crate::box_corners(b);
            let flat: &[f32] = corners.as_flattened();
            // SAFETY: f32 has no padding; reinterpreting as bytes is sound.
            let bytes = unsafe {
                std::slice::from_raw_parts(flat.as_ptr().cast::<u8>(), std::mem::size_of_val(flat))
            };
            self.vertices
                .write((u64::from(first) + i as u64) * 96, bytes);
        }
    }

    /// Records the copy of the queries issued since the last resolve as 32-bit predicates
    /// (waited for on the device) and the barrier that makes them visible to
    /// conditional-rendering reads; returns how many.
    ///
    /// # Safety
    /// `cmd` is recording, outside a render pass instance, after those queries ended.
    pub unsafe fn record_resolve(&mut self, device: &ash::Device, cmd: vk::CommandBuffer) -> u32 {
        let (first, n) = (self.resolved, self.issued - self.resolved);
        if n > 0 {
            // SAFETY: per the caller; queries first..issued were reset and ended in this
            // command buffer; the buffer holds 4 bytes per query.
            unsafe {
                device.cmd_copy_query_pool_results(
                    cmd,
                    self.pool,
                    first,
                    n,
                    self.predicates.buffer,
                    u64::from(first) * 4,
                    4,
                    vk::QueryResultFlags::WAIT,
                );
            }
        }
        let barrier = vk::MemoryBarrier2::default()
            .src_stage_mask(vk::PipelineStageFlags2::ALL_TRANSFER)
            .src_access_mask(vk::AccessFlags2::TRANSFER_WRITE)
            .dst_stage_mask(vk::PipelineStageFlags2::CONDITIONAL_RENDERING_EXT)
            .dst_access_mask(vk::AccessFlags2::CONDITIONAL_RENDERING_READ_EXT);
        // SAFETY: per the caller.
        unsafe {
            device.cmd_pipeline_barrier2(
                cmd,
                &vk::DependencyInfo::default().memory_barriers(&[barrier]),
            )
        };
        self.resolved = self.issued;
        n
    }

    /// The slot's buffers, to bind into the arena (the predicate buffer when there is one).
    pub fn buffers(&mut self) -> Vec<&mut HostBuffer> {
        let mut out = vec![&mut self.vertices, &mut self.results];
        if self.predicates.buffer != vk::Buffer::null() {
            out.push(&mut self.predicates);
        }
        out
    }

    /// Destroys the pool and buffers.
    ///
    /// # Safety
    /// The device no longer uses them.
    pub unsafe fn destroy(&mut self, device: &ash::Device) {
        // SAFETY: per the caller; null handles are skipped.
        unsafe {
            if self.pool != vk::QueryPool::null() {
                device.destroy_query_pool(self.pool, None);
                self.pool = vk::QueryPool::null();
            }
            self.vertices.destroy(device);
            self.results.destroy(device);
            self.predicates.destroy(device);
        }
    }
}
