//! The blocks' arithmetic, apart from the module: each kind is a small
//! state machine over time-stamped samples (`time` in synchronized µs), so
//! it is tested without a network or a board.

/// Why a constructor refused its arguments: the one failure code every
/// block class uses ([`BAD_ARGUMENT`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BadArgument;

pub use pipes_core::manager::BAD_ARGUMENT;

fn finite(x: f32) -> Result<f32, BadArgument> {
    x.is_finite().then_some(x).ok_or(BadArgument)
}

/// A threshold crossing, with hysteresis: rises when the value goes above
/// `threshold`, falls when it goes below `threshold - hysteresis`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Comparator {
    threshold: f32,
    hysteresis: f32,
    /// Whether a rise halts the module's axis.
    pub halt: bool,
    above: bool,
    crossings: u32,
    /// When the latest crossing's sample was taken (0: none yet).
    crossed_at: u64,
}

/// What a sample did to a [`Comparator`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Crossing {
    /// Nothing changed.
    None,
    /// It went above the threshold.
    Rose,
    /// It went below the threshold less the hysteresis.
    Fell,
}

impl Comparator {
    /// A comparator; refuses a threshold that is not finite and a
    /// hysteresis that is negative or not finite. It starts below.
    pub fn new(threshold: f32, hysteresis: f32, halt: bool) -> Result<Self, BadArgument> {
        let hysteresis =
            finite(hysteresis).and_then(|h| (h >= 0.0).then_some(h).ok_or(BadArgument))?;
        Ok(Comparator {
            threshold: finite(threshold)?,
            hysteresis,
            halt,
            above: false,
            crossings: 0,
            crossed_at: 0,
        })
    }

    /// Takes the sample `value` taken at `time`. A value that is not a
    /// number changes nothing.
    pub fn sample(&mut self, time: u64, value: f32) -> Crossing {
        let c = if !self.above && value > self.threshold {
            Crossing::Rose
        } else if self.above && value < self.threshold - self.hysteresis {
            Crossing::Fell
        } else {
            return Crossing::None;
        };
        self.above = c == Crossing::Rose;
        self.crossings = self.crossings.wrapping_add(1);
        self.crossed_at = time;
        c
    }

    /// The outputs: the latest crossing's time, whether the value is
    /// above, and the crossings so far.
    pub fn outputs(&self) -> (u64, bool, u32) {
        (self.crossed_at, self.above, self.crossings)
    }
}

/// `gain × value + offset`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scale {
    gain: f32,
    offset: f32,
}

impl Scale {
    /// A scale; both must be finite.
    pub fn new(gain: f32, offset: f32) -> Result<Self, BadArgument> {
        Ok(Scale {
            gain: finite(gain)?,
            offset: finite(offset)?,
        })
    }

    /// The scaled value.
    pub fn apply(&self, value: f32) -> f32 {
        self.gain * value + self.offset
    }
}

/// A first-order low-pass filter that follows the samples' own time
/// stamps, so uneven sample spacing does not change its cutoff.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lowpass {
    /// 2π × cutoff, rad/µs.
    omega_per_us: f32,
    last: Option<(u64, f32)>,
}

impl Lowpass {
    /// A filter with its -3 dB point at `cutoff_hz` (positive, finite).
    pub fn new(cutoff_hz: f32) -> Result<Self, BadArgument> {
        let f = finite(cutoff_hz)?;
        if f <= 0.0 {
            return Err(BadArgument);
        }
        Ok(Lowpass {
            omega_per_us: 2.0 * core::f32::consts::PI * f * 1e-6,
            last: None,
        })
    }

    /// The output after the sample `value` at `time`. The first sample
    /// passes through; a sample no later than the previous one leaves the
    /// output as it was (a repeated reading is not new information).
    pub fn apply(&mut self, time: u64, value: f32) -> f32 {
        let y = match self.last {
            None => value,
            Some((t, y)) if time <= t => {
                return y;
            }
            Some((t, y)) => {
                // Exact for a step held over the interval: 1 - e^(-ω Δt).
                let dt = (time - t) as f32;
                let alpha = 1.0 - libm::expf(-self.omega_per_us * dt);
                y + alpha * (value - y)
            }
        };
        self.last = Some((time, y));
        y
    }
}

/// A clamp to `[min, max]` and, unless `rate` is 0, a limit on how fast the
/// output moves (units per second, by the samples' time stamps).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limiter {
    min: f32,
    max: f32,
    /// Units per µs (0: no rate limit).
    rate_per_us: f32,
    last: Option<(u64, f32)>,
}

impl Limiter {
    /// A limiter; refuses `min > max`, a rate below 0, or anything not
    /// finite.
    pub fn new(min: f32, max: f32, rate: f32) -> Result<Self, BadArgument> {
        let (min, max, rate) = (finite(min)?, finite(max)?, finite(rate)?);
        if min > max || rate < 0.0 {
            return Err(BadArgument);
        }
        Ok(Limiter {
            min,
            max,
            rate_per_us: rate * 1e-6,
            last: None,
        })
    }

    /// The output after the sample `value` at `time`. The first sample is
    /// only clamped; a sample no later than the previous one cannot move
    /// a rate-limited output.
    pub fn apply(&mut self, time: u64, value: f32) -> f32 {
        let clamped = value.max(self.min).min(self.max);
        let y = match self.last {
            Some((t, y)) if self.rate_per_us > 0.0 => {
                let step = self.rate_per_us * time.saturating_sub(t) as f32;
                clamped.max(y - step).min(y + step)
            }
            _ => clamped,
        };
        self.last = Some((time.max(self.last.map_or(0, |l| l.0)), y));
        y
    }
}

