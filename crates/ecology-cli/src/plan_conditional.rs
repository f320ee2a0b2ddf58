//! `ecology plan --conditional`: the conditional planner, printing the plan
//! as an indented tree (each branch with its observation and probability)
//! or as JSON.

use std::time::Duration;

use ecology_actions::conditional::{self, Branch, round};
use ecology_actions::{
    Budget, ConditionalOptions, ConditionalOutcome, ConditionalPlan, ConditionalRequest,
    ConditionalVerdict, HeuristicKind, OpId, PlanTree, Task,
};
use serde_json::{Value, json};

use crate::plan::PlanArgs;
use crate::{EXIT_BAD_INPUT, EXIT_NO_SOLUTION, EXIT_OK};
use ecology_config::WallClock;

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
    let outcome = ecology_actions::plan_conditional(&request, &options, clock);
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
                if best.root.actions() > 0 {
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
    println!(
        "; {} actions in the tree, at most {} per branch; {}, {} beliefs expanded, {} µs",
        plan.root.actions(),
        plan.root.depth(),
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

fn tree_json(task: &Task, node: &PlanTree) -> Value {
    match node {
        PlanTree::Stop { success } => json!({"done": true, "success": round(*success)}),
        PlanTree::Act { step, branches } => json!({
            "action": step.to_string(),
            "configure": step.configure.as_ref().map(ToString::to_string),
            "cost": step.cost,
            "branches": branches.iter().map(|b| branch_json(task, b)).collect::<Vec<_>>(),
        }),
    }
}

fn branch_json(task: &Task, branch: &Branch) -> Value {
    json!({
        "observation": branch
            .observation
            .iter()
            .map(|&(atom, holds)| json!({"atom": task.atom_name(atom), "holds": holds}))
            .collect::<Vec<_>>(),
        "text": conditional::observation_text(task, &branch.observation),
        "probability": round(branch.probability),
        "plan": tree_json(task, &branch.next),
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
        "plan": tree_json(task, &plan.root),
        "stats": {
            "expanded": outcome.stats.expanded,
            "beliefs": outcome.stats.beliefs,
            "rounds": outcome.stats.rounds,
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
