//! Multiqueries: the i-queue's nodes grouped greedily by their probability of staying invisible,
//! one query for the boxes of a whole group, by the paper's cost/benefit rule.

use super::Chcpp;
use crate::bvh::ObjectBvh;
use crate::error::Result;
use crate::{CullStats, OcclusionBackend};

use super::QueryKind;

impl Chcpp {
    /// Groups the batch (i-queue nodes) greedily into multiqueries, highest probability of
    /// staying invisible first, and issues one query per group.
    pub(super) fn issue_multiqueries(
        &mut self,
        bvh: &ObjectBvh,
        backend: &mut dyn OcclusionBackend,
        stats: &mut CullStats,
    ) -> Result<()> {
        let mut nodes = std::mem::take(&mut self.batch);
        // Highest p first, ties by node id; p computed once per node, not per comparison.
        let mut order = std::mem::take(&mut self.batch_order);
        order.clear();
        order.extend(nodes.iter().map(|&n| (self.stays_invisible(n), n)));
        order.sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        nodes.clear();
        nodes.extend(order.iter().map(|&(_, n)| n));
        self.batch_order = order;
        let mut i = 0;
        let mut result = Ok(());
        while i < nodes.len() && result.is_ok() {
            let j = self.multiquery_group_end(&nodes, i);
            result = self.issue(bvh, &nodes[i..j], QueryKind::Invisible, backend, stats);
            i = j;
        }
        self.batch = nodes;
        result
    }

    /// The end of the multiquery group that starts at `nodes[i]` (sorted by `p`, highest
    /// first). A group M of several nodes costs `1 + (1 - Π p) · |M|` queries in expectation
    /// (the multiquery, plus one per node if it fails); a single query costs 1. The group grows
    /// while its benefit per cost, `|M| / cost(M)`, does not decrease; a single node is worth 1,
    /// so a pair is only formed when `p₁·p₂ > 1/2`.
    pub(super) fn multiquery_group_end(&self, nodes: &[u32], i: usize) -> usize {
        let mut prod = 1.0f32;
        let mut best_value = 0.0f32;
        let mut objects = 0.0f32;
        let mut j = i;
        let budget = self.mode.multiquery_objects(&self.params);
        while j < nodes.len() {
            let pj = self.stays_invisible(nodes[j]).max(0.0);
            let size = (j - i + 1) as f32;
            if let Some(budget) = budget {
                // Predicated: a failed multiquery draws every node's objects under its
                // predicate: the group stays within the expected extra draws it may cost.
                objects += self.predicated.objects_below(nodes[j]) as f32;
                if j > i && (1.0 - prod * pj) * objects > budget {
                    break;
                }
            }
            let cost = if j == i {
                1.0
            } else {
                1.0 + (1.0 - prod * pj) * size
            };
            let value = size / cost;
            if j > i && value < best_value {
                break;
            }
            best_value = value;
            prod *= pj;
            j += 1;
        }
        j
    }

    /// `p(k) = 0.99 - 0.7 e^(-k)`: the probability that a node invisible for `k` frames stays
    /// invisible (fitted by the paper's authors); `k` counts the frames since it was last
    /// visible, not counting this one, frustum-culled frames included, but only within its
    /// current run of visits (`watched_since`). A node that was not visited last frame (it lay
    /// below a closed node, e.g. a car whose parent was just opened) has no recent history:
    /// k = 0, then 1, 2, ... as it is seen invisible frame after frame, however long ago it
    /// was last visible. Counting from its last visibility instead (frame 0 for a node never
    /// visible) made a node seen invisible once look like p = 0.99, and on `parking` and
    /// `city` half of all multiqueries failed.
    pub(super) fn stays_invisible(&self, node: u32) -> f32 {
        let s = &self.state[node as usize];
        let k = self
            .frame
            .saturating_sub((s.last_visible + 1).max(s.watched_since));
        0.99 - 0.7 * (-(k as f32)).exp()
    }
}
