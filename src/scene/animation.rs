//! A glTF file's first animation, played on the objects it moves: the objects under a node that
//! a translation, rotation or scale channel animates are kept out of [`Scene::objects`] and
//! become movers when [`Movers::add`](super::movers::Movers::add) places them, so every
//! algorithm culls them as it culls the built-in movers (exactly, with their boxes in the
//! hierarchy each frame). A mesh it deforms is played too: a skinned mesh whose joints (or
//! node) it moves, or a mesh whose morph weights it animates. Its vertices are morphed and
//! skinned again on the CPU for each frame ([`Animation::pose_meshes`]) and its object is a
//! mover whose box is that of its posed vertices.
//!
//! [`Scene::objects`]: super::Scene::objects

use glam::{Mat4, Vec3};

use super::gltf_ext::{local_at, Channel, Trs, WeightsChannel};
use super::gltf_skin::{pose_vertex, Influences};
use super::{Aabb, Object, Vertex};

/// Frames of a walk per second of animation time.
pub const ANIMATION_FPS: f32 = 30.0;

/// The objects a glTF animation moves, and its channels.
#[derive(Clone, Debug, Default)]
pub struct Animation {
    /// The moving objects, placed at the animation's start.
    pub objects: Vec<AnimatedObject>,
    /// Sorted by node (stably: of two channels of one property, the later still wins).
    channels: Vec<Channel>,
    /// Morph-weights channels, sorted by node (the first of a node is played).
    weights: Vec<WeightsChannel>,
    /// Seconds of one loop (the last key of any channel).
    duration: f32,
    /// The objects that draw meshes it deforms.
    pub deformed: Vec<DeformedObject>,
    /// The meshes it deforms.
    meshes: Vec<DeformedMesh>,
    /// The skins of those meshes.
    rigs: Vec<Rig>,
    /// Every node of the file: its parent and rest transform (empty without skinned meshes).
    nodes: Vec<RestNode>,
    /// The nodes reachable from a root, each after its parent.
    order: Vec<usize>,
    /// Whether a channel animates the node or a node above it.
    moved: Vec<bool>,
    /// Which of the file's animations this is, as `--animation` takes it: `1 "Walk"`, or the
    /// index alone for an animation without a name (empty when none was read).
    label: String,
}

/// A node of the file, for posing joints: its parent and its rest transform.
#[derive(Clone, Debug)]
pub(super) struct RestNode {
    pub parent: Option<usize>,
    pub rest: Trs,
}

/// A skin that the animation plays: its joints' nodes and their inverse bind matrices.
#[derive(Clone, Debug)]
pub(super) struct Rig {
    pub joints: Vec<usize>,
    pub inverse_bind: Vec<Mat4>,
}

/// The vertices of one primitive that the animation deforms: its own range of the scene's
/// vertices.
#[derive(Clone, Debug)]
pub(super) struct DeformedMesh {
    /// Its first vertex in the scene's vertices.
    pub first_vertex: u32,
    /// Positions and normals before skinning, and before morphing when its weights are
    /// animated (else morphed by the default weights).
    pub rest: Vec<Vertex>,
    /// Positions and normals as loaded (kept where a pose fails).
    pub loaded: Vec<Vertex>,
    /// Its vertices' joint influences and its rig, when skinned.
    pub skin: Option<(Influences, usize)>,
    /// Its morph targets' displacements (positions, normals), when its weights are animated.
    pub targets: Vec<TargetDeltas>,
    /// The node that holds it: vertices without weight follow it, its weights are its.
    pub node: usize,
}

/// Where an object hangs from animated nodes: the world transform above the topmost one, the
/// nodes from it down (index and rest transform), its instance transform and its
/// object-space box.
pub(super) type Place = (Mat4, Vec<(usize, Trs)>, Mat4, Aabb);

/// One morph target's displacements of a primitive's positions and normals.
pub(super) type TargetDeltas = (Option<Vec<Vec3>>, Option<Vec<Vec3>>);

/// An object that draws a mesh the animation deforms.
#[derive(Clone, Debug)]
pub struct DeformedObject {
    /// The object at the animation's start (for a skinned mesh its transform is the
    /// identity, or its `EXT_mesh_gpu_instancing` transform, times `--scale`; for a morphed
    /// one its node's).
    pub object: Object,
    /// Its mesh in [`Animation::pose_meshes`]' meshes.
    pub mesh: usize,
    /// Where it hangs when a channel moves a node above an unskinned morphed mesh.
    place: Option<AnimatedObject>,
}

