//! Heaters: temperature control and thermal-runaway protection on the
//! module, so a hotend or a bed is safe whatever the host does.
//!
//! A module drives up to [`HEATERS`] heaters (a board has two PWM
//! outputs). Each has an output (a PWM channel, its duty capped at
//! `max_power`), a sensor (an analog input with an NTC thermistor), limits
//! (`min_temp`, `max_temp`), PID gains, and runaway settings. The host
//! configures them (`heater_sensor`, `heater_output`, `heater_limits`,
//! `heater_gains`, `heater_runaway`) and then sets a target
//! (`heater_target`) or an open-loop duty for autotuning (`heater_power`).
//!
//! **Control.** Every [`CONTROL_PERIOD`] (100 ms of local time), from the
//! runtime's loop ([`Heaters::poll`], woken at [`Heaters::wake_at`], like
//! [`crate::io::Io::poll`]), each heater with a sensor and limits reads its
//! temperature, checks it, and drives its output:
//!
//! ```text
//! duty = (kp·e + ki·∫e dt − kd·dT/dt) / 255        e = target − T, °C; t in s
//! ```
//!
//! clamped to `0..=max_power`: Klipper's convention ([`PID_PARAM_BASE`]),
//! so Klipper's `pid_Kp`, `pid_Ki`, `pid_Kd` and its `PID_CALIBRATE`
//! results are the numbers to give `heater_gains`. The integral is clamped
//! to `0..=max_power·255/ki` (its term never asks for more than
//! `max_power`) and held while the output saturates (anti-windup). The
//! derivative is of the measured temperature (a target step does not kick
//! it), smoothed over [`DERIVATIVE_TIME_S`] (1 s).
//!
//! **Runaway protection** (Klipper's `verify_heater`, on the module). A
//! heater's output is cut (duty 0) and latched off, and a
//! [`FaultKind::HeaterRunaway`](crate::fault::FaultKind::HeaterRunaway)
//! fault recorded with a [`RunawayReason`], when:
//! - **not heating**: heating toward a target, the temperature has not
//!   risen by `heating_gain_c` (2 °C) within `check_gain_time_s` (20 s; a
//!   host may give a bed 60 s);
//! - **fell from target**: having reached the target, it is below
//!   `target − hysteresis_c` (5 °C) and the error below that band, summed
//!   over time, passes `max_error` (120 °C·s);
//! - **sensor open**: the reading is within 1/256 of full scale, or below
//!   `min_temp` (a thermistor gone open reads cold);
//! - **sensor short**: the reading is within 1/256 of zero;
//! - **over max_temp**: the temperature reached `max_temp`.
//!
//! The sensor and limit checks run whenever a heater has a sensor and
//! limits, also in open-loop power mode and while it is off. A faulted
//! heater stays off and refuses targets and power until `heater_clear`,
//! which succeeds only while its sensor reads sane.
//!
//! **Stops.** Every stop (`halt`, a backstop) and the output watchdog turn
//! every heater off (target 0, duty 0; [`Heaters::off_all`]), whatever the
//! safe value of its PWM output; a host that comes back sets the target
//! again. A PWM output a heater drives is refused to `pwm_write` and
//! `set_safe_pwm` ([`crate::io::IoError::HeaterOutput`]).

use crate::board::IoHw;
use osap_core::{Duration, Instant};

/// Heaters a module drives (one per PWM output of the boards).
pub const HEATERS: usize = 2;
/// How often a heater reads its sensor, checks it and sets its output.
pub const CONTROL_PERIOD: Duration = Duration::from_millis(100);
/// Klipper's PID scale: a gain of `kp` gives `kp/255` of full duty per °C.
pub const PID_PARAM_BASE: f32 = 255.0;
/// The derivative's smoothing time, s (Klipper's `smooth_time` default).
pub const DERIVATIVE_TIME_S: f32 = 1.0;
/// A raw reading within this of full scale reads as an open sensor, within
/// this of zero as a shorted one (1/256 of full scale).
pub const SENSOR_MARGIN: u16 = 256;

