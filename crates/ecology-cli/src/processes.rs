//! `ecology demo --processes` and `ecology run SCENARIO --processes`: a
//! scenario as separate processes on loopback — the world, one process per
//! PEIS, and the executive — started and watched by this launcher.
//!
//! The launcher is a PEIS too (`launcher`): it follows the executive's `log`
//! tuple and injects the scenario's faults as the scenario says, into the
//! processes themselves: a component fault is the PEIS's `C.fault` tuple, set
//! by remote set (the PEIS applies it to its own component); a crash is a
//! real SIGKILL of the PEIS process; a revival starts it again. When the
//! executive exits, the launcher stops every process it started (SIGTERM,
//! then SIGKILL after 3 s) and exits with the executive's exit code.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant};

use anyhow::Context;
use ecology_sim::{FaultKind, FaultSpec, Scenario, ScenarioTask, Trigger, WORLD};
use ecology_tuples::{Key, PeisId, TupleEvent, TuplePattern, TupleSpace, Value};
use ecology_zenoh::security::{GrantPattern, KeysDir, Role};
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::{Child, Command};
use tokio::sync::mpsc;
use tokio::task::JoinSet;

use crate::network::{self, NetArgs};
use crate::{EXIT_BAD_INPUT, EXIT_NO_SOLUTION};

/// How long a process may take to say it is ready.
const READY_TIMEOUT: Duration = Duration::from_secs(30);
/// How long a process may take to stop after SIGTERM before it is killed.
const STOP_TIMEOUT: Duration = Duration::from_secs(3);
/// What the launcher calls the executive's process (its PEIS name is the task's).
const EXECUTIVE: &str = "executive";
/// The launcher's own PEIS name.
const LAUNCHER: &str = "launcher";

/// What the launcher runs with.
#[derive(Debug, Clone)]
pub struct Launch {
    /// The scenario file.
    pub scenario: PathBuf,
    /// The seed for the world and the components.
    pub seed: Option<u64>,
    /// JSON lines on stdout (everything else on stderr).
    pub json: bool,
}

/// A line a child printed.
struct Line {
    who: String,
    stderr: bool,
    text: String,
}

/// One process the launcher started.
struct Process {
    args: Vec<String>,
    child: Child,
}

impl Process {
    fn pid(&self) -> Option<Pid> {
        self.child
            .id()
            .and_then(|id| i32::try_from(id).ok())
            .map(Pid::from_raw)
    }

    fn signal(&self, signal: Signal) {
        if let Some(pid) = self.pid() {
            // The process may have exited already; then there is nothing to signal.
            let _ = kill(pid, signal);
        }
    }

    /// SIGTERM, then SIGKILL if it has not exited within [`STOP_TIMEOUT`].
    async fn stop(mut self) {
        self.signal(Signal::SIGTERM);
        if tokio::time::timeout(STOP_TIMEOUT, self.child.wait())
            .await
            .is_err()
        {
            let _ = self.child.kill().await;
        }
    }
}

/// Starts processes of this binary and forwards their output as [`Line`]s.
struct Spawner {
    exe: PathBuf,
    lines: mpsc::UnboundedSender<Line>,
    readers: JoinSet<()>,
}

impl Spawner {
    fn spawn(&mut self, name: &str, args: Vec<String>) -> anyhow::Result<Process> {
        let mut child = Command::new(&self.exe)
            .args(&args)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .kill_on_drop(true)
            .spawn()
            .with_context(|| format!("starting {name}"))?;
        let streams = [
            (false, child.stdout.take().map(|s| Box::new(s) as Box<_>)),
            (true, child.stderr.take().map(|s| Box::new(s) as Box<_>)),
        ];
        for (stderr, stream) in streams {
            let Some(stream): Option<Box<dyn tokio::io::AsyncRead + Send + Unpin>> = stream else {
                continue;
            };
            let lines = self.lines.clone();
            let who = name.to_string();
            self.readers.spawn(async move {
                let mut reader = BufReader::new(stream).lines();
                while let Ok(Some(text)) = reader.next_line().await {
                    let line = Line {
                        who: who.clone(),
                        stderr,
                        text,
                    };
                    if lines.send(line).is_err() {
                        return;
                    }
                }
            });
        }
        Ok(Process { args, child })
    }
}

