//! The conformance suite: behaviour every `TupleSpace` implementation must show, run against each one.
//!
//! An implementation provides a [`Harness`] and instantiates every test with [`conformance_tests!`](crate::conformance_tests).
//! Tests wait for observable events under [`Harness::patience`]; they never sleep to wait.

use std::collections::BTreeMap;
use std::future::Future;
use std::time::{Duration, Instant};

use crate::{
    Key, KeyPattern, MetaPointer, PeisId, PeisOptions, PresenceEvent, PresenceSubscription,
    RemoteSetPolicy, RemovalReason, Subscription, Tuple, TupleError, TupleEvent, TuplePattern,
    TupleSpace, Value,
};

/// How the suite drives one implementation.
pub trait Harness: Send {
    /// The implementation under test.
    type Space: TupleSpace;
    /// A PEIS the suite can make vanish (stop without leaving), such as a child process.
    type Vanishing: Send;

    /// Joins PEIS `name`; returns once it and every PEIS joined before see each other.
    fn join(
        &mut self,
        name: &str,
        options: PeisOptions,
    ) -> impl Future<Output = Self::Space> + Send;

    /// Makes `space` leave the ecology in an orderly way.
    fn leave(&mut self, space: Self::Space) -> impl Future<Output = ()> + Send;

    /// Joins PEIS `name` as one that can vanish; returns once the PEIS joined before see it.
    fn join_vanishing(
        &mut self,
        name: &str,
        options: PeisOptions,
    ) -> impl Future<Output = Self::Vanishing> + Send;

    /// Makes the PEIS vanish without a goodbye (a crash, a killed process).
    fn vanish(&mut self, peis: Self::Vanishing) -> impl Future<Output = ()> + Send;

    /// Moves the clock the spaces use for timestamps and expiry forward by `d`.
    fn advance(&self, d: Duration);

    /// Whether leases run on [`Harness::advance`] (virtual time) rather than on real time.
    fn leases_on_virtual_time(&self) -> bool;

    /// How long to wait for one expected event before failing.
    fn patience(&self) -> Duration;

    /// Releases everything the harness holds.
    fn finish(self) -> impl Future<Output = ()> + Send;
}

/// Instantiates every conformance test as a `#[tokio::test]` for the harness built by `$make` (an async expression).
#[macro_export]
macro_rules! conformance_tests {
    ($make:expr) => {
        $crate::conformance_tests!(@tests $make;
            last_value_per_key, order_per_key, wildcard_subscriptions, late_subscriber_gets_current_values,
            meta_tuple_refollows_pointer, remote_set_is_applied_by_owner, claims_are_arbitrated_by_the_owner,
            non_owner_cannot_publish,
            expiry_removes_tuples, presence_join_and_leave, presence_of_one_peis, vanished_peis_left_within_lease,
            a_rejoining_peis_starts_a_later_epoch, readers_are_known);
    };
    (@tests $make:expr; $($name:ident),*) => {
        $(
            #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
            async fn $name() {
                let mut harness = $make;
                $crate::conformance::$name(&mut harness).await;
                $crate::conformance::Harness::finish(harness).await;
            }
        )*
    };
}

fn key(k: &str) -> Key {
    Key::new(k).expect("test keys are valid")
}

fn peis(p: &str) -> PeisId {
    PeisId::new(p).expect("test names are valid")
}

fn pattern(p: &str) -> TuplePattern {
    TuplePattern::parse(p).expect("test patterns are valid")
}

/// Keys a PEIS may publish of itself when it joins, which the suite looks past: over Zenoh,
/// `contract`, the version of the wire contract it reads (`docs/tuples.md`, "Compatibility").
/// The in-process space has no wire, and announces nothing.
pub const ANNOUNCED_KEYS: &[&str] = &["contract"];

/// Whether `event` is about one of the [`ANNOUNCED_KEYS`].
pub fn is_announcement(event: &TupleEvent) -> bool {
    !matches!(event, TupleEvent::Retargeted { .. })
        && ANNOUNCED_KEYS.contains(&event.subject().1.as_str())
}

/// The next event of `sub` that is not an announcement ([`ANNOUNCED_KEYS`]), failing the test if
/// none comes within `patience`.
pub async fn next_event(sub: &mut Subscription, patience: Duration) -> TupleEvent {
    let deadline = tokio::time::Instant::now() + patience;
    loop {
        match tokio::time::timeout_at(deadline, sub.next()).await {
            Ok(Some(event)) if is_announcement(&event) => {}
            Ok(Some(event)) => return event,
            Ok(None) => panic!("subscription ended while an event was expected"),
            Err(_) => panic!("no event within {patience:?}"),
        }
    }
}

