//! What a simulated module's board carries, as a [`SimSpec`](super::SimSpec)
//! describes it: its motor and limit switch, its I/O pins with an
//! accelerometer on one and heaters on a PWM output and an analog input
//! each, and its UF2 bootloader.

use serde::{Deserialize, Serialize};

/// A board setting out of range; the message names the key and why.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct BoardError(String);

impl BoardError {
    pub(super) fn new(message: impl Into<String>) -> Self {
        BoardError(message.into())
    }
}
use std::path::PathBuf;
use uf2_link::uf2::{RP2040_FAMILY_ID, SAMD51_FAMILY_ID};

/// Digital pins of a simulated module (as on the RP2040 board).
pub const DIGITAL_PINS: u8 = 4;
/// PWM outputs of a simulated module.
pub const PWM_OUTPUTS: u8 = 2;
/// Analog inputs of a simulated module.
pub const ANALOG_INPUTS: u8 = 3;
/// The microstep modes the simulated driver can set: 1 to 256, as a
/// TMC2209 or TMC5160 does (and as the machine file allows).
pub const DRIVER_MICROSTEPS: [u16; 9] = [1, 2, 4, 8, 16, 32, 64, 128, 256];

fn default_full_steps_per_unit() -> f64 {
    80.0
}

/// What the motor of a simulated module drives, `[module.motor]` in a
/// topology file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotorSpec {
    /// Full motor steps per unit of carriage travel (80: a 1.8° motor on a
    /// GT2 belt and 20-tooth pulley, in mm). What the module's `set_scale`
    /// should be told for its positions to be carriage units.
    #[serde(default = "default_full_steps_per_unit")]
    pub full_steps_per_unit: f64,
    /// A limit switch at this carriage position (units), pressed below it
    /// (a minimum endstop); absent: no switch (its input reads released,
    /// unless a [`SwitchSpec`](super::SwitchSpec) over several motors
    /// drives it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub limit_min: Option<f64>,
    /// A limit switch pressed above this carriage position (a maximum
    /// endstop). At most one of `limit_min` and `limit_max`: the module has
    /// one limit input.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub limit_max: Option<f64>,
    /// Keep every step edge (time and direction) for [`Motor::edges`](crate::machine::board::Motor::edges). On
    /// by default; a very long run may turn it off and read only the counts.
    #[serde(default = "yes")]
    pub record: bool,
    /// The motor's rotor behind its driver, which stalls when asked for
    /// more torque than it has (absent: the carriage takes every step).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotor: Option<RotorSpec>,
}

/// A simulated stepper's rotor (see
/// [`Rotor`](crate::machine::board::rotor::Rotor)): its motor, the load's
/// inertia reflected onto its shaft, and how damped it follows.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RotorSpec {
    /// The motor.
    pub model: maxl::motor::StepperModel,
    /// The load's inertia on the motor's shaft, kg·m².
    pub load_inertia_kgm2: f64,
    /// The damping ratio of the rotor's small-signal mode; default 0.3.
    #[serde(default = "default_rotor_damping")]
    pub damping_ratio: f64,
}

fn default_rotor_damping() -> f64 {
    0.3
}

fn yes() -> bool {
    true
}

impl Default for MotorSpec {
    fn default() -> Self {
        MotorSpec {
            full_steps_per_unit: default_full_steps_per_unit(),
            limit_min: None,
            limit_max: None,
            record: true,
            rotor: None,
        }
    }
}

