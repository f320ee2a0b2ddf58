//! In-process benchmark: set → subscriber throughput and latency (p50/p99) on one core.
//!
//! Run with `cargo bench -p ecology-tuples --bench in_process`.

use std::sync::Arc;
use std::time::{Duration, Instant};

use ecology_tuples::{InProcessSpace, Key, PeisId, PeisOptions, SystemClock, TupleSpace, Value};

const THROUGHPUT_TUPLES: u64 = 2_000_000;
const BATCH: u64 = 1_000;
const LATENCY_SAMPLES: usize = 200_000;

fn percentile(sorted: &[Duration], p: f64) -> Duration {
    let index = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[index.min(sorted.len() - 1)]
}

fn main() {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    runtime.block_on(async {
        let space = InProcessSpace::new(Arc::new(SystemClock));
        let publisher = space
            .join(PeisId::new("publisher").expect("name"), PeisOptions::default())
            .expect("join");
        let subscriber = space
            .join(PeisId::new("subscriber").expect("name"), PeisOptions::default())
            .expect("join");
        let mut sub = subscriber
            .subscribe("publisher:sensor.*".parse().expect("pattern"))
            .await
            .expect("subscribe");
        let key = Key::new("sensor.range").expect("key");
        let payload = Value::bytes(vec![0u8; 64]);

        // Throughput: the publisher sets a batch, the subscriber drains it, on one thread.
        let start = Instant::now();
        let mut received = 0u64;
        for _ in 0..THROUGHPUT_TUPLES / BATCH {
            for _ in 0..BATCH {
                publisher.set(key.clone(), payload.clone()).await.expect("set");
            }
            for _ in 0..BATCH {
                sub.next().await.expect("event");
                received += 1;
            }
        }
        let elapsed = start.elapsed();
        let rate = received as f64 / elapsed.as_secs_f64();
        println!(
            "in-process throughput: {received} tuples of 64 B in {:.3} s = {:.0} tuples/s (target 1,000,000)",
            elapsed.as_secs_f64(),
            rate
        );

        // Latency: one set, then wait for the subscriber to see it.
        let mut latencies = Vec::with_capacity(LATENCY_SAMPLES);
        for _ in 0..LATENCY_SAMPLES {
            let sent = Instant::now();
            publisher.set(key.clone(), payload.clone()).await.expect("set");
            sub.next().await.expect("event");
            latencies.push(sent.elapsed());
        }
        latencies.sort();
        println!(
            "in-process latency set -> subscriber: p50 {:?}, p99 {:?} ({LATENCY_SAMPLES} samples)",
            percentile(&latencies, 0.50),
            percentile(&latencies, 0.99)
        );
        drop(sub);
        space.shutdown().await;
    });
}
