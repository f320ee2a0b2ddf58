//! Membership: PEIS that leave and come back. Departures within a loss window judged
//! together, the ecology lost and back, an action waiting for the PEIS it cannot do without,
//! and orphans: what was written to a PEIS that left, taken back or put back on its return.

use std::collections::{BTreeMap, BTreeSet};

use ecology_config::Exclusion;
use ecology_tuples::PeisId;

use crate::log::LogEvent;

use super::timers::{Timer, start};
use super::{Command, ComponentKey, Executive};

/// Takes the entries of `map` for the components of `peis` out of it.
fn take_on<V>(map: &mut BTreeMap<ComponentKey, V>, peis: &PeisId) -> Vec<(ComponentKey, V)> {
    let keys: Vec<ComponentKey> = map.keys().filter(|(p, _)| p == peis).cloned().collect();
    keys.into_iter()
        .filter_map(|k| map.remove(&k).map(|v| (k, v)))
        .collect()
}

/// What the executive had written to a component of a PEIS that left: what it
/// takes back, or puts back, when that PEIS returns in the same run.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub(super) struct Orphan {
    /// The executive switched it on.
    pub(super) switched_on: bool,
    /// The params it gave it.
    pub(super) params: Option<String>,
}

/// The action's exclusions and failed components at one moment: what they are again when what
/// happened since is forgiven.
type Excluded = (Vec<Exclusion>, BTreeSet<ComponentKey>);

/// PEIS that left within one [`ExecConfig::loss_window`](crate::ExecConfig::loss_window), judged
/// together when it closes ([`Timer::LossWindow`]).
#[derive(Debug)]
pub(super) struct Departures {
    /// Every PEIS that left in the window, those back since included.
    pub(super) gone: Vec<PeisId>,
    /// How many PEIS were present before the first left.
    pub(super) present_before: usize,
    /// The action's exclusions and failed components before the first left: what they are again
    /// if the ecology turns out lost (its components did not fail; the network did).
    pub(super) before: Excluded,
    /// Why the action found no configuration meanwhile: it fails with that once the departures
    /// are judged, unless the ecology was lost.
    pub(super) no_configuration: Option<String>,
}

/// PEIS that left, judged gone, without whom the action found no configuration: it waits
/// [`ExecConfig::return_wait`](crate::ExecConfig::return_wait) for them before it fails
/// ([`Timer::ReturnWait`]).
#[derive(Debug)]
pub(super) struct Awaited {
    /// Those still gone.
    pub(super) gone: BTreeSet<PeisId>,
    /// Those back, whose tuples are read again for a loss window before the action is
    /// configured again (one restarted comes back with new tuples).
    pub(super) back: BTreeSet<PeisId>,
    /// Whether [`Timer::ReturnSettle`] runs: a loss window after the latest return.
    pub(super) settle: bool,
    /// The action's exclusions and failed components before they left: what their return
    /// allows again.
    pub(super) before: Excluded,
    /// Why the action has no configuration without them.
    pub(super) reason: String,
}

/// The executive lost the ecology: it waits for it ([`Timer::Reconnect`]), acting on nothing.
#[derive(Debug)]
pub(super) struct Lost {
    /// The PEIS that left at once.
    pub(super) gone: BTreeSet<PeisId>,
    /// Those of them back since.
    pub(super) back: BTreeSet<PeisId>,
    /// How many PEIS were present before the first left.
    pub(super) present_before: usize,
    /// Whether [`Timer::LostSettle`] runs, a window after the latest return: then the task goes
    /// on, if most are back.
    pub(super) settle: bool,
}

impl Executive {
    /// A PEIS that restarted starts afresh: forget what was written to its
    /// components, so a new deploy writes it again.
    pub(super) fn forget(&mut self, peis: &PeisId) {
        self.params.retain(|(p, _), _| p != peis);
        self.started.retain(|(p, _)| p != peis);
        self.maybe_written.retain(|(p, _)| p != peis);
        self.orphans.retain(|(p, _), _| p != peis);
    }

    /// Whether `peis` is present.
    pub(super) fn is_present(&self, peis: &PeisId) -> bool {
        self.mirror.peis().get(peis).is_some_and(|v| v.present)
    }

    /// Whether `peis` is known to be away (not merely never heard of).
    pub(super) fn is_absent(&self, peis: &PeisId) -> bool {
        self.mirror.peis().get(peis).is_some_and(|v| !v.present)
    }

    /// How many PEIS are present.
    fn present_count(&self) -> usize {
        self.mirror.peis().values().filter(|v| v.present).count()
    }

