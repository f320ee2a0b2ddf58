//! Seeded randomness: SplitMix64 from `rand_xoshiro`, so the same seed gives
//! the same synthetic ecology, fault schedule and sensor noise everywhere.
//!
//! The stream is the one the project's own SplitMix64 produced before it
//! moved here (the state is the seed, as `seed_from_u64` sets it), so every
//! seeded scenario, benchmark instance and recorded number is unchanged.

use rand_core::{RngCore, SeedableRng};
use rand_xoshiro::SplitMix64;

/// A seeded generator with the few draws the project needs.
#[derive(Debug, Clone)]
pub struct Rng(SplitMix64);

impl Rng {
    /// A generator from `seed`.
    pub fn new(seed: u64) -> Rng {
        Rng(SplitMix64::seed_from_u64(seed))
    }

    /// A generator for one stream, such as one component, derived from a
    /// seed and a name, so that streams do not depend on each other's use.
    pub fn derive(seed: u64, name: &str) -> Rng {
        // FNV-1a over the name, mixed with the seed.
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        for b in name.bytes() {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
        let mut rng = Rng::new(seed ^ h);
        rng.next_u64();
        rng
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0.next_u64()
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in `0..n` (`n` > 0).
    pub fn below(&mut self, n: u64) -> u64 {
        self.next_u64() % n.max(1)
    }

    /// Uniform in `0..n` (`n` > 0), as an index: [`Rng::below`] for lengths and counts.
    pub fn index(&mut self, n: usize) -> usize {
        // usize is at most 64 bits here, so both conversions are exact.
        usize::try_from(self.below(u64::try_from(n).unwrap_or(u64::MAX))).unwrap_or(0)
    }

    /// Puts `items` in a uniformly random order (Fisher and Yates).
    pub fn shuffle<T>(&mut self, items: &mut [T]) {
        for i in (1..items.len()).rev() {
            items.swap(i, self.index(i + 1));
        }
    }

    /// True with probability `p`.
    pub fn chance(&mut self, p: f64) -> bool {
        self.uniform() <= p
    }

    /// Normally distributed with mean 0 and standard deviation `sigma` (Box–Muller).
    pub fn gaussian(&mut self, sigma: f64) -> f64 {
        let u1 = self.uniform().max(f64::MIN_POSITIVE);
        let u2 = self.uniform();
        sigma * (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

#[cfg(test)]
mod tests {
    use super::Rng;

    /// The SplitMix64 the project wrote by hand before, kept here to pin the stream.
    fn reference(state: &mut u64) -> u64 {
        *state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = *state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    #[test]
    fn the_stream_is_the_one_seeds_always_gave() {
        for seed in [0, 1, 42, 0x05ee_d0f4_a7e5, u64::MAX] {
            let mut rng = Rng::new(seed);
            let mut state = seed;
            for _ in 0..100 {
                assert_eq!(rng.next_u64(), reference(&mut state), "seed {seed}");
            }
        }
    }

    #[test]
    fn draws_stay_in_range() {
        let mut rng = Rng::derive(7, "hsm:ca1");
        for _ in 0..1000 {
            let u = rng.uniform();
            assert!((0.0..1.0).contains(&u));
            assert!(rng.below(5) < 5);
            assert!(rng.gaussian(1.0).is_finite());
        }
    }
}
