//! A CPU [`OcclusionBackend`] for tests: [`MockBackend`] answers each occlusion query from a
//! visibility function the test supplies (pixels seen by a box), completes results when the test
//! says (at once, at the next submission, or only on a wait), and logs what a culler asked for,
//! so a host can test its integration of a culler, and the algorithms their contract, with no
//! GPU and no Vulkan driver.
//!
//! ```
//! use coherent_cull::camera::{Camera, CameraPose};
//! use coherent_cull::chcpp::{Chcpp, ChcppParams};
//! use coherent_cull::glam::Vec3;
//! use coherent_cull::testing::MockBackend;
//! use coherent_cull::{Aabb, Culler, FrameInput, ObjectBvh};
//!
//! // Four boxes in a row; only the ones left of x = 3 can be seen.
//! let bvh = ObjectBvh::from_boxes((0..4).map(|i| {
//!     let x = 2.0 * i as f32;
//!     [[x, 0.0, -10.0], [x + 1.0, 1.0, -9.0]]
//! }), 1);
//! let mut backend = MockBackend::new(|b: &Aabb| if b.min.x < 3.0 { 100 } else { 0 });
//! let pose = CameraPose { eye: Vec3::new(3.0, 0.5, 5.0), target: Vec3::new(3.0, 0.5, -10.0) };
//! let camera = Camera::from_pose(pose, 1.0, 100.0);
//! let mut culler = Chcpp::new(ChcppParams::default());
//! for frame in 0..3 {
//!     let input = FrameInput { bvh: &bvh, view: (&camera).into(), frame, exact_visible: None };
//!     culler.cull_frame(&input, &mut backend).unwrap();
//!     if frame == 2 {
//!         assert_eq!(backend.drawn_last_frame(), vec![0, 1]);
//!     }
//!     backend.end_frame();
//! }
//! ```

use std::collections::BTreeSet;

use crate::{Aabb, OcclusionBackend, QueryId, QueryPurpose, Result};

/// When the mock's query results become readable through
/// [`OcclusionBackend::query_result`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Completion {
    /// As soon as the query is issued (an infinitely fast device).
    Immediate,
    /// Once the submission holding it went out: a [`OcclusionBackend::flush`],
    /// [`OcclusionBackend::finish`] or [`OcclusionBackend::submit_frame`] (a fast device).
    #[default]
    AfterSubmit,
    /// Only after a [`OcclusionBackend::wait_query`] (which completes everything issued so
    /// far) or the end of the frame: a slow device, where every result is a round trip.
    OnWait,
}

/// One thing a culler asked the mock for, in order: the decision trace of a frame.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum MockEvent {
    /// Objects drawn by one call.
    Draw(Vec<u32>),
    /// A query: its id, purpose, number of boxes and whether it saw pixels.
    Query {
        /// The id handed out.
        id: QueryId,
        /// What the culler said it is for.
        purpose: QueryPurpose,
        /// Boxes drawn inside the query.
        boxes: usize,
        /// The answer the visibility function gave.
        visible: bool,
    },
    /// Back to render state.
    RestoreRenderState,
    /// A submission inside the frame.
    Flush,
    /// A blocking wait for a query.
    Wait(QueryId),
    /// The end of the frame ([`OcclusionBackend::finish`] or
    /// [`OcclusionBackend::submit_frame`]).
    EndOfFrame,
    /// The queries issued so far became predicates ([`OcclusionBackend::resolve_predicates`]).
    Resolve,
    /// A query whose boxes count only if a predicate of this frame is true
    /// ([`OcclusionBackend::issue_query_if`]).
    QueryIf {
        /// The id handed out.
        id: QueryId,
        /// The query whose predicate decides.
        predicate: QueryId,
        /// Boxes drawn inside the query (when the predicate holds).
        boxes: usize,
        /// Whether it saw pixels (false when the predicate was false).
        visible: bool,
    },
    /// A part decided by the backend's own test ([`OcclusionBackend::test_part_if`]; only
    /// with [`MockBackend::with_part_test`]).
    PartTest {
        /// The id handed out.
        id: QueryId,
        /// The query whose predicate decides.
        predicate: QueryId,
        /// Boxes tested.
        boxes: usize,
        /// The answer: the predicate held and a box was visible.
        visible: bool,
    },
    /// Objects drawn under a query's predicate.
    DrawIf {
        /// The query whose predicate decides.
        query: QueryId,
        /// The objects.
        objects: Vec<u32>,
        /// Whether the predicate was true (the objects were drawn).
        taken: bool,
    },
}

