// Small deterministic generators for tests and benches: fixed seeds give
// the same sequences on every run and machine. Shared by the integration
// tests (`common::rng`), the planner bench (`#[path]`) and the unit tests in
// `src/eval.rs` (`include!`), so this file holds plain items and no inner
// attributes or inner doc comments. Not every user takes every generator.

/// 64-bit linear congruential generator (Knuth's MMIX constants); yields the
/// top 31 bits of the state.
#[allow(dead_code)]
pub(crate) struct Lcg(pub u64);

#[allow(dead_code)]
impl Lcg {
    /// The next value, in `0..2^31`.
    pub(crate) fn next(&mut self) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        self.0 >> 33
    }

    /// The next value reduced to `0..n` (`n` > 0).
    pub(crate) fn range(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

/// Marsaglia's xorshift64 (13, 7, 17); the seed must not be zero.
#[allow(dead_code)]
pub(crate) struct XorShift(pub u64);

#[allow(dead_code)]
impl XorShift {
    /// The next state, any `u64` but zero.
    pub(crate) fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    /// The next value as an `f64` in `[0, 1)`.
    pub(crate) fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// xorshift64* (12, 25, 27 and a multiplier); the seed must not be zero.
#[allow(dead_code)]
pub(crate) struct XorShiftStar(pub u64);

#[allow(dead_code)]
impl XorShiftStar {
    /// The next value as an `f64` in `[0, 1)`.
    pub(crate) fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
}
