//! Allocation counts: a separate binary, because it installs a counting global allocator.
//! Its tests take [`SERIAL`] so that one test's allocations are never counted in another's.

#[path = "../common/mod.rs"]
mod common;

#[path = "../common/counting_alloc.rs"]
mod counting_alloc;

mod allocations;
mod dynamic_allocations;

/// Held by each test of this binary while it counts.
pub static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());