/// Counts of one frame, as a recorder on a real device would count them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MockCounts {
    /// Draw calls ([`OcclusionBackend::draw_objects`] calls with at least one object).
    pub draw_calls: u32,
    /// Objects drawn.
    pub objects_drawn: u32,
    /// Queries issued.
    pub queries: u32,
    /// Boxes drawn inside queries.
    pub query_boxes: u32,
    /// Switches between render state and query state (either way).
    pub state_changes: u32,
    /// Submissions: flushes inside the frame plus the end of the frame.
    pub submits: u32,
    /// Blocking waits.
    pub waits: u32,
    /// Predicate resolves (pass breaks on a real device).
    pub resolves: u32,
    /// Draw calls under a predicate.
    pub predicated_draws: u32,
    /// Objects sent in those draws.
    pub predicated_objects: u32,
    /// Of those, objects whose predicate was true (drawn).
    pub predicated_objects_drawn: u32,
    /// Queries issued under a predicate ([`OcclusionBackend::issue_query_if`]).
    pub predicated_queries: u32,
    /// Parts decided by the backend's own test ([`OcclusionBackend::test_part_if`]).
    pub tested_parts: u32,
    /// Draws under a predicate handed over as ranges of the draw order
    /// ([`OcclusionBackend::draw_order_ranges_if`]; also counted in `predicated_draws`).
    pub order_range_draws: u32,
    /// The ranges of those draws.
    pub order_ranges: u32,
}

struct Issued {
    pixels: u64,
    frame: u64,
    /// Readable through `query_result` (completed on the mock device).
    complete: bool,
    /// Usable as a predicate (a resolve came after it in its frame).
    resolved: bool,
}

/// A CPU occlusion backend answering queries from a visibility function (see the module docs).
pub struct MockBackend<'a> {
    visibility: Box<dyn FnMut(&Aabb) -> u64 + 'a>,
    completion: Completion,
    frames_in_flight: u32,
    frame: u64,
    in_query_state: bool,
    queries: Vec<Issued>,
    events: Vec<MockEvent>,
    counts: MockCounts,
    drawn: BTreeSet<u32>,
    early_reads: u64,
    predicates: bool,
    predicated_queries: bool,
    part_test: bool,
    gathering: bool,
    draw_order: Vec<u32>,
    draw_orders: u32,
    query_limit: Option<u32>,
}

impl<'a> MockBackend<'a> {
    /// A backend whose queries see `visibility(box)` pixels for each box drawn inside them
    /// (a query sees the sum over its boxes). Results complete at the next submission, one
    /// frame in flight.
    pub fn new(visibility: impl FnMut(&Aabb) -> u64 + 'a) -> MockBackend<'a> {
        MockBackend {
            visibility: Box::new(visibility),
            completion: Completion::default(),
            frames_in_flight: 1,
            frame: 0,
            in_query_state: false,
            queries: Vec::new(),
            events: Vec::new(),
            counts: MockCounts::default(),
            drawn: BTreeSet::new(),
            early_reads: 0,
            predicates: true,
            predicated_queries: true,
            part_test: false,
            gathering: false,
            draw_order: Vec::new(),
            draw_orders: 0,
            query_limit: None,
        }
    }

    /// A backend without predicated draws (a device without conditional rendering): the
    /// predicated mode must refuse it.
    pub fn without_predicates(mut self) -> MockBackend<'a> {
        self.predicates = false;
        self
    }

