//! The action planner's benchmark: gripper, blocks world and logistics at
//! growing sizes, satisficing (greedy best-first, FF, preferred operators)
//! and optimal (A*, LM-cut), with time and nodes expanded. Every plan is
//! checked by the validator.
//!
//! Run with `cargo bench -p ecology-actions --bench plan`. An optimal run
//! stops at the per-row cap; once one does, larger sizes of that family skip
//! the optimal run.

use std::time::{Duration, Instant};

use ecology_actions::WallClock;
use ecology_actions::problems::{self, GeneratorError, Instance};
use ecology_actions::{Budget, Options, Outcome, Request, Strategy, Verdict};

/// Caps each optimal run.
const OPTIMAL_CAP: Duration = Duration::from_secs(10);
/// Caps each satisficing run.
const SATISFICING_CAP: Duration = Duration::from_secs(30);

fn run(inst: &Instance, strategy: Strategy, cap: Duration) -> (String, Duration) {
    let start = Instant::now();
    let task = match ecology_actions::ground(&inst.domain, &inst.problem) {
        Ok(task) => task,
        Err(err) => return (format!("grounding failed: {err}"), start.elapsed()),
    };
    let options = Options {
        strategy,
        budget: Budget {
            max_expansions: None,
            max_time: Some(cap),
        },
        improve: true,
    };
    let outcome: Outcome = ecology_actions::plan(&Request::new(&task), &options, &WallClock(start));
    let elapsed = start.elapsed();
    let cell = match &outcome.verdict {
        Verdict::Found(plan) => {
            let valid = ecology_actions::validate(&inst.domain, &inst.problem, &plan.calls());
            let mark = if valid == Ok(plan.cost) {
                ""
            } else {
                " INVALID"
            };
            format!(
                "{:>9.1} {:>9} {:>6}{mark}",
                elapsed.as_secs_f64() * 1000.0,
                outcome.stats.expanded,
                plan.cost
            )
        }
        Verdict::Unsolvable(_) => format!("{:>26}", "unsolvable"),
        Verdict::BudgetExceeded => format!(
            "{:>9} {:>9} {:>6}",
            format!(">{}s", cap.as_secs()),
            outcome.stats.expanded,
            "-"
        ),
    };
    (cell, elapsed)
}

fn main() -> Result<(), GeneratorError> {
    let mut families: Vec<(&str, Vec<Instance>)> = Vec::new();
    let mut gripper = Vec::new();
    for balls in [2, 4, 6, 8, 10, 12, 20, 30, 40] {
        gripper.push(problems::gripper(balls)?);
    }
    families.push(("gripper", gripper));
    let mut blocks = Vec::new();
    for n in [4, 6, 8, 10, 12, 15, 20, 25, 30] {
        blocks.push(problems::blocks(n, n as u64)?);
    }
    families.push(("blocks", blocks));
    let mut logistics = Vec::new();
    for (cities, packages) in [(2, 2), (2, 4), (3, 4), (4, 6), (6, 8), (8, 12), (10, 16)] {
        logistics.push(problems::logistics(cities, packages, cities as u64)?);
    }
    families.push(("logistics", logistics));

    println!(
        "| {:<18} | {:>9} | {:>26} | {:>26} |",
        "problem", "operators", "satisficing: ms nodes cost", "optimal: ms nodes cost"
    );
    println!("|{:-<20}|{:->11}|{:->28}|{:->28}|", "", "", "", "");
    for (_, instances) in &families {
        let mut optimal_gave_up = false;
        for inst in instances {
            let operators = ecology_actions::ground(&inst.domain, &inst.problem)
                .map(|t| t.operators().len())
                .unwrap_or(0);
            let (sat, _) = run(inst, Strategy::SATISFICING, SATISFICING_CAP);
            let opt = if optimal_gave_up {
                format!("{:>26}", "skipped")
            } else {
                let (cell, elapsed) = run(inst, Strategy::OPTIMAL, OPTIMAL_CAP);
                optimal_gave_up = elapsed >= OPTIMAL_CAP;
                cell
            };
            println!("| {:<18} | {:>9} | {sat} | {opt} |", inst.name, operators);
        }
    }
    Ok(())
}