/// A free QUIC endpoint on 127.0.0.1: every process of the launch proves its name.
fn free_endpoint() -> anyhow::Result<String> {
    let socket =
        std::net::UdpSocket::bind("127.0.0.1:0").context("finding a free port on 127.0.0.1")?;
    Ok(format!("quic/127.0.0.1:{}", socket.local_addr()?.port()))
}

/// A keys directory for one launch: every process a member, the executive with its role, and
/// the launcher granted the `fault` tuples it injects faults through.
fn launch_keys(dir: &Path, scenario: &Scenario) -> anyhow::Result<()> {
    let mut keys = KeysDir::init(dir)?;
    for name in std::iter::once(WORLD)
        .chain(scenario.peis.iter().map(|p| p.name.as_str()))
        .chain([LAUNCHER])
    {
        keys.add(PeisId::new(name)?, Role::Peis)?;
    }
    keys.add(PeisId::new(&task(scenario).executive)?, Role::Executive)?;
    keys.grant(
        PeisId::new(LAUNCHER)?,
        None,
        vec![GrantPattern::new("*.fault")?],
    )?;
    Ok(())
}

fn strings(items: &[&str]) -> Vec<String> {
    items.iter().map(ToString::to_string).collect()
}

/// Runs `launch.scenario` as separate processes; returns the exit code.
pub fn run(launch: &Launch) -> anyhow::Result<u8> {
    let scenario = match Scenario::load(&launch.scenario) {
        Ok(scenario) => scenario,
        Err(e) => {
            eprintln!("error: {e}");
            return Ok(EXIT_BAD_INPUT);
        }
    };
    // One executive process, started with the others: several tasks, or one that starts
    // later, run in process only (for now).
    if let [one] = scenario.tasks.as_slice()
        && one.start.is_zero()
    {
        network::runtime()?.block_on(launch_all(launch, &scenario))
    } else {
        let names: Vec<&str> = scenario
            .tasks
            .iter()
            .map(|t| t.executive.as_str())
            .collect();
        eprintln!(
            "error: --processes runs one task that starts at once, and {} has {} ({}): run it in process, without --processes",
            launch.scenario.display(),
            if names.len() > 1 {
                format!("{} tasks", names.len())
            } else {
                "a task starting later".to_string()
            },
            names.join(", ")
        );
        Ok(EXIT_BAD_INPUT)
    }
}

/// The scenario's one task (`run` launches no other).
fn task(scenario: &Scenario) -> &ScenarioTask {
    &scenario.tasks[0]
}

/// The scenario's plan as a plan file (the form `ecology plan` prints).
fn plan_text(scenario: &Scenario) -> String {
    task(scenario)
        .plan
        .steps
        .iter()
        .map(|step| match &step.goal {
            Some(goal) => format!("{}  ; configure {goal}\n", step.action),
            None => format!("{}\n", step.action),
        })
        .collect()
}

/// Prints a line of the run: on stdout, or on stderr when stdout carries JSON.
fn show(json: bool, text: &str) {
    use std::io::Write;
    if json {
        eprintln!("{text}");
    } else {
        let mut out = std::io::stdout().lock();
        let _ = writeln!(out, "{text}");
        let _ = out.flush();
    }
}

