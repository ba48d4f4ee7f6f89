//! The per-frame scene update allocates nothing: placing 1,000 movers (their boxes into the
//! hierarchy) and refitting it, frame after frame, performs no heap allocation on frames without
//! a rebuild (counted with a global allocator that counts this thread's allocations).

use crate::counting_alloc;

use std::sync::atomic::Ordering;

use coherent::scene::movers::Movers;
use coherent::scene::Scene;

#[test]
fn mover_updates_do_not_allocate() {
    let _serial = crate::SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let mut scene = Scene::load("city", 0.25, 4096).unwrap();
    let movers = Movers::add(&mut scene, 1000);
    let mut bvh = scene.hierarchy(1);
    let mut steady = 0;
    for f in 0..120u64 {
        let before = counting_alloc::ALLOCATIONS.load(Ordering::Relaxed);
        counting_alloc::COUNTING.with(|c| c.set(true));
        movers
            .for_each_at(f, |object, b, _| Ok(bvh.set_bounds(object, b)?))
            .unwrap();
        let stats = bvh.update();
        counting_alloc::COUNTING.with(|c| c.set(false));
        let allocated = counting_alloc::ALLOCATIONS.load(Ordering::Relaxed) - before;
        assert!(stats.dirty_leaves > 0, "the movers moved");
        if !stats.rebuilt {
            assert_eq!(allocated, 0, "frame {f} allocated {allocated} times");
            steady += 1;
        }
    }
    assert!(steady > 100, "{steady} frames without a rebuild");
    bvh.validate().unwrap();
}