/// The deformed meshes at one frame, from [`Animation::pose_meshes`]: scratch that is reused.
#[derive(Clone, Debug, Default)]
pub struct MeshPose {
    /// The frame posed (`None`: nothing posed yet).
    pub frame: Option<u64>,
    world: Vec<Mat4>,
    joints: Vec<Mat4>,
    weights: Vec<f32>,
    morphed: Vec<Vertex>,
    /// Every mesh's posed vertices, mesh after mesh.
    vertices: Vec<Vertex>,
    /// Mesh `i`'s vertices are `vertices[start[i]..start[i + 1]]`.
    start: Vec<usize>,
    /// Each mesh's box, posed.
    bounds: Vec<Aabb>,
}

impl MeshPose {
    /// Mesh `i`'s first vertex in the scene and its posed vertices.
    pub fn mesh(&self, i: usize) -> &[Vertex] {
        &self.vertices[self.start[i]..self.start[i + 1]]
    }

    /// Mesh `i`'s box, posed.
    pub fn bounds(&self, i: usize) -> Aabb {
        self.bounds[i]
    }
}

/// One object under an animated node.
#[derive(Clone, Debug)]
pub struct AnimatedObject {
    /// The object at the animation's start.
    pub object: Object,
    /// Its object-space box (the box of the vertices its triangles use).
    pub local: Aabb,
    /// The world transform above the topmost animated node it hangs from.
    parent: Mat4,
    /// Its nodes from that topmost animated one down: index and rest transform.
    chain: Vec<(usize, Trs)>,
    /// Its `EXT_mesh_gpu_instancing` transform (the identity without one).
    instance: Mat4,
}

impl Animation {
    /// An animation of `channels` (translation, rotation and scale channels of one glTF
    /// animation) and `weights` (its morph-weights channels) with no objects yet.
    pub(super) fn new(mut channels: Vec<Channel>, mut weights: Vec<WeightsChannel>) -> Animation {
        channels.sort_by_key(|c| c.node);
        weights.sort_by_key(|w| w.node);
        let duration = channels
            .iter()
            .map(Channel::end)
            .chain(weights.iter().map(WeightsChannel::end))
            .fold(0.0, f32::max);
        Animation {
            objects: Vec::new(),
            channels,
            weights,
            duration,
            ..Animation::default()
        }
    }

    /// The morph-weights channel of node `node`, if it has one.
    pub(super) fn weights_of(&self, node: usize) -> Option<&WeightsChannel> {
        let i = self.weights.partition_point(|w| w.node < node);
        self.weights.get(i).filter(|w| w.node == node)
    }

    /// Gives the file's nodes (each with its parent and rest transform) and the order in which
    /// they are posed (each after its parent), for the skins it may play.
    pub(super) fn set_nodes(&mut self, nodes: Vec<RestNode>, order: Vec<usize>) {
        let mut moved = vec![false; nodes.len()];
        for &n in &order {
            moved[n] =
                self.animates(n) || nodes[n].parent.is_some_and(|p| moved.get(p) == Some(&true));
        }
        self.nodes = nodes;
        self.order = order;
        self.moved = moved;
    }

    /// Whether the animation moves a joint among `joints` (nodes), which a skin then follows.
    pub(super) fn moves_any(&self, joints: &[usize]) -> bool {
        joints.iter().any(|&j| self.moved.get(j) == Some(&true))
    }

    /// Adds a skin the animation plays; returns its index.
    pub(super) fn add_rig(&mut self, rig: Rig) -> usize {
        self.rigs.push(rig);
        self.rigs.len() - 1
    }

    /// Adds a mesh the animation deforms; returns its index.
    pub(super) fn add_deformed_mesh(&mut self, mesh: DeformedMesh) -> usize {
        self.meshes.push(mesh);
        self.meshes.len() - 1
    }

    /// Adds an object that draws deformed mesh `mesh`; `place` (the world transform above
    /// the topmost animated node, the nodes from it down, the instance transform and the
    /// object-space box) when a channel moves a node above an unskinned morphed mesh.
    pub(super) fn add_deformed(&mut self, mut object: Object, mesh: usize, place: Option<Place>) {
        let mut place = place.map(|(parent, chain, instance, local)| AnimatedObject {
            object: object.clone(),
            local,
            parent,
            chain,
            instance,
        });
        if let Some(a) = &mut place {
            object.transform = self.transform_of(a, 0.0);
            a.object.transform = object.transform;
        }
        self.deformed.push(DeformedObject {
            object,
            mesh,
            place,
        });
    }

