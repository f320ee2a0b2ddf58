//! The executive: sequencer, deployer and monitor as one event loop (the
//! paper's Sections VI and VII).
//!
//! [`Executive::handle`] takes the time and one [`Event`] (a tuple update, a
//! PEIS joining or leaving, a timer, the start command) and returns the
//! [`Command`]s to carry out (remote sets to PEIS, timers). It does no IO, so a
//! whole run can be driven and tested with virtual time.
//!
//! For each action of the plan: acquire the state from the mirror, plan the
//! cheapest configuration without the components that failed during the
//! action, deploy it (switch components on, write their `params`, point their
//! `mi-` inputs at producers' outputs), wait until every component reports
//! `running`, then switch off what the previous configuration started and no
//! longer needs (make-before-break). The action is done when every
//! functionality with a postcondition reports `done`. A component in `error`,
//! `waiting` beyond a grace period, never `running` after deployment, or on a
//! PEIS that left, is a failure: it is excluded and the action reconfigured.
//! When no configuration exists the action fails with the planner's
//! explanation.
//!
//! The state is declared here and handled in rooms, each an `impl Executive`
//! of its own: `sequencer` (the plan, action by action), `deployment`
//! (acquire, plan, deploy, put back), `monitoring` (what the components
//! report, failures), `membership` (PEIS that leave and return, the ecology
//! lost and back) and `timers` ([`Timer`], and where each one that runs out is
//! acted on).

mod deployment;
mod membership;
mod monitoring;
mod report;
mod sequencer;
mod timers;

pub use timers::Timer;

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::time::Duration;

use ecology_config::{Clock as PlannerClock, Configuration, NoClock};
use ecology_domain::{Domain, EcologyState};
use ecology_tuples::{ComponentId, Key, PeisId};

use crate::interest::{Intake, Interest};
use crate::log::{LogEntry, LogEvent};
use crate::mirror::{Change, Mirror};
use crate::plan::{Observation, Plan, PlanBranch, PlannedAction};

use deployment::Stopwatch;
use membership::{Awaited, Departures, Lost, Orphan};
use sequencer::ActionRun;

/// What the executive reacts to.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Event {
    /// Start executing the plan.
    Start,
    /// A tuple was set (DESIGN section 5); `seq` increases per owner and key.
    Tuple {
        /// The owner PEIS.
        owner: PeisId,
        /// The dotted key.
        key: Key,
        /// The value, as text.
        value: String,
        /// The run of the owner that wrote it (0 when unknown); a greater epoch means the owner restarted.
        epoch: u64,
        /// The tuple's sequence number within the owner's run.
        seq: u64,
    },
    /// A remote set the executive asked for failed (the owner refused it or could not be reached).
    RemoteSetFailed {
        /// The PEIS that owns the tuple.
        owner: PeisId,
        /// The dotted key.
        key: Key,
        /// Why.
        reason: String,
        /// No answer came: the owner is gone, or out of reach, or the executive is (its own
        /// network, or a router, lost); not a refusal. See [`ExecConfig::unanswered_grace`].
        unanswered: bool,
    },
    /// A remote set the executive asked for was carried out: the owner answered.
    RemoteSetAnswered {
        /// The PEIS that owns the tuple.
        owner: PeisId,
        /// The dotted key.
        key: Key,
    },
    /// A PEIS appeared.
    PeisJoined(PeisId),
    /// A PEIS disappeared (left, crashed or lost).
    PeisLeft(PeisId),
    /// A timer fired.
    Timer(Timer),
}

/// What the executive asks its driver to do.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Command {
    /// Ask `owner` to set its tuple `key` to `value` (a remote set). The driver reports how each
    /// one ended, once: [`Event::RemoteSetAnswered`] or [`Event::RemoteSetFailed`]; until then
    /// the executive takes the way to `owner` as not known to work.
    RemoteSet {
        /// The PEIS that owns the tuple.
        owner: PeisId,
        /// The dotted key.
        key: Key,
        /// The value.
        value: String,
    },
    /// Fire `Event::Timer(timer)` after `after`, instead of when it was to fire if it was
    /// started already (see [`Timer`]).
    StartTimer {
        /// The timer.
        timer: Timer,
        /// The delay.
        after: Duration,
    },
    /// Forget a timer: it does not fire.
    CancelTimer(Timer),
}