/// An event at a synchronized time: armed with a time, it fires once on
/// the first run at or after it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Trigger {
    /// The pin it sets when it fires (`None`: it only sends its event).
    pub pin: Option<(u8, bool)>,
    armed: Option<u64>,
    /// The armed time that fired last: it does not fire again.
    fired_for: Option<u64>,
    fired_at: u64,
    fired: u32,
}

/// [`Trigger`]'s "no pin".
pub const NO_PIN: u8 = 0xff;

impl Trigger {
    /// A trigger that sets `pin` to `level` when it fires; pin
    /// [`NO_PIN`] sets none.
    pub fn new(pin: u8, level: bool) -> Self {
        Trigger {
            pin: (pin != NO_PIN).then_some((pin, level)),
            armed: None,
            fired_for: None,
            fired_at: 0,
            fired: 0,
        }
    }

    /// Runs with the armed time `at` at synchronized time `now`: whether
    /// it fires now. A new `at` re-arms it; each `at` fires once.
    pub fn run(&mut self, at: u64, now: u64) -> bool {
        if self.armed != Some(at) && self.fired_for != Some(at) {
            self.armed = Some(at);
        }
        match self.armed {
            Some(t) if now >= t => {
                self.armed = None;
                self.fired_for = Some(t);
                self.fired_at = now;
                self.fired = self.fired.wrapping_add(1);
                true
            }
            _ => false,
        }
    }

    /// The outputs: when it last fired (synchronized µs; 0: never) and how
    /// often it has.
    pub fn outputs(&self) -> (u64, u32) {
        (self.fired_at, self.fired)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_comparator_crosses_once_each_way_with_hysteresis() {
        let mut c = Comparator::new(1.0, 0.2, true).unwrap();
        let samples = [0.5, 1.0, 1.01, 1.5, 0.9, 0.81, 0.79, 1.2];
        let got: std::vec::Vec<_> = samples
            .iter()
            .enumerate()
            .map(|(i, v)| c.sample(i as u64 * 100, *v))
            .collect();
        use Crossing::*;
        // At the threshold is not above it; between 0.8 and 1.0 it stays up.
        assert_eq!(got, [None, None, Rose, None, None, None, Fell, Rose]);
        assert_eq!(c.outputs(), (700, true, 3));
        assert_eq!(c.sample(800, f32::NAN), None);
        assert!(Comparator::new(f32::INFINITY, 0.0, false).is_err());
        assert!(Comparator::new(1.0, -0.1, false).is_err());
    }

    #[test]
    fn a_lowpass_reaches_63_percent_after_one_time_constant() {
        // 10 Hz: τ = 1/(2π·10) s = 15.915 ms; sampled unevenly.
        let mut l = Lowpass::new(10.0).unwrap();
        assert_eq!(l.apply(0, 0.0), 0.0);
        let mut t = 0u64;
        let mut y = 0.0;
        for (i, dt) in [1000u64, 3000, 500, 4000].iter().cycle().enumerate() {
            if t + dt > 15_915 {
                // The last step lands exactly on τ.
                y = l.apply(15_915, 1.0);
                assert!(i > 3);
                break;
            }
            t += dt;
            y = l.apply(t, 1.0);
        }
        assert!((y - (1.0 - (-1.0f32).exp())).abs() < 1e-4, "{y}");
        // A repeated time stamp is not new information.
        assert_eq!(l.apply(15_915, 100.0), y);
        assert!(Lowpass::new(0.0).is_err());
    }

    #[test]
    fn a_limiter_clamps_and_limits_its_rate() {
        let mut l = Limiter::new(-1.0, 1.0, 10.0).unwrap();
        assert_eq!(l.apply(0, 5.0), 1.0);
        // 10 units/s: 0.01 per ms.
        assert!((l.apply(1000, -5.0) - 0.99).abs() < 1e-6);
        assert!((l.apply(101_000, -5.0) + 0.01).abs() < 1e-5);
        assert_eq!(l.apply(301_000, -5.0), -1.0);
        let mut clamp = Limiter::new(0.0, 2.0, 0.0).unwrap();
        assert_eq!(clamp.apply(0, -3.0), 0.0);
        assert_eq!(clamp.apply(0, 3.0), 2.0);
        assert!(Limiter::new(1.0, 0.0, 0.0).is_err());
        assert!(Limiter::new(0.0, 1.0, -1.0).is_err());
    }

    #[test]
    fn a_trigger_fires_once_per_time() {
        let mut t = Trigger::new(3, true);
        assert_eq!(t.pin, Some((3, true)));
        assert!(!t.run(1000, 999));
        assert!(t.run(1000, 1050));
        assert_eq!(t.outputs(), (1050, 1));
        assert!(!t.run(1000, 2000), "each time fires once");
        assert!(
            t.run(500, 2000),
            "a new time re-arms it, late fires at once"
        );
        assert_eq!(t.outputs(), (2000, 2));
        assert_eq!(Trigger::new(NO_PIN, true).pin, None);
    }

    #[test]
    fn a_scale_is_gain_and_offset() {
        assert_eq!(Scale::new(2.0, -1.0).unwrap().apply(3.0), 5.0);
        assert!(Scale::new(f32::NAN, 0.0).is_err());
    }
}
