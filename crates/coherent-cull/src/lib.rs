//! # coherent-cull
//!
//! Occlusion culling with hardware occlusion queries, as a library without a graphics API:
//! CHC++ (Mattausch, Bittner, Wimmer, "CHC++: Coherent Hierarchical Culling Revisited", 2008)
//! and what it is measured against — view-frustum culling, hierarchical stop-and-wait, CHC
//! (Bittner et al. 2004), NOHC (Guthe et al. 2006), potentially visible sets and an
//! exact-visibility oracle — over a BVH of the scene's objects ([`ObjectBvh`]). One trait for
//! the algorithms ([`Culler`], one file each) and one for the renderer ([`OcclusionBackend`]):
//! the algorithms decide what to draw and which boxes to query, the backend records the draws
//! and queries on the device and reports the queries' pixel counts. No Vulkan, no I/O, no
//! windowing; it depends on glam, mint and thiserror only.
//!
//! # Embedding in an engine
//!
//! A host keeps its own device, frame loop and camera and uses a culler in four steps.
//!
//! 1. **The hierarchy, from plain boxes.** [`ObjectBvh::from_boxes`] over the world boxes of
//!    the objects to cull (object `i` is the host's draw `i`), as `[min, max]` arrays
//!    (`[[f32; 3]; 2]`) or [`Aabb`]s ([`Aabb::from_min_max`] takes any `mint` point). Objects
//!    that move, appear and vanish go through [`ObjectBvh::set_bounds`],
//!    [`ObjectBvh::insert`], [`ObjectBvh::remove`] and [`ObjectBvh::update`] between frames
//!    (see [Moving objects](#moving-objects)).
//! 2. **An [`OcclusionBackend`].** For an ash host, `coherent_ash::QueryBackend` (crate
//!    `coherent-ash`) implements it over the host's command buffers; any other host implements
//!    it over its own:
//!    - [`draw_objects`](OcclusionBackend::draw_objects): draw the objects in the main depth
//!      pass with the opaque pipeline (depth test and write on);
//!    - [`issue_query_for`](OcclusionBackend::issue_query_for): in the same pass, with depth
//!      test on and depth and color writes off, begin a precise occlusion query, draw the
//!      boxes, end it; [`restore_render_state`](OcclusionBackend::restore_render_state)
//!      rebinds the opaque pipeline;
//!    - [`flush`](OcclusionBackend::flush): submit what was recorded, so its queries can
//!      complete (in-frame mode: end the pass, submit, go on in a new pass that loads color
//!      and depth);
//!    - [`query_result`](OcclusionBackend::query_result) never blocks;
//!      [`wait_query`](OcclusionBackend::wait_query) does (that is stall time);
//!      [`finish`](OcclusionBackend::finish) submits the rest of the frame and waits for it;
//!    - with `k` frames in flight, [`frames_in_flight`](OcclusionBackend::frames_in_flight)
//!      returns `k`, query results stay readable for `k` frames (one query pool per
//!      frame-in-flight slot) and [`submit_frame`](OcclusionBackend::submit_frame) ends a
//!      frame without waiting.
//!
//!    [`testing::MockBackend`] implements it on the CPU from a visibility function, for tests.
//! 3. **A [`CameraView`] each frame:** the world-to-clip matrix, the eye and the
//!    [`DepthConvention`], as plain arrays or `mint` types ([`CameraView::new`]); perspective,
//!    reverse-Z, infinite far, off-axis, jittered and orthographic projections all work. With
//!    the hierarchy and the frame number it makes the [`FrameInput`] of
//!    [`Culler::cull_frame`], which records the frame's draws and queries through the backend.
//! 4. **A [`Latency`] mode** (CHC and CHC++): [`Latency::InFrame`] is exact — a previously
//!    invisible node whose query says visible is drawn in the same frame — at the price of
//!    several submissions and waits inside the frame; [`Latency::NextFrame`] submits once per
//!    frame and never waits, and an object that comes into view appears a frame late;
//!    [`Latency::NextFrameConservative`] also draws nodes without a recent result (they just
//!    entered the frustum), popping less for more draws. With `k` frames in flight
//!    ([`chcpp::Chcpp::with_frames_in_flight`]) results are read `k` frames late.
//!
//! Algorithms by name: [`create`], [`create_with`] (NOHC needs a [`CostModel`], PVS a [`Pvs`],
//! both in a [`CullerSetup`]) and [`create_named`] (`chcpp@next-frame-k2`); [`ALGORITHMS`]
//! lists the names.
//!
//! ```
//! use coherent_cull::camera::{look_to_rh, perspective_infinite_reverse_rh};
//! use coherent_cull::chcpp::{Chcpp, ChcppParams};
//! use coherent_cull::glam::Vec3;
//! use coherent_cull::testing::MockBackend;
//! use coherent_cull::{Aabb, CameraView, Culler, DepthConvention, FrameInput, Latency, ObjectBvh};
//!
//! // 1. The hierarchy from plain boxes: ten crates down a street, 4 m apart.
//! let crates = (0..10).map(|i| {
//!     let z = -4.0 * i as f32 - 5.0;
//!     [[-1.0, 0.0, z - 1.0], [1.0, 2.0, z]]
//! });
//! let mut bvh = ObjectBvh::from_boxes(crates, 1);
//!
//! // 2. The backend: here the CPU mock, where a wall 20 m ahead hides whatever is behind it.
//! let mut backend = MockBackend::new(|b: &Aabb| if b.max.z > -20.0 { 100 } else { 0 });
//!
//! // 3. The camera from the host's own matrices (reverse-Z, infinite far plane).
//! let eye = Vec3::new(0.0, 1.0, 0.0);
//! let view_proj = perspective_infinite_reverse_rh(1.0, 16.0 / 9.0, 0.1)
//!     * look_to_rh(eye, Vec3::NEG_Z, Vec3::Y);
//! let camera = CameraView::new(
//!     view_proj.to_cols_array_2d(),
//!     eye.to_array(),
//!     DepthConvention::REVERSE_Z_INFINITE,
//! );
//!
//! // 4. The mode: in-frame, exact.
//! let mut culler = Chcpp::new(ChcppParams::default()).with_latency(Latency::InFrame);
//! let mut frame = 0;
//! let mut cull = |bvh: &ObjectBvh, backend: &mut MockBackend| {
//!     frame += 1;
//!     let input = FrameInput { bvh, view: camera, frame, exact_visible: None };
//!     culler.cull_frame(&input, backend)
//! };
//! for _ in 0..3 {
//!     let stats = cull(&bvh, &mut backend)?;
//!     assert_eq!(backend.drawn_last_frame(), [0, 1, 2, 3]); // the crates before the wall
//!     assert_eq!(stats.objects_drawn, 4);
//!     backend.end_frame();
//! }
//!
//! // The last crate is carried in front of the wall: drawn in the very next frame.
//! bvh.set_bounds(9, [[2.0, 0.0, -12.0], [3.0, 1.0, -11.0]])?;
//! bvh.update();
//! cull(&bvh, &mut backend)?;
//! assert_eq!(backend.drawn_last_frame(), [0, 1, 2, 3, 9]);
//! # Ok::<(), coherent_cull::Error>(())
//! ```
//!
//! # Moving objects
//!
//! The hierarchy ([`ObjectBvh`]) follows the scene: between frames a host moves, inserts and
//! removes objects and calls [`ObjectBvh::update`], which refits the boxes of what changed (or
//! rebuilds a degraded tree). The next `cull_frame` sees the new boxes. The rules that keep
//! temporal culling exact with motion, in the terms of ALGORITHMS.md:
//!
//! 1. *Every test uses the current boxes.* Frustum tests, queries and tight bounding volumes
//!    read the refitted node boxes of this frame (CHC++'s tight volumes are stored as descendant
//!    node ids, not as boxes), so an object that was invisible and moved into view is covered by
//!    the box the next query tests.
//! 2. *Nothing is assumed invisible without a query of its current box.* CHC and CHC++ satisfy
//!    this by construction: a node invisible last frame is always queried before it may be
//!    culled; only *visibility* is carried across frames (a previously visible node is opened
//!    and drawn without waiting), and assuming visible is never wrong, only slower. An algorithm
//!    that skips queries for nodes it believes invisible (a query interval for invisible nodes,
//!    a precomputed set) must re-test a node whose box changed since its last test:
//!    [`ObjectBvh::changed_since`]`(node, epoch_of_last_test)`; one that cannot know where
//!    movers are (a PVS) draws them frustum-culled only.
//! 3. *What was learnt about a node whose box grew is not known.* A node whose box grew beyond
//!    its box at the last visit ([`ObjectBvh::grown_since`]) covers space it was never tested
//!    in: CHC++ gives it no invisibility history (`k = 0`), so it is not grouped into a
//!    multiquery that would likely fail. Its visibility flag is kept (rule 2: harmless).
//! 4. *Node state survives refits* (node ids are stable); nodes added by an insert start
//!    unknown (not visible: queried); after a full rebuild (new node ids) a leaf counts as
//!    visible last frame if one of its objects was drawn then, and that pulls up.
//!
//! Stateless algorithms (vfc, stop-and-wait, the oracle) are exact with motion as they are: they
//! test this frame's boxes. To make another algorithm mover-aware: keep per node the
//! [`ObjectBvh::epoch`] of its last test, apply rule 2 with `changed_since` wherever it would
//! skip a test, and refit its per-node caches when [`ObjectBvh::structure`] changes.
//!
//! # Objects that hide nothing
//!
//! Every algorithm assumes that what it draws writes depth: the boxes it queries next are
//! tested against it. Translucent (blended) surfaces write none, and objects without bounds (a
//! sky, an endless ground) have no box to test. Keep them out of the hierarchy with
//! [`ObjectBvh::build_where`] (their ids stay reserved: [`ObjectBvh::insert`] never hands them
//! out) and draw them yourself after `cull_frame`: the blended ones back to front, depth tested
//! against what the culler drew. The built-in renderer of the `coherent` package does so with
//! glTF BLEND materials, and tests the heavy ones with occlusion queries of their boxes
//! against the depth the culled pass left (one resolve, a predicate each) before drawing them.

