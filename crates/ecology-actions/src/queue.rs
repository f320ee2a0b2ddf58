//! The priority queues of the relaxed explorations (LM-cut's `Queue`;
//! h-max, h-add and FF's `OrderedQueue`): Dijkstra-like, so keys are small
//! integers that mostly grow. Small keys go to buckets (no comparisons, no
//! sifting); the rare large ones to a binary heap, so huge action costs
//! cost time, not memory.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// Keys below this go to buckets.
const BUCKETS: u64 = 1 << 14;

/// A min-queue of `(key, item)`.
#[derive(Debug, Clone, Default)]
pub(crate) struct Queue {
    buckets: Vec<Vec<u32>>,
    /// No bucket below this holds an item.
    current: usize,
    /// Items in buckets.
    in_buckets: usize,
    heap: BinaryHeap<Reverse<(u64, u32)>>,
}

impl Queue {
    pub(crate) fn push(&mut self, key: u64, item: u32) {
        if key < BUCKETS {
            let k = key as usize;
            if k >= self.buckets.len() {
                self.buckets.resize_with(k + 1, Vec::new);
            }
            self.buckets[k].push(item);
            self.in_buckets += 1;
            self.current = self.current.min(k);
        } else {
            self.heap.push(Reverse((key, item)));
        }
    }

    /// The item of the smallest key, with its key.
    pub(crate) fn pop(&mut self) -> Option<(u64, u32)> {
        if self.in_buckets > 0 {
            self.advance();
            return self.take();
        }
        self.heap.pop().map(|Reverse(entry)| entry)
    }

    /// Moves to the first bucket holding an item (there is one); whether
    /// that is another bucket.
    fn advance(&mut self) -> bool {
        let from = self.current;
        while self.buckets[self.current].is_empty() {
            self.current += 1;
        }
        self.current != from
    }

    /// Takes an item of the current bucket: every bucket key is below every
    /// heap key.
    fn take(&mut self) -> Option<(u64, u32)> {
        let item = self.buckets[self.current].pop()?;
        self.in_buckets -= 1;
        Some((self.current as u64, item))
    }

    pub(crate) fn clear(&mut self) {
        if self.in_buckets > 0 {
            for b in &mut self.buckets[self.current..] {
                b.clear();
            }
        }
        self.in_buckets = 0;
        self.current = 0;
        self.heap.clear();
    }
}

/// A min-queue of `(key, item)` that pops exactly as a binary heap of
/// `(key, item)` does (equal keys by ascending item), for explorations that
/// never push a key below the last one popped (h-add and h-max: an
/// operator's value is at least its preconditions'). Small keys go to
/// buckets, each sorted once when popping reaches it; an item pushed into
/// the bucket being popped goes in its place. FF's exploration on it makes
/// the same choices as on a heap, faster.
#[derive(Debug, Clone, Default)]
pub(crate) struct OrderedQueue {
    /// The buckets, the one being popped sorted descending when `sorted`
    /// (so its smallest item is taken from the back).
    queue: Queue,
    sorted: bool,
}

impl OrderedQueue {
    /// Pushes `item` under `key`, which must not be below the last key
    /// popped since the last `clear`.
    pub(crate) fn push(&mut self, key: u64, item: u32) {
        let q = &mut self.queue;
        debug_assert!(key >= q.current as u64, "a key below the last popped");
        if self.sorted && key == q.current as u64 {
            let bucket = &mut q.buckets[q.current];
            let at = bucket.partition_point(|&x| x > item);
            bucket.insert(at, item);
            q.in_buckets += 1;
        } else {
            q.push(key, item);
        }
    }

    /// The smallest `(key, item)`.
    pub(crate) fn pop(&mut self) -> Option<(u64, u32)> {
        let q = &mut self.queue;
        if q.in_buckets == 0 {
            return q.heap.pop().map(|Reverse(entry)| entry);
        }
        if q.advance() || !self.sorted {
            q.buckets[q.current].sort_unstable_by(|a, b| b.cmp(a));
            self.sorted = true;
        }
        q.take()
    }

    pub(crate) fn clear(&mut self) {
        self.queue.clear();
        self.sorted = false;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pops_in_key_order_across_buckets_and_heap() {
        let mut q = Queue::default();
        let keys = [5, BUCKETS + 3, 0, 7, 5, BUCKETS - 1, u64::MAX - 1, 2];
        for (i, &k) in keys.iter().enumerate() {
            q.push(k, i as u32);
        }
        let mut popped = Vec::new();
        // A push below the last key popped still comes out first.
        let (k, _) = q.pop().expect("not empty");
        popped.push(k);
        q.push(1, 99);
        while let Some((k, _)) = q.pop() {
            popped.push(k);
        }
        assert_eq!(
            popped,
            vec![0, 1, 2, 5, 5, 7, BUCKETS - 1, BUCKETS + 3, u64::MAX - 1]
        );
        q.push(3, 1);
        q.clear();
        assert_eq!(q.pop(), None);
    }

    #[test]
    fn the_ordered_queue_pops_as_a_heap_does() {
        let mut rng = ecology_core::Rng::new(7);
        for round in 0..200 {
            let mut ordered = OrderedQueue::default();
            let mut heap = BinaryHeap::new();
            // Keys never below the last popped: pushes at the last key
            // (zero-cost operators) and above, some beyond the buckets.
            let mut last = 0;
            for _ in 0..rng.index(20) {
                let key = rng.below(4);
                let item = rng.below(50) as u32;
                ordered.push(key, item);
                heap.push(Reverse((key, item)));
            }
            for step in 0..300 {
                if rng.chance(0.6) {
                    let key = if rng.chance(0.05) {
                        BUCKETS + rng.below(5)
                    } else {
                        last + rng.below(3)
                    };
                    let item = rng.below(50) as u32;
                    ordered.push(key, item);
                    heap.push(Reverse((key, item)));
                } else {
                    let expected = heap.pop().map(|Reverse(e)| e);
                    assert_eq!(ordered.pop(), expected, "round {round}, step {step}");
                    if let Some((key, _)) = expected {
                        last = key;
                    }
                }
            }
            ordered.clear();
            assert_eq!(ordered.pop(), None);
        }
    }
}
