//! Conditional planning within a horizon that binds: `problems::corridor`
//! (a corridor of moves, and independent faults whose repairs compete for
//! the actions the walk leaves) at the sizes and horizons given on the
//! command line, one run each, with the plan checked against the oracle's
//! evaluation where its tree is small. Peak memory is the process's: run
//! one size per process (`/usr/bin/time -v`) to read it.
//!
//! `cargo bench -p ecology-actions --bench corridor -- LENGTH FACTS HORIZON...`
//! (a list of triples; default `8 6 10`).

use std::time::Instant;

use ecology_actions::problems;
use ecology_actions::{
    ConditionalOptions, ConditionalRequest, ConditionalVerdict, WallClock, plan_conditional,
};

fn main() {
    let numbers: Vec<usize> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let numbers = if numbers.len() >= 3 {
        numbers
    } else {
        vec![8, 6, 10]
    };
    println!(
        "{:<16} {:>7} {:>10} {:>10} {:>10} {:>8} {:>10}",
        "problem", "horizon", "ms", "expanded", "beliefs", "success", "cost"
    );
    for triple in numbers.chunks_exact(3) {
        let (length, facts, horizon) = (triple[0], triple[1], triple[2] as u32);
        let inst = problems::corridor(length, facts).expect("generated");
        let start = Instant::now();
        let task = ecology_actions::ground(&inst.domain, &inst.problem).expect("ground");
        let options = ConditionalOptions {
            horizon,
            ..ConditionalOptions::default()
        };
        let outcome =
            plan_conditional(&ConditionalRequest::new(&task), &options, &WallClock(start));
        let elapsed = start.elapsed();
        let plan = match &outcome.verdict {
            ConditionalVerdict::Found(p) | ConditionalVerdict::BelowThreshold(p) => p,
            other => panic!("{}: {other:?}", inst.name),
        };
        if plan.graph.tree_actions() <= 100_000 {
            let named = ecology_actions::oracle_conditional::named(&task, &plan.graph);
            let (p, c) =
                ecology_actions::oracle_conditional::evaluate(&inst.domain, &inst.problem, &named)
                    .expect("the plan runs");
            assert!((p - plan.success).abs() < 1e-6 && (c - plan.expected_cost).abs() < 1e-6);
        }
        println!(
            "{:<16} {:>7} {:>10.1} {:>10} {:>10} {:>8.6} {:>10.6}",
            inst.name,
            horizon,
            elapsed.as_secs_f64() * 1e3,
            outcome.stats.expanded,
            outcome.stats.beliefs,
            plan.success,
            plan.expected_cost
        );
    }
}
