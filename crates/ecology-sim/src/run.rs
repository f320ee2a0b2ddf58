//! Running a scenario: the world as a PEIS stepping in virtual time, one host
//! per PEIS with simulated components, fault injection, and one executive per
//! task driving its plan, all in one process on the in-process tuple space.
//!
//! The simulation loop owns virtual time: each step it lets every task run
//! until the ecology has settled, applies the motor commands, grasps and
//! sounds the components published, injects the faults that are due, moves
//! the robots, publishes the new ground truth and advances the clock by one
//! fixed step. With [`Pace::Speed`] it also waits on the wall clock so that
//! simulated time runs at that multiple of real time.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use ecology_domain::EcologyState;
use ecology_exec::{
    Acquisition, Controls, DriverConfig, ExecConfig, Executive, Intake, LogEntry, LogEvent, Replan,
    RunStatus, drive_until,
};
use ecology_peis::{HostError, run_host};
use ecology_tuples::contract;
use ecology_tuples::{
    Clock, InProcessPeis, InProcessSpace, Key, PeisId, PeisOptions, PresenceEvent, Subscription,
    Timestamp, Tuple, TupleError, TupleEvent, TuplePattern, TupleSpace, VirtualClock,
};
use tokio::sync::watch;
use tokio::task::{AbortHandle, JoinSet};

use crate::components::Faults;
use crate::conflicts::{Change, ConflictCheck};
use crate::host::{RobotRoom, simulated_components, with_robot_room};
use crate::replan::WorldReplanner;
use crate::scenario::{FaultKind, FaultSpec, PeisDef, Scenario, ScenarioTask, Trigger};
use crate::world::World;
use crate::world_peis::WorldPeis;
use ecology_tuples::world::WORLD;

/// How fast simulated time runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pace {
    /// As fast as the machine can step it.
    Unpaced,
    /// This many simulated seconds per wall-clock second (1.0 = real time).
    Speed(f64),
}

/// How to run a scenario.
#[derive(Debug, Clone, PartialEq)]
pub struct RunOptions {
    /// The seed of every noise source.
    pub seed: u64,
    /// How fast.
    pub pace: Pace,
    /// The simulation's fixed time step.
    pub step: Duration,
    /// Whether the observer also gets every tuple change and presence event ([`Update::Tuple`],
    /// [`Update::Presence`]), for a live view of the run.
    pub observe_tuples: bool,
    /// What of the ecology the executive acquires.
    pub acquisition: Acquisition,
    /// Time the executive's state acquisition and planning by the wall clock
    /// (the log's `micros`, and the planner's time budget); without it they
    /// read 0 and the run is reproducible from its seed alone.
    pub wall_stopwatch: bool,
    /// Whether the run takes down what it built when it ends: the hosts, the executives and
    /// the tuple space. A process that exits right after the run (`ecology run`) leaves them
    /// standing, for the kernel to take back with the process: in a building of 10,000 PEIS
    /// taking them down piece by piece was a tenth of the run. Anything that runs on in the
    /// same process (a sweep, a test) takes them down, or it keeps their memory.
    pub tear_down: bool,
}

impl RunOptions {
    /// Unpaced, 50 ms steps, with `seed`.
    pub fn seeded(seed: u64) -> RunOptions {
        RunOptions {
            seed,
            pace: Pace::Unpaced,
            step: Duration::from_millis(50),
            observe_tuples: false,
            acquisition: Acquisition::OnDemand,
            wall_stopwatch: false,
            tear_down: true,
        }
    }
}

/// What a run reports while it goes.
#[derive(Debug, Clone, PartialEq)]
pub enum Update {
    /// An executive logged this (its time since the run started).
    Log {
        /// The executive's PEIS name (`executive` for a scenario's `[task]`).
        executive: String,
        /// What it logged.
        entry: LogEntry,
    },
    /// A fault was injected at simulated time `t`.
    Injected {
        /// Simulated time since the start.
        t: Duration,
        /// What, such as `hsm:ca1 stalls`.
        what: String,
    },
    /// Another simulated second passed.
    Progress {
        /// Simulated time since the start.
        t: Duration,
    },
    /// A tuple changed (only with [`RunOptions::observe_tuples`]).
    Tuple(TupleEvent),
    /// A PEIS joined or left (only with [`RunOptions::observe_tuples`]).
    Presence(PresenceEvent),
}

