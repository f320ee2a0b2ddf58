//! The in-process tuple space: every PEIS of an ecology in one process, on an injected clock.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, Weak};

use rustc_hash::FxHashMap;
use tokio::sync::{Notify, mpsc, watch};
use tokio::task::JoinHandle;

use crate::clock::Clock;
use crate::error::TupleError;
use crate::model::{PresenceEvent, Timestamp, Tuple, TupleEvent, Value};
use crate::name::{Key, PeisId};
use crate::owned::OwnedTuples;
use crate::pattern::{OwnerPattern, TuplePattern};
use crate::space::{PeisOptions, TupleSpace};
use crate::subscription::{self, EventSender, PresenceSubscription, Subscription};

/// An ecology in one process. PEIS join it with [`InProcessSpace::join`] and get an [`InProcessPeis`] handle.
///
/// It owns one background task that removes expired tuples and reports vanished PEIS as left
/// when their lease runs out, both on the injected [`Clock`]. The task stops when the space is
/// dropped or [`InProcessSpace::shutdown`] is awaited. Creating a space needs a tokio runtime.
#[derive(Debug)]
pub struct InProcessSpace {
    shared: Arc<Shared>,
    shutdown: watch::Sender<bool>,
    timer: Option<JoinHandle<()>>,
}

#[derive(Debug)]
struct Shared {
    clock: Arc<dyn Clock>,
    state: Mutex<State>,
    // Wakes the timer task when an earlier deadline may have appeared.
    wake: Notify,
    generations: AtomicU64,
    // The epoch of the latest join: epochs are the join time in ns, made strictly increasing.
    last_epoch: AtomicU64,
}

#[derive(Debug, Default)]
struct State {
    peers: BTreeMap<PeisId, Peer>,
    subscribers: Subscribers,
    presence: Vec<(u64, mpsc::UnboundedSender<PresenceEvent>)>,
    /// Subscriptions to one PEIS's presence, by that PEIS: a PEIS host watches only those who
    /// asked it for something, so with N PEIS a join reaches a few subscribers, not N.
    presence_of: FxHashMap<PeisId, Vec<(u64, mpsc::UnboundedSender<PresenceEvent>)>>,
    next_subscriber: u64,
    /// Who reads the tuples components asked about ([`TupleSpace::watch_readers`]), by owner.
    read_watches: FxHashMap<PeisId, FxHashMap<Key, watch::Sender<bool>>>,
}

#[derive(Debug)]
struct Peer {
    tuples: OwnedTuples,
    options: PeisOptions,
    generation: u64,
    // Set when the PEIS vanished: it is reported as left at this time.
    lease_end: Option<Timestamp>,
}

#[derive(Debug)]
struct Subscriber {
    id: u64,
    /// What it follows: one pattern, or several for [`InProcessPeis::subscribe_any`].
    patterns: Vec<TuplePattern>,
    events: EventSender,
}

impl Subscriber {
    fn matches(&self, owner: &PeisId, key: &Key) -> bool {
        self.patterns.iter().any(|p| p.matches(owner, key))
    }
}

/// The tuple subscriptions, those of one owner apart from those of any owner, and among those of
/// one owner those of one key apart, so that a change is matched only against the subscriptions
/// that can want it (a PEIS host subscribes to its own requests: with a thousand PEIS, nearly all
/// subscriptions name one owner; and a robot's host follows its own pose among the world's
/// tuples). Each list is in the order of subscribing, and a change reaches its subscribers in that
/// order across all of them.
#[derive(Debug, Default)]
struct Subscribers {
    by_owner: FxHashMap<PeisId, OwnerSubscribers>,
    any_owner: Vec<Subscriber>,
    /// Where each subscription is kept.
    placed: FxHashMap<u64, Place>,
}

/// The subscriptions that name one owner.
#[derive(Debug, Default)]
struct OwnerSubscribers {
    /// Those that name one key of it.
    by_key: FxHashMap<Key, Vec<Subscriber>>,
    /// The others.
    patterns: Vec<Subscriber>,
}

/// Where a subscription is kept in [`Subscribers`].
#[derive(Debug)]
enum Place {
    AnyOwner,
    Owner(PeisId),
    Key(PeisId, Key),
}

