//! Moving objects in GI (`gi --movers N`, and what a glTF file's animation moves): the movers
//! as world-space triangles that follow their transforms frame by frame (the renderer's vertex
//! tail, the ray scene's mover hierarchy, the imperfect shadow maps' points), and which VPLs a
//! move affects. A mesh that the animation deforms (a skin, morph weights) is posed each frame:
//! its triangles keep the split of its first pose ([`Piece`]s placed on the posed corners), so
//! the renderer's triangle count never changes.
//! Incremental instant radiosity deletes the VPLs that lay on a moved object (their surface is
//! gone) and re-renders the shadow maps of the VPLs whose hemisphere holds the object's old or
//! new box (the map may have changed there); every other map is kept.

use glam::{Mat3, Mat4, Vec3};

use super::geometry::{Piece, WorldGeometry};
use super::vpl::Vpl;
use crate::error::Result;
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
    /// For each mover whose mesh the animation deforms: how to pose its triangles.
    shapes: Vec<Option<Shape>>,
}

/// How a deformed mover's triangles follow its posed vertices.
#[derive(Clone, Debug)]
struct Shape {
    /// The scene's vertex where the deformed mesh starts (as [`Movers::for_each_deformed`]
    /// passes it).
    first_vertex: u32,
    /// The object's triangles as scene vertex indices.
    corners: Vec<[u32; 3]>,
    /// The pieces the first pose's triangles were split into.
    pieces: Vec<Piece>,
    /// Scratch: the posed triangles and their normals.
    posed: (Vec<[Vec3; 3]>, Vec<[Vec3; 3]>),
}