async fn launch_all(launch: &Launch, scenario: &Scenario) -> anyhow::Result<u8> {
    let json = launch.json;
    let seed = launch.seed.unwrap_or(scenario.seed).to_string();
    let folder = launch
        .scenario
        .parent()
        .unwrap_or(Path::new(""))
        .to_path_buf();
    let scenario_file = launch.scenario.display().to_string();
    let work = std::env::temp_dir().join(format!("ecology-launch-{}", std::process::id()));
    std::fs::create_dir_all(&work).with_context(|| format!("creating {}", work.display()))?;
    let plan_file = work.join("plan.txt");
    std::fs::write(&plan_file, plan_text(scenario))
        .with_context(|| format!("writing {}", plan_file.display()))?;
    let keys_dir = work.join("keys");
    launch_keys(&keys_dir, scenario)?;
    let keys = keys_dir.display().to_string();

    let (lines_tx, mut lines) = mpsc::unbounded_channel();
    let mut spawner = Spawner {
        exe: std::env::current_exe().context("finding the ecology binary")?,
        lines: lines_tx,
        readers: JoinSet::new(),
    };
    let world_endpoint = free_endpoint()?;
    let mut processes: BTreeMap<String, Process> = BTreeMap::new();
    let result = async {
        show(
            json,
            &format!(
                "scenario {}: {} (seed {seed}), as {} processes on 127.0.0.1, over mutual TLS",
                scenario.name,
                scenario.description,
                scenario.peis.len() + 2
            ),
        );
        // The world first: every other process connects to it and finds the rest by gossip.
        let world_args = [
            "world",
            &scenario_file,
            "--seed",
            &seed,
            "--listen",
            &world_endpoint,
            "--keys",
            &keys,
        ];
        let world = spawner.spawn(WORLD, strings(&world_args))?;
        processes.insert(WORLD.to_string(), world);
        await_ready(&mut lines, &[WORLD], json).await?;
        for def in &scenario.peis {
            let endpoint = free_endpoint()?;
            let args = [
                "peis",
                &scenario_file,
                "--name",
                &def.name,
                "--seed",
                &seed,
                "--listen",
                &endpoint,
                "--connect",
                &world_endpoint,
                "--keys",
                &keys,
            ];
            let process = spawner.spawn(&def.name, strings(&args))?;
            processes.insert(def.name.clone(), process);
        }
        let names: Vec<&str> = scenario.peis.iter().map(|p| p.name.as_str()).collect();
        await_ready(&mut lines, &names, json).await?;

        // The launcher joins to follow the executive and to set fault tuples.
        let net = NetArgs {
            listen: vec![free_endpoint()?],
            connect: vec![world_endpoint.clone()],
            keys: Some(keys_dir.clone()),
            ..NetArgs::default()
        };
        let me = PeisId::new(LAUNCHER)?;
        let launcher = match network::join(me, &net).await {
            Ok(space) => space,
            Err(network::JoinFailure::NameTaken(id)) => {
                anyhow::bail!("a PEIS named {id} is already present")
            }
            Err(network::JoinFailure::Other(e) | network::JoinFailure::BadConfig(e)) => {
                return Err(e);
            }
        };
        let log_pattern = TuplePattern::parse(&format!("{}:log", task(scenario).executive))?;
        let mut log = launcher.subscribe(log_pattern).await?;

        let mut wait_for: Vec<&str> = vec![WORLD];
        wait_for.extend(scenario.peis.iter().map(|p| p.name.as_str()));
        let wait_for = wait_for.join(",");
        let domain_file = folder.join(&task(scenario).domain_file).display().to_string();
        // A problem lets the executive plan again when an action fails; a plan is run as it is.
        let (task_flag, task_file) = match &task(scenario).problem {
            Some((_, problem_file)) => ("--problem", folder.join(problem_file).display().to_string()),
            None => ("--plan", plan_file.display().to_string()),
        };
        let action_timeout = scenario.action_timeout.as_secs_f64().max(0.001).to_string();
        let executive_endpoint = free_endpoint()?;
        let mut executive_args = strings(&[
            "task",
            "--domain",
            &domain_file,
            task_flag,
            &task_file,
            "--wait-for",
            &wait_for,
            "--action-timeout",
            &action_timeout,
            "--listen",
            &executive_endpoint,
            "--connect",
            &world_endpoint,
            "--keys",
            &keys,
        ]);
        if json {
            executive_args.push("--json".to_string());
        }
        if task(scenario).executive != ecology_sim::EXECUTIVE {
            executive_args.extend(["--name".to_string(), task(scenario).executive.clone()]);
        }
        let mut executive = spawner.spawn(EXECUTIVE, executive_args)?;
        let started = Instant::now();
        let mut faults = Faults::new(scenario, started);
        let mut clock = ExecClock::default();
        let mut interrupted = false;
        let stop = network::stop_signal();
        tokio::pin!(stop);
        let status = loop {
            let due = faults.next_due();
            tokio::select! {
                status = executive.child.wait() => break status.context("waiting for the executive")?,
                Some(line) = lines.recv() => forward(&line, json),
                Some(event) = log.next() => {
                    if let TupleEvent::Changed(tuple) = event
                        && let Ok(text) = tuple.text()
                        && let Ok(entry) = serde_json::from_str::<serde_json::Value>(text)
                    {
                        clock.seen(&entry);
                        faults.observe(&entry);
                    }
                }
                () = sleep_until(due) => {
                    for fault in faults.take_due() {
                        inject(&fault, &launcher, &mut processes, &mut spawner, &clock, json).await;
                    }
                }
                which = &mut stop, if !interrupted => {
                    interrupted = true;
                    show(json, &format!("launcher: {which}: stopping the executive"));
                    executive.signal(Signal::SIGTERM);
                }
            }
        };
        // What the executive printed last is still in the pipe.
        drop(executive);
        while let Ok(Some(line)) = tokio::time::timeout(Duration::from_millis(200), lines.recv()).await {
            forward(&line, json);
        }
        launcher.close().await;
        Ok(status.code().map_or(EXIT_NO_SOLUTION, |c| {
            u8::try_from(c).unwrap_or(EXIT_NO_SOLUTION)
        }))
    }
    .await;

    // Everything started is stopped, whatever happened.
    let stopping: Vec<Process> = std::mem::take(&mut processes).into_values().collect();
    for process in stopping {
        process.stop().await;
    }
    while let Ok(Some(line)) = tokio::time::timeout(Duration::from_millis(200), lines.recv()).await
    {
        forward(&line, json);
    }
    spawner.readers.shutdown().await;
    let _ = std::fs::remove_dir_all(&work);
    result
}

