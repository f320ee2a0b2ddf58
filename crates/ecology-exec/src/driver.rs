//! The driver: connects the sans-IO [`Executive`] to a tuple space.
//!
//! It subscribes to every tuple and to presence, turns what arrives into
//! [`Event`]s, carries out the [`Command`]s (remote sets, timers on the
//! space's clock), and returns when the run is over. It spawns nothing: the
//! whole loop is one future the caller owns.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::future::Future;
use std::sync::Arc;
use std::time::Duration;

use futures_util::stream::{FuturesOrdered, SelectAll};
use futures_util::{FutureExt, StreamExt};
use tokio::task::JoinSet;

use ecology_tuples::{
    Clock, Key, PeisId, PresenceEvent, Timestamp, Tuple, TupleError, TupleEvent, TuplePattern,
    TupleSpace, Value,
};

use crate::executive::{Command, Event, Executive, RunStatus, Timer};
use crate::interest::Interest;
use crate::log::LogEntry;
use crate::plan::{Observation, Plan};

/// How the driver runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DriverConfig {
    /// How long to take in the ecology's current tuples before starting.
    pub settle: Duration,
    /// Give up after this long (the run is then still `Running`).
    pub limit: Option<Duration>,
    /// What of the ecology to acquire.
    pub acquisition: Acquisition,
}

impl Default for DriverConfig {
    fn default() -> DriverConfig {
        DriverConfig {
            settle: Duration::from_millis(200),
            limit: None,
            acquisition: Acquisition::OnDemand,
        }
    }
}

/// What of the ecology the driver acquires for the executive.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Acquisition {
    /// What the plan's configuration goals can use ([`Executive::interest`]):
    /// every PEIS's directory of component types, and the contract tuples of
    /// the PEIS with a component of a type of interest. When a replan needs
    /// more, more is followed before the new plan starts.
    #[default]
    OnDemand,
    /// Every tuple of every PEIS.
    Everything,
}

/// Runs `exec` on `space` until the task is done or failed (or the limit passes).
pub async fn drive<S: TupleSpace>(
    space: &S,
    clock: Arc<dyn Clock>,
    exec: &mut Executive,
    config: DriverConfig,
) -> Result<RunStatus, TupleError> {
    drive_observed(space, clock, exec, config, |_| {}).await
}

/// [`drive`], calling `observe` with every log entry as soon as the executive
/// writes it (a live timeline, or fault injection keyed to executive events).
pub async fn drive_observed<S: TupleSpace>(
    space: &S,
    clock: Arc<dyn Clock>,
    exec: &mut Executive,
    config: DriverConfig,
    observe: impl FnMut(&LogEntry),
) -> Result<RunStatus, TupleError> {
    drive_until(
        space,
        clock,
        exec,
        config,
        observe,
        std::future::pending(),
        Controls::default(),
    )
    .await
}

/// What a running task can be asked besides its events: a new plan when an action fails, and where
/// it stands.
#[derive(Default)]
pub struct Controls<'a> {
    /// Makes a new plan when an action fails (see [`drive_until`]).
    pub replan: Option<&'a mut dyn Replan>,
    /// Woken to print on stderr where the executive stands: [`Executive::describe`], its timers
    /// and the remote sets under way (`ecology task` wakes it on SIGUSR1).
    pub report: Option<&'a tokio::sync::Notify>,
}

impl std::fmt::Debug for Controls<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Controls")
            .field("replan", &self.replan.is_some())
            .field("report", &self.report.is_some())
            .finish()
    }
}

/// Action-level recovery: a new plan when an action fails (the paper's
/// Section VII: the failed action is marked unavailable and the task is
/// planned again from the world as it is).
pub trait Replan: Send {
    /// The tuples that describe the world, read when an action fails.
    fn observe(&self) -> TuplePattern;

    /// A new plan without the action instances of `failed` (every one that
    /// failed in this task), from the world as the tuples `world` describe
    /// it and, under uncertainty, from the belief that what the task's
    /// sensing actions `observed` leaves; `Err` says why there is none.
    fn replan(
        &mut self,
        failed: &[String],
        observed: &[Observation],
        world: &[Tuple],
    ) -> Result<Plan, String>;
}

