//! [`QuerySet`]: the query side shared by [`QueryBackend`](crate::QueryBackend)'s frames and
//! any host that runs its own frame (the built-in renderer of the `coherent` package, which
//! submits and waits inside a frame, uses it directly).

use ash::vk;
use coherent_cull::{Aabb, Error, Result};

use crate::slots::{Arena, HostBuffer};
use crate::{vk_err, BoxPipeline, QueryCounts, BOX_FACES};

/// Bytes of one box's 8 corners (3 floats each).
const BOX_BYTES: u64 = 8 * 12;
/// Bytes of one copied result: the 32-bit value and the 32-bit availability word.
const RESULT_BYTES: u64 = 8;
/// Bytes of one predicate (a 32-bit value, as conditional rendering reads it).
const PREDICATE_BYTES: u64 = 4;
/// Smallest allocation the set makes: the best-practices validation layer reports smaller
/// ones (drivers prefer few large allocations).
const MIN_ALLOCATION: u64 = 256 * 1024;

/// How a [`QuerySet`] is sized and what it may do.
#[derive(Clone, Debug)]
pub struct QuerySetDesc {
    /// Queries per query pool: the set creates one pool at first and more as it grows.
    pub queries_per_pool: u32,
    /// Most queries the set holds between two resets (it grows up to this).
    pub max_queries: u32,
    /// Boxes per host-visible buffer of box corners (one box draw never spans two).
    pub boxes_per_buffer: u32,
    /// Most boxes the set holds between two resets.
    pub max_boxes: u32,
    /// Predicate buffers for conditional rendering ([`QuerySet::record_resolve`],
    /// [`QuerySet::begin_block`]): the device needs `VK_EXT_conditional_rendering` with
    /// `conditionalRendering` enabled.
    pub predicates: bool,
    /// The device has `hostQueryReset` enabled: [`QuerySet::reset_from_host`] works, and the set
    /// may grow while a frame is recorded (a new pool is reset from the host). Without it the
    /// set is created at its full size (`max_queries` in pools of `queries_per_pool`, all
    /// boxes) and reset with [`QuerySet::record_reset`].
    pub host_query_reset: bool,
}

/// One query pool with the host-visible copies of its results and its predicates.
struct PoolChunk {
    pool: vk::QueryPool,
    results: HostBuffer,
    predicates: HostBuffer,
    /// Leading queries used (or never reset) since the last reset.
    dirty: u32,
}

/// A growing set of precise occlusion queries: their pools and resets, the world-space box
/// corners each query draws (host-visible, with a shared index buffer), the copies of their
/// results into host-visible memory, and their 32-bit predicates for conditional rendering.
///
/// Query ids are dense from 0 after each reset. What the set records is counted
/// ([`QuerySet::counts`]). It records into the caller's command buffers and never submits or
/// waits: the caller knows when a copy's submission has completed and only then reads
/// [`QuerySet::copied_result`] or [`QuerySet::predicate`].
///
/// A frame with the set, in a host that submits inside its frame:
/// 1. after every earlier use has completed: [`QuerySet::reset_from_host`] (or
///    [`QuerySet::record_reset`] in the frame's first command buffer, outside rendering);
/// 2. inside rendering: [`QuerySet::bind`] the box pipeline and buffers whenever the host
///    bound its own since, then [`QuerySet::record_query`] per query;
/// 3. outside rendering, before each submission whose results the host wants to read:
///    [`QuerySet::record_copy`];
/// 4. once that submission completed: [`QuerySet::copied_result`].
///
/// Predicated draws: outside rendering [`QuerySet::record_resolve`] turns the results issued so
/// far into predicates; inside rendering [`QuerySet::begin_block`] / [`QuerySet::end_block`]
/// enclose draws that run only where a predicate is non-zero, and
/// [`QuerySet::record_query`] with a predicate draws a query's boxes under it.
pub struct QuerySet {
    device: ash::Device,
    memory: vk::PhysicalDeviceMemoryProperties,
    desc: QuerySetDesc,
    conditional: Option<ash::ext::conditional_rendering::DeviceFn>,
    pools: Vec<PoolChunk>,
    /// Host-visible buffers of box corners, `boxes_per_buffer` boxes each.
    boxes: Vec<HostBuffer>,
    /// The 36 indices of each of `boxes_per_buffer` boxes.
    indices: HostBuffer,
    /// Every allocation the buffers live in.
    arenas: Vec<Arena>,
    issued: u32,
    resolved: u32,
    copied: u32,
    boxes_used: u32,
    /// The box buffer bound by the last [`QuerySet::bind`] or box draw in this state.
    bound_boxes: Option<usize>,
    open_block: bool,
    /// Predicates were copied and no barrier has made them visible to conditional rendering.
    unguarded: bool,
    skip_barrier: bool,
    counts: QueryCounts,
}

