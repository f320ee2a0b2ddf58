//! Tests of the Zenoh tuple space: the conformance suite over several sessions on 127.0.0.1, a separate
//! PEIS process that vanishes, interop with stock Zenoh clients, malformed samples, and the wire format.

use std::io::BufRead;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use ecology_tuples::conformance::{Harness, next_event, until, wait_presence};
use ecology_tuples::{
    Key, KeyPattern, Mimetype, PeisId, PeisOptions, PresenceEvent, PresenceSubscription,
    RemovalReason, Timestamp, TupleError, TupleEvent, TuplePattern, TupleSpace, Value,
    VirtualClock,
};
use ecology_zenoh::wire::{self, Metadata, WireError};
use ecology_zenoh::{ZenohOptions, ZenohPeis};

const PATIENCE: Duration = Duration::from_secs(10);

fn free_endpoint() -> String {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("bind 127.0.0.1:0");
    let port = listener.local_addr().expect("local address").port();
    format!("tcp/127.0.0.1:{port}")
}

fn peis(p: &str) -> PeisId {
    PeisId::new(p).expect("valid name")
}

fn key(k: &str) -> Key {
    Key::new(k).expect("valid key")
}

/// A PEIS in a separate OS process; killed when dropped, so a failing test leaves no process behind.
struct PeerProcess {
    child: Child,
}

impl PeerProcess {
    fn spawn(
        name: &str,
        listen: &str,
        connect: &[String],
        lease: Duration,
        tuples: &[&str],
    ) -> Self {
        let mut command = Command::new(env!("CARGO_BIN_EXE_ecology-zenoh-peer"));
        command.args(["--name", name, "--listen", listen]);
        for endpoint in connect {
            command.args(["--connect", endpoint]);
        }
        command.args(["--lease-ms", &lease.as_millis().to_string()]);
        command.args(tuples);
        let child = command
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect("spawn ecology-zenoh-peer");
        Self { child }
    }

    /// Waits for the process to print `ready`.
    async fn ready(&mut self) {
        let stdout = self.child.stdout.take().expect("piped stdout");
        let line = tokio::time::timeout(
            PATIENCE,
            tokio::task::spawn_blocking(move || {
                let mut line = String::new();
                std::io::BufReader::new(stdout)
                    .read_line(&mut line)
                    .map(|_| line)
            }),
        )
        .await
        .expect("peer ready in time")
        .expect("reader task")
        .expect("read peer stdout");
        assert_eq!(line.trim(), "ready");
    }

    /// Freezes the process: its sockets stay open but it sends nothing, as when a network is lost.
    fn freeze(&self) {
        let status = Command::new("kill")
            .args(["-STOP", &self.child.id().to_string()])
            .status()
            .expect("run kill");
        assert!(status.success());
    }
}

impl Drop for PeerProcess {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Runs every PEIS as its own Zenoh session on 127.0.0.1, connected in a full mesh, on one virtual clock.
struct ZenohHarness {
    clock: VirtualClock,
    members: Vec<Member>,
    processes: Vec<PeerProcess>,
}

struct Member {
    space: ZenohPeis,
    endpoint: String,
    presence: PresenceSubscription,
}

impl ZenohHarness {
    fn new() -> Self {
        Self {
            clock: VirtualClock::default(),
            members: Vec::new(),
            processes: Vec::new(),
        }
    }

    /// The endpoint a newcomer dials: the first member's; gossip completes the mesh.
    fn endpoints(&self) -> Vec<String> {
        self.members
            .iter()
            .take(1)
            .map(|m| m.endpoint.clone())
            .collect()
    }

    /// Waits until every member sees `name` present.
    async fn everyone_sees(&mut self, name: &PeisId) {
        for member in &mut self.members {
            wait_presence(
                &mut member.presence,
                &PresenceEvent::Joined(name.clone()),
                PATIENCE,
            )
            .await;
        }
    }
}

impl Harness for ZenohHarness {
    type Space = ZenohPeis;
    type Vanishing = PeerProcess;

    async fn join(&mut self, name: &str, options: PeisOptions) -> ZenohPeis {
        let endpoint = free_endpoint();
        let mut zenoh_options = ZenohOptions::new(peis(name));
        zenoh_options.peis = options;
        zenoh_options.listen = vec![endpoint.clone()];
        zenoh_options.connect = self.endpoints();
        zenoh_options.clock = Arc::new(self.clock.clone());
        let space = ZenohPeis::open(zenoh_options).await.expect("open session");
        let mut presence = space.subscribe_presence().await.expect("presence");
        let mut unseen: std::collections::BTreeSet<PeisId> = self
            .members
            .iter()
            .map(|m| m.space.peis().clone())
            .collect();
        let waited = tokio::time::timeout(PATIENCE, async {
            while !unseen.is_empty() {
                match presence.next().await {
                    Some(PresenceEvent::Joined(id)) => {
                        unseen.remove(&id);
                    }
                    Some(PresenceEvent::Left(_)) => {}
                    None => return,
                }
            }
        });
        if waited.await.is_err() {
            panic!(
                "{name} does not see every member join; it sees {:?}",
                space.peers().await
            );
        }
        self.everyone_sees(&peis(name)).await;
        self.members.push(Member {
            space: space.clone(),
            endpoint,
            presence,
        });
        space
    }

    async fn leave(&mut self, space: ZenohPeis) {
        self.members.retain(|m| m.space.peis() != space.peis());
        space.close().await;
    }

    async fn join_vanishing(&mut self, name: &str, options: PeisOptions) -> PeerProcess {
        let mut process = PeerProcess::spawn(
            name,
            &free_endpoint(),
            &self.endpoints(),
            options.lease,
            &[],
        );
        process.ready().await;
        self.everyone_sees(&peis(name)).await;
        process
    }

    async fn vanish(&mut self, process: PeerProcess) {
        process.freeze();
        self.processes.push(process);
    }

    fn advance(&self, d: Duration) {
        self.clock.advance(d);
    }

    fn leases_on_virtual_time(&self) -> bool {
        false
    }

    fn patience(&self) -> Duration {
        PATIENCE
    }

