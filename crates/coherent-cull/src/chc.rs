//! CHC (Bittner et al. 2004): the CHC++ traversal with none of its four parts — queries issued
//! one at a time as nodes are reached (a state change per query), every visible leaf queried
//! every frame, each node queried with its own box.

use super::chcpp::{Chcpp, ChcppParams};
use super::{CullStats, Culler, FrameInput, OcclusionBackend};
use crate::error::Result;

/// Coherent hierarchical culling.
pub struct Chc(Chcpp);

impl Default for Chc {
    fn default() -> Self {
        Chc(Chcpp::named("chc", ChcppParams::chc()))
    }
}

impl Culler for Chc {
    fn name(&self) -> &str {
        "chc"
    }

    fn reads_tests_after_frame(&self) -> bool {
        self.0.reads_tests_after_frame()
    }

    fn cull_frame(
        &mut self,
        input: &FrameInput,
        backend: &mut dyn OcclusionBackend,
    ) -> Result<CullStats> {
        self.0.cull_frame(input, backend)
    }

    fn reset(&mut self) {
        self.0.reset();
    }
}
