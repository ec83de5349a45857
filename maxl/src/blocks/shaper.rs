//! Input shaping: the planner's positions convolved with a short train of
//! impulses that cancels a machine's resonance, before kinematics.
//!
//! # Model
//!
//! A shaper is a set of impulses `(A_i, t_i)` with `Σ A_i = 1`, `A_i > 0`,
//! `0 = t_0 < t_1 < … < t_n` (`t_n` is its **duration**). Driving a lightly
//! damped mode (frequency `f`, damping ratio `ζ`) with `Σ A_i · u(t − t_i)`
//! instead of `u(t)` leaves `V(f, ζ)` of the residual vibration `u` leaves,
//! whatever `u` is (the vibrations of the delayed copies cancel);
//! [`residual_vibration`] computes `V`. With `K = exp(−ζπ/√(1−ζ²))` and
//! `t_d = 1/(f·√(1−ζ²))` (the damped period), before normalising the
//! amplitudes to sum to 1:
//!
//! | kind | code | amplitudes | times | `V` at `f` |
//! |---|---|---|---|---|
//! | ZV | 1 | `1, K` | `0, t_d/2` | 0 |
//! | MZV | 2 | `1 − 1/√2, (√2 − 1)·K^¾, (1 − 1/√2)·K^{3/2}` | `0, 3t_d/8, 3t_d/4` | 0 |
//! | EI | 3 | Singhose's fit for a 5 % tolerance (cubic in `ζ`) | `0, t₂(ζ)·t_d, t_d` | 5 % |
//! | 2-hump EI | 4 | Singhose's fit for 5 % (cubic in `ζ`) | cubic in `ζ`, × `1/f`, ≈ `0, ½, 1, 1½ /f` | ≈ 0 (5 % humps either side) |
//! | ZVD | 5 | `1, 2K, K²` | `0, t_d/2, t_d` | 0 |
//! | 3-hump EI | 6 | closed form in `K` and the 5 % tolerance (below) | `0, ½, 1, 1½, 2 · t_d` | ≈ 0 (5 % humps across a wide band) |
//!
//! (MZV, EI, 2-hump and 3-hump EI as the Klipper firmware defines them for
//! printers; the EI family trades exact cancellation at `f` for a wider
//! band where `V ≤ 5 %`.) Kind 0 is no shaper. 3-hump EI, with `v` the
//! tolerance: `a₁ = (1 + 3v + 2√(2v(v + 1)))/16`, `a₂ = (1 − v)K/4`,
//! `a₃ = ((1 + v)/2 − 2a₁)K²`, `a₄ = a₂K²`, `a₅ = a₁K⁴`.
//!
//! # Streaming
//!
//! [`InputShaper`] takes the planner's sampled position of every axis at
//! each stamp, `x(T)`, and returns the shaped position at the **same
//! stamp**:
//!
//! ```text
//! s_k(T) = Σ_i A_ki · x_k(T − t_ki − d_k)      d_k = L − Σ_i A_ki·t_ki
//! ```
//!
//! The output is causal: it uses only inputs at or before `T`, so the
//! timer's lead is unaffected. Its **lag** `L` is the largest impulse
//! centroid `Σ A_i t_i` over the axes; every other axis (an unshaped one
//! too) is delayed by `d_k` so that all axes lag by the same `L`. At
//! constant velocity the output is then exactly the input `L` earlier, on the
//! same path; only velocity changes (corners, accelerations) are smoothed,
//! over the kernel's duration. A move's shaped end comes `d_k + t_kn` (at
//! most [`InputShaper::window_s`]) after the planner's.
//!
//! `x(T − τ)` between two held samples is interpolated linearly (for an
//! input whose points accelerate at `a`, that is within `a·Δt²/8` of any
//! smooth curve through them: 1.6 µm at 3000 mm/s² and Δt = 2048 µs);
//! stamps need not be evenly spaced. Before its first sample the block
//! assumes the input rested at the first sample's position, so a fresh
//! shaper starts at rest. It holds just the samples the longest kernel
//! reaches back to (`window / Δt + 2`). At rest the output equals the input
//! bit-exactly (it is computed as `x(T) + Σ A_i (x(T − τ_i) − x(T))`).
//!
//! A shaper is changed ([`InputShaper::set_axis`]) only while every held
//! sample of every axis equals the newest one (the machine has been at rest
//! for the whole window), since a new kernel — or a new common lag —
//! applied to a moving input would step the output. After the planner's
//! coordinates jump (its `set_position`), call [`InputShaper::reset`], or the
//! shaper would move the machine smoothly across the jump.
//!
//! # PIPES class `Shaper` ([`ShaperBlock`], axes x, y, z)
//!
//! | member | inputs | outputs |
//! |---|---|---|
//! | constructor `Shaper` | `kind: u8, freq_hz: f32, damping: f32` (for x and y; z unshaped) | |
//! | `Shaper.shape` | `stamp: u64, x: f32, y: f32, z: f32` | `stamp: u64, x: f32, y: f32, z: f32` |
//! | `Shaper.set_axis` | `axis: u8, kind: u8, freq_hz: f32, damping: f32` | |
//! | `Shaper.axis` | `axis: u8` | `kind: u8, freq_hz: f32, damping: f32, duration_us: u32` |
//! | `Shaper.status` | | `lag_us: u32, window_us: u32, samples: u32, settled: bool` |
//! | `Shaper.reset` | | |
//!
//! The wire's `f32` frequency and damping are read as the shortest decimal
//! that rounds to them (so `0.4` is 0.4, within EI's limit).
//!
//! Failure codes ([`ShaperError::code`]; the constructor fails with 1, 2 or
//! 3): 1 bad frequency (not finite, or outside 1..=1000 Hz), 2 bad damping
//! (outside `[0, 1)`, or above the kind's fitted range: 0.99 for ZV, MZV
//! and ZVD, 0.4 for EI, 0.3 for 2-hump and 3-hump EI), 3 unknown kind, 4 stamp before
//! the newest sample, 5 a position not finite, 6 no such axis, 7 not at rest
//! (`set_axis`).

