//! The object hierarchy: a binary BVH over object bounds in one node array with parents and
//! depths, built top-down with the surface area heuristic (SAH) over 16 centroid bins per axis,
//! deterministic (the same boxes give the same tree). Culling state lives beside it, indexed by
//! node.
//!
//! The hierarchy follows a dynamic scene (see [Moving objects](crate#moving-objects)): a host calls
//! [`ObjectBvh::set_bounds`], [`ObjectBvh::insert`] and [`ObjectBvh::remove`] between frames and
//! then [`ObjectBvh::update`], which refits the boxes of what moved bottom-up (cost proportional to
//! the moved objects times the depth) and rebuilds the whole tree when its quality, the summed
//! surface area of its interior nodes, has grown past [`RebuildPolicy::area_factor`] times the
//! value right after the last build (or when inserts and removals have touched more than
//! [`RebuildPolicy::churn_fraction`] of the objects). Object ids are stable: an id names the same
//! object until it is removed (a later insert may reuse it). Every update stamps the nodes whose
//! boxes changed with the update's epoch, so that cullers can tell which nodes moved since they
//! last looked ([`ObjectBvh::changed_since`], [`ObjectBvh::grown_since`]); node ids stay valid
//! until the next rebuild ([`ObjectBvh::rebuilds`]) or insert ([`ObjectBvh::structure`]).

use std::collections::BinaryHeap;

use glam::Vec3;

use crate::error::{Error, Result};
use crate::Aabb;

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
        // An interior node has two different children; leaves have [MAX, MAX] or, for the root
        // of an empty hierarchy, [0, 0]. A leaf whose objects were all removed keeps being a
        // leaf (with no objects and an empty box).
        self.object_count > 0 || self.children[0] == self.children[1]
    }
}

/// The object BVH. Node 0 is the root.
#[derive(Clone, Debug)]
pub struct ObjectBvh {
    /// All nodes; right after a build parents come before children (nodes added by
    /// [`ObjectBvh::insert`] are appended, after their parents' position).
    pub nodes: Vec<BvhNode>,
    /// Object indices, grouped by leaf.
    pub leaf_objects: Vec<u32>,
    dynamics: Dynamics,
}

impl ObjectBvh {
    /// Builds the hierarchy over `bounds` (one per object; object `i` gets id `i`) with at most
    /// `leaf_size` objects per leaf (a leaf takes several only where the SAH says splitting
    /// them does not pay). An empty input gives a root leaf with no objects.
    ///
    /// A box that is not a box (a NaN or infinite corner, or `min` above `max` on an axis,
    /// [`Aabb::is_valid`] false) stands for a point at the origin, here and in
    /// [`ObjectBvh::set_bounds`] and [`ObjectBvh::insert`]: nothing panics and the hierarchy
    /// stays finite, but such an object is drawn only when that point is seen. Keep objects
    /// that have no bounds (a sky, an endless ground plane) out of the hierarchy and draw them
    /// yourself every frame.
    pub fn build(bounds: &[Aabb], leaf_size: u32) -> ObjectBvh {
        ObjectBvh::build_where(bounds, |_| true, leaf_size)
    }

    /// [`ObjectBvh::build`] over the objects for which `keep(id)` holds: the others keep their
    /// ids (object `i` is still `bounds[i]`) but are in no leaf, so no traversal meets them,
    /// and [`ObjectBvh::insert`] never hands their ids out. For objects the host draws itself
    /// outside the culled pass, such as blended (translucent) surfaces, which occlude nothing
    /// and are drawn back to front after everything else.
    pub fn build_where(bounds: &[Aabb], keep: impl Fn(u32) -> bool, leaf_size: u32) -> ObjectBvh {
        let object_bounds: Vec<Aabb> = bounds.iter().map(bounds_or_point).collect();
        let ids: Vec<u32> = (0..bounds.len() as u32).filter(|&i| keep(i)).collect();
        let (nodes, leaf_objects) = build_nodes(&object_bounds, &ids, leaf_size);
        let mut out = ObjectBvh {
            nodes,
            leaf_objects,
            dynamics: Dynamics {
                leaf_size,
                object_leaf: vec![u32::MAX; bounds.len()],
                object_bounds,
                ..Dynamics::default()
            },
        };
        out.after_build();
        out
    }

