//! The host of one PEIS and its init component (the paper's PEIS-init).
//!
//! The init component publishes `components.C.type`, `.cost` and `.currState`
//! for every component, and applies `components.C.reqState` requests (which
//! other PEIS make by remote set): `on` starts the component after its
//! start-up delay, `off` stops it. When a component is on and has `C.params`,
//! the host runs its body with those params; new params restart it, and
//! empty params stop it (`idle`). A body that returns an error is reported as
//! `error` with the error as `C.cause` (`on` again restarts it); one that panics too, so a failing
//! component never takes the PEIS down. Every body runs in a task the host
//! owns. On shutdown the host stops every body and reports every component
//! that was on as switched off, so the ecology sees it go before the PEIS
//! leaves.
//!
//! The host is also a dead man's switch. Several executives may hold a component at once: the
//! space arbitrates their requests and keeps the holders as the tuple `components.C.holders`
//! (see `ecology_tuples::claims`). The host watches the presence of every holder, and of no
//! other PEIS: once one has been gone for [`HostOptions::release_after`] (after its lease, if it
//! vanished), the host drops it from every component it holds
//! ([`TupleSpace::release_claims`]); a component whose last holder that was is put back, `reqState`
//! `off` if a request switched it on and empty `params`, as that PEIS would have on ending its
//! task. What another holder still uses keeps running. A holder that is not seen present within
//! that time after it claimed (it left before the host could watch it) is released too. So a
//! partition, a lost router or a killed executive never leaves a component running for a task
//! nobody runs any more, and never takes one from a task that still runs.

use std::collections::BTreeMap;
use std::future::Future;
use std::sync::Arc;
use std::task::Poll;
use std::time::Duration;

use ecology_tuples::contract::ComponentField;
use ecology_tuples::{
    Clock, ComponentId, Key, KeyPattern, OwnerPattern, PeisId, PresenceEvent, PresenceSubscription,
    Timestamp, TupleError, TupleEvent, TuplePattern, TupleSpace, Value,
};
use tokio::task::{AbortHandle, JoinSet};

use crate::component::{Component, ComponentError, Context};

/// One component of a PEIS.
pub struct ComponentSpec<S: TupleSpace> {
    /// Its name, such as `l1`.
    pub name: String,
    /// Its type, such as `laser` (the `pc` fact's type).
    pub kind: String,
    /// Its cost: running cost when on, start-up cost when off.
    pub cost: u64,
    /// Whether it is on when the PEIS starts.
    pub on: bool,
    /// How long switching it on takes.
    pub startup: Duration,
    /// The places it sees (`components.C.covers`), such as the rooms a ceiling camera is mounted
    /// over; empty when it does not say.
    pub covers: Vec<String>,
    /// Its body.
    pub body: Arc<dyn Component<S>>,
}

impl<S: TupleSpace> std::fmt::Debug for ComponentSpec<S> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ComponentSpec")
            .field("name", &self.name)
            .field("kind", &self.kind)
            .field("cost", &self.cost)
            .field("on", &self.on)
            .field("startup", &self.startup)
            .field("covers", &self.covers)
            .finish_non_exhaustive()
    }
}

/// Why a host stopped.
#[derive(Debug, thiserror::Error)]
pub enum HostError {
    /// The tuple space failed.
    #[error("tuple space: {0}")]
    Space(#[from] TupleError),
    /// A component name makes an invalid key.
    #[error("invalid component name `{0}`")]
    InvalidName(String),
}

/// How a host runs, beyond its components.
#[derive(Clone)]
pub struct HostOptions {
    /// How long the PEIS that switched a component on or gave it params may be gone (after its
    /// presence ended) before the host puts them back by itself: `reqState` `off`, empty `params`.
    /// A PEIS that comes back within it keeps what it asked for.
    pub release_after: Duration,
    /// Told, in a sentence, what the host did by itself (`switched ca1 off: executive is gone`).
    pub note: Arc<dyn Fn(String) + Send + Sync>,
}

impl Default for HostOptions {
    /// One second: presence already ends a lease after a PEIS vanished, and one more second lets
    /// a router that restarts at once, or a link that flaps, pass without undoing a task. Notes
    /// go nowhere.
    fn default() -> Self {
        Self {
            release_after: Duration::from_secs(1),
            note: Arc::new(|_| {}),
        }
    }
}

impl std::fmt::Debug for HostOptions {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HostOptions")
            .field("release_after", &self.release_after)
            .finish_non_exhaustive()
    }
}

