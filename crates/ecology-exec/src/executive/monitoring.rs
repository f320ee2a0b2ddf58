//! Monitoring: what the components of the configuration report (status, observations,
//! unreadable inputs), remote sets that failed or got no answer, grace periods that ran out,
//! and the failures that exclude a component and reconfigure the action.

use std::time::Duration;

use ecology_config::Exclusion;
use ecology_tuples::contract::{self, ComponentField};
use ecology_tuples::{ComponentId, Key, PeisId};

use crate::log::LogEvent;
use crate::plan::parse_observations;

use super::deployment::{component_key, components_of, input_key};
use super::sequencer::Phase;
use super::timers::{Timer, start};
use super::{Command, ComponentKey, Executive};

/// The component a remote set of `key` is to: `components.C.reqState`, or `C.params` and
/// `C.mi-…`, where it is the first segment.
fn set_component(key: &Key) -> Option<ComponentId> {
    ComponentField::parse(key)
        .map(|(c, _)| c)
        .or_else(|| key.segments().next().and_then(|c| ComponentId::new(c).ok()))
}

impl Executive {
    /// A component reported `status`: running or done (its consumers wired to it now), in
    /// error (failed), or waiting (timed by its grace).
    pub(super) fn on_status(&mut self, key: ComponentKey, status: &str, out: &mut Vec<Command>) {
        // Components outside the current configuration, and ones that already
        // failed during this action, are not acted on.
        if !self.in_current_config(&key) {
            return;
        }
        if self
            .run
            .as_ref()
            .is_none_or(|run| run.failed.contains(&key))
        {
            return;
        }
        if status == "waiting" && self.blame_unreadable(&key, out) {
            return;
        }
        let Some(run) = &mut self.run else { return };
        if status != "waiting" {
            if run.waiting.remove(&key) {
                out.push(Command::CancelTimer(Timer::Waiting(key.clone())));
            }
            // Its spell of waiting is over: a later one may be given longer again.
            run.waited_longer.remove(&key);
        }
        match status {
            "running" | "done" => {
                if let Phase::Deploying { pending } = &mut run.phase {
                    pending.remove(&key);
                }
                // Its consumers' inputs can point at it now.
                let (ready, later): (Vec<_>, Vec<_>) = std::mem::take(&mut run.deferred)
                    .into_iter()
                    .partition(|(producer, _)| *producer == key);
                run.deferred = later;
                out.extend(ready.into_iter().map(|(_, wire)| wire));
                if status == "done" {
                    run.done.insert(key);
                }
                self.check_deployed(out);
                self.check_done(out);
            }
            "error" => {
                let cause = self
                    .mirror
                    .component(key.0.as_str(), key.1.as_str())
                    .and_then(|c| c.cause.clone())
                    .unwrap_or_else(|| "error".to_string());
                self.failure(vec![key], cause, out);
            }
            "waiting" if !run.waiting.contains(&key) && run.phase == Phase::Running => {
                self.time_waiting(key, self.config.waiting_grace, out);
            }
            _ => {}
        }
    }

