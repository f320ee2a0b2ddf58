//! A fuzz harness on stable Rust: every entry point that reads user input,
//! fed seeded random and mutated inputs; it counts executions and panics
//! (there must be none), and finds the slowest input and the peak memory of
//! one input against the bound of 64 MiB plus 100 times the input's size.
//!
//! `cargo bench -p ecology-cli --bench fuzz` (1,000,000 inputs per entry
//! point; `ECOLOGY_FUZZ_INPUTS=N` for another number, `ECOLOGY_FUZZ_SEED=S`
//! for another seed). An input that panics, or breaks a bound, is written to
//! `target/fuzz-findings/` so that it can be replayed.

use std::panic::AssertUnwindSafe;
use std::path::Path;
use std::time::{Duration, Instant};

use ecology_sim::Rng;
use peak_alloc::PeakAlloc;

#[global_allocator]
static MEMORY: PeakAlloc = PeakAlloc;

/// Memory one input may use: 64 MiB plus 100 times its size.
fn memory_bound(input: &[u8]) -> usize {
    64 * 1024 * 1024 + 100 * input.len()
}

/// Time one input may take.
const TIME_BOUND: Duration = Duration::from_secs(1);

const PEIS_HOME: &str = include_str!("../../../domains/peis-home.eco");
const PEIS_HOME_FACTS: &str = include_str!("../../../domains/peis-home.facts");
const PEIS_HOME_TASK: &str = include_str!("../../../domains/peis-home-task.problem");
const UNCERTAIN: &str = include_str!("../../../domains/peis-home-uncertain.eco");
const NEWSPAPER: &str = include_str!("../../../domains/newspaper-uncertain.problem");
const KITCHEN: &str = include_str!("../../../scenarios/kitchen.toml");
const PLAN: &str = "(move astrid living-room entrance)  ; configure (navigate astrid entrance)\n(wake astrid johanna bedroom)  ; configure (wake-up astrid johanna)\n";

/// Fragments mutations splice in: the language's own tokens, and the kinds of
/// values that have broken readers before.
const TOKENS: &[&str] = &[
    "(",
    ")",
    "((((",
    "))))",
    "?x",
    ":parameters",
    ":precondition",
    ":subtasks",
    ":channels",
    "(and",
    "(not",
    "(=",
    ":hz",
    "1e400",
    "-1",
    "18446744073709551616",
    "1.8e19",
    "\0",
    "\u{7}",
    "\u{feff}",
    "é",
    "\"",
    "[",
    "]",
    "[[peis]]",
    "[[fault]]",
    "=",
    "meta",
    ".",
    "..",
    "*",
    "**",
    "\n",
    ";",
    "\r\n",
    "\t",
    "\\u0000",
    "inf",
    "NaN",
];

/// Reads one input; whatever it returns is dropped.
type Reader = Box<dyn Fn(&[u8])>;

/// One entry point: a name, the inputs it starts from, and the call.
struct Entry {
    name: &'static str,
    seeds: Vec<Vec<u8>>,
    call: Reader,
}

