//! Large ecologies, measured: the paper's task in generated homes of N PEIS
//! (`ecology generate home --peis N`), with the executive acquiring the state
//! on demand (the default) and, side by side in the same run, reading every
//! tuple (`--acquire everything`).
//!
//! - In process: `ecology run FILE --timings` for N = 10, 100, 1,000 (and
//!   10,000 with `ECOLOGY_LARGE_FULL=1`): wall time of the whole run, the
//!   state built and the configuration planned per action, tuples and bytes
//!   the executive took in, peak memory of the process.
//! - Over Zenoh: a router, the world (`ecology world`), every other PEIS in
//!   one process (`ecology peis FILE --all`), all clients of the router, then
//!   `ecology task --timings` for N = 10, 100, 300, 1,000 (10 and 1,000 three times in turn,
//!   in fresh homes, the medians compared): state acquisition
//!   before the first action, action start → configuration running, planning,
//!   tuples and bytes, the executive's peak memory.
//! - As processes: 1,000 PEIS as four `ecology peis FILE --name …` processes
//!   of 250 each and the world, behind one router, then behind two routers
//!   that share them; the same, plus each process's peak memory and the
//!   routers' CPU time.
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

/// The names of the PEIS of a generated home, the world's apart.
fn peis_names(file: &str) -> Vec<String> {
    let text = std::fs::read_to_string(file).expect("reads the generated home");
    let mut names = Vec::new();
    let mut in_peis = false;
    for line in text.lines() {
        if line.starts_with('[') {
            in_peis = line == "[[peis]]";
        } else if in_peis && let Some(name) = line.strip_prefix("name = ") {
            names.push(name.trim_matches('"').to_string());
        }
    }
    names
}

/// A process's peak resident memory (`VmHWM`), MB, and its CPU time (user + system), s.
fn usage(pid: u32) -> (f64, f64) {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    let peak_kb: f64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
        .unwrap_or(0.0);
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    // Fields after the command's closing parenthesis: utime and stime are the 12th and 13th.
    let after = stat.rsplit_once(')').map_or("", |(_, rest)| rest);
    let fields: Vec<&str> = after.split_whitespace().collect();
    let ticks = |i: usize| {
        fields
            .get(i)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(0.0)
    };
    // The kernel's clock ticks are 100 a second on Linux.
    (peak_kb / 1024.0, (ticks(11) + ticks(12)) / 100.0)
}

/// An ecology of `file` over Zenoh: `routers` routers (each connected to the first), the
/// world, and the other PEIS in `parts` processes, the parts spread over the routers in turn.
struct Home {
    routers: Vec<(Proc, String)>,
    world: Proc,
    parts: Vec<Proc>,
}

impl Home {
    fn start(file: &str, parts: usize, routers: usize, hold_contract: bool) -> Home {
        let mut started: Vec<(Proc, String)> = Vec::new();
        for _ in 0..routers {
            let endpoint = free_endpoint();
            let mut args = vec!["router".to_string(), "--listen".into(), endpoint.clone()];
            if let Some((_, first)) = started.first() {
                args.extend(["--connect".to_string(), first.clone()]);
            }
            if !hold_contract {
                args.push("--no-contract-cache".into());
            }
            // `ready` waits for a line that starts with the process's name.
            let router = Proc::start("router", &support::as_strs(&args)).ready();
            started.push((router, endpoint));
        }
        let client = |i: usize| {
            let endpoint = &started[i % started.len()].1;
            vec!["--connect".to_string(), endpoint.clone(), "--client".into()]
        };
        let mut world = vec!["world".to_string(), file.to_string()];
        world.extend(client(0));
        let world = Proc::start("world", &support::as_strs(&world)).ready();
        let names = peis_names(file);
        let share = names.len().div_ceil(parts);
        let mut processes = Vec::new();
        for (i, chunk) in names.chunks(share).enumerate() {
            let mut args = vec!["peis".to_string(), file.to_string()];
            if parts == 1 {
                args.push("--all".into());
            } else {
                args.extend(["--name".to_string(), chunk.join(",")]);
            }
            args.extend(client(i));
            processes.push(Proc::start(&format!("peis{i}"), &support::as_strs(&args)));
        }
        for (process, chunk) in processes.iter_mut().zip(names.chunks(share)) {
            let ready = format!("{} PEIS ready", chunk.len());
            process.wait_for(&ready, |l| l == ready);
        }
        let home = Home {
            routers: started,
            world,
            parts: processes,
        };
        home.settle();
        home
    }

