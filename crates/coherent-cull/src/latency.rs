//! Frames in flight over a backend that completes every frame (the built-in renderer):
//! [`FramesInFlight`] keeps each frame's query results in one of `k` slots and hands them out
//! until the slot is reused `k` frames later, as a host with `k` frames in flight and one query
//! pool per frame does. It lets the latency modes run with `k > 1` on the built-in renderer
//! (tests, `walk`) with the GPU's real results; a host engine implements
//! [`OcclusionBackend::frames_in_flight`] itself (see `examples/engine.rs`).

use super::{CullStats, Culler, FrameInput, OcclusionBackend, QueryId, QueryPurpose};
use crate::error::{Error, Result};
use crate::Aabb;

/// One frame-in-flight slot: the queries its last frame issued and, once that frame has
/// completed, their results.
#[derive(Default)]
struct Slot {
    frame: u64,
    /// The wrapped backend's ids of the slot frame's queries, in issue order.
    inner: Vec<QueryId>,
    /// Their pixel counts, filled when the frame has completed.
    results: Vec<u64>,
    complete: bool,
}

/// A culler run as if the host had `k` frames in flight: query ids stay readable for `k`
/// frames (one slot per frame), and a query of frame N becomes readable in frame N+k, when
/// the host would have waited for frame N's fence. Before that, [`OcclusionBackend::query_result`]
/// says "not ready" (and [`FramesInFlight::early_reads`] counts it).
pub struct FramesInFlight {
    inner: Box<dyn Culler>,
    k: u32,
    frame: u64,
    slots: Vec<Slot>,
    early_reads: u64,
}

impl FramesInFlight {
    /// `inner` run with `k` frames in flight (`k` clamped to 1 to
    /// [`MAX_FRAMES_IN_FLIGHT`](crate::MAX_FRAMES_IN_FLIGHT)).
    pub fn new(inner: Box<dyn Culler>, k: u32) -> FramesInFlight {
        let k = k.clamp(1, crate::MAX_FRAMES_IN_FLIGHT);
        FramesInFlight {
            inner,
            k,
            frame: 0,
            slots: (0..k).map(|_| Slot::default()).collect(),
            early_reads: 0,
        }
    }

    /// Reads of a query before its frame's slot would have been waited for (`k` frames later):
    /// 0 for a culler that keeps the frames-in-flight contract.
    pub fn early_reads(&self) -> u64 {
        self.early_reads
    }
}

impl Culler for FramesInFlight {
    fn name(&self) -> &str {
        self.inner.name()
    }

    fn needs_exact_visibility(&self) -> bool {
        self.inner.needs_exact_visibility()
    }

    fn needs_box_visibility(&self) -> bool {
        self.inner.needs_box_visibility()
    }

    fn reads_tests_after_frame(&self) -> bool {
        // The wrapped culler's tests are read right after the frame (`collect`).
        self.inner.reads_tests_after_frame()
    }

    fn cull_frame(
        &mut self,
        input: &FrameInput,
        backend: &mut dyn OcclusionBackend,
    ) -> Result<CullStats> {
        self.frame += 1;
        let slot = (self.frame % u64::from(self.k)) as usize;
        // The slot's previous frame (N-k) is read by the culler at the start of this frame;
        // its queries are dropped when this frame issues its first one.
        let mut b = SlotBackend {
            inner: backend,
            slots: &mut self.slots,
            slot,
            frame: self.frame,
            k: self.k,
            early_reads: &mut self.early_reads,
            started: false,
            waited: false,
        };
        self.inner.cull_frame(input, &mut b)
    }

    fn reset(&mut self) {
        self.inner.reset();
        for s in &mut self.slots {
            *s = Slot::default();
        }
    }
}

/// The backend a [`FramesInFlight`] culler sees: the real one, with slot-tagged query ids.
struct SlotBackend<'a> {
    inner: &'a mut dyn OcclusionBackend,
    slots: &'a mut [Slot],
    slot: usize,
    frame: u64,
    k: u32,
    early_reads: &'a mut u64,
    /// This frame has taken over its slot.
    started: bool,
    /// This frame was finished with a wait ([`OcclusionBackend::finish`]), so its own
    /// results are readable now.
    waited: bool,
}

impl SlotBackend<'_> {
    /// Id = slot + k · index within the slot's frame.
    fn decode(&self, id: QueryId) -> Result<(usize, usize)> {
        let (slot, index) = ((id % self.k) as usize, (id / self.k) as usize);
        match self.slots.get(slot) {
            Some(s) if index < s.inner.len() => Ok((slot, index)),
            _ => Err(Error::Input(format!(
                "query {id} is not in flight (frames in flight: {})",
                self.k
            ))),
        }
    }

    /// Files the wrapped backend's query `inner` in this frame's slot and returns its id.
    fn slot_query(&mut self, inner: QueryId) -> QueryId {
        let s = &mut self.slots[self.slot];
        if !self.started {
            // The slot is reused: frame N-k's queries are gone (the host would reset them).
            self.started = true;
            s.inner.clear();
            s.results.clear();
            s.complete = false;
            s.frame = self.frame;
        }
        s.inner.push(inner);
        self.slot as u32 + self.k * (s.inner.len() as u32 - 1)
    }

    /// The wrapped backend's id of `query`, a query of this frame (a predicate).
    fn this_frames_query(&self, query: QueryId) -> Result<QueryId> {
        let (slot, index) = self.decode(query)?;
        if slot != self.slot || self.slots[slot].frame != self.frame {
            return Err(Error::Input(format!(
                "query {query} is not a predicate of this frame"
            )));
        }
        Ok(self.slots[slot].inner[index])
    }

    /// Collects this frame's results once it has completed.
    fn collect(&mut self) -> Result<()> {
        let inner_ids = std::mem::take(&mut self.slots[self.slot].inner);
        let mut results = std::mem::take(&mut self.slots[self.slot].results);
        results.clear();
        let mut read = Ok(());
        for &q in &inner_ids {
            match self.inner.query_result(q) {
                Ok(Some(p)) => results.push(p),
                Ok(None) => {
                    read = Err(Error::Input(format!(
                        "query {q} not complete after its frame finished"
                    )));
                    break;
                }
                Err(e) => {
                    read = Err(e);
                    break;
                }
            }
        }
        let s = &mut self.slots[self.slot];
        s.inner = inner_ids;
        s.results = results;
        s.complete = read.is_ok();
        read
    }
}