/// Receives [`Update`]s as they happen.
pub type Observer = Box<dyn FnMut(Update) + Send>;

/// How one task of a run ended.
#[derive(Debug, Clone)]
pub struct TaskReport {
    /// Its executive's PEIS name.
    pub executive: String,
    /// The executive's final status (`Running` when the time limit hit, `Idle`
    /// when it never started).
    pub status: RunStatus,
    /// The executive's whole log, timed since the run started.
    pub log: Vec<LogEntry>,
    /// What the executive took in from the ecology.
    pub intake: Intake,
}

/// How a run ended.
#[derive(Debug, Clone)]
pub struct Report {
    /// Every task done: `Done`; else the first task's that failed; else
    /// (the time limit hit) the first unfinished one's.
    pub status: RunStatus,
    /// Each task, in the scenario's order.
    pub tasks: Vec<TaskReport>,
    /// The faults injected, with their simulated times.
    pub injected: Vec<(Duration, String)>,
    /// Simulated time at the end.
    pub sim_time: Duration,
    /// Whether the scenario's time limit stopped the run.
    pub timed_out: bool,
    /// Failures the executive acted on that the ground truth does not bear
    /// out: a component it failed for `error` or `waiting` that reports
    /// something else, a PEIS it took for gone that is present. A duplicate
    /// or late tuple taken as news would show here. With several tasks, each
    /// line starts with the executive's name.
    pub spurious: Vec<String>,
    /// Components that served two executives at once: one's params changed
    /// to another's while the first ran them, or an input re-pointed away
    /// from an executive's wiring (see `conflicts.rs`). One line each.
    pub conflicts: Vec<String>,
    /// The world at the end (ground truth).
    pub world: World,
}

/// Why a run could not take place.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The tuple space refused something.
    #[error("tuple space: {0}")]
    Space(#[from] TupleError),
    /// A PEIS host stopped with an error.
    #[error("PEIS {peis}: {error}")]
    Host {
        /// The PEIS.
        peis: String,
        /// The error.
        error: HostError,
    },
    /// A task of the run panicked or was lost.
    #[error("simulation task: {0}")]
    Task(String),
}

/// Settling passes per step: enough for a sensor reading to travel through
/// the longest chain of components (camera → tracking → pose tracking →
/// navigation → world) and for the executive to take in every change.
const SETTLE_PASSES: usize = 48;

