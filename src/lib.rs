//! # coherent
//!
//! Temporal coherence in object space on raw Vulkan (ash): online occlusion culling with
//! hardware occlusion queries — CHC++ (Mattausch, Bittner, Wimmer 2008) and what it is measured
//! against (view-frustum culling, hierarchical stop-and-wait, CHC, an exact-visibility oracle) —
//! and incremental instant radiosity (Laine et al. 2007).
//!
//! The data flows one way: [`scene`] → [`bvh`] → [`culling`] decides → [`render`] records through
//! [`gpu`] → [`report`]. Culling algorithms never call Vulkan: they talk to the
//! [`culling::OcclusionBackend`] trait ("draw these objects", "draw these boxes inside a query",
//! "submit", "is query N ready"), which [`render::Renderer`] implements and which a host engine
//! can implement over its own device and command buffers (see `examples/embed.rs`).
//!
//! ```
//! use coherent::bvh::ObjectBvh;
//! use coherent::culling::chcpp::{Chcpp, ChcppParams};
//! use coherent::gpu::GpuContext;
//! use coherent::render::Renderer;
//! use coherent::scene::Scene;
//!
//! # fn main() -> coherent::Result<()> {
//! let ctx = GpuContext::headless()?; // validation on, messages captured per context
//! let scene = Scene::load("city", 0.1, 4096)?;
//! let bounds: Vec<_> = scene.objects.iter().map(|o| o.bounds).collect();
//! let bvh = ObjectBvh::build(&bounds, 1);
//! let mut renderer = Renderer::new(&ctx, &scene, 320, 180)?;
//! let mut culler = Chcpp::new(ChcppParams::default());
//! let path = scene.path("street")?.clone();
//! for frame in 0..10 {
//!     let camera = renderer.camera(path.pose_at(frame as f32), &bvh);
//!     let result = renderer.render_frame(&mut culler, &bvh, &camera, frame)?;
//!     println!(
//!         "frame {frame}: {:.1} ms, {} queries, {} state changes, {} draws",
//!         result.frame_ms, result.counts.queries_begun, result.counts.state_changes,
//!         result.counts.draw_calls
//!     );
//! }
//! renderer.save_png(&std::env::temp_dir().join("coherent-doc-frame.png"))?;
//! assert_eq!(ctx.validation_log().count(), 0);
//! # Ok(())
//! # }
//! ```
//!
//! ## Embedding in an engine
//!
//! A host engine keeps its own device, frame loop and camera and uses a culler in four steps:
//!
//! 1. **Hierarchy.** Build an [`bvh::ObjectBvh`] over the world boxes of the objects it wants
//!    culled (object `i` is the host's draw `i`): `ObjectBvh::from_boxes` takes plain arrays
//!    `[min, max]` (`[[f32; 3]; 2]`), as do `set_bounds` and `insert` for objects that move,
//!    appear and vanish; [`scene::Aabb::from_min_max`] takes any `mint` point and
//!    `Aabb::to_arrays` gives the query boxes back as arrays. No glam type is needed.
//! 2. **Backend.** Implement [`culling::OcclusionBackend`] over its command buffer:
//!    - `draw_objects`: inside its main depth pass (dynamic rendering or a render pass), bind
//!      its opaque pipeline (depth test LESS or GREATER for reverse-Z, depth write on) and draw
//!      the objects.
//!    - `issue_query` / `issue_query_for`: in the same pass, bind a query pipeline (depth test
//!      on, the compare of its depth convention *or-equal*, depth and color writes off, a small
//!      depth bias towards the eye), `vkCmdBeginQuery` on a precise occlusion query that was
//!      reset outside the pass (`vkCmdResetQueryPool` before the pass, or host reset), draw the
//!      boxes, `vkCmdEndQuery`. `restore_render_state` rebinds the opaque pipeline.
//!    - `flush` (in-frame mode only): end the pass, submit, begin a new pass with LOAD ops on
//!      the same color and depth (the image layouts stay attachment layouts; no barrier
//!      beyond the pass's own). `query_result` must never block: check that the submission
//!      holding the query has completed (a timeline value or fence) before reading it. The
//!      built-in renderer reads no result through `vkGetQueryPoolResults` in the frame: each
//!      submission ends with `vkCmdCopyQueryPoolResults` of its queries into a host-visible
//!      buffer, read once the submission has completed (on lavapipe `vkGetQueryPoolResults`
//!      waits for the whole device, so it would also wait for later submissions).
//!      `wait_query` waits for the submission (that is stall time).
//!    - `finish`: submit what is left and wait for it (the built-in renderer does). In the
//!      latency modes with `k = 1` the culler reads its queries with `query_result` right
//!      after `finish` and never waits; a result not back then is dropped and its node keeps
//!      its last known state.
//!    - **`k` frames in flight** (`Chcpp::with_frames_in_flight(k)`): the frame ends with
//!      `submit_frame` (one submission, no wait) and frame N's queries are read at the start
//!      of `cull_frame` for frame N+k. The host keeps one query pool (and result storage) per
//!      frame-in-flight slot, hands out ids that name the slot, waits for the slot's fence
//!      before calling `cull_frame` for the frame that reuses it (its normal frame pacing),
//!      resets the slot's queries inside that frame's command buffer
//!      (`vkCmdResetQueryPool` before the pass, so after the culler has read them), and
//!      returns `k` from `frames_in_flight`. On drivers where `vkGetQueryPoolResults` waits
//!      for the whole device (lavapipe), copy the results with `vkCmdCopyQueryPoolResults`
//!      into a host-visible buffer at the end of the frame and read that.
//!      `examples/engine.rs` is such a host (two frames in flight).
//! 3. **Camera.** Each frame, hand the culler a [`scene::camera::CameraView`]: the
//!    world-to-clip matrix, the eye and the depth convention, as plain arrays or `mint` types
//!    (no glam version is forced on the host). Reverse-Z, infinite far, jittered, off-axis and
//!    orthographic projections all work.
//! 4. **Mode.** Pick a [`culling::Latency`]: `InFrame` is exact but splits the frame into
//!    several submissions and waits for results inside it; `NextFrame` submits once per frame and
//!    never waits, and objects that come into view appear one frame late;
//!    `NextFrameConservative` draws nodes that have no result from the last frame (they just
//!    entered the frustum), popping less for more draws. The README's "Embedding in an engine"
//!    section has the measured cost of each.
//!
//! ```
//! use coherent::culling::chcpp::{Chcpp, ChcppParams};
//! use coherent::culling::Latency;
//! use coherent::scene::camera::{perspective_infinite_reverse_rh, CameraView, DepthConvention};
//!
//! // The host's own matrices, as plain column-major arrays.
//! let proj = perspective_infinite_reverse_rh(1.0, 16.0 / 9.0, 0.1);
//! let view_proj: [f32; 16] = proj.to_cols_array();
//! let view = CameraView::new(view_proj, [0.0, 0.0, 0.0], DepthConvention::REVERSE_Z_INFINITE);
//! assert!(view.frustum().intersects(&coherent::scene::Aabb::new(
//!     glam::Vec3::new(-1.0, 0.0, -10.0),
//!     glam::Vec3::new(1.0, 2.0, -8.0),
//! )));
//! let culler = Chcpp::new(ChcppParams::default())
//!     .with_latency(Latency::NextFrame)
//!     .with_frames_in_flight(2); // the host has two frames in flight
//! assert_eq!(culler.latency(), Latency::NextFrame);
//!
//! // The hierarchy and its updates from plain arrays, too.
//! use coherent::bvh::ObjectBvh;
//! let mut bvh = ObjectBvh::from_boxes([[[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]; 4], 1);
//! bvh.set_bounds(1, [[2.0, 0.0, 0.0], [3.0, 1.0, 1.0]]).unwrap();
//! let car = bvh.insert([[5.0, 0.0, 5.0], [6.0, 1.0, 7.0]]);
//! bvh.update();
//! assert_eq!(bvh.object_bounds(car).map(|b| b.to_arrays()), Some([[5.0, 0.0, 5.0], [6.0, 1.0, 7.0]]));
//! ```
/// The culling core: every algorithm, the backend trait, the camera math (`coherent-cull`).
pub use coherent_cull as culling;
/// The object hierarchy (from `coherent-cull`).
pub use coherent_cull::bvh;
pub mod error;
pub mod gi;
pub mod gpu;
pub mod render;
pub mod report;
pub mod scene;

pub use error::{Error, Result};
