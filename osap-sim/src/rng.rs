//! Seeded randomness: a small PRNG and the delay distributions of the models.
//!
//! The generator is implemented here (xoshiro256++ seeded through SplitMix64)
//! rather than taken from a crate so that a seed gives the same run on every
//! platform and with every dependency version, for as long as this file does
//! not change. Every component of a simulation (each node, each link
//! direction) draws from its own [`Rng::stream`], so adding traffic or a
//! sampler in one place does not shift the random numbers seen elsewhere.

use crate::error::SimError;
use crate::Nanos;

/// A deterministic pseudo-random generator (xoshiro256++).
#[derive(Debug, Clone)]
pub struct Rng {
    s: [u64; 4],
}

/// One step of SplitMix64, used to expand seeds.
fn splitmix64(x: &mut u64) -> u64 {
    *x = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    let mut z = *x;
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

impl Rng {
    /// A generator seeded with `seed`.
    pub fn new(seed: u64) -> Self {
        let mut x = seed;
        let s = [
            splitmix64(&mut x),
            splitmix64(&mut x),
            splitmix64(&mut x),
            splitmix64(&mut x),
        ];
        Rng { s }
    }

    /// An independent stream for component `index` of kind `domain` (for
    /// example `("node", 3)`), derived from the simulation seed.
    pub fn stream(seed: u64, domain: &str, index: u64) -> Self {
        // FNV-1a of the domain keeps streams of different kinds apart.
        let tag = domain.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
            (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
        });
        let mut x = seed ^ tag.rotate_left(17) ^ index.wrapping_mul(0xd6e8_feb8_6659_fd93);
        Rng::new(splitmix64(&mut x))
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        let s = &mut self.s;
        let result = s[0].wrapping_add(s[3]).rotate_left(23).wrapping_add(s[0]);
        let t = s[1] << 17;
        s[2] ^= s[0];
        s[3] ^= s[1];
        s[1] ^= s[2];
        s[0] ^= s[3];
        s[2] ^= t;
        s[3] = s[3].rotate_left(45);
        result
    }

    /// A uniform number in `[0, 1)`.
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// A uniform number in `[lo, hi)`.
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    /// True with probability `p`. Draws nothing when `p <= 0`, so a model
    /// with a feature switched off consumes no randomness for it.
    pub fn chance(&mut self, p: f64) -> bool {
        p > 0.0 && self.unit() < p
    }

    /// A uniform integer in `[0, n)` (`n > 0`).
    pub fn below(&mut self, n: u64) -> u64 {
        // Multiply-shift: unbiased enough for simulation purposes.
        ((u128::from(self.next_u64()) * u128::from(n.max(1))) >> 64) as u64
    }

    /// An exponentially distributed number with the given mean.
    pub fn exponential(&mut self, mean: f64) -> f64 {
        // 1 - unit() is in (0, 1], so the logarithm is finite.
        -mean * (1.0 - self.unit()).ln()
    }

    /// A standard normal number (Box-Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = 1.0 - self.unit();
        let u2 = self.unit();
        (-2.0 * u1.ln()).sqrt() * (core::f64::consts::TAU * u2).cos()
    }
}

/// A distribution of a non-negative delay, in microseconds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Dist {
    /// Always this value.
    Const(f64),
    /// Uniform in `[lo, hi]`.
    Uniform {
        /// Smallest value, µs.
        lo: f64,
        /// Largest value, µs.
        hi: f64,
    },
    /// `min` plus an exponential with mean `mean`: the shape of software
    /// latency on an operating system (a floor and a long tail).
    Exp {
        /// Floor, µs.
        min: f64,
        /// Mean of the exponential part, µs.
        mean: f64,
    },
    /// Normal with `mean` and `sd`, clamped below at `min`.
    Normal {
        /// Mean, µs.
        mean: f64,
        /// Standard deviation, µs.
        sd: f64,
        /// Values below this are raised to it, µs.
        min: f64,
    },
}

