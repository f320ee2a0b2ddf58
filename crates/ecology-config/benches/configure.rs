//! Benchmark of the configuration planner: the paper's reference goal, then a
//! curve over synthetic ecologies of 10 to 10,000 PEIS, side by side with the
//! brute-force enumerator where it finishes.
//!
//! Run with `cargo bench -p ecology-config --bench configure` (add `-- --quick`
//! for fewer repetitions). Peak memory is the heap high-water mark during
//! planning, measured by a counting allocator.

// The counting allocator forwards to the system allocator; that needs `unsafe`.
#![allow(unsafe_code)]

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use ecology_config::oracle::{self, Limit};
use ecology_config::synthetic::{self, Shape};
use ecology_config::{NoClock, Options, PaperCost, Request, Status, plan};

use common::median;

struct Counting;

static CURRENT: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded unchanged to the system allocator.
        let ptr = unsafe { System.alloc(layout) };
        if !ptr.is_null() {
            let now = CURRENT.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        ptr
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.dealloc(ptr, layout) };
        CURRENT.fetch_sub(layout.size(), Ordering::Relaxed);
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

fn human(d: Duration) -> String {
    let us = d.as_secs_f64() * 1e6;
    if us < 1000.0 {
        format!("{us:.1} µs")
    } else if us < 1e6 {
        format!("{:.2} ms", us / 1000.0)
    } else {
        format!("{:.2} s", us / 1e6)
    }
}

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    let runs = |n: usize| if quick { (n / 10).max(1) } else { n };

    // 1. The paper's reference goal.
    let domain = ecology_domain::parse_domain(include_bytes!("../../../domains/peis-home.eco"))
        .expect("reference domain");
    let state = ecology_domain::parse_facts(include_bytes!("../../../domains/peis-home.facts"))
        .expect("reference facts");
    let goal = ecology_domain::parse_goal("(navigate astrid bedroom)").expect("goal");
    let request = Request {
        domain: &domain,
        state: &state,
        goal: &goal,
        exclusions: &[],
    };
    let (time, outcome) = median(runs(2000), || {
        plan(&request, &Options::default(), &NoClock).expect("valid")
    });
    let (oracle_time, _) = median(runs(200), || {
        oracle::enumerate(&domain, &state, &goal, &[], &PaperCost, Limit(1_000_000))
    });
    println!("reference goal (navigate astrid bedroom) on the paper's state:");
    println!(
        "  planner {} (cost {}, {} nodes expanded)   brute force {}   ratio {:.1}x   target < 100 µs",
        human(time),
        outcome.configurations[0].cost,
        outcome.stats.expanded,
        human(oracle_time),
        oracle_time.as_secs_f64() / time.as_secs_f64()
    );
    println!();

    // 2. The curve.
    println!("synthetic ecologies: 10 components per PEIS, 20 types, 3 methods per task, depth 4");
    println!(
        "{:>6} {:>8} {:>12} {:>9} {:>10} {:>12} {:>11} {:>8} {:>14} {:>8}",
        "PEIS",
        "facts",
        "alternatives",
        "expanded",
        "generated",
        "plan time",
        "peak heap",
        "proven",
        "brute force",
        "ratio"
    );
    for (peis, reps) in [
        (10, 200),
        (30, 100),
        (100, 40),
        (300, 15),
        (1000, 7),
        (3000, 3),
        (10_000, 3),
    ] {
        let instance = synthetic::ecology(Shape {
            peis,
            components_per_peis: 10,
            types: 20,
            methods: 3,
            depth: 4,
            seed: 2007,
        })
        .expect("generates");
        let request = instance.request();
        let base = CURRENT.load(Ordering::Relaxed);
        PEAK.store(base, Ordering::Relaxed);
        let (time, outcome) = median(runs(reps), || {
            plan(&request, &Options::default(), &NoClock).expect("valid")
        });
        let peak = PEAK.load(Ordering::Relaxed) - base;
        // The brute force enumerates every decomposition tree; past a cap it
        // gives up, and past 30 PEIS it is not tried at all.
        const TREES: usize = 20_000;
        let brute: Result<Duration, &str> = if peis <= 30 {
            let (t, found) = median(runs(3), || {
                oracle::enumerate(
                    &instance.domain,
                    &instance.state,
                    &instance.goal,
                    &[],
                    &PaperCost,
                    Limit(TREES),
                )
            });
            match found {
                Some(list) => {
                    assert_eq!(
                        list.first().map(|c| c.cost),
                        outcome.configurations.first().map(|c| c.cost),
                        "planner and brute force disagree"
                    );
                    Ok(t)
                }
                None => Err("> 20000 trees"),
            }
        } else {
            Err("not run")
        };
        println!(
            "{:>6} {:>8} {:>12} {:>9} {:>10} {:>12} {:>8.1} MB {:>8} {:>14} {:>8}",
            peis,
            instance.state.len(),
            outcome.stats.alternatives,
            outcome.stats.expanded,
            outcome.stats.generated,
            human(time),
            peak as f64 / 1e6,
            if outcome.status == Status::Proven {
                "yes"
            } else {
                "no"
            },
            brute.map_or_else(str::to_string, human),
            brute.map_or("—".to_string(), |b| format!(
                "{:.0}x",
                b.as_secs_f64() / time.as_secs_f64()
            )),
        );
    }
}