impl QuerySet {
    /// Creates the first query pool, box buffer and index buffer (all of them without
    /// `host_query_reset`).
    ///
    /// # Safety
    /// `device` was created from `physical_device` of `instance`, with `occlusionQueryPrecise`
    /// enabled (and `conditionalRendering` for `predicates`, `hostQueryReset` for
    /// `host_query_reset`), and outlives the set.
    pub unsafe fn new(
        instance: &ash::Instance,
        physical_device: vk::PhysicalDevice,
        device: &ash::Device,
        desc: QuerySetDesc,
    ) -> Result<QuerySet> {
        check_desc(&desc)?;
        // SAFETY: the caller guarantees the handles belong together.
        if desc.predicates
            && !unsafe { crate::has_conditional_rendering(instance, physical_device) }
        {
            return Err(Error::Unsupported {
                feature: "VK_EXT_conditional_rendering (conditionalRendering), which \
                          predicates need"
                    .into(),
            });
        }
        // SAFETY: as above.
        let memory = unsafe { instance.get_physical_device_memory_properties(physical_device) };
        let mut set = QuerySet {
            device: device.clone(),
            memory,
            conditional: desc.predicates.then(|| {
                ash::ext::conditional_rendering::Device::new(instance, device)
                    .fp()
                    .clone()
            }),
            pools: Vec::new(),
            boxes: Vec::new(),
            indices: HostBuffer::null(),
            arenas: Vec::new(),
            issued: 0,
            resolved: 0,
            copied: 0,
            boxes_used: 0,
            bound_boxes: None,
            open_block: false,
            unguarded: false,
            skip_barrier: false,
            counts: QueryCounts::default(),
            desc,
        };
        // On an error below `set` is dropped and destroys what was created so far.
        let (pools, box_buffers) = if set.desc.host_query_reset {
            (1, 1)
        } else {
            (
                set.desc.max_queries.div_ceil(set.desc.queries_per_pool),
                set.desc.max_boxes.div_ceil(set.desc.boxes_per_buffer),
            )
        };
        // SAFETY: valid device (the caller).
        unsafe { set.grow(pools, box_buffers, true)? };
        let per = set.desc.boxes_per_buffer;
        let indices: Vec<u32> = (0..per)
            .flat_map(|b| BOX_FACES.iter().map(move |i| i + 8 * b))
            .collect();
        set.indices.write(0, crate::as_bytes(&indices));
        Ok(set)
    }