use std::collections::VecDeque;
use std::f64::consts::PI;
use std::fmt;

use pipes_core::function::CallError;

/// The lowest shaper frequency, Hz.
pub const MIN_FREQ_HZ: f64 = 1.0;
/// The highest shaper frequency, Hz.
pub const MAX_FREQ_HZ: f64 = 1000.0;
/// The residual vibration EI and 2-hump EI allow at the design frequency.
pub const EI_VIBRATION_TOLERANCE: f64 = 0.05;

/// Why a shaper call was refused. Each maps to a PIPES failure code
/// ([`ShaperError::code`]).
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum ShaperError {
    /// A frequency that is not finite or outside
    /// [`MIN_FREQ_HZ`]..=[`MAX_FREQ_HZ`].
    BadFrequency(f64),
    /// A damping ratio outside `[0, max]`.
    BadDamping {
        /// Asked for.
        damping: f64,
        /// The kind's largest damping ratio.
        max: f64,
    },
    /// A kind code that names no shaper.
    UnknownKind(u8),
    /// The stamp is before the newest sample.
    Stale {
        /// The stamp.
        stamp: u64,
        /// The newest sample's stamp.
        newest: u64,
    },
    /// A position is not finite.
    BadNumber,
    /// No such axis.
    BadAxis(usize),
    /// The input has not been at rest over the held window.
    Moving,
}

impl ShaperError {
    /// The PIPES failure code (see the module docs).
    pub fn code(&self) -> u8 {
        match self {
            ShaperError::BadFrequency(_) => 1,
            ShaperError::BadDamping { .. } => 2,
            ShaperError::UnknownKind(_) => 3,
            ShaperError::Stale { .. } => 4,
            ShaperError::BadNumber => 5,
            ShaperError::BadAxis(_) => 6,
            ShaperError::Moving => 7,
        }
    }
}

impl fmt::Display for ShaperError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ShaperError::BadFrequency(hz) => write!(
                f,
                "shaper frequency {hz} Hz is not in {MIN_FREQ_HZ}..={MAX_FREQ_HZ} Hz"
            ),
            ShaperError::BadDamping { damping, max } => {
                write!(f, "damping ratio {damping} is not in [0, {max}]")
            }
            ShaperError::UnknownKind(k) => write!(
                f,
                "shaper kind {k} is unknown (0 none, 1 ZV, 2 MZV, 3 EI, 4 2-hump EI, 5 ZVD, 6 3-hump EI)"
            ),
            ShaperError::Stale { stamp, newest } => {
                write!(f, "stamp {stamp} is before the newest sample ({newest})")
            }
            ShaperError::BadNumber => write!(f, "a position is not finite"),
            ShaperError::BadAxis(a) => write!(f, "there is no axis {a}"),
            ShaperError::Moving => write!(
                f,
                "the input is not at rest over the shaper's window: change shapers at rest"
            ),
        }
    }
}