/// Each component's state, by name. Boxed: a map's node has room for eleven entries, and a host
/// of one or two components would otherwise carry the rest empty (2 KB a host in a building).
type States<S> = BTreeMap<String, Box<State<S>>>;

struct State<S: TupleSpace> {
    spec: ComponentSpec<S>,
    on: bool,
    starting_until: Option<Timestamp>,
    params: Option<String>,
    generation: u64,
    task: Option<AbortHandle>,
}

type Outcome = (String, u64, Result<(), ComponentError>);

/// The contract's key for `field` of component `c`.
fn field(c: &str, field: ComponentField) -> Result<Key, HostError> {
    ComponentId::new(c)
        .map(|id| field.key(&id))
        .map_err(|_| HostError::InvalidName(c.to_string()))
}

/// Runs one PEIS with `components` on `space` until `shutdown` completes, with the default
/// [`HostOptions`].
pub async fn run_host<S: TupleSpace>(
    space: S,
    clock: Arc<dyn Clock>,
    components: Vec<ComponentSpec<S>>,
    shutdown: impl Future<Output = ()> + Send,
) -> Result<(), HostError> {
    run_host_with(space, clock, components, HostOptions::default(), shutdown).await
}

/// Says on `space` that `component` (of type `kind`) now covers the places `now` where it covered
/// `was`: its `components.C.covers`, and a room key `rooms.ROOM.C` for each place (put for those it
/// gains, deleted for those it loses), by which an executive finds who covers a room without
/// reading every PEIS. A camera on a robot that moves says so each time it enters another room.
pub async fn announce_covers<S: TupleSpace>(
    space: &S,
    component: &ComponentId,
    kind: &str,
    was: &[String],
    now: &[String],
) -> Result<(), TupleError> {
    let room = |place: &String| {
        ecology_tuples::contract::room_key(place, component).map_err(TupleError::Invalid)
    };
    for place in was.iter().filter(|p| !now.contains(p)) {
        space.delete(room(place)?).await?;
    }
    space
        .set(
            ComponentField::Covers.key(component),
            Value::text(now.join(" ")),
        )
        .await?;
    for place in now.iter().filter(|p| !was.contains(p)) {
        space.set(room(place)?, Value::text(kind)).await?;
    }
    Ok(())
}