    /// Waits until the routers are idle: a home of a thousand PEIS is ready (every PEIS
    /// joined) seconds before its routers have passed on everything the joins started, and an
    /// executive started then would measure the joins, not itself.
    fn settle(&self) {
        let busy = || -> f64 {
            self.routers
                .iter()
                .map(|(p, _)| usage(p.pid().as_raw() as u32).1)
                .sum()
        };
        let started = Instant::now();
        let mut before = busy();
        while started.elapsed().as_secs() < 60 {
            std::thread::sleep(std::time::Duration::from_millis(500));
            let now = busy();
            // Below a tenth of a core over the half second: settled.
            if now - before < 0.05 {
                break;
            }
            before = now;
        }
        eprintln!(
            "a home of {} processes settled {:.1} s after it was ready",
            self.parts.len(),
            started.elapsed().as_secs_f64()
        );
    }

    /// The paper's task by an executive connected to the first router, in the building's domain
    /// (its ceiling cameras see only the rooms they cover), as `generate home` writes it.
    fn task(&self, acquire: &str) -> Measured {
        let domain = support::root().join("domains/peis-building.eco");
        let problem = support::root().join("domains/peis-home-task.problem");
        let (domain, problem) = (domain.display().to_string(), problem.display().to_string());
        let task = [
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
            "--connect",
            &self.routers[0].1,
            "--client",
        ];
        let started = Instant::now();
        let out = ecology().args(task).output().expect("runs ecology task");
        read_timings(&out, started.elapsed().as_secs_f64())
    }

    /// Each process's name, peak memory (MB) and CPU time (s) so far.
    fn usage(&self) -> Vec<(String, f64, f64)> {
        let named = self
            .routers
            .iter()
            .map(|(p, _)| ("router", p))
            .chain(std::iter::once(("world", &self.world)))
            .chain(self.parts.iter().map(|p| ("peis", p)));
        named
            .enumerate()
            .map(|(i, (kind, p))| {
                let (peak, cpu) = usage(p.pid().as_raw() as u32);
                (format!("{kind}#{i}"), peak, cpu)
            })
            .collect()
    }
}

/// How many times in turn the acquisitions of the homes of 10 and 1,000 PEIS are taken over Zenoh
/// (their medians are compared).
const TURNS: usize = 3;

fn over_zenoh(file: &str, acquire: &str, hold_contract: bool) -> Measured {
    Home::start(file, 1, 1, hold_contract).task(acquire)
}

fn row(where_: &str, peis: usize, acquire: &str, m: &Measured) {
    let to_running = m
        .to_running
        .map_or("-".to_string(), |ms| format!("{ms:.0} ms"));
    println!(
        "| {where_} | {peis} | {acquire} | {} | {:.2} s | {:.1} ms | {to_running} | {:.1} ms | {:.1} ms | {} | {} | {:.0} MB |",
        if m.done { "done" } else { "FAILED" },
        m.wall,
        m.acquisition,
        m.state_ms,
        m.plan_ms,
        m.tuples,
        m.bytes,
        m.peak_mb,
    );
}

/// How many runs of each size, in turn, the in-process ratio takes the median of.
const RATIO_RUNS: usize = 9;

