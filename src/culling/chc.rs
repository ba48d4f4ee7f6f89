//! TEMPORARY: CHC lands next.
use super::{CullStats, Culler, FrameInput, OcclusionBackend};
use crate::error::Result;
/// CHC.
#[derive(Default)]
pub struct Chc(super::vfc::Vfc);
impl Culler for Chc {
    fn name(&self) -> &str { "chc" }
    fn cull_frame(&mut self, input: &FrameInput, backend: &mut dyn OcclusionBackend) -> Result<CullStats> { self.0.cull_frame(input, backend) }
    fn reset(&mut self) {}
}