impl Subscribers {
    fn push(&mut self, subscriber: Subscriber) {
        let id = subscriber.id;
        let place = match subscriber.patterns.as_slice() {
            [one] => match (&one.owner, one.key.as_exact()) {
                (OwnerPattern::Exact(id), Some(key)) => Place::Key(id.clone(), key),
                (OwnerPattern::Exact(id), None) => Place::Owner(id.clone()),
                (OwnerPattern::Any, _) => Place::AnyOwner,
            },
            _ => Place::AnyOwner,
        };
        match &place {
            Place::Key(owner, key) => self
                .by_owner
                .entry(owner.clone())
                .or_default()
                .by_key
                .entry(key.clone())
                .or_default()
                .push(subscriber),
            Place::Owner(owner) => self
                .by_owner
                .entry(owner.clone())
                .or_default()
                .patterns
                .push(subscriber),
            Place::AnyOwner => self.any_owner.push(subscriber),
        }
        self.placed.insert(id, place);
    }

    fn remove(&mut self, id: u64) {
        match self.placed.remove(&id) {
            Some(Place::Key(owner, key)) => {
                if let Some(of) = self.by_owner.get_mut(&owner) {
                    if let Some(list) = of.by_key.get_mut(&key) {
                        list.retain(|s| s.id != id);
                        if list.is_empty() {
                            of.by_key.remove(&key);
                        }
                    }
                    if of.by_key.is_empty() && of.patterns.is_empty() {
                        self.by_owner.remove(&owner);
                    }
                }
            }
            Some(Place::Owner(owner)) => {
                if let Some(of) = self.by_owner.get_mut(&owner) {
                    of.patterns.retain(|s| s.id != id);
                    if of.by_key.is_empty() && of.patterns.is_empty() {
                        self.by_owner.remove(&owner);
                    }
                }
            }
            Some(Place::AnyOwner) => self.any_owner.retain(|s| s.id != id),
            None => {}
        }
    }

    /// The subscriptions that can want tuple (`owner`, `key`): of that key, of that owner, of any
    /// owner; each list in the order of subscribing.
    fn candidates(&self, owner: &PeisId, key: &Key) -> [&[Subscriber]; 3] {
        let of = self.by_owner.get(owner);
        let by_key = of
            .and_then(|of| of.by_key.get(key))
            .map_or(&[][..], Vec::as_slice);
        let patterns = of.map_or(&[][..], |of| of.patterns.as_slice());
        [by_key, patterns, self.any_owner.as_slice()]
    }

    /// Whether a live subscription matches tuple (`owner`, `key`).
    fn any_matching(&self, owner: &PeisId, key: &Key) -> bool {
        self.candidates(owner, key)
            .iter()
            .flat_map(|list| list.iter())
            .any(|s| !s.events.is_closed() && s.matches(owner, key))
    }

    /// Sends `event` to every subscription it matches, in the order they were made; drops those
    /// whose receiver is gone.
    fn broadcast(&mut self, event: &TupleEvent) {
        let (owner, key) = event.subject();
        let lists = self.candidates(owner, key);
        let mut next = [0usize; 3];
        let mut closed = Vec::new();
        // The three lists merged by the order of subscribing.
        while let Some(l) = (0..3)
            .filter(|&l| next[l] < lists[l].len())
            .min_by_key(|&l| lists[l][next[l]].id)
        {
            let s = &lists[l][next[l]];
            next[l] += 1;
            if s.matches(owner, key) && !s.events.send(event.clone()) {
                closed.push(s.id);
            }
        }
        for id in closed {
            self.remove(id);
        }
    }
}

impl InProcessSpace {
    /// An empty ecology on `clock`. Must be called inside a tokio runtime.
    pub fn new(clock: Arc<dyn Clock>) -> Self {
        let shared = Arc::new(Shared {
            clock,
            state: Mutex::new(State::default()),
            wake: Notify::new(),
            generations: AtomicU64::new(0),
            last_epoch: AtomicU64::new(0),
        });
        let (shutdown, shutdown_rx) = watch::channel(false);
        let timer = tokio::spawn(run_timer(shared.clone(), shutdown_rx));
        Self {
            shared,
            shutdown,
            timer: Some(timer),
        }
    }

