//! The ecology as separate processes on 127.0.0.1: `ecology world`, `ecology
//! peis` and `ecology task` over Zenoh, with real faults (SIGKILL, SIGSTOP and
//! SIGCONT, restarts, slow start-up) and a router.
//!
//! Each test writes a small PEIS-Home scenario in which Astrid stands in the
//! entrance, two metres from the bedroom, so a move takes a few seconds. The
//! tests run one at a time: each starts four or five processes that publish
//! at 20 Hz, and two such ecologies on two cores would blur their timings.

use std::io::BufRead;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use serde_json::Value;

/// Bounds every wait of these tests.
const PATIENCE: Duration = Duration::from_secs(60);

static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

fn one_at_a_time() -> MutexGuard<'static, ()> {
    ONE_AT_A_TIME
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn free_endpoint() -> String {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("bind 127.0.0.1:0");
    format!(
        "tcp/127.0.0.1:{}",
        listener.local_addr().expect("address").port()
    )
}

/// A line a process printed, and when it was read.
#[derive(Debug, Clone)]
struct Line {
    text: String,
    at: Instant,
}

/// An `ecology` process, killed when dropped; its stdout read line by line.
struct Proc {
    name: String,
    child: Child,
    lines: mpsc::Receiver<Line>,
    seen: Vec<Line>,
}

impl Proc {
    fn start(name: &str, args: &[&str]) -> Proc {
        let mut child = Command::new(env!("CARGO_BIN_EXE_ecology"))
            .args(args)
            .current_dir(root())
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("spawn ecology");
        let out = child.stdout.take().expect("piped stdout");
        let (tx, lines) = mpsc::channel();
        std::thread::spawn(move || {
            for line in std::io::BufReader::new(out).lines() {
                let Ok(text) = line else { return };
                if tx
                    .send(Line {
                        text,
                        at: Instant::now(),
                    })
                    .is_err()
                {
                    return;
                }
            }
        });
        Proc {
            name: name.to_string(),
            child,
            lines,
            seen: Vec::new(),
        }
    }

    fn pid(&self) -> Pid {
        Pid::from_raw(i32::try_from(self.child.id()).expect("pid fits"))
    }

    fn signal(&self, signal: Signal) {
        kill(self.pid(), signal).expect("signal the process");
    }

