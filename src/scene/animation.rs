//! A glTF file's first animation, played on the objects it moves: the objects under a node that
//! a translation, rotation or scale channel animates are kept out of [`Scene::objects`] and
//! become movers when [`Movers::add`](super::movers::Movers::add) places them, so every
//! algorithm culls them as it culls the built-in movers (exactly, with their boxes in the
//! hierarchy each frame). Skinned meshes stay in their default pose; morph weights are not
//! animated.
//!
//! [`Scene::objects`]: super::Scene::objects

use glam::{Mat4, Vec3};

use super::gltf_ext::{local_at, Channel, Trs};
use super::{Aabb, Object};

/// Frames of a walk per second of animation time.
pub const ANIMATION_FPS: f32 = 30.0;

/// The objects a glTF animation moves, and its channels.
#[derive(Clone, Debug, Default)]
pub struct Animation {
    /// The moving objects, placed at the animation's start.
    pub objects: Vec<AnimatedObject>,
    /// Sorted by node (stably: of two channels of one property, the later still wins).
    channels: Vec<Channel>,
    /// Seconds of one loop (the last key of any channel).
    duration: f32,
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
    /// animation) with no objects yet.
    pub(super) fn new(mut channels: Vec<Channel>) -> Animation {
        channels.sort_by_key(|c| c.node);
        let duration = channels.iter().map(Channel::end).fold(0.0, f32::max);
        Animation {
            objects: Vec::new(),
            channels,
            duration,
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

    /// Object `i`'s world transform at walk frame `frame` (the animation loops; a transform
    /// that is not finite, or that takes the object farther from the origin than a loaded
    /// vertex may lie, falls back to the object's start).
    pub fn transform_at(&self, i: usize, frame: u64) -> Mat4 {
        let t = if self.duration > 0.0 {
            (frame as f32 / ANIMATION_FPS) % self.duration
        } else {
            0.0
        };
        self.transform_of(&self.objects[i], t)
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
    }
}