    /// Joins PEIS `peis` to the ecology; every subscriber to presence sees it join.
    pub fn join(&self, peis: PeisId, options: PeisOptions) -> Result<InProcessPeis, TupleError> {
        let generation = self.shared.generations.fetch_add(1, Ordering::Relaxed);
        let mut state = self.shared.lock();
        if state.peers.contains_key(&peis) {
            return Err(TupleError::AlreadyPresent(peis));
        }
        // Under the state lock, so two joins cannot take the same epoch.
        let now = self.shared.clock.now().as_nanos();
        let epoch = now.max(self.shared.last_epoch.load(Ordering::Relaxed) + 1);
        self.shared.last_epoch.store(epoch, Ordering::Relaxed);
        state.peers.insert(
            peis.clone(),
            Peer {
                tuples: OwnedTuples::new(peis.clone(), epoch),
                options,
                generation,
                lease_end: None,
            },
        );
        state.broadcast_presence(&PresenceEvent::Joined(peis.clone()));
        drop(state);
        Ok(InProcessPeis {
            shared: self.shared.clone(),
            me: peis.clone(),
            membership: Arc::new(Membership {
                shared: Arc::downgrade(&self.shared),
                peis,
                generation,
            }),
        })
    }

    /// The clock the space runs on.
    pub fn clock(&self) -> &Arc<dyn Clock> {
        &self.shared.clock
    }

    /// Delivers `tuple` once more to every subscriber it matches, as a
    /// network may duplicate a sample or deliver it late; the store does not
    /// change. For fault injection: receivers must tell it from news by its
    /// `(epoch, seq)`.
    pub fn redeliver(&self, tuple: Tuple) {
        self.shared.lock().broadcast(&TupleEvent::Changed(tuple));
    }

    /// The current tuple (owner, key) as its owner holds it, without going
    /// through a subscription: the ground truth, for checking what a
    /// receiver made of the tuples it got.
    pub fn peek(&self, owner: &PeisId, key: &Key) -> Option<Tuple> {
        let state = self.shared.lock();
        let now = self.shared.clock.now();
        state.peers.get(owner)?.tuples.get(key, now).cloned()
    }

    /// Whether `peis` is present now (joined, and neither left nor vanished).
    pub fn is_present(&self, peis: &PeisId) -> bool {
        self.shared
            .lock()
            .peers
            .get(peis)
            .is_some_and(|p| p.lease_end.is_none())
    }

    /// Stops the background task and waits for it.
    pub async fn shutdown(mut self) {
        let _ = self.shutdown.send(true);
        if let Some(timer) = self.timer.take() {
            // The task only ends by the signal, or by panicking; either way there is nothing to do.
            let _ = timer.await;
        }
    }
}

impl Drop for InProcessSpace {
    fn drop(&mut self) {
        let _ = self.shutdown.send(true);
        if let Some(timer) = self.timer.take() {
            timer.abort();
        }
    }
}

async fn run_timer(shared: Arc<Shared>, mut shutdown: watch::Receiver<bool>) {
    loop {
        let notified = shared.wake.notified();
        tokio::pin!(notified);
        // Register for wake-ups before reading the deadline, so none is missed in between.
        notified.as_mut().enable();
        let sleep = match shared.lock().next_deadline() {
            Some(deadline) => shared.clock.sleep_until(deadline),
            None => Box::pin(std::future::pending()),
        };
        tokio::select! {
            biased;
            _ = shutdown.changed() => return,
            _ = sleep => {}
            _ = notified => {}
        }
        let now = shared.clock.now();
        shared.lock().process_due(now);
    }
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        // A panic while holding the lock leaves consistent data (every update is one step), so poison is ignored.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }
}

impl State {
    fn next_deadline(&self) -> Option<Timestamp> {
        self.peers
            .values()
            .flat_map(|p| p.tuples.next_expiry().into_iter().chain(p.lease_end))
            .min()
    }

    fn process_due(&mut self, now: Timestamp) {
        let mut events = Vec::new();
        let mut vanished = Vec::new();
        for (id, peer) in &mut self.peers {
            events.extend(peer.tuples.expire_due(now));
            if peer.lease_end.is_some_and(|end| end <= now) {
                vanished.push(id.clone());
            }
        }
        for event in &events {
            self.broadcast(event);
        }
        for id in vanished {
            self.peers.remove(&id);
            self.broadcast_presence(&PresenceEvent::Left(id));
        }
    }

    fn broadcast(&mut self, event: &TupleEvent) {
        self.subscribers.broadcast(event);
    }

    /// Brings every watch of who reads a tuple up to date after subscriptions came or went.
    fn update_read_watches(&mut self) {
        let subscribers = &self.subscribers;
        self.read_watches.retain(|owner, keys| {
            keys.retain(|key, watch| {
                let read = subscribers.any_matching(owner, key);
                watch.send_if_modified(|now| std::mem::replace(now, read) != read);
                !watch.is_closed()
            });
            !keys.is_empty()
        });
    }

