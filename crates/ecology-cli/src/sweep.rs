//! `ecology sweep SCENARIO --seeds N`: the scenario under N random fault
//! schedules (one per seed, as `ecology run SCENARIO --random-faults --seed S`
//! makes them), in virtual time on every core; a table of how the runs
//! ended, and the seeds that misbehaved so that they can be replayed. A run
//! of several tasks is done when every task is, and fails with the first
//! failed task's reason; a failure the ground truth does not bear out
//! (spurious) or a component that served two executives at once (a
//! conflict) makes the sweep fail.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Args;
use ecology_exec::{LogEvent, RunStatus};
use ecology_sim::{RunOptions, Scenario};

use crate::{EXIT_BAD_INPUT, EXIT_NO_SOLUTION, EXIT_OK};

/// Arguments of `ecology sweep`.
#[derive(Debug, Args)]
pub struct SweepArgs {
    /// The scenario file (TOML); its own faults are replaced by random ones.
    pub scenario: PathBuf,
    /// How many seeds to run.
    #[arg(long, value_name = "N", default_value_t = 1000)]
    pub seeds: u64,
    /// The first seed.
    #[arg(long, value_name = "S", default_value_t = 0)]
    pub first: u64,
    /// Worker threads (default: one per core).
    #[arg(long, value_name = "J")]
    pub jobs: Option<usize>,
}

/// How one seed's run ended.
#[derive(Debug)]
enum Ending {
    Done,
    Failed(String),
    Stuck,
    Error(String),
}

struct Outcome {
    seed: u64,
    ending: Ending,
    reconfigurations: usize,
    spurious: Vec<String>,
    conflicts: Vec<String>,
    wall: Duration,
    sim: Duration,
}

fn run_seed(scenario: &Scenario, seed: u64) -> Outcome {
    let started = Instant::now();
    let faulty = ecology_sim::with_random_faults(scenario, seed);
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .build();
    let report = runtime.map_err(anyhow::Error::from).and_then(|rt| {
        rt.block_on(ecology_sim::run(
            &faulty,
            &RunOptions::seeded(seed),
            Box::new(|_| {}),
        ))
        .map_err(anyhow::Error::from)
    });
    let wall = started.elapsed();
    match report {
        Ok(report) => Outcome {
            seed,
            ending: match &report.status {
                _ if report.timed_out => Ending::Stuck,
                RunStatus::Done => Ending::Done,
                RunStatus::Failed { .. } => {
                    // Why the last action of the (first) failed task failed says more
                    // than "no plan remains".
                    let log = report
                        .tasks
                        .iter()
                        .find(|t| matches!(t.status, RunStatus::Failed { .. }))
                        .map(|t| t.log.as_slice())
                        .unwrap_or_default();
                    let action = log.iter().rev().find_map(|e| match &e.event {
                        LogEvent::ActionFailed { reason, .. } => Some(reason.clone()),
                        _ => None,
                    });
                    let task = log.iter().rev().find_map(|e| match &e.event {
                        LogEvent::TaskFailed { reason } => Some(reason.clone()),
                        _ => None,
                    });
                    Ending::Failed(action.or(task).unwrap_or_default())
                }
                RunStatus::Idle | RunStatus::Running { .. } => Ending::Stuck,
            },
            reconfigurations: report
                .tasks
                .iter()
                .flat_map(|t| &t.log)
                .filter(|e| e.event.name() == "reconfiguration")
                .count(),
            spurious: report.spurious,
            conflicts: report.conflicts,
            wall,
            sim: report.sim_time,
        },
        Err(e) => Outcome {
            seed,
            ending: Ending::Error(format!("{e:#}")),
            reconfigurations: 0,
            spurious: Vec::new(),
            conflicts: Vec::new(),
            wall,
            sim: Duration::ZERO,
        },
    }
}

/// The kind of a failure reason, for the table: its first line, up to a colon.
fn reason_kind(reason: &str) -> String {
    let first = reason.lines().next().unwrap_or("").trim();
    let kind = first.split_once(": ").map_or(first, |(head, _)| head);
    if kind.is_empty() {
        "(no reason)".to_string()
    } else {
        kind.to_string()
    }
}

