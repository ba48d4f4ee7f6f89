//! Tight bounding volumes: a node is queried with the boxes of its descendants a few levels
//! down instead of its own box, while their total surface area stays small. They are kept as
//! descendant node ids, so a query always draws the current (refitted) boxes.
//!
//! The predicated mode queries with the nodes' own boxes unless `predicated_tight_bounds` is
//! on (as [`ChcppParams::for_gpu`] has it): seen along a street, a node's descendants overlap
//! on screen, and on a CPU rasterizer every fragment of every box is depth-tested.

use super::{Chcpp, ChcppParams};
use crate::bvh::ObjectBvh;
use crate::Aabb;

impl Chcpp {
    /// The boxes a node is queried with: its tight volume's current boxes (empty leaves left
    /// by removals skipped), or its own box.
    pub(super) fn query_boxes(&self, bvh: &ObjectBvh, node: u32, out: &mut Vec<Aabb>) {
        match &self.tight[node as usize] {
            Some(t) if self.uses_tight_bounds() => out.extend(
                t.iter()
                    .map(|&d| bvh.nodes[d as usize].bounds)
                    .filter(Aabb::is_valid),
            ),
            _ => out.push(bvh.nodes[node as usize].bounds),
        }
    }

    /// Whether queries use tight bounding volumes: `tight_bounds`, and in the predicated mode
    /// also `predicated_tight_bounds`.
    pub(super) fn uses_tight_bounds(&self) -> bool {
        self.params.tight_bounds
            && (self.params.predicated_tight_bounds
                || self.mode.latency() != crate::Latency::Predicated)
    }
}

/// Tight bounding volume of `node`: the boxes of its descendants one level further down at a
/// time (leaves stand for themselves), as long as their total surface area stays within
/// `tight_area_factor` times the node's, up to `tight_depth` levels; the deepest level that
/// passes wins. `None` when already the first level fails (query the node's own box).
pub(super) fn tight_boxes(bvh: &ObjectBvh, node: u32, params: &ChcppParams) -> Option<Vec<u32>> {
    let root = &bvh.nodes[node as usize];
    if root.is_leaf() {
        return None;
    }
    let limit = params.tight_area_factor * root.bounds.surface_area();
    let mut level = vec![node];
    let mut best = None;
    for _ in 0..params.tight_depth {
        let mut next = Vec::with_capacity(level.len() * 2);
        for &n in &level {
            let nn = &bvh.nodes[n as usize];
            if nn.is_leaf() {
                next.push(n);
            } else {
                next.extend_from_slice(&nn.children);
            }
        }
        if next == level {
            break; // only leaves left
        }
        let area: f32 = next
            .iter()
            .map(|&n| bvh.nodes[n as usize].bounds.surface_area())
            .sum();
        if area > limit {
            break;
        }
        best = Some(next.clone());
        level = next;
    }
    best
}