    /// The number of meshes it deforms.
    pub fn deformed_meshes(&self) -> usize {
        self.meshes.len()
    }

    /// Deformed mesh `i`'s first vertex in the scene's vertices.
    pub fn deformed_first_vertex(&self, i: usize) -> u32 {
        self.meshes[i].first_vertex
    }

    /// Deformed object `i`'s world transform at walk frame `frame`.
    pub fn deformed_transform(&self, i: usize, frame: u64) -> Mat4 {
        let d = &self.deformed[i];
        match &d.place {
            Some(a) => self.transform_of(a, self.time_at(frame)),
            None => d.object.transform,
        }
    }

    /// Poses every deformed mesh at walk frame `frame` into `pose` (nothing to do when it
    /// holds that frame already): its weights at the animation's time morph it, then its
    /// joints' nodes at that time skin it. A mesh whose pose is not finite, or reaches
    /// farther than a loaded vertex may lie, keeps its loaded vertices.
    pub fn pose_meshes(&self, frame: u64, pose: &mut MeshPose) {
        if pose.frame == Some(frame) && pose.start.len() == self.meshes.len() + 1 {
            return;
        }
        pose.frame = Some(frame);
        let t = self.time_at(frame);
        pose.world.clear();
        pose.world.resize(self.nodes.len(), Mat4::IDENTITY);
        for &n in &self.order {
            let node = &self.nodes[n];
            let parent = node.parent.map_or(Mat4::IDENTITY, |p| pose.world[p]);
            pose.world[n] = parent * local_at(node.rest, self.channels_of(n), t);
        }
        pose.vertices.clear();
        pose.start.clear();
        pose.bounds.clear();
        pose.start.push(0);
        let MeshPose {
            world,
            joints,
            weights,
            morphed,
            vertices,
            start,
            bounds: boxes,
            ..
        } = pose;
        for mesh in &self.meshes {
            let source = if mesh.targets.is_empty() {
                &mesh.rest
            } else {
                match self.weights_of(mesh.node) {
                    Some(w) => w.at(t, weights),
                    None => weights.clear(),
                }
                morph(&mesh.rest, &mesh.targets, weights, morphed);
                &*morphed
            };
            let first = vertices.len();
            let mut bounds = Aabb::EMPTY;
            let mut finite = true;
            match &mesh.skin {
                Some((influences, rig)) => {
                    let rig = &self.rigs[*rig];
                    joints.clear();
                    joints.extend(
                        rig.joints
                            .iter()
                            .zip(&rig.inverse_bind)
                            .map(|(&j, ibm)| world[j] * *ibm),
                    );
                    let fallback = world[mesh.node];
                    for (i, v) in source.iter().enumerate() {
                        let m = influences.matrix(i, joints, fallback);
                        let (p, normal, _) = pose_vertex(
                            &m,
                            Vec3::from_array(v.position),
                            Vec3::from_array(v.normal),
                        );
                        finite &= p.is_finite();
                        bounds.grow(p);
                        vertices.push(Vertex {
                            position: p.to_array(),
                            normal: normal
                                .unwrap_or(Vec3::from_array(mesh.loaded[i].normal))
                                .to_array(),
                        });
                    }
                }
                None => {
                    for v in source {
                        let p = Vec3::from_array(v.position);
                        finite &= p.is_finite();
                        bounds.grow(p);
                        vertices.push(*v);
                    }
                }
            }
            let reach = bounds.min.abs().max(bounds.max.abs()).max_element();
            if !finite || reach.is_nan() || reach > super::gltf::MAX_COORDINATE {
                vertices.truncate(first);
                vertices.extend_from_slice(&mesh.loaded);
                bounds = mesh.loaded.iter().fold(Aabb::EMPTY, |mut b, v| {
                    b.grow(Vec3::from_array(v.position));
                    b
                });
            }
            start.push(vertices.len());
            boxes.push(bounds);
        }
    }

    /// The animation's time at walk frame `frame`, in seconds (it loops).
    fn time_at(&self, frame: u64) -> f32 {
        if self.duration > 0.0 {
            (frame as f32 / ANIMATION_FPS) % self.duration
        } else {
            0.0
        }
    }

