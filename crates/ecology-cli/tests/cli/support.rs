//! What the tests and the fault benchmark share to run the ecology as
//! processes: a guard for an `ecology` process that reads its output line by
//! line, a small PEIS-Home scenario, and an ecology of world, astrid and hsm.

#![allow(dead_code, unreachable_pub)]

use std::io::BufRead;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use serde_json::Value;

/// What a scenario fixture changes in the PEIS-Home.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Variant {
    /// As in the paper: the laser off (0.3 s to start), the tracking system on.
    Paper,
    /// The tracking system off, taking this many seconds to switch on.
    SlowTracking(f64),
    /// The laser already on, so a reconfiguration to it starts nothing.
    LaserOn,
}

/// Whether the processes' stderr is dropped instead of shown (the benchmark sets it).
pub static QUIET: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Bounds every wait of these tests.
pub const PATIENCE: Duration = Duration::from_secs(60);

pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

pub fn free_endpoint() -> String {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("bind 127.0.0.1:0");
    format!(
        "tcp/127.0.0.1:{}",
        listener.local_addr().expect("address").port()
    )
}

/// A QUIC endpoint on a UDP port free now: a port free for TCP may be a QUIC listener's already
/// (the probe of one test handed out the port another test's PEIS listened on over UDP).
pub fn free_quic_endpoint() -> String {
    let socket = std::net::UdpSocket::bind("127.0.0.1:0").expect("bind 127.0.0.1:0");
    format!(
        "quic/127.0.0.1:{}",
        socket.local_addr().expect("address").port()
    )
}

/// A line a process printed, and when it was read.
#[derive(Debug, Clone)]
pub struct Line {
    pub text: String,
    pub at: Instant,
}

/// An `ecology` process, killed when dropped; its stdout read line by line.
pub struct Proc {
    pub name: String,
    pub child: Child,
    pub lines: mpsc::Receiver<Line>,
    pub seen: Vec<Line>,
    /// Held open until the process is dropped (`ecology tuples set --hold` waits for its end).
    _stdin: Option<std::process::ChildStdin>,
}

impl Proc {
    /// `ecology ARGS…`, from the repository's root.
    pub fn start(name: &str, args: &[&str]) -> Proc {
        let mut command = Command::new(env!("CARGO_BIN_EXE_ecology"));
        command.args(args);
        Proc::spawn(name, command)
    }

    /// `ecology ARGS…` as [`Proc::start`], its stderr read with its stdout (for warnings and
    /// errors a test checks).
    pub fn start_with_stderr(name: &str, args: &[&str]) -> Proc {
        let mut command = Command::new("sh");
        command
            .args([
                "-c",
                r#"exec "$0" "$@" 2>&1"#,
                env!("CARGO_BIN_EXE_ecology"),
            ])
            .args(args);
        Proc::spawn(name, command)
    }