    /// A PEIS left: what was written to it is kept as orphans (it may come back in the same
    /// run, still running it), and the departure is judged a window later, with any others.
    pub(super) fn on_left(&mut self, peis: PeisId, out: &mut Vec<Command>) {
        let was_present = self.is_present(&peis);
        let present_before = self.present_count();
        self.mirror.left(&peis);
        if !was_present {
            return;
        }
        if self.run.is_some() {
            self.record(LogEvent::PeisLeft {
                peis: peis.to_string(),
            });
        }
        let started: Vec<ComponentKey> = self
            .started
            .iter()
            .filter(|(p, _)| *p == peis)
            .cloned()
            .collect();
        for key in started {
            self.started.remove(&key);
            self.orphans.entry(key).or_default().switched_on = true;
        }
        for (key, value) in take_on(&mut self.params, &peis) {
            self.orphans.entry(key).or_default().params = Some(value);
        }
        if self.lost.is_some() {
            return;
        }
        let Some(run) = &self.run else { return };
        match &mut self.departures {
            Some(departures) => departures.gone.push(peis.clone()),
            None => {
                let before = (run.excluded.clone(), run.failed.clone());
                out.push(start(Timer::LossWindow, self.config.loss_window));
                self.departures = Some(Departures {
                    gone: vec![peis.clone()],
                    present_before,
                    before,
                    no_configuration: None,
                });
            }
        }
        self.on_peis_gone(&peis, format!("PEIS {peis} left the ecology"), out);
    }

    /// A PEIS joined. While the ecology is lost, returns are counted towards going on; while
    /// departures are judged, it is dealt with at the judgement (its tuples, which the mirror
    /// shows as they were before it left, are read again meanwhile); otherwise what the
    /// executive wrote to it before it left and no longer uses is put back (its components were
    /// failed when it left, so the configuration has moved on).
    pub(super) fn on_joined(&mut self, peis: PeisId, out: &mut Vec<Command>) {
        let was_present = self.is_present(&peis);
        self.mirror.joined(&peis);
        if was_present {
            return;
        }
        if self.run.is_some() {
            self.record(LogEvent::PeisJoined {
                peis: peis.to_string(),
            });
        }
        if let Some(lost) = &mut self.lost {
            if lost.gone.contains(&peis) {
                lost.back.insert(peis);
                lost.settle = true;
                out.push(start(Timer::LostSettle, self.config.loss_window));
            }
            return;
        }
        if self
            .departures
            .as_ref()
            .is_some_and(|d| d.gone.contains(&peis))
        {
            return;
        }
        if self
            .awaited
            .as_ref()
            .is_some_and(|a| a.gone.contains(&peis))
        {
            self.on_awaited_return(peis, out);
            return;
        }
        self.reclaim(&peis);
        self.release_unused(&peis, out);
    }

    /// Takes back what was written to `peis` before it left: a switch-on always (asking for
    /// `off` releases this executive's claim and switches off nothing another holds), params
    /// where the mirror shows the same (or none yet). Params that show empty were put back by
    /// the PEIS (its executive gone too long) or are a write that has not echoed yet and may
    /// still land: not believed to run, but cleared if no configuration writes them again.
    fn reclaim(&mut self, peis: &PeisId) {
        for (key, orphan) in take_on(&mut self.orphans, peis) {
            if orphan.switched_on {
                self.started.insert(key.clone());
            }
            if let Some(params) = orphan.params {
                let view = self.mirror.component(key.0.as_str(), key.1.as_str());
                match view.and_then(|v| v.params.as_deref()).map(str::trim) {
                    None => {
                        self.params.insert(key, params);
                    }
                    Some(seen) if seen == params.trim() => {
                        self.params.insert(key, params);
                    }
                    Some("") => {
                        self.maybe_written.insert(key);
                    }
                    // Someone else's params: not this executive's to take back.
                    Some(_) => {}
                }
            }
        }
    }

    /// Puts back what this task wrote to `peis` that the current configuration does not use.
    fn release_unused(&mut self, peis: &PeisId, out: &mut Vec<Command>) {
        let (switched_off, stopped) = self.put_back(
            |exec, key| key.0 == *peis && !exec.in_current_config(key),
            out,
        );
        if !switched_off.is_empty() || !stopped.is_empty() {
            self.record(LogEvent::Reclaimed {
                peis: peis.to_string(),
                switched_off,
                stopped,
            });
        }
    }