impl core::error::Error for ShaperError {}

impl From<ShaperError> for CallError {
    fn from(e: ShaperError) -> CallError {
        CallError::Failed(e.code().into())
    }
}

/// The shapers (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ShaperKind {
    /// Zero vibration: two impulses, half a damped period apart.
    Zv,
    /// Modified ZV: three impulses over ¾ of a damped period.
    Mzv,
    /// Extra-insensitive, 5 % tolerance: three impulses over a damped period.
    Ei,
    /// Two-hump extra-insensitive, 5 % tolerance: four impulses over 1½
    /// periods.
    TwoHumpEi,
    /// Zero vibration and derivative: three impulses over a damped period.
    Zvd,
    /// Three-hump extra-insensitive, 5 % tolerance: five impulses over two
    /// periods, the widest band of all.
    ThreeHumpEi,
}

impl ShaperKind {
    /// Every kind, in code order.
    pub const ALL: [ShaperKind; 6] = [
        ShaperKind::Zv,
        ShaperKind::Mzv,
        ShaperKind::Ei,
        ShaperKind::TwoHumpEi,
        ShaperKind::Zvd,
        ShaperKind::ThreeHumpEi,
    ];

    /// The wire code (1..=6; 0 is no shaper).
    pub fn code(self) -> u8 {
        match self {
            ShaperKind::Zv => 1,
            ShaperKind::Mzv => 2,
            ShaperKind::Ei => 3,
            ShaperKind::TwoHumpEi => 4,
            ShaperKind::Zvd => 5,
            ShaperKind::ThreeHumpEi => 6,
        }
    }

    /// The kind a wire code names: `None` for 0 (no shaper).
    pub fn from_code(code: u8) -> Result<Option<ShaperKind>, ShaperError> {
        match code {
            0 => Ok(None),
            c => ShaperKind::ALL
                .into_iter()
                .find(|k| k.code() == c)
                .map(Some)
                .ok_or(ShaperError::UnknownKind(c)),
        }
    }

    /// The name printers use for it (`zv`, `mzv`, `ei`, `2hump_ei`, `zvd`,
    /// `3hump_ei`).
    pub fn name(self) -> &'static str {
        match self {
            ShaperKind::Zv => "zv",
            ShaperKind::Mzv => "mzv",
            ShaperKind::Ei => "ei",
            ShaperKind::TwoHumpEi => "2hump_ei",
            ShaperKind::Zvd => "zvd",
            ShaperKind::ThreeHumpEi => "3hump_ei",
        }
    }

    /// The largest damping ratio the kind takes: its fit's range for EI
    /// (0.4) and 2-hump EI (0.3), the same for 3-hump EI, else 0.99.
    pub fn max_damping(self) -> f64 {
        match self {
            ShaperKind::Ei => 0.4,
            ShaperKind::TwoHumpEi | ShaperKind::ThreeHumpEi => 0.3,
            ShaperKind::Zv | ShaperKind::Mzv | ShaperKind::Zvd => 0.99,
        }
    }
}

/// One impulse: an amplitude and its delay.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Impulse {
    /// Amplitude (the amplitudes of a shaper sum to 1).
    pub amplitude: f64,
    /// Delay, s.
    pub time_s: f64,
}

/// A shaper tuned to a mode: kind, frequency and damping ratio, checked.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShaperConfig {
    kind: ShaperKind,
    freq_hz: f64,
    damping: f64,
}

/// `c[0] + c[1]·x + c[2]·x² + c[3]·x³`.
fn cubic(c: [f64; 4], x: f64) -> f64 {
    ((c[3] * x + c[2]) * x + c[1]) * x + c[0]
}

/// 2-hump EI (5 %): per impulse, the cubic in `ζ` of its time (× `1/f`)
/// and of its amplitude (Singhose's fit, as Klipper uses it).
const TWO_HUMP_EI: [([f64; 4], [f64; 4]); 4] = [
    ([0.0, 0.0, 0.0, 0.0], [0.16054, 0.76699, 2.26560, -1.22750]),
    (
        [0.49890, 0.16270, -0.54262, 6.16180],
        [0.33911, 0.45081, -2.58080, 1.73650],
    ),
    (
        [0.99748, 0.18382, -1.58270, 8.17120],
        [0.34089, -0.61533, -0.68765, 0.42261],
    ),
    (
        [1.49920, -0.09297, -0.28338, 1.85710],
        [0.15997, -0.60246, 1.00280, -0.93145],
    ),
];

