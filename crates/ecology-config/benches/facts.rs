//! Reading a state: `.facts` text to an `EcologyState` (every fact read, checked, lowercased,
//! and stored once, behind an index by hash), then the planner's interning of every name and
//! indexing of the facts, side by side with a plain line reader of the same text; and, for
//! scale, the whole preparation of a search after reading (grounding the goal and preparing
//! the shared providers too).
//!
//! The state is the one `scripts/bench-budget` plans on: 256 PEIS sharing providers over three
//! levels of 4 components each (`synthetic::sharing`, seed 1), about 1.9 MB. Run with
//! `cargo bench -p ecology-config --bench facts`.

mod common;

use std::hint::black_box;
use std::io::BufRead;
use std::time::Duration;

use common::median;

use ecology_config::synthetic::{self, Sharing};
use ecology_config::{Options, PaperCost, Request, Search};

fn main() {
    let shape = Sharing {
        peis: 256,
        levels: 3,
        types: 2,
        per_level: 4,
        needs: 2,
        failed: 0.0,
        rates: false,
        seed: 1,
    };
    let instance = synthetic::sharing(shape).expect("a valid shape");
    let text = instance.facts_text.as_bytes();
    let megabytes = text.len() as f64 / 1e6;
    let facts = ecology_domain::parse_facts(text).expect("the state parses");
    println!(
        "state: {:.2} MB, {} lines, {} facts; median of 21 runs each (5 for the search)",
        megabytes,
        text.iter().filter(|&&b| b == b'\n').count(),
        facts.len()
    );
    let (lines, ()) = median(21, || {
        let count = std::io::BufReader::new(text).lines().count();
        black_box(count);
    });
    let (read, ()) = median(21, || {
        let state = ecology_domain::parse_facts(black_box(text)).expect("parses");
        black_box(state.len());
    });
    let (compiled, ()) = median(21, || {
        let state = ecology_domain::parse_facts(black_box(text)).expect("parses");
        black_box(ecology_config::compile_state(&instance.domain, &state));
    });
    let (prepared, ()) = median(5, || {
        let state = ecology_domain::parse_facts(black_box(text)).expect("parses");
        let request = Request {
            domain: &instance.domain,
            state: &state,
            goal: &instance.goal,
            exclusions: &instance.exclusions,
        };
        let search = Search::new(&request, &PaperCost, &Options::default()).expect("grounds");
        black_box(search.found());
    });
    let rate = |d: Duration| megabytes / d.as_secs_f64();
    println!("{:<44} {:>9} {:>10}", "", "time", "throughput");
    for (what, time) in [
        ("plain line reader (BufRead::lines)", lines),
        ("parse_facts: read, checked, stored once", read),
        ("parse_facts, then interned and indexed", compiled),
        ("parse_facts, then a search prepared", prepared),
    ] {
        println!(
            "{what:<44} {:>6.1} ms {:>6.0} MB/s",
            time.as_secs_f64() * 1e3,
            rate(time)
        );
    }
    println!(
        "read, interned and indexed at {:.0} MB/s (target: at least 100), {:.1}x the plain line reader's time",
        rate(compiled),
        compiled.as_secs_f64() / lines.as_secs_f64()
    );
}