impl MotorSpec {
    /// Checks the values; the message says which and why.
    pub fn check(&self) -> Result<(), BoardError> {
        if !(self.full_steps_per_unit.is_finite() && self.full_steps_per_unit > 0.0) {
            return Err(BoardError::new(format!(
                "[module.motor] full_steps_per_unit {} must be finite and positive",
                self.full_steps_per_unit
            )));
        }
        if self.limit_min.is_some() && self.limit_max.is_some() {
            return Err(BoardError::new(
                "[module.motor] has both limit_min and limit_max: a module has one limit input",
            ));
        }
        for x in [self.limit_min, self.limit_max].into_iter().flatten() {
            if !x.is_finite() {
                return Err(BoardError::new(format!(
                    "[module.motor] limit position {x} must be finite"
                )));
            }
        }
        if let Some(r) = &self.rotor {
            r.model
                .check()
                .map_err(|e| BoardError::new(format!("[module.motor.rotor.model] {e}")))?;
            for (name, v) in [
                ("load_inertia_kgm2", r.load_inertia_kgm2),
                ("damping_ratio", r.damping_ratio),
            ] {
                if !(v.is_finite() && v >= 0.0) {
                    return Err(BoardError::new(format!(
                        "[module.motor.rotor] {name} {v} must be finite and at least 0"
                    )));
                }
            }
        }
        Ok(())
    }
}

/// What the I/O pins of a simulated module read at boot, `[module.io]`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IoSpec {
    /// Levels of the digital pins while nothing drives them (at most 4).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub digital: Vec<bool>,
    /// Analog inputs, fractions of full scale `0..=1` (at most 3).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub analog: Vec<f64>,
    /// An accelerometer on one analog input, seeing this module's carriage
    /// (`[module.io.accel]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub accel: Option<AccelSpec>,
    /// Heated blocks, each heated by a PWM output and read by a thermistor
    /// on an analog input (`[[module.io.heater]]`; at most one per PWM
    /// output).
    #[serde(default, rename = "heater", skip_serializing_if = "Vec::is_empty")]
    pub heaters: Vec<HeaterSpec>,
    /// A melt behind this module's extruder, weighed by a load cell on two
    /// digital pins (`[module.io.melt]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub melt: Option<MeltSpec>,
    /// A load cell this module's axis presses on a bed with, on two
    /// digital pins (`[module.io.contact]`): a nozzle load-cell probe.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub contact: Option<ContactSpec>,
    /// A spindle commanded by a PWM output, its tachometer on a digital
    /// pin (`[module.io.spindle]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub spindle: Option<super::SpindleSpec>,
}

impl IoSpec {
    /// Checks the values; the message says which and why.
    pub fn check(&self) -> Result<(), BoardError> {
        if self.digital.len() > usize::from(DIGITAL_PINS) {
            return Err(BoardError::new(format!(
                "[module.io] digital lists {} pins; a module has {DIGITAL_PINS}",
                self.digital.len()
            )));
        }
        if self.analog.len() > usize::from(ANALOG_INPUTS) {
            return Err(BoardError::new(format!(
                "[module.io] analog lists {} inputs; a module has {ANALOG_INPUTS}",
                self.analog.len()
            )));
        }
        if let Some(v) = self.analog.iter().find(|v| !(0.0..=1.0).contains(*v)) {
            return Err(BoardError::new(format!(
                "[module.io] analog value {v} must be a fraction of full scale, 0 to 1"
            )));
        }
        if let Some(a) = &self.accel {
            a.check()?;
        }
        if let Some(sp) = &self.spindle {
            sp.check()?;
            if self.heaters.iter().any(|h| h.pwm == sp.pwm) {
                return Err(BoardError::new(format!(
                    "[module.io.spindle] pwm {} drives a heater too: give each its own output",
                    sp.pwm
                )));
            }
        }
        if let Some(c) = &self.contact {
            c.check()?;
            if self.melt.is_some() {
                return Err(BoardError::new(
                    "[module.io.contact] and [module.io.melt] on one module: a module reads one \
                     load cell (its driver has one converter)",
                ));
            }
        }
        if let Some(m) = &self.melt {
            m.check()?;
            if !self.heaters.iter().any(|h| h.pwm == m.heater_pwm) {
                return Err(BoardError::new(format!(
                    "[module.io.melt] heater_pwm {} drives no [[module.io.heater]] of this \
                     module: the melt is at its block's temperature",
                    m.heater_pwm
                )));
            }
        }
        for (i, h) in self.heaters.iter().enumerate() {
            h.check()?;
            let before = &self.heaters[..i];
            if before.iter().any(|o| o.pwm == h.pwm) {
                return Err(BoardError::new(format!(
                    "[[module.io.heater]] two heaters on pwm {}: give each its own output",
                    h.pwm
                )));
            }
            let taken = before.iter().any(|o| o.analog == h.analog)
                || self.accel.as_ref().is_some_and(|a| a.channel == h.analog);
            if taken {
                return Err(BoardError::new(format!(
                    "[[module.io.heater]] analog {} already reads another heater or the \
                     accelerometer: give each its own input",
                    h.analog
                )));
            }
        }
        Ok(())
    }
}

