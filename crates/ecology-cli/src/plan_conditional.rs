//! `ecology plan --conditional`: the conditional planner, printing the plan
//! as an indented graph (each branch with its observation and probability,
//! shared parts labelled and joined) or as JSON.

use std::time::Duration;

use ecology_actions::conditional::{self, Branch, round};
use ecology_actions::{
    Budget, ConditionalOptions, ConditionalOutcome, ConditionalPlan, ConditionalRequest,
    ConditionalSnapshot, ConditionalVerdict, HeuristicKind, OpId, PlanGraph, PlanNode, Task,
};
use serde_json::{Value, json};

use crate::plan::PlanArgs;
use crate::progress::ProgressLine;
use crate::{EXIT_BAD_INPUT, EXIT_NO_SOLUTION, EXIT_OK};
use ecology_config::{Clock, WallClock};

/// Plans `task` conditionally as `args` say; returns the exit code.
pub fn run(
    args: &PlanArgs,
    task: &Task,
    excluded: Vec<OpId>,
    clock: &WallClock,
) -> anyhow::Result<u8> {
    if let Some(p) = args.min_probability
        && !(0.0..=1.0).contains(&p)
    {
        eprintln!("error: --min-probability must be in [0, 1], given {p}");
        return Ok(EXIT_BAD_INPUT);
    }
    let heuristic = match args.heuristic {
        None => HeuristicKind::LmCut,
        Some(h) if h.is_admissible() => h,
        Some(_) => {
            eprintln!("error: --conditional needs an admissible heuristic: max, lmcut or blind");
            return Ok(EXIT_BAD_INPUT);
        }
    };
    let options = ConditionalOptions {
        min_probability: args.min_probability,
        horizon: args.horizon,
        heuristic,
        budget: Budget {
            max_expansions: args.max_nodes,
            max_time: args.max_millis.map(Duration::from_millis),
        },
    };
    let request = ConditionalRequest {
        excluded,
        ..ConditionalRequest::new(task)
    };
    let mut line = ProgressLine::new(!args.json);
    let mut observe = |s: ConditionalSnapshot| {
        line.update(clock.elapsed(), || {
            format!(
                "{} beliefs expanded, {} distinct (--max-millis bounds the search)",
                s.expanded, s.beliefs
            )
        })
    };
    let outcome =
        ecology_actions::plan_conditional_observed(&request, &options, clock, &mut observe);
    line.clear();
    let threshold = args.min_probability;
    match &outcome.verdict {
        ConditionalVerdict::Found(plan) => {
            if args.json {
                println!("{}", outcome_json(task, plan, &outcome, None));
            } else {
                print_plan(task, plan, &outcome);
            }
            Ok(EXIT_OK)
        }
        ConditionalVerdict::BelowThreshold(best) => {
            let reason = match threshold {
                Some(t) => format!(
                    "no plan of at most {} actions per branch reaches the goal with probability {t}; \
                     the best reaches it with probability {}",
                    args.horizon,
                    round(best.success)
                ),
                None => format!(
                    "no plan of at most {} actions per branch can reach the goal",
                    args.horizon
                ),
            };
            if args.json {
                println!(
                    "{}",
                    outcome_json(task, best, &outcome, Some(("below threshold", &reason)))
                );
            } else {
                eprintln!("no plan: {reason}");
                if best.graph.actions() > 0 {
                    println!("; the most probable plan found:");
                    print_plan(task, best, &outcome);
                }
            }
            Ok(EXIT_NO_SOLUTION)
        }
        ConditionalVerdict::BudgetExceeded(best) => {
            let probability = best.as_ref().map_or(0.0, |b| round(b.success));
            let reason = format!(
                "no plan found within the budget ({} beliefs expanded in {} ms); \
                 the best partial plan reaches the goal with probability {probability}",
                outcome.stats.expanded,
                outcome.stats.micros / 1000
            );
            if args.json {
                let value = match best {
                    Some(best) => {
                        outcome_json(task, best, &outcome, Some(("budget exceeded", &reason)))
                    }
                    None => json!({"error": "budget exceeded", "reason": reason}),
                };
                println!("{value}");
            } else {
                eprintln!("{reason}");
            }
            Ok(EXIT_NO_SOLUTION)
        }
    }
}

fn print_plan(task: &Task, plan: &ConditionalPlan, outcome: &ConditionalOutcome) {
    println!(
        "; success probability {}, expected cost {}",
        round(plan.success),
        round(plan.expected_cost)
    );
    let (actions, tree) = (plan.graph.actions(), plan.graph.tree_actions());
    let size = if actions as u64 == tree {
        format!("{actions} actions in the tree")
    } else {
        format!("{actions} actions in the graph ({tree} as a tree)")
    };
    println!(
        "; {size}, at most {} per branch; {}, {} beliefs expanded, {} µs",
        plan.graph.depth(),
        if outcome.complete {
            "search complete"
        } else {
            "search incomplete"
        },
        outcome.stats.expanded,
        outcome.stats.micros
    );
    print!("{}", plan.display(task));
}

/// The plan as nested JSON: a node that more than one branch reaches is
/// written once, with `"label": N`, and `{"go_to": N}` elsewhere.
fn graph_json(task: &Task, graph: &PlanGraph) -> Value {
    let labels = graph.labels();
    let mut written = vec![false; graph.nodes.len()];
    node_json(task, graph, &labels, &mut written, 0)
}

fn node_json(
    task: &Task,
    graph: &PlanGraph,
    labels: &[Option<usize>],
    written: &mut [bool],
    id: usize,
) -> Value {
    if let Some(label) = labels[id] {
        if written[id] {
            return json!({"go_to": label});
        }
        written[id] = true;
    }
    let mut value = match &graph.nodes[id] {
        PlanNode::Stop { success } => json!({"done": true, "success": round(*success)}),
        PlanNode::Act { step, branches } => json!({
            "action": step.to_string(),
            "configure": step.configure.as_ref().map(ToString::to_string),
            "cost": step.cost,
            "branches": branches
                .iter()
                .map(|b| branch_json(task, graph, labels, written, b))
                .collect::<Vec<_>>(),
        }),
    };
    if let Some(label) = labels[id] {
        value["label"] = json!(label);
    }
    value
}

fn branch_json(
    task: &Task,
    graph: &PlanGraph,
    labels: &[Option<usize>],
    written: &mut [bool],
    branch: &Branch,
) -> Value {
    json!({
        "observation": branch
            .observation
            .iter()
            .map(|&(atom, holds)| json!({"atom": task.atom_name(atom), "holds": holds}))
            .collect::<Vec<_>>(),
        "text": conditional::observation_text(task, &branch.observation),
        "probability": round(branch.probability),
        "plan": node_json(task, graph, labels, written, branch.next),
    })
}

fn outcome_json(
    task: &Task,
    plan: &ConditionalPlan,
    outcome: &ConditionalOutcome,
    error: Option<(&str, &str)>,
) -> Value {
    let mut value = json!({
        "success": round(plan.success),
        "expected_cost": round(plan.expected_cost),
        "complete": outcome.complete,
        "plan": graph_json(task, &plan.graph),
        "stats": {
            "expanded": outcome.stats.expanded,
            "beliefs": outcome.stats.beliefs,
            "rounds": outcome.stats.rounds,
            "shared": outcome.stats.shared,
            "actions": plan.graph.actions(),
            "tree_actions": plan.graph.tree_actions(),
            "micros": outcome.stats.micros,
        },
    });
    if let Some((error, reason)) = error {
        value["error"] = json!(error);
        value["reason"] = json!(reason);
        value["best_probability"] = json!(round(plan.success));
    }
    value
}
