//! The per-frame scene update allocates nothing: placing 1,000 movers (their boxes into the
//! hierarchy) and refitting it, frame after frame, performs no heap allocation on frames without
//! a rebuild (counted with a global allocator that counts this thread's allocations).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};

use coherent::bvh::ObjectBvh;
use coherent::scene::movers::Movers;
use coherent::scene::Scene;

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
fn mover_updates_do_not_allocate() {
    let mut scene = Scene::load("city", 0.25, 4096).unwrap();
    let movers = Movers::add(&mut scene, 1000);
    let bounds: Vec<_> = scene.objects.iter().map(|o| o.bounds).collect();
    let mut bvh = ObjectBvh::build(&bounds, 1);
    let mut steady = 0;
    for f in 0..120u64 {
        let before = ALLOCATIONS.load(Ordering::Relaxed);
        COUNTING.with(|c| c.set(true));
        movers
            .for_each_at(f, |object, b, _| bvh.set_bounds(object, b))
            .unwrap();
        let stats = bvh.update();
        COUNTING.with(|c| c.set(false));
        let allocated = ALLOCATIONS.load(Ordering::Relaxed) - before;
        assert!(stats.dirty_leaves > 0, "the movers moved");
        if !stats.rebuilt {
            assert_eq!(allocated, 0, "frame {f} allocated {allocated} times");
            steady += 1;
        }
    }
    assert!(steady > 100, "{steady} frames without a rebuild");
    bvh.validate().unwrap();
}