type Schedule = Arc<Mutex<Vec<(Timestamp, FaultSpec)>>>;

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Runs `scenario` to the end of its tasks (or its time limit), reporting to
/// `observer` as it goes. Needs a current-thread tokio runtime for
/// reproducible runs (any runtime works, but only one thread is deterministic).
pub async fn run(
    scenario: &Scenario,
    options: &RunOptions,
    observer: Observer,
) -> Result<Report, RunError> {
    let observer = Arc::new(Mutex::new(observer));
    let clock = VirtualClock::default();
    let shared: Arc<dyn Clock> = Arc::new(clock.clone());
    let start = shared.now();
    let space = Arc::new(InProcessSpace::new(shared.clone()));
    let world_peis = space.join(
        PeisId::new(WORLD).map_err(TupleError::Invalid)?,
        PeisOptions::default(),
    )?;
    // Watching goes through the world's own handle, so it adds no PEIS to the ecology.
    let watcher = world_peis.clone();
    let truth = Arc::new(Mutex::new(GroundTruth {
        tuples: GroundTruth::follow(&watcher, scenario)?,
        clock: shared.clone(),
        start,
        check: ConflictCheck::default(),
    }));

    let schedule: Schedule = Arc::new(Mutex::new(
        scenario
            .faults
            .iter()
            .filter_map(|f| match f.trigger {
                Trigger::At(at) => Some((start.saturating_add(at), f.clone())),
                Trigger::After { .. } => None,
            })
            .collect(),
    ));
    let (stop, stopped) = watch::channel(false);
    let injected = Arc::new(Mutex::new(Vec::new()));
    let simulation = Simulation {
        space: space.clone(),
        clock: clock.clone(),
        shared: shared.clone(),
        start,
        world: scenario.world_for(options.seed),
        peis: scenario.peis.clone(),
        faults: Faults::default(),
        redelivers: scenario
            .faults
            .iter()
            .any(|f| matches!(f.kind, FaultKind::Duplicate | FaultKind::Late)),
        schedule: schedule.clone(),
        seed: options.seed,
        pace: options.pace,
        step: options.step,
        observer: observer.clone(),
        injected: injected.clone(),
        truth: truth.clone(),
        tear_down: options.tear_down,
    };
    let mut tasks = JoinSet::new();
    tasks.spawn(simulation.run(world_peis, stopped));

    let mut watching = JoinSet::new();
    if options.observe_tuples {
        watch_tuples(&watcher, &observer, &mut watching).await?;
    }
    let context = Drive {
        scenario,
        options,
        space: &space,
        shared: &shared,
        start,
        schedule: &schedule,
        observer: &observer,
        truth: &truth,
    };
    // Every task's executive in this task, polled in the scenario's order: reproducible.
    let driven =
        futures_util::future::join_all(scenario.tasks.iter().map(|task| context.drive(task))).await;
    let _ = stop.send(true);
    watching.abort_all();
    let mut outcome = Ok(scenario.world_for(options.seed));
    while let Some(joined) = tasks.join_next().await {
        outcome = match joined {
            Ok(result) => result,
            Err(e) => Err(RunError::Task(e.to_string())),
        };
    }
    let sim_time = shared.now().saturating_duration_since(start);
    let conflicts = {
        let mut truth = lock(&truth);
        truth.take_in();
        truth.check.conflicts().to_vec()
    };
    drop(watcher);
    drop(truth);
    let several = scenario.tasks.len() > 1;
    let mut reports = Vec::new();
    let mut spurious = Vec::new();
    let mut failure = None;
    for driven in driven {
        let status = match driven.status {
            Ok(status) => status,
            Err(e) => {
                failure.get_or_insert(e);
                RunStatus::Idle
            }
        };
        for line in driven.spurious {
            spurious.push(if several {
                format!("{}: {line}", driven.executive)
            } else {
                line
            });
        }
        reports.push(TaskReport {
            executive: driven.executive,
            status,
            log: driven.log,
            intake: driven.intake,
        });
    }
    if options.tear_down
        && let Ok(space) = Arc::try_unwrap(space)
    {
        space.shutdown().await;
    }
    if let Some(e) = failure {
        return Err(e.into());
    }
    let world = outcome?;
    let injected = lock(&injected).clone();
    let unfinished = |s: &RunStatus| matches!(s, RunStatus::Running { .. } | RunStatus::Idle);
    let status = if reports.iter().all(|r| r.status == RunStatus::Done) {
        RunStatus::Done
    } else {
        reports
            .iter()
            .find(|r| matches!(r.status, RunStatus::Failed { .. }))
            .or_else(|| reports.iter().find(|r| unfinished(&r.status)))
            .map_or(RunStatus::Idle, |r| r.status.clone())
    };
    Ok(Report {
        timed_out: reports.iter().any(|r| unfinished(&r.status)),
        status,
        tasks: reports,
        injected,
        sim_time,
        world,
        spurious,
        conflicts,
    })
}

/// What the ground-truth check of several executives reads: every tuple
/// change of the ecology, taken in before each log entry (so both are seen in
/// the order they happened: the in-process space hands a change to its
/// subscribers as it makes it) and at every step of the simulation.
struct GroundTruth {
    /// Nothing with one executive: there is no other for it to conflict with.
    tuples: Option<Subscription>,
    clock: Arc<dyn Clock>,
    start: Timestamp,
    check: ConflictCheck,
}

