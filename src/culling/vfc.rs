//! View-frustum culling: the baseline every engine has. Front-to-back through the BVH, draws
//! every leaf whose box touches the frustum, no queries.

use super::{CullStats, Culler, FrameInput, OcclusionBackend, View};
use crate::bvh::DistanceQueue;
use crate::error::Result;

/// View-frustum culling only.
#[derive(Default)]
pub struct Vfc {
    batch: Vec<u32>,
    queue: DistanceQueue,
}

impl Culler for Vfc {
    fn name(&self) -> &str {
        "vfc"
    }

    fn cull_frame(
        &mut self,
        input: &FrameInput,
        backend: &mut dyn OcclusionBackend,
    ) -> Result<CullStats> {
        let view = View::new(&input.view);
        let mut stats = CullStats::default();
        self.batch.clear();
        let batch = &mut self.batch;
        input
            .bvh
            .front_to_back_with(&mut self.queue, view.eye, |id, node| {
                stats.nodes_visited += 1;
                if !view.frustum.intersects(&node.bounds) {
                    stats.frustum_culled += 1;
                    return false;
                }
                if node.is_leaf() {
                    batch.extend_from_slice(input.bvh.objects(id));
                }
                true
            });
        stats.objects_drawn = batch.len() as u32;
        backend.draw_objects(batch)?;
        backend.finish()?;
        Ok(stats)
    }

    fn reset(&mut self) {}
}