    /// A backend with predicated draws but without queries under a predicate: the predicated
    /// mode keeps to one predicate level.
    pub fn without_predicated_queries(mut self) -> MockBackend<'a> {
        self.predicated_queries = false;
        self
    }

    /// A backend that decides the parts of split nodes by a test of its own
    /// ([`OcclusionBackend::test_part_if`]): a part is visible when its predicate holds and
    /// the visibility function gives one of its boxes a pixel; its result is 1 or 0. Without
    /// it (the default) parts are queried.
    pub fn with_part_test(mut self) -> MockBackend<'a> {
        self.part_test = true;
        self
    }

    /// A backend that takes draws under queries of this frame before their resolve
    /// ([`OcclusionBackend::gathers_predicated_draws`]), as the built-in renderer's gathering
    /// does: on the mock a query's value is known when it is issued, so such a draw is
    /// decided at once.
    pub fn with_gathering(mut self) -> MockBackend<'a> {
        self.gathering = true;
        self
    }

    /// A backend where a box sees 100 pixels when it overlaps one of `regions` (closed boxes),
    /// else none.
    pub fn visible_regions(regions: Vec<Aabb>) -> MockBackend<'a> {
        MockBackend::new(move |b: &Aabb| {
            let hit = regions.iter().any(|r| b.overlaps(r));
            if hit {
                100
            } else {
                0
            }
        })
    }

    /// When results become readable (default [`Completion::AfterSubmit`]).
    pub fn with_completion(mut self, completion: Completion) -> MockBackend<'a> {
        self.completion = completion;
        self
    }

    /// Pretends the host has `k` frames in flight (at least 1): query ids stay valid for `k`
    /// frames, and a query of frame N is readable from frame N+k on (as after the host waited
    /// for frame N's fence); reading it earlier answers "not ready" and counts an early read.
    pub fn with_frames_in_flight(mut self, k: u32) -> MockBackend<'a> {
        self.frames_in_flight = k.max(1);
        self
    }

    /// Refuses every query of a frame past `limit` with an [`crate::Error::Input`] ("more
    /// than N queries in a frame"), as a host whose query pools are full does; `None` (the
    /// default): no limit.
    pub fn set_query_limit(&mut self, limit: Option<u32>) {
        self.query_limit = limit;
    }

    /// Replaces the visibility function (the world changed).
    pub fn set_visibility(&mut self, visibility: impl FnMut(&Aabb) -> u64 + 'a) {
        self.visibility = Box::new(visibility);
    }

    /// Starts the next frame: clears the event log, the counts and the drawn set. Call it
    /// after each `cull_frame`.
    pub fn end_frame(&mut self) {
        self.frame += 1;
        self.events.clear();
        self.counts = MockCounts::default();
        self.drawn.clear();
        self.in_query_state = false;
    }

    /// The last draw order a culler set ([`OcclusionBackend::set_draw_order`]; empty if none).
    pub fn draw_order(&self) -> &[u32] {
        &self.draw_order
    }

    /// How many times a culler set the draw order.
    pub fn draw_orders_set(&self) -> u32 {
        self.draw_orders
    }

    /// What the culler asked for since the last [`MockBackend::end_frame`], in order.
    pub fn events(&self) -> &[MockEvent] {
        &self.events
    }

    /// The counts since the last [`MockBackend::end_frame`].
    pub fn counts(&self) -> MockCounts {
        self.counts
    }

    /// Objects drawn since the last [`MockBackend::end_frame`], sorted, each once.
    pub fn drawn_last_frame(&self) -> Vec<u32> {
        self.drawn.iter().copied().collect()
    }

    /// Whether `object` was drawn since the last [`MockBackend::end_frame`].
    pub fn was_drawn(&self, object: u32) -> bool {
        self.drawn.contains(&object)
    }

    /// Reads of a query before its result was readable in the frames-in-flight contract (a
    /// culler that keeps the contract never makes one).
    pub fn early_reads(&self) -> u64 {
        self.early_reads
    }

    /// Records a query of `boxes` (entering query state); it counts the pixels the visibility
    /// function gives them when `drawn`, else none (boxes under a false predicate). Returns its
    /// id and pixels, or the error of a frame past its query limit.
    fn record_query(&mut self, boxes: &[Aabb], drawn: bool) -> Result<(QueryId, u64)> {
        if let Some(limit) = self.query_limit.filter(|&l| self.counts.queries >= l) {
            return Err(crate::Error::Input(format!(
                "more than {limit} queries in a frame"
            )));
        }
        if !self.in_query_state {
            self.in_query_state = true;
            self.counts.state_changes += 1;
        }
        let pixels: u64 = if drawn {
            boxes.iter().map(|b| (self.visibility)(b)).sum()
        } else {
            0
        };
        let id = self.issue(pixels);
        self.counts.queries += 1;
        self.counts.query_boxes += boxes.len() as u32;
        Ok((id, pixels))
    }

    /// A new result of this frame (a query's or a tested part's) seeing `pixels`; its id.
    fn issue(&mut self, pixels: u64) -> QueryId {
        let id = self.queries.len() as QueryId;
        self.queries.push(Issued {
            pixels,
            frame: self.frame,
            complete: self.completion == Completion::Immediate,
            resolved: false,
        });
        id
    }

    /// Query `query` as a predicate: issued in this frame and, unless the draws under it wait
    /// for the resolve (`before_resolve`: a gathering backend), resolved since.
    fn predicate(&self, query: QueryId, before_resolve: bool) -> Result<&Issued> {
        let q = self.issued(query)?;
        if q.frame != self.frame || !(q.resolved || before_resolve) {
            return Err(crate::Error::Input(format!(
                "query {query} is not a resolved predicate of this frame"
            )));
        }
        Ok(q)
    }

    fn complete_all(&mut self) {
        for q in &mut self.queries {
            q.complete = true;
        }
    }

    fn enter_render_state(&mut self) {
        if self.in_query_state {
            self.in_query_state = false;
            self.counts.state_changes += 1;
        }
    }

    fn issued(&self, query: QueryId) -> Result<&Issued> {
        self.queries.get(query as usize).ok_or_else(|| {
            crate::Error::Input(format!("query {query} was never issued on this backend"))
        })
    }

    /// Whether frame `f`'s results are readable now: at once within the frame with one frame in
    /// flight, else `k` frames later.
    fn frame_readable(&self, f: u64) -> bool {
        f == self.frame || f + u64::from(self.frames_in_flight) <= self.frame
    }
}

