//! The default pose of glTF meshes: morph targets at their default weights and skins at their
//! joints' node transforms, applied to the vertices once at load. A skin whose joints the
//! first animation moves keeps its vertices' influences ([`Influences`]) and is posed again
//! each frame ([`super::animation::Animation::pose_skins`]).
//!
//! glTF 2.0 (sections "Morph Targets" and "Skins"): a morphed position is the base position
//! plus the sum of each target's displacement times its weight (the node's `weights`, else the
//! mesh's, else 0). A skinned vertex is `sum_i w_i * J_i * v` with `J_i` the world transform of
//! joint `i` times its inverse bind matrix; the transform of the node that holds the skinned
//! mesh is ignored, so skinned vertices come out in world space.

use ::gltf::accessor::{DataType, Dimensions};
use ::gltf::buffer::Data;
use ::gltf::mesh::Semantic;
use ::gltf::{Document, Node, Primitive, Skin};
use glam::{Mat3, Mat4, Vec3};

use super::gltf_draco::DracoPrimitive;

/// Most `JOINTS_n`/`WEIGHTS_n` sets read per vertex (four influences each).
const MAX_INFLUENCE_SETS: u32 = 4;

/// The world transform of every node that is reachable from a node without a parent (`None`
/// for the others, which only a cycle leaves out).
pub(super) fn all_world_transforms(doc: &Document) -> Vec<Option<Mat4>> {
    super::gltf_ext::world_transforms(doc, &super::gltf::parentless_nodes(doc))
}

/// The weights of `node`'s morph targets: its own `weights`, else its mesh's (empty: none).
pub(super) fn morph_weights(node: &Node<'_>) -> Vec<f32> {
    node.weights()
        .or_else(|| node.mesh().and_then(|m| m.weights()))
        .map(<[f32]>::to_vec)
        .unwrap_or_default()
}

/// `J_i` of each joint of `skin`: the joint's world transform times its inverse bind matrix
/// (the identity when the skin has none).
pub(super) fn joint_matrices(
    skin: &Skin<'_>,
    world: &[Option<Mat4>],
    buffers: &[Data],
) -> Result<Vec<Mat4>, String> {
    let label = format!("skin {}", skin.index());
    let inverse_bind = inverse_bind_matrices(skin, buffers)?;
    skin.joints()
        .zip(inverse_bind)
        .map(|(joint, ibm)| {
            let w =
                world.get(joint.index()).copied().flatten().ok_or_else(|| {
                    format!("{label}: joint node {} is in a cycle", joint.index())
                })?;
            let m = w * ibm;
            if m.is_finite() {
                Ok(m)
            } else {
                Err(format!(
                    "{label}: joint node {} has a non-finite matrix",
                    joint.index()
                ))
            }
        })
        .collect()
}

/// The inverse bind matrix of each joint of `skin` (the identity when it has none).
pub(super) fn inverse_bind_matrices(
    skin: &Skin<'_>,
    buffers: &[Data],
) -> Result<Vec<Mat4>, String> {
    let label = format!("skin {}", skin.index());
    let joints = skin.joints().len();
    let Some(acc) = skin.inverse_bind_matrices() else {
        return Ok(vec![Mat4::IDENTITY; joints]);
    };
    let at = |e: String| format!("{label}: inverseBindMatrices accessor {}: {e}", acc.index());
    if acc.dimensions() != Dimensions::Mat4 || acc.data_type() != DataType::F32 {
        return Err(at(format!(
            "{:?} {:?} elements, not float MAT4",
            acc.data_type(),
            acc.dimensions()
        )));
    }
    if acc.count() < joints {
        return Err(at(format!("{} matrices for {joints} joints", acc.count())));
    }
    let (bytes, stride) = super::gltf::check_accessor(&acc, buffers).map_err(at)?;
    Ok((0..joints)
        .map(|i| {
            let mut m = [0.0f32; 16];
            for (k, c) in m.iter_mut().enumerate() {
                let b = &bytes[i * stride + 4 * k..];
                *c = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
            }
            Mat4::from_cols_array(&m)
        })
        .collect())
}

/// The displacements of a primitive's positions and normals under its morph targets (`None`
/// where no target with a weight moves them).
#[derive(Default)]
pub(super) struct MorphDeltas {
    pub positions: Option<Vec<Vec3>>,
    pub normals: Option<Vec<Vec3>>,
}

