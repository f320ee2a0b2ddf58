//! The component contract of every PEIS, held by a router so that an executive's question about
//! all of them is one round trip to the router, not a query every PEIS answers.
//!
//! A router keeps the latest value of every tuple under the contract's two key expressions
//! ([`HELD`]: each PEIS's directory, `components/C/…`, each component's own fields, `C/FIELD`, and
//! the rooms its components cover, `rooms/ROOM/C`),
//! and answers queries on them as a *complete* queryable: Zenoh then sends a query these key
//! expressions cover to the router alone, instead of to every PEIS. It never holds outputs
//! (`C/out/INFO`), nor anything outside the contract.
//!
//! What it holds stays true to the owners:
//! - it takes every put and delete of those keys (the owner's `(epoch, seq)` orders them);
//! - a PEIS's tuples are forgotten when its liveliness token goes;
//! - when a PEIS's token appears (it joined, or it was there before this router, or beyond another
//!   router), the router asks that PEIS for its tuples, unless it sees it start (its `contract`
//!   tuple, which a PEIS publishes first, right after its token); until it has the answer, a query
//!   that covers that PEIS is passed on to it, so that an answer is never short of a PEIS present;
//! - an expired tuple is not given out.

use std::collections::{HashMap, HashSet};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use tokio::sync::mpsc;
use zenoh::Session;
use zenoh::bytes::{Encoding, ZBytes};
use zenoh::key_expr::KeyExpr;
use zenoh::query::{ConsolidationMode, Query, QueryTarget};
use zenoh::sample::{Locality, Sample, SampleKind};

use ecology_tuples::{Clock, PeisId, SystemClock};

use crate::wire::{self, Metadata};

/// The key expressions a router holds: each PEIS's directory, its components' own fields, and
/// the rooms its components cover (`rooms/ROOM/C`, asked for by room).
pub const HELD: [&str; 3] = ["peis/*/components/**", "peis/*/*/*", "peis/*/rooms/*/*"];

/// [`HELD`] as key expressions, made once: every sample a router takes in is sorted by them.
pub(crate) fn held() -> &'static [KeyExpr<'static>] {
    static HELD_EXPRS: std::sync::LazyLock<Vec<KeyExpr<'static>>> =
        std::sync::LazyLock::new(|| {
            HELD.iter()
                .filter_map(|held| KeyExpr::try_from(*held).ok())
                .collect()
        });
    &HELD_EXPRS
}

/// Which of [`HELD`] `is` says yes of, a bit each (bit `i` for `HELD[i]`).
fn mask(is: impl Fn(&KeyExpr<'static>) -> bool) -> u8 {
    held()
        .iter()
        .enumerate()
        .filter(|(_, held)| is(held))
        .fold(0, |mask, (i, _)| mask | 1 << i)
}

/// Where the routers that hold the contract say so, a liveliness token each
/// (`@ecology/holds-contract/ZID`): a PEIS asks for them to know whether to ask a router alone.
pub const HOLDS_CONTRACT: &str = "@ecology/holds-contract";

/// The holders' tokens, and those that say a holder answers under [`HELD_ROUTE`]
/// (`@ecology/holds-contract/ZID/routed`).
pub const HOLDERS: &str = "@ecology/holds-contract/**";

/// The last chunk of a holder's second token: it answers under [`HELD_ROUTE`].
pub const ROUTED: &str = "routed";

/// Where a question of every PEIS that the holders answer can be asked instead: `peis/*/rooms/
/// kitchen/*` as `@ecology/held/peis/*/rooms/kitchen/*`. Zenoh finds who answers a key expression
/// with a wildcard in place of the PEIS by weighing every PEIS's declarations (2–3 ms per question
/// at a thousand PEIS); under this prefix there is only the holders' queryable to weigh.
pub const HELD_ROUTE: &str = "@ecology/held";

/// The question asked under [`HELD_ROUTE`], when the key expression is one.
fn held_asked(key_expr: &str) -> Option<KeyExpr<'static>> {
    let asked = key_expr.strip_prefix(HELD_ROUTE)?.strip_prefix('/')?;
    KeyExpr::try_from(asked.to_string()).ok()
}