/// The next presence event, failing the test if none comes within `patience`.
pub async fn next_presence(sub: &mut PresenceSubscription, patience: Duration) -> PresenceEvent {
    match tokio::time::timeout(patience, sub.next()).await {
        Ok(Some(event)) => event,
        Ok(None) => panic!("presence subscription ended while an event was expected"),
        Err(_) => panic!("no presence event within {patience:?}"),
    }
}

/// Skips presence events until `wanted`, failing the test if it does not come within `patience`.
pub async fn wait_presence(
    sub: &mut PresenceSubscription,
    wanted: &PresenceEvent,
    patience: Duration,
) {
    let deadline = Instant::now() + patience;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        if next_presence(sub, left).await == *wanted {
            return;
        }
    }
}

/// Publishes `k` = `v` as `space`'s own tuple.
async fn publish<S: TupleSpace>(space: &S, k: &str, v: &str) -> Tuple {
    space.set(key(k), Value::text(v)).await.expect("set")
}

/// Subscribes `space` to pattern `p`.
async fn watch<S: TupleSpace>(space: &S, p: &str) -> Subscription {
    space.subscribe(pattern(p)).await.expect("subscribe")
}

fn changed_text(event: &TupleEvent) -> Option<(String, String, String)> {
    match event {
        TupleEvent::Changed(t) => Some((
            t.owner.to_string(),
            t.key.to_string(),
            t.text().expect("test values are text").to_owned(),
        )),
        _ => None,
    }
}

/// Collects `Changed` events as (owner, key) → value until every marker (owner, key) has been seen.
async fn collect_until_markers(
    sub: &mut Subscription,
    markers: &[(&str, &str)],
    patience: Duration,
) -> BTreeMap<(String, String), String> {
    let mut seen = BTreeMap::new();
    while !markers
        .iter()
        .all(|(o, k)| seen.contains_key(&((*o).to_owned(), (*k).to_owned())))
    {
        let event = next_event(sub, patience).await;
        let (owner, key, value) =
            changed_text(&event).unwrap_or_else(|| panic!("unexpected event {event:?}"));
        seen.insert((owner, key), value);
    }
    seen
}

/// A key holds its last value; `get` and `get_matching` return it, and `seq` counts the writes.
pub async fn last_value_per_key<H: Harness>(h: &mut H) {
    let a = h.join("astrid", PeisOptions::default()).await;
    let b = h.join("pippi", PeisOptions::default()).await;
    for v in ["1", "2", "3"] {
        publish(&a, "tc1.out.position", v).await;
    }
    let got = b
        .get(peis("astrid"), key("tc1.out.position"))
        .await
        .expect("get")
        .expect("the tuple exists");
    assert_eq!(got.text(), Ok("3"));
    assert_eq!(got.owner, peis("astrid"));
    assert_eq!(got.seq, 3);
    assert_eq!(got.mimetype.as_str(), "text/plain");
    let mut all = b
        .get_matching(pattern("astrid:**"))
        .await
        .expect("get_matching");
    all.retain(|t| !ANNOUNCED_KEYS.contains(&t.key.as_str()));
    assert_eq!(all, vec![got]);
    assert_eq!(
        b.get(peis("astrid"), key("tc1.out.speed"))
            .await
            .expect("get"),
        None
    );
    assert!(b.delete(key("nothing")).await.is_ok_and(|existed| !existed));
}

/// Subscribers see every write of a key, in order.
pub async fn order_per_key<H: Harness>(h: &mut H) {
    let a = h.join("astrid", PeisOptions::default()).await;
    let b = h.join("pippi", PeisOptions::default()).await;
    let mut sub = watch(&b, "astrid:counter").await;
    for i in 0..200 {
        a.set(key("counter"), Value::text(i.to_string()))
            .await
            .expect("set");
    }
    let mut last_seq = 0;
    for i in 0..200 {
        match next_event(&mut sub, h.patience()).await {
            TupleEvent::Changed(t) => {
                assert_eq!(t.text(), Ok(i.to_string().as_str()));
                assert!(t.seq > last_seq, "seq {} after {last_seq}", t.seq);
                last_seq = t.seq;
            }
            other => panic!("unexpected {other:?}"),
        }
    }
}

