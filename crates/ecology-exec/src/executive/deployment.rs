//! Deployment: acquire the state, plan the cheapest configuration, deploy it (switch on, give
//! params, wire inputs, make-before-break), and put back what the task wrote when it no longer
//! needs it.

use std::collections::BTreeSet;
use std::time::Duration;

use ecology_config::{Clock as PlannerClock, Configuration, Exclusion, Options, Request};
use ecology_domain::{Call, EcologyState};
use ecology_tuples::contract::{self, ComponentField};
use ecology_tuples::{ComponentId, Key, PeisId};

use crate::log::{LogChannel, LogComponent, LogEvent, LogFunctionality, LogUnavailable};

use super::sequencer::Phase;
use super::timers::{Timer, start};
use super::{Command, ComponentKey, Executive};

/// The typed names of the component `peis`:`component` of a configuration;
/// `None` when either is not a valid name in the tuple space (the planner
/// reads names from facts, which may say anything).
pub(super) fn component_key(peis: &str, component: &str) -> Option<ComponentKey> {
    Some((PeisId::new(peis).ok()?, ComponentId::new(component).ok()?))
}

/// `component` as the log names it.
pub(super) fn logged(component: &ComponentKey) -> LogComponent {
    LogComponent::new(component.0.as_str(), component.1.as_str())
}

/// The first component of `config` whose PEIS or name is not valid in the
/// tuple space: it cannot be deployed.
fn invalid_component(config: &Configuration) -> Option<(String, String)> {
    let functionalities = config
        .functionalities
        .iter()
        .map(|f| (&f.peis, &f.component));
    let producers = config
        .channels
        .iter()
        .map(|c| (&c.from_peis, &c.from_component));
    functionalities
        .chain(producers)
        .find(|(p, c)| component_key(p, c).is_none())
        .map(|(p, c)| (p.to_string(), c.to_string()))
}

/// The components of `config`'s functionalities that `keep` selects.
pub(super) fn components_of(
    config: &Configuration,
    keep: impl Fn(&ecology_config::FunctionalityInstance) -> bool,
) -> Vec<ComponentKey> {
    config
        .functionalities
        .iter()
        .filter(|f| keep(f))
        .filter_map(|f| component_key(&f.peis, &f.component))
        .collect()
}

/// The remote set that switches `component` on or off.
fn req_state(component: &ComponentKey, state: &str) -> Command {
    Command::RemoteSet {
        owner: component.0.clone(),
        key: ComponentField::ReqState.key(&component.1),
        value: state.to_string(),
    }
}

/// The remote set that gives `component` its functionality instance (empty: none).
fn params(component: &ComponentKey, value: String) -> Command {
    Command::RemoteSet {
        owner: component.0.clone(),
        key: ComponentField::Params.key(&component.1),
        value,
    }
}

/// The key of the meta-tuple that wires channel `c` into its consumer:
/// `C.mi-INFO`, or `C.mi-INFO.ARG…` when the consumer has another input of
/// the same kind in `all` (two images from two cameras), so that the two
/// never share a key. `None` when the information's name makes no valid key.
pub(super) fn input_key(
    consumer: &ComponentId,
    c: &ecology_config::ChannelInstance,
    all: &[ecology_config::ChannelInstance],
) -> Option<Key> {
    let shared = all.iter().any(|other| {
        other.to_peis == c.to_peis
            && other.to_component == c.to_component
            && other.info_name == c.info_name
            && other.info != c.info
    });
    if !shared {
        return contract::input_key(consumer, &c.info_name, &[]).ok();
    }
    let args: Vec<&str> = c
        .info
        .trim_matches(|ch| ch == '(' || ch == ')')
        .split_whitespace()
        .skip(1)
        .filter(|a| !a.starts_with(':'))
        .take_while(|a| {
            a.chars()
                .all(|ch| ch.is_ascii_alphanumeric() || ch == '_' || ch == '-')
        })
        .collect();
    contract::input_key(consumer, &c.info_name, &args).ok()
}

/// `d` in whole microseconds, for the log.
fn micros(d: Duration) -> u64 {
    u64::try_from(d.as_micros()).unwrap_or(u64::MAX)
}

/// Measures how long acquisition and planning take, for the log. The
/// executive reads no clock of its own: without one, they log as 0 µs.
pub(super) struct Stopwatch(pub(super) Box<dyn PlannerClock + Send>);

