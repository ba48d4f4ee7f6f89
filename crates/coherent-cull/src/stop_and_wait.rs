//! Hierarchical stop-and-wait: front-to-back traversal; query each node's box and wait for the
//! answer; visible interior nodes are opened, visible leaves rendered, invisible subtrees culled.

use super::{CullStats, Culler, FrameInput, OcclusionBackend, View};
use crate::bvh::DistanceQueue;
use crate::error::Result;

/// Stop-and-wait hierarchical occlusion culling.
#[derive(Default)]
pub struct StopAndWait {
    queue: DistanceQueue,
    /// A query counting more than this many pixels means visible.
    pub pixel_threshold: u64,
}

impl Culler for StopAndWait {
    fn name(&self) -> &str {
        "stop-and-wait"
    }

    fn cull_frame(
        &mut self,
        input: &FrameInput,
        backend: &mut dyn OcclusionBackend,
    ) -> Result<CullStats> {
        let view = View::new(&input.view);
        let bvh = input.bvh;
        let mut stats = CullStats::default();
        self.queue.clear();
        self.queue
            .push(0, bvh.nodes[0].bounds.distance_squared(view.eye));
        while let Some(id) = self.queue.pop() {
            let node = &bvh.nodes[id as usize];
            stats.nodes_visited += 1;
            if !view.in_view(&node.bounds) {
                stats.frustum_culled += 1;
                continue;
            }
            if !view.eye_inside(&node.bounds) {
                let q = backend.issue_query(std::slice::from_ref(&node.bounds))?;
                stats.queries += 1;
                stats.query_batches += 1;
                let pixels = backend.wait_query(q)?;
                if pixels <= self.pixel_threshold {
                    stats.query_culled += 1;
                    continue;
                }
                stats.visible_results += 1;
            }
            if node.is_leaf() {
                let objects = bvh.objects(id);
                stats.objects_drawn += objects.len() as u32;
                backend.draw_objects(objects)?;
            } else {
                for c in node.children {
                    self.queue
                        .push(c, bvh.nodes[c as usize].bounds.distance_squared(view.eye));
                }
            }
        }
        backend.finish()?;
        Ok(stats)
    }

    fn reset(&mut self) {}
}
