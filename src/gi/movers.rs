//! Moving objects in GI (`gi --movers N`): the scene's built-in movers as world-space triangles
//! that follow their transforms frame by frame (the renderer's vertex tail, the ray scene's
//! mover hierarchy, the imperfect shadow maps' points), and which VPLs a move affects.
//! Incremental instant radiosity deletes the VPLs that lay on a moved object (their surface is
//! gone) and re-renders the shadow maps of the VPLs whose hemisphere holds the object's old or
//! new box (the map may have changed there); every other map is kept.

use glam::{Mat3, Mat4, Vec3};

use super::geometry::WorldGeometry;
use super::vpl::Vpl;
use crate::scene::movers::Movers;
use crate::scene::{Aabb, Scene};

/// The movers of a GI run and their current places.
#[derive(Clone, Debug)]
pub struct GiMovers {
    movers: Movers,
    /// Each mover's triangles in object space (tessellated like the static ones).
    local: Vec<WorldGeometry>,
    /// Each mover's current transform.
    transforms: Vec<Mat4>,
    /// Each mover's current world box.
    boxes: Vec<Aabb>,
}

/// One mover's move between two frames: its world box before and after.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Move {
    /// The box before the move.
    pub old: Aabb,
    /// The box after the move.
    pub new: Aabb,
}

impl GiMovers {
    /// The movers of `scene` (added by [`Movers::add`]), placed at frame 0, their triangles
    /// split so that no edge is longer than `max_edge`.
    pub fn new(scene: &Scene, movers: Movers, max_edge: f32) -> GiMovers {
        let mut local = Vec::with_capacity(movers.len());
        let mut transforms = Vec::with_capacity(movers.len());
        let mut boxes = Vec::with_capacity(movers.len());
        for i in 0..movers.len() {
            let object = movers.object(i) as usize;
            let geometry = WorldGeometry::object_local(scene, object);
            // Slightly shorter than the static edges, so that placing the pieces (a rigid
            // motion, exact only up to rounding) never makes the renderer split them again.
            local.push(geometry.tessellated(max_edge * 0.999));
            let t = movers.transform_at(i, 0);
            boxes.push(local[i].bounds.transformed(&t));
            transforms.push(t);
        }
        GiMovers {
            movers,
            local,
            transforms,
            boxes,
        }
    }

    /// Number of movers.
    pub fn len(&self) -> usize {
        self.movers.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.movers.is_empty()
    }

    /// Every mover's triangles at its current place, in mover order.
    pub fn geometry(&self) -> WorldGeometry {
        let mut out = WorldGeometry::empty();
        for (g, t) in self.local.iter().zip(&self.transforms) {
            out.append(&g.placed(t));
        }
        out
    }

    /// Moves every mover to its place at `frame`; returns the moves of those whose transform
    /// changed.
    pub fn advance(&mut self, frame: u64) -> Vec<Move> {
        let mut moves = Vec::new();
        for i in 0..self.movers.len() {
            let t = self.movers.transform_at(i, frame);
            if t == self.transforms[i] {
                continue;
            }
            let new = self.local[i].bounds.transformed(&t);
            moves.push(Move {
                old: self.boxes[i],
                new,
            });
            self.transforms[i] = t;
            self.boxes[i] = new;
        }
        moves
    }
}

impl WorldGeometry {
    /// A copy moved by the rigid transform `t` (normals rotated with it).
    pub fn placed(&self, t: &Mat4) -> WorldGeometry {
        let rotation = Mat3::from_mat4(t.inverse().transpose());
        let mut bounds = Aabb::EMPTY;
        let triangles = self
            .triangles
            .iter()
            .map(|tri| {
                tri.map(|p| {
                    let q = t.transform_point3(p);
                    bounds.grow(q);
                    q
                })
            })
            .collect();
        let normals = self
            .normals
            .iter()
            .map(|n| n.map(|v| (rotation * v).normalize_or_zero()))
            .collect();
        WorldGeometry {
            triangles,
            normals,
            albedo: self.albedo.clone(),
            bounds,
            masks: self.masks.clone(),
        }
    }
}

/// Whether `vpl` lay on a moved object: its position is inside a move's old box (grown by
/// `eps`). Such a VPL's surface has gone, so it is deleted (and replaced within the budget).
pub fn on_moved_object(vpl: &Vpl, moves: &[Move], eps: f32) -> bool {
    moves
        .iter()
        .any(|m| m.old.enlarged(eps).contains(vpl.position))
}

/// Whether any part of `b` lies in front of the base plane of the hemisphere at `position`
/// with normal `normal` (further than `eps`): only then can it appear in that paraboloid map
/// (the shadow pass drops what is behind the plane).
pub fn box_in_hemisphere(b: &Aabb, position: Vec3, normal: Vec3, eps: f32) -> bool {
    if !b.is_valid() {
        return false;
    }
    let half = b.extent() * 0.5;
    let reach = (b.center() - position).dot(normal) + half.dot(normal.abs());
    reach > eps
}

/// The layers of the VPLs (other than those in `fresh`, rendered anyway) whose shadow map a
/// move may have changed: their hemisphere holds the mover's old or new box.
pub fn stale_layers(vpls: &[Vpl], moves: &[Move], fresh: &[u32], eps: f32) -> Vec<u32> {
    if moves.is_empty() {
        return Vec::new();
    }
    vpls.iter()
        .filter(|v| !fresh.contains(&v.layer))
        .filter(|v| {
            moves.iter().any(|m| {
                box_in_hemisphere(&m.old, v.position, v.normal, eps)
                    || box_in_hemisphere(&m.new, v.position, v.normal, eps)
            })
        })
        .map(|v| v.layer)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vpl(position: Vec3, normal: Vec3, layer: u32) -> Vpl {
        Vpl {
            id: u64::from(layer),
            position,
            normal,
            albedo: Vec3::ONE,
            disk_point: glam::Vec2::ZERO,
            weight: 0.1,
            layer,
        }
    }

    #[test]
    fn only_vpls_facing_a_moved_box_are_stale() {
        let unit = Aabb::new(Vec3::splat(-0.5), Vec3::splat(0.5));
        let moves = [Move {
            old: unit,
            new: Aabb::new(unit.min + Vec3::X, unit.max + Vec3::X),
        }];
        let vpls = [
            // Below the box, facing up: sees it.
            vpl(Vec3::new(0.0, -2.0, 0.0), Vec3::Y, 0),
            // Below the box, facing down: the box is behind its plane.
            vpl(Vec3::new(0.0, -2.0, 0.0), Vec3::NEG_Y, 1),
            // Beside the new box, facing away from both.
            vpl(Vec3::new(3.0, 0.0, 0.0), Vec3::X, 2),
            // On the far side facing back: sees the new box.
            vpl(Vec3::new(3.0, 0.0, 0.0), Vec3::NEG_X, 3),
        ];
        assert_eq!(stale_layers(&vpls, &moves, &[], 1e-4), vec![0, 3]);
        // A fresh VPL is rendered anyway and not listed twice.
        assert_eq!(stale_layers(&vpls, &moves, &[0], 1e-4), vec![3]);
        assert!(stale_layers(&vpls, &[], &[], 1e-4).is_empty());
        assert!(on_moved_object(&vpl(Vec3::ZERO, Vec3::Y, 4), &moves, 1e-3));
        assert!(!on_moved_object(&vpl(Vec3::X, Vec3::Y, 5), &moves, 1e-3));
    }
}