/// Which routers hold the contract, from the tokens [`HOLDERS`] gave: none; some, each answering
/// under [`HELD_ROUTE`]; or some, of which one at least does not (a router built before it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Holders {
    /// No router holds the contract: every PEIS answers for itself.
    None,
    /// Every holder answers under [`HELD_ROUTE`].
    Routed,
    /// A holder answers only where it holds (the key expressions of [`HELD`]).
    Plain,
}

impl Holders {
    /// The holders that `tokens` (their key expressions) name.
    pub fn of<'a>(tokens: impl IntoIterator<Item = &'a str>) -> Holders {
        let mut plain = HashSet::new();
        let mut routed = HashSet::new();
        for token in tokens {
            let Some(rest) = token
                .strip_prefix(HOLDS_CONTRACT)
                .and_then(|r| r.strip_prefix('/'))
            else {
                continue;
            };
            match rest.split_once('/') {
                Some((zid, ROUTED)) => routed.insert(zid.to_string()),
                Some(_) => false,
                None => plain.insert(rest.to_string()),
            };
        }
        match (plain.is_empty(), plain.is_subset(&routed)) {
            (true, _) => Holders::None,
            (false, true) => Holders::Routed,
            (false, false) => Holders::Plain,
        }
    }
}

/// The parameter of the questions a router asks the PEIS themselves: other routers' holdings
/// leave them unanswered.
const FROM_A_HOLDER: &str = "ecology_holder";

/// How many PEIS a router asks for their tuples at once.
const ASKED_AT_ONCE: usize = 32;

/// How long after a PEIS appears a router asks it for its tuples: time for its `contract` tuple,
/// which a PEIS that starts publishes right after its presence token, to arrive and make the
/// question needless. Until it is asked and has answered, a query that covers it is passed on to
/// it.
const ASK_AFTER: Duration = Duration::from_millis(500);

/// How long after a PEIS did not answer in full a router asks it again.
const ASK_AGAIN_AFTER: Duration = Duration::from_secs(1);

/// How long the router waits for a PEIS's tuples when it asks for them.
const ASK_WITHIN: Duration = Duration::from_secs(5);

/// One tuple as its owner last sent it.
struct Held {
    key_expr: KeyExpr<'static>,
    /// Which of [`HELD`] it falls under, a bit each: a question that covers all of one of them
    /// takes it, and one within one of them that it is not under passes it by, without comparing
    /// key expressions.
    under: u8,
    payload: ZBytes,
    encoding: Encoding,
    /// `encoding` as text, for a bundle.
    encoding_text: String,
    attachment: Option<ZBytes>,
    /// The owner's `(epoch, seq)`: a value older than the one held is not taken.
    order: (u64, u64),
    /// When it expires, in ns since the Unix epoch.
    expiry: Option<u64>,
}

/// One PEIS's tuples by key expression, apart under each of [`HELD`]: a question within one of
/// them (who covers a room: `peis/*/rooms/kitchen/*`) looks at the tuples under it alone, not at
/// every tuple of every PEIS. A key under several (a component named `components`) is kept apart
/// too, and looked at by every question.
#[derive(Default)]
struct Holding([HashMap<String, Held>; HELD.len() + 1]);

impl Holding {
    /// Where tuples under `under` are kept.
    fn slot(under: u8) -> usize {
        match under.count_ones() {
            1 => under.trailing_zeros() as usize,
            _ => HELD.len(),
        }
    }

    fn get(&self, key: &str) -> Option<&Held> {
        self.0.iter().find_map(|tuples| tuples.get(key))
    }

    fn insert(&mut self, key: String, held: Held) {
        self.0[Holding::slot(held.under)].insert(key, held);
    }

