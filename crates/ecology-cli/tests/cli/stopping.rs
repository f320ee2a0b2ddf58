//! Every process stops when asked: within its bound (`ECOLOGY_STOP_WITHIN`, 10 s by default) after
//! SIGINT or SIGTERM whatever the network does, at once on a second signal; and SIGUSR1 prints
//! where a process stands without stopping it.

use std::process::Command;
use std::time::{Duration, Instant};

use nix::sys::signal::Signal;

use crate::processes::process_slot;
use crate::support::{Fixture, Proc, TO_BEDROOM, Variant, free_endpoint, is_event};

/// The bound the tests give every process, in seconds.
const BOUND: &str = "3";

/// How much later than its bound a process may end: the watchdog's own wake-up and the exit.
const MARGIN: Duration = Duration::from_millis(1500);

/// `ecology ARGS…` with the stop bound of these tests, its stderr read with its stdout.
fn ecology(name: &str, args: &[&str]) -> Proc {
    ecology_within(name, args, BOUND)
}

/// `ecology ARGS…` with the stop bound `within` (seconds), its stderr read with its stdout.
fn ecology_within(name: &str, args: &[&str], within: &str) -> Proc {
    let mut command = Command::new("sh");
    command
        .args([
            "-c",
            r#"exec "$0" "$@" 2>&1"#,
            env!("CARGO_BIN_EXE_ecology"),
        ])
        .args(args)
        .env("ECOLOGY_STOP_WITHIN", within);
    Proc::spawn(name, command)
}

/// Waits for `proc` to exit, at most `limit` after `since`; how long it took from `since`, its exit
/// code (`None`: killed by a signal) and what it printed.
fn ended(proc: Proc, since: Instant, limit: Duration) -> (Duration, Option<i32>, String) {
    let (code, lines) = proc.finish_by(since + limit);
    let took = since.elapsed();
    let said: Vec<&str> = lines.iter().map(|l| l.text.as_str()).collect();
    (took, code, said.join("\n"))
}

/// A home whose every process is a client of one router, the task mid-move.
struct RouterHome {
    _fixture: Fixture,
    router: Proc,
    world: Proc,
    peis: Proc,
    task: Proc,
    router_at: String,
}

impl RouterHome {
    /// The home of `test`, its executive stopping within `task_within` seconds.
    fn start(test: &str, task_within: &str) -> RouterHome {
        let fixture = Fixture::new(test, &[TO_BEDROOM], Variant::Paper);
        let scenario = fixture.scenario();
        let plan = fixture.plan();
        let router_at = free_endpoint();
        let router = Proc::start("router", &["router", "--listen", &router_at]).ready();
        let client = ["--connect", router_at.as_str(), "--client"];
        let world = ecology(
            "world",
            &[&["world", scenario.as_str()][..], &client].concat(),
        )
        .ready();
        let mut peis = ecology(
            "peis",
            &[&["peis", scenario.as_str(), "--all"][..], &client].concat(),
        );
        peis.wait_for("both PEIS", |l| l.contains("2 PEIS ready"));
        let task_args = [
            "task",
            "--domain",
            "domains/peis-home.eco",
            "--plan",
            plan.as_str(),
            "--json",
            "--wait-for",
            "world,astrid,hsm",
        ];
        let mut task = ecology_within(
            "executive",
            &[&task_args[..], &client].concat(),
            task_within,
        );
        task.wait_for("running", |l| is_event(l, "running"));
        RouterHome {
            _fixture: fixture,
            router,
            world,
            peis,
            task,
            router_at,
        }
    }

    /// `ecology ARGS… --connect ROUTER --client`.
    fn client(&self, name: &str, args: &[&str]) -> Proc {
        let client = ["--connect", self.router_at.as_str(), "--client"];
        ecology(name, &[args, &client].concat())
    }
}

fn bound() -> Duration {
    Duration::from_secs_f64(BOUND.parse::<f64>().expect("seconds"))
}