    async fn finish(self) {
        for member in self.members {
            member.space.close().await;
        }
        drop(self.processes);
    }
}

mod conformance {
    use super::ZenohHarness;
    ecology_tuples::conformance_tests!(ZenohHarness::new());
}

/// A raw Zenoh session (a stock client) connected to `endpoint`.
async fn stock_client(endpoint: &str) -> zenoh::Session {
    let mut config = zenoh::Config::default();
    config
        .insert_json5("connect/endpoints", &format!("[\"{endpoint}\"]"))
        .expect("config");
    config
        .insert_json5("listen/endpoints", &format!("[\"{}\"]", free_endpoint()))
        .expect("config");
    config
        .insert_json5("scouting/multicast/enabled", "false")
        .expect("config");
    zenoh::open(config).await.expect("open stock client")
}

async fn lone_peis(name: &str, options: PeisOptions) -> (ZenohPeis, String) {
    let endpoint = free_endpoint();
    let mut zenoh_options = ZenohOptions::new(peis(name));
    zenoh_options.peis = options;
    zenoh_options.listen = vec![endpoint.clone()];
    (
        ZenohPeis::open(zenoh_options).await.expect("open"),
        endpoint,
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_plain_put_is_a_tuple_and_malformed_samples_are_counted() {
    let mut options = PeisOptions::default();
    options.limits.max_value_bytes = 64;
    let (watcher, endpoint) = lone_peis("watcher", options).await;
    let mut sub = watcher
        .subscribe(TuplePattern::everything())
        .await
        .expect("subscribe");
    let client = stock_client(&endpoint).await;

    client
        .put("peis/robot/sensor/temperature", "21.5")
        .await
        .expect("put");
    match next_event(&mut sub, PATIENCE).await {
        TupleEvent::Changed(t) => {
            assert_eq!(
                (t.owner.as_str(), t.key.as_str()),
                ("robot", "sensor.temperature")
            );
            assert_eq!((t.text(), t.seq), (Ok("21.5"), 0));
            assert_eq!(t.mimetype.as_str(), Mimetype::OCTET_STREAM);
        }
        other => panic!("unexpected {other:?}"),
    }
    client
        .put("peis/robot/sensor/label", "kitchen")
        .encoding(zenoh::bytes::Encoding::TEXT_PLAIN)
        .await
        .expect("put");
    match next_event(&mut sub, PATIENCE).await {
        TupleEvent::Changed(t) => assert_eq!(t.mimetype.as_str(), "text/plain"),
        other => panic!("unexpected {other:?}"),
    }

    assert_eq!(watcher.malformed_samples(), 0);
    client.put("peis/robot", "no key").await.expect("put");
    client.put("peis/ro-bot/a/@x", "bad key").await.ok();
    client
        .put("peis/robot/x", "bad attachment")
        .attachment(vec![9u8, 9])
        .await
        .expect("put");
    client
        .put("peis/robot/x", vec![0u8; 65])
        .await
        .expect("put");
    let mut truncated = Metadata::of_request(&Value::text("x")).encode();
    truncated.pop();
    client
        .put("peis/robot/x", "truncated")
        .attachment(truncated)
        .await
        .expect("put");
    // A key has one spelling, one segment per chunk: `sensor/temperature`, never `sensor.temperature`.
    client
        .put("peis/robot/sensor.temperature", "99")
        .await
        .expect("put");
    client.put("peis/robot/after", "valid").await.expect("put");
    match next_event(&mut sub, PATIENCE).await {
        TupleEvent::Changed(t) => assert_eq!((t.key.as_str(), t.text()), ("after", Ok("valid"))),
        other => panic!("unexpected {other:?}"),
    }
    assert_eq!(watcher.malformed_samples(), 5);
    client.delete("peis/robot/after").await.expect("delete");
    assert!(matches!(
        next_event(&mut sub, PATIENCE).await,
        TupleEvent::Removed {
            seq: 0,
            reason: RemovalReason::Deleted,
            ..
        }
    ));
    client.close().await.expect("close");
    watcher.close().await;
}

/// A PEIS's subscription to its own tuples hears its own writes alone, and is not declared to the
/// network (a router of a thousand PEIS matched four such declarations of each against every key
/// it knew): another session's put on one of its keys, which a subscription to every PEIS does
/// hear, is not taken for its tuple.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_subscription_to_its_own_tuples_hears_only_its_own_writes() {
    let (watcher, endpoint) = lone_peis("watcher", PeisOptions::default()).await;
    let pattern = |text: &str| TuplePattern::parse(text).expect("pattern");
    let mut own = watcher
        .subscribe(pattern("watcher:*"))
        .await
        .expect("subscribe");
    let mut every = watcher.subscribe(pattern("*:*")).await.expect("subscribe");
    let client = stock_client(&endpoint).await;
    // Put again until it is heard at all: the first may go out before the link is up.
    let mut heard = false;
    for _ in 0..50 {
        client
            .put("peis/watcher/spoof", "not mine")
            .await
            .expect("put");
        // Its own tuples (the contract) come too.
        while let Ok(Some(event)) =
            tokio::time::timeout(Duration::from_millis(200), every.next()).await
        {
            heard |= matches!(event, TupleEvent::Changed(t) if t.key.as_str() == "spoof");
        }
        if heard {
            break;
        }
    }
    assert!(heard, "the subscription to every PEIS hears the put");
    watcher
        .set(key("mine"), Value::text("written here"))
        .await
        .expect("set");
    match next_event(&mut own, PATIENCE).await {
        TupleEvent::Changed(t) => assert_eq!(
            (t.key.as_str(), t.text()),
            ("mine", Ok("written here")),
            "the first event of its own subscription is its own write"
        ),
        other => panic!("unexpected {other:?}"),
    }
    client.close().await.expect("close");
    watcher.close().await;
}

/// An owner that never answers a remote set is out of reach, not refusing: Zenoh's own
/// "Timeout" error reply is not the owner's reason.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_remote_set_nobody_answers_in_time_is_unanswered_not_refused() {
    let endpoint = free_endpoint();
    let mut options = ZenohOptions::new(peis("executive"));
    options.listen = vec![endpoint.clone()];
    options.query_timeout = Duration::from_millis(300);
    let executive = ZenohPeis::open(options).await.expect("open");
    // A stock client that takes remote sets to "ghost" and keeps them, unanswered.
    let client = stock_client(&endpoint).await;
    let held = Arc::new(std::sync::Mutex::new(Vec::new()));
    let keep = held.clone();
    let _queryable = client
        .declare_queryable(wire::remote_set_key_expr(&peis("ghost"), &key("c1.params")))
        .callback(move |query| keep.lock().expect("lock").push(query))
        .await
        .expect("queryable");
    let mut asked = false;
    for _ in 0..50 {
        let result = executive
            .set_remote(peis("ghost"), key("c1.params"), Value::text("(cam)"))
            .await;
        // Until the queryable is known, there is no one to ask at all.
        if !held.lock().expect("lock").is_empty() {
            match result {
                Err(TupleError::OwnerUnreachable { owner, .. }) => assert_eq!(owner, peis("ghost")),
                other => panic!("a set that timed out reads as {other:?}"),
            }
            asked = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(asked, "the stock client's queryable was never asked");
    client.close().await.expect("close");
    executive.close().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stock_client_can_get_and_remote_set() {
    let options = PeisOptions {
        remote_set: ecology_tuples::RemoteSetPolicy::allow([KeyPattern::new(
            "components.*.reqState",
        )
        .expect("pattern")]),
        ..PeisOptions::default()
    };
    let (astrid, endpoint) = lone_peis("astrid", options).await;
    astrid
        .set(
            key("components.l1.cost"),
            Value::text("100").with_ts_user(Timestamp(7)),
        )
        .await
        .expect("set");
    let client = stock_client(&endpoint).await;

    let replies = client.get("peis/astrid/components/**").await.expect("get");
    let reply = replies.recv_async().await.expect("one reply");
    let sample = reply.result().expect("a sample");
    assert_eq!(sample.key_expr().as_str(), "peis/astrid/components/l1/cost");
    assert_eq!(&*sample.payload().to_bytes(), b"100");
    let meta =
        Metadata::decode(&sample.attachment().expect("attachment").to_bytes()).expect("metadata");
    assert_eq!(
        (meta.seq, meta.ts_user, meta.mimetype.as_str()),
        (1, Some(Timestamp(7)), "text/plain")
    );

    let replies = client
        .get("peis/astrid/@set/components/l1/reqState")
        .payload("on")
        .await
        .expect("remote set");
    let reply = replies.recv_async().await.expect("one reply");
    assert!(reply.result().is_ok(), "{:?}", reply.result().err());
    let applied = astrid
        .get(peis("astrid"), key("components.l1.reqState"))
        .await
        .expect("get")
        .expect("applied");
    assert_eq!((applied.text(), applied.seq), (Ok("on"), 1));

    // A key has one spelling, one segment per chunk: any other is refused, whatever it would
    // name, and nothing is written.
    for spelling in [
        "peis/astrid/@set/components/l1.reqState",
        "peis/astrid/@set/components.l1/reqState",
        "peis/astrid/@set/components.l1.reqState",
        "peis/astrid/@by/exec/components/l1.reqState",
    ] {
        let replies = client
            .get(spelling)
            .payload("off")
            .await
            .expect("remote set");
        let reply = replies.recv_async().await.expect("one reply");
        let err = reply.result().expect_err(spelling);
        let reason = String::from_utf8_lossy(&err.payload().to_bytes()).into_owned();
        assert!(reason.contains("one exact key"), "{spelling}: {reason}");
    }
    let still = astrid
        .get(peis("astrid"), key("components.l1.reqState"))
        .await
        .expect("get")
        .expect("applied");
    assert_eq!((still.text(), still.seq), (Ok("on"), 1));

    let replies = client
        .get("peis/astrid/@set/secret")
        .payload("x")
        .await
        .expect("remote set");
    let reply = replies.recv_async().await.expect("one reply");
    let err = reply.result().expect_err("refused");
    let reason = String::from_utf8_lossy(&err.payload().to_bytes()).into_owned();
    assert!(reason.contains("not allowed"), "{reason}");
    client.close().await.expect("close");
    astrid.close().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_name_cannot_join_twice_and_a_config_file_is_honoured() {
    let (first, endpoint) = lone_peis("astrid", PeisOptions::default()).await;
    let dir = std::env::temp_dir().join(format!("ecology-zenoh-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let file = dir.join("zenoh.json5");
    std::fs::write(
        &file,
        format!(
            "{{ mode: \"peer\", connect: {{ endpoints: [\"{endpoint}\"] }}, listen: {{ endpoints: [\"{}\"] }}, scouting: {{ multicast: {{ enabled: false }} }} }}",
            free_endpoint()
        ),
    )
    .expect("write config");
    let mut options = ZenohOptions::new(peis("astrid"));
    options.zenoh_config = Some(file.clone());
    let second = ZenohPeis::open(options).await;
    assert!(
        matches!(
            second,
            Err(ecology_zenoh::ZenohError::Space(
                TupleError::AlreadyPresent(_)
            ))
        ),
        "{second:?}"
    );
    let mut options = ZenohOptions::new(peis("pippi"));
    options.zenoh_config = Some(file);
    let pippi = ZenohPeis::open(options).await.expect("open from file");
    assert_eq!(
        pippi.peers().await.expect("peers"),
        vec![peis("astrid"), peis("pippi")]
    );
    let mut bad = ZenohOptions::new(peis("bad"));
    bad.zenoh_config = Some(dir.join("missing.json5"));
    assert!(matches!(
        ZenohPeis::open(bad).await,
        Err(ecology_zenoh::ZenohError::Config { .. })
    ));
    pippi.close().await;
    first.close().await;
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn tuples_map_to_key_expressions() {
    assert_eq!(
        wire::tuple_key_expr(&peis("astrid"), &key("components.l1.status")),
        "peis/astrid/components/l1/status"
    );
    assert_eq!(
        wire::parse_tuple_key_expr("peis/astrid/components/l1/status"),
        Ok((peis("astrid"), key("components.l1.status")))
    );
    for bad in [
        "peis/astrid",
        "peis",
        "other/astrid/x",
        "peis/a.b/x",
        "peis/astrid/a//b",
        "peis/astrid/@set/x",
    ] {
        assert!(wire::parse_tuple_key_expr(bad).is_err(), "{bad}");
    }
    assert_eq!(
        wire::remote_set_key_expr(&peis("astrid"), &key("components.l1.reqState")),
        "peis/astrid/@set/components/l1/reqState"
    );
    let by = wire::requested_set_key_expr(&peis("astrid"), &peis("exec-a"), &key("l1.params"));
    assert_eq!(by, "peis/astrid/@by/exec-a/l1/params");
    assert_eq!(
        wire::parse_remote_set_key_expr(&peis("astrid"), &by),
        Ok((Some(peis("exec-a")), key("l1.params")))
    );
    assert_eq!(
        wire::parse_remote_set_key_expr(&peis("astrid"), "peis/astrid/@set/l1/params"),
        Ok((None, key("l1.params")))
    );
    for bad in [
        "peis/astrid/@by/l1",
        "peis/astrid/@by/a.b/l1/params",
        "peis/astridx/@set/l1/params",
        "peis/astrid/l1/params",
    ] {
        assert!(
            wire::parse_remote_set_key_expr(&peis("astrid"), bad).is_err(),
            "{bad}"
        );
    }
    assert_eq!(wire::alive_key_expr(&peis("astrid")), "peis/astrid/@alive");
    assert_eq!(
        wire::parse_alive_key_expr("peis/astrid/@alive"),
        Ok(peis("astrid"))
    );
    let pattern = |p: &str| wire::pattern_key_expr(&TuplePattern::parse(p).expect("valid"));
    assert_eq!(
        pattern("*:components.*.status"),
        "peis/*/components/*/status"
    );
    assert_eq!(pattern("astrid:**"), "peis/astrid/**");
    assert_eq!(pattern("a:x.**.*"), "peis/a/x/*/**");
    for p in [
        "*:components.*.status",
        "astrid:**",
        "a:x.**.*.y.**.*",
        "a:**.*",
    ] {
        let ke = pattern(p);
        assert!(zenoh::key_expr::KeyExpr::new(ke.clone()).is_ok(), "{ke}");
        assert!(
            zenoh::key_expr::keyexpr::new(&ke).is_ok_and(|k| k.as_str() == ke),
            "{ke} is canonical"
        );
    }
}

#[test]
fn metadata_round_trips_and_malformed_attachments_are_rejected() {
    let tuple = ecology_tuples::Tuple {
        owner: peis("astrid"),
        key: key("x"),
        data: bytes::Bytes::from_static(b"v"),
        mimetype: Mimetype::new("application/json").expect("valid"),
        ts_write: Timestamp(1),
        ts_user: Some(Timestamp(2)),
        expiry: Some(Timestamp(3)),
        seq: 42,
        epoch: 7,
        creator: Some(peis("executive")),
    };
    let encoded = Metadata::of_tuple(&tuple).encode();
    assert_eq!(
        encoded.len(),
        2 + 8 * 5 + 1 + "application/json".len() + 1 + "executive".len()
    );
    assert_eq!(&encoded[..2], &[wire::VERSION, 0b1_1011]);
    assert_eq!(&encoded[34..42], &7u64.to_le_bytes());
    assert_eq!(&encoded[2..10], &42u64.to_le_bytes());
    let decoded = Metadata::decode(&encoded).expect("decodes");
    assert_eq!(
        decoded
            .clone()
            .into_tuple(peis("astrid"), key("x"), tuple.data.clone()),
        tuple
    );

    let minimal = Metadata::of_removal(5, 0, Timestamp(9), true).encode();
    assert_eq!(minimal.len(), 2 + 16 + 1 + Mimetype::OCTET_STREAM.len());
    assert!(Metadata::decode(&minimal).is_ok_and(|m| m.expired && m.seq == 5));

    // From version 2 on, what follows the known fields is ignored, and a later version that only
    // appends reads as this one; version 1 has nothing after its fields (the corpus has the rest).
    let mut appended = encoded.clone();
    appended.push(0);
    assert_eq!(Metadata::decode(&appended), Ok(decoded.clone()));
    appended[0] = 3;
    assert_eq!(Metadata::decode(&appended), Ok(decoded.clone()));
    let mut trailing = minimal.clone();
    trailing.push(0);
    let mut version = encoded.clone();
    version[0] = 0;
    let mut bad_mime = encoded.clone();
    bad_mime[2 + 8 * 5 + 1] = 0xff;
    let mut bad_creator = encoded.clone();
    let last = bad_creator.len() - 1;
    bad_creator[last] = 0xff;
    for (bytes, expected) in [
        (
            &encoded[..encoded.len() - 1],
            WireError::Attachment("too short"),
        ),
        (&trailing[..], WireError::Attachment("trailing bytes")),
        (&version[..], WireError::Attachment("unknown version")),
        (
            &bad_mime[..],
            WireError::Attachment("mimetype is not UTF-8"),
        ),
        (
            &bad_creator[..],
            WireError::Attachment("creator is not UTF-8"),
        ),
        (&[][..], WireError::Attachment("too short")),
    ] {
        assert_eq!(Metadata::decode(bytes), Err(expected));
    }
}

/// A bundle of held tuples, byte for byte as `docs/network.md` documents it, read back whole;
/// every way it can be cut short or bent is an error, never a panic or a tuple made up.
#[test]
fn a_bundle_of_held_tuples_reads_back_and_refuses_what_is_malformed() {
    let tuples = [
        wire::Bundled {
            key_expr: "peis/astrid/components/s1/type",
            encoding: "zenoh/bytes",
            payload: b"self-loc",
            attachment: Some(&[1, 0, 7]),
        },
        wire::Bundled {
            key_expr: "peis/hsm/ca1/status",
            encoding: "text/plain",
            payload: b"",
            attachment: None,
        },
    ];
    let bytes = wire::encode_bundle(tuples, ["exec"]);
    let mut expected = vec![1u8];
    expected.extend_from_slice(&2u32.to_le_bytes());
    expected.extend_from_slice(&30u16.to_le_bytes());
    expected.extend_from_slice(b"peis/astrid/components/s1/type");
    expected.push(11);
    expected.extend_from_slice(b"zenoh/bytes");
    expected.extend_from_slice(&8u32.to_le_bytes());
    expected.extend_from_slice(b"self-loc");
    expected.extend_from_slice(&3u32.to_le_bytes());
    expected.extend_from_slice(&[1, 0, 7]);
    expected.extend_from_slice(&19u16.to_le_bytes());
    expected.extend_from_slice(b"peis/hsm/ca1/status");
    expected.push(10);
    expected.extend_from_slice(b"text/plain");
    expected.extend_from_slice(&0u32.to_le_bytes());
    expected.extend_from_slice(&u32::MAX.to_le_bytes());
    expected.push(4);
    expected.extend_from_slice(b"exec");
    assert_eq!(bytes, expected);
    let whole = wire::Bundle {
        tuples: tuples.to_vec(),
        silent: vec!["exec"],
    };
    assert_eq!(wire::decode_bundle(&bytes), Ok(whole));
    assert_eq!(
        wire::decode_bundle(&wire::encode_bundle([], [])),
        Ok(wire::Bundle::default())
    );
    // Cut anywhere before the names, a bundle is too short; cut inside a name too.
    let names_at = bytes.len() - 5;
    for cut in (0..names_at).chain([names_at + 1, names_at + 3]) {
        assert_eq!(
            wire::decode_bundle(&bytes[..cut]),
            Err(WireError::Bundle("too short")),
            "cut at {cut}"
        );
    }
    let mut version = bytes.clone();
    version[0] = 2;
    let mut not_text = bytes.clone();
    not_text[7] = 0xff;
    let mut more = bytes.clone();
    more[1] = 3;
    for (bytes, expected) in [
        (&version[..], WireError::Bundle("unknown version")),
        (&not_text[..], WireError::Bundle("text that is not UTF-8")),
        // A third tuple promised: the name after the second is read as one, and falls short.
        (&more[..], WireError::Bundle("too short")),
    ] {
        assert_eq!(wire::decode_bundle(bytes), Err(expected));
    }
}

/// One entry of the attachment corpus (`tests/corpus/attachments.txt`): its name and fields.
struct CorpusEntry {
    name: String,
    fields: std::collections::BTreeMap<String, String>,
}

/// The corpus of attachments written to each published version, and malformed ones.
fn corpus() -> Vec<CorpusEntry> {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus/attachments.txt");
    let text = std::fs::read_to_string(&path).expect("the corpus");
    let mut entries: Vec<CorpusEntry> = Vec::new();
    for line in text.lines().map(str::trim) {
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            entries.push(CorpusEntry {
                name: name.to_owned(),
                fields: std::collections::BTreeMap::new(),
            });
            continue;
        }
        let (field, value) = line.split_once('=').expect("`key = value`");
        let entry = entries.last_mut().expect("a field inside an entry");
        entry
            .fields
            .insert(field.trim().to_owned(), value.trim().to_owned());
    }
    entries
}

fn unhex(text: &str) -> Vec<u8> {
    let digits: Vec<u8> = text.bytes().filter(|b| !b.is_ascii_whitespace()).collect();
    digits
        .chunks(2)
        .map(|pair| u8::from_str_radix(std::str::from_utf8(pair).expect("ASCII"), 16).expect("hex"))
        .collect()
}

/// The metadata an entry of the corpus says a reader reads.
fn corpus_metadata(entry: &CorpusEntry) -> Metadata {
    let field = |name: &str| {
        entry
            .fields
            .get(name)
            .unwrap_or_else(|| panic!("{}: no {name}", entry.name))
            .as_str()
    };
    let number = |name: &str| field(name).parse::<u64>().expect("a number");
    let optional = |name: &str| (field(name) != "-").then(|| number(name));
    Metadata {
        seq: number("seq"),
        ts_write: Timestamp(number("ts_write")),
        ts_user: optional("ts_user").map(Timestamp),
        expiry: optional("expiry"),
        expired: field("expired") == "yes",
        epoch: number("epoch"),
        mimetype: Mimetype::new(field("mimetype")).expect("a valid mimetype"),
        creator: (field("creator") != "-").then(|| peis(field("creator"))),
    }
}

/// Every attachment of the corpus reads as it says (or is refused for its reason), and the
/// writer writes the entries marked `encodes` byte for byte: version 1 without a creator, 2 with.
#[test]
fn the_attachment_corpus_of_every_published_version_is_read_and_written() {
    let entries = corpus();
    assert!(entries.len() >= 20, "{} entries", entries.len());
    let mut encoded = 0;
    for entry in &entries {
        let bytes = unhex(&entry.fields["hex"]);
        let decoded = Metadata::decode(&bytes);
        if let Some(reason) = entry.fields.get("refused") {
            assert_eq!(
                decoded.map_err(|e| e.to_string()),
                Err(format!("malformed attachment: {reason}")),
                "{}",
                entry.name
            );
            continue;
        }
        let expected = corpus_metadata(entry);
        assert_eq!(decoded.as_ref(), Ok(&expected), "{}", entry.name);
        if entry.fields["encodes"] == "yes" {
            assert_eq!(expected.encode(), bytes, "{}", entry.name);
            encoded += 1;
        }
    }
    assert!(encoded >= 6, "{encoded} entries written byte for byte");
}

/// The Python example's reader (`examples/python/ecology_peis.py`) reads the same corpus the same
/// way, by `examples/python/check_corpus.py`; skipped when no Python with zenoh is at hand.
#[test]
fn the_python_example_reads_the_attachment_corpus() {
    let python = std::env::var("ECOLOGY_PYTHON").unwrap_or_else(|_| "python3".to_owned());
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let has_zenoh = Command::new(&python)
        .args(["-c", "import zenoh"])
        .status()
        .is_ok_and(|s| s.success());
    if !has_zenoh {
        println!(
            "skipped: no Python with the eclipse-zenoh package at `{python}` (set ECOLOGY_PYTHON)"
        );
        return;
    }
    let out = Command::new(&python)
        .arg(root.join("examples/python/check_corpus.py"))
        .arg(root.join("crates/ecology-zenoh/tests/corpus/attachments.txt"))
        .output()
        .expect("run check_corpus.py");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let entries = corpus().len();
    assert!(text.contains(&format!("{entries} entries read")), "{text}");
}

/// A keys directory in a fresh temporary folder with the given members, removed when dropped.
struct TempKeys {
    dir: std::path::PathBuf,
    keys: ecology_zenoh::security::KeysDir,
}

impl TempKeys {
    fn new(tag: &str, members: &[(&str, ecology_zenoh::security::Role)]) -> Self {
        let dir = std::env::temp_dir().join(format!(
            "ecology-zenoh-{tag}-{}-{:?}",
            std::process::id(),
            std::time::SystemTime::now()
        ));
        let mut keys = ecology_zenoh::security::KeysDir::init(&dir).expect("init keys");
        for (name, role) in members {
            keys.add(peis(name), *role).expect("add member");
        }
        Self { dir, keys }
    }

    /// Lets member `who` remote-set hsm's keys matching `pattern`, in its own name.
    fn grant_on_hsm(&mut self, who: &str, pattern: &str) {
        let pattern = ecology_zenoh::security::GrantPattern::new(pattern).expect("pattern");
        self.keys
            .grant(peis(who), Some(peis("hsm")), vec![pattern])
            .expect("grant");
    }

    fn options(&self, name: &str, listen: &str, connect: &[String]) -> ZenohOptions {
        let mut options = ZenohOptions::new(peis(name));
        options.listen = vec![listen.to_owned()];
        options.connect = connect.to_vec();
        options.security = ecology_zenoh::Security::Authenticated(Box::new(
            self.keys.identity(&peis(name)).expect("identity"),
        ));
        options
    }
}

impl Drop for TempKeys {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// A QUIC endpoint on a UDP port free now: a port free for TCP may be a QUIC listener's already
/// (a PEIS of this test listened over UDP on the port the probe handed to the next).
fn free_quic_endpoint() -> String {
    let socket = std::net::UdpSocket::bind("127.0.0.1:0").expect("bind 127.0.0.1:0");
    let port = socket.local_addr().expect("local address").port();
    format!("quic/127.0.0.1:{port}")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn authenticated_members_talk_over_mutual_tls_and_only_the_executive_sets_remotely() {
    use ecology_zenoh::security::Role;
    let keys = TempKeys::new(
        "mtls",
        &[
            ("hsm", Role::Peis),
            ("executive", Role::Executive),
            ("pippi", Role::Peis),
            ("operator", Role::Peis),
        ],
    );
    let mut keys = keys;
    keys.grant_on_hsm("operator", "ca1.fault");
    let hsm_endpoint = free_quic_endpoint();
    let hsm = ZenohPeis::open(keys.options("hsm", &hsm_endpoint, &[]))
        .await
        .expect("hsm joins over TLS");
    hsm.set(key("ca1.status"), Value::text("running"))
        .await
        .expect("set");
    let executive = ZenohPeis::open(keys.options(
        "executive",
        &free_quic_endpoint(),
        std::slice::from_ref(&hsm_endpoint),
    ))
    .await
    .expect("executive joins over TLS");
    let pippi = ZenohPeis::open(keys.options(
        "pippi",
        &free_quic_endpoint(),
        std::slice::from_ref(&hsm_endpoint),
    ))
    .await
    .expect("pippi joins over TLS");

    // Reads work for every member, and presence is seen.
    let mut presence = pippi.subscribe_presence().await.expect("presence");
    wait_presence(&mut presence, &PresenceEvent::Joined(peis("hsm")), PATIENCE).await;
    let mut sub = pippi
        .subscribe(TuplePattern::exact(peis("hsm"), &key("ca1.status")))
        .await
        .expect("subscribe");
    match next_event(&mut sub, PATIENCE).await {
        TupleEvent::Changed(t) => assert_eq!(t.text(), Ok("running")),
        other => panic!("unexpected {other:?}"),
    }

    // The executive may switch a component on; pippi may not, and hsm's tuple stays as it was.
    let set = executive
        .set_remote(
            peis("hsm"),
            key("components.ca1.reqState"),
            Value::text("on"),
        )
        .await
        .expect("the executive's remote set is applied");
    assert_eq!(set.text(), Ok("on"));
    assert_eq!(
        set.creator,
        Some(peis("executive")),
        "the owner keeps who asked"
    );
    let refused = pippi
        .set_remote(
            peis("hsm"),
            key("components.ca1.reqState"),
            Value::text("off"),
        )
        .await;
    assert!(
        refused.is_err(),
        "pippi's remote set was applied: {refused:?}"
    );
    // A grant lets a member set a key in its own name.
    let operator = ZenohPeis::open(keys.options(
        "operator",
        &free_quic_endpoint(),
        std::slice::from_ref(&hsm_endpoint),
    ))
    .await
    .expect("operator joins over TLS");
    let fault = operator
        .set_remote(peis("hsm"), key("ca1.fault"), Value::text("stall"))
        .await
        .expect("a granted remote set is applied");
    assert_eq!(fault.creator, Some(peis("operator")));
    let refused = executive
        .set_remote(peis("hsm"), key("components.ca1.cost"), Value::text("0"))
        .await;
    assert!(
        refused.is_err(),
        "a key outside the executive's grant was set: {refused:?}"
    );
    let now = hsm
        .get(peis("hsm"), key("components.ca1.reqState"))
        .await
        .expect("get")
        .expect("present");
    assert_eq!(now.text(), Ok("on"));
    assert_eq!(now.creator, Some(peis("executive")));
    assert_eq!(
        hsm.get(peis("hsm"), key("components.ca1.cost"))
            .await
            .expect("get"),
        None
    );

    // A stock client without a certificate cannot reach hsm at all.
    let mut config = zenoh::Config::default();
    config
        .insert_json5("connect/endpoints", &format!("[\"{hsm_endpoint}\"]"))
        .expect("config");
    config
        .insert_json5("scouting/multicast/enabled", "false")
        .expect("config");
    config
        .insert_json5("connect/exit_on_failure", "true")
        .expect("config");
    config
        .insert_json5("connect/timeout_ms", "1000")
        .expect("config");
    assert!(
        zenoh::open(config).await.is_err(),
        "a client without a certificate opened a session with hsm"
    );

    // Plain TCP endpoints are refused with the fix in the message.
    let mut tcp = keys.options("pippi", &free_endpoint(), &[]);
    tcp.name = peis("pippi");
    match ZenohPeis::open(tcp).await {
        Err(e) => assert!(e.to_string().contains("write quic/127.0.0.1:"), "{e}"),
        Ok(_) => panic!("a tcp endpoint was accepted with keys"),
    }
    // Nor can a Zenoh configuration file undo the keys: a plain TCP endpoint or multicast
    // scouting there is refused too, saying why, and nothing is opened.
    let file = keys.dir.join("weak.json5");
    for (weakening, refusal) in [
        (
            format!(r#"{{ listen: {{ endpoints: ["{}"] }} }}"#, free_endpoint()),
            "every endpoint is QUIC",
        ),
        (
            format!(
                r#"{{ listen: {{ endpoints: {{ peer: ["{}"] }} }} }}"#,
                free_endpoint()
            ),
            "every endpoint is QUIC",
        ),
        (
            r#"{ scouting: { multicast: { enabled: true } } }"#.to_owned(),
            "multicast scouting stays off",
        ),
    ] {
        std::fs::write(&file, &weakening).expect("write the file");
        let mut weak = keys.options("pippi", &free_quic_endpoint(), &[]);
        weak.name = peis("pippi");
        weak.listen.clear();
        weak.zenoh_config = Some(file.clone());
        match ZenohPeis::open(weak).await {
            Err(e) => assert!(e.to_string().contains(refusal), "{weakening}: {e}"),
            Ok(_) => panic!("{weakening} was taken with keys"),
        }
    }
    for space in [pippi, executive, hsm] {
        space.close().await;
    }
}

/// The Python with the stock `eclipse-zenoh` package: `ECOLOGY_PYTHON` (set by `scripts/test`),
/// or `python3` if it can import zenoh; `None` (and the test says it is skipped) otherwise.
fn python_with_zenoh() -> Option<String> {
    let candidates = std::env::var("ECOLOGY_PYTHON")
        .into_iter()
        .chain(["python3".to_owned()]);
    for python in candidates {
        let ok = Command::new(&python)
            .args(["-c", "import zenoh"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
        if ok {
            return Some(python);
        }
    }
    eprintln!("skipped: no Python with the eclipse-zenoh package (scripts/test sets one up)");
    None
}

/// The attacker script as a process; killed when dropped.
struct Attacker {
    child: Child,
    lines: std::sync::mpsc::Receiver<String>,
}

impl Attacker {
    fn spawn(python: &str, args: &[String]) -> Self {
        let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/attacker.py");
        let mut child = Command::new(python)
            .arg(script)
            .args(args)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect("spawn the attacker");
        let stdout = child.stdout.take().expect("piped stdout");
        let (tx, lines) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in std::io::BufReader::new(stdout)
                .lines()
                .map_while(Result::ok)
            {
                if tx.send(line).is_err() {
                    return;
                }
            }
        });
        Self { child, lines }
    }

    /// The next line the attacker prints, within `patience`.
    async fn line(&self, patience: Duration) -> String {
        let deadline = std::time::Instant::now() + patience;
        loop {
            match self.lines.try_recv() {
                Ok(line) => return line,
                Err(std::sync::mpsc::TryRecvError::Empty)
                    if std::time::Instant::now() < deadline =>
                {
                    tokio::time::sleep(Duration::from_millis(20)).await;
                }
                Err(e) => panic!("no line from the attacker within {patience:?}: {e:?}"),
            }
        }
    }

    fn say(&mut self, text: &str) {
        use std::io::Write;
        let stdin = self.child.stdin.as_mut().expect("piped stdin");
        writeln!(stdin, "{text}").expect("write to the attacker");
    }
}

impl Drop for Attacker {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn number(report: &str, field: &str) -> u64 {
    let at = report
        .find(&format!("\"{field}\": "))
        .unwrap_or_else(|| panic!("no {field} in {report}"));
    report[at + field.len() + 4..]
        .chars()
        .take_while(char::is_ascii_digit)
        .collect::<String>()
        .parse()
        .unwrap_or_else(|_| panic!("{field} is not a number in {report}"))
}

/// Every forgery found against the open tuple space, tried 1,000 times or more each by the stock
/// Python client holding a certificate of its own (an enrolled but malicious member): none is
/// accepted by the PEIS, and the victim joins and works while the attack runs.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_malicious_member_forges_nothing_and_the_victim_joins_and_works() {
    use ecology_zenoh::security::Role;
    let Some(python) = python_with_zenoh() else {
        return;
    };
    let keys = TempKeys::new(
        "attack",
        &[
            ("hsm", Role::Peis),
            ("executive", Role::Executive),
            ("watcher", Role::Peis),
            ("mallory", Role::Peis),
        ],
    );
    // Mallory may set hsm's `ca1.fault` in her own name: what she sends there naming the
    // executive in its creator stamp must be refused by hsm itself, not by the access rules.
    let mut keys = keys;
    keys.grant_on_hsm("mallory", "ca1.fault");
    let watcher_endpoint = free_quic_endpoint();
    let watcher = ZenohPeis::open(keys.options("watcher", &watcher_endpoint, &[]))
        .await
        .expect("watcher joins");
    let mut everything = watcher
        .subscribe(TuplePattern::everything())
        .await
        .expect("subscribe");
    let mut presence = watcher.subscribe_presence().await.expect("presence");

    // The attacker declares tokens as hsm and as 1,000 made-up PEIS before hsm exists.
    let file = |f: &str| keys.dir.join(f).display().to_string();
    let mut attacker = Attacker::spawn(
        &python,
        &[
            "--connect".into(),
            watcher_endpoint.clone(),
            "--victim".into(),
            "hsm".into(),
            "--tries".into(),
            "1000".into(),
            "--peers".into(),
            "3".into(),
            "--ca".into(),
            file("ca.crt"),
            "--cert".into(),
            file("mallory.crt"),
            "--key".into(),
            file("mallory.key"),
        ],
    );
    assert_eq!(attacker.line(PATIENCE).await, "tokens");
    tokio::time::sleep(Duration::from_millis(300)).await;
    let peers = watcher.peers().await.expect("peers");
    assert_eq!(
        peers,
        [peis("watcher")],
        "forged presence tokens were taken"
    );

    // hsm joins although a token under its name was declared first, and works.
    let hsm = ZenohPeis::open(keys.options(
        "hsm",
        &free_quic_endpoint(),
        std::slice::from_ref(&watcher_endpoint),
    ))
    .await
    .expect("hsm joins despite the forged token");
    for (k, v) in [
        ("components.ca1.type", "cams"),
        ("components.ca1.cost", "20"),
        ("ca1.status", "running"),
    ] {
        hsm.set(key(k), Value::text(v)).await.expect("set");
    }
    let executive = ZenohPeis::open(keys.options(
        "executive",
        &free_quic_endpoint(),
        std::slice::from_ref(&watcher_endpoint),
    ))
    .await
    .expect("executive joins");
    wait_presence(&mut presence, &PresenceEvent::Joined(peis("hsm")), PATIENCE).await;

    // hsm keeps publishing while the attack runs, so there are real samples to replay.
    let beating = {
        let hsm = hsm.clone();
        tokio::spawn(async move {
            for i in 0u64.. {
                let _ = hsm
                    .set(key("ca1.out.image"), Value::text(format!("frame {i}")))
                    .await;
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
        })
    };
    attacker.say("go");
    let report = attacker.line(Duration::from_secs(120)).await;
    eprintln!("attacker: {report}");
    assert_eq!(attacker.line(PATIENCE).await, "attacking");
    assert!(report.contains("\"joined\": true"), "{report}");
    assert!(
        number(&report, "linked_peers") >= 3,
        "the attacker did not reach every PEIS: {report}"
    );
    for (field, at_least) in [
        ("puts", 2000),
        ("deletes", 1000),
        ("replays", 1000),
        ("sets", 1000),
    ] {
        assert!(
            number(&report, field) >= at_least,
            "{field} below {at_least}: {report}"
        );
    }
    assert_eq!(number(&report, "set_accepted"), 0, "{report}");
    assert_eq!(number(&report, "queries_answered"), 0, "{report}");

    // The executive's own remote set still works while the attack runs.
    executive
        .set_remote(
            peis("hsm"),
            key("components.ca1.reqState"),
            Value::text("on"),
        )
        .await
        .expect("the executive's remote set");

    // 1,000 gets of hsm's tuples: every answer is hsm's own.
    let mut gets = 0;
    for _ in 0..1000 {
        for t in watcher
            .get_matching(TuplePattern::parse("hsm:**").expect("pattern"))
            .await
            .expect("get")
        {
            assert!(
                t.seq < u64::MAX && !t.text().unwrap_or("").contains("FORGED"),
                "{t:?}"
            );
        }
        gets += 1;
    }

    // Whatever reached the watcher came from hsm itself.
    beating.abort();
    let mut seen = 0;
    while let Ok(Some(event)) =
        tokio::time::timeout(Duration::from_millis(500), everything.next()).await
    {
        seen += 1;
        match &event {
            TupleEvent::Changed(t) => {
                let text = t.text().unwrap_or("");
                assert!(
                    !text.contains("FORGED") && t.seq < u64::MAX && t.epoch < u64::MAX,
                    "forged tuple accepted: {t:?}"
                );
                assert_ne!((t.key.as_str(), text), ("ca1.status", "error"), "{t:?}");
            }
            TupleEvent::Removed { owner, key, .. } => {
                panic!("a removal was accepted: {owner}:{key}")
            }
            TupleEvent::Retargeted { .. } => {}
        }
    }
    let now = |k: &str| {
        let hsm = hsm.clone();
        let k = key(k);
        async move {
            hsm.get(peis("hsm"), k)
                .await
                .expect("get")
                .map(|t| t.text().map(str::to_owned))
        }
    };
    assert_eq!(
        now("components.ca1.reqState").await,
        Some(Ok("on".to_owned()))
    );
    assert_eq!(
        now("components.ca1.type").await,
        Some(Ok("cams".to_owned()))
    );
    assert_eq!(now("ca1.fault").await, None);
    let peers = watcher.peers().await.expect("peers");
    assert_eq!(
        peers,
        [peis("executive"), peis("hsm"), peis("watcher")],
        "{peers:?}"
    );
    assert!(number(&report, "tokens") > 1000, "{report}");
    eprintln!(
        "accepted forgeries: 0 of {} puts, {} deletes, {} replays, {} remote sets, {} tokens; \
         {gets} gets answered by hsm only; {seen} genuine changes seen",
        number(&report, "puts"),
        number(&report, "deletes"),
        number(&report, "replays"),
        number(&report, "sets"),
        number(&report, "tokens"),
    );
    drop(attacker);
    for space in [executive, hsm, watcher] {
        space.close().await;
    }
}

/// Without a certificate of the ecology the stock client cannot even open a session.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_outsider_without_a_certificate_cannot_join() {
    use ecology_zenoh::security::Role;
    let Some(python) = python_with_zenoh() else {
        return;
    };
    let keys = TempKeys::new("outsider", &[("hsm", Role::Peis)]);
    let endpoint = free_quic_endpoint();
    let hsm = ZenohPeis::open(keys.options("hsm", &endpoint, &[]))
        .await
        .expect("hsm joins");
    // Over QUIC without a certificate. (A secured PEIS has no plain TCP endpoint to try: one
    // given to it, even in a Zenoh configuration file, is refused before it opens anything;
    // `authenticated_members_talk_over_mutual_tls_and_only_the_executive_sets_remotely` shows it.)
    let attacker = Attacker::spawn(
        &python,
        &[
            "--connect".into(),
            endpoint,
            "--victim".into(),
            "hsm".into(),
        ],
    );
    let line = attacker.line(Duration::from_secs(20)).await;
    assert!(line.contains("\"joined\": false"), "{line}");
    hsm.close().await;
}

/// A router on a free endpoint, run until the returned sender is dropped or fires; `full` is
/// told each time it holds `max_sessions`.
fn start_router(
    max_sessions: usize,
    full: impl Fn(usize) + Send + Sync + 'static,
) -> (String, tokio::sync::oneshot::Sender<()>) {
    start_router_with(
        ecology_zenoh::RouterOptions {
            max_sessions,
            ..ecology_zenoh::RouterOptions::default()
        },
        full,
    )
}

fn start_router_with(
    options: ecology_zenoh::RouterOptions,
    full: impl Fn(usize) + Send + Sync + 'static,
) -> (String, tokio::sync::oneshot::Sender<()>) {
    let endpoint = free_endpoint();
    let options = ecology_zenoh::RouterOptions {
        listen: vec![endpoint.clone()],
        ..options
    };
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    tokio::spawn(ecology_zenoh::run_router(options, |_| {}, full, async {
        let _ = stopped.await;
    }));
    (endpoint, stop)
}

/// A queryable of `session` on `key_expr` that counts the queries it gets and hands each to
/// `answer`: the count, and the queryable (it answers while kept).
async fn counting_queryable(
    session: &zenoh::Session,
    key_expr: &str,
    answer: impl Fn(zenoh::query::Query) + Send + Sync + 'static,
) -> (Arc<AtomicUsize>, zenoh::query::Queryable<()>) {
    let count = Arc::new(AtomicUsize::new(0));
    let counter = count.clone();
    let queryable = session
        .declare_queryable(key_expr.to_owned())
        .callback(move |query| {
            counter.fetch_add(1, Ordering::Relaxed);
            answer(query);
        })
        .await
        .expect("queryable");
    (count, queryable)
}

/// A raw Zenoh client of the router at `endpoint`, giving up connecting after `timeout`.
async fn stock_router_client(endpoint: &str, timeout: Duration) -> zenoh::Result<zenoh::Session> {
    let mut config = zenoh::Config::default();
    for (key, value) in [
        ("mode", "\"client\"".to_owned()),
        ("connect/endpoints", format!("[\"{endpoint}\"]")),
        ("connect/timeout_ms", timeout.as_millis().to_string()),
        ("connect/exit_on_failure", "true".to_owned()),
        ("scouting/multicast/enabled", "false".to_owned()),
    ] {
        config.insert_json5(key, &value).expect("config");
    }
    zenoh::open(config).await
}

/// What a stock client writing a PEIS's text tuple attaches: its run (epoch 7) and `seq`.
fn stock_meta(seq: u64) -> Metadata {
    Metadata {
        seq,
        ts_write: Timestamp(1),
        ts_user: None,
        expiry: None,
        expired: false,
        epoch: 7,
        mimetype: Mimetype::text(),
        creator: None,
    }
}

/// A PEIS that is a client of the router at `endpoint`.
async fn router_client_peis(name: &str, endpoint: &str) -> ZenohPeis {
    let mut options = ZenohOptions::new(peis(name));
    options.mode = ecology_zenoh::Mode::Client;
    options.connect = vec![endpoint.to_owned()];
    ZenohPeis::open(options).await.expect("open")
}

/// A router told to stop closes its sessions but waits for them only `close_within`: given time,
/// it says it closed cleanly; given none (a thousand PEIS leaving at once kept Zenoh closing for
/// over 10 s), it says it stopped without them. Either way it stops at once.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_router_told_to_stop_waits_for_its_sessions_only_so_long() {
    use ecology_zenoh::Closed;
    for (close_within, expected) in [
        (PATIENCE, Closed::Cleanly),
        (Duration::ZERO, Closed::CutShort),
    ] {
        let endpoint = free_endpoint();
        let options = ecology_zenoh::RouterOptions {
            listen: vec![endpoint.clone()],
            close_within,
            ..ecology_zenoh::RouterOptions::default()
        };
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let router = tokio::spawn(ecology_zenoh::run_router(options, |_| {}, |_| {}, async {
            let _ = stopped.await;
        }));
        tokio::time::sleep(Duration::from_millis(300)).await;
        let _client = stock_router_client(&endpoint, PATIENCE)
            .await
            .expect("a client of the router");
        let _ = stop.send(());
        let closed = tokio::time::timeout(PATIENCE, router)
            .await
            .expect("the router stops within its bound")
            .expect("its task ends")
            .expect("it ran");
        assert_eq!(closed, expected, "closing within {close_within:?}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_router_says_so_and_takes_a_session_again_once_one_leaves() {
    let (told, mut full) = tokio::sync::mpsc::unbounded_channel();
    let (endpoint, _stop) = start_router(2, move |max| {
        let _ = told.send(max);
    });
    tokio::time::sleep(Duration::from_millis(300)).await;
    let first = stock_router_client(&endpoint, PATIENCE)
        .await
        .expect("first");
    let _second = stock_router_client(&endpoint, PATIENCE)
        .await
        .expect("second");
    let max = tokio::time::timeout(PATIENCE, full.recv()).await;
    assert_eq!(max, Ok(Some(2)), "the router says it is full");
    assert!(
        stock_router_client(&endpoint, Duration::from_secs(1))
            .await
            .is_err(),
        "a third session is refused"
    );
    first.close().await.expect("close");
    let third = stock_router_client(&endpoint, PATIENCE).await;
    assert!(third.is_ok(), "once one left, a session is taken again");
    let max = tokio::time::timeout(PATIENCE, full.recv()).await;
    assert_eq!(max, Ok(Some(2)), "full again, it says so again");
}

/// Through a router, a PEIS asks the ecology only what it cannot know itself: a subscription to
/// its own tuples is answered from its own store, and a present PEIS that answers nothing is not
/// asked again (among a thousand PEIS, those queries kept the router busy for seconds). A stock
/// client counts the queries it is sent for `a`'s tuples and for its own.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn through_a_router_a_peis_asks_for_nothing_it_has_and_asks_once() {
    // A router that holds nothing: every PEIS answers for itself (the router that holds the
    // contract is `a_router_answers_for_the_contract_of_every_peis_until_it_goes`).
    let options = ecology_zenoh::RouterOptions {
        hold_contract: false,
        ..ecology_zenoh::RouterOptions::default()
    };
    let (endpoint, _stop) = start_router_with(options, |_| {});
    tokio::time::sleep(Duration::from_millis(300)).await;
    let spy = stock_router_client(&endpoint, PATIENCE).await.expect("spy");
    let (asked_about_a, _about_a) = counting_queryable(&spy, "peis/a/**", drop).await;
    let (asked_the_spy, _of_spy) = counting_queryable(&spy, "peis/spy/**", drop).await;
    // Present as a PEIS is, its queryables declared before its token.
    let _token = spy
        .liveliness()
        .declare_token("peis/spy/@alive")
        .await
        .expect("token");
    let a = router_client_peis("a", &endpoint).await;
    a.set(key("x.one"), Value::text("1")).await.expect("set");
    let mut own = a
        .subscribe(TuplePattern::parse("a:x.*").expect("pattern"))
        .await
        .expect("subscribe");
    match next_event(&mut own, PATIENCE).await {
        TupleEvent::Changed(t) => assert_eq!((t.key.as_str(), t.text()), ("x.one", Ok("1"))),
        other => panic!("unexpected {other:?}"),
    }
    assert_eq!(
        asked_about_a.load(Ordering::Relaxed),
        0,
        "its own tuples come from its store"
    );
    let _everyone = a
        .subscribe(TuplePattern::parse("*:y.*").expect("pattern"))
        .await
        .expect("subscribe");
    // A PEIS that answered nothing was asked again up to five times, the last 3 s later.
    tokio::time::sleep(Duration::from_millis(3500)).await;
    let asked = asked_the_spy.load(Ordering::Relaxed);
    assert!(
        (1..=2).contains(&asked),
        "the spy, present and silent, is asked once by the snapshot and at most once more: {asked}"
    );
    a.close().await;
}

/// Many PEIS that appear at once beside a subscription to every PEIS are caught up with in one
/// question of every PEIS, not one question each (a thousand of them, asked one by one, put a
/// thousand questions on their router for each such subscription). A stock client answers for 40
/// PEIS whose tuples were set before they appeared; every one of them reaches the subscription,
/// and the client is asked far fewer than 40 questions.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn peis_appearing_together_are_caught_up_with_in_one_question() {
    let (endpoint, _stop) = start_router(8, |_| {});
    tokio::time::sleep(Duration::from_millis(300)).await;
    let a = router_client_peis("a", &endpoint).await;
    let mut velocities = a
        .subscribe(TuplePattern::parse("*:*.out.velocity").expect("pattern"))
        .await
        .expect("subscribe");
    let crowd = stock_router_client(&endpoint, PATIENCE)
        .await
        .expect("crowd");
    let (asked, _queryable) = counting_queryable(&crowd, "peis/**", |query| {
        let Some(rest) = query.key_expr().as_str().strip_prefix("peis/") else {
            return;
        };
        let owners: Vec<String> = match rest.split('/').next() {
            Some("*") => (0..40).map(|i| format!("s{i}")).collect(),
            Some(one) if one.starts_with('s') => vec![one.to_string()],
            _ => return,
        };
        for owner in owners {
            let meta = stock_meta(1);
            let _ = zenoh::Wait::wait(
                query
                    .reply(format!("peis/{owner}/m1/out/velocity"), "0.1 0")
                    .attachment(meta.encode()),
            );
        }
    })
    .await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    let mut tokens = Vec::new();
    for i in 0..40 {
        tokens.push(
            crowd
                .liveliness()
                .declare_token(format!("peis/s{i}/@alive"))
                .await
                .expect("token"),
        );
    }
    let mut owners = std::collections::BTreeSet::new();
    while owners.len() < 40 {
        match next_event(&mut velocities, PATIENCE).await {
            TupleEvent::Changed(t) => {
                owners.insert(t.owner.to_string());
            }
            other => panic!("unexpected {other:?}"),
        }
    }
    let questions = asked.load(Ordering::Relaxed);
    assert!(
        questions < 20,
        "40 PEIS appearing together were asked {questions} questions"
    );
    a.close().await;
    crowd.close().await.expect("close");
}

/// Through a router that holds the contract, a PEIS knows who reads its outputs: nobody, once its
/// router has answered (the router's own holding does not read an output); a client subscribed
/// through the router, until it unsubscribes or goes; a watch of its readers is told when one
/// comes. Until the router has answered, an output counts as read.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn through_a_router_a_peis_knows_who_reads_its_outputs() {
    let (endpoint, _stop) = start_router(8, |_| {});
    tokio::time::sleep(Duration::from_millis(300)).await;
    let cam = router_client_peis("cam", &endpoint).await;
    let image = key("c1.out.image");
    cam.set(image.clone(), Value::text("robot 1 2 0"))
        .await
        .expect("set");
    assert!(
        cam.is_read(&image),
        "before the router can have answered, an output counts as read"
    );
    until(Duration::from_secs(3), "nobody reads it", || {
        !cam.is_read(&image)
    })
    .await;
    let mut readers = cam.watch_readers(&image);
    assert!(!*readers.borrow());
    let tracker = router_client_peis("tracker", &endpoint).await;
    let mut reading = tracker
        .subscribe(TuplePattern::parse("cam:c1.out.image").expect("pattern"))
        .await
        .expect("subscribe");
    tokio::time::timeout(PATIENCE, readers.wait_for(|read| *read))
        .await
        .expect("told when the tracker came")
        .expect("watching");
    assert!(cam.is_read(&image));
    match next_event(&mut reading, PATIENCE).await {
        TupleEvent::Changed(t) => assert_eq!(t.text(), Ok("robot 1 2 0")),
        other => panic!("unexpected {other:?}"),
    }
    drop(reading);
    until(PATIENCE, "nobody reads it once the tracker stops", || {
        !cam.is_read(&image)
    })
    .await;
    let _reading = tracker
        .subscribe(TuplePattern::parse("*:*.out.*").expect("pattern"))
        .await
        .expect("subscribe");
    until(PATIENCE, "the tracker reads it by a wildcard", || {
        cam.is_read(&image)
    })
    .await;
    tracker.close().await;
    until(PATIENCE, "nobody reads it once the tracker is gone", || {
        !cam.is_read(&image)
    })
    .await;
    cam.close().await;
}

/// A router that holds the contract asks a PEIS that appears for its tuples only when it did not
/// see it start: a PEIS that starts publishes its `contract` tuple right after its presence token,
/// and the router takes every tuple after it as it goes by. `started` does so and is not asked;
/// `back` (as a PEIS is that came back without starting again) publishes no contract and is asked.
/// Both are read through the router.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_router_does_not_ask_a_peis_it_saw_start() {
    let (endpoint, _stop) = start_router(8, |_| {});
    tokio::time::sleep(Duration::from_millis(300)).await;
    let mut asked = Vec::new();
    let mut clients = Vec::new();
    for name in ["started", "back"] {
        let client = stock_router_client(&endpoint, PATIENCE)
            .await
            .expect("client");
        let (count, queryable) =
            counting_queryable(&client, &format!("peis/{name}/**"), drop).await;
        // A new client sends a put only once it knows of a subscriber: the router's, here.
        tokio::time::sleep(Duration::from_millis(300)).await;
        let token = client
            .liveliness()
            .declare_token(format!("peis/{name}/@alive"))
            .await
            .expect("token");
        let mut tuples = vec![("components/c1/type", "cams"), ("c1/status", "running")];
        if name == "started" {
            tuples.insert(0, (wire::CONTRACT_KEY, "2"));
        }
        for (seq, (key, text)) in tuples.into_iter().enumerate() {
            let meta = stock_meta(seq as u64 + 1);
            client
                .put(format!("peis/{name}/{key}"), text)
                .attachment(meta.encode())
                .await
                .expect("put");
        }
        asked.push(count);
        clients.push((client, queryable, token));
    }
    let deadline = tokio::time::Instant::now() + PATIENCE;
    while asked[1].load(Ordering::Relaxed) == 0 {
        assert!(
            tokio::time::Instant::now() < deadline,
            "back was never asked"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // Well past the wait before asking (0.5 s) of the PEIS that appeared first.
    tokio::time::sleep(Duration::from_millis(500)).await;
    assert_eq!(
        asked[0].load(Ordering::Relaxed),
        0,
        "the router saw started start: it did not ask it"
    );
    let a = router_client_peis("a", &endpoint).await;
    let mut owners: Vec<String> = a
        .get_matching(TuplePattern::parse("*:*.status").expect("pattern"))
        .await
        .expect("get")
        .into_iter()
        .map(|t| t.owner.to_string())
        .filter(|owner| owner != "a")
        .collect();
    owners.sort();
    assert_eq!(owners, ["back", "started"]);
    a.close().await;
    for (client, _, _) in clients {
        client.close().await.expect("close");
    }
}

/// A router holds the component contract of every PEIS and answers for it: a stock client that
/// writes `ghost`'s tuples and answers no query at all is still read through the router, its
/// directory and its component's status (not its outputs, which the router does not hold), until
/// its token goes. A router told not to hold the contract answers nothing for it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_router_answers_for_the_contract_of_every_peis_until_it_goes() {
    for hold_contract in [true, false] {
        let options = ecology_zenoh::RouterOptions {
            hold_contract,
            ..ecology_zenoh::RouterOptions::default()
        };
        let (endpoint, _stop) = start_router_with(options, |_| {});
        tokio::time::sleep(Duration::from_millis(300)).await;
        let ghost = stock_router_client(&endpoint, PATIENCE)
            .await
            .expect("ghost");
        // It answers no query, and counts those asked of every PEIS (`peis/*/…`).
        let asked = Arc::new(AtomicUsize::new(0));
        let counter = asked.clone();
        let _queryable = ghost
            .declare_queryable("peis/ghost/**")
            .callback(move |query| {
                if query.key_expr().as_str().starts_with("peis/*/") {
                    counter.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                }
            })
            .await
            .expect("queryable");
        // A new client sends a put only once it knows of a subscriber: the router's, here.
        tokio::time::sleep(Duration::from_millis(300)).await;
        let token = ghost
            .liveliness()
            .declare_token("peis/ghost/@alive")
            .await
            .expect("token");
        for (seq, (key_expr, text)) in [
            ("peis/ghost/components/c1/type", "cams"),
            ("peis/ghost/c1/status", "running"),
            ("peis/ghost/c1/out/image", "astrid 1 1 0"),
        ]
        .into_iter()
        .enumerate()
        {
            let meta = stock_meta(seq as u64 + 1);
            ghost
                .put(key_expr, text)
                .attachment(meta.encode())
                .await
                .expect("put");
        }
        let a = router_client_peis("a", &endpoint).await;
        let read = |pattern: &'static str| {
            let a = a.clone();
            async move {
                a.get_matching(TuplePattern::parse(pattern).expect("pattern"))
                    .await
                    .expect("get")
                    .into_iter()
                    .filter(|t| t.owner.as_str() == "ghost")
                    .map(|t| (t.key.to_string(), t.text().unwrap_or("").to_string()))
                    .collect::<Vec<_>>()
            }
        };
        let deadline = tokio::time::Instant::now() + Duration::from_secs(5);
        let mut contract = read("*:*.*").await;
        while hold_contract && contract.is_empty() && tokio::time::Instant::now() < deadline {
            tokio::time::sleep(Duration::from_millis(50)).await;
            contract = read("*:*.*").await;
        }
        if !hold_contract {
            assert_eq!(contract, [], "nobody answers for ghost");
            a.close().await;
            continue;
        }
        assert_eq!(contract, [("c1.status".to_string(), "running".to_string())]);
        // Once the router is known to hold the contract, a question of every PEIS is its alone.
        let before = asked.load(std::sync::atomic::Ordering::Relaxed);
        assert_eq!(read("*:*.*").await.len(), 1);
        assert_eq!(
            asked.load(std::sync::atomic::Ordering::Relaxed),
            before,
            "ghost was asked what the router holds"
        );
        assert_eq!(
            read("*:components.**").await,
            [("components.c1.type".to_string(), "cams".to_string())]
        );
        assert_eq!(read("*:*.out.*").await, [], "outputs are not held");
        // A question about one PEIS is answered from what is held for it (ghost answers nothing
        // itself), under each of the held key expressions and within one of them.
        for (pattern, key, value) in [
            ("ghost:*.*", "c1.status", "running"),
            ("ghost:components.**", "components.c1.type", "cams"),
            ("ghost:c1.*", "c1.status", "running"),
            ("ghost:components.*.type", "components.c1.type", "cams"),
        ] {
            let expected = [(key.to_string(), value.to_string())];
            assert_eq!(read(pattern).await, expected, "{pattern}");
        }
        // Asked for a bundle, the router answers in one reply; asked as before, a reply a tuple.
        let asker = stock_router_client(&endpoint, PATIENCE)
            .await
            .expect("asker");
        for (selector, bundled) in [
            (format!("peis/*/*/*?{}", wire::BUNDLE_PARAMETER), true),
            ("peis/*/*/*".to_string(), false),
        ] {
            let replies = asker
                .get(selector.as_str())
                .target(zenoh::query::QueryTarget::AllComplete)
                .await
                .expect("get");
            let mut got = Vec::new();
            while let Ok(reply) = replies.recv_async().await {
                got.push(reply.result().expect("a reply").clone());
            }
            if bundled {
                assert_eq!(got.len(), 1, "{got:?}");
                assert_eq!(got[0].encoding().to_string(), wire::BUNDLE_ENCODING);
                let bytes = got[0].payload().to_bytes();
                let bundle = wire::decode_bundle(&bytes).expect("a bundle");
                let keys: Vec<&str> = bundle.tuples.iter().map(|t| t.key_expr).collect();
                assert!(keys.contains(&"peis/ghost/c1/status"), "{keys:?}");
                assert!(
                    bundle.tuples.iter().all(|t| t.attachment.is_some()),
                    "{bundle:?}"
                );
                // PEIS a holds nothing under `peis/*/*/*`: named, to be asked itself.
                assert!(bundle.silent.contains(&"a"), "{bundle:?}");
                assert!(!bundle.silent.contains(&"ghost"), "{bundle:?}");
            } else {
                let ghost: Vec<_> = got
                    .iter()
                    .filter(|s| s.key_expr().as_str().starts_with("peis/ghost/"))
                    .collect();
                assert_eq!(ghost.len(), 1, "{got:?}");
                assert!(
                    got.iter()
                        .all(|s| s.encoding().to_string() != wire::BUNDLE_ENCODING),
                    "{got:?}"
                );
            }
        }
        // The same question under `@ecology/held/`: the router alone answers, in one bundle of
        // the tuples' own keys; outside what it holds, nothing.
        for (selector, expected) in [
            (
                format!("@ecology/held/peis/*/*/*?{}", wire::BUNDLE_PARAMETER),
                Some("peis/ghost/c1/status"),
            ),
            (
                format!("@ecology/held/peis/*/*/out/*?{}", wire::BUNDLE_PARAMETER),
                None,
            ),
        ] {
            let replies = asker
                .get(selector.as_str())
                .accept_replies(zenoh::query::ReplyKeyExpr::Any)
                .target(zenoh::query::QueryTarget::AllComplete)
                .await
                .expect("get");
            let mut got = Vec::new();
            while let Ok(reply) = replies.recv_async().await {
                got.push(reply.result().expect("a reply").clone());
            }
            let keys: Vec<String> = got
                .iter()
                .flat_map(|sample| {
                    let bytes = sample.payload().to_bytes();
                    let bundle = wire::decode_bundle(&bytes).expect("a bundle");
                    bundle
                        .tuples
                        .iter()
                        .map(|t| t.key_expr.to_string())
                        .collect::<Vec<_>>()
                })
                .collect();
            match expected {
                Some(key) => {
                    assert_eq!(got.len(), 1, "{selector}: {got:?}");
                    assert!(keys.iter().any(|k| k == key), "{selector}: {keys:?}");
                }
                None => assert!(got.is_empty(), "{selector}: {got:?}"),
            }
        }
        asker.close().await.expect("close");
        token.undeclare().await.expect("undeclare");
        let deadline = tokio::time::Instant::now() + Duration::from_secs(5);
        while !read("*:*.*").await.is_empty() {
            assert!(
                tokio::time::Instant::now() < deadline,
                "ghost's tuples outlived its token"
            );
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        a.close().await;
    }
}
