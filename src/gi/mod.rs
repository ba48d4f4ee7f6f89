//! Incremental instant radiosity (Laine et al. 2007): a spotlight, CPU ray casting, the VPL set in
//! the unit-disk domain, and (in the renderer) layered paraboloid shadow maps and deferred shading.

pub mod light;
pub mod raycast;
pub mod vpl;