    /// Whether a channel animates node `node`.
    pub(super) fn animates(&self, node: usize) -> bool {
        !self.channels_of(node).is_empty()
    }

    /// The channels that animate node `node`.
    fn channels_of(&self, node: usize) -> &[Channel] {
        let start = self.channels.partition_point(|c| c.node < node);
        let end = start + self.channels[start..].partition_point(|c| c.node == node);
        &self.channels[start..end]
    }

    /// Adds an object hanging from the nodes `chain` (each with its rest transform, the first
    /// animated) under `parent`, with its instance transform; `object` holds its rest place.
    pub(super) fn add(
        &mut self,
        mut object: Object,
        local: Aabb,
        parent: Mat4,
        chain: Vec<(usize, Trs)>,
        instance: Mat4,
    ) {
        let mut a = AnimatedObject {
            object: object.clone(),
            local,
            parent,
            chain,
            instance,
        };
        let start = self.transform_of(&a, 0.0);
        object.transform = start;
        object.bounds = local.transformed(&start);
        a.object = object;
        self.objects.push(a);
    }

    /// Seconds of one loop.
    pub fn duration(&self) -> f32 {
        self.duration
    }

    /// Which of the file's animations this is: `1 "Walk"`, or the index alone for one
    /// without a name (empty when it was not read from a file).
    pub fn label(&self) -> &str {
        &self.label
    }

    /// Names the file's animation this is (see [`Animation::label`]).
    pub(super) fn set_label(&mut self, label: String) {
        self.label = label;
    }

    /// Object `i`'s world transform at walk frame `frame` (the animation loops; a transform
    /// that is not finite, or that takes the object farther from the origin than a loaded
    /// vertex may lie, falls back to the object's start).
    pub fn transform_at(&self, i: usize, frame: u64) -> Mat4 {
        self.transform_of(&self.objects[i], self.time_at(frame))
    }

    fn transform_of(&self, a: &AnimatedObject, t: f32) -> Mat4 {
        let mut m = a.parent;
        for &(node, rest) in &a.chain {
            m *= local_at(rest, self.channels_of(node), t);
        }
        let m = m * a.instance;
        let b = a.local.transformed(&m);
        let reach = b.min.abs().max(b.max.abs()).max_element();
        if m.is_finite() && reach <= super::gltf::MAX_COORDINATE {
            m
        } else {
            a.object.transform
        }
    }

    /// Multiplies every coordinate by `factor` (as [`Scene::magnify`](super::Scene::magnify)).
    pub(super) fn magnify(&mut self, factor: f32) {
        let m = Mat4::from_scale(Vec3::splat(factor));
        for a in &mut self.objects {
            a.parent = m * a.parent;
            a.object.transform = m * a.object.transform;
            a.object.bounds = a.local.transformed(&a.object.transform);
        }
        for d in &mut self.deformed {
            d.object.transform = m * d.object.transform;
            d.object.bounds = Aabb {
                min: d.object.bounds.min * factor,
                max: d.object.bounds.max * factor,
            };
            if let Some(a) = &mut d.place {
                a.parent = m * a.parent;
                a.object.transform = d.object.transform;
            }
        }
    }
}

/// `rest` morphed by `targets` at `weights` into `out`: each position plus its targets'
/// displacements times their weights, each normal the same and normalized (kept where the sum
/// vanishes). Targets without a weight count as weight 0.
fn morph(rest: &[Vertex], targets: &[TargetDeltas], weights: &[f32], out: &mut Vec<Vertex>) {
    out.clear();
    out.extend_from_slice(rest);
    for ((positions, normals), &w) in targets.iter().zip(weights) {
        if w == 0.0 {
            continue;
        }
        for (v, d) in out.iter_mut().zip(positions.iter().flatten()) {
            v.position = (Vec3::from_array(v.position) + w * *d).to_array();
        }
        for (v, d) in out.iter_mut().zip(normals.iter().flatten()) {
            v.normal = (Vec3::from_array(v.normal) + w * *d).to_array();
        }
    }
    if targets.iter().any(|(_, n)| n.is_some()) {
        for (v, r) in out.iter_mut().zip(rest) {
            v.normal = Vec3::from_array(v.normal)
                .try_normalize()
                .unwrap_or(Vec3::from_array(r.normal))
                .to_array();
        }
    }
}
