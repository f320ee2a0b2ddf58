//! The action planners as the simulator and `ecology task` use them: a plan
//! for a problem (conditional when the problem is uncertain), and the
//! planners' plans turned into the executive's [`Plan`].

use std::collections::HashMap;
use std::sync::Arc;

use ecology_actions::{
    Budget, ConditionalOptions, ConditionalRequest, ConditionalVerdict, PlanGraph, PlanNode, Task,
};
use ecology_domain::{Domain, Problem};
use ecology_exec::{Observation, Plan, PlanBranch, PlannedAction};

/// Why a problem has no plan of actions.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PlanError {
    /// The problem cannot be grounded in the domain.
    #[error("{0}")]
    Task(String),
    /// The action planner found no plan (or ran out of budget), and why.
    #[error("no plan: {0}")]
    NoPlan(String),
}

/// A plan for `problem`, each action with its `:configure` goal: from the
/// action planner (its default, satisficing search), or, when the problem
/// has uncertain outcomes or an uncertain initial state, the conditional
/// planner's most probable plan, the cheapest in expectation among those.
pub fn plan_actions(domain: &Domain, problem: &Problem) -> Result<Plan, PlanError> {
    let task =
        ecology_actions::ground(domain, problem).map_err(|e| PlanError::Task(e.to_string()))?;
    if task.is_uncertain() {
        run_conditional_planner(&ConditionalRequest::new(&task)).map_err(PlanError::NoPlan)
    } else {
        run_action_planner(&ecology_actions::Request::new(&task))
            .map(Plan::from)
            .map_err(PlanError::NoPlan)
    }
}

/// The action planner's plan for `request`, each action with its
/// `:configure` goal; `Err` says why there is none.
pub(crate) fn run_action_planner(
    request: &ecology_actions::Request<'_>,
) -> Result<Vec<PlannedAction>, String> {
    let outcome = ecology_actions::plan(
        request,
        &ecology_actions::Options::default(),
        &ecology_actions::NoClock,
    );
    match outcome.verdict {
        ecology_actions::Verdict::Found(plan) => Ok(plan
            .steps
            .iter()
            .map(|step| PlannedAction::new(step.to_string(), step.configure.clone()))
            .collect()),
        ecology_actions::Verdict::Unsolvable(why) => Err(why.to_string()),
        ecology_actions::Verdict::BudgetExceeded => {
            Err("the action planner's budget ran out".to_string())
        }
    }
}

/// How many beliefs the conditional planner may expand for one plan: a
/// search over beliefs can grow exponentially, and the executive waits for
/// it when it plans again.
const CONDITIONAL_EXPANSIONS: u64 = 200_000;

/// The conditional planner's most probable plan for `request` (default
/// options, at most [`CONDITIONAL_EXPANSIONS`] beliefs expanded); `Err` when
/// no plan reaches the goal at all, or the budget ran out first (a partial
/// plan would stop where the search did).
pub(crate) fn run_conditional_planner(request: &ConditionalRequest<'_>) -> Result<Plan, String> {
    let options = ConditionalOptions {
        budget: Budget {
            max_expansions: Some(CONDITIONAL_EXPANSIONS),
            max_time: None,
        },
        ..ConditionalOptions::default()
    };
    let outcome = ecology_actions::plan_conditional(request, &options, &ecology_actions::NoClock);
    let plan = match outcome.verdict {
        ConditionalVerdict::Found(plan) | ConditionalVerdict::BelowThreshold(plan) => plan,
        ConditionalVerdict::BudgetExceeded(_) => {
            return Err(format!(
                "the conditional planner's budget ran out ({CONDITIONAL_EXPANSIONS} beliefs expanded)"
            ));
        }
    };
    if plan.success <= ecology_core::EPSILON {
        return Err(
            "no conditional plan reaches the goal with any probability within the horizon"
                .to_string(),
        );
    }
    Ok(executive_plan(request.task, &plan.graph))
}

/// The conditional planner's plan as the executive's: actions in order
/// until one that branches on what it observes. Branches that join in the
/// planner's graph share their plan.
pub fn executive_plan(task: &Task, graph: &PlanGraph) -> Plan {
    let mut made = HashMap::new();
    executive_plan_from(task, graph, 0, &mut made)
}

/// The executive's plan from node `start` of `graph`; `made` holds the
/// plans already made for the nodes that branches lead to.
fn executive_plan_from(
    task: &Task,
    graph: &PlanGraph,
    start: usize,
    made: &mut HashMap<usize, Arc<Plan>>,
) -> Plan {
    let mut steps = Vec::new();
    let mut node = start;
    loop {
        let (step, branches) = match &graph.nodes[node] {
            PlanNode::Stop { success } => {
                return Plan {
                    steps,
                    branches: Vec::new(),
                    success: *success,
                };
            }
            PlanNode::Act { step, branches } => (step, branches),
        };
        let operator = task.operator(step.op);
        steps.push(PlannedAction {
            action: step.to_string(),
            goal: step.configure.clone(),
            observe: operator
                .observe
                .iter()
                .map(|&a| task.atom_name(a))
                .collect(),
        });
        if let [only] = &branches[..]
            && only.observation.is_empty()
        {
            node = only.next;
            continue;
        }
        let branches = branches
            .iter()
            .map(|b| {
                let plan = match made.get(&b.next) {
                    Some(plan) => plan.clone(),
                    None => {
                        let plan = Arc::new(executive_plan_from(task, graph, b.next, made));
                        made.insert(b.next, plan.clone());
                        plan
                    }
                };
                PlanBranch {
                    observation: b
                        .observation
                        .iter()
                        .map(|&(atom, holds)| Observation {
                            atom: task.atom_name(atom),
                            holds,
                        })
                        .collect(),
                    probability: b.probability,
                    plan,
                }
            })
            .collect();
        return Plan::branching(steps, branches);
    }
}
