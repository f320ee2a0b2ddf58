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

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::sync::Arc;
use std::time::Duration;

use ecology_config::{Clock as PlannerClock, Configuration, Exclusion, NoClock, Options, Request};
use ecology_domain::{Domain, EcologyState};
use ecology_tuples::contract::{self, ComponentField};
use ecology_tuples::{ComponentId, Key, PeisId};

use crate::interest::{Intake, Interest};
use crate::log::{LogEntry, LogEvent};
use crate::mirror::{Change, Mirror};
use crate::plan::{
    Observation, Plan, PlanBranch, PlannedAction, observations_text, parse_observations,
};

/// A timer the executive asks for: what runs out when it fires.
///
/// There is at most one of each value at a time. A driver keeps one deadline per `Timer`:
/// [`Command::StartTimer`] of a timer already started replaces its deadline, and
/// [`Command::CancelTimer`] removes it, so a timer fires once, as it was last started, and never
/// once cancelled. That is what keeps a firing from being stale, where a fresh id per start used
/// to: a timer started again does not fire for its earlier start. The executive still acts on
/// [`Event::Timer`] only while its own state has that timer running, and ignores it otherwise.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Timer {
    /// The action's time runs out ([`ExecConfig::action_timeout`]).
    Action,
    /// The components of the new configuration had their time to report `running`
    /// ([`ExecConfig::deploy_timeout`]).
    Deploy,
    /// The component reports `waiting` for longer than [`ExecConfig::waiting_grace`] (or, when
    /// nothing can stand in for it, [`ExecConfig::return_wait`] more).
    Waiting(ComponentKey),
    /// A remote set to the component got no answer for [`ExecConfig::unanswered_grace`].
    Unanswered(ComponentKey),
    /// The window of departures closes ([`ExecConfig::loss_window`]): they are judged.
    LossWindow,
    /// The lost ecology did not come back in time ([`ExecConfig::reconnect_timeout`]).
    Reconnect,
    /// A loss window after the latest return of a PEIS of the lost ecology.
    LostSettle,
    /// The PEIS an action without a configuration waits for did not return in time
    /// ([`ExecConfig::return_wait`]).
    ReturnWait,
    /// A loss window after the latest return of a PEIS the action waits for.
    ReturnSettle,
}

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