    /// A consumer that reports `waiting` because it cannot read an input
    /// (its cause is `unreadable INPUT: …`) blames the producer wired to that
    /// input: the producer failed, at once, and the consumer keeps its place.
    /// `false` when the cause is another, or names no input of `consumer`.
    fn blame_unreadable(&mut self, consumer: &ComponentKey, out: &mut Vec<Command>) -> bool {
        let Some(cause) = self
            .mirror
            .component(consumer.0.as_str(), consumer.1.as_str())
            .and_then(|c| c.cause.clone())
        else {
            return false;
        };
        let Some((input, detail)) = contract::parse_unreadable(&cause) else {
            return false;
        };
        let Some(config) = self.run.as_ref().and_then(|r| r.config.as_ref()) else {
            return false;
        };
        let into: Vec<&ecology_config::ChannelInstance> = config
            .channels
            .iter()
            .filter(|c| {
                &*c.to_peis == consumer.0.as_str() && &*c.to_component == consumer.1.as_str()
            })
            .collect();
        let prefix = format!("{}.mi-", consumer.1);
        let named = |c: &ecology_config::ChannelInstance| {
            input_key(&consumer.1, c, &config.channels)
                .is_some_and(|k| k.as_str().strip_prefix(&prefix) == Some(input))
        };
        let channel = into.iter().find(|c| named(c)).or_else(|| {
            // `image` for one of two images: only when it names one channel.
            let same: Vec<_> = into.iter().filter(|c| &*c.info_name == input).collect();
            (same.len() == 1).then(|| same[0])
        });
        let Some(producer) = channel.and_then(|c| component_key(&c.from_peis, &c.from_component))
        else {
            return false;
        };
        if producer == *consumer {
            return false;
        }
        let why = if detail.is_empty() {
            format!("{}:{} cannot read its {input}", consumer.0, consumer.1)
        } else {
            format!(
                "{}:{} cannot read its {input}: {detail}",
                consumer.0, consumer.1
            )
        };
        self.failure(vec![producer], why, out);
        true
    }

    /// A component of the configuration reported what it observed.
    pub(super) fn on_observed(
        &mut self,
        key: ComponentKey,
        literals: &str,
        out: &mut Vec<Command>,
    ) {
        if !self.in_current_config(&key) {
            return;
        }
        let Some(run) = &mut self.run else { return };
        let wanted = &self.plan[run.index].observe;
        if wanted.is_empty() || run.failed.contains(&key) {
            return;
        }
        match parse_observations(literals) {
            Ok(read) => {
                for o in read {
                    if wanted.contains(&o.atom) {
                        run.observed.insert(o.atom, o.holds);
                    }
                }
                self.check_done(out);
            }
            Err(why) => {
                let cause = format!("it wrote an observation that cannot be read: {why}");
                self.failure(vec![key], cause, out);
            }
        }
    }

    /// A PEIS left or restarted: every component of the configuration on it failed.
    pub(super) fn on_peis_gone(&mut self, peis: &PeisId, cause: String, out: &mut Vec<Command>) {
        let Some(config) = self.run.as_ref().and_then(|r| r.config.as_ref()) else {
            return;
        };
        let lost = components_of(config, |f| &*f.peis == peis.as_str());
        if !lost.is_empty() {
            self.failure(lost, cause, out);
        }
    }

    /// Starts the grace period of every component of the running
    /// configuration that reports `waiting` and has none: one that was
    /// waiting across a redeploy is timed again.
    pub(super) fn arm_waiting_timers(&mut self, out: &mut Vec<Command>) {
        let Some(run) = &self.run else { return };
        let Some(config) = &run.config else { return };
        let waiting: Vec<ComponentKey> = components_of(config, |_| true)
            .into_iter()
            .filter(|k| !run.waiting.contains(k) && !run.failed.contains(k))
            .filter(|(p, c)| {
                self.mirror
                    .component(p.as_str(), c.as_str())
                    .is_some_and(|v| v.status.as_deref() == Some("waiting"))
            })
            .collect();
        for key in waiting {
            self.time_waiting(key, self.config.waiting_grace, out);
        }
    }

    /// Times the waiting of `key`: it is judged when `after` runs out.
    fn time_waiting(&mut self, key: ComponentKey, after: Duration, out: &mut Vec<Command>) {
        out.push(start(Timer::Waiting(key.clone()), after));
        if let Some(run) = &mut self.run {
            run.waiting.insert(key);
        }
    }