fn default_beta() -> f64 {
    3950.0
}

fn default_r25_ohms() -> f64 {
    100_000.0
}

fn default_pullup_ohms() -> f64 {
    4_700.0
}

fn default_ambient_c() -> f64 {
    25.0
}

/// A heated block on a module's I/O pins (`[[module.io.heater]]` in a
/// topology file): a heater of `power_w` on PWM output `pwm` heats a block
/// of `heat_capacity_j_per_k` that loses `loss_w_per_k` to the room,
///
/// ```text
/// C·dT/dt = power_w·duty − loss_w_per_k·(T − ambient_c)
/// ```
///
/// and an NTC thermistor to ground in it, with a pullup to the converter's
/// reference, is read on analog input `analog` (the fraction `R / (R +
/// pullup_ohms)` of full scale). The thermistor is a Beta model (`beta`,
/// `r25_ohms`), or the Steinhart–Hart curve `steinhart_hart = [a, b, c]`
/// (`1/T = a + b·ln R + c·ln³R`, T in K) instead when that is given. The
/// defaults are the common printer thermistor: 100 kΩ at 25 °C, β 3950,
/// on a 4.7 kΩ pullup.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeaterSpec {
    /// The PWM output that drives the heater (0..=1).
    pub pwm: u8,
    /// The analog input its thermistor is read on (0..=2).
    pub analog: u8,
    /// The thermistor's β, K (> 0; default 3950).
    #[serde(default = "default_beta")]
    pub beta: f64,
    /// The thermistor's resistance at 25 °C, Ω (> 0; default 100 000).
    #[serde(default = "default_r25_ohms")]
    pub r25_ohms: f64,
    /// The thermistor's Steinhart–Hart curve `[a, b, c]`, 1/K, instead of
    /// `beta` and `r25_ohms` (its resistance must fall as it warms).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub steinhart_hart: Option<[f64; 3]>,
    /// The pullup, Ω (> 0; default 4 700).
    #[serde(default = "default_pullup_ohms")]
    pub pullup_ohms: f64,
    /// The heater's power at full duty, W (≥ 0; 40 for a hotend
    /// cartridge; 0 stands for a broken one).
    pub power_w: f64,
    /// The block's heat capacity, J/K (> 0; about 15 for a hotend's block
    /// and nozzle).
    pub heat_capacity_j_per_k: f64,
    /// What the block loses to the room per kelvin above it, W/K (≥ 0).
    pub loss_w_per_k: f64,
    /// The room, °C (default 25); the block starts at it.
    #[serde(default = "default_ambient_c")]
    pub ambient_c: f64,
    /// From this many seconds after the module boots, the thermistor reads
    /// open (full scale), as a thermistor whose wire broke.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sensor_fails_at_s: Option<f64>,
}