#![deny(missing_docs)]

pub mod aabb;
pub mod bvh;
pub mod camera;
pub mod chc;
pub mod chcpp;
pub mod error;
pub mod latency;
pub mod nohc;
pub mod oracle;
pub mod order;
pub mod pvs;
pub mod rng;
pub mod stop_and_wait;
pub mod testing;
pub mod vfc;

use glam::Vec3;

pub use aabb::Aabb;
pub use bvh::ObjectBvh;
pub use camera::{CameraView, DepthConvention, Frustum, PixelGrid};
pub use error::{Error, Result};
/// The glam version this crate's math types use (hosts need not use glam: every input also
/// takes plain arrays or `mint` types).
pub use glam;

pub use chcpp::ChcppParams;

/// The README's example, compiled and run as a doc test.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
struct ReadmeExample;
pub use nohc::{CostModel, NohcParams};
pub use order::SubtreeOrder;
pub use pvs::Pvs;

/// An occlusion query handed out by the backend, valid within one frame.
pub type QueryId = u32;

/// What a query is for, so that a backend can count and show queries by purpose.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum QueryPurpose {
    /// One node whose result decides traversal in this frame (a previously invisible node,
    /// or any node of stop-and-wait). Its boxes may be a tight bounding volume.
    Node,
    /// Several previously invisible nodes in one query (a CHC++ multiquery).
    Multiquery,
    /// A previously visible leaf, tested for the next frame (the v-queue).
    VisibleLeaf,
}