/// [`drive_observed`], stopping the task when `stop` completes (an operator's
/// interrupt): the executive releases what the task used, and the driver
/// carries that out before it returns.
///
/// Remote sets go out concurrently to different PEIS and in order to each
/// one; one that fails comes back to the executive as
/// [`Event::RemoteSetFailed`]. When an action fails, the `replan` of `controls` (if any) is
/// asked for a new plan from the world as observed, and the task goes on
/// with it ([`Executive::replan`]); without one, or when no plan remains, the
/// task is abandoned ([`Executive::abandon_because`]). Before returning, the
/// driver waits for every remote set it sent (each is bounded by the
/// space's own timeout).
pub async fn drive_until<S: TupleSpace>(
    space: &S,
    clock: Arc<dyn Clock>,
    exec: &mut Executive,
    config: DriverConfig,
    mut observe: impl FnMut(&LogEntry),
    stop: impl Future<Output = ()>,
    controls: Controls<'_>,
) -> Result<RunStatus, TupleError> {
    let Controls { mut replan, report } = controls;
    exec.acting_as(space.peis().clone());
    let mut observed = exec.log().len();
    let start = clock.now();
    let elapsed = |clock: &Arc<dyn Clock>| clock.now().saturating_duration_since(start);
    let acquiring = std::time::Instant::now();
    let mut tuples = Follow::new(space.clone());
    let interest = match config.acquisition {
        Acquisition::OnDemand => exec.interest(),
        Acquisition::Everything => Interest::Everything,
    };
    // What the state handed the executive as it was read comes first.
    let mut commands = tuples.widen(exec, elapsed(&clock), &interest).await?;
    exec.note_acquisition(acquiring.elapsed());
    let mut presence = space.subscribe_presence().await?;
    let mut timers = Timers::default();
    let mut sets = RemoteSets::new(space.clone());
    let settle_until = start.saturating_add(config.settle);
    let mut started = false;
    tokio::pin!(stop);
    let mut stopped = false;
    loop {
        // Commands not yet carried out come before anything else.
        let idle = commands.is_empty();
        if idle && matches!(exec.status(), RunStatus::Failed { .. }) && !exec.finished() {
            commands = match replan.as_deref_mut() {
                Some(replanner) if !stopped => {
                    // A failed read leaves the replanner the plan's own assumptions.
                    let world = space
                        .get_matching(replanner.observe())
                        .await
                        .unwrap_or_default();
                    match replanner.replan(exec.failed_actions(), &exec.observations(), &world) {
                        Ok(plan) => {
                            // What the new plan can use is acquired before it starts.
                            let more = exec.interest_of(&plan);
                            let mut commands = tuples.widen(exec, elapsed(&clock), &more).await?;
                            commands.extend(exec.replan(elapsed(&clock), plan));
                            commands
                        }
                        Err(why) => exec.abandon_because(elapsed(&clock), Some(&why)),
                    }
                }
                _ => exec.abandon(elapsed(&clock)),
            };
        } else if idle && matches!(exec.status(), RunStatus::Done | RunStatus::Failed { .. }) {
            sets.flush(exec, &clock, start).await;
            for entry in &exec.log()[observed..] {
                observe(entry);
            }
            return Ok(exec.status().clone());
        } else if idle && config.limit.is_some_and(|limit| elapsed(&clock) >= limit) {
            sets.flush(exec, &clock, start).await;
            return Ok(exec.status().clone());
        }
        if commands.is_empty() {
            let next_timer = timers.next();
            let wake_at = match (started, &next_timer) {
                (false, _) => Some(settle_until),
                (true, Some((_, at))) => Some(*at),
                (true, None) => None,
            };
            let wake_at = match (wake_at, config.limit) {
                (Some(at), Some(limit)) => Some(at.min(start.saturating_add(limit))),
                (None, Some(limit)) => Some(start.saturating_add(limit)),
                (at, None) => at,
            };
            let sleep = async {
                match wake_at {
                    Some(at) => clock.sleep_until(at).await,
                    None => std::future::pending().await,
                }
            };
            commands = tokio::select! {
                // Biased: the same events give the same order every run (virtual
                // time is reproducible), and a stop or a due timer is never
                // starved by a stream of tuples.
                biased;
                () = &mut stop, if !stopped => {
                    stopped = true;
                    exec.stop(elapsed(&clock), "stopped by the operator")
                }
                () = sleep => {
                    let now = clock.now();
                    if !started && now >= settle_until {
                        started = true;
                        exec.handle(elapsed(&clock), Event::Start)
                    } else if let Some((timer, _)) = next_timer.filter(|(_, at)| *at <= now) {
                        timers.cancel(&timer);
                        exec.handle(elapsed(&clock), Event::Timer(timer))
                    } else {
                        Vec::new()
                    }
                }
                // Asked where it stands (`ecology task` on SIGUSR1): the executive, its timers
                // and the remote sets under way, on stderr.
                () = async {
                    match report {
                        Some(asked) => asked.notified().await,
                        None => std::future::pending().await,
                    }
                } => {
                    let now = clock.now();
                    eprint!(
                        "{}{}{}",
                        exec.describe(),
                        timers.describe(now),
                        sets.describe()
                    );
                    Vec::new()
                }
                Some(outcome) = sets.next_outcome() => exec.handle(elapsed(&clock), outcome),
                event = presence.next() => match event {
                    // It does not leave its own ecology: through a router, the executive sees
                    // its own token go with the router (and come back with it).
                    Some(PresenceEvent::Left(p)) if p == *space.peis() => Vec::new(),
                    Some(PresenceEvent::Joined(p)) => exec.handle(elapsed(&clock), Event::PeisJoined(p)),
                    Some(PresenceEvent::Left(p)) => exec.handle(elapsed(&clock), Event::PeisLeft(p)),
                    None => Vec::new(),
                },
                event = tuples.next() => match event {
                    Some(TupleEvent::Changed(t)) => {
                        let now = elapsed(&clock);
                        let mut out = exec.handle(now, tuple_event(&t));
                        // The tuples already here are taken in at once while they ask for
                        // nothing, instead of one turn of this loop each (a thousand PEIS
                        // announce seven thousand at the start). Nothing else can come in the
                        // meantime, and whatever one of them asks for is carried out before the
                        // next is read, as in a turn of its own.
                        let mut more = TAKEN_AT_ONCE;
                        while out.is_empty() && more > 0 {
                            more -= 1;
                            match tuples.ready() {
                                Some(TupleEvent::Changed(t)) => out = exec.handle(now, tuple_event(&t)),
                                Some(_) => {}
                                None => break,
                            }
                        }
                        out
                    }
                    Some(_) => Vec::new(),
                    None => return Ok(exec.status().clone()),
                },
            };
        }
        // A PEIS that now says it covers a room of the scope (a robot that entered it) is
        // followed from now on.
        if tuples.has_found() {
            commands.extend(tuples.follow_found(exec, elapsed(&clock)).await?);
        }
        for entry in &exec.log()[observed..] {
            observe(entry);
        }
        observed = exec.log().len();
        for command in commands.drain(..) {
            match command {
                Command::StartTimer { timer, after } => {
                    timers.start(timer, clock.now().saturating_add(after));
                }
                Command::CancelTimer(timer) => timers.cancel(&timer),
                Command::RemoteSet { owner, key, value } => sets.send(owner, key, value),
            }
        }
    }
}