impl ShaperConfig {
    /// A shaper of `kind` for a mode at `freq_hz` with damping ratio
    /// `damping`.
    pub fn new(kind: ShaperKind, freq_hz: f64, damping: f64) -> Result<ShaperConfig, ShaperError> {
        if !(MIN_FREQ_HZ..=MAX_FREQ_HZ).contains(&freq_hz) {
            return Err(ShaperError::BadFrequency(freq_hz));
        }
        let max = kind.max_damping();
        if !(0.0..=max).contains(&damping) {
            return Err(ShaperError::BadDamping { damping, max });
        }
        Ok(ShaperConfig {
            kind,
            freq_hz,
            damping,
        })
    }

    /// From wire values: `Ok(None)` for kind 0 (whose frequency and damping
    /// are not looked at).
    pub fn from_wire(
        kind: u8,
        freq_hz: f64,
        damping: f64,
    ) -> Result<Option<ShaperConfig>, ShaperError> {
        ShaperKind::from_code(kind)?
            .map(|k| ShaperConfig::new(k, freq_hz, damping))
            .transpose()
    }

    /// The kind.
    pub fn kind(&self) -> ShaperKind {
        self.kind
    }

    /// The mode's frequency, Hz.
    pub fn freq_hz(&self) -> f64 {
        self.freq_hz
    }

    /// The mode's damping ratio.
    pub fn damping(&self) -> f64 {
        self.damping
    }

    /// The impulses: amplitudes positive and summing to 1, times ascending
    /// from 0.
    pub fn impulses(&self) -> Vec<Impulse> {
        let z = self.damping;
        let df = (1.0 - z * z).sqrt();
        let k = (-z * PI / df).exp();
        let t_d = 1.0 / (self.freq_hz * df);
        let (a, t): (Vec<f64>, Vec<f64>) = match self.kind {
            ShaperKind::Zv => (vec![1.0, k], vec![0.0, 0.5 * t_d]),
            ShaperKind::Mzv => {
                let a1 = 1.0 - 1.0 / 2f64.sqrt();
                let k = k.powf(0.75);
                (
                    vec![a1, (2f64.sqrt() - 1.0) * k, a1 * k * k],
                    vec![0.0, 0.375 * t_d, 0.75 * t_d],
                )
            }
            ShaperKind::Zvd => (vec![1.0, 2.0 * k, k * k], vec![0.0, 0.5 * t_d, t_d]),
            ShaperKind::Ei => {
                let v = EI_VIBRATION_TOLERANCE;
                let a1 = cubic(
                    [
                        0.24968 + 0.24961 * v,
                        0.80008 + 1.23328 * v,
                        0.49599 + 3.17316 * v,
                        0.0,
                    ],
                    z,
                );
                let a3 = cubic(
                    [
                        0.25149 + 0.21474 * v,
                        -0.83249 + 1.41498 * v,
                        0.85181 - 4.90094 * v,
                        0.0,
                    ],
                    z,
                );
                let t2 = cubic(
                    [
                        0.4999,
                        (0.46159 + 8.57843 * v) * v,
                        (4.26169 - 108.644 * v) * v,
                        (1.75601 + 336.989 * v) * v,
                    ],
                    z,
                );
                (vec![a1, 1.0 - a1 - a3, a3], vec![0.0, t2 * t_d, t_d])
            }
            ShaperKind::ThreeHumpEi => {
                let v = EI_VIBRATION_TOLERANCE;
                let a1 = 0.0625 * (1.0 + 3.0 * v + 2.0 * (2.0 * (v + 1.0) * v).sqrt());
                let a2 = 0.25 * (1.0 - v) * k;
                let a3 = (0.5 * (1.0 + v) - 2.0 * a1) * k * k;
                (
                    vec![a1, a2, a3, a2 * k * k, a1 * k.powi(4)],
                    vec![0.0, 0.5 * t_d, t_d, 1.5 * t_d, 2.0 * t_d],
                )
            }
            ShaperKind::TwoHumpEi => TWO_HUMP_EI
                .iter()
                .map(|&(tc, ac)| (cubic(ac, z), cubic(tc, z) / self.freq_hz))
                .unzip(),
        };
        let sum: f64 = a.iter().sum();
        a.iter()
            .zip(&t)
            .map(|(&a, &t)| Impulse {
                amplitude: a / sum,
                time_s: t,
            })
            .collect()
    }