/// Time limits of the executive.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ExecConfig {
    /// How long every component of a new configuration has to report `running`.
    pub deploy_timeout: Duration,
    /// How long a component may report `waiting` before it counts as failed.
    pub waiting_grace: Duration,
    /// How long one action may take.
    pub action_timeout: Duration,
    /// How many alternative configurations to log with each choice.
    pub alternatives: usize,
    /// How much search one configuration may take: nodes, and time by the
    /// executive's stopwatch ([`Executive::with_stopwatch`]). When it runs
    /// out, the best configuration found is used; when none was found, the
    /// action fails with that reason.
    pub planning: ecology_config::Budget,
    /// PEIS that leave within this long of the first are judged together: when at least two,
    /// and more than half of those present, left, the executive has lost the ecology (its own
    /// network, or the router) rather than they their components. Each departure is acted on at
    /// once; only an action that finds no configuration meanwhile waits for the judgement.
    pub loss_window: Duration,
    /// How long to wait for a lost ecology to come back before the task fails.
    pub reconnect_timeout: Duration,
    /// How long a remote set to a component of the configuration that got no answer waits
    /// before the component is blamed: long enough for the owner's departure, or the
    /// executive's loss of the ecology, to show first (a presence lease of 2 s, then the
    /// loss window). The owner may be gone, and a set the executive sends while it is cut off
    /// itself, or while the router is down, gets no answer either: neither is the component's
    /// failure.
    pub unanswered_grace: Duration,
    /// How long an action left without a configuration by PEIS that left waits for them to
    /// return before it fails: a robot on a poor link can go silent for its whole lease and be
    /// back a second or two later. Also how much longer than [`ExecConfig::waiting_grace`] a
    /// component still `waiting` is given when no configuration can do without it: what it waits
    /// for may only be held up. Zero fails at once.
    pub return_wait: Duration,
}

impl Default for ExecConfig {
    fn default() -> ExecConfig {
        ExecConfig {
            deploy_timeout: Duration::from_secs(10),
            waiting_grace: Duration::from_secs(2),
            action_timeout: Duration::from_secs(600),
            alternatives: 3,
            planning: ecology_config::Budget {
                max_expansions: Some(1_000_000),
                max_time: Some(Duration::from_secs(2)),
            },
            loss_window: Duration::from_secs(1),
            reconnect_timeout: Duration::from_secs(30),
            unanswered_grace: Duration::from_secs(3),
            return_wait: Duration::from_secs(5),
        }
    }
}

/// Where a run stands.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RunStatus {
    /// Not started.
    Idle,
    /// Executing action `index`.
    Running {
        /// The action's index in the plan.
        index: usize,
    },
    /// Every action is done.
    Done,
    /// An action failed and nothing replanned around it, or the task was stopped.
    Failed {
        /// The failed action's index.
        index: usize,
        /// Why.
        reason: String,
    },
}

/// A component of the ecology: its PEIS and its name there.
type ComponentKey = (PeisId, ComponentId);

/// The executive. See the module documentation.
#[derive(Debug)]
pub struct Executive {
    stopwatch: Stopwatch,
    /// The domain, compiled once for the configuration planner, which runs
    /// for every action.
    planner: ecology_config::Planner,
    world: EcologyState,
    /// The actions of this plan so far: those run, the one running, and
    /// those that follow before the next branching.
    plan: Vec<PlannedAction>,
    /// What follows the last action of `plan`, by what it observes.
    branches: Vec<PlanBranch>,
    /// Without branches: how probable it is that the goal holds once `plan` is done.
    success: f64,
    /// Everything the task's sensing actions observed, the latest value of each atom.
    knowledge: BTreeMap<String, bool>,
    config: ExecConfig,
    mirror: Mirror,
    status: RunStatus,
    run: Option<ActionRun>,
    /// The configuration running now (from this or an earlier action).
    running: Option<Configuration>,
    /// Components this executive switched on, to switch off when unneeded.
    started: BTreeSet<ComponentKey>,
    /// The `params` last written to each component.
    params: BTreeMap<ComponentKey, String>,
    /// What it wrote to components of PEIS that left and may come back in the same run.
    orphans: BTreeMap<ComponentKey, Orphan>,
    /// Components whose `params` it wrote before their PEIS left, where on its return they
    /// showed empty: put back by that PEIS, or its write not landed yet (it may still). Not
    /// believed to run them; cleared when put back unless a configuration writes them again.
    maybe_written: BTreeSet<ComponentKey>,
    /// The remote sets asked for that are neither answered nor failed yet: by owner and key,
    /// their values in the order asked (the driver carries out one owner's sets in order).
    /// While a PEIS has one, the way to it is not known to work.
    in_flight: BTreeMap<(PeisId, Key), VecDeque<String>>,
    /// Departures being judged, if any.
    departures: Option<Departures>,
    /// Set while the ecology is lost.
    lost: Option<Lost>,
    awaited: Option<Awaited>,
    /// Whether the task has ended and what it used has been released.
    finished: bool,
    /// Every action instance that failed in this task, in order.
    failed_actions: Vec<String>,
    now: Duration,
    log: Vec<LogEntry>,
    intake: Intake,
}