    fn broadcast_presence(&mut self, event: &PresenceEvent) {
        self.presence
            .retain(|(_, tx)| tx.send(event.clone()).is_ok());
        let (PresenceEvent::Joined(peis) | PresenceEvent::Left(peis)) = event;
        self.retain_presence_of(peis, |(_, tx)| tx.send(event.clone()).is_ok());
    }

    /// Keeps the subscriptions to `peis`'s presence that `keep` says to, and forgets that PEIS
    /// once none is left.
    fn retain_presence_of(
        &mut self,
        peis: &PeisId,
        keep: impl FnMut(&(u64, mpsc::UnboundedSender<PresenceEvent>)) -> bool,
    ) {
        if let Some(list) = self.presence_of.get_mut(peis) {
            list.retain(keep);
            if list.is_empty() {
                self.presence_of.remove(peis);
            }
        }
    }

    /// The peer entry of a live handle: present, same incarnation, not vanished.
    fn live_peer(&mut self, me: &PeisId, generation: u64) -> Result<&mut Peer, TupleError> {
        match self.peers.get_mut(me) {
            Some(peer) if peer.generation == generation && peer.lease_end.is_none() => Ok(peer),
            _ => Err(TupleError::Departed(me.clone())),
        }
    }

    fn set_owned(
        &mut self,
        owner: &PeisId,
        generation: Option<u64>,
        key: Key,
        value: Value,
        now: Timestamp,
    ) -> Result<(Tuple, bool), TupleError> {
        let peer = match generation {
            Some(generation) => self.live_peer(owner, generation)?,
            None => self
                .peers
                .get_mut(owner)
                .ok_or_else(|| TupleError::Departed(owner.clone()))?,
        };
        peer.options.limits.check(&key, &value)?;
        let expires = value.time_to_live.is_some();
        let tuple = peer.tuples.set(key, value, now);
        self.broadcast(&TupleEvent::Changed(tuple.clone()));
        Ok((tuple, expires))
    }
}

/// Leaves the ecology when the last clone of a handle is dropped.
#[derive(Debug)]
struct Membership {
    shared: Weak<Shared>,
    peis: PeisId,
    generation: u64,
}

impl Drop for Membership {
    fn drop(&mut self) {
        if let Some(shared) = self.shared.upgrade() {
            let mut state = shared.lock();
            let current = state
                .peers
                .get(&self.peis)
                .is_some_and(|p| p.generation == self.generation && p.lease_end.is_none());
            if current {
                state.peers.remove(&self.peis);
                state.broadcast_presence(&PresenceEvent::Left(self.peis.clone()));
            }
        }
    }
}

/// Removes a subscriber when its subscription is dropped.
#[derive(Debug)]
struct SubscriberGuard {
    shared: Weak<Shared>,
    id: u64,
    kind: Watched,
}

/// What a subscription watches.
#[derive(Debug)]
enum Watched {
    Tuples,
    Presence,
    PresenceOf(PeisId),
}

impl Drop for SubscriberGuard {
    fn drop(&mut self) {
        if let Some(shared) = self.shared.upgrade() {
            let mut state = shared.lock();
            match &self.kind {
                Watched::Tuples => {
                    state.subscribers.remove(self.id);
                    if !state.read_watches.is_empty() {
                        state.update_read_watches();
                    }
                }
                Watched::Presence => state.presence.retain(|(id, _)| *id != self.id),
                Watched::PresenceOf(peis) => {
                    state.retain_presence_of(peis, |(id, _)| *id != self.id);
                }
            }
        }
    }
}

/// One PEIS's handle on an [`InProcessSpace`]. Clones act as the same PEIS; when the last clone
/// is dropped (or [`InProcessPeis::leave`] is called) the PEIS leaves the ecology.
#[derive(Clone, Debug)]
pub struct InProcessPeis {
    shared: Arc<Shared>,
    me: PeisId,
    membership: Arc<Membership>,
}

impl InProcessPeis {
    /// Leaves the ecology now: presence subscribers see `Left`, and the PEIS's tuples are gone.
    /// Other clones of this handle stop working.
    pub fn leave(self) {
        let mut state = self.shared.lock();
        if state
            .live_peer(&self.me, self.membership.generation)
            .is_ok()
        {
            state.peers.remove(&self.me);
            state.broadcast_presence(&PresenceEvent::Left(self.me.clone()));
        }
    }