impl OcclusionBackend for MockBackend<'_> {
    fn draw_objects(&mut self, objects: &[u32]) -> Result<()> {
        if objects.is_empty() {
            return Ok(());
        }
        self.enter_render_state();
        self.counts.draw_calls += 1;
        self.counts.objects_drawn += objects.len() as u32;
        self.drawn.extend(objects.iter().copied());
        self.events.push(MockEvent::Draw(objects.to_vec()));
        Ok(())
    }

    fn issue_query(&mut self, boxes: &[Aabb]) -> Result<QueryId> {
        self.issue_query_for(boxes, QueryPurpose::Node)
    }

    fn issue_query_for(&mut self, boxes: &[Aabb], purpose: QueryPurpose) -> Result<QueryId> {
        let (id, pixels) = self.record_query(boxes, true)?;
        self.events.push(MockEvent::Query {
            id,
            purpose,
            boxes: boxes.len(),
            visible: pixels > 0,
        });
        Ok(id)
    }

    fn restore_render_state(&mut self) -> Result<()> {
        self.enter_render_state();
        self.events.push(MockEvent::RestoreRenderState);
        Ok(())
    }

    fn flush(&mut self) -> Result<()> {
        self.counts.submits += 1;
        self.events.push(MockEvent::Flush);
        if self.completion == Completion::AfterSubmit {
            self.complete_all();
        }
        Ok(())
    }

    fn query_result(&mut self, query: QueryId) -> Result<Option<u64>> {
        let q = self.issued(query)?;
        let (pixels, frame, complete) = (q.pixels, q.frame, q.complete);
        if !self.frame_readable(frame) {
            self.early_reads += 1;
            return Ok(None);
        }
        Ok(complete.then_some(pixels))
    }

    fn wait_query(&mut self, query: QueryId) -> Result<u64> {
        let q = self.issued(query)?;
        let (pixels, frame) = (q.pixels, q.frame);
        if !self.frame_readable(frame) {
            // A host would wait for the frame's fence here: allowed, but it is a wait.
            self.early_reads += 1;
        }
        self.counts.waits += 1;
        self.events.push(MockEvent::Wait(query));
        self.complete_all();
        Ok(pixels)
    }

    fn finish(&mut self) -> Result<()> {
        self.counts.submits += 1;
        self.events.push(MockEvent::EndOfFrame);
        self.complete_all();
        Ok(())
    }

    fn frames_in_flight(&self) -> u32 {
        self.frames_in_flight
    }

    fn submit_frame(&mut self) -> Result<()> {
        self.counts.submits += 1;
        self.events.push(MockEvent::EndOfFrame);
        self.complete_all();
        Ok(())
    }

    fn supports_predicates(&self) -> bool {
        self.predicates
    }

    fn resolve_predicates(&mut self) -> Result<()> {
        if !self.predicates {
            return Err(crate::predicates_unsupported());
        }
        let frame = self.frame;
        for q in self.queries.iter_mut().filter(|q| q.frame == frame) {
            q.resolved = true;
        }
        self.counts.resolves += 1;
        self.events.push(MockEvent::Resolve);
        Ok(())
    }

    fn supports_predicated_queries(&self) -> bool {
        self.predicates && self.predicated_queries
    }

    fn issue_query_if(
        &mut self,
        predicate: QueryId,
        boxes: &[Aabb],
        _purpose: QueryPurpose,
    ) -> Result<QueryId> {
        if !self.supports_predicated_queries() {
            return Err(crate::predicates_unsupported());
        }
        let taken = self.predicate(predicate, false)?.pixels > 0;
        let (id, pixels) = self.record_query(boxes, taken)?;
        let visible = pixels > 0;
        self.counts.predicated_queries += 1;
        self.events.push(MockEvent::QueryIf {
            id,
            predicate,
            boxes: boxes.len(),
            visible,
        });
        Ok(id)
    }

    fn gathers_predicated_draws(&mut self) -> bool {
        self.predicates && self.gathering
    }

    fn test_part_if(&mut self, predicate: QueryId, boxes: &[Aabb]) -> Result<Option<QueryId>> {
        if !self.part_test || !self.supports_predicates() {
            return Ok(None);
        }
        let taken = self.predicate(predicate, false)?.pixels > 0;
        let visible = taken && boxes.iter().any(|b| (self.visibility)(b) > 0);
        let id = self.issue(u64::from(visible));
        // Its objects may be drawn under it before the resolve that tests it (the backend
        // draws them after the test); on the mock the answer is known now.
        self.queries[id as usize].resolved = true;
        self.counts.tested_parts += 1;
        self.events.push(MockEvent::PartTest {
            id,
            predicate,
            boxes: boxes.len(),
            visible,
        });
        Ok(Some(id))
    }

    fn set_draw_order(&mut self, order: &[u32]) -> Result<()> {
        self.draw_order = order.to_vec();
        self.draw_orders += 1;
        Ok(())
    }

    /// Checks that `order` is the draw order set last (the contract), then draws the objects
    /// of `ranges` as [`OcclusionBackend::draw_objects_if`] does.
    fn draw_order_ranges_if(
        &mut self,
        query: QueryId,
        order: &[u32],
        ranges: &[std::ops::Range<u32>],
    ) -> Result<()> {
        if order != self.draw_order.as_slice() {
            return Err(crate::Error::Input(format!(
                "ranges of a draw order of {} objects, not the one set ({} objects)",
                order.len(),
                self.draw_order.len()
            )));
        }
        let mut objects = Vec::with_capacity(crate::ranges_len(ranges));
        crate::extend_order_objects(&mut objects, order, ranges)?;
        self.draw_objects_if(query, &objects)?;
        if !objects.is_empty() {
            self.counts.order_range_draws += 1;
            self.counts.order_ranges += ranges.len() as u32;
        }
        Ok(())
    }

    fn draw_objects_if(&mut self, query: QueryId, objects: &[u32]) -> Result<()> {
        if !self.predicates {
            return Err(crate::predicates_unsupported());
        }
        // A gathering backend keeps the draws until the resolve: any query of this frame.
        let q = self.predicate(query, self.gathering)?;
        if objects.is_empty() {
            return Ok(());
        }
        let taken = q.pixels > 0;
        self.enter_render_state();
        self.counts.draw_calls += 1;
        self.counts.predicated_draws += 1;
        self.counts.predicated_objects += objects.len() as u32;
        if taken {
            self.counts.predicated_objects_drawn += objects.len() as u32;
            self.drawn.extend(objects.iter().copied());
        }
        self.events.push(MockEvent::DrawIf {
            query,
            objects: objects.to_vec(),
            taken,
        });
        Ok(())
    }
}