/// What a culling algorithm needs from a renderer: the embedding API. A host engine implements
/// this over its own device and command buffers.
pub trait OcclusionBackend {
    /// Record draws of these objects (render state, depth test and write on).
    fn draw_objects(&mut self, objects: &[u32]) -> Result<()>;
    /// Record one occlusion query covering all `boxes` (query state: depth test on, no writes).
    fn issue_query(&mut self, boxes: &[Aabb]) -> Result<QueryId>;
    /// [`OcclusionBackend::issue_query`] saying what the query is for. Default: the same
    /// query; backends that count or draw queries by purpose override it.
    fn issue_query_for(&mut self, boxes: &[Aabb], purpose: QueryPurpose) -> Result<QueryId> {
        let _ = purpose;
        self.issue_query(boxes)
    }
    /// Go back to render state after a query (an unbatched culler does this after every query,
    /// as the original CHC toggles write masks around each one). Default: nothing.
    fn restore_render_state(&mut self) -> Result<()> {
        Ok(())
    }
    /// Submit everything recorded so far, so its queries can complete.
    fn flush(&mut self) -> Result<()>;
    /// The query's pixel count if it is ready, without waiting; `None` if not (yet).
    fn query_result(&mut self, query: QueryId) -> Result<Option<u64>>;
    /// Waits for the query's pixel count (flushing first if needed); the wait is stall time.
    fn wait_query(&mut self, query: QueryId) -> Result<u64>;
    /// Submits what is left and waits until the frame's work has completed on the device.
    fn finish(&mut self) -> Result<()>;
    /// How many frames a query stays readable after the frame that issued it: a host with `k`
    /// frames in flight keeps one query pool (or range) per frame-in-flight slot, hands out
    /// ids that name the slot, and resets a slot's queries only after the culler's
    /// `cull_frame` that reuses the slot has started (with `vkCmdResetQueryPool` recorded in
    /// that frame, or a host reset after `cull_frame`). Default 1: ids are valid within one
    /// frame. A culler reading `k` frames late checks this.
    fn frames_in_flight(&self) -> u32 {
        1
    }
    /// Submits what is left of the frame without waiting for it (a host with frames in
    /// flight, which waits for frame N's fence before it records frame N+k). Default:
    /// [`OcclusionBackend::finish`].
    fn submit_frame(&mut self) -> Result<()> {
        self.finish()
    }
    /// Whether the backend can draw under a query's predicate on the device
    /// ([`OcclusionBackend::resolve_predicates`], [`OcclusionBackend::draw_objects_if`]), which
    /// [`Latency::Predicated`] needs. Default: no.
    fn supports_predicates(&self) -> bool {
        false
    }
    /// Makes the pixel counts of every query issued so far in this frame usable as predicates
    /// of [`OcclusionBackend::draw_objects_if`], on the device and without a CPU wait. On
    /// Vulkan with `VK_EXT_conditional_rendering`: end rendering, copy the results
    /// (`vkCmdCopyQueryPoolResults`, 32-bit, `WAIT`) into the predicate buffer, a barrier from
    /// the copy to `CONDITIONAL_RENDERING_READ`, and resume rendering with LOAD ops: a pass
    /// break, not a submission. Default: refuses with [`Error::Unsupported`].
    fn resolve_predicates(&mut self) -> Result<()> {
        Err(predicates_unsupported())
    }
    /// Records draws of `objects` (render state, as [`OcclusionBackend::draw_objects`]) that
    /// the device executes only if `query` counted at least one sample; `query` was issued in
    /// this frame before the last [`OcclusionBackend::resolve_predicates`], or is a part that
    /// [`OcclusionBackend::test_part_if`] took (drawn after its test). Default: refuses with
    /// [`Error::Unsupported`].
    fn draw_objects_if(&mut self, query: QueryId, objects: &[u32]) -> Result<()> {
        let _ = (query, objects);
        Err(predicates_unsupported())
    }
    /// The order in which the predicated mode hands over objects: every object of the
    /// hierarchy, the objects of every subtree contiguous ([`SubtreeOrder`]). A backend may
    /// keep one draw command per object in this order and draw a run of `objects` that is a
    /// run of the order with one command range; `objects` of later calls may still come in
    /// any order. Called before the frame's first conditional draw whenever the hierarchy's
    /// leaves changed. Default: ignored.
    fn set_draw_order(&mut self, order: &[u32]) -> Result<()> {
        let _ = order;
        Ok(())
    }
    /// [`OcclusionBackend::draw_objects_if`] for the objects `order[r]` of each range `r` of
    /// `ranges`, in that order: `order` is the draw order last given to
    /// [`OcclusionBackend::set_draw_order`], passed again so that a backend can ignore the
    /// ranges. The predicated mode hands over whole subtrees this way (a subtree is one range
    /// of the order, adjacent ranges merged), so a backend that keeps one draw command per
    /// object in the order records a range as one multi-draw without looking at its objects:
    /// at the city's x16 scale that is about 100,000 objects a frame under predicates.
    /// Ranges past the end of `order` are refused with [`Error::Input`]. Default: the objects
    /// gathered into one list for [`OcclusionBackend::draw_objects_if`].
    fn draw_order_ranges_if(
        &mut self,
        query: QueryId,
        order: &[u32],
        ranges: &[std::ops::Range<u32>],
    ) -> Result<()> {
        let mut objects = Vec::with_capacity(ranges_len(ranges));
        extend_order_objects(&mut objects, order, ranges)?;
        self.draw_objects_if(query, &objects)
    }
    /// Whether draws under a query of this frame that is not resolved yet may be handed over
    /// ([`OcclusionBackend::draw_order_ranges_if`], with the draw order set): the backend
    /// keeps them and draws them after the next [`OcclusionBackend::resolve_predicates`],
    /// where their predicates are known (the built-in renderer gathers the passed ones on
    /// the device into one indirect draw, with no conditional block per query). The
    /// predicated mode then hands a frame's draws over before its one resolve when it splits
    /// no node (one predicate level). Default: no.
    fn gathers_predicated_draws(&mut self) -> bool {
        false
    }
    /// Whether the backend can issue a query under another query's predicate
    /// ([`OcclusionBackend::issue_query_if`]): the predicated mode then tests the parts of a
    /// queried node in the same frame, behind a second predicate resolve, instead of drawing
    /// the whole node under one predicate. Default: no (one predicate level).
    fn supports_predicated_queries(&self) -> bool {
        false
    }
    /// Issues an occlusion query for `boxes` (as [`OcclusionBackend::issue_query_for`]) whose
    /// boxes the device draws only if `predicate` counted at least one sample: when it did not,
    /// the new query counts 0. `predicate` was issued in this frame before the last
    /// [`OcclusionBackend::resolve_predicates`]. On Vulkan: the box draws inside a conditional
    /// block on the predicate (begin and end of a query are not affected by a predicate, the
    /// draws are). Default: refuses with [`Error::Unsupported`].
    fn issue_query_if(
        &mut self,
        predicate: QueryId,
        boxes: &[Aabb],
        purpose: QueryPurpose,
    ) -> Result<QueryId> {
        let _ = (predicate, boxes, purpose);
        Err(predicates_unsupported())
    }
    /// A part of a split node (predicated mode) decided by the backend's own test instead of
    /// a query: as [`OcclusionBackend::issue_query_if`], the returned id's predicate (and its
    /// result, read later like a query's) is non-zero only if `predicate` counted a sample and
    /// `boxes` may be visible against the depth drawn so far; the test may be coarser than a
    /// query (more parts drawn) but must never fail a box that owns a pixel. It is decided at
    /// the next [`OcclusionBackend::resolve_predicates`]; its result is 1 or 0, not a pixel
    /// count. The part's objects may be handed to [`OcclusionBackend::draw_order_ranges_if`]
    /// or [`OcclusionBackend::draw_objects_if`] under the returned id before that resolve: a
    /// backend that offers the test draws them after it, where the predicate is known (so it
    /// may gather the draws of many parts into one). `Ok(None)`: no such test now (the part
    /// is then queried). Default: `Ok(None)`.
    fn test_part_if(&mut self, predicate: QueryId, boxes: &[Aabb]) -> Result<Option<QueryId>> {
        let _ = (predicate, boxes);
        Ok(None)
    }
}