impl std::fmt::Debug for Stopwatch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Stopwatch")
    }
}

/// The stopwatch's time since `start`: what a planning budget is measured by.
struct Since<'a> {
    clock: &'a (dyn PlannerClock + Send),
    start: Duration,
}

impl PlannerClock for Since<'_> {
    fn elapsed(&self) -> Duration {
        self.clock.elapsed().saturating_sub(self.start)
    }
}

impl Executive {
    /// The state a configuration for `goal` is planned from: the components of the types the
    /// goal's methods can use, or all of them when they could use any, and the atoms of the
    /// running action's precondition that the methods read ([`ecology_config::Planner::facts_at_action`]:
    /// where the robot is when it sets off, say).
    pub(super) fn planning_state(&self, goal: &Call) -> EcologyState {
        let types = ecology_config::component_types(self.planner.domain(), goal);
        let mut state = self.mirror.state(&self.world, types.as_ref());
        if let Some(run) = &self.run {
            for fact in self.planner.facts_at_action(&self.plan[run.index].action) {
                state.insert(fact);
            }
        }
        state
    }

    /// Acquires the state, plans the action's cheapest configuration without what it excludes,
    /// and deploys it; without one, the action has no configuration.
    pub(super) fn configure(&mut self, reconfiguration: bool, out: &mut Vec<Command>) {
        let Some(run) = &self.run else { return };
        let index = run.index;
        let mut exclusions = run.excluded.clone();
        exclusions.extend(run.held.iter().map(|(p, c)| Exclusion::Component {
            peis: p.to_string(),
            component: c.to_string(),
        }));
        let Some(goal) = self.plan[index].goal.clone() else {
            return;
        };
        let before = self.stopwatch.0.elapsed();
        let state = self.planning_state(&goal);
        let (peis, components) = self.mirror.counts();
        let unavailable = self.add_unavailable(&mut exclusions);
        let acquired = self.stopwatch.0.elapsed();
        self.record(LogEvent::StateAcquired {
            peis,
            components,
            unavailable,
            micros: micros(acquired.saturating_sub(before)),
        });
        let count = self.config.alternatives.max(1);
        let outcome = match self.plan_configurations(&state, &goal, &exclusions, count, true) {
            Ok(outcome) => outcome,
            Err(err) => {
                self.no_configuration(err.to_string(), out);
                return;
            }
        };
        let Some(chosen) = outcome.configurations.first().cloned() else {
            let reason = if outcome.status == ecology_config::Status::BudgetExceeded {
                format!(
                    "the configuration planner's budget ran out ({} nodes expanded) before it found a configuration for {goal}",
                    outcome.stats.expanded
                )
            } else {
                outcome
                    .explanation
                    .map_or_else(|| format!("no configuration for {goal}"), |e| e.to_string())
            };
            self.no_configuration(reason, out);
            return;
        };
        self.stop_awaiting(out);
        let planned = self.stopwatch.0.elapsed();
        self.record(LogEvent::Configuration {
            micros: micros(planned.saturating_sub(acquired)),
            goal: goal.to_string(),
            cost: chosen.cost,
            optimal: chosen.optimal,
            functionalities: chosen
                .functionalities
                .iter()
                .map(|f| LogFunctionality {
                    call: f.call(),
                    component: LogComponent::new(f.peis.clone(), f.component.clone()),
                })
                .collect(),
            alternatives: outcome.configurations.iter().map(|c| c.cost).collect(),
            reconfiguration,
        });
        if let Some((peis, component)) = invalid_component(&chosen) {
            let cause = "its PEIS or component name is not valid in the tuple space".to_string();
            self.exclude(vec![(peis, component)], cause, out);
            return;
        }
        self.deploy(chosen, out);
    }

    /// Adds the components that report `error` to `exclusions`: such a component stays out until
    /// it reports something else (its PEIS restarting it counts), whatever action it failed in.
    /// Returns why each one added is unavailable.
    pub(super) fn add_unavailable(&self, exclusions: &mut Vec<Exclusion>) -> Vec<LogUnavailable> {
        let mut unavailable = Vec::new();
        for (p, c, cause) in self.mirror.in_error() {
            let exclusion = Exclusion::Component {
                peis: p.to_string(),
                component: c.to_string(),
            };
            if !exclusions.contains(&exclusion) {
                exclusions.push(exclusion);
                unavailable.push(LogUnavailable {
                    component: logged(&(p, c)),
                    cause,
                });
            }
        }
        unavailable
    }

