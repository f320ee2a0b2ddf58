//! Tests of the tuple model and the in-process space: the conformance suite on virtual time, and validation.

use std::sync::Arc;
use std::time::Duration;

use crate::conformance::{Harness, next_event};
use crate::*;

/// Runs the in-process space on a virtual clock.
struct InProcessHarness {
    clock: VirtualClock,
    space: InProcessSpace,
}

impl InProcessHarness {
    fn new() -> Self {
        let clock = VirtualClock::default();
        let space = InProcessSpace::new(Arc::new(clock.clone()));
        Self { clock, space }
    }
}

impl Harness for InProcessHarness {
    type Space = InProcessPeis;
    type Vanishing = InProcessPeis;

    async fn join(&mut self, name: &str, options: PeisOptions) -> InProcessPeis {
        let id = PeisId::new(name).expect("valid name");
        self.space.join(id, options).expect("join")
    }

    async fn leave(&mut self, space: InProcessPeis) {
        space.leave();
    }

    async fn join_vanishing(&mut self, name: &str, options: PeisOptions) -> InProcessPeis {
        self.join(name, options).await
    }

    async fn vanish(&mut self, peis: InProcessPeis) {
        peis.vanish();
    }

    fn advance(&self, d: Duration) {
        self.clock.advance(d);
    }

    fn leases_on_virtual_time(&self) -> bool {
        true
    }

    fn patience(&self) -> Duration {
        Duration::from_secs(5)
    }

    async fn finish(self) {
        self.space.shutdown().await;
    }
}

mod conformance {
    use super::InProcessHarness;
    crate::conformance_tests!(InProcessHarness::new());
}

fn key(k: &str) -> Key {
    Key::new(k).expect("valid key")
}

fn peis(p: &str) -> PeisId {
    PeisId::new(p).expect("valid name")
}

#[test]
fn keys_and_names_are_validated() {
    for ok in ["a", "components.l1.status", "tc1.mi-position", "x_y.Z-9"] {
        assert!(Key::new(ok).is_ok(), "{ok}");
    }
    for (bad, reason) in [
        ("", "it is empty"),
        ("a..b", "a segment between dots is empty"),
        (".a", "a segment between dots is empty"),
        ("a.", "a segment between dots is empty"),
        ("a/b", "segments may only hold letters, digits, '-' and '_'"),
        ("a.*", "segments may only hold letters, digits, '-' and '_'"),
        (
            "@set",
            "segments may only hold letters, digits, '-' and '_'",
        ),
        ("é", "segments may only hold letters, digits, '-' and '_'"),
    ] {
        assert_eq!(
            Key::new(bad),
            Err(ValidationError::Key {
                key: bad.to_owned(),
                reason
            })
        );
    }
    assert!(Key::new(&"a".repeat(256)).is_err());
    assert!(PeisId::new("astrid").is_ok());
    for bad in ["", "a.b", "a/b", "*", "@alive"] {
        assert!(PeisId::new(bad).is_err(), "{bad}");
    }
    let err = Key::new("a..b").expect_err("invalid");
    assert_eq!(
        err.to_string(),
        "invalid key \"a..b\": a segment between dots is empty"
    );
}

#[test]
fn patterns_match_segments() {
    let check = |pattern: &str, key_text: &str, expected: bool| {
        let p = KeyPattern::new(pattern).expect("valid pattern");
        assert_eq!(
            p.matches(&key(key_text)),
            expected,
            "{pattern} vs {key_text}"
        );
    };
    check("a.b", "a.b", true);
    check("a.b", "a.b.c", false);
    check("a.*", "a.b", true);
    check("a.*", "a.b.c", false);
    check("a.*", "a", false);
    check("*.status", "l1.status", true);
    check("a.**", "a", true);
    check("a.**", "a.b.c", true);
    check("**", "x", true);
    check("**.status", "components.l1.status", true);
    check("**.status", "components.l1.cost", false);
    check("a.**.z", "a.z", true);
    check("a.**.z", "a.b.c.z", true);
    check("a.**.z", "a.b.c.y", false);
    check("a.**.b.*", "a.x.b.y.b.z", true);
    check("**.**.x", "x", true);
    check("x", "x", true);
    check("b", "a.b", false);
    check("components.*.reqState", "components.c1.holders", false);
    check("components.*.reqState", "c1.reqState", false);
    assert_eq!(
        KeyPattern::new("a.**.**.b").expect("valid").to_string(),
        "a.**.b"
    );
    for bad in ["", "a..b", "a*", "a.b*", "***", "a/b"] {
        assert!(KeyPattern::new(bad).is_err(), "{bad}");
    }
    let tp = TuplePattern::parse("astrid:components.*.status").expect("valid");
    assert!(tp.matches(&peis("astrid"), &key("components.l1.status")));
    assert!(!tp.matches(&peis("pippi"), &key("components.l1.status")));
    assert_eq!(tp.to_string(), "astrid:components.*.status");
    let any_owner = TuplePattern::parse("components.**").expect("valid");
    assert_eq!(any_owner.owner, OwnerPattern::Any);
    assert!(TuplePattern::parse("a.b:c").is_err());
}