    /// Whether a remote set asked of the PEIS of `consumer`, or of the PEIS of a producer wired
    /// to it, is still neither answered nor failed: the way there is not known to work, so what
    /// the consumer waits for may be held up on it.
    fn way_unproven(&self, consumer: &ComponentKey) -> bool {
        let Some(config) = self.run.as_ref().and_then(|r| r.config.as_ref()) else {
            return false;
        };
        let producers = config.channels.iter().filter(|c| {
            &*c.to_peis == consumer.0.as_str() && &*c.to_component == consumer.1.as_str()
        });
        std::iter::once(consumer.0.as_str())
            .chain(producers.map(|c| &*c.from_peis))
            .any(|p| self.in_flight.keys().any(|(q, _)| q.as_str() == p))
    }

    /// A remote set failed: logged, and when it deployed a component of the configuration, that
    /// component failed (it cannot be switched on or wired). A refusal fails it at once; a set that
    /// got no answer waits [`ExecConfig::unanswered_grace`](crate::ExecConfig::unanswered_grace)
    /// first, since the owner's departure, or the executive's own loss of the ecology, may be what
    /// kept the answer away, and each has its own remedy.
    pub(super) fn on_remote_set_failed(
        &mut self,
        owner: PeisId,
        key: Key,
        value: Option<String>,
        reason: String,
        unanswered: bool,
        out: &mut Vec<Command>,
    ) {
        let component = set_component(&key);
        self.record(LogEvent::RemoteSetFailed {
            owner: owner.to_string(),
            key: key.to_string(),
            reason: reason.clone(),
        });
        if let Some(component) = component {
            let target = (owner, component);
            // Whatever the executive believed it wrote there is unknown now, also if its PEIS
            // left meanwhile: the next configuration that uses it writes it again.
            self.params.remove(&target);
            if let Some(orphan) = self.orphans.get_mut(&target) {
                orphan.params = None;
            }
            if !unanswered && let Some(holders) = ecology_tuples::claims::held_by(&reason) {
                self.held_by_others(target, holders, out);
                return;
            }
            if self.in_current_config(&target) {
                let cause = format!("could not set {key}: {reason}");
                let held = self
                    .run
                    .as_ref()
                    .is_some_and(|run| run.unanswered.contains_key(&target));
                if !unanswered {
                    self.failure(vec![target], cause, out);
                } else if self.is_absent(&target.0) || self.lost.is_some() {
                    // Its PEIS gone already (its departure failed what it ran), or the ecology
                    // lost (nothing is blamed): nothing more to do.
                } else {
                    // Its PEIS is still heard: the set goes again, unless a later one of the
                    // same key follows it anyway. An answer clears the component.
                    let later = self
                        .in_flight
                        .contains_key(&(target.0.clone(), key.clone()));
                    if let Some(value) = value.filter(|_| !later) {
                        self.record(LogEvent::RemoteSetRetried {
                            owner: target.0.to_string(),
                            key: key.to_string(),
                        });
                        out.push(Command::RemoteSet {
                            owner: target.0.clone(),
                            key: key.clone(),
                            value,
                        });
                    }
                    if !held {
                        out.push(start(
                            Timer::Unanswered(target.clone()),
                            self.config.unanswered_grace,
                        ));
                        if let Some(run) = &mut self.run {
                            run.unanswered.insert(target, (key, cause));
                        }
                    }
                }
            }
        }
    }

    /// The owner of `target` refused a request because other executives, `holders`, hold it
    /// with other params or wiring (two executives planned from the same state, and the other
    /// asked first). Not a failure: nothing is blamed or excluded for good. The action is
    /// configured again without it, once, and it is considered again when its holders change.
    /// What was asked of it before the refusal is put back by make-before-break, like any
    /// component the new configuration does not use.
    pub(super) fn held_by_others(
        &mut self,
        target: ComponentKey,
        holders: Vec<PeisId>,
        out: &mut Vec<Command>,
    ) {
        if !self.in_current_config(&target) || self.lost.is_some() {
            return;
        }
        let Some(run) = &mut self.run else { return };
        if !run.held.insert(target.clone()) {
            return;
        }
        self.record(LogEvent::Held {
            peis: target.0.to_string(),
            component: target.1.to_string(),
            holders: holders.iter().map(ToString::to_string).collect(),
        });
        self.configure(true, out);
    }