    /// Reads lines until one satisfies `want`; returns it.
    fn wait_for(&mut self, what: &str, want: impl Fn(&str) -> bool) -> Line {
        let deadline = Instant::now() + PATIENCE;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(line) => {
                    self.seen.push(line.clone());
                    if want(&line.text) {
                        return line;
                    }
                }
                Err(_) => panic!(
                    "{} never printed {what}; it printed:\n{}",
                    self.name,
                    self.transcript()
                ),
            }
        }
    }

    fn ready(mut self) -> Proc {
        let name = self.name.clone();
        self.wait_for("its ready line", |l| {
            l.starts_with(&format!("{name} ready"))
        });
        self
    }

    /// Waits for the process to exit; returns its exit code and every line it printed.
    fn finish(mut self) -> (Option<i32>, Vec<Line>) {
        let deadline = Instant::now() + PATIENCE;
        loop {
            match self.child.try_wait().expect("try_wait") {
                Some(status) => {
                    while let Ok(line) = self.lines.recv_timeout(Duration::from_secs(2)) {
                        self.seen.push(line);
                    }
                    return (status.code(), std::mem::take(&mut self.seen));
                }
                None if Instant::now() > deadline => {
                    panic!("{} did not exit:\n{}", self.name, self.transcript())
                }
                None => std::thread::sleep(Duration::from_millis(20)),
            }
        }
    }

    fn transcript(&self) -> String {
        self.seen
            .iter()
            .map(|l| l.text.as_str())
            .collect::<Vec<_>>()
            .join("\n")
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A scenario file and a plan file in a fresh folder, removed when dropped.
struct Fixture {
    folder: PathBuf,
}

impl Fixture {
    /// Astrid in the entrance facing the bedroom door; `tr1` as given (`on`, `startup`).
    fn new(test: &str, tr1_on: bool, tr1_startup: f64, plan: &[(&str, &str)]) -> Fixture {
        let folder = std::env::temp_dir().join(format!("ecology-{test}-{}", std::process::id()));
        std::fs::create_dir_all(&folder).expect("temp folder");
        let domain = root().join("domains/peis-home.eco");
        let steps: Vec<String> = plan
            .iter()
            .map(|(action, goal)| format!("  {{ action = \"{action}\", configure = \"{goal}\" }},"))
            .collect();
        let scenario = format!(
            r#"name = "{test}"
seed = 7
[task]
domain = "{domain}"
plan = [
{steps}
]
[map]
rooms = [
  {{ name = "living-room", x = [0.0, 3.0], y = [0.0, 3.0] }},
  {{ name = "entrance",    x = [2.5, 5.0], y = [3.0, 5.0] }},
  {{ name = "bedroom",     x = [0.0, 2.5], y = [3.0, 5.0] }},
]
doors = [
  {{ between = ["living-room", "entrance"], at = [2.75, 3.0] }},
  {{ between = ["entrance", "bedroom"],     at = [2.5, 4.0] }},
]
[[robot]]
name = "astrid"
at = [3.3, 4.0, 3.14159]
[[peis]]
name = "astrid"
components = [
  {{ id = "l1",  type = "laser",    cost = 100, on = false, startup = 0.3 }},
  {{ id = "od1", type = "odomet",   cost = 10,  on = true }},
  {{ id = "tc1", type = "tc",       cost = 20,  on = true }},
  {{ id = "s1",  type = "self-loc", cost = 20,  on = true }},
]
[[peis]]
name = "hsm"
components = [
  {{ id = "ca1", type = "cams",   cost = 20, on = true }},
  {{ id = "tr1", type = "tr-sys", cost = 20, on = {tr1_on}, startup = {tr1_startup} }},
]
"#,
            domain = domain.display(),
            steps = steps.join("\n"),
        );
        std::fs::write(folder.join("scenario.toml"), scenario).expect("write scenario");
        let plan_text: String = plan
            .iter()
            .map(|(action, goal)| format!("{action}  ; configure {goal}\n"))
            .collect();
        std::fs::write(folder.join("plan.txt"), plan_text).expect("write plan");
        Fixture { folder }
    }

    fn scenario(&self) -> String {
        self.folder.join("scenario.toml").display().to_string()
    }

    fn plan(&self) -> String {
        self.folder.join("plan.txt").display().to_string()
    }
}

impl Drop for Fixture {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.folder);
    }
}

const TO_BEDROOM: (&str, &str) = (
    "(move astrid entrance bedroom)",
    "(navigate astrid bedroom)",
);
const TO_ENTRANCE: (&str, &str) = (
    "(move astrid bedroom entrance)",
    "(navigate astrid entrance)",
);

/// A running ecology: the world, astrid and hsm, each a process.
struct Ecology {
    world_endpoint: String,
    _world: Proc,
    _astrid: Proc,
    hsm: Proc,
    hsm_args: Vec<String>,
}

impl Ecology {
    fn start(fixture: &Fixture, hsm_extra: &[&str]) -> Ecology {
        let scenario = fixture.scenario();
        let world_endpoint = free_endpoint();
        let world =
            Proc::start("world", &["world", &scenario, "--listen", &world_endpoint]).ready();
        let peis = |name: &str, extra: &[&str]| -> Vec<String> {
            let mut args: Vec<String> = [
                "peis",
                scenario.as_str(),
                "--name",
                name,
                "--listen",
                &free_endpoint(),
                "--connect",
                &world_endpoint,
            ]
            .iter()
            .map(ToString::to_string)
            .collect();
            args.extend(extra.iter().map(ToString::to_string));
            args
        };
        let astrid_args = peis("astrid", &[]);
        let hsm_args = peis("hsm", hsm_extra);
        let astrid = Proc::start("astrid", &as_strs(&astrid_args)).ready();
        let hsm = Proc::start("hsm", &as_strs(&hsm_args)).ready();
        Ecology {
            world_endpoint,
            _world: world,
            _astrid: astrid,
            hsm,
            hsm_args,
        }
    }