    /// Up to `count` configurations for `goal` in `state` without `exclusions`, under the
    /// planning budget, which counts from now; when there is none, why if `explain`.
    pub(super) fn plan_configurations(
        &self,
        state: &EcologyState,
        goal: &ecology_domain::Call,
        exclusions: &[Exclusion],
        count: usize,
        explain: bool,
    ) -> Result<ecology_config::Outcome, ecology_config::RequestError> {
        let request = Request {
            domain: self.planner.domain(),
            state,
            goal,
            exclusions,
        };
        let options = Options {
            count,
            budget: self.config.planning,
            explain,
        };
        let since = Since {
            clock: &*self.stopwatch.0,
            start: self.stopwatch.0.elapsed(),
        };
        self.planner.plan(&request, &options, &since)
    }

    /// Switches on, parameterizes and wires the components of `config`,
    /// whose names are all valid (`invalid_component` is `None`).
    pub(super) fn deploy(&mut self, config: Configuration, out: &mut Vec<Command>) {
        let mut switched_on = Vec::new();
        let mut pending = BTreeSet::new();
        let mut finished = Vec::new();
        for f in &config.functionalities {
            let Some(key) = component_key(&f.peis, &f.component) else {
                continue;
            };
            let view = self.mirror.component(&f.peis, &f.component);
            let on = view.is_some_and(|v| v.on);
            if !on {
                out.push(req_state(&key, "on"));
                self.started.insert(key.clone());
                switched_on.push(logged(&key));
            }
            let call = f.call();
            let unchanged = self.params.get(&key) == Some(&call);
            // A component kept from the previous configuration with the same
            // params is ready if it runs, and may even have finished its step.
            let status = view.and_then(|v| v.status.as_deref());
            // One that other executives hold running these very params is shared: asking for
            // them restarts nothing, so it is ready if it runs.
            let shared = !unchanged
                && view.and_then(|v| v.params.as_deref()).map(str::trim) == Some(call.trim())
                && !self.mirror.held_by_others(&f.peis, &f.component).is_empty();
            let ready = (unchanged || shared) && matches!(status, Some("running" | "done"));
            if unchanged && status == Some("done") {
                finished.push(key.clone());
            }
            if !unchanged {
                out.push(params(&key, call.clone()));
                self.maybe_written.remove(&key);
                self.params.insert(key.clone(), call);
            }
            if !ready {
                pending.insert(key);
            }
        }
        let mut channels = Vec::new();
        let mut deferred = Vec::new();
        for c in &config.channels {
            channels.push(LogChannel {
                from: LogComponent::new(c.from_peis.clone(), c.from_component.clone()),
                to: LogComponent::new(c.to_peis.clone(), c.to_component.clone()),
                info: c.info.clone(),
            });
            let (Some(producer), Some(consumer)) = (
                component_key(&c.from_peis, &c.from_component),
                component_key(&c.to_peis, &c.to_component),
            ) else {
                continue;
            };
            // An information name that makes no valid key cannot be wired; the
            // consumer then reports what it misses.
            let Some(key) = input_key(&consumer.1, c, &config.channels) else {
                continue;
            };
            let wire = Command::RemoteSet {
                owner: consumer.0,
                key,
                value: format!(
                    "(meta {} {}.out.{})",
                    c.from_peis, c.from_component, c.info_name
                ),
            };
            // Make-before-break: an input is re-pointed only once its new
            // producer runs, so its consumer never reads from nothing.
            if pending.contains(&producer) {
                deferred.push((producer, wire));
            } else {
                out.push(wire);
            }
        }
        self.record(LogEvent::Deployed {
            switched_on,
            channels,
        });
        let Some(run) = &mut self.run else { return };
        let deploy_timer = !pending.is_empty();
        if deploy_timer {
            out.push(start(Timer::Deploy, self.config.deploy_timeout));
        } else if run.deploy_timer {
            out.push(Command::CancelTimer(Timer::Deploy));
        }
        // What went unanswered before is sent again where the new configuration needs it.
        out.extend(
            run.take_component_timers()
                .into_iter()
                .map(Command::CancelTimer),
        );
        run.done = finished.into_iter().collect();
        run.deferred = deferred;
        run.deploy_timer = deploy_timer;
        run.config = Some(config);
        run.phase = Phase::Deploying { pending };
        self.check_deployed(out);
    }