    /// A root leaf with no objects.
    fn empty_nodes() -> Vec<BvhNode> {
        vec![BvhNode {
            bounds: Aabb::new(Vec3::ZERO, Vec3::ZERO),
            parent: u32::MAX,
            children: [0; 2],
            first_object: 0,
            object_count: 0,
            depth: 0,
        }]
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

/// The nodes and leaf objects of a hierarchy over the objects `ids` (their boxes in `bounds`,
/// indexed by id, all valid): a top-down binned SAH build, depth-first, so parents come before
/// children and each leaf owns a contiguous range of the leaf objects.
fn build_nodes(bounds: &[Aabb], ids: &[u32], leaf_size: u32) -> (Vec<BvhNode>, Vec<u32>) {
    if ids.is_empty() {
        return (ObjectBvh::empty_nodes(), Vec::new());
    }
    let leaf_size = leaf_size.max(1) as usize;
    let mut prims: Vec<Prim> = ids
        .iter()
        .map(|&id| {
            let b = bounds[id as usize];
            Prim {
                id,
                bounds: b,
                centroid: b.center(),
            }
        })
        .collect();
    let mut out = ObjectBvh {
        nodes: Vec::with_capacity(2 * ids.len() - 1),
        leaf_objects: Vec::with_capacity(ids.len()),
        dynamics: Dynamics::default(),
    };
    // (range of `prims`, parent, depth); the first child is pushed last, so it comes next.
    let mut stack = vec![(0..prims.len(), u32::MAX, 0u32)];
    while let Some((range, parent, depth)) = stack.pop() {
        let prims = &mut prims[range.clone()];
        let (node_bounds, centroids) = bounds_and_centroids(prims);
        let id = out.nodes.len() as u32;
        if parent != u32::MAX {
            out.link_child(parent, id);
        }
        let mut node = BvhNode {
            bounds: node_bounds,
            parent,
            children: [u32::MAX; 2],
            first_object: 0,
            object_count: 0,
            depth,
        };
        match split(prims, &node_bounds, &centroids, leaf_size) {
            Some(mid) => {
                out.nodes.push(node);
                let mid = range.start + mid;
                stack.push((mid..range.end, id, depth + 1));
                stack.push((range.start..mid, id, depth + 1));
            }
            None => {
                node.first_object = out.leaf_objects.len() as u32;
                node.object_count = prims.len() as u32;
                out.leaf_objects.extend(prims.iter().map(|p| p.id));
                out.nodes.push(node);
            }
        }
    }
    (out.nodes, out.leaf_objects)
}

/// The box of `prims` and the box of their centroids.
fn bounds_and_centroids(prims: &[Prim]) -> (Aabb, Aabb) {
    let mut centroids = Aabb::EMPTY;
    let mut bounds = Aabb::EMPTY;
    for p in prims {
        bounds = bounds.union(&p.bounds);
        centroids.grow(p.centroid);
    }
    (bounds, centroids)
}

/// Centroid bins per axis of the SAH build.
const SAH_BINS: usize = 16;
/// The SAH cost of visiting an interior node, relative to the cost of one object in a leaf.
const SAH_TRAVERSAL_COST: f32 = 1.0;

/// An object during the build.
#[derive(Clone, Copy)]
struct Prim {
    id: u32,
    bounds: Aabb,
    centroid: Vec3,
}

/// A split plane between two centroid bins.
#[derive(Clone, Copy)]
struct BinnedSplit {
    axis: usize,
    /// Bins below this go to the first child.
    plane: usize,
    /// `Σ area(child) · objects(child)` over both children.
    cost: f32,
}

/// Decides a node over `prims` (its box `node`, its centroids' box `centroids`): `None` for a
/// leaf, else reorders `prims` so that `prims[..mid]` is the first child and returns `mid`.
/// A leaf when the objects fit in one and the SAH says a split does not pay; the best binned
/// split otherwise; a median split when the SAH cannot tell (all centroids coincide, or the
/// box has no area).
fn split(prims: &mut [Prim], node: &Aabb, centroids: &Aabb, leaf_size: usize) -> Option<usize> {
    let n = prims.len();
    if n == 1 {
        return None;
    }
    let area = node.surface_area();
    let binned = best_binned_split(prims, centroids).filter(|_| area > 0.0 && area.is_finite());
    match binned {
        Some(s) => {
            let split_cost = SAH_TRAVERSAL_COST + s.cost / area;
            if n <= leaf_size && n as f32 <= split_cost {
                return None;
            }
            let bins = Bins::new(centroids);
            Some(partition(prims, |p| bins.bin(p.centroid, s.axis) < s.plane))
        }
        None if n <= leaf_size => None,
        None => Some(median_split(prims, centroids)),
    }
}

/// Maps centroids to bins along each axis of a centroid box.
struct Bins {
    min: Vec3,
    scale: Vec3,
}

impl Bins {
    fn new(centroids: &Aabb) -> Bins {
        let extent = centroids.extent();
        Bins {
            min: centroids.min,
            scale: Vec3::select(
                extent.cmpgt(Vec3::ZERO),
                SAH_BINS as f32 / extent,
                Vec3::ZERO,
            ),
        }
    }
    fn bin(&self, c: Vec3, axis: usize) -> usize {
        (((c[axis] - self.min[axis]) * self.scale[axis]) as usize).min(SAH_BINS - 1)
    }
}

/// The cheapest split between centroid bins over the three axes (ties: the first axis and
/// plane), or `None` when all centroids coincide.
fn best_binned_split(prims: &[Prim], centroids: &Aabb) -> Option<BinnedSplit> {
    let bins = Bins::new(centroids);
    let mut best: Option<BinnedSplit> = None;
    for axis in 0..3 {
        if bins.scale[axis] <= 0.0 || !bins.scale[axis].is_finite() {
            continue;
        }
        let mut count = [0u32; SAH_BINS];
        let mut bounds = [Aabb::EMPTY; SAH_BINS];
        for p in prims {
            let b = bins.bin(p.centroid, axis);
            count[b] += 1;
            bounds[b] = bounds[b].union(&p.bounds);
        }
        // Right side of each plane, swept from the last bin.
        let mut right_cost = [0f32; SAH_BINS];
        let (mut acc, mut acc_count) = (Aabb::EMPTY, 0u32);
        for plane in (1..SAH_BINS).rev() {
            acc = acc.union(&bounds[plane]);
            acc_count += count[plane];
            right_cost[plane] = if acc_count > 0 {
                acc.surface_area() * acc_count as f32
            } else {
                f32::NAN
            };
        }
        let (mut acc, mut acc_count) = (Aabb::EMPTY, 0u32);
        for plane in 1..SAH_BINS {
            acc = acc.union(&bounds[plane - 1]);
            acc_count += count[plane - 1];
            if acc_count == 0 || acc_count as usize == prims.len() {
                continue;
            }
            let cost = acc.surface_area() * acc_count as f32 + right_cost[plane];
            if best.is_none_or(|b| cost < b.cost) {
                best = Some(BinnedSplit { axis, plane, cost });
            }
        }
    }
    best
}

/// Moves the objects for which `first` holds to the front; returns how many there are.
fn partition(prims: &mut [Prim], first: impl Fn(&Prim) -> bool) -> usize {
    let mut mid = 0;
    for i in 0..prims.len() {
        if first(&prims[i]) {
            prims.swap(mid, i);
            mid += 1;
        }
    }
    mid
}

/// Splits at the median centroid along the centroid box's longest axis (ties by object id),
/// which halves the objects whatever their positions.
fn median_split(prims: &mut [Prim], centroids: &Aabb) -> usize {
    let e = centroids.extent();
    let axis = if e.x >= e.y && e.x >= e.z {
        0
    } else if e.y >= e.z {
        1
    } else {
        2
    };
    let mid = prims.len() / 2;
    prims.select_nth_unstable_by(mid, |a, b| {
        a.centroid[axis]
            .total_cmp(&b.centroid[axis])
            .then(a.id.cmp(&b.id))
    });
    mid
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

/// When [`ObjectBvh::update`] rebuilds the whole tree instead of refitting it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RebuildPolicy {
    /// Rebuild when the summed surface area of the interior nodes exceeds this many times its
    /// value right after the last build (default 1.5: refitted boxes have grown by half, so a
    /// traversal opens about that many more nodes than a fresh tree would).
    pub area_factor: f32,
    /// Rebuild when inserts and removals since the last build exceed this fraction of the
    /// objects (default 0.25): inserted objects hang below their nearest leaf and removed ones
    /// leave empty leaves behind.
    pub churn_fraction: f32,
}

impl Default for RebuildPolicy {
    fn default() -> Self {
        RebuildPolicy {
            area_factor: 1.5,
            churn_fraction: 0.25,
        }
    }
}

/// What one [`ObjectBvh::update`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct UpdateStats {
    /// Leaves whose objects moved, appeared or vanished.
    pub dirty_leaves: u32,
    /// Nodes whose box the refit changed.
    pub refitted_nodes: u32,
    /// Whether the tree was rebuilt (node ids changed).
    pub rebuilt: bool,
    /// Summed interior surface area over its value after the last build (after this update).
    pub quality: f32,
}

/// The dynamic side of the hierarchy: object boxes by id, the leaf of each object, what moved.
#[derive(Clone, Debug, Default)]
struct Dynamics {
    leaf_size: u32,
    /// Box of each object id (EMPTY once removed).
    object_bounds: Vec<Aabb>,
    /// Leaf of each object id (`u32::MAX`: removed).
    object_leaf: Vec<u32>,
    /// Removed ids, reused by inserts.
    free: Vec<u32>,
    /// Leaves to refit at the next update, and a mark per node so each is listed once.
    dirty: Vec<u32>,
    dirty_mark: Vec<bool>,
    /// Per node: the epoch of the last update that changed its box, and of the last one that
    /// grew it beyond its previous box.
    changed_at: Vec<u64>,
    grown_at: Vec<u64>,
    epoch: u64,
    /// Bumped when nodes are added or renumbered.
    structure: u64,
    rebuilds: u32,
    /// Summed interior surface area now and right after the last build.
    area: f64,
    built_area: f64,
    /// Inserts and removals since the last build.
    churn: usize,
    /// Bumped when an object enters or leaves a leaf (insert, remove, build).
    layout: u64,
    live: usize,
    policy: RebuildPolicy,
}

/// Whether `outer` encloses `inner` (an empty `inner` is enclosed by anything).
fn encloses(outer: &Aabb, inner: &Aabb) -> bool {
    !inner.is_valid() || (outer.min.cmple(inner.min).all() && inner.max.cmple(outer.max).all())
}

/// Scene updates: set_bounds / insert / remove between frames, then update.
impl ObjectBvh {
    /// [`ObjectBvh::build`] from boxes as plain arrays `[min, max]` (or [`Aabb`]s): object
    /// `i` is the `i`-th box.
    pub fn from_boxes<B: Into<Aabb>>(boxes: impl IntoIterator<Item = B>, leaf_size: u32) -> Self {
        let bounds: Vec<Aabb> = boxes.into_iter().map(Into::into).collect();
        ObjectBvh::build(&bounds, leaf_size)
    }

