//! Fuzzes the path files and the PVS, calibration, interior walk and path check cache files (the
//! first byte picks the format, see `fuzz/cache_input.rs`): any bytes must be read and used, or
//! refused with a one-line error naming the file, never panic.
#![no_main]

use std::path::PathBuf;
use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;

#[path = "../cache_input.rs"]
mod cache_input;

/// A private directory per fuzzing process.
fn dir() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("coherent-fuzz-cache-{}", std::process::id()));
        std::fs::create_dir_all(&d).expect("fuzz temp dir");
        d
    })
}

fuzz_target!(|data: &[u8]| {
    cache_input::run(dir(), data).expect("write fuzz input");
});