    /// Creates `pools` more query pools and `box_buffers` more box buffers (and the index
    /// buffer when `indices`) in one allocation; new pools are reset from the host when the
    /// device allows it and otherwise wait for the next [`QuerySet::record_reset`].
    unsafe fn grow(&mut self, pools: u32, box_buffers: u32, indices: bool) -> Result<()> {
        let d = &self.desc;
        let (per_pool, per_box) = (d.queries_per_pool, d.boxes_per_buffer);
        let first_pool = self.pools.len();
        let first_box = self.boxes.len();
        // SAFETY (whole block): valid device; what was created is owned by `self` at once and
        // destroyed with it on an error.
        unsafe {
            if indices {
                self.indices = HostBuffer::create(
                    &self.device,
                    u64::from(per_box) * 36 * 4,
                    vk::BufferUsageFlags::INDEX_BUFFER,
                )?;
            }
            for _ in 0..pools {
                let info = vk::QueryPoolCreateInfo::default()
                    .query_type(vk::QueryType::OCCLUSION)
                    .query_count(per_pool);
                let pool = self
                    .device
                    .create_query_pool(&info, None)
                    .map_err(vk_err("vkCreateQueryPool"))?;
                self.pools.push(PoolChunk {
                    pool,
                    results: HostBuffer::null(),
                    predicates: HostBuffer::null(),
                    dirty: per_pool,
                });
                let chunk = self.pools.last_mut().expect("just pushed");
                chunk.results = HostBuffer::create(
                    &self.device,
                    u64::from(per_pool) * RESULT_BYTES,
                    vk::BufferUsageFlags::TRANSFER_DST,
                )?;
                if self.desc.predicates {
                    chunk.predicates = HostBuffer::create(
                        &self.device,
                        u64::from(per_pool) * PREDICATE_BYTES,
                        vk::BufferUsageFlags::TRANSFER_DST
                            | vk::BufferUsageFlags::CONDITIONAL_RENDERING_EXT,
                    )?;
                }
            }
            for _ in 0..box_buffers {
                self.boxes.push(HostBuffer::create(
                    &self.device,
                    u64::from(per_box) * BOX_BYTES,
                    vk::BufferUsageFlags::VERTEX_BUFFER,
                )?);
            }
            let mut buffers: Vec<&mut HostBuffer> = Vec::new();
            if indices {
                buffers.push(&mut self.indices);
            }
            for c in &mut self.pools[first_pool..] {
                buffers.push(&mut c.results);
                if c.predicates.buffer != vk::Buffer::null() {
                    buffers.push(&mut c.predicates);
                }
            }
            buffers.extend(self.boxes[first_box..].iter_mut());
            let arena = Arena::new(&self.device, &self.memory, &mut buffers, MIN_ALLOCATION)?;
            self.arenas.push(arena);
            if self.desc.host_query_reset {
                for c in &mut self.pools[first_pool..] {
                    self.device.reset_query_pool(c.pool, 0, per_pool);
                    c.dirty = 0;
                }
            }
        }
        Ok(())
    }

    /// The description the set was made with.
    pub fn desc(&self) -> &QuerySetDesc {
        &self.desc
    }

    /// Queries the pools hold now.
    pub fn capacity(&self) -> u32 {
        self.pools.len() as u32 * self.desc.queries_per_pool
    }

    /// Queries recorded since the last reset (the next query's id).
    pub fn issued(&self) -> u32 {
        self.issued
    }

    /// Queries whose results [`QuerySet::record_copy`] copied since the last reset.
    pub fn copied(&self) -> u32 {
        self.copied
    }

    /// Queries whose results are predicates ([`QuerySet::record_resolve`]).
    pub fn resolved(&self) -> u32 {
        self.resolved
    }

    /// What the set recorded since the last reset: `queries`, `query_boxes`, `box_draws`,
    /// `pipeline_binds` and `buffer_binds` (by [`QuerySet::bind`] and box draws), `resets`,
    /// `result_copies`, `resolves`, `conditional_blocks` and `predicated_queries`. The other
    /// fields are left to the caller ([`QuerySet::counts_mut`]).
    pub fn counts(&self) -> QueryCounts {
        self.counts
    }

    /// The counts, for a caller that adds what it records around the set (state changes,
    /// object draws, query purposes).
    pub fn counts_mut(&mut self) -> &mut QueryCounts {
        &mut self.counts
    }

    /// Forgets the last frame's queries, boxes, copies, predicates and counts.
    fn start(&mut self) {
        self.issued = 0;
        self.resolved = 0;
        self.copied = 0;
        self.boxes_used = 0;
        self.bound_boxes = None;
        self.open_block = false;
        self.unguarded = false;
        self.counts = QueryCounts::default();
    }

    /// Records the reset of every query used since the last reset (`vkCmdResetQueryPool`) and
    /// starts over from query 0; returns the pools reset. Read the copies of the last use
    /// ([`QuerySet::copied_result`]) before: they are forgotten.
    ///
    /// # Safety
    /// `cmd` is recording, outside a render pass instance; every earlier command buffer that
    /// used the set is submitted before it (or has completed).
    pub unsafe fn record_reset(&mut self, cmd: vk::CommandBuffer) -> u32 {
        self.start();
        let mut n = 0;
        for c in &mut self.pools {
            if c.dirty > 0 {
                // SAFETY: per the caller; the range lies in the pool.
                unsafe { self.device.cmd_reset_query_pool(cmd, c.pool, 0, c.dirty) };
                c.dirty = 0;
                n += 1;
            }
        }
        self.counts.resets = n;
        n
    }