    /// Moves to `Running` once nothing is pending, switching off what the
    /// previous configuration started and this one does not use.
    pub(super) fn check_deployed(&mut self, out: &mut Vec<Command>) {
        let Some(run) = &mut self.run else { return };
        let Phase::Deploying { pending } = &run.phase else {
            return;
        };
        if !pending.is_empty() {
            return;
        }
        run.phase = Phase::Running;
        if std::mem::take(&mut run.deploy_timer) {
            out.push(Command::CancelTimer(Timer::Deploy));
        }
        let config = run.config.clone();
        let mut switched_off = Vec::new();
        if let Some(config) = &config {
            let unneeded: Vec<ComponentKey> = self
                .started
                .iter()
                .filter(|(p, c)| !config.uses(p.as_str(), c.as_str()))
                .cloned()
                .collect();
            for key in unneeded {
                out.push(req_state(&key, "off"));
                self.started.remove(&key);
                self.params.remove(&key);
                switched_off.push(logged(&key));
            }
        }
        self.running = config;
        self.record(LogEvent::Running { switched_off });
        self.arm_waiting_timers(out);
        self.check_done(out);
    }

    /// Whether the action's configuration uses `key`.
    pub(super) fn in_current_config(&self, key: &ComponentKey) -> bool {
        self.run
            .as_ref()
            .and_then(|r| r.config.as_ref())
            .is_some_and(|c| c.uses(key.0.as_str(), key.1.as_str()))
    }

    /// Puts back what the task wrote to the components `which` picks: those it switched on go
    /// off, those it borrowed lose their params. Returns both.
    pub(super) fn put_back(
        &mut self,
        which: impl Fn(&Self, &ComponentKey) -> bool,
        out: &mut Vec<Command>,
    ) -> (Vec<LogComponent>, Vec<LogComponent>) {
        let switched: Vec<ComponentKey> = self
            .started
            .iter()
            .filter(|k| which(self, k))
            .cloned()
            .collect();
        let borrowed: Vec<ComponentKey> = self
            .params
            .keys()
            .chain(&self.maybe_written)
            .filter(|k| which(self, k) && !self.started.contains(*k))
            .cloned()
            .collect::<BTreeSet<_>>()
            .into_iter()
            .collect();
        let mut switched_off = Vec::new();
        for key in switched {
            out.push(req_state(&key, "off"));
            self.started.remove(&key);
            self.params.remove(&key);
            self.maybe_written.remove(&key);
            switched_off.push(logged(&key));
        }
        let mut stopped = Vec::new();
        for key in borrowed {
            out.push(params(&key, String::new()));
            self.params.remove(&key);
            self.maybe_written.remove(&key);
            stopped.push(logged(&key));
        }
        (switched_off, stopped)
    }

    /// Leaves the ecology as the task found it: switches off every component
    /// this task switched on, and clears the `params` of components it only
    /// borrowed (their bodies stop; they report `idle`). Logged once.
    pub(super) fn release(&mut self, out: &mut Vec<Command>) {
        if self.finished {
            return;
        }
        self.finished = true;
        // What is on a PEIS out of reach is left to it: its host puts back what an executive
        // gone for a second had asked for (and sets to it would only wait out their timeout).
        let (switched_off, stopped) = self.put_back(|exec, key| !exec.is_absent(&key.0), out);
        let mut unreachable: BTreeSet<ComponentKey> =
            std::mem::take(&mut self.orphans).into_keys().collect();
        unreachable.extend(std::mem::take(&mut self.started));
        unreachable.extend(std::mem::take(&mut self.params).into_keys());
        unreachable.extend(std::mem::take(&mut self.maybe_written));
        self.running = None;
        let unreachable: Vec<LogComponent> = unreachable.iter().map(logged).collect();
        if !switched_off.is_empty() || !stopped.is_empty() || !unreachable.is_empty() {
            self.record(LogEvent::Released {
                switched_off,
                stopped,
                unreachable,
            });
        }
    }
}
