//! Frequency sweeps for system identification, sampled at the timer's stamps.
//!
//! A chirp from `f0` to `f1` Hz over `duration` seconds, started at stamp
//! `t_s`, is at `τ = (t − t_s)` seconds
//!
//! ```text
//! position(τ) = center + amplitude · w(τ) · sin φ(τ)
//! linear:       f(τ) = f0 + (f1 − f0) τ / T      φ(τ) = 2π (f0 τ + (f1 − f0) τ² / 2T)
//! exponential:  f(τ) = f0 · k^(τ/T), k = f1/f0    φ(τ) = 2π f0 T (k^(τ/T) − 1) / ln k
//! ```
//!
//! The phase is computed in closed form from the integer µs since the start
//! (exact in `f64`), never accumulated, so the millionth cycle is as exact as
//! the first. `w` is 1, or with a fade of `F` seconds a raised cosine
//! `(1 − cos(π τ/F))/2` over the first and last `F` seconds: position and
//! velocity are then zero relative to `center` at both ends, so the axis
//! starts and ends at rest. Before the start and after the end the position
//! is `center`. Frequencies are not checked against the stamp rate: keep `f1`
//! well under half the sampling rate (`1/(2Δt)`).
//!
//! # PIPES class `Chirp` ([`ChirpBlock`])
//!
//! | member | inputs | outputs |
//! |---|---|---|
//! | constructor `Chirp` | `f0: f32, f1: f32, duration_s: f32, amplitude: f32, exponential: bool` | |
//! | `Chirp.start` | `at: u64` (a stamp; 0: the next stamp sampled) | |
//! | `Chirp.sample` | `stamp: u64` | `stamp: u64, position: f32` |
//! | `Chirp.done` | | `done: bool` |
//! | `Chirp.set_center` | `center: f32` | |
//! | `Chirp.set_fade` | `fade_s: f32` | |
//!
//! The constructor's chirp has center 0 and no fade. Failure code 1
//! ([`FAIL_BAD_NUMBER`], from the constructor, `set_center` and `set_fade`): a bad
//! number (not finite; a frequency < 0, or ≤ 0 for an exponential chirp; a
//! duration ≤ 0 or over 10⁶ s; an amplitude < 0; a fade < 0 or over half the
//! duration). `sample` and `done` do not fail.

use std::f64::consts::PI;
use std::fmt;

use pipes_core::function::CallError;

/// The longest chirp, seconds (keeps every time exact in `f64` µs).
pub const MAX_DURATION_S: f64 = 1e6;

/// `Chirp` failure code: a bad number.
pub const FAIL_BAD_NUMBER: u8 = 1;

/// Which chirp parameter is out of its domain. Every one is failure code
/// [`FAIL_BAD_NUMBER`] on the wire.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum ChirpError {
    /// A parameter is not finite.
    NotFinite,
    /// An exponential chirp has a frequency that is not positive.
    ExponentialNeedsPositive,
    /// A frequency is negative.
    NegativeFrequency,
    /// The duration is not positive or longer than 1e6 s.
    BadDuration,
    /// The amplitude is negative.
    NegativeAmplitude,
    /// The fade is negative or longer than half the duration.
    BadFade,
}

impl fmt::Display for ChirpError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let what = match self {
            ChirpError::NotFinite => "every parameter must be finite",
            ChirpError::ExponentialNeedsPositive => "an exponential chirp needs f0 > 0 and f1 > 0",
            ChirpError::NegativeFrequency => "frequencies must be >= 0",
            ChirpError::BadDuration => "duration must be > 0 and at most 1e6 s",
            ChirpError::NegativeAmplitude => "amplitude must be >= 0",
            ChirpError::BadFade => "fade must be >= 0 and at most half the duration",
        };
        write!(f, "bad chirp parameter: {what}")
    }
}

impl core::error::Error for ChirpError {}

impl From<ChirpError> for CallError {
    fn from(_: ChirpError) -> CallError {
        CallError::Failed(pipes_core::FailureCode::from_code(FAIL_BAD_NUMBER))
    }
}

