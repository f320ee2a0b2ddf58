//! Limits on one search, shared by the configuration and the action planner.

use std::time::Duration;

/// Limits on one search; `None` means unlimited.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Budget {
    /// Nodes expanded at most.
    pub max_expansions: Option<u64>,
    /// Time at most, as measured by the caller's [`Clock`](crate::Clock).
    pub max_time: Option<Duration>,
}