impl HeaterSpec {
    /// Checks the values; the message says which and why.
    pub fn check(&self) -> Result<(), BoardError> {
        if self.pwm >= PWM_OUTPUTS {
            return Err(BoardError::new(format!(
                "[[module.io.heater]] pwm {} does not exist: a module has PWM outputs 0 to {}",
                self.pwm,
                PWM_OUTPUTS - 1
            )));
        }
        if self.analog >= ANALOG_INPUTS {
            return Err(BoardError::new(format!(
                "[[module.io.heater]] analog {} does not exist: a module has analog inputs 0 to {}",
                self.analog,
                ANALOG_INPUTS - 1
            )));
        }
        let positive = [
            ("beta", self.beta),
            ("r25_ohms", self.r25_ohms),
            ("pullup_ohms", self.pullup_ohms),
            ("heat_capacity_j_per_k", self.heat_capacity_j_per_k),
        ];
        for (key, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(BoardError::new(format!(
                    "[[module.io.heater]] {key} {v} must be finite and positive"
                )));
            }
        }
        for (key, v) in [
            ("power_w", self.power_w),
            ("loss_w_per_k", self.loss_w_per_k),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(BoardError::new(format!(
                    "[[module.io.heater]] {key} {v} must be finite and 0 or more"
                )));
            }
        }
        if let Some([a, b, c]) = self.steinhart_hart {
            // Falling resistance from 1 Ω to 100 MΩ: ln R from 0 to 18.4.
            let slope = |l: f64| b + 3.0 * c * l * l;
            if !([a, b, c].iter().all(|v| v.is_finite()) && slope(0.0) > 0.0 && slope(18.42) > 0.0)
            {
                return Err(BoardError::new(format!(
                    "[[module.io.heater]] steinhart_hart [{a}, {b}, {c}] is no thermistor: its \
                     resistance must fall as it warms, from 1 Ω to 100 MΩ"
                )));
            }
        }
        if !(self.ambient_c.is_finite() && self.ambient_c > -273.15) {
            return Err(BoardError::new(format!(
                "[[module.io.heater]] ambient_c {} must be finite and above absolute zero",
                self.ambient_c
            )));
        }
        if let Some(t) = self.sensor_fails_at_s {
            if !(t.is_finite() && t >= 0.0) {
                return Err(BoardError::new(format!(
                    "[[module.io.heater]] sensor_fails_at_s {t} must be finite and 0 or more \
                     (seconds after the module boots)"
                )));
            }
        }
        Ok(())
    }
}

/// An accelerometer on a module's analog input (`[module.io.accel]` in a
/// topology file).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AccelSpec {
    /// The analog input it is wired to (0..=2).
    pub channel: u8,
    /// The mode's natural frequency, Hz (> 0).
    pub resonance_hz: f64,
    /// The mode's damping ratio (≥ 0).
    pub damping_ratio: f64,
    /// Acceleration at full scale, carriage units/s² (> 0): a reading of
    /// 0 is `−range`, 1 is `+range`, 0.5 is at rest.
    pub range: f64,
    /// Axis units per carriage unit (±1 for an axis on this motor alone; a
    /// CoreXY belt motor moves with x and y alike). The sensor measures
    /// along the axis, so its reading is the carriage's times this.
    #[serde(default = "one")]
    pub coef: f64,
}

fn one() -> f64 {
    1.0
}

impl AccelSpec {
    /// Checks the values; the message says which and why.
    pub fn check(&self) -> Result<(), BoardError> {
        if self.channel >= ANALOG_INPUTS {
            return Err(BoardError::new(format!(
                "[module.io.accel] channel {} does not exist: a module has analog inputs 0 to {}",
                self.channel,
                ANALOG_INPUTS - 1
            )));
        }
        if !(self.resonance_hz.is_finite() && self.resonance_hz > 0.0) {
            return Err(BoardError::new(format!(
                "[module.io.accel] resonance_hz {} must be finite and positive",
                self.resonance_hz
            )));
        }
        if !(self.damping_ratio.is_finite() && self.damping_ratio >= 0.0) {
            return Err(BoardError::new(format!(
                "[module.io.accel] damping_ratio {} must be finite and 0 or more",
                self.damping_ratio
            )));
        }
        if !(self.range.is_finite() && self.range > 0.0) {
            return Err(BoardError::new(format!(
                "[module.io.accel] range {} must be finite and positive (units/s² at full scale)",
                self.range
            )));
        }
        if !(self.coef.is_finite() && self.coef != 0.0) {
            return Err(BoardError::new(format!(
                "[module.io.accel] coef {} must be finite and not 0",
                self.coef
            )));
        }
        Ok(())
    }
}