    /// The window of departures closed: the executive lost the ecology when at least two, and
    /// more than half of the PEIS present, are still gone; otherwise each is a failure of its
    /// components, acted on with what else failed meanwhile.
    pub(super) fn judge_departures(&mut self, out: &mut Vec<Command>) {
        let Some(departures) = self.departures.take() else {
            return;
        };
        if self.run.is_none() || self.finished {
            return;
        }
        let (gone, returned): (BTreeSet<PeisId>, BTreeSet<PeisId>) =
            departures.gone.into_iter().partition(|p| self.is_absent(p));
        if gone.len() >= 2 && gone.len() * 2 > departures.present_before {
            // Waiting already for others, who are among the lost now: from before them.
            let before = match &self.awaited {
                Some(awaited) => awaited.before.clone(),
                None => departures.before,
            };
            self.stop_awaiting(out);
            if let Some(run) = &mut self.run {
                (run.excluded, run.failed) = before;
            }
            self.stop_component_timers(out);
            self.record(LogEvent::EcologyLost {
                gone: gone.iter().map(ToString::to_string).collect(),
                present: departures.present_before,
                waiting: self.config.reconnect_timeout,
            });
            out.push(start(Timer::Reconnect, self.config.reconnect_timeout));
            self.lost = Some(Lost {
                gone: gone.into_iter().collect(),
                back: BTreeSet::new(),
                present_before: departures.present_before,
                settle: false,
            });
            return;
        }
        // Those back already were away for less than the window (the executive's own process or
        // link stalled, say): what their departure took out of the action is allowed again.
        self.forgive(&returned, &departures.before);
        for peis in &returned {
            self.reclaim(peis);
        }
        if let Some(reason) = departures.no_configuration {
            // Those still gone may be back shortly (a robot on a poor link): the action waits
            // for them before it fails.
            let waits = !gone.is_empty() && !self.config.return_wait.is_zero();
            if waits {
                self.await_return(gone, departures.before, reason.clone(), out);
            }
            if !returned.is_empty() {
                // Found while they were away: configured again from the ecology as it is now.
                self.configure(true, out);
            } else if !waits {
                self.fail_action(reason, out);
            }
        }
        for peis in &returned {
            self.release_unused(peis, out);
        }
    }

    /// Allows again what the departure of the PEIS `back` took out of the action: the
    /// exclusions and failures that were not there `before` it.
    fn forgive(&mut self, back: &BTreeSet<PeisId>, before: &Excluded) {
        let Some(run) = &mut self.run else { return };
        let (before_excluded, before_failed) = before;
        let is_back = |peis: &str| back.iter().any(|p| p.as_str() == peis);
        run.excluded.retain(|e| {
            let (Exclusion::Component { peis, .. } | Exclusion::Peis(peis)) = e;
            !is_back(peis) || before_excluded.contains(e)
        });
        run.failed
            .retain(|k| !back.contains(&k.0) || before_failed.contains(k));
    }

    /// The action found no configuration without the PEIS `gone`, judged gone: it waits
    /// [`ExecConfig::return_wait`](crate::ExecConfig::return_wait) for them, with any it waited for
    /// already.
    fn await_return(
        &mut self,
        gone: BTreeSet<PeisId>,
        before: Excluded,
        reason: String,
        out: &mut Vec<Command>,
    ) {
        // Its timer starts again, for the earlier PEIS too.
        let (mut all, back, settle, before) = match self.awaited.take() {
            // The earlier snapshot: it is before every departure waited for.
            Some(earlier) => (earlier.gone, earlier.back, earlier.settle, earlier.before),
            None => (BTreeSet::new(), BTreeSet::new(), false, before),
        };
        all.extend(gone);
        self.stop_component_timers(out);
        self.record(LogEvent::AwaitingReturn {
            gone: all.iter().map(ToString::to_string).collect(),
            waiting: self.config.return_wait,
        });
        out.push(start(Timer::ReturnWait, self.config.return_wait));
        self.awaited = Some(Awaited {
            gone: all,
            back,
            settle,
            before,
            reason,
        });
    }

    /// A PEIS the action waited for is back: its tuples are read again for a loss window, then
    /// the action is configured again ([`Executive::settle_returns`]).
    fn on_awaited_return(&mut self, peis: PeisId, out: &mut Vec<Command>) {
        let Some(awaited) = &mut self.awaited else {
            return;
        };
        awaited.gone.remove(&peis);
        awaited.back.insert(peis);
        awaited.settle = true;
        out.push(start(Timer::ReturnSettle, self.config.loss_window));
    }

    /// A loss window after the latest return of PEIS the action waited for: what their departure
    /// took out of the action (and their restart, if they restarted) is allowed again, and the
    /// action is configured again from the ecology as it is now; what they no longer run is put
    /// back.
    pub(super) fn settle_returns(&mut self, out: &mut Vec<Command>) {
        let Some(awaited) = &mut self.awaited else {
            return;
        };
        awaited.settle = false;
        let back = std::mem::take(&mut awaited.back);
        let before = awaited.before.clone();
        self.forgive(&back, &before);
        for peis in &back {
            self.reclaim(peis);
        }
        self.configure(true, out);
        for peis in &back {
            self.release_unused(peis, out);
        }
    }