    /// The duration: the last impulse's time, s.
    pub fn duration_s(&self) -> f64 {
        self.impulses().last().map_or(0.0, |i| i.time_s)
    }

    /// The centroid `Σ A_i t_i`, s: how far the shaped signal lags a ramp.
    pub fn centroid_s(&self) -> f64 {
        centroid(&self.impulses())
    }
}

/// `Σ A_i t_i`, s.
fn centroid(imp: &[Impulse]) -> f64 {
    imp.iter().map(|i| i.amplitude * i.time_s).sum()
}

/// The residual vibration of a mode at `freq_hz`, damping ratio `damping`,
/// driven through `impulses`, relative to driving it directly (1: no
/// reduction, 0: cancelled), measured when the last impulse has been given.
pub fn residual_vibration(impulses: &[Impulse], freq_hz: f64, damping: f64) -> f64 {
    let w = 2.0 * PI * freq_hz;
    let wd = w * (1.0 - damping * damping).sqrt();
    let t_n = impulses.last().map_or(0.0, |i| i.time_s);
    let (mut c, mut s) = (0.0, 0.0);
    for i in impulses {
        let e = i.amplitude * (-damping * w * (t_n - i.time_s)).exp();
        c += e * (wd * i.time_s).cos();
        s += e * (wd * i.time_s).sin();
    }
    c.hypot(s)
}

/// One impulse of an axis's kernel: an amplitude and a delay of
/// `whole + frac` µs (`frac` in `[0, 1)`).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Tap {
    amp: f64,
    whole: u64,
    frac: f64,
}

impl Tap {
    fn new(amp: f64, delay_s: f64) -> Tap {
        let us = (delay_s * 1e6).max(0.0);
        let whole = us.floor();
        Tap {
            amp,
            whole: whole as u64,
            frac: us - whole,
        }
    }

    fn delay_s(&self) -> f64 {
        (self.whole as f64 + self.frac) * 1e-6
    }
}

/// Input shaping of `N` axes on a stream of stamped positions (see the
/// module docs).
#[derive(Clone, Debug)]
pub struct InputShaper<const N: usize> {
    axes: [Option<ShaperConfig>; N],
    /// Per axis, the impulses with the axis's alignment delay added.
    kernels: [Vec<Tap>; N],
    lag_s: f64,
    /// The longest delay of any tap, µs (rounded up).
    window_us: u64,
    /// Input samples, oldest first, back to the one at or before
    /// `newest − window`.
    history: VecDeque<(u64, [f64; N])>,
}

impl<const N: usize> InputShaper<N> {
    /// A shaper for each axis (`None`: the axis is only delayed by the
    /// common lag).
    pub fn new(axes: [Option<ShaperConfig>; N]) -> InputShaper<N> {
        let mut s = InputShaper {
            axes,
            kernels: core::array::from_fn(|_| Vec::new()),
            lag_s: 0.0,
            window_us: 0,
            history: VecDeque::new(),
        };
        s.build();
        s
    }

    /// No axis shaped: the output is the input.
    pub fn unshaped() -> InputShaper<N> {
        InputShaper::new([None; N])
    }

    /// Rebuilds the kernels, lag and window from `axes`.
    fn build(&mut self) {
        let imps: [Vec<Impulse>; N] =
            core::array::from_fn(|k| self.axes[k].map(|c| c.impulses()).unwrap_or_default());
        self.lag_s = imps.iter().map(|i| centroid(i)).fold(0.0, f64::max);
        let lag = self.lag_s;
        self.kernels = core::array::from_fn(|k| {
            if imps[k].is_empty() {
                return vec![Tap::new(1.0, lag)];
            }
            let shift = (lag - centroid(&imps[k])).max(0.0);
            imps[k]
                .iter()
                .map(|i| Tap::new(i.amplitude, i.time_s + shift))
                .collect()
        });
        self.window_us = self
            .kernels
            .iter()
            .flatten()
            .map(|t| t.whole + u64::from(t.frac > 0.0))
            .max()
            .unwrap_or(0);
    }