impl GroundTruth {
    /// Follows what the check reads, and nothing more, so that it reads no component's output
    /// (an output nobody else reads is not published): every two-segment key (`C.params`,
    /// `C.mi-INFO`, …) and `C.mi-INFO.ARG` for each information of the tasks' domains.
    fn follow(
        watcher: &InProcessPeis,
        scenario: &Scenario,
    ) -> Result<Option<Subscription>, TupleError> {
        if scenario.tasks.len() < 2 {
            return Ok(None);
        }
        let mut infos = std::collections::BTreeSet::new();
        for task in &scenario.tasks {
            for f in &task.domain.functionalities {
                infos.extend(f.inputs.iter().map(|i| i.name.to_string()));
            }
        }
        let mut patterns = vec![TuplePattern::parse("*:*.*").map_err(TupleError::Invalid)?];
        // An information whose name is no key segment has no `mi-` tuple to follow.
        patterns.extend(
            infos
                .iter()
                .filter_map(|info| TuplePattern::parse(&format!("*:*.mi-{info}.*")).ok()),
        );
        watcher.subscribe_any(patterns).map(Some)
    }

    /// Feeds the check every tuple change not yet taken in.
    fn take_in(&mut self) {
        let Some(tuples) = &mut self.tuples else {
            return;
        };
        while let Some(event) = tuples.try_next() {
            let (change, at) = match &event {
                TupleEvent::Changed(tuple) => (
                    Change {
                        owner: tuple.owner.as_str(),
                        key: tuple.key.as_str(),
                        value: tuple.text().unwrap_or(""),
                        epoch: tuple.epoch,
                        creator: tuple.creator.as_ref().map(PeisId::as_str),
                    },
                    tuple.ts_write,
                ),
                TupleEvent::Removed {
                    owner, key, epoch, ..
                } => (
                    Change {
                        owner: owner.as_str(),
                        key: key.as_str(),
                        value: "",
                        epoch: *epoch,
                        creator: None,
                    },
                    self.clock.now(),
                ),
                _ => continue,
            };
            self.check
                .changed(at.saturating_duration_since(self.start), change);
        }
    }
}

/// What every task's drive shares.
struct Drive<'a> {
    scenario: &'a Scenario,
    options: &'a RunOptions,
    space: &'a Arc<InProcessSpace>,
    shared: &'a Arc<dyn Clock>,
    start: Timestamp,
    schedule: &'a Schedule,
    observer: &'a Arc<Mutex<Observer>>,
    truth: &'a Arc<Mutex<GroundTruth>>,
}

/// How one task's drive ended.
struct Driven {
    executive: String,
    status: Result<RunStatus, TupleError>,
    log: Vec<LogEntry>,
    intake: Intake,
    spurious: Vec<String>,
}

/// Reads every tuple change and presence event through the handle `me` of a
/// PEIS already present (so watching adds no PEIS to the ecology) and hands
/// them to `observer`, in a task `watching` owns.
async fn watch_tuples(
    me: &InProcessPeis,
    observer: &Arc<Mutex<Observer>>,
    watching: &mut JoinSet<()>,
) -> Result<(), TupleError> {
    let mut tuples = me.subscribe(TuplePattern::everything()).await?;
    let mut presence = me.subscribe_presence().await?;
    let observer = observer.clone();
    watching.spawn(async move {
        loop {
            let update = tokio::select! {
                Some(event) = tuples.next() => Update::Tuple(event),
                Some(event) = presence.next() => Update::Presence(event),
                else => return,
            };
            (lock(&observer))(update);
        }
    });
    Ok(())
}

