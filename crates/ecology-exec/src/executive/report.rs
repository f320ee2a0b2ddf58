//! Where the executive stands, in words: what an operator reads from a process that seems stuck
//! (`ecology task` prints it on SIGUSR1).

use std::fmt::Write;

use super::sequencer::Phase;
use super::{Executive, RunStatus};

/// A component as `PEIS:C`.
fn named<'a>(components: impl IntoIterator<Item = &'a super::ComponentKey>) -> String {
    let names: Vec<String> = components
        .into_iter()
        .map(|(p, c)| format!("{p}:{c}"))
        .collect();
    if names.is_empty() {
        "none".to_string()
    } else {
        names.join(", ")
    }
}

impl Executive {
    /// Where the executive stands: the task's status, the action running and its phase, what is
    /// deployed, failed, held, waiting or unanswered, the remote sets not yet answered, and
    /// whether departures are being judged or the ecology is lost. One fact per line.
    pub fn describe(&self) -> String {
        let mut out = String::new();
        let status = match &self.status {
            RunStatus::Idle => "not started".to_string(),
            RunStatus::Running { index } => format!("running action {}", index + 1),
            RunStatus::Done => "done".to_string(),
            RunStatus::Failed { index, reason } => {
                let first = reason.lines().next().unwrap_or("");
                format!("failed at action {}: {first}", index + 1)
            }
        };
        let _ = writeln!(
            out,
            "task: {status}{}, {:.3} s in",
            if self.finished { ", released" } else { "" },
            self.now.as_secs_f64()
        );
        if let Some(run) = &self.run {
            let action = self.plan.get(run.index).map_or("?", |a| a.action.as_str());
            let phase = match &run.phase {
                Phase::Deploying { pending } => {
                    format!("deploying, waiting for {}", named(pending))
                }
                Phase::Running => "running, waiting for its postconditions".to_string(),
            };
            let _ = writeln!(out, "action {}: {action}: {phase}", run.index + 1);
            if let Some(config) = &run.config {
                let _ = writeln!(
                    out,
                    "  configuration: cost {}, {} functionalities, {} channels",
                    config.cost,
                    config.functionalities.len(),
                    config.channels.len()
                );
            }
            let _ = writeln!(out, "  failed: {}", named(&run.failed));
            let _ = writeln!(out, "  held by others: {}", named(&run.held));
            let _ = writeln!(out, "  waiting: {}", named(&run.waiting));
            let _ = writeln!(out, "  unanswered: {}", named(run.unanswered.keys()));
            let _ = writeln!(out, "  done: {}", named(&run.done));
        }
        let _ = writeln!(out, "switched on by this task: {}", named(&self.started));
        let in_flight: Vec<String> = self
            .in_flight
            .iter()
            .map(|((owner, key), values)| format!("{owner}:{key} ({} asked)", values.len()))
            .collect();
        let _ = writeln!(
            out,
            "remote sets not yet answered: {}",
            if in_flight.is_empty() {
                "none".to_string()
            } else {
                in_flight.join(", ")
            }
        );
        if self.departures.is_some() {
            let _ = writeln!(out, "judging departures of PEIS");
        }
        if self.lost.is_some() {
            let _ = writeln!(out, "the ecology is lost: waiting for it to come back");
        }
        if self.awaited.is_some() {
            let _ = writeln!(out, "waiting for PEIS to come back");
        }
        out
    }
}