/// 0 °C in kelvin.
const ZERO_C_IN_K: f32 = 273.15;

/// Why a heater call was refused: the failure code a caller sees.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
#[non_exhaustive]
pub enum HeaterError {
    /// No heater with that index (there are [`HEATERS`]).
    NoSuchHeater = 1,
    /// No such PWM output or analog input on this board.
    NoSuchPin = 2,
    /// A value out of range: not finite, a thermistor value or `max_power`
    /// not positive, `min_temp` not below `max_temp`, a negative gain or
    /// runaway setting, a target outside `[min_temp, max_temp)`, a duty
    /// outside `0..=1`.
    BadValue = 3,
    /// The heater lacks its sensor, output or limits (and gains, for a
    /// target).
    NotConfigured = 4,
    /// The heater is latched off by a runaway fault.
    Faulted = 5,
    /// `heater_clear` found the sensor still open, shorted or out of its
    /// limits.
    SensorFault = 6,
    /// The setting can only change while the heater is off.
    Busy = 7,
    /// The I/O hardware was never installed (a firmware without it).
    NoHardware = 8,
    /// Another heater drives that PWM output.
    InUse = 9,
}

impl HeaterError {
    /// Every heater error, in code order.
    pub const ALL: [HeaterError; 9] = [
        HeaterError::NoSuchHeater,
        HeaterError::NoSuchPin,
        HeaterError::BadValue,
        HeaterError::NotConfigured,
        HeaterError::Faulted,
        HeaterError::SensorFault,
        HeaterError::Busy,
        HeaterError::NoHardware,
        HeaterError::InUse,
    ];

    /// The failure code.
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// The error with failure code `code`; `None` for a code that is not a
    /// heater error.
    pub fn from_code(code: u8) -> Option<HeaterError> {
        Self::ALL.into_iter().find(|e| e.code() == code)
    }
}

impl core::fmt::Display for HeaterError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            HeaterError::NoSuchHeater => "no such heater",
            HeaterError::NoSuchPin => "no such PWM output or analog input on this board",
            HeaterError::BadValue => "a value out of range",
            HeaterError::NotConfigured => "the heater is not configured",
            HeaterError::Faulted => "the heater is latched off by a runaway fault",
            HeaterError::SensorFault => "the heater's sensor does not read sane",
            HeaterError::Busy => "the heater is on",
            HeaterError::NoHardware => "the I/O hardware was never installed",
            HeaterError::InUse => "another heater drives that PWM output",
        })
    }
}

impl core::error::Error for HeaterError {}

impl From<HeaterError> for pipes_core::FailureCode {
    fn from(e: HeaterError) -> Self {
        pipes_core::FailureCode::Other(e.code())
    }
}

impl From<HeaterError> for pipes_core::function::CallError {
    fn from(e: HeaterError) -> Self {
        pipes_core::function::CallError::Failed(e.into())
    }
}

/// Why a heater was cut: the second byte of a
/// [`FaultKind::HeaterRunaway`](crate::fault::FaultKind::HeaterRunaway)
/// detail ([`runaway_detail`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum RunawayReason {
    /// Heating toward a target, it did not gain `heating_gain_c` within
    /// `check_gain_time_s`.
    NotHeating = 1,
    /// Having reached its target, it fell below `target − hysteresis_c` for
    /// more than `max_error` °C·s.
    FellFromTarget = 2,
    /// The sensor reads open (near full scale, or below `min_temp`).
    SensorOpen = 3,
    /// The sensor reads shorted (near zero).
    SensorShort = 4,
    /// The temperature reached `max_temp`.
    OverTemp = 5,
}

impl RunawayReason {
    /// Every reason, in code order.
    pub const ALL: [RunawayReason; 5] = [
        RunawayReason::NotHeating,
        RunawayReason::FellFromTarget,
        RunawayReason::SensorOpen,
        RunawayReason::SensorShort,
        RunawayReason::OverTemp,
    ];