impl Drive<'_> {
    /// Drives `task`'s plan with its executive, which joins the ecology under
    /// its name at the task's start, until the task ends or the time limit
    /// passes: faults triggered by its events are scheduled as they are
    /// logged, and every failure it logs is checked against the ground truth.
    async fn drive(&self, task: &ScenarioTask) -> Driven {
        let Drive {
            scenario,
            options,
            space,
            shared,
            start,
            schedule,
            observer,
            truth,
        } = *self;
        if !task.start.is_zero() {
            shared.sleep_until(start.saturating_add(task.start)).await;
        }
        // The log is timed from the executive's start; the run's from its own.
        let offset = shared.now().saturating_duration_since(start);
        let mut exec = Executive::new(
            task.domain.clone(),
            EcologyState::new(),
            task.plan.clone(),
            ExecConfig {
                action_timeout: scenario.action_timeout,
                ..ExecConfig::default()
            },
        );
        let shifted = |entry: &LogEntry| LogEntry {
            t: entry.t + offset,
            event: entry.event.clone(),
        };
        let joined = PeisId::new(&task.executive)
            .map_err(TupleError::Invalid)
            .and_then(|id| space.join(id, PeisOptions::default()));
        let me = match joined {
            Ok(me) => me,
            Err(e) => {
                return Driven {
                    executive: task.executive.clone(),
                    status: Err(e),
                    log: Vec::new(),
                    intake: *exec.intake(),
                    spurious: Vec::new(),
                };
            }
        };
        if options.wall_stopwatch {
            exec = exec.with_stopwatch(Box::new(ecology_core::WallClock::start()));
        }
        let config = DriverConfig {
            limit: Some(scenario.time_limit.saturating_sub(offset)),
            acquisition: options.acquisition,
            ..DriverConfig::default()
        };
        let first = scenario.tasks.first().map(|t| t.executive.as_str());
        let mut triggers: Vec<(FaultSpec, bool)> = scenario
            .faults
            .iter()
            .filter(|f| match &f.trigger {
                Trigger::After { executive, .. } => {
                    executive.as_deref().or(first) == Some(task.executive.as_str())
                }
                Trigger::At(_) => false,
            })
            .map(|f| (f.clone(), false))
            .collect();
        let mut current_action: Option<usize> = None;
        let mut spurious = Vec::new();
        // Action-level recovery when the task has a problem to plan again.
        let mut replanner = task
            .problem
            .as_ref()
            .map(|(problem, _)| WorldReplanner::new(task.domain.clone(), problem.clone()));
        let driven = {
            let observe = |entry: &LogEntry| {
                let entry = shifted(entry);
                let index = match &entry.event {
                    LogEvent::ActionStarted { index, .. }
                    | LogEvent::ActionDone { index, .. }
                    | LogEvent::ActionFailed { index, .. } => Some(*index),
                    _ => current_action,
                };
                if let LogEvent::ActionStarted { index, .. } = entry.event {
                    current_action = Some(index);
                }
                for (fault, fired) in &mut triggers {
                    if let Some(delay) = fault.trigger.fired_by(entry.event.name(), index)
                        && !*fired
                    {
                        *fired = true;
                        lock(schedule).push((shared.now().saturating_add(delay), fault.clone()));
                    }
                }
                if let Some((peis, component, cause)) = entry.event.failure()
                    && let Some(why) = unfounded(space, peis, component, cause)
                {
                    spurious.push(format!(
                        "{:.3}s {peis}:{component} ({cause}): {why}",
                        entry.t.as_secs_f64()
                    ));
                }
                {
                    // What changed before the entry was logged is taken in first.
                    let mut truth = lock(truth);
                    truth.take_in();
                    truth.check.logged(&task.executive, &entry.event);
                }
                (lock(observer))(Update::Log {
                    executive: task.executive.clone(),
                    entry,
                });
            };
            drive_until(
                &me,
                shared.clone(),
                &mut exec,
                config,
                observe,
                std::future::pending(),
                Controls {
                    replan: replanner.as_mut().map(|r| r as &mut dyn Replan),
                    report: None,
                },
            )
            .await
        };
        drop(me);
        let driven = Driven {
            executive: task.executive.clone(),
            status: driven,
            log: exec.log().iter().map(shifted).collect(),
            intake: *exec.intake(),
            spurious,
        };
        if !self.options.tear_down {
            // Left to the kernel with the process (see `RunOptions::tear_down`).
            std::mem::forget(exec);
        }
        driven
    }
}