/// How many objects `ranges` of a draw order hold
/// ([`OcclusionBackend::draw_order_ranges_if`]).
pub fn ranges_len(ranges: &[std::ops::Range<u32>]) -> usize {
    ranges.iter().map(|r| r.len()).sum()
}

/// The objects `order[range]`, or [`Error::Input`] when the range does not lie in `order`.
pub fn order_slice<'a>(order: &'a [u32], range: &std::ops::Range<u32>) -> Result<&'a [u32]> {
    order
        .get(range.start as usize..range.end as usize)
        .ok_or_else(|| {
            Error::Input(format!(
                "draw order range {}..{} outside the order of {} objects",
                range.start,
                range.end,
                order.len()
            ))
        })
}

/// How many objects `ranges` of `order` hold, or [`Error::Input`] when one of them does not lie
/// in `order` ([`OcclusionBackend::draw_order_ranges_if`]).
pub fn order_ranges_len(order: &[u32], ranges: &[std::ops::Range<u32>]) -> Result<usize> {
    for r in ranges {
        order_slice(order, r)?;
    }
    Ok(ranges_len(ranges))
}

/// Appends the objects `order[r]` of each range `r` of `ranges` to `out`, or fails with
/// [`Error::Input`] (appending nothing more) at a range that does not lie in `order`.
pub fn extend_order_objects(
    out: &mut Vec<u32>,
    order: &[u32],
    ranges: &[std::ops::Range<u32>],
) -> Result<()> {
    for r in ranges {
        out.extend_from_slice(order_slice(order, r)?);
    }
    Ok(())
}

