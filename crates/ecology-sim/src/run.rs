//! Running a scenario: the world as a PEIS stepping in virtual time, one host
//! per PEIS with simulated components, fault injection, and the executive
//! driving the plan, all in one process on the in-process tuple space.
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
    Acquisition, DriverConfig, ExecConfig, Executive, Intake, LogEntry, LogEvent, Replan,
    RunStatus, drive_until,
};
use ecology_peis::{HostError, run_host};
use ecology_tuples::contract;
use ecology_tuples::{
    Clock, InProcessPeis, InProcessSpace, Key, PeisId, PeisOptions, PresenceEvent, Timestamp,
    Tuple, TupleError, TupleEvent, TuplePattern, TupleSpace, VirtualClock,
};
use tokio::sync::watch;
use tokio::task::{AbortHandle, JoinSet};

use crate::components::{Faults, WORLD};
use crate::host::simulated_components;
use crate::replan::WorldReplanner;
use crate::scenario::{FaultKind, FaultSpec, PeisDef, Scenario, Trigger};
use crate::world::World;
use crate::world_peis::WorldPeis;

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
        }
    }
}

/// What a run reports while it goes.
#[derive(Debug, Clone, PartialEq)]
pub enum Update {
    /// The executive logged this.
    Log(LogEntry),
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

/// How a run ended.
#[derive(Debug, Clone)]
pub struct Report {
    /// The executive's final status (`Running` when the time limit hit).
    pub status: RunStatus,
    /// The executive's whole log.
    pub log: Vec<LogEntry>,
    /// The faults injected, with their simulated times.
    pub injected: Vec<(Duration, String)>,
    /// Simulated time at the end.
    pub sim_time: Duration,
    /// Whether the scenario's time limit stopped the run.
    pub timed_out: bool,
    /// Failures the executive acted on that the ground truth does not bear
    /// out: a component it failed for `error` or `waiting` that reports
    /// something else, a PEIS it took for gone that is present. A duplicate
    /// or late tuple taken as news would show here.
    pub spurious: Vec<String>,
    /// The world at the end (ground truth).
    pub world: World,
    /// What the executive took in from the ecology.
    pub intake: Intake,
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

/// Runs `scenario` to the end of its task (or its time limit), reporting to
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
        schedule: schedule.clone(),
        seed: options.seed,
        pace: options.pace,
        step: options.step,
        observer: observer.clone(),
        injected: injected.clone(),
    };
    let mut tasks = JoinSet::new();
    tasks.spawn(simulation.run(world_peis, stopped));

    let me = space.join(
        PeisId::new("executive").map_err(TupleError::Invalid)?,
        PeisOptions::default(),
    )?;
    let mut watching = JoinSet::new();
    if options.observe_tuples {
        watch_tuples(&me, &observer, &mut watching).await?;
    }
    let (exec, driven, spurious) = drive_scenario(
        scenario, options, &me, &space, &shared, &schedule, &observer,
    )
    .await;
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
    drop(me);
    if let Ok(space) = Arc::try_unwrap(space) {
        space.shutdown().await;
    }
    let status = driven?;
    let world = outcome?;
    let injected = lock(&injected).clone();
    Ok(Report {
        timed_out: matches!(status, RunStatus::Running { .. } | RunStatus::Idle),
        status,
        log: exec.log().to_vec(),
        injected,
        sim_time,
        world,
        spurious,
        intake: *exec.intake(),
    })
}

/// Reads every tuple change and presence event through the executive's own
/// handle `me` (so watching adds no PEIS to the ecology) and hands them to
/// `observer`, in a task `watching` owns.
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