    fn remove(&mut self, key: &str) {
        for tuples in &mut self.0 {
            tuples.remove(key);
        }
    }

    fn retain(&mut self, keep: impl Fn(&Held) -> bool) {
        for tuples in &mut self.0 {
            tuples.retain(|_, held| keep(held));
        }
    }

    fn values(&self) -> impl Iterator<Item = &Held> {
        self.0.iter().flat_map(HashMap::values)
    }

    fn is_empty(&self) -> bool {
        self.0.iter().all(HashMap::is_empty)
    }

    /// The tuples that may be under one of the held key expressions `mask` has a bit of.
    fn under(&self, mask: u8) -> impl Iterator<Item = &Held> {
        self.0
            .iter()
            .enumerate()
            .filter(move |(slot, _)| *slot == HELD.len() || mask & 1 << slot != 0)
            .flat_map(|(_, tuples)| tuples.values())
    }
}

#[derive(Default)]
struct State {
    /// Per PEIS, its tuples.
    tuples: HashMap<PeisId, Holding>,
    /// PEIS present whose tuples were asked for and not yet received: a query that covers one of
    /// them is passed on to it.
    asking: HashSet<PeisId>,
    /// PEIS present: their tokens are alive.
    present: HashSet<PeisId>,
}

type Shared = Arc<Mutex<State>>;

fn lock(state: &Shared) -> std::sync::MutexGuard<'_, State> {
    state.lock().unwrap_or_else(PoisonError::into_inner)
}

/// The owner of a key expression `peis/OWNER/…`.
fn owner_of(key_expr: &str) -> Option<PeisId> {
    let rest = key_expr.strip_prefix(wire::ROOT)?.strip_prefix('/')?;
    let owner = rest.split('/').next()?;
    PeisId::new(owner).ok()
}

/// Takes in one sample of a held key.
/// Takes in one sample of a held key; whether it was taken (not older than the value held).
fn take(state: &Shared, sample: &Sample) -> bool {
    let Some(owner) = owner_of(sample.key_expr().as_str()) else {
        return false;
    };
    let key = sample.key_expr().as_str().to_owned();
    let mut state = lock(state);
    let tuples = state.tuples.entry(owner).or_default();
    match sample.kind() {
        SampleKind::Delete => tuples.remove(&key),
        SampleKind::Put => {
            let meta = sample
                .attachment()
                .and_then(|a| Metadata::decode(&a.to_bytes()).ok());
            let order = meta.as_ref().map_or((0, 0), |m| (m.epoch, m.seq));
            if tuples.get(&key).is_some_and(|held| held.order > order) {
                return false;
            }
            let key_expr = sample.key_expr().clone().into_owned();
            let under = mask(|held| held.intersects(&key_expr));
            tuples.insert(
                key,
                Held {
                    key_expr,
                    under,
                    payload: sample.payload().clone(),
                    encoding: sample.encoding().clone(),
                    encoding_text: sample.encoding().to_string(),
                    attachment: sample.attachment().cloned(),
                    order,
                    expiry: meta.and_then(|m| m.expiry),
                },
            );
        }
    }
    true
}

/// What the router holds for the contract; dropping it stops holding.
pub struct ContractCache {
    tasks: Vec<tokio::task::JoinHandle<()>>,
    _subscribers: Vec<zenoh::pubsub::Subscriber<()>>,
    _tokens: zenoh::pubsub::Subscriber<()>,
    _holder: (
        zenoh::liveliness::LivelinessToken,
        zenoh::liveliness::LivelinessToken,
    ),
}

impl Drop for ContractCache {
    fn drop(&mut self) {
        for task in &self.tasks {
            task.abort();
        }
    }
}

