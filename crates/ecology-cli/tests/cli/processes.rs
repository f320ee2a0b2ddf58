//! The ecology as separate processes on 127.0.0.1: `ecology world`, `ecology
//! peis` and `ecology task` over Zenoh, with real faults (SIGKILL, SIGSTOP and
//! SIGCONT, restarts, slow start-up) and a router.
//!
//! Each test writes a small PEIS-Home scenario in which Astrid stands in the
//! entrance, two metres from the bedroom, so a move takes a few seconds. At
//! most two such tests run at once ([`process_slot`] hands out the slots):
//! most of a test's time is waiting on real time (a move, a lease, a cable
//! cut for seconds), and each uses ports, namespaces and addresses of its own.

use std::process::Command;
use std::sync::{Condvar, Mutex};
use std::time::{Duration, Instant};

use nix::sys::signal::Signal;
use serde_json::Value;

use crate::support::{
    Ecology, Fixture, Line, Proc, TO_BEDROOM, TO_ENTRANCE, Variant, as_strs, event, free_endpoint,
    free_quic_endpoint, is_event, read_tuples, root, task_on, watch_tuples,
};

/// How many tests that start an ecology of processes run at once: `ECOLOGY_PROCESS_TESTS`, 2 by
/// default (1 runs them one at a time, as before).
fn process_slots() -> usize {
    std::env::var("ECOLOGY_PROCESS_TESTS")
        .ok()
        .and_then(|n| n.parse().ok())
        .filter(|&n| n > 0)
        .unwrap_or(2)
}

/// The slots taken, and a wake-up for a test waiting for one.
static TAKEN: (Mutex<usize>, Condvar) = (Mutex::new(0), Condvar::new());

/// A test's slots among those that start an ecology of processes; given back when dropped.
pub(crate) struct Slot(usize);

impl Drop for Slot {
    fn drop(&mut self) {
        let (taken, freed) = &TAKEN;
        *taken
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) -= self.0;
        freed.notify_all();
    }
}

/// Waits for `wanted` free slots, and takes them.
fn take_slots(wanted: usize) -> Slot {
    let (taken, freed) = &TAKEN;
    let mut now = taken
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    while *now + wanted > process_slots().max(wanted) {
        now = freed
            .wait(now)
            .unwrap_or_else(std::sync::PoisonError::into_inner);
    }
    *now += wanted;
    Slot(wanted)
}

/// Waits for a slot to start an ecology of processes (see the module's note).
pub(crate) fn process_slot() -> Slot {
    take_slots(1)
}

/// Waits until no other test runs an ecology of processes, and keeps them all out until dropped:
/// for the ROS 2 tests, two of which at once failed (DDS discovery and lifecycle calls on a loaded
/// machine, though each runs on a ROS domain of its own).
pub(crate) fn process_slot_alone() -> Slot {
    take_slots(process_slots())
}

pub(crate) fn events(lines: &[Line]) -> Events {
    Events(lines.iter().map(|l| event(&l.text)).collect())
}

/// A run's events, shown one short line each when an assertion fails: a failure's message then
/// fits in the tail of a long log, where a pretty-printed dump of every event pushed it out.
pub(crate) struct Events(pub(crate) Vec<Value>);

impl std::ops::Deref for Events {
    type Target = Vec<Value>;

    fn deref(&self) -> &Vec<Value> {
        &self.0
    }
}

impl std::fmt::Debug for Events {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        /// Longer lines are cut: an event that carries a whole state says enough in its start.
        const WIDTH: usize = 200;
        writeln!(f, "{} events:", self.0.len())?;
        for event in &self.0 {
            let line = event.to_string();
            match line.char_indices().nth(WIDTH) {
                Some((cut, _)) => writeln!(f, "  {} …", &line[..cut])?,
                None => writeln!(f, "  {line}")?,
            }
        }
        Ok(())
    }
}

pub(crate) fn named<'a>(events: &'a [Value], name: &str) -> Vec<&'a Value> {
    events.iter().filter(|e| e["event"] == name).collect()
}