/// The error of a backend without predicated draws.
pub fn predicates_unsupported() -> Error {
    Error::Unsupported {
        feature: "predicated draws (VK_EXT_conditional_rendering: the predicated latency mode)"
            .into(),
    }
}

/// Per-frame input of a culler.
pub struct FrameInput<'a> {
    /// The object hierarchy.
    pub bvh: &'a ObjectBvh,
    /// The camera: view-projection matrix, eye and depth convention (`(&camera).into()` for
    /// the built-in [`crate::camera::Camera`]). A matrix with a NaN entry (a window of size
    /// zero, say) is no error: its frustum holds nothing, so the cullers that test it draw
    /// nothing, as rendering with it would show nothing (the oracles draw the set they are
    /// given), and the next frame with a good view is exact again.
    pub view: CameraView,
    /// Frame number (for temporal state).
    pub frame: u64,
    /// The exact visible set (only for cullers whose [`Culler::needs_exact_visibility`]);
    /// for a culler whose [`Culler::needs_box_visibility`], the objects whose own bounding
    /// box shows against the exact depth.
    pub exact_visible: Option<&'a [u32]>,
}

/// Most frames in flight a latency mode takes (`-kN`, [`chcpp::Chcpp::with_frames_in_flight`],
/// [`latency::FramesInFlight`]); hosts keep two or three.
pub const MAX_FRAMES_IN_FLIGHT: u32 = 16;

/// When a CHC-family culler reads its occlusion query results.
///
/// - `InFrame` (default): exact. A frame is a chain of submissions; a previously invisible
///   node is traversed in the same frame once its query says visible, so nothing visible is
///   missing. Costs round trips (submits) and waits (stalls) inside the frame.
/// - `NextFrame`: every query is issued in frame N and read after it, for frame N+1: one
///   submission per frame and no waits. Nodes use their last known visibility; an object that
///   becomes visible appears one frame late (the pop). A result that is not back when read
///   leaves the node's last known state. With `k` frames in flight
///   ([`chcpp::Chcpp::with_frames_in_flight`], default `k = 1`) frame N's queries are read at
///   the start of frame N+k (the backend keeps one query pool per frame in flight,
///   [`OcclusionBackend::frames_in_flight`], and ends frames with
///   [`OcclusionBackend::submit_frame`], no wait); objects appear `k` frames late.
/// - `NextFrameConservative`: as `NextFrame`, but a node whose last known state is older than
///   `k` frames (no result read for it in the last frame: it entered the frustum, or its
///   parent was just opened) is drawn rather than assumed invisible: fewer pops, more draws.
/// - `Predicated`: exact with one submission per frame and no waits. Queries are read `k`
///   frames late as in `NextFrame` to update the hierarchy, but a previously invisible node is
///   not assumed invisible: its query is issued after the frame's unconditional draws, and its
///   objects are drawn under the query's predicate on the device
///   ([`OcclusionBackend::draw_objects_if`]). Needs a backend with predicates
///   ([`OcclusionBackend::supports_predicates`]); see [`chcpp`] for the argument.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Latency {
    /// Exact, segments within the frame.
    #[default]
    InFrame,
    /// Results read one frame late.
    NextFrame,
    /// Results read one frame late; nodes without a recent result are drawn.
    NextFrameConservative,
    /// Exact with one submission: previously invisible nodes drawn under their query's
    /// predicate on the device.
    Predicated,
}

