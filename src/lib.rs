//! # coherent
//!
//! Temporal coherence in object space on raw Vulkan (ash): online occlusion culling with hardware
//! occlusion queries (CHC++ and the algorithms it is measured against) and incremental instant
//! radiosity.
pub mod bvh;
pub mod culling;
pub mod error;
pub mod gi;
pub mod gpu;
pub mod render;
pub mod report;
pub mod scene;

pub use error::{Error, Result};