async fn sleep_until(at: Option<Instant>) {
    match at {
        Some(at) => tokio::time::sleep_until(at.into()).await,
        None => std::future::pending().await,
    }
}

/// Waits until every process of `names` has printed its `NAME ready` line,
/// forwarding what they print.
async fn await_ready(
    lines: &mut mpsc::UnboundedReceiver<Line>,
    names: &[&str],
    json: bool,
) -> anyhow::Result<()> {
    let deadline = tokio::time::Instant::now() + READY_TIMEOUT;
    let mut waiting: Vec<&str> = names.to_vec();
    while !waiting.is_empty() {
        let line = tokio::time::timeout_at(deadline, lines.recv())
            .await
            .map_err(|_| {
                anyhow::anyhow!(
                    "{} did not start within {READY_TIMEOUT:?}",
                    waiting.join(", ")
                )
            })?
            .ok_or_else(|| anyhow::anyhow!("{} stopped before ready", waiting.join(", ")))?;
        forward(&line, json);
        let who = line.who.as_str();
        if line.stderr && line.text.starts_with("error") && waiting.contains(&who) {
            anyhow::bail!("{who} could not start: {}", line.text);
        }
        if line.text.starts_with(&format!("{who} ready")) {
            waiting.retain(|w| *w != who);
        }
    }
    Ok(())
}

/// Shows a child's line: the executive's as it is, the others' indented.
fn forward(line: &Line, json: bool) {
    if line.who == EXECUTIVE {
        if line.stderr {
            eprintln!("{}", line.text);
        } else {
            use std::io::Write;
            let mut out = std::io::stdout().lock();
            let _ = writeln!(out, "{}", line.text);
            let _ = out.flush();
        }
    } else {
        show(json, &format!("           [{}] {}", line.who, line.text));
    }
}

/// The executive's time, estimated from its last log entry.
#[derive(Default)]
struct ExecClock {
    last: Option<(f64, Instant)>,
}

impl ExecClock {
    fn seen(&mut self, entry: &serde_json::Value) {
        if let Some(t) = entry.get("t").and_then(serde_json::Value::as_f64) {
            self.last = Some((t, Instant::now()));
        }
    }

    fn now(&self) -> f64 {
        self.last
            .map_or(0.0, |(t, at)| t + at.elapsed().as_secs_f64())
    }
}

/// The scenario's faults: pending triggers and the injections they scheduled.
struct Faults {
    waiting: Vec<FaultSpec>,
    scheduled: Vec<(Instant, FaultSpec)>,
    current_action: Option<usize>,
}