/// `*` matches one segment or any owner, `**` any number of segments.
pub async fn wildcard_subscriptions<H: Harness>(h: &mut H) {
    let a = h.join("astrid", PeisOptions::default()).await;
    let b = h.join("pippi", PeisOptions::default()).await;
    let c = h.join("hsm", PeisOptions::default()).await;
    let mut statuses = watch(&b, "*:components.*.status").await;
    let mut astrid_components = watch(&b, "astrid:components.**").await;
    for (k, v) in [
        ("components.l1.status", "running"),
        ("components.l1.cost", "100"),
        ("components.l1.x.status", "deep"),
        ("other.status", "other"),
        ("components.marker.status", "marker"),
    ] {
        publish(&a, k, v).await;
    }
    publish(&c, "components.ca1.status", "running").await;
    publish(&c, "components.marker.status", "marker").await;

    let seen = collect_until_markers(
        &mut statuses,
        &[
            ("astrid", "components.marker.status"),
            ("hsm", "components.marker.status"),
        ],
        h.patience(),
    )
    .await;
    let keys: Vec<_> = seen.keys().map(|(o, k)| format!("{o}:{k}")).collect();
    assert_eq!(
        keys,
        [
            "astrid:components.l1.status",
            "astrid:components.marker.status",
            "hsm:components.ca1.status",
            "hsm:components.marker.status"
        ]
    );

    let seen = collect_until_markers(
        &mut astrid_components,
        &[("astrid", "components.marker.status")],
        h.patience(),
    )
    .await;
    let keys: Vec<_> = seen.keys().map(|(_, k)| k.as_str()).collect();
    assert_eq!(
        keys,
        [
            "components.l1.cost",
            "components.l1.status",
            "components.l1.x.status",
            "components.marker.status"
        ]
    );
}

/// A subscriber that comes late first gets the current value of every matching tuple, then changes.
pub async fn late_subscriber_gets_current_values<H: Harness>(h: &mut H) {
    let a = h.join("astrid", PeisOptions::default()).await;
    let b = h.join("pippi", PeisOptions::default()).await;
    publish(&a, "x.one", "1").await;
    publish(&a, "x.two", "2").await;
    publish(&a, "x.one", "3").await;
    publish(&a, "x.three", "gone").await;
    assert!(a.delete(key("x.three")).await.expect("delete"));
    publish(&a, "y.one", "elsewhere").await;

    let mut sub = watch(&b, "astrid:x.*").await;
    let mut current = BTreeMap::new();
    for _ in 0..2 {
        let event = next_event(&mut sub, h.patience()).await;
        let (_, k, v) = changed_text(&event).unwrap_or_else(|| panic!("unexpected {event:?}"));
        current.insert(k, v);
    }
    let expected: BTreeMap<String, String> = [("x.one", "3"), ("x.two", "2")]
        .into_iter()
        .map(|(k, v)| (k.to_owned(), v.to_owned()))
        .collect();
    assert_eq!(current, expected);
    publish(&a, "x.two", "5").await;
    let event = next_event(&mut sub, h.patience()).await;
    assert_eq!(
        changed_text(&event),
        Some(("astrid".into(), "x.two".into(), "5".into()))
    );
}

