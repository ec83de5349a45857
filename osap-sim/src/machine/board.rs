//! Simulated module hardware: the [`Board`] osap-module's logic drives in a
//! simulated module, in place of a firmware's peripherals.
//!
//! - the **stepper driver** records its enable line and microstep mode;
//! - the **motor** takes every step the step words make (the module task
//!   clocks them out as the firmware's step generator does) and keeps each
//!   step edge with its time on the module's local clock; it moves a
//!   carriage whose position is the motor's steps over the mechanics'
//!   `full_steps_per_unit` and the driver's microstep mode, and a
//!   **limit switch** at a carriage position changes level as the carriage
//!   crosses it;
//! - the **I/O pins** (as on the RP2040 board: 4 digital pins, 2 PWM
//!   outputs, 3 analog inputs) record what the module writes and read what
//!   the topology or a test sets; an analog input may carry an
//!   **accelerometer** ([`accel`]) that sees the carriage through a
//!   mass-spring mode, and a PWM output with an analog input may carry a
//!   **heated block** ([`heater`]) that the output heats and a thermistor
//!   on the input reads;
//! - a **UF2 bootloader** ([`bootloader`]), if the topology gives the
//!   module one: `enter_bootloader` then takes the module off the network
//!   and shows a drive a UF2 file can be copied onto.

pub mod accel;
pub mod bootloader;
pub mod contact;
pub mod heater;
pub mod hx711;
pub mod melt;
pub mod rotor;
pub mod spindle;

use super::winch::WinchMotor;

use super::clock::DriftClock;
use crate::topology::{
    IoSpec, MotorSpec, ANALOG_INPUTS, DIGITAL_PINS, DRIVER_MICROSTEPS, PWM_OUTPUTS,
};
use accel::Accel;
use bootloader::BootHook;
use contact::Contact;
use heater::ThermalHeater;
use melt::Melt;
use osap_core::Instant;
use osap_module::board::{Board, IoHw, StepperHw};
use spindle::Spindle;

/// One step the motor took.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepEdge {
    /// The step tick's time on the module's local clock, µs.
    pub local: Instant,
    /// Upward (`true`) or downward.
    pub up: bool,
    /// Where the step left the carriage, units.
    pub position: f64,
}

/// The finest microstep the motor counts in: every step is a whole number
/// of these (`FINEST / microsteps`), so positions are exact however the
/// driver's mode changed.
const FINEST: i64 = 256;

/// The simulated stepper driver's pins, and, on a winch's motor, its coil
/// drive and shaft encoder.
#[derive(Debug, Clone)]
pub struct Driver {
    enabled: bool,
    microsteps: u16,
    /// The winch spool the motor turns, if it turns one: its encoder and
    /// coils reach the winch's physics.
    winch: Option<WinchMotor>,
}

impl Driver {
    /// Whether the driver is powered.
    pub fn enabled(&self) -> bool {
        self.enabled
    }

    /// The microstep mode its mode pins set.
    pub fn microsteps(&self) -> u16 {
        self.microsteps
    }
}

impl StepperHw for Driver {
    fn set_enable(&mut self, on: bool) {
        self.enabled = on;
        if let Some(w) = &self.winch {
            w.plant.now().set_enabled(w.index, on);
        }
    }

    fn read_shaft(&mut self) -> Option<i64> {
        let w = self.winch.as_ref()?;
        w.plant.now().read_shaft(w.index)
    }

    fn drive_coils(&mut self, coils: Option<maxl::phase::Coils>) -> bool {
        match &self.winch {
            Some(w) => {
                w.plant.now().drive_coils(w.index, coils);
                true
            }
            None => false,
        }
    }

    fn set_microsteps(&mut self, microsteps: u16) -> bool {
        let ok = DRIVER_MICROSTEPS.contains(&microsteps);
        if ok {
            self.microsteps = microsteps;
        }
        ok
    }
}

/// The motor, its carriage and its limit switch.
#[derive(Debug, Clone)]
pub struct Motor {
    spec: MotorSpec,
    /// Where the carriage is, in 1/[`FINEST`] full steps.
    fine: i64,
    /// Net steps taken, in the microstep mode of each step.
    steps: i64,
    edges: Vec<StepEdge>,
    /// Limit-switch edges not yet delivered to the module: (local time,
    /// new level).
    pending_limit: Vec<(Instant, bool)>,
    /// The switch input's level after the newest step.
    limit_level: bool,
    /// The rotor, when the spec simulates stalls.
    rotor: Option<rotor::Rotor>,
}

