//! The exact-visibility oracle: draws exactly the objects that cover at least one pixel, as
//! found by an untimed ID-buffer pass before the frame. No queries; the physical limit.

use super::{CullStats, Culler, FrameInput, OcclusionBackend};
use crate::error::{Error, Result};

/// Renders only the exactly visible objects.
#[derive(Default)]
pub struct Oracle;

impl Culler for Oracle {
    fn name(&self) -> &str {
        "oracle"
    }

    fn needs_exact_visibility(&self) -> bool {
        true
    }

    fn cull_frame(
        &mut self,
        input: &FrameInput,
        backend: &mut dyn OcclusionBackend,
    ) -> Result<CullStats> {
        let visible = input
            .exact_visible
            .ok_or_else(|| Error::Input("the oracle needs the exact visible set".into()))?;
        backend.draw_objects(visible)?;
        backend.finish()?;
        Ok(CullStats {
            objects_drawn: visible.len() as u32,
            ..Default::default()
        })
    }

    fn reset(&mut self) {}
}
