//! CHC++'s queues and batches: previously invisible nodes wait in the i-queue and go out as a
//! batch of `b` (with the multiqueries of `multiquery.rs`), due visible-leaf queries wait in the
//! v-queue until the traversal has nothing else to do, and the render queue is drawn before
//! each batch: one switch into query state per batch. Unbatched (CHC), each query goes out
//! alone as its node is reached.

use super::{Chcpp, Pending, QueryKind};
use crate::bvh::ObjectBvh;
use crate::error::Result;
use crate::{CullStats, OcclusionBackend, QueryPurpose};

impl Chcpp {
    /// Whether queries wait in the i- and v-queues (batching, or a latency mode that issues
    /// them after the traversal: the predicated mode, whose predicates need the queries before
    /// the conditional draws).
    pub(super) fn queues_queries(&self) -> bool {
        self.params.batching || self.mode.issues_after_traversal()
    }

    /// Nodes per i-queue batch (`b`; 1 without batching).
    fn i_queue_batch_size(&self) -> usize {
        if self.params.batching {
            self.params.batch_size.max(1)
        } else {
            1
        }
    }

    /// Whether the i-queue (with the nodes of failed multiqueries) holds a full batch. Never
    /// in a mode that issues it once, after the traversal (predicated).
    pub(super) fn i_queue_full(&self) -> bool {
        !self.mode.issues_after_traversal()
            && self.i_queue.len() + self.requery.len() >= self.i_queue_batch_size()
    }

    pub(super) fn flush_render_queue(&mut self, backend: &mut dyn OcclusionBackend) -> Result<()> {
        if !self.render_queue.is_empty() {
            backend.draw_objects(&self.render_queue)?;
            self.render_queue.clear();
        }
        Ok(())
    }

    /// Unbatched (CHC): render what is queued, then issue this node's query on its own.
    pub(super) fn issue_unbatched(
        &mut self,
        bvh: &ObjectBvh,
        node: u32,
        kind: QueryKind,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        self.flush_render_queue(backend)?;
        stats.query_batches += 1;
        self.issue(bvh, &[node], kind, backend, stats)
    }

    /// Issues the i-queue as one batch: render queue first, one switch into query state,
    /// multiqueries grouped by the cost/benefit rule, then submit.
    pub(super) fn issue_i_queue(
        &mut self,
        bvh: &ObjectBvh,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        if self.i_queue.is_empty() && self.requery.is_empty() {
            return Ok(());
        }
        // Issued before the traversal ran dry only once it holds `b` nodes; at the end of the
        // traversal it holds fewer.
        if self.i_queue_full() {
            stats.full_batches += 1;
        }
        self.flush_render_queue(backend)?;
        stats.query_batches += 1;
        // Nodes of failed multiqueries: one query each.
        self.batch.clear();
        self.batch.append(&mut self.requery);
        self.issue_batch_singly(bvh, QueryKind::Invisible, backend, stats)?;
        self.batch.clear();
        self.batch.append(&mut self.i_queue);
        if self.params.multiqueries && self.batch.len() > 1 {
            self.issue_multiqueries(bvh, backend, stats)?;
        } else {
            self.issue_batch_singly(bvh, QueryKind::Invisible, backend, stats)?;
        }
        // Due visible-leaf queries ride along while we are in query state anyway: no extra
        // state change for them.
        self.batch.clear();
        self.batch.append(&mut self.v_queue);
        self.issue_batch_singly(bvh, QueryKind::Visible, backend, stats)?;
        self.issue_probes(bvh, backend, stats)?;
        self.submit(backend)?;
        self.unsubmitted = 0;
        Ok(())
    }

    /// Issues up to `limit` v-queue queries as one batch.
    pub(super) fn issue_v_queue(
        &mut self,
        bvh: &ObjectBvh,
        limit: usize,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        if self.v_queue.is_empty() && self.predicated.probes.is_empty() {
            return Ok(());
        }
        self.flush_render_queue(backend)?;
        stats.query_batches += 1;
        let n = limit.min(self.v_queue.len());
        self.batch.clear();
        self.batch.extend(self.v_queue.drain(..n));
        self.issue_batch_singly(bvh, QueryKind::Visible, backend, stats)?;
        self.issue_probes(bvh, backend, stats)?;
        self.submit(backend)?;
        self.unsubmitted = 0;
        Ok(())
    }

    /// Issues each node of `self.batch` with its own query.
    pub(super) fn issue_batch_singly(
        &mut self,
        bvh: &ObjectBvh,
        kind: QueryKind,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        let batch = std::mem::take(&mut self.batch);
        let result = batch
            .iter()
            .try_for_each(|&n| self.issue(bvh, &[n], kind, backend, stats));
        self.batch = batch;
        result
    }

    /// Issues one query for `nodes` (a multiquery when several) with their boxes.
    pub(super) fn issue(
        &mut self,
        bvh: &ObjectBvh,
        nodes: &[u32],
        kind: QueryKind,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        let mut boxes = std::mem::take(&mut self.boxes);
        boxes.clear();
        for &n in nodes {
            self.query_boxes(bvh, n, &mut boxes);
        }
        let purpose = match kind {
            QueryKind::Visible => QueryPurpose::VisibleLeaf,
            QueryKind::Invisible if nodes.len() > 1 => QueryPurpose::Multiquery,
            QueryKind::Invisible | QueryKind::Probe | QueryKind::Part => QueryPurpose::Node,
        };
        let id = backend.issue_query_for(&boxes, purpose);
        self.boxes = boxes;
        let id = id?;
        stats.queries += 1;
        match kind {
            QueryKind::Invisible => stats.invisible_node_queries += 1,
            QueryKind::Visible => stats.visible_leaf_queries += 1,
            QueryKind::Probe | QueryKind::Part => {}
        }
        if nodes.len() > 1 {
            stats.multiqueries += 1;
        }
        let first = self.query_nodes.len() as u32;
        self.query_nodes.extend_from_slice(nodes);
        self.query_queue.push_back(Pending {
            id,
            first,
            count: nodes.len() as u32,
            kind,
            split: false,
        });
        self.unsubmitted += 1;
        // A query issued alone, between draws (CHC without batching, in a mode that reads
        // results in the frame or the next): back to drawing at once. Queued queries (batching,
        // or the predicated mode, which issues every query after the traversal) go out
        // together, with one switch.
        let interleaved = !self.queues_queries();
        if interleaved {
            backend.restore_render_state()?;
        }
        if interleaved && self.unsubmitted >= self.params.flush_interval {
            self.submit(backend)?;
            self.unsubmitted = 0;
        }
        Ok(())
    }

    /// The traversal queue ran dry: issue the i-queue (unbatched: submit what was recorded).
    /// What every latency mode but the predicated one does.
    pub(super) fn issue_remaining_queries(
        &mut self,
        bvh: &ObjectBvh,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        self.issue_i_queue(bvh, backend, stats)?;
        if !self.params.batching && self.unsubmitted > 0 {
            self.flush_render_queue(backend)?;
            self.submit(backend)?;
            self.unsubmitted = 0;
        }
        Ok(())
    }

    /// Submits recorded work so its queries can complete; a latency mode that reads results
    /// after the frame submits nothing before the frame's end (one submission per frame).
    pub(super) fn submit(&mut self, backend: &mut dyn OcclusionBackend) -> Result<()> {
        if self.mode.reads_in_frame() {
            backend.flush()?;
        }
        Ok(())
    }
}