/// A subscription through a meta-tuple follows its pointer and re-follows when it changes.
pub async fn meta_tuple_refollows_pointer<H: Harness>(h: &mut H) {
    let astrid = h.join("astrid", PeisOptions::default()).await;
    let pippi = h.join("pippi", PeisOptions::default()).await;
    let hsm = h.join("hsm", PeisOptions::default()).await;
    publish(&astrid, "s1.out.position", "a1").await;
    publish(&pippi, "ol2.out.position", "p1").await;
    let to_astrid = MetaPointer {
        owner: peis("astrid"),
        key: key("s1.out.position"),
    };
    let to_pippi = MetaPointer {
        owner: peis("pippi"),
        key: key("ol2.out.position"),
    };
    hsm.set_meta(key("tr1.mi-position"), &to_astrid)
        .await
        .expect("set meta");
    let stored = hsm
        .get(peis("hsm"), key("tr1.mi-position"))
        .await
        .expect("get")
        .expect("meta-tuple exists");
    assert_eq!(stored.text(), Ok("(meta astrid s1.out.position)"));
    assert_eq!(stored.meta_pointer(), Ok(to_astrid.clone()));

    let mut sub = astrid
        .subscribe_meta(peis("hsm"), key("tr1.mi-position"))
        .await
        .expect("subscribe_meta");
    let retargeted = |target: Option<MetaPointer>| TupleEvent::Retargeted {
        meta_owner: peis("hsm"),
        meta_key: key("tr1.mi-position"),
        target,
    };
    let p = h.patience();
    assert_eq!(
        next_event(&mut sub, p).await,
        retargeted(Some(to_astrid.clone()))
    );
    assert_eq!(
        changed_text(&next_event(&mut sub, p).await),
        Some(("astrid".into(), "s1.out.position".into(), "a1".into()))
    );
    publish(&astrid, "s1.out.position", "a2").await;
    assert_eq!(
        changed_text(&next_event(&mut sub, p).await),
        Some(("astrid".into(), "s1.out.position".into(), "a2".into()))
    );

    hsm.set_meta(key("tr1.mi-position"), &to_pippi)
        .await
        .expect("set meta");
    assert_eq!(next_event(&mut sub, p).await, retargeted(Some(to_pippi)));
    assert_eq!(
        changed_text(&next_event(&mut sub, p).await),
        Some(("pippi".into(), "ol2.out.position".into(), "p1".into()))
    );
    // The old target is no longer followed.
    publish(&astrid, "s1.out.position", "a3").await;
    publish(&pippi, "ol2.out.position", "p2").await;
    assert_eq!(
        changed_text(&next_event(&mut sub, p).await),
        Some(("pippi".into(), "ol2.out.position".into(), "p2".into()))
    );

    // A value that is not a pointer follows nothing.
    publish(&hsm, "tr1.mi-position", "not a pointer").await;
    assert_eq!(next_event(&mut sub, p).await, retargeted(None));
    hsm.set_meta(key("tr1.mi-position"), &to_astrid)
        .await
        .expect("set meta");
    assert_eq!(next_event(&mut sub, p).await, retargeted(Some(to_astrid)));
    assert_eq!(
        changed_text(&next_event(&mut sub, p).await),
        Some(("astrid".into(), "s1.out.position".into(), "a3".into()))
    );
}

/// A remote set is a request: the owner applies it under its own sequence numbers, or refuses it.
pub async fn remote_set_is_applied_by_owner<H: Harness>(h: &mut H) {
    let policy =
        RemoteSetPolicy::allow([KeyPattern::new("components.*.reqState").expect("pattern")]);
    let mut options = PeisOptions {
        remote_set: policy,
        ..PeisOptions::default()
    };
    options.limits.max_value_bytes = 16;
    let astrid = h.join("astrid", options).await;
    let deployer = h.join("deployer", PeisOptions::default()).await;
    let watcher = h.join("watcher", PeisOptions::default()).await;
    let mut sub = watch(&watcher, "astrid:**").await;

    publish(&astrid, "components.l1.reqState", "off").await;
    let applied = deployer
        .set_remote(
            peis("astrid"),
            key("components.l1.reqState"),
            Value::text("on"),
        )
        .await
        .expect("remote set");
    assert_eq!(applied.owner, peis("astrid"));
    assert_eq!(applied.seq, 2, "the owner's sequence continues");
    assert_eq!(applied.text(), Ok("on"));
    assert_eq!(
        applied.creator,
        Some(peis("deployer")),
        "the owner keeps who asked"
    );
    let own = astrid
        .get(peis("astrid"), key("components.l1.reqState"))
        .await
        .expect("get")
        .expect("exists");
    assert_eq!(own, applied);
    let p = h.patience();
    for expected in ["off", "on"] {
        match next_event(&mut sub, p).await {
            TupleEvent::Changed(t) => {
                assert_eq!((t.owner.as_str(), t.text()), ("astrid", Ok(expected)));
                let creator = (expected == "on").then(|| peis("deployer"));
                assert_eq!(t.creator, creator, "subscribers see who asked");
            }
            other => panic!("unexpected {other:?}"),
        }
    }

    let refused = deployer
        .set_remote(peis("astrid"), key("secret"), Value::text("x"))
        .await;
    assert!(
        matches!(refused, Err(TupleError::RemoteSetRefused { .. })),
        "{refused:?}"
    );
    let too_big = deployer
        .set_remote(
            peis("astrid"),
            key("components.l1.reqState"),
            Value::text("x".repeat(17)),
        )
        .await;
    assert!(
        matches!(too_big, Err(TupleError::RemoteSetRefused { .. })),
        "{too_big:?}"
    );
    assert_eq!(
        astrid
            .get(peis("astrid"), key("secret"))
            .await
            .expect("get"),
        None
    );
    // The contract: `reqState` is `on` or `off`; anything else is refused, saying so.
    let restart = deployer
        .set_remote(
            peis("astrid"),
            key("components.l1.reqState"),
            Value::text("restart"),
        )
        .await;
    match restart {
        Err(TupleError::RemoteSetRefused { reason, .. }) => {
            assert!(reason.contains("must be on or off"), "{reason}");
        }
        other => panic!("a reqState of restart was not refused: {other:?}"),
    }
    assert_eq!(
        astrid
            .get(peis("astrid"), key("components.l1.reqState"))
            .await
            .expect("get")
            .and_then(|t| t.text().ok().map(str::to_string)),
        Some("on".to_string()),
        "a refused request changes nothing"
    );
    let absent = deployer
        .set_remote(
            peis("ghost"),
            key("components.l1.reqState"),
            Value::text("on"),
        )
        .await;
    assert!(
        matches!(absent, Err(TupleError::OwnerUnreachable { .. })),
        "{absent:?}"
    );
    // Remote set to oneself is a plain set.
    let mine = deployer
        .set_remote(peis("deployer"), key("plan"), Value::text("p"))
        .await
        .expect("own set");
    assert_eq!(mine.owner, peis("deployer"));
}