impl Default for Dist {
    fn default() -> Self {
        Dist::ZERO
    }
}

impl Dist {
    /// No delay.
    pub const ZERO: Dist = Dist::Const(0.0);

    /// Uniform in `[lo, hi]` µs.
    pub const fn uniform(lo: f64, hi: f64) -> Dist {
        Dist::Uniform { lo, hi }
    }

    /// An exponential with mean `mean` µs above a floor of `min` µs.
    pub const fn exp(min: f64, mean: f64) -> Dist {
        Dist::Exp { min, mean }
    }

    /// The mean, µs (of the unclamped distribution for `Normal`).
    pub fn mean_us(&self) -> f64 {
        match *self {
            Dist::Const(v) => v,
            Dist::Uniform { lo, hi } => (lo + hi) / 2.0,
            Dist::Exp { min, mean } => min + mean,
            Dist::Normal { mean, min, .. } => mean.max(min),
        }
    }

    /// Draws a value, µs.
    pub fn sample_us(&self, rng: &mut Rng) -> f64 {
        match *self {
            Dist::Const(v) => v,
            Dist::Uniform { lo, hi } => rng.uniform(lo, hi),
            Dist::Exp { min, mean } => min + rng.exponential(mean),
            Dist::Normal { mean, sd, min } => (mean + sd * rng.normal()).max(min),
        }
    }

    /// Draws a value, rounded to whole nanoseconds.
    pub fn sample_ns(&self, rng: &mut Rng) -> Nanos {
        us_to_ns(self.sample_us(rng))
    }

    /// Checks that every parameter is finite and no value can be negative;
    /// `what` names the parameter in the error.
    pub fn validate(&self, what: &str) -> Result<(), SimError> {
        let ok = |v: f64| v.is_finite() && v >= 0.0;
        let good = match *self {
            Dist::Const(v) => ok(v),
            Dist::Uniform { lo, hi } => ok(lo) && ok(hi) && lo <= hi,
            Dist::Exp { min, mean } => ok(min) && ok(mean),
            Dist::Normal { mean, sd, min } => mean.is_finite() && ok(sd) && ok(min),
        };
        if good {
            Ok(())
        } else {
            Err(SimError::config(format!(
                "{what}: {self:?} is not a valid delay distribution \
                 (values must be finite and non-negative, lo <= hi)"
            )))
        }
    }
}

/// Microseconds (non-negative, finite) to whole nanoseconds.
pub(crate) fn us_to_ns(us: f64) -> Nanos {
    // Validation keeps inputs finite and non-negative; `as` saturates anyway.
    (us * 1000.0).round().max(0.0) as Nanos
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn streams_are_reproducible_and_distinct() {
        let a: Vec<u64> = (0..4)
            .map({
                let mut r = Rng::stream(7, "node", 1);
                move |_| r.next_u64()
            })
            .collect();
        let b: Vec<u64> = (0..4)
            .map({
                let mut r = Rng::stream(7, "node", 1);
                move |_| r.next_u64()
            })
            .collect();
        let c = Rng::stream(7, "node", 2).next_u64();
        let d = Rng::stream(7, "link", 1).next_u64();
        assert_eq!(a, b);
        assert_ne!(a[0], c);
        assert_ne!(a[0], d);
    }

    #[test]
    fn distributions_have_their_means() {
        let mut r = Rng::new(1);
        let n = 20_000;
        for d in [Dist::uniform(2.0, 20.0), Dist::exp(10.0, 50.0)] {
            let mean = (0..n).map(|_| d.sample_us(&mut r)).sum::<f64>() / n as f64;
            assert!(
                (mean - d.mean_us()).abs() < d.mean_us() * 0.03,
                "{d:?}: {mean}"
            );
        }
        assert!(Dist::uniform(3.0, 1.0).validate("x").is_err());
        assert!(Dist::Const(f64::NAN).validate("x").is_err());
    }
}
