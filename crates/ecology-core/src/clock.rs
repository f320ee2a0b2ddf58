//! Time from the caller: the core reads no clock of its own.

use std::time::Duration;

/// Time since a search started, from the caller (the planners read no clock).
pub trait Clock {
    /// Time elapsed since the planner was called.
    fn elapsed(&self) -> Duration;
}

/// A clock that never advances: no time budget, and `micros` reads 0.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoClock;

impl Clock for NoClock {
    fn elapsed(&self) -> Duration {
        Duration::ZERO
    }
}

/// Wall-clock time since the given instant: the one clock that reads the
/// wall, for the callers at the edge (commands, benchmarks, a driver timing
/// its planner). Nothing in the core constructs it.
#[derive(Debug, Clone, Copy)]
pub struct WallClock(pub std::time::Instant);

impl WallClock {
    /// A clock started now.
    pub fn start() -> WallClock {
        WallClock(std::time::Instant::now())
    }
}

impl Clock for WallClock {
    fn elapsed(&self) -> Duration {
        self.0.elapsed()
    }
}