/// The executive's timers that run: one deadline per [`Timer`], so that one started again fires
/// only for its latest start, and one cancelled never (see [`Timer`]).
#[derive(Debug, Default)]
pub(crate) struct Timers {
    /// Each timer's deadline, and when it was started among the others: timers due at once fire
    /// in the order they were started.
    running: BTreeMap<Timer, (Timestamp, u64)>,
    started: u64,
}

impl Timers {
    /// Starts `timer` to fire `at`, instead of when it was to if it runs already.
    pub(crate) fn start(&mut self, timer: Timer, at: Timestamp) {
        self.started += 1;
        self.running.insert(timer, (at, self.started));
    }

    /// Stops `timer`, if it runs.
    pub(crate) fn cancel(&mut self, timer: &Timer) {
        self.running.remove(timer);
    }

    /// The timers that run and how long until each fires, one line.
    pub(crate) fn describe(&self, now: Timestamp) -> String {
        let mut due: Vec<(&Timer, &(Timestamp, u64))> = self.running.iter().collect();
        due.sort_by_key(|(_, at)| **at);
        let timers: Vec<String> = due
            .iter()
            .map(|(timer, (at, _))| {
                format!(
                    "{timer:?} in {:.3} s",
                    at.saturating_duration_since(now).as_secs_f64()
                )
            })
            .collect();
        if timers.is_empty() {
            "timers: none\n".to_string()
        } else {
            format!("timers: {}\n", timers.join(", "))
        }
    }