#[test]
fn meta_pointers_parse_and_print() {
    let p = MetaPointer::parse("  (meta astrid tc1.out.position) ").expect("valid");
    assert_eq!(p.owner, peis("astrid"));
    assert_eq!(p.to_string(), "(meta astrid tc1.out.position)");
    for bad in [
        "meta a b",
        "(meta a)",
        "(meta a b c)",
        "(other a b)",
        "(meta a.b c)",
        "(meta a b..c)",
    ] {
        assert!(MetaPointer::parse(bad).is_err(), "{bad}");
    }
}

#[tokio::test]
async fn values_over_the_limit_and_non_text_are_rejected_with_context() {
    let clock = VirtualClock::default();
    let space = InProcessSpace::new(Arc::new(clock));
    let mut options = PeisOptions::default();
    assert_eq!(options.limits.max_value_bytes, 1 << 20);
    let big = space.join(peis("big"), options.clone()).expect("join");
    assert!(
        big.set(key("k"), Value::bytes(vec![0u8; 1 << 20]))
            .await
            .is_ok()
    );
    let over = big
        .set(key("k"), Value::bytes(vec![0u8; (1 << 20) + 1]))
        .await;
    assert_eq!(
        over,
        Err(TupleError::Invalid(ValidationError::ValueTooLarge {
            key: key("k"),
            size: (1 << 20) + 1,
            limit: 1 << 20
        }))
    );
    options.limits.max_value_bytes = 4;
    let small = space.join(peis("small"), options).expect("join");
    let err = small
        .set(key("k"), Value::text("12345"))
        .await
        .expect_err("too large");
    assert_eq!(
        err.to_string(),
        "value of 5 bytes for key k is over the limit of 4 bytes"
    );
    let err = small
        .set_remote(peis("big"), key("k"), Value::text("12345"))
        .await
        .expect_err("too large for the sender too");
    assert!(matches!(
        err,
        TupleError::Invalid(ValidationError::ValueTooLarge { .. })
    ));

    let binary = big
        .set(key("blob"), Value::bytes(vec![b'o', b'k', 0xff]))
        .await
        .expect("set");
    assert_eq!(
        binary.text(),
        Err(ValidationError::NotUtf8 {
            owner: peis("big"),
            key: key("blob"),
            offset: 2
        })
    );
    assert!(matches!(
        binary.meta_pointer(),
        Err(ValidationError::NotUtf8 { .. })
    ));
    let text = big.set(key("t"), Value::text("hello")).await.expect("set");
    let err = text.meta_pointer().expect_err("not a pointer");
    assert!(err.to_string().contains("is not a meta-tuple"), "{err}");
    space.shutdown().await;
}

#[tokio::test]
async fn expiry_is_exact_on_virtual_time() {
    let clock = VirtualClock::default();
    let space = InProcessSpace::new(Arc::new(clock.clone()));
    let a = space.join(peis("a"), PeisOptions::default()).expect("join");
    let ttl = Duration::from_millis(100);
    a.set(key("v"), Value::text("x").with_time_to_live(ttl))
        .await
        .expect("set");
    clock.advance(ttl - Duration::from_nanos(1));
    assert!(a.get(peis("a"), key("v")).await.expect("get").is_some());
    clock.advance(Duration::from_nanos(1));
    assert_eq!(a.get(peis("a"), key("v")).await.expect("get"), None);
    space.shutdown().await;
}

