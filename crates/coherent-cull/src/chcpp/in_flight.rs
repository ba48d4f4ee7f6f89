//! `k` frames in flight for CHC++'s latency modes: a frame's queries are read `k` frames later,
//! at the start of frame N+k, once the host has waited for frame N (its own frame pacing: the
//! fence of the frame-in-flight slot it is about to reuse). The culler never waits: one
//! submission per frame ([`OcclusionBackend::submit_frame`]), a result not back leaves the
//! node's last known state. `k = 1` is the plain next-frame mode (read right after `finish`).

use std::collections::VecDeque;

use super::{Chcpp, Pending};
use crate::bvh::ObjectBvh;
use crate::error::{Error, Result};
use crate::{CullStats, OcclusionBackend};

/// One frame's queries, kept until they are read.
#[derive(Default)]
struct FrameQueries {
    /// The culler's frame that issued them.
    frame: u64,
    /// The hierarchy's rebuild count then (a rebuild renumbers nodes: the results are dropped).
    rebuilds: u32,
    queries: VecDeque<Pending>,
    nodes: Vec<u32>,
}

/// The frames whose queries are in flight, oldest first, and spare buffers for the next ones,
/// so that steady frames do not allocate.
#[derive(Default)]
pub(super) struct InFlightQueries {
    frames: VecDeque<FrameQueries>,
    spare: Vec<FrameQueries>,
}

impl Chcpp {
    /// The same culler reading a frame's query results `k` frames after issuing them, for a
    /// host with `k` frames in flight (latency modes only; `k` is clamped to 1, the default,
    /// to [`MAX_FRAMES_IN_FLIGHT`](crate::MAX_FRAMES_IN_FLIGHT)). The backend must keep query
    /// results readable that long ([`OcclusionBackend::frames_in_flight`]); objects that come
    /// into view appear `k` frames late.
    pub fn with_frames_in_flight(mut self, k: u32) -> Chcpp {
        self.frames_in_flight = k.clamp(1, crate::MAX_FRAMES_IN_FLIGHT);
        self
    }

    /// `k`: frames between issuing a query and reading it in a latency mode.
    pub fn frames_in_flight(&self) -> u32 {
        self.frames_in_flight
    }

    /// Whether this frame's queries are kept for a later frame rather than read after it.
    pub(super) fn reads_frames_later(&self) -> bool {
        self.frames_in_flight > 1 && !self.mode.reads_in_frame()
    }

    /// Start of a frame (`k > 1`): reads the queries of frame N-k and older. A frame issued
    /// before a rebuild of the hierarchy (new node ids) is dropped.
    pub(super) fn read_frames_in_flight(
        &mut self,
        bvh: &ObjectBvh,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        if !self.reads_frames_later() {
            return Ok(());
        }
        let k = self.frames_in_flight;
        if backend.frames_in_flight() < k {
            return Err(Error::Input(format!(
                "{} reads queries {k} frames late, but the backend keeps them for {} \
                 (OcclusionBackend::frames_in_flight)",
                self.name,
                backend.frames_in_flight()
            )));
        }
        self.prepare(bvh);
        let this_frame = self.frame + 1;
        while let Some(mut f) = self
            .in_flight
            .frames
            .pop_front_if_due(this_frame, u64::from(k))
        {
            let nodes_known = f.nodes.iter().all(|&n| (n as usize) < self.state.len());
            if f.rebuilds == bvh.rebuilds() && nodes_known {
                std::mem::swap(&mut self.query_queue, &mut f.queries);
                std::mem::swap(&mut self.query_nodes, &mut f.nodes);
                let read = self.read_late_results(bvh, backend, stats);
                std::mem::swap(&mut self.query_queue, &mut f.queries);
                std::mem::swap(&mut self.query_nodes, &mut f.nodes);
                read?;
            }
            f.queries.clear();
            f.nodes.clear();
            self.in_flight.spare.push(f);
        }
        self.query_queue.clear();
        self.query_nodes.clear();
        Ok(())
    }

    /// Reads the queries in `query_queue` without waiting (a result not back is dropped).
    fn read_late_results(
        &mut self,
        bvh: &ObjectBvh,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        let eye = self.eye;
        while let Some(q) = self.query_queue.pop_front() {
            if let Some(pixels) = backend.query_result(q.id)? {
                self.handle_returned_query(bvh, q, pixels, eye, backend, stats)?;
            }
        }
        Ok(())
    }

    /// End of a frame (`k > 1`): submits it without waiting and keeps its queries for frame
    /// N+k.
    pub(super) fn submit_frame_in_flight(
        &mut self,
        bvh: &ObjectBvh,
        backend: &mut dyn OcclusionBackend,
    ) -> Result<()> {
        backend.submit_frame()?;
        let mut f = self.in_flight.spare.pop().unwrap_or_default();
        f.frame = self.frame;
        f.rebuilds = bvh.rebuilds();
        std::mem::swap(&mut f.queries, &mut self.query_queue);
        std::mem::swap(&mut f.nodes, &mut self.query_nodes);
        self.in_flight.frames.push_back(f);
        Ok(())
    }

    /// Forgets the queries in flight (a reset: their nodes' state is gone).
    pub(super) fn forget_frames_in_flight(&mut self) {
        while let Some(mut f) = self.in_flight.frames.pop_front() {
            f.queries.clear();
            f.nodes.clear();
            self.in_flight.spare.push(f);
        }
    }
}

/// Pops the oldest frame if it was issued at least `k` frames before `frame`.
trait PopDue {
    fn pop_front_if_due(&mut self, frame: u64, k: u64) -> Option<FrameQueries>;
}

impl PopDue for VecDeque<FrameQueries> {
    fn pop_front_if_due(&mut self, frame: u64, k: u64) -> Option<FrameQueries> {
        if self.front().is_some_and(|f| f.frame + k <= frame) {
            self.pop_front()
        } else {
            None
        }
    }
}
