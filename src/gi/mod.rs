//! Incremental instant radiosity (Laine et al. 2007): a spotlight, CPU ray casting (through
//! [`crate::scene::raycast`]), the VPL set in the unit-disk domain, and (in the renderer) layered
//! paraboloid shadow maps or imperfect shadow maps, and deferred shading. The runs along a light
//! path with their reports belong to the application (`app::gi_run`).

pub mod light;
pub mod vpl;

pub mod deferred;
pub mod geometry;
pub mod ism;
pub mod movers;
pub mod renderer;
pub mod shadow;
pub mod textures;

pub use ism::IsmOptions;
pub use renderer::{GiFrame, GiOptions, GiRenderer, OutputMode};
