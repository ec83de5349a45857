//! A simulated heated block on a module's I/O pins: a heater on a PWM
//! output, a thermistor on an analog input (see
//! [`HeaterSpec`](crate::topology::HeaterSpec)).
//!
//! The block follows
//!
//! ```text
//! C·dT/dt = P·duty − loss·(T − ambient)
//! ```
//!
//! The duty only changes when the module writes its PWM output, so between
//! two events (a write, a read) the block relaxes exponentially toward
//! `ambient + P·duty/loss` with time constant `C/loss`; the model steps
//! that in closed form from one event to the next (no integrator error,
//! however far apart). Time is the simulation's, in seconds since the
//! module booted. This is the plant only: the control and the runaway
//! checks are the module's own ([`osap_module::heater`]).

use crate::topology::HeaterSpec;

/// 0 °C in kelvin.
const ZERO_C_IN_K: f64 = 273.15;

/// The running model of one block.
#[derive(Debug, Clone)]
pub struct ThermalHeater {
    spec: HeaterSpec,
    /// The block's temperature at `at`, °C.
    temp: f64,
    /// Seconds since boot the state is at.
    at: f64,
    /// The heater's duty since `at`, a fraction.
    duty: f64,
}

impl ThermalHeater {
    /// A cold block (at the room's temperature) at boot.
    pub fn new(spec: HeaterSpec) -> Self {
        ThermalHeater {
            temp: spec.ambient_c,
            spec,
            at: 0.0,
            duty: 0.0,
        }
    }

    /// What it is.
    pub fn spec(&self) -> &HeaterSpec {
        &self.spec
    }

    /// The block's temperature at `secs` after boot (not before the latest
    /// event), °C.
    pub fn temperature(&self, secs: f64) -> f64 {
        let s = &self.spec;
        let dt = (secs - self.at).max(0.0);
        let heat = s.power_w * self.duty;
        if s.loss_w_per_k > 0.0 {
            let settle = s.ambient_c + heat / s.loss_w_per_k;
            let decay = (-dt * s.loss_w_per_k / s.heat_capacity_j_per_k).exp();
            settle + (self.temp - settle) * decay
        } else {
            // A block that loses nothing heats linearly.
            self.temp + heat * dt / s.heat_capacity_j_per_k
        }
    }

    /// The heater's duty now, a fraction.
    pub fn duty(&self) -> f64 {
        self.duty
    }

    /// Moves the state to `secs` after boot.
    fn advance(&mut self, secs: f64) {
        if secs > self.at {
            self.temp = self.temperature(secs);
            self.at = secs;
        }
    }

    /// The module set the heater's PWM output to `duty` (of 65 535) at
    /// `secs` after boot.
    pub(crate) fn set_duty(&mut self, secs: f64, duty: u16) {
        self.advance(secs);
        self.duty = f64::from(duty) / 65_535.0;
    }

    /// Whether the thermistor reads open at `secs` after boot.
    pub fn sensor_failed(&self, secs: f64) -> bool {
        self.spec.sensor_fails_at_s.is_some_and(|t| secs >= t)
    }

    /// The thermistor's reading at `secs` after boot, a fraction of full
    /// scale: `R / (R + pullup)`, 1 once the sensor failed.
    pub fn read(&mut self, secs: f64) -> f64 {
        self.advance(secs);
        if self.sensor_failed(secs) {
            return 1.0;
        }
        let s = &self.spec;
        let r = thermistor_ohms(s, self.temp);
        r / (r + s.pullup_ohms)
    }
}