fn entries() -> Vec<Entry> {
    let domain = ecology_domain::parse_domain(PEIS_HOME.as_bytes()).expect("the reference domain");
    let uncertain =
        ecology_domain::parse_domain(UNCERTAIN.as_bytes()).expect("the uncertain domain");
    let text = |bytes: &[u8]| String::from_utf8_lossy(bytes).into_owned();
    let wire = ecology_zenoh::wire::Metadata::of_tuple(&ecology_tuples::Tuple {
        owner: ecology_tuples::PeisId::new("astrid").expect("name"),
        key: ecology_tuples::Key::new("l1.status").expect("key"),
        data: bytes::Bytes::from_static(b"running"),
        mimetype: ecology_tuples::Mimetype::new("text/plain").expect("mimetype"),
        ts_write: ecology_tuples::Timestamp(1),
        ts_user: Some(ecology_tuples::Timestamp(2)),
        expiry: None,
        seq: 3,
        epoch: 4,
        creator: None,
    })
    .encode();
    vec![
        Entry {
            name: ".eco domain",
            seeds: vec![PEIS_HOME.into(), UNCERTAIN.into()],
            call: Box::new(|b| drop(ecology_domain::parse_domain(b))),
        },
        Entry {
            name: ".facts state",
            seeds: vec![PEIS_HOME_FACTS.into()],
            call: Box::new(|b| drop(ecology_domain::parse_facts(b))),
        },
        Entry {
            name: "goal",
            seeds: vec![
                "(navigate astrid bedroom)".into(),
                "(wake-up astrid johanna)".into(),
            ],
            call: Box::new(move |b| drop(ecology_domain::parse_goal(&text(b)))),
        },
        Entry {
            name: "PDDL problem",
            seeds: vec![PEIS_HOME_TASK.into()],
            call: Box::new(move |b| drop(ecology_domain::parse_problem_for(&domain, b))),
        },
        Entry {
            name: "uncertain problem",
            seeds: vec![NEWSPAPER.into()],
            call: Box::new(move |b| drop(ecology_domain::parse_problem_for(&uncertain, b))),
        },
        Entry {
            name: "scenario TOML",
            seeds: vec![KITCHEN.into()],
            call: Box::new(move |b| {
                let read = |_: &Path| Ok(PEIS_HOME.as_bytes().to_vec());
                drop(ecology_sim::Scenario::parse(&text(b), "fuzz.toml", &read));
            }),
        },
        Entry {
            name: "plan file",
            seeds: vec![PLAN.into()],
            call: Box::new(move |b| drop(ecology_exec::parse_plan(&text(b)))),
        },
        Entry {
            name: "meta-tuple",
            seeds: vec!["(meta hsm ca1.out.image)".into()],
            call: Box::new(move |b| drop(ecology_tuples::MetaPointer::parse(&text(b)))),
        },
        Entry {
            name: "tuple key expression",
            seeds: vec![
                "peis/astrid/components/l1/status".into(),
                "peis/hsm/@set/ca1/fault".into(),
            ],
            call: Box::new(move |b| {
                let ke = text(b);
                drop(ecology_zenoh::wire::parse_tuple_key_expr(&ke));
                drop(ecology_zenoh::wire::parse_alive_key_expr(&ke));
                if let Ok(owner) = ecology_tuples::PeisId::new("hsm") {
                    drop(ecology_zenoh::wire::parse_remote_set_key_expr(&owner, &ke));
                }
            }),
        },
        Entry {
            name: "tuple / remote-set attachment",
            seeds: vec![wire],
            call: Box::new(|b| {
                if let Ok(meta) = ecology_zenoh::wire::Metadata::decode(b) {
                    let value = meta.into_request(bytes::Bytes::new());
                    if let Ok(key) = ecology_tuples::Key::new("l1.reqState") {
                        drop(ecology_tuples::Limits::default().check(&key, &value));
                    }
                }
            }),
        },
    ]
}

/// An input from `seeds`: a mutation of one (most of the time), or random bytes.
fn input(rng: &mut Rng, seeds: &[Vec<u8>]) -> Vec<u8> {
    let pick = |rng: &mut Rng, n: usize| usize::try_from(rng.below(n.max(1) as u64)).unwrap_or(0);
    if rng.below(10) == 0 {
        let len = pick(rng, 512);
        return (0..len).map(|_| rng.below(256) as u8).collect();
    }
    let mut bytes = seeds[pick(rng, seeds.len())].clone();
    for _ in 0..1 + pick(rng, 8) {
        let at = pick(rng, bytes.len() + 1);
        match rng.below(6) {
            0 => {
                if at < bytes.len() {
                    bytes[at] = rng.below(256) as u8;
                }
            }
            1 => {
                let end = (at + pick(rng, 64)).min(bytes.len());
                bytes.drain(at..end);
            }
            2 => {
                let token = TOKENS[pick(rng, TOKENS.len())].as_bytes();
                bytes.splice(at..at, token.iter().copied());
            }
            3 => {
                // Repeat a piece many times: long lines, deep nesting, big numbers.
                let end = (at + 1 + pick(rng, 16)).min(bytes.len());
                let piece: Vec<u8> = bytes[at.min(end)..end].to_vec();
                let times = 1 + pick(rng, 2000);
                let repeated: Vec<u8> = piece
                    .iter()
                    .copied()
                    .cycle()
                    .take(piece.len() * times)
                    .collect();
                bytes.splice(at..at, repeated);
            }
            4 => {
                let from = pick(rng, bytes.len() + 1);
                let end = (from + pick(rng, 256)).min(bytes.len());
                let piece: Vec<u8> = bytes[from..end].to_vec();
                bytes.splice(at..at, piece);
            }
            _ => bytes.truncate(at),
        }
    }
    bytes
}

