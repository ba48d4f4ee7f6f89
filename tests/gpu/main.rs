//! The root package's GPU integration tests, one binary (each file is a module; linking one
//! binary instead of twenty keeps the build small). Every test runs under the Khronos validation
//! layer on lavapipe unless `COHERENT_DEVICE` names another device.

#[path = "../common/mod.rs"]
mod common;

mod builtin_paths;
mod culling;
mod dynamic;
mod embedding;
mod foundation;
mod fuzz_regressions;
mod gi;
mod gi_faithful;
mod gi_ism;
mod gi_movers;
mod gi_textures;
mod hiz;
mod materials;
mod materials_gi;
mod nohc_pvs;
mod predicated;
mod query_backend;
mod reliability;
mod scenes;
mod viewer;
mod vulkan_1_2;
mod walk;
