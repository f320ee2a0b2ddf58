//! `ecology tuples` across separate OS processes on 127.0.0.1: one holds a PEIS, others get, set, watch and list it.

use std::io::BufRead;
use std::process::{Child, Command, Output, Stdio};
use std::sync::mpsc;
use std::time::Duration;

const PATIENCE: Duration = Duration::from_secs(30);

fn free_endpoint() -> String {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("bind 127.0.0.1:0");
    format!(
        "tcp/127.0.0.1:{}",
        listener.local_addr().expect("address").port()
    )
}

fn ecology(args: &[&str]) -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_ecology"));
    command.arg("tuples").args(args);
    command
}

/// Runs a joining `ecology tuples` invocation to completion, bounded by PATIENCE.
fn run_joined(connect: &str, args: &[&str]) -> Output {
    let listen = free_endpoint();
    let child = ecology(&["--listen", &listen, "--connect", connect])
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn ecology");
    let pid = child.id();
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(child.wait_with_output());
    });
    match rx.recv_timeout(PATIENCE) {
        Ok(output) => output.expect("wait for ecology"),
        Err(_) => {
            let _ = Command::new("kill").args(["-9", &pid.to_string()]).status();
            panic!("ecology tuples {args:?} did not finish within {PATIENCE:?}");
        }
    }
}

fn stdout(output: &Output) -> String {
    String::from_utf8_lossy(&output.stdout).into_owned()
}

/// The PEIS `astrid` in its own process, killed when dropped.
struct Holder(Child);

impl Drop for Holder {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn two_processes_share_tuples() {
    let endpoint = free_endpoint();
    let mut holder = Holder(
        ecology(&["--name", "astrid", "--listen", &endpoint])
            .args(["set", "astrid", "components.l1.status", "running", "--hold"])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect("spawn holder"),
    );
    let out = holder.0.stdout.take().expect("piped stdout");
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(out).lines() {
            let Ok(line) = line else { return };
            if tx.send(line).is_err() {
                return;
            }
        }
    });
    let first = rx.recv_timeout(PATIENCE).expect("holder reports the set");
    assert_eq!(first, "astrid components.l1.status seq 1");
    assert_eq!(rx.recv_timeout(PATIENCE).expect("holder ready"), "ready");

    let got = run_joined(&endpoint, &["get", "astrid", "components.l1.status"]);
    assert_eq!(
        (got.status.code(), stdout(&got).as_str()),
        (Some(0), "running\n")
    );

    let missing = run_joined(&endpoint, &["get", "astrid", "components.l1.cost"]);
    assert_eq!(missing.status.code(), Some(1));
    assert!(
        String::from_utf8_lossy(&missing.stderr).contains("no tuple (astrid components.l1.cost)")
    );

    let set = run_joined(
        &endpoint,
        &[
            "--name",
            "operator",
            "set",
            "astrid",
            "components.l1.reqState",
            "on",
        ],
    );
    assert_eq!(
        (set.status.code(), stdout(&set).as_str()),
        (Some(0), "astrid components.l1.reqState seq 1\n")
    );
    let got = run_joined(&endpoint, &["get", "astrid", "components.l1.reqState"]);
    assert_eq!(stdout(&got), "on\n");
    // Who set a tuple by remote set shows, and holds the component it switched on.
    let watched = run_joined(
        &endpoint,
        &["watch", "astrid:components.l1.*", "--json", "--count", "3"],
    );
    let lines = stdout(&watched);
    let by_key = |k: &str| {
        lines
            .lines()
            .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
            .find(|e| e["key"] == k)
            .unwrap_or_else(|| panic!("no {k} in {lines}"))
    };
    assert_eq!(by_key("components.l1.reqState")["set_by"], "operator");
    assert_eq!(by_key("components.l1.holders")["value"], "operator");
    assert_eq!(by_key("components.l1.status").get("set_by"), None);

    let unreachable = run_joined(&endpoint, &["set", "ghost", "x", "1"]);
    assert_eq!(unreachable.status.code(), Some(1));

    let watched = run_joined(
        &endpoint,
        &[
            "watch",
            "astrid:components.*.status",
            "--json",
            "--count",
            "1",
        ],
    );
    assert_eq!(watched.status.code(), Some(0));
    let line = stdout(&watched);
    let event: serde_json::Value = serde_json::from_str(line.trim()).expect("one JSON object");
    assert_eq!(event["event"], "changed");
    assert_eq!(event["owner"], "astrid");
    assert_eq!(event["key"], "components.l1.status");
    assert_eq!(event["value"], "running");
    assert_eq!(event["seq"], 1);

    let readable = run_joined(&endpoint, &["watch", "astrid:**", "--count", "3"]);
    let text = stdout(&readable);
    assert!(
        text.contains("components.l1.status") && text.contains("\"running\""),
        "{text}"
    );
    assert!(text.contains(", set by operator)"), "{text}");
    assert!(text.contains("age "), "{text}");

    let peers = run_joined(&endpoint, &["--name", "lister", "peers"]);
    assert_eq!(stdout(&peers), "astrid\nlister\n");

    let taken = run_joined(&endpoint, &["--name", "astrid", "peers"]);
    assert_eq!(taken.status.code(), Some(2));

    // Closing the holder's standard input makes it leave; it exits cleanly.
    drop(holder.0.stdin.take());
    let (tx, rx) = mpsc::channel();
    let mut child = std::mem::replace(
        &mut holder.0,
        Command::new("true").spawn().expect("spawn true"),
    );
    std::thread::spawn(move || {
        let _ = tx.send(child.wait());
    });
    let status = rx
        .recv_timeout(PATIENCE)
        .expect("holder exits")
        .expect("wait");
    assert!(status.success());
}

