//! A simulated melt behind the module's extruder, and the load cell that
//! weighs the filament's push (an HX711 bridge converter on two digital
//! pins, emulated bit for bit so the module's own driver reads it).
//!
//! **Flow.** Each microstep the drive takes pushes `δV = area · step`
//! mm³ of filament into the melt zone. The melt leaves the nozzle at the
//! outflow `Q` (mm³/s), which follows the inflow as a first-order lag of
//! `response_ms` (the melt zone's compliance), integrated exactly between
//! steps: a step adds `δV / τ` to `Q`, which decays as `e^(−t/τ)`
//! between steps. The filament needs the force of the melt law at that
//! outflow and the block's temperature,
//!
//! ```text
//! F = flow_k · Q^flow_n · exp(−temp_coeff · (T − t_ref))
//! ```
//!
//! **Slip.** While `F` exceeds the drive's grip (`grip_n`, the machine
//! file's `max_force_n`), a step the drive takes does not move the
//! filament: it is counted as slipped (under-extrusion) and adds no melt.
//!
//! **Load cell.** An HX711 ([`super::hx711`]) converts `F_s`, the force
//! through the cell's own first-order lag (`sensor_tau_ms`), every
//! `1 / sample_hz`.

use super::hx711::{Edge, Hx711, Hx711Spec};
use crate::topology::MeltSpec;
use osap_core::Instant;
use std::collections::VecDeque;

/// The running melt and its load cell.
#[derive(Debug, Clone)]
pub struct Melt {
    spec: MeltSpec,
    /// Filament cross-section, mm².
    area: f64,
    /// Outflow, mm³/s.
    q: f64,
    /// The void a retraction left above the melt, mm³: the next push
    /// fills it before it presses on the melt.
    gap: f64,
    /// The force through the cell's lag, N.
    sensed: f64,
    /// Local time the state is at.
    at: Instant,
    /// Steps clocked out but not yet due: (local time, filament mm).
    pending: VecDeque<(Instant, f64)>,
    /// The block's temperature now, °C (set by the board).
    temp_c: f64,
    stats: MeltStats,
    /// The load cell's converter.
    cell: Hx711,
    /// Whether the last step the drive took slipped.
    slipping: bool,
}

/// What the melt did: the counts a test or `osap run` reports.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct MeltStats {
    /// Filament pushed into the melt, mm.
    pub pushed_mm: f64,
    /// Filament the drive stepped while it slipped, mm.
    pub slipped_mm: f64,
    /// Times the filament began to slip.
    pub slips: u64,
    /// The largest force on the filament, N.
    pub peak_force_n: f64,
    /// Samples the load cell converted and the module read.
    pub samples_read: u64,
}

impl Melt {
    /// A melt at rest, its block at `ambient_c`.
    pub fn new(spec: MeltSpec, ambient_c: f64) -> Self {
        let r = spec.filament_diameter / 2.0;
        let cell = Hx711::new(Hx711Spec {
            sample_hz: spec.sample_hz,
            counts_per_newton: spec.counts_per_newton,
            offset_counts: spec.offset_counts,
            noise_n: spec.noise_n,
            seed: spec.seed,
        });
        Melt {
            area: std::f64::consts::PI * r * r,
            spec,
            q: 0.0,
            gap: 0.0,
            sensed: 0.0,
            at: Instant::ZERO,
            pending: VecDeque::new(),
            temp_c: ambient_c,
            stats: MeltStats::default(),
            cell,
            slipping: false,
        }
    }

    /// What it is.
    pub fn spec(&self) -> &MeltSpec {
        &self.spec
    }

    /// What it did.
    pub fn stats(&self) -> MeltStats {
        MeltStats {
            samples_read: self.cell.samples_read(),
            ..self.stats
        }
    }

    /// The outflow now, mm³/s.
    pub fn outflow(&self) -> f64 {
        self.q
    }

    /// The force the melt law gives at outflow `q` and the block's
    /// temperature, N.
    pub fn force_at(&self, q: f64) -> f64 {
        let s = &self.spec;
        if q <= 0.0 {
            return 0.0;
        }
        s.flow_k * q.powf(s.flow_n) * (-s.temp_coeff * (self.temp_c - s.t_ref)).exp()
    }

    /// The force on the filament now, N.
    pub fn force(&self) -> f64 {
        self.force_at(self.q)
    }

    /// The drive moved the filament by `delta_mm` at local `local` (steps
    /// are clocked out ahead of time and act when due); the melt runs on
    /// to local `now`.
    pub fn step(&mut self, local: Instant, delta_mm: f64, now: Instant) {
        self.pending.push_back((local, delta_mm));
        self.advance(now);
    }

    /// The block's temperature, °C, from now on.
    pub fn set_temperature(&mut self, celsius: f64) {
        self.temp_c = celsius;
    }

    fn tau(&self) -> f64 {
        self.spec.response_ms / 1000.0
    }