/// Several executives ask one PEIS for its components: the owner grants a free component, shares
/// one that would run the same, refuses one that would run otherwise (naming who holds it),
/// releases only the requester's claim, puts a component back after its last holder, and drops a
/// holder that is gone (`crate::claims`).
pub async fn claims_are_arbitrated_by_the_owner<H: Harness>(h: &mut H) {
    let hsm = h.join("hsm", PeisOptions::default()).await;
    let a = h.join("exec-a", PeisOptions::default()).await;
    let b = h.join("exec-b", PeisOptions::default()).await;
    let ask = |space: &H::Space, k: &str, v: &str| {
        let space = space.clone();
        let (k, v) = (key(k), Value::text(v));
        async move { space.set_remote(peis("hsm"), k, v).await }
    };
    let read = |k: &str| {
        let hsm = hsm.clone();
        let k = key(k);
        async move {
            let tuple = hsm.get(peis("hsm"), k).await.expect("get");
            tuple.map(|t| t.text().expect("text").to_owned())
        }
    };
    publish(&hsm, "components.ca1.currState", "off").await;
    publish(&hsm, "components.tr1.currState", "on").await;

    // Free: granted. The same params: shared, without writing them again.
    ask(&a, "tr1.params", "(tracking-system hsm tr1 astrid)")
        .await
        .expect("free");
    let params = hsm
        .get(peis("hsm"), key("tr1.params"))
        .await
        .expect("get")
        .expect("set");
    assert_eq!(
        read("components.tr1.holders").await.as_deref(),
        Some("exec-a")
    );
    let wire = "(meta hsm ca1.out.image)";
    ask(&a, "tr1.mi-image", wire).await.expect("wired");
    ask(&b, "tr1.params", "(tracking-system hsm tr1 astrid)")
        .await
        .expect("shared");
    ask(&b, "tr1.mi-image", wire)
        .await
        .expect("the same wiring");
    assert_eq!(
        read("components.tr1.holders").await.as_deref(),
        Some("exec-a exec-b")
    );
    let again = hsm
        .get(peis("hsm"), key("tr1.params"))
        .await
        .expect("get")
        .expect("set");
    assert_eq!(
        again.seq, params.seq,
        "sharing does not restart the component"
    );

    // Other params or other wiring: refused, naming the holders; nothing changes.
    let refused = ask(&b, "tr1.params", "(tracking-system hsm tr1 bob)").await;
    let Err(TupleError::RemoteSetRefused { reason, .. }) = refused else {
        panic!("re-aiming a shared tracker must be refused: {refused:?}");
    };
    assert_eq!(
        crate::claims::held_by(&reason),
        Some(vec![peis("exec-a")]),
        "{reason}"
    );
    let refused = ask(&b, "tr1.mi-image", "(meta hsm ca2.out.image)").await;
    assert!(
        matches!(refused, Err(TupleError::RemoteSetRefused { .. })),
        "{refused:?}"
    );
    assert_eq!(
        read("tr1.params").await.as_deref(),
        Some("(tracking-system hsm tr1 astrid)")
    );
    assert_eq!(read("tr1.mi-image").await.as_deref(), Some(wire));

    // Nobody releases what another holds: a's release leaves b's component running.
    ask(&a, "tr1.params", "")
        .await
        .expect("a release is never refused");
    assert_eq!(
        read("tr1.params").await.as_deref(),
        Some("(tracking-system hsm tr1 astrid)")
    );
    assert_eq!(
        read("components.tr1.holders").await.as_deref(),
        Some("exec-b")
    );
    // Now b holds it alone, and may re-aim it.
    ask(&b, "tr1.params", "(tracking-system hsm tr1 bob)")
        .await
        .expect("sole holder");

    // Switched on by a, shared by b; the last holder's release switches it off.
    ask(&a, "components.ca1.reqState", "on")
        .await
        .expect("free");
    ask(&b, "components.ca1.reqState", "on")
        .await
        .expect("on is on");
    ask(&a, "components.ca1.reqState", "off")
        .await
        .expect("release");
    assert_eq!(read("components.ca1.reqState").await.as_deref(), Some("on"));
    assert_eq!(
        read("components.ca1.holders").await.as_deref(),
        Some("exec-b")
    );
    ask(&b, "ca1.params", "").await.expect("release by params");
    assert_eq!(
        read("components.ca1.reqState").await.as_deref(),
        Some("off")
    );
    assert_eq!(read("components.ca1.holders").await.as_deref(), Some(""));

    // The owner drops a holder that is gone: the last holder's component is put back.
    assert_eq!(
        hsm.release_claims(peis("exec-b"))
            .await
            .expect("release")
            .len(),
        2
    );
    assert_eq!(read("tr1.params").await.as_deref(), Some(""));
    assert_eq!(read("components.tr1.holders").await.as_deref(), Some(""));
    assert!(
        hsm.release_claims(peis("exec-b"))
            .await
            .expect("release")
            .is_empty()
    );
}

