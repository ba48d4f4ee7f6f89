//! Shared by the integration tests: random scenes, a camera path, a visibility model for the
//! mock backend, and one frame run through a culler.
#![allow(dead_code)]

use coherent_cull::camera::{Camera, CameraPose, Frustum};
use coherent_cull::glam::Vec3;
use coherent_cull::rng::Rng;
use coherent_cull::testing::{MockBackend, MockCounts, MockEvent};
use coherent_cull::{Aabb, CullStats, Culler, FrameInput, ObjectBvh};

/// Pixels a visible box sees in the visibility models below.
pub const PIXELS: u64 = 100;

/// `n` boxes of mixed sizes on a 200 × 200 ground (some tall), from `seed`.
pub fn random_boxes(n: u32, seed: u64) -> Vec<Aabb> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| {
            let p = Vec3::new(rng.range(0.0, 200.0), 0.0, rng.range(0.0, 200.0));
            let s = Vec3::new(
                rng.range(1.0, 4.0),
                rng.range(1.0, 12.0),
                rng.range(1.0, 4.0),
            );
            Aabb::new(p, p + s)
        })
        .collect()
}

/// Tall landmarks: regions seen from everywhere (as towers over the roofs).
pub fn landmarks() -> Vec<Aabb> {
    [(40.0, 150.0), (160.0, 60.0), (120.0, 170.0)]
        .iter()
        .map(|&(x, z)| Aabb::new(Vec3::new(x, 0.0, z), Vec3::new(x + 6.0, 40.0, z + 6.0)))
        .collect()
}

/// Frame `f` of a walk at eye height around the middle of the ground, looking inwards and a
/// little ahead.
pub fn walk(f: u64) -> Camera {
    let a = 0.035 * f as f32;
    let center = Vec3::new(100.0, 0.0, 100.0);
    let eye = center + Vec3::new(a.cos() * 55.0, 1.7, a.sin() * 55.0);
    let ahead = Vec3::new(-(a + 0.9).sin(), 0.0, (a + 0.9).cos());
    let target = center.lerp(eye, 0.3) + ahead * 40.0 + Vec3::Y * 1.7;
    Camera::from_pose(CameraPose { eye, target }, 16.0 / 9.0, 500.0)
}

/// A camera far above one corner, seeing the whole ground.
pub fn overview() -> Camera {
    Camera::from_pose(
        CameraPose {
            eye: Vec3::new(-150.0, 250.0, -150.0),
            target: Vec3::new(100.0, 0.0, 100.0),
        },
        1.0,
        2000.0,
    )
}

/// The visibility model of a frame: a box sees pixels when it is in the frustum and near the
/// eye (within `range`, as in fog or a dense town) or overlaps a landmark. A box that holds a
/// visible box is visible too, as on a real depth buffer, so hierarchical culling can be exact.
#[derive(Clone)]
pub struct Fog {
    pub frustum: Frustum,
    pub eye: Vec3,
    pub range: f32,
    pub landmarks: Vec<Aabb>,
}

impl Fog {
    pub fn new(camera: &Camera, range: f32) -> Fog {
        Fog {
            frustum: camera.frustum(),
            eye: camera.eye,
            range,
            landmarks: landmarks(),
        }
    }

    pub fn visible(&self, b: &Aabb) -> bool {
        self.frustum.intersects(b)
            && (b.distance_squared(self.eye) < self.range * self.range
                || self.landmarks.iter().any(|l| l.overlaps(b)))
    }

    pub fn pixels(&self, b: &Aabb) -> u64 {
        if self.visible(b) {
            PIXELS
        } else {
            0
        }
    }

    /// The objects of `bvh` whose own box is visible: what an exact culler must draw.
    pub fn visible_objects(&self, bvh: &ObjectBvh) -> Vec<u32> {
        live_objects(bvh)
            .into_iter()
            .filter(|&o| self.visible(&bvh.object_bounds(o).unwrap()))
            .collect()
    }
}

/// Every object in the hierarchy, sorted.
pub fn live_objects(bvh: &ObjectBvh) -> Vec<u32> {
    let mut all = bvh.leaf_objects.clone();
    all.retain(|&o| bvh.object_bounds(o).is_some());
    all.sort_unstable();
    all.dedup();
    all
}

/// The objects of `bvh` whose box touches the frustum of `camera`.
pub fn in_frustum(bvh: &ObjectBvh, camera: &Camera) -> Vec<u32> {
    let frustum = camera.frustum();
    live_objects(bvh)
        .into_iter()
        .filter(|&o| frustum.intersects(&bvh.object_bounds(o).unwrap()))
        .collect()
}

/// What one frame did.
#[derive(Clone, Debug)]
pub struct Frame {
    pub stats: CullStats,
    pub counts: MockCounts,
    pub drawn: Vec<u32>,
    pub events: Vec<MockEvent>,
}

impl Frame {
    /// Query events as (purpose, boxes, visible).
    pub fn queries(&self) -> Vec<(coherent_cull::QueryPurpose, usize, bool)> {
        self.events
            .iter()
            .filter_map(|e| match e {
                MockEvent::Query {
                    purpose,
                    boxes,
                    visible,
                    ..
                } => Some((*purpose, *boxes, *visible)),
                _ => None,
            })
            .collect()
    }

    /// Queries issued for `purpose`.
    pub fn queries_for(&self, purpose: coherent_cull::QueryPurpose) -> usize {
        self.queries().iter().filter(|q| q.0 == purpose).count()
    }
}

/// Culls frame `frame` seen by `camera` and collects what the backend saw, then starts the
/// backend's next frame.
pub fn run(
    culler: &mut dyn Culler,
    bvh: &ObjectBvh,
    camera: &Camera,
    backend: &mut MockBackend,
    frame: u64,
) -> Frame {
    run_with(culler, bvh, camera, backend, frame, None)
}

/// [`run`] with an exact visible set (the oracle).
pub fn run_with(
    culler: &mut dyn Culler,
    bvh: &ObjectBvh,
    camera: &Camera,
    backend: &mut MockBackend,
    frame: u64,
    exact_visible: Option<&[u32]>,
) -> Frame {
    let input = FrameInput {
        bvh,
        view: camera.into(),
        frame,
        exact_visible,
    };
    let stats = culler.cull_frame(&input, backend).expect("cull_frame");
    let out = Frame {
        stats,
        counts: backend.counts(),
        drawn: backend.drawn_last_frame(),
        events: backend.events().to_vec(),
    };
    backend.end_frame();
    out
}

/// The objects of `want` missing from the sorted `drawn`.
pub fn missing(want: &[u32], drawn: &[u32]) -> Vec<u32> {
    want.iter()
        .copied()
        .filter(|o| drawn.binary_search(o).is_err())
        .collect()
}