    /// A remote set was answered: if it was sent again after getting no answer, its component
    /// is cleared.
    pub(super) fn on_remote_set_answered(
        &mut self,
        owner: PeisId,
        key: &Key,
        out: &mut Vec<Command>,
    ) {
        let Some(run) = &mut self.run else { return };
        let Some(component) = set_component(key) else {
            return;
        };
        let target = (owner, component);
        if run.unanswered.get(&target).is_some_and(|(k, _)| k == key) {
            run.unanswered.remove(&target);
            out.push(Command::CancelTimer(Timer::Unanswered(target)));
        }
    }

    /// The components of the new configuration did not all report `running` in time: those
    /// still pending are to blame.
    pub(super) fn deploy_timed_out(&mut self, out: &mut Vec<Command>) {
        let Some(run) = &mut self.run else { return };
        if !std::mem::take(&mut run.deploy_timer) {
            return;
        }
        if let Phase::Deploying { pending } = &run.phase {
            // Components still switching on are to blame; only when every
            // pending one is on (and so waits for something) are all blamed.
            let starting: Vec<ComponentKey> = pending
                .iter()
                .filter(|(p, c)| {
                    !self
                        .mirror
                        .component(p.as_str(), c.as_str())
                        .is_some_and(|v| v.on)
                })
                .cloned()
                .collect();
            let (late, cause) = if starting.is_empty() {
                // A component waiting for a producer that is itself not
                // running is not to blame: its input is wired only once
                // the producer runs. Blame the pending components whose
                // producers all run (all of them, in a cycle).
                let config = run.config.as_ref();
                let starved = |key: &ComponentKey| {
                    config.is_some_and(|c| {
                        c.channels.iter().any(|ch| {
                            &*ch.to_peis == key.0.as_str()
                                && &*ch.to_component == key.1.as_str()
                                && component_key(&ch.from_peis, &ch.from_component).is_some_and(
                                    |producer| producer != *key && pending.contains(&producer),
                                )
                        })
                    })
                };
                let sources: Vec<ComponentKey> =
                    pending.iter().filter(|k| !starved(k)).cloned().collect();
                let late = if sources.is_empty() {
                    pending.iter().cloned().collect()
                } else {
                    sources
                };
                let cause = format!(
                    "did not report running within {:?}",
                    self.config.deploy_timeout
                );
                (late, cause)
            } else {
                let cause = format!(
                    "did not finish switching on within {:?}",
                    self.config.deploy_timeout
                );
                (starting, cause)
            };
            self.failure(late, cause, out);
        }
    }

    /// A remote set to `key` got no answer for
    /// [`ExecConfig::unanswered_grace`](crate::ExecConfig::unanswered_grace), and neither was it
    /// answered since.
    pub(super) fn unanswered_over(&mut self, key: ComponentKey, out: &mut Vec<Command>) {
        let Some(run) = &mut self.run else { return };
        let Some((_, cause)) = run.unanswered.remove(&key) else {
            return;
        };
        // Neither gone nor out of reach: the component is to blame after all.
        if self.is_present(&key.0) {
            let cause = format!(
                "{cause} ({} is still present {:?} later)",
                key.0, self.config.unanswered_grace
            );
            self.failure(vec![key], cause, out);
        }
    }

