//! Tight bounding volumes: a node is queried with the boxes of its descendants a few levels
//! down instead of its own box, while their total surface area stays small. They are kept as
//! descendant node ids, so a query always draws the current (refitted) boxes.
//!
//! The predicated mode queries with the nodes' own boxes unless `predicated_tight_bounds` is
//! on (as [`ChcppParams::for_gpu`] has it): seen along a street, a node's descendants overlap
//! on screen, and on a CPU rasterizer every fragment of every box is depth-tested.

use super::{Chcpp, ChcppParams, SCREEN_SPLIT_GAIN};
use crate::bvh::ObjectBvh;
use crate::camera::projected_rect;
use crate::Aabb;
use crate::View;

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
            _ => match &self.frame_view {
                Some(view) if self.uses_screen_split() => {
                    screen_split(bvh, node, view, self.params.predicated_screen_split, out)
                }
                _ => out.push(bvh.nodes[node as usize].bounds),
            },
        }
    }

    /// Whether large query boxes are split by their screen area
    /// ([`ChcppParams::predicated_screen_split`]): the predicated mode only.
    fn uses_screen_split(&self) -> bool {
        self.params.predicated_screen_split > 0.0
            && self.mode.latency() == crate::Latency::Predicated
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

/// Most boxes one node's test is split into by [`screen_split`].
const SCREEN_SPLIT_MOST: usize = 16;

/// The fraction of the screen that `b`'s screen rectangle covers, clipped to the screen;
/// `INFINITY` when a corner lies at or behind the eye plane (no bound).
pub(super) fn screen_fraction(view: &View, b: &Aabb) -> f32 {
    match projected_rect(&view.camera().view_proj, b) {
        None => f32::INFINITY,
        Some((lo, hi)) => {
            let lo = lo.clamp(glam::Vec2::splat(-1.0), glam::Vec2::splat(1.0));
            let hi = hi.clamp(glam::Vec2::splat(-1.0), glam::Vec2::splat(1.0));
            let d = (hi - lo).max(glam::Vec2::ZERO);
            d.x * d.y * 0.25
        }
    }
}

/// `node`'s query boxes split by screen area: a box above `min_fraction` of the screen is
/// replaced by its children's boxes that are in view while theirs add up to less than
/// [`SCREEN_SPLIT_GAIN`] of its own, level by level, at most [`SCREEN_SPLIT_MOST`] boxes.
/// Exact: every object below the node that can own a pixel lies in a child in view.
pub(super) fn screen_split(
    bvh: &ObjectBvh,
    node: u32,
    view: &View,
    min_fraction: f32,
    out: &mut Vec<Aabb>,
) {
    let start = out.len();
    // Boxes kept plus boxes on the stack never exceed SCREEN_SPLIT_MOST (no allocation).
    let mut stack = [(0u32, 0.0f32); SCREEN_SPLIT_MOST];
    stack[0] = (
        node,
        screen_fraction(view, &bvh.nodes[node as usize].bounds),
    );
    let mut top = 1;
    while top > 0 {
        top -= 1;
        let (n, area) = stack[top];
        let nn = &bvh.nodes[n as usize];
        let room = out.len() - start + top + 2 <= SCREEN_SPLIT_MOST;
        if nn.is_leaf() || area <= min_fraction || !room {
            out.push(nn.bounds);
            continue;
        }
        let mut kids = [(0u32, 0.0f32); 2];
        let mut count = 0;
        let mut sum = 0.0;
        for &c in &nn.children {
            let b = &bvh.nodes[c as usize].bounds;
            if b.is_valid() && view.in_view(b) {
                let a = screen_fraction(view, b);
                kids[count] = (c, a);
                count += 1;
                sum += a;
            }
        }
        if area.is_infinite() || sum < SCREEN_SPLIT_GAIN * area {
            stack[top..top + count].copy_from_slice(&kids[..count]);
            top += count;
        } else {
            out.push(nn.bounds);
        }
    }
    if out.len() == start {
        // No child in view: the node's own box (its test then fails or shows as before).
        out.push(bvh.nodes[node as usize].bounds);
    }
}
