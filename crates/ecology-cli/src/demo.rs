//! `ecology demo` and `ecology run SCENARIO`: a scenario of the simulated
//! PEIS-Home, in-process, with the executive's timeline printed as it happens.

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use ecology_exec::{Acquisition, Intake, LogEntry, LogEvent, RunStatus};
use ecology_sim::{Pace, RunOptions, Scenario, Update};
use ecology_view::log_json;

use crate::{EXIT_BAD_INPUT, EXIT_NO_SOLUTION, EXIT_OK};

/// The paper's experiment, built in so that `ecology demo` runs anywhere.
const DEMO_SCENARIO: &str = include_str!("../../../scenarios/peis-home.toml");
const DEMO_FILES: &[(&str, &str)] = &[
    (
        "../domains/peis-home.eco",
        include_str!("../../../domains/peis-home.eco"),
    ),
    (
        "../domains/peis-home-task.problem",
        include_str!("../../../domains/peis-home-task.problem"),
    ),
];

/// Options of `ecology demo` and `ecology run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// Simulated seconds per wall-clock second (default: as fast as possible).
    #[arg(long, value_name = "X", conflicts_with = "realtime")]
    pub speed: Option<f64>,
    /// Run in real time (the same as --speed 1).
    #[arg(long)]
    pub realtime: bool,
    /// Print the executive's event log as JSON lines instead of the timeline.
    #[arg(long)]
    pub json: bool,
    /// The seed of the simulation's noise (default: the scenario's).
    #[arg(long, value_name = "N")]
    pub seed: Option<u64>,
    /// Run as separate processes over Zenoh on 127.0.0.1 (the world, each PEIS, the executive),
    /// in real time, with faults injected into the processes themselves.
    #[arg(long, conflicts_with_all = ["speed", "realtime"])]
    pub processes: bool,
    /// Replace the scenario's faults by a random schedule made from the seed
    /// (as `ecology sweep` does; replays one of its seeds).
    #[arg(long, conflicts_with = "processes")]
    pub random_faults: bool,
    /// Serve a live web view of the run (best with --realtime); it stays up after the run until Ctrl-C.
    #[arg(long, conflicts_with = "processes")]
    pub view: bool,
    /// Where --view serves the page (port 0 picks a free one).
    #[arg(long, value_name = "ADDR", default_value = crate::view::DEFAULT_BIND, requires = "view")]
    pub bind: std::net::SocketAddr,
    /// What of the ecology the executive reads: what the plan's goals can use, or every tuple.
    #[arg(long, value_enum, default_value_t = Acquire::OnDemand, conflicts_with = "processes")]
    pub acquire: Acquire,
    /// Time the executive by the wall clock and report it on stderr: state
    /// acquisition, planning per configuration, tuples and bytes taken in,
    /// peak memory. (Without it the log's times read 0, and a run is the
    /// same from the same seed.)
    #[arg(long, conflicts_with = "processes")]
    pub timings: bool,
}

/// What of the ecology the executive reads (`--acquire`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Acquire {
    /// The PEIS with a component of a type the plan's goals can use (their
    /// contract tuples), after a directory of every PEIS's component types.
    OnDemand,
    /// Every tuple of every PEIS.
    Everything,
}

impl From<Acquire> for Acquisition {
    fn from(acquire: Acquire) -> Acquisition {
        match acquire {
            Acquire::OnDemand => Acquisition::OnDemand,
            Acquire::Everything => Acquisition::Everything,
        }
    }
}

/// Arguments of `ecology run`.
#[derive(Debug, Args)]
pub struct ScenarioArgs {
    /// The scenario file (TOML), such as scenarios/peis-home.toml.
    pub scenario: PathBuf,
    #[command(flatten)]
    pub options: RunArgs,
}

/// `ecology demo`: the paper's Section VIII.
pub fn demo(args: &RunArgs) -> anyhow::Result<u8> {
    let read = |path: &Path| -> Result<Vec<u8>, String> {
        DEMO_FILES
            .iter()
            .find(|(name, _)| Path::new(name) == path)
            .map(|(_, text)| text.as_bytes().to_vec())
            .ok_or_else(|| "not built into the demo".to_string())
    };
    if args.processes {
        return demo_processes(args);
    }
    match Scenario::parse(DEMO_SCENARIO, "scenarios/peis-home.toml", &read) {
        Ok(scenario) => simulate(&scenario, args),
        Err(e) => {
            eprintln!("error: {e}");
            Ok(EXIT_BAD_INPUT)
        }
    }
}

