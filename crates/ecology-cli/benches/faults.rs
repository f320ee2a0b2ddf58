//! Real faults, measured: the world, astrid and hsm run as processes over
//! Zenoh on 127.0.0.1; each round starts the executive on one move of
//! Astrid's, waits until she navigates on hsm's ceiling cameras, then kills
//! (SIGKILL) or freezes (SIGSTOP) the hsm process, and measures
//!
//! - fault → detected: from the signal to the executive's `failure` line
//!   (read from its stdout, so the pipe is included);
//! - detected → running: from the `failure` to the `running` of the new
//!   configuration, on the executive's own clock (planning, the remote sets,
//!   and the components reporting `running`).
//!
//! Astrid's laser is already on, so the new configuration starts nothing: a
//! component's own start-up time is not measured. hsm runs with a 1 s lease,
//! the reference a frozen PEIS is measured against.
//!
//! `cargo bench -p ecology-cli --bench faults` (30 rounds of each; set
//! `ECOLOGY_FAULT_ROUNDS` for another number).

#[path = "../tests/cli/support.rs"]
mod support;

use std::time::{Duration, Instant};

use nix::sys::signal::Signal;
use support::{Ecology, Fixture, Proc, TO_BEDROOM, TO_ENTRANCE, Variant, as_strs, event, is_event};

const LEASE: Duration = Duration::from_secs(1);

#[derive(Clone, Copy, PartialEq)]
enum Fault {
    Kill,
    Stop,
}

struct Round {
    detected: Duration,
    reconfigured: Duration,
}

fn percentile(values: &mut [Duration], p: f64) -> Duration {
    values.sort();
    let rank = ((p / 100.0) * values.len() as f64).ceil() as usize;
    values[rank.clamp(1, values.len()) - 1]
}

fn ms(d: Duration) -> String {
    format!("{:.1}", d.as_secs_f64() * 1000.0)
}

fn round(ecology: &mut Ecology, fixture: &Fixture, fault: Fault) -> Round {
    let mut task = ecology.task(fixture, &["--settle", "0.2"]);
    task.wait_for("running", |l| is_event(l, "running"));
    let signal = match fault {
        Fault::Kill => Signal::SIGKILL,
        Fault::Stop => Signal::SIGSTOP,
    };
    ecology.hsm.signal(signal);
    let at = Instant::now();
    let failure = task.wait_for("a failure", |l| is_event(l, "failure"));
    let running = task.wait_for("running again", |l| is_event(l, "running"));
    let t = |line: &support::Line| event(&line.text)["t"].as_f64().unwrap_or(0.0);
    let round = Round {
        detected: failure.at.duration_since(at),
        reconfigured: Duration::from_secs_f64((t(&running) - t(&failure)).max(0.0)),
    };
    // Stop the task (it releases what it used) and bring hsm back for the next round.
    task.signal(Signal::SIGINT);
    let _ = task.finish();
    ecology.hsm.signal(Signal::SIGKILL);
    ecology.hsm = Proc::start("hsm", &as_strs(&ecology.hsm_args)).ready();
    round
}

fn main() {
    // `cargo bench` passes `--bench`; this benchmark takes no other arguments.
    let rounds: usize = std::env::var("ECOLOGY_FAULT_ROUNDS")
        .ok()
        .and_then(|n| n.parse().ok())
        .unwrap_or(30);
    support::QUIET.store(true, std::sync::atomic::Ordering::Relaxed);
    let there = Fixture::new("bench-there", &[TO_BEDROOM], Variant::LaserOn);
    let back = Fixture::new("bench-back", &[TO_ENTRANCE], Variant::LaserOn);
    let lease = format!("{}", LEASE.as_secs_f64());
    let mut ecology = Ecology::start(&there, &["--lease", &lease]);
    println!(
        "{rounds} rounds per fault; world, astrid and hsm as processes on 127.0.0.1; hsm's lease {} ms",
        LEASE.as_millis()
    );
    println!(
        "{:<8} {:>4}  {:>22}  {:>22}  {:>18}  target",
        "fault", "n", "fault→detected p50/p99", "detected→running p50/p99", "total p50/p99"
    );
    for fault in [Fault::Kill, Fault::Stop] {
        let mut detected = Vec::new();
        let mut reconfigured = Vec::new();
        let mut total = Vec::new();
        for i in 0..rounds {
            let fixture = if i % 2 == 0 { &there } else { &back };
            let r = round(&mut ecology, fixture, fault);
            detected.push(r.detected);
            reconfigured.push(r.reconfigured);
            total.push(r.detected + r.reconfigured);
        }
        let (name, target) = match fault {
            Fault::Kill => (
                "SIGKILL",
                format!(
                    "total p99 < 50 ms: {}",
                    if percentile(&mut total, 99.0) < Duration::from_millis(50) {
                        "met"
                    } else {
                        "NOT met"
                    }
                ),
            ),
            Fault::Stop => {
                let bound = LEASE + Duration::from_millis(100);
                let p99 = percentile(&mut detected, 99.0);
                (
                    "SIGSTOP",
                    format!(
                        "detected p99 < lease + 100 ms: {} (p99 = {:.2} × lease)",
                        if p99 < bound { "met" } else { "NOT met" },
                        p99.as_secs_f64() / LEASE.as_secs_f64()
                    ),
                )
            }
        };
        println!(
            "{:<8} {:>4}  {:>22}  {:>22}  {:>18}  {}",
            name,
            rounds,
            format!(
                "{} / {} ms",
                ms(percentile(&mut detected, 50.0)),
                ms(percentile(&mut detected, 99.0))
            ),
            format!(
                "{} / {} ms",
                ms(percentile(&mut reconfigured, 50.0)),
                ms(percentile(&mut reconfigured, 99.0))
            ),
            format!(
                "{} / {} ms",
                ms(percentile(&mut total, 50.0)),
                ms(percentile(&mut total, 99.0))
            ),
            target
        );
    }
}