    /// Resets every query used since the last reset from the host (`vkResetQueryPool`, needs
    /// `host_query_reset`) and starts over from query 0.
    ///
    /// # Safety
    /// Every command buffer that used the set has completed.
    pub unsafe fn reset_from_host(&mut self) -> Result<()> {
        if !self.desc.host_query_reset {
            return Err(Error::Unsupported {
                feature: "host query resets (QuerySetDesc::host_query_reset, the device's \
                          hostQueryReset)"
                    .into(),
            });
        }
        self.start();
        for c in &mut self.pools {
            if c.dirty > 0 {
                // SAFETY: per the caller; hostQueryReset is enabled (the desc says so).
                unsafe { self.device.reset_query_pool(c.pool, 0, c.dirty) };
                c.dirty = 0;
            }
        }
        Ok(())
    }

    /// Binds `pipeline` (pushing `view_proj` when the pipeline has its own layout; with the
    /// host's layout the host has pushed it at offset 0), the box index buffer and the
    /// current box buffer. Call it inside rendering before the first query, and again after
    /// the host bound a pipeline or vertex or index buffers of its own.
    ///
    /// # Safety
    /// `cmd` is recording inside a rendering compatible with `pipeline`, which was made on the
    /// set's device.
    pub unsafe fn bind(
        &mut self,
        cmd: vk::CommandBuffer,
        pipeline: &BoxPipeline,
        view_proj: &[f32; 16],
    ) {
        let current = self.current_box_buffer();
        // SAFETY: per the caller; the buffers live as long as the set.
        unsafe {
            pipeline.bind(&self.device, cmd, view_proj);
            self.device
                .cmd_bind_index_buffer(cmd, self.indices.buffer, 0, vk::IndexType::UINT32);
            self.device
                .cmd_bind_vertex_buffers(cmd, 0, &[self.boxes[current].buffer], &[0]);
        }
        self.bound_boxes = Some(current);
        self.counts.pipeline_binds += 1;
        self.counts.buffer_binds += 1;
    }

    /// The box buffer the next box goes into (the last one when all are full).
    fn current_box_buffer(&self) -> usize {
        ((self.boxes_used / self.desc.boxes_per_buffer) as usize).min(self.boxes.len() - 1)
    }

    /// Grows (or refuses) so that query `self.issued` and `boxes` more boxes have room.
    fn make_room(&mut self, boxes: u32) -> Result<()> {
        let d = &self.desc;
        if self.issued >= d.max_queries {
            return Err(Error::Input(format!(
                "more than {} queries between two resets (raise max_queries)",
                d.max_queries
            )));
        }
        let end = u64::from(self.boxes_used) + u64::from(boxes);
        if boxes == 0 || end > u64::from(d.max_boxes) {
            return Err(Error::Input(format!(
                "a query of {boxes} boxes: room for {} more before the next reset (raise \
                 max_boxes)",
                d.max_boxes - self.boxes_used
            )));
        }
        let pools = (self.issued + 1)
            .div_ceil(d.queries_per_pool)
            .saturating_sub(self.pools.len() as u32);
        let box_buffers = (end as u32)
            .div_ceil(d.boxes_per_buffer)
            .saturating_sub(self.boxes.len() as u32);
        if pools + box_buffers > 0 {
            // Without host resets everything was created up front: this cannot be reached.
            if !self.desc.host_query_reset {
                return Err(Error::Input("the query set is full".into()));
            }
            // SAFETY: valid device.
            unsafe { self.grow(pools, box_buffers, false)? };
        }
        Ok(())
    }