// Every kind of process, each a client of one router, is running (the task mid-move); the router
// freezes (SIGSTOP), so nothing any of them sends is answered; each is asked to stop once and ends
// within its bound. The executive cannot release what it used through a frozen router (each remote
// set waits 2 s for its answer), so with a bound of 1.5 s it is stopped by its bound, saying what
// it was doing. SIGUSR1 beforehand tells where each stands.
#[test]
fn every_process_stops_within_its_bound_with_its_router_frozen() {
    let _slot = process_slot();
    let home = RouterHome::start("frozen-router", "1.5");
    let view = home
        .client("view", &["view", "--bind", "127.0.0.1:0"])
        .ready();
    let mut watch = home.client("watch", &["tuples", "watch", "hsm:**"]);
    watch.wait_for("a tuple", |l| l.starts_with("hsm "));
    let RouterHome {
        _fixture,
        router,
        world,
        mut peis,
        mut task,
        ..
    } = home;

    // Asked where it stands, the executive says so, and goes on.
    task.signal(Signal::SIGUSR1);
    task.wait_for("its report", |l| l.starts_with("== ecology task (pid"));
    for part in [
        "state: running (not asked to stop)",
        "runtime: ",
        "threads: ",
        "task: running action 1",
        "action 1: (move astrid entrance bedroom): running, waiting for its postconditions",
        "switched on by this task: ",
        "timers: ",
        "remote sets under way: ",
    ] {
        task.wait_for(part, |l| l.starts_with(part));
    }
    peis.signal(Signal::SIGUSR1);
    peis.wait_for("its report", |l| l.starts_with("== ecology peis (pid"));
    peis.wait_for("its state", |l| l == "state: running (not asked to stop)");

    router.signal(Signal::SIGSTOP);
    let asked = Instant::now();
    let limit = bound() + MARGIN;
    for proc in [&task, &peis, &world, &view, &watch] {
        proc.signal(Signal::SIGTERM);
    }
    let (took, code, said) = ended(task, asked, Duration::from_secs_f64(1.5) + MARGIN);
    assert!(took >= Duration::from_millis(1400), "{took:?}\n{said}");
    assert_eq!(code, Some(1), "{said}");
    assert!(
        said.contains(
            "error: SIGTERM: not stopped within 1.5 s (still switching off what the task switched \
             on); exiting now, without finishing"
        ),
        "{said}"
    );
    for proc in [peis, world, view, watch] {
        let name = proc.name.clone();
        let (took, code, said) = ended(proc, asked, limit);
        assert!(took < limit, "{name} took {took:?}:\n{said}");
        assert!(
            code == Some(0)
                || (code == Some(1) && said.contains("not stopped within 3.0 s (still ")),
            "{name} ({code:?}):\n{said}"
        );
    }
    drop(router);
}

// Asked twice, a process ends at once, whatever it was waiting for: here the executive, releasing
// through a frozen router.
#[test]
fn a_second_signal_ends_a_process_at_once() {
    let _slot = process_slot();
    let RouterHome {
        _fixture,
        router,
        mut task,
        ..
    } = RouterHome::start("second-signal", BOUND);
    router.signal(Signal::SIGSTOP);
    task.signal(Signal::SIGTERM);
    std::thread::sleep(Duration::from_millis(1000));
    // Still releasing: its remote sets wait for their answers.
    assert!(
        task.child.try_wait().expect("try_wait").is_none(),
        "the executive did not wait for its remote sets:\n{}",
        task.transcript()
    );
    task.signal(Signal::SIGTERM);
    let again = Instant::now();
    let (took, code, said) = ended(task, again, Duration::from_secs(1));
    assert!(took < Duration::from_millis(500), "{took:?}\n{said}");
    assert_eq!(code, None, "ended by the second signal:\n{said}");
    drop(router);
}

// The executive is asked to stop mid-move, and the PEIS it must release are gone (killed) as it
// releases: it ends within its bound. Then the world, whose peers are all gone, is stopped too.
#[test]
fn an_executive_whose_peis_are_gone_mid_release_stops_within_its_bound() {
    let _slot = process_slot();
    let fixture = Fixture::new("gone-mid-release", &[TO_BEDROOM], Variant::Paper);
    let scenario = fixture.scenario();
    let world_at = free_endpoint();
    let world = ecology("world", &["world", &scenario, "--listen", &world_at]).ready();
    let peis = |name: &'static str| {
        let listen = free_endpoint();
        ecology(
            name,
            &[
                "peis",
                &scenario,
                "--name",
                name,
                "--listen",
                &listen,
                "--connect",
                &world_at,
            ],
        )
        .ready()
    };
    let astrid = peis("astrid");
    let hsm = peis("hsm");
    let listen = free_endpoint();
    let plan = fixture.plan();
    let mut task = ecology(
        "executive",
        &[
            "task",
            "--domain",
            "domains/peis-home.eco",
            "--plan",
            &plan,
            "--json",
            "--wait-for",
            "world,astrid,hsm",
            "--listen",
            &listen,
            "--connect",
            &world_at,
        ],
    );
    task.wait_for("running", |l| is_event(l, "running"));
    task.signal(Signal::SIGTERM);
    let asked = Instant::now();
    astrid.signal(Signal::SIGKILL);
    hsm.signal(Signal::SIGKILL);
    let limit = Duration::from_secs_f64(BOUND.parse::<f64>().expect("seconds")) + MARGIN;
    let (took, code, said) = ended(task, asked, limit);
    assert!(took < limit, "took {took:?}:\n{said}");
    assert!(
        code == Some(1),
        "a stopped task is not done ({code:?}):\n{said}"
    );
    assert!(
        said.contains("SIGTERM: stopping the task and switching off what it switched on"),
        "{said}"
    );
    world.signal(Signal::SIGTERM);
    let asked = Instant::now();
    let (took, code, said) = ended(world, asked, limit);
    assert!(took < limit, "took {took:?}:\n{said}");
    assert_eq!(code, Some(0), "{said}");
}
