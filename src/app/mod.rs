//! The application: what the `coherent` binary runs on the library. Walkthroughs with their
//! reports and plots, the interactive viewer with its overlay, NOHC's device calibration, the PVS
//! build and the GI runs. The library (`gpu`, `scene`, `render`, `gi`) never imports it.

pub mod calibrate;
pub mod gi_run;
pub mod overlay;
pub mod pvs_build;
pub mod report;
pub mod viewer;
pub mod walk;
