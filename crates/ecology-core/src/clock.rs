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
