//! What of the ecology the executive acquires (the paper's Section V: the
//! state "can be acquired on demand", for the parts of the ecology the goal
//! concerns).
//!
//! The configuration planner reads `(pc P TYPE C)`, `(cost P C N on|off)` and
//! `(status P C S)` of the PEIS it may use. A plan whose configuration goals
//! name the types of the components they can use ([`component_types`]) needs
//! the component contract, not the data the components stream: the driver
//! follows every PEIS's directory and its components' own fields, and no
//! outputs. A goal that could use a component of any type needs everything.
//!
//! Narrower still, a plan whose goals can use only the PEIS they name and those
//! that cover the rooms its actions start in ([`component_scope`]: a building's
//! cameras) needs the contract of those PEIS alone, found by asking who covers
//! each room: what it acquires does not grow with the building.

use std::collections::{BTreeSet, HashSet};
use std::sync::Arc;
use std::time::Duration;

use ecology_config::{Planner, Scope, component_scope, component_types};
use ecology_domain::{EcologyState, Fact};

use crate::plan::{Plan, PlanBranch, PlannedAction};

/// What of the ecology an executive needs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Interest {
    /// Every tuple of every PEIS.
    Everything,
    /// The contract tuples of the PEIS with a component of one of these types.
    Types(BTreeSet<String>),
    /// The contract tuples of the PEIS the scope names and of those that cover its rooms
    /// (`rooms.ROOM.C`).
    Scoped(Scope),
}

impl Interest {
    /// What the configuration goals of `steps` and of every branch after them can use, each
    /// planned in the world its action starts in ([`Planner::facts_at_action`]) besides `world`.
    pub fn of_plan(
        planner: &Planner,
        world: &EcologyState,
        steps: &[PlannedAction],
        branches: &[PlanBranch],
    ) -> Interest {
        let domain = planner.domain();
        let mut types = BTreeSet::new();
        let mut scope = Some(Scope::default());
        let mut todo: Vec<(&[PlannedAction], &[PlanBranch])> = vec![(steps, branches)];
        // Branches that join share their plan: each is read once.
        let mut seen = HashSet::new();
        // The world's facts, and after them those of the action at hand.
        let mut facts: Vec<Fact> = world.facts().to_vec();
        let of_world = facts.len();
        while let Some((steps, branches)) = todo.pop() {
            for step in steps {
                let Some(goal) = &step.goal else { continue };
                match component_types(domain, goal) {
                    Some(more) => types.extend(more),
                    None => return Interest::Everything,
                }
                if let Some(within) = &mut scope {
                    facts.truncate(of_world);
                    facts.extend(planner.facts_at_action(&step.action));
                    match component_scope(domain, goal, &facts) {
                        Some(more) => within.extend(more),
                        None => scope = None,
                    }
                }
            }
            todo.extend(
                branches
                    .iter()
                    .filter(|b| seen.insert(Arc::as_ptr(&b.plan)))
                    .map(|b| (b.plan.steps.as_slice(), b.plan.branches.as_slice())),
            );
        }
        match scope {
            Some(scope) if !types.is_empty() => Interest::Scoped(scope),
            _ => Interest::Types(types),
        }
    }

    /// [`Interest::of_plan`] of a whole plan.
    pub fn of(planner: &Planner, world: &EcologyState, plan: &Plan) -> Interest {
        Interest::of_plan(planner, world, &plan.steps, &plan.branches)
    }
}

/// What the executive took in from the ecology.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Intake {
    /// Tuple updates received.
    pub tuples: u64,
    /// Their bytes: owner, key and value.
    pub bytes: u64,
    /// Whether every tuple was followed; otherwise the component contract of
    /// every PEIS, without the outputs (on demand).
    pub everything: bool,
    /// Under a scope ([`Interest::Scoped`]): the PEIS whose contract was followed, and the rooms
    /// whose covering PEIS were asked for; `None` when the contract of every PEIS was.
    pub scope: Option<(u32, u32)>,
    /// How long the driver took to acquire the state before the task
    /// started (its directory and the followed PEIS's tuples), by the wall clock.
    pub acquisition: Duration,
}