impl Faults {
    fn new(scenario: &Scenario, started: Instant) -> Self {
        let mut faults = Faults {
            waiting: Vec::new(),
            scheduled: Vec::new(),
            current_action: None,
        };
        for fault in &scenario.faults {
            match fault.trigger {
                Trigger::At(at) => faults.scheduled.push((started + at, fault.clone())),
                Trigger::After { .. } => faults.waiting.push(fault.clone()),
            }
        }
        faults
    }

    /// Takes in one executive log entry (a JSON object) and schedules the faults it triggers.
    fn observe(&mut self, entry: &serde_json::Value) {
        let name = entry.get("event").and_then(serde_json::Value::as_str);
        let index = entry
            .get("index")
            .and_then(serde_json::Value::as_u64)
            .and_then(|i| usize::try_from(i).ok());
        if name == Some("action_started") {
            self.current_action = index;
        }
        let index = index.or(self.current_action);
        let mut still_waiting = Vec::new();
        for fault in std::mem::take(&mut self.waiting) {
            let fired = name.and_then(|name| fault.trigger.fired_by(name, index));
            match fired {
                Some(delay) => self.scheduled.push((Instant::now() + delay, fault)),
                None => still_waiting.push(fault),
            }
        }
        self.waiting = still_waiting;
    }

    fn next_due(&self) -> Option<Instant> {
        self.scheduled.iter().map(|(at, _)| *at).min()
    }

    fn take_due(&mut self) -> Vec<FaultSpec> {
        let now = Instant::now();
        let (due, later): (Vec<_>, Vec<_>) = std::mem::take(&mut self.scheduled)
            .into_iter()
            .partition(|(at, _)| *at <= now);
        self.scheduled = later;
        due.into_iter().map(|(_, f)| f).collect()
    }
}

/// Carries out one fault on the processes.
async fn inject(
    fault: &FaultSpec,
    launcher: &ecology_zenoh::ZenohPeis,
    processes: &mut BTreeMap<String, Process>,
    spawner: &mut Spawner,
    clock: &ExecClock,
    json: bool,
) {
    let component = fault.component.clone().unwrap_or_default();
    let target = format!("{}:{component}", fault.peis);
    let note = |what: String| {
        show(json, &format!("{:>8.3}s  [launcher] {what}", clock.now()));
    };
    let tuple = match fault.kind {
        FaultKind::Stall => Some((
            "stall".to_string(),
            format!("{target} stalls (fault tuple set)"),
        )),
        FaultKind::Garble => Some((
            "garble".to_string(),
            format!("{target} garbles its outputs (fault tuple set)"),
        )),
        FaultKind::Fail => Some((
            format!("fail {}", fault.cause),
            format!("{target} fails: {} (fault tuple set)", fault.cause),
        )),
        FaultKind::Recover => Some((
            "recover".to_string(),
            format!("{target} recovers (fault tuple set)"),
        )),
        FaultKind::Duplicate | FaultKind::Late => {
            // A network's duplicates and late deliveries cannot be made to order
            // between processes; the in-process run injects them.
            note(format!(
                "{target}: a {:?} delivery is injected only in-process",
                fault.kind
            ));
            None
        }
        FaultKind::Kill => {
            if let Some(process) = processes.get(&fault.peis) {
                process.signal(Signal::SIGKILL);
                note(format!("PEIS {} killed (SIGKILL)", fault.peis));
            }
            None
        }
        FaultKind::Revive => {
            let args = processes.get(&fault.peis).map(|p| p.args.clone());
            if let Some(args) = args {
                match spawner.spawn(&fault.peis, args) {
                    Ok(process) => {
                        let old = processes.insert(fault.peis.clone(), process);
                        if let Some(mut old) = old {
                            let _ = old.child.kill().await;
                        }
                        note(format!("PEIS {} started again", fault.peis));
                    }
                    Err(e) => note(format!("PEIS {} could not start again: {e:#}", fault.peis)),
                }
            }
            None
        }
    };
    let Some((value, what)) = tuple else { return };
    let (Ok(owner), Ok(key)) = (
        PeisId::new(&fault.peis),
        Key::new(&format!("{component}.fault")),
    ) else {
        return;
    };
    match launcher.set_remote(owner, key, Value::text(value)).await {
        Ok(_) => note(what),
        Err(e) => note(format!("could not inject the fault into {target}: {e}")),
    }
}