impl Motor {
    fn new(spec: MotorSpec) -> Self {
        let mut m = Motor {
            rotor: spec.rotor.map(rotor::Rotor::new),
            spec,
            fine: 0,
            steps: 0,
            edges: Vec::new(),
            pending_limit: Vec::new(),
            limit_level: true,
        };
        m.limit_level = m.level_at(0.0);
        m
    }

    /// The switch input's level with the carriage at `units`: pulled up
    /// (`true`) while released, pulled low while pressed.
    fn level_at(&self, units: f64) -> bool {
        let pressed = match (self.spec.limit_min, self.spec.limit_max) {
            (Some(min), _) => units <= min,
            (None, Some(max)) => units >= max,
            (None, None) => false,
        };
        !pressed
    }

    /// Takes one step at local time `local` with the driver in `microsteps`.
    fn step(&mut self, local: Instant, up: bool, microsteps: u16) {
        let size = FINEST / i64::from(microsteps.max(1));
        self.steps += if up { 1 } else { -1 };
        let signed = if up { size } else { -size };
        let follows = match &mut self.rotor {
            Some(r) => r.step(local, signed as f64 / FINEST as f64),
            None => true,
        };
        if !follows {
            // Stalled: the module counted the step, the carriage did not
            // move.
            return;
        }
        self.fine += signed;
        let position = self.position();
        if self.spec.record {
            self.edges.push(StepEdge {
                local,
                up,
                position,
            });
        }
        let level = self.level_at(position);
        if level != self.limit_level {
            self.limit_level = level;
            self.pending_limit.push((local, level));
        }
    }

    /// What the motor drives.
    pub fn spec(&self) -> &MotorSpec {
        &self.spec
    }

    /// Where the carriage is, units (after the newest step clocked out,
    /// which may be up to a step-generator lead ahead of now).
    pub fn position(&self) -> f64 {
        self.fine as f64 / (self.spec.full_steps_per_unit * FINEST as f64)
    }

    /// Where the carriage is, in the motor's finest unit (kept across a
    /// module's power cycle: the carriage does not move when it reboots).
    pub(crate) fn carriage(&self) -> i64 {
        self.fine
    }

    /// Puts the carriage at `fine` (see [`carriage`](Self::carriage)) with no
    /// steps counted, as a freshly booted module finds it.
    pub(crate) fn place(&mut self, fine: i64) {
        self.fine = fine;
        self.limit_level = self.level_at(self.position());
    }

    /// Net microsteps taken.
    pub fn steps(&self) -> i64 {
        self.steps
    }

    /// The rotor, when the motor simulates stalls (its stalls, its lag).
    pub fn rotor(&self) -> Option<&rotor::Rotor> {
        self.rotor.as_ref()
    }

    /// Every step edge kept so far (see [`MotorSpec::record`]).
    pub fn edges(&self) -> &[StepEdge] {
        &self.edges
    }

    /// Takes the step edges kept so far, leaving none.
    pub fn take_edges(&mut self) -> Vec<StepEdge> {
        std::mem::take(&mut self.edges)
    }

    /// The motor's own switch's level after the newest step (`true`:
    /// released; always `true` without `limit_min`/`limit_max`, also when
    /// a [`SwitchSpec`](crate::topology::SwitchSpec) drives the module's input).
    pub fn limit_level(&self) -> bool {
        self.limit_level
    }

    /// The earliest limit edge not yet handed to the module, local µs.
    pub(crate) fn next_limit_edge(&self) -> Option<Instant> {
        self.pending_limit.first().map(|e| e.0)
    }

    /// Takes the limit edges due by local time `now`, oldest first.
    pub(crate) fn take_limit_edges(&mut self, now: Instant) -> Vec<(Instant, bool)> {
        let due = self.pending_limit.partition_point(|e| e.0 <= now);
        self.pending_limit.drain(..due).collect()
    }
}

/// A PWM output's settings over time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PwmWrite {
    /// When, local µs.
    pub local: Instant,
    /// Which output.
    pub channel: u8,
    /// Duty, of 65 535.
    pub duty: u16,
}

/// A digital pin driven by the module.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DigitalWrite {
    /// When, local µs.
    pub local: Instant,
    /// Which pin.
    pub pin: u8,
    /// The level driven.
    pub level: bool,
}

