//! Cameras and walkthrough sampling. The camera math (frusta, projections, the culler's
//! [`CameraView`]) lives in `coherent-cull` and is re-exported here.

use glam::Vec3;

pub use coherent_cull::camera::*;

use super::CameraPath;

/// Frames between two keyframes of a walkthrough path.
pub const FRAMES_PER_KEY: f32 = 30.0;

impl CameraPath {
    /// Number of frames of one pass along the path.
    pub fn natural_frames(&self) -> u32 {
        ((self.keys.len().max(1) - 1) as f32 * FRAMES_PER_KEY).max(1.0) as u32
    }
    /// The pose at `frame` (30 frames per key, smooth interpolation, clamped at the end).
    pub fn pose_at(&self, frame: f32) -> CameraPose {
        let n = self.keys.len();
        if n == 0 {
            return CameraPose {
                eye: Vec3::new(0.0, 1.0, 5.0),
                target: Vec3::ZERO,
            };
        }
        if n == 1 {
            return self.keys[0];
        }
        let t = (frame / FRAMES_PER_KEY).clamp(0.0, (n - 1) as f32);
        let i = (t.floor() as usize).min(n - 2);
        let f = t - i as f32;
        let get = |k: isize| self.keys[k.clamp(0, n as isize - 1) as usize];
        let (p0, p1, p2, p3) = (
            get(i as isize - 1),
            get(i as isize),
            get(i as isize + 1),
            get(i as isize + 2),
        );
        CameraPose {
            eye: catmull_rom(p0.eye, p1.eye, p2.eye, p3.eye, f),
            target: catmull_rom(p0.target, p1.target, p2.target, p3.target, f),
        }
    }
    /// The pose of frame `i` of a walk of `count` frames covering the whole path once.
    pub fn sample(&self, i: u32, count: u32) -> CameraPose {
        let len = self.natural_frames() as f32;
        let f = if count <= 1 {
            0.0
        } else {
            i as f32 * len / (count - 1) as f32
        };
        self.pose_at(f)
    }
}

fn catmull_rom(p0: Vec3, p1: Vec3, p2: Vec3, p3: Vec3, t: f32) -> Vec3 {
    let t2 = t * t;
    let t3 = t2 * t;
    0.5 * ((2.0 * p1)
        + (-p0 + p2) * t
        + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * t2
        + (-p0 + 3.0 * p1 - 3.0 * p2 + p3) * t3)
}