    /// Records one precise occlusion query that draws `boxes` (36 indices per box, as few
    /// draws as the box buffers allow) and returns its id. With `predicate` (a query resolved
    /// by [`QuerySet::record_resolve`]) the box draws lie inside a conditional block on it:
    /// begin and end of a query are not predicated, so under a zero predicate the query counts
    /// no sample.
    ///
    /// # Safety
    /// `cmd` is recording inside rendering, after [`QuerySet::bind`] with no pipeline or
    /// buffer bound by the host since; no query and no block is active; the set was reset
    /// in (or before) this command buffer's submission order.
    pub unsafe fn record_query(
        &mut self,
        cmd: vk::CommandBuffer,
        boxes: &[Aabb],
        predicate: Option<u32>,
    ) -> Result<u32> {
        if self.bound_boxes.is_none() {
            return Err(Error::Input(
                "a query before QuerySet::bind: the box pipeline is not bound".into(),
            ));
        }
        if let Some(p) = predicate {
            self.check_block(p)?;
        }
        self.make_room(boxes.len() as u32)?;
        let id = self.issued;
        let (chunk, index) = self.location(id);
        let pool = self.pools[chunk].pool;
        // SAFETY (whole block): per the caller; the query was reset and is used once; the
        // predicate was checked; the boxes written below lie in their buffers.
        unsafe {
            self.device
                .cmd_begin_query(cmd, pool, index, vk::QueryControlFlags::PRECISE);
            if let Some(p) = predicate {
                self.begin_conditional(cmd, p);
            }
            let per_box = self.desc.boxes_per_buffer;
            let mut rest = boxes;
            while !rest.is_empty() {
                let buffer = (self.boxes_used / per_box) as usize;
                let first = self.boxes_used % per_box;
                let n = (per_box - first).min(rest.len() as u32);
                write_corners(&mut self.boxes[buffer], first, &rest[..n as usize]);
                if self.bound_boxes != Some(buffer) {
                    self.device
                        .cmd_bind_vertex_buffers(cmd, 0, &[self.boxes[buffer].buffer], &[0]);
                    self.bound_boxes = Some(buffer);
                    self.counts.buffer_binds += 1;
                }
                self.device
                    .cmd_draw_indexed(cmd, 36 * n, 1, 0, (first * 8) as i32, 0);
                self.counts.box_draws += 1;
                self.boxes_used += n;
                rest = &rest[n as usize..];
            }
            if predicate.is_some() {
                self.end_block(cmd);
                self.counts.predicated_queries += 1;
            }
            self.device.cmd_end_query(cmd, pool, index);
        }
        let c = &mut self.pools[chunk];
        c.dirty = c.dirty.max(index + 1);
        self.issued += 1;
        self.counts.queries += 1;
        self.counts.query_boxes += boxes.len() as u32;
        Ok(id)
    }

    /// Records the copies of the results of the queries issued since the last copy (value and
    /// availability, 32-bit, waited for on the device) into host-visible memory, and a barrier
    /// that makes them visible to the host once the submission completed. Returns how many.
    ///
    /// # Safety
    /// `cmd` is recording outside a render pass instance, after those queries ended (in this
    /// command buffer or one submitted before it).
    pub unsafe fn record_copy(&mut self, cmd: vk::CommandBuffer) -> u32 {
        let (first, n) = (self.copied, self.issued - self.copied);
        if n == 0 {
            return 0;
        }
        // SAFETY: per the caller.
        unsafe {
            self.copy_results(cmd, first, n, false);
            self.barrier(
                cmd,
                vk::PipelineStageFlags::HOST,
                vk::AccessFlags::HOST_READ,
            );
        }
        self.copied = self.issued;
        n
    }

    /// The copied result of query `id` (its sample count), read from host memory; `None` when
    /// no copy covered it or the copy found it unavailable. Only meaningful once the
    /// submission with the copy has completed.
    pub fn copied_result(&self, id: u32) -> Option<u32> {
        if id >= self.copied {
            return None;
        }
        let (chunk, slot) = self.location(id);
        let r = &self.pools[chunk].results;
        let at = u64::from(slot) * 2;
        let (value, available) = (r.read_u32(at), r.read_u32(at + 1));
        (available != 0).then_some(value)
    }

    /// Records the copies of the results issued since the last resolve as 32-bit predicates
    /// (waited for on the device) and the barrier that makes them visible to conditional
    /// rendering; returns how many. A pass break: the caller ends rendering before and
    /// resumes it (LOAD ops) after.
    ///
    /// # Safety
    /// `cmd` is recording outside a render pass instance, after those queries ended.
    pub unsafe fn record_resolve(&mut self, cmd: vk::CommandBuffer) -> Result<u32> {
        if self.conditional.is_none() {
            return Err(coherent_cull::predicates_unsupported());
        }
        let (first, n) = (self.resolved, self.issued - self.resolved);
        // SAFETY: per the caller.
        unsafe { self.copy_results(cmd, first, n, true) };
        if self.skip_barrier {
            self.unguarded = true;
        } else {
            // SAFETY: per the caller.
            unsafe {
                self.barrier(
                    cmd,
                    vk::PipelineStageFlags::CONDITIONAL_RENDERING_EXT,
                    vk::AccessFlags::CONDITIONAL_RENDERING_READ_EXT,
                )
            };
            self.unguarded = false;
        }
        self.resolved = self.issued;
        self.counts.resolves += 1;
        Ok(n)
    }