/// A chirp's parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChirpConfig {
    /// Start frequency, Hz.
    pub f0: f64,
    /// End frequency, Hz.
    pub f1: f64,
    /// Duration, s.
    pub duration_s: f64,
    /// Peak deviation from `center`.
    pub amplitude: f64,
    /// The rest position.
    pub center: f64,
    /// Exponential (logarithmic) sweep instead of linear.
    pub exponential: bool,
    /// Fade-in and fade-out length, s (0: none).
    pub fade_s: f64,
}

impl ChirpConfig {
    fn check(&self) -> Result<(), ChirpError> {
        let finite = [
            self.f0,
            self.f1,
            self.duration_s,
            self.amplitude,
            self.center,
            self.fade_s,
        ]
        .iter()
        .all(|x| x.is_finite());
        if !finite {
            return Err(ChirpError::NotFinite);
        }
        if self.exponential && (self.f0 <= 0.0 || self.f1 <= 0.0) {
            return Err(ChirpError::ExponentialNeedsPositive);
        }
        if self.f0 < 0.0 || self.f1 < 0.0 {
            return Err(ChirpError::NegativeFrequency);
        }
        if self.duration_s <= 0.0 || self.duration_s > MAX_DURATION_S {
            return Err(ChirpError::BadDuration);
        }
        if self.amplitude < 0.0 {
            return Err(ChirpError::NegativeAmplitude);
        }
        if self.fade_s < 0.0 || self.fade_s > self.duration_s / 2.0 {
            return Err(ChirpError::BadFade);
        }
        Ok(())
    }
}

/// When the chirp starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Start {
    Idle,
    NextSample,
    At(u64),
}

/// A frequency sweep (see the module docs).
#[derive(Clone, Debug)]
pub struct Chirp {
    cfg: ChirpConfig,
    start: Start,
    last_stamp: Option<u64>,
}

impl Chirp {
    /// A chirp, not started.
    pub fn new(cfg: ChirpConfig) -> Result<Chirp, ChirpError> {
        cfg.check()?;
        Ok(Chirp {
            cfg,
            start: Start::Idle,
            last_stamp: None,
        })
    }

    /// The parameters.
    pub fn config(&self) -> &ChirpConfig {
        &self.cfg
    }

    /// Sets the rest position.
    pub fn set_center(&mut self, center: f64) -> Result<(), ChirpError> {
        self.reconfigure(ChirpConfig { center, ..self.cfg })
    }

    /// Sets the fade length, s.
    pub fn set_fade(&mut self, fade_s: f64) -> Result<(), ChirpError> {
        self.reconfigure(ChirpConfig { fade_s, ..self.cfg })
    }

    fn reconfigure(&mut self, cfg: ChirpConfig) -> Result<(), ChirpError> {
        cfg.check()?;
        self.cfg = cfg;
        Ok(())
    }

    /// Starts the sweep at stamp `at` (µs); `None`: at the next stamp
    /// sampled.
    pub fn start(&mut self, at: Option<u64>) {
        self.start = match at {
            Some(t) => Start::At(t),
            None => Start::NextSample,
        };
        self.last_stamp = None;
    }

    /// The start stamp, once known.
    pub fn start_us(&self) -> Option<u64> {
        match self.start {
            Start::At(t) => Some(t),
            _ => None,
        }
    }

    /// The duration in whole µs.
    pub fn duration_us(&self) -> u64 {
        (self.cfg.duration_s * 1e6).round() as u64
    }

    /// The end stamp, once the start is known.
    pub fn end_us(&self) -> Option<u64> {
        self.start_us()
            .map(|s| s.saturating_add(self.duration_us()))
    }

    /// Instantaneous frequency `tau` seconds into the sweep, Hz.
    pub fn frequency(&self, tau: f64) -> f64 {
        let c = &self.cfg;
        let x = tau / c.duration_s;
        if c.exponential {
            c.f0 * (c.f1 / c.f0).powf(x)
        } else {
            c.f0 + (c.f1 - c.f0) * x
        }
    }