    /// The reason's code.
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// The reason of code `code`, if it is one.
    pub fn from_code(code: u8) -> Option<RunawayReason> {
        Self::ALL.into_iter().find(|r| r.code() == code)
    }

    /// A short name.
    pub fn name(self) -> &'static str {
        match self {
            RunawayReason::NotHeating => "not heating",
            RunawayReason::FellFromTarget => "fell from target",
            RunawayReason::SensorOpen => "sensor open",
            RunawayReason::SensorShort => "sensor short",
            RunawayReason::OverTemp => "over max_temp",
        }
    }
}

/// A [`FaultKind::HeaterRunaway`](crate::fault::FaultKind::HeaterRunaway)
/// detail: the heater's index in the low byte, the reason's code in the
/// next.
pub fn runaway_detail(index: u8, reason: RunawayReason) -> u32 {
    u32::from(index) | u32::from(reason.code()) << 8
}

/// The heater index and reason a runaway detail holds (`None`: a reason
/// this version does not know).
pub fn runaway_parts(detail: u32) -> (u8, Option<RunawayReason>) {
    (detail as u8, RunawayReason::from_code((detail >> 8) as u8))
}

/// An NTC thermistor to ground, with a pullup to the converter's
/// reference (the reading is the fraction `R / (R + pullup_ohms)` of full
/// scale), read by the Steinhart–Hart equation
///
/// ```text
/// 1/T = a + b·ln R + c·(ln R)³        T in K, R in Ω
/// ```
///
/// A Beta thermistor is the case `c = 0` ([`Thermistor::from_beta`]); the
/// host fits `a`, `b` and `c` to a thermistor's datasheet points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Thermistor {
    /// Steinhart–Hart `a`, 1/K.
    pub a: f32,
    /// Steinhart–Hart `b`, 1/K.
    pub b: f32,
    /// Steinhart–Hart `c`, 1/K.
    pub c: f32,
    /// The pullup, Ω (4 700 on most printer boards).
    pub pullup_ohms: f32,
}

/// `ln R` of the ends of the resistances a thermistor is read over (1 Ω to
/// 100 MΩ): its curve must fall with temperature across them.
const LN_OHMS_RANGE: (f32, f32) = (0.0, 18.42);

impl Thermistor {
    /// A Beta thermistor: `beta`, K (3950 for the common 100 kΩ hotend
    /// thermistor), `r25_ohms` at 25 °C.
    pub fn from_beta(beta: f32, r25_ohms: f32, pullup_ohms: f32) -> Thermistor {
        Thermistor {
            a: 1.0 / (25.0 + ZERO_C_IN_K) - libm::logf(r25_ohms) / beta,
            b: 1.0 / beta,
            c: 0.0,
            pullup_ohms,
        }
    }

    /// Whether the values are finite, the pullup positive, and the curve
    /// one of a thermistor: its resistance falls as it warms (`b + 3c·ln²R
    /// > 0`) across 1 Ω to 100 MΩ.
    pub fn is_valid(&self) -> bool {
        let finite = [self.a, self.b, self.c, self.pullup_ohms]
            .iter()
            .all(|v| v.is_finite());
        let slope = |ln_r: f32| self.b + 3.0 * self.c * ln_r * ln_r;
        finite
            && self.pullup_ohms > 0.0
            && slope(LN_OHMS_RANGE.0) > 0.0
            && slope(LN_OHMS_RANGE.1) > 0.0
    }

    /// The temperature, °C, of a raw reading (of 65 535); at the ends of
    /// the scale absolute zero or NaN, which the sensor check reads as
    /// open.
    pub fn celsius(&self, raw: u16) -> f32 {
        let raw = f32::from(raw);
        let ln_r = libm::logf(self.pullup_ohms * raw / (65_535.0 - raw));
        let inv = self.a + self.b * ln_r + self.c * ln_r * ln_r * ln_r;
        1.0 / inv - ZERO_C_IN_K
    }
}

