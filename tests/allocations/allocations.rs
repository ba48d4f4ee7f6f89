//! Steady frames allocate nothing: after a warm-up, rendering frames of vfc, chc, chcpp, nohc
//! and chcpp in the predicated mode performs no heap allocation in the culler or the
//! renderer's recording path (counted with a global allocator that counts this thread's
//! allocations while a frame is being rendered).

use crate::common;

use crate::counting_alloc;

use std::sync::atomic::Ordering;

use coherent::culling;
use coherent::render::Renderer;

#[test]
fn steady_frames_do_not_allocate() {
    let _serial = crate::SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let (ctx, log) = common::context();
    {
        let (scene, bvh) = common::scene("city", 0.1);
        let path = scene.path("street").unwrap().clone();
        let mut r = Renderer::new(&ctx, &scene, 160, 90).unwrap();
        let (warmup, counted) = (30u32, 50u32);
        let setup = common::setup(common::triangles(&scene), (160, 90), 0.05);
        for name in ["vfc", "chc", "chcpp", "nohc", "chcpp@predicated"] {
            let mut alg = match name.split_once('@') {
                Some((base, "predicated")) => {
                    culling::create_latency(base, &setup.params, culling::Latency::Predicated)
                        .unwrap()
                }
                _ => culling::create_with(name, &setup).unwrap(),
            };
            let mut per_frame = Vec::with_capacity(counted as usize);
            for f in 0..warmup + counted {
                let cam = r.camera(path.sample(f, warmup + counted), &bvh);
                let before = counting_alloc::ALLOCATIONS.load(Ordering::Relaxed);
                counting_alloc::COUNTING.with(|c| c.set(f >= warmup));
                let res = r.render_frame(alg.as_mut(), &bvh, &cam, f as u64);
                counting_alloc::COUNTING.with(|c| c.set(false));
                res.unwrap();
                if f >= warmup {
                    per_frame.push(counting_alloc::ALLOCATIONS.load(Ordering::Relaxed) - before);
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
