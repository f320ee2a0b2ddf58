//! What the sans-IO core of Ecology shares, written once: time from the
//! caller ([`Clock`], [`NoClock`], and [`WallClock`] for the edge), limits on a search ([`Budget`]) and
//! seeded randomness ([`Rng`]), and when two probabilities are the same
//! ([`EPSILON`]).
//!
//! It reads no clock, does no IO and depends on no runtime, so the planners
//! (`ecology-config`, `ecology-actions`) and the simulation can all use it.

mod budget;
mod clock;
mod rng;

pub use budget::Budget;
pub use clock::{Clock, NoClock, WallClock};
pub use rng::Rng;

/// Probabilities closer than this are equal (sums of products of floats):
/// for the conditional planner and for the executive running its plans.
pub const EPSILON: f64 = 1e-9;