/// The I/O pins.
#[derive(Debug, Clone)]
pub struct Pins {
    clock: DriftClock,
    digital: [bool; DIGITAL_PINS as usize],
    analog: [f64; ANALOG_INPUTS as usize],
    pwm: [u16; PWM_OUTPUTS as usize],
    writes: Vec<DigitalWrite>,
    pwm_writes: Vec<PwmWrite>,
    accel: Option<Accel>,
    heaters: Vec<ThermalHeater>,
    melt: Option<Melt>,
    contact: Option<Contact>,
    spindle: Option<Spindle>,
}

impl Pins {
    fn new(spec: &IoSpec, clock: DriftClock) -> Self {
        let mut digital = [false; DIGITAL_PINS as usize];
        for (d, s) in digital.iter_mut().zip(&spec.digital) {
            *d = *s;
        }
        let mut analog = [0.0; ANALOG_INPUTS as usize];
        for (a, s) in analog.iter_mut().zip(&spec.analog) {
            *a = *s;
        }
        Pins {
            clock,
            digital,
            analog,
            pwm: [0; PWM_OUTPUTS as usize],
            writes: Vec::new(),
            pwm_writes: Vec::new(),
            accel: spec.accel.clone().map(Accel::new),
            heaters: spec
                .heaters
                .iter()
                .cloned()
                .map(ThermalHeater::new)
                .collect(),
            // Placed where the carriage starts by the board.
            contact: None,
            spindle: spec.spindle.clone().map(Spindle::new),
            melt: spec.melt.clone().map(|m| {
                let ambient = spec
                    .heaters
                    .iter()
                    .find(|h| h.pwm == m.heater_pwm)
                    .map_or(25.0, |h| h.ambient_c);
                Melt::new(m, ambient)
            }),
        }
    }

    /// The bed contact under the axis, if the board has one.
    pub fn contact(&self) -> Option<&Contact> {
        self.contact.as_ref()
    }

    /// The spindle on the pins, if the board has one.
    pub fn spindle(&self) -> Option<&Spindle> {
        self.spindle.as_ref()
    }

    /// Puts a load of `nm` N·m on the spindle from now on (a cut, or a
    /// tool caught in the work); `false` if the board has no spindle.
    pub fn load_spindle(&mut self, nm: f64) -> bool {
        let secs = self.secs_since_boot();
        match &mut self.spindle {
            Some(s) => {
                s.set_load(secs, nm);
                true
            }
            None => false,
        }
    }

    /// The spindle's speed now, rpm; `None` without one.
    pub fn spindle_rpm(&mut self) -> Option<f64> {
        let secs = self.secs_since_boot();
        self.spindle.as_mut().map(|s| s.rpm(secs))
    }

    /// The melt behind the extruder, if the board has one.
    pub fn melt(&self) -> Option<&Melt> {
        self.melt.as_ref()
    }

    /// Gives the melt its block's temperature now.
    fn warm_melt(&mut self) {
        let secs = self.secs_since_boot();
        if let Some(m) = &mut self.melt {
            let pwm = m.spec().heater_pwm;
            if let Some(h) = self.heaters.iter().find(|h| h.spec().pwm == pwm) {
                m.set_temperature(h.temperature(secs));
            }
        }
    }

    /// The heated blocks.
    pub fn heaters(&self) -> &[ThermalHeater] {
        &self.heaters
    }

    /// Seconds since the module booted, the heated blocks' time.
    pub fn secs_since_boot(&self) -> f64 {
        osap_host::clock::now()
            .saturating_duration_since(self.clock.boot())
            .as_secs_f64()
    }

    /// The accelerometer, if an analog input carries one.
    pub fn accel(&self) -> Option<&Accel> {
        self.accel.as_ref()
    }

    /// Sets what digital pin `pin` reads (an outside signal); `false` if
    /// there is no such pin.
    pub fn set_digital(&mut self, pin: u8, level: bool) -> bool {
        match self.digital.get_mut(usize::from(pin)) {
            Some(d) => {
                *d = level;
                true
            }
            None => false,
        }
    }

    /// Sets what analog input `channel` reads, a fraction of full scale
    /// (clamped to `0..=1`); `false` if there is no such input.
    pub fn set_analog(&mut self, channel: u8, value: f64) -> bool {
        match self.analog.get_mut(usize::from(channel)) {
            Some(a) => {
                *a = if value.is_nan() {
                    0.0
                } else {
                    value.clamp(0.0, 1.0)
                };
                true
            }
            None => false,
        }
    }

    /// Digital pin levels now.
    pub fn digital(&self) -> [bool; DIGITAL_PINS as usize] {
        self.digital
    }

    /// PWM duties now, of 65 535.
    pub fn pwm(&self) -> [u16; PWM_OUTPUTS as usize] {
        self.pwm
    }

