//! `ZenohPeis`: one PEIS's handle on a tuple space carried by Zenoh.

use std::collections::{BTreeSet, HashMap, HashSet};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use bytes::Bytes;
use ecology_tuples::{
    Clock, Key, Mimetype, OwnedTuples, PeisId, PeisOptions, PresenceEvent, PresenceSubscription,
    RemovalReason, Subscription, Tuple, TupleError, TupleEvent, TuplePattern, TupleSpace, Value,
};
use tokio::sync::{Notify, mpsc, watch};
use tokio::task::JoinHandle;
use zenoh::Wait;
use zenoh::key_expr::KeyExpr;
use zenoh::pubsub::Publisher;
use zenoh::qos::CongestionControl;
use zenoh::query::{ConsolidationMode, Query, QueryTarget, ReplyKeyExpr};
use zenoh::sample::{Locality, Sample, SampleKind};

use crate::cache::{HELD_ROUTE, Holders};
use crate::relink;
use crate::wire::{self, Metadata, WireError};
use crate::{Mode, Notices, ZenohError, ZenohOptions};

/// One PEIS in an ecology over Zenoh: a Zenoh session plus what the PEIS owns.
///
/// Opening publishes the tuple `contract` (the attachment version it reads, [`wire::VERSION`]),
/// declares a queryable on `peis/NAME/**` (answers `get` for its tuples), queryables on
/// `peis/NAME/@set/**` and `peis/NAME/@by/**` (apply remote sets), and the liveliness token
/// `peis/NAME/@alive`.
/// One owned task serves both queryables and removes expired tuples; it stops on
/// [`ZenohPeis::close`] or when the last clone of the handle is dropped.
#[derive(Clone, Debug)]
pub struct ZenohPeis {
    inner: Arc<Inner>,
}

#[derive(Debug)]
struct Inner {
    core: Arc<Core>,
    shutdown: watch::Sender<bool>,
    service: Mutex<Option<JoinHandle<()>>>,
    /// Dials again the links this session dialled and lost (peers only), until `shutdown`.
    _relink: Option<relink::Relink>,
}

struct Core {
    me: PeisId,
    options: PeisOptions,
    session: zenoh::Session,
    /// The session's runtime, closed after it.
    runtime: relink::OwnedRuntime,
    clock: Arc<dyn Clock>,
    store: Mutex<OwnedTuples>,
    // Held from assigning a seq to handing the sample to Zenoh, so samples of a key leave in seq order.
    // A plain mutex: Zenoh's put is synchronous (its future is `ready(wait())`), so nothing awaits
    // while it is held; it blocks only while another set hands its sample over.
    publishers: Mutex<Publishers>,
    /// Who reads each tuple this PEIS was asked about ([`TupleSpace::is_read`]).
    readers: Mutex<HashMap<Key, Readers>>,
    expiry_changed: Notify,
    malformed: Arc<AtomicU64>,
    query_timeout: Duration,
    /// Whether a PEIS can be seen present before it can be asked (peers, which link through
    /// gossip): then one that answers nothing is asked again. Also: whether it is a peer, which
    /// knows who reads its tuples at once ([`READERS_ANSWER`]). Through a router, a PEIS declares
    /// its queryables before its token (and a Zenoh client declares them again in that order when
    /// it reconnects), so its first full answer is all it has.
    answers_lag_presence: bool,
    token: Mutex<Option<zenoh::liveliness::LivelinessToken>>,
    route_hints: Arc<RouteHints>,
    /// Whether this PEIS runs in the secured mode: then remote sets name their requester.
    secured: bool,
    /// The contract version each owner this PEIS remote-sets reads, as learnt.
    contracts: Arc<Mutex<HashMap<PeisId, u8>>>,
    /// Keeps `contracts` current; declared at the first remote set to another PEIS.
    contract_watch: tokio::sync::OnceCell<ContractWatch>,
    /// Which routers hold the contract, and when that was asked ([`held_for_all`]).
    holders: Mutex<Option<(std::time::Instant, Holders)>>,
    /// The holders' tokens as followed since [`ZenohPeis::follow_holders`] (`None` before).
    holder_tokens: Arc<Mutex<Option<BTreeSet<String>>>>,
    holders_watch: tokio::sync::OnceCell<zenoh::pubsub::Subscriber<()>>,
}

/// The subscriptions that keep [`Core::contracts`] current: an owner's announcement (put or
/// removed), and its presence ending, which forgets what it read (its next run may read another
/// version). Their callbacks only touch the map.
struct ContractWatch {
    _announced: zenoh::pubsub::Subscriber<()>,
    _left: zenoh::pubsub::Subscriber<()>,
}

/// Key expressions of tuples this PEIS's subscriptions receive, to be declared to Zenoh.
///
/// Zenoh caches the route of incoming data only on a key expression its routing tables know; a
/// sample on any other key has its route computed again against every declaration in the session,
/// which was most of the cost of receiving. So the first sample of each tuple asks the service task
/// to declare its key expression; the samples after it take the cached route. A subscriber callback
/// runs inside Zenoh's routing and cannot declare there itself.
#[derive(Debug)]
struct RouteHints {
    requested: Mutex<HashSet<String>>,
    declare: mpsc::UnboundedSender<String>,
}

/// At most this many key expressions are declared for routing; past it, routes are computed per sample.
const MAX_ROUTE_HINTS: usize = 4096;

impl RouteHints {
    fn request(&self, key_expr: &str) {
        let mut requested = lock(&self.requested);
        if requested.len() < MAX_ROUTE_HINTS && !requested.contains(key_expr) {
            requested.insert(key_expr.to_owned());
            let _ = self.declare.send(key_expr.to_owned());
        }
    }
}

impl std::fmt::Debug for Core {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Core")
            .field("me", &self.me)
            .field("zid", &self.session.zid())
            .finish_non_exhaustive()
    }
}

