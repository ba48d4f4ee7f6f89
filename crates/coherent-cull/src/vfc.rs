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

impl Vfc {
    /// Draws, front to back, every object of a leaf in the frustum that `keep` accepts, in one
    /// batch, and finishes the frame (vfc keeps everything; pvs keeps its cell's set).
    pub(crate) fn draw_in_frustum(
        &mut self,
        input: &FrameInput,
        backend: &mut dyn OcclusionBackend,
        keep: impl Fn(u32) -> bool,
    ) -> Result<CullStats> {
        let view = View::new(&input.view);
        let mut stats = CullStats::default();
        self.batch.clear();
        let batch = &mut self.batch;
        input
            .bvh
            .front_to_back_with(&mut self.queue, view.eye, |id, node| {
                stats.nodes_visited += 1;
                if !view.in_view(&node.bounds) {
                    stats.frustum_culled += 1;
                    return false;
                }
                if node.is_leaf() {
                    let objects = input.bvh.objects(id);
                    batch.extend(objects.iter().filter(|&&o| keep(o)));
                }
                true
            });
        stats.objects_drawn = batch.len() as u32;
        backend.draw_objects(batch)?;
        backend.finish()?;
        Ok(stats)
    }
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
        self.draw_in_frustum(input, backend, |_| true)
    }

    fn reset(&mut self) {}
}
