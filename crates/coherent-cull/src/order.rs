//! One depth-first order of a hierarchy's objects in which every subtree is a contiguous range.

use crate::bvh::ObjectBvh;

/// The objects of an [`ObjectBvh`] in depth-first order (the second child of a node before the
/// first, as a stack-based walk meets them), so that the objects below any node form one
/// contiguous slice ([`SubtreeOrder::subtree`]).
///
/// The predicated mode of CHC++ hands a backend the objects of whole subtrees; a backend that
/// keeps one draw command per object in this order
/// ([`OcclusionBackend::set_draw_order`](crate::OcclusionBackend::set_draw_order)) draws such a
/// subtree with one command range instead of one command written per object.
#[derive(Clone, Debug, Default)]
pub struct SubtreeOrder {
    objects: Vec<u32>,
    /// Per node: the first index into `objects` of its subtree, and how many objects it holds.
    ranges: Vec<(u32, u32)>,
    /// The hierarchy's `layout()` and node count this order was made for.
    made_for: Option<(u64, usize)>,
    stack: Vec<u32>,
}

impl SubtreeOrder {
    /// The order of `bvh`'s objects.
    pub fn new(bvh: &ObjectBvh) -> SubtreeOrder {
        let mut order = SubtreeOrder::default();
        order.update(bvh);
        order
    }

    /// Makes the order again when objects entered or left leaves since it was made (build,
    /// rebuild, insert, remove: [`ObjectBvh::layout`]); refits keep it. Returns whether it
    /// changed.
    pub fn update(&mut self, bvh: &ObjectBvh) -> bool {
        let key = (bvh.layout(), bvh.nodes.len());
        if self.made_for == Some(key) {
            return false;
        }
        self.objects.clear();
        self.ranges.clear();
        self.ranges.resize(bvh.nodes.len(), (0, 0));
        // Pre-order: a node's range starts where the walk meets it; its objects follow.
        let mut visited = Vec::with_capacity(bvh.nodes.len());
        self.stack.clear();
        if !bvh.nodes.is_empty() {
            self.stack.push(0);
        }
        while let Some(n) = self.stack.pop() {
            let node = &bvh.nodes[n as usize];
            self.ranges[n as usize].0 = self.objects.len() as u32;
            visited.push(n);
            if node.is_leaf() {
                self.objects.extend_from_slice(bvh.objects(n));
            } else {
                self.stack.extend_from_slice(&node.children);
            }
        }
        // Children were met after their parents: counts bottom-up in reverse.
        for &n in visited.iter().rev() {
            let node = &bvh.nodes[n as usize];
            self.ranges[n as usize].1 = if node.is_leaf() {
                node.object_count
            } else {
                node.children
                    .iter()
                    .map(|&c| self.ranges[c as usize].1)
                    .sum()
            };
        }
        self.made_for = Some(key);
        true
    }

    /// Every object, in the order.
    pub fn objects(&self) -> &[u32] {
        &self.objects
    }

    /// The objects below `node`, in the order (empty for a node the hierarchy does not have).
    pub fn subtree(&self, node: u32) -> &[u32] {
        match self.ranges.get(node as usize) {
            Some(&(first, count)) => &self.objects[first as usize..(first + count) as usize],
            None => &[],
        }
    }

    /// Where the objects below `node` lie in [`SubtreeOrder::objects`] (empty for a node the
    /// hierarchy does not have).
    pub fn range(&self, node: u32) -> std::ops::Range<u32> {
        match self.ranges.get(node as usize) {
            Some(&(first, count)) => first..first + count,
            None => 0..0,
        }
    }

    /// How many objects lie below `node` (0 for a node the hierarchy does not have).
    pub fn count_below(&self, node: u32) -> u32 {
        self.ranges.get(node as usize).map_or(0, |r| r.1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Aabb;
    use glam::Vec3;

    fn boxes(n: u32) -> Vec<Aabb> {
        (0..n)
            .map(|i| {
                let p = Vec3::new((i % 7) as f32 * 3.0, (i / 7) as f32 * 2.0, (i % 3) as f32);
                Aabb::new(p, p + Vec3::ONE)
            })
            .collect()
    }

    /// Every node's objects, gathered by walking its subtree.
    fn below(bvh: &ObjectBvh, node: u32) -> Vec<u32> {
        let n = &bvh.nodes[node as usize];
        if n.is_leaf() {
            return bvh.objects(node).to_vec();
        }
        let mut out = below(bvh, n.children[1]);
        out.extend(below(bvh, n.children[0]));
        out
    }

    #[test]
    fn every_subtree_is_its_objects_in_walk_order() {
        for leaf_size in [1, 4] {
            let bvh = ObjectBvh::build(&boxes(50), leaf_size);
            let order = SubtreeOrder::new(&bvh);
            let mut all = order.objects().to_vec();
            all.sort_unstable();
            assert_eq!(all, (0..50).collect::<Vec<_>>());
            for n in 0..bvh.nodes.len() as u32 {
                assert_eq!(order.subtree(n), below(&bvh, n).as_slice(), "node {n}");
                assert_eq!(order.count_below(n) as usize, order.subtree(n).len());
                let r = order.range(n);
                assert_eq!(
                    &order.objects()[r.start as usize..r.end as usize],
                    order.subtree(n)
                );
            }
            assert!(order.subtree(bvh.nodes.len() as u32).is_empty());
            assert!(order.range(bvh.nodes.len() as u32).is_empty());
        }
    }

    #[test]
    fn follows_inserts_and_removals_not_refits() {
        let mut bvh = ObjectBvh::build(&boxes(20), 1);
        let mut order = SubtreeOrder::new(&bvh);
        let moved = bvh.object_bounds(3).unwrap();
        let step = Vec3::splat(0.25);
        bvh.set_bounds(3, Aabb::new(moved.min + step, moved.max + step))
            .unwrap();
        assert!(!bvh.update().rebuilt);
        assert!(!order.update(&bvh), "a refit keeps the order");
        bvh.remove(5).unwrap();
        bvh.update();
        assert!(order.update(&bvh));
        assert!(!order.objects().contains(&5));
        let id = bvh.insert(Aabb::new(Vec3::splat(-5.0), Vec3::splat(-4.0)));
        bvh.update();
        assert!(order.update(&bvh));
        assert!(order.objects().contains(&id));
        assert_eq!(order.objects().len(), 20);
        for n in 0..bvh.nodes.len() as u32 {
            assert_eq!(order.subtree(n), below(&bvh, n).as_slice(), "node {n}");
        }
    }
}