    /// The executive on `plan`, printing JSON lines.
    fn task(&self, fixture: &Fixture, extra: &[&str]) -> Proc {
        let mut args = vec!["task", "--domain", "domains/peis-home.eco", "--plan"];
        let plan = fixture.plan();
        args.push(&plan);
        let listen = free_endpoint();
        args.extend([
            "--json",
            "--wait-for",
            "world,astrid,hsm",
            "--listen",
            &listen,
            "--connect",
            &self.world_endpoint,
        ]);
        args.extend_from_slice(extra);
        Proc::start("executive", &args)
    }
}

fn as_strs(args: &[String]) -> Vec<&str> {
    args.iter().map(String::as_str).collect()
}

fn event(line: &str) -> Value {
    serde_json::from_str(line).unwrap_or_else(|e| panic!("not a JSON line ({e}): {line}"))
}

fn is_event(line: &str, name: &str) -> bool {
    serde_json::from_str::<Value>(line).is_ok_and(|v| v["event"] == name)
}

fn events(lines: &[Line]) -> Vec<Value> {
    lines.iter().map(|l| event(&l.text)).collect()
}

fn named<'a>(events: &'a [Value], name: &str) -> Vec<&'a Value> {
    events.iter().filter(|e| e["event"] == name).collect()
}

fn costs(events: &[Value]) -> Vec<(u64, bool)> {
    named(events, "configuration")
        .iter()
        .map(|e| {
            (
                e["cost"].as_u64().expect("cost"),
                e["reconfiguration"].as_bool().expect("flag"),
            )
        })
        .collect()
}

fn strings(value: &Value) -> Vec<String> {
    value
        .as_array()
        .map(|a| {
            a.iter()
                .filter_map(|s| s.as_str().map(str::to_string))
                .collect()
        })
        .unwrap_or_default()
}

/// How long after `fault_at` the executive logged the failure, on the
/// executive's clock: its `running` line was read at `running.at`, so the
/// fault happened at t(running) + (fault_at - running.at).
fn detection_delay(running: &Line, fault_at: Instant, failure: &Value) -> f64 {
    let t_running = event(&running.text)["t"].as_f64().expect("t");
    let t_fault = t_running + fault_at.duration_since(running.at).as_secs_f64();
    failure["t"].as_f64().expect("t") - t_fault
}

#[test]
fn sigkill_of_the_camera_peis_reconfigures_astrid_to_her_laser() {
    let _one = one_at_a_time();
    let fixture = Fixture::new("sigkill", true, 0.0, &[TO_BEDROOM]);
    let ecology = Ecology::start(&fixture, &[]);
    let mut task = ecology.task(&fixture, &[]);
    let running = task.wait_for("running", |l| is_event(l, "running"));
    ecology.hsm.signal(Signal::SIGKILL);
    let killed_at = Instant::now();
    let (code, lines) = task.finish();
    let all = events(&lines);
    assert_eq!(code, Some(0), "{all:#?}");
    assert_eq!(costs(&all), [(80, false), (170, true)], "{all:#?}");
    let failures = named(&all, "failure");
    assert!(!failures.is_empty());
    assert!(
        failures
            .iter()
            .all(|f| f["peis"] == "hsm" && f["cause"] == "PEIS hsm left the ecology"),
        "{failures:#?}"
    );
    // A killed process's TCP connections close at once: far quicker than the 2 s lease.
    let delay = detection_delay(&running, killed_at, failures[0]);
    assert!(delay < 1.0, "detected {delay:.3} s after the kill");
    let deployed = named(&all, "deployed");
    assert_eq!(strings(&deployed[1]["switched_on"]), ["astrid:l1"]);
    // Nothing left switched on: the laser this task switched on goes off at the end.
    let released = named(&all, "released");
    assert_eq!(strings(&released[0]["switched_off"]), ["astrid:l1"]);
    assert_eq!(
        all.last().map(|e| e["event"].clone()),
        Some("task_done".into())
    );
    drop(ecology);
}

