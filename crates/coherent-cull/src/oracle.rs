//! The exact-visibility oracle: draws exactly the objects that cover at least one pixel, as
//! found by an untimed ID-buffer pass before the frame. No queries; the physical limit.
//!
//! Its variant [`BoxOracle`] (`oracle-box`) draws the objects whose own bounding box shows
//! against the depth of the same pass (tested as occlusion-query boxes are): what an ideal
//! culler that tests boxes would draw, with no query paid for. The time between it and the
//! oracle is the price of testing boxes rather than objects; the time between a box culler and
//! it is the price of the culler's hierarchy, history and queries.

use super::{CullStats, Culler, FrameInput, OcclusionBackend};
use crate::error::{Error, Result};

/// Renders only the exactly visible objects.
#[derive(Default)]
pub struct Oracle;

/// Renders only the objects whose own bounding box shows against the exact depth
/// ([`Culler::needs_box_visibility`]).
#[derive(Default)]
pub struct BoxOracle;

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
        draw_given(self.name(), input, backend)
    }

    fn reset(&mut self) {}
}

impl Culler for BoxOracle {
    fn name(&self) -> &str {
        "oracle-box"
    }

    fn needs_exact_visibility(&self) -> bool {
        true
    }

    fn needs_box_visibility(&self) -> bool {
        true
    }

    fn cull_frame(
        &mut self,
        input: &FrameInput,
        backend: &mut dyn OcclusionBackend,
    ) -> Result<CullStats> {
        draw_given(self.name(), input, backend)
    }

    fn reset(&mut self) {}
}

/// Draws the set the renderer computed before the frame and ends the frame.
fn draw_given(
    name: &str,
    input: &FrameInput,
    backend: &mut dyn OcclusionBackend,
) -> Result<CullStats> {
    let visible = input
        .exact_visible
        .ok_or_else(|| Error::Input(format!("{name} needs the exact visible set")))?;
    backend.draw_objects(visible)?;
    backend.finish()?;
    Ok(CullStats {
        objects_drawn: visible.len() as u32,
        ..Default::default()
    })
}