    /// `key` reported `waiting` for its whole grace: blamed, unless what it waits for may be
    /// held up, or nothing can stand in for it.
    pub(super) fn waiting_over(&mut self, key: ComponentKey, out: &mut Vec<Command>) {
        let Some(run) = &mut self.run else { return };
        if !run.waiting.remove(&key) {
            return;
        }
        let extended = run.waited_longer.contains(&key);
        if self.way_unproven(&key) {
            // Not the component's fault while its PEIS, or a producer's, has not answered
            // yet: the grace starts again, and the set is answered or fails meanwhile.
            self.time_waiting(key, self.config.waiting_grace, out);
            return;
        }
        let waited_for = self
            .mirror
            .component(key.0.as_str(), key.1.as_str())
            .and_then(|c| c.cause.clone());
        if !extended && !self.config.return_wait.is_zero() && !self.replaceable(&key) {
            // Nothing can stand in for it: it is given as long as a PEIS that left is waited
            // for, since what it waits for may only be held up (a link that keeps dropping).
            self.record(LogEvent::WaitingLonger {
                peis: key.0.to_string(),
                component: key.1.to_string(),
                waited_for: waited_for.clone().unwrap_or_default(),
                waiting: self.config.return_wait,
            });
            if let Some(run) = &mut self.run {
                run.waited_longer.insert(key.clone());
            }
            self.time_waiting(key, self.config.return_wait, out);
            return;
        }
        let grace = if extended {
            self.config.waiting_grace + self.config.return_wait
        } else {
            self.config.waiting_grace
        };
        let cause = waited_for.map_or_else(
            || format!("waiting for longer than {grace:?}"),
            |c| format!("waiting for longer than {grace:?}: {c}"),
        );
        self.failure(vec![key], cause, out);
    }

    /// Whether the action has a configuration without `key` (and without what it excludes
    /// already): a plan for the question alone, logged nowhere. A planner that runs out of
    /// budget counts as yes: nothing shows that the component cannot be done without.
    fn replaceable(&self, key: &ComponentKey) -> bool {
        let Some(run) = &self.run else { return true };
        let Some(goal) = &self.plan[run.index].goal else {
            return true;
        };
        let mut exclusions = run.excluded.clone();
        exclusions.push(Exclusion::Component {
            peis: key.0.to_string(),
            component: key.1.to_string(),
        });
        self.add_unavailable(&mut exclusions);
        let state = self.planning_state(goal);
        // Only whether one exists: no explanation, so that "none" is answered
        // before grounding when it can be.
        self.plan_configurations(&state, goal, &exclusions, 1, false)
            .is_ok_and(|o| {
                !o.configurations.is_empty() || o.status == ecology_config::Status::BudgetExceeded
            })
    }

    /// Excludes the failed components and reconfigures the action; while the
    /// ecology is lost, nothing is judged a failure.
    pub(super) fn failure(
        &mut self,
        failed: Vec<ComponentKey>,
        cause: String,
        out: &mut Vec<Command>,
    ) {
        if self.lost.is_some() {
            return;
        }
        let Some(run) = &mut self.run else { return };
        let fresh: Vec<ComponentKey> = failed
            .into_iter()
            .filter(|k| !run.failed.contains(k))
            .collect();
        if fresh.is_empty() {
            return;
        }
        run.failed.extend(fresh.iter().cloned());
        let names = fresh
            .into_iter()
            .map(|(p, c)| (p.to_string(), c.to_string()))
            .collect();
        self.exclude(names, cause, out);
    }

    /// Excludes the components `failed` (PEIS and name) for the rest of the
    /// action, logs why, and reconfigures.
    pub(super) fn exclude(
        &mut self,
        failed: Vec<(String, String)>,
        cause: String,
        out: &mut Vec<Command>,
    ) {
        let Some(run) = &mut self.run else { return };
        for (peis, component) in &failed {
            run.excluded.push(Exclusion::Component {
                peis: peis.clone(),
                component: component.clone(),
            });
        }
        let excluded: Vec<String> = run.excluded.iter().map(ToString::to_string).collect();
        for (peis, component) in failed {
            self.record(LogEvent::Failure {
                peis,
                component,
                cause: cause.clone(),
            });
        }
        self.record(LogEvent::Reconfiguration { excluded });
        self.configure(true, out);
    }
}