    /// Every level the module drove, in order.
    pub fn writes(&self) -> &[DigitalWrite] {
        &self.writes
    }

    /// Every PWM duty the module set, in order.
    pub fn pwm_writes(&self) -> &[PwmWrite] {
        &self.pwm_writes
    }
}

impl IoHw for Pins {
    fn digital_pins(&self) -> u8 {
        DIGITAL_PINS
    }
    fn write_digital(&mut self, pin: u8, level: bool) {
        if let Some(c) = self.contact.as_mut().filter(|c| c.spec().clock_pin == pin) {
            c.write_clock(self.clock.now(), level);
            self.digital[usize::from(pin)] = level;
            return;
        }
        // The load cell's clock: the converter sees the edge (and the
        // pin's thousands of edges a second are not kept in `writes`).
        if self
            .melt
            .as_ref()
            .is_some_and(|m| m.spec().clock_pin == pin)
        {
            self.warm_melt();
            let now = self.clock.now();
            if let Some(m) = &mut self.melt {
                m.write_clock(now, level);
            }
            self.digital[usize::from(pin)] = level;
            return;
        }
        if let Some(d) = self.digital.get_mut(usize::from(pin)) {
            *d = level;
            self.writes.push(DigitalWrite {
                local: self.clock.now(),
                pin,
                level,
            });
        }
    }
    fn read_digital(&mut self, pin: u8) -> bool {
        let now = self.clock.now();
        if let Some(m) = self.melt.as_mut().filter(|m| m.spec().data_pin == pin) {
            return m.read_data(now);
        }
        if let Some(c) = self.contact.as_ref().filter(|c| c.spec().data_pin == pin) {
            return c.read_data(now);
        }
        self.digital.get(usize::from(pin)).copied().unwrap_or(false)
    }
    fn pwm_outputs(&self) -> u8 {
        PWM_OUTPUTS
    }
    fn write_pwm(&mut self, channel: u8, duty: u16) {
        let secs = self.secs_since_boot();
        if let Some(p) = self.pwm.get_mut(usize::from(channel)) {
            *p = duty;
            for h in self.heaters.iter_mut().filter(|h| h.spec().pwm == channel) {
                h.set_duty(secs, duty);
            }
            if let Some(s) = self.spindle.as_mut().filter(|s| s.spec().pwm == channel) {
                s.set_duty(secs, duty);
            }
            self.pwm_writes.push(PwmWrite {
                local: self.clock.now(),
                channel,
                duty,
            });
        }
    }
    fn read_pwm(&self, channel: u8) -> u16 {
        self.pwm.get(usize::from(channel)).copied().unwrap_or(0)
    }
    fn edge_count(&mut self, pin: u8) -> Option<(u32, Instant)> {
        // Only the spindle's tachometer pin has a counter on it.
        let secs = self.secs_since_boot();
        let now = self.clock.now();
        let s = self.spindle.as_mut().filter(|s| s.spec().tach_pin == pin)?;
        let (count, edge) = s.edges(secs);
        let back = ((secs - edge).max(0.0) * 1e6).round() as u64;
        let local = if count == 0 {
            Instant::ZERO
        } else {
            Instant::from_micros(now.as_micros().saturating_sub(back))
        };
        Some((count, local))
    }
    fn analog_inputs(&self) -> u8 {
        ANALOG_INPUTS
    }
    fn read_analog(&mut self, channel: u8) -> u16 {
        // A 12-bit converter's reading, shifted left by 4, as on the boards.
        let now = self.clock.now();
        let secs = self.secs_since_boot();
        let heater = self.heaters.iter_mut().find(|h| h.spec().analog == channel);
        let v = match (&mut self.accel, heater) {
            (_, Some(h)) => h.read(secs),
            (Some(a), None) if a.spec().channel == channel => a.read(now),
            _ => self
                .analog
                .get(usize::from(channel))
                .copied()
                .unwrap_or(0.0),
        };
        ((v * 4095.0).round() as u16) << 4
    }
}

/// What a module's outputs drive now, read back through its board's
/// [`IoHw`] (`read_pwm`, `read_digital`): how a test, or `osap serve
/// --control`'s `outputs`, sees that a tool went off.
#[derive(Debug, Clone, PartialEq)]
pub struct Outputs {
    /// Each PWM output's duty, a fraction of full scale.
    pub pwm: Vec<f64>,
    /// Each digital pin's level.
    pub digital: Vec<bool>,
}

