//! Placeholder replaced by the in-process throughput and latency benchmark.
fn main() {}