/// `ecology demo --processes`: the built-in files are written to a temporary
/// folder, since every process reads them.
fn demo_processes(args: &RunArgs) -> anyhow::Result<u8> {
    let folder = std::env::temp_dir().join(format!("ecology-demo-{}", std::process::id()));
    let scenario = folder.join("scenarios/peis-home.toml");
    let write = |path: &Path, text: &str| -> anyhow::Result<()> {
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent)
                .with_context(|| format!("creating {}", parent.display()))?;
        }
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
    };
    let written = (|| {
        write(&scenario, DEMO_SCENARIO)?;
        for (name, text) in DEMO_FILES {
            write(&folder.join("scenarios").join(name), text)?;
        }
        Ok::<_, anyhow::Error>(())
    })();
    let code = written.and_then(|()| {
        crate::processes::run(&crate::processes::Launch {
            scenario: scenario.clone(),
            seed: args.seed,
            json: args.json,
        })
    });
    let _ = std::fs::remove_dir_all(&folder);
    code
}

/// `ecology run SCENARIO`.
pub fn run(args: &ScenarioArgs) -> anyhow::Result<u8> {
    if args.options.processes {
        return crate::processes::run(&crate::processes::Launch {
            scenario: args.scenario.clone(),
            seed: args.options.seed,
            json: args.options.json,
        });
    }
    match Scenario::load(&args.scenario) {
        Ok(scenario) => simulate(&scenario, &args.options),
        Err(e) => {
            eprintln!("error: {e}");
            Ok(EXIT_BAD_INPUT)
        }
    }
}

/// Why `scenario` cannot run in simulated time: a component that is a ROS 2 node.
pub(crate) fn ros2_refusal(scenario: &Scenario) -> Option<String> {
    scenario.peis.iter().find_map(|p| {
        let c = p.components.iter().find(|c| c.ros2.is_some())?;
        Some(format!(
            "component {}:{} is a ROS 2 node: ROS 2 nodes run in real time, only in `ecology peis` \
             processes (`ecology run --processes`, or `ecology peis FILE --name {}`), not in the \
             simulated time of `ecology run`",
            p.name, c.id, p.name
        ))
    })
}

fn simulate(scenario: &Scenario, args: &RunArgs) -> anyhow::Result<u8> {
    if let Some(refusal) = ros2_refusal(scenario) {
        eprintln!("error: {refusal}");
        return Ok(EXIT_BAD_INPUT);
    }
    let seed = args.seed.unwrap_or(scenario.seed);
    let randomized;
    let scenario = if args.random_faults {
        randomized = ecology_sim::with_random_faults(scenario, seed);
        &randomized
    } else {
        scenario
    };
    let pace = match (args.realtime, args.speed) {
        (true, _) => Pace::Speed(1.0),
        (false, Some(x)) if x.is_finite() && x > 0.0 => Pace::Speed(x),
        (false, Some(x)) => {
            eprintln!("error: --speed must be a positive number, not {x}");
            return Ok(EXIT_BAD_INPUT);
        }
        (false, None) => Pace::Unpaced,
    };
    let served = if args.view {
        Some(crate::view::Served::start(args.bind)?)
    } else {
        None
    };
    let hub = served.as_ref().map(|s| s.hub.clone());
    let options = RunOptions {
        pace,
        observe_tuples: hub.is_some(),
        acquisition: args.acquire.into(),
        wall_stopwatch: args.timings,
        // This process exits right after the run (`exit_at_once`): the kernel takes it all back.
        tear_down: false,
        ..RunOptions::seeded(seed)
    };
    // One thread: the run is reproducible from its seed.
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .build()
        .context("cannot start the runtime")?;
    let json = args.json;
    // With several tasks, each line says whose executive logged it; one task's
    // output stays as it always was.
    let several = scenario.tasks.len() > 1;
    let progress = std::io::stderr().is_terminal();
    if !json {
        println!(
            "scenario {}: {} (seed {})",
            scenario.name, scenario.description, options.seed
        );
    }
    let observer = Box::new(move |update: Update| {
        let mut out = std::io::stdout().lock();
        if progress {
            eprint!("\r\x1b[K");
        }
        if let Some(hub) = &hub {
            match &update {
                Update::Log { executive, entry } => {
                    let whose = several.then_some(executive.as_str());
                    hub.update(|v| v.log(entry, whose));
                }
                Update::Tuple(event) => hub.update(|v| v.tuple(event)),
                Update::Presence(event) => hub.update(|v| v.presence(event)),
                Update::Injected { .. } | Update::Progress { .. } => {}
            }
        }
        match update {
            Update::Tuple(_) | Update::Presence(_) => {}
            Update::Log { executive, entry } if json => {
                let whose = several.then_some(executive.as_str());
                let _ = writeln!(out, "{}", log_json::json_line(&entry, whose));
            }
            Update::Log { executive, entry } if several => {
                let _ = writeln!(out, "{}", prefixed(&entry, &executive));
            }
            Update::Log { entry, .. } => {
                let _ = writeln!(out, "{entry}");
            }
            Update::Injected { t, what } if !json => {
                let _ = writeln!(out, "{:>8.3}s  [simulation] {what}", t.as_secs_f64());
            }
            Update::Injected { .. } => {}
            Update::Progress { t } => {
                if progress {
                    eprint!("  … simulated {:.0} s", t.as_secs_f64());
                }
            }
        }
        let _ = out.flush();
    });
    let wall = Instant::now();
    let report = runtime
        .block_on(ecology_sim::run(scenario, &options, observer))
        .context("the simulation failed")?;
    let wall = wall.elapsed();
    // The hosts the run left standing are the runtime's tasks: dropping it would take them down.
    std::mem::forget(runtime);
    if progress {
        eprint!("\r\x1b[K");
    }
    let sim = report.sim_time;
    eprintln!(
        "simulated {:.1} s in {:.2} s of wall time ({:.0}x real time)",
        sim.as_secs_f64(),
        wall.as_secs_f64(),
        sim.as_secs_f64() / wall.as_secs_f64().max(1e-9)
    );
    if args.timings {
        for task in &report.tasks {
            let text = timings(&task.log, &task.intake);
            match text.strip_prefix("executive:") {
                Some(rest) if several => eprint!("{}:{rest}", task.executive),
                _ => eprint!("{text}"),
            }
        }
    }
    for what in &report.spurious {
        eprintln!("warning: a failure the ground truth does not bear out: {what}");
    }
    for what in &report.conflicts {
        eprintln!("warning: a component served two executives: {what}");
    }
    if let Some(served) = served {
        crate::view::hold(&served)?;
        served.stop();
    }
    if report.timed_out {
        let unfinished: Vec<&str> = report
            .tasks
            .iter()
            .filter(|t| matches!(t.status, RunStatus::Idle | RunStatus::Running { .. }))
            .map(|t| t.executive.as_str())
            .collect();
        let which = if several {
            format!("the task of {}", unfinished.join(" and of "))
        } else {
            "the task".to_string()
        };
        eprintln!(
            "error: {which} did not finish within the scenario's time limit ({} s)",
            scenario.time_limit.as_secs_f64()
        );
    }
    // Exit 0 only when every task is done.
    Ok(match report.status {
        RunStatus::Done => EXIT_OK,
        _ => EXIT_NO_SOLUTION,
    })
}

