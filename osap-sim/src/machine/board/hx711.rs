//! An HX711-kind bridge converter on two digital pins, emulated bit for
//! bit so the module's own driver reads it: what the simulated load cells
//! ([`super::melt`], [`super::contact`]) weigh with.
//!
//! The converter completes a conversion every `1 / sample_hz`; its data
//! line goes low when one is ready. The 24-bit sample is `offset_counts +
//! counts_per_newton · F + noise`, the force `F` being what its owner
//! reports at the first clock edge of the read-out, and the noise Gaussian
//! of `noise_n` newtons. The module clocks the sample out MSB first on 24
//! rising clock edges; a 25th edge ends the read (channel A, gain 128),
//! and the data line stays high until the next conversion.

use crate::rng::Rng;
use osap_core::Instant;

/// The converter's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hx711Spec {
    /// Conversions a second.
    pub sample_hz: f64,
    /// Counts per newton.
    pub counts_per_newton: f64,
    /// Counts at no force.
    pub offset_counts: f64,
    /// Noise, N (one σ).
    pub noise_n: f64,
    /// The noise's seed.
    pub seed: u64,
}

/// The converter's state.
#[derive(Debug, Clone)]
pub struct Hx711 {
    spec: Hx711Spec,
    rng: Rng,
    /// The read-out: the sample being shifted, edges seen.
    shifting: Option<(u32, u8)>,
    /// When the next conversion is ready.
    next_ready: Instant,
    /// The clock line's level.
    sck: bool,
    /// Samples the module read whole.
    samples_read: u64,
}

/// What a clock edge asks of the converter's owner.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Edge {
    /// Nothing.
    None,
    /// A read-out starts: [`Hx711::load`] the force now.
    Sample,
}

impl Hx711 {
    /// A converter whose first conversion is ready at once.
    pub fn new(spec: Hx711Spec) -> Self {
        Hx711 {
            rng: Rng::new(spec.seed),
            spec,
            shifting: None,
            next_ready: Instant::ZERO,
            sck: false,
            samples_read: 0,
        }
    }

    /// Samples the module read whole.
    pub fn samples_read(&self) -> u64 {
        self.samples_read
    }

    /// The data line at local `now`: low while a conversion waits to be
    /// read, then each bit as it is clocked out.
    pub fn read_data(&self, now: Instant) -> bool {
        match self.shifting {
            Some((sample, edges)) => (sample >> (24 - u32::from(edges))) & 1 == 1,
            None => now < self.next_ready,
        }
    }

    /// The module drives the clock line to `level` at local `now`. On
    /// [`Edge::Sample`] the owner must [`load`](Self::load) the force
    /// before the next edge.
    pub fn write_clock(&mut self, now: Instant, level: bool) -> Edge {
        let rising = level && !self.sck;
        self.sck = level;
        if !rising {
            return Edge::None;
        }
        match self.shifting {
            // A pulse with no conversion ready shifts nothing.
            None if now < self.next_ready => Edge::None,
            None => Edge::Sample,
            Some((sample, edges)) if edges < 24 => {
                self.shifting = Some((sample, edges + 1));
                Edge::None
            }
            // The 25th edge: read done; the next conversion is due a
            // period after the one just read.
            Some(_) => {
                self.samples_read += 1;
                let period = (1e6 / self.spec.sample_hz) as u64;
                let due = self.next_ready.as_micros() + period;
                let now_us = now.as_micros();
                // Conversions not read are overwritten: the next one
                // ready after now.
                let next = if due > now_us {
                    due
                } else {
                    now_us + period - (now_us - due) % period
                };
                self.next_ready = Instant::from_micros(next);
                self.shifting = None;
                Edge::None
            }
        }
    }

    /// Converts `force` newtons: the sample the read-out that just began
    /// shifts out (its first bit is out with this edge).
    pub fn load(&mut self, force: f64) {
        let s = &self.spec;
        let force = force + s.noise_n * self.rng.normal();
        let counts = (s.offset_counts + s.counts_per_newton * force).round();
        let counts = counts.clamp(-8_388_608.0, 8_388_607.0) as i32;
        self.shifting = Some(((counts as u32) & 0x00ff_ffff, 1));
    }
}