/// PID gains in Klipper's units (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gains {
    /// Proportional, per °C (of 255).
    pub kp: f32,
    /// Integral, per °C·s (of 255).
    pub ki: f32,
    /// Derivative, per °C/s (of 255).
    pub kd: f32,
}

/// Runaway settings (Klipper's `[verify_heater]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Runaway {
    /// The band below the target that counts as holding it, °C (5).
    pub hysteresis_c: f32,
    /// The error below the band tolerated while holding, °C·s (120).
    pub max_error: f32,
    /// The rise expected while heating, °C (2) ...
    pub heating_gain_c: f32,
    /// ... within this time, s (20; 60 suits a bed).
    pub check_gain_time_s: f32,
}

impl Runaway {
    /// Klipper's defaults for a hotend: 5 °C, 120 °C·s, 2 °C in 20 s.
    pub const DEFAULT: Runaway = Runaway {
        hysteresis_c: 5.0,
        max_error: 120.0,
        heating_gain_c: 2.0,
        check_gain_time_s: 20.0,
    };
}

impl Default for Runaway {
    fn default() -> Self {
        Runaway::DEFAULT
    }
}

/// What a heater is doing: `heater_read`'s `state`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum HeaterState {
    /// Off (target 0).
    Off = 0,
    /// Heating toward its target: below `target − hysteresis_c`.
    Heating = 1,
    /// Holding its target: at or above `target − hysteresis_c`.
    Holding = 2,
    /// Open loop at a duty `heater_power` set.
    Power = 3,
    /// Latched off by a runaway fault until `heater_clear`.
    Faulted = 4,
}

impl HeaterState {
    /// Every state, in code order.
    pub const ALL: [HeaterState; 5] = [
        HeaterState::Off,
        HeaterState::Heating,
        HeaterState::Holding,
        HeaterState::Power,
        HeaterState::Faulted,
    ];

