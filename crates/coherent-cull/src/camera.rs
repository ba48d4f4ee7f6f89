//! Camera math: a perspective [`Camera`], the [`CameraView`] a culler takes each frame (any
//! projection, plain arrays or `mint` types in), [`Frustum`] planes, the [`DepthConvention`] and
//! the projections engines use (reverse-Z, infinite far, off-axis, orthographic).

use glam::{Mat4, Vec3, Vec4};

use crate::Aabb;

/// A camera pose: where the eye is and the point it looks at.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraPose {
    /// Eye position.
    pub eye: Vec3,
    /// Point looked at.
    pub target: Vec3,
}

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

/// The near plane distance of [`Camera::from_pose`] (scene units): geometry closer to the eye
/// than this is clipped away, so an eye this close to a surface sees through it.
pub const NEAR_PLANE: f32 = 0.1;

impl Camera {
    /// A camera at `pose` with a 60° field of view and the near plane [`NEAR_PLANE`].
    pub fn from_pose(pose: CameraPose, aspect: f32, far: f32) -> Camera {
        Camera {
            eye: pose.eye,
            target: pose.target,
            fov_y: 60f32.to_radians(),
            aspect,
            near: NEAR_PLANE,
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
    /// Whether the box lies entirely inside every plane (so every box inside it intersects).
    pub fn contains(&self, b: &Aabb) -> bool {
        self.planes.iter().all(|p| {
            let n = p.truncate();
            let v = Vec3::select(n.cmpge(Vec3::ZERO), b.min, b.max);
            n.dot(v) + p.w >= 0.0
        })
    }
    /// Every plane, as a mask for [`Frustum::cut_planes`].
    pub const ALL_PLANES: u8 = 0b11_1111;

    /// The box against the planes of `mask` (bit `i`: `planes[i]`): `None` when it lies
    /// entirely outside one of them, else the mask of those that cut it (0: inside them all).
    /// With [`Frustum::ALL_PLANES`], `None` is `!intersects` and `Some(0)` is `contains`; a
    /// box inside another needs testing only against the planes that cut the outer one.
    pub fn cut_planes(&self, b: &Aabb, mask: u8) -> Option<u8> {
        let mut cut = 0;
        for (i, p) in self.planes.iter().enumerate() {
            let bit = 1u8 << i;
            if mask & bit == 0 {
                continue;
            }
            let n = p.truncate();
            let positive = n.cmpge(Vec3::ZERO);
            if n.dot(Vec3::select(positive, b.max, b.min)) + p.w < 0.0 {
                return None;
            }
            if n.dot(Vec3::select(positive, b.min, b.max)) + p.w < 0.0 {
                cut |= bit;
            }
        }
        Some(cut)
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

/// How a clip matrix maps depth: the near plane to 0 (standard) or to 1 (reverse-Z), and whether
/// the far plane is at infinity (then the frustum has no far plane).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DepthConvention {
    /// Near maps to depth 1 and far to 0.
    pub reverse_z: bool,
    /// No far plane (an infinite perspective projection).
    pub infinite_far: bool,
}

impl DepthConvention {
    /// Near at 0, far at 1 (what [`Camera::projection`] produces).
    pub const STANDARD: DepthConvention = DepthConvention {
        reverse_z: false,
        infinite_far: false,
    };
    /// Near at 1, far at 0.
    pub const REVERSE_Z: DepthConvention = DepthConvention {
        reverse_z: true,
        infinite_far: false,
    };
    /// Near at 1, far at infinity (depth 0): what most engines ship.
    pub const REVERSE_Z_INFINITE: DepthConvention = DepthConvention {
        reverse_z: true,
        infinite_far: true,
    };
}

/// A culler's per-frame camera input: world-to-clip matrix (x, y in -1..1, depth 0..1 in
/// `depth`'s convention), the eye position and the depth
/// convention. Any projection works: perspective, off-axis, jittered, orthographic, infinite.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraView {
    /// World to clip.
    pub view_proj: Mat4,
    /// Eye position (for an orthographic view, any point on the view axis).
    pub eye: Vec3,
    /// Depth convention of `view_proj`.
    pub depth: DepthConvention,
    /// The pixel grid the frame is rasterized on, when the host knows it
    /// ([`CameraView::with_pixel_grid`]); `None`: the frustum alone decides what is in view.
    pub pixel_grid: Option<PixelGrid>,
}

/// The pixels a view is rasterized on: a viewport of `width` x `height` pixels at a
/// whole-pixel offset (its height may be negative in Vulkan: the grid is the same), one sample
/// per pixel at its centre (`rasterizationSamples` 1).
///
/// Rasterization covers a sample only where a triangle holds the sample's point, so an object
/// whose bounding box projects between pixel centres, holding none of them, can own no pixel:
/// with a grid the cullers treat it as outside the frustum (exact, unlike culling by a size
/// threshold). Far along a long street a car or a lamp often falls between the centres, and its
/// box still shows through the sky around it. A margin of 1/8 pixel covers the rasterizer's
/// sub-pixel snapping (Vulkan requires at least 4 bits, 1/16 pixel) and rounding.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PixelGrid {
    /// Viewport width in pixels.
    pub width: u32,
    /// Viewport height in pixels.
    pub height: u32,
}

impl PixelGrid {
    /// How far (pixels) beyond a projected box a triangle inside it may still cover a centre.
    pub const MARGIN: f32 = 0.125;