impl Shape {
    /// The mover's triangles (`rest`: split, with albedo and masks) on `vertices`, the posed
    /// vertices of the mesh that starts at `first_vertex`.
    fn pose(&mut self, rest: &WorldGeometry, vertices: &[crate::scene::Vertex]) -> WorldGeometry {
        let (triangles, normals) = &mut self.posed;
        triangles.clear();
        normals.clear();
        for c in &self.corners {
            let v = c.map(|i| {
                (i.checked_sub(self.first_vertex))
                    .and_then(|k| vertices.get(k as usize))
                    .map_or((Vec3::ZERO, Vec3::Y), |v| {
                        (
                            Vec3::from(v.position),
                            Vec3::from(v.normal).normalize_or_zero(),
                        )
                    })
            });
            triangles.push(v.map(|(p, _)| p));
            normals.push(v.map(|(_, n)| n));
        }
        rest.reshaped(&self.pieces, triangles, normals)
    }
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
        let mut shapes = Vec::with_capacity(movers.len());
        let mut mips = crate::gi::geometry::TextureMips::default();
        for i in 0..movers.len() {
            let object = movers.object(i) as usize;
            let geometry = WorldGeometry::object_local(scene, object, &mut mips);
            let t = movers.transform_at(i, 0);
            let (split, shape) = Self::split(scene, &movers, i, &geometry, &t, max_edge);
            local.push(split);
            shapes.push(shape);
            boxes.push(local[i].bounds.transformed(&t));
            transforms.push(t);
        }
        GiMovers {
            movers,
            local,
            transforms,
            boxes,
            shapes,
        }
    }

    /// Mover `i`'s `geometry` (in its own space) split so that no edge is longer than
    /// `max_edge` once placed by `t` in its first pose, and posed as the scene's vertices are
    /// when its mesh is deformed (with the shape that poses it from then on). The split is
    /// made on the placed, posed triangles, since the placement or the pose may stretch them
    /// (a scaled node, a skinned mesh whose bind pose is in other units): slightly shorter
    /// than the static edges, so that placing the pieces (exact only up to rounding) never
    /// makes the renderer split them again.
    fn split(
        scene: &Scene,
        movers: &Movers,
        i: usize,
        geometry: &WorldGeometry,
        t: &Mat4,
        max_edge: f32,
    ) -> (WorldGeometry, Option<Shape>) {
        let object = movers.object(i) as usize;
        let vertices = |first: u32| scene.vertices.get(first as usize..).unwrap_or_default();
        let mut shape = movers.deformed_first_vertex(i).map(|first_vertex| {
            // Each triangle whole until the split below.
            let whole = (0..geometry.triangles.len() as u32)
                .map(|source| Piece {
                    source,
                    weights: [Vec3::X, Vec3::Y, Vec3::Z],
                })
                .collect();
            let o = &scene.objects[object];
            let range = o.first_index as usize..(o.first_index + o.index_count) as usize;
            let corners = scene.indices.get(range).unwrap_or_default();
            Shape {
                first_vertex,
                corners: corners
                    .chunks_exact(3)
                    .map(|t| [0, 1, 2].map(|k| o.vertex_offset + t[k]))
                    .collect(),
                pieces: whole,
                posed: Default::default(),
            }
        });
        let placed = match &mut shape {
            Some(s) => s.pose(geometry, vertices(s.first_vertex)).placed(t),
            None => geometry.placed(t),
        };
        let (_, pieces) = placed.tessellated_pieces(max_edge * 0.999);
        let rest = geometry.pieces_of(&pieces);
        match shape {
            Some(mut s) => {
                s.pieces = pieces;
                // The first pose through the same interpolation as every later one, so that
                // an unchanged pose reads as unchanged.
                let posed = s.pose(&rest, vertices(s.first_vertex));
                (posed, Some(s))
            }
            None => (rest, None),
        }
    }

    /// Number of movers.
    pub fn len(&self) -> usize {
        self.movers.len()
    }

    /// The glTF file's animation they play ([`Movers::animation_label`]).
    pub fn animation_label(&self) -> Option<&str> {
        self.movers.animation_label()
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

    /// Moves every mover to its place at `frame` and poses the meshes the animation deforms;
    /// returns the moves of those whose transform or shape changed.
    pub fn advance(&mut self, frame: u64) -> Result<Vec<Move>> {
        let mut reshaped = vec![false; self.movers.len()];
        if self.shapes.iter().any(Option::is_some) {
            let (shapes, local) = (&mut self.shapes, &mut self.local);
            self.movers.for_each_deformed(frame, |first, vertices| {
                for (i, shape) in shapes.iter_mut().enumerate() {
                    let Some(shape) = shape.as_mut().filter(|s| s.first_vertex == first) else {
                        continue;
                    };
                    let posed = shape.pose(&local[i], vertices);
                    if posed.triangles != local[i].triangles || posed.normals != local[i].normals {
                        local[i] = posed;
                        reshaped[i] = true;
                    }
                }
                Ok(())
            })?;
        }
        let mut moves = Vec::new();
        for (i, reshaped) in reshaped.into_iter().enumerate() {
            let t = self.movers.transform_at(i, frame);
            if t == self.transforms[i] && !reshaped {
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
        Ok(moves)
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
            textures: self.textures.clone(),
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

    fn area(g: &WorldGeometry) -> f32 {
        g.triangles
            .iter()
            .map(|t| 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length())
            .sum()
    }

    /// A skinned and a morphed column (1 x 1 x 1, its top lifted by 4 at 1 s): split into
    /// pieces, its triangles follow the pose each frame with the same count, its surface is
    /// the posed column's, and a pose that changes nothing moves nothing.
    #[test]
    fn deformed_movers_keep_their_pieces_on_the_posed_shape() {
        use crate::scene::gltf::testdata::{morphed_column, skinned_column};
        let dir = crate::testing::TempDir::new("gi_deformed");
        for (name, b) in [
            ("skinned", skinned_column(4.0)),
            ("morphed", morphed_column(4.0)),
        ] {
            let path = dir.path().join(format!("{name}.gltf"));
            std::fs::write(&path, b.gltf_embedded()).unwrap();
            let mut scene = Scene::load(path.to_str().unwrap(), 1.0, 0).unwrap();
            let movers = Movers::add(&mut scene, 0);
            assert!(movers.deformed_first_vertex(0).is_some(), "{name}");
            let mut gi = GiMovers::new(&scene, movers, 0.3);
            let count = gi.geometry().triangles.len();
            assert!(count > 12 * 8, "{name}: split into pieces ({count})");
            let rest = gi.geometry();
            assert!((area(&rest) - 6.0).abs() < 1e-4, "{name}: {}", area(&rest));
            assert!(
                gi.advance(0).unwrap().is_empty(),
                "{name}: frame 0 is the rest pose"
            );
            // 1 s: the top lifted by 4, the box 5 high; the pieces cover the posed column.
            let moves = gi.advance(30).unwrap();
            assert_eq!(moves.len(), 1, "{name}");
            assert_eq!(moves[0].old, rest.bounds, "{name}");
            assert!((moves[0].new.max.y - moves[0].old.max.y - 4.0).abs() < 1e-5);
            let posed = gi.geometry();
            assert_eq!(posed.triangles.len(), count, "{name}");
            assert_eq!(posed.bounds, moves[0].new, "{name}");
            assert!(
                (area(&posed) - 22.0).abs() < 1e-3,
                "{name}: {}",
                area(&posed)
            );
            // The side pieces' normals stay horizontal; the same frame again moves nothing.
            for (t, n) in posed.triangles.iter().zip(&posed.normals) {
                let side = t.iter().any(|p| p.y > 0.1 + moves[0].new.min.y)
                    && t.iter().any(|p| p.y < moves[0].new.max.y - 0.1);
                if side {
                    assert!(n.iter().all(|n| n.y.abs() < 1e-5), "{name}: {n:?}");
                }
            }
            assert!(gi.advance(30).unwrap().is_empty(), "{name}");
            // Back at the start of the loop: the rest shape again.
            assert_eq!(gi.advance(60).unwrap().len(), 1, "{name}");
            assert_eq!(gi.geometry().triangles, rest.triangles, "{name}");
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