    /// Decays the outflow, and lags the sensed force behind the force,
    /// over `dt` seconds.
    fn relax(&mut self, dt: f64) {
        if dt <= 0.0 {
            return;
        }
        let force = self.force();
        let ts = self.spec.sensor_tau_ms / 1000.0;
        self.sensed = if ts > 0.0 {
            force + (self.sensed - force) * (-dt / ts).exp()
        } else {
            force
        };
        self.q *= (-dt / self.tau()).exp();
    }

    /// The drive moves `volume` mm³ of filament (negative: retracts). The
    /// melt holds `q·τ` mm³ pressed: a retraction first relieves that,
    /// and what it pulls back beyond leaves a void; a push first fills
    /// the void, then presses the melt.
    fn press(&mut self, volume: f64) {
        let tau = self.tau();
        if volume < 0.0 {
            let pressed = self.q.max(0.0) * tau;
            let relieved = (-volume).min(pressed);
            self.q -= relieved / tau;
            self.gap += -volume - relieved;
        } else {
            let filled = volume.min(self.gap);
            self.gap -= filled;
            self.q += (volume - filled) / tau;
        }
    }

    /// Advances to local `now`, applying the steps due.
    fn advance(&mut self, now: Instant) {
        while let Some(&(t, d)) = self.pending.front() {
            if t > now {
                break;
            }
            self.pending.pop_front();
            let t = t.max(self.at);
            self.relax((t - self.at).as_secs_f64());
            self.at = t;
            let force = self.force();
            if force > self.spec.grip_n && d > 0.0 {
                if !self.slipping {
                    self.stats.slips += 1;
                    self.slipping = true;
                }
                self.stats.slipped_mm += d;
                continue;
            }
            self.slipping = false;
            self.stats.pushed_mm += d;
            self.press(d * self.area);
            self.stats.peak_force_n = self.stats.peak_force_n.max(self.force());
        }
        if now > self.at {
            self.relax((now - self.at).as_secs_f64());
            self.at = now;
        }
    }

    /// The converter's data line at local `now`.
    pub fn read_data(&mut self, now: Instant) -> bool {
        self.cell.read_data(now)
    }

