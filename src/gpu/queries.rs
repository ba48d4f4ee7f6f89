//! Query pools that grow: precise occlusion queries and timestamps. Queries are reset from the
//! host at the start of a frame and read without `WAIT` (availability bit), so a caller can poll.
//!
//! Pools made [`QueryPools::with_readback`] also get one host-visible buffer per pool: a command
//! buffer copies its queries' results there ([`Recorder::copy_query_results`]) and, once it has
//! completed (known from its timeline value), [`QueryPools::copied`] reads them from memory
//! without calling the driver. On lavapipe every `vkGetQueryPoolResults` waits for the whole
//! device to go idle, so reading one query of a completed submission through it also waited for
//! every submission after it: with about 5000 queries a frame on the `overhead` path that wait
//! was most of the frame.
//!
//! [`Recorder::copy_query_results`]: super::Recorder::copy_query_results

use std::sync::Arc;

use ash::vk;
use gpu_allocator::MemoryLocation;

use super::{Buffer, GpuContext};
use crate::error::{Result, VkContext};

/// Bytes per copied result: the 64-bit value and the 64-bit availability word.
pub(crate) const COPIED_RESULT_BYTES: u64 = 16;

/// A growing set of query pools of one type; query ids are dense from 0 within a frame.
pub struct QueryPools {
    ctx: Arc<GpuContext>,
    ty: vk::QueryType,
    chunk: u32,
    pools: Vec<vk::QueryPool>,
    /// With readback: the result buffer of each pool (`chunk` results of 16 bytes).
    results: Option<Vec<Buffer>>,
    used: u32,
}

impl QueryPools {
    /// Pools of `ty` holding `chunk` queries each; one pool is created now.
    pub fn new(ctx: &Arc<GpuContext>, ty: vk::QueryType, chunk: u32) -> Result<QueryPools> {
        QueryPools::create(ctx, ty, chunk, false)
    }

    /// [`QueryPools::new`] with a host-visible result buffer per pool, for results that command
    /// buffers copy ([`Recorder::copy_query_results`](super::Recorder::copy_query_results)) and
    /// the host reads with [`QueryPools::copied`].
    pub fn with_readback(
        ctx: &Arc<GpuContext>,
        ty: vk::QueryType,
        chunk: u32,
    ) -> Result<QueryPools> {
        QueryPools::create(ctx, ty, chunk, true)
    }

    fn create(
        ctx: &Arc<GpuContext>,
        ty: vk::QueryType,
        chunk: u32,
        readback: bool,
    ) -> Result<QueryPools> {
        let mut q = QueryPools {
            ctx: ctx.clone(),
            ty,
            chunk: chunk.max(1),
            pools: Vec::new(),
            results: readback.then(Vec::new),
            used: 0,
        };
        q.grow()?;
        Ok(q)
    }

    fn grow(&mut self) -> Result<()> {
        if let Some(results) = self.results.as_mut() {
            results.push(Buffer::new(
                &self.ctx,
                "query results",
                u64::from(self.chunk) * COPIED_RESULT_BYTES,
                vk::BufferUsageFlags::TRANSFER_DST,
                MemoryLocation::GpuToCpu,
            )?);
        }
        let info = vk::QueryPoolCreateInfo::default()
            .query_type(self.ty)
            .query_count(self.chunk);
        // SAFETY: valid device and create info.
        let pool = match unsafe { self.ctx.device.create_query_pool(&info, None) } {
            Ok(p) => p,
            Err(e) => {
                if let Some(results) = self.results.as_mut() {
                    results.pop();
                }
                return Err(e).vk("vkCreateQueryPool");
            }
        };
        // SAFETY: hostQueryReset is enabled; the pool is new and unused.
        unsafe { self.ctx.device.reset_query_pool(pool, 0, self.chunk) };
        self.pools.push(pool);
        Ok(())
    }

    /// Queries per pool.
    pub(crate) fn chunk(&self) -> u32 {
        self.chunk
    }