#[test]
fn bad_input_exits_with_2() {
    for args in [
        &["get", "astrid", "a..b"][..],
        &["get", "as.trid", "k"],
        &["watch", "astrid:comp*"],
        &["--name", "bad name", "peers"],
    ] {
        let output = ecology(args)
            .stdin(Stdio::null())
            .output()
            .expect("run ecology");
        assert_eq!(output.status.code(), Some(2), "{args:?}");
        assert!(!output.stderr.is_empty());
    }
    let usage = ecology(&["get", "astrid"]).output().expect("run ecology");
    assert_eq!(usage.status.code(), Some(2));
}

/// `ecology tuples watch` stops on SIGINT every time, also between changes.
#[test]
fn watch_stops_on_sigint_every_time() {
    use crate::support::Proc;
    let endpoint = free_endpoint();
    let holder = Proc::start(
        "astrid",
        &[
            "tuples", "--name", "astrid", "--listen", &endpoint, "set", "astrid", "x", "1",
            "--hold",
        ],
    );
    let mut holder = holder;
    holder.wait_for("ready", |l| l == "ready");
    for round in 0..10 {
        let listen = free_endpoint();
        let mut watch = Proc::start(
            "watch",
            &[
                "tuples",
                "--listen",
                &listen,
                "--connect",
                &endpoint,
                "watch",
                "astrid:x",
                "--json",
            ],
        );
        watch.wait_for("the current value", |l| l.contains("\"value\":\"1\""));
        watch.signal(nix::sys::signal::Signal::SIGINT);
        let (code, _) = watch.finish();
        assert_eq!(code, Some(0), "round {round}");
    }
}

/// `ecology tuples peers` joined through one PEIS lists the PEIS that one
/// knows too, once gossip has linked them.
/// `alpha` holding its tuple `x` = 1, and `beta`, which connected to it, holding its own; with
/// the endpoint beta listens on.
fn alpha_and_beta() -> (crate::support::Proc, crate::support::Proc, String) {
    use crate::support::Proc;
    let first = free_endpoint();
    let second = free_endpoint();
    let mut a = Proc::start(
        "alpha",
        &[
            "tuples", "--name", "alpha", "--listen", &first, "set", "alpha", "x", "1", "--hold",
        ],
    );
    a.wait_for("ready", |l| l == "ready");
    let mut b = Proc::start(
        "beta",
        &[
            "tuples",
            "--name",
            "beta",
            "--listen",
            &second,
            "--connect",
            &first,
            "set",
            "beta",
            "x",
            "1",
            "--hold",
        ],
    );
    b.wait_for("ready", |l| l == "ready");
    (a, b, second)
}

#[test]
fn peers_through_a_third_peis_lists_everyone() {
    let (_alpha, _beta, second) = alpha_and_beta();
    for round in 0..5 {
        let listed = run_joined(&second, &["--name", "gamma", "peers"]);
        assert_eq!(
            stdout(&listed),
            "alpha\nbeta\ngamma\n",
            "round {round}: {}",
            String::from_utf8_lossy(&listed.stderr)
        );
    }
}