#[tokio::test]
async fn a_vanished_peis_stays_present_until_its_lease_ends() {
    let clock = VirtualClock::default();
    let space = InProcessSpace::new(Arc::new(clock.clone()));
    let watcher = space
        .join(peis("watcher"), PeisOptions::default())
        .expect("join");
    let doomed = space
        .join(peis("doomed"), PeisOptions::default())
        .expect("join");
    let clone = doomed.clone();
    doomed.vanish();
    assert_eq!(
        clone.set(key("k"), Value::text("v")).await,
        Err(TupleError::Departed(peis("doomed")))
    );
    clock.advance(Duration::from_millis(1999));
    assert_eq!(
        watcher.peers().await.expect("peers"),
        vec![peis("doomed"), peis("watcher")]
    );
    assert!(matches!(
        space.join(peis("doomed"), PeisOptions::default()),
        Err(TupleError::AlreadyPresent(_))
    ));
    let mut presence = watcher.subscribe_presence().await.expect("subscribe");
    clock.advance(Duration::from_millis(1));
    crate::conformance::wait_presence(
        &mut presence,
        &PresenceEvent::Left(peis("doomed")),
        Duration::from_secs(5),
    )
    .await;
    space.shutdown().await;
}

#[tokio::test]
async fn dropping_every_clone_of_a_handle_leaves() {
    let space = InProcessSpace::new(Arc::new(VirtualClock::default()));
    let watcher = space
        .join(peis("watcher"), PeisOptions::default())
        .expect("join");
    let mut presence = watcher.subscribe_presence().await.expect("subscribe");
    let a = space.join(peis("a"), PeisOptions::default()).expect("join");
    let a2 = a.clone();
    drop(a);
    assert_eq!(watcher.peers().await.expect("peers").len(), 2);
    drop(a2);
    let p = Duration::from_secs(5);
    let mut events = Vec::new();
    for _ in 0..3 {
        events.push(crate::conformance::next_presence(&mut presence, p).await);
    }
    assert_eq!(
        events,
        [
            PresenceEvent::Joined(peis("watcher")),
            PresenceEvent::Joined(peis("a")),
            PresenceEvent::Left(peis("a"))
        ]
    );
    space.shutdown().await;
}

#[tokio::test]
async fn subscriptions_are_streams_an_event_loop_can_select_over() {
    let space = InProcessSpace::new(Arc::new(SystemClock));
    let a = space.join(peis("a"), PeisOptions::default()).expect("join");
    let mut statuses = a
        .subscribe(TuplePattern::parse("a:*.status").expect("pattern"))
        .await
        .expect("sub");
    let mut presence = a.subscribe_presence().await.expect("sub");
    assert_eq!(
        presence.next().await,
        Some(PresenceEvent::Joined(peis("a")))
    );
    assert!(statuses.try_next().is_none());
    a.set(key("l1.status"), Value::text("running"))
        .await
        .expect("set");
    let event = tokio::select! {
        e = statuses.next() => e,
        p = presence.next() => panic!("unexpected presence {p:?}"),
    };
    assert!(matches!(event, Some(TupleEvent::Changed(t)) if t.text() == Ok("running")));
    // Through the Stream trait as well.
    a.set(key("l1.status"), Value::text("done"))
        .await
        .expect("set");
    let polled = std::future::poll_fn(|cx| {
        futures_core::Stream::poll_next(std::pin::Pin::new(&mut statuses), cx)
    })
    .await;
    assert!(matches!(polled, Some(TupleEvent::Changed(t)) if t.seq == 2));
    drop(statuses);
    // A dropped subscription is unregistered, so later sets do not queue events for it.
    a.set(key("l1.status"), Value::text("again"))
        .await
        .expect("set");
    let mut fresh = a.subscribe(TuplePattern::everything()).await.expect("sub");
    assert!(
        matches!(next_event(&mut fresh, Duration::from_secs(1)).await, TupleEvent::Changed(t) if t.seq == 3)
    );
    space.shutdown().await;
}