impl OcclusionBackend for SlotBackend<'_> {
    fn draw_objects(&mut self, objects: &[u32]) -> Result<()> {
        self.inner.draw_objects(objects)
    }

    fn issue_query(&mut self, boxes: &[Aabb]) -> Result<QueryId> {
        self.issue_query_for(boxes, QueryPurpose::Node)
    }

    fn issue_query_for(&mut self, boxes: &[Aabb], purpose: QueryPurpose) -> Result<QueryId> {
        let inner = self.inner.issue_query_for(boxes, purpose)?;
        Ok(self.slot_query(inner))
    }

    fn supports_predicated_queries(&self) -> bool {
        self.inner.supports_predicated_queries()
    }

    fn issue_query_if(
        &mut self,
        predicate: QueryId,
        boxes: &[Aabb],
        purpose: QueryPurpose,
    ) -> Result<QueryId> {
        let predicate = self.this_frames_query(predicate)?;
        let inner = self.inner.issue_query_if(predicate, boxes, purpose)?;
        Ok(self.slot_query(inner))
    }

    fn gathers_predicated_draws(&mut self) -> bool {
        self.inner.gathers_predicated_draws()
    }

    fn test_part_if(&mut self, predicate: QueryId, boxes: &[Aabb]) -> Result<Option<QueryId>> {
        let predicate = self.this_frames_query(predicate)?;
        let inner = self.inner.test_part_if(predicate, boxes)?;
        Ok(inner.map(|id| self.slot_query(id)))
    }

    fn restore_render_state(&mut self) -> Result<()> {
        self.inner.restore_render_state()
    }

    fn flush(&mut self) -> Result<()> {
        self.inner.flush()
    }

    fn query_result(&mut self, query: QueryId) -> Result<Option<u64>> {
        let (slot, index) = self.decode(query)?;
        let s = &self.slots[slot];
        if s.frame == self.frame && self.started && !s.complete {
            // This frame's own query (an in-frame culler): ask the real backend.
            let q = s.inner[index];
            return self.inner.query_result(q);
        }
        let own_and_waited = s.frame == self.frame && self.waited;
        if s.frame + u64::from(self.k) > self.frame && !own_and_waited {
            // Frame N's fence has not been waited for before frame N+k.
            *self.early_reads += 1;
            return Ok(None);
        }
        Ok(s.results.get(index).copied())
    }

    fn wait_query(&mut self, query: QueryId) -> Result<u64> {
        let (slot, index) = self.decode(query)?;
        let s = &self.slots[slot];
        if s.frame == self.frame && self.started && !s.complete {
            let q = s.inner[index];
            return self.inner.wait_query(q);
        }
        s.results
            .get(index)
            .copied()
            .ok_or_else(|| Error::Input(format!("query {query} of an earlier frame has no result")))
    }

    fn finish(&mut self) -> Result<()> {
        self.submit_frame()?;
        self.waited = true;
        Ok(())
    }

    fn frames_in_flight(&self) -> u32 {
        self.k
    }

    fn supports_predicates(&self) -> bool {
        self.inner.supports_predicates()
    }

    fn resolve_predicates(&mut self) -> Result<()> {
        self.inner.resolve_predicates()
    }

    fn draw_objects_if(&mut self, query: QueryId, objects: &[u32]) -> Result<()> {
        let inner = self.this_frames_query(query)?;
        self.inner.draw_objects_if(inner, objects)
    }

    fn set_draw_order(&mut self, order: &[u32]) -> Result<()> {
        self.inner.set_draw_order(order)
    }

    fn draw_order_ranges_if(
        &mut self,
        query: QueryId,
        order: &[u32],
        ranges: &[std::ops::Range<u32>],
    ) -> Result<()> {
        let inner = self.this_frames_query(query)?;
        self.inner.draw_order_ranges_if(inner, order, ranges)
    }

    fn submit_frame(&mut self) -> Result<()> {
        // The wrapped backend completes each frame; the slot hides the results for k frames.
        self.inner.finish()?;
        if self.started {
            self.collect()?;
        }
        Ok(())
    }
}

/// `chc` or `chcpp` in a latency mode reading each frame's queries `k` frames later
/// ([`super::chcpp::Chcpp::with_frames_in_flight`]); `k = 1` is [`super::create_latency`].
/// The backend must keep results for `k` frames: wrap the culler in a [`FramesInFlight`]
/// for the built-in renderer.
pub fn create_with_frames_in_flight(
    name: &str,
    params: &super::ChcppParams,
    latency: super::Latency,
    k: u32,
) -> Result<Box<dyn Culler>> {
    use super::chcpp::Chcpp;
    let culler = match (name, latency) {
        ("chcpp", l) if l != super::Latency::InFrame => Chcpp::new(params.clone()),
        ("chc", l) if l != super::Latency::InFrame => {
            Chcpp::named("chc", super::ChcppParams::chc())
        }
        _ => return super::create_latency(name, params, latency),
    };
    Ok(Box::new(
        culler.with_latency(latency).with_frames_in_flight(k),
    ))
}
