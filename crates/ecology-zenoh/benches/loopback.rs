//! Placeholder replaced by the Zenoh loopback benchmark.
fn main() {}
