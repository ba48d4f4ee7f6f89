//! The object hierarchy: a binary BVH over object bounds built with obvhs (PLOC), flattened into
//! our own node array with parents and depths. Culling state lives beside it, indexed by node.

use std::collections::BinaryHeap;

use glam::Vec3;
use obvhs::aabb::Aabb as OAabb;
use obvhs::bvh2::Bvh2;
use obvhs::{Boundable, BvhBuildParams};

use crate::scene::Aabb;

/// One node: an interior node with two children, or a leaf with a range of objects.
#[derive(Clone, Debug)]
pub struct BvhNode {
    /// World-space bounds of everything below.
    pub bounds: Aabb,
    /// Parent index (`u32::MAX` for the root).
    pub parent: u32,
    /// Children (interior nodes only).
    pub children: [u32; 2],
    /// First entry in [`ObjectBvh::leaf_objects`] (leaves only).
    pub first_object: u32,
    /// Number of objects (0 for interior nodes).
    pub object_count: u32,
    /// Depth (root 0).
    pub depth: u32,
}

impl BvhNode {
    /// Whether this is a leaf.
    pub fn is_leaf(&self) -> bool {
        // No node has the root (0) as a child, so children [0, 0] mark a leaf too: the root of
        // an empty hierarchy is a leaf without objects, not a node whose children are itself.
        self.object_count > 0 || self.children == [0, 0]
    }
}

/// The object BVH. Node 0 is the root.
#[derive(Clone, Debug)]
pub struct ObjectBvh {
    /// All nodes; parents come before children.
    pub nodes: Vec<BvhNode>,
    /// Object indices, grouped by leaf.
    pub leaf_objects: Vec<u32>,
}

struct Bounded(OAabb);
impl Boundable for Bounded {
    fn aabb(&self) -> OAabb {
        self.0
    }
}

impl ObjectBvh {
    /// Builds the hierarchy over `bounds` (one per object) with at most `leaf_size` objects per
    /// leaf. An empty input gives a root leaf with no objects.
    pub fn build(bounds: &[Aabb], leaf_size: u32) -> ObjectBvh {
        if bounds.is_empty() {
            return ObjectBvh::empty();
        }
        let bvh2 = build_bvh2(bounds, leaf_size);
        let mut out = ObjectBvh::flatten(&bvh2, bounds);
        out.fit_interior_bounds();
        out
    }

    /// A root leaf with no objects.
    fn empty() -> ObjectBvh {
        ObjectBvh {
            nodes: vec![BvhNode {
                bounds: Aabb::new(Vec3::ZERO, Vec3::ZERO),
                parent: u32::MAX,
                children: [0; 2],
                first_object: 0,
                object_count: 0,
                depth: 0,
            }],
            leaf_objects: Vec::new(),
        }
    }

    /// Copies obvhs's tree into our node array, depth-first from its root (index 0) so that
    /// parents come before children; leaves get their objects' bounds.
    fn flatten(bvh2: &Bvh2, bounds: &[Aabb]) -> ObjectBvh {
        let mut out = ObjectBvh {
            nodes: Vec::with_capacity(bvh2.nodes.len()),
            leaf_objects: Vec::with_capacity(bounds.len()),
        };
        let mut stack = vec![(0usize, u32::MAX, 0u32)];
        while let Some((src, parent, depth)) = stack.pop() {
            let n = &bvh2.nodes[src];
            let id = out.nodes.len() as u32;
            if parent != u32::MAX {
                out.link_child(parent, id);
            }
            let mut node = BvhNode {
                bounds: Aabb::EMPTY,
                parent,
                children: [u32::MAX; 2],
                first_object: 0,
                object_count: 0,
                depth,
            };
            if n.prim_count > 0 || bvh2.nodes.len() == 1 {
                node.first_object = out.leaf_objects.len() as u32;
                let count = n.prim_count.max(1);
                for k in 0..count {
                    let obj = bvh2.primitive_indices[(n.first_index + k) as usize];
                    node.bounds = node.bounds.union(&bounds_or_point(&bounds[obj as usize]));
                    out.leaf_objects.push(obj);
                }
                node.object_count = count;
                out.nodes.push(node);
            } else {
                out.nodes.push(node);
                stack.push((n.first_index as usize + 1, id, depth + 1));
                stack.push((n.first_index as usize, id, depth + 1));
            }
        }
        out
    }