#[test]
fn sigstop_is_detected_by_the_lease_and_sigcont_changes_nothing() {
    let _one = one_at_a_time();
    let fixture = Fixture::new("sigstop", true, 0.0, &[TO_BEDROOM]);
    let lease = 1.0;
    let ecology = Ecology::start(&fixture, &["--lease", "1"]);
    let mut task = ecology.task(&fixture, &[]);
    let running = task.wait_for("running", |l| is_event(l, "running"));
    ecology.hsm.signal(Signal::SIGSTOP);
    let stopped_at = Instant::now();
    let failure = task.wait_for("a failure", |l| is_event(l, "failure"));
    let delay = detection_delay(&running, stopped_at, &event(&failure.text));
    // Zenoh declares a silent link dead when the lease runs out (it checks a
    // few times a lease), never before; under load allow half a second more.
    assert!(
        (lease * 0.5..lease + 0.5).contains(&delay),
        "detected {delay:.3} s after SIGSTOP with a {lease} s lease"
    );
    ecology.hsm.signal(Signal::SIGCONT);
    let (code, lines) = task.finish();
    let all = events(&lines);
    assert_eq!(code, Some(0), "{all:#?}");
    // hsm comes back with its old tuples and stale images: no second reconfiguration.
    assert_eq!(costs(&all), [(80, false), (170, true)], "{all:#?}");
    assert_eq!(named(&all, "reconfiguration").len(), 1, "{all:#?}");
    assert!(
        named(&all, "failure")
            .iter()
            .all(|f| f["cause"] == "PEIS hsm left the ecology"),
        "{all:#?}"
    );
    drop(ecology);
}

#[test]
fn a_killed_peis_restarted_under_its_name_is_used_again() {
    let _one = one_at_a_time();
    let fixture = Fixture::new("restart", true, 0.0, &[TO_BEDROOM, TO_ENTRANCE]);
    let mut ecology = Ecology::start(&fixture, &[]);
    let mut task = ecology.task(&fixture, &[]);
    task.wait_for("running", |l| is_event(l, "running"));
    ecology.hsm.signal(Signal::SIGKILL);
    task.wait_for("the failure", |l| is_event(l, "failure"));
    // The same PEIS starts again: a new run, its tuples numbered from 1 again.
    let hsm = Proc::start("hsm", &as_strs(&ecology.hsm_args)).ready();
    ecology.hsm = hsm;
    let (code, lines) = task.finish();
    let all = events(&lines);
    assert_eq!(code, Some(0), "{all:#?}");
    // Move 1: cameras, then the laser; move 2: the restarted hsm's cameras again.
    assert_eq!(
        costs(&all),
        [(80, false), (170, true), (80, false)],
        "{all:#?}"
    );
    let last = named(&all, "configuration")[2];
    assert!(
        strings(&last["functionalities"])
            .contains(&"(tracking-system hsm tr1 astrid) on hsm:tr1".to_string()),
        "{last:#}"
    );
    drop(ecology);
}

#[test]
fn a_component_slower_to_start_than_the_deploy_timeout_is_excluded() {
    let _one = one_at_a_time();
    // tr1 is off and takes 20 s to start: cameras cost 20 + (20 + 10) + 40 = 90 < 170.
    let fixture = Fixture::new("slow", false, 20.0, &[TO_BEDROOM]);
    let ecology = Ecology::start(&fixture, &[]);
    let task = ecology.task(&fixture, &["--deploy-timeout", "1"]);
    let (code, lines) = task.finish();
    let all = events(&lines);
    assert_eq!(code, Some(0), "{all:#?}");
    assert_eq!(costs(&all), [(90, false), (170, true)], "{all:#?}");
    let failures = named(&all, "failure");
    assert_eq!(failures.len(), 1, "{all:#?}");
    assert_eq!(failures[0]["component"], "tr1");
    assert_eq!(
        failures[0]["cause"],
        "did not finish switching on within 1s"
    );
    // What it asked to switch on and no longer needs is switched off again.
    let running = named(&all, "running");
    assert!(
        running
            .iter()
            .any(|r| strings(&r["switched_off"]).contains(&"hsm:tr1".to_string())),
        "{all:#?}"
    );
    drop(ecology);
}