/// The displacements of `prim`'s `n` vertices under its morph targets at `weights`.
pub(super) fn morph_deltas(
    prim: &Primitive<'_>,
    weights: &[f32],
    buffers: &[Data],
    n: usize,
    label: &str,
) -> Result<MorphDeltas, String> {
    let mut deltas = MorphDeltas::default();
    for (t, target) in prim.morph_targets().enumerate() {
        let w = weights.get(t).copied().unwrap_or(0.0);
        if w == 0.0 {
            continue;
        }
        if !w.is_finite() {
            return Err(format!("{label}: morph target {t} has a non-finite weight"));
        }
        let (positions, normals) = target_deltas(&target, t, buffers, n, label)?;
        for (d, sum) in [
            (positions, &mut deltas.positions),
            (normals, &mut deltas.normals),
        ] {
            let Some(d) = d else { continue };
            let sum = sum.get_or_insert_with(|| vec![Vec3::ZERO; n]);
            for (s, d) in sum.iter_mut().zip(d) {
                *s += w * d;
            }
        }
    }
    Ok(deltas)
}

/// Every morph target's displacements of `prim`'s `n` positions and normals (`None` where a
/// target moves neither), for weights that an animation plays.
pub(super) fn morph_targets(
    prim: &Primitive<'_>,
    buffers: &[Data],
    n: usize,
    label: &str,
) -> Result<Vec<super::animation::TargetDeltas>, String> {
    prim.morph_targets()
        .enumerate()
        .map(|(t, target)| target_deltas(&target, t, buffers, n, label))
        .collect()
}

/// Morph target `t`'s displacements of `n` positions and normals.
fn target_deltas(
    target: &::gltf::mesh::MorphTarget<'_>,
    t: usize,
    buffers: &[Data],
    n: usize,
    label: &str,
) -> Result<super::animation::TargetDeltas, String> {
    let read =
        |acc: Option<::gltf::Accessor<'_>>, what: &str| -> Result<Option<Vec<Vec3>>, String> {
            let Some(acc) = acc else {
                return Ok(None);
            };
            let at = |e: String| {
                format!(
                    "{label}: morph target {t} {what} accessor {}: {e}",
                    acc.index()
                )
            };
            if acc.count() != n {
                return Err(at(format!("{} elements for {n} vertices", acc.count())));
            }
            super::gltf::read_vec3(&acc, buffers).map(Some).map_err(at)
        };
    Ok((
        read(target.positions(), "POSITION")?,
        read(target.normals(), "NORMAL")?,
    ))
}

/// A skinned node's pose: its skin's joint matrices (of [`joint_matrices`]) and the node's
/// own world transform, which vertices without weight keep.
pub(super) struct SkinPose {
    pub joints: Vec<Mat4>,
    pub fallback: Mat4,
}

/// A primitive's vertices and triangles while they are loaded.
pub(super) struct Triangles<'a> {
    pub positions: &'a mut [Vec3],
    pub normals: &'a mut [Vec3],
    pub indices: &'a mut [u32],
}

/// Each vertex's joint influences: the (joint, weight) pairs of its `JOINTS_n`/`WEIGHTS_n`
/// sets whose weight is finite and positive.
#[derive(Clone, Debug, Default)]
pub(super) struct Influences {
    /// Vertex `i`'s pairs are `pairs[start[i]..start[i + 1]]`.
    start: Vec<u32>,
    pairs: Vec<(u32, f32)>,
}

impl Influences {
    /// The influences of `prim`'s `n` vertices.
    pub fn read(
        prim: &Primitive<'_>,
        draco: Option<&DracoPrimitive>,
        n: usize,
        buffers: &[Data],
        label: &str,
    ) -> Result<Influences, String> {
        let mut per_vertex: Vec<Vec<(u32, f32)>> = vec![Vec::new(); n];
        for set in 0..MAX_INFLUENCE_SETS {
            let (Some(js), Some(ws)) = (
                influence_set(prim, draco, Semantic::Joints(set), n, buffers, label)?,
                influence_set(prim, draco, Semantic::Weights(set), n, buffers, label)?,
            ) else {
                break;
            };
            for (v, (j, w)) in per_vertex.iter_mut().zip(js.iter().zip(&ws)) {
                for k in 0..4 {
                    if w[k].is_finite() && w[k] > 0.0 {
                        v.push((j[k] as u32, w[k]));
                    }
                }
            }
        }
        let mut out = Influences {
            start: Vec::with_capacity(n + 1),
            pairs: Vec::new(),
        };
        out.start.push(0);
        for v in per_vertex {
            out.pairs.extend(v);
            let end = u32::try_from(out.pairs.len())
                .map_err(|_| format!("{label}: too many joint influences"))?;
            out.start.push(end);
        }
        Ok(out)
    }

    /// Vertex `i`'s (joint, weight) pairs.
    pub fn of(&self, i: usize) -> &[(u32, f32)] {
        &self.pairs[self.start[i] as usize..self.start[i + 1] as usize]
    }