    /// Simulates a crash: the PEIS stops without saying goodbye, as if its process were killed.
    /// The others see it `Left` once its lease has run out on the clock.
    pub fn vanish(self) {
        let now = self.shared.clock.now();
        let mut state = self.shared.lock();
        if let Ok(peer) = state.live_peer(&self.me, self.membership.generation) {
            peer.lease_end = Some(now.saturating_add(peer.options.lease));
        }
        drop(state);
        self.shared.wake.notify_one();
    }

    fn generation(&self) -> u64 {
        self.membership.generation
    }

    /// Subscribes to the tuples matching any of `patterns` as one subscription: the current ones
    /// first, then every change in the order the space makes them, whichever pattern it matches
    /// (separate subscriptions would each keep their own order).
    pub fn subscribe_any(&self, patterns: Vec<TuplePattern>) -> Result<Subscription, TupleError> {
        let now = self.shared.clock.now();
        let mut state = self.shared.lock();
        self.check_live(&mut state)?;
        let (tx, rx) = subscription::events();
        // Under the lock, the snapshot and the registration are one step: nothing falls in between.
        // By owner, then key; a tuple that several patterns match, once.
        let mut current: BTreeMap<(&PeisId, &Key), &Tuple> = BTreeMap::new();
        for pattern in &patterns {
            let owners: Box<dyn Iterator<Item = &Peer>> = match &pattern.owner {
                OwnerPattern::Exact(id) => Box::new(state.peers.get(id).into_iter()),
                OwnerPattern::Any => Box::new(state.peers.values()),
            };
            for peer in owners {
                for tuple in peer.tuples.matching(&pattern.key, now) {
                    if patterns.len() == 1 {
                        tx.send(TupleEvent::Changed(tuple.clone()));
                    } else {
                        current.insert((&tuple.owner, &tuple.key), tuple);
                    }
                }
            }
        }
        for tuple in current.into_values() {
            tx.send(TupleEvent::Changed(tuple.clone()));
        }
        let id = state.next_subscriber;
        state.next_subscriber += 1;
        state.subscribers.push(Subscriber {
            id,
            patterns,
            events: tx,
        });
        if !state.read_watches.is_empty() {
            state.update_read_watches();
        }
        let guard = SubscriberGuard {
            shared: Arc::downgrade(&self.shared),
            id,
            kind: Watched::Tuples,
        };
        Ok(Subscription::from_channel(rx, guard))
    }

    fn check_live(&self, state: &mut State) -> Result<(), TupleError> {
        state.live_peer(&self.me, self.generation()).map(|_| ())
    }

    fn set_now(&self, key: Key, value: Value) -> Result<Tuple, TupleError> {
        let now = self.shared.clock.now();
        let (tuple, expires) =
            self.shared
                .lock()
                .set_owned(&self.me, Some(self.generation()), key, value, now)?;
        if expires {
            self.shared.wake.notify_one();
        }
        Ok(tuple)
    }
}

impl TupleSpace for InProcessPeis {
    fn peis(&self) -> &PeisId {
        &self.me
    }

    async fn set(&self, key: Key, value: Value) -> Result<Tuple, TupleError> {
        self.set_now(key, value)
    }

    fn is_read(&self, key: &Key) -> bool {
        self.shared.lock().subscribers.any_matching(&self.me, key)
    }

    fn watch_readers(&self, key: &Key) -> watch::Receiver<bool> {
        let mut state = self.shared.lock();
        let read = state.subscribers.any_matching(&self.me, key);
        state
            .read_watches
            .entry(self.me.clone())
            .or_default()
            .entry(key.clone())
            .or_insert_with(|| watch::Sender::new(read))
            .subscribe()
    }

    async fn delete(&self, key: Key) -> Result<bool, TupleError> {
        let mut state = self.shared.lock();
        let peer = state.live_peer(&self.me, self.generation())?;
        match peer.tuples.delete(&key) {
            Some(event) => {
                state.broadcast(&event);
                Ok(true)
            }
            None => Ok(false),
        }
    }

    async fn release_claims(&self, holder: PeisId) -> Result<Vec<Tuple>, TupleError> {
        let now = self.shared.clock.now();
        let mut state = self.shared.lock();
        let peer = state.live_peer(&self.me, self.generation())?;
        let written = peer.tuples.release_holder(&holder, now);
        for tuple in &written {
            state.broadcast(&TupleEvent::Changed(tuple.clone()));
        }
        Ok(written)
    }

    async fn get(&self, owner: PeisId, key: Key) -> Result<Option<Tuple>, TupleError> {
        let now = self.shared.clock.now();
        let mut state = self.shared.lock();
        self.check_live(&mut state)?;
        Ok(state
            .peers
            .get(&owner)
            .and_then(|p| p.tuples.get(&key, now))
            .cloned())
    }

