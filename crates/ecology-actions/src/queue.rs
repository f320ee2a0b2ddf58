//! The priority queue of the relaxed explorations (LM-cut, h-max, h-add
//! and FF): Dijkstra-like, so keys are small integers that mostly grow.
//! Small keys go to buckets (no comparisons, no sifting); the rare large
//! ones to a binary heap, so huge action costs cost time, not memory.
//!
//! Within a bucket the item pushed last comes out first, as in Fast
//! Downward's bucket queue. Which supporter h-add keeps for a fact, among
//! those of equal cost, follows from that order, and so do FF's relaxed
//! plans and preferred operators: with it, greedy search expands 208
//! states on childsnack-opt14 pfile03-2 (Fast Downward's eager search:
//! 209) where popping equal keys by ascending fact took 13,040.

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
            while self.buckets[self.current].is_empty() {
                self.current += 1;
            }
            // Every bucket key is below every heap key.
            let item = self.buckets[self.current].pop()?;
            self.in_buckets -= 1;
            return Some((self.current as u64, item));
        }
        self.heap.pop().map(|Reverse(entry)| entry)
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
    fn equal_keys_come_out_last_pushed_first() {
        let mut q = Queue::default();
        for item in [4, 9, 2] {
            q.push(6, item);
        }
        q.push(1, 7);
        let popped: Vec<_> = std::iter::from_fn(|| q.pop()).collect();
        assert_eq!(popped, vec![(1, 7), (6, 2), (6, 9), (6, 4)]);
    }
}
