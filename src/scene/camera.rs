//! Cameras, view frusta and walkthrough sampling.

use glam::{Mat4, Vec3, Vec4};

use super::{Aabb, CameraPath, CameraPose};

/// Frames between two keyframes of a walkthrough path.
pub const FRAMES_PER_KEY: f32 = 30.0;

/// A perspective camera (right-handed, y up, Vulkan depth 0..1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position.
    pub eye: Vec3,
    /// Point looked at.
    pub target: Vec3,
    /// Vertical field of view in radians.
    pub fov_y: f32,
    /// Width / height.
    pub aspect: f32,
    /// Near plane distance.
    pub near: f32,
    /// Far plane distance.
    pub far: f32,
}

impl Camera {
    /// A camera at `pose` with a 60° field of view.
    pub fn from_pose(pose: CameraPose, aspect: f32, far: f32) -> Camera {
        Camera {
            eye: pose.eye,
            target: pose.target,
            fov_y: 60f32.to_radians(),
            aspect,
            near: 0.1,
            far,
        }
    }
    /// World to view.
    pub fn view(&self) -> Mat4 {
        let dir = (self.target - self.eye).normalize_or(Vec3::NEG_Z);
        let up = if dir.cross(Vec3::Y).length_squared() < 1e-6 {
            Vec3::Z
        } else {
            Vec3::Y
        };
        look_to_rh(self.eye, dir, up)
    }
    /// View to clip (depth 0..1).
    pub fn projection(&self) -> Mat4 {
        perspective_rh(self.fov_y, self.aspect, self.near, self.far)
    }
    /// World to clip.
    pub fn view_proj(&self) -> Mat4 {
        self.projection() * self.view()
    }
    /// Distance from the eye to a corner of the near-plane rectangle: a box closer than this to
    /// the eye may be clipped by the near plane, so its query cannot be trusted.
    pub fn near_corner_distance(&self) -> f32 {
        let h = self.near * (self.fov_y * 0.5).tan();
        let w = h * self.aspect;
        (self.near * self.near + h * h + w * w).sqrt()
    }
    /// The view frustum.
    pub fn frustum(&self) -> Frustum {
        Frustum::from_matrix(&self.view_proj())
    }
}

/// Six planes (a, b, c, d) with inside where a·x + b·y + c·z + d >= 0.
#[derive(Clone, Copy, Debug)]
pub struct Frustum {
    /// Left, right, bottom, top, near, far.
    pub planes: [Vec4; 6],
}

impl Frustum {
    /// Extracts the planes of a clip matrix with depth 0..1.
    pub fn from_matrix(m: &Mat4) -> Frustum {
        let r0 = m.row(0);
        let r1 = m.row(1);
        let r2 = m.row(2);
        let r3 = m.row(3);
        let planes = [r3 + r0, r3 - r0, r3 + r1, r3 - r1, r2, r3 - r2];
        Frustum {
            planes: planes.map(|p| p / p.truncate().length().max(1e-20)),
        }
    }
    /// Conservative box test: false only if the box is entirely outside one plane.
    pub fn intersects(&self, b: &Aabb) -> bool {
        self.planes.iter().all(|p| {
            let n = p.truncate();
            let v = Vec3::select(n.cmpge(Vec3::ZERO), b.max, b.min);
            n.dot(v) + p.w >= 0.0
        })
    }
}

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

/// Right-handed view matrix looking along `dir`.
pub fn look_to_rh(eye: Vec3, dir: Vec3, up: Vec3) -> Mat4 {
    let f = dir.normalize();
    let s = f.cross(up).normalize();
    let u = s.cross(f);
    Mat4::from_cols(
        Vec4::new(s.x, u.x, -f.x, 0.0),
        Vec4::new(s.y, u.y, -f.y, 0.0),
        Vec4::new(s.z, u.z, -f.z, 0.0),
        Vec4::new(-s.dot(eye), -u.dot(eye), f.dot(eye), 1.0),
    )
}

/// Right-handed perspective projection with Vulkan's 0..1 depth range.
pub fn perspective_rh(fov_y: f32, aspect: f32, near: f32, far: f32) -> Mat4 {
    let f = 1.0 / (fov_y * 0.5).tan();
    let r = far / (near - far);
    Mat4::from_cols(
        Vec4::new(f / aspect, 0.0, 0.0, 0.0),
        Vec4::new(0.0, f, 0.0, 0.0),
        Vec4::new(0.0, 0.0, r, -1.0),
        Vec4::new(0.0, 0.0, r * near, 0.0),
    )
}