    /// The module drives the converter's clock line to `level` at local
    /// `now`; a read-out that starts converts the sensed force then.
    pub fn write_clock(&mut self, now: Instant, level: bool) {
        if self.cell.write_clock(now, level) == Edge::Sample {
            self.advance(now);
            self.cell.load(self.sensed);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use osap_core::Duration;

    fn secs(s: f64) -> Duration {
        Duration::from_micros((s * 1e6).round() as u64)
    }

    fn pla() -> MeltSpec {
        MeltSpec {
            flow_k: 8.0,
            flow_n: 0.6,
            temp_coeff: 0.02,
            t_ref: 210.0,
            response_ms: 60.0,
            noise_n: 0.0,
            grip_n: 40.0,
            ..MeltSpec::default()
        }
    }

    /// Pushes filament at `mm_s` for `secs` in steps of `step_mm`.
    fn push(m: &mut Melt, from: Instant, mm_s: f64, duration: f64, step_mm: f64) -> Instant {
        let n = (mm_s * duration / step_mm).round() as u64;
        let dt = step_mm / mm_s;
        for k in 1..=n {
            m.step(from + secs(dt * k as f64), step_mm, from);
        }
        let end = from + secs(duration);
        m.advance(end);
        end
    }

    #[test]
    fn a_steady_push_settles_to_its_flow_with_the_response_time() {
        let mut m = Melt::new(pla(), 210.0);
        m.set_temperature(210.0);
        let step = 1.0 / 400.0;
        let v = 2.0; // mm/s of 1.75 mm filament: 4.81 mm³/s
        let q = v * m.area;
        // One τ in: 1 − 1/e of the flow.
        let t = push(&mut m, Instant::ZERO, v, 0.060, step);
        assert!(
            (m.outflow() / q - (1.0 - (-1.0f64).exp())).abs() < 0.02,
            "{}",
            m.outflow() / q
        );
        push(&mut m, t, v, 1.0, step);
        // Settled: the flow within the step ripple (δV/τ), the force the law's.
        assert!((m.outflow() / q - 1.0).abs() < 0.02, "{}", m.outflow() / q);
        let law = 8.0 * q.powf(0.6);
        assert!(
            (m.force() / law - 1.0).abs() < 0.01,
            "{} vs {law}",
            m.force()
        );
        assert_eq!(m.stats().slips, 0);
        assert!((m.stats().pushed_mm - 2.12).abs() < 1e-9);
    }

    #[test]
    fn past_the_grip_the_filament_slips_and_is_counted() {
        let mut m = Melt::new(pla(), 180.0);
        m.set_temperature(180.0); // cold: 1.8× the force at 210 °C
        let step = 1.0 / 400.0;
        // 20 mm/s of filament: 48 mm³/s, far past what 40 N pushes.
        push(&mut m, Instant::ZERO, 20.0, 1.0, step);
        let s = m.stats();
        assert!(s.slips >= 1 && s.slipped_mm > 10.0, "{s:?}");
        assert!(s.pushed_mm + s.slipped_mm > 19.99);
        // The force stays at the grip: a step is refused above it.
        assert!(s.peak_force_n < 40.0 * 1.05, "{s:?}");
    }

    /// A slicer's retraction and unretraction (0.8 mm at 35 mm/s) between
    /// two extrusions: the unretraction fills the void the retraction
    /// left and presses the melt back only as it was, where the same
    /// 0.8 mm pushed into a full nozzle slips the filament.
    #[test]
    fn an_unretraction_fills_the_void_of_its_retraction() {
        let mut m = Melt::new(pla(), 210.0);
        m.set_temperature(210.0);
        let step = 1.0 / 400.0;
        let t = push(&mut m, Instant::ZERO, 2.0, 1.0, step);
        let steady = m.force();
        let t = retract(&mut m, t, 35.0, 0.8, step);
        assert!(m.outflow() <= 1e-9, "{}", m.outflow());
        let t = push(&mut m, t + secs(0.2), 35.0, 0.8 / 35.0, step);
        // The melt pressed as it was before the retraction, no more.
        assert!(
            m.force() < steady * 1.01,
            "{} N, steady {steady} N",
            m.force()
        );
        push(&mut m, t, 2.0, 1.0, step);
        let s = m.stats();
        assert_eq!(s.slips, 0, "{s:?}");
        assert!(s.peak_force_n < steady * 1.02, "{s:?}, steady {steady}");
        // Into a full nozzle, the same push slips.
        let mut full = Melt::new(pla(), 210.0);
        full.set_temperature(210.0);
        let t = push(&mut full, Instant::ZERO, 2.0, 1.0, step);
        push(&mut full, t, 35.0, 0.8 / 35.0, step);
        assert!(full.stats().slips >= 1, "{:?}", full.stats());
    }

    /// Pulls `mm` of filament back at `mm_s`.
    fn retract(m: &mut Melt, from: Instant, mm_s: f64, mm: f64, step_mm: f64) -> Instant {
        let n = (mm / step_mm).round() as u64;
        let dt = step_mm / mm_s;
        for k in 1..=n {
            m.step(from + secs(dt * k as f64), -step_mm, from);
        }
        let end = from + secs(dt * n as f64);
        m.advance(end);
        end
    }

    #[test]
    fn the_load_cell_is_read_bit_by_bit_at_its_rate() {
        let mut m = Melt::new(
            MeltSpec {
                offset_counts: 120_000.0,
                counts_per_newton: 5_000.0,
                ..pla()
            },
            210.0,
        );
        // Ready at once: data low; 24 rising edges shift out the sample.
        let t0 = Instant::from_micros(1_000);
        assert!(!m.read_data(t0));
        let mut sample = 0u32;
        for _ in 0..24 {
            m.write_clock(t0, true);
            sample = sample << 1 | u32::from(m.read_data(t0));
            m.write_clock(t0, false);
        }
        m.write_clock(t0, true);
        m.write_clock(t0, false);
        assert_eq!(sample, 120_000, "no force: the offset");
        assert_eq!(m.stats().samples_read, 1);
        // Not ready again until the next conversion, 12.5 ms after the
        // one read (conversions run on from boot).
        assert!(m.read_data(Instant::from_micros(12_499)));
        assert!(!m.read_data(Instant::from_micros(12_500)));
        // A negative reading comes out in two's complement.
        let mut neg = Melt::new(
            MeltSpec {
                offset_counts: -5.0,
                ..pla()
            },
            210.0,
        );
        let mut sample = 0u32;
        for _ in 0..24 {
            neg.write_clock(t0, true);
            sample = sample << 1 | u32::from(neg.read_data(t0));
            neg.write_clock(t0, false);
        }
        assert_eq!(sample, 0x00ff_fffb);
    }

    #[test]
    fn bad_melts_are_named() {
        let bad = |f: fn(&mut MeltSpec)| {
            let mut s = MeltSpec::default();
            f(&mut s);
            s.check().unwrap_err().to_string()
        };
        assert!(bad(|s| s.flow_k = 0.0).contains("flow_k"));
        assert!(bad(|s| s.flow_n = 2.0).contains("flow_n"));
        assert!(bad(|s| s.response_ms = f64::NAN).contains("response_ms"));
        assert!(bad(|s| s.noise_n = -1.0).contains("noise_n"));
        assert!(bad(|s| s.clock_pin = 0).contains("same pin"));
        assert!(bad(|s| s.data_pin = 9).contains("data_pin 9"));
        assert_eq!(MeltSpec::default().check(), Ok(()));
        // The melt is in a heater's block.
        let io = crate::topology::IoSpec {
            melt: Some(MeltSpec::default()),
            ..Default::default()
        };
        assert!(io.check().unwrap_err().to_string().contains("heater_pwm 0"));
    }
}