impl Executive {
    /// An executive for `plan` (a sequence of actions, or a conditional
    /// [`Plan`]) in `domain`; `world` holds facts about the world the
    /// configuration planner may need besides the acquired ones.
    pub fn new(
        domain: Domain,
        world: EcologyState,
        plan: impl Into<Plan>,
        config: ExecConfig,
    ) -> Executive {
        let plan = plan.into();
        Executive {
            stopwatch: Stopwatch(Box::new(NoClock)),
            planner: ecology_config::Planner::new(domain),
            world,
            plan: plan.steps,
            branches: plan.branches,
            success: plan.success,
            knowledge: BTreeMap::new(),
            config,
            mirror: Mirror::new(),
            status: RunStatus::Idle,
            run: None,
            running: None,
            started: BTreeSet::new(),
            params: BTreeMap::new(),
            orphans: BTreeMap::new(),
            maybe_written: BTreeSet::new(),
            in_flight: BTreeMap::new(),
            departures: None,
            lost: None,
            awaited: None,
            finished: false,
            failed_actions: Vec::new(),
            now: Duration::ZERO,
            log: Vec::new(),
            intake: Intake::default(),
        }
    }

    /// Times state acquisition and planning with `clock`, so the log says
    /// how long each took (`StateAcquired::micros`, `Configuration::micros`).
    pub fn with_stopwatch(mut self, clock: Box<dyn PlannerClock + Send>) -> Executive {
        self.stopwatch = Stopwatch(clock);
        self
    }

    /// Where the run stands.
    pub fn status(&self) -> &RunStatus {
        &self.status
    }

    /// Every event logged so far.
    pub fn log(&self) -> &[LogEntry] {
        &self.log
    }

    /// Tells the executive its own PEIS name (the driver does, from its tuple space), so that it
    /// tells its own claims on components from other executives'.
    pub fn acting_as(&mut self, me: PeisId) {
        self.mirror.acting_as(me);
    }

    /// The mirror of the ecology's tuples.
    pub fn mirror(&self) -> &Mirror {
        &self.mirror
    }

    /// What of the ecology the rest of the plan (every branch included) needs.
    pub fn interest(&self) -> Interest {
        Interest::of_plan(&self.planner, &self.world, &self.plan, &self.branches)
    }

    /// What of the ecology [`Interest::of`] `plan` needs, in this executive's domain.
    pub fn interest_of(&self, plan: &Plan) -> Interest {
        Interest::of(&self.planner, &self.world, plan)
    }

    /// What the executive took in from the ecology so far.
    pub fn intake(&self) -> &Intake {
        &self.intake
    }

    /// The driver's part of the intake: how long acquiring the state took
    /// before the task started.
    pub fn note_acquisition(&mut self, took: Duration) {
        self.intake.acquisition = took;
    }

    /// The driver's part of the intake: whether it follows every tuple, and under a scope how
    /// many PEIS's contracts and how many rooms.
    pub fn note_followed(&mut self, everything: bool, scope: Option<(u32, u32)>) {
        self.intake.everything = everything;
        self.intake.scope = scope;
    }

    /// The configuration running now, if any.
    pub fn running(&self) -> Option<&Configuration> {
        self.running.as_ref()
    }

    /// Whether the task has ended and everything it used has been released.
    pub fn finished(&self) -> bool {
        self.finished
    }

    /// Every action instance that failed in this task so far, in order: what
    /// a replanner must leave out.
    pub fn failed_actions(&self) -> &[String] {
        &self.failed_actions
    }

    /// What the task's sensing actions have observed so far (the latest
    /// value of each atom): the evidence a replanner narrows the initial
    /// belief with.
    pub fn observations(&self) -> Vec<Observation> {
        self.knowledge
            .iter()
            .map(|(atom, &holds)| Observation {
                atom: atom.clone(),
                holds,
            })
            .collect()
    }