/// Drives the scenario's plan with the executive as `me` until the task
/// ends or the time limit passes: faults triggered by executive events are
/// scheduled as they are logged, and every failure the executive logs is
/// checked against the ground truth. Returns the executive, how the drive
/// ended, and the failures the ground truth does not bear out.
async fn drive_scenario(
    scenario: &Scenario,
    options: &RunOptions,
    me: &InProcessPeis,
    space: &Arc<InProcessSpace>,
    shared: &Arc<dyn Clock>,
    schedule: &Schedule,
    observer: &Arc<Mutex<Observer>>,
) -> (Executive, Result<RunStatus, TupleError>, Vec<String>) {
    let mut exec = Executive::new(
        scenario.domain.clone(),
        EcologyState::new(),
        scenario.plan.clone(),
        ExecConfig {
            action_timeout: scenario.action_timeout,
            ..ExecConfig::default()
        },
    );
    if options.wall_stopwatch {
        exec = exec.with_stopwatch(Box::new(ecology_core::WallClock::start()));
    }
    let config = DriverConfig {
        limit: Some(scenario.time_limit),
        acquisition: options.acquisition,
        ..DriverConfig::default()
    };
    let mut triggers: Vec<(FaultSpec, bool)> = scenario
        .faults
        .iter()
        .filter(|f| matches!(f.trigger, Trigger::After { .. }))
        .map(|f| (f.clone(), false))
        .collect();
    let mut current_action: Option<usize> = None;
    let mut spurious = Vec::new();
    // Action-level recovery when the scenario has a problem to plan again.
    let mut replanner = scenario
        .problem
        .as_ref()
        .map(|(problem, _)| WorldReplanner::new(scenario.domain.clone(), problem.clone()));
    let driven = {
        let truth = space;
        let observe = |entry: &LogEntry| {
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
                && let Some(why) = unfounded(truth, peis, component, cause)
            {
                spurious.push(format!(
                    "{:.3}s {peis}:{component} ({cause}): {why}",
                    entry.t.as_secs_f64()
                ));
            }
            (lock(observer))(Update::Log(entry.clone()));
        };
        drive_until(
            me,
            shared.clone(),
            &mut exec,
            config,
            observe,
            std::future::pending(),
            replanner.as_mut().map(|r| r as &mut dyn Replan),
        )
        .await
    };
    (exec, driven, spurious)
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
    schedule: Schedule,
    seed: u64,
    pace: Pace,
    step: Duration,
    observer: Arc<Mutex<Observer>>,
    injected: Arc<Mutex<Vec<(Duration, String)>>>,
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
    stop: watch::Sender<bool>,
    stopped: watch::Receiver<bool>,
}

impl Hosts {
    fn new() -> Hosts {
        let (stop, stopped) = watch::channel(false);
        Hosts {
            tasks: JoinSet::new(),
            running: BTreeMap::new(),
            stop,
            stopped,
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

    /// Stops every host and waits for them; the first that failed, if any.
    async fn shut_down(mut self) -> Option<RunError> {
        let _ = self.stop.send(true);
        let mut failure = None;
        while let Some(joined) = self.tasks.join_next().await {
            if let Ok((peis, Err(error))) = joined
                && self.running.contains_key(&peis)
                && failure.is_none()
            {
                failure = Some(RunError::Host { peis, error });
            }
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
        let mut stop = hosts.stopped.clone();
        let name = def.name.clone();
        let host = run_host(
            handle.clone(),
            self.shared.clone(),
            simulated_components(def, &self.faults, self.seed),
            async move {
                let _ = stop.wait_for(|s| *s).await;
            },
        );
        let task = hosts.tasks.spawn(async move { (name, host.await) });
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
        let pattern = TuplePattern::parse("*:*.status").map_err(TupleError::Invalid)?;
        let mut statuses = space.subscribe(pattern).await?;
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
            while let Some(event) = statuses.try_next() {
                if let TupleEvent::Changed(tuple) = event {
                    remember(&mut recent, tuple);
                }
            }
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
        let stopped = hosts.shut_down().await;
        match failure.or(stopped) {
            Some(e) => Err(e),
            None => Ok(world.into_world()),
        }
    }
}
