//! Large ecologies, measured: the paper's task in generated homes of N PEIS
//! (`ecology generate home --peis N`), with the executive acquiring the state
//! on demand (the default) and, side by side in the same run, reading every
//! tuple (`--acquire everything`).
//!
//! - In process: `ecology run FILE --timings` for N = 10, 100, 1,000 (and
//!   10,000 with `ECOLOGY_LARGE_FULL=1`): wall time of the whole run, the
//!   state built and the configuration planned per action, tuples and bytes
//!   the executive took in, PEIS followed, peak memory of the process.
//! - Over Zenoh: a router, the world (`ecology world`), every other PEIS in
//!   one process (`ecology peis FILE --all`), all clients of the router, then
//!   `ecology task --timings` for N = 10, 100, 300: state acquisition before
//!   the first action, action start → configuration running, planning,
//!   tuples and bytes, the executive's peak memory.
//!
//! `cargo bench -p ecology-cli --bench large`

#[path = "../tests/cli/support.rs"]
mod support;

use std::path::Path;
use std::process::{Command, Output};
use std::time::Instant;

use support::{Proc, event, free_endpoint};

/// What one executive run reported.
#[derive(Debug, Default)]
struct Measured {
    /// The whole command, by the wall clock, in seconds.
    wall: f64,
    /// State acquisition before the first action, ms.
    acquisition: f64,
    /// The first action's start → its configuration running, ms (over Zenoh).
    to_running: Option<f64>,
    /// Building the state and planning, per configuration: the largest, ms.
    state_ms: f64,
    plan_ms: f64,
    tuples: u64,
    bytes: u64,
    followed: String,
    peak_mb: f64,
    done: bool,
}

/// Reads what `--timings` printed on stderr.
fn read_timings(out: &Output, wall: f64) -> Measured {
    let stderr = String::from_utf8_lossy(&out.stderr);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let mut m = Measured {
        wall,
        done: out.status.success(),
        ..Measured::default()
    };
    let number = |text: &str, before: &str| -> Option<f64> {
        let at = text.find(before)?;
        let head = text[..at].trim_end();
        let start = head.rfind(' ').map_or(0, |i| i + 1);
        head[start..].trim_start_matches('(').parse().ok()
    };
    for line in stderr.lines() {
        if line.starts_with("executive: state acquired in") {
            m.acquisition = number(line, "ms (").unwrap_or(0.0);
            m.tuples = number(line, "tuples,").unwrap_or(0.0) as u64;
            m.bytes = number(line, "bytes").unwrap_or(0.0) as u64;
            m.followed = match line.split_once("ms (").and_then(|(_, r)| r.split_once(')')) {
                Some((what, _)) => what.replace(" PEIS followed", ""),
                None => String::new(),
            };
        } else if line.contains("components built in") {
            m.state_ms = m.state_ms.max(number(line, "ms, planned").unwrap_or(0.0));
            let planned = line.rsplit("planned in ").next().unwrap_or("");
            m.plan_ms = m
                .plan_ms
                .max(number(&format!(" {planned}"), "ms").unwrap_or(0.0));
        } else if line.starts_with("peak memory:") {
            m.peak_mb = number(line, "MB").unwrap_or(0.0);
        }
    }
    // Over Zenoh: the first action's start → its configuration running, on the executive's clock.
    let mut started = None;
    for line in stdout.lines().filter(|l| l.starts_with('{')) {
        let e = event(line);
        match e["event"].as_str() {
            Some("action_started") if started.is_none() => started = e["t"].as_f64(),
            Some("running") if m.to_running.is_none() => {
                m.to_running = started.zip(e["t"].as_f64()).map(|(a, b)| (b - a) * 1e3);
            }
            _ => {}
        }
    }
    m
}

fn ecology() -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_ecology"));
    command.current_dir(support::root());
    command
}

/// Writes the generated home of `peis` PEIS into `dir`; its path.
fn generate(dir: &Path, peis: usize) -> String {
    let file = dir.join(format!("home-{peis}.toml"));
    let file = file.display().to_string();
    let out = ecology()
        .args(["generate", "home", "--peis", &peis.to_string(), "-o", &file])
        .output()
        .expect("runs ecology generate");
    assert!(out.status.success(), "generate: {out:?}");
    file
}

