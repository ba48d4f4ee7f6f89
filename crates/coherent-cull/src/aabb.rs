//! The axis-aligned box every test is made of: object bounds, node boxes, query boxes.

use glam::{Mat4, Vec3};

/// Axis-aligned bounding box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// The smallest corner.
    pub min: Vec3,
    /// The largest corner.
    pub max: Vec3,
}

impl Aabb {
    /// The empty box (min = +inf, max = -inf); growing it with any point makes it valid.
    pub const EMPTY: Aabb = Aabb {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
    };

    /// The box from `min` to `max`.
    pub fn new(min: Vec3, max: Vec3) -> Self {
        Aabb { min, max }
    }
    /// Grows the box to contain `p`.
    pub fn grow(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }
    /// The smallest box containing both.
    pub fn union(&self, o: &Aabb) -> Aabb {
        Aabb {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }
    /// Whether `min <= max` on every axis and both corners are finite.
    pub fn is_valid(&self) -> bool {
        self.min.cmple(self.max).all() && self.min.is_finite() && self.max.is_finite()
    }
    /// The centre point.
    pub fn center(&self) -> Vec3 {
        (self.min + self.max) * 0.5
    }
    /// `max - min`.
    pub fn extent(&self) -> Vec3 {
        self.max - self.min
    }
    /// Surface area (0 for an empty box).
    pub fn surface_area(&self) -> f32 {
        let e = self.extent().max(Vec3::ZERO);
        2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
    }
    /// Whether `p` is inside or on the boundary.
    pub fn contains(&self, p: Vec3) -> bool {
        p.cmpge(self.min).all() && p.cmple(self.max).all()
    }
    /// Whether the two closed boxes share a point (touching counts).
    pub fn overlaps(&self, other: &Aabb) -> bool {
        self.min.cmple(other.max).all() && other.min.cmple(self.max).all()
    }
    /// Squared distance from `p` to the box (0 inside).
    pub fn distance_squared(&self, p: Vec3) -> f32 {
        let d = (self.min - p).max(p - self.max).max(Vec3::ZERO);
        d.length_squared()
    }
    /// The box grown by `by` on every side.
    pub fn enlarged(&self, by: f32) -> Aabb {
        Aabb {
            min: self.min - Vec3::splat(by),
            max: self.max + Vec3::splat(by),
        }
    }
    /// The eight corners; bit 0 of the index picks max x, bit 1 max y, bit 2 max z.
    pub fn corners(&self) -> [Vec3; 8] {
        std::array::from_fn(|i| {
            Vec3::new(
                if i & 1 == 0 { self.min.x } else { self.max.x },
                if i & 2 == 0 { self.min.y } else { self.max.y },
                if i & 4 == 0 { self.min.z } else { self.max.z },
            )
        })
    }
    /// The box around this box transformed by `m`.
    pub fn transformed(&self, m: &Mat4) -> Aabb {
        let mut out = Aabb::EMPTY;
        for c in self.corners() {
            out.grow(m.transform_point3(c));
        }
        out
    }
}

/// Interop: boxes from and to plain arrays or `mint` points, so a host needs no glam (or this
/// crate's glam version).
impl Aabb {
    /// A box from its corners as plain arrays (`[f32; 3]`) or any `mint` point (glam,
    /// nalgebra and cgmath convert to them).
    pub fn from_min_max(
        min: impl Into<mint::Point3<f32>>,
        max: impl Into<mint::Point3<f32>>,
    ) -> Aabb {
        let (min, max): ([f32; 3], [f32; 3]) = (min.into().into(), max.into().into());
        Aabb::new(Vec3::from_array(min), Vec3::from_array(max))
    }
    /// The corners `[min, max]` as plain arrays.
    pub fn to_arrays(&self) -> [[f32; 3]; 2] {
        [self.min.to_array(), self.max.to_array()]
    }
}

impl From<[[f32; 3]; 2]> for Aabb {
    fn from([min, max]: [[f32; 3]; 2]) -> Aabb {
        Aabb::from_min_max(min, max)
    }
}

impl From<Aabb> for [[f32; 3]; 2] {
    fn from(b: Aabb) -> [[f32; 3]; 2] {
        b.to_arrays()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn boxes_overlap_when_they_share_a_point() {
        let a = Aabb::new(Vec3::ZERO, Vec3::ONE);
        let inside = Aabb::new(Vec3::splat(0.25), Vec3::splat(0.5));
        let touching = Aabb::new(Vec3::new(1.0, 0.0, 0.0), Vec3::new(2.0, 1.0, 1.0));
        let apart = Aabb::new(Vec3::new(1.5, 0.0, 0.0), Vec3::new(2.0, 1.0, 1.0));
        let apart_in_z = Aabb::new(Vec3::new(0.0, 0.0, 2.0), Vec3::new(1.0, 1.0, 3.0));
        for (b, want) in [
            (inside, true),
            (touching, true),
            (apart, false),
            (apart_in_z, false),
        ] {
            assert_eq!(a.overlaps(&b), want, "{b:?}");
            assert_eq!(b.overlaps(&a), want, "{b:?} (swapped)");
        }
    }
}