    /// Handles one event at time `now` (time since the run's clock started).
    pub fn handle(&mut self, now: Duration, event: Event) -> Vec<Command> {
        self.now = self.now.max(now);
        let mut out = Vec::new();
        match event {
            Event::Start => {
                if self.status == RunStatus::Idle {
                    let actions = self.plan.iter().map(|a| a.action.clone()).collect();
                    let branches = self.branch_observations();
                    self.record(LogEvent::Plan { actions, branches });
                    self.start_action(0, &mut out);
                }
            }
            Event::Tuple {
                owner,
                key,
                value,
                epoch,
                seq,
            } => {
                self.intake.tuples += 1;
                self.intake.bytes +=
                    (owner.as_str().len() + key.as_str().len() + value.len()) as u64;
                for change in self.mirror.apply(&owner, &key, &value, epoch, seq) {
                    match change {
                        Change::Status {
                            peis,
                            component,
                            status,
                        } => self.on_status((peis, component), &status, &mut out),
                        Change::Observed {
                            peis,
                            component,
                            literals,
                        } => self.on_observed((peis, component), &literals, &mut out),
                        Change::Restarted { peis } => {
                            if self.run.is_some() {
                                self.record(LogEvent::PeisRestarted {
                                    peis: peis.to_string(),
                                });
                            }
                            self.forget(&peis);
                            self.on_peis_gone(&peis, format!("PEIS {peis} restarted"), &mut out);
                        }
                        Change::Holders { peis, component } => {
                            // Released or taken by others: considered again at the next configuration.
                            if let Some(run) = &mut self.run {
                                run.held.remove(&(peis, component));
                            }
                        }
                        Change::Other => {}
                    }
                }
            }
            Event::RemoteSetFailed {
                owner,
                key,
                reason,
                unanswered,
            } => {
                let value = self.set_over(&owner, &key);
                self.on_remote_set_failed(owner, key, value, reason, unanswered, &mut out);
            }
            Event::RemoteSetAnswered { owner, key } => {
                self.set_over(&owner, &key);
                self.on_remote_set_answered(owner, &key, &mut out);
            }
            Event::PeisJoined(peis) => self.on_joined(peis, &mut out),
            Event::PeisLeft(peis) => self.on_left(peis, &mut out),
            Event::Timer(timer) => self.on_timer(timer, &mut out),
        }
        self.sent(out)
    }

    /// `out`, its remote sets kept as in flight until answered or failed.
    fn sent(&mut self, out: Vec<Command>) -> Vec<Command> {
        for command in &out {
            if let Command::RemoteSet { owner, key, value } = command {
                self.in_flight
                    .entry((owner.clone(), key.clone()))
                    .or_default()
                    .push_back(value.clone());
            }
        }
        out
    }

    /// The first remote set of `key` asked of `owner` is over, answered or failed: its value.
    fn set_over(&mut self, owner: &PeisId, key: &Key) -> Option<String> {
        let at = (owner.clone(), key.clone());
        let values = self.in_flight.get_mut(&at)?;
        let value = values.pop_front();
        if values.is_empty() {
            self.in_flight.remove(&at);
        }
        value
    }

    /// Action-level recovery: after an action failed, continue with a new
    /// plan (from the action planner, without the failed actions and from
    /// the world as observed).
    pub fn replan(&mut self, now: Duration, plan: impl Into<Plan>) -> Vec<Command> {
        self.now = self.now.max(now);
        let mut out = Vec::new();
        if self.finished || !matches!(self.status, RunStatus::Failed { .. }) {
            return out;
        }
        let failed = self.failed_actions.last().cloned().unwrap_or_default();
        self.plan.clear();
        self.continue_with(plan.into());
        let actions = self.plan.iter().map(|a| a.action.clone()).collect();
        let branches = self.branch_observations();
        self.record(LogEvent::Replanned {
            failed,
            actions,
            branches,
        });
        self.start_action(0, &mut out);
        self.sent(out)
    }

    /// Gives up after a failed action: the task fails, and what it used is released.
    pub fn abandon(&mut self, now: Duration) -> Vec<Command> {
        self.abandon_because(now, None)
    }

    /// [`Executive::abandon`], saying why no other plan was tried or found
    /// (the action planner's explanation).
    pub fn abandon_because(&mut self, now: Duration, why: Option<&str>) -> Vec<Command> {
        self.now = self.now.max(now);
        let mut out = Vec::new();
        if self.finished {
            return out;
        }
        if let RunStatus::Failed { index, .. } = &self.status {
            let mut reason = format!("action {} failed", self.plan[*index].action);
            if let Some(why) = why {
                reason.push_str(&format!(" and no plan remains: {why}"));
            }
            self.release(&mut out);
            self.record(LogEvent::TaskFailed { reason });
        }
        self.sent(out)
    }

    /// Stops the task where it stands (the operator interrupted it): the
    /// current action fails with `reason`, what the task used is released,
    /// and the task fails.
    pub fn stop(&mut self, now: Duration, reason: &str) -> Vec<Command> {
        self.now = self.now.max(now);
        let mut out = Vec::new();
        if self.finished {
            return out;
        }
        if self.run.is_some() {
            self.fail_action(reason.to_string(), &mut out);
        }
        let index = match &self.status {
            RunStatus::Failed { index, .. } | RunStatus::Running { index } => *index,
            RunStatus::Idle | RunStatus::Done => 0,
        };
        self.status = RunStatus::Failed {
            index,
            reason: reason.to_string(),
        };
        self.release(&mut out);
        self.record(LogEvent::TaskFailed {
            reason: reason.to_string(),
        });
        self.sent(out)
    }

    fn record(&mut self, event: LogEvent) {
        self.log.push(LogEntry { t: self.now, event });
    }
}