    /// Sets an object's world bounds (it moved); the next [`ObjectBvh::update`] refits.
    /// `bounds`: an [`Aabb`] or plain arrays `[min, max]` (see [`Aabb::from_min_max`] for
    /// `mint` points); a box that is not valid stands for a point at the origin (see
    /// [`ObjectBvh::build`]).
    pub fn set_bounds(&mut self, object: u32, bounds: impl Into<Aabb>) -> Result<()> {
        let bounds: Aabb = bounds.into();
        let leaf = self.leaf_of(object)?;
        self.dynamics.object_bounds[object as usize] = bounds_or_point(&bounds);
        self.mark_dirty(leaf);
        Ok(())
    }

    /// Adds an object with world `bounds` and returns its id, stable until it is removed. It
    /// hangs below the leaf whose box grows least; the next [`ObjectBvh::update`] refits.
    /// `bounds` as in [`ObjectBvh::set_bounds`].
    pub fn insert(&mut self, bounds: impl Into<Aabb>) -> u32 {
        let b = bounds_or_point(&bounds.into());
        let d = &mut self.dynamics;
        let id = match d.free.pop() {
            Some(id) => id,
            None => {
                d.object_bounds.push(Aabb::EMPTY);
                d.object_leaf.push(u32::MAX);
                d.object_bounds.len() as u32 - 1
            }
        };
        d.object_bounds[id as usize] = b;
        d.churn += 1;
        d.layout += 1;
        d.live += 1;
        let leaf = self.best_leaf(&b);
        let target = if self.nodes[leaf as usize].object_count == 0 {
            leaf // an empty leaf (or the empty root) takes the object
        } else {
            self.split_leaf(leaf)
        };
        let node = &mut self.nodes[target as usize];
        node.first_object = self.leaf_objects.len() as u32;
        node.object_count = 1;
        self.leaf_objects.push(id);
        self.dynamics.object_leaf[id as usize] = target;
        self.mark_dirty(target);
        id
    }

