//! The exact-visibility oracle: draws exactly the objects that cover at least one pixel, as
//! found by an untimed ID-buffer pass before the frame. No queries; the physical limit.
//!
//! Its variant `oracle-box` draws the objects whose own bounding box shows against the depth
//! of the same pass (tested as occlusion-query boxes are): what an ideal culler that tests
//! boxes would draw, with no query paid for. The time between it and the oracle is the price of
//! testing boxes rather than objects; the time between a box culler and it is the price of the
//! culler's hierarchy, history and queries.

use super::{CullStats, Culler, FrameInput, OcclusionBackend};
use crate::error::{Error, Result};

/// Renders only the exactly visible objects (or, [`Oracle::boxes`], the objects whose box is
/// visible).
#[derive(Default)]
pub struct Oracle {
    boxes: bool,
}

impl Oracle {
    /// The box oracle, `oracle-box`: draws the objects whose bounding box covers a pixel of the
    /// exact depth ([`Culler::needs_box_visibility`]).
    pub fn boxes() -> Oracle {
        Oracle { boxes: true }
    }
}

impl Culler for Oracle {
    fn name(&self) -> &str {
        if self.boxes {
            "oracle-box"
        } else {
            "oracle"
        }
    }

    fn needs_exact_visibility(&self) -> bool {
        true
    }

    fn needs_box_visibility(&self) -> bool {
        self.boxes
    }

    fn cull_frame(
        &mut self,
        input: &FrameInput,
        backend: &mut dyn OcclusionBackend,
    ) -> Result<CullStats> {
        let visible = input
            .exact_visible
            .ok_or_else(|| Error::Input(format!("{} needs the exact visible set", self.name())))?;
        backend.draw_objects(visible)?;
        backend.finish()?;
        Ok(CullStats {
            objects_drawn: visible.len() as u32,
            ..Default::default()
        })
    }

    fn reset(&mut self) {}
}