    /// The result buffer that query `id` is copied into (readback pools only).
    pub(crate) fn result_buffer(&self, id: u32) -> Option<&Buffer> {
        self.results.as_ref()?.get((id / self.chunk) as usize)
    }

    /// The copied result of query `id`, read from memory. Only meaningful once the command
    /// buffer that copied it has completed (the caller checks its timeline value): before that
    /// the slot holds an earlier frame's result. `None` when the copy found the result
    /// unavailable, or for pools without readback.
    pub fn copied(&self, id: u32) -> Option<u64> {
        let bytes = self.result_buffer(id)?.mapped()?;
        let at = (id % self.chunk) as usize * COPIED_RESULT_BYTES as usize;
        let word = |o: usize| {
            let mut b = [0u8; 8];
            b.copy_from_slice(bytes.get(at + o..at + o + 8)?);
            Some(u64::from_ne_bytes(b))
        };
        let (value, available) = (word(0)?, word(8)?);
        (available != 0).then_some(value)
    }

    /// Number of queries the pools hold now.
    pub fn capacity(&self) -> u32 {
        self.chunk * self.pools.len() as u32
    }

    /// Queries handed out since the last reset.
    pub fn used(&self) -> u32 {
        self.used
    }

    /// Hands out the next query id, creating a pool when all are used.
    pub fn allocate(&mut self) -> Result<u32> {
        if self.used == self.capacity() {
            self.grow()?;
        }
        self.used += 1;
        Ok(self.used - 1)
    }

    /// Queries `first..first + count` (clamped to those handed out) split at pool
    /// boundaries: `(first id, pool, first slot in the pool, queries)` per pool.
    pub(crate) fn pool_ranges(
        &self,
        first: u32,
        count: u32,
    ) -> impl Iterator<Item = (u32, vk::QueryPool, u32, u32)> + '_ {
        let end = first.saturating_add(count).min(self.used);
        let mut id = first;
        std::iter::from_fn(move || {
            (id < end).then(|| {
                let (pool, slot) = self.location(id);
                let n = (self.chunk - slot).min(end - id);
                let range = (id, pool, slot, n);
                id += n;
                range
            })
        })
    }

    /// Pool and slot of a query id.
    pub fn location(&self, id: u32) -> (vk::QueryPool, u32) {
        (self.pools[(id / self.chunk) as usize], id % self.chunk)
    }

    /// Resets every query handed out since the last reset (host reset; none may be in flight).
    /// Their copied results are cleared too, so a result that no command buffer copies this
    /// time reads as unavailable, never as last frame's.
    pub fn reset(&mut self) {
        let mut left = self.used;
        for (i, &pool) in self.pools.iter().enumerate() {
            if left == 0 {
                break;
            }
            let n = left.min(self.chunk);
            // SAFETY: the caller guarantees no submitted work still uses these queries.
            unsafe { self.ctx.device.reset_query_pool(pool, 0, n) };
            if let Some(buffer) = self.results.as_mut().and_then(|r| r.get_mut(i)) {
                buffer.zero_prefix(n as usize * COPIED_RESULT_BYTES as usize);
            }
            left -= n;
        }
        self.used = 0;
    }

    /// The result of query `id` if available, without waiting.
    pub fn poll(&self, id: u32) -> Result<Option<u64>> {
        let (pool, slot) = self.location(id);
        let mut data = [[0u64; 2]];
        // SAFETY: the query was reset and its command buffer submitted; no WAIT flag.
        let r = unsafe {
            self.ctx.device.get_query_pool_results(
                pool,
                slot,
                &mut data,
                vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WITH_AVAILABILITY,
            )
        };
        match r {
            Ok(()) => Ok(if data[0][1] != 0 {
                Some(data[0][0])
            } else {
                None
            }),
            Err(vk::Result::NOT_READY) => Ok(None),
            Err(e) => Err(e).vk("vkGetQueryPoolResults"),
        }
    }
}

impl Drop for QueryPools {
    fn drop(&mut self) {
        for &p in &self.pools {
            // SAFETY: the owner guarantees no work in flight uses the pools.
            unsafe { self.ctx.device.destroy_query_pool(p, None) };
        }
    }
}