/// A handle publishes only its own PEIS's tuples; another PEIS's tuples change only if that PEIS agrees.
pub async fn non_owner_cannot_publish<H: Harness>(h: &mut H) {
    let astrid = h
        .join(
            "astrid",
            PeisOptions {
                remote_set: RemoteSetPolicy::deny_all(),
                ..PeisOptions::default()
            },
        )
        .await;
    let intruder = h.join("intruder", PeisOptions::default()).await;
    let watcher = h.join("watcher", PeisOptions::default()).await;
    let mut sub = watch(&watcher, "astrid:**").await;
    publish(&astrid, "components.l1.status", "running").await;
    // The intruder's `set` of the same key lands under its own name, never under astrid's.
    let own = publish(&intruder, "components.l1.status", "error").await;
    assert_eq!(own.owner, peis("intruder"));
    let refused = intruder
        .set_remote(
            peis("astrid"),
            key("components.l1.status"),
            Value::text("error"),
        )
        .await;
    assert!(
        matches!(refused, Err(TupleError::RemoteSetRefused { .. })),
        "{refused:?}"
    );
    publish(&astrid, "marker", "m").await;
    let seen = collect_until_markers(&mut sub, &[("astrid", "marker")], h.patience()).await;
    assert_eq!(
        seen.get(&("astrid".to_owned(), "components.l1.status".to_owned())),
        Some(&"running".to_owned())
    );
    assert_eq!(seen.len(), 2, "{seen:?}");
    let current = watcher
        .get(peis("astrid"), key("components.l1.status"))
        .await
        .expect("get")
        .expect("exists");
    assert_eq!((current.text(), current.seq), (Ok("running"), 1));
}

/// A tuple with a time to live disappears when it runs out, and subscribers see it removed.
pub async fn expiry_removes_tuples<H: Harness>(h: &mut H) {
    let a = h.join("astrid", PeisOptions::default()).await;
    let b = h.join("pippi", PeisOptions::default()).await;
    let mut sub = watch(&b, "astrid:**").await;
    let ttl = Duration::from_millis(500);
    a.set(key("volatile"), Value::text("v1").with_time_to_live(ttl))
        .await
        .expect("set");
    publish(&a, "stable", "s").await;
    let p = h.patience();
    let first = next_event(&mut sub, p).await;
    let TupleEvent::Changed(volatile) = first else {
        panic!("unexpected {first:?}")
    };
    assert_eq!(volatile.expiry, Some(volatile.ts_write.saturating_add(ttl)));
    assert!(matches!(
        next_event(&mut sub, p).await,
        TupleEvent::Changed(_)
    ));

    // Rewriting before expiry starts a new time to live.
    h.advance(Duration::from_millis(300));
    a.set(key("volatile"), Value::text("v2").with_time_to_live(ttl))
        .await
        .expect("set");
    assert!(matches!(
        next_event(&mut sub, p).await,
        TupleEvent::Changed(_)
    ));
    h.advance(Duration::from_millis(300));
    let alive = b.get(peis("astrid"), key("volatile")).await.expect("get");
    assert_eq!(alive.as_ref().map(|t| t.text()), Some(Ok("v2")));

    h.advance(Duration::from_millis(300));
    match next_event(&mut sub, p).await {
        TupleEvent::Removed {
            owner,
            key: k,
            reason,
            ..
        } => {
            assert_eq!(
                (owner, k, reason),
                (peis("astrid"), key("volatile"), RemovalReason::Expired)
            );
        }
        other => panic!("unexpected {other:?}"),
    }
    assert_eq!(
        b.get(peis("astrid"), key("volatile")).await.expect("get"),
        None
    );
    assert!(
        b.get(peis("astrid"), key("stable"))
            .await
            .expect("get")
            .is_some()
    );
}