fn default_reboot_ms() -> u64 {
    300
}

/// Which chip a simulated board stands for, and so which UF2 bootloader.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Chip {
    /// A Raspberry Pi Pico: the RP2040 boot ROM's USB drive.
    #[default]
    Rp2040,
    /// An Adafruit Metro M4 (SAMD51J19): Adafruit's UF2 bootloader.
    Samd51,
}

impl Chip {
    /// The UF2 family id the chip's bootloader takes.
    pub fn family_id(self) -> u32 {
        match self {
            Chip::Rp2040 => RP2040_FAMILY_ID,
            Chip::Samd51 => SAMD51_FAMILY_ID,
        }
    }

    /// The chip's name, as the topology spells it.
    pub fn name(self) -> &'static str {
        match self {
            Chip::Rp2040 => "rp2040",
            Chip::Samd51 => "samd51",
        }
    }

    /// What its bootloader's `INFO_UF2.TXT` says.
    pub fn info_text(self) -> &'static str {
        match self {
            Chip::Rp2040 => "UF2 Bootloader v3.0\r\nModel: Raspberry Pi RP2\r\nBoard-ID: RPI-RP2\r\n",
            Chip::Samd51 => {
                "UF2 Bootloader v3.14.0 SFHWRO\r\nModel: Metro M4 Express\r\nBoard-ID: SAMD51J19A-Metro-v0\r\n"
            }
        }
    }
}

/// A simulated module's UF2 bootloader, `[module.bootloader]`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BootloaderSpec {
    /// The directory its drive appears in (created if missing). Point
    /// `OSAP_UF2_MOUNTS` at it (or at its parent) for `osap flash` to find
    /// it.
    pub drive: PathBuf,
    /// Which chip, and so which bootloader and UF2 family (default
    /// `rp2040`).
    #[serde(default)]
    pub chip: Chip,
    /// How long the board takes to reboot into the new firmware once a UF2
    /// has landed, ms (default 300).
    #[serde(default = "default_reboot_ms")]
    pub reboot_ms: u64,
}

impl BootloaderSpec {
    /// A bootloader of `chip` whose drive is `drive`.
    pub fn new(drive: impl Into<PathBuf>, chip: Chip) -> Self {
        BootloaderSpec {
            drive: drive.into(),
            chip,
            reboot_ms: default_reboot_ms(),
        }
    }

    /// Checks the values; the message says which and why.
    pub fn check(&self) -> Result<(), BoardError> {
        if self.drive.as_os_str().is_empty() {
            return Err(BoardError::new(
                "[module.bootloader] drive is empty: give the directory its \
                 simulated USB drive appears in",
            ));
        }
        if self.reboot_ms > 60_000 {
            return Err(BoardError::new(format!(
                "[module.bootloader] reboot_ms {} is over a minute: a board reboots in well \
                 under a second",
                self.reboot_ms
            )));
        }
        Ok(())
    }
}

