//! Zenoh loopback benchmark between two OS processes: ecology `set` → subscriber versus raw Zenoh `put` →
//! subscriber callback, measured in the same run, with ratios.
//!
//! Run with `cargo bench -p ecology-zenoh --bench loopback`. The bench re-runs itself as the subscriber
//! process (`loopback sub ...`). Latency is publisher send time (wall clock, in the payload) to receipt.
//! For profiling one side alone, `LOOPBACK_ONLY=raw` or `LOOPBACK_ONLY=ecology` runs only its phases
//! (the other side's figures then read 0 and the ratios are meaningless).
//! `LOOPBACK_TLS=1` runs the ecology side authenticated (mutual TLS and the access rules, with keys made
//! for the run), the raw side still on plain TCP: the ratios then show what security costs.

use std::io::{BufRead, Write};
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use ecology_tuples::{Key, PeisId, TupleEvent, TupleSpace, Value};
use ecology_zenoh::security::{KeysDir, Role};
use ecology_zenoh::{Security, ZenohOptions, ZenohPeis};

const THROUGHPUT: usize = 100_000;
const LATENCY: usize = 5_000;
const PAYLOAD: usize = 64;

fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}

fn payload() -> Vec<u8> {
    let mut p = vec![0u8; PAYLOAD];
    p[..8].copy_from_slice(&now_ns().to_le_bytes());
    p
}

fn sent_at(data: &[u8]) -> u64 {
    let mut b = [0u8; 8];
    b.copy_from_slice(&data[..8]);
    u64::from_le_bytes(b)
}

/// Whether the phases of `side` (`raw` or `ecology`) run; both do unless `LOOPBACK_ONLY` names one.
fn runs(side: &str) -> bool {
    std::env::var("LOOPBACK_ONLY").map_or(true, |only| only == side)
}

fn free_endpoint() -> String {
    let l = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    format!("tcp/127.0.0.1:{}", l.local_addr().expect("addr").port())
}

/// What the subscriber records for one phase: receipt count, first and last receipt, latencies.
#[derive(Default)]
struct Phase {
    count: usize,
    first_sent: u64,
    last_received: u64,
    latencies: Vec<u64>,
}

impl Phase {
    fn record(&mut self, data: &[u8]) {
        let now = now_ns();
        let sent = sent_at(data);
        if self.count == 0 {
            self.first_sent = sent;
        }
        self.count += 1;
        self.last_received = now;
        self.latencies.push(now.saturating_sub(sent));
    }