/// Presence subscribers see who is present, who joins and who leaves; a left PEIS's tuples are gone.
pub async fn presence_join_and_leave<H: Harness>(h: &mut H) {
    let watcher = h.join("watcher", PeisOptions::default()).await;
    let mut presence = watcher.subscribe_presence().await.expect("subscribe");
    let p = h.patience();
    assert_eq!(
        next_presence(&mut presence, p).await,
        PresenceEvent::Joined(peis("watcher"))
    );
    let newcomer = h.join("newcomer", PeisOptions::default()).await;
    publish(&newcomer, "hello", "world").await;
    assert_eq!(
        next_presence(&mut presence, p).await,
        PresenceEvent::Joined(peis("newcomer"))
    );
    assert_eq!(
        watcher.peers().await.expect("peers"),
        vec![peis("newcomer"), peis("watcher")]
    );
    h.leave(newcomer).await;
    assert_eq!(
        next_presence(&mut presence, p).await,
        PresenceEvent::Left(peis("newcomer"))
    );
    assert_eq!(watcher.peers().await.expect("peers"), vec![peis("watcher")]);
    assert_eq!(
        watcher
            .get(peis("newcomer"), key("hello"))
            .await
            .expect("get"),
        None
    );
    // The name is free again.
    let _again = h.join("newcomer", PeisOptions::default()).await;
    assert_eq!(
        next_presence(&mut presence, p).await,
        PresenceEvent::Joined(peis("newcomer"))
    );
}

/// A subscription to one PEIS's presence sees that PEIS join and leave, and nobody else; made
/// while it is present, it starts with its `Joined`.
pub async fn presence_of_one_peis<H: Harness>(h: &mut H) {
    let watcher = h.join("watcher", PeisOptions::default()).await;
    let p = h.patience();
    let mut early = watcher
        .subscribe_presence_of(peis("target"))
        .await
        .expect("subscribe");
    let bystander = h.join("bystander", PeisOptions::default()).await;
    let target = h.join("target", PeisOptions::default()).await;
    // The bystander joined first: had its join reached this subscription, it would come first.
    assert_eq!(
        next_presence(&mut early, p).await,
        PresenceEvent::Joined(peis("target"))
    );
    let mut late = watcher
        .subscribe_presence_of(peis("target"))
        .await
        .expect("subscribe");
    assert_eq!(
        next_presence(&mut late, p).await,
        PresenceEvent::Joined(peis("target"))
    );
    h.leave(bystander).await;
    h.leave(target).await;
    for sub in [&mut early, &mut late] {
        assert_eq!(
            next_presence(sub, p).await,
            PresenceEvent::Left(peis("target"))
        );
    }
    let _again = h.join("target", PeisOptions::default()).await;
    assert_eq!(
        next_presence(&mut early, p).await,
        PresenceEvent::Joined(peis("target"))
    );
}

/// A PEIS that vanishes without leaving is reported as left once its lease has run out.
pub async fn vanished_peis_left_within_lease<H: Harness>(h: &mut H) {
    let lease = Duration::from_millis(1000);
    let watcher = h.join("watcher", PeisOptions::default()).await;
    let mut presence = watcher.subscribe_presence().await.expect("subscribe");
    let doomed = h
        .join_vanishing(
            "doomed",
            PeisOptions {
                lease,
                ..PeisOptions::default()
            },
        )
        .await;
    let p = h.patience();
    wait_presence(&mut presence, &PresenceEvent::Joined(peis("doomed")), p).await;
    h.vanish(doomed).await;
    let vanished_at = Instant::now();
    if h.leases_on_virtual_time() {
        h.advance(lease);
        wait_presence(&mut presence, &PresenceEvent::Left(peis("doomed")), p).await;
    } else {
        // Real time: the lease itself, plus a margin for a loaded machine, bounds the wait.
        let bound = lease + Duration::from_millis(1500);
        wait_presence(&mut presence, &PresenceEvent::Left(peis("doomed")), bound).await;
        let took = vanished_at.elapsed();
        assert!(took <= bound, "reported left after {took:?}");
    }
    assert_eq!(watcher.peers().await.expect("peers"), vec![peis("watcher")]);
}