    /// Removes an object: it is in no leaf from now on (its leaf may stay empty until the next
    /// rebuild). Its id may be handed out again by a later insert.
    pub fn remove(&mut self, object: u32) -> Result<()> {
        let leaf = self.leaf_of(object)?;
        let n = &mut self.nodes[leaf as usize];
        let range = n.first_object as usize..(n.first_object + n.object_count) as usize;
        let last = range.end - 1;
        if let Some(pos) = self.leaf_objects[range].iter().position(|&o| o == object) {
            self.leaf_objects.swap(n.first_object as usize + pos, last);
            n.object_count -= 1;
        }
        let d = &mut self.dynamics;
        d.object_leaf[object as usize] = u32::MAX;
        d.object_bounds[object as usize] = Aabb::EMPTY;
        d.free.push(object);
        d.churn += 1;
        d.layout += 1;
        d.live -= 1;
        self.mark_dirty(leaf);
        Ok(())
    }

    /// Applies the changes since the last update: refits the boxes above every changed leaf
    /// (bottom-up, stopping where a box does not change), then rebuilds the whole tree if its
    /// quality has degraded past the [`RebuildPolicy`].
    pub fn update(&mut self) -> UpdateStats {
        self.dynamics.epoch += 1;
        let mut stats = UpdateStats {
            dirty_leaves: self.dynamics.dirty.len() as u32,
            ..UpdateStats::default()
        };
        let dirty = std::mem::take(&mut self.dynamics.dirty);
        for &leaf in &dirty {
            self.dynamics.dirty_mark[leaf as usize] = false;
            stats.refitted_nodes += self.refit_from(leaf);
        }
        self.dynamics.dirty = dirty;
        self.dynamics.dirty.clear();
        if self.needs_rebuild() {
            self.rebuild();
            stats.rebuilt = true;
        }
        stats.quality = self.quality();
        stats
    }

    /// Rebuilds the tree over the live objects (node ids change; object ids do not).
    pub fn rebuild(&mut self) {
        let d = &self.dynamics;
        let ids: Vec<u32> = (0..d.object_leaf.len() as u32)
            .filter(|&i| d.object_leaf[i as usize] != u32::MAX)
            .collect();
        let (nodes, leaf_objects) = build_nodes(&d.object_bounds, &ids, d.leaf_size);
        self.nodes = nodes;
        self.leaf_objects = leaf_objects;
        self.dynamics.rebuilds += 1;
        self.after_build();
    }

    /// Summed interior surface area over its value right after the last build (1 when fresh).
    pub fn quality(&self) -> f32 {
        let d = &self.dynamics;
        if d.built_area > 0.0 {
            (d.area / d.built_area) as f32
        } else {
            1.0
        }
    }

    /// The rebuild policy.
    pub fn policy(&self) -> RebuildPolicy {
        self.dynamics.policy
    }

    /// Sets the rebuild policy.
    pub fn set_policy(&mut self, policy: RebuildPolicy) {
        self.dynamics.policy = policy;
    }

    /// The number of updates so far: the epoch the nodes' change stamps refer to.
    pub fn epoch(&self) -> u64 {
        self.dynamics.epoch
    }

    /// Whether `node`'s box changed in an update after `epoch`.
    pub fn changed_since(&self, node: u32, epoch: u64) -> bool {
        self.dynamics.changed_at[node as usize] > epoch
    }

    /// Whether `node`'s box grew beyond its previous box in an update after `epoch` (it may now
    /// cover space it did not cover then).
    pub fn grown_since(&self, node: u32, epoch: u64) -> bool {
        self.dynamics.grown_at[node as usize] > epoch
    }

    /// Full rebuilds so far (each renumbers the nodes).
    pub fn rebuilds(&self) -> u32 {
        self.dynamics.rebuilds
    }

    /// Bumped whenever nodes are added (insert) or renumbered (rebuild): per-node state sized
    /// or indexed by an older structure must be extended or rebuilt.
    pub fn structure(&self) -> u64 {
        self.dynamics.structure
    }

    /// Bumped whenever an object enters or leaves a leaf (build, rebuild, insert, remove):
    /// per-leaf object lists kept elsewhere ([`crate::SubtreeOrder`]) are stale when it moved.
    pub fn layout(&self) -> u64 {
        self.dynamics.layout
    }

    /// One past the largest object id ever handed out (per-object arrays need this length).
    pub fn object_capacity(&self) -> usize {
        self.dynamics.object_bounds.len()
    }

    /// Objects in the hierarchy now.
    pub fn live_objects(&self) -> usize {
        self.dynamics.live
    }

    /// An object's current box, or `None` if the id is not in the hierarchy.
    pub fn object_bounds(&self, object: u32) -> Option<Aabb> {
        self.leaf_of(object)
            .ok()
            .map(|_| self.dynamics.object_bounds[object as usize])
    }

    /// Checks the invariants: links agree, every leaf's box encloses its objects' boxes, every
    /// interior box encloses its children's, every live object is in its leaf. The first
    /// violation, in words.
    pub fn validate(&self) -> std::result::Result<(), String> {
        for (i, n) in self.nodes.iter().enumerate() {
            if n.is_leaf() {
                for &o in self.objects(i as u32) {
                    let b = &self.dynamics.object_bounds[o as usize];
                    if !encloses(&n.bounds, b) {
                        return Err(format!("leaf {i} does not enclose object {o}"));
                    }
                    if self.dynamics.object_leaf[o as usize] != i as u32 {
                        return Err(format!("object {o} is in leaf {i} but not mapped to it"));
                    }
                }
                continue;
            }
            for c in n.children {
                let child = &self.nodes[c as usize];
                if child.parent != i as u32 {
                    return Err(format!(
                        "node {c} is a child of {i} but has parent {}",
                        child.parent
                    ));
                }
                if !encloses(&n.bounds, &child.bounds) {
                    return Err(format!("node {i} does not enclose its child {c}"));
                }
            }
        }
        let placed: usize = self
            .nodes
            .iter()
            .filter(|n| n.is_leaf())
            .map(|n| n.object_count as usize)
            .sum();
        if placed != self.dynamics.live {
            return Err(format!(
                "{placed} objects in leaves, {} live",
                self.dynamics.live
            ));
        }
        Ok(())
    }

