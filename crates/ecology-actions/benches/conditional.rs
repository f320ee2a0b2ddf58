//! The conditional planner's benchmark: IPPC's triangle tireworld at growing
//! sizes (reimplemented in `problems::tireworld`), the newspaper task of
//! `domains/`, and the planner side by side with the brute-force oracle's
//! exhaustive search over plans (the baseline: no PPDDL planner installs
//! from PyPI here). Every plan's success probability and expected cost are
//! checked against the oracle's evaluation of it.
//!
//! Run with `cargo bench -p ecology-actions --bench conditional`.

use std::time::{Duration, Instant};

use ecology_actions::oracle_conditional::{self, Exhaustive};
use ecology_actions::problems::{self, Instance};
use ecology_actions::{
    Budget, ConditionalOptions, ConditionalRequest, ConditionalVerdict, WallClock, plan_conditional,
};

/// Caps each planner run.
const CAP: Duration = Duration::from_secs(60);

/// The largest plan (unfolded into a tree) the oracle evaluates.
const ORACLE_MAX_TREE: u64 = 1_000_000;

fn newspaper() -> Instance {
    let domain = include_str!("../../../domains/peis-home-uncertain.eco");
    let problem = include_str!("../../../domains/newspaper-uncertain.problem");
    Instance {
        name: "newspaper".into(),
        domain_text: domain.into(),
        problem_text: problem.into(),
        domain: ecology_domain::parse_domain(domain.as_bytes()).expect("domain"),
        problem: ecology_domain::parse_problem(problem.as_bytes()).expect("problem"),
        optimal_cost: None,
    }
}

/// Plans `inst`; returns the table row and the time.
fn row(inst: &Instance, horizon: u32, threshold: Option<f64>) -> (String, Duration) {
    let start = Instant::now();
    let task = match ecology_actions::ground(&inst.domain, &inst.problem) {
        Ok(task) => task,
        Err(err) => return (format!("grounding failed: {err}"), start.elapsed()),
    };
    let options = ConditionalOptions {
        min_probability: threshold,
        horizon,
        budget: Budget {
            max_expansions: None,
            max_time: Some(CAP),
        },
        ..ConditionalOptions::default()
    };
    let outcome = plan_conditional(&ConditionalRequest::new(&task), &options, &WallClock(start));
    let elapsed = start.elapsed();
    let (plan, status) = match &outcome.verdict {
        ConditionalVerdict::Found(p) => (p, "found"),
        ConditionalVerdict::BelowThreshold(p) => (p, "below"),
        ConditionalVerdict::BudgetExceeded(Some(p)) => (p, "budget"),
        ConditionalVerdict::BudgetExceeded(None) => {
            return (format!("{:>10.1}  budget exceeded", ms(elapsed)), elapsed);
        }
    };
    let named = oracle_conditional::named(&task, &plan.graph);
    // The oracle follows every world the plan can reach, and worlds differ
    // in what no longer matters (the spares left behind): as many as the
    // tree has paths.
    let check = if plan.graph.tree_actions() > ORACLE_MAX_TREE {
        "large"
    } else {
        match oracle_conditional::evaluate(&inst.domain, &inst.problem, &named) {
            Ok((p, c))
                if (p - plan.success).abs() < 1e-6
                    && (c - plan.expected_cost).abs() < 1e-6 * (1.0 + c) =>
            {
                "ok"
            }
            Ok(_) => "DIFFERS",
            Err(_) => "INVALID",
        }
    };
    (
        format!(
            "{:>10.1} {:>9} {:>8} {:>8.4} {:>8.3} {:>8} {:>12} {:>6} {:>6} {:>6}",
            ms(elapsed),
            outcome.stats.expanded,
            outcome.stats.beliefs,
            plan.success,
            plan.expected_cost,
            plan.graph.actions(),
            plan.graph.tree_actions(),
            if outcome.stats.shared { "yes" } else { "no" },
            status,
            check
        ),
        elapsed,
    )
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}