#[test]
fn peis_that_reach_each_other_only_through_a_router_configure_an_action() {
    let _one = one_at_a_time();
    let fixture = Fixture::new("router", true, 0.0, &[TO_BEDROOM]);
    let router_endpoint = free_endpoint();
    let _router = Proc::start("router", &["router", "--listen", &router_endpoint]).ready();
    // Clients of the router: every tuple, query and presence token passes through it.
    let through = ["--client", "--connect", router_endpoint.as_str()];
    let scenario = fixture.scenario();
    let mut args = vec!["world", scenario.as_str()];
    args.extend(through);
    let _world = Proc::start("world", &args).ready();
    let mut procs = Vec::new();
    for name in ["astrid", "hsm"] {
        let mut args = vec!["peis", scenario.as_str(), "--name", name];
        args.extend(through);
        procs.push(Proc::start(name, &args).ready());
    }
    let plan = fixture.plan();
    let mut args = vec![
        "task",
        "--domain",
        "domains/peis-home.eco",
        "--plan",
        plan.as_str(),
        "--json",
        "--wait-for",
        "world,astrid,hsm",
    ];
    args.extend(through);
    let (code, lines) = Proc::start("executive", &args).finish();
    let all = events(&lines);
    assert_eq!(code, Some(0), "{all:#?}");
    assert_eq!(costs(&all), [(80, false)], "{all:#?}");
    assert_eq!(
        all.last().map(|e| e["event"].clone()),
        Some("task_done".into())
    );
}

#[test]
fn a_peis_process_switches_its_components_off_and_leaves_on_sigterm() {
    let _one = one_at_a_time();
    let fixture = Fixture::new("sigterm", true, 0.0, &[TO_BEDROOM]);
    let ecology = Ecology::start(&fixture, &[]);
    let mut watch = Proc::start(
        "watch",
        &[
            "tuples",
            "--listen",
            &free_endpoint(),
            "--connect",
            &ecology.world_endpoint,
            "watch",
            "hsm:components.*.currState",
            "--json",
        ],
    );
    // The snapshot: both components on.
    for _ in 0..2 {
        watch.wait_for("currState on", |l| l.contains("\"value\":\"on\""));
    }
    ecology.hsm.signal(Signal::SIGTERM);
    let asked = Instant::now();
    let Ecology { hsm, .. } = ecology;
    let (code, lines) = hsm.finish();
    let took = asked.elapsed();
    assert_eq!(code, Some(0));
    assert!(took < Duration::from_secs(1), "took {took:?} to stop");
    assert!(
        lines.iter().any(|l| l
            .text
            .contains("components switched off, presence withdrawn")),
        "{lines:?}"
    );
    for _ in 0..2 {
        watch.wait_for("currState off", |l| l.contains("\"value\":\"off\""));
    }
}

#[test]
fn the_papers_experiment_as_separate_processes() {
    let _one = one_at_a_time();
    let (code, lines) = Proc::start("demo", &["demo", "--processes", "--json"]).finish();
    let all = events(&lines);
    assert_eq!(code, Some(0), "{all:#?}");
    // Section VIII: 80 to the entrance, 100 to grasp, 80 to the bedroom until
    // the tracking system fails, 170 with the laser switched on, 20 to wake.
    assert_eq!(
        costs(&all),
        [
            (80, false),
            (100, false),
            (80, false),
            (170, true),
            (20, false)
        ],
        "{all:#?}"
    );
    let failures = named(&all, "failure");
    assert_eq!(failures.len(), 1, "{all:#?}");
    assert_eq!(
        (
            failures[0]["peis"].as_str(),
            failures[0]["component"].as_str()
        ),
        (Some("hsm"), Some("tr1"))
    );
    let deployed = named(&all, "deployed");
    assert!(
        deployed
            .iter()
            .any(|d| strings(&d["switched_on"]) == ["astrid:l1"])
    );
    assert_eq!(
        all.last().map(|e| e["event"].clone()),
        Some("task_done".into())
    );
}