impl Outputs {
    /// Reads every output of `io`.
    pub fn read(io: &mut dyn IoHw) -> Outputs {
        Outputs {
            pwm: (0..io.pwm_outputs())
                .map(|c| f64::from(io.read_pwm(c)) / 65_535.0)
                .collect(),
            digital: (0..io.digital_pins()).map(|p| io.read_digital(p)).collect(),
        }
    }
}

impl std::fmt::Display for Outputs {
    /// `pwm0=0.050 pwm1=0.000 d0=0 d1=1 d2=0 d3=0`: duties to a thousandth
    /// (a 16-bit duty rounded), levels as 0 or 1.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let pwm = self
            .pwm
            .iter()
            .enumerate()
            .map(|(i, d)| format!("pwm{i}={d:.3}"));
        let digital = self
            .digital
            .iter()
            .enumerate()
            .map(|(i, l)| format!("d{i}={}", u8::from(*l)));
        let all: Vec<String> = pwm.chain(digital).collect();
        f.write_str(&all.join(" "))
    }
}

/// A simulated module's board: driver, motor, pins, the module's
/// drifting local clock, and a UF2 bootloader if it has one.
#[derive(Debug, Clone)]
pub struct SimBoard {
    clock: DriftClock,
    driver: Driver,
    motor: Motor,
    pins: Pins,
    /// What rebooting into the bootloader does (`None`: no bootloader).
    boot: Option<BootHook>,
}

impl SimBoard {
    /// A board at rest: driver off, full steps, carriage at 0.
    pub fn new(clock: DriftClock, motor: MotorSpec, io: &IoSpec) -> Self {
        let motor = Motor::new(motor);
        let mut pins = Pins::new(io, clock);
        pins.contact = io
            .contact
            .clone()
            .map(|c| Contact::new(c, motor.position()));
        SimBoard {
            clock,
            driver: Driver {
                enabled: false,
                microsteps: 1,
                winch: None,
            },
            motor,
            pins,
            boot: None,
        }
    }

    /// Puts the board's motor on a winch's spool: its driver gets a shaft
    /// encoder and a coil drive, and its steps turn the spool.
    pub(crate) fn set_winch(&mut self, winch: WinchMotor) {
        self.driver.winch = Some(winch);
    }

    /// Gives the board a bootloader: rebooting into it calls `hook`.
    pub(crate) fn set_bootloader(&mut self, hook: BootHook) {
        self.boot = Some(hook);
    }

    /// The stepper driver.
    pub fn driver(&self) -> &Driver {
        &self.driver
    }

    /// The motor.
    pub fn motor(&self) -> &Motor {
        &self.motor
    }

    /// The motor, to take its step edges.
    pub fn motor_mut(&mut self) -> &mut Motor {
        &mut self.motor
    }

    /// The I/O pins.
    pub fn pins(&self) -> &Pins {
        &self.pins
    }

    /// The I/O pins, to set what they read.
    pub fn pins_mut(&mut self) -> &mut Pins {
        &mut self.pins
    }

    /// The module's local clock.
    pub fn clock(&self) -> DriftClock {
        self.clock
    }

    /// Takes one step of a step word, at local `local`.
    pub(crate) fn step(&mut self, local: Instant, up: bool) {
        let microsteps = self.driver.microsteps;
        if let Some(w) = &self.driver.winch {
            let full = 1.0 / f64::from(microsteps.max(1));
            w.plant
                .now()
                .step_motor(w.index, if up { full } else { -full });
        }
        let before = self.motor.position();
        self.motor.step(local, up, microsteps);
        let moved = self.motor.position() - before;
        if let Some(a) = &mut self.pins.accel {
            a.step(local, moved);
        }
        if let Some(c) = &mut self.pins.contact {
            c.step(local, self.motor.position());
        }
        if self.pins.melt.is_some() {
            self.pins.warm_melt();
            let now = self.clock.now();
            if let Some(m) = &mut self.pins.melt {
                m.step(local, moved, now);
            }
        }
    }
}

impl Board for SimBoard {
    fn stepper(&mut self) -> &mut dyn StepperHw {
        &mut self.driver
    }
    fn io(&mut self) -> Option<&mut dyn IoHw> {
        Some(&mut self.pins)
    }
    fn now(&self) -> Instant {
        self.clock.now()
    }
    fn has_bootloader(&self) -> bool {
        self.boot.is_some()
    }
    fn reboot_to_bootloader(&mut self) {
        if let Some(hook) = &self.boot {
            hook.call();
        }
    }
}