    /// The timer that fires next, and when.
    pub(crate) fn next(&self) -> Option<(Timer, Timestamp)> {
        self.running
            .iter()
            .min_by_key(|(_, due)| **due)
            .map(|(timer, (at, _))| (timer.clone(), *at))
    }
}

/// At most how many tuples already here the driver takes in in one turn of its loop, so that a
/// stop, a due timer or a departure is never kept waiting long behind a stream of tuples.
const TAKEN_AT_ONCE: usize = 256;

/// The subscriptions that bring the executive its tuples: everything, the component contract of
/// every PEIS without the outputs, or that of the PEIS a scope names and of those that cover its
/// rooms (on demand).
///
/// The contract of every PEIS is two wildcard subscriptions whatever the number of PEIS: the
/// directory (`*:components.**`) and each component's own fields (`*:*.*`: `C.status`, `.cause`,
/// `.params`, `.observed` and the input pointers `C.mi-INFO`, but not the outputs `C.out.INFO`,
/// which are three segments). The contract's keys do not name a component's type, so a key
/// expression cannot select by type; selecting PEIS by type meant one subscription per PEIS of
/// interest, each with its own round trips through a router, which made acquiring on demand
/// slower than reading everything. What the data streams carry, the outputs and the world, is what
/// on demand leaves out.
///
/// A scope ([`Interest::Scoped`]) is narrower: one wildcard subscription per room (`*:rooms.ROOM.*`,
/// who covers it), and the two contract subscriptions of each PEIS it names and of each that
/// answers, or later says it covers one of the rooms (a robot whose camera enters it).
struct Follow<S: TupleSpace> {
    space: S,
    /// What is followed so far.
    followed: Followed,
    /// Under a scope: the rooms whose covering PEIS are followed.
    rooms: BTreeSet<String>,
    /// Under a scope: the PEIS whose contract is followed.
    peis: BTreeSet<PeisId>,
    /// Under a scope: PEIS that said they cover a room and are not followed yet.
    found: BTreeSet<PeisId>,
    subs: SelectAll<ecology_tuples::Subscription>,
}

/// What [`Follow`] subscribes to: each step covers the one before.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Followed {
    Nothing,
    /// The contract of the PEIS of a scope ([`Interest::Scoped`]).
    Scope,
    /// The component contract of every PEIS ([`contract`]): what any type of interest needs.
    Contract,
    Everything,
}

impl<S: TupleSpace> Follow<S> {
    fn new(space: S) -> Self {
        Follow {
            space,
            followed: Followed::Nothing,
            rooms: BTreeSet::new(),
            peis: BTreeSet::new(),
            found: BTreeSet::new(),
            subs: SelectAll::new(),
        }
    }

    /// Follows what `more` adds to what is followed, handing the executive
    /// what is there now; returns the executive's commands.
    async fn widen(
        &mut self,
        exec: &mut Executive,
        now: Duration,
        more: &Interest,
    ) -> Result<Vec<Command>, TupleError> {
        let wanted = match more {
            Interest::Everything => Followed::Everything,
            Interest::Types(types) if types.is_empty() => Followed::Nothing,
            Interest::Types(_) => Followed::Contract,
            Interest::Scoped(_) => Followed::Scope,
        };
        if wanted < self.followed || wanted == Followed::Nothing {
            return Ok(Vec::new());
        }
        let patterns = match (wanted, more) {
            (Followed::Scope, Interest::Scoped(scope)) => {
                let mut patterns = Vec::new();
                for room in &scope.rooms {
                    if self.rooms.contains(room) {
                        continue;
                    }
                    match ecology_tuples::contract::room_pattern(room) {
                        Ok(pattern) => {
                            self.rooms.insert(room.clone());
                            patterns.push(pattern);
                        }
                        // A room no key can name is covered by nobody that says so.
                        Err(_) => continue,
                    }
                }
                for peis in &scope.peis {
                    if let Ok(peis) = PeisId::new(peis) {
                        patterns.extend(self.contract_of(peis));
                    }
                }
                patterns
            }
            _ if wanted == self.followed => return Ok(Vec::new()),
            (Followed::Everything, _) => vec![TuplePattern::everything()],
            _ => contract(ecology_tuples::OwnerPattern::Any),
        };
        if wanted > self.followed {
            // What is followed now covers all that was: the new subscriptions bring it again,
            // and the mirror drops what it has.
            self.subs = SelectAll::new();
        }
        if wanted > Followed::Scope {
            self.found.clear();
        }
        self.followed = wanted;
        let mut out = self.subscribe(exec, now, patterns).await?;
        // Those that answered who covers a room are followed in turn (and the intake told).
        out.extend(self.follow_found(exec, now).await?);
        Ok(out)
    }

