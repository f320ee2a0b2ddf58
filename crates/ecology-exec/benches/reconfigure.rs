//! Reconfiguration latency, in-process, per phase: from the tracking system's
//! failure to the new configuration fully wired and running.
//!
//! Each run starts the paper's PEIS-Home (Astrid, the home security monitor,
//! Pippi) on the in-process tuple space with real time and no start-up
//! delays, lets the executive configure `(navigate astrid bedroom)` with the
//! ceiling cameras, then makes the tracking system fail. Phases:
//! - detect: the failure happening → the executive handling the `error` status;
//! - acquire: building the ecology state from the mirror;
//! - plan: the configuration planner;
//! - deploy: deploy commands sent → every component of the new configuration running.
//!
//! Run with `cargo bench -p ecology-exec --bench reconfigure` (`-- --quick` for fewer runs).

use std::sync::Arc;
use std::time::Duration;

use ecology_domain::{EcologyState, parse_domain, parse_facts, parse_goal};
use ecology_exec::{DriverConfig, ExecConfig, Executive, LogEvent, PlannedAction, drive};
use ecology_peis::{Component, ComponentError, Context};
use ecology_tuples::{
    Clock, InProcessPeis, InProcessSpace, PeisId, PeisOptions, SystemClock, Timestamp, Value,
};

// The hosts the executive's tests run against; the benchmark does not make PEIS vanish.
#[allow(dead_code)]
#[path = "../src/tests/peis_home.rs"]
mod peis_home;

use ecology_config::WallClock;
use peis_home::Hosts;

const PEIS_HOME: &[u8] = include_bytes!("../../../domains/peis-home.eco");
const FACTS: &[u8] = include_bytes!("../../../domains/peis-home.facts");

/// The executive's stopwatch: real time.
fn io(functionality: &str) -> (&'static [&'static str], &'static [&'static str]) {
    match functionality {
        "laser" => (&[], &["range-scan"]),
        "odometry" => (&[], &["odometry"]),
        "ceiling-cameras" | "camera" => (&[], &["image"]),
        "scan-matching" => (&["range-scan", "odometry"], &["position"]),
        "pose-tracking" => (&["global-pos"], &["position"]),
        "tracking-system" | "object-localizer" => (&["image"], &["global-pos"]),
        "navigation" => (&["position"], &[]),
        _ => (&[], &[]),
    }
}

/// An event-driven component: running as soon as every input has a value,
/// publishing its outputs on every input (producers every 10 ms); `fail`
/// makes it return an error at once.
fn body(fail: Arc<tokio::sync::Notify>) -> Arc<dyn Component<InProcessPeis>> {
    Arc::new(move |ctx: Context<InProcessPeis>| {
        let fail = fail.clone();
        async move {
            let (ins, outs) = io(ctx.functionality());
            let mut inputs = ctx.inputs(ins).await?;
            let mut running = false;
            loop {
                inputs.poll();
                if inputs.missing(Duration::from_secs(1)).is_empty() {
                    if !running {
                        ctx.status("running", None).await?;
                        running = true;
                    }
                    for out in outs {
                        ctx.output(out, Value::text("x")).await?;
                    }
                }
                tokio::select! {
                    () = fail.notified() => return Err(ComponentError::Fault("camera stopped".into())),
                    _ = inputs.changed(), if !ins.is_empty() => {}
                    () = ctx.sleep(Duration::from_millis(10)), if ins.is_empty() => {}
                }
            }
        }
    })
}