/// The typed names of the component `peis`:`component` of a configuration;
/// `None` when either is not a valid name in the tuple space (the planner
/// reads names from facts, which may say anything).
fn component_key(peis: &str, component: &str) -> Option<ComponentKey> {
    Some((PeisId::new(peis).ok()?, ComponentId::new(component).ok()?))
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
fn components_of(
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
fn input_key(
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

/// The component a remote set of `key` is to: `components.C.reqState`, or `C.params` and
/// `C.mi-…`, where it is the first segment.
fn set_component(key: &Key) -> Option<ComponentId> {
    ComponentField::parse(key)
        .map(|(c, _)| c)
        .or_else(|| key.segments().next().and_then(|c| ComponentId::new(c).ok()))
}

/// Takes the entries of `map` for the components of `peis` out of it.
fn take_on<V>(map: &mut BTreeMap<ComponentKey, V>, peis: &PeisId) -> Vec<(ComponentKey, V)> {
    let keys: Vec<ComponentKey> = map.keys().filter(|(p, _)| p == peis).cloned().collect();
    keys.into_iter()
        .filter_map(|k| map.remove(&k).map(|v| (k, v)))
        .collect()
}

fn micros(d: Duration) -> u64 {
    u64::try_from(d.as_micros()).unwrap_or(u64::MAX)
}

/// Starts `timer`, to fire `after` from now (instead of when it was to, if it runs already).
fn start(timer: Timer, after: Duration) -> Command {
    Command::StartTimer { timer, after }
}

#[derive(Debug, Clone, PartialEq, Eq)]
enum Phase {
    /// Waiting for the components of the new configuration to run.
    Deploying { pending: BTreeSet<ComponentKey> },
    /// Running; waiting for postconditions.
    Running,
}

#[derive(Debug)]
struct ActionRun {
    index: usize,
    excluded: Vec<Exclusion>,
    failed: BTreeSet<ComponentKey>,
    config: Option<Configuration>,
    phase: Phase,
    /// Whether [`Timer::Deploy`] runs. [`Timer::Action`] runs as long as the action does.
    deploy_timer: bool,
    /// The components whose [`Timer::Waiting`] runs, or ran out while the ecology was lost.
    waiting: BTreeSet<ComponentKey>,
    /// Components whose waiting was given longer, since nothing could stand in for them: once
    /// per spell of waiting (until they report another status).
    waited_longer: BTreeSet<ComponentKey>,
    /// Components whose remote set got no answer, each timed by its [`Timer::Unanswered`]: the
    /// set's key (an answer to it, sent again, clears the component), and the failure's cause,
    /// should they be blamed when the timer runs out.
    unanswered: BTreeMap<ComponentKey, (Key, String)>,
    done: BTreeSet<ComponentKey>,
    /// Inputs to re-point once their new producer runs (make-before-break):
    /// the producer, and the remote set that wires its consumer.
    deferred: Vec<(ComponentKey, Command)>,
    /// What the configuration reported of the atoms a sensing action reveals.
    observed: BTreeMap<String, bool>,
}

impl ActionRun {
    /// Takes the timers of the configuration's components: their waiting grace periods and
    /// their remote sets that got no answer.
    fn take_component_timers(&mut self) -> Vec<Timer> {
        let waiting = std::mem::take(&mut self.waiting).into_iter();
        let unanswered = std::mem::take(&mut self.unanswered).into_keys();
        waiting
            .map(Timer::Waiting)
            .chain(unanswered.map(Timer::Unanswered))
            .collect()
    }
}

/// What the executive had written to a component of a PEIS that left: what it
/// takes back, or puts back, when that PEIS returns in the same run.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
struct Orphan {
    /// The executive switched it on.
    switched_on: bool,
    /// The params it gave it.
    params: Option<String>,
}

/// The action's exclusions and failed components at one moment: what they are again when what
/// happened since is forgiven.
type Excluded = (Vec<Exclusion>, BTreeSet<ComponentKey>);

/// PEIS that left within one [`ExecConfig::loss_window`], judged together when it closes
/// ([`Timer::LossWindow`]).
#[derive(Debug)]
struct Departures {
    /// Every PEIS that left in the window, those back since included.
    gone: Vec<PeisId>,
    /// How many PEIS were present before the first left.
    present_before: usize,
    /// The action's exclusions and failed components before the first left: what they are again
    /// if the ecology turns out lost (its components did not fail; the network did).
    before: Excluded,
    /// Why the action found no configuration meanwhile: it fails with that once the departures
    /// are judged, unless the ecology was lost.
    no_configuration: Option<String>,
}

/// PEIS that left, judged gone, without whom the action found no configuration: it waits
/// [`ExecConfig::return_wait`] for them before it fails ([`Timer::ReturnWait`]).
#[derive(Debug)]
struct Awaited {
    /// Those still gone.
    gone: BTreeSet<PeisId>,
    /// Those back, whose tuples are read again for a loss window before the action is
    /// configured again (one restarted comes back with new tuples).
    back: BTreeSet<PeisId>,
    /// Whether [`Timer::ReturnSettle`] runs: a loss window after the latest return.
    settle: bool,
    /// The action's exclusions and failed components before they left: what their return
    /// allows again.
    before: Excluded,
    /// Why the action has no configuration without them.
    reason: String,
}

/// The executive lost the ecology: it waits for it ([`Timer::Reconnect`]), acting on nothing.
#[derive(Debug)]
struct Lost {
    gone: BTreeSet<PeisId>,
    back: BTreeSet<PeisId>,
    present_before: usize,
    /// Whether [`Timer::LostSettle`] runs, a window after the latest return: then the task goes
    /// on, if most are back.
    settle: bool,
}

/// Measures how long acquisition and planning take, for the log. The
/// executive reads no clock of its own: without one, they log as 0 µs.
struct Stopwatch(Box<dyn PlannerClock + Send>);

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

    /// The mirror of the ecology's tuples.
    pub fn mirror(&self) -> &Mirror {
        &self.mirror
    }

    /// What of the ecology the rest of the plan (every branch included) needs.
    pub fn interest(&self) -> Interest {
        Interest::of_plan(self.planner.domain(), &self.plan, &self.branches)
    }

    /// What of the ecology [`Interest::of`] `plan` needs, in this executive's domain.
    pub fn interest_of(&self, plan: &Plan) -> Interest {
        Interest::of(self.planner.domain(), plan)
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

    /// The driver's part of the intake: how many PEIS it follows on demand.
    pub fn note_followed(&mut self, followed: usize) {
        self.intake.followed = followed;
    }

    /// The configuration running now, if any.
    pub fn running(&self) -> Option<&Configuration> {
        self.running.as_ref()
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

    /// A PEIS that restarted starts afresh: forget what was written to its
    /// components, so a new deploy writes it again.
    fn forget(&mut self, peis: &PeisId) {
        self.params.retain(|(p, _), _| p != peis);
        self.started.retain(|(p, _)| p != peis);
        self.orphans.retain(|(p, _), _| p != peis);
    }

    fn is_present(&self, peis: &PeisId) -> bool {
        self.mirror.peis().get(peis).is_some_and(|v| v.present)
    }

    /// Whether `peis` is known to be away (not merely never heard of).
    fn is_absent(&self, peis: &PeisId) -> bool {
        self.mirror.peis().get(peis).is_some_and(|v| !v.present)
    }

    fn present_count(&self) -> usize {
        self.mirror.peis().values().filter(|v| v.present).count()
    }

    /// A PEIS left: what was written to it is kept as orphans (it may come back in the same
    /// run, still running it), and the departure is judged a window later, with any others.
    fn on_left(&mut self, peis: PeisId, out: &mut Vec<Command>) {
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
    fn on_joined(&mut self, peis: PeisId, out: &mut Vec<Command>) {
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

    /// Takes back what was written to `peis` before it left, where the mirror shows it still
    /// stands: switched on if it is on, params if they are the same (or not yet seen).
    fn reclaim(&mut self, peis: &PeisId) {
        for (key, orphan) in take_on(&mut self.orphans, peis) {
            let view = self.mirror.component(key.0.as_str(), key.1.as_str());
            if orphan.switched_on && view.is_some_and(|v| v.on) {
                self.started.insert(key.clone());
            }
            if let Some(params) = orphan.params {
                let seen = view.and_then(|v| v.params.as_deref());
                if seen.is_none_or(|seen| seen == params) {
                    self.params.insert(key, params);
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

    /// Puts back what the task wrote to the components `which` picks: those it switched on go
    /// off, those it borrowed lose their params. Returns both, named `P:C`.
    fn put_back(
        &mut self,
        which: impl Fn(&Self, &ComponentKey) -> bool,
        out: &mut Vec<Command>,
    ) -> (Vec<String>, Vec<String>) {
        let switched: Vec<ComponentKey> = self
            .started
            .iter()
            .filter(|k| which(self, k))
            .cloned()
            .collect();
        let borrowed: Vec<ComponentKey> = self
            .params
            .keys()
            .filter(|k| which(self, k) && !self.started.contains(*k))
            .cloned()
            .collect();
        let mut switched_off = Vec::new();
        for key in switched {
            out.push(req_state(&key, "off"));
            self.started.remove(&key);
            self.params.remove(&key);
            switched_off.push(format!("{}:{}", key.0, key.1));
        }
        let mut stopped = Vec::new();
        for key in borrowed {
            out.push(params(&key, String::new()));
            self.params.remove(&key);
            stopped.push(format!("{}:{}", key.0, key.1));
        }
        (switched_off, stopped)
    }

    /// Stops timing the components of the action: its deploy timeout, waiting grace periods and
    /// unanswered remote sets.
    fn stop_component_timers(&mut self, out: &mut Vec<Command>) {
        let Some(run) = &mut self.run else { return };
        if std::mem::take(&mut run.deploy_timer) {
            out.push(Command::CancelTimer(Timer::Deploy));
        }
        out.extend(
            run.take_component_timers()
                .into_iter()
                .map(Command::CancelTimer),
        );
    }

    /// The window of departures closed: the executive lost the ecology when at least two, and
    /// more than half of the PEIS present, are still gone; otherwise each is a failure of its
    /// components, acted on with what else failed meanwhile.
    fn judge_departures(&mut self, out: &mut Vec<Command>) {
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
    /// [`ExecConfig::return_wait`] for them, with any it waited for already.
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
    fn settle_returns(&mut self, out: &mut Vec<Command>) {
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
    fn return_wait_over(&mut self, out: &mut Vec<Command>) {
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
    fn stop_awaiting(&mut self, out: &mut Vec<Command>) {
        if let Some(awaited) = self.awaited.take() {
            out.push(Command::CancelTimer(Timer::ReturnWait));
            if awaited.settle {
                out.push(Command::CancelTimer(Timer::ReturnSettle));
            }
        }
    }

    /// The action has no configuration: it fails, or, while departures are judged, waits for
    /// the judgement (it may be the executive that lost the network).
    fn no_configuration(&mut self, reason: String, out: &mut Vec<Command>) {
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
    fn try_resume(&mut self, out: &mut Vec<Command>) {
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
    fn give_up(&mut self, out: &mut Vec<Command>) {
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

    fn record(&mut self, event: LogEvent) {
        self.log.push(LogEntry { t: self.now, event });
    }

    fn start_action(&mut self, index: usize, out: &mut Vec<Command>) {
        if index >= self.plan.len() && self.success <= ecology_core::EPSILON {
            // A conditional plan that gives up here: nothing the robots can
            // do reaches the goal from what was observed.
            let reason =
                "the plan gives up here: from what was observed, no action reaches the goal"
                    .to_string();
            self.status = RunStatus::Failed {
                index: index.saturating_sub(1),
                reason: reason.clone(),
            };
            self.run = None;
            self.release(out);
            self.record(LogEvent::TaskFailed { reason });
            return;
        }
        if index >= self.plan.len() {
            self.status = RunStatus::Done;
            self.run = None;
            self.release(out);
            self.record(LogEvent::TaskDone);
            return;
        }
        self.status = RunStatus::Running { index };
        let action = self.plan[index].action.clone();
        self.record(LogEvent::ActionStarted {
            index,
            action: action.clone(),
        });
        out.push(start(Timer::Action, self.config.action_timeout));
        self.run = Some(ActionRun {
            index,
            excluded: Vec::new(),
            failed: BTreeSet::new(),
            config: None,
            phase: Phase::Running,
            deploy_timer: false,
            waiting: BTreeSet::new(),
            waited_longer: BTreeSet::new(),
            unanswered: BTreeMap::new(),
            done: BTreeSet::new(),
            deferred: Vec::new(),
            observed: BTreeMap::new(),
        });
        if self.plan[index].goal.is_none() {
            if !self.plan[index].observe.is_empty() {
                // Nothing would be deployed to report what it observes.
                let reason = format!(
                    "it observes {} but has no configuration goal to observe with",
                    self.plan[index].observe.join(" ")
                );
                self.fail_action(reason, out);
                return;
            }
            self.finish_action(out);
            return;
        }
        self.configure(false, out);
    }

    /// Acquire state, plan, deploy.
    /// Adds the components that report `error` to `exclusions`: such a component stays out until
    /// it reports something else (its PEIS restarting it counts), whatever action it failed in.
    /// Returns why each one added is unavailable.
    fn add_unavailable(&self, exclusions: &mut Vec<Exclusion>) -> Vec<String> {
        let mut unavailable = Vec::new();
        for (p, c, cause) in self.mirror.in_error() {
            let exclusion = Exclusion::Component {
                peis: p.to_string(),
                component: c.to_string(),
            };
            if !exclusions.contains(&exclusion) {
                exclusions.push(exclusion);
                unavailable.push(format!("{p}:{c} reports error ({cause})"));
            }
        }
        unavailable
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
        let state = self.mirror.state(&self.world);
        // Only whether one exists: no explanation, so that "none" is answered
        // before grounding when it can be.
        self.plan_configurations(&state, goal, &exclusions, 1, false)
            .is_ok_and(|o| {
                !o.configurations.is_empty() || o.status == ecology_config::Status::BudgetExceeded
            })
    }

    /// Up to `count` configurations for `goal` in `state` without `exclusions`, under the
    /// planning budget, which counts from now; when there is none, why if `explain`.
    fn plan_configurations(
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

    fn configure(&mut self, reconfiguration: bool, out: &mut Vec<Command>) {
        let Some(run) = &self.run else { return };
        let index = run.index;
        let mut exclusions = run.excluded.clone();
        let Some(goal) = self.plan[index].goal.clone() else {
            return;
        };
        let before = self.stopwatch.0.elapsed();
        let state = self.mirror.state(&self.world);
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
                .map(|f| format!("{} on {}:{}", f.call(), f.peis, f.component))
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

    /// Switches on, parameterizes and wires the components of `config`,
    /// whose names are all valid (`invalid_component` is `None`).
    fn deploy(&mut self, config: Configuration, out: &mut Vec<Command>) {
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
                switched_on.push(format!("{}:{}", f.peis, f.component));
            }
            let call = f.call();
            let unchanged = self.params.get(&key) == Some(&call);
            // A component kept from the previous configuration with the same
            // params is ready if it runs, and may even have finished its step.
            let status = view.and_then(|v| v.status.as_deref());
            let ready = unchanged && matches!(status, Some("running" | "done"));
            if unchanged && status == Some("done") {
                finished.push(key.clone());
            }
            if !unchanged {
                out.push(params(&key, call.clone()));
                self.params.insert(key.clone(), call);
            }
            if !ready {
                pending.insert(key);
            }
        }
        let mut channels = Vec::new();
        let mut deferred = Vec::new();
        for c in &config.channels {
            channels.push(format!(
                "{}:{} → {}:{} {}",
                c.from_peis, c.from_component, c.to_peis, c.to_component, c.info
            ));
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
    fn check_deployed(&mut self, out: &mut Vec<Command>) {
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
                switched_off.push(format!("{}:{}", key.0, key.1));
            }
        }
        self.running = config;
        self.record(LogEvent::Running { switched_off });
        self.arm_waiting_timers(out);
        self.check_done(out);
    }

    /// Starts the grace period of every component of the running
    /// configuration that reports `waiting` and has none: one that was
    /// waiting across a redeploy is timed again.
    fn arm_waiting_timers(&mut self, out: &mut Vec<Command>) {
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

    fn in_current_config(&self, key: &ComponentKey) -> bool {
        self.run
            .as_ref()
            .and_then(|r| r.config.as_ref())
            .is_some_and(|c| c.uses(key.0.as_str(), key.1.as_str()))
    }

    fn on_status(&mut self, key: ComponentKey, status: &str, out: &mut Vec<Command>) {
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

    /// A PEIS left or restarted: every component of the configuration on it failed.
    fn on_peis_gone(&mut self, peis: &PeisId, cause: String, out: &mut Vec<Command>) {
        let Some(config) = self.run.as_ref().and_then(|r| r.config.as_ref()) else {
            return;
        };
        let lost = components_of(config, |f| &*f.peis == peis.as_str());
        if !lost.is_empty() {
            self.failure(lost, cause, out);
        }
    }

    /// A remote set failed: logged, and when it deployed a component of the configuration, that
    /// component failed (it cannot be switched on or wired). A refusal fails it at once; a set
    /// that got no answer waits [`ExecConfig::unanswered_grace`] first, since the owner's
    /// departure, or the executive's own loss of the ecology, may be what kept the answer away,
    /// and each has its own remedy.
    fn on_remote_set_failed(
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

    /// A remote set was answered: if it was sent again after getting no answer, its component
    /// is cleared.
    fn on_remote_set_answered(&mut self, owner: PeisId, key: &Key, out: &mut Vec<Command>) {
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

    /// A timer ran out: what it timed is acted on, if it still runs in the executive's state.
    fn on_timer(&mut self, timer: Timer, out: &mut Vec<Command>) {
        let lost_own = matches!(
            timer,
            Timer::LossWindow | Timer::Reconnect | Timer::LostSettle
        );
        if self.lost.is_some() && !lost_own {
            // While lost, only its own timers count: whatever else ran out timed the network.
            return;
        }
        match timer {
            Timer::LossWindow => self.judge_departures(out),
            Timer::Reconnect => self.give_up(out),
            Timer::LostSettle => {
                if self.lost.as_ref().is_some_and(|lost| lost.settle) {
                    self.try_resume(out);
                }
            }
            Timer::ReturnSettle => {
                if self.awaited.as_ref().is_some_and(|a| a.settle) {
                    self.settle_returns(out);
                }
            }
            Timer::ReturnWait => self.return_wait_over(out),
            Timer::Action => {
                if self.run.is_some() {
                    let reason = format!(
                        "the action did not finish within {:?}",
                        self.config.action_timeout
                    );
                    self.fail_action(reason, out);
                }
            }
            Timer::Deploy => self.deploy_timed_out(out),
            Timer::Unanswered(key) => self.unanswered_over(key, out),
            Timer::Waiting(key) => self.waiting_over(key, out),
        }
    }

    /// The components of the new configuration did not all report `running` in time: those
    /// still pending are to blame.
    fn deploy_timed_out(&mut self, out: &mut Vec<Command>) {
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

    /// A remote set to `key` got no answer for [`ExecConfig::unanswered_grace`], and neither
    /// was it answered since.
    fn unanswered_over(&mut self, key: ComponentKey, out: &mut Vec<Command>) {
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
    fn waiting_over(&mut self, key: ComponentKey, out: &mut Vec<Command>) {
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

    /// Excludes the failed components and reconfigures the action; while the
    /// ecology is lost, nothing is judged a failure.
    fn failure(&mut self, failed: Vec<ComponentKey>, cause: String, out: &mut Vec<Command>) {
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
    fn exclude(&mut self, failed: Vec<(String, String)>, cause: String, out: &mut Vec<Command>) {
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

    fn check_done(&mut self, out: &mut Vec<Command>) {
        let Some(run) = &self.run else { return };
        if run.phase != Phase::Running {
            return;
        }
        let Some(config) = &run.config else { return };
        let finishing = components_of(config, |f| !f.postcondition.is_empty());
        // An action is done when every functionality with a postcondition
        // reports `done`; one whose configuration has none (it only provides
        // information) is done as soon as its configuration runs.
        let observed = self.plan[run.index]
            .observe
            .iter()
            .all(|atom| run.observed.contains_key(atom));
        if observed && finishing.iter().all(|k| run.done.contains(k)) {
            self.finish_action(out);
        }
    }

    fn finish_action(&mut self, out: &mut Vec<Command>) {
        let Some(run) = &self.run else { return };
        let index = run.index;
        let action = self.plan[index].action.clone();
        let observation: Vec<Observation> = self.plan[index]
            .observe
            .iter()
            .filter_map(|atom| {
                run.observed.get(atom).map(|&holds| Observation {
                    atom: atom.clone(),
                    holds,
                })
            })
            .collect();
        if !observation.is_empty() {
            for o in &observation {
                self.knowledge.insert(o.atom.clone(), o.holds);
            }
            self.record(LogEvent::Observed {
                index,
                action: action.clone(),
                observation: observations_text(&observation),
            });
        }
        let branch = if index + 1 == self.plan.len() && !self.branches.is_empty() {
            let Some(chosen) = self.branches.iter().position(|b| {
                b.observation
                    .iter()
                    .all(|o| self.knowledge.get(&o.atom) == Some(&o.holds))
            }) else {
                let reason = format!(
                    "it observed {}, which no branch of the plan expects",
                    observations_text(&self.observations())
                );
                self.fail_action(reason, out);
                return;
            };
            Some(std::mem::take(&mut self.branches).swap_remove(chosen))
        } else {
            None
        };
        let Some(mut run) = self.run.take() else {
            return;
        };
        out.push(Command::CancelTimer(Timer::Action));
        out.extend(
            run.take_component_timers()
                .into_iter()
                .map(Command::CancelTimer),
        );
        // Inputs still waiting for their producer are wired all the same:
        // the next action may keep them.
        out.extend(run.deferred.into_iter().map(|(_, wire)| wire));
        self.record(LogEvent::ActionDone { index, action });
        if let Some(branch) = branch {
            self.record(LogEvent::Branch {
                observation: observations_text(&branch.observation),
                probability: branch.probability,
                actions: branch.plan.steps.iter().map(|a| a.action.clone()).collect(),
            });
            self.continue_with(Arc::unwrap_or_clone(branch.plan));
        }
        self.start_action(index + 1, out);
    }

    /// Goes on with `plan` after the actions of the path so far.
    fn continue_with(&mut self, plan: Plan) {
        self.plan.extend(plan.steps);
        self.branches = plan.branches;
        self.success = plan.success;
    }

    /// The observations the pending branches expect, for the log.
    fn branch_observations(&self) -> Vec<String> {
        self.branches
            .iter()
            .map(|b| observations_text(&b.observation))
            .collect()
    }

    /// A component of the configuration reported what it observed.
    fn on_observed(&mut self, key: ComponentKey, literals: &str, out: &mut Vec<Command>) {
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

    fn fail_action(&mut self, reason: String, out: &mut Vec<Command>) {
        self.stop_awaiting(out);
        let Some(mut run) = self.run.take() else {
            return;
        };
        out.push(Command::CancelTimer(Timer::Action));
        if run.deploy_timer {
            out.push(Command::CancelTimer(Timer::Deploy));
        }
        out.extend(
            run.take_component_timers()
                .into_iter()
                .map(Command::CancelTimer),
        );
        self.failed_actions
            .push(self.plan[run.index].action.clone());
        self.record(LogEvent::ActionFailed {
            index: run.index,
            action: self.plan[run.index].action.clone(),
            reason: reason.clone(),
        });
        self.status = RunStatus::Failed {
            index: run.index,
            reason,
        };
    }

    /// Leaves the ecology as the task found it: switches off every component
    /// this task switched on, and clears the `params` of components it only
    /// borrowed (their bodies stop; they report `idle`). Logged once.
    fn release(&mut self, out: &mut Vec<Command>) {
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
        self.running = None;
        let unreachable: Vec<String> = unreachable
            .into_iter()
            .map(|(p, c)| format!("{p}:{c}"))
            .collect();
        if !switched_off.is_empty() || !stopped.is_empty() || !unreachable.is_empty() {
            self.record(LogEvent::Released {
                switched_off,
                stopped,
                unreachable,
            });
        }
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
}