/// A melt behind a module's extruder and the load cell that weighs it
/// (`[module.io.melt]` in a topology file; see
/// [`crate::machine::board::melt`]): the module's motor pushes filament
/// of `filament_diameter` into a melt zone whose outflow lags with
/// `response_ms`, at the temperature of the block `heater_pwm` heats, and
/// the filament needs `F = flow_k · Q^flow_n · exp(−temp_coeff · (T −
/// t_ref))` newtons. An HX711 on digital pins `data_pin` and `clock_pin`
/// weighs it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeltSpec {
    /// The filament, mm (default 1.75).
    #[serde(default = "default_filament")]
    pub filament_diameter: f64,
    /// The PWM output of the heater whose block the melt is in.
    #[serde(default)]
    pub heater_pwm: u8,
    /// Force at 1 mm³/s and `t_ref`, N (> 0).
    pub flow_k: f64,
    /// The flow exponent (0 < n ≤ 1.5; below 1: shear-thinning).
    pub flow_n: f64,
    /// How fast the melt thins as it warms, 1/°C (≥ 0).
    pub temp_coeff: f64,
    /// The reference temperature, °C.
    pub t_ref: f64,
    /// The outflow's lag behind the push, ms (> 0).
    pub response_ms: f64,
    /// The load cell's noise, N (one σ, ≥ 0).
    #[serde(default)]
    pub noise_n: f64,
    /// The drive's grip: above this force the filament slips, N (> 0).
    pub grip_n: f64,
    /// The converter's data line: this digital pin.
    #[serde(default)]
    pub data_pin: u8,
    /// The converter's clock line: this digital pin.
    #[serde(default = "one_u8")]
    pub clock_pin: u8,
    /// Conversions a second (10 or 80 on an HX711; default 80).
    #[serde(default = "default_sample_hz")]
    pub sample_hz: f64,
    /// Counts per newton (default 2 000: a 5 kg cell at gain 128).
    #[serde(default = "default_counts_per_newton")]
    pub counts_per_newton: f64,
    /// Counts at no force (default 85 000: a bridge's own imbalance).
    #[serde(default = "default_offset_counts")]
    pub offset_counts: f64,
    /// The cell's own lag, ms (default 2).
    #[serde(default = "default_sensor_tau_ms")]
    pub sensor_tau_ms: f64,
    /// The noise's seed.
    #[serde(default)]
    pub seed: u64,
}

fn default_filament() -> f64 {
    1.75
}
fn one_u8() -> u8 {
    1
}
fn default_sample_hz() -> f64 {
    80.0
}
fn default_counts_per_newton() -> f64 {
    2_000.0
}
fn default_offset_counts() -> f64 {
    85_000.0
}
fn default_sensor_tau_ms() -> f64 {
    2.0
}

impl Default for MeltSpec {
    /// A PLA-like melt on a 40 N drive: 20 N at 5 mm³/s and 210 °C, 32 N
    /// (80 % of the grip) at 10 mm³/s.
    fn default() -> Self {
        MeltSpec {
            filament_diameter: default_filament(),
            heater_pwm: 0,
            flow_k: 8.0,
            flow_n: 0.6,
            temp_coeff: 0.02,
            t_ref: 210.0,
            response_ms: 60.0,
            noise_n: 0.05,
            grip_n: 40.0,
            data_pin: 0,
            clock_pin: 1,
            sample_hz: default_sample_hz(),
            counts_per_newton: default_counts_per_newton(),
            offset_counts: default_offset_counts(),
            sensor_tau_ms: default_sensor_tau_ms(),
            seed: 0,
        }
    }
}

impl MeltSpec {
    /// Checks the values; the message says which and why.
    pub fn check(&self) -> Result<(), BoardError> {
        let positive = [
            ("filament_diameter", self.filament_diameter),
            ("flow_k", self.flow_k),
            ("response_ms", self.response_ms),
            ("grip_n", self.grip_n),
            ("sample_hz", self.sample_hz),
            ("counts_per_newton", self.counts_per_newton),
        ];
        for (key, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(BoardError::new(format!(
                    "[module.io.melt] {key} {v} must be finite and positive"
                )));
            }
        }
        for (key, v) in [
            ("temp_coeff", self.temp_coeff),
            ("noise_n", self.noise_n),
            ("sensor_tau_ms", self.sensor_tau_ms),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(BoardError::new(format!(
                    "[module.io.melt] {key} {v} must be finite and 0 or more"
                )));
            }
        }
        if !(self.flow_n > 0.0 && self.flow_n <= 1.5) {
            return Err(BoardError::new(format!(
                "[module.io.melt] flow_n {} must be within (0, 1.5]: melts thin or stay \
                 Newtonian as they flow faster",
                self.flow_n
            )));
        }
        if !self.t_ref.is_finite() || !self.offset_counts.is_finite() {
            return Err(BoardError::new(
                "[module.io.melt] t_ref and offset_counts must be finite",
            ));
        }
        for (key, pin) in [("data_pin", self.data_pin), ("clock_pin", self.clock_pin)] {
            if pin >= DIGITAL_PINS {
                return Err(BoardError::new(format!(
                    "[module.io.melt] {key} {pin} does not exist: a module has digital pins 0 \
                     to {}",
                    DIGITAL_PINS - 1
                )));
            }
        }
        if self.data_pin == self.clock_pin {
            return Err(BoardError::new(
                "[module.io.melt] data_pin and clock_pin are the same pin: the converter needs two",
            ));
        }
        if self.heater_pwm >= PWM_OUTPUTS {
            return Err(BoardError::new(format!(
                "[module.io.melt] heater_pwm {} does not exist",
                self.heater_pwm
            )));
        }
        Ok(())
    }
}