fn main() {
    support::QUIET.store(true, std::sync::atomic::Ordering::Relaxed);
    let dir = std::env::temp_dir().join(format!("ecology-bench-large-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temporary folder");
    let full = std::env::var_os("ECOLOGY_LARGE_FULL").is_some();
    println!(
        "| where | PEIS | acquire | task | wall | acquisition | start → running | state (max) | planning (max) | tuples in | bytes in | peak memory |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    let mut sizes = vec![10, 100, 1000];
    if full {
        sizes.push(10_000);
    }
    let mut files = Vec::new();
    for &peis in &sizes {
        let file = generate(&dir, peis);
        for acquire in ["on-demand", "everything"] {
            let m = in_process(&file, acquire);
            row("in process", peis, acquire, &m);
        }
        files.push((peis, file));
    }
    // The ratio of wall times compares medians of runs taken in turn, one of each size after the
    // other: from one run of each it came out anywhere from 2.3x to 4.6x on this machine.
    let mut runs: Vec<(usize, Vec<f64>)> =
        files.iter().map(|(peis, _)| (*peis, Vec::new())).collect();
    for _ in 0..RATIO_RUNS {
        for ((_, file), (_, walls)) in files.iter().zip(runs.iter_mut()) {
            walls.push(in_process(file, "on-demand").wall);
        }
    }
    let walls: Vec<(usize, f64)> = runs
        .into_iter()
        .map(|(peis, mut walls)| {
            walls.sort_by(f64::total_cmp);
            (peis, walls[walls.len() / 2])
        })
        .collect();
    let mut acquisitions = Vec::new();
    let mut uncached = Vec::new();
    for peis in [10, 100, 300, 1000] {
        let file = generate(&dir, peis);
        // The homes of the target's two ends are asked several times in turn, each in a fresh
        // home, and the medians compared: a few milliseconds each, within this machine's spread
        // from one task to the next.
        let turns = if [10, 1000].contains(&peis) { TURNS } else { 1 };
        let mut taken: Vec<(&str, Vec<f64>)> = vec![("on-demand", vec![]), ("everything", vec![])];
        for _ in 0..turns {
            for (acquire, times) in &mut taken {
                let m = over_zenoh(&file, acquire, true);
                row("Zenoh", peis, acquire, &m);
                times.push(m.acquisition);
            }
        }
        for (acquire, mut times) in taken {
            times.sort_by(f64::total_cmp);
            acquisitions.push((peis, acquire, times[times.len() / 2]));
        }
        // Side by side: the same, with routers that hold nothing (every PEIS answers).
        let m = over_zenoh(&file, "on-demand", false);
        row("Zenoh, router holds nothing", peis, "on-demand", &m);
        uncached.push((peis, m.acquisition));
    }
    let file = generate(&dir, 1000);
    let mut usages = Vec::new();
    for routers in [1, 2] {
        let home = Home::start(&file, 4, routers, true);
        let where_ = format!(
            "4 processes, {routers} router{}",
            if routers > 1 { "s" } else { "" }
        );
        for acquire in ["on-demand", "everything"] {
            let m = home.task(acquire);
            row(&where_, 1000, acquire, &m);
        }
        usages.push((where_, home.usage()));
    }
    println!("\nEvery process of the runs as processes, at their end (both tasks done):\n");
    println!("| run | process | peak memory | CPU time |");
    println!("|---|---|---|---|");
    for (run, usage) in &usages {
        for (name, peak, cpu) in usage {
            println!("| {run} | {name} | {peak:.0} MB | {cpu:.1} s |");
        }
    }
    let value_of =
        |xs: &[(usize, f64)], n: usize| xs.iter().find(|(p, _)| *p == n).map(|(_, v)| *v);
    let ratio = |xs: &[(usize, f64)], a: usize, b: usize| {
        value_of(xs, b)
            .zip(value_of(xs, a))
            .map(|(b, a)| b / a.max(1e-9))
    };
    println!();
    for &(size, slower) in &[(1000, 3.0), (10_000, 30.0)] {
        if let (Some(r), Some(big), Some(small)) = (
            ratio(&walls, 10, size),
            value_of(&walls, size),
            value_of(&walls, 10),
        ) {
            println!(
                "in process, on demand: {size} PEIS take {r:.1}x the wall time of 10 (medians of {RATIO_RUNS} runs in turn: {big:.3} s and {small:.3} s; target: at most {slower}x)"
            );
        }
    }
    let on_demand: Vec<(usize, f64)> = acquisitions
        .iter()
        .filter(|(_, a, _)| *a == "on-demand")
        .map(|(n, _, ms)| (*n, *ms))
        .collect();
    for (peis, _, everything) in acquisitions.iter().filter(|(_, a, _)| *a == "everything") {
        if let Some((_, mine)) = on_demand.iter().find(|(n, _)| n == peis) {
            let r = mine / everything.max(1e-9);
            let of = if [10, 1000].contains(peis) {
                format!(" (medians of {TURNS} in turn)")
            } else {
                String::new()
            };
            println!(
                "over Zenoh, {peis} PEIS: acquisition on demand is {r:.2}x that of reading everything{of} (target: at most 1x)"
            );
        }
    }
    for (peis, without) in &uncached {
        if let Some((_, with)) = on_demand.iter().find(|(n, _)| n == peis) {
            println!(
                "over Zenoh, {peis} PEIS: on demand, a router that holds the contract takes {:.2}x the time of one that holds nothing",
                with / without.max(1e-9)
            );
        }
    }
    if let Some(r) = ratio(&on_demand, 10, 1000) {
        println!(
            "over Zenoh, on demand: acquisition at 1,000 PEIS is {r:.1}x that at 10 (medians of {TURNS} in turn; target: at most 3x)"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
