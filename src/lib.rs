//! # coherent
//!
//! Temporal coherence in object space on raw Vulkan (ash): online occlusion culling with
//! hardware occlusion queries — CHC++ (Mattausch, Bittner, Wimmer 2008) and what it is measured
//! against (view-frustum culling, hierarchical stop-and-wait, CHC, an exact-visibility oracle) —
//! and incremental instant radiosity (Laine et al. 2007).
//!
//! The data flows one way: [`scene`] → [`bvh`] → [`culling`] decides → [`render`] records through
//! [`gpu`] → [`app::report`]. The library is [`gpu`], [`scene`], [`render`] and [`gi`]; [`app`] is
//! the application on top of it (walks and their reports, the viewer, NOHC's calibration, the PVS
//! build, GI runs), which the library never imports. Culling algorithms never call Vulkan: they
//! talk to the [`culling::OcclusionBackend`] trait ("draw these objects", "draw these boxes inside
//! a query", "submit", "is query N ready"), which [`render::Renderer`] implements and which a host
//! engine can implement over its own device and command buffers (see `examples/engine.rs`).
//!
//! ```
//! use coherent::culling::chcpp::{Chcpp, ChcppParams};
//! use coherent::gpu::GpuContext;
//! use coherent::render::Renderer;
//! use coherent::scene::Scene;
//!
//! # fn main() -> coherent::Result<()> {
//! let ctx = GpuContext::headless()?; // validation on, messages captured per context
//! let scene = Scene::load("city", 0.1, 4096)?;
//! // Blended (glTF BLEND) objects stay out of it: the renderer draws them after the culled pass.
//! let bvh = scene.hierarchy(1);
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
//! let png = std::env::temp_dir().join("coherent-doc-frame.png");
//! renderer.save_png(&png)?;
//! assert_eq!(ctx.validation_log().count(), 0);
//! # std::fs::remove_file(&png).ok();
//! # Ok(())
//! # }
//! ```
//!
//! ## Embedding in an engine
//!
//! An engine does not need this crate: the culling core is `coherent-cull` (no Vulkan, no I/O)
//! and the query side for ash hosts is `coherent-ash` (query pools per frame in flight, result
//! copies, the box pipeline; no shaderc). Their crate docs are the embedding guide, and
//! `examples/engine.rs` is a complete host. The built-in renderer records its occlusion queries
//! through coherent-ash too (its `QuerySet` and `BoxPipeline`, with submissions inside the frame
//! for the in-frame modes). This crate re-exports the core as [`culling`] and [`bvh`] for the
//! built-in renderer and the command line.

/// The culling core: every algorithm, the backend trait, the camera math (`coherent-cull`).
pub use coherent_cull as culling;
/// The object hierarchy (from `coherent-cull`).
pub use coherent_cull::bvh;
pub mod app;
pub mod error;
pub mod gi;
pub mod gpu;
pub mod image_io;
mod parallel;
pub mod render;
pub mod scene;
#[doc(hidden)]
pub mod testing;

pub use error::{Error, Result};