    fn report(&mut self, name: &str) -> String {
        self.latencies.sort_unstable();
        let p = |q: f64| {
            let i = ((self.latencies.len().max(1) - 1) as f64 * q).round() as usize;
            self.latencies.get(i).copied().unwrap_or(0)
        };
        let secs = (self.last_received.saturating_sub(self.first_sent)) as f64 / 1e9;
        format!("{name} {} {:.6} {} {}", self.count, secs, p(0.5), p(0.99))
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime");
    if args.get(1).map(String::as_str) == Some("sub") {
        runtime.block_on(subscriber(
            &args[2],
            &args[3],
            args.get(4).map(String::as_str),
        ));
    } else {
        runtime.block_on(publisher());
    }
}

async fn raw_session(listen: Option<&str>, connect: Option<&str>) -> zenoh::Session {
    let mut c = zenoh::Config::default();
    c.insert_json5("scouting/multicast/enabled", "false")
        .expect("config");
    if let Some(l) = listen {
        c.insert_json5("listen/endpoints", &format!("[\"{l}\"]"))
            .expect("config");
    } else {
        c.insert_json5("listen/endpoints", &format!("[\"{}\"]", free_endpoint()))
            .expect("config");
    }
    if let Some(e) = connect {
        c.insert_json5("connect/endpoints", &format!("[\"{e}\"]"))
            .expect("config");
    }
    zenoh::open(c).await.expect("open raw session")
}

/// The ecology side's security: the member's identity in `keys`, or open.
fn security(keys: Option<&str>, name: &str) -> Security {
    match keys {
        Some(dir) => {
            let keys = KeysDir::open(std::path::Path::new(dir)).expect("open keys");
            let name = PeisId::new(name).expect("name");
            Security::Authenticated(Box::new(keys.identity(&name).expect("identity")))
        }
        None => Security::Open,
    }
}

/// A free endpoint for the ecology side: TLS when it runs with keys.
fn ecology_endpoint(keys: Option<&str>) -> String {
    match keys {
        Some(_) => free_endpoint().replacen("tcp/", "quic/", 1),
        None => free_endpoint(),
    }
}

async fn subscriber(ecology_endpoint_to: &str, raw_endpoint: &str, keys: Option<&str>) {
    let phases: Arc<Mutex<[Phase; 4]>> = Arc::new(Mutex::new(Default::default()));
    let raw = raw_session(None, Some(raw_endpoint)).await;
    let p = phases.clone();
    let _raw_sub = raw
        .declare_subscriber("bench/raw/*")
        .callback(move |sample| {
            let data = sample.payload().to_bytes();
            let i = if sample.key_expr().as_str().ends_with("tp") {
                0
            } else {
                1
            };
            p.lock().expect("lock")[i].record(&data);
        })
        .await
        .expect("raw subscriber");

    let mut options = ZenohOptions::new(PeisId::new("bench-sub").expect("name"));
    options.listen = vec![ecology_endpoint(keys)];
    options.connect = vec![ecology_endpoint_to.to_owned()];
    options.security = security(keys, "bench-sub");
    let peis = ZenohPeis::open(options).await.expect("open");
    let mut sub = peis
        .subscribe("bench-pub:bench.*".parse().expect("pattern"))
        .await
        .expect("subscribe");
    let p = phases.clone();
    let ecology_task = tokio::spawn(async move {
        while let Some(event) = sub.next().await {
            if let TupleEvent::Changed(t) = event {
                let i = if t.key.as_str().ends_with("tp") { 2 } else { 3 };
                p.lock().expect("lock")[i].record(&t.data);
            }
        }
    });
    println!("ready");
    let _ = std::io::stdout().flush();
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        let done = {
            let ph = phases.lock().expect("lock");
            (!runs("raw") || ph[0].count >= THROUGHPUT && ph[1].count >= LATENCY)
                && (!runs("ecology") || ph[2].count >= THROUGHPUT && ph[3].count >= LATENCY)
        };
        if done || Instant::now() > deadline {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let mut ph = phases.lock().expect("lock");
    for (i, name) in [
        "raw-throughput",
        "raw-latency",
        "ecology-throughput",
        "ecology-latency",
    ]
    .iter()
    .enumerate()
    {
        println!("{}", ph[i].report(name));
    }
    ecology_task.abort();
}

/// Sends `n` messages back to back, or paced one per `gap`.
async fn paced<F, Fut>(n: usize, gap: Option<Duration>, mut send: F)
where
    F: FnMut() -> Fut,
    Fut: std::future::Future<Output = ()>,
{
    for _ in 0..n {
        let start = Instant::now();
        send().await;
        if let Some(gap) = gap {
            while start.elapsed() < gap {
                std::hint::spin_loop();
            }
        }
    }
}

async fn publisher() {
    let keys_dir = std::env::var("LOOPBACK_TLS")
        .is_ok_and(|v| v == "1")
        .then(|| {
            let dir =
                std::env::temp_dir().join(format!("ecology-loopback-keys-{}", std::process::id()));
            let _ = std::fs::remove_dir_all(&dir);
            let mut keys = KeysDir::init(&dir).expect("init keys");
            for name in ["bench-pub", "bench-sub"] {
                keys.add(PeisId::new(name).expect("name"), Role::Peis)
                    .expect("add");
            }
            dir.display().to_string()
        });
    let keys = keys_dir.as_deref();
    let ecology_endpoint = ecology_endpoint(keys);
    let raw_endpoint = free_endpoint();
    let raw = raw_session(Some(&raw_endpoint), None).await;
    let mut options = ZenohOptions::new(PeisId::new("bench-pub").expect("name"));
    options.listen = vec![ecology_endpoint.clone()];
    options.security = security(keys, "bench-pub");
    let peis = ZenohPeis::open(options).await.expect("open");

    let exe = std::env::current_exe().expect("current exe");
    let mut child = Command::new(exe)
        .args(["sub", &ecology_endpoint, &raw_endpoint])
        .args(keys)
        .stdout(Stdio::piped())
        .spawn()
        .expect("spawn subscriber");
    let mut lines = std::io::BufReader::new(child.stdout.take().expect("stdout")).lines();
    assert_eq!(lines.next().and_then(Result::ok).as_deref(), Some("ready"));
    // Let both subscribers' declarations reach this process (a benchmark may simply wait).
    tokio::time::sleep(Duration::from_secs(1)).await;

    let gap = Some(Duration::from_micros(200));
    let tp = Key::new("bench.tp").expect("key");
    let lat = Key::new("bench.lat").expect("key");
    let raw_put = |ke: &'static str| {
        let raw = raw.clone();
        move || {
            let raw = raw.clone();
            async move {
                raw.put(ke, payload())
                    .congestion_control(zenoh::qos::CongestionControl::Block)
                    .await
                    .expect("put");
            }
        }
    };
    let set = |key: Key| {
        let peis = peis.clone();
        move || {
            let peis = peis.clone();
            let key = key.clone();
            async move {
                peis.set(key, Value::bytes(payload())).await.expect("set");
            }
        }
    };
    if runs("raw") {
        paced(THROUGHPUT, None, raw_put("bench/raw/tp")).await;
        paced(LATENCY, gap, raw_put("bench/raw/lat")).await;
    }
    if runs("ecology") {
        paced(THROUGHPUT, None, set(tp)).await;
        paced(LATENCY, gap, set(lat)).await;
    }

    let mut results = std::collections::BTreeMap::new();
    for line in lines.map_while(Result::ok).take(4) {
        let f: Vec<&str> = line.split_whitespace().collect();
        let count: usize = f[1].parse().unwrap_or(0);
        let secs: f64 = f[2].parse().unwrap_or(f64::NAN);
        let p50: f64 = f[3].parse().unwrap_or(f64::NAN);
        let p99: f64 = f[4].parse().unwrap_or(f64::NAN);
        results.insert(f[0].to_owned(), (count, secs, p50, p99));
    }
    let _ = child.wait();
    let get = |k: &str| {
        results
            .get(k)
            .copied()
            .unwrap_or((0, f64::NAN, f64::NAN, f64::NAN))
    };
    let (rc, rs, _, _) = get("raw-throughput");
    let (ec, es, _, _) = get("ecology-throughput");
    let (_, _, r50, r99) = get("raw-latency");
    let (_, _, e50, e99) = get("ecology-latency");
    let raw_rate = rc as f64 / rs;
    let eco_rate = ec as f64 / es;
    println!(
        "zenoh loopback, two processes, {PAYLOAD}-byte values, {THROUGHPUT} back to back, {LATENCY} paced at 200 us{}",
        if keys.is_some() {
            "; ecology side over QUIC with mutual TLS and access rules, raw side plain TCP"
        } else {
            ""
        }
    );
    println!("                      raw zenoh put     ecology set     ratio (target)");
    println!(
        "throughput (msg/s)    {raw_rate:>13.0}   {eco_rate:>13.0}     {:.2}x (>= 0.80x)",
        eco_rate / raw_rate
    );
    println!(
        "latency p50 (us)      {:>13.1}   {:>13.1}     {:.2}x (<= 1.25x)",
        r50 / 1e3,
        e50 / 1e3,
        e50 / r50
    );
    println!(
        "latency p99 (us)      {:>13.1}   {:>13.1}     {:.2}x",
        r99 / 1e3,
        e99 / 1e3,
        e99 / r99
    );
    println!("received: raw {rc}/{THROUGHPUT}, ecology {ec}/{THROUGHPUT}");
    peis.close().await;
    let _ = raw.close().await;
    if let Some(dir) = keys {
        let _ = std::fs::remove_dir_all(dir);
    }
}
