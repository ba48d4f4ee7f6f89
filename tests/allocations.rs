//! Steady frames allocate nothing: after a warm-up, rendering frames of vfc, chc, chcpp and nohc
//! performs no heap allocation in the culler or the renderer's recording path (counted with a
//! global allocator that counts this thread's allocations while a frame is being rendered).

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};

use coherent::culling;
use coherent::render::Renderer;

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

thread_local! {
    static COUNTING: Cell<bool> = const { Cell::new(false) };
}

// SAFETY: forwards to the system allocator; only adds a counter.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if COUNTING.with(Cell::get) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if COUNTING.with(Cell::get) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn steady_frames_do_not_allocate() {
    let (ctx, log) = common::context();
    {
        let (scene, bvh) = common::scene("city", 0.1);
        let path = scene.path("street").unwrap().clone();
        let mut r = Renderer::new(&ctx, &scene, 160, 90).unwrap();
        let (warmup, counted) = (30u32, 50u32);
        let setup = common::setup(common::triangles(&scene), (160, 90), 0.05);
        for name in ["vfc", "chc", "chcpp", "nohc"] {
            let mut alg = culling::create_with(name, &setup).unwrap();
            let mut per_frame = Vec::with_capacity(counted as usize);
            for f in 0..warmup + counted {
                let cam = r.camera(path.sample(f, warmup + counted), &bvh);
                let before = ALLOCATIONS.load(Ordering::Relaxed);
                COUNTING.with(|c| c.set(f >= warmup));
                let res = r.render_frame(alg.as_mut(), &bvh, &cam, f as u64);
                COUNTING.with(|c| c.set(false));
                res.unwrap();
                if f >= warmup {
                    per_frame.push(ALLOCATIONS.load(Ordering::Relaxed) - before);
                }
            }
            assert!(
                per_frame.iter().all(|&n| n == 0),
                "{name}: allocations per steady frame: {per_frame:?}"
            );
        }
    }
    drop(ctx);
    common::assert_silent(&log);
}