/// The Python to run the example with: `ECOLOGY_PYTHON` (set by `scripts/test`
/// to its virtual environment), else the repository's `.venv`, else `python3`.
fn python() -> String {
    if let Ok(python) = std::env::var("ECOLOGY_PYTHON") {
        return python;
    }
    let venv = root().join(".venv/bin/python");
    if venv.exists() {
        return venv.display().to_string();
    }
    "python3".to_string()
}

#[test]
fn a_component_written_in_python_is_switched_on_wired_and_run() {
    let python = python();
    match Command::new(&python).arg("--version").output() {
        Ok(out) if out.status.success() => {}
        _ => {
            println!("skipped: no Python at `{python}` to run examples/python/robot_counter.py");
            return;
        }
    }
    let has_zenoh = Command::new(&python)
        .args(["-c", "import zenoh"])
        .status()
        .is_ok_and(|s| s.success());
    assert!(
        has_zenoh,
        "{python} has no `zenoh` module: run scripts/test, which installs eclipse-zenoh into .venv"
    );
    let _one = one_at_a_time();
    let scenario = root()
        .join("scenarios/peis-home.toml")
        .display()
        .to_string();
    let world_endpoint = free_endpoint();
    let _world = Proc::start("world", &["world", &scenario, "--listen", &world_endpoint]).ready();
    let _hsm = Proc::start(
        "hsm",
        &[
            "peis",
            &scenario,
            "--name",
            "hsm",
            "--listen",
            &free_endpoint(),
            "--connect",
            &world_endpoint,
        ],
    )
    .ready();
    let counter_endpoint = free_endpoint();
    let mut counter = {
        let mut child = Command::new(&python)
            .arg(root().join("examples/python/robot_counter.py"))
            .args(["--listen", &counter_endpoint, "--connect", &world_endpoint])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("spawn the Python PEIS");
        let out = child.stdout.take().expect("piped stdout");
        let (tx, lines) = mpsc::channel();
        std::thread::spawn(move || {
            for line in std::io::BufReader::new(out).lines() {
                let Ok(text) = line else { return };
                let at = Instant::now();
                if tx.send(Line { text, at }).is_err() {
                    return;
                }
            }
        });
        Proc {
            name: "counter".to_string(),
            child,
            lines,
            seen: Vec::new(),
        }
    };
    counter.wait_for("ready", |l| l == "ready");
    let listen = free_endpoint();
    let task = Proc::start(
        "executive",
        &[
            "task",
            "--domain",
            "examples/python/robot-counter.eco",
            "--plan",
            "examples/python/robot-counter.plan",
            "--json",
            "--wait-for",
            "world,hsm,counter",
            "--listen",
            &listen,
            "--connect",
            &world_endpoint,
        ],
    );
    let (code, lines) = task.finish();
    let all = events(&lines);
    assert_eq!(code, Some(0), "{all:#?}");
    // Discovered (its init tuples priced it: start-up 5 + default 5), switched on, wired, done.
    assert_eq!(costs(&all), [(30, false)], "{all:#?}");
    let deployed = named(&all, "deployed");
    assert_eq!(strings(&deployed[0]["switched_on"]), ["counter:c1"]);
    assert_eq!(
        strings(&deployed[0]["channels"]),
        ["hsm:ca1 → counter:c1 (image hsm)"]
    );
    assert_eq!(named(&all, "action_done").len(), 1, "{all:#?}");
    // The counter this task switched on is switched off again.
    let released = named(&all, "released");
    assert_eq!(strings(&released[0]["switched_off"]), ["counter:c1"]);
    // Stopped by SIGTERM, the Python PEIS exits cleanly.
    counter.signal(Signal::SIGTERM);
    let (code, _) = counter.finish();
    assert_eq!(code, Some(0));
}
