//! TEMPORARY: CHC++ lands next.
use super::{CullStats, Culler, FrameInput, OcclusionBackend};
use crate::error::Result;
/// Parameters.
#[derive(Clone, Debug, Default)]
pub struct ChcppParams {}
/// CHC++.
pub struct Chcpp(super::vfc::Vfc);
impl Chcpp { /// New.
 pub fn new(_p: ChcppParams) -> Self { Chcpp(Default::default()) } }
impl Culler for Chcpp {
    fn name(&self) -> &str { "chcpp" }
    fn cull_frame(&mut self, input: &FrameInput, backend: &mut dyn OcclusionBackend) -> Result<CullStats> { self.0.cull_frame(input, backend) }
    fn reset(&mut self) {}
}