    /// Whether the screen rectangle `lo..hi` (framebuffer pixels, y either way up), grown by
    /// [`PixelGrid::MARGIN`], holds the centre of a pixel of the grid.
    pub fn holds_centre(&self, lo: [f32; 2], hi: [f32; 2]) -> bool {
        let size = [self.width as f32, self.height as f32];
        (0..2).all(|a| {
            // Centres lie at i + 0.5 for i in 0..size.
            let first = (lo[a] - Self::MARGIN - 0.5).ceil().max(0.0);
            let last = (hi[a] + Self::MARGIN - 0.5).floor().min(size[a] - 1.0);
            first <= last
        })
    }
}

impl CameraView {
    /// A view from plain arrays or any `mint` type (glam, nalgebra and cgmath convert to
    /// them): `view_proj` column-major world-to-clip, `eye` the eye position.
    pub fn new(
        view_proj: impl Into<mint::ColumnMatrix4<f32>>,
        eye: impl Into<mint::Point3<f32>>,
        depth: DepthConvention,
    ) -> CameraView {
        let m: [[f32; 4]; 4] = view_proj.into().into();
        let e: [f32; 3] = eye.into().into();
        CameraView {
            view_proj: Mat4::from_cols_array_2d(&m),
            eye: Vec3::from_array(e),
            depth,
            pixel_grid: None,
        }
    }

    /// The same view, rasterized on a `width` x `height` grid with one sample per pixel (see
    /// [`PixelGrid`]): objects that fall between pixel centres are culled with those outside
    /// the frustum. Leave it out for multisampled or otherwise sampled frames. A zero size
    /// is taken as no grid.
    pub fn with_pixel_grid(mut self, width: u32, height: u32) -> CameraView {
        self.pixel_grid = (width > 0 && height > 0).then_some(PixelGrid { width, height });
        self
    }