fn main() {
    println!("Conditional planner (AO* over beliefs, LM-cut on the all-outcomes determinization)");
    println!(
        "{:<18} {:>6} {:>5} {:>7} {:>5} {:>10} {:>9} {:>8} {:>8} {:>8} {:>8} {:>12} {:>6} {:>6} {:>6}",
        "problem",
        "atoms",
        "ops",
        "horizon",
        "P>=",
        "ms",
        "expanded",
        "beliefs",
        "success",
        "E[cost]",
        "actions",
        "tree actions",
        "shared",
        "status",
        "oracle"
    );
    let mut cases: Vec<(Instance, u32, Option<f64>)> = vec![(newspaper(), 20, None)];
    cases.push((newspaper(), 20, Some(0.6)));
    for n in 1..=8 {
        let inst = problems::tireworld(n).expect("generated");
        // The safe road is 4n moves, and a flat tire costs two more actions.
        let horizon = 12 * n as u32;
        cases.push((inst.clone(), horizon, None));
        if n <= 4 {
            cases.push((inst, horizon, Some(0.75)));
        }
    }
    let mut slow = false;
    for (inst, horizon, threshold) in &cases {
        if slow && inst.name.starts_with("tireworld") {
            println!(
                "{:<18} skipped: a smaller size hit the {CAP:?} cap",
                inst.name
            );
            continue;
        }
        let task = ecology_actions::ground(&inst.domain, &inst.problem).expect("ground");
        let (cells, elapsed) = row(inst, *horizon, *threshold);
        slow |= elapsed >= CAP;
        println!(
            "{:<18} {:>6} {:>5} {:>7} {:>5} {cells}",
            inst.name,
            task.atom_count(),
            task.operators().len(),
            horizon,
            threshold.map_or("max".to_string(), |t| t.to_string()),
        );
    }

    println!();
    println!(
        "Side by side with the exhaustive search (the oracle tries every action at every node)"
    );
    println!(
        "{:<18} {:>7} {:>12} {:>14} {:>8} {:>10}",
        "problem", "horizon", "planner ms", "exhaustive ms", "ratio", "agree"
    );
    let mut baseline: Vec<(Instance, u32)> = vec![(newspaper(), 4), (newspaper(), 5)];
    for h in [4, 6, 8, 10, 12] {
        baseline.push((problems::tireworld(1).expect("generated"), h));
    }
    for h in [6, 8] {
        baseline.push((problems::tireworld(2).expect("generated"), h));
    }
    for seed in 0..3 {
        baseline.push((problems::random_uncertain(seed).expect("generated"), 5));
    }
    for (inst, horizon) in &baseline {
        let start = Instant::now();
        let task = ecology_actions::ground(&inst.domain, &inst.problem).expect("ground");
        let options = ConditionalOptions {
            horizon: *horizon,
            ..ConditionalOptions::default()
        };
        let outcome =
            plan_conditional(&ConditionalRequest::new(&task), &options, &WallClock(start));
        let planner = start.elapsed();
        let plan = match &outcome.verdict {
            ConditionalVerdict::Found(p) | ConditionalVerdict::BelowThreshold(p) => p.clone(),
            other => panic!("{}: {other:?}", inst.name),
        };
        let start = Instant::now();
        let exhaustive =
            oracle_conditional::most_probable(&inst.domain, &inst.problem, *horizon, 20_000_000);
        let oracle = start.elapsed();
        let agree = match exhaustive {
            Exhaustive::Best { success, cost } => {
                if (success - plan.success).abs() < 1e-6
                    && (cost - plan.expected_cost).abs() < 1e-6 * (1.0 + cost)
                {
                    "yes"
                } else {
                    "NO"
                }
            }
            Exhaustive::TooLarge => "too large",
        };
        println!(
            "{:<18} {:>7} {:>12.2} {:>14.2} {:>8.0} {:>10}",
            inst.name,
            horizon,
            ms(planner),
            ms(oracle),
            oracle.as_secs_f64() / planner.as_secs_f64().max(1e-9),
            agree
        );
    }
}