/// A PEIS that leaves and joins again starts a new run: its sequence numbers start again, in a
/// greater epoch, so a subscriber takes its tuples as newer than the old run's.
pub async fn a_rejoining_peis_starts_a_later_epoch<H: Harness>(h: &mut H) {
    let watcher = h.join("watcher", PeisOptions::default()).await;
    let p = h.patience();
    let first = h.join("phoenix", PeisOptions::default()).await;
    let mut old = None;
    for v in ["a", "b"] {
        old = Some(publish(&first, "x", v).await);
    }
    let old = old.expect("set twice");
    assert_eq!(old.seq, 2);
    assert_ne!(old.epoch, 0, "a PEIS says which run wrote a tuple");
    h.leave(first).await;
    let mut sub = watcher
        .subscribe(TuplePattern::parse("phoenix:x").expect("pattern"))
        .await
        .expect("subscribe");
    h.advance(Duration::from_millis(1));
    let second = h.join("phoenix", PeisOptions::default()).await;
    let new = publish(&second, "x", "c").await;
    assert_eq!(new.seq, 1, "a new run numbers its tuples from 1");
    assert!(new.epoch > old.epoch, "{} after {}", new.epoch, old.epoch);
    match next_event(&mut sub, p).await {
        TupleEvent::Changed(t) => {
            assert_eq!((t.text(), t.seq, t.epoch), (Ok("c"), 1, new.epoch));
        }
        other => panic!("unexpected {other:?}"),
    }
}

/// Waits until `condition` holds, failing the test with `what` if it does not within `patience`.
/// For what no event announces (who reads a tuple): asked again every 10 ms.
pub async fn until(patience: Duration, what: &str, condition: impl Fn() -> bool) {
    let deadline = Instant::now() + patience;
    while !condition() {
        assert!(Instant::now() < deadline, "not within {patience:?}: {what}");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

/// Whether anyone reads a tuple: nobody at first; then a subscriber of another PEIS to exactly it,
/// to a wildcard matching it, or through a meta-tuple pointing at it, each until it is dropped.
/// A subscription to another key does not read it. An implementation may count a tuple as read
/// while it cannot know yet, for at most a second of its clock from the first time it is asked.
pub async fn readers_are_known<H: Harness>(h: &mut H) {
    let cam = h.join("cam", PeisOptions::default()).await;
    let tracker = h.join("tracker", PeisOptions::default()).await;
    let patience = h.patience();
    let image = key("c1.out.image");
    publish(&cam, "c1.out.image", "robot 1 2 0").await;
    let _ = cam.is_read(&image);
    h.advance(Duration::from_secs(2));
    let (asked, asked_of) = (&image, &cam);
    let read_is = move |want: bool, what: &'static str| {
        until(patience, what, move || asked_of.is_read(asked) == want)
    };
    read_is(false, "nobody reads it at first").await;

    let exact = watch(&tracker, "cam:c1.out.image").await;
    read_is(true, "an exact subscriber reads it").await;
    drop(exact);
    read_is(false, "nobody reads it once the subscriber is gone").await;

    let other = watch(&tracker, "cam:c1.status").await;
    let wildcard = watch(&tracker, "*:*.out.*").await;
    read_is(true, "a wildcard subscriber reads it").await;
    drop(wildcard);
    read_is(false, "a subscriber to another key does not read it").await;
    drop(other);

    let pointer = MetaPointer {
        owner: peis("cam"),
        key: image.clone(),
    };
    tracker
        .set_meta(key("t1.mi-image"), &pointer)
        .await
        .expect("set meta");
    let mut through_meta = tracker
        .subscribe_meta(peis("tracker"), key("t1.mi-image"))
        .await
        .expect("subscribe meta");
    // The meta-tuple is followed once its pointer has been read: its target's value comes next.
    loop {
        if let TupleEvent::Changed(t) = next_event(&mut through_meta, patience).await {
            assert_eq!(t.text(), Ok("robot 1 2 0"));
            break;
        }
    }
    read_is(true, "a subscriber through a meta-tuple reads it").await;
    drop(through_meta);
    read_is(false, "nobody reads it once that subscriber is gone").await;
}