/// One run; returns (detect, acquire, plan, deploy, total) in microseconds.
async fn run_once() -> Option<[f64; 5]> {
    let clock: Arc<dyn Clock> = Arc::new(SystemClock);
    let space = InProcessSpace::new(clock.clone());
    let facts = parse_facts(FACTS).ok()?;
    let fail = Arc::new(tokio::sync::Notify::new());
    let never = Arc::new(tokio::sync::Notify::new());
    let hosts = Hosts::start(&space, &clock, &facts, Duration::ZERO, |p, c| {
        body(if (p, c) == ("hsm", "tr1") {
            fail.clone()
        } else {
            never.clone()
        })
    })
    .ok()?;
    let me = space
        .join(PeisId::new("executive").ok()?, PeisOptions::default())
        .ok()?;
    let domain = parse_domain(PEIS_HOME).ok()?;
    let plan = vec![PlannedAction::new(
        "(move astrid entrance bedroom)".to_string(),
        Some(parse_goal("(navigate astrid bedroom)").ok()?),
    )];
    let mut exec = Executive::new(domain, EcologyState::new(), plan, ExecConfig::default())
        .with_stopwatch(Box::new(WallClock::start()));
    let driver_start: Timestamp = clock.now();
    let trigger_at = Arc::new(std::sync::Mutex::new(None::<Timestamp>));
    let trigger = {
        let trigger_at = trigger_at.clone();
        let clock = clock.clone();
        let fail = fail.clone();
        tokio::spawn(async move {
            tokio::time::sleep(Duration::from_millis(150)).await;
            if let Ok(mut at) = trigger_at.lock() {
                *at = Some(clock.now());
            }
            fail.notify_one();
        })
    };
    let config = DriverConfig {
        settle: Duration::from_millis(20),
        limit: Some(Duration::from_millis(350)),
        ..DriverConfig::default()
    };
    drive(&me, clock.clone(), &mut exec, config).await.ok()?;
    let _ = trigger.await;
    hosts.stop().await;
    space.shutdown().await;

    let triggered = trigger_at.lock().ok().and_then(|at| *at)?;
    let t0 = triggered
        .saturating_duration_since(driver_start)
        .as_secs_f64()
        * 1e6;
    let log = exec.log();
    let failure = log
        .iter()
        .position(|e| matches!(e.event, LogEvent::Failure { .. }))?;
    let after = &log[failure..];
    let us = |e: &ecology_exec::LogEntry| e.t.as_secs_f64() * 1e6;
    let acquire = after.iter().find_map(|e| match e.event {
        LogEvent::StateAcquired { micros, .. } => Some(micros as f64),
        _ => None,
    })?;
    let (plan_us, configured) = after.iter().find_map(|e| match e.event {
        LogEvent::Configuration {
            micros,
            reconfiguration: true,
            ..
        } => Some((micros as f64, us(e))),
        _ => None,
    })?;
    let running = after
        .iter()
        .find(|e| matches!(e.event, LogEvent::Running { .. }))
        .map(us)?;
    let detect = us(&log[failure]) - t0;
    // Log times are taken when an event arrives, so the acquisition and
    // planning done while handling the failure fall inside `running - configured`.
    let deploy = (running - configured - acquire - plan_us).max(0.0);
    Some([detect, acquire, plan_us, deploy, running - t0])
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    let i = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    let runs = if quick { 10 } else { 60 };
    let runtime = match tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("cannot start a runtime: {e}");
            std::process::exit(1);
        }
    };
    let mut samples: Vec<[f64; 5]> = Vec::new();
    let mut failed = 0;
    for _ in 0..runs {
        match runtime.block_on(run_once()) {
            Some(s) => samples.push(s),
            None => failed += 1,
        }
    }
    println!(
        "reconfiguration latency, in-process, {} runs ({failed} without a complete reconfiguration):",
        samples.len()
    );
    println!("{:>10} {:>12} {:>12}", "phase", "p50", "p99");
    for (i, phase) in ["detect", "acquire", "plan", "deploy", "total"]
        .iter()
        .enumerate()
    {
        let mut v: Vec<f64> = samples.iter().map(|s| s[i]).collect();
        v.sort_by(f64::total_cmp);
        if v.is_empty() {
            continue;
        }
        println!(
            "{phase:>10} {:>9.0} µs {:>9.0} µs",
            percentile(&v, 0.5),
            percentile(&v, 0.99)
        );
    }
    println!("target: total p50 under 1 ms (1000 µs)");
}
