//! A load cell under the module's axis that presses a bed: a nozzle
//! load-cell probe ([`ContactSpec`], `[module.io.contact]`).
//!
//! The module's own carriage is the tip: past `touch_at` the bed pushes
//! back with `stiffness_n_per_unit` newtons per unit, and nothing before
//! it. Steps are clocked out ahead of time and move the tip when due, so
//! the force at a conversion is the one where the carriage is at that
//! instant. An HX711-kind converter ([`super::hx711`]) weighs it.

use super::hx711::{Edge, Hx711, Hx711Spec};
use crate::topology::ContactSpec;
use osap_core::Instant;
use std::collections::VecDeque;

/// The bed contact and its converter.
#[derive(Debug, Clone)]
pub struct Contact {
    spec: ContactSpec,
    cell: Hx711,
    /// Where the carriage is as of `at`.
    position: f64,
    /// Carriage positions clocked out but not yet due: (local time, position).
    pending: VecDeque<(Instant, f64)>,
    /// The largest force the bed has pushed with, N.
    peak_n: f64,
}

impl Contact {
    /// A contact with the carriage at `position`.
    pub fn new(spec: ContactSpec, position: f64) -> Self {
        let cell = Hx711::new(Hx711Spec {
            sample_hz: spec.sample_hz,
            counts_per_newton: spec.counts_per_newton,
            offset_counts: spec.offset_counts,
            noise_n: spec.noise_n,
            seed: spec.seed,
        });
        Contact {
            spec,
            cell,
            position,
            pending: VecDeque::new(),
            peak_n: 0.0,
        }
    }

    /// What it is.
    pub fn spec(&self) -> &ContactSpec {
        &self.spec
    }

    /// The largest force the bed has pushed with so far, N (as of the
    /// latest conversion).
    pub fn peak_force(&self) -> f64 {
        self.peak_n
    }

    /// The carriage is at `position` from local `local` on.
    pub fn step(&mut self, local: Instant, position: f64) {
        self.pending.push_back((local, position));
    }

    /// The force the bed pushes with at local `now`, N.
    pub fn force(&mut self, now: Instant) -> f64 {
        while let Some(&(t, p)) = self.pending.front() {
            if t > now {
                break;
            }
            self.position = p;
            self.pending.pop_front();
        }
        let past = if self.spec.pressing_below {
            self.spec.touch_at - self.position
        } else {
            self.position - self.spec.touch_at
        };
        let f = self.spec.stiffness_n_per_unit * past.max(0.0);
        self.peak_n = self.peak_n.max(f);
        f
    }

    /// The converter's data line at local `now`.
    pub fn read_data(&self, now: Instant) -> bool {
        self.cell.read_data(now)
    }

    /// The module drives the converter's clock line to `level` at local
    /// `now`.
    pub fn write_clock(&mut self, now: Instant, level: bool) {
        if self.cell.write_clock(now, level) == Edge::Sample {
            let f = self.force(now);
            self.cell.load(f);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec() -> ContactSpec {
        ContactSpec {
            touch_at: -2.0,
            pressing_below: true,
            stiffness_n_per_unit: 40.0,
            data_pin: 0,
            clock_pin: 1,
            sample_hz: 320.0,
            counts_per_newton: 2000.0,
            offset_counts: 0.0,
            noise_n: 0.0,
            seed: 0,
        }
    }

    #[test]
    fn the_bed_pushes_back_only_past_the_touch_and_when_the_step_is_due() {
        let mut c = Contact::new(spec(), 0.0);
        let at = |us| Instant::from_micros(us);
        c.step(at(1000), -1.9);
        c.step(at(2000), -2.1);
        assert_eq!(c.force(at(1500)), 0.0);
        assert_eq!(c.force(at(1999)), 0.0, "clocked out, not yet due");
        assert!((c.force(at(2000)) - 4.0).abs() < 1e-9);
        assert!((c.peak_force() - 4.0).abs() < 1e-9);
    }

    #[test]
    fn a_read_out_shifts_the_force_at_its_first_edge() {
        let mut c = Contact::new(spec(), -2.5);
        let now = Instant::from_micros(10);
        assert!(!c.read_data(now), "a conversion is ready at once");
        let mut sample = 0u32;
        for edge in 0..24 {
            c.write_clock(Instant::from_micros(20 + 2 * edge), true);
            sample = (sample << 1) | u32::from(c.read_data(now));
            c.write_clock(Instant::from_micros(21 + 2 * edge), false);
        }
        c.write_clock(Instant::from_micros(80), true);
        assert_eq!(sample, 40_000, "20 N at 2 000 counts per newton");
        assert!(
            c.read_data(Instant::from_micros(81)),
            "busy until the next conversion"
        );
    }
}