/// Starts holding the contract's tuples on the router's `session`.
pub async fn start(session: &Session) -> zenoh::Result<ContractCache> {
    let state: Shared = Arc::default();
    let mut tasks = Vec::new();
    let mut subscribers = Vec::new();
    // What is taken in goes out again under `@ecology/held/`, for the subscribers there (see
    // [`HELD_ROUTE`]), in the order taken, by a task of its own: a callback runs inside Zenoh's
    // routing.
    let (taken, mut to_pass_on) = mpsc::unbounded_channel::<Sample>();
    let passer = session.clone();
    tasks.push(tokio::spawn(async move {
        while let Some(sample) = to_pass_on.recv().await {
            let key_expr = format!("{HELD_ROUTE}/{}", sample.key_expr());
            let attachment = sample.attachment().cloned();
            let _ = match sample.kind() {
                SampleKind::Put => {
                    let mut put = passer
                        .put(key_expr, sample.payload().clone())
                        .encoding(sample.encoding().clone())
                        .allowed_destination(Locality::Remote);
                    if let Some(attachment) = attachment {
                        put = put.attachment(attachment);
                    }
                    put.await
                }
                SampleKind::Delete => {
                    let mut delete = passer
                        .delete(key_expr)
                        .allowed_destination(Locality::Remote);
                    if let Some(attachment) = attachment {
                        delete = delete.attachment(attachment);
                    }
                    delete.await
                }
            };
        }
    }));
    for held in HELD {
        let into = state.clone();
        let taken = taken.clone();
        // Taken in as the router routes it, before anything the owner sends after it (such as
        // its answer to the remote set that wrote it): a read that follows sees it.
        subscribers.push(
            session
                .declare_subscriber(held)
                .callback(move |sample| {
                    if take(&into, &sample) {
                        let _ = taken.send(sample);
                    }
                })
                .await?,
        );
    }
    // A PEIS that starts publishes its `contract` tuple first, right after its presence token,
    // and every tuple it writes after it: seen after its token, the router takes all its tuples as
    // they go by and need not ask it. (A thousand PEIS joining put two thousand questions on their
    // router, each matched against every key expression it knew.) One that came back without
    // starting again, or that was there before this router, does not publish it again, and is
    // asked.
    let started = state.clone();
    subscribers.push(
        session
            .declare_subscriber(format!("{}/*/{}", wire::ROOT, wire::CONTRACT_KEY))
            .callback(move |sample| {
                if sample.kind() != SampleKind::Put {
                    return;
                }
                let Some(owner) = owner_of(sample.key_expr().as_str()) else {
                    return;
                };
                let epoch = sample
                    .attachment()
                    .and_then(|a| Metadata::decode(&a.to_bytes()).ok())
                    .map_or(0, |meta| meta.epoch);
                let mut state = lock(&started);
                if state.asking.remove(&owner)
                    && let Some(tuples) = state.tuples.get_mut(&owner)
                {
                    // What is left of an earlier run of the PEIS goes.
                    tuples.retain(|held| held.order.0 >= epoch);
                }
            })
            .await?,
    );
    // Presence: a PEIS that appears is asked for its tuples; one that goes is forgotten.
    let (appeared, mut to_ask) = mpsc::unbounded_channel::<(PeisId, tokio::time::Instant)>();
    let appeared_again = appeared.clone();
    let watched = state.clone();
    let tokens = session
        .liveliness()
        .declare_subscriber(wire::ALL_ALIVE)
        .history(true)
        .callback(move |sample| {
            let Ok(peis) = wire::parse_alive_key_expr(sample.key_expr().as_str()) else {
                return;
            };
            let mut state = lock(&watched);
            if sample.kind() == SampleKind::Put {
                state.present.insert(peis.clone());
                state.asking.insert(peis.clone());
                drop(state);
                let _ = appeared.send((peis, tokio::time::Instant::now()));
            } else {
                state.present.remove(&peis);
                state.asking.remove(&peis);
                state.tuples.remove(&peis);
            }
        })
        .await?;
    let asker = session.clone();
    let filled = state.clone();
    tasks.push(tokio::spawn(async move {
        // Each PEIS asked at once; owned here, so that stopping the cache stops them.
        let mut asking = tokio::task::JoinSet::new();
        while let Some((peis, appeared)) = to_ask.recv().await {
            // In the order they appeared, so one wait covers a thousand that appear together.
            tokio::time::sleep_until(appeared + ASK_AFTER).await;
            while asking.try_join_next().is_some() {}
            // A thousand PEIS joining at once are asked a few at a time, so that none times out.
            while asking.len() >= ASKED_AT_ONCE {
                asking.join_next().await;
            }
            let session = asker.clone();
            let state = filled.clone();
            let again = appeared_again.clone();
            asking.spawn(async move {
                // Started since it appeared: its tuples come as they are published.
                if !lock(&state).asking.contains(&peis) {
                    return;
                }
                let mut answered = true;
                for held in HELD {
                    let Some(rest) = held.strip_prefix("peis/*/") else {
                        continue;
                    };
                    let Ok(replies) =
                        ask_the_peis(&session, format!("{}/{peis}/{rest}", wire::ROOT)).await
                    else {
                        answered = false;
                        continue;
                    };
                    while let Ok(reply) = replies.recv_async().await {
                        match reply.result() {
                            Ok(sample)
                                if owner_of(sample.key_expr().as_str()) == Some(peis.clone()) =>
                            {
                                take(&state, sample);
                            }
                            Ok(_) => {}
                            Err(_) => answered = false,
                        }
                    }
                }
                let ask_again = {
                    let mut state = lock(&state);
                    // What is left of an earlier run of the PEIS (written while it was away) goes.
                    if let Some(tuples) = state.tuples.get_mut(&peis) {
                        let run = tuples.values().map(|h| h.order.0).max().unwrap_or(0);
                        tuples.retain(|held| held.order.0 == run);
                    }
                    if answered {
                        state.asking.remove(&peis);
                    }
                    !answered && state.present.contains(&peis)
                };
                // Not answered in full: passed on to meanwhile, and asked again a little later.
                if ask_again {
                    tokio::time::sleep(ASK_AGAIN_AFTER).await;
                    let _ = again.send((peis, tokio::time::Instant::now()));
                }
            });
        }
    }));
    // Each held key expression, asked as it is; and all of them under `@ecology/held/`, where
    // Zenoh finds this queryable without weighing every PEIS's (see [`HELD_ROUTE`]).
    let routes = HELD
        .iter()
        .map(|held| (held.to_string(), false))
        .chain([(format!("{HELD_ROUTE}/**"), true)]);
    for (route, prefixed) in routes {
        let queryable = session
            .declare_queryable(route.as_str())
            .complete(true)
            .allowed_origin(Locality::Remote)
            .await?;
        let state = state.clone();
        let session = session.clone();
        tasks.push(tokio::spawn(async move {
            let mut answering = tokio::task::JoinSet::new();
            while let Ok(query) = queryable.recv_async().await {
                while answering.try_join_next().is_some() {}
                let asked = if prefixed {
                    match held_asked(query.key_expr().as_str()) {
                        Some(asked) => asked,
                        None => continue,
                    }
                } else {
                    query.key_expr().clone().into_owned()
                };
                // Zenoh asks this queryable alone only for a question its key expression covers
                // whole; one it merely meets (`peis/*/*/out/image` meets `peis/*/components/**`)
                // also goes to every PEIS, which answer it. Under `@ecology/held/`, a question
                // that lies within none of the held key expressions is not answered.
                if !held().iter().any(|held| held.includes(&asked)) {
                    continue;
                }
                // Another router's holding asking a PEIS: the PEIS answers, not this one (two
                // routers that passed such questions on to each other asked each other forever).
                if query.parameters().contains_key(FROM_A_HOLDER) {
                    continue;
                }
                let state = state.clone();
                let session = session.clone();
                answering.spawn(async move { answer(&session, &state, query, asked).await });
            }
        }));
    }
    // Declared last: whoever sees them can ask the queryables above. The second says that this
    // router answers under `@ecology/held/` too (a router built before did not).
    let holder = session
        .liveliness()
        .declare_token(format!("{HOLDS_CONTRACT}/{}", session.zid()))
        .await?;
    let holder_by_route = session
        .liveliness()
        .declare_token(format!("{HOLDS_CONTRACT}/{}/{ROUTED}", session.zid()))
        .await?;
    Ok(ContractCache {
        tasks,
        _holder: (holder, holder_by_route),
        _subscribers: subscribers,
        _tokens: tokens,
    })
}