    /// The contract patterns of `peis`, when it is not followed yet (and now is).
    fn contract_of(&mut self, peis: PeisId) -> Vec<TuplePattern> {
        if !self.peis.insert(peis.clone()) {
            return Vec::new();
        }
        contract(ecology_tuples::OwnerPattern::Exact(peis))
    }

    /// Follows the contract of the PEIS found covering a room since the last call; returns the
    /// executive's commands.
    async fn follow_found(
        &mut self,
        exec: &mut Executive,
        now: Duration,
    ) -> Result<Vec<Command>, TupleError> {
        let mut out = Vec::new();
        while !self.found.is_empty() {
            let found = std::mem::take(&mut self.found);
            let patterns: Vec<TuplePattern> = found
                .into_iter()
                .flat_map(|peis| self.contract_of(peis))
                .collect();
            out.extend(self.subscribe(exec, now, patterns).await?);
        }
        self.note(exec);
        Ok(out)
    }

    /// Tells the executive what is followed, for its intake.
    fn note(&self, exec: &mut Executive) {
        let count = |n: usize| u32::try_from(n).unwrap_or(u32::MAX);
        let scope = (self.followed == Followed::Scope)
            .then(|| (count(self.peis.len()), count(self.rooms.len())));
        exec.note_followed(self.followed == Followed::Everything, scope);
    }

    /// Subscribes to `patterns`, handing the executive what is there now; returns its commands.
    async fn subscribe(
        &mut self,
        exec: &mut Executive,
        now: Duration,
        patterns: Vec<TuplePattern>,
    ) -> Result<Vec<Command>, TupleError> {
        // Subscribed together, so that the queries behind them go out at once, and each taken in
        // as soon as it and those before it are in, while the answers to the others are on their
        // way: at 1,000 PEIS over Zenoh, the directory's answer came several milliseconds before
        // the fields', and taking it in took as long.
        let space = self.space.clone();
        let mut subscribed: FuturesOrdered<_> =
            patterns.into_iter().map(|p| space.subscribe(p)).collect();
        let mut out = Vec::new();
        while let Some(sub) = subscribed.next().await {
            let mut sub = sub?;
            while let Some(event) = sub.try_next() {
                self.notice(&event);
                if let TupleEvent::Changed(t) = event {
                    out.extend(exec.handle(now, tuple_event(&t)));
                }
            }
            self.subs.push(sub);
        }
        Ok(out)
    }

    /// Notes a PEIS that says it covers a room of the scope, when it is not followed yet.
    fn notice(&mut self, event: &TupleEvent) {
        if self.followed != Followed::Scope {
            return;
        }
        if let TupleEvent::Changed(t) = event
            && ecology_tuples::contract::parse_room_key(t.key.as_str())
                .is_some_and(|(room, _)| self.rooms.contains(room))
            && !self.peis.contains(&t.owner)
        {
            self.found.insert(t.owner.clone());
        }
    }

    /// Whether PEIS were found covering a room that are not followed yet.
    fn has_found(&self) -> bool {
        !self.found.is_empty()
    }

    /// The next tuple event of any subscription (only those woken are looked at).
    async fn next(&mut self) -> Option<TupleEvent> {
        if self.subs.is_empty() {
            return std::future::pending().await;
        }
        let event = self.subs.next().await;
        if let Some(event) = &event {
            self.notice(event);
        }
        event
    }

    /// A tuple event that is already here, if any, without waiting.
    fn ready(&mut self) -> Option<TupleEvent> {
        let event = self.subs.next().now_or_never().flatten();
        if let Some(event) = &event {
            self.notice(event);
        }
        event
    }
}