    /// The wait for PEIS to return ran out. Those back, their tuples still being read again,
    /// are configured with now, without those still gone; otherwise the action fails, saying
    /// whom it waited for.
    pub(super) fn return_wait_over(&mut self, out: &mut Vec<Command>) {
        let Some(mut awaited) = self.awaited.take() else {
            return;
        };
        if !awaited.back.is_empty() {
            if std::mem::take(&mut awaited.settle) {
                out.push(Command::CancelTimer(Timer::ReturnSettle));
            }
            awaited.gone.clear();
            self.awaited = Some(awaited);
            // With no configuration then, the action fails.
            self.settle_returns(out);
            return;
        }
        // Said on the reason's first line, ahead of the explanation's tree.
        let gone: Vec<String> = awaited.gone.iter().map(ToString::to_string).collect();
        let (first, rest) = match awaited.reason.split_once('\n') {
            Some((first, rest)) => (first, format!("\n{rest}")),
            None => (awaited.reason.as_str(), String::new()),
        };
        let reason = format!(
            "{first}; {} left and {} not back within {:?}{rest}",
            gone.join(", "),
            if gone.len() == 1 { "was" } else { "were" },
            self.config.return_wait,
        );
        self.fail_action(reason, out);
    }

    /// Stops waiting for PEIS to return, if it was.
    pub(super) fn stop_awaiting(&mut self, out: &mut Vec<Command>) {
        if let Some(awaited) = self.awaited.take() {
            out.push(Command::CancelTimer(Timer::ReturnWait));
            if awaited.settle {
                out.push(Command::CancelTimer(Timer::ReturnSettle));
            }
        }
    }

    /// The action has no configuration: it fails, or, while departures are judged, waits for
    /// the judgement (it may be the executive that lost the network).
    pub(super) fn no_configuration(&mut self, reason: String, out: &mut Vec<Command>) {
        if let Some(departures) = &mut self.departures {
            departures.no_configuration = Some(reason);
            self.stop_component_timers(out);
            return;
        }
        if let Some(awaited) = &mut self.awaited
            && !(awaited.gone.is_empty() && awaited.back.is_empty())
        {
            // Others it waits for may still return, or are back and settling.
            awaited.reason = reason;
            self.stop_component_timers(out);
            return;
        }
        self.stop_awaiting(out);
        self.fail_action(reason, out);
    }

    /// A window after the latest return of a lost PEIS: the task goes on when more than half
    /// of those lost are back, reconfiguring from the ecology as it is now.
    pub(super) fn try_resume(&mut self, out: &mut Vec<Command>) {
        let Some(lost) = &mut self.lost else { return };
        lost.settle = false;
        lost.back
            .retain(|p| self.mirror.peis().get(p).is_some_and(|v| v.present));
        if lost.back.len() * 2 <= lost.gone.len() {
            return;
        }
        let Some(lost) = self.lost.take() else { return };
        out.push(Command::CancelTimer(Timer::Reconnect));
        let missing: Vec<String> = lost
            .gone
            .difference(&lost.back)
            .map(ToString::to_string)
            .collect();
        self.record(LogEvent::EcologyBack {
            back: lost.back.iter().map(ToString::to_string).collect(),
            missing,
        });
        for peis in &lost.back {
            self.reclaim(peis);
        }
        // Its action's time counts afresh: what it timed was the network.
        if self.run.is_some() {
            out.push(start(Timer::Action, self.config.action_timeout));
        }
        self.configure(true, out);
    }

    /// The lost ecology did not come back in time: the task fails, saying so.
    pub(super) fn give_up(&mut self, out: &mut Vec<Command>) {
        let Some(lost) = self.lost.take() else { return };
        if lost.settle {
            out.push(Command::CancelTimer(Timer::LostSettle));
        }
        let names = |set: &BTreeSet<PeisId>| {
            set.iter()
                .map(ToString::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        };
        let back: BTreeSet<PeisId> = lost
            .back
            .iter()
            .filter(|p| self.is_present(p))
            .cloned()
            .collect();
        let came_back = if back.is_empty() {
            "none came back".to_string()
        } else {
            format!("only {} came back", names(&back))
        };
        let reason = format!(
            "the executive lost the ecology: {} of the {} PEIS present ({}) left at once, and {came_back} within {:?}; \
             the PEIS put back what it had switched on once it was gone for a second",
            lost.gone.len(),
            lost.present_before,
            names(&lost.gone),
            self.config.reconnect_timeout,
        );
        self.fail_action(reason.clone(), out);
        self.release(out);
        self.record(LogEvent::TaskFailed { reason });
    }
}