    /// The state of code `code` (as `heater_read` reports it), if it is
    /// one.
    pub fn from_code(code: u8) -> Option<HeaterState> {
        Self::ALL.get(usize::from(code)).copied()
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Mode {
    Off,
    Target(f32),
    Power(f32),
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Sensor {
    analog: u8,
    thermistor: Thermistor,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Output {
    pwm: u8,
    max_power: f32,
}

/// `verify_heater`'s state.
#[derive(Debug, Clone, Copy, Default)]
struct Verify {
    last_target: f32,
    approaching: bool,
    starting: bool,
    goal_temp: f32,
    goal_time: Instant,
    error: f32,
}

/// One heater: its settings and its control and runaway state.
#[derive(Debug, Clone, Copy)]
pub struct Heater {
    sensor: Option<Sensor>,
    output: Option<Output>,
    limits: Option<(f32, f32)>,
    gains: Option<Gains>,
    runaway: Runaway,
    mode: Mode,
    fault: Option<RunawayReason>,
    /// The latest reading: local time, °C.
    reading: Option<(Instant, f32)>,
    duty: f32,
    integ: f32,
    deriv: f32,
    verify: Verify,
    /// When its next control period is due, local time.
    next: Instant,
}

impl Heater {
    const fn new() -> Self {
        Heater {
            sensor: None,
            output: None,
            limits: None,
            gains: None,
            runaway: Runaway::DEFAULT,
            mode: Mode::Off,
            fault: None,
            reading: None,
            duty: 0.0,
            integ: 0.0,
            deriv: 0.0,
            verify: Verify {
                last_target: 0.0,
                approaching: false,
                starting: false,
                goal_temp: 0.0,
                goal_time: Instant::ZERO,
                error: 0.0,
            },
            next: Instant::ZERO,
        }
    }

    /// Whether it reads and checks its sensor every period: it has a sensor
    /// and limits.
    fn monitored(&self) -> bool {
        self.sensor.is_some() && self.limits.is_some()
    }

    /// The latest reading: local time and °C (`None` before the first).
    pub fn reading(&self) -> Option<(Instant, f32)> {
        self.reading
    }

    /// The target, °C (0: off or open loop).
    pub fn target(&self) -> f32 {
        match self.mode {
            Mode::Target(t) => t,
            _ => 0.0,
        }
    }

    /// The duty it drives, a fraction of full scale.
    pub fn duty(&self) -> f32 {
        self.duty
    }

    /// The latched runaway fault, if any.
    pub fn fault(&self) -> Option<RunawayReason> {
        self.fault
    }

    /// What it is doing.
    pub fn state(&self) -> HeaterState {
        if self.fault.is_some() {
            return HeaterState::Faulted;
        }
        match self.mode {
            Mode::Off => HeaterState::Off,
            Mode::Power(_) => HeaterState::Power,
            Mode::Target(t) => match self.reading {
                Some((_, temp)) if temp >= t - self.runaway.hysteresis_c => HeaterState::Holding,
                _ => HeaterState::Heating,
            },
        }
    }

    /// Off: target 0, output 0, the control state reset.
    fn off(&mut self, hw: &mut dyn IoHw) {
        self.mode = Mode::Off;
        self.integ = 0.0;
        self.verify = Verify::default();
        self.drive(hw, 0.0);
    }

    fn drive(&mut self, hw: &mut dyn IoHw, duty: f32) {
        self.duty = duty;
        if let Some(o) = self.output {
            hw.write_pwm(o.pwm, (duty * 65_535.0 + 0.5) as u16);
        }
    }

    /// The sensor and limit checks on a reading.
    fn check_sensor(&self, raw: u16, temp: f32) -> Option<RunawayReason> {
        let (min, max) = self.limits?;
        if raw >= u16::MAX - SENSOR_MARGIN {
            Some(RunawayReason::SensorOpen)
        } else if raw <= SENSOR_MARGIN {
            Some(RunawayReason::SensorShort)
        } else if temp.is_nan() || temp < min {
            // An open thermistor reads cold.
            Some(RunawayReason::SensorOpen)
        } else if temp >= max {
            Some(RunawayReason::OverTemp)
        } else {
            None
        }
    }

    /// Klipper's `verify_heater` check, at local `now`, `dt` s after the
    /// previous reading.
    fn check_runaway(
        &mut self,
        now: Instant,
        temp: f32,
        target: f32,
        dt: f32,
    ) -> Option<RunawayReason> {
        let r = self.runaway;
        let v = &mut self.verify;
        if temp >= target - r.hysteresis_c {
            // Near the target: the checks start again.
            v.approaching = false;
            v.starting = false;
            if temp <= target + r.hysteresis_c {
                v.error = 0.0;
            }
            v.last_target = target;
            return None;
        }
        v.error += (target - r.hysteresis_c - temp) * dt;
        let gain_time = || Duration::from_micros((r.check_gain_time_s * 1e6) as u64);
        if !v.approaching {
            if target != v.last_target {
                // A new target: it must start to rise.
                v.approaching = true;
                v.starting = true;
                v.goal_temp = temp + r.heating_gain_c;
                v.goal_time = now + gain_time();
            } else if v.error >= r.max_error {
                return Some(RunawayReason::FellFromTarget);
            }
        } else if temp >= v.goal_temp {
            v.starting = false;
            v.error = 0.0;
            v.goal_temp = temp + r.heating_gain_c;
            v.goal_time = now + gain_time();
        } else if now >= v.goal_time {
            return Some(RunawayReason::NotHeating);
        } else if v.starting {
            // Still cooling when the target came: the rise counts from the
            // lowest reading.
            v.goal_temp = v.goal_temp.min(temp + r.heating_gain_c);
        }
        v.last_target = target;
        None
    }

    /// The PID's duty for `target` at `temp`, `dt` s after the previous
    /// reading (the derivative is already updated).
    fn pid(&mut self, temp: f32, target: f32, dt: f32) -> f32 {
        let (Some(g), Some(o)) = (self.gains, self.output) else {
            return 0.0;
        };
        let err = target - temp;
        let integ_max = if g.ki > 0.0 {
            o.max_power * PID_PARAM_BASE / g.ki
        } else {
            0.0
        };
        let integ = (self.integ + err * dt).clamp(0.0, integ_max);
        let co = (g.kp * err + g.ki * integ - g.kd * self.deriv) * (1.0 / PID_PARAM_BASE);
        let bounded = co.clamp(0.0, o.max_power);
        // Anti-windup: the integral grows only while the output is free.
        if co == bounded {
            self.integ = integ;
        }
        bounded
    }

    /// One control period at local `now`: read, check, drive. Returns a
    /// new runaway fault.
    fn poll(&mut self, hw: &mut dyn IoHw, now: Instant) -> Option<RunawayReason> {
        let sensor = self.sensor?;
        self.limits?;
        let raw = hw.read_analog(sensor.analog);
        let temp = sensor.thermistor.celsius(raw);
        let (dt, dtemp) = match self.reading {
            Some((t, prev)) if now > t => ((now - t).as_micros() as f32 * 1e-6, temp - prev),
            _ => (0.0, 0.0),
        };
        self.reading = Some((now, temp));
        // The smoothed derivative (Klipper's): a plain difference over a
        // period of at least DERIVATIVE_TIME_S, an average below it.
        if dt >= DERIVATIVE_TIME_S {
            self.deriv = dtemp / dt;
        } else if dtemp.is_finite() {
            self.deriv =
                (self.deriv * (DERIVATIVE_TIME_S - dt) + dtemp) * (1.0 / DERIVATIVE_TIME_S);
        }
        if self.fault.is_some() {
            self.drive(hw, 0.0);
            return None;
        }
        let fault = self.check_sensor(raw, temp).or_else(|| match self.mode {
            Mode::Target(target) => self.check_runaway(now, temp, target, dt),
            _ => None,
        });
        if let Some(reason) = fault {
            self.fault = Some(reason);
            self.off(hw);
            return Some(reason);
        }
        let duty = match self.mode {
            Mode::Off => 0.0,
            Mode::Power(d) => d,
            Mode::Target(target) => self.pid(temp, target, dt),
        };
        let cap = self.output.map_or(0.0, |o| o.max_power);
        self.drive(hw, duty.min(cap));
        None
    }
}

/// Every heater of a module.
#[derive(Debug, Clone)]
pub struct Heaters {
    heaters: [Heater; HEATERS],
}

impl Default for Heaters {
    fn default() -> Self {
        Heaters::new()
    }
}

fn finite(values: &[f32]) -> bool {
    values.iter().all(|v| v.is_finite())
}

impl Heaters {
    /// No heater configured.
    pub const fn new() -> Self {
        Heaters {
            heaters: [Heater::new(); HEATERS],
        }
    }

    /// Heater `index`, if there is one.
    pub fn heater(&self, index: u8) -> Option<&Heater> {
        self.heaters.get(usize::from(index))
    }

    fn get(&mut self, index: u8) -> Result<&mut Heater, HeaterError> {
        self.heaters
            .get_mut(usize::from(index))
            .ok_or(HeaterError::NoSuchHeater)
    }

    /// Heater `index`, for a setting that may change only while it is off.
    fn idle(&mut self, index: u8) -> Result<&mut Heater, HeaterError> {
        let h = self.get(index)?;
        if h.mode != Mode::Off {
            return Err(HeaterError::Busy);
        }
        Ok(h)
    }

    /// Whether a heater drives PWM output `pwm` (`pwm_write` and
    /// `set_safe_pwm` then refuse it).
    pub fn drives(&self, pwm: u8) -> bool {
        self.heaters
            .iter()
            .any(|h| h.output.is_some_and(|o| o.pwm == pwm))
    }

    /// Heater `index` reads analog input `analog` through `thermistor`.
    /// Only while the heater is off.
    pub fn set_sensor(
        &mut self,
        hw: &dyn IoHw,
        index: u8,
        analog: u8,
        thermistor: Thermistor,
    ) -> Result<(), HeaterError> {
        if analog >= hw.analog_inputs() {
            return Err(HeaterError::NoSuchPin);
        }
        let h = self.idle(index)?;
        if !thermistor.is_valid() {
            return Err(HeaterError::BadValue);
        }
        h.sensor = Some(Sensor { analog, thermistor });
        h.reading = None;
        Ok(())
    }

    /// Heater `index` drives PWM output `pwm`, at most `max_power` (a
    /// fraction, `0 < max_power ≤ 1`) of full duty. The output goes to 0 at
    /// once, and a previous output of the heater's too. Only while the
    /// heater is off.
    pub fn set_output(
        &mut self,
        hw: &mut dyn IoHw,
        index: u8,
        pwm: u8,
        max_power: f32,
    ) -> Result<(), HeaterError> {
        if pwm >= hw.pwm_outputs() {
            return Err(HeaterError::NoSuchPin);
        }
        let other = self
            .heaters
            .iter()
            .enumerate()
            .any(|(i, h)| i != usize::from(index) && h.output.is_some_and(|o| o.pwm == pwm));
        let h = self.idle(index)?;
        if !(max_power > 0.0 && max_power <= 1.0) {
            return Err(HeaterError::BadValue);
        }
        if other {
            return Err(HeaterError::InUse);
        }
        if let Some(old) = h.output {
            hw.write_pwm(old.pwm, 0);
        }
        h.output = Some(Output { pwm, max_power });
        h.drive(hw, 0.0);
        Ok(())
    }

    /// Heater `index`'s limits, °C: it runs between `min_temp` and
    /// `max_temp` (finite, `min_temp < max_temp`). Only while the heater is
    /// off.
    pub fn set_limits(
        &mut self,
        index: u8,
        min_temp: f32,
        max_temp: f32,
    ) -> Result<(), HeaterError> {
        let h = self.idle(index)?;
        if !(finite(&[min_temp, max_temp]) && min_temp < max_temp) {
            return Err(HeaterError::BadValue);
        }
        h.limits = Some((min_temp, max_temp));
        Ok(())
    }

    /// Heater `index`'s PID gains, Klipper's units (finite, not negative).
    /// Only while the heater is off.
    pub fn set_gains(&mut self, index: u8, gains: Gains) -> Result<(), HeaterError> {
        let h = self.idle(index)?;
        let all = [gains.kp, gains.ki, gains.kd];
        if !(finite(&all) && all.iter().all(|g| *g >= 0.0)) {
            return Err(HeaterError::BadValue);
        }
        h.gains = Some(gains);
        Ok(())
    }

    /// Heater `index`'s runaway settings (finite; `max_error`,
    /// `heating_gain_c` and `check_gain_time_s` positive, `hysteresis_c`
    /// not negative, `check_gain_time_s` at most an hour). Only while the
    /// heater is off.
    pub fn set_runaway(&mut self, index: u8, runaway: Runaway) -> Result<(), HeaterError> {
        let h = self.idle(index)?;
        let r = runaway;
        let ok = finite(&[
            r.hysteresis_c,
            r.max_error,
            r.heating_gain_c,
            r.check_gain_time_s,
        ]) && r.hysteresis_c >= 0.0
            && r.max_error > 0.0
            && r.heating_gain_c > 0.0
            && r.check_gain_time_s > 0.0
            && r.check_gain_time_s <= 3_600.0;
        if !ok {
            return Err(HeaterError::BadValue);
        }
        h.runaway = runaway;
        Ok(())
    }

    /// Heater `index` holds `celsius` (in `[min_temp, max_temp)`); 0 turns
    /// it off. Leaves open-loop power mode. Refused for a heater without
    /// sensor, output, limits or gains, and for a faulted one (0 is always
    /// taken).
    pub fn set_target(
        &mut self,
        hw: &mut dyn IoHw,
        index: u8,
        celsius: f32,
    ) -> Result<(), HeaterError> {
        let h = self.get(index)?;
        if celsius == 0.0 {
            h.off(hw);
            return Ok(());
        }
        if h.fault.is_some() {
            return Err(HeaterError::Faulted);
        }
        let (Some((min, max)), Some(_), Some(_), Some(_)) = (h.limits, h.sensor, h.output, h.gains)
        else {
            return Err(HeaterError::NotConfigured);
        };
        if !(celsius >= min && celsius < max) {
            return Err(HeaterError::BadValue);
        }
        if h.mode != Mode::Target(celsius) {
            if !matches!(h.mode, Mode::Target(_)) {
                h.integ = 0.0;
                h.verify = Verify::default();
            }
            h.mode = Mode::Target(celsius);
        }
        // The next period comes at once: the heater starts now.
        h.next = Instant::ZERO;
        Ok(())
    }

    /// Heater `index` runs open loop at `duty` (`0..=1`, capped at
    /// `max_power`), for autotuning: the sensor, `max_temp` and the
    /// watchdog still guard it, the heating and holding checks do not. A
    /// target (or 0) leaves it.
    pub fn set_power(&mut self, index: u8, duty: f32) -> Result<(), HeaterError> {
        let h = self.get(index)?;
        if h.fault.is_some() {
            return Err(HeaterError::Faulted);
        }
        if !(h.monitored() && h.output.is_some()) {
            return Err(HeaterError::NotConfigured);
        }
        if !(0.0..=1.0).contains(&duty) {
            return Err(HeaterError::BadValue);
        }
        h.mode = Mode::Power(duty);
        h.integ = 0.0;
        h.verify = Verify::default();
        h.next = Instant::ZERO;
        Ok(())
    }

    /// Clears heater `index`'s runaway fault, if its sensor reads sane now
    /// (neither open nor shorted, within its limits); the heater is then
    /// off. A heater without a fault clears at once.
    pub fn clear(&mut self, hw: &mut dyn IoHw, index: u8) -> Result<(), HeaterError> {
        let h = self.get(index)?;
        if h.fault.is_none() {
            return Ok(());
        }
        if let Some(s) = h.sensor {
            let raw = hw.read_analog(s.analog);
            if h.check_sensor(raw, s.thermistor.celsius(raw)).is_some() {
                return Err(HeaterError::SensorFault);
            }
        }
        h.fault = None;
        h.off(hw);
        Ok(())
    }

    /// Turns every heater off (target 0, duty 0): every stop and the output
    /// watchdog do. A faulted heater stays faulted.
    pub fn off_all(&mut self, hw: &mut dyn IoHw) {
        for h in &mut self.heaters {
            h.off(hw);
        }
    }

    /// Runs heater `index`'s control period if it has a sensor and limits
    /// and its period is due at local `now`. Returns the runaway fault it
    /// found. One heater at a time, so a firmware holds its critical
    /// section for one heater's work (about 80 µs on a 125 MHz Cortex-M0+,
    /// in soft float).
    pub fn poll_heater(
        &mut self,
        hw: &mut dyn IoHw,
        now: Instant,
        index: u8,
    ) -> Option<RunawayReason> {
        let h = self.heaters.get_mut(usize::from(index))?;
        if !h.monitored() || now < h.next {
            return None;
        }
        // Late periods are not made up: the next is a period from now.
        h.next = now + CONTROL_PERIOD;
        h.poll(hw, now)
    }

    /// [`poll_heater`](Self::poll_heater) for every heater, by index.
    pub fn poll(&mut self, hw: &mut dyn IoHw, now: Instant) -> [Option<RunawayReason>; HEATERS] {
        let mut faults = [None; HEATERS];
        for (i, f) in faults.iter_mut().enumerate() {
            *f = self.poll_heater(hw, now, i as u8);
        }
        faults
    }

    /// When [`poll`](Self::poll) next has work, local time: `None` while no
    /// heater has a sensor and limits.
    pub fn wake_at(&self) -> Option<Instant> {
        self.heaters
            .iter()
            .filter(|h| h.monitored())
            .map(|h| h.next)
            .min()
    }
}