    /// Vertex `i`'s skin matrix: its joints' matrices weighted by their share of its total
    /// weight, or `fallback` when it has no weight. Every joint must be in `joints`.
    pub fn matrix(&self, i: usize, joints: &[Mat4], fallback: Mat4) -> Mat4 {
        let inf = self.of(i);
        let total: f32 = inf.iter().map(|&(_, w)| w).sum();
        if total > 0.0 {
            inf.iter().fold(Mat4::ZERO, |m, &(j, w)| {
                m + joints[j as usize] * (w / total)
            })
        } else {
            fallback
        }
    }
}

/// `position` and `normal` moved by skin matrix `m`: the normal by its inverse transpose (as
/// the cofactor matrix times the sign of the determinant, which needs no division) and
/// normalized (`None` where `m` makes it unusable), and whether `m` mirrors.
pub(super) fn pose_vertex(m: &Mat4, position: Vec3, normal: Vec3) -> (Vec3, Option<Vec3>, bool) {
    let p = m.transform_point3(position);
    let (a, b, c) = (
        m.x_axis.truncate(),
        m.y_axis.truncate(),
        m.z_axis.truncate(),
    );
    let cofactor = Mat3::from_cols(b.cross(c), c.cross(a), a.cross(b));
    let det = a.dot(b.cross(c));
    let n = if det.abs() > f32::MIN_POSITIVE {
        cofactor * normal * det.signum()
    } else {
        Mat3::from_cols(a, b, c) * normal
    };
    (p, n.try_normalize(), det < 0.0)
}

/// Moves `prim`'s positions and normals by `skin` into world space, and turns over the
/// winding of each triangle whose first vertex's skin matrix mirrors. A vertex without weight
/// keeps the node's transform instead of collapsing to the origin. Normals that the skin makes
/// unusable are returned as `false` in the mask for the caller to recompute. Returns the
/// vertices' influences too (for a skin that an animation plays).
pub(super) fn skin_vertices(
    prim: &Primitive<'_>,
    skin: &SkinPose,
    buffers: &[Data],
    draco: Option<&DracoPrimitive>,
    t: Triangles<'_>,
    label: &str,
) -> Result<(Vec<bool>, Influences), String> {
    let Triangles {
        positions,
        normals,
        indices,
    } = t;
    let (joints, fallback) = (&skin.joints, skin.fallback);
    let n = positions.len();
    let influences = Influences::read(prim, draco, n, buffers, label)?;
    for i in 0..n {
        if let Some(&(j, _)) = influences
            .of(i)
            .iter()
            .find(|&&(j, _)| j as usize >= joints.len())
        {
            return Err(format!(
                "{label}: vertex {i} names joint {j} of a skin with {} joints",
                joints.len()
            ));
        }
    }
    let mut mirrors = vec![false; n];
    let mut valid = vec![true; n];
    for i in 0..n {
        let m = influences.matrix(i, joints, fallback);
        let (p, normal, mirrored) = pose_vertex(&m, positions[i], normals[i]);
        if !p.is_finite() {
            return Err(format!("{label}: vertex {i} is not finite after skinning"));
        }
        positions[i] = p;
        mirrors[i] = mirrored;
        match normal {
            Some(unit) => normals[i] = unit,
            None => valid[i] = false,
        }
    }
    for t in indices.chunks_exact_mut(3) {
        if mirrors[t[0] as usize] {
            t.swap(1, 2);
        }
    }
    Ok((valid, influences))
}

/// One `JOINTS_n` or `WEIGHTS_n` attribute of the `n` vertices (from the primitive's Draco
/// stream when it holds it), `None` when the primitive has none.
fn influence_set(
    prim: &Primitive<'_>,
    draco: Option<&DracoPrimitive>,
    semantic: Semantic,
    n: usize,
    buffers: &[Data],
    label: &str,
) -> Result<Option<Vec<[f32; 4]>>, String> {
    let name = semantic.to_string();
    if let Some(values) = draco.and_then(|d| d.attribute(&name)) {
        return Ok(Some(values.to_vec()));
    }
    let Some(acc) = prim.get(&semantic) else {
        return Ok(None);
    };
    let at = |e: String| format!("{label}: {name} accessor {}: {e}", acc.index());
    if acc.count() != n || acc.dimensions() != Dimensions::Vec4 {
        return Err(at(format!(
            "{} {:?} elements for {n} vertices (VEC4 each)",
            acc.count(),
            acc.dimensions()
        )));
    }
    let integer = matches!(acc.data_type(), DataType::U8 | DataType::U16) && !acc.normalized();
    if matches!(semantic, Semantic::Joints(_)) && !integer {
        return Err(at(format!(
            "{:?} components, not unsigned bytes or shorts",
            acc.data_type()
        )));
    }
    super::gltf_material::read_elements(&acc, buffers)
        .map(Some)
        .map_err(at)
}
