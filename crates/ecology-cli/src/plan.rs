//! `ecology plan`: the action planner, from a domain and a problem file to a
//! plan whose actions carry their configuration goals.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use clap::Args;
use ecology_actions::{
    Budget, HeuristicKind, OpId, Options, Outcome, Plan, Request, Snapshot, Stats, Strategy,
    Verdict,
};
use serde_json::{Value, json};

use crate::input;
use crate::progress::{ProgressLine, standing};
use crate::{EXIT_BAD_INPUT, EXIT_NO_SOLUTION, EXIT_OK};
use ecology_config::{Clock, WallClock};

/// Arguments of `ecology plan`.
#[derive(Debug, Args)]
pub struct PlanArgs {
    /// The domain file (.eco or PDDL) with `:action` schemas.
    #[arg(long)]
    pub domain: PathBuf,
    /// The problem file: `(define (problem NAME) (:domain NAME) ...)`.
    #[arg(long)]
    pub problem: PathBuf,
    /// Find a cheapest plan (A* with an admissible heuristic) instead of a fast one.
    #[arg(long)]
    pub optimal: bool,
    /// Lazy search: a state's successors are evaluated only when taken from
    /// the queue (faster where states have many successors, plans often
    /// dearer); not with --optimal.
    #[arg(long, conflicts_with = "optimal")]
    pub lazy: bool,
    /// Greedy search guided by the heuristic alone, without the landmark
    /// count beside it; not with --optimal.
    #[arg(long, conflicts_with = "optimal")]
    pub no_landmarks: bool,
    /// The first plan found, without the bounded search for a cheaper one
    /// that follows it (weighted A*, as in LAMA); not with --optimal.
    #[arg(long, conflicts_with = "optimal")]
    pub no_improve: bool,
    /// The heuristic: ff, add, max, lmcut or blind (default: ff, or lmcut with --optimal).
    #[arg(long, value_name = "NAME")]
    pub heuristic: Option<HeuristicKind>,
    /// An unavailable action instance, such as '(move astrid living-room bedroom)'; repeatable.
    #[arg(long, value_name = "ACTION")]
    pub exclude: Vec<String>,
    /// Stop after expanding this many search nodes.
    #[arg(long, value_name = "N")]
    pub max_nodes: Option<u64>,
    /// Stop after this many milliseconds.
    #[arg(long, value_name = "MS")]
    pub max_millis: Option<u64>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
    /// Plan conditionally: probabilistic outcomes, sensing actions and
    /// uncertain initial states; the plan is a graph branching on observations.
    #[arg(long)]
    pub conditional: bool,
    /// With --conditional: the least success probability wanted (default: the most probable plan).
    #[arg(long, value_name = "P", requires = "conditional")]
    pub min_probability: Option<f64>,
    /// With --conditional: the most actions on any branch.
    #[arg(long, value_name = "N", requires = "conditional", default_value_t = 20)]
    pub horizon: u32,
}