    /// Records the copies of the results of queries `first..first + n`, pool by pool: as
    /// 32-bit predicates into the predicate buffers, or as (value, availability) pairs into
    /// the result buffers; `vkCmdCopyQueryPoolResults` waits for each on the device.
    ///
    /// # Safety
    /// `cmd` is recording outside a render pass instance, after those queries ended.
    unsafe fn copy_results(
        &mut self,
        cmd: vk::CommandBuffer,
        first: u32,
        n: u32,
        predicates: bool,
    ) {
        for (chunk, slot, count) in self.ranges(first, n) {
            let c = &self.pools[chunk];
            let (buffer, stride, flags) = if predicates {
                (
                    c.predicates.buffer,
                    PREDICATE_BYTES,
                    vk::QueryResultFlags::WAIT,
                )
            } else {
                (
                    c.results.buffer,
                    RESULT_BYTES,
                    vk::QueryResultFlags::WAIT | vk::QueryResultFlags::WITH_AVAILABILITY,
                )
            };
            // SAFETY: per the caller; the range lies in the pool and, at `stride` bytes a
            // query, in the buffer (TRANSFER_DST).
            unsafe {
                self.device.cmd_copy_query_pool_results(
                    cmd,
                    c.pool,
                    slot,
                    count,
                    buffer,
                    u64::from(slot) * stride,
                    stride,
                    flags,
                )
            };
            if !predicates {
                self.counts.result_copies += 1;
            }
        }
    }

    /// Records copies of the results of queries `first..first + n` as 32-bit values (waited
    /// for on the device) into the host's `buffer`, 4 bytes per query at byte `4 * id`: for a
    /// host that turns results into predicates of its own on the device (a compute pass that
    /// reads a query's value). The buffer needs `TRANSFER_DST` usage and room for query
    /// `first + n - 1`; the host records the barrier to its readers.
    ///
    /// # Safety
    /// `cmd` is recording outside a render pass instance, after those queries ended (in this
    /// command buffer or one submitted before it); `buffer` is valid and large enough.
    pub unsafe fn record_copy_values(
        &mut self,
        cmd: vk::CommandBuffer,
        buffer: vk::Buffer,
        first: u32,
        n: u32,
    ) -> Result<()> {
        if first.checked_add(n).is_none_or(|end| end > self.issued) {
            return Err(Error::Input(format!(
                "queries {first}..{} were not all issued ({} were)",
                u64::from(first) + u64::from(n),
                self.issued
            )));
        }
        for (chunk, slot, count) in self.ranges(first, n) {
            let id = chunk as u64 * u64::from(self.desc.queries_per_pool) + u64::from(slot);
            // SAFETY: per the caller; the range lies in the pool.
            unsafe {
                self.device.cmd_copy_query_pool_results(
                    cmd,
                    self.pools[chunk].pool,
                    slot,
                    count,
                    buffer,
                    id * PREDICATE_BYTES,
                    PREDICATE_BYTES,
                    vk::QueryResultFlags::WAIT,
                )
            };
            self.counts.result_copies += 1;
        }
        Ok(())
    }

    /// A global barrier from the copies (transfer writes) to `stage`'s `access`: a Vulkan 1.0
    /// barrier, so that a host needs neither Vulkan 1.3 nor `synchronization2`.
    ///
    /// # Safety
    /// `cmd` is recording outside a render pass instance.
    unsafe fn barrier(
        &self,
        cmd: vk::CommandBuffer,
        stage: vk::PipelineStageFlags,
        access: vk::AccessFlags,
    ) {
        let barrier = vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
            .dst_access_mask(access);
        // SAFETY: per the caller.
        unsafe {
            self.device.cmd_pipeline_barrier(
                cmd,
                vk::PipelineStageFlags::TRANSFER,
                stage,
                vk::DependencyFlags::empty(),
                &[barrier],
                &[],
                &[],
            )
        };
    }