    /// The shaper of `axis` (`None`: unshaped, or no such axis).
    pub fn axis(&self, axis: usize) -> Option<ShaperConfig> {
        self.axes.get(axis).copied().flatten()
    }

    /// Sets the shaper of `axis` (`None`: unshaped). Refused with
    /// [`ShaperError::Moving`] unless every held sample equals the newest
    /// (or none is held); then the history is reduced to the newest sample,
    /// the position the input rested at.
    pub fn set_axis(
        &mut self,
        axis: usize,
        shaper: Option<ShaperConfig>,
    ) -> Result<(), ShaperError> {
        if axis >= N {
            return Err(ShaperError::BadAxis(axis));
        }
        if !self.settled() {
            return Err(ShaperError::Moving);
        }
        self.axes[axis] = shaper;
        self.build();
        while self.history.len() > 1 {
            self.history.pop_front();
        }
        Ok(())
    }

    /// The common lag `L`, s: at constant velocity the output is the input
    /// `L` earlier.
    pub fn lag_s(&self) -> f64 {
        self.lag_s
    }

    /// How far back the output reaches, s: the longest delay of any
    /// impulse (alignment included). A move's shaped end comes at most this
    /// long after the input's.
    pub fn window_s(&self) -> f64 {
        self.window_us as f64 * 1e-6
    }

    /// The impulses axis `axis` applies, alignment delay included (empty for
    /// no such axis).
    pub fn kernel(&self, axis: usize) -> Vec<Impulse> {
        self.kernels.get(axis).map_or_else(Vec::new, |k| {
            k.iter()
                .map(|t| Impulse {
                    amplitude: t.amp,
                    time_s: t.delay_s(),
                })
                .collect()
        })
    }

    /// Samples held.
    pub fn len(&self) -> usize {
        self.history.len()
    }

    /// Whether no sample is held.
    pub fn is_empty(&self) -> bool {
        self.history.is_empty()
    }

    /// The newest sample's stamp.
    pub fn newest(&self) -> Option<u64> {
        self.history.back().map(|&(t, _)| t)
    }

    /// Whether every held sample equals the newest: the output is the input
    /// (also when nothing is held).
    pub fn settled(&self) -> bool {
        match self.history.back() {
            None => true,
            Some((_, last)) => self.history.iter().all(|(_, x)| x == last),
        }
    }

    /// Forgets the history: the next sample starts the shaper afresh, at
    /// rest there.
    pub fn reset(&mut self) {
        self.history.clear();
    }

    /// The input of axis `k` at `stamp − whole − frac` µs, interpolated
    /// linearly between held samples, the oldest one before them.
    fn input_at(&self, k: usize, stamp: u64, whole: u64, frac: f64) -> f64 {
        let h = &self.history;
        let oldest = h.front().map_or(0.0, |(_, x)| x[k]);
        let Some(base) = stamp.checked_sub(whole) else {
            return oldest;
        };
        // The last sample at or before base − frac.
        let limit = if frac > 0.0 {
            base.checked_sub(1)
        } else {
            Some(base)
        };
        let Some(limit) = limit else {
            return oldest;
        };
        let i = h.partition_point(|&(t, _)| t <= limit);
        if i == 0 {
            return oldest;
        }
        let (t0, x0) = h[i - 1];
        match h.get(i) {
            None => x0[k],
            Some(&(t1, x1)) => {
                let a = ((base - t0) as f64 - frac) / (t1 - t0) as f64;
                x0[k] + a * (x1[k] - x0[k])
            }
        }
    }

    /// Takes the input `x` at `stamp` and returns the shaped position there.
    /// A stamp equal to the newest replaces that sample; an earlier one is
    /// refused ([`ShaperError::Stale`]), as is a position that is not finite;
    /// a refused sample leaves the shaper as it was.
    pub fn shape(&mut self, stamp: u64, x: [f64; N]) -> Result<[f64; N], ShaperError> {
        if x.iter().any(|v| !v.is_finite()) {
            return Err(ShaperError::BadNumber);
        }
        match self.history.back() {
            Some(&(newest, _)) if stamp < newest => {
                return Err(ShaperError::Stale { stamp, newest });
            }
            Some(&(newest, _)) if stamp == newest => {
                self.history.pop_back();
            }
            _ => {}
        }
        self.history.push_back((stamp, x));
        // Keep one sample at or before the oldest time any tap reaches, and
        // the previous sample (whether the input is at rest needs two).
        let reach = stamp.saturating_sub(self.window_us);
        while self.history.len() > 2 && self.history[1].0 <= reach {
            self.history.pop_front();
        }
        Ok(core::array::from_fn(|k| {
            let now = x[k];
            now + self.kernels[k]
                .iter()
                .map(|t| t.amp * (self.input_at(k, stamp, t.whole, t.frac) - now))
                .sum::<f64>()
        }))
    }
}