impl Latency {
    /// Every mode, in the order reports list them.
    pub const ALL: [Latency; 4] = [
        Latency::InFrame,
        Latency::NextFrame,
        Latency::NextFrameConservative,
        Latency::Predicated,
    ];
    /// The command-line name: `in-frame`, `next-frame`, `next-frame-conservative`,
    /// `predicated`.
    pub fn name(self) -> &'static str {
        match self {
            Latency::InFrame => "in-frame",
            Latency::NextFrame => "next-frame",
            Latency::NextFrameConservative => "next-frame-conservative",
            Latency::Predicated => "predicated",
        }
    }
    /// Parses a command-line name (a `-kN` suffix, see [`Latency::parse_in_flight`], is
    /// accepted and dropped).
    pub fn parse(name: &str) -> Result<Latency> {
        Latency::parse_in_flight(name).map(|(latency, _)| latency)
    }
    /// Parses a command-line name with an optional `-kN` suffix for `N` frames in flight
    /// (`next-frame-k2`; default 1, at most [`MAX_FRAMES_IN_FLIGHT`]; in-frame only with 1).
    pub fn parse_in_flight(name: &str) -> Result<(Latency, u32)> {
        let (base, k) = match name.rsplit_once("-k").map(|(b, k)| (b, k.parse::<u32>())) {
            Some((base, Ok(k))) => (base, k),
            _ => (name, 1),
        };
        let latency = Latency::parse_base(base)?;
        if k == 0 || k > MAX_FRAMES_IN_FLIGHT || (latency == Latency::InFrame && k != 1) {
            return Err(Error::Input(format!(
                "latency \"{name}\": frames in flight must be 1 to {MAX_FRAMES_IN_FLIGHT}, \
                 and 1 in-frame"
            )));
        }
        Ok((latency, k))
    }
    fn parse_base(name: &str) -> Result<Latency> {
        Latency::ALL
            .into_iter()
            .find(|l| l.name() == name)
            .ok_or_else(|| {
                Error::Input(format!(
                    "unknown latency \"{name}\" (known: in-frame, next-frame, next-frame-conservative, predicated)"
                ))
            })
    }
    /// The report name of `algorithm` in this mode: the plain name in-frame, else
    /// `ALGORITHM@MODE`.
    pub fn report_name(self, algorithm: &str) -> String {
        match self {
            Latency::InFrame => algorithm.to_string(),
            other => format!("{algorithm}@{}", other.name()),
        }
    }
}

/// Creates `chc` or `chcpp` reading its queries in `latency` mode; every other algorithm only
/// in-frame (`nohc`, which has the modes too, needs its cost model: [`create_named`]).
pub fn create_latency(
    name: &str,
    params: &ChcppParams,
    latency: Latency,
) -> Result<Box<dyn Culler>> {
    match (name, latency) {
        (_, Latency::InFrame) => create(name, params),
        ("chcpp", l) => Ok(Box::new(chcpp::Chcpp::new(params.clone()).with_latency(l))),
        ("chc", l) => Ok(Box::new(
            chcpp::Chcpp::named("chc", ChcppParams::chc()).with_latency(l),
        )),
        ("nohc", l) => Err(Error::Input(format!(
            "nohc@{} needs a device cost model: create it with create_named and a CullerSetup \
             whose nohc is set",
            l.name()
        ))),
        (other, l) => Err(Error::Input(format!(
            "{other} has no latency mode {} (only chc, chcpp and nohc)",
            l.name()
        ))),
    }
}

/// `algorithms` with `chc`, `chcpp` and `nohc` expanded to one report name per latency mode
/// in `modes` ([`Latency::report_name`]); the others once, in-frame.
pub fn with_latencies(algorithms: &[String], modes: &[Latency]) -> Vec<String> {
    let mut out = Vec::new();
    for a in algorithms {
        if has_latency_modes(a) {
            out.extend(modes.iter().map(|m| m.report_name(a)));
        } else {
            out.push(a.clone());
        }
    }
    out
}

/// Creates an algorithm by report name: `ALGORITHM@MODE` (`chcpp@next-frame`) in a latency
/// mode, `ALGORITHM@MODE-kN` with `N` frames in flight (on the built-in renderer through
/// [`latency::FramesInFlight`]), else as [`create_with`]. `nohc@MODE` takes its cost model
/// from `setup`.
pub fn create_named(name: &str, setup: &CullerSetup) -> Result<Box<dyn Culler>> {
    match name.split_once('@') {
        Some(("nohc", mode)) => match Latency::parse_in_flight(mode)? {
            (Latency::InFrame, _) => create_with("nohc", setup),
            (l, 1) => Ok(Box::new(nohc_with(setup)?.with_latency(l))),
            (l, k) => Ok(Box::new(latency::FramesInFlight::new(
                Box::new(nohc_with(setup)?.with_latency(l).with_frames_in_flight(k)),
                k,
            ))),
        },
        Some((alg, mode)) => match Latency::parse_in_flight(mode)? {
            (l, 1) => create_latency(alg, &setup.params, l),
            (l, k) => Ok(Box::new(latency::FramesInFlight::new(
                latency::create_with_frames_in_flight(alg, &setup.params, l, k)?,
                k,
            ))),
        },
        None => create_with(name, setup),
    }
}

/// Whether `name` has the latency modes ([`with_latencies`]): chc, chcpp and nohc.
pub fn has_latency_modes(name: &str) -> bool {
    matches!(name, "chc" | "chcpp" | "nohc")
}

/// [`with_latencies`] from command-line names, which may carry a `-kN` suffix for `N` frames
/// in flight (`next-frame-k2`, reported as `chcpp@next-frame-k2`).
pub fn with_latency_names(algorithms: &[String], modes: &[String]) -> Result<Vec<String>> {
    let mut out = Vec::new();
    for a in algorithms {
        if has_latency_modes(a) {
            for m in modes {
                let (l, k) = Latency::parse_in_flight(m)?;
                out.push(match k {
                    1 => l.report_name(a),
                    k => format!("{a}@{}-k{k}", l.name()),
                });
            }
        } else {
            out.push(a.clone());
        }
    }
    Ok(out)
}