    /// Whether `b` may cover a pixel centre of the view's grid: true without a grid, or when
    /// a corner of `b` lies at or behind the eye plane (its projection is unbounded there).
    pub fn may_cover_centre(&self, b: &Aabb) -> bool {
        let Some(grid) = self.pixel_grid else {
            return true;
        };
        let Some((lo, hi)) = projected_rect(&self.view_proj, b) else {
            return true;
        };
        let size = glam::Vec2::new(grid.width as f32, grid.height as f32);
        let to_pixels = |ndc: glam::Vec2| ((ndc * 0.5 + 0.5) * size).to_array();
        grid.holds_centre(to_pixels(lo), to_pixels(hi))
    }
    /// The view frustum: near and far planes by the depth convention, no far plane if infinite.
    pub fn frustum(&self) -> Frustum {
        Frustum::from_matrix_with(&self.view_proj, self.depth)
    }
    /// Whether the projection is orthographic (clip w does not depend on the position).
    pub fn is_orthographic(&self) -> bool {
        let w = self.view_proj.row(3);
        w.truncate().length() <= 1e-6 * w.w.abs()
    }
    /// The four corners of the near-plane rectangle in world space.
    pub fn near_corners(&self) -> [Vec3; 4] {
        let inv = self.view_proj.inverse();
        let z = if self.depth.reverse_z { 1.0 } else { 0.0 };
        [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
            .map(|(x, y)| inv.project_point3(Vec3::new(x, y, z)))
    }
    /// Unit view direction: the near plane's inward normal.
    pub fn forward(&self) -> Vec3 {
        self.frustum().planes[4].truncate()
    }
    /// The point front-to-back order measures distance from: the eye for a perspective view;
    /// for an orthographic one, a point far behind the near plane on the view axis, so that
    /// distance grows with depth along the (parallel) view rays.
    pub fn order_point(&self) -> Vec3 {
        if !self.is_orthographic() {
            return self.eye;
        }
        let c = self.near_corners();
        let center = (c[0] + c[1] + c[2] + c[3]) * 0.25;
        center - self.forward() * 1.0e4
    }
}

impl From<&Camera> for CameraView {
    fn from(c: &Camera) -> CameraView {
        CameraView {
            view_proj: c.view_proj(),
            eye: c.eye,
            depth: DepthConvention::STANDARD,
            pixel_grid: None,
        }
    }
}

impl From<&CameraView> for CameraView {
    fn from(v: &CameraView) -> CameraView {
        *v
    }
}

impl Frustum {
    /// Extracts the planes of a clip matrix in a depth convention; an infinite far plane
    /// becomes a plane every point is inside of.
    pub fn from_matrix_with(m: &Mat4, depth: DepthConvention) -> Frustum {
        let (r0, r1, r2, r3) = (m.row(0), m.row(1), m.row(2), m.row(3));
        let (near, far) = if depth.reverse_z {
            (r3 - r2, r2)
        } else {
            (r2, r3 - r2)
        };
        let far = if depth.infinite_far {
            Vec4::new(0.0, 0.0, 0.0, 1.0)
        } else {
            far
        };
        let planes = [r3 + r0, r3 - r0, r3 + r1, r3 - r1, near, far];
        Frustum {
            planes: planes.map(|p| p / p.truncate().length().max(1e-20)),
        }
    }
}

/// The rectangle (normalized device x and y) around the projections of `b`'s corners by
/// `view_proj`; `None` when a corner lies at or behind the eye plane (or the matrix gives NaN),
/// where the projection has no bound.
pub(crate) fn projected_rect(view_proj: &Mat4, b: &Aabb) -> Option<(glam::Vec2, glam::Vec2)> {
    let mut lo = glam::Vec2::INFINITY;
    let mut hi = glam::Vec2::NEG_INFINITY;
    for corner in b.corners() {
        let c = *view_proj * corner.extend(1.0);
        if c.w.is_nan() || c.w <= 1e-6 * c.truncate().length().max(1.0) {
            return None;
        }
        let ndc = glam::Vec2::new(c.x, c.y) / c.w;
        lo = lo.min(ndc);
        hi = hi.max(ndc);
    }
    Some((lo, hi))
}

/// Right-handed reverse-Z perspective projection with an infinite far plane (near at depth 1,
/// infinity at 0): the projection most engines use.
pub fn perspective_infinite_reverse_rh(fov_y: f32, aspect: f32, near: f32) -> Mat4 {
    let f = 1.0 / (fov_y * 0.5).tan();
    Mat4::from_cols(
        Vec4::new(f / aspect, 0.0, 0.0, 0.0),
        Vec4::new(0.0, f, 0.0, 0.0),
        Vec4::new(0.0, 0.0, 0.0, -1.0),
        Vec4::new(0.0, 0.0, near, 0.0),
    )
}

/// Right-handed reverse-Z perspective projection with a finite far plane (near at depth 1,
/// far at 0).
pub fn perspective_reverse_rh(fov_y: f32, aspect: f32, near: f32, far: f32) -> Mat4 {
    let f = 1.0 / (fov_y * 0.5).tan();
    let r = far / (near - far);
    Mat4::from_cols(
        Vec4::new(f / aspect, 0.0, 0.0, 0.0),
        Vec4::new(0.0, f, 0.0, 0.0),
        Vec4::new(0.0, 0.0, -1.0 - r, -1.0),
        Vec4::new(0.0, 0.0, -r * near, 0.0),
    )
}

/// Right-handed off-axis (asymmetric) perspective projection, depth 0..1: the near-plane
/// rectangle spans `left..right` and `bottom..top` at distance `near`.
pub fn frustum_rh(left: f32, right: f32, bottom: f32, top: f32, near: f32, far: f32) -> Mat4 {
    let (w, h) = (right - left, top - bottom);
    let r = far / (near - far);
    Mat4::from_cols(
        Vec4::new(2.0 * near / w, 0.0, 0.0, 0.0),
        Vec4::new(0.0, 2.0 * near / h, 0.0, 0.0),
        Vec4::new((right + left) / w, (top + bottom) / h, r, -1.0),
        Vec4::new(0.0, 0.0, r * near, 0.0),
    )
}

/// Right-handed orthographic projection, depth 0..1.
pub fn orthographic_rh(left: f32, right: f32, bottom: f32, top: f32, near: f32, far: f32) -> Mat4 {
    let (w, h, d) = (right - left, top - bottom, far - near);
    Mat4::from_cols(
        Vec4::new(2.0 / w, 0.0, 0.0, 0.0),
        Vec4::new(0.0, 2.0 / h, 0.0, 0.0),
        Vec4::new(0.0, 0.0, -1.0 / d, 0.0),
        Vec4::new(-(right + left) / w, -(top + bottom) / h, -near / d, 1.0),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    /// A box holds a pixel centre (i + 0.5) of the grid only where its projection, grown by
    /// the margin, reaches one on both axes inside the grid; a box at or behind the eye plane,
    /// or a view without a grid, may cover any.
    #[test]
    fn pixel_centres_decide_what_a_box_may_cover() {
        // World x and y are framebuffer pixels: a 10 x 4 grid seen along -z.
        let m = orthographic_rh(0.0, 10.0, 0.0, 4.0, 0.1, 100.0)
            * look_to_rh(Vec3::ZERO, Vec3::NEG_Z, Vec3::Y);
        let view = CameraView::new(m.to_cols_array_2d(), [0.0; 3], DepthConvention::STANDARD)
            .with_pixel_grid(10, 4);
        let at = |x0: f32, x1: f32, y0: f32, y1: f32| {
            view.may_cover_centre(&Aabb::new(Vec3::new(x0, y0, -6.0), Vec3::new(x1, y1, -5.0)))
        };
        assert!(!at(1.7, 2.2, 0.2, 0.8), "between the centres 1.5 and 2.5");
        assert!(at(2.4, 2.6, 0.2, 0.8), "holds (2.5, 0.5)");
        assert!(!at(2.4, 2.6, 0.7, 1.3), "x holds one, y none");
        assert!(at(2.3, 2.45, 0.2, 0.8), "2.5 lies within the margin");
        assert!(!at(2.3, 2.35, 0.2, 0.8), "2.5 lies beyond the margin");
        assert!(
            !at(-1.0, 0.3, 0.2, 0.8),
            "its part on the grid holds no centre"
        );
        assert!(!at(9.8, 12.0, 0.2, 0.8), "the centre 10.5 is off the grid");
        assert!(at(-5.0, 50.0, -5.0, 50.0), "covers the grid");
        let mut plain = view;
        plain.pixel_grid = None;
        assert!(plain.may_cover_centre(&Aabb::new(
            Vec3::new(1.7, 0.2, -6.0),
            Vec3::new(2.2, 0.8, -5.0)
        )));
        assert_eq!(view.with_pixel_grid(0, 4).pixel_grid, None);
        // In perspective, a box reaching behind the eye projects without bound.
        let p = perspective_rh(1.0, 2.5, 0.1, 100.0) * look_to_rh(Vec3::ZERO, Vec3::NEG_Z, Vec3::Y);
        let persp = CameraView::new(p.to_cols_array_2d(), [0.0; 3], DepthConvention::STANDARD)
            .with_pixel_grid(10, 4);
        let tiny = Aabb::new(Vec3::new(0.001, 0.001, -1.0), Vec3::new(0.002, 0.002, 1.0));
        assert!(persp.may_cover_centre(&tiny));
        let far = Aabb::new(
            Vec3::new(0.001, 0.001, -50.0),
            Vec3::new(0.002, 0.002, -49.0),
        );
        assert!(
            !persp.may_cover_centre(&far),
            "far off the centres near the middle"
        );
    }

    /// `cut_planes` with every plane agrees with `intersects` and `contains`; with the planes
    /// that cut an enclosing box it gives a box inside it the same answer as with all planes.
    #[test]
    fn cut_planes_agree_with_intersects_and_contains() {
        let view = look_to_rh(Vec3::ZERO, Vec3::new(0.3, -0.1, -1.0), Vec3::Y);
        let f = Frustum::from_matrix(&(perspective_infinite_reverse_rh(1.0, 1.5, 0.1) * view));
        let mut rng = Rng::new(7);
        let mut v = |scale: f32| {
            Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 2.0 * scale - Vec3::splat(scale)
        };
        let (mut outside, mut inside, mut cut) = (0, 0, 0);
        for _ in 0..2000 {
            let c = v(40.0);
            let outer = Aabb::new(c - v(6.0).abs(), c + v(6.0).abs());
            let all = f.cut_planes(&outer, Frustum::ALL_PLANES);
            assert_eq!(all.is_some(), f.intersects(&outer));
            assert_eq!(all == Some(0), f.contains(&outer));
            match all {
                None => outside += 1,
                Some(0) => inside += 1,
                Some(mask) => {
                    cut += 1;
                    let a = outer.min + (outer.max - outer.min) * 0.25;
                    let inner = Aabb::new(a, a + (outer.max - outer.min) * 0.5);
                    let masked = f.cut_planes(&inner, mask);
                    let full = f.cut_planes(&inner, Frustum::ALL_PLANES);
                    assert_eq!(masked.is_some(), full.is_some());
                    assert_eq!(masked == Some(0), full == Some(0));
                }
            }
        }
        assert!(
            outside > 0 && inside > 0 && cut > 0,
            "{outside} {inside} {cut}"
        );
    }
}