    async fn get_matching(&self, pattern: TuplePattern) -> Result<Vec<Tuple>, TupleError> {
        let now = self.shared.clock.now();
        let mut state = self.shared.lock();
        self.check_live(&mut state)?;
        Ok(state
            .peers
            .values()
            .filter(|p| pattern.owner.matches(p.tuples.owner()))
            .flat_map(|p| p.tuples.matching(&pattern.key, now))
            .cloned()
            .collect())
    }

    async fn subscribe(&self, pattern: TuplePattern) -> Result<Subscription, TupleError> {
        self.subscribe_any(vec![pattern])
    }

    async fn set_remote(&self, owner: PeisId, key: Key, value: Value) -> Result<Tuple, TupleError> {
        let own_limits = {
            let mut state = self.shared.lock();
            state
                .live_peer(&self.me, self.generation())?
                .options
                .limits
                .clone()
        };
        own_limits.check(&key, &value)?;
        if owner == self.me {
            return self.set_now(key, value);
        }
        let now = self.shared.clock.now();
        let mut state = self.shared.lock();
        self.check_live(&mut state)?;
        match state.peers.get(&owner) {
            Some(peer) if peer.lease_end.is_none() => {
                if let Err(e) = peer.options.limits.check(&key, &value) {
                    return Err(TupleError::RemoteSetRefused {
                        owner,
                        key,
                        reason: e.to_string(),
                    });
                }
                if !peer.options.remote_set.permits(&key) {
                    return Err(TupleError::RemoteSetRefused {
                        owner,
                        key,
                        reason: "its remote-set policy does not allow this key".to_owned(),
                    });
                }
                if let Err(reason) = crate::contract::check_request(&key, &value.data) {
                    return Err(TupleError::RemoteSetRefused { owner, key, reason });
                }
            }
            _ => return Err(TupleError::OwnerUnreachable { owner, key }),
        }
        // The owner applies the request with its own sequence numbers and limits, records who
        // asked, and arbitrates claims on its components (`crate::claims`).
        let value = value.with_creator(self.me.clone());
        let expires = value.time_to_live.is_some();
        let requester = self.me.clone();
        let peer = state
            .peers
            .get_mut(&owner)
            .ok_or_else(|| TupleError::Departed(owner.clone()))?;
        let (written, answer) = peer
            .tuples
            .set_requested(Some(&requester), key.clone(), value, now)
            .map_err(|reason| TupleError::RemoteSetRefused {
                owner: owner.clone(),
                key,
                reason,
            })?;
        for tuple in written {
            state.broadcast(&TupleEvent::Changed(tuple));
        }
        drop(state);
        if expires {
            self.shared.wake.notify_one();
        }
        Ok(answer)
    }

    async fn peers(&self) -> Result<Vec<PeisId>, TupleError> {
        let mut state = self.shared.lock();
        self.check_live(&mut state)?;
        Ok(state.peers.keys().cloned().collect())
    }

    async fn subscribe_presence(&self) -> Result<PresenceSubscription, TupleError> {
        let mut state = self.shared.lock();
        self.check_live(&mut state)?;
        let (tx, rx) = mpsc::unbounded_channel();
        for id in state.peers.keys() {
            let _ = tx.send(PresenceEvent::Joined(id.clone()));
        }
        let id = state.next_subscriber;
        state.next_subscriber += 1;
        state.presence.push((id, tx));
        let guard = SubscriberGuard {
            shared: Arc::downgrade(&self.shared),
            id,
            kind: Watched::Presence,
        };
        Ok(PresenceSubscription::from_channel(rx, guard))
    }

    async fn subscribe_presence_of(
        &self,
        peis: PeisId,
    ) -> Result<PresenceSubscription, TupleError> {
        let mut state = self.shared.lock();
        self.check_live(&mut state)?;
        let (tx, rx) = mpsc::unbounded_channel();
        if state.peers.contains_key(&peis) {
            let _ = tx.send(PresenceEvent::Joined(peis.clone()));
        }
        let id = state.next_subscriber;
        state.next_subscriber += 1;
        state
            .presence_of
            .entry(peis.clone())
            .or_default()
            .push((id, tx));
        let guard = SubscriberGuard {
            shared: Arc::downgrade(&self.shared),
            id,
            kind: Watched::PresenceOf(peis),
        };
        Ok(PresenceSubscription::from_channel(rx, guard))
    }
}