/// `ecology plan ...`
pub fn plan(args: &PlanArgs) -> anyhow::Result<u8> {
    let clock = WallClock(Instant::now());
    let Ok(domain) = input::domain(&args.domain)? else {
        return Ok(EXIT_BAD_INPUT);
    };
    let Ok(problem) = input::problem(&args.problem, &domain)? else {
        return Ok(EXIT_BAD_INPUT);
    };
    // `--max-millis` bounds the whole command: grounding too. The plan starts
    // from the problem's initial states alone, so only what relaxed
    // reachability reaches from them is grounded.
    let limits = ecology_actions::GroundLimits {
        max_time: args.max_millis.map(Duration::from_millis),
        instances: ecology_actions::Instances::Reachable,
        ..ecology_actions::GroundLimits::default()
    };
    let task = match ecology_actions::ground_within(&domain, &problem, &limits, &clock) {
        Ok(task) => task,
        Err(err @ ecology_actions::GroundError::OutOfTime { .. }) => {
            let reason = format!(
                "no plan found within the budget: {err}; the problem may still be solvable"
            );
            if args.json {
                println!("{}", json!({"error": "budget exceeded", "reason": reason}));
            } else {
                eprintln!("{reason}");
            }
            return Ok(EXIT_NO_SOLUTION);
        }
        Err(err) => {
            eprintln!("error: {}: {err}", args.problem.display());
            return Ok(EXIT_BAD_INPUT);
        }
    };
    let mut excluded: Vec<OpId> = Vec::new();
    for text in &args.exclude {
        let Ok(call) = input::goal(text) else {
            return Ok(EXIT_BAD_INPUT);
        };
        // Well formed but never applicable (no operators): excluding it changes nothing.
        match task.find_operators(&call) {
            Ok(ops) => excluded.extend(ops),
            Err(err) => {
                eprintln!("error: --exclude '{text}': {err}");
                return Ok(EXIT_BAD_INPUT);
            }
        }
    }
    if args.conditional {
        return crate::plan_conditional::run(args, &task, excluded, &clock);
    }
    if task.is_uncertain() {
        eprintln!(
            "error: {}: the problem has probabilistic effects, observations or uncertain facts; \
             plan it with --conditional",
            args.problem.display()
        );
        return Ok(EXIT_BAD_INPUT);
    }
    let strategy = match (args.optimal, args.heuristic) {
        (false, heuristic) => Strategy::greedy(
            heuristic.unwrap_or(HeuristicKind::Ff),
            args.lazy,
            !args.no_landmarks,
        ),
        (true, None) => Strategy::OPTIMAL,
        (true, Some(heuristic)) if heuristic.is_admissible() => Strategy::AStar { heuristic },
        (true, Some(_)) => {
            eprintln!("error: --optimal needs an admissible heuristic: max, lmcut or blind");
            return Ok(EXIT_BAD_INPUT);
        }
    };
    let options = Options {
        strategy,
        budget: Budget {
            max_expansions: args.max_nodes,
            max_time: args.max_millis.map(Duration::from_millis),
        },
        improve: !args.optimal && !args.no_improve,
    };
    let request = Request::replan(&task, task.initial().clone(), excluded);
    let mut line = ProgressLine::new(!args.json);
    let mut observe = |s: Snapshot| line.update(clock.elapsed(), || searching(&s));
    let outcome = ecology_actions::plan_observed(&request, &options, &clock, &mut observe);
    line.clear();
    match &outcome.verdict {
        Verdict::Found(plan) => {
            if args.json {
                println!("{}", plan_json(plan, &outcome));
            } else {
                print_plan(plan, &outcome);
            }
            Ok(EXIT_OK)
        }
        Verdict::Unsolvable(why) => {
            if args.json {
                println!(
                    "{}",
                    json!({"error": "unsolvable", "reason": why.to_string(), "stats": stats_json(&outcome.stats)})
                );
            } else {
                eprintln!("no plan: {why}");
            }
            Ok(EXIT_NO_SOLUTION)
        }
        Verdict::BudgetExceeded => {
            let bound = outcome
                .lower_bound
                .map_or(String::new(), |b| format!("; none costs less than {b}"));
            let reason = format!(
                "no plan found within the budget ({} nodes expanded in {} ms{bound}); the problem may still be solvable",
                outcome.stats.expanded,
                outcome.stats.micros / 1000
            );
            if args.json {
                println!(
                    "{}",
                    json!({"error": "budget exceeded", "reason": reason, "lower_bound": outcome.lower_bound, "stats": stats_json(&outcome.stats)})
                );
            } else {
                eprintln!("{reason}");
            }
            Ok(EXIT_NO_SOLUTION)
        }
    }
}

/// What the progress line says of a running search.
fn searching(s: &Snapshot) -> String {
    format!(
        "{} nodes expanded, {} states stored; {} (--max-millis bounds the search)",
        s.expanded,
        s.states,
        standing("plan", s.best, s.lower_bound)
    )
}

fn print_plan(plan: &Plan, outcome: &Outcome) {
    let width = plan
        .steps
        .iter()
        .map(|s| s.to_string().len())
        .max()
        .unwrap_or(0);
    for step in &plan.steps {
        match &step.configure {
            Some(goal) => println!("{:width$}  ; configure {goal}", step.to_string()),
            None => println!("{step}"),
        }
    }
    println!("; cost = {}", plan.cost);
    let first = outcome.stats.first.map_or(String::new(), |first| {
        format!(
            " (the first plan: cost {}, {} nodes)",
            first.cost, first.expanded
        )
    });
    println!(
        "; {}, {} nodes expanded, {} µs{first}",
        if outcome.optimal {
            "proven optimal"
        } else {
            "not proven optimal"
        },
        outcome.stats.expanded,
        outcome.stats.micros
    );
}

fn stats_json(stats: &Stats) -> Value {
    json!({
        "expanded": stats.expanded,
        "generated": stats.generated,
        "micros": stats.micros,
        "first": stats.first.map(|f| json!({"cost": f.cost, "expanded": f.expanded})),
    })
}

fn plan_json(plan: &Plan, outcome: &Outcome) -> Value {
    json!({
        "plan": plan.steps.iter().map(ToString::to_string).collect::<Vec<_>>(),
        "configure": plan
            .steps
            .iter()
            .map(|s| s.configure.as_ref().map(ToString::to_string))
            .collect::<Vec<_>>(),
        "cost": plan.cost,
        "optimal": outcome.optimal,
        "stats": stats_json(&outcome.stats),
    })
}