/// What an algorithm did in a frame, from its own bookkeeping (the recorder's counts are the
/// authority on queries and draws; tests cross-check these against them).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CullStats {
    /// Nodes visited.
    pub nodes_visited: u32,
    /// Objects sent to the backend for drawing unconditionally (draws under a predicate are
    /// `predicated_objects`).
    pub objects_drawn: u32,
    /// Queries issued in all.
    pub queries: u32,
    /// Queries for nodes that were invisible last frame (the i-queue), multiqueries included.
    pub invisible_node_queries: u32,
    /// Nodes that were invisible last frame and were tested this frame (put in the i-queue when
    /// batching), each counted once: the re-queries after a failed multiquery are `requeried`.
    pub invisible_nodes_tested: u32,
    /// Queries for previously visible leaves (the v-queue).
    pub visible_leaf_queries: u32,
    /// Multiqueries (queries covering more than one node).
    pub multiqueries: u32,
    /// Multiqueries that came back visible (their nodes were re-queried).
    pub failed_multiqueries: u32,
    /// Query results that said visible.
    pub visible_results: u32,
    /// Query batches (switches into query state by the algorithm).
    pub query_batches: u32,
    /// Of those, i-queue batches issued because the i-queue reached its batch size `b` (the
    /// others went out when the traversal queue ran dry, or carried only v-queue leaves).
    pub full_batches: u32,
    /// Nodes queried one by one because the multiquery that held them came back visible.
    pub requeried: u32,
    /// Predicate resolves (pass breaks) in the predicated mode.
    pub predicate_resolves: u32,
    /// Draw calls recorded under a query's predicate (conditional blocks).
    pub predicated_draws: u32,
    /// Objects sent in those draws (the device draws those whose predicate is true).
    pub predicated_objects: u32,
    /// Queries issued under another query's predicate (the predicated mode's second level:
    /// the parts of a node whose own query decides whether their boxes are drawn).
    pub predicated_queries: u32,
    /// Times the traversal had nothing left to do and blocked on a query result inside the
    /// frame: each is a round trip to the device (reading the results after the frame is not
    /// counted).
    pub blocking_waits: u32,
    /// Nodes culled by the frustum.
    pub frustum_culled: u32,
    /// Nodes culled by a query result.
    pub query_culled: u32,
}

/// A culling algorithm with its temporal state. Every culler is `Send`, so one made by name
/// ([`create_named`]) can move to the thread that records the host's frames.
pub trait Culler: Send {
    /// Name used on the command line and in reports.
    fn name(&self) -> &str;
    /// Whether the renderer must compute the exact visible set before the frame (oracle).
    fn needs_exact_visibility(&self) -> bool {
        false
    }
    /// Whether [`FrameInput::exact_visible`] should instead hold the objects whose own
    /// bounding box shows against the exact depth (the box oracle, `oracle-box`): what an
    /// ideal culler that tests boxes would draw.
    fn needs_box_visibility(&self) -> bool {
        false
    }
    /// Whether this culler never reads a box test inside the frame that issued it, nor waits
    /// for one: it reads them after the frame's [`OcclusionBackend::finish`] in the same call,
    /// or (`k` frames in flight) `k` frames later, through a backend that keeps them that long
    /// ([`OcclusionBackend::frames_in_flight`]; [`latency::FramesInFlight`] reads them right after the
    /// frame and keeps them). The predicated mode. A backend may then answer such tests in
    /// any way that is readable after the frame (the built-in renderer draws them all as
    /// flags, one instanced draw at each predicate resolve, instead of one occlusion query
    /// each). Default: no.
    fn reads_tests_after_frame(&self) -> bool {
        false
    }
    /// Decides visibility and records draws and queries through `backend`; must read back every
    /// query it issued before returning (after [`OcclusionBackend::finish`] if need be).
    ///
    /// An error from the backend (a query refused for want of room, say) ends the frame early:
    /// what was recorded is incomplete, so the host drops or finishes it as after any failed
    /// recording. The culler's later frames stay exact, with or without [`Culler::reset`].
    fn cull_frame(
        &mut self,
        input: &FrameInput,
        backend: &mut dyn OcclusionBackend,
    ) -> Result<CullStats>;
    /// Forgets temporal state (e.g. after a camera cut).
    fn reset(&mut self);
}

/// The algorithm names [`create_with`] accepts.
pub const ALGORITHMS: &[&str] = &[
    "vfc",
    "stop-and-wait",
    "chc",
    "chcpp",
    "oracle",
    "oracle-box",
    "nohc",
    "pvs",
];

/// What algorithms need beyond a name: CHC++'s parameters (their pixel threshold applies to
/// every algorithm that queries), NOHC's cost model, the PVS of the scene.
#[derive(Clone, Default)]
pub struct CullerSetup {
    /// CHC++ parameters.
    pub params: ChcppParams,
    /// NOHC's parameters (cost model from `coherent calibrate`, viewport, triangles).
    pub nohc: Option<NohcParams>,
    /// The scene's potentially visible sets.
    pub pvs: Option<std::sync::Arc<Pvs>>,
}

/// Checks an algorithm name without creating it.
pub fn check_name(name: &str) -> Result<()> {
    if ALGORITHMS.contains(&name) {
        Ok(())
    } else {
        Err(Error::Input(format!(
            "unknown algorithm \"{name}\" (known: {})",
            ALGORITHMS.join(", ")
        )))
    }
}