fn in_process(file: &str, acquire: &str) -> Measured {
    let started = Instant::now();
    let out = ecology()
        .args(["run", file, "--timings", "--json", "--acquire", acquire])
        .output()
        .expect("runs ecology run");
    read_timings(&out, started.elapsed().as_secs_f64())
}

fn over_zenoh(file: &str, peis: usize, acquire: &str) -> Measured {
    let router = free_endpoint();
    let client = ["--connect", &router, "--client"];
    let _router = Proc::start("router", &["router", "--listen", &router]).ready();
    let mut world = vec!["world", file];
    world.extend(client);
    let _world = Proc::start("world", &world).ready();
    let mut all = vec!["peis", file, "--all"];
    all.extend(client);
    let mut hosts = Proc::start("hosts", &all);
    let ready = format!("{} PEIS ready", peis - 1);
    hosts.wait_for(&ready, |l| l == ready);
    let domain = support::root().join("domains/peis-home.eco");
    let problem = support::root().join("domains/peis-home-task.problem");
    let (domain, problem) = (domain.display().to_string(), problem.display().to_string());
    let mut task = vec![
        "task",
        "--domain",
        &domain,
        "--problem",
        &problem,
        "--json",
        "--timings",
        "--acquire",
        acquire,
        "--wait-for",
        "world,astrid,hsm,pippi",
    ];
    task.extend(client);
    let started = Instant::now();
    let out = ecology().args(&task).output().expect("runs ecology task");
    read_timings(&out, started.elapsed().as_secs_f64())
}

fn row(where_: &str, peis: usize, acquire: &str, m: &Measured) {
    let to_running = m
        .to_running
        .map_or("-".to_string(), |ms| format!("{ms:.0} ms"));
    println!(
        "| {where_} | {peis} | {acquire} | {} | {:.2} s | {:.1} ms | {to_running} | {:.1} ms | {:.1} ms | {} | {} | {} | {:.0} MB |",
        if m.done { "done" } else { "FAILED" },
        m.wall,
        m.acquisition,
        m.state_ms,
        m.plan_ms,
        m.followed,
        m.tuples,
        m.bytes,
        m.peak_mb,
    );
}

fn main() {
    support::QUIET.store(true, std::sync::atomic::Ordering::Relaxed);
    let dir = std::env::temp_dir().join(format!("ecology-bench-large-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temporary folder");
    let full = std::env::var_os("ECOLOGY_LARGE_FULL").is_some();
    println!(
        "| where | PEIS | acquire | task | wall | acquisition | start → running | state (max) | planning (max) | PEIS followed | tuples in | bytes in | peak memory |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    let mut sizes = vec![10, 100, 1000];
    if full {
        sizes.push(10_000);
    }
    let mut walls = Vec::new();
    for &peis in &sizes {
        let file = generate(&dir, peis);
        for acquire in ["on-demand", "everything"] {
            let m = in_process(&file, acquire);
            row("in process", peis, acquire, &m);
            if acquire == "on-demand" {
                walls.push((peis, m.wall));
            }
        }
    }
    let mut acquisitions = Vec::new();
    for peis in [10, 100, 300] {
        let file = generate(&dir, peis);
        for acquire in ["on-demand", "everything"] {
            let m = over_zenoh(&file, peis, acquire);
            row("Zenoh", peis, acquire, &m);
            if acquire == "on-demand" {
                acquisitions.push((peis, m.acquisition));
            }
        }
    }
    let ratio = |xs: &[(usize, f64)], a: usize, b: usize| {
        let get = |n| xs.iter().find(|(p, _)| *p == n).map(|(_, v)| *v);
        get(b).zip(get(a)).map(|(b, a)| b / a.max(1e-9))
    };
    if let Some(r) = ratio(&walls, 10, 1000) {
        println!(
            "\nin process, on demand: 1,000 PEIS take {r:.1}x the wall time of 10 (target: at most 3x)"
        );
    }
    if let Some(r) = ratio(&acquisitions, 10, 300) {
        println!(
            "over Zenoh, on demand: acquisition at 300 PEIS is {r:.1}x that at 10 (target: at most 2x)"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