/// Why a failure the executive logged is not borne out by the ground truth
/// at that instant, if it is not.
fn unfounded(truth: &InProcessSpace, peis: &str, component: &str, cause: &str) -> Option<String> {
    let id = PeisId::new(peis).ok()?;
    if cause.starts_with("PEIS ") && cause.ends_with(" left the ecology") {
        return truth.is_present(&id).then(|| format!("{peis} is present"));
    }
    if let Some((consumer, _)) = cause.split_once(" cannot read its ") {
        // Blamed by its consumer: the consumer really says it cannot read.
        let (peis, component) = consumer.split_once(':')?;
        let id = PeisId::new(peis).ok()?;
        let read = |field: &str| {
            let key = Key::new(&format!("{component}.{field}")).ok()?;
            truth
                .peek(&id, &key)
                .and_then(|t| t.text().ok().map(str::to_string))
        };
        let says = read("status").as_deref() == Some("waiting")
            && read("cause").is_some_and(|c| contract::parse_unreadable(&c).is_some());
        return (!says).then(|| format!("{consumer} does not say it cannot read"));
    }
    let expected = if cause.starts_with("waiting for longer than") {
        "waiting"
    } else if cause.starts_with("PEIS ")
        || cause.starts_with("did not ")
        || cause.starts_with("could not set ")
    {
        // A restart, a timeout or a refused remote set: facts of their own.
        return None;
    } else {
        "error"
    };
    let key = Key::new(&format!("{component}.status")).ok()?;
    let status = truth
        .peek(&id, &key)
        .and_then(|t| t.text().ok().map(str::to_string));
    match status {
        Some(status) if status == expected => None,
        // Gone with its PEIS: the executive's view lags by no more than the departure.
        None => None,
        Some(status) => Some(format!("it reports {status}")),
    }
}

/// The simulation loop and what it owns.
struct Simulation {
    space: Arc<InProcessSpace>,
    clock: VirtualClock,
    shared: Arc<dyn Clock>,
    start: Timestamp,
    world: World,
    peis: Vec<PeisDef>,
    faults: Faults,
    /// Whether the scenario delivers status tuples again (duplicates, late arrivals).
    redelivers: bool,
    schedule: Schedule,
    seed: u64,
    pace: Pace,
    step: Duration,
    observer: Arc<Mutex<Observer>>,
    injected: Arc<Mutex<Vec<(Duration, String)>>>,
    /// Taken in every step, so that what it buffers stays small.
    truth: Arc<Mutex<GroundTruth>>,
    /// [`RunOptions::tear_down`].
    tear_down: bool,
}

/// A running PEIS host: its handle (to crash it) and its task.
struct Hosted {
    handle: InProcessPeis,
    task: AbortHandle,
}

/// The PEIS hosts the simulation loop owns: every host task (crashed ones
/// are aborted), the ones running now, and the signal that stops them.
struct Hosts {
    tasks: JoinSet<(String, Result<(), HostError>)>,
    running: BTreeMap<String, Hosted>,
}

impl Hosts {
    fn new() -> Hosts {
        Hosts {
            tasks: JoinSet::new(),
            running: BTreeMap::new(),
        }
    }

    /// A host that stopped on its own failed (a crashed PEIS's host is aborted).
    fn failed(&mut self) -> Option<RunError> {
        while let Some(joined) = self.tasks.try_join_next() {
            if let Ok((peis, Err(error))) = joined
                && self.running.contains_key(&peis)
            {
                return Some(RunError::Host { peis, error });
            }
        }
        None
    }

    /// Ends every host where it stands, the run being over, and waits for them; the first that
    /// had failed, if any. A host that stops alone switches its components off one by one; at the
    /// end of a run nobody is left to hear it, and in a building that was a tenth of the run.
    /// Without `tear_down` the hosts are left as they stand, never to be polled again.
    async fn shut_down(mut self, tear_down: bool) -> Option<RunError> {
        let failure = self.failed();
        if tear_down {
            self.tasks.abort_all();
            while self.tasks.join_next().await.is_some() {}
        } else {
            std::mem::forget(self);
        }
        failure
    }
}

