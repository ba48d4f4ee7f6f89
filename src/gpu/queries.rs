//! Query pools that grow, for timestamps (GPU time per frame). Queries are reset from the host
//! at the start of a frame and read without `WAIT` (availability bit), once the frame has
//! completed. Occlusion queries live in coherent-ash's `QuerySet`, which the scene renderer
//! shares with hosts: it copies their results into host memory, because on lavapipe every
//! `vkGetQueryPoolResults` waits for the whole device to go idle.

use std::sync::Arc;

use ash::vk;

use super::GpuContext;
use crate::error::{Result, VkContext};

/// A growing set of query pools of one type; query ids are dense from 0 within a frame.
pub struct QueryPools {
    ctx: Arc<GpuContext>,
    ty: vk::QueryType,
    chunk: u32,
    pools: Vec<vk::QueryPool>,
    used: u32,
}

impl QueryPools {
    /// Pools of `ty` holding `chunk` queries each; one pool is created now.
    pub fn new(ctx: &Arc<GpuContext>, ty: vk::QueryType, chunk: u32) -> Result<QueryPools> {
        let mut q = QueryPools {
            ctx: ctx.clone(),
            ty,
            chunk: chunk.max(1),
            pools: Vec::new(),
            used: 0,
        };
        q.grow()?;
        Ok(q)
    }

    fn grow(&mut self) -> Result<()> {
        let info = vk::QueryPoolCreateInfo::default()
            .query_type(self.ty)
            .query_count(self.chunk);
        // SAFETY: valid device and create info.
        let pool =
            unsafe { self.ctx.device.create_query_pool(&info, None) }.vk("vkCreateQueryPool")?;
        // SAFETY: hostQueryReset is enabled; the pool is new and unused.
        unsafe { self.ctx.device.reset_query_pool(pool, 0, self.chunk) };
        self.pools.push(pool);
        Ok(())
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

    /// Pool and slot of a query id.
    pub fn location(&self, id: u32) -> (vk::QueryPool, u32) {
        (self.pools[(id / self.chunk) as usize], id % self.chunk)
    }

    /// Resets every query handed out since the last reset (host reset; none may be in flight).
    pub fn reset(&mut self) {
        let mut left = self.used;
        for &pool in &self.pools {
            if left == 0 {
                break;
            }
            let n = left.min(self.chunk);
            // SAFETY: the caller guarantees no submitted work still uses these queries.
            unsafe { self.ctx.device.reset_query_pool(pool, 0, n) };
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