/// Answers `query`, which asks for `asked` (its key expression, or what it names under
/// [`HELD_ROUTE`]), from what is held, and passes it on to the PEIS still being asked. What is
/// held goes in one reply, a bundle (`wire::encode_bundle`), when the querier asks for one
/// (`wire::BUNDLE_PARAMETER`): a thousand PEIS's contract is some seven thousand tuples, and a
/// reply each cost more than everything else of the question together.
async fn answer(session: &Session, state: &Shared, query: Query, asked: KeyExpr<'static>) {
    let bundle = query.parameters().contains_key(wire::BUNDLE_PARAMETER);
    let now = SystemClock.now().as_nanos();
    // The held key expressions the question covers whole, and those it lies within.
    let covers = mask(|held| asked.includes(held));
    let within = mask(|held| held.includes(&asked));
    // Only the tuples under the held key expressions the question covers or lies within can be
    // asked for (one within none is compared with every tuple).
    let looked_at = if within == 0 {
        u8::MAX
    } else {
        covers | within
    };
    let mut first = None;
    let mut bundled = wire::BundleWriter::default();
    let mut replies = Vec::new();
    // A question about one PEIS (`peis/NAME/…`, as a querier catching up with a PEIS that
    // appeared asks) weighs that PEIS's tuples alone, not those of every PEIS present.
    let only = owner_of(asked.as_str());
    let pass_on: HashSet<PeisId> = {
        let state = lock(state);
        let present: Vec<&PeisId> = match &only {
            Some(owner) => state.present.get(owner).into_iter().collect(),
            None => state.present.iter().collect(),
        };
        for peis in present {
            if state.asking.contains(peis) {
                continue;
            }
            let mut any = false;
            let held_for = state.tuples.get(peis);
            for held in held_for.into_iter().flat_map(|h| h.under(looked_at)) {
                let asked_for = held.under & covers != 0
                    || (within & !held.under == 0 && asked.intersects(&held.key_expr));
                if held.expiry.is_some_and(|at| at <= now) || !asked_for {
                    continue;
                }
                any = true;
                if bundle {
                    first.get_or_insert_with(|| held.key_expr.clone());
                    bundled.push(wire::Bundled {
                        key_expr: held.key_expr.as_str(),
                        encoding: &held.encoding_text,
                        payload: &held.payload.to_bytes(),
                        attachment: held.attachment.as_ref().map(ZBytes::to_bytes).as_deref(),
                    });
                } else {
                    replies.push((
                        held.key_expr.clone(),
                        held.payload.clone(),
                        held.encoding.clone(),
                        held.attachment.clone(),
                    ));
                }
            }
            // Present, and nothing held for it at all: the querier, told so, asks it itself (as
            // it would ask a PEIS present that no answer came from). One whose tuples are held
            // and none of them asked for has nothing to say: most PEIS, asked who covers a room.
            let covered = || {
                KeyExpr::try_from(format!("{}/{peis}/**", wire::ROOT))
                    .is_ok_and(|all| asked.intersects(&all))
            };
            let nothing_held = held_for.is_none_or(Holding::is_empty);
            if bundle && !any && nothing_held && covered() {
                bundled.silent(peis.as_str());
            }
        }
        state.asking.clone()
    };
    if let Some(first) = first {
        // Its key is one of the tuples it carries: a reply must be about what was asked.
        let _ = query
            .reply(first, bundled.finish())
            .encoding(Encoding::from(wire::BUNDLE_ENCODING))
            .await;
    }
    for (key, payload, encoding, attachment) in replies {
        let mut reply = query.reply(key, payload).encoding(encoding);
        if let Some(attachment) = attachment {
            reply = reply.attachment(attachment);
        }
        let _ = reply.await;
    }
    // The PEIS still being asked answer for themselves: the same question, asked of every PEIS
    // at once (one query, as if nobody held anything), with only their answers passed on.
    if pass_on.is_empty() {
        return;
    }
    let Ok(replies) = ask_the_peis(session, asked.to_string()).await else {
        return;
    };
    let mut short = false;
    while let Ok(reply) = replies.recv_async().await {
        let Ok(sample) = reply.result() else {
            short = true;
            continue;
        };
        if !owner_of(sample.key_expr().as_str()).is_some_and(|o| pass_on.contains(&o)) {
            continue;
        }
        let mut reply = query
            .reply(sample.key_expr().clone(), sample.payload().clone())
            .encoding(sample.encoding().clone());
        if let Some(attachment) = sample.attachment() {
            reply = reply.attachment(attachment.clone());
        }
        let _ = reply.await;
    }
    // Some PEIS did not answer in full (a question of theirs timed out): the querier is told,
    // and may ask each PEIS it knows to be present but heard nothing from.
    if short {
        let _ = query
            .reply_err("a PEIS this router is still asking did not answer in full")
            .await;
    }
}