    /// Any `command`, from the repository's root, its stdout read line by line. Its stderr goes to
    /// `NAME.log` in the folder `ECOLOGY_TEST_STDERR` names, when set (with `RUST_LOG=zenoh=debug`,
    /// each process's Zenoh log apart), else to the test's own.
    pub fn spawn(name: &str, mut command: Command) -> Proc {
        let mut child = command
            .current_dir(root())
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(match std::env::var_os("ECOLOGY_TEST_STDERR") {
                Some(dir) => Stdio::from(
                    std::fs::File::create(std::path::Path::new(&dir).join(format!("{name}.log")))
                        .expect("a log file"),
                ),
                None if QUIET.load(std::sync::atomic::Ordering::Relaxed) => Stdio::null(),
                None => Stdio::inherit(),
            })
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {name}: {e}"));
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
            _stdin: child.stdin.take(),
            child,
            lines,
            seen: Vec::new(),
        }
    }

    /// Writes `text` and a newline to the process's standard input.
    pub fn say(&mut self, text: &str) {
        use std::io::Write;
        let stdin = self._stdin.as_mut().expect("piped stdin");
        writeln!(stdin, "{text}").expect("write to the process");
    }

    pub fn pid(&self) -> Pid {
        Pid::from_raw(i32::try_from(self.child.id()).expect("pid fits"))
    }

    pub fn signal(&self, signal: Signal) {
        kill(self.pid(), signal).expect("signal the process");
    }

    /// Reads lines until one satisfies `want`; returns it.
    pub fn wait_for(&mut self, what: &str, want: impl Fn(&str) -> bool) -> Line {
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

    pub fn ready(mut self) -> Proc {
        let name = self.name.clone();
        self.wait_for("its ready line", |l| {
            l.starts_with(&format!("{name} ready"))
        });
        self
    }

    /// Waits for the process to exit; returns its exit code and every line it printed.
    pub fn finish(self) -> (Option<i32>, Vec<Line>) {
        self.finish_by(Instant::now() + PATIENCE)
    }

    /// [`Proc::finish`], failing the test if the process still runs at `deadline`.
    pub fn finish_by(mut self, deadline: Instant) -> (Option<i32>, Vec<Line>) {
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

    pub fn transcript(&self) -> String {
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
pub struct Fixture {
    pub folder: PathBuf,
}

impl Fixture {
    /// Astrid in the entrance facing the bedroom door, hsm with its cameras, and `plan`.
    pub fn new(test: &str, plan: &[(&str, &str)], variant: Variant) -> Fixture {
        let (laser_on, tr1_on, tr1_startup) = match variant {
            Variant::Paper => (false, true, 0.0),
            Variant::SlowTracking(startup) => (false, false, startup),
            Variant::LaserOn => (true, true, 0.0),
        };
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
  {{ id = "l1",  type = "laser",    cost = 100, on = {laser_on}, startup = 0.3 }},
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

    /// `scenarios/two-robots.toml`: Astrid in the entrance and Bob in the living room, each with
    /// a laser (off), odometry, a thinking cap and self-localisation; hsm with one ceiling camera
    /// and one tracking system.
    /// Astrid's plan (`plan`) moves her to the bedroom, Bob's (`plan_of("bob")`) him to the
    /// kitchen.
    pub fn two_robots(test: &str) -> Fixture {
        Fixture::two_robots_with(test, "")
    }

    /// [`Fixture::two_robots`], with `hsm_more` added to hsm's components (such as a second
    /// tracking system).
    pub fn two_robots_with(test: &str, hsm_more: &str) -> Fixture {
        let folder = std::env::temp_dir().join(format!("ecology-{test}-{}", std::process::id()));
        std::fs::create_dir_all(&folder).expect("temp folder");
        let shipped = std::fs::read_to_string(root().join("scenarios/two-robots.toml"))
            .expect("scenarios/two-robots.toml");
        // Its paths are relative to the scenario's folder, which this copy is not in.
        let domains = format!("{}/", root().join("domains").display());
        let scenario = shipped
            .replace("../domains/", &domains)
            .replace("  { id = \"tr1\"", &format!("{hsm_more}  {{ id = \"tr1\""));
        std::fs::write(folder.join("scenario.toml"), scenario).expect("write scenario");
        for (file, (action, goal)) in [("plan.txt", TO_BEDROOM), ("bob.txt", BOB_TO_KITCHEN)] {
            std::fs::write(folder.join(file), format!("{action}  ; configure {goal}\n"))
                .expect("write plan");
        }
        Fixture { folder }
    }

    pub fn scenario(&self) -> String {
        self.folder.join("scenario.toml").display().to_string()
    }

    /// The plan file of `robot`'s own task (a fixture with several).
    pub fn plan_of(&self, robot: &str) -> String {
        self.folder
            .join(format!("{robot}.txt"))
            .display()
            .to_string()
    }

    pub fn plan(&self) -> String {
        self.folder.join("plan.txt").display().to_string()
    }
}

impl Drop for Fixture {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.folder);
    }
}

pub const TO_BEDROOM: (&str, &str) = (
    "(move astrid entrance bedroom)",
    "(navigate astrid bedroom)",
);
pub const BOB_TO_KITCHEN: (&str, &str) =
    ("(move bob living-room kitchen)", "(navigate bob kitchen)");

pub const TO_ENTRANCE: (&str, &str) = (
    "(move astrid bedroom entrance)",
    "(navigate astrid entrance)",
);

/// A running ecology: the world, astrid and hsm, each a process.
pub struct Ecology {
    pub world_endpoint: String,
    /// The keys directory every process joins with, if any (then endpoints are TLS).
    pub keys: Option<String>,
    pub world: Proc,
    /// Where astrid listens.
    pub astrid_endpoint: String,
    _astrid: Proc,
    pub hsm: Proc,
    pub hsm_args: Vec<String>,
    /// More PEIS processes (Bob's, [`Ecology::start_with_bob`]).
    others: Vec<Proc>,
}

impl Ecology {
    pub fn start(fixture: &Fixture, hsm_extra: &[&str]) -> Ecology {
        Ecology::start_with(fixture, hsm_extra, None)
    }

    /// As [`Ecology::start`], every process with `--keys keys` on QUIC endpoints when given.
    pub fn start_with(fixture: &Fixture, hsm_extra: &[&str], keys: Option<&str>) -> Ecology {
        let scenario = fixture.scenario();
        let endpoint = || match keys {
            Some(_) => free_quic_endpoint(),
            None => free_endpoint(),
        };
        let secured: Vec<&str> = keys.map_or(vec![], |k| vec!["--keys", k]);
        let world_endpoint = endpoint();
        let mut world_args = vec!["world", &scenario, "--listen", &world_endpoint];
        world_args.extend(&secured);
        let world = Proc::start("world", &world_args).ready();
        let peis = |name: &str, extra: &[&str]| -> Vec<String> {
            let mut args: Vec<String> = [
                "peis",
                scenario.as_str(),
                "--name",
                name,
                "--listen",
                &endpoint(),
                "--connect",
                &world_endpoint,
            ]
            .iter()
            .map(ToString::to_string)
            .collect();
            args.extend(secured.iter().chain(extra).map(ToString::to_string));
            args
        };
        let astrid_args = peis("astrid", &[]);
        let hsm_args = peis("hsm", hsm_extra);
        let astrid = Proc::start("astrid", &as_strs(&astrid_args)).ready();
        let astrid_endpoint = astrid_args[5].clone();
        let hsm = Proc::start("hsm", &as_strs(&hsm_args)).ready();
        Ecology {
            world_endpoint,
            keys: keys.map(ToString::to_string),
            world,
            astrid_endpoint,
            _astrid: astrid,
            hsm,
            hsm_args,
            others: Vec::new(),
        }
    }

    /// As [`Ecology::start`] for [`Fixture::two_robots`]: Bob a process too.
    pub fn start_with_bob(fixture: &Fixture) -> Ecology {
        let mut ecology = Ecology::start(fixture, &[]);
        let scenario = fixture.scenario();
        let listen = free_endpoint();
        let bob = Proc::start(
            "bob",
            &[
                "peis",
                &scenario,
                "--name",
                "bob",
                "--listen",
                &listen,
                "--connect",
                &ecology.world_endpoint,
            ],
        )
        .ready();
        ecology.others.push(bob);
        ecology
    }

    /// The executive `name` on `plan`, printing JSON lines, once the world, Astrid, Bob and hsm
    /// are present.
    pub fn task_as(&self, name: &str, plan: &str) -> Proc {
        let listen = free_endpoint();
        Proc::start(
            name,
            &[
                "task",
                "--name",
                name,
                "--domain",
                "domains/peis-home.eco",
                "--plan",
                plan,
                "--json",
                "--wait-for",
                "world,astrid,bob,hsm",
                "--listen",
                &listen,
                "--connect",
                &self.world_endpoint,
            ],
        )
    }

    /// The tuples of `owner` as they stand, by key, read by `ecology tuples watch`.
    pub fn read(&self, owner: &str) -> std::collections::BTreeMap<String, String> {
        read_tuples(&self.world_endpoint, owner)
            .into_iter()
            .filter_map(|(key, v)| Some((key, v["value"].as_str()?.to_string())))
            .collect()
    }

    /// The executive on `plan`, printing JSON lines.
    pub fn task(&self, fixture: &Fixture, extra: &[&str]) -> Proc {
        task_on(&self.world_endpoint, self.keys.as_deref(), fixture, extra)
    }
}

/// The tuples of `owner` as they stand, by key, as `ecology tuples watch --json` prints them
/// (`value`, `set_by`, …), read through a PEIS connected to `endpoint`.
pub fn read_tuples(endpoint: &str, owner: &str) -> std::collections::BTreeMap<String, Value> {
    let watch = watch_tuples(endpoint, "reader", &format!("{owner}:**"));
    let mut seen = std::collections::BTreeMap::new();
    while let Ok(line) = watch.lines.recv_timeout(Duration::from_millis(1500)) {
        let v = event(&line.text);
        if let (Some(key), Some(_)) = (v["key"].as_str(), v["value"].as_str()) {
            seen.insert(key.to_string(), v.clone());
        }
    }
    watch.signal(Signal::SIGINT);
    seen
}

/// `ecology tuples watch PATTERN --json` as PEIS `name`, connected to `endpoint`: one JSON line
/// per change.
pub fn watch_tuples(endpoint: &str, name: &str, pattern: &str) -> Proc {
    let listen = free_endpoint();
    Proc::start(
        name,
        &[
            "tuples",
            "--listen",
            &listen,
            "--connect",
            endpoint,
            "--name",
            name,
            "watch",
            pattern,
            "--json",
        ],
    )
}

/// The executive on `fixture`'s plan, connected to the world at `world_endpoint`, printing JSON
/// lines; with `--keys keys` on a QUIC endpoint when given.
pub fn task_on(
    world_endpoint: &str,
    keys: Option<&str>,
    fixture: &Fixture,
    extra: &[&str],
) -> Proc {
    let mut args = vec!["task", "--domain", "domains/peis-home.eco", "--plan"];
    let plan = fixture.plan();
    args.push(&plan);
    let listen = match keys {
        Some(_) => free_quic_endpoint(),
        None => free_endpoint(),
    };
    if let Some(keys) = keys {
        args.extend(["--keys", keys]);
    }
    args.extend([
        "--json",
        "--wait-for",
        "world,astrid,hsm",
        "--listen",
        &listen,
        "--connect",
        world_endpoint,
    ]);
    args.extend_from_slice(extra);
    Proc::start("executive", &args)
}

pub fn as_strs(args: &[String]) -> Vec<&str> {
    args.iter().map(String::as_str).collect()
}

pub fn event(line: &str) -> Value {
    serde_json::from_str(line).unwrap_or_else(|e| panic!("not a JSON line ({e}): {line}"))
}

pub fn is_event(line: &str, name: &str) -> bool {
    serde_json::from_str::<Value>(line).is_ok_and(|v| v["event"] == name)
}