/// Creates an algorithm by name with what it needs from `setup`.
pub fn create_with(name: &str, setup: &CullerSetup) -> Result<Box<dyn Culler>> {
    match name {
        "nohc" => Ok(Box::new(nohc_with(setup)?)),
        "pvs" => {
            let pvs = setup.pvs.clone().ok_or_else(|| {
                Error::Input("pvs needs the scene's potentially visible sets".into())
            })?;
            Ok(Box::new(pvs::PvsCuller::new(pvs)))
        }
        _ => create(name, &setup.params),
    }
}

/// NOHC with the cost model of `setup` and its pixel threshold, in-frame.
fn nohc_with(setup: &CullerSetup) -> Result<chcpp::Chcpp> {
    let mut p = setup
        .nohc
        .clone()
        .ok_or_else(|| Error::Input("nohc needs a device cost model (CullerSetup::nohc)".into()))?;
    p.flush_interval = p.flush_interval.max(1);
    let mut c = chcpp::Chcpp::nohc(p);
    c.set_pixel_threshold(setup.params.pixel_threshold);
    Ok(c)
}

/// Creates an algorithm that needs nothing but CHC++'s parameters by name (`chcpp` takes
/// `params`; every algorithm that queries takes its pixel threshold). `nohc` and `pvs` need
/// [`create_with`].
pub fn create(name: &str, params: &ChcppParams) -> Result<Box<dyn Culler>> {
    Ok(match name {
        "vfc" => Box::new(vfc::Vfc::default()),
        "stop-and-wait" => {
            let mut s = stop_and_wait::StopAndWait::default();
            s.pixel_threshold = params.pixel_threshold;
            Box::new(s)
        }
        "chc" => Box::new(chc::Chc::default()),
        "chcpp" => Box::new(chcpp::Chcpp::new(params.clone())),
        "oracle" => Box::new(oracle::Oracle),
        "oracle-box" => Box::new(oracle::BoxOracle),
        "nohc" | "pvs" => {
            return Err(Error::Input(format!(
                "{name} needs more than CHC++'s parameters: use culling::create_with"
            )))
        }
        other => {
            return Err(Error::Input(format!(
                "unknown algorithm \"{other}\" (known: {})",
                ALGORITHMS.join(", ")
            )))
        }
    })
}

/// Whether a node's query can't be trusted because the eye is inside its box or the near plane
/// cuts it inside the view: such a node is treated as visible without a query. Works for any
/// projection (perspective, off-axis, orthographic, reverse-Z, infinite far).
pub fn eye_inside(bounds: &Aabb, view: &CameraView) -> bool {
    View::new(view).eye_inside(bounds)
}

/// Helper shared by the algorithms: the frustum, eye and front-to-back origin of a frame.
#[doc(hidden)]
#[derive(Clone, Debug)]
pub struct View {
    /// The view frustum's planes.
    pub frustum: Frustum,
    /// The point front-to-back order measures from ([`CameraView::order_point`]).
    pub eye: Vec3,
    /// The near-plane rectangle's bounding box, enlarged by `margin`.
    near_box: Aabb,
    margin: f32,
    /// The camera: its true eye position, and its grid for the pixel-centre test.
    camera: CameraView,
}

impl View {
    /// The frustum, eye, order point and near-plane box of `view`.
    pub fn new(view: &CameraView) -> View {
        let frustum = view.frustum();
        let c = view.near_corners();
        let center = (c[0] + c[1] + c[2] + c[3]) * 0.25;
        let half = c.iter().map(|p| (*p - center).length()).fold(0.0, f32::max);
        let margin = half * 0.02 + 1e-4;
        let near_box = Aabb::new(
            c.iter().fold(Vec3::INFINITY, |a, p| a.min(*p)),
            c.iter().fold(Vec3::NEG_INFINITY, |a, p| a.max(*p)),
        )
        .enlarged(margin);
        View {
            frustum,
            eye: view.order_point(),
            near_box,
            margin,
            camera: *view,
        }
    }

    /// Whether a box may show: it meets the frustum and, with a pixel grid, may cover a pixel
    /// centre ([`CameraView::may_cover_centre`]).
    pub fn in_view(&self, bounds: &Aabb) -> bool {
        self.frustum.intersects(bounds) && self.camera.may_cover_centre(bounds)
    }

    /// The frame's camera.
    pub(crate) fn camera(&self) -> &CameraView {
        &self.camera
    }

    /// The pixel-centre half of [`View::in_view`], for a box already known to meet the frustum.
    pub fn may_cover_centre(&self, bounds: &Aabb) -> bool {
        self.camera.may_cover_centre(bounds)
    }

    /// See [`eye_inside`]: the eye is in the (slightly enlarged) box, or the box reaches the
    /// near plane where the near rectangle is.
    pub fn eye_inside(&self, bounds: &Aabb) -> bool {
        let b = bounds.enlarged(self.margin);
        if b.contains(self.camera.eye) {
            return true;
        }
        let near = self.frustum.planes[4];
        let n = near.truncate();
        let closest = Vec3::select(n.cmpge(Vec3::ZERO), b.min, b.max);
        let reaches_near = n.dot(closest) + near.w <= 0.0;
        reaches_near && b.overlaps(&self.near_box)
    }
}
