//! Cost functions: what a functionality instance and a channel cost.
//!
//! The planner's search is exact for any [`CostModel`] whose costs are
//! non-negative and depend only on the component or channel priced (not on the
//! rest of the configuration): a configuration's cost is then the sum over its
//! distinct components and channels, which is what the lower bounds assume.

use ecology_domain::{ComponentCost, Power};

/// Prices components and channels. Implementations must be additive (see the module docs).
pub trait CostModel {
    /// The cost of running a functionality on component `component` of `peis`,
    /// given what the state says of the component and the functionality's default cost.
    fn component_cost(
        &self,
        peis: &str,
        component: &str,
        state: Option<ComponentCost>,
        default: u64,
    ) -> u64;

    /// The cost of a channel from a component on `from` to one on `to`
    /// (different PEIS), given the state's `channel-cost` fact if any.
    fn channel_cost(&self, from: &str, to: &str, state: Option<u64>) -> u64;
}

/// The paper's cost model (DESIGN section 7).
///
/// A component that is on costs its running cost from the state; one that is
/// off costs its start-up cost from the state plus the functionality's default
/// cost; one the state says nothing about costs the default. A channel between
/// two PEIS costs the state's `channel-cost`, or nothing.
#[derive(Debug, Clone, Copy, Default)]
pub struct PaperCost;

impl CostModel for PaperCost {
    fn component_cost(&self, _: &str, _: &str, state: Option<ComponentCost>, default: u64) -> u64 {
        match state {
            Some(ComponentCost {
                amount,
                power: Power::On,
            }) => amount,
            Some(ComponentCost {
                amount,
                power: Power::Off,
            }) => amount.saturating_add(default),
            None => default,
        }
    }

    fn channel_cost(&self, _: &str, _: &str, state: Option<u64>) -> u64 {
        state.unwrap_or(0)
    }
}