/// A name taken one hop away is refused, and `get` and `set` through another PEIS reach a PEIS
/// one hop away: each waits for the links gossip opens before it asks.
#[test]
fn one_hop_away_a_name_is_taken_and_get_and_set_reach_the_owner() {
    let (_alpha, _beta, second) = alpha_and_beta();
    for round in 0..4 {
        // A short lease: it waits that long, plus 1 s, for alpha to leave.
        let taken = run_joined(&second, &["--name", "alpha", "--lease", "0.5", "peers"]);
        assert_eq!(taken.status.code(), Some(2), "round {round}: {taken:?}");
        assert!(
            String::from_utf8_lossy(&taken.stderr).contains("alpha is already present"),
            "{taken:?}"
        );
        let got = run_joined(&second, &["get", "alpha", "x"]);
        assert_eq!(
            (got.status.code(), stdout(&got).as_str()),
            (Some(0), "1\n"),
            "round {round}: {got:?}"
        );
        let value = format!("{round}");
        let set = run_joined(&second, &["set", "alpha", "y", &value]);
        assert_eq!(set.status.code(), Some(0), "round {round}: {set:?}");
    }
}

/// Nobody listens on the endpoint: joining fails once `--connect-timeout` is over, which is "not
/// found" (1), as for an owner that cannot be reached, with the reason on stderr.
#[test]
fn a_peis_that_cannot_be_reached_exits_1() {
    let nobody = free_endpoint();
    let out = ecology(&[
        "--connect",
        &nobody,
        "--connect-timeout",
        "1",
        "get",
        "astrid",
        "x",
    ])
    .output()
    .expect("run ecology tuples");
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains(&format!(
            "joining the ecology (nothing at {nobody} took this session within 1s \
             (--connect-timeout)"
        )),
        "{out:?}"
    );
}

/// Several `--connect` endpoints, the first with nobody behind it: a peer and a client of a router
/// join through the next one, at once. Zenoh alone kept dialling the first until the connect
/// timeout and never tried the next.
#[test]
fn the_first_endpoint_down_a_process_joins_through_the_next() {
    use crate::support::Proc;
    let nobody = free_endpoint();
    let router = free_endpoint();
    let _router = Proc::start("router", &["router", "--listen", &router]).ready();
    let alpha = free_endpoint();
    let mut a = Proc::start(
        "alpha",
        &[
            "tuples", "--name", "alpha", "--listen", &alpha, "set", "alpha", "x", "1", "--hold",
        ],
    );
    a.wait_for("ready", |l| l == "ready");
    for (mode, endpoint) in [("peer", &alpha), ("client", &router)] {
        let mut args = vec!["--connect", &nobody, "--connect", endpoint];
        if mode == "client" {
            args.push("--client");
        }
        args.extend(["--connect-timeout", "10", "peers"]);
        let started = std::time::Instant::now();
        let out = ecology(&args).output().expect("run ecology tuples");
        assert_eq!(out.status.code(), Some(0), "{mode}: {out:?}");
        // Well within the connect timeout, which it used to run out.
        assert!(
            started.elapsed() < Duration::from_secs(5),
            "{mode}: {:?}",
            started.elapsed()
        );
        let listed = stdout(&out);
        if mode == "peer" {
            assert!(listed.lines().any(|l| l == "alpha"), "{listed}");
        }
    }
}

/// `--listen tcp/127.0.0.1:0` takes a free port, and the readiness line names the port it
/// listens on: another process reaches the PEIS there.
#[test]
fn port_zero_is_shown_as_the_port_taken() {
    use crate::support::Proc;
    let mut hsm = Proc::start(
        "hsm",
        &[
            "peis",
            "scenarios/peis-home.toml",
            "--name",
            "hsm",
            "--listen",
            "tcp/127.0.0.1:0",
        ],
    );
    let ready = hsm.wait_for("ready", |l| l.starts_with("hsm ready"));
    let endpoint = ready
        .text
        .split("listening on ")
        .nth(1)
        .map(|rest| {
            rest.split([',', ';'])
                .next()
                .unwrap_or(rest)
                .trim()
                .to_string()
        })
        .expect("an endpoint");
    assert!(!endpoint.ends_with(":0"), "{}", ready.text);
    let got = run_joined(&endpoint, &["get", "hsm", "components.ca1.type"]);
    assert_eq!(
        (got.status.code(), stdout(&got).as_str()),
        (Some(0), "cams\n"),
        "{got:?}"
    );
}