pub(crate) fn costs(events: &[Value]) -> Vec<(u64, bool)> {
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

pub(crate) fn strings(value: &Value) -> Vec<String> {
    value
        .as_array()
        .map(|a| {
            a.iter()
                .filter_map(|s| s.as_str().map(str::to_string))
                .collect()
        })
        .unwrap_or_default()
}

/// How long after `fault_at` the executive logged `seen`, on the
/// executive's clock: its `running` line was read at `running.at`, so the
/// fault happened at t(running) + (fault_at - running.at).
fn detection_delay(running: &Line, fault_at: Instant, seen: &Value) -> f64 {
    let t_running = event(&running.text)["t"].as_f64().expect("t");
    let t_fault = t_running + fault_at.duration_since(running.at).as_secs_f64();
    seen["t"].as_f64().expect("t") - t_fault
}

#[test]
fn sigkill_of_the_camera_peis_reconfigures_astrid_to_her_laser() {
    let _slot = process_slot();
    let fixture = Fixture::new("sigkill", &[TO_BEDROOM], Variant::Paper);
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
    let _slot = process_slot();
    let fixture = Fixture::new("sigstop", &[TO_BEDROOM], Variant::Paper);
    let lease = 1.0;
    let ecology = Ecology::start(&fixture, &["--lease", "1"]);
    let mut task = ecology.task(&fixture, &[]);
    let running = task.wait_for("running", |l| is_event(l, "running"));
    ecology.hsm.signal(Signal::SIGSTOP);
    let stopped_at = Instant::now();
    let left = task.wait_for("a departure", |l| is_event(l, "peis_left"));
    let delay = detection_delay(&running, stopped_at, &event(&left.text));
    // Zenoh declares a silent link dead when the lease runs out (it checks a
    // few times a lease), never before; under load allow half a second more.
    assert!(
        (lease * 0.5..lease + 0.5).contains(&delay),
        "detected {delay:.3} s after SIGSTOP with a {lease} s lease"
    );
    // Once the executive has reconfigured around it, hsm wakes up.
    task.wait_for("the failure", |l| is_event(l, "failure"));
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
    // It came back in the same run with the old configuration's params, which the executive
    // takes back at once: the camera and the tracker stop.
    let reclaimed = named(&all, "reclaimed");
    assert_eq!(reclaimed.len(), 1, "{all:#?}");
    assert_eq!(reclaimed[0]["peis"], "hsm");
    assert_eq!(strings(&reclaimed[0]["stopped"]), ["hsm:ca1", "hsm:tr1"]);
    drop(ecology);
}

#[test]
fn a_killed_peis_restarted_under_its_name_is_used_again() {
    let _slot = process_slot();
    let fixture = Fixture::new("restart", &[TO_BEDROOM, TO_ENTRANCE], Variant::Paper);
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
    let _slot = process_slot();
    // tr1 is off and takes 20 s to start: cameras cost 20 + (20 + 10) + 40 = 90 < 170.
    let fixture = Fixture::new("slow", &[TO_BEDROOM], Variant::SlowTracking(20.0));
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

/// A tracking system that writes `global-pos` as `x,y;theta` (its `garble` fault): Astrid's pose
/// tracking reports it cannot read that input, the executive excludes the tracking system, not the
/// pose tracking, and the move is done on the laser with the same s1 running scan matching.
#[test]
fn a_producer_of_unreadable_values_is_excluded_and_its_consumer_is_not() {
    let _slot = process_slot();
    let fixture = Fixture::new("garble", &[TO_BEDROOM], Variant::Paper);
    let mut ecology = Ecology::start(&fixture, &[]);
    let (code, _) = Proc::start(
        "fault",
        &[
            "tuples",
            "--connect",
            &ecology.world_endpoint,
            "set",
            "hsm",
            "tr1.fault",
            "garble",
        ],
    )
    .finish();
    assert_eq!(code, Some(0));
    ecology.hsm.wait_for("the garble fault", |l| {
        l.contains("tr1 garbles its outputs")
    });
    let (code, lines) = ecology.task(&fixture, &[]).finish();
    let all = events(&lines);
    assert_eq!(code, Some(0), "{all:#?}");
    assert_eq!(costs(&all), [(80, false), (170, true)], "{all:#?}");
    let failures = named(&all, "failure");
    assert_eq!(failures.len(), 1, "{all:#?}");
    assert_eq!(
        (&failures[0]["peis"], &failures[0]["component"]),
        (&"hsm".into(), &"tr1".into())
    );
    let cause = failures[0]["cause"].as_str().expect("cause");
    assert!(
        cause.starts_with("astrid:s1 cannot read its global-pos: expected X Y THETA"),
        "{cause}"
    );
    let last = named(&all, "configuration").last().copied().cloned();
    assert!(
        last.as_ref().is_some_and(|c| strings(&c["functionalities"])
            .contains(&"(scan-matching astrid s1) on astrid:s1".to_string())),
        "{last:#?}"
    );
    assert_eq!(
        all.last().map(|e| e["event"].clone()),
        Some("task_done".into())
    );
}

/// A second `ecology peis --name hsm` that joins through astrid, one hop from hsm, is refused with
/// the reason, every time: it waits for the links gossip opens before it checks its name, then its
/// lease plus 1 s for hsm to leave, which a live hsm does not.
#[test]
fn a_name_present_one_hop_away_is_refused() {
    let _slot = process_slot();
    let fixture = Fixture::new("twin", &[TO_BEDROOM], Variant::Paper);
    let ecology = Ecology::start(&fixture, &[]);
    let scenario = fixture.scenario();
    for round in 0..3 {
        let listen = free_endpoint();
        // Its stderr read too. A short lease: it waits that long, plus 1 s, for hsm to leave.
        let (code, lines) = Proc::start_with_stderr(
            "twin",
            &[
                "peis",
                &scenario,
                "--name",
                "hsm",
                "--listen",
                &listen,
                "--connect",
                &ecology.astrid_endpoint,
                "--lease",
                "0.5",
            ],
        )
        .finish();
        assert_eq!(code, Some(2), "round {round}: {lines:?}");
        let said: Vec<&str> = lines.iter().map(|l| l.text.as_str()).collect();
        assert!(
            said.iter()
                .any(|l| l.starts_with("a PEIS named hsm is present: waiting up to 1.5s"))
                && said.contains(&"error: a PEIS named hsm is already present in the ecology"),
            "round {round}: {said:?}"
        );
    }
    // The first hsm is untouched.
    assert!(ecology.hsm.pid().as_raw() > 0);
    let (code, lines) = Proc::start(
        "peers",
        &["tuples", "--connect", &ecology.astrid_endpoint, "peers"],
    )
    .finish();
    assert_eq!(code, Some(0));
    let names: Vec<&str> = lines.iter().map(|l| l.text.as_str()).collect();
    assert!(names.contains(&"hsm"), "{names:?}");
}

/// The world process killed mid-move: the components that read its ground truth report `error`
/// within a second of its silence, and the task ends with the reason instead of waiting for the
/// action's timeout.
#[test]
fn the_world_gone_mid_move_fails_its_readers_within_seconds() {
    let _slot = process_slot();
    let fixture = Fixture::new("world-gone", &[TO_BEDROOM], Variant::Paper);
    let ecology = Ecology::start(&fixture, &[]);
    let mut task = ecology.task(&fixture, &[]);
    task.wait_for("running", |l| is_event(l, "running"));
    ecology.world.signal(Signal::SIGKILL);
    let killed_at = Instant::now();
    let (code, lines) = task.finish();
    let ended = killed_at.elapsed();
    println!("the task ended {ended:?} after the world was killed");
    let all = events(&lines);
    assert_eq!(code, Some(1), "{all:#?}");
    let failures = named(&all, "failure");
    assert!(
        failures.iter().any(|f| f["cause"]
            .as_str()
            .is_some_and(|c| c.starts_with("no ground truth from the world PEIS for 1 s"))),
        "{all:#?}"
    );
    assert!(
        ended < Duration::from_secs(15),
        "the task ended {ended:?} after the world was killed"
    );
    assert_eq!(
        all.last().map(|e| e["event"].clone()),
        Some("task_failed".into()),
        "{all:#?}"
    );
}

#[test]
fn peis_that_reach_each_other_only_through_a_router_configure_an_action() {
    through_a_router(false);
}

/// The same over mutual TLS: the router is a member with the router role, and its clients accept
/// what it forwards.
#[test]
fn a_secured_router_forwards_for_its_members() {
    through_a_router(true);
}

/// A router holds `--max-sessions` sessions: once full it says so, and refuses the next PEIS.
#[test]
fn a_full_router_says_so_and_refuses_the_next_peis() {
    let _slot = process_slot();
    let fixture = Fixture::new("full-router", &[TO_BEDROOM], Variant::Paper);
    let endpoint = free_endpoint();
    // Its stderr, where the warning goes, read too.
    let mut router = Proc::start_with_stderr(
        "router",
        &["router", "--listen", &endpoint, "--max-sessions", "2"],
    )
    .ready();
    let through = ["--client", "--connect", endpoint.as_str()];
    let scenario = fixture.scenario();
    let _world = Proc::start(
        "world",
        &[&["world", scenario.as_str()][..], &through].concat(),
    )
    .ready();
    let _astrid = Proc::start(
        "astrid",
        &[
            &["peis", scenario.as_str(), "--name", "astrid"][..],
            &through,
        ]
        .concat(),
    )
    .ready();
    router.wait_for("that it is full", |l| {
        l.starts_with("warning: the router holds 2 sessions, the most it takes (--max-sessions)")
    });
    // Its stderr, where the error goes, read too.
    let (code, lines) = Proc::start_with_stderr(
        "hsm",
        &[
            &["peis", scenario.as_str(), "--name", "hsm"][..],
            &through,
            &["--connect-timeout", "5"],
        ]
        .concat(),
    )
    .finish();
    assert_ne!(code, Some(0), "a third session is refused");
    assert!(
        lines.iter().any(|l| l.text.contains(&format!(
            "nothing at {endpoint} took this session within 5s (--connect-timeout): is it up, \
             and if it is a router, not full at its --max-sessions?"
        ))),
        "{lines:?}"
    );
}

/// A PEIS started before the router it connects to, as after a power cut: it keeps trying (30 s
/// by default, `--connect-timeout`), says after 5 s that it is still joining, and joins once the
/// router is up.
#[test]
fn a_peis_started_before_its_router_joins_once_the_router_is_up() {
    let _slot = process_slot();
    let fixture = Fixture::new("router-later", &[TO_BEDROOM], Variant::Paper);
    let endpoint = free_endpoint();
    let scenario = fixture.scenario();
    let mut astrid = Proc::start_with_stderr(
        "astrid",
        &[
            "peis",
            &scenario,
            "--name",
            "astrid",
            "--client",
            "--connect",
            &endpoint,
        ],
    );
    astrid.wait_for("that it is still joining", |l| {
        l.starts_with(&format!(
            "still joining: nothing at {endpoint} has taken the session for 5s; trying for 30s in \
             all (--connect-timeout)"
        ))
    });
    let _router = Proc::start("router", &["router", "--listen", &endpoint]).ready();
    let _astrid = astrid.ready();
    let (code, lines) = Proc::start(
        "peers",
        &["tuples", "--client", "--connect", &endpoint, "peers"],
    )
    .finish();
    assert_eq!(code, Some(0), "{lines:?}");
    assert!(lines.iter().any(|l| l.text == "astrid"), "{lines:?}");
}

/// The processes that run an ecology keep their memory in small pages: transparent huge pages
/// made a home of 1,000 PEIS hold a third more memory, and stalled the first plan.
#[test]
fn a_router_and_a_peis_run_without_transparent_huge_pages() {
    let _slot = process_slot();
    let fixture = Fixture::new("small-pages", &[TO_BEDROOM], Variant::Paper);
    let endpoint = free_endpoint();
    let router = Proc::start("router", &["router", "--listen", &endpoint]).ready();
    let scenario = fixture.scenario();
    let astrid = Proc::start(
        "astrid",
        &[
            "peis",
            scenario.as_str(),
            "--name",
            "astrid",
            "--client",
            "--connect",
            endpoint.as_str(),
        ],
    )
    .ready();
    let thp = |proc: &Proc| {
        let status = std::fs::read_to_string(format!("/proc/{}/status", proc.pid()))
            .expect("reads the process's status");
        status
            .lines()
            .find_map(|l| l.strip_prefix("THP_enabled:"))
            .map(|v| v.trim().to_string())
    };
    let Some(router_thp) = thp(&router) else {
        eprintln!("skipped: this kernel does not report THP_enabled in /proc/PID/status");
        return;
    };
    assert_eq!(router_thp, "0", "the router's huge pages are off");
    assert_eq!(
        thp(&astrid).as_deref(),
        Some("0"),
        "the PEIS's huge pages are off"
    );
}

/// `ecology task` on `domain` and `plan` as JSON lines, once the PEIS `wait_for` are present,
/// with `through` (how it reaches the ecology).
fn task_args<'a>(
    domain: &'a str,
    plan: &'a str,
    wait_for: &'a str,
    through: &[&'a str],
) -> Vec<&'a str> {
    let mut args = vec![
        "task",
        "--domain",
        domain,
        "--plan",
        plan,
        "--json",
        "--wait-for",
        wait_for,
    ];
    args.extend(through);
    args
}

/// [`task_args`] for the PEIS-Home's move.
fn home_task_args<'a>(plan: &'a str, through: &[&'a str]) -> Vec<&'a str> {
    task_args("domains/peis-home.eco", plan, "world,astrid,hsm", through)
}

fn through_a_router(secured: bool) {
    let _slot = process_slot();
    let fixture = Fixture::new("router", &[TO_BEDROOM], Variant::Paper);
    let keys = fixture.folder.join("keys").display().to_string();
    let mut secure: Vec<&str> = Vec::new();
    let mut router_endpoint = free_endpoint();
    if secured {
        make_keys(&keys, &["world", "astrid", "hsm"], &["router"]);
        secure = vec!["--keys", &keys];
        router_endpoint = free_quic_endpoint();
    }
    let mut args = vec!["router", "--listen", &router_endpoint];
    args.extend(&secure);
    let _router = Proc::start("router", &args).ready();
    // Clients of the router: every tuple, query and presence token passes through it.
    let mut through = vec!["--client", "--connect", router_endpoint.as_str()];
    through.extend(&secure);
    let scenario = fixture.scenario();
    let mut args = vec!["world", scenario.as_str()];
    args.extend(&through);
    let _world = Proc::start("world", &args).ready();
    let mut procs = Vec::new();
    for name in ["astrid", "hsm"] {
        let mut args = vec!["peis", scenario.as_str(), "--name", name];
        args.extend(&through);
        procs.push(Proc::start(name, &args).ready());
    }
    let plan = fixture.plan();
    let (code, lines) = Proc::start("executive", &home_task_args(&plan, &through)).finish();
    let all = events(&lines);
    assert_eq!(code, Some(0), "{all:#?}");
    assert_eq!(costs(&all), [(80, false)], "{all:#?}");
    assert_eq!(
        all.last().map(|e| e["event"].clone()),
        Some("task_done".into())
    );
}

/// A secured router (QUIC, keys for world, astrid, hsm and the executive) and the world, its
/// client; both stopped when dropped.
struct SecuredRouter {
    keys: String,
    endpoint: String,
    _router: Proc,
    _world: Proc,
}

impl SecuredRouter {
    fn start(fixture: &Fixture) -> SecuredRouter {
        let keys = fixture.folder.join("keys").display().to_string();
        make_keys(&keys, &["world", "astrid", "hsm"], &["router"]);
        let endpoint = free_quic_endpoint();
        let router = Proc::start(
            "router",
            &["router", "--listen", &endpoint, "--keys", &keys],
        )
        .ready();
        let through = ["--client", "--connect", &endpoint, "--keys", &keys];
        let scenario = fixture.scenario();
        let world = Proc::start(
            "world",
            &[&["world", scenario.as_str()][..], &through].concat(),
        )
        .ready();
        SecuredRouter {
            keys,
            endpoint,
            _router: router,
            _world: world,
        }
    }

    /// The arguments that make a process a client of the router, with its keys.
    fn through(&self) -> [&str; 5] {
        [
            "--client",
            "--connect",
            &self.endpoint,
            "--keys",
            &self.keys,
        ]
    }
}

/// An executive killed outright mid-move, on a secured router, and started again at once, as a
/// supervisor restarts a crashed process: over QUIC the router keeps the killed run's session, and
/// its name, until its lease runs out. The new run says it waits for that, joins once the name is
/// free, and does the task on the cameras (80). It used to exit 2 at once: "a PEIS named executive
/// is already present".
#[test]
fn an_executive_killed_and_started_again_at_once_waits_for_its_name_and_does_the_task() {
    let _slot = process_slot();
    let fixture = Fixture::new("restarted", &[TO_BEDROOM], Variant::Paper);
    let secured = SecuredRouter::start(&fixture);
    let through = secured.through();
    let scenario = fixture.scenario();
    let _hosts = ["astrid", "hsm"].map(|name| {
        Proc::start(
            name,
            &[&["peis", scenario.as_str(), "--name", name][..], &through].concat(),
        )
        .ready()
    });
    let plan = fixture.plan();
    let args = home_task_args(&plan, &through);
    let mut first = Proc::start("executive", &args);
    first.wait_for("running", |l| is_event(l, "running"));
    first.signal(Signal::SIGKILL);
    // Its stderr, where the notice goes, read too.
    let (code, lines) = Proc::start_with_stderr("executive-again", &args).finish();
    let (json, said): (Vec<Line>, Vec<Line>) =
        lines.into_iter().partition(|l| l.text.starts_with('{'));
    let all = events(&json);
    assert_eq!(code, Some(0), "{said:?} {all:#?}");
    assert!(
        said.iter().any(|l| l.text
            == "a PEIS named executive is present: waiting up to 3s for it to leave (a run of it \
                that just stopped stays present until its lease runs out)"),
        "{said:?}"
    );
    assert_eq!(costs(&all), [(80, false)], "{all:#?}");
    assert_eq!(
        all.last().map(|e| e["event"].clone()),
        Some("task_done".into())
    );
}

/// Several PEIS in one process (`ecology peis FILE --name astrid,hsm`), clients of a secured
/// router: each joins with its own certificate and presence, takes remote sets as its own, is
/// refused a twin, and is seen gone after its own lease when the process is killed.
#[test]
fn several_peis_in_one_process_each_behave_as_a_process_of_their_own() {
    let _slot = process_slot();
    let fixture = Fixture::new("many", &[TO_BEDROOM], Variant::Paper);
    let secured = SecuredRouter::start(&fixture);
    let through = secured.through();
    let scenario = fixture.scenario();
    let hosts_args = [
        &[
            "peis",
            scenario.as_str(),
            "--name",
            "astrid,hsm",
            "--lease",
            "1",
        ][..],
        &through,
    ]
    .concat();
    let mut hosts = Proc::start("hosts", &hosts_args);
    hosts.wait_for("both ready", |l| l == "2 PEIS ready");
    for name in ["astrid", "hsm"] {
        assert!(
            hosts
                .seen
                .iter()
                .any(|l| l.text.starts_with(&format!("{name} ready: "))),
            "{}",
            hosts.transcript()
        );
    }
    // A twin of one of them is refused, as it would be beside a process of its own.
    let (code, _) = Proc::start(
        "twin",
        &[&["peis", scenario.as_str(), "--name", "hsm"][..], &through].concat(),
    )
    .finish();
    assert_eq!(code, Some(2), "a second hsm must be refused");
    // The executive switches, wires and runs components of both, through remote sets.
    let plan = fixture.plan();
    let (code, lines) = Proc::start("executive", &home_task_args(&plan, &through)).finish();
    let all = events(&lines);
    assert_eq!(code, Some(0), "{all:#?}");
    assert_eq!(costs(&all), [(80, false)], "{all:#?}");
    // Killed, the process leaves no goodbye: each of its PEIS is seen gone after its lease.
    let watch_args = [
        &["tuples", "--name", "executive"][..],
        &through,
        &["watch", "*:components.*.currState"],
    ]
    .concat();
    let mut watch = Proc::start("watch", &watch_args);
    watch.wait_for("the snapshot", |l| l.contains("currState"));
    hosts.signal(Signal::SIGKILL);
    let killed = Instant::now();
    let gone = |watch: &Proc, name: &str| {
        let line = format!("- {name} left");
        watch.seen.iter().any(|l| l.text == line)
    };
    while !(gone(&watch, "astrid") && gone(&watch, "hsm")) {
        watch.wait_for("a PEIS leaving", |l| l.ends_with(" left"));
    }
    let took = killed.elapsed();
    assert!(
        took < Duration::from_secs(4),
        "both seen gone {took:?} after the kill, with a lease of 1 s"
    );
}

#[test]
fn a_peis_process_switches_its_components_off_and_leaves_on_sigterm() {
    let _slot = process_slot();
    let fixture = Fixture::new("sigterm", &[TO_BEDROOM], Variant::Paper);
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
        ],
    );
    // The snapshot: both components on.
    for _ in 0..2 {
        watch.wait_for("currState on", |l| {
            l.contains("currState") && l.contains("\"on\"")
        });
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
    // Watchers see the components off before the PEIS leaves, as it did them.
    watch.wait_for("hsm left", |l| l == "- hsm left");
    let transcript = watch.transcript();
    let before_leaving = transcript.split("- hsm left").next().unwrap_or("");
    let off = before_leaving
        .lines()
        .filter(|l| l.contains("currState") && l.contains("\"off\""))
        .count();
    assert_eq!(off, 2, "{transcript}");
}

/// A process of several PEIS that cannot join yet (nothing listens where it connects) says each
/// second how many have joined, and stops at once when told to, leaving nothing behind.
#[test]
fn a_peis_process_stopped_while_joining_exits_at_once() {
    let _slot = process_slot();
    let fixture = Fixture::new("joining", &[TO_BEDROOM], Variant::Paper);
    let scenario = fixture.scenario();
    let nobody = free_endpoint();
    let mut hosts = Proc::start(
        "hosts",
        &["peis", &scenario, "--all", "--connect", &nobody, "--client"],
    );
    let progress = hosts.wait_for("progress", |l| l.starts_with("… "));
    assert!(
        progress.text.starts_with("… 0 of ") && progress.text.ends_with(" PEIS joined"),
        "{progress:?}"
    );
    hosts.signal(Signal::SIGTERM);
    let asked = Instant::now();
    let (code, lines) = hosts.finish();
    let took = asked.elapsed();
    assert_eq!(code, Some(0), "{lines:?}");
    assert!(took < Duration::from_secs(1), "took {took:?} to stop");
    assert!(
        lines
            .iter()
            .any(|l| l.text.starts_with("SIGTERM while joining: 0 of ")),
        "{lines:?}"
    );
}

/// A process of a hundred PEIS or more announces a presence lease of 5 s unless told one (a
/// router dropped sessions of a busy process of a thousand that announced 2 s); one of a few keeps
/// the default of 2 s, and `--lease` chooses for any.
#[test]
fn a_process_of_many_peis_takes_a_longer_lease() {
    let _slot = process_slot();
    let file = std::env::temp_dir().join(format!("ecology-lease-{}.toml", std::process::id()));
    let file_text = file.to_string_lossy().to_string();
    let made = Proc::start(
        "generate",
        &["generate", "home", "--peis", "101", "--output", &file_text],
    )
    .finish();
    assert_eq!(made.0, Some(0), "{:?}", made.1);
    let fixture = Fixture::new("lease", &[TO_BEDROOM], Variant::Paper);
    let few = fixture.scenario();
    for (scenario, lease, said) in [
        (
            file_text.as_str(),
            None,
            Some("100 PEIS in one process: presence lease 5 s (--lease to choose)"),
        ),
        (file_text.as_str(), Some("3"), None),
        (few.as_str(), None, None),
    ] {
        // Nothing listens where they connect: they say what they announce, then keep trying.
        let nobody = free_endpoint();
        let mut args = vec!["peis", scenario, "--all", "--connect", &nobody, "--client"];
        args.extend(lease.iter().flat_map(|l| ["--lease", l]));
        let mut hosts = Proc::start("hosts", &args);
        hosts.wait_for("progress", |l| l.starts_with("… "));
        hosts.signal(Signal::SIGTERM);
        let (code, lines) = hosts.finish();
        assert_eq!(code, Some(0), "{lines:?}");
        let leases: Vec<&str> = lines
            .iter()
            .map(|l| l.text.as_str())
            .filter(|l| l.contains("presence lease"))
            .collect();
        assert_eq!(leases, said.into_iter().collect::<Vec<_>>(), "{args:?}");
    }
    let _ = std::fs::remove_file(&file);
}

/// A generated building over Zenoh, behind a router that holds the contract: in the building's
/// domain the executive asks who covers the room Astrid sets off from, and reads the contract of
/// three PEIS of the sixty (Astrid, hsm and Pippi, whose camera covers the living room she stands
/// in), not of every PEIS; the move is configured on hsm's cameras and done.
#[test]
fn a_building_behind_a_router_is_acquired_room_by_room() {
    let _slot = process_slot();
    let folder = std::env::temp_dir().join(format!("ecology-rooms-{}", std::process::id()));
    std::fs::create_dir_all(&folder).expect("temp folder");
    let file = folder.join("home.toml").display().to_string();
    let plan = folder.join("plan.txt");
    std::fs::write(
        &plan,
        "(move astrid living-room entrance)  ; configure (navigate astrid entrance)\n",
    )
    .expect("write plan");
    let plan = plan.display().to_string();
    let made = Proc::start(
        "generate",
        &[
            "generate", "home", "--peis", "60", "--seed", "3", "--output", &file,
        ],
    )
    .finish();
    assert_eq!(made.0, Some(0), "{:?}", made.1);
    let router_at = free_endpoint();
    let _router = Proc::start("router", &["router", "--listen", &router_at]).ready();
    let client = ["--connect", router_at.as_str(), "--client"];
    let _world = Proc::start("world", &[&["world", file.as_str()][..], &client].concat()).ready();
    let mut peis = Proc::start(
        "peis",
        &[&["peis", file.as_str(), "--all"][..], &client].concat(),
    );
    peis.wait_for("the building", |l| l == "59 PEIS ready");
    let domain = root()
        .join("domains/peis-building.eco")
        .display()
        .to_string();
    let task = [
        "task",
        "--domain",
        domain.as_str(),
        "--plan",
        plan.as_str(),
        "--json",
        "--timings",
        "--wait-for",
        "world,astrid,hsm,pippi",
    ];
    let (code, lines) =
        Proc::start_with_stderr("executive", &[&task[..], &client].concat()).finish();
    let text: Vec<&str> = lines.iter().map(|l| l.text.as_str()).collect();
    assert_eq!(code, Some(0), "{text:#?}");
    assert!(
        text.iter().any(|l| l.contains(
            "the contract of 3 PEIS followed, those the goals name and those covering 1 room,"
        )),
        "{text:#?}"
    );
    let all: Vec<Value> = text
        .iter()
        .filter(|l| l.starts_with('{'))
        .map(|l| event(l))
        .collect();
    let configured: Vec<&Value> = all
        .iter()
        .filter(|e| e["event"] == "configuration")
        .collect();
    assert_eq!(configured.len(), 1, "{all:#?}");
    assert_eq!(configured[0]["cost"], 80, "{all:#?}");
    assert_eq!(
        all.last().map(|e| e["event"].clone()),
        Some("task_done".into()),
        "{all:#?}"
    );
    let _ = std::fs::remove_dir_all(&folder);
}

#[test]
fn the_papers_experiment_as_separate_processes() {
    let _slot = process_slot();
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

/// A keys directory at `dir` made with `ecology keys`: `peis` as PEIS members, `executive` with
/// the executive role, and `routers` with the router role.
fn make_keys(dir: &str, peis: &[&str], routers: &[&str]) {
    let mut commands = vec![
        vec!["keys", "init", dir],
        vec!["keys", "add", dir, "executive", "--role", "executive"],
    ];
    commands.push([&["keys", "add", dir][..], peis].concat());
    for router in routers {
        commands.push(vec!["keys", "add", dir, router, "--role", "router"]);
    }
    for args in commands {
        let out = Command::new(env!("CARGO_BIN_EXE_ecology"))
            .args(&args)
            .output()
            .expect("ecology keys");
        assert!(out.status.success(), "{args:?}: {out:?}");
    }
}

/// The Python to run the examples with: `ECOLOGY_PYTHON` (set by `scripts/test`
/// to its virtual environment), else the repository's `.venv`, else `python3`.
/// Whether `python` can import `modules` (`"rclpy, lifecycle_msgs"`).
pub(crate) fn imports(python: &str, modules: &str) -> bool {
    Command::new(python)
        .args(["-c", &format!("import {modules}")])
        .status()
        .is_ok_and(|s| s.success())
}

pub(crate) fn python() -> String {
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
    let has_zenoh = imports(&python, "zenoh");
    assert!(
        has_zenoh,
        "{python} has no `zenoh` module: run scripts/test, which installs eclipse-zenoh into .venv"
    );
    let _slot = process_slot();
    let ecology = WithPython::start(
        &python,
        "scenarios/peis-home.toml",
        &["hsm"],
        "examples/python/robot_counter.py",
        "counter",
    );
    let count = || {
        ecology.task(
            "examples/python/robot-counter.eco",
            "examples/python/robot-counter.plan",
            "world,hsm,counter",
        )
    };
    let (code, all) = count();
    assert_the_counter_ran(code, &all);
    // Nobody read its count: it was never written. It counted all the same (done).
    let tuples = read_tuples(&ecology.hub, "counter");
    assert_eq!(
        tuples.get("c1.out.robot-count"),
        None,
        "an output nobody reads is not written: {tuples:#?}"
    );
    assert!(tuples.contains_key("c1.status"), "{tuples:#?}");
    // Read while the task runs again, the count goes out.
    let watcher = watch_tuples(&ecology.hub, "watcher", "counter:c1.out.robot-count");
    let (code, all) = count();
    assert_the_counter_ran(code, &all);
    let counted = watcher
        .lines
        .recv_timeout(Duration::from_secs(2))
        .map(|line| event(&line.text));
    watcher.signal(Signal::SIGINT);
    let counted = counted.expect("the watcher saw the count");
    assert_eq!(counted["key"], "c1.out.robot-count", "{counted}");
    assert!(
        counted["value"]
            .as_str()
            .is_some_and(|v| v.parse::<u32>().is_ok()),
        "{counted}"
    );
    // A second Python `counter` joining through hsm, one hop from the first, is refused.
    let mut twin = Command::new(&python);
    twin.arg(root().join("examples/python/robot_counter.py"))
        .args([
            "--listen",
            &free_endpoint(),
            "--connect",
            &ecology.peis[0].1,
        ]);
    let (code, lines) = Proc::spawn("twin", twin).finish();
    assert_eq!(code, Some(1), "{lines:?}");
    assert!(lines.iter().all(|l| l.text != "ready"), "{lines:?}");
    ecology.stop_component();
}

/// The task on the Python counter was done: the counter discovered (its init tuples priced it:
/// start-up 5 + default 5), switched on, wired to hsm's cameras, its step done without a failure,
/// and switched off again.
fn assert_the_counter_ran(code: Option<i32>, all: &[Value]) {
    assert_eq!(code, Some(0), "{all:#?}");
    assert_eq!(costs(all), [(30, false)], "{all:#?}");
    let deployed = named(all, "deployed");
    assert_eq!(strings(&deployed[0]["switched_on"]), ["counter:c1"]);
    assert_eq!(
        strings(&deployed[0]["channels"]),
        ["hsm:ca1 → counter:c1 (image hsm)"]
    );
    assert!(named(all, "failure").is_empty(), "{all:#?}");
    assert_eq!(named(all, "action_done").len(), 1, "{all:#?}");
    let released = named(all, "released");
    assert_eq!(strings(&released[0]["switched_off"]), ["counter:c1"]);
}

/// A component written to the earlier contract (attachment version 1 only, remote sets on `@set`
/// only, no claims, no `contract` tuple: `tests/fixtures/peis-v1`, frozen from commit 45bdeba) is
/// discovered, switched on, given params, wired, run to done and released by today's executive,
/// which speaks version 1 to it because it announced no other (docs/tuples.md, "Compatibility").
#[test]
fn a_component_of_the_earlier_contract_is_discovered_switched_wired_and_released() {
    let python = python();
    let has_zenoh = imports(&python, "zenoh");
    if !has_zenoh {
        println!(
            "skipped: no Python with the eclipse-zenoh package at `{python}` to run {EARLIER}"
        );
        return;
    }
    // Its reader reads what a writer of today sends a version 1 owner: the corpus's earlier entries.
    let corpus = Command::new(&python)
        .arg(root().join("examples/python/check_corpus.py"))
        .arg(root().join("crates/ecology-zenoh/tests/corpus/attachments.txt"))
        .args(["--earlier", "--reader"])
        .arg(root().join(EARLIER))
        .output()
        .expect("check_corpus.py");
    assert!(corpus.status.success(), "{corpus:?}");
    let _slot = process_slot();
    the_earlier_component_runs(WithPython::start(
        &python,
        "scenarios/peis-home.toml",
        &["hsm"],
        EARLIER,
        "counter",
    ));
}

/// The same through a router that holds the contract of every PEIS: the router asks the earlier
/// component for its tuples with a selector parameter it ignores and answers for it byte for byte
/// (docs/tuples.md, "Compatibility"); every Rust process a client of the router, the component a
/// peer connected to it.
#[test]
fn a_component_of_the_earlier_contract_works_through_a_router_that_holds_the_contract() {
    let python = python();
    if !imports(&python, "zenoh") {
        println!(
            "skipped: no Python with the eclipse-zenoh package at `{python}` to run {EARLIER}"
        );
        return;
    }
    let _slot = process_slot();
    the_earlier_component_runs(WithPython::behind_a_router(
        &python,
        "scenarios/peis-home.toml",
        &["hsm"],
        EARLIER,
        "counter",
    ));
}

/// The frozen component of the earlier contract.
const EARLIER: &str = "crates/ecology-cli/tests/fixtures/peis-v1/robot_counter.py";

/// The counter's task on `ecology`, whose component is [`EARLIER`]: done, and its tuples as the
/// earlier contract leaves them.
fn the_earlier_component_runs(ecology: WithPython) {
    let (code, all) = ecology.task(
        "examples/python/robot-counter.eco",
        "examples/python/robot-counter.plan",
        "world,hsm,counter",
    );
    assert_the_counter_ran(code, &all);
    // Its tuples: every remote set applied (it refuses any attachment but version 1), the count
    // done, switched off again; it keeps no holders, records no creator and announces nothing.
    let tuples = read_tuples(&ecology.hub, "counter");
    let value = |key: &str| tuples.get(key).and_then(|t| t["value"].as_str());
    assert_eq!(value("components.c1.reqState"), Some("off"), "{tuples:#?}");
    assert_eq!(value("components.c1.currState"), Some("off"), "{tuples:#?}");
    assert_eq!(
        value("c1.params"),
        Some("(count-robots counter c1 hsm)"),
        "{tuples:#?}"
    );
    assert_eq!(
        value("c1.mi-image"),
        Some("(meta hsm ca1.out.image)"),
        "{tuples:#?}"
    );
    assert_eq!(value("c1.status"), Some("idle"), "{tuples:#?}");
    assert!(value("c1.out.robot-count").is_some(), "{tuples:#?}");
    assert_eq!(value("components.c1.holders"), None, "{tuples:#?}");
    assert_eq!(value("contract"), None, "{tuples:#?}");
    assert!(
        tuples.values().all(|t| t.get("set_by").is_none()),
        "{tuples:#?}"
    );
    ecology.stop_component();
}

/// An ecology of processes with one component written in Python: the world and the PEIS `peis`
/// of a scenario and a Python PEIS, each listening on an endpoint of its own and connected to the
/// world, or all connected to a router (the Rust processes as its clients).
pub(crate) struct WithPython {
    /// The endpoint the others connect to: the world's, or the router's.
    pub(crate) hub: String,
    /// How a Rust process joins: listening and connected to the world, or a client of the router.
    client: bool,
    _router: Option<Proc>,
    _world: Proc,
    /// Each PEIS's process and the endpoint it listens on (none behind a router).
    pub(crate) peis: Vec<(Proc, String)>,
    component: Proc,
}

impl WithPython {
    /// Starts the world and `peis` of `scenario`, then `script` (named `name`) with `python`;
    /// returns once each said it is ready.
    pub(crate) fn start(
        python: &str,
        scenario: &str,
        peis: &[&str],
        script: &str,
        name: &str,
    ) -> WithPython {
        Self::start_on(None, python, scenario, peis, script, name)
    }

    /// The same, every process connected to `ecology router` (holding the contract, as by
    /// default) and nothing else.
    pub(crate) fn behind_a_router(
        python: &str,
        scenario: &str,
        peis: &[&str],
        script: &str,
        name: &str,
    ) -> WithPython {
        let endpoint = free_endpoint();
        let router = Proc::start("router", &["router", "--listen", &endpoint]).ready();
        Self::start_on(
            Some((router, endpoint)),
            python,
            scenario,
            peis,
            script,
            name,
        )
    }

    fn start_on(
        router: Option<(Proc, String)>,
        python: &str,
        scenario: &str,
        peis: &[&str],
        script: &str,
        name: &str,
    ) -> WithPython {
        let scenario = root().join(scenario).display().to_string();
        let client = router.is_some();
        let (router, hub) = match router {
            Some((proc, endpoint)) => (Some(proc), endpoint),
            None => (None, free_endpoint()),
        };
        let join = |command: &[&str], listen: &str| -> Vec<String> {
            let through: &[&str] = if client {
                &["--client", "--connect", &hub]
            } else if command[0] == "world" {
                &["--listen", listen]
            } else {
                &["--listen", listen, "--connect", &hub]
            };
            command
                .iter()
                .chain(through)
                .map(|a| a.to_string())
                .collect()
        };
        let world_args = join(&["world", &scenario], &hub);
        let world = Proc::start("world", &as_strs(&world_args)).ready();
        let peis = peis
            .iter()
            .map(|&peis| {
                let listen = if client {
                    String::new()
                } else {
                    free_endpoint()
                };
                let args = join(&["peis", &scenario, "--name", peis], &listen);
                (Proc::start(peis, &as_strs(&args)).ready(), listen)
            })
            .collect();
        let mut command = Command::new(python);
        command
            .arg(root().join(script))
            .args(["--listen", &free_endpoint(), "--connect", &hub]);
        let mut component = Proc::spawn(name, command);
        component.wait_for("ready", |l| l == "ready");
        WithPython {
            hub,
            client,
            _router: router,
            _world: world,
            peis,
            component,
        }
    }

    /// The executive on `domain` and `plan`, once `wait_for` are present: its exit code and events.
    pub(crate) fn task(&self, domain: &str, plan: &str, wait_for: &str) -> (Option<i32>, Events) {
        let listen = free_endpoint();
        let through = if self.client {
            ["--client", "--connect", &self.hub].to_vec()
        } else {
            ["--listen", &listen, "--connect", &self.hub].to_vec()
        };
        let task = Proc::start("executive", &task_args(domain, plan, wait_for, &through));
        let (code, lines) = task.finish();
        (code, events(&lines))
    }

    /// Stops the Python PEIS with SIGTERM; it exits cleanly.
    pub(crate) fn stop_component(self) {
        self.component.signal(Signal::SIGTERM);
        let (code, _) = self.component.finish();
        assert_eq!(code, Some(0));
    }
}

#[test]
fn over_zenoh_a_failed_action_is_planned_around_until_no_plan_remains() {
    let _slot = process_slot();
    let (code, lines) = Proc::start(
        "launcher",
        &["run", "scenarios/no-plan.toml", "--processes", "--json"],
    )
    .finish();
    let all = events(&lines);
    assert_eq!(code, Some(1), "{all:#?}");
    let replans = named(&all, "replan");
    assert_eq!(replans.len(), 1, "{all:#?}");
    assert_eq!(replans[0]["failed"], "(move astrid living-room entrance)");
    assert_eq!(
        strings(&replans[0]["actions"])[0],
        "(move pippi kitchen living-room)"
    );
    let failed = named(&all, "task_failed");
    assert!(
        failed[0]["reason"]
            .as_str()
            .is_some_and(|r| r.contains("no plan remains")),
        "{all:#?}"
    );
    assert_eq!(
        strings(&named(&all, "released")[0]["switched_off"]),
        ["astrid:l1"]
    );
}

/// Issue: only the owner writes its tuples. Every process with keys over mutual TLS; the stock
/// Python client, enrolled as `mallory`, declares hsm's presence token before hsm starts, then
/// forges hsm's tuples (its cameras' and tracking system's status `error`), deletes and replays
/// them and asks hsm to switch its cameras off, over and over while Astrid moves on hsm's cameras.
/// hsm joins, nothing forged is accepted, and the move is done on the cameras (80) without a
/// failure or a reconfiguration.
#[test]
fn an_enrolled_attacker_cannot_stop_a_task_on_a_secured_ecology() {
    let python = python();
    let has_zenoh = imports(&python, "zenoh");
    if !has_zenoh {
        println!("skipped: no Python with the eclipse-zenoh package at `{python}`");
        return;
    }
    let _slot = process_slot();
    let fixture = Fixture::new("attacked", &[TO_BEDROOM], Variant::Paper);
    let keys = fixture.folder.join("keys");
    let k = keys.display().to_string();
    make_keys(&k, &["world", "astrid", "hsm", "mallory"], &[]);
    // The world first, so the attacker has somewhere to connect before hsm exists.
    let world_endpoint = free_quic_endpoint();
    let scenario = fixture.scenario();
    let _world = Proc::start(
        "world",
        &[
            "world",
            &scenario,
            "--listen",
            &world_endpoint,
            "--keys",
            &k,
        ],
    )
    .ready();
    let file = |f: &str| keys.join(f).display().to_string();
    let mut attacker_command = Command::new(&python);
    attacker_command
        .arg(root().join("crates/ecology-zenoh/tests/attacker.py"))
        .args([
            "--connect",
            &world_endpoint,
            "--victim",
            "hsm",
            "--peers",
            "3",
        ])
        .args(["--ca", &file("ca.crt"), "--cert", &file("mallory.crt")])
        .args(["--key", &file("mallory.key")]);
    let mut attacker = Proc::spawn("attacker", attacker_command);
    attacker.wait_for("tokens", |l| l == "tokens");
    let peis = |name: &str| {
        Proc::start(
            name,
            &[
                "peis",
                &scenario,
                "--name",
                name,
                "--listen",
                &free_quic_endpoint(),
                "--connect",
                &world_endpoint,
                "--keys",
                &k,
            ],
        )
        .ready()
    };
    let _astrid = peis("astrid");
    let _hsm = peis("hsm");
    // The attack's burst starts as the executive joins, and goes on until the task ends.
    attacker.say("go");
    let task = task_on(&world_endpoint, Some(&k), &fixture, &[]);
    let report = attacker.wait_for("its report", |l| l.starts_with('{')).text;
    println!("attacker: {report}");
    assert!(
        report.contains("\"joined\": true") && report.contains("\"set_accepted\": 0"),
        "{report}"
    );
    attacker.wait_for("attacking", |l| l == "attacking");
    let (code, lines) = task.finish();
    let all = events(&lines);
    assert_eq!(code, Some(0), "{all:#?}");
    assert!(
        named(&all, "failure").is_empty(),
        "a forged status was taken for a failure: {all:#?}"
    );
    assert_eq!(costs(&all), [(80, false)], "{all:#?}");
    assert_eq!(
        all.last().map(|e| e["event"].clone()),
        Some("task_done".into())
    );
}

/// `ecology view` over Zenoh: a process of its own that joins the ecology, follows every tuple,
/// presence and the executive's log tuple, and serves the state the page shows.
#[test]
fn the_view_follows_an_ecology_of_processes() {
    let _slot = process_slot();
    let fixture = Fixture::new("view", &[TO_BEDROOM], Variant::Paper);
    let ecology = Ecology::start(&fixture, &[]);
    let mut view = Proc::start(
        "view",
        &[
            "view",
            "--bind",
            "127.0.0.1:0",
            "--listen",
            &free_endpoint(),
            "--connect",
            &ecology.world_endpoint,
        ],
    );
    let ready = view.wait_for("view ready", |l| l.starts_with("view ready: "));
    let url = ready.text["view ready: ".len()..]
        .split(';')
        .next()
        .expect("the address")
        .to_owned();
    let (code, lines) = ecology.task(&fixture, &[]).finish();
    assert_eq!(code, Some(0), "{:#?}", events(&lines));
    let port: u16 = url
        .trim_end_matches('/')
        .rsplit(':')
        .next()
        .and_then(|p| p.parse().ok())
        .expect("a port in the address");
    let deadline = Instant::now() + Duration::from_secs(20);
    let state = loop {
        let state = http_get_json(port, "/state");
        if state["status"] == "task done" {
            break state;
        }
        assert!(
            Instant::now() < deadline,
            "the view never saw the task done: {state}"
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    assert_eq!(state["configuration"]["cost"], 80, "{state}");
    assert_eq!(state["plan"][0]["state"], "done", "{state}");
    let names: Vec<&str> = state["peis"]
        .as_array()
        .expect("peis")
        .iter()
        .filter(|p| p["present"] == true)
        .filter_map(|p| p["name"].as_str())
        .collect();
    for name in ["astrid", "hsm", "world"] {
        assert!(names.contains(&name), "{name} not shown present: {names:?}");
    }
    assert!(
        state["svg"]
            .as_str()
            .is_some_and(|s| s.contains(r#"data-component="hsm:tr1""#)),
        "{state}"
    );
    view.signal(Signal::SIGINT);
    let (code, _) = view.finish();
    assert_eq!(code, Some(0));
}

/// GET `path` from 127.0.0.1:`port` as JSON (`null` when it cannot be had).
fn http_get_json(port: u16, path: &str) -> Value {
    use std::io::{Read, Write};
    let Ok(mut stream) = std::net::TcpStream::connect(("127.0.0.1", port)) else {
        return Value::Null;
    };
    let _ = stream.set_read_timeout(Some(Duration::from_secs(5)));
    let _ = write!(
        stream,
        "GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n"
    );
    let mut response = Vec::new();
    let _ = stream.read_to_end(&mut response);
    let response = String::from_utf8_lossy(&response);
    response
        .split_once("\r\n\r\n")
        .and_then(|(_, body)| serde_json::from_str(body).ok())
        .unwrap_or(Value::Null)
}

/// A conditional plan over Zenoh: `ecology task` plans the uncertain problem conditionally, Astrid's
/// object localizer (in her own `ecology peis` process) writes what it sees as `ol3.observed`, and
/// the executive follows the branch of it. Seed 1 puts the newspaper at the entrance (the in-process
/// tests run both branches).
#[test]
fn over_zenoh_a_conditional_plan_branches_on_what_a_peis_observes() {
    let _slot = process_slot();
    let (code, lines) = Proc::start(
        "launcher",
        &[
            "run",
            "scenarios/newspaper.toml",
            "--processes",
            "--seed",
            "1",
            "--json",
        ],
    )
    .finish();
    let all = events(&lines);
    assert_eq!(code, Some(0), "{all:#?}");
    let observed = named(&all, "observed");
    assert_eq!(observed.len(), 1, "{all:#?}");
    assert_eq!(observed[0]["action"], "(look astrid newspaper entrance)");
    assert_eq!(observed[0]["observation"], "(thing-at newspaper entrance)");
    let branch = named(&all, "branch");
    assert_eq!(branch.len(), 1, "{all:#?}");
    assert_eq!(
        strings(&branch[0]["actions"]),
        [
            "(get astrid newspaper entrance)",
            "(move astrid entrance bedroom)",
            "(wake astrid johanna bedroom)"
        ]
    );
    assert_eq!(named(&all, "task_done").len(), 1, "{all:#?}");
}

/// The issue's two tasks started together in one home, as processes on a secured router: Astrid
/// to the bedroom (`exec-astrid`) and Bob to the kitchen (`exec-bob`). Both plan the ceiling
/// cameras; hsm gives its one tracking system to the first request and refuses the other, which
/// takes its own laser. Nobody is blamed, both arrive, the tracker is never re-aimed while held,
/// the holder hsm records is the member that asked (its certificate's name), and when both are
/// done nothing is held any more.
#[test]
fn two_tasks_started_together_take_nothing_from_each_other() {
    let _slot = process_slot();
    let fixture = Fixture::two_robots("two-tasks");
    let file = |name: &str| fixture.folder.join(name).display().to_string();
    let keys = file("keys");
    for args in [
        vec!["keys", "init", &keys],
        vec![
            "keys", "add", &keys, "world", "astrid", "bob", "hsm", "watcher",
        ],
        vec!["keys", "add", &keys, "exec-astrid", "--role", "executive"],
        vec!["keys", "add", &keys, "exec-bob", "--role", "executive"],
        vec!["keys", "add", &keys, "router", "--role", "router"],
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_ecology"))
            .args(&args)
            .output()
            .expect("ecology keys");
        assert!(out.status.success(), "{args:?}: {out:?}");
    }
    let endpoint = free_quic_endpoint();
    let _router = Proc::start(
        "router",
        &["router", "--listen", &endpoint, "--keys", &keys],
    )
    .ready();
    let through = ["--client", "--connect", endpoint.as_str(), "--keys", &keys];
    let scenario = fixture.scenario();
    let _world = Proc::start("world", &[&["world", &scenario][..], &through].concat()).ready();
    let _hosts = ["astrid", "bob", "hsm"].map(|name| {
        Proc::start(
            name,
            &[&["peis", scenario.as_str(), "--name", name][..], &through].concat(),
        )
        .ready()
    });
    let watch = |name: &str, pattern: &str| {
        let mut args = vec!["tuples"];
        args.extend(through);
        args.extend(["--name", name, "watch", pattern, "--json"]);
        Proc::start(name, &args)
    };
    let params = watch("watcher", "hsm:*.params");
    let tasks = [
        ("exec-astrid", fixture.plan()),
        ("exec-bob", fixture.plan_of("bob")),
    ]
    .map(|(name, plan)| {
        let mut args = vec!["task", "--name", name, "--domain", "domains/peis-home.eco"];
        args.extend([
            "--plan",
            &plan,
            "--json",
            "--wait-for",
            "world,astrid,bob,hsm",
        ]);
        args.extend(through);
        Proc::start(name, &args)
    });
    let mut ends = Vec::new();
    for task in tasks {
        let name = task.name.clone();
        let (code, lines) = task.finish();
        let all = events(&lines);
        assert_eq!(code, Some(0), "{name}: {all:#?}");
        assert_eq!(
            all.last().map(|e| e["event"].clone()),
            Some("task_done".into()),
            "{name}: {all:#?}"
        );
        assert!(named(&all, "failure").is_empty(), "{name}: {all:#?}");
        ends.push(costs(&all).last().map(|c| c.0));
    }
    ends.sort();
    assert_eq!(ends, [Some(80), Some(170)], "one tracker, one laser");

    // What hsm's params went through: set by an executive (its certificate's name), never
    // changed to another's while held, and released at the end.
    let mut seen: Vec<Value> = Vec::new();
    while let Ok(line) = params.lines.recv_timeout(Duration::from_millis(1500)) {
        seen.push(event(&line.text));
    }
    let tracker: Vec<&Value> = seen.iter().filter(|e| e["key"] == "tr1.params").collect();
    let values: Vec<&str> = tracker.iter().filter_map(|e| e["value"].as_str()).collect();
    assert!(values.len() >= 2, "{seen:#?}");
    for pair in values.windows(2) {
        assert!(
            pair[0].is_empty() || pair[1].is_empty() || pair[0] == pair[1],
            "the tracker was re-aimed while held: {values:?}"
        );
    }
    assert_eq!(values.last(), Some(&""), "{values:?}");
    let robot = values[0]
        .trim_end_matches(')')
        .rsplit(' ')
        .next()
        .unwrap_or("");
    assert_eq!(
        tracker[0]["set_by"].as_str(),
        Some(format!("exec-{robot}").as_str()),
        "{tracker:#?}"
    );
}

/// Astrid's and Bob's executives share hsm's ceiling cameras, each with a tracking system of its
/// own, when Astrid's is interrupted (SIGINT) mid-move: it releases its own claims only. Its
/// tracker is put back, the cameras keep running for Bob, whose two moves are done on them with
/// no failure, and when he is done nothing is held any more.
#[test]
fn an_executive_interrupted_while_sharing_releases_only_its_own_claims() {
    let _slot = process_slot();
    let fixture = Fixture::two_robots_with(
        "sigint-shared",
        "  { id = \"tr2\", type = \"tr-sys\", cost = 20, on = true },\n",
    );
    let bob_plan = fixture.folder.join("bob-twice.txt");
    std::fs::write(
        &bob_plan,
        "(move bob living-room kitchen)  ; configure (navigate bob kitchen)\n\
         (move bob kitchen living-room)  ; configure (navigate bob living-room)\n",
    )
    .expect("plan");
    let ecology = Ecology::start_with_bob(&fixture);
    let mut astrid = ecology.task_as("exec-astrid", &fixture.plan());
    let bob = ecology.task_as("exec-bob", &bob_plan.display().to_string());
    astrid.wait_for("running", |l| is_event(l, "running"));
    astrid.signal(Signal::SIGINT);
    let (code, lines) = astrid.finish();
    let all = events(&lines);
    assert_ne!(code, Some(0), "{all:#?}");
    assert_eq!(named(&all, "released").len(), 1, "{all:#?}");
    let (code, lines) = bob.finish();
    let all = events(&lines);
    assert_eq!(code, Some(0), "{all:#?}");
    assert!(named(&all, "failure").is_empty(), "{all:#?}");
    assert!(costs(&all).iter().all(|c| c.0 == 80), "{all:#?}");
    let tuples = ecology.read("hsm");
    // Nothing is held: each holders tuple is empty, or was never written (under load, Bob may
    // start only after Astrid let go, and then never needs the second tracker).
    for key in [
        "components.ca1.holders",
        "components.tr1.holders",
        "components.tr2.holders",
    ] {
        assert_eq!(
            tuples.get(key).map_or("", String::as_str),
            "",
            "{key}: {tuples:#?}"
        );
    }
    assert!(
        tuples.contains_key("components.tr1.holders"),
        "the tracker was never claimed: {tuples:#?}"
    );
}