/// The thermistor's resistance at `celsius`, Ω.
fn thermistor_ohms(s: &HeaterSpec, celsius: f64) -> f64 {
    let inv_t = 1.0 / (celsius + ZERO_C_IN_K);
    let Some([a, b, c]) = s.steinhart_hart else {
        return s.r25_ohms * (s.beta * (inv_t - 1.0 / (25.0 + ZERO_C_IN_K))).exp();
    };
    // a + b·L + c·L³ = 1/T for L = ln R: Newton from the curve's Beta
    // part; the slope b + 3c·L² is positive (the spec is checked).
    let mut l = (inv_t - a) / b;
    for _ in 0..50 {
        let step = (a + b * l + c * l * l * l - inv_t) / (b + 3.0 * c * l * l);
        l -= step;
        if step.abs() < 1e-12 {
            break;
        }
    }
    l.exp()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hotend() -> HeaterSpec {
        HeaterSpec {
            pwm: 0,
            analog: 0,
            beta: 3950.0,
            r25_ohms: 100_000.0,
            steinhart_hart: None,
            pullup_ohms: 4_700.0,
            power_w: 40.0,
            heat_capacity_j_per_k: 15.0,
            loss_w_per_k: 0.1,
            ambient_c: 25.0,
            sensor_fails_at_s: Some(100.0),
        }
    }

    #[test]
    fn the_block_steps_exactly_and_the_sensor_fails_on_time() {
        let mut h = ThermalHeater::new(hotend());
        assert!((h.read(0.0) - 100.0 / 104.7).abs() < 1e-9, "25 °C: R = R25");
        h.set_duty(0.0, 65_535);
        // One step of 60 s or 6 000 of 10 ms: the same temperature, that of
        // the closed form, 425 − 400·e^(−60/150).
        let want = 425.0 - 400.0 * (-0.4f64).exp();
        let mut fine = ThermalHeater::new(hotend());
        fine.set_duty(0.0, 65_535);
        for k in 1..=6_000 {
            fine.read(f64::from(k) * 0.01);
        }
        assert!((h.temperature(60.0) - want).abs() < 1e-9);
        assert!((fine.temperature(60.0) - want).abs() < 1e-9);
        // Off: it cools toward the room.
        h.set_duty(60.0, 0);
        let cooled = 25.0 + (want - 25.0) * (-0.2f64).exp();
        assert!((h.temperature(90.0) - cooled).abs() < 1e-9);
        assert!(h.read(99.999) < 1.0);
        assert_eq!(h.read(100.0), 1.0, "open from sensor_fails_at_s");
        let mut lossless = hotend();
        lossless.loss_w_per_k = 0.0;
        let mut l = ThermalHeater::new(lossless);
        l.set_duty(0.0, 65_535);
        assert!((l.temperature(3.0) - 33.0).abs() < 1e-9);
    }

    #[test]
    fn bad_specs_are_named() {
        let bad = |f: fn(&mut HeaterSpec)| {
            let mut s = hotend();
            f(&mut s);
            s.check().unwrap_err().to_string()
        };
        assert!(bad(|s| s.pwm = 2).contains("pwm 2"));
        assert!(bad(|s| s.analog = 3).contains("analog 3"));
        assert!(bad(|s| s.beta = 0.0).contains("beta"));
        assert!(bad(|s| s.heat_capacity_j_per_k = f64::NAN).contains("heat_capacity_j_per_k"));
        assert!(bad(|s| s.power_w = -1.0).contains("power_w"));
        assert!(bad(|s| s.loss_w_per_k = f64::INFINITY).contains("loss_w_per_k"));
        assert!(bad(|s| s.ambient_c = -300.0).contains("ambient_c"));
        assert!(bad(|s| s.sensor_fails_at_s = Some(-1.0)).contains("sensor_fails_at_s"));
        assert!(bad(|s| s.steinhart_hart = Some([1e-3, -1e-4, 0.0])).contains("steinhart_hart"));
        assert!(bad(|s| s.steinhart_hart = Some([1e-3, 2e-4, -1e-6])).contains("fall"));
        assert_eq!(hotend().check(), Ok(()));
    }

    #[test]
    fn a_steinhart_hart_thermistor_reads_its_own_curve() {
        // A curve with a real cubic term (EPCOS 100K's, through its
        // datasheet points); at each temperature the resistance the sim
        // gives maps back through the curve to that temperature.
        let (a, b, c) = (7.221_363e-4, 2.167_666e-4, 8.929_358e-8);
        let spec = HeaterSpec {
            steinhart_hart: Some([a, b, c]),
            ..hotend()
        };
        assert_eq!(spec.check(), Ok(()));
        for celsius in [0.0, 25.0, 150.0, 250.0, 300.0] {
            let l = thermistor_ohms(&spec, celsius).ln();
            let back = 1.0 / (a + b * l + c * l * l * l) - ZERO_C_IN_K;
            assert!(
                (back - celsius).abs() < 1e-9,
                "{celsius} °C came back {back}"
            );
        }
        // Without the cubic term it is the Beta model it names.
        let beta = HeaterSpec {
            steinhart_hart: Some([1.0 / 298.15 - 1e5f64.ln() / 3950.0, 1.0 / 3950.0, 0.0]),
            ..hotend()
        };
        for celsius in [25.0, 210.0] {
            let (x, y) = (
                thermistor_ohms(&beta, celsius),
                thermistor_ohms(&hotend(), celsius),
            );
            assert!((x / y - 1.0).abs() < 1e-9, "{celsius} °C: {x} Ω, not {y}");
        }
    }
}