impl Drop for Inner {
    fn drop(&mut self) {
        let _ = self.shutdown.send(true);
        if let Some(service) = lock(&self.service).take() {
            service.abort();
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // Every critical section leaves the data consistent, so a poisoned lock is still usable.
    m.lock().unwrap_or_else(|p| p.into_inner())
}

fn transport(operation: &'static str) -> impl FnOnce(zenoh::Error) -> TupleError {
    move |e| TupleError::Transport {
        operation,
        message: e.to_string(),
    }
}

/// Waits until what this PEIS published has reached the PEIS it is linked to, so that they see
/// its last tuples (components off, `idle`) before its presence ends. Zenoh sends declarations,
/// such as withdrawing a liveliness token, ahead of data still queued: a query, queued behind the
/// data at the data's priority, comes back only after the peers took in everything before it.
/// Bounded by the query timeout; a peer that does not answer is not waited for longer.
async fn flush(core: &Core) {
    let Ok(replies) = core
        .session
        .get(format!("{}/*/{FLUSH}", wire::ROOT))
        .consolidation(ConsolidationMode::None)
        .timeout(core.query_timeout.min(Duration::from_millis(500)))
        .with(flume::unbounded())
        .await
    else {
        return;
    };
    while replies.recv_async().await.is_ok() {}
}

/// The key a leaving PEIS queries to flush what it published; the replies are not read.
const FLUSH: &str = "leaving";

/// How long the set of linked peers must stay the same for the mesh to count as formed.
const LINKS_QUIET: Duration = Duration::from_millis(250);
/// How long a PEIS waits at most for the mesh to form when it joins.
const LINKS_SETTLE_MAX: Duration = Duration::from_secs(3);

/// Waits until the mesh around a session that just opened has formed. A peer is linked at first
/// only to the PEIS it connected to; gossip then tells it the others' endpoints and it links to
/// them too, and peers do not relay for each other. So until those links form, a query (is my name
/// taken? what is astrid's tuple?) reaches only the first PEIS. Waits until the set of linked
/// peers has not changed for [`LINKS_QUIET`], at most [`LINKS_SETTLE_MAX`]; at once when no peer
/// is linked at all (the first PEIS of an ecology).
async fn settle_links(session: &zenoh::Session) {
    let linked =
        || -> BTreeSet<zenoh::session::ZenohId> { session.info().peers_zid().wait().collect() };
    let start = tokio::time::Instant::now();
    let mut seen = linked();
    if seen.is_empty() {
        return;
    }
    let mut since = start;
    while since.elapsed() < LINKS_QUIET && start.elapsed() < LINKS_SETTLE_MAX {
        tokio::time::sleep(Duration::from_millis(25)).await;
        let now = linked();
        if now != seen {
            seen = now;
            since = tokio::time::Instant::now();
        }
    }
}

impl ZenohPeis {
    /// Opens a Zenoh session and joins the ecology as `options.name`.
    ///
    /// Fails if the configuration is invalid, an endpoint cannot be listened on or connected to,
    /// or a PEIS with the same name is still present after a wait of the lease plus 1 s (a run of
    /// it that just stopped stays present until its lease runs out). Needs tokio's multi-thread
    /// runtime.
    pub async fn open(options: ZenohOptions) -> Result<Self, ZenohError> {
        let (session, runtime) = relink::open(&options).await?;
        let (shutdown, shutdown_rx) = watch::channel(false);
        let relinking = match options.mode {
            Mode::Peer => Some(
                relink::relink(&session, runtime.runtime(), shutdown_rx.clone())
                    .await
                    .map_err(|e| ZenohError::Open {
                        message: e.to_string(),
                    })?,
            ),
            // A client's one link is to its router, which Zenoh itself dials again.
            Mode::Client => None,
        };
        let me = options.name.clone();
        if options.mode == Mode::Peer {
            settle_links(&session).await;
        }
        let mut answer = name_taken(&session, &me, options.query_timeout).await;
        if answer == Ok(true) {
            answer = wait_for_name(&session, &options).await;
        }
        let taken = match answer {
            Ok(false) => None,
            Ok(true) => Some(ZenohError::Space(TupleError::AlreadyPresent(me.clone()))),
            Err(message) => Some(ZenohError::NameUnknown {
                name: me.to_string(),
                message,
            }),
        };
        if let Some(refused) = taken {
            let _ = session.close().await;
            runtime.close().await;
            return Err(refused);
        }
        let get_queryable = session
            .declare_queryable(format!("{}/{}/**", wire::ROOT, me))
            .await
            .map_err(|e| ZenohError::Open {
                message: e.to_string(),
            })?;
        let set_queryable = session
            .declare_queryable(format!("{}/{}/@set/**", wire::ROOT, me))
            .await
            .map_err(|e| ZenohError::Open {
                message: e.to_string(),
            })?;
        // Remote sets that name their requester (`@by`): `**` does not reach into a chunk that
        // starts with `@`, so they have a queryable of their own.
        let by_queryable = session
            .declare_queryable(format!("{}/{}/@by/**", wire::ROOT, me))
            .await
            .map_err(|e| ZenohError::Open {
                message: e.to_string(),
            })?;
        let token = session
            .liveliness()
            .declare_token(wire::alive_key_expr(&me))
            .await
            .map_err(|e| ZenohError::Open {
                message: e.to_string(),
            })?;
        let (declare, declare_rx) = mpsc::unbounded_channel();
        let core = Arc::new(Core {
            // This run's epoch: later runs of the same PEIS start later, so their epochs are greater.
            store: Mutex::new(OwnedTuples::new(
                me.clone(),
                options.clock.now().as_nanos().max(1),
            )),
            me,
            options: options.peis,
            session,
            runtime,
            clock: options.clock,
            publishers: Mutex::new(Publishers::default()),
            readers: Mutex::new(HashMap::new()),
            expiry_changed: Notify::new(),
            malformed: Arc::new(AtomicU64::new(0)),
            query_timeout: options.query_timeout,
            answers_lag_presence: options.mode == Mode::Peer,
            token: Mutex::new(Some(token)),
            route_hints: Arc::new(RouteHints {
                requested: Mutex::new(HashSet::new()),
                declare,
            }),
            secured: matches!(options.security, crate::Security::Authenticated(_)),
            contracts: Arc::new(Mutex::new(HashMap::new())),
            contract_watch: tokio::sync::OnceCell::new(),
            holders: Mutex::new(None),
            holder_tokens: Arc::new(Mutex::new(None)),
            holders_watch: tokio::sync::OnceCell::new(),
        });
        // In the store before the service task answers its first get: whoever sees this PEIS
        // present and asks what it reads gets the answer.
        let contract = Key::new(wire::CONTRACT_KEY).map_err(|e| ZenohError::Open {
            message: e.to_string(),
        })?;
        publish(&core, contract, Value::text(wire::VERSION.to_string())).map_err(|e| {
            ZenohError::Open {
                message: e.to_string(),
            }
        })?;
        let service = tokio::spawn(serve(
            core.clone(),
            get_queryable,
            [set_queryable, by_queryable],
            declare_rx,
            shutdown_rx,
        ));
        Ok(Self {
            inner: Arc::new(Inner {
                core,
                shutdown,
                service: Mutex::new(Some(service)),
                _relink: relinking,
            }),
        })
    }

    /// Follows which routers hold the component contract from now on, so that a question of it
    /// need not first ask them (an executive does so before it starts its task: its first
    /// questions then go out at once). Does nothing among peers, where no router holds anything,
    /// or when Zenoh refuses the subscriber (the holders are then asked as before).
    pub async fn follow_holders(&self) {
        let core = &self.inner.core;
        if core.answers_lag_presence {
            return;
        }
        let tokens = core.holder_tokens.clone();
        let watched = core
            .holders_watch
            .get_or_try_init(|| async {
                core.session
                    .liveliness()
                    .declare_subscriber(crate::cache::HOLDERS)
                    .history(true)
                    .callback(move |sample| {
                        let token = sample.key_expr().as_str().to_owned();
                        let mut tokens = lock(&tokens);
                        let tokens = tokens.get_or_insert_with(BTreeSet::new);
                        match sample.kind() {
                            SampleKind::Put => tokens.insert(token),
                            SampleKind::Delete => tokens.remove(&token),
                        };
                    })
                    .await
            })
            .await;
        if watched.is_err() {
            return;
        }
        // The history comes with no end: a liveliness query has one, and what it finds is there.
        if let Ok(replies) = ask_alive_tokens(&core.session, core.query_timeout).await {
            lock(&core.holder_tokens)
                .get_or_insert_with(BTreeSet::new)
                .extend(replies);
        }
    }

    /// Leaves the ecology: stops the service task, withdraws the liveliness token and closes the session.
    pub async fn close(self) {
        // Also tells the re-dialler to stop: links lost while closing are not dialled again.
        let _ = self.inner.shutdown.send(true);
        let service = lock(&self.inner.service).take();
        if let Some(service) = service {
            // The task ends on the signal; an error would only mean it panicked, which leaves nothing to clean.
            let _ = service.await;
        }
        let token = lock(&self.inner.core.token).take();
        if let Some(token) = token {
            flush(&self.inner.core).await;
            let _ = token.undeclare().await;
        }
        let _ = self.inner.core.session.close().await;
        self.inner.core.runtime.close().await;
    }

    /// Samples dropped because they could not be read as tuples (bad key, attachment or size).
    pub fn malformed_samples(&self) -> u64 {
        self.inner.core.malformed.load(Ordering::Relaxed)
    }

    /// Every tuple matching `pattern`, asked of the PEIS that own them.
    async fn query_tuples(&self, pattern: &TuplePattern) -> Result<Vec<Tuple>, TupleError> {
        query_tuples(&self.inner.core, pattern).await
    }
}

/// How many times a PEIS joining asks whether its name is taken before it gives up.
const NAME_CHECKS: u32 = 3;

/// What one presence query told of a name.
#[derive(Debug, PartialEq, Eq)]
enum NameAnswer {
    /// A PEIS of that name answered with its token.
    Taken,
    /// Every answer came, and none was a token.
    Free,
    /// An answer was an error (the query timed out, as it can while a router takes in two
    /// thousand PEIS joining), and no token came: it tells nothing.
    Unanswered(String),
}

/// The answer of one presence query's replies ([`ask_alive`]'s).
fn name_answer<T>(replies: impl IntoIterator<Item = Result<T, String>>) -> NameAnswer {
    let mut answer = NameAnswer::Free;
    for reply in replies {
        match reply {
            Ok(_) => return NameAnswer::Taken,
            Err(why) => answer = NameAnswer::Unanswered(why),
        }
    }
    answer
}

/// Whether a PEIS named `me` is present, asked again while the answer is
/// [`NameAnswer::Unanswered`], up to [`NAME_CHECKS`] times; then the error is what the last got.
async fn name_taken(
    session: &zenoh::Session,
    me: &PeisId,
    timeout: Duration,
) -> Result<bool, String> {
    let mut why = String::new();
    for _ in 0..NAME_CHECKS {
        let replies = ask_alive(session, &wire::alive_key_expr(me), timeout)
            .await
            .map_err(|e| e.to_string())?;
        match name_answer(replies) {
            NameAnswer::Taken => return Ok(true),
            NameAnswer::Free => return Ok(false),
            NameAnswer::Unanswered(last) => why = last,
        }
    }
    Err(format!(
        "{NAME_CHECKS} presence queries in a row went unanswered ({why})"
    ))
}

/// How much longer than its own lease a joining PEIS waits for a PEIS of its name to leave.
const NAME_GRACE: Duration = Duration::from_secs(1);

/// How often a joining PEIS asks again whether its name is still taken.
const NAME_POLL: Duration = Duration::from_millis(250);

/// Whether the name of `options` is still taken after waiting up to the lease plus
/// [`NAME_GRACE`] for the PEIS holding it to leave.
///
/// A run of a PEIS that just stopped (killed outright over QUIC, frozen, or cut off) stays present
/// until its lease runs out: a run started again at once, as a supervisor restarts a crashed
/// process, would otherwise be refused as its own twin. A PEIS of that name that is alive stays,
/// and the name is still taken at the end.
async fn wait_for_name(session: &zenoh::Session, options: &ZenohOptions) -> Result<bool, String> {
    let me = &options.name;
    let wait = options.peis.lease + NAME_GRACE;
    if let Some(Notices(say)) = &options.notices {
        say(&format!(
            "a PEIS named {me} is present: waiting up to {}s for it to leave (a run of it that \
             just stopped stays present until its lease runs out)",
            wait.as_secs_f64()
        ));
    }
    let deadline = tokio::time::Instant::now() + wait;
    while tokio::time::Instant::now() < deadline {
        tokio::time::sleep(NAME_POLL).await;
        if !name_taken(session, me, options.query_timeout).await? {
            return Ok(false);
        }
    }
    Ok(true)
}

/// The payload of the error reply Zenoh gives a query that ran out of time (the asker's session,
/// or a router that forwarded it): no PEIS wrote it.
const ZENOH_TIMEOUT: &[u8] = b"Timeout";

/// Every tuple matching `pattern`, asked of the PEIS that own them.
async fn query_tuples(core: &Core, pattern: &TuplePattern) -> Result<Vec<Tuple>, TupleError> {
    let mut tuples = query_tuples_answered(core, pattern).await?.tuples;
    tuples.sort_by(|a, b| (&a.owner, &a.key).cmp(&(&b.owner, &b.key)));
    Ok(tuples)
}

/// What a question of the ecology got.
struct Answer {
    tuples: Vec<Tuple>,
    /// Whether every PEIS asked answered in full: false when an answer came back as an error, as
    /// a query that timed out does (or a router that holds the contract says one it passed the
    /// question on to did).
    in_full: bool,
    /// When the routers that hold the contract answered in bundles: the PEIS present that they
    /// held nothing for under the question (to be asked themselves). Their answer stands for
    /// every other PEIS present.
    silent: Option<BTreeSet<PeisId>>,
}

/// [`query_tuples`], and how it was answered.
async fn query_tuples_answered(core: &Core, pattern: &TuplePattern) -> Result<Answer, TupleError> {
    let key_expr = wire::pattern_key_expr(pattern);
    // Replies of every query go into an unbounded channel: with Zenoh's default (256), a query of
    // a thousand PEIS filled it, and Zenoh's thread delivering the rest blocked holding the
    // session's lock, while the task that drains it waited, on the same thread, for that lock in
    // a second query begun beside the first (a liveliness query takes it at once): deadlock.
    // A question of every PEIS that a router holds the answer to (the contract's keys) is asked of
    // the router alone; otherwise of every PEIS that matches, each answering for itself.
    // A router asked alone answers with what it holds in one bundle.
    // Routers that all answer under `@ecology/held/` are asked there, where Zenoh need not weigh
    // every PEIS's declarations to find them; their replies carry the tuples' own keys.
    // A question about one PEIS goes there too: an executive in a building asks after a few PEIS
    // one by one, and weighing a thousand PEIS's declarations cost each question as much as the
    // answer.
    let holders = held_for_all(core, &key_expr).await;
    let (target, selector, replies_from) = match (holders, &pattern.owner) {
        (Holders::Routed, _) => (
            QueryTarget::AllComplete,
            format!("{HELD_ROUTE}/{key_expr}?{}", wire::BUNDLE_PARAMETER),
            ReplyKeyExpr::Any,
        ),
        (Holders::Plain, ecology_tuples::OwnerPattern::Any) => (
            QueryTarget::AllComplete,
            format!("{key_expr}?{}", wire::BUNDLE_PARAMETER),
            ReplyKeyExpr::MatchingQuery,
        ),
        (Holders::Plain | Holders::None, _) => (
            QueryTarget::BestMatching,
            key_expr,
            ReplyKeyExpr::MatchingQuery,
        ),
    };
    let replies = core
        .session
        .get(selector)
        .accept_replies(replies_from)
        .target(target)
        .consolidation(ConsolidationMode::None)
        .timeout(core.query_timeout)
        .with(flume::unbounded())
        .await
        .map_err(transport("get"))?;
    let mut tuples = Vec::new();
    let mut recent = Recent::default();
    let mut answered = true;
    // The replies that carried tuples: a bundle counts once.
    let mut sources = 0usize;
    let mut silent = None;
    let bundle_encoding = zenoh::bytes::Encoding::from(wire::BUNDLE_ENCODING);
    while let Ok(reply) = replies.recv_async().await {
        let Ok(sample) = reply.result() else {
            answered = false;
            continue;
        };
        sources += 1;
        if *sample.encoding() == bundle_encoding {
            let bytes = sample.payload().to_bytes();
            let Ok(bundle) = wire::decode_bundle(&bytes) else {
                core.malformed.fetch_add(1, Ordering::Relaxed);
                answered = false;
                continue;
            };
            silent
                .get_or_insert_with(BTreeSet::new)
                .extend(bundle.silent.iter().filter_map(|p| PeisId::new(p).ok()));
            for t in bundle.tuples {
                let encoding = || t.encoding.to_owned();
                let decoded = decode_put(
                    t.key_expr,
                    t.payload,
                    t.attachment,
                    encoding,
                    &core.options,
                    core.clock.as_ref(),
                    &mut recent,
                );
                match decoded {
                    Ok(TupleEvent::Changed(t)) if pattern.matches(&t.owner, &t.key) => {
                        tuples.push(t);
                    }
                    Ok(_) => {}
                    Err(_) => {
                        core.malformed.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
            continue;
        }
        match decode_sample(sample, &core.options, core.clock.as_ref(), &mut recent) {
            Ok(TupleEvent::Changed(t)) if pattern.matches(&t.owner, &t.key) => tuples.push(t),
            Ok(_) => {}
            Err(_) => {
                core.malformed.fetch_add(1, Ordering::Relaxed);
            }
        }
    }
    // A tuple heard from twice (two routers, or a router and its owner) is kept once, as heard
    // first. A bundle alone holds each tuple once: its router holds one value a key. (Sorting the
    // seven thousand tuples of a thousand PEIS's contract took a tenth of the question.)
    if sources > 1 {
        tuples.sort_by(|a, b| (&a.owner, &a.key).cmp(&(&b.owner, &b.key)));
        tuples.dedup_by(|a, b| a.owner == b.owner && a.key == b.key);
    }
    Ok(Answer {
        tuples,
        in_full: answered,
        silent,
    })
}

/// Whether routers hold the component contract of every PEIS (see the module `cache`), and
/// whether each answers under `@ecology/held/`: then a question of every PEIS that the contract's
/// key expressions cover is asked of them alone, as a query of complete queryables (under that
/// prefix when all of them answer there). Routers that hold it say so with liveliness tokens, and a
/// liveliness query has a definite end, so the answer is known in one round trip (a querier's
/// matching status is not, right after it is declared). Without one (peers, routers started with
/// `--no-contract-cache`, earlier routers), every PEIS is asked as before.
async fn held_for_all(core: &Core, key_expr: &str) -> Holders {
    // Among peers there is no router to hold anything.
    if core.answers_lag_presence {
        return Holders::None;
    }
    let Ok(asked) = KeyExpr::try_from(key_expr) else {
        return Holders::None;
    };
    if !crate::cache::held()
        .iter()
        .any(|held| held.includes(&asked))
    {
        return Holders::None;
    }
    // Followed (an executive's session), or asked once for the questions that go out together
    // (an executive's acquisition asks a dozen within milliseconds).
    if let Some(tokens) = lock(&core.holder_tokens).as_ref() {
        return Holders::of(tokens.iter().map(String::as_str));
    }
    if let Some((at, holders)) = *lock(&core.holders)
        && at.elapsed() < HOLDERS_KNOWN_FOR
    {
        return holders;
    }
    let Ok(tokens) = ask_alive_tokens(&core.session, core.query_timeout).await else {
        return Holders::None;
    };
    let holders = Holders::of(tokens.iter().map(String::as_str));
    *lock(&core.holders) = Some((std::time::Instant::now(), holders));
    holders
}

/// The holders' tokens present now ([`crate::cache::HOLDERS`]).
async fn ask_alive_tokens(
    session: &zenoh::Session,
    timeout: Duration,
) -> zenoh::Result<Vec<String>> {
    let replies = session
        .liveliness()
        .get(crate::cache::HOLDERS)
        .timeout(timeout)
        .with(flume::unbounded())
        .await?;
    let mut tokens = Vec::new();
    while let Ok(reply) = replies.recv_async().await {
        if let Ok(sample) = reply.result() {
            tokens.push(sample.key_expr().as_str().to_owned());
        }
    }
    Ok(tokens)
}

/// How long the answer to which routers hold the contract stands before it is asked again.
const HOLDERS_KNOWN_FOR: Duration = Duration::from_millis(500);

/// How each tuple this PEIS has published and not removed goes out: its first value by a plain
/// put, every later one through a declared Zenoh publisher.
///
/// A declared publisher resolves its key expression and its route once, and a publisher nobody
/// subscribes to sends nothing (Zenoh's writer-side filtering); a put on a plain key expression
/// string validates the string and has its route computed again every time. But each publisher
/// declares an interest to the router, and a router checks every subscriber declared after it
/// against every interest of every client: a thousand PEIS in one ecology, each with a publisher for
/// every tuple it had ever written (most of them written once, as a component's type and cost
/// are), cost their router about as much work again after they joined as all the rest. So only a
/// tuple written again gets a publisher.
#[derive(Default)]
struct Publishers(HashMap<Key, Option<Publisher<'static>>>);

/// The way the next value of one tuple goes out.
enum Route<'a> {
    /// The tuple's own publisher.
    Declared(&'a Publisher<'static>),
    /// A plain put on this key expression: the tuple's first value.
    First(KeyExpr<'static>),
}

impl Publishers {
    fn route(
        &mut self,
        session: &zenoh::Session,
        owner: &PeisId,
        key: &Key,
    ) -> Result<Route<'_>, TupleError> {
        use std::collections::hash_map::Entry;
        let key_expr =
            || KeyExpr::try_from(wire::tuple_key_expr(owner, key)).map_err(transport("put"));
        match self.0.entry(key.clone()) {
            Entry::Occupied(e) => {
                let slot = e.into_mut();
                if slot.is_none() {
                    let publisher = session
                        .declare_publisher(key_expr()?)
                        .congestion_control(CongestionControl::Block)
                        .wait()
                        .map_err(transport("put"))?;
                    *slot = Some(publisher);
                }
                Ok(Route::Declared(slot.as_ref().expect("declared above")))
            }
            Entry::Vacant(e) => {
                let key_expr = key_expr()?;
                e.insert(None);
                Ok(Route::First(key_expr))
            }
        }
    }
}

/// How long a tuple's readers are taken to be unknown after a client PEIS first asks: a Zenoh
/// client learns who subscribes to a key expression by asking its router, when it declares a
/// publisher for it, and counts no subscriber until the answer is in (about 1 ms on loopback).
/// Until then the tuple counts as read, so a one-off output is not lost. A peer is told of its
/// peers' subscribers as they are declared, and knows at once.
const READERS_ANSWER: Duration = Duration::from_millis(100);

/// Whether anyone subscribes to one tuple of this PEIS: a publisher declared only for its matching
/// status (it never puts), kept up to date by a callback of Zenoh's.
struct Readers {
    _publisher: Publisher<'static>,
    matching: Arc<watch::Sender<bool>>,
    since: ecology_tuples::Timestamp,
}

impl Readers {
    fn declare(core: &Core, key: &Key) -> Result<Readers, TupleError> {
        let key_expr =
            KeyExpr::try_from(wire::tuple_key_expr(&core.me, key)).map_err(transport("readers"))?;
        let publisher = core
            .session
            .declare_publisher(key_expr)
            .wait()
            .map_err(transport("readers"))?;
        let matching = Arc::new(watch::Sender::new(false));
        let seen = matching.clone();
        publisher
            .matching_listener()
            .callback(move |status| {
                seen.send_replace(status.matching());
            })
            .background()
            .wait()
            .map_err(transport("readers"))?;
        Ok(Readers {
            _publisher: publisher,
            matching,
            since: core.clock.now(),
        })
    }

    /// The readers of this PEIS's tuple `key` in `known`, declared the first time it is asked
    /// about; `None` when Zenoh refuses the declaration.
    fn of<'a>(known: &'a mut HashMap<Key, Readers>, core: &Core, key: &Key) -> Option<&'a Readers> {
        match known.entry(key.clone()) {
            std::collections::hash_map::Entry::Occupied(e) => Some(e.into_mut()),
            std::collections::hash_map::Entry::Vacant(e) => Readers::declare(core, key)
                .ok()
                .map(|declared| &*e.insert(declared)),
        }
    }
}

/// Publishes `value` as this PEIS's tuple `key`: the one path for local sets, remote sets applied, and expiry.
fn publish(core: &Core, key: Key, value: Value) -> Result<Tuple, TupleError> {
    let mut publishers = lock(&core.publishers);
    // Resolved before the store changes, so a failure leaves neither a new tuple nor a used seq.
    let route = publishers.route(&core.session, &core.me, &key)?;
    let tuple = lock(&core.store).set(key, value, core.clock.now());
    send(core, route, &tuple)?;
    Ok(tuple)
}

/// Applies a remote set from `requester` under the claims rules (`ecology_tuples::claims`) and
/// publishes what it wrote; returns the tuple to answer with, or the reason it was refused.
/// `publishers` is held throughout, so no other write of this PEIS comes between the decision
/// and its writes.
fn publish_requested(
    core: &Core,
    requester: Option<&PeisId>,
    key: Key,
    value: Value,
) -> Result<Tuple, String> {
    let mut publishers = lock(&core.publishers);
    let (written, answer) =
        lock(&core.store).set_requested(requester, key, value, core.clock.now())?;
    publish_written(core, &mut publishers, &written).map_err(|e| e.to_string())?;
    Ok(answer)
}

/// Publishes what this PEIS wrote to its store, `written`, each on its route; the caller holds
/// `publishers` since the writes.
fn publish_written(
    core: &Core,
    publishers: &mut Publishers,
    written: &[Tuple],
) -> Result<(), TupleError> {
    for tuple in written {
        let route = publishers.route(&core.session, &core.me, &tuple.key)?;
        send(core, route, tuple)?;
    }
    Ok(())
}

/// Hands `tuple`, already in the store, to Zenoh on `route`.
fn send(core: &Core, route: Route<'_>, tuple: &Tuple) -> Result<(), TupleError> {
    if tuple.expiry.is_some() {
        core.expiry_changed.notify_one();
    }
    let attachment = Metadata::of_tuple(tuple).encode();
    match route {
        Route::Declared(publisher) => publisher
            .put(tuple.data.clone())
            .attachment(attachment)
            .wait(),
        Route::First(key_expr) => core
            .session
            .put(key_expr, tuple.data.clone())
            .attachment(attachment)
            .congestion_control(CongestionControl::Block)
            .wait(),
    }
    .map_err(transport("put"))
}

/// Publishes a removal of this PEIS's tuple; the caller holds `publishers` since the seq was assigned.
fn publish_removal(
    core: &Core,
    publishers: &mut Publishers,
    event: &TupleEvent,
) -> Result<(), TupleError> {
    if let TupleEvent::Removed {
        owner,
        key,
        seq,
        epoch,
        reason,
    } = event
    {
        let meta = Metadata::of_removal(
            *seq,
            *epoch,
            core.clock.now(),
            *reason == RemovalReason::Expired,
        );
        // The publisher goes with the tuple, so the cache holds only live tuples.
        let result = match publishers.0.remove(key).flatten() {
            Some(publisher) => publisher.delete().attachment(meta.encode()).wait(),
            None => core
                .session
                .delete(wire::tuple_key_expr(owner, key))
                .attachment(meta.encode())
                .congestion_control(CongestionControl::Block)
                .wait(),
        };
        result.map_err(transport("delete"))?;
    }
    Ok(())
}

/// The service task: answers `get` queries, applies remote sets, and expires tuples on the clock.
async fn serve(
    core: Arc<Core>,
    get_queryable: zenoh::query::Queryable<zenoh::handlers::FifoChannelHandler<Query>>,
    set_queryables: [zenoh::query::Queryable<zenoh::handlers::FifoChannelHandler<Query>>; 2],
    mut route_hints: mpsc::UnboundedReceiver<String>,
    mut shutdown: watch::Receiver<bool>,
) {
    // Declared for routing only; the session undeclares them when it closes.
    let mut declared = Vec::new();
    loop {
        let notified = core.expiry_changed.notified();
        tokio::pin!(notified);
        notified.as_mut().enable();
        let next = lock(&core.store).next_expiry();
        let sleep = match next {
            Some(at) => core.clock.sleep_until(at),
            None => Box::pin(std::future::pending()),
        };
        tokio::select! {
            _ = shutdown.changed() => return,
            query = get_queryable.recv_async() => match query {
                Ok(query) => answer_get(&core, query).await,
                Err(_) => return,
            },
            query = set_queryables[0].recv_async() => match query {
                Ok(query) => apply_remote_set(&core, query).await,
                Err(_) => return,
            },
            query = set_queryables[1].recv_async() => match query {
                Ok(query) => apply_remote_set(&core, query).await,
                Err(_) => return,
            },
            _ = sleep => {
                let mut publishers = lock(&core.publishers);
                let events = lock(&core.store).expire_due(core.clock.now());
                for event in &events {
                    // A failed publication of an expiry leaves the tuple removed locally; `get` agrees.
                    let _ = publish_removal(&core, &mut publishers, event);
                }
            }
            Some(key_expr) = route_hints.recv() => {
                // Without the declaration the samples still arrive, by the slower route.
                if let Ok(ke) = core.session.declare_keyexpr(key_expr).await {
                    declared.push(ke);
                }
            }
            _ = &mut notified => {}
        }
    }
}

async fn answer_get(core: &Core, query: Query) {
    let now = core.clock.now();
    let matching: Vec<Tuple> = {
        let store = lock(&core.store);
        let query_ke = query.key_expr();
        store
            .matching(&ecology_tuples::KeyPattern::any(), now)
            .filter(|t| {
                KeyExpr::try_from(wire::tuple_key_expr(&t.owner, &t.key))
                    .is_ok_and(|ke| query_ke.intersects(&ke))
            })
            .cloned()
            .collect()
    };
    for tuple in matching {
        let _ = query
            .reply(
                wire::tuple_key_expr(&tuple.owner, &tuple.key),
                tuple.data.clone(),
            )
            .attachment(Metadata::of_tuple(&tuple).encode())
            .await;
    }
}

async fn apply_remote_set(core: &Core, query: Query) {
    let outcome = remote_set_value(core, &query).and_then(|(key, value)| {
        let requester = value.creator.clone();
        publish_requested(core, requester.as_ref(), key, value)
    });

    let _ = match outcome {
        Ok(tuple) => {
            query
                .reply(query.key_expr().clone(), tuple.data.clone())
                .attachment(Metadata::of_tuple(&tuple).encode())
                .await
        }
        Err(reason) => query.reply_err(reason).await,
    };
}

fn remote_set_value(core: &Core, query: &Query) -> Result<(Key, Value), String> {
    let (named, key) = wire::parse_remote_set_key_expr(&core.me, query.key_expr().as_str())
        .map_err(|e| format!("{e} (a remote set needs one exact key)"))?;
    let data = query
        .payload()
        .map(|p| Bytes::from(p.to_bytes().into_owned()))
        .unwrap_or_default();
    let value = match query.attachment() {
        Some(att) => Metadata::decode(&att.to_bytes())
            .map_err(|e| e.to_string())?
            .into_request(data),
        None => Value::bytes(data),
    };
    let value = requester(core, named, value)?;
    if key.as_str() == wire::CONTRACT_KEY {
        return Err(format!("{key} is written by {} alone", core.me));
    }
    if let Err(e) = core.options.limits.check(&key, &value) {
        return Err(e.to_string());
    }
    if !core.options.remote_set.permits(&key) {
        return Err(format!("remote set of {key} is not allowed by {}", core.me));
    }
    ecology_tuples::contract::check_request(&key, &value.data)?;
    Ok((key, value))
}

/// The request `value` with its creator set to who asked. In the secured mode that is the
/// requester its key expression names (`@by`), which the access rules let only that member use;
/// a request without one, or whose creator stamp names someone else, is refused. In the open mode
/// it is the name the request gives, key expression first, which nothing checks.
fn requester(core: &Core, named: Option<PeisId>, value: Value) -> Result<Value, String> {
    match (named, value.creator.clone()) {
        (Some(named), Some(stamp)) if named != stamp => Err(format!(
            "the request's creator stamp names {stamp}, but {named} sent it"
        )),
        (Some(named), _) => Ok(value.with_creator(named)),
        (None, _) if core.secured => Err(format!(
            "{} takes remote sets only from a named requester (peis/{}/@by/REQUESTER/KEY)",
            core.me, core.me
        )),
        (None, _) => Ok(value),
    }
}

/// What the previous sample of a subscription was about, reused when the next one repeats it.
///
/// A subscriber mostly sees the same few keys and mimetypes; reusing them spares parsing and
/// validating the key expression and allocating the names for every sample.
#[derive(Default)]
struct Recent {
    key_expr: String,
    subject: Option<(PeisId, Key)>,
    mimetype: Option<Mimetype>,
    route_hints: Option<Arc<RouteHints>>,
    /// Whether the sample being read arrived under `@ecology/held/`: its route is that key
    /// expression's, not the tuple's.
    routed: bool,
}

impl Recent {
    /// Notes the key expression the sample being read arrived on.
    fn arrived_on(&mut self, key_expr: &str) {
        self.routed = key_expr.starts_with(HELD_ROUTE);
    }

    fn subject(&mut self, key_expr: &str) -> Result<(PeisId, Key), WireError> {
        if let Some(subject) = self.subject.as_ref().filter(|_| self.key_expr == key_expr) {
            return Ok(subject.clone());
        }
        let known = self.subject.as_ref().map(|(owner, _)| owner);
        let subject = wire::parse_tuple_key_expr_reusing(key_expr, known)?;
        if let Some(hints) = &self.route_hints {
            if self.routed {
                hints.request(&format!("{HELD_ROUTE}/{key_expr}"));
            } else {
                hints.request(key_expr);
            }
        }
        key_expr.clone_into(&mut self.key_expr);
        self.subject = Some(subject.clone());
        Ok(subject)
    }

    fn metadata(&mut self, attachment: &[u8]) -> Result<Metadata, WireError> {
        let meta = Metadata::decode_reusing(attachment, self.mimetype.as_ref())?;
        if self.mimetype.as_ref() != Some(&meta.mimetype) {
            self.mimetype = Some(meta.mimetype.clone());
        }
        Ok(meta)
    }
}

/// Reads a sample as a tuple event. A sample with no attachment gets default metadata.
fn decode_sample(
    sample: &Sample,
    options: &PeisOptions,
    clock: &dyn Clock,
    recent: &mut Recent,
) -> Result<TupleEvent, WireError> {
    let attachment = sample.attachment().map(zenoh::bytes::ZBytes::to_bytes);
    // A tuple passed on by the routers that hold the contract, under `@ecology/held/`, is the
    // owner's as it sent it.
    let arrived_on = sample.key_expr().as_str();
    let key_expr = arrived_on
        .strip_prefix(HELD_ROUTE)
        .and_then(|rest| rest.strip_prefix('/'))
        .unwrap_or(arrived_on);
    recent.arrived_on(arrived_on);
    match sample.kind() {
        SampleKind::Put => decode_put(
            key_expr,
            &sample.payload().to_bytes(),
            attachment.as_deref(),
            || sample.encoding().to_string(),
            options,
            clock,
            recent,
        ),
        SampleKind::Delete => {
            let (owner, key) = recent.subject(key_expr)?;
            let meta = match attachment {
                Some(att) => Some(recent.metadata(&att)?),
                None => None,
            };
            let (seq, epoch, expired) = meta.map_or((0, 0, false), |m| (m.seq, m.epoch, m.expired));
            Ok(TupleEvent::Removed {
                owner,
                key,
                seq,
                epoch,
                reason: if expired {
                    RemovalReason::Expired
                } else {
                    RemovalReason::Deleted
                },
            })
        }
    }
}

/// Reads one value put on `key_expr` as a tuple event: from a sample, or from a bundle of held
/// tuples. Without an attachment it gets default metadata, its mimetype from its `encoding`.
fn decode_put(
    key_expr: &str,
    payload: &[u8],
    attachment: Option<&[u8]>,
    encoding: impl FnOnce() -> String,
    options: &PeisOptions,
    clock: &dyn Clock,
    recent: &mut Recent,
) -> Result<TupleEvent, WireError> {
    let (owner, key) = recent.subject(key_expr)?;
    let meta = match attachment {
        Some(att) => Some(recent.metadata(att)?),
        None => None,
    };
    let size = payload.len();
    if size > options.limits.max_value_bytes {
        return Err(WireError::TooLarge {
            size,
            limit: options.limits.max_value_bytes,
        });
    }
    let data = Bytes::copy_from_slice(payload);
    let meta = meta.unwrap_or_else(|| Metadata {
        seq: 0,
        ts_write: clock.now(),
        ts_user: None,
        expiry: None,
        expired: false,
        epoch: 0,
        mimetype: mimetype_of_encoding(&encoding()),
        creator: None,
    });
    Ok(TupleEvent::Changed(meta.into_tuple(owner, key, data)))
}

/// The mimetype of a value without metadata: its Zenoh encoding if it names one, else
/// octet-stream.
fn mimetype_of_encoding(encoding: &str) -> Mimetype {
    if encoding == "zenoh/bytes" {
        return Mimetype::octet_stream();
    }
    Mimetype::new(encoding).unwrap_or_else(|_| Mimetype::octet_stream())
}

/// Merges a subscription's snapshots with live samples: the snapshot taken
/// when it starts, and one of each PEIS that links to this one later.
struct Merge {
    events: ecology_tuples::EventSender,
    recent: Recent,
    snapshot_done: bool,
    buffered: Vec<TupleEvent>,
    // Per key, the (epoch, seq) last delivered; anything at or below it is a
    // duplicate or stale (a snapshot and a live sample may carry the same tuple).
    delivered: HashMap<(PeisId, Key), (u64, u64)>,
}

impl Merge {
    fn live(&mut self, event: TupleEvent) {
        if self.snapshot_done {
            self.deliver(event);
        } else {
            self.buffered.push(event);
        }
    }

    fn deliver(&mut self, event: TupleEvent) {
        let (epoch, seq) = match &event {
            TupleEvent::Changed(t) => (t.epoch, t.seq),
            TupleEvent::Removed { seq, epoch, .. } => (*epoch, *seq),
            TupleEvent::Retargeted { .. } => (0, 0),
        };
        // A sample without metadata (seq 0) cannot be ordered: always news.
        if seq > 0 {
            let (owner, key) = event.subject();
            match self.delivered.entry((owner.clone(), key.clone())) {
                std::collections::hash_map::Entry::Occupied(mut seen) => {
                    if (epoch, seq) <= *seen.get() {
                        return;
                    }
                    seen.insert((epoch, seq));
                }
                std::collections::hash_map::Entry::Vacant(new) => {
                    new.insert((epoch, seq));
                }
            }
        }
        self.events.send(event);
    }

    fn finish_snapshot(&mut self, tuples: Vec<Tuple>) {
        for tuple in tuples {
            self.deliver(TupleEvent::Changed(tuple));
        }
        self.snapshot_done = true;
        for event in std::mem::take(&mut self.buffered) {
            self.deliver(event);
        }
    }

    /// The tuples of a PEIS that linked to this one after the snapshot.
    fn catch_up(&mut self, tuples: Vec<Tuple>) {
        for tuple in tuples {
            self.live(TupleEvent::Changed(tuple));
        }
    }
}

/// How many PEIS that appeared, at most, a subscription to every PEIS asks after at once.
const CATCH_UP_BATCH: usize = 1024;
/// From how many PEIS that appeared a subscription to every PEIS asks them with one question of
/// every PEIS rather than one question each: each question costs the router a match against the
/// keys of every PEIS, and one of every PEIS costs it a message to each.
const ASK_EVERY_PEIS_FROM: usize = 8;

/// How many more times a present PEIS that answered nothing is asked for its tuples.
const CATCH_UP_ATTEMPTS: u32 = 5;
/// The pause before the first of those; each next one waits one more of these.
const CATCH_UP_PAUSE: std::time::Duration = std::time::Duration::from_millis(200);

/// Aborts a task when dropped: the catch-up task of a subscription.
pub(crate) struct AbortOnDrop(pub(crate) JoinHandle<()>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.abort();
    }
}

impl TupleSpace for ZenohPeis {
    fn peis(&self) -> &PeisId {
        &self.inner.core.me
    }

    async fn set(&self, key: Key, value: Value) -> Result<Tuple, TupleError> {
        self.inner.core.options.limits.check(&key, &value)?;
        publish(&self.inner.core, key, value)
    }

    fn is_read(&self, key: &Key) -> bool {
        let core = &self.inner.core;
        let mut known = lock(&core.readers);
        // Not knowing, publish.
        Readers::of(&mut known, core, key).is_none_or(|readers| {
            *readers.matching.borrow()
                || (!core.answers_lag_presence
                    && core.clock.now().saturating_duration_since(readers.since) < READERS_ANSWER)
        })
    }

    fn watch_readers(&self, key: &Key) -> watch::Receiver<bool> {
        let core = &self.inner.core;
        let mut known = lock(&core.readers);
        match Readers::of(&mut known, core, key) {
            Some(readers) => readers.matching.subscribe(),
            // Not knowing, never wake: the component goes on asking `is_read`.
            None => watch::Sender::new(false).subscribe(),
        }
    }

    async fn delete(&self, key: Key) -> Result<bool, TupleError> {
        let core = &self.inner.core;
        let mut publishers = lock(&core.publishers);
        let removal = lock(&core.store).delete(&key);
        match removal {
            Some(event) => {
                publish_removal(core, &mut publishers, &event)?;
                Ok(true)
            }
            None => Ok(false),
        }
    }

    async fn release_claims(&self, holder: PeisId) -> Result<Vec<Tuple>, TupleError> {
        let core = &self.inner.core;
        // Held from the decision to the last put, as for a remote set.
        let mut publishers = lock(&core.publishers);
        let written = lock(&core.store).release_holder(&holder, core.clock.now());
        publish_written(core, &mut publishers, &written)?;
        Ok(written)
    }

    async fn get(&self, owner: PeisId, key: Key) -> Result<Option<Tuple>, TupleError> {
        let core = &self.inner.core;
        if owner == core.me {
            return Ok(lock(&core.store).get(&key, core.clock.now()).cloned());
        }
        let tuples = self.query_tuples(&TuplePattern::exact(owner, &key)).await?;
        Ok(tuples.into_iter().next())
    }

    async fn get_matching(&self, pattern: TuplePattern) -> Result<Vec<Tuple>, TupleError> {
        self.query_tuples(&pattern).await
    }

    async fn subscribe(&self, pattern: TuplePattern) -> Result<Subscription, TupleError> {
        let core = &self.inner.core;
        let (tx, rx) = ecology_tuples::events();
        let merge = Arc::new(Mutex::new(Merge {
            events: tx,
            recent: Recent {
                route_hints: Some(core.route_hints.clone()),
                ..Recent::default()
            },
            snapshot_done: false,
            buffered: Vec::new(),
            delivered: HashMap::new(),
        }));
        let live = merge.clone();
        let malformed = core.malformed.clone();
        let options = core.options.clone();
        let clock = core.clock.clone();
        let filter = pattern.clone();
        // Only this PEIS writes its own tuples (a remote set is answered by it, and it publishes
        // what the set wrote), so a subscription to them takes its own puts alone and is not
        // declared to the network: a PEIS host subscribes to four sets of its own tuples at
        // start, and a router of a thousand PEIS matched each of those four thousand
        // declarations against every key expression it knew.
        let origin = if pattern.owner == ecology_tuples::OwnerPattern::Exact(core.me.clone()) {
            Locality::SessionLocal
        } else {
            Locality::Any
        };
        // Through routers that hold the contract and pass it on under `@ecology/held/`, what they
        // hold is followed there: Zenoh matches a subscriber there with no PEIS's declarations (a
        // subscriber to `peis/*/rooms/kitchen/*` cost a router of a thousand PEIS milliseconds).
        let key_expr = wire::pattern_key_expr(&pattern);
        let key_expr =
            if origin == Locality::Any && held_for_all(core, &key_expr).await == Holders::Routed {
                format!("{HELD_ROUTE}/{key_expr}")
            } else {
                key_expr
            };
        // Declare first, then ask for the current values: nothing set in between is missed.
        let subscriber = core
            .session
            .declare_subscriber(key_expr)
            .allowed_origin(origin)
            .callback(move |sample| {
                let mut merge = lock(&live);
                let merge = &mut *merge;
                match decode_sample(&sample, &options, clock.as_ref(), &mut merge.recent) {
                    Ok(event) => {
                        let (owner, key) = event.subject();
                        if filter.matches(owner, key) {
                            merge.live(event);
                        }
                    }
                    Err(_) => {
                        malformed.fetch_add(1, Ordering::Relaxed);
                    }
                }
            })
            .await
            .map_err(transport("subscribe"))?;
        if pattern.owner == ecology_tuples::OwnerPattern::Exact(core.me.clone()) {
            // Only this PEIS writes its tuples: their current values are in its own store, and
            // no other PEIS need be watched or asked. (Asking the ecology cost each such
            // subscription two queries and a presence watch through the router: a PEIS host
            // subscribes to three sets of its own tuples at start, so a thousand PEIS put six
            // thousand queries on their router.)
            let snapshot = lock(&core.store)
                .matching(&pattern.key, core.clock.now())
                .cloned()
                .collect();
            lock(&merge).finish_snapshot(snapshot);
            return Ok(Subscription::from_channel(rx, subscriber));
        }
        // Peers do not relay, and they meet through gossip: a PEIS that links
        // to this one after the snapshot has tuples that will never arrive as
        // changes. Each PEIS that appears is asked for its matching tuples.
        let (appeared, mut appearances) = mpsc::unbounded_channel::<(PeisId, u32)>();
        let retry = appeared.clone();
        let owners = pattern.owner.clone();
        let alive = match &pattern.owner {
            ecology_tuples::OwnerPattern::Exact(id) => wire::alive_key_expr(id),
            ecology_tuples::OwnerPattern::Any => wire::ALL_ALIVE.to_owned(),
        };
        let watcher = core
            .session
            .liveliness()
            .declare_subscriber(alive.clone())
            .callback(move |sample| {
                if sample.kind() == SampleKind::Put
                    && let Ok(id) = wire::parse_alive_key_expr(sample.key_expr().as_str())
                    && owners.matches(&id)
                {
                    let _ = appeared.send((id, 0));
                }
            })
            .await
            .map_err(transport("subscribe"))?;
        let catch_up = {
            let core = core.clone();
            let merge = merge.clone();
            let key = pattern.key.clone();
            tokio::spawn(async move {
                // PEIS to ask again, and when: present but silent so far (their presence can
                // arrive before the link that carries their answers).
                let mut again: Vec<(tokio::time::Instant, PeisId, u32)> = Vec::new();
                loop {
                    let due = again.iter().map(|(at, _, _)| *at).min();
                    let (id, attempt) = tokio::select! {
                        got = appearances.recv() => match got {
                            Some(next) => next,
                            None => return,
                        },
                        () = async {
                            match due {
                                Some(at) => tokio::time::sleep_until(at).await,
                                None => std::future::pending().await,
                            }
                        } => {
                            let now = tokio::time::Instant::now();
                            let Some(i) = again.iter().position(|(at, _, _)| *at <= now) else {
                                continue;
                            };
                            let (_, id, attempt) = again.swap_remove(i);
                            (id, attempt)
                        }
                    };
                    // Those that appeared meanwhile are asked with it. A thousand PEIS
                    // appearing at once, asked one by one, put a thousand questions on their
                    // router for each subscription to every PEIS, each matched against the keys
                    // of every PEIS; so many are asked with one question of every PEIS.
                    let mut batch = vec![(id, attempt)];
                    while batch.len() < CATCH_UP_BATCH
                        && let Ok(next) = appearances.try_recv()
                    {
                        batch.push(next);
                    }
                    let questions: Vec<TuplePattern> = if batch.len() >= ASK_EVERY_PEIS_FROM {
                        vec![TuplePattern {
                            owner: ecology_tuples::OwnerPattern::Any,
                            key: key.clone(),
                        }]
                    } else {
                        batch
                            .iter()
                            .map(|(id, _)| TuplePattern {
                                owner: ecology_tuples::OwnerPattern::Exact(id.clone()),
                                key: key.clone(),
                            })
                            .collect()
                    };
                    // Those heard from, and those a question in full found with nothing to
                    // catch up: asking each of a thousand PEIS five more times, for each
                    // subscription to every PEIS, kept their router busy for seconds.
                    let mut settled = BTreeSet::new();
                    for question in &questions {
                        let Ok(answer) = query_tuples_answered(&core, question).await else {
                            continue;
                        };
                        if answer.in_full && !core.answers_lag_presence {
                            match &question.owner {
                                ecology_tuples::OwnerPattern::Exact(id) => {
                                    settled.insert(id.clone());
                                }
                                ecology_tuples::OwnerPattern::Any => {
                                    settled.extend(batch.iter().map(|(id, _)| id.clone()));
                                }
                            }
                        }
                        settled.extend(answer.tuples.iter().map(|t| t.owner.clone()));
                        if !answer.tuples.is_empty() {
                            lock(&merge).catch_up(answer.tuples);
                        }
                    }
                    for (id, attempt) in batch {
                        // A PEIS that never answers is caught up with by its next changes.
                        if !settled.contains(&id) && attempt < CATCH_UP_ATTEMPTS {
                            let at = tokio::time::Instant::now() + CATCH_UP_PAUSE * (attempt + 1);
                            again.push((at, id, attempt + 1));
                        }
                    }
                }
            })
        };
        let answer = query_tuples_answered(core, &pattern).await?;
        let snapshot = answer.tuples;
        // Every present PEIS the snapshot heard nothing from is asked on its own. The routers
        // that hold the contract, answering in full in bundles, name those they hold nothing for
        // among the PEIS present (they see every token before it reaches this PEIS); otherwise
        // the PEIS present are asked for, which at 1,000 PEIS took as long as the question itself
        // (and, asked beside it, delayed it as long). One that appears later is caught by the
        // watcher above. A subscription to one PEIS asks after that one only.
        let heard: BTreeSet<PeisId> = snapshot.iter().map(|t| t.owner.clone()).collect();
        let unheard = match (answer.silent.filter(|_| answer.in_full), &pattern.owner) {
            (Some(silent), _) => Ok(silent),
            // The one PEIS asked after answered: nobody is left to ask (an executive follows a
            // building's PEIS one by one, and this saved a round trip for each).
            (None, ecology_tuples::OwnerPattern::Exact(id)) if heard.contains(id) => {
                Ok(BTreeSet::new())
            }
            (None, _) => alive_matching(core, &alive).await,
        };
        if let Ok(unheard) = unheard {
            for id in unheard {
                if id != core.me && !heard.contains(&id) && pattern.owner.matches(&id) {
                    let _ = retry.send((id, 0));
                }
            }
        }
        lock(&merge).finish_snapshot(snapshot);
        let guard = (subscriber, watcher, AbortOnDrop(catch_up));
        Ok(Subscription::from_channel(rx, guard))
    }

    async fn set_remote(&self, owner: PeisId, key: Key, value: Value) -> Result<Tuple, TupleError> {
        let core = &self.inner.core;
        core.options.limits.check(&key, &value)?;
        if owner == core.me {
            return publish(core, key, value);
        }
        // Spoken in the owner's version: an owner that reads version 2 records who asked (the
        // tuple's creator), watches the presence of whoever switched its components on, and puts
        // them back when that PEIS is gone; in the secured mode it takes the requester from the
        // key expression. One that reads only version 1 gets the earlier request, unnamed.
        let contract = contract_of(core, &owner).await;
        let (value, key_expr) = if contract.is_some_and(|version| version < wire::VERSION) {
            (
                Value {
                    creator: None,
                    ..value
                },
                wire::remote_set_key_expr(&owner, &key),
            )
        } else if core.secured {
            (
                value.with_creator(core.me.clone()),
                wire::requested_set_key_expr(&owner, &core.me, &key),
            )
        } else {
            (
                value.with_creator(core.me.clone()),
                wire::remote_set_key_expr(&owner, &key),
            )
        };
        let replies = core
            .session
            .get(key_expr)
            .payload(value.data.clone())
            .attachment(Metadata::of_request(&value).encode())
            .consolidation(ConsolidationMode::None)
            .timeout(core.query_timeout)
            .await
            .map_err(transport("remote set"))?;
        let Ok(reply) = replies.recv_async().await else {
            return Err(TupleError::OwnerUnreachable { owner, key });
        };
        // The owner answered (or refused): what it reads is known until it leaves, unless it
        // announced something meanwhile.
        let answered =
            !matches!(reply.result(), Err(err) if &*err.payload().to_bytes() == ZENOH_TIMEOUT);
        if let Some(version) = contract.filter(|_| answered && core.contract_watch.get().is_some())
        {
            lock(&core.contracts)
                .entry(owner.clone())
                .or_insert(version);
        }
        match reply.result() {
            Ok(sample) => {
                let meta = sample
                    .attachment()
                    .ok_or("the reply has no metadata")
                    .and_then(|att| {
                        Metadata::decode(&att.to_bytes())
                            .map_err(|_| "the reply's metadata is malformed")
                    })
                    .map_err(|message| TupleError::Transport {
                        operation: "remote set",
                        message: message.to_owned(),
                    })?;
                let data = Bytes::from(sample.payload().to_bytes().into_owned());
                Ok(meta.into_tuple(owner, key, data))
            }
            // Zenoh's own answer to a query that ran out of time, from this session or a
            // router on the way: the owner said nothing.
            Err(err) if &*err.payload().to_bytes() == ZENOH_TIMEOUT => {
                Err(TupleError::OwnerUnreachable { owner, key })
            }
            Err(err) => Err(TupleError::RemoteSetRefused {
                owner,
                key,
                reason: String::from_utf8_lossy(&err.payload().to_bytes()).into_owned(),
            }),
        }
    }

    async fn peers(&self) -> Result<Vec<PeisId>, TupleError> {
        let core = &self.inner.core;
        let mut peers = alive_peis(core).await?;
        peers.insert(core.me.clone());
        Ok(peers.into_iter().collect())
    }

    async fn subscribe_presence(&self) -> Result<PresenceSubscription, TupleError> {
        // Whoever follows every PEIS's presence (an executive, the view) is the one that
        // remote-sets them: it learns now what each reads, and what each newcomer announces, so
        // that no remote set waits to ask.
        learn_contracts(&self.inner.core).await;
        subscribe_alive(&self.inner.core, wire::ALL_ALIVE).await
    }

    async fn subscribe_presence_of(
        &self,
        peis: PeisId,
    ) -> Result<PresenceSubscription, TupleError> {
        subscribe_alive(&self.inner.core, &wire::alive_key_expr(&peis)).await
    }
}

/// Whether [`Core::contracts`] is kept current, starting to keep it if it is not yet. Without the
/// watch, what an owner reads is asked again at every remote set.
async fn watching_contracts(core: &Core) -> bool {
    if core.contract_watch.get().is_none()
        && let Ok(watch) = watch_contracts(core).await
    {
        let _ = core.contract_watch.set(watch);
    }
    core.contract_watch.get().is_some()
}

/// The contract version a sample of a PEIS's `contract` tuple announces.
fn announced(sample: &zenoh::sample::Sample) -> Option<u8> {
    std::str::from_utf8(&sample.payload().to_bytes())
        .ok()
        .and_then(wire::parse_contract)
}

/// Starts keeping [`Core::contracts`] current, and asks every PEIS present what it reads.
async fn learn_contracts(core: &Core) {
    if !watching_contracts(core).await {
        return;
    }
    let Ok(replies) = core
        .session
        .get(format!("{}/*/{}", wire::ROOT, wire::CONTRACT_KEY))
        .consolidation(ConsolidationMode::None)
        .timeout(core.query_timeout.min(Duration::from_secs(1)))
        .with(flume::unbounded())
        .await
    else {
        return;
    };
    while let Ok(reply) = replies.recv_async().await {
        let Ok(sample) = reply.result() else { continue };
        let Ok((owner, _)) = wire::parse_tuple_key_expr(sample.key_expr().as_str()) else {
            continue;
        };
        if let Some(version) = announced(sample) {
            lock(&core.contracts).insert(owner, version);
        }
    }
}

/// The contract version `owner` reads: what it announced in its tuple `contract`, version 1 if
/// it announced none but answers at all; `None` if it did not answer in time. Learnt once per
/// owner and kept until its presence ends; the first remote set to an owner asks (at most 1 s,
/// twice if it answers nothing), later ones do not.
async fn contract_of(core: &Core, owner: &PeisId) -> Option<u8> {
    // Watch before asking, so an announcement or a departure between the two is not missed.
    let watching = watching_contracts(core).await;
    if let Some(&version) = lock(&core.contracts).get(owner) {
        return Some(version);
    }
    let contract = wire::tuple_key_expr(owner, &Key::new(wire::CONTRACT_KEY).ok()?);
    match ask_contract(core, owner, &contract, &contract, watching).await {
        Heard::Version(version) => Some(version),
        Heard::Answered => Some(wire::VERSION_1),
        Heard::Failed => None,
        // No reply at all: either nobody holds the tuple (an owner of version 1) or nothing
        // reached the owner (a link just lost or not yet back, as for a process that was stopped
        // for seconds). Taking an unreachable owner for one of version 1 would send it an
        // unnamed request, which, if it landed once the link was back, would make nobody a
        // holder of what it switched on, so that nothing put it back. So the owner is asked for
        // everything it holds: its answer has its `contract` if it announced one, and shows
        // that it answers at all.
        Heard::Nothing => {
            let everything = format!("{}/{owner}/**", wire::ROOT);
            match ask_contract(core, owner, &everything, &contract, watching).await {
                Heard::Version(version) => Some(version),
                Heard::Answered => Some(wire::VERSION_1),
                Heard::Failed | Heard::Nothing => None,
            }
        }
    }
}

/// What a question about an owner's contract got.
enum Heard {
    /// Its tuple `contract` announced this version.
    Version(u8),
    /// It answered, without announcing a version.
    Answered,
    /// An answer came back as an error (a question that timed out).
    Failed,
    /// No answer at all.
    Nothing,
}

/// Asks `key_expr` of `owner` (at most 1 s) and reads its `contract` tuple (`contract`) among the
/// answers; a version learnt is kept while `watching`.
async fn ask_contract(
    core: &Core,
    owner: &PeisId,
    key_expr: &str,
    contract: &str,
    watching: bool,
) -> Heard {
    let Ok(replies) = core
        .session
        .get(key_expr)
        .consolidation(ConsolidationMode::None)
        .timeout(core.query_timeout.min(Duration::from_secs(1)))
        .with(flume::unbounded())
        .await
    else {
        return Heard::Failed;
    };
    let (mut answered, mut failed) = (false, false);
    while let Ok(reply) = replies.recv_async().await {
        let Ok(sample) = reply.result() else {
            failed = true;
            continue;
        };
        answered = true;
        if sample.key_expr().as_str() == contract
            && let Some(version) = announced(sample)
        {
            if watching {
                lock(&core.contracts).insert(owner.clone(), version);
            }
            return Heard::Version(version);
        }
    }
    match (failed, answered) {
        (true, _) => Heard::Failed,
        (false, true) => Heard::Answered,
        (false, false) => Heard::Nothing,
    }
}

/// Declares the subscriptions of [`ContractWatch`].
async fn watch_contracts(core: &Core) -> Result<ContractWatch, zenoh::Error> {
    let contracts = core.contracts.clone();
    let announced = core
        .session
        .declare_subscriber(format!("{}/*/{}", wire::ROOT, wire::CONTRACT_KEY))
        .callback(move |sample| {
            let Ok((owner, _)) = wire::parse_tuple_key_expr(sample.key_expr().as_str()) else {
                return;
            };
            let version = match sample.kind() {
                SampleKind::Put => announced(&sample),
                SampleKind::Delete => None,
            };
            let mut contracts = lock(&contracts);
            match version {
                Some(version) => contracts.insert(owner, version),
                None => contracts.remove(&owner),
            };
        })
        .await?;
    let contracts = core.contracts.clone();
    let left = core
        .session
        .liveliness()
        .declare_subscriber(wire::ALL_ALIVE)
        .callback(move |sample| {
            if sample.kind() == SampleKind::Delete
                && let Ok(owner) = wire::parse_alive_key_expr(sample.key_expr().as_str())
            {
                lock(&contracts).remove(&owner);
            }
        })
        .await?;
    Ok(ContractWatch {
        _announced: announced,
        _left: left,
    })
}

/// A presence subscription to the liveliness tokens matching `key_expr`: every PEIS's, or one's.
async fn subscribe_alive(core: &Core, key_expr: &str) -> Result<PresenceSubscription, TupleError> {
    let (tx, rx) = mpsc::unbounded_channel();
    let presence = Arc::new(Mutex::new(Presence {
        present: BTreeSet::new(),
        events: tx,
    }));
    let live = presence.clone();
    let subscriber = core
        .session
        .liveliness()
        .declare_subscriber(key_expr)
        .history(true)
        .callback(move |sample| {
            if let Ok(id) = wire::parse_alive_key_expr(sample.key_expr().as_str()) {
                lock(&live).observe(id, sample.kind() == SampleKind::Put);
            }
        })
        .await
        .map_err(transport("subscribe to presence"))?;
    // Tokens already known are delivered as history; asking once more covers a token whose link
    // forms while the subscriber is being declared. `Presence` drops repeats.
    reconcile_presence(core, key_expr, &presence).await?;
    Ok(PresenceSubscription::from_channel(rx, subscriber))
}

/// Who a presence subscription has reported present; turns token samples into join and leave events once each.
struct Presence {
    present: BTreeSet<PeisId>,
    events: mpsc::UnboundedSender<PresenceEvent>,
}

impl Presence {
    fn observe(&mut self, id: PeisId, alive: bool) {
        let event = if alive && self.present.insert(id.clone()) {
            PresenceEvent::Joined(id)
        } else if !alive && self.present.remove(&id) {
            PresenceEvent::Left(id)
        } else {
            return;
        };
        let _ = self.events.send(event);
    }
}

/// Asks for the liveliness tokens matching `key_expr` and reports PEIS not yet seen as joined.
async fn reconcile_presence(
    core: &Core,
    key_expr: &str,
    presence: &Mutex<Presence>,
) -> Result<(), TupleError> {
    let alive = alive_matching(core, key_expr).await?;
    // Only joins are reconciled: a reply missing from a slow query must not read as a PEIS lost;
    // departures arrive as token deletions (or when the transport lease runs out).
    let mut presence = lock(presence);
    for id in alive {
        presence.observe(id, true);
    }
    Ok(())
}

/// Every PEIS whose liveliness token answers a query now.
async fn alive_peis(core: &Core) -> Result<BTreeSet<PeisId>, TupleError> {
    alive_matching(core, wire::ALL_ALIVE).await
}

/// The PEIS whose liveliness tokens match `key_expr` and answer a query now.
async fn alive_matching(core: &Core, key_expr: &str) -> Result<BTreeSet<PeisId>, TupleError> {
    let replies = ask_alive(&core.session, key_expr, core.query_timeout)
        .await
        .map_err(transport("peers"))?;
    Ok(replies.into_iter().filter_map(Result::ok).collect())
}

/// The replies to a liveliness query on `key_expr`: the PEIS of each token, or the message of an
/// error reply (a query that timed out gets one).
async fn ask_alive(
    session: &zenoh::Session,
    key_expr: &str,
    timeout: Duration,
) -> zenoh::Result<Vec<Result<PeisId, String>>> {
    let replies = session
        .liveliness()
        .get(key_expr)
        .timeout(timeout)
        .with(flume::unbounded())
        .await?;
    let mut got = Vec::new();
    while let Ok(reply) = replies.recv_async().await {
        match reply.result() {
            Ok(sample) => {
                if let Ok(id) = wire::parse_alive_key_expr(sample.key_expr().as_str()) {
                    got.push(Ok(id));
                }
            }
            Err(e) => got.push(Err(
                String::from_utf8_lossy(&e.payload().to_bytes()).into_owned()
            )),
        }
    }
    Ok(got)
}

#[cfg(test)]
mod tests {
    use super::{NameAnswer, name_answer};

    #[test]
    fn a_name_check_that_timed_out_says_nothing_of_the_name() {
        let timeout = || Err("Timeout".to_owned());
        assert_eq!(name_answer::<()>([]), NameAnswer::Free);
        assert_eq!(name_answer([Ok(())]), NameAnswer::Taken);
        assert_eq!(
            name_answer([timeout()]),
            NameAnswer::Unanswered("Timeout".to_owned())
        );
        // A token is a token, whatever else came.
        assert_eq!(name_answer([timeout(), Ok(())]), NameAnswer::Taken);
        assert_eq!(name_answer([Ok(()), timeout()]), NameAnswer::Taken);
    }
}
