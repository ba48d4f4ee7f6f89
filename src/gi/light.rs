//! The primary light of incremental instant radiosity: a 180° spotlight with
//! cosine-weighted emission. Directions map to the unit disk by Malley's method,
//! so uniformly spread disk points give cosine-distributed VPLs.

use glam::{Vec2, Vec3};

/// A hemispherical (180°) spotlight with cosine-weighted emission.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spotlight {
    /// World-space position.
    pub position: Vec3,
    /// Main emission direction (need not be normalized).
    pub direction: Vec3,
    /// Total emitted RGB flux.
    pub power: Vec3,
}

impl Spotlight {
    /// Creates a spotlight.
    pub fn new(position: Vec3, direction: Vec3, power: Vec3) -> Self {
        Self {
            position,
            direction,
            power,
        }
    }

    /// The unit direction the light points in (-Y for a zero direction).
    pub fn axis(&self) -> Vec3 {
        self.direction.try_normalize().unwrap_or(Vec3::NEG_Y)
    }

    /// Orthonormal light frame `(tangent, bitangent, direction)`, right-handed,
    /// well defined for any direction including straight up or down
    /// (Duff et al. 2017 branchless basis). A zero direction falls back to -Y.
    pub fn basis(&self) -> (Vec3, Vec3, Vec3) {
        let n = self.axis();
        let (t, b) = n.any_orthonormal_pair();
        (t, b, n)
    }

    /// Malley's method: unit-disk point `p` to the world direction
    /// `(x, y, sqrt(1 - x² - y²))` in the light frame. Points outside the disk
    /// are clamped onto its rim.
    pub fn disk_to_direction(&self, p: Vec2) -> Vec3 {
        let p = if p.length_squared() > 1.0 {
            p.normalize()
        } else {
            p
        };
        let z = (1.0 - p.length_squared()).max(0.0).sqrt();
        let (t, b, n) = self.basis();
        (t * p.x + b * p.y + n * z).normalize()
    }

    /// Inverse of [`Spotlight::disk_to_direction`] for the direction towards
    /// `world_point`; `None` when the point is not strictly in front of the light
    /// (light-frame z <= 0) or coincides with the light position.
    pub fn direction_to_disk(&self, world_point: Vec3) -> Option<Vec2> {
        let d = (world_point - self.position).try_normalize()?;
        let (t, b, n) = self.basis();
        if d.dot(n) <= 0.0 {
            return None;
        }
        Some(Vec2::new(d.dot(t), d.dot(b)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn basis_is_orthonormal_for_all_directions() {
        for dir in [
            Vec3::Y,
            Vec3::NEG_Y,
            Vec3::Z,
            Vec3::NEG_Z,
            Vec3::new(1.0, -2.0, 0.3),
        ] {
            let light = Spotlight::new(Vec3::ZERO, dir, Vec3::ONE);
            let (t, b, n) = light.basis();
            assert!(t.is_normalized() && b.is_normalized() && n.is_normalized());
            assert!(t.dot(b).abs() < 1e-5 && t.dot(n).abs() < 1e-5 && b.dot(n).abs() < 1e-5);
            assert!((t.cross(b) - n).length() < 1e-5);
        }
    }

    #[test]
    fn disk_round_trip() {
        let light = Spotlight::new(Vec3::new(0.0, 2.0, 0.0), Vec3::NEG_Y, Vec3::ONE);
        let p = Vec2::new(0.3, -0.5);
        let d = light.disk_to_direction(p);
        let q = light.direction_to_disk(light.position + 3.0 * d).unwrap();
        assert!((p - q).length() < 1e-5);
        assert_eq!(light.disk_to_direction(Vec2::ZERO), Vec3::NEG_Y);
        assert!(light.direction_to_disk(Vec3::new(0.0, 3.0, 0.0)).is_none());
        assert!(light.direction_to_disk(Vec3::new(1.0, 2.0, 0.0)).is_none());
    }
}
