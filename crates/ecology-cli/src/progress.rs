//! A line on stderr saying how a long search is going. It shows only when
//! stderr is a terminal, first after a second and then redrawn once a
//! second, and is erased when the search ends: results, pipes and logs never
//! see it.

use std::io::{IsTerminal, Write};
use std::time::Duration;

/// How long a search runs before its progress shows, and how often it is redrawn.
const EVERY: Duration = Duration::from_secs(1);

/// The progress line of one search.
#[derive(Debug)]
pub struct ProgressLine {
    on: bool,
    next: Duration,
    shown: bool,
}

impl ProgressLine {
    /// A line that shows when `wanted` and stderr is a terminal.
    pub fn new(wanted: bool) -> ProgressLine {
        ProgressLine {
            on: wanted && std::io::stderr().is_terminal(),
            next: EVERY,
            shown: false,
        }
    }

    /// Draws `text()` when a second has passed since it was last drawn;
    /// `elapsed` is the time since the search began.
    pub fn update(&mut self, elapsed: Duration, text: impl FnOnce() -> String) {
        if !self.on || elapsed < self.next {
            return;
        }
        self.next = elapsed + EVERY;
        self.shown = true;
        let mut err = std::io::stderr().lock();
        let _ = write!(err, "\r\x1b[K  … {} s: {}", elapsed.as_secs(), text());
        let _ = err.flush();
    }

    /// Erases the line, if it was drawn.
    pub fn clear(&mut self) {
        if std::mem::take(&mut self.shown) {
            eprint!("\r\x1b[K");
        }
    }
}

/// How a search for the cheapest `noun` stands, for its progress line: the
/// cheapest found so far and the cost below which none exists, when known.
pub fn standing(noun: &str, best: Option<u64>, lower_bound: Option<u64>) -> String {
    let best = match best {
        Some(cost) => format!("the best {noun} so far costs {cost}"),
        None => format!("no {noun} yet"),
    };
    match lower_bound {
        Some(bound) => format!("{best}, none costs less than {bound}"),
        None => best,
    }
}

impl Drop for ProgressLine {
    fn drop(&mut self) {
        self.clear();
    }
}