    fn leaf_of(&self, object: u32) -> Result<u32> {
        match self.dynamics.object_leaf.get(object as usize) {
            Some(&leaf) if leaf != u32::MAX => Ok(leaf),
            _ => Err(Error::Input(format!(
                "object {object} is not in the hierarchy"
            ))),
        }
    }

    fn mark_dirty(&mut self, leaf: u32) {
        let d = &mut self.dynamics;
        if !d.dirty_mark[leaf as usize] {
            d.dirty_mark[leaf as usize] = true;
            d.dirty.push(leaf);
        }
    }

    /// Per-node and per-object bookkeeping after a (re)build.
    fn after_build(&mut self) {
        let n = self.nodes.len();
        let d = &mut self.dynamics;
        d.dirty.clear();
        // Room for every leaf, so that marking what moved never allocates in a frame.
        d.dirty.reserve(n);
        d.dirty_mark = vec![false; n];
        d.changed_at = vec![d.epoch; n];
        d.grown_at = vec![d.epoch; n];
        d.structure += 1;
        d.layout += 1;
        d.churn = 0;
        d.object_leaf.iter_mut().for_each(|l| *l = u32::MAX);
        d.live = 0;
        for (i, node) in self.nodes.iter().enumerate() {
            if node.is_leaf() {
                let range =
                    node.first_object as usize..(node.first_object + node.object_count) as usize;
                for &o in &self.leaf_objects[range] {
                    d.object_leaf[o as usize] = i as u32;
                    d.live += 1;
                }
            }
        }
        d.area = interior_area(&self.nodes);
        d.built_area = d.area;
    }

    /// Refits `leaf` from its objects and its ancestors from their children, up to the first
    /// box that does not change. Returns the nodes changed.
    fn refit_from(&mut self, leaf: u32) -> u32 {
        let n = &self.nodes[leaf as usize];
        let mut new = if n.is_leaf() {
            self.objects(leaf).iter().fold(Aabb::EMPTY, |b, &o| {
                b.union(&self.dynamics.object_bounds[o as usize])
            })
        } else {
            // A root leaf that was split since it was marked.
            let [a, b] = n.children;
            self.nodes[a as usize]
                .bounds
                .union(&self.nodes[b as usize].bounds)
        };
        let mut node = leaf;
        let mut changed = 0;
        loop {
            let n = &mut self.nodes[node as usize];
            let old = n.bounds;
            if old == new {
                break;
            }
            n.bounds = new;
            changed += 1;
            let d = &mut self.dynamics;
            d.changed_at[node as usize] = d.epoch;
            if !encloses(&old, &new) {
                d.grown_at[node as usize] = d.epoch;
            }
            if !n.is_leaf() {
                d.area += (new.surface_area() - old.surface_area()) as f64;
            }
            let parent = n.parent;
            if parent == u32::MAX {
                break;
            }
            let [a, b] = self.nodes[parent as usize].children;
            new = self.nodes[a as usize]
                .bounds
                .union(&self.nodes[b as usize].bounds);
            node = parent;
        }
        changed
    }

    fn needs_rebuild(&self) -> bool {
        let d = &self.dynamics;
        let churned = d.churn as f32 > d.policy.churn_fraction * d.live.max(1) as f32;
        let degraded = d.built_area > 0.0 && d.area > d.policy.area_factor as f64 * d.built_area;
        churned || degraded
    }

    /// The leaf whose box grows least (in surface area) when `b` joins it, found by descending
    /// into the child that grows least.
    fn best_leaf(&self, b: &Aabb) -> u32 {
        let mut node = 0u32;
        while !self.nodes[node as usize].is_leaf() {
            let [x, y] = self.nodes[node as usize].children;
            let growth = |c: u32| {
                let cb = &self.nodes[c as usize].bounds;
                cb.union(b).surface_area() - cb.surface_area().max(0.0)
            };
            node = if growth(x) <= growth(y) { x } else { y };
        }
        node
    }

    /// Turns `leaf` into an interior node's first child and adds an empty leaf as its second;
    /// returns the new leaf. The root stays node 0 (a root leaf moves to a new index).
    fn split_leaf(&mut self, leaf: u32) -> u32 {
        let old = self.nodes[leaf as usize].clone();
        let (kept, parent) = if leaf == 0 {
            let moved = self.push_node(BvhNode {
                parent: 0,
                depth: 1,
                ..old.clone()
            });
            for k in 0..old.object_count {
                let o = self.leaf_objects[(old.first_object + k) as usize];
                self.dynamics.object_leaf[o as usize] = moved;
            }
            self.mark_dirty(moved);
            (moved, 0)
        } else {
            let p = self.push_node(BvhNode {
                children: [leaf, u32::MAX],
                first_object: 0,
                object_count: 0,
                ..old.clone()
            });
            let grand = &mut self.nodes[old.parent as usize];
            let slot = usize::from(grand.children[0] != leaf);
            grand.children[slot] = p;
            let l = &mut self.nodes[leaf as usize];
            l.parent = p;
            l.depth += 1;
            (leaf, p)
        };
        let depth = self.nodes[kept as usize].depth;
        let new_leaf = self.push_node(BvhNode {
            bounds: Aabb::EMPTY,
            parent,
            children: [u32::MAX; 2],
            first_object: 0,
            object_count: 0,
            depth,
        });
        let p = &mut self.nodes[parent as usize];
        p.children = [kept, new_leaf];
        p.object_count = 0;
        p.bounds = old.bounds;
        self.dynamics.area += old.bounds.surface_area() as f64;
        self.dynamics.structure += 1;
        new_leaf
    }