struct Finding {
    executions: u64,
    panics: u64,
    slowest: (Duration, usize),
    peak: (usize, usize),
    over_bounds: u64,
}

fn save(entry: &str, what: &str, n: u64, bytes: &[u8]) {
    let folder = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../target/fuzz-findings");
    let _ = std::fs::create_dir_all(&folder);
    let name = format!("{}-{what}-{n}.bin", entry.replace([' ', '/', '.'], "_"));
    let _ = std::fs::write(folder.join(name), bytes);
}

fn fuzz(entry: &Entry, inputs: u64, seed: u64) -> Finding {
    let mut rng = Rng::derive(seed, entry.name);
    let mut finding = Finding {
        executions: 0,
        panics: 0,
        slowest: (Duration::ZERO, 0),
        peak: (0, 0),
        over_bounds: 0,
    };
    for n in 0..inputs {
        let bytes = input(&mut rng, &entry.seeds);
        let before = MEMORY.current_usage();
        MEMORY.reset_peak_usage();
        let started = Instant::now();
        let outcome = std::panic::catch_unwind(AssertUnwindSafe(|| (entry.call)(&bytes)));
        let took = started.elapsed();
        let used = MEMORY.peak_usage().saturating_sub(before);
        finding.executions += 1;
        if outcome.is_err() {
            finding.panics += 1;
            save(entry.name, "panic", n, &bytes);
        }
        if took > finding.slowest.0 {
            finding.slowest = (took, bytes.len());
        }
        if used > finding.peak.0 {
            finding.peak = (used, bytes.len());
        }
        if took > TIME_BOUND || used > memory_bound(&bytes) {
            finding.over_bounds += 1;
            save(entry.name, "bound", n, &bytes);
        }
    }
    finding
}

fn main() {
    let inputs: u64 = std::env::var("ECOLOGY_FUZZ_INPUTS")
        .ok()
        .and_then(|n| n.parse().ok())
        .unwrap_or(1_000_000);
    let seed: u64 = std::env::var("ECOLOGY_FUZZ_SEED")
        .ok()
        .and_then(|n| n.parse().ok())
        .unwrap_or(2007);
    // Panics are counted, not printed.
    std::panic::set_hook(Box::new(|_| {}));
    println!(
        "{inputs} inputs per entry point, seed {seed}; bounds: 1 s and 64 MiB + 100 x the input per input"
    );
    println!(
        "{:<30} {:>10} {:>7} {:>22} {:>26} {:>8}",
        "entry point",
        "inputs",
        "panics",
        "slowest (input bytes)",
        "peak memory (input bytes)",
        "over"
    );
    let mut total_panics = 0;
    let mut total_over = 0;
    for entry in entries() {
        let started = Instant::now();
        let f = fuzz(&entry, inputs, seed);
        total_panics += f.panics;
        total_over += f.over_bounds;
        println!(
            "{:<30} {:>10} {:>7} {:>13.3} ms ({:>6}) {:>16.1} KiB ({:>6}) {:>8}   [{:.0} s]",
            entry.name,
            f.executions,
            f.panics,
            f.slowest.0.as_secs_f64() * 1000.0,
            f.slowest.1,
            f.peak.0 as f64 / 1024.0,
            f.peak.1,
            f.over_bounds,
            started.elapsed().as_secs_f64()
        );
    }
    println!("panics: {total_panics} (must be 0); inputs over a bound: {total_over} (must be 0)");
    if total_panics + total_over > 0 {
        println!("the inputs are in target/fuzz-findings/");
        std::process::exit(1);
    }
}