/// Asks the PEIS themselves for what `key_expr` covers: every queryable but this router's own,
/// marked so that other routers' holdings leave it unanswered.
async fn ask_the_peis(
    session: &Session,
    key_expr: String,
) -> zenoh::Result<flume::Receiver<zenoh::query::Reply>> {
    session
        .get(format!("{key_expr}?{FROM_A_HOLDER}"))
        .target(QueryTarget::All)
        .allowed_destination(Locality::Remote)
        .consolidation(ConsolidationMode::None)
        .timeout(ASK_WITHIN)
        .with(flume::unbounded())
        .await
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn holders_are_asked_under_the_held_route_only_when_every_one_answers_there() {
        let of = |tokens: &[&str]| Holders::of(tokens.iter().copied());
        assert_eq!(of(&[]), Holders::None);
        assert_eq!(of(&["@ecology/holds-contract/a1/routed"]), Holders::None);
        assert_eq!(
            of(&[
                "@ecology/holds-contract/a1",
                "@ecology/holds-contract/a1/routed"
            ]),
            Holders::Routed
        );
        // A router built before the route, beside one of today: both are asked where both answer.
        assert_eq!(
            of(&[
                "@ecology/holds-contract/a1",
                "@ecology/holds-contract/a1/routed",
                "@ecology/holds-contract/b2",
            ]),
            Holders::Plain
        );
        assert_eq!(
            of(&["@ecology/holds-contract/a1", "@ecology/other/a1/routed"]),
            Holders::Plain
        );
    }

    #[test]
    fn a_question_under_the_held_route_is_the_question_after_it() {
        assert_eq!(
            held_asked("@ecology/held/peis/*/rooms/kitchen/*").map(|k| k.to_string()),
            Some("peis/*/rooms/kitchen/*".to_string())
        );
        assert_eq!(held_asked("@ecology/held"), None);
        assert_eq!(held_asked("@ecology/heldpeis/*"), None);
        assert_eq!(held_asked("peis/*/rooms/kitchen/*"), None);
    }

    #[test]
    fn a_tuple_is_kept_apart_under_the_held_key_expression_it_falls_under() {
        assert_eq!(Holding::slot(0b001), 0);
        assert_eq!(Holding::slot(0b100), 2);
        // Under two (a component named `components`): looked at by every question.
        assert_eq!(Holding::slot(0b011), HELD.len());
        assert_eq!(Holding::slot(0), HELD.len());
    }
}