    fn push_node(&mut self, node: BvhNode) -> u32 {
        self.nodes.push(node);
        let d = &mut self.dynamics;
        d.dirty_mark.push(false);
        d.changed_at.push(d.epoch + 1);
        d.grown_at.push(d.epoch + 1);
        self.nodes.len() as u32 - 1
    }
}

/// Summed surface area of the interior nodes.
fn interior_area(nodes: &[BvhNode]) -> f64 {
    nodes
        .iter()
        .filter(|n| !n.is_leaf())
        .map(|n| n.bounds.surface_area() as f64)
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn unit_box(p: Vec3) -> Aabb {
        Aabb::new(p, p + Vec3::ONE)
    }

    /// A box that is not valid stands for a point at the origin in build, set_bounds and
    /// insert, as the docs of `build` say; the hierarchy stays finite.
    #[test]
    fn boxes_that_are_not_valid_stand_for_a_point_at_the_origin() {
        let origin = Aabb::new(Vec3::ZERO, Vec3::ZERO);
        let bad = [
            Aabb::new(Vec3::splat(f32::NAN), Vec3::ONE),
            Aabb::new(Vec3::splat(f32::NEG_INFINITY), Vec3::splat(f32::INFINITY)),
            Aabb::new(Vec3::splat(2.0), Vec3::ONE),
        ];
        let mut boxes = vec![unit_box(Vec3::splat(10.0))];
        boxes.extend(bad);
        let mut bvh = ObjectBvh::build(&boxes, 1);
        for o in 1..4 {
            assert_eq!(bvh.object_bounds(o), Some(origin), "object {o}");
        }
        bvh.set_bounds(0, bad[0]).unwrap();
        let id = bvh.insert(bad[2]);
        bvh.update();
        assert_eq!(bvh.object_bounds(0), Some(origin));
        assert_eq!(bvh.object_bounds(id), Some(origin));
        bvh.validate().unwrap();
        let root = &bvh.nodes[0].bounds;
        assert!(root.is_valid(), "root {root:?}");
    }

    /// `n` unit boxes on a jittered grid.
    fn grid(n: u32, rng: &mut Rng) -> Vec<Aabb> {
        (0..n)
            .map(|i| {
                let p = Vec3::new(
                    (i % 20) as f32 * 3.0,
                    rng.range(0.0, 2.0),
                    (i / 20) as f32 * 3.0,
                );
                unit_box(p)
            })
            .collect()
    }

    #[test]
    fn refit_keeps_every_box_enclosing_after_1000_random_moves() {
        let mut rng = Rng::new(7);
        let boxes = grid(400, &mut rng);
        let mut bvh = ObjectBvh::build(&boxes, 1);
        bvh.set_policy(RebuildPolicy {
            area_factor: f32::INFINITY,
            churn_fraction: f32::INFINITY,
        });
        let mut current = boxes.clone();
        for step in 0..1000 {
            let o = rng.below(400);
            let d = Vec3::new(
                rng.range(-4.0, 4.0),
                rng.range(-1.0, 1.0),
                rng.range(-4.0, 4.0),
            );
            current[o as usize] = unit_box(current[o as usize].min + d);
            bvh.set_bounds(o, current[o as usize]).unwrap();
            if step % 10 == 9 {
                let s = bvh.update();
                assert!(!s.rebuilt);
                bvh.validate().unwrap();
            }
        }
        bvh.update();
        bvh.validate().unwrap();
        for (o, b) in current.iter().enumerate() {
            assert_eq!(bvh.object_bounds(o as u32), Some(*b));
        }
        // The root is exactly the union of all boxes (refit is tight, not only enclosing).
        let all = current.iter().fold(Aabb::EMPTY, |a, b| a.union(b));
        assert_eq!(bvh.nodes[0].bounds, all);
        assert_eq!(bvh.rebuilds(), 0);
    }

    #[test]
    fn refit_cost_follows_what_moved() {
        let mut rng = Rng::new(3);
        let boxes = grid(400, &mut rng);
        let mut bvh = ObjectBvh::build(&boxes, 1);
        let s = bvh.update();
        assert_eq!((s.dirty_leaves, s.refitted_nodes), (0, 0));
        // A move inside its own box changes only the leaf.
        bvh.set_bounds(5, Aabb::new(boxes[5].min, boxes[5].max - Vec3::splat(0.5)))
            .unwrap();
        let s = bvh.update();
        assert_eq!(s.dirty_leaves, 1);
        assert!(s.refitted_nodes <= bvh.nodes[bvh.dynamics.object_leaf[5] as usize].depth + 1);
        let leaf = bvh.dynamics.object_leaf[5];
        assert!(bvh.changed_since(leaf, bvh.epoch() - 1));
        assert!(!bvh.grown_since(leaf, bvh.epoch() - 1));
        assert!(
            !bvh.changed_since(0, bvh.epoch() - 1),
            "the root did not change"
        );
    }

    #[test]
    fn rebuild_when_quality_degrades_and_not_otherwise() {
        let mut rng = Rng::new(11);
        let boxes = grid(400, &mut rng);
        let mut bvh = ObjectBvh::build(&boxes, 1);
        // Small jitter for many frames: the tree stays good, no rebuild.
        let mut current = boxes.clone();
        for _ in 0..50 {
            for (o, b) in current.iter_mut().enumerate() {
                let home = boxes[o].min;
                let d = Vec3::new(rng.range(-0.2, 0.2), 0.0, rng.range(-0.2, 0.2));
                *b = unit_box(home + d);
                bvh.set_bounds(o as u32, *b).unwrap();
            }
            let s = bvh.update();
            assert!(!s.rebuilt, "quality {}", s.quality);
        }
        assert_eq!(bvh.rebuilds(), 0);
        // Shuffle the objects across the grid: the refitted boxes overlap, quality degrades.
        let mut rebuilt_at = None;
        for step in 0..400u32 {
            let o = (step * 37) % 400;
            let to = boxes[((o * 211 + 101) % 400) as usize].min;
            bvh.set_bounds(o, unit_box(to)).unwrap();
            let before = bvh.quality();
            let s = bvh.update();
            if s.rebuilt {
                assert!(bvh.quality() <= 1.0 + 1e-3, "fresh after a rebuild");
                assert!(before <= bvh.policy().area_factor);
                rebuilt_at = Some(step);
                break;
            }
            assert!(s.quality <= bvh.policy().area_factor);
        }
        assert!(rebuilt_at.is_some(), "degraded tree was rebuilt");
        bvh.validate().unwrap();
        assert_eq!(bvh.rebuilds(), 1);
    }

    #[test]
    fn insert_and_remove_keep_ids_and_invariants() {
        let mut rng = Rng::new(5);
        let boxes = grid(100, &mut rng);
        let mut bvh = ObjectBvh::build(&boxes, 1);
        // Between the others: no box grows much, so no rebuild.
        let a = bvh.insert(unit_box(Vec3::new(31.5, 0.5, 7.5)));
        assert_eq!(a, 100);
        bvh.remove(3).unwrap();
        assert!(bvh.remove(3).is_err(), "removed twice");
        assert!(bvh.set_bounds(3, boxes[0]).is_err());
        let s = bvh.update();
        assert!(!s.rebuilt);
        bvh.validate().unwrap();
        let far = bvh.insert(unit_box(Vec3::new(200.0, 0.0, 0.0)));
        let s = bvh.update();
        assert!(s.rebuilt, "a far object degrades the tree: rebuilt");
        assert!(bvh.nodes[0].bounds.max.x >= 201.0);
        bvh.remove(far).unwrap();
        let in_leaves = |bvh: &ObjectBvh, o: u32| {
            (0..bvh.nodes.len() as u32)
                .any(|n| bvh.nodes[n as usize].is_leaf() && bvh.objects(n).contains(&o))
        };
        assert!(in_leaves(&bvh, a));
        assert!(!in_leaves(&bvh, 3));
        // Many inserts: the churn rule rebuilds, ids survive it.
        let ids: Vec<u32> = (0..40)
            .map(|i| bvh.insert(unit_box(Vec3::new(-50.0 - i as f32 * 2.0, 0.0, 0.0))))
            .collect();
        assert_eq!(ids[0], far, "the freed id is reused");
        let s = bvh.update();
        assert!(s.rebuilt);
        bvh.validate().unwrap();
        for &id in ids.iter().chain([a].iter()) {
            assert!(in_leaves(&bvh, id));
        }
        assert_eq!(bvh.live_objects(), 140);
    }

    /// `build_where` leaves the objects it skips in no leaf, through updates and rebuilds,
    /// and `insert` never hands out their ids.
    #[test]
    fn objects_left_out_of_the_build_stay_out() {
        let mut rng = Rng::new(9);
        let boxes = grid(60, &mut rng);
        let left_out = |o: u32| o % 7 == 3;
        let mut bvh = ObjectBvh::build_where(&boxes, |o| !left_out(o), 2);
        bvh.validate().unwrap();
        let in_leaves = |bvh: &ObjectBvh, o: u32| {
            (0..bvh.nodes.len() as u32)
                .any(|n| bvh.nodes[n as usize].is_leaf() && bvh.objects(n).contains(&o))
        };
        let kept = (0..60).filter(|&o| !left_out(o)).count();
        assert_eq!(bvh.live_objects(), kept);
        assert_eq!(bvh.object_capacity(), 60);
        for o in 0..60 {
            assert_eq!(in_leaves(&bvh, o), !left_out(o), "object {o}");
        }
        assert!(bvh.set_bounds(3, boxes[0]).is_err(), "3 is in no leaf");
        // New ids come after the last one, never a left-out one, and survive a rebuild.
        let ids: Vec<u32> = (0..30)
            .map(|i| bvh.insert(unit_box(Vec3::new(-40.0 - i as f32 * 2.0, 0.0, 0.0))))
            .collect();
        assert_eq!(ids, (60..90).collect::<Vec<u32>>());
        assert!(bvh.update().rebuilt);
        bvh.validate().unwrap();
        for o in 0..90 {
            assert_eq!(in_leaves(&bvh, o), !(o < 60 && left_out(o)), "object {o}");
        }
    }

    #[test]
    fn an_empty_hierarchy_grows_and_shrinks() {
        let mut bvh = ObjectBvh::build(&[], 1);
        let a = bvh.insert(unit_box(Vec3::ZERO));
        let b = bvh.insert(unit_box(Vec3::splat(5.0)));
        bvh.update();
        bvh.validate().unwrap();
        assert_eq!(bvh.nodes[0].bounds, Aabb::new(Vec3::ZERO, Vec3::splat(6.0)));
        bvh.remove(a).unwrap();
        bvh.remove(b).unwrap();
        bvh.update();
        bvh.validate().unwrap();
        assert_eq!(bvh.live_objects(), 0);
    }

    /// The SAH cost of a tree (traversal and object cost 1), relative to the root's area.
    fn sah_cost(bvh: &ObjectBvh) -> f64 {
        let root = bvh.nodes[0].bounds.surface_area() as f64;
        let cost = |n: &BvhNode| {
            let a = n.bounds.surface_area() as f64 / root;
            if n.is_leaf() {
                a * n.object_count as f64
            } else {
                a * SAH_TRAVERSAL_COST as f64
            }
        };
        bvh.nodes.iter().map(cost).sum()
    }

    /// The SAH cost (as [`sah_cost`]) of the naive tree: split at the median centroid along
    /// the longest axis of the centroids' box, one object per leaf.
    fn median_split_cost(boxes: &mut [Aabb], root_area: f64) -> f64 {
        let b = boxes.iter().fold(Aabb::EMPTY, |a, b| a.union(b));
        let a = b.surface_area() as f64 / root_area;
        if boxes.len() == 1 {
            return a;
        }
        let c = boxes.iter().fold(Aabb::EMPTY, |mut c, b| {
            c.grow(b.center());
            c
        });
        let axis = c.extent().max_position();
        let mid = boxes.len() / 2;
        boxes.select_nth_unstable_by(mid, |x, y| x.center()[axis].total_cmp(&y.center()[axis]));
        let (l, r) = boxes.split_at_mut(mid);
        a * SAH_TRAVERSAL_COST as f64
            + median_split_cost(l, root_area)
            + median_split_cost(r, root_area)
    }

    /// `n` boxes of mixed sizes over a city-sized block (low and wide, some tall).
    fn random_scene(n: u32, rng: &mut Rng) -> Vec<Aabb> {
        (0..n)
            .map(|_| {
                let p = Vec3::new(
                    rng.range(0.0, 300.0),
                    rng.range(0.0, 5.0),
                    rng.range(0.0, 300.0),
                );
                let s = Vec3::new(
                    rng.range(0.2, 8.0),
                    rng.range(0.2, 30.0),
                    rng.range(0.2, 8.0),
                );
                Aabb::new(p, p + s)
            })
            .collect()
    }

    #[test]
    fn sah_build_is_no_worse_than_a_median_split() {
        let mut rng = Rng::new(19);
        let mut boxes = random_scene(3000, &mut rng);
        let bvh = ObjectBvh::build(&boxes, 1);
        bvh.validate().unwrap();
        let sah = sah_cost(&bvh);
        let root = bvh.nodes[0].bounds.surface_area() as f64;
        let median = median_split_cost(&mut boxes, root);
        assert!(
            sah <= median,
            "SAH build {sah:.2}, median split {median:.2}"
        );
        // Not only no worse: on scattered boxes of mixed sizes the SAH saves a good share.
        assert!(
            sah < 0.95 * median,
            "SAH build {sah:.2}, median split {median:.2}"
        );
    }

    #[test]
    fn build_lays_out_parents_first_and_leaves_contiguous() {
        let mut rng = Rng::new(23);
        let boxes = random_scene(500, &mut rng);
        for leaf_size in [1, 4] {
            let bvh = ObjectBvh::build(&boxes, leaf_size);
            bvh.validate().unwrap();
            let again = ObjectBvh::build(&boxes, leaf_size);
            assert_eq!(bvh.leaf_objects, again.leaf_objects, "deterministic");
            let mut next_object = 0;
            for (i, n) in bvh.nodes.iter().enumerate() {
                if i > 0 {
                    assert!((n.parent as usize) < i, "parent before child");
                    assert_eq!(n.depth, bvh.nodes[n.parent as usize].depth + 1);
                }
                if n.is_leaf() {
                    assert!(n.object_count >= 1 && n.object_count <= leaf_size);
                    // Depth-first: leaves own consecutive ranges in node order.
                    assert_eq!(n.first_object, next_object);
                    next_object += n.object_count;
                } else {
                    let [a, b] = n.children;
                    assert_eq!(
                        n.bounds,
                        bvh.nodes[a as usize]
                            .bounds
                            .union(&bvh.nodes[b as usize].bounds)
                    );
                    assert_eq!(a as usize, i + 1, "the first child follows its parent");
                }
            }
            let mut all = bvh.leaf_objects.clone();
            all.sort_unstable();
            assert_eq!(all, (0..500).collect::<Vec<u32>>(), "every object once");
        }
    }

    #[test]
    fn leaves_group_objects_only_when_the_sah_says_so() {
        // Pairs of almost identical boxes far apart: with room for 4 objects a leaf takes a
        // pair (splitting it saves nothing), never two pairs.
        let boxes: Vec<Aabb> = (0..64)
            .map(|i| unit_box(Vec3::new((i / 2) as f32 * 10.0, 0.0, (i % 2) as f32 * 0.01)))
            .collect();
        let bvh = ObjectBvh::build(&boxes, 4);
        bvh.validate().unwrap();
        assert_eq!(bvh.leaf_count(), 32);
        assert!(bvh
            .nodes
            .iter()
            .filter(|n| n.is_leaf())
            .all(|n| n.object_count == 2));
        let single = ObjectBvh::build(&boxes, 1);
        assert_eq!(single.leaf_count(), 64);
    }

    #[test]
    fn coinciding_centroids_split_at_the_median() {
        let boxes = vec![unit_box(Vec3::splat(3.0)); 9];
        let bvh = ObjectBvh::build(&boxes, 1);
        bvh.validate().unwrap();
        assert_eq!(bvh.leaf_count(), 9);
        assert_eq!(bvh.nodes.iter().map(|n| n.depth).max(), Some(4), "balanced");
        let bvh = ObjectBvh::build(&boxes, 4);
        bvh.validate().unwrap();
        assert!(bvh.nodes.iter().all(|n| n.object_count <= 4));
        assert_eq!(bvh.leaf_count(), 3);
    }
}