    /// Leaves out the barrier after the predicate copies of [`QuerySet::record_resolve`] (for
    /// the test that shows such predicates are refused: the validation layers do not track
    /// predicate reads, so the set does).
    #[doc(hidden)]
    pub fn skip_resolve_barrier(&mut self, skip: bool) {
        self.skip_barrier = skip;
    }

    /// Whether a block on `query` may begin now.
    fn check_block(&self, query: u32) -> Result<()> {
        if self.conditional.is_none() {
            return Err(coherent_cull::predicates_unsupported());
        }
        if query >= self.resolved {
            return Err(Error::Input(format!(
                "query {query} is not a resolved predicate"
            )));
        }
        if self.unguarded {
            return Err(Error::Input(
                "a conditional block reads predicates that no barrier made visible after \
                 their copy"
                    .into(),
            ));
        }
        if self.open_block {
            return Err(Error::Input("conditional blocks cannot nest".into()));
        }
        Ok(())
    }

    /// Records `vkCmdBeginConditionalRenderingEXT` on the predicate of `query` (checked).
    unsafe fn begin_conditional(&mut self, cmd: vk::CommandBuffer, query: u32) {
        let (chunk, slot) = self.location(query);
        let buffer = self.pools[chunk].predicates.buffer;
        // SAFETY: per the caller; the predicate buffer has CONDITIONAL_RENDERING_EXT usage
        // and the offset is a multiple of 4 inside it.
        unsafe { self.begin_conditional_at(cmd, buffer, u64::from(slot) * PREDICATE_BYTES) };
    }

    /// Records `vkCmdBeginConditionalRenderingEXT` on the 32-bit value at `offset` of
    /// `buffer` (checked by the caller).
    unsafe fn begin_conditional_at(
        &mut self,
        cmd: vk::CommandBuffer,
        buffer: vk::Buffer,
        offset: u64,
    ) {
        if let Some(fp) = self.conditional.as_ref() {
            let info = vk::ConditionalRenderingBeginInfoEXT::default()
                .buffer(buffer)
                .offset(offset);
            // SAFETY: the caller checked the block; the buffer has CONDITIONAL_RENDERING_EXT
            // usage and the offset is a multiple of 4 inside it.
            unsafe { (fp.cmd_begin_conditional_rendering_ext)(cmd, &info) };
            self.open_block = true;
            self.counts.conditional_blocks += 1;
        }
    }

    /// Opens a conditional block: the draws until [`QuerySet::end_block`] run only if query
    /// `query`'s predicate is non-zero. Refuses a query that is not resolved, predicates copied
    /// without their barrier, and a block inside a block.
    ///
    /// # Safety
    /// `cmd` is recording inside rendering, in the command buffer of the resolve or one
    /// submitted after it.
    pub unsafe fn begin_block(&mut self, cmd: vk::CommandBuffer, query: u32) -> Result<()> {
        self.check_block(query)?;
        // SAFETY: per the caller; checked above.
        unsafe { self.begin_conditional(cmd, query) };
        Ok(())
    }

    /// Opens a conditional block on a predicate the host wrote itself: the 32-bit value at
    /// byte `offset` of `buffer` (which has `CONDITIONAL_RENDERING_EXT` usage; the host made
    /// its write visible to `CONDITIONAL_RENDERING_READ_EXT` with a barrier). Close it with
    /// [`QuerySet::end_block`]. Refuses a block inside a block, an offset that is not a
    /// multiple of 4, and a set without predicates.
    ///
    /// # Safety
    /// `cmd` is recording inside rendering; `buffer` is valid and holds `offset + 4` bytes.
    pub unsafe fn begin_block_at(
        &mut self,
        cmd: vk::CommandBuffer,
        buffer: vk::Buffer,
        offset: u64,
    ) -> Result<()> {
        if self.conditional.is_none() {
            return Err(coherent_cull::predicates_unsupported());
        }
        if self.open_block {
            return Err(Error::Input("conditional blocks cannot nest".into()));
        }
        if !offset.is_multiple_of(PREDICATE_BYTES) {
            return Err(Error::Input(format!(
                "a predicate's offset ({offset}) must be a multiple of 4"
            )));
        }
        // SAFETY: per the caller; checked above.
        unsafe { self.begin_conditional_at(cmd, buffer, offset) };
        Ok(())
    }