    /// Makes `child` the next free child slot of `parent`.
    fn link_child(&mut self, parent: u32, child: u32) {
        let p = &mut self.nodes[parent as usize];
        if p.children[0] == u32::MAX {
            p.children[0] = child;
        } else {
            p.children[1] = child;
        }
    }

    /// Interior bounds bottom-up (children come after parents).
    fn fit_interior_bounds(&mut self) {
        for i in (0..self.nodes.len()).rev() {
            if !self.nodes[i].is_leaf() {
                let [a, b] = self.nodes[i].children;
                self.nodes[i].bounds = self.nodes[a as usize]
                    .bounds
                    .union(&self.nodes[b as usize].bounds);
            }
        }
    }

    /// The objects of a leaf (empty for interior nodes).
    pub fn objects(&self, node: u32) -> &[u32] {
        let n = &self.nodes[node as usize];
        &self.leaf_objects[n.first_object as usize..(n.first_object + n.object_count) as usize]
    }

    /// Number of leaves.
    pub fn leaf_count(&self) -> usize {
        self.nodes.iter().filter(|n| n.is_leaf()).count()
    }

    /// Visits nodes front to back from `eye` (by distance to their boxes); `visit` returns
    /// whether to descend into the node.
    pub fn front_to_back(&self, eye: Vec3, visit: impl FnMut(u32, &BvhNode) -> bool) {
        self.front_to_back_with(&mut DistanceQueue::default(), eye, visit);
    }

    /// [`ObjectBvh::front_to_back`] with a caller's queue, reused from frame to frame so that
    /// steady frames do not allocate.
    pub fn front_to_back_with(
        &self,
        queue: &mut DistanceQueue,
        eye: Vec3,
        mut visit: impl FnMut(u32, &BvhNode) -> bool,
    ) {
        queue.clear();
        queue.push(0, self.nodes[0].bounds.distance_squared(eye));
        while let Some(id) = queue.pop() {
            let node = &self.nodes[id as usize];
            if visit(id, node) && !node.is_leaf() {
                for c in node.children {
                    queue.push(c, self.nodes[c as usize].bounds.distance_squared(eye));
                }
            }
        }
    }
}

/// obvhs's binary BVH (PLOC) over `bounds`, invalid boxes replaced by the origin.
fn build_bvh2(bounds: &[Aabb], leaf_size: u32) -> Bvh2 {
    let prims: Vec<Bounded> = bounds
        .iter()
        .map(|b| {
            let (min, max) = if b.is_valid() {
                (b.min, b.max)
            } else {
                (Vec3::ZERO, Vec3::ZERO)
            };
            Bounded(OAabb::new(min.into(), max.into()))
        })
        .collect();
    let mut params = BvhBuildParams::fast_build();
    params.max_prims_per_leaf = leaf_size.clamp(1, 255);
    params.collapse_traversal_cost = 1.0;
    let mut t = std::time::Duration::ZERO;
    obvhs::bvh2::builder::build_bvh2(&prims, params, &mut t)
}

fn bounds_or_point(b: &Aabb) -> Aabb {
    if b.is_valid() {
        *b
    } else {
        Aabb::new(Vec3::ZERO, Vec3::ZERO)
    }
}

/// A min-priority queue of nodes keyed by squared distance (ties broken by node id, so traversal
/// order is deterministic).
#[derive(Default, Debug)]
pub struct DistanceQueue {
    heap: BinaryHeap<Entry>,
}

#[derive(Debug, PartialEq)]
struct Entry {
    dist: f32,
    node: u32,
}
impl Eq for Entry {}
impl PartialOrd for Entry {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Entry {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        other
            .dist
            .total_cmp(&self.dist)
            .then_with(|| other.node.cmp(&self.node))
    }
}

impl DistanceQueue {
    /// Adds a node.
    pub fn push(&mut self, node: u32, dist: f32) {
        self.heap.push(Entry { dist, node });
    }
    /// Removes the nearest node.
    pub fn pop(&mut self) -> Option<u32> {
        self.heap.pop().map(|e| e.node)
    }
    /// Whether empty.
    pub fn is_empty(&self) -> bool {
        self.heap.is_empty()
    }
    /// Makes room for `additional` more nodes (so steady frames do not allocate).
    pub fn reserve(&mut self, additional: usize) {
        self.heap.reserve(additional);
    }
    /// Empties the queue.
    pub fn clear(&mut self) {
        self.heap.clear();
    }
}