/// The last two status tuples of each (PEIS, key), to deliver again as
/// duplicates and late arrivals.
type Recent = BTreeMap<(String, String), Vec<Tuple>>;

/// Keeps `tuple` among the last two of its (PEIS, key).
fn remember(recent: &mut Recent, tuple: Tuple) {
    let history = recent
        .entry((tuple.owner.to_string(), tuple.key.to_string()))
        .or_default();
    history.push(tuple);
    if history.len() > 2 {
        history.remove(0);
    }
}

impl Simulation {
    /// Starts the host of `def` among `hosts` (not yet counted as running).
    fn start_host(&self, def: &PeisDef, hosts: &mut Hosts) -> Result<Hosted, TupleError> {
        let handle = self.space.join(
            PeisId::new(&def.name).map_err(TupleError::Invalid)?,
            PeisOptions::default(),
        )?;
        let name = def.name.clone();
        // Ended by `Hosts::shut_down`, not asked to stop.
        let host = run_host(
            handle.clone(),
            self.shared.clone(),
            simulated_components(def, &self.faults, self.seed),
            std::future::pending(),
        );
        // Only a robot's host follows its room: wrapped, every host's future (a thousand in a
        // building, each spawned as a task) was four times the size.
        let task = if RobotRoom::needed(def) {
            let (space, def) = (handle.clone(), def.clone());
            hosts
                .tasks
                .spawn(async move { (name, with_robot_room(space, &def, host).await) })
        } else {
            hosts.tasks.spawn(async move { (name, host.await) })
        };
        Ok(Hosted { handle, task })
    }

    /// The faults of the schedule due at `now`, taken out of it.
    fn due_faults(&self, now: Timestamp) -> Vec<FaultSpec> {
        let mut schedule = lock(&self.schedule);
        let (due, later): (Vec<_>, Vec<_>) = schedule.drain(..).partition(|(at, _)| *at <= now);
        *schedule = later;
        due.into_iter().map(|(_, f)| f).collect()
    }

    /// Injects `fault` at `now` (`t` into the run); an error only when a
    /// revived PEIS cannot join the space.
    fn inject(
        &self,
        fault: FaultSpec,
        now: Timestamp,
        t: Duration,
        recent: &Recent,
        hosts: &mut Hosts,
    ) -> Result<(), RunError> {
        let component = fault.component.clone().unwrap_or_default();
        let target = format!("{}:{component}", fault.peis);
        match fault.kind {
            FaultKind::Fail => {
                self.faults.update(&fault.peis, &component, |s| {
                    s.failed = Some(fault.cause.clone());
                });
                self.note(t, format!("{target} fails: {}", fault.cause));
            }
            FaultKind::Stall => {
                self.faults
                    .update(&fault.peis, &component, |s| s.stalled = true);
                self.note(t, format!("{target} stalls (stops publishing)"));
            }
            FaultKind::Garble => {
                self.faults
                    .update(&fault.peis, &component, |s| s.garbled = true);
                self.note(t, format!("{target} garbles its outputs"));
            }
            FaultKind::Recover => {
                self.faults
                    .update(&fault.peis, &component, |s| *s = Default::default());
                self.note(t, format!("{target} recovers"));
            }
            FaultKind::Duplicate | FaultKind::Late => {
                let key = (fault.peis.clone(), format!("{component}.status"));
                let history = recent.get(&key).map(Vec::as_slice).unwrap_or_default();
                let (tuple, what) = match (fault.kind, history) {
                    (FaultKind::Duplicate, [.., last]) => (last, "again"),
                    (_, [older, _]) => (older, "late, after a newer one"),
                    _ => return Ok(()),
                };
                self.space.redeliver(tuple.clone());
                self.note(
                    t,
                    format!(
                        "{target}.status `{}` (seq {}) delivered {what}",
                        tuple.text().unwrap_or(""),
                        tuple.seq
                    ),
                );
            }
            FaultKind::Kill => {
                if let Some(hosted) = hosts.running.remove(&fault.peis) {
                    hosted.task.abort();
                    hosted.handle.vanish();
                    self.note(t, format!("PEIS {} crashes", fault.peis));
                }
            }
            FaultKind::Revive => self.revive(fault, now, t, hosts)?,
        }
        Ok(())
    }