    /// Closes the open conditional block (nothing when none is open).
    ///
    /// # Safety
    /// `cmd` is the command buffer, and the rendering instance, of the open block.
    pub unsafe fn end_block(&mut self, cmd: vk::CommandBuffer) {
        if let (Some(fp), true) = (self.conditional.as_ref(), self.open_block) {
            // SAFETY: per the caller.
            unsafe { (fp.cmd_end_conditional_rendering_ext)(cmd) };
            self.open_block = false;
        }
    }

    /// The predicate of query `query` as the device saw it (read from host memory): `None`
    /// unless it was resolved. Only meaningful once the submission with the resolve has
    /// completed.
    pub fn predicate(&self, query: u32) -> Option<u32> {
        if query >= self.resolved {
            return None;
        }
        let (chunk, slot) = self.location(query);
        Some(self.pools[chunk].predicates.read_u32(u64::from(slot)))
    }

    /// Pool chunk and slot of query `id`.
    fn location(&self, id: u32) -> (usize, u32) {
        location(self.desc.queries_per_pool, id)
    }

    /// Queries `first..first + count` split at pool boundaries: (chunk, first slot, count).
    fn ranges(&self, first: u32, count: u32) -> impl Iterator<Item = (usize, u32, u32)> {
        let per = self.desc.queries_per_pool;
        let end = first + count;
        let mut id = first;
        std::iter::from_fn(move || {
            (id < end).then(|| {
                let (chunk, slot) = location(per, id);
                let n = (per - slot).min(end - id);
                id += n;
                (chunk, slot, n)
            })
        })
    }

    /// Destroys every Vulkan object of the set (also done on drop).
    ///
    /// # Safety
    /// The device has finished every command buffer that used the set.
    pub unsafe fn destroy(&mut self) {
        // SAFETY: per the caller; null handles are skipped.
        unsafe {
            for c in &mut self.pools {
                self.device.destroy_query_pool(c.pool, None);
                c.results.destroy(&self.device);
                c.predicates.destroy(&self.device);
            }
            self.pools.clear();
            for b in &mut self.boxes {
                b.destroy(&self.device);
            }
            self.boxes.clear();
            self.indices.destroy(&self.device);
            for a in &mut self.arenas {
                a.destroy(&self.device);
            }
            self.arenas.clear();
        }
    }
}

impl Drop for QuerySet {
    fn drop(&mut self) {
        // SAFETY: the owner drops the set only once the device is done with it.
        unsafe { self.destroy() };
    }
}

/// Pool chunk and slot of query `id` with `per` queries a pool.
fn location(per: u32, id: u32) -> (usize, u32) {
    ((id / per) as usize, id % per)
}

/// Writes the corners of `boxes` from box `first` of `buffer` on.
fn write_corners(buffer: &mut HostBuffer, first: u32, boxes: &[Aabb]) {
    let mut bytes = [0u8; BOX_BYTES as usize];
    for (i, b) in boxes.iter().enumerate() {
        for (c, corner) in crate::box_corners(b).iter().enumerate() {
            for (k, v) in corner.iter().enumerate() {
                let at = 12 * c + 4 * k;
                bytes[at..at + 4].copy_from_slice(&v.to_ne_bytes());
            }
        }
        buffer.write((u64::from(first) + i as u64) * BOX_BYTES, &bytes);
    }
}

/// The set is `Send` from its parts (its host buffers' mappings are); this fails to compile
/// if a part stops being so.
const _: fn() = || {
    fn send<T: Send>() {}
    send::<QuerySet>();
};

fn check_desc(d: &QuerySetDesc) -> Result<()> {
    if d.queries_per_pool == 0 || d.max_queries == 0 || d.boxes_per_buffer == 0 || d.max_boxes == 0
    {
        return Err(Error::Input(
            "queries_per_pool, max_queries, boxes_per_buffer and max_boxes must be at least 1"
                .into(),
        ));
    }
    if u64::from(d.boxes_per_buffer) * 36 > u64::from(u32::MAX) {
        return Err(Error::Input(format!(
            "boxes_per_buffer {} is too large for 32-bit indices",
            d.boxes_per_buffer
        )));
    }
    Ok(())
}