/// A three-axis [`InputShaper`] as the PIPES class `Shaper` (see the module
/// docs).
///
/// Its methods are the class's members; the shaper itself is the public
/// field.
#[derive(Clone, Debug)]
pub struct ShaperBlock(pub InputShaper<3>);

/// A wire `f32` as the shortest decimal that rounds to it (0.1 → 0.1, not
/// 0.10000000149), so limits such as a damping of 0.4 are met as typed.
fn wire_f64(v: f32) -> f64 {
    v.to_string().parse().unwrap_or(f64::NAN)
}

/// µs as a wire `u32`, rounded, saturating.
fn micros_u32(s: f64) -> u32 {
    let us = (s * 1e6).round();
    if us >= u32::MAX as f64 {
        u32::MAX
    } else {
        us as u32
    }
}

#[pipes_core::class(name = "Shaper")]
impl ShaperBlock {
    /// The constructor `Shaper`: shaper `kind` (0 none, 1 ZV, 2 MZV, 3 EI,
    /// 4 2-hump EI, 5 ZVD) for a mode at `freq_hz` with damping ratio
    /// `damping` on x and y; z unshaped (fails with 1, 2 or 3).
    #[constructor]
    pub fn new(kind: u8, freq_hz: f32, damping: f32) -> Result<ShaperBlock, ShaperError> {
        let c = ShaperConfig::from_wire(kind, wire_f64(freq_hz), wire_f64(damping))?;
        Ok(ShaperBlock(InputShaper::new([c, c, None])))
    }

    /// `Shaper.shape`: the shaped position at the stamp, with the stamp
    /// passed through ([`InputShaper::shape`]).
    #[outputs = "stamp, x, y, z"]
    pub fn shape(
        &mut self,
        stamp: u64,
        x: f32,
        y: f32,
        z: f32,
    ) -> Result<(u64, f32, f32, f32), ShaperError> {
        let f = f64::from;
        let [x, y, z] = self.0.shape(stamp, [f(x), f(y), f(z)])?;
        Ok((stamp, x as f32, y as f32, z as f32))
    }

    /// `Shaper.set_axis`: axis 0, 1 or 2 (x, y, z) gets shaper `kind` (0:
    /// none) for `freq_hz` and `damping` ([`InputShaper::set_axis`]; at rest
    /// only).
    pub fn set_axis(
        &mut self,
        axis: u8,
        kind: u8,
        freq_hz: f32,
        damping: f32,
    ) -> Result<(), ShaperError> {
        let c = ShaperConfig::from_wire(kind, wire_f64(freq_hz), wire_f64(damping))?;
        self.0.set_axis(usize::from(axis), c)
    }

    /// `Shaper.axis`: the shaper of an axis (kind 0 and zeros for none) and
    /// its duration, µs.
    #[outputs = "kind, freq_hz, damping, duration_us"]
    pub fn axis(&self, axis: u8) -> Result<(u8, f32, f32, u32), ShaperError> {
        let a = usize::from(axis);
        if a >= 3 {
            return Err(ShaperError::BadAxis(a));
        }
        Ok(self.0.axis(a).map_or((0, 0.0, 0.0, 0), |c| {
            (
                c.kind().code(),
                c.freq_hz() as f32,
                c.damping() as f32,
                micros_u32(c.duration_s()),
            )
        }))
    }

    /// `Shaper.status`: the common lag and the window (µs), the samples
    /// held, and whether the output has settled onto the input.
    #[outputs = "lag_us, window_us, samples, settled"]
    pub fn status(&self) -> (u32, u32, u32, bool) {
        (
            micros_u32(self.0.lag_s()),
            micros_u32(self.0.window_s()),
            u32::try_from(self.0.len()).unwrap_or(u32::MAX),
            self.0.settled(),
        )
    }

    /// `Shaper.reset`: forgets the history ([`InputShaper::reset`]).
    pub fn reset(&mut self) {
        self.0.reset();
    }
}