/// The timeline line of `entry` with its executive's name after the time:
/// `   0.200s  [exec-bob] plan: …`.
fn prefixed(entry: &LogEntry, executive: &str) -> String {
    let text = entry.to_string();
    match text.find("s  ") {
        Some(at) => format!("{}[{executive}] {}", &text[..at + 3], &text[at + 3..]),
        None => format!("[{executive}] {text}"),
    }
}

/// What `--timings` reports: the executive's intake, its state acquisition
/// and planning by the wall clock, and the process's peak memory.
pub(crate) fn timings(log: &[LogEntry], intake: &Intake) -> String {
    let followed = match (intake.everything, intake.scope) {
        (true, _) => "everything followed".to_string(),
        (false, Some((peis, rooms))) => format!(
            "the contract of {peis} PEIS followed, those the goals name and those covering {rooms} \
             room{}, no outputs",
            if rooms == 1 { "" } else { "s" }
        ),
        (false, None) => "the contract followed, no outputs".to_string(),
    };
    let mut out = format!(
        "executive: state acquired in {:.1} ms ({followed}); took in {} tuples, {} bytes\n",
        intake.acquisition.as_secs_f64() * 1e3,
        intake.tuples,
        intake.bytes,
    );
    let mut state = (0, 0, 0);
    for entry in log {
        match &entry.event {
            LogEvent::StateAcquired {
                peis,
                components,
                micros,
                ..
            } => state = (*peis, *components, *micros),
            LogEvent::Configuration { goal, micros, .. } => {
                let (peis, components, built) = state;
                out += &format!(
                    "  {:>8.3}s  {goal}: state of {peis} PEIS and {components} components built in {:.2} ms, planned in {:.2} ms\n",
                    entry.t.as_secs_f64(),
                    built as f64 / 1e3,
                    *micros as f64 / 1e3
                );
            }
            _ => {}
        }
    }
    if let Some(peak) = peak_memory() {
        out += &format!("peak memory: {:.0} MB\n", peak as f64 / 1e6);
    }
    out
}

/// This process's peak resident memory in bytes (`VmHWM`), where the system tells.
fn peak_memory() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}