/// `try_next` hands over every event that has arrived, however many, in one turn of the task:
/// tokio's cooperative budget (128 operations a turn) must not make a subscriber that receives
/// more than that per turn fall behind.
#[tokio::test]
async fn try_next_takes_every_event_that_arrived_in_one_turn() {
    let space = InProcessSpace::new(Arc::new(VirtualClock::default()));
    let writer = space
        .join(PeisId::new("world").expect("name"), PeisOptions::default())
        .expect("join");
    let reader = space
        .join(PeisId::new("camera").expect("name"), PeisOptions::default())
        .expect("join");
    let mut poses = reader
        .subscribe(TuplePattern::parse("world:**").expect("pattern"))
        .await
        .expect("subscribe");
    for robot in 0..500 {
        let key = Key::new(&format!("robots.bot-{robot}.pose")).expect("key");
        writer.set(key, Value::text("1 2 0")).await.expect("set");
    }
    let mut taken = 0;
    while poses.try_next().is_some() {
        taken += 1;
    }
    assert_eq!(taken, 500);
    space.shutdown().await;
}

// A subscription to one key of one owner (kept apart, so that a change of another key passes it
// by) gets that key's changes and no other's, beside subscriptions to patterns of the same owner
// and of any owner; once dropped it gets nothing, and the others still do.
#[tokio::test]
async fn a_subscription_to_one_key_gets_that_key_alone() {
    let space = InProcessSpace::new(Arc::new(VirtualClock::default()));
    let world = space
        .join(peis("world"), PeisOptions::default())
        .expect("join");
    let robot = space
        .join(peis("bot-1"), PeisOptions::default())
        .expect("join");
    let subscribe = |pattern: &str| {
        let robot = robot.clone();
        let pattern = TuplePattern::parse(pattern).expect("pattern");
        async move { robot.subscribe(pattern).await.expect("subscribe") }
    };
    let mut anything = subscribe("*:**").await;
    let mut mine = subscribe("world:robots.bot-1.pose").await;
    let mut the_world = subscribe("world:robots.*.pose").await;
    let mut again = subscribe("world:robots.bot-1.pose").await;
    let set = |k: &'static str| {
        let world = world.clone();
        async move { world.set(key(k), Value::text("1 2 0")).await.expect("set") }
    };
    set("robots.bot-2.pose").await;
    set("robots.bot-1.pose").await;
    let keys = |sub: &mut crate::Subscription| {
        let mut keys = Vec::new();
        while let Some(TupleEvent::Changed(t)) = sub.try_next() {
            keys.push(t.key.to_string());
        }
        keys
    };
    assert_eq!(keys(&mut mine), ["robots.bot-1.pose"]);
    assert_eq!(keys(&mut again), ["robots.bot-1.pose"]);
    assert_eq!(
        keys(&mut the_world),
        ["robots.bot-2.pose", "robots.bot-1.pose"]
    );
    assert_eq!(
        keys(&mut anything),
        ["robots.bot-2.pose", "robots.bot-1.pose"]
    );
    assert!(world.is_read(&key("robots.bot-1.pose")));
    drop(mine);
    drop(the_world);
    drop(anything);
    set("robots.bot-1.pose").await;
    assert_eq!(keys(&mut again), ["robots.bot-1.pose"]);
    drop(again);
    set("robots.bot-1.pose").await;
    assert!(!world.is_read(&key("robots.bot-1.pose")));
    space.shutdown().await;
}

proptest::proptest! {
    /// A pattern matches what walking its segments matches, whatever its last segment (the
    /// pattern tells keys that end otherwise at once).
    #[test]
    fn a_pattern_matches_what_its_segments_match(
        pattern in proptest::collection::vec(proptest::sample::select(vec!["a", "b", "*", "**"]), 1..5),
        key_segments in proptest::collection::vec(proptest::sample::select(vec!["a", "b", "c"]), 1..6),
    ) {
        let p = KeyPattern::new(&pattern.join(".")).expect("valid pattern");
        let k = key(&key_segments.join("."));
        // Walking: each `**` any run of segments, each `*` one, anything else itself.
        fn walk(p: &[&str], k: &[&str]) -> bool {
            match (p.first(), k.first()) {
                (None, None) => true,
                (Some(&"**"), _) => walk(&p[1..], k) || (!k.is_empty() && walk(p, &k[1..])),
                (Some(&"*"), Some(_)) => walk(&p[1..], &k[1..]),
                (Some(s), Some(t)) => s == t && walk(&p[1..], &k[1..]),
                _ => false,
            }
        }
        proptest::prop_assert_eq!(p.matches(&k), walk(&pattern, &key_segments), "{} vs {}", pattern.join("."), k);
    }
}
