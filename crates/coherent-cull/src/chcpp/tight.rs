//! Tight bounding volumes: a node is queried with the boxes of its descendants a few levels
//! down instead of its own box, while their total surface area stays small. They are kept as
//! descendant node ids, so a query always draws the current (refitted) boxes.

use super::{Chcpp, ChcppParams};
use crate::bvh::ObjectBvh;
use crate::Aabb;

impl Chcpp {
    /// The boxes a node is queried with: its tight volume's current boxes (empty leaves left
    /// by removals skipped), or its own box: always when it has no tight volume, and with
    /// `tight_screen_area`, for boxes that are rasterized (`rasterized`: a query's, not a
    /// backend's own part test), when the tight boxes would cover at least as much of this
    /// frame's screen as the own box.
    pub(super) fn query_boxes(
        &self,
        bvh: &ObjectBvh,
        node: u32,
        rasterized: bool,
        out: &mut Vec<Aabb>,
    ) {
        let own = bvh.nodes[node as usize].bounds;
        match &self.tight[node as usize] {
            Some(t) if self.params.tight_bounds => {
                let boxes = t
                    .iter()
                    .map(|&d| bvh.nodes[d as usize].bounds)
                    .filter(Aabb::is_valid);
                if rasterized
                    && self.params.tight_screen_area
                    && !covers_less(boxes.clone(), &own, &self.view_proj)
                {
                    out.push(own);
                } else {
                    out.extend(boxes);
                }
            }
            _ => out.push(own),
        }
    }
}

/// Whether `boxes`, each rasterized on its own, cover less of the screen through `view_proj`
/// than `own`, the box around them. When `own` reaches behind the eye plane its area is
/// unbounded and the boxes count as less; when one of them does (and `own` does not), as more.
fn covers_less(boxes: impl Iterator<Item = Aabb>, own: &Aabb, view_proj: &glam::Mat4) -> bool {
    let Some(limit) = own.screen_area(view_proj) else {
        return true;
    };
    let mut sum = 0.0;
    for b in boxes {
        match b.screen_area(view_proj) {
            Some(a) => sum += a,
            None => return false,
        }
        if sum >= limit {
            return false;
        }
    }
    true
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