/// `ecology sweep SCENARIO --seeds N`.
pub fn sweep(args: &SweepArgs) -> anyhow::Result<u8> {
    let scenario = match Scenario::load(&args.scenario) {
        Ok(scenario) => scenario,
        Err(e) => {
            eprintln!("error: {e}");
            return Ok(EXIT_BAD_INPUT);
        }
    };
    if let Some(refusal) = crate::demo::ros2_refusal(&scenario) {
        eprintln!("error: {refusal}");
        return Ok(EXIT_BAD_INPUT);
    }
    let jobs = args
        .jobs
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, usize::from))
        .max(1);
    let end = args.first.saturating_add(args.seeds);
    let total = args.seeds;
    let next = Arc::new(AtomicU64::new(args.first));
    let outcomes = Arc::new(Mutex::new(Vec::new()));
    let started = Instant::now();
    let scenario = Arc::new(scenario);
    let workers: Vec<_> = (0..jobs)
        .map(|_| {
            let (next, outcomes, scenario) = (next.clone(), outcomes.clone(), scenario.clone());
            std::thread::spawn(move || {
                loop {
                    let seed = next.fetch_add(1, Ordering::Relaxed);
                    if seed >= end {
                        return;
                    }
                    let outcome = run_seed(&scenario, seed);
                    if let Ok(mut all) = outcomes.lock() {
                        all.push(outcome);
                        let n = all.len() as u64;
                        if n % 500 == 0 {
                            eprintln!("  … {n} of {total} seeds");
                        }
                    }
                }
            })
        })
        .collect();
    for worker in workers {
        worker
            .join()
            .map_err(|_| anyhow::anyhow!("a sweep worker panicked"))?;
    }
    let wall = started.elapsed();
    let mut outcomes = Arc::try_unwrap(outcomes)
        .map_err(|_| anyhow::anyhow!("sweep workers still running"))?
        .into_inner()
        .map_err(|_| anyhow::anyhow!("a sweep worker panicked"))
        .context("collecting the sweep")?;
    outcomes.sort_by_key(|o| o.seed);
    print_table(args, &scenario, &outcomes, jobs, wall);
    let bad = outcomes.iter().any(|o| {
        matches!(o.ending, Ending::Stuck | Ending::Error(_))
            || !o.spurious.is_empty()
            || !o.conflicts.is_empty()
    });
    Ok(if bad { EXIT_NO_SOLUTION } else { EXIT_OK })
}

fn print_table(
    args: &SweepArgs,
    scenario: &Scenario,
    outcomes: &[Outcome],
    jobs: usize,
    wall: Duration,
) {
    let done = outcomes
        .iter()
        .filter(|o| matches!(o.ending, Ending::Done))
        .count();
    let mut reasons: BTreeMap<String, usize> = BTreeMap::new();
    for o in outcomes {
        if let Ending::Failed(reason) = &o.ending {
            *reasons.entry(reason_kind(reason)).or_default() += 1;
        }
    }
    let failed: usize = reasons.values().sum();
    let stuck: Vec<u64> = outcomes
        .iter()
        .filter(|o| matches!(o.ending, Ending::Stuck))
        .map(|o| o.seed)
        .collect();
    let errors: Vec<&Outcome> = outcomes
        .iter()
        .filter(|o| matches!(o.ending, Ending::Error(_)))
        .collect();
    let spurious: Vec<&Outcome> = outcomes.iter().filter(|o| !o.spurious.is_empty()).collect();
    let conflicts: Vec<&Outcome> = outcomes
        .iter()
        .filter(|o| !o.conflicts.is_empty())
        .collect();
    let reconfigurations: usize = outcomes.iter().map(|o| o.reconfigurations).sum();
    let slowest = outcomes.iter().max_by_key(|o| o.wall);
    println!(
        "{} seeds ({}..{}) of {} with random fault schedules, {jobs} threads, {:.1} s",
        outcomes.len(),
        args.first,
        args.first + args.seeds,
        scenario.name,
        wall.as_secs_f64()
    );
    println!("  task done          {done:>7}");
    println!("  task failed        {failed:>7}   (each with a reason)");
    let mut by_count: Vec<(&String, &usize)> = reasons.iter().collect();
    by_count.sort_by(|a, b| b.1.cmp(a.1).then(a.0.cmp(b.0)));
    for (reason, n) in by_count.iter().take(6) {
        println!("    {n:>7}  {reason}");
    }
    println!("  stuck              {:>7}   (must be 0)", stuck.len());
    println!(
        "  spurious           {:>7}   (failures the ground truth does not bear out; must be 0)",
        spurious.iter().map(|o| o.spurious.len()).sum::<usize>()
    );
    println!(
        "  conflicts          {:>7}   (components that served two executives at once; must be 0)",
        conflicts.iter().map(|o| o.conflicts.len()).sum::<usize>()
    );
    println!("  reconfigurations   {reconfigurations:>7}");
    if !errors.is_empty() {
        println!("  runs in error      {:>7}", errors.len());
    }
    if let Some(o) = slowest {
        println!(
            "  slowest run        seed {}: {:.2} s of wall time for {:.1} s simulated",
            o.seed,
            o.wall.as_secs_f64(),
            o.sim.as_secs_f64()
        );
    }
    let replay = |seed: u64| {
        format!(
            "ecology run {} --random-faults --seed {seed}",
            args.scenario.display()
        )
    };
    for seed in stuck.iter().take(10) {
        println!("  stuck: {}", replay(*seed));
    }
    for o in spurious.iter().take(10) {
        println!("  spurious: {}: {}", replay(o.seed), o.spurious.join("; "));
    }
    for o in conflicts.iter().take(10) {
        println!("  conflict: {}: {}", replay(o.seed), o.conflicts.join("; "));
    }
    for o in errors.iter().take(10) {
        if let Ending::Error(e) = &o.ending {
            println!("  error: {}: {e}", replay(o.seed));
        }
    }
}