    /// Phase `tau` seconds into the sweep, radians (closed form).
    pub fn phase(&self, tau: f64) -> f64 {
        let c = &self.cfg;
        let t = c.duration_s;
        let cycles = if !c.exponential {
            c.f0 * tau + (c.f1 - c.f0) * tau * tau / (2.0 * t)
        } else {
            let ln_k = (c.f1 / c.f0).ln();
            if ln_k.abs() < 1e-12 {
                c.f0 * tau
            } else {
                // exp_m1 keeps the small-τ phase exact.
                c.f0 * t * (ln_k * tau / t).exp_m1() / ln_k
            }
        };
        2.0 * PI * cycles
    }

    /// The fade envelope `tau` seconds into the sweep (0..=1).
    pub fn envelope(&self, tau: f64) -> f64 {
        let (f, t) = (self.cfg.fade_s, self.cfg.duration_s);
        if f <= 0.0 {
            return 1.0;
        }
        let edge = tau.min(t - tau);
        if edge >= f {
            1.0
        } else {
            0.5 * (1.0 - (PI * edge.max(0.0) / f).cos())
        }
    }

    /// The position at `t` (µs) for a sweep started at `start` (µs); pure.
    pub fn position_from(&self, start: u64, t: u64) -> f64 {
        let c = &self.cfg;
        if t < start || t - start >= self.duration_us() {
            return c.center;
        }
        let tau = (t - start) as f64 * 1e-6;
        c.center + c.amplitude * self.envelope(tau) * self.phase(tau).sin()
    }

    /// The position at `stamp`; `center` before the start and after the
    /// end. A start "at the next stamp" is fixed here.
    pub fn sample(&mut self, stamp: u64) -> f64 {
        if self.start == Start::NextSample {
            self.start = Start::At(stamp);
        }
        self.last_stamp = Some(self.last_stamp.map_or(stamp, |l| l.max(stamp)));
        match self.start {
            Start::At(s) => self.position_from(s, stamp),
            _ => self.cfg.center,
        }
    }

    /// Whether a stamp at or after the end has been sampled.
    pub fn done(&self) -> bool {
        match (self.end_us(), self.last_stamp) {
            (Some(end), Some(last)) => last >= end,
            _ => false,
        }
    }
}

/// A [`Chirp`] as the PIPES class `Chirp` (see the module docs).
///
/// Its methods are the class's members, in `f32`; the chirp itself is the
/// public field.
#[derive(Clone, Debug)]
pub struct ChirpBlock(pub Chirp);

#[pipes_core::class(name = "Chirp")]
impl ChirpBlock {
    /// The constructor `Chirp`: a sweep from `f0` to `f1` Hz over
    /// `duration_s`, center 0, no fade, not started.
    #[constructor]
    pub fn new(
        f0: f32,
        f1: f32,
        duration_s: f32,
        amplitude: f32,
        exponential: bool,
    ) -> Result<ChirpBlock, ChirpError> {
        Chirp::new(ChirpConfig {
            f0: f0.into(),
            f1: f1.into(),
            duration_s: duration_s.into(),
            amplitude: amplitude.into(),
            center: 0.0,
            exponential,
            fade_s: 0.0,
        })
        .map(ChirpBlock)
    }

    /// `Chirp.start`: starts at stamp `at`; 0 means the next stamp sampled.
    pub fn start(&mut self, at: u64) {
        self.0.start((at != 0).then_some(at));
    }

    /// `Chirp.sample`: the stamp and the position there.
    #[outputs = "stamp, position"]
    pub fn sample(&mut self, stamp: u64) -> (u64, f32) {
        (stamp, self.0.sample(stamp) as f32)
    }

    /// `Chirp.done`: whether a stamp at or after the end has been sampled.
    #[outputs = "done"]
    pub fn done(&self) -> bool {
        self.0.done()
    }

    /// `Chirp.set_center`: [`Chirp::set_center`].
    pub fn set_center(&mut self, center: f32) -> Result<(), ChirpError> {
        self.0.set_center(center.into())
    }

    /// `Chirp.set_fade`: [`Chirp::set_fade`].
    pub fn set_fade(&mut self, fade_s: f32) -> Result<(), ChirpError> {
        self.0.set_fade(fade_s.into())
    }
}