/// The component contract of the PEIS `owner` matches, without the outputs: the directory
/// (the init component's `components.C.type`, `.cost`, `.currState`, `.reqState`, `.holders`,
/// `.covers`) and each component's `C.status`, `.cause`, `.params`, `.observed` and input
/// pointers `C.mi-INFO`.
fn contract(owner: ecology_tuples::OwnerPattern) -> Vec<TuplePattern> {
    ["components.**", "*.*"]
        .into_iter()
        .map(|key| TuplePattern {
            owner: owner.clone(),
            key: ecology_tuples::KeyPattern::new(key).expect("a valid pattern"),
        })
        .collect()
}

/// The executive's event for tuple `t` (a value that is not text reads as empty).
fn tuple_event(t: &Tuple) -> Event {
    Event::Tuple {
        owner: t.owner.clone(),
        key: t.key.clone(),
        value: t.text().unwrap_or_default().to_string(),
        epoch: t.epoch,
        seq: t.seq,
    }
}

/// The owner a remote set went to, and what became of it: answered or failed.
type SetOutcome = (PeisId, Event);

/// The remote sets in flight: one at a time to each PEIS, in the order asked,
/// and concurrently to different PEIS, so one unreachable PEIS delays no other.
struct RemoteSets<S: TupleSpace> {
    space: S,
    queued: BTreeMap<PeisId, VecDeque<(Key, String)>>,
    busy: BTreeSet<PeisId>,
    tasks: JoinSet<SetOutcome>,
}

impl<S: TupleSpace> RemoteSets<S> {
    /// The PEIS a remote set is under way to, and how many wait behind it, one line.
    fn describe(&self) -> String {
        let busy: Vec<String> = self
            .busy
            .iter()
            .map(|p| {
                let queued = self.queued.get(p).map_or(0, VecDeque::len);
                format!("{p} (+{queued} queued)")
            })
            .collect();
        format!(
            "remote sets under way: {} ({} tasks)\n",
            if busy.is_empty() {
                "none".to_string()
            } else {
                busy.join(", ")
            },
            self.tasks.len()
        )
    }

    fn new(space: S) -> Self {
        RemoteSets {
            space,
            queued: BTreeMap::new(),
            busy: BTreeSet::new(),
            tasks: JoinSet::new(),
        }
    }

    fn send(&mut self, owner: PeisId, key: Key, value: String) {
        self.queued
            .entry(owner.clone())
            .or_default()
            .push_back((key, value));
        self.start_next(&owner);
    }

    fn start_next(&mut self, owner: &PeisId) {
        if self.busy.contains(owner) {
            return;
        }
        let Some((key, value)) = self.queued.get_mut(owner).and_then(VecDeque::pop_front) else {
            self.queued.remove(owner);
            return;
        };
        self.busy.insert(owner.clone());
        let space = self.space.clone();
        let owner = owner.clone();
        self.tasks.spawn(async move {
            let result = if owner == *space.peis() {
                space.set(key.clone(), Value::text(&value)).await
            } else {
                space
                    .set_remote(owner.clone(), key.clone(), Value::text(&value))
                    .await
            };
            let outcome = match result {
                Ok(_) => Event::RemoteSetAnswered {
                    owner: owner.clone(),
                    key,
                },
                Err(e) => Event::RemoteSetFailed {
                    owner: owner.clone(),
                    key,
                    reason: e.to_string(),
                    unanswered: matches!(
                        e,
                        TupleError::OwnerUnreachable { .. } | TupleError::Transport { .. }
                    ),
                },
            };
            (owner, outcome)
        });
    }

    /// What became of the next remote set to end, answered or failed, as an event; `None` when
    /// none is in flight.
    async fn next_outcome(&mut self) -> Option<Event> {
        while let Some(joined) = self.tasks.join_next().await {
            let Ok((owner, outcome)) = joined else {
                // A set task cannot panic short of a bug in the space; nothing to report then.
                continue;
            };
            self.busy.remove(&owner);
            self.start_next(&owner);
            return Some(outcome);
        }
        None
    }

    /// Waits until every queued set has been carried out, handing their outcomes to the
    /// executive (which may only log failures now).
    async fn flush(&mut self, exec: &mut Executive, clock: &Arc<dyn Clock>, start: Timestamp) {
        while let Some(outcome) = self.next_outcome().await {
            let now = clock.now().saturating_duration_since(start);
            let _ = exec.handle(now, outcome);
        }
    }
}