/// Runs one PEIS with `components` on `space` until `shutdown` completes.
pub async fn run_host_with<S: TupleSpace>(
    space: S,
    clock: Arc<dyn Clock>,
    components: Vec<ComponentSpec<S>>,
    options: HostOptions,
    shutdown: impl Future<Output = ()> + Send,
) -> Result<(), HostError> {
    let me = space.peis().clone();
    let mut states: States<S> = BTreeMap::new();
    for spec in components {
        let c = spec.name.clone();
        // The name checked once for its five keys.
        let id = ComponentId::new(&c).map_err(|_| HostError::InvalidName(c.clone()))?;
        let power = if spec.on { "on" } else { "off" };
        let announced = [
            (ComponentField::Type, spec.kind.clone()),
            (ComponentField::Cost, spec.cost.to_string()),
            (ComponentField::CurrState, power.to_string()),
            (ComponentField::Status, "idle".to_string()),
        ];
        for (field, value) in announced {
            space.set(field.key(&id), Value::text(value)).await?;
        }
        if !spec.covers.is_empty() {
            announce_covers(&space, &id, &spec.kind, &[], &spec.covers).await?;
        }
        states.insert(
            c,
            Box::new(State {
                on: spec.on,
                spec,
                starting_until: None,
                params: None,
                generation: 0,
                task: None,
            }),
        );
    }
    // Of this PEIS's own keys: its name is valid already.
    let own = |key: &str| {
        KeyPattern::new(key)
            .map(|key| TuplePattern {
                owner: OwnerPattern::Exact(me.clone()),
                key,
            })
            .map_err(|e| HostError::Space(TupleError::Invalid(e)))
    };
    let requests_pattern = own("components.*.reqState")?;
    let params_pattern = own("*.params")?;
    let holders_pattern = own("components.*.holders")?;
    let mut requests = space.subscribe(requests_pattern).await?;
    let mut params = space.subscribe(params_pattern).await?;
    let mut claims = space.subscribe(holders_pattern).await?;
    // Who holds each component, as its holders tuple last said.
    let mut holders: BTreeMap<String, Vec<PeisId>> = BTreeMap::new();
    // The presence of each holder, and of no other PEIS: with N PEIS, a host that heard every
    // join and leave would make the ecology's start cost N² events.
    let mut watched: BTreeMap<PeisId, PresenceSubscription> = BTreeMap::new();
    // Each PEIS whose presence ended, or that has not been seen since it asked, and when what it
    // asked for is put back unless it is seen.
    let mut gone: BTreeMap<PeisId, Timestamp> = BTreeMap::new();
    let mut tasks: JoinSet<Outcome> = JoinSet::new();
    tokio::pin!(shutdown);
    // The helpers awaited in the loop are boxed: inline, their state made every host's future
    // (a thousand of them in a building) larger by a third.
    loop {
        let next_start = states
            .values()
            .filter_map(|s| s.starting_until)
            .chain(gone.values().copied())
            .min();
        let wake = async {
            match next_start {
                Some(at) => clock.sleep_until(at).await,
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            // Biased: reproducible in virtual time, and shutdown comes first.
            biased;
            () = &mut shutdown => break,
            event = requests.next() => {
                let Some(TupleEvent::Changed(t)) = event else { continue };
                let Some((c, ComponentField::ReqState)) = ComponentField::parse(&t.key) else { continue };
                let Some(state) = states.get_mut(c.as_str()) else { continue };
                match t.text().unwrap_or("").trim() {
                    "on" if !state.on && state.starting_until.is_none() => {
                        state.starting_until = Some(clock.now().saturating_add(state.spec.startup));
                    }
                    // On already, but its body stopped (it failed, or finished):
                    // switching it on again runs its params afresh.
                    "on" if state.on && state.task.is_none() && state.params.is_some() => {
                        let c = c.to_string();
                        Box::pin(start(&space, &clock, &mut states, &c, &mut tasks)).await?;
                    }
                    "off" => {
                        state.starting_until = None;
                        if let Some(task) = state.task.take() {
                            task.abort();
                        }
                        state.generation += 1;
                        if state.on {
                            state.on = false;
                            let c = c.to_string();
                            space.set(field(&c, ComponentField::CurrState)?, Value::text("off")).await?;
                            space.set(field(&c, ComponentField::Status)?, Value::text("idle")).await?;
                        }
                    }
                    _ => {}
                }
            }
            event = params.next() => {
                let Some(TupleEvent::Changed(t)) = event else { continue };
                let Some((c, ComponentField::Params)) = ComponentField::parse(&t.key) else { continue };
                let Some(state) = states.get_mut(c.as_str()) else { continue };
                let had_params = state.params.is_some();
                state.params = t.text().ok().map(|p| p.trim().to_string()).filter(|p| !p.is_empty());
                // Cleared params leave it idle, whether its body still ran or had finished (`done`).
                let stopping = state.params.is_none() && (state.task.is_some() || had_params);
                if state.on {
                    let c = c.to_string();
                    Box::pin(start(&space, &clock, &mut states, &c, &mut tasks)).await?;
                    if stopping {
                        space.set(field(&c, ComponentField::Status)?, Value::text("idle")).await?;
                    }
                }
            }
            event = claims.next() => {
                let Some(TupleEvent::Changed(t)) = event else { continue };
                let Some((c, ComponentField::Holders)) = ComponentField::parse(&t.key) else { continue };
                let now_held = ecology_tuples::claims::parse_holders(t.text().unwrap_or(""));
                for holder in &now_held {
                    Box::pin(watch(&space, &clock, &options, holder, &mut watched, &mut gone)).await?;
                }
                holders.insert(c.to_string(), now_held);
                // A PEIS that holds nothing here any more is watched no longer.
                watched.retain(|p, _| holders.values().any(|h| h.contains(p)));
                gone.retain(|p, _| watched.contains_key(p));
            }
            Some(joined) = tasks.join_next(), if !tasks.is_empty() => {
                let (c, generation, result) = match joined {
                    Ok(outcome) => outcome,
                    // Aborted tasks are expected; a panicking body is a fault of
                    // that component only, but its name is lost with the panic,
                    // so find the component whose task is gone.
                    Err(e) if e.is_cancelled() => continue,
                    Err(e) => {
                        let Some((c, generation)) = states.iter().find(|(_, s)| s.task.as_ref().is_some_and(|t| t.id() == e.id())).map(|(c, s)| (c.clone(), s.generation)) else { continue };
                        (c, generation, Err(ComponentError::Fault(format!("panicked: {e}"))))
                    }
                };
                let Some(state) = states.get_mut(&c) else { continue };
                if state.generation != generation {
                    continue;
                }
                state.task = None;
                if let Err(e) = result {
                    space.set(field(&c, ComponentField::Cause)?, Value::text(e.to_string())).await?;
                    space.set(field(&c, ComponentField::Status)?, Value::text("error")).await?;
                }
            }
            event = next_presence(&mut watched) => match event {
                PresenceEvent::Joined(p) => {
                    gone.remove(&p);
                }
                PresenceEvent::Left(p) => {
                    gone.entry(p).or_insert(clock.now().saturating_add(options.release_after));
                }
            },
            () = wake => {
                let now = clock.now();
                let due: Vec<PeisId> = gone.iter().filter(|(_, at)| **at <= now).map(|(p, _)| p.clone()).collect();
                for peis in due {
                    gone.remove(&peis);
                    watched.remove(&peis);
                    Box::pin(release(&space, &peis, &options)).await?;
                }
                let ready: Vec<String> = states
                    .iter()
                    .filter(|(_, s)| s.starting_until.is_some_and(|at| at <= now))
                    .map(|(c, _)| c.clone())
                    .collect();
                for c in ready {
                    if let Some(state) = states.get_mut(&c) {
                        state.starting_until = None;
                        state.on = true;
                    }
                    space.set(field(&c, ComponentField::CurrState)?, Value::text("on")).await?;
                    Box::pin(start(&space, &clock, &mut states, &c, &mut tasks)).await?;
                }
            }
        }
    }
    tasks.shutdown().await;
    for (c, state) in &states {
        if state.on {
            space
                .set(field(c, ComponentField::CurrState)?, Value::text("off"))
                .await?;
            space
                .set(field(c, ComponentField::Status)?, Value::text("idle"))
                .await?;
        }
    }
    Ok(())
}

/// Drops `gone` from the holders of every component it holds; the space puts back each one it
/// was the last to hold, and the request handlers then apply that like any other request.
async fn release<S: TupleSpace>(
    space: &S,
    gone: &PeisId,
    options: &HostOptions,
) -> Result<(), HostError> {
    for tuple in space.release_claims(gone.clone()).await? {
        let Some((c, field)) = ComponentField::parse(&tuple.key) else {
            continue;
        };
        let note = match field {
            ComponentField::ReqState => format!("{c} switched off: {gone}, which held it, is gone"),
            ComponentField::Params => format!("{c} stopped: {gone}, which held it, is gone"),
            ComponentField::Holders if !tuple.text().unwrap_or("").trim().is_empty() => {
                format!("{gone} no longer holds {c}: it is gone; others still do")
            }
            _ => continue,
        };
        (options.note)(note);
    }
    Ok(())
}

/// Starts watching the presence of `holder`, unless it is watched already. Until it is seen
/// present it counts as gone, so one that left before it could be watched is released too.
async fn watch<S: TupleSpace>(
    space: &S,
    clock: &Arc<dyn Clock>,
    options: &HostOptions,
    holder: &PeisId,
    watched: &mut BTreeMap<PeisId, PresenceSubscription>,
    gone: &mut BTreeMap<PeisId, Timestamp>,
) -> Result<(), HostError> {
    if watched.contains_key(holder) {
        return Ok(());
    }
    let presence = space.subscribe_presence_of(holder.clone()).await?;
    watched.insert(holder.clone(), presence);
    gone.entry(holder.clone())
        .or_insert(clock.now().saturating_add(options.release_after));
    Ok(())
}

/// The next presence event of a watched PEIS; pending while there is none.
fn next_presence(
    watched: &mut BTreeMap<PeisId, PresenceSubscription>,
) -> impl Future<Output = PresenceEvent> + '_ {
    std::future::poll_fn(move |cx| {
        for presence in watched.values_mut() {
            if let Poll::Ready(Some(event)) = presence.poll_event(cx) {
                return Poll::Ready(event);
            }
        }
        Poll::Pending
    })
}

/// (Re)starts component `c`'s body if it is on and has params.
async fn start<S: TupleSpace>(
    space: &S,
    clock: &Arc<dyn Clock>,
    states: &mut States<S>,
    c: &str,
    tasks: &mut JoinSet<Outcome>,
) -> Result<(), HostError> {
    let Some(state) = states.get_mut(c) else {
        return Ok(());
    };
    if let Some(task) = state.task.take() {
        task.abort();
    }
    state.generation += 1;
    let Some(params) = state.params.clone() else {
        return Ok(());
    };
    space
        .set(
            field(c, ComponentField::Status)?,
            Value::text("initializing"),
        )
        .await?;
    let ctx = Context::new(space.clone(), c.to_string(), params, clock.clone());
    let body = state.spec.body.clone();
    let generation = state.generation;
    let name = c.to_string();
    let handle = tasks.spawn(async move { (name, generation, body.run(ctx).await) });
    state.task = Some(handle);
    Ok(())
}