    /// Starts the host of a crashed PEIS again; while the space still holds
    /// it present (its lease has not run out), tries again shortly.
    fn revive(
        &self,
        fault: FaultSpec,
        now: Timestamp,
        t: Duration,
        hosts: &mut Hosts,
    ) -> Result<(), RunError> {
        if hosts.running.contains_key(&fault.peis) {
            return Ok(());
        }
        let Some(def) = self.peis.iter().find(|p| p.name == fault.peis).cloned() else {
            return Ok(());
        };
        match self.start_host(&def, hosts) {
            Ok(hosted) => {
                hosts.running.insert(def.name.clone(), hosted);
                self.note(t, format!("PEIS {} starts again", fault.peis));
            }
            Err(TupleError::AlreadyPresent(_)) => {
                lock(&self.schedule).push((now.saturating_add(Duration::from_millis(500)), fault))
            }
            Err(e) => return Err(RunError::Space(e)),
        }
        Ok(())
    }

    fn note(&self, t: Duration, what: String) {
        lock(&self.injected).push((t, what.clone()));
        (lock(&self.observer))(Update::Injected { t, what });
    }

    async fn run(
        self,
        space: InProcessPeis,
        stop: watch::Receiver<bool>,
    ) -> Result<World, RunError> {
        let mut world = WorldPeis::join(&space, self.world.clone(), self.seed).await?;

        // The recent status tuples of every component, to deliver again as
        // duplicates and late arrivals.
        // Kept only when the scenario has such faults.
        let mut statuses = if self.redelivers {
            let pattern = TuplePattern::parse("*:*.status").map_err(TupleError::Invalid)?;
            Some(space.subscribe(pattern).await?)
        } else {
            None
        };
        let mut recent = Recent::new();
        let mut hosts = Hosts::new();
        for def in self.peis.clone() {
            let hosted = self.start_host(&def, &mut hosts)?;
            hosts.running.insert(def.name.clone(), hosted);
        }
        let wall_start = Instant::now();
        let mut next_progress = Duration::from_secs(1);
        let mut failure = None;
        loop {
            for _ in 0..SETTLE_PASSES {
                tokio::task::yield_now().await;
            }
            if *stop.borrow() {
                break;
            }
            let now = self.shared.now();
            let t = now.saturating_duration_since(self.start);
            failure = hosts.failed();
            if failure.is_some() {
                break;
            }
            while let Some(event) = statuses.as_mut().and_then(Subscription::try_next) {
                if let TupleEvent::Changed(tuple) = event {
                    remember(&mut recent, tuple);
                }
            }
            lock(&self.truth).take_in();
            // Faults that are due.
            for fault in self.due_faults(now) {
                if let Err(e) = self.inject(fault, now, t, &recent, &mut hosts) {
                    failure = Some(e);
                    break;
                }
            }
            if failure.is_some() {
                break;
            }

            // One step of the world, published, then time moves on.
            world.step(&space, self.step).await?;
            self.clock.advance(self.step);
            let t = t + self.step;
            if t >= next_progress {
                next_progress += Duration::from_secs(1);
                (lock(&self.observer))(Update::Progress { t });
            }
            if let Pace::Speed(speed) = self.pace
                && speed > 0.0
            {
                let due = wall_start + t.div_f64(speed);
                tokio::time::sleep_until(due.into()).await;
            }
        }
        let stopped = hosts.shut_down(self.tear_down).await;
        match failure.or(stopped) {
            Some(e) => Err(e),
            None => Ok(world.into_world()),
        }
    }
}
