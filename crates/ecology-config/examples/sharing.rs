//! Plans for, or writes out, one shared-provider ecology from
//! `ecology_config::synthetic::sharing`; used by `scripts/bench-config`.
//!
//! `cargo run --release -p ecology-config --example sharing -- export DIR P L K CPP R F SEED`
//! writes `DIR/domain.eco`, `DIR/state.facts`, `DIR/goal` and `DIR/exclusions`
//! (one `PEIS:COMPONENT` a line); `… -- solve DIR [MAX_MILLIS]` reads them back
//! and plans, printing one line `cost=… status=… micros=… cold_micros=…
//! explained_micros=… first_micros=… expanded=… lower_bound=…`. `micros` is
//! the work of a [`Planner`] whose domain was compiled beforehand, as the
//! executive's is (reading the state, grounding, search, assembling the
//! configuration), answering what the peers answer: the cheapest
//! configuration, or that there is none (`Options::explain` off).
//! `cold_micros` is that of [`plan`], which compiles the domain too, and
//! `explained_micros` the planner's again with the explanation of a "none"
//! that `ecology configure` prints. Each is the median of up to 1,000 runs
//! while they take under half a second in all, in microseconds with three
//! decimals. `… -- run P L K CPP R F SEED
//! [MAX_MILLIS]` generates and plans without files.

use std::time::{Duration, Instant};

/// The allocator of the `ecology` binary, so that the benchmark measures
/// what users run.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

use ecology_config::synthetic::{self, Sharing};
use ecology_config::{Budget, Clock, Options, Outcome, Planner, WallClock, plan};

fn shape(args: &[String]) -> Sharing {
    let n = |i: usize| args[i].parse::<usize>().expect("a number");
    Sharing {
        peis: n(0),
        levels: n(1),
        types: n(2),
        per_level: n(3),
        needs: n(4),
        failed: args[5].parse().expect("a fraction"),
        rates: false,
        seed: args[6].parse().expect("a seed"),
    }
}

/// An instance written by `export`.
fn read(dir: &std::path::Path) -> synthetic::Instance {
    let read = |name: &str| std::fs::read_to_string(dir.join(name)).expect("reads");
    let (domain_text, facts_text, goal_text) =
        (read("domain.eco"), read("state.facts"), read("goal"));
    synthetic::Instance {
        domain: ecology_domain::parse_domain(domain_text.as_bytes()).expect("parses"),
        state: ecology_domain::parse_facts(facts_text.as_bytes()).expect("parses"),
        goal: ecology_domain::parse_goal(goal_text.trim()).expect("parses"),
        domain_text,
        facts_text,
        goal_text,
        components: Vec::new(),
        exclusions: read("exclusions")
            .lines()
            .map(|l| l.parse().expect("an exclusion"))
            .collect(),
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.first().map(String::as_str) {
        Some("export") => {
            let dir = std::path::PathBuf::from(&args[1]);
            let instance = synthetic::sharing(shape(&args[2..])).expect("generates");
            std::fs::create_dir_all(&dir).expect("creates the directory");
            std::fs::write(dir.join("domain.eco"), &instance.domain_text).expect("writes");
            std::fs::write(dir.join("state.facts"), &instance.facts_text).expect("writes");
            std::fs::write(dir.join("goal"), &instance.goal_text).expect("writes");
            let excluded: String = instance
                .exclusions
                .iter()
                .map(|e| format!("{e}\n"))
                .collect();
            std::fs::write(dir.join("exclusions"), excluded).expect("writes");
        }
        Some(mode @ ("run" | "solve")) => {
            let start = Instant::now();
            let (instance, max_time) = if mode == "run" {
                let instance = synthetic::sharing(shape(&args[1..])).expect("generates");
                (instance, args.get(8))
            } else {
                (read(std::path::Path::new(&args[1])), args.get(2))
            };
            let max_time = max_time.map(|m| Duration::from_millis(m.parse().expect("ms")));
            let request = instance.request();
            // What the peers answer: the cheapest configuration, or that
            // there is none.
            let options = Options {
                count: 1,
                budget: Budget {
                    max_expansions: None,
                    max_time,
                },
                explain: false,
            };
            // What `ecology configure` answers: also why there is none.
            let explaining = Options {
                explain: true,
                ..options
            };
            let generated = start.elapsed();
            // Up to 1,000 runs while they take under half a second in all;
            // the median is reported (a lone run, or the first few dozen of
            // a fresh process, mostly measure cold caches).
            let median = |once: &dyn Fn() -> (Duration, Outcome)| {
                let mut runs = Vec::new();
                let began = Instant::now();
                while runs.len() < 1000
                    && (runs.is_empty() || began.elapsed() < Duration::from_millis(500))
                {
                    runs.push(once());
                }
                runs.sort_by_key(|r| r.0);
                runs.swap_remove(runs.len() / 2)
            };
            let planner = Planner::new(instance.domain.clone());
            // The planner's own domain, as the executive passes it.
            let prepared = ecology_config::Request {
                domain: planner.domain(),
                ..request
            };
            let planned = |options: &Options| {
                median(&|| {
                    let clock = WallClock::start();
                    let outcome = planner
                        .plan(&prepared, options, &clock)
                        .expect("valid goal");
                    (clock.elapsed(), outcome)
                })
            };
            let (total, outcome) = planned(&options);
            let (cold, _) = median(&|| {
                let clock = WallClock::start();
                let outcome = plan(&request, &options, &clock).expect("valid goal");
                (clock.elapsed(), outcome)
            });
            let (explained, _) = planned(&explaining);
            let micros = |d: Duration| format!("{:.3}", d.as_secs_f64() * 1e6);
            println!(
                "cost={} status={:?} micros={} cold_micros={} explained_micros={} generate_micros={} first_micros={} expanded={} lower_bound={}",
                outcome
                    .configurations
                    .first()
                    .map_or("none".to_string(), |c| c.cost.to_string()),
                outcome.status,
                micros(total),
                micros(cold),
                micros(explained),
                generated.as_micros(),
                outcome
                    .stats
                    .first_micros
                    .map_or("none".to_string(), |m| m.to_string()),
                outcome.stats.expanded,
                outcome
                    .lower_bound
                    .map_or("none".to_string(), |b| b.to_string()),
            );
        }
        _ => eprintln!(
            "usage: sharing export DIR P L K CPP R F SEED | sharing solve DIR [MAX_MILLIS] | sharing run P L K CPP R F SEED [MAX_MILLIS]"
        ),
    }
}
