//! The action planner on PDDL files, for the side-by-side benchmark
//! (`scripts/bench-actions`): writes generated problems to files, and solves
//! a domain and problem file pair printing one line of results.
//!
//! ```text
//! solve write DIR NAME...        # NAME: gripper-N, blocks-N, logistics-C-P, parking-CURBS-SEED
//! solve run DOMAIN PROBLEM [--optimal] [--lazy] [--no-landmarks] [--timeout-s S] [--plan]
//! ```
//!
//! `run` prints `status=found cost=N expanded=N generated=N evaluated=N
//! ms=T ground_ms=T operators=N initial_h=N valid=BOOL` (or
//! `status=unsolvable|timeout`); `ms` runs
//! from before reading the files to the end of the search, so it includes
//! reading, parsing and grounding, like the whole-process time the script
//! measures for both planners. The plan is checked by the validator
//! (`valid`), after the time is taken.

use std::process::ExitCode;
use std::time::{Duration, Instant};

use ecology_actions::problems::{self, Instance};
use ecology_actions::{Budget, HeuristicKind, Options, Request, Strategy, Verdict, WallClock};

fn generate(name: &str) -> Result<Instance, String> {
    let parts: Vec<&str> = name.split('-').collect();
    let num = |s: &str| s.parse::<usize>().map_err(|e| format!("{name}: {e}"));
    let inst = match parts.as_slice() {
        ["gripper", n] => problems::gripper(num(n)?),
        ["blocks", n] => problems::blocks(num(n)?, num(n)? as u64),
        ["logistics", c, p] => problems::logistics(num(c)?, num(p)?, num(c)? as u64),
        ["parking", c, seed] => problems::parking(num(c)?, num(seed)? as u64),
        _ => return Err(format!("unknown problem `{name}`")),
    };
    inst.map_err(|e| e.to_string())
}

fn write(dir: &str, names: &[String]) -> Result<(), String> {
    std::fs::create_dir_all(dir).map_err(|e| format!("{dir}: {e}"))?;
    for name in names {
        let inst = generate(name)?;
        let family = name.split('-').next().unwrap_or(name);
        let domain = format!("{dir}/{family}-domain.pddl");
        std::fs::write(&domain, &inst.domain_text).map_err(|e| format!("{domain}: {e}"))?;
        let problem = format!("{dir}/{name}.pddl");
        std::fs::write(&problem, &inst.problem_text).map_err(|e| format!("{problem}: {e}"))?;
    }
    Ok(())
}

fn run(args: &[String]) -> Result<(), String> {
    let start = Instant::now();
    let [domain_path, problem_path, rest @ ..] = args else {
        return Err(
            "run DOMAIN PROBLEM [--optimal] [--lazy] [--no-landmarks] [--no-improve] [--weight W] [--timeout-s S] [--plan]"
                .into(),
        );
    };
    let (mut optimal, mut lazy, mut landmarks, mut weight) = (false, false, true, None);
    let mut improve = true;
    let mut timeout = None;
    let mut print_plan = false;
    let mut rest = rest.iter();
    while let Some(arg) = rest.next() {
        match arg.as_str() {
            "--optimal" => optimal = true,
            "--plan" => print_plan = true,
            "--lazy" => lazy = true,
            "--no-landmarks" => landmarks = false,
            "--no-improve" => improve = false,
            "--weight" => {
                let w = rest.next().ok_or("--weight needs a value")?;
                weight = Some(w.parse().map_err(|e| format!("--weight: {e}"))?);
            }
            "--timeout-s" => {
                let s = rest.next().ok_or("--timeout-s needs a value")?;
                let s: f64 = s.parse().map_err(|e| format!("--timeout-s: {e}"))?;
                timeout = Some(Duration::from_secs_f64(s));
            }
            other => return Err(format!("unknown argument `{other}`")),
        }
    }
    let strategy = match (optimal, weight) {
        (true, _) => Strategy::OPTIMAL,
        (false, Some(weight)) => Strategy::Weighted {
            heuristic: HeuristicKind::Ff,
            weight,
        },
        (false, None) => Strategy::greedy(HeuristicKind::Ff, lazy, landmarks),
    };
    let domain_text = std::fs::read(domain_path).map_err(|e| format!("{domain_path}: {e}"))?;
    let problem_text = std::fs::read(problem_path).map_err(|e| format!("{problem_path}: {e}"))?;
    let domain =
        ecology_domain::parse_domain(&domain_text).map_err(|d| format!("{domain_path}: {d}"))?;
    let problem = ecology_domain::parse_problem_for(&domain, &problem_text)
        .map_err(|d| format!("{problem_path}: {d}"))?;
    // One search from the initial state: ground only what it can reach, as Fast Downward does.
    let limits = ecology_actions::GroundLimits {
        instances: ecology_actions::Instances::Reachable,
        ..ecology_actions::GroundLimits::default()
    };
    let task =
        ecology_actions::ground_within(&domain, &problem, &limits, &ecology_actions::NoClock)
            .map_err(|e| e.to_string())?;
    let ground_ms = start.elapsed().as_secs_f64() * 1000.0;
    let options = Options {
        strategy,
        budget: Budget {
            max_expansions: None,
            max_time: timeout,
        },
        improve: improve && !optimal,
    };
    let outcome = ecology_actions::plan(&Request::new(&task), &options, &WallClock(start));
    let ms = start.elapsed().as_secs_f64() * 1000.0;
    let s = &outcome.stats;
    let counts = format!(
        "expanded={} generated={} evaluated={} ms={ms:.1} ground_ms={ground_ms:.1} operators={} initial_h={}",
        s.expanded,
        s.generated,
        s.evaluated,
        task.operators().len(),
        s.initial_h
            .map_or("dead-end".to_string(), |h| h.to_string())
    );
    match &outcome.verdict {
        Verdict::Found(plan) => {
            let valid =
                ecology_actions::validate(&domain, &problem, &plan.calls()) == Ok(plan.cost);
            if print_plan {
                print!("{plan}");
            }
            println!(
                "status=found cost={} optimal={} {counts} valid={valid}",
                plan.cost, outcome.optimal
            );
        }
        Verdict::Unsolvable(_) => println!("status=unsolvable {counts}"),
        Verdict::BudgetExceeded => println!("status=timeout {counts}"),
    }
    Ok(())
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let result = match args.split_first() {
        Some((cmd, rest)) if cmd == "write" => match rest.split_first() {
            Some((dir, names)) => write(dir, names),
            None => Err("write DIR NAME...".into()),
        },
        Some((cmd, rest)) if cmd == "run" => run(rest),
        _ => Err(
            "usage: solve write DIR NAME... | solve run DOMAIN PROBLEM [--optimal] [--lazy] [--no-landmarks] [--timeout-s S] [--plan]"
                .into(),
        ),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("solve: {e}");
            ExitCode::from(2)
        }
    }
}