/// A load cell under a module's axis that presses a bed
/// (`[module.io.contact]` in a topology file; see
/// [`crate::machine::board::contact`]): a nozzle load-cell probe. Past
/// `touch_at` the bed pushes back with `stiffness_n_per_unit` newtons per
/// unit of the module's carriage; an HX711-kind converter on `data_pin` and
/// `clock_pin` weighs it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ContactSpec {
    /// The carriage position (the module's units) where the tip touches.
    pub touch_at: f64,
    /// Pressing while the carriage is below `touch_at` (default; `false`:
    /// above it).
    #[serde(default = "default_true")]
    pub pressing_below: bool,
    /// How hard the bed pushes back, N per unit past the touch (default
    /// 40: a printer's bed and gantry).
    #[serde(default = "default_stiffness")]
    pub stiffness_n_per_unit: f64,
    /// The converter's data line: this digital pin.
    #[serde(default)]
    pub data_pin: u8,
    /// The converter's clock line: this digital pin.
    #[serde(default = "one_u8")]
    pub clock_pin: u8,
    /// Conversions a second (default 320: an HX717, as probing load cells
    /// use; an HX711 gives 10 or 80).
    #[serde(default = "default_contact_hz")]
    pub sample_hz: f64,
    /// Counts per newton (default 2 000).
    #[serde(default = "default_counts_per_newton")]
    pub counts_per_newton: f64,
    /// Counts at no force (default 85 000).
    #[serde(default = "default_offset_counts")]
    pub offset_counts: f64,
    /// The cell's noise, N (one σ; default 0.02).
    #[serde(default = "default_contact_noise")]
    pub noise_n: f64,
    /// The noise's seed.
    #[serde(default)]
    pub seed: u64,
}

fn default_true() -> bool {
    true
}
fn default_stiffness() -> f64 {
    40.0
}
fn default_contact_hz() -> f64 {
    320.0
}
fn default_contact_noise() -> f64 {
    0.02
}

impl ContactSpec {
    /// Checks the values; the message says which and why.
    pub fn check(&self) -> Result<(), BoardError> {
        for (key, v) in [
            ("stiffness_n_per_unit", self.stiffness_n_per_unit),
            ("sample_hz", self.sample_hz),
            ("counts_per_newton", self.counts_per_newton),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(BoardError::new(format!(
                    "[module.io.contact] {key} {v} must be finite and positive"
                )));
            }
        }
        let finite = self.noise_n.is_finite()
            && self.noise_n >= 0.0
            && self.touch_at.is_finite()
            && self.offset_counts.is_finite();
        if !finite {
            return Err(BoardError::new(
                "[module.io.contact] touch_at and offset_counts must be finite, noise_n 0 or more",
            ));
        }
        for (key, pin) in [("data_pin", self.data_pin), ("clock_pin", self.clock_pin)] {
            if pin >= DIGITAL_PINS {
                return Err(BoardError::new(format!(
                    "[module.io.contact] {key} {pin} does not exist: a module has digital pins 0 \
                     to {}",
                    DIGITAL_PINS - 1
                )));
            }
        }
        if self.data_pin == self.clock_pin {
            return Err(BoardError::new(
                "[module.io.contact] data_pin and clock_pin must differ",
            ));
        }
        Ok(())
    }
}
