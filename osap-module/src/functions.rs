//! The module's PIPES functions: what a network scan finds on every
//! osap-rs module firmware, whatever the board.
//!
//! Each is a method of [`Module`] (callable from Rust as is) and a PIPES
//! function: a [`ModuleFn`] binds one of them to one module through a
//! [`ModuleHandle`], so a runtime can hold them in one array. Failure codes
//! are [`StepperError`], [`IoError`], [`BootError`] and [`HeaterError`]
//! codes, plus [`NOT_INSTALLED`]. Each explains itself: its documentation
//! (below, on each [`FnId`] variant and `Module` method) is written once,
//! in [`module_function_table!`](crate::module_function_table), and sent
//! with its signature when a host asks ([`DOCS`], `pipes_core::docs`;
//! `osap describe`).
//!
//! | function | inputs | outputs |
//! |---|---|---|
//! | `add_point` | `time: u64`, `position: f32` | — |
//! | `set_interval` | `interval_us: u32` | — |
//! | `get_position` | — | `time: u64`, `position: f32` |
//! | `get_status` | — | `mode: u8`, `queued: u16`, `enabled: bool`, `faults: u32` |
//! | `get_counters` | — | `points: u32`, `refused: u32`, `last_refused: u8`, `filled: u32` |
//! | `get_steps` | — | `steps: i64`, `up: u64`, `down: u64`, `late: u64` |
//! | `set_enable` | `on: bool` | — |
//! | `set_scale` | `full_steps_per_unit: f32` | — |
//! | `set_microsteps` | `microsteps: u16` | — |
//! | `set_limits` | `max_vel: f32`, `max_acc: f32`, `max_jerk: f32` | — |
//! | `read_limit` | — | `time: u64`, `level: bool`, `edges: u32` |
//! | `halt` | — | — |
//! | `digital_write` | `pin: u8`, `level: bool` | — |
//! | `digital_read` | `pin: u8` | `time: u64`, `level: bool` |
//! | `pwm_write` | `channel: u8`, `duty: f32` | — |
//! | `pulse` | `pin: u8`, `duration_us: u32` | — |
//! | `pulse_at` | `time: u64`, `pin: u8`, `duration_us: u32` | — |
//! | `analog_read` | `channel: u8` | `time: u64`, `value: f32` |
//! | `get_fault` | — | `time: u64`, `code: u8`, `detail: u32`, `count: u32` |
//! | `enter_bootloader` | — | — |
//! | `set_safe_pwm` | `channel: u8`, `duty: f32` | — |
//! | `set_safe_digital` | `pin: u8`, `level: bool` | — |
//! | `set_output_watchdog` | `timeout_ms: u32` | — |
//! | `heater_sensor` | `index: u8`, `analog: u8`, `a: f32`, `b: f32`, `c: f32`, `pullup_ohms: f32` | — |
//! | `heater_output` | `index: u8`, `pwm: u8`, `max_power: f32` | — |
//! | `heater_limits` | `index: u8`, `min_temp: f32`, `max_temp: f32` | — |
//! | `heater_gains` | `index: u8`, `kp: f32`, `ki: f32`, `kd: f32` | — |
//! | `heater_runaway` | `index: u8`, `hysteresis_c: f32`, `max_error: f32`, `heating_gain_c: f32`, `check_gain_time_s: f32` | — |
//! | `heater_target` | `index: u8`, `celsius: f32` | — |
//! | `heater_power` | `index: u8`, `duty: f32` | — |
//! | `heater_read` | `index: u8` | `time: u64`, `temp: f32`, `target: f32`, `power: f32`, `state: u8` |
//! | `heater_clear` | `index: u8` | — |
//! | `loadcell_setup` | `data_pin: u8`, `clock_pin: u8` | — |
//! | `loadcell_tare` | `samples: u16` | — |
//! | `loadcell_scale` | `newtons_per_count: f32` | — |
//! | `loadcell_read` | — | `time: u64`, `force: f32`, `raw: i32`, `samples: u32`, `taring: bool` |
//! | `tach_setup` | `pin: u8`, `pulses_per_rev: u16` | — |
//! | `tach_read` | — | `time: u64`, `rpm: f32` |
//! | `set_torque` | `fraction: f32` | — |
//! | `torque_off` | — | — |
//! | `level_point` | `time: u64`, `channel: u8`, `before: f32`, `after: f32` | — |
//! | `event_point` | `time: u64`, `pin: u8`, `level: bool` | — |
//! | `level_read` | — | `time: u64`, `pwm0: f32`, `pwm1: f32`, `pins: u32` |
//! | `sample_block` | `source0: u8`, `arg0: u8`, `source1: u8`, `arg1: u8`, `source2: u8`, `arg2: u8`, `latency_us: u32`, `session: u32` | `seq: u32`, `first: u32`, `time: u64`, `samples: arry_u8`, `session: u32` |
//!
//! Times are synchronized system µs. `read_limit` is meant as a pipe source
//! with its output mode set to "on change": it then sends each switch edge
//! with the edge's own time stamp, taken in the pin interrupt. So is
//! `get_fault`: it then sends each new fault once (kinds and details in
//! [`crate::fault`]). `enter_bootloader` answers first and reboots the
//! board into its UF2 bootloader 100 ms later, for a firmware update
//! (`osap flash`; see [`crate::boot`]).
//!
//! Every output has a safe value (`set_safe_pwm`, `set_safe_digital`; 0
//! duty and low until set) that it takes on every stop: `halt`, a backstop,
//! and the output watchdog, which `set_output_watchdog` arms (off at boot):
//! when no call or pipe datagram has reached any of the module's functions
//! for its timeout, the module applies the safe values by itself and
//! `get_fault` reports it (see [`crate::io`] and [`crate::watchdog`]).
//!
//! `set_limits` turns on the firmware's check of incoming points: with
//! limits set, `add_point` refuses a point past the velocity, acceleration
//! or jerk limit (`OverLimit`) and `get_fault` reports it, saying which
//! limit (see [`crate::stepper`] and [`crate::fault`]). Limits are off
//! until set.
//!
//! The `loadcell_` functions read a load cell through an HX711-kind
//! converter on two digital pins (see [`crate::loadcell`]):
//! `loadcell_read` as an "on change" pipe source streams every sample.
//!
//! The `tach_` functions measure a speed from the pulses on a digital pin
//! (a spindle's hall sensor or encoder; see [`crate::tach`]): the board
//! counts the edges, the module turns them into turns a minute over whole
//! pulse periods, and `tach_read` as an "on change" pipe source streams
//! every new measurement. A spindle's speed is then measured where it
//! is, the same on firmware and in simulation.
//! `set_torque` makes the motor a torque device, commuted from its shaft
//! encoder on the module (see [`crate::torque`]); `get_position` then
//! reports the shaft's real position, and every stop, `set_enable`,
//! `torque_off` and the output watchdog end the torque with the motor
//! holding where it stands.
//!
//! `level_point` and `event_point` queue tool outputs at synchronized
//! times, on the motion's time base: a PWM duty ramped linearly between
//! points (and stepped at a point where its two duties differ), and a pin
//! going high or low. The module
//! applies them on its own loop; every stop clears them before the safe
//! values go out, and a direct `pwm_write` or `digital_write` drops the
//! points queued for its output. `level_read`, as a pipe source on a
//! timer, reports what the outputs actually drive, time-stamped (see
//! [`crate::levels`]).
//!
//! `sample_block` batches samples of up to three read functions into
//! stamped, numbered blocks, one datagram each, for captures at 1 kHz and
//! beyond (see [`crate::sampler`]).
//!
//! The `heater_` functions configure and run up to two heaters, whose PID
//! control and runaway protection run on the module (see
//! [`crate::heater`]): a heater that runs away or loses its sensor cuts
//! itself off, `get_fault` reports why, and it stays off until
//! `heater_clear`. Every stop and the output watchdog turn heaters off.

use crate::board::Board;
use crate::boot::BootError;
use crate::heater::{Gains, HeaterError, Runaway, Thermistor};
use crate::io::IoError;
use crate::loadcell::LoadCellError;
use crate::stepper::StepperError;
use crate::{Module, ModuleHandle};
use osap_core::SystemInstant;
use pipes_core::export::{FromPipes, PipesOutputs, PipesType};
use pipes_core::function::{CallError, Implementation, Outputs};
use pipes_core::signature::{Arg, Signature};
use pipes_core::Value;

/// Failure code of every function on a firmware that never installed its
/// board (see [`crate::ModuleCell::install`]).
pub const NOT_INSTALLED: u8 = 100;

// One text per function: each function's documentation is written once,
// as the `///` lines of its entry in [`module_function_table!`]. From
// there it is the text the function publishes with its signature
// ([`DOCS`], `Implementation::docs`), the docs of its [`FnId`] variant,
// and (through `fn_docs!`, defined here so that it is in scope for the
// methods below) the docs of the `Module` method of the same name: the
// methods carry `#[doc = fn_docs!(name)]`, never a copy of the prose.
macro_rules! method_docs {
    ($(
        $(#[doc = $doc:tt])*
        $f:ident ( $($in:ident : $inty:ty),* ) $(-> ( $($out:ident : $outty:ty),* ))? ;
    )*) => {
        /// Each function's documentation, by its name.
        macro_rules! fn_docs {
            $(($f) => { pipes_core::doc_text!($(#[doc = $doc])*) };)*
        }
    };
}
crate::module_function_table!(method_docs);

impl<B: Board> Module<B> {
    #[doc = fn_docs!(add_point)]
    pub fn add_point(&mut self, time: u64, position: f32) -> Result<(), CallError> {
        Ok(self.queue_point(SystemInstant::from_micros(time), position)?)
    }

    #[doc = fn_docs!(set_interval)]
    pub fn set_interval(&mut self, interval_us: u32) -> Result<(), CallError> {
        Ok(self.stepper.set_interval(interval_us)?)
    }

    #[doc = fn_docs!(get_position)]
    pub fn get_position(&mut self) -> Result<(u64, f32), CallError> {
        let (time, position) = self.stepper.position();
        Ok((time.as_micros(), position))
    }

    #[doc = fn_docs!(get_status)]
    pub fn get_status(&mut self) -> Result<(u8, u16, bool, u32), CallError> {
        let s = &self.stepper;
        Ok((s.mode() as u8, s.queued(), s.enabled(), s.counters().faults))
    }

    #[doc = fn_docs!(get_counters)]
    pub fn get_counters(&mut self) -> Result<(u32, u32, u8, u32), CallError> {
        let c = self.stepper.counters();
        Ok((
            c.points,
            c.refused,
            c.last_refused.map_or(0, StepperError::code),
            c.filled,
        ))
    }

    #[doc = fn_docs!(get_steps)]
    pub fn get_steps(&mut self) -> Result<(i64, u64, u64, u64), CallError> {
        Ok(self.stepper.step_counts())
    }

    #[doc = fn_docs!(set_enable)]
    pub fn set_enable(&mut self, on: bool) -> Result<(), CallError> {
        self.end_torque();
        self.stepper.set_enable(on);
        self.board.stepper().set_enable(on);
        Ok(())
    }

    #[doc = fn_docs!(set_scale)]
    pub fn set_scale(&mut self, full_steps_per_unit: f32) -> Result<(), CallError> {
        Ok(self.stepper.set_scale(full_steps_per_unit)?)
    }

    #[doc = fn_docs!(set_microsteps)]
    pub fn set_microsteps(&mut self, microsteps: u16) -> Result<(), CallError> {
        self.stepper.check_idle()?;
        if !self.board.stepper().set_microsteps(microsteps) {
            return Err(StepperError::BadValue.into());
        }
        Ok(self.stepper.set_microsteps(microsteps)?)
    }

    #[doc = fn_docs!(set_limits)]
    pub fn set_limits(
        &mut self,
        max_vel: f32,
        max_acc: f32,
        max_jerk: f32,
    ) -> Result<(), CallError> {
        Ok(self.stepper.set_limits(crate::stepper::Limits {
            max_vel,
            max_acc,
            max_jerk,
        })?)
    }

    #[doc = fn_docs!(read_limit)]
    pub fn read_limit(&mut self) -> Result<(u64, bool, u32), CallError> {
        Ok((
            self.limit.time.as_micros(),
            self.limit.level,
            self.limit.edges,
        ))
    }

    #[doc = fn_docs!(halt)]
    pub fn halt(&mut self) -> Result<(), CallError> {
        self.halt_axis();
        Ok(())
    }

    #[doc = fn_docs!(get_fault)]
    pub fn get_fault(&mut self) -> Result<(u64, u8, u32, u32), CallError> {
        Ok(self.fault.outputs())
    }

    #[doc = fn_docs!(digital_write)]
    pub fn digital_write(&mut self, pin: u8, level: bool) -> Result<(), CallError> {
        let hw = self.board.io().ok_or(IoError::NoHardware)?;
        self.io.digital_write(hw, pin, level)?;
        self.tracks.clear_pin(pin);
        Ok(())
    }

    #[doc = fn_docs!(digital_read)]
    pub fn digital_read(&mut self, pin: u8) -> Result<(u64, bool), CallError> {
        let now = self.system_now();
        let hw = self.board.io().ok_or(IoError::NoHardware)?;
        Ok((now.as_micros(), self.io.digital_read(hw, pin)?))
    }

    #[doc = fn_docs!(pwm_write)]
    pub fn pwm_write(&mut self, channel: u8, duty: f32) -> Result<(), CallError> {
        let hw = self.board.io().ok_or(IoError::NoHardware)?;
        if self.heaters.drives(channel) {
            return Err(IoError::HeaterOutput.into());
        }
        self.io.pwm_write(hw, channel, duty)?;
        self.tracks.clear_channel(channel);
        Ok(())
    }

    #[doc = fn_docs!(pulse)]
    pub fn pulse(&mut self, pin: u8, duration_us: u32) -> Result<(), CallError> {
        let now = self.board.now();
        let hw = self.board.io().ok_or(IoError::NoHardware)?;
        Ok(self.io.pulse(hw, now, pin, duration_us)?)
    }

    #[doc = fn_docs!(pulse_at)]
    pub fn pulse_at(&mut self, time: u64, pin: u8, duration_us: u32) -> Result<(), CallError> {
        let now = self.system_now();
        let hw = self.board.io().ok_or(IoError::NoHardware)?;
        let start = SystemInstant::from_micros(time);
        Ok(self.io.pulse_at(hw, now, start, pin, duration_us)?)
    }

    #[doc = fn_docs!(analog_read)]
    pub fn analog_read(&mut self, channel: u8) -> Result<(u64, f32), CallError> {
        let now = self.system_now();
        let hw = self.board.io().ok_or(IoError::NoHardware)?;
        Ok((now.as_micros(), self.io.analog_read(hw, channel)?))
    }

    #[doc = fn_docs!(enter_bootloader)]
    pub fn enter_bootloader(&mut self) -> Result<(), CallError> {
        if !self.board.has_bootloader() {
            return Err(BootError::Unsupported.into());
        }
        if !self.stepper.is_standing() || self.stepper.is_torque() {
            return Err(BootError::Moving.into());
        }
        let now = self.board.now();
        self.boot.arm(now);
        Ok(())
    }

    #[doc = fn_docs!(set_safe_pwm)]
    pub fn set_safe_pwm(&mut self, channel: u8, duty: f32) -> Result<(), CallError> {
        let hw = self.board.io().ok_or(IoError::NoHardware)?;
        if self.heaters.drives(channel) {
            return Err(IoError::HeaterOutput.into());
        }
        Ok(self.io.set_safe_pwm(hw, channel, duty)?)
    }

    #[doc = fn_docs!(set_safe_digital)]
    pub fn set_safe_digital(&mut self, pin: u8, level: bool) -> Result<(), CallError> {
        let hw = self.board.io().ok_or(IoError::NoHardware)?;
        Ok(self.io.set_safe_digital(hw, pin, level)?)
    }

    #[doc = fn_docs!(set_output_watchdog)]
    pub fn set_output_watchdog(&mut self, timeout_ms: u32) -> Result<(), CallError> {
        let now = self.board.now();
        self.watchdog.set(timeout_ms, now);
        Ok(())
    }

    #[doc = fn_docs!(heater_sensor)]
    pub fn heater_sensor(
        &mut self,
        index: u8,
        analog: u8,
        a: f32,
        b: f32,
        c: f32,
        pullup_ohms: f32,
    ) -> Result<(), CallError> {
        let hw = self.board.io().ok_or(HeaterError::NoHardware)?;
        let thermistor = Thermistor {
            a,
            b,
            c,
            pullup_ohms,
        };
        Ok(self.heaters.set_sensor(hw, index, analog, thermistor)?)
    }

    #[doc = fn_docs!(heater_output)]
    pub fn heater_output(&mut self, index: u8, pwm: u8, max_power: f32) -> Result<(), CallError> {
        let hw = self.board.io().ok_or(HeaterError::NoHardware)?;
        Ok(self.heaters.set_output(hw, index, pwm, max_power)?)
    }

    #[doc = fn_docs!(heater_limits)]
    pub fn heater_limits(
        &mut self,
        index: u8,
        min_temp: f32,
        max_temp: f32,
    ) -> Result<(), CallError> {
        Ok(self.heaters.set_limits(index, min_temp, max_temp)?)
    }

    #[doc = fn_docs!(heater_gains)]
    pub fn heater_gains(&mut self, index: u8, kp: f32, ki: f32, kd: f32) -> Result<(), CallError> {
        Ok(self.heaters.set_gains(index, Gains { kp, ki, kd })?)
    }

    #[doc = fn_docs!(heater_runaway)]
    pub fn heater_runaway(
        &mut self,
        index: u8,
        hysteresis_c: f32,
        max_error: f32,
        heating_gain_c: f32,
        check_gain_time_s: f32,
    ) -> Result<(), CallError> {
        let runaway = Runaway {
            hysteresis_c,
            max_error,
            heating_gain_c,
            check_gain_time_s,
        };
        Ok(self.heaters.set_runaway(index, runaway)?)
    }

    #[doc = fn_docs!(heater_target)]
    pub fn heater_target(&mut self, index: u8, celsius: f32) -> Result<(), CallError> {
        let hw = self.board.io().ok_or(HeaterError::NoHardware)?;
        Ok(self.heaters.set_target(hw, index, celsius)?)
    }

    #[doc = fn_docs!(heater_power)]
    pub fn heater_power(&mut self, index: u8, duty: f32) -> Result<(), CallError> {
        Ok(self.heaters.set_power(index, duty)?)
    }

    #[doc = fn_docs!(heater_read)]
    pub fn heater_read(&mut self, index: u8) -> Result<(u64, f32, f32, f32, u8), CallError> {
        let h = self
            .heaters
            .heater(index)
            .ok_or(HeaterError::NoSuchHeater)?;
        let (time, temp) = match h.reading() {
            Some((local, temp)) => (self.time.system_time(local).as_micros(), temp),
            None => (0, 0.0),
        };
        Ok((time, temp, h.target(), h.duty(), h.state() as u8))
    }

    #[doc = fn_docs!(heater_clear)]
    pub fn heater_clear(&mut self, index: u8) -> Result<(), CallError> {
        let hw = self.board.io().ok_or(HeaterError::NoHardware)?;
        Ok(self.heaters.clear(hw, index)?)
    }
}

impl<B: Board> Module<B> {
    #[doc = fn_docs!(loadcell_setup)]
    pub fn loadcell_setup(&mut self, data_pin: u8, clock_pin: u8) -> Result<(), CallError> {
        let now = self.board.now();
        let hw = self.board.io().ok_or(LoadCellError::NoHardware)?;
        Ok(self.loadcell.setup(hw, data_pin, clock_pin, now)?)
    }

    #[doc = fn_docs!(loadcell_tare)]
    pub fn loadcell_tare(&mut self, samples: u16) -> Result<(), CallError> {
        Ok(self.loadcell.tare(samples)?)
    }

    #[doc = fn_docs!(loadcell_scale)]
    pub fn loadcell_scale(&mut self, newtons_per_count: f32) -> Result<(), CallError> {
        Ok(self.loadcell.set_scale(newtons_per_count)?)
    }

    #[doc = fn_docs!(loadcell_read)]
    pub fn loadcell_read(&mut self) -> Result<(u64, f32, i32, u32, bool), CallError> {
        self.loadcell.check(self.board.now())?;
        let (time, force, raw) = match self.loadcell.newest() {
            Some(r) => (self.time.system_time(r.at).as_micros(), r.force, r.raw),
            None => (0, 0.0, 0),
        };
        Ok((
            time,
            force,
            raw,
            self.loadcell.samples(),
            self.loadcell.taring(),
        ))
    }
}

impl<B: Board> Module<B> {
    #[doc = fn_docs!(tach_setup)]
    pub fn tach_setup(&mut self, pin: u8, pulses_per_rev: u16) -> Result<(), CallError> {
        let now = self.board.now();
        let hw = self.board.io().ok_or(IoError::NoHardware)?;
        Ok(self.tach.setup(hw, pin, pulses_per_rev, now)?)
    }

    #[doc = fn_docs!(tach_read)]
    pub fn tach_read(&mut self) -> Result<(u64, f32), CallError> {
        let s = self.tach.speed()?;
        Ok((self.time.system_time(s.at).as_micros(), s.rpm))
    }

    #[doc = fn_docs!(set_torque)]
    pub fn set_torque(&mut self, fraction: f32) -> Result<(), CallError> {
        Ok(self.torque_request(fraction)?)
    }

    #[doc = fn_docs!(torque_off)]
    pub fn torque_off(&mut self) -> Result<(), CallError> {
        self.end_torque();
        Ok(())
    }

    #[doc = fn_docs!(level_point)]
    pub fn level_point(
        &mut self,
        time: u64,
        channel: u8,
        before: f32,
        after: f32,
    ) -> Result<(), CallError> {
        let now = self.system_now();
        let hw = self.board.io().ok_or(IoError::NoHardware)?;
        if self.heaters.drives(channel) {
            return Err(IoError::HeaterOutput.into());
        }
        let time = SystemInstant::from_micros(time);
        self.tracks
            .level_point(hw, now, time, channel, before, after)?;
        self.io.mark_pwm_output(channel);
        Ok(())
    }

    #[doc = fn_docs!(event_point)]
    pub fn event_point(&mut self, time: u64, pin: u8, level: bool) -> Result<(), CallError> {
        let now = self.system_now();
        let hw = self.board.io().ok_or(IoError::NoHardware)?;
        let time = SystemInstant::from_micros(time);
        self.tracks.event_point(hw, now, time, pin, level)?;
        self.io.mark_digital_output(pin);
        Ok(())
    }

    #[doc = fn_docs!(sample_block)]
    #[allow(clippy::too_many_arguments)]
    pub fn sample_block(
        &mut self,
        source0: u8,
        arg0: u8,
        source1: u8,
        arg1: u8,
        source2: u8,
        arg2: u8,
        latency_us: u32,
        session: u32,
    ) -> Result<(u32, u32, u64, crate::sampler::Block, u32), CallError> {
        let sources = [(source0, arg0), (source1, arg1), (source2, arg2)];
        let c = self.run_sampler(sources, latency_us, session)?;
        Ok((c.seq, c.first, c.time, c.block, c.session))
    }

    #[doc = fn_docs!(level_read)]
    pub fn level_read(&mut self) -> Result<(u64, f32, f32, u32), CallError> {
        let local = self.board.now();
        let now = self.time.system_time(local);
        let hw = self.board.io().ok_or(IoError::NoHardware)?;
        // The tracks first catch up to the read's time, so what it reports
        // is what they drive now (the loop's own updates may be due in the
        // same pass, after this function's run).
        self.tracks.poll(hw, local, now);
        let ([pwm0, pwm1], pins) = crate::levels::applied(hw);
        Ok((now.as_micros(), pwm0, pwm1, pins))
    }
}

/// The next input of a call, as a `T`.
fn next_input<'a, T: FromPipes<'a>>(
    inputs: &mut core::slice::Iter<'a, Value<'_>>,
) -> Result<T, CallError> {
    inputs
        .next()
        .and_then(T::from_value)
        .ok_or(CallError::Failed(pipes_core::FailureCode::from_code(
            pipes_core::export::INPUT_DECODE_FAILED,
        )))
}

macro_rules! module_functions {
    ($(
        $(#[doc = $doc:tt])*
        $f:ident ( $($in:ident : $inty:ty),* ) $(-> ( $($out:ident : $outty:ty),* ))? ;
    )*) => {
        /// Which of the module's functions: one per [`Module`] method of
        /// the same name, in the order a scan lists them.
        #[allow(non_camel_case_types)]
        #[derive(Debug, Clone, Copy, PartialEq, Eq)]
        #[repr(u8)]
        pub enum FnId {
            $(
                $(#[doc = $doc])*
                $f,
            )*
        }

        /// Each function's documentation, in the order of [`ALL`]: the
        /// `///` lines of its table entry, which it publishes with its
        /// signature (in flash, read in place).
        pub static DOCS: [&str; ALL.len()] = [$(pipes_core::doc_text!($(#[doc = $doc])*)),*];

        /// Every function, in the order a scan lists them.
        pub const ALL: [FnId; [$(stringify!($f)),*].len()] = [$(FnId::$f),*];

        /// Each function's signature.
        #[allow(non_upper_case_globals)]
        pub mod signature {
            use super::*;
            $(
                #[doc = concat!("`", stringify!($f), "`")]
                pub static $f: Signature = Signature {
                    name: stringify!($f),
                    inputs: &[$(Arg::new(stringify!($in), <$inty as PipesType>::TYPE)),*],
                    outputs: &[$($(Arg::new(stringify!($out), <$outty as PipesType>::TYPE)),*)?],
                };
            )*
        }

        /// Every function's signature, in the order of [`ALL`]: the
        /// interface every osap-rs module firmware presents.
        pub const SIGNATURES: [&Signature; ALL.len()] = [$(&signature::$f),*];

        /// Runs function `id` on `module`, already in hand (the sampler
        /// calls its sources so, inside the module's lock).
        pub(crate) fn call_on<B: Board>(
            id: FnId,
            module: &mut Module<B>,
            inputs: &[Value<'_>],
            outputs: &mut Outputs<'_>,
        ) -> Result<(), CallError> {
            let mut args = inputs.iter();
            match id {
                $(
                    FnId::$f => {
                        $(let $in: $inty = next_input(&mut args)?;)*
                        module.$f($($in),*)?.write(outputs)
                    }
                )*
            }
        }

        fn dispatch<H: ModuleHandle>(
            id: FnId,
            module: &H,
            inputs: &[Value<'_>],
            outputs: &mut Outputs<'_>,
        ) -> Result<(), CallError> {
            // One match for both paths (flash is scarce); the outputs are
            // encoded inside the module's lock, a few bytes' work.
            module
                .with(|m| call_on(id, m, inputs, outputs))
                .ok_or(CallError::Failed(pipes_core::FailureCode::Other(NOT_INSTALLED)))?
        }
    };
}

/// Hands the module's function table to macro `$m`: one entry per
/// function, in port order, its documentation as `///` lines (which reach
/// `$m` as `#[doc = ".."]` attributes: match them with
/// `$(#[doc = $doc:tt])*`), then `name(input: type, ..) -> (output: type,
/// ..);` (no `->` for a function without outputs). The documentation is
/// each function's only text: see [`FnId::docs`]. This module builds its
/// function set from it, and a host builds typed handles from it (see
/// osap-machine's `network::modfn`), so both read one table and cannot
/// disagree.
///
/// ```
/// macro_rules! count {
///     ($($(#[doc = $doc:tt])* $f:ident ( $($in:ident : $inty:ty),* ) $(-> ( $($out:ident : $outty:ty),* ))? ;)*) => {
///         [$(stringify!($f)),*].len()
///     };
/// }
/// assert_eq!(osap_module::module_function_table!(count), osap_module::functions::ALL.len());
/// ```
#[macro_export]
macro_rules! module_function_table {
    ($m:ident) => {
        $m! {
            /// Queues a control point: the axis is at `position` (user units) at
            /// synchronized `time` (a multiple of the interval).
            add_point(time: u64, position: f32);
            /// Sets the control-point interval, µs (a power of two, 256 to 16 384),
            /// while no stream is queued.
            set_interval(interval_us: u32);
            /// Where the steps sent so far put the motor (user units), and the
            /// synchronized time of the latest step tick they include.
            get_position() -> (time: u64, position: f32);
            /// The axis mode (0 disabled, 1 idle, 2 tracking, 3 backstop, 4 halted, 5
            /// torque),
            /// points queued, whether the motor is powered, and faults since boot.
            get_status() -> (mode: u8, queued: u16, enabled: bool, faults: u32);
            /// Points accepted, refused, the latest refusal's code, and single gaps
            /// filled.
            get_counters() -> (points: u32, refused: u32, last_refused: u8, filled: u32);
            /// Where the steps put the motor, in microsteps (net steps; a scale or
            /// microstep change re-expresses it), then the steps up, steps down and
            /// late steps (steps that went out on a later tick than the one they
            /// fell due at, more than one step tick late; each is a fault, see
            /// [`crate::fault`]) since the step generator last started: at boot, on
            /// `set_enable`, `halt`, and a scale or microstep change.
            get_steps() -> (steps: i64, up: u64, down: u64, late: u64);
            /// Powers the motor or lets it go limp; powering down stops the axis
            /// where it stands and drops its stream, powering up clears a fault or a
            /// halt.
            set_enable(on: bool);
            /// Sets the motor's full steps per user unit (the microstep mode
            /// multiplies it), while no stream is queued.
            set_scale(full_steps_per_unit: f32);
            /// Sets the driver's microstep mode (1, 2, 4, .. 256, as the board's
            /// driver offers), while no stream is queued.
            set_microsteps(microsteps: u16);
            /// Sets the limits on incoming points, in user units (those of
            /// `add_point`'s position) per s, s² and s³, while no stream is queued:
            /// `add_point` then refuses a point past one (`OverLimit`, a fault
            /// `get_fault` reports). 0 turns a limit off; `set_limits(0, 0, 0)`
            /// (the default) turns the check off. A limit that is not finite, is
            /// negative, or rounds to nothing at the interval and scale is a
            /// `BadValue`; a later interval, scale or microstep change that would
            /// make one round to nothing is refused the same way.
            set_limits(max_vel: f32, max_acc: f32, max_jerk: f32);
            /// The limit switch: when its level last changed (synchronized µs, 0:
            /// never), its level, and the edges seen since boot.
            read_limit() -> (time: u64, level: bool, edges: u32);
            /// Stops stepping at once and drops the stream (an emergency stop), and
            /// drives every output to its safe value (`set_safe_pwm`,
            /// `set_safe_digital`); the axis refuses points until the motor is
            /// disabled and enabled again. Safe to repeat.
            halt();
            /// Drives digital pin `pin` high or low.
            digital_write(pin: u8, level: bool);
            /// Reads digital pin `pin`: the synchronized time of the read and the
            /// level.
            digital_read(pin: u8) -> (time: u64, level: bool);
            /// Sets PWM output `channel`'s duty cycle, a fraction `0..=1`; refused
            /// for an output a heater drives.
            pwm_write(channel: u8, duty: f32);
            /// Drives `pin` high now and low `duration_us` later (at most 10 s).
            pulse(pin: u8, duration_us: u32);
            /// Schedules a pulse of `duration_us` on `pin` at synchronized `time`
            /// (at most 60 s ahead; 16 may wait at once).
            pulse_at(time: u64, pin: u8, duration_us: u32);
            /// Samples analog input `channel`: the synchronized time of the sample
            /// and the reading as a fraction of full scale.
            analog_read(channel: u8) -> (time: u64, value: f32);
            /// The latest fault: its synchronized time, its kind
            /// ([`crate::fault::FaultKind`] code), its detail, and the faults since
            /// boot (see [`crate::fault`]).
            get_fault() -> (time: u64, code: u8, detail: u32, count: u32);
            /// Reboots the board into its bootloader for a firmware update, after
            /// this call has answered (see [`crate::boot`]): refused on a board
            /// without one, and while the axis has motion queued or running.
            enter_bootloader();
            /// Sets the duty (a fraction, `0..=1`) PWM output `channel` takes on
            /// every stop and when the output watchdog fires (0 until set). The
            /// output keeps its duty until then. Refused for an output a heater
            /// drives (its safe duty is 0).
            set_safe_pwm(channel: u8, duty: f32);
            /// Sets the level digital pin `pin` takes on every stop and when the
            /// output watchdog fires (low until set). The pin keeps its level until
            /// then.
            set_safe_digital(pin: u8, level: bool);
            /// Arms the output watchdog: when no call or pipe datagram reaches any
            /// of the module's functions for `timeout_ms`, the module drives every
            /// output to its safe value and `get_fault` reports it. 0 turns it off
            /// (as at boot). See [`crate::watchdog`].
            set_output_watchdog(timeout_ms: u32);
            /// Heater `index` (0 or 1) reads analog input `analog` through an NTC
            /// thermistor to ground with a `pullup_ohms` pullup, whose curve is
            /// the Steinhart–Hart `1/T = a + b·ln R + c·ln³R` (T in K, R in Ω; a
            /// Beta thermistor has `c = 0`, `b = 1/β`). Only while the heater is
            /// off.
            heater_sensor(index: u8, analog: u8, a: f32, b: f32, c: f32, pullup_ohms: f32);
            /// Heater `index` drives PWM output `pwm`, at most `max_power` (`0 <
            /// max_power ≤ 1`) of full duty; the output goes to 0. Only while the
            /// heater is off.
            heater_output(index: u8, pwm: u8, max_power: f32);
            /// Heater `index` runs between `min_temp` and `max_temp`, °C: below
            /// `min_temp` its sensor reads open, at `max_temp` it cuts itself off.
            /// Only while the heater is off.
            heater_limits(index: u8, min_temp: f32, max_temp: f32);
            /// Heater `index`'s PID gains in Klipper's units (`pid_Kp`, `pid_Ki`,
            /// `pid_Kd`; see [`crate::heater`]). Only while the heater is off.
            heater_gains(index: u8, kp: f32, ki: f32, kd: f32);
            /// Heater `index`'s runaway protection (Klipper's `verify_heater`;
            /// defaults 5 °C, 120 °C·s, 2 °C, 20 s; see [`crate::heater`]). Only
            /// while the heater is off.
            heater_runaway(index: u8, hysteresis_c: f32, max_error: f32, heating_gain_c: f32, check_gain_time_s: f32);
            /// Heater `index` holds `celsius` (within `[min_temp, max_temp)`); 0
            /// turns it off. Refused for a heater not fully configured or latched
            /// off by a fault. Leaves open-loop power mode.
            heater_target(index: u8, celsius: f32);
            /// Heater `index` runs open loop at `duty` (`0..=1`, capped at
            /// `max_power`), for autotuning; its sensor checks, `max_temp` and the
            /// output watchdog still guard it. `heater_target` leaves it.
            heater_power(index: u8, duty: f32);
            /// Heater `index`: the synchronized time of its latest reading (0:
            /// none yet), its temperature (°C), its target (0: off or open loop),
            /// the duty it drives (`0..=1`), and its state (0 off, 1 heating, 2
            /// holding, 3 open-loop power, 4 faulted; see
            /// [`crate::heater::HeaterState`]).
            heater_read(index: u8) -> (time: u64, temp: f32, target: f32, power: f32, state: u8);
            /// Clears heater `index`'s runaway fault if its sensor reads sane now
            /// (refused with `SensorFault` otherwise); the heater is then off.
            heater_clear(index: u8);
            /// The load cell's converter is on digital pins `data_pin` (its data
            /// line) and `clock_pin` (its clock).
            loadcell_setup(data_pin: u8, clock_pin: u8);
            /// The next `samples` readings (1 to 1 000) become the load cell's
            /// zero; `loadcell_read`'s `taring` is true until they are in.
            loadcell_tare(samples: u16);
            /// The load cell's scale, newtons per count (not 0; negative for a
            /// cell mounted the other way).
            loadcell_scale(newtons_per_count: f32);
            /// The newest sample: when it was read (synchronized µs; 0 before the
            /// first), its force, N, its raw counts, samples read since setup, and
            /// whether a tare is under way. Fails when no converter answers
            /// (`NoConverter`, `Silent`): a dead cell's zeros are never a force.
            loadcell_read() -> (time: u64, force: f32, raw: i32, samples: u32, taring: bool);
            /// Measures a speed from digital pin `pin`'s pulses, `pulses_per_rev`
            /// a turn (1 to 1 000; see [`crate::tach`]); refused with `NoCounter`
            /// on a pin the board cannot count pulses on.
            tach_setup(pin: u8, pulses_per_rev: u16);
            /// The newest measured speed: when it was measured (synchronized µs:
            /// the pulse it ends at, or the read that lowered it for want of
            /// pulses) and turns a minute (0 after 0.5 s without a pulse).
            /// `NoCounter` until `tach_setup`.
            tach_read() -> (time: u64, rpm: f32);
            /// Drives the motor as a torque device at `fraction` of its holding
            /// torque (`-1..=1`; positive turns the way positive positions go),
            /// commuting from its shaft encoder (see [`crate::torque`]): the first
            /// call leaves position mode (the motor enabled, not halted, no stream;
            /// `Unsupported` on a board without an encoder or coil drive), later
            /// ones change the torque. `get_position` then reports the shaft, and
            /// `add_point` is refused (`WrongMode`). `torque_off`, `halt`,
            /// `set_enable` and the output watchdog end it: the motor holds where
            /// it stands.
            set_torque(fraction: f32);
            /// Ends torque mode: the motor holds the shaft where it stands, and a
            /// stream may start there. Safe to repeat, and in position mode.
            torque_off();
            /// A point on PWM output `channel` (0 or 1) at synchronized `time`
            /// (at most 60 s ahead): the duty ramps linearly from the point
            /// before to `before` there and leaves at `after` (`0..=1`; a step
            /// where they differ); 64 points wait an output. Points come in
            /// time order: one stamped before now is `Late`, before (or at) one
            /// queued `OutOfOrder`, past the queue `Full`. Refused for an output
            /// a heater drives. Every stop and a `pwm_write` to the output drop
            /// what waits (see [`crate::levels`]).
            level_point(time: u64, channel: u8, before: f32, after: f32);
            /// Digital pin `pin` goes to `level` at synchronized `time` (at most
            /// 60 s ahead); 32 changes wait at once, in time order (`Late`,
            /// `OutOfOrder`, `Full` as for `level_point`). Every stop and a
            /// `digital_write` to the pin drop what waits.
            event_point(time: u64, pin: u8, level: bool);
            /// What the outputs drive now, as a pipe source's record of what a
            /// tool did: the synchronized time of the read, the duty PWM outputs
            /// 0 and 1 drive (`0..=1`), and the levels of digital pins 0 to 31
            /// (bit `k` is pin `k`). The level and event tracks are brought up to
            /// the read's time first.
            level_read() -> (time: u64, pwm0: f32, pwm1: f32, pins: u32);
            /// Samples up to three read functions (table index, 255: none; one `u8`
            /// argument) on its timer into stamped, numbered blocks. A block goes down
            /// its pipes when full or `latency_us` old (0: close it now); see
            /// [`crate::sampler`].
            sample_block(source0: u8, arg0: u8, source1: u8, arg1: u8, source2: u8, arg2: u8, latency_us: u32, session: u32) -> (seq: u32, first: u32, time: u64, samples: $crate::sampler::Block, session: u32);
        }
    };
}

module_function_table!(module_functions);

/// One of the module's functions bound to one module: what a function
/// port runs.
#[derive(Debug, Clone)]
pub struct ModuleFn<H> {
    id: FnId,
    module: H,
}

impl<H: ModuleHandle> ModuleFn<H> {
    /// Function `id` of the module `module` reaches.
    pub fn new(id: FnId, module: H) -> Self {
        ModuleFn { id, module }
    }

    /// Which function it is.
    pub fn id(&self) -> FnId {
        self.id
    }

    /// The module it is bound to.
    pub fn module(&self) -> &H {
        &self.module
    }
}

impl<H: ModuleHandle> Implementation for ModuleFn<H> {
    fn signature(&self) -> &'static Signature {
        SIGNATURES[self.id as usize]
    }

    fn call(&mut self, inputs: &[Value<'_>], outputs: &mut Outputs<'_>) -> Result<(), CallError> {
        dispatch(self.id, &self.module, inputs, outputs)
    }

    /// The function's table from [`crate::failure`]: what the host names
    /// its refusals by.
    fn failures(&self) -> &'static [pipes_core::failure::Failure] {
        self.id.failures()
    }

    /// The function's documentation, from [`DOCS`].
    fn docs(&self) -> &'static str {
        self.id.docs()
    }
}

impl FnId {
    /// The function's documentation ([`DOCS`]): the `///` lines of its
    /// entry in [`module_function_table!`](crate::module_function_table).
    pub fn docs(self) -> &'static str {
        DOCS.get(self as usize).copied().unwrap_or("")
    }
}

/// FNV-1a, 32 bits: one step.
const fn fnv1a(mut hash: u32, bytes: &[u8]) -> u32 {
    let mut i = 0;
    while i < bytes.len() {
        hash ^= bytes[i] as u32;
        hash = hash.wrapping_mul(0x0100_0193);
        i += 1;
    }
    hash
}

/// FNV-1a's starting value.
const FNV_OFFSET: u32 = 0x811C_9DC5;

/// A `str8` as a scan reads it: a length byte, then the bytes.
const fn hash_str8(hash: u32, s: &str) -> u32 {
    fnv1a(fnv1a(hash, &[s.len() as u8]), s.as_bytes())
}

/// The identity of a function set: FNV-1a over what a scan reads of each
/// signature, in order (the function count, then per function its name,
/// and for inputs and outputs the count and each argument's name and type
/// key, as `docs/pipes.md` §5 lays them out). Two sets with the same id
/// present the same functions at the same ports.
pub const fn function_set_id(signatures: &[&Signature]) -> u32 {
    let mut hash = fnv1a(FNV_OFFSET, &[signatures.len() as u8]);
    let mut f = 0;
    while f < signatures.len() {
        let sig = signatures[f];
        hash = hash_str8(hash, sig.name);
        let lists = [sig.inputs, sig.outputs];
        let mut l = 0;
        while l < lists.len() {
            let args = lists[l];
            hash = fnv1a(hash, &[args.len() as u8]);
            let mut a = 0;
            while a < args.len() {
                hash = hash_str8(hash, args[a].name);
                hash = fnv1a(hash, &[args[a].ty.key()]);
                a += 1;
            }
            l += 1;
        }
        f += 1;
    }
    hash
}

/// [`function_set_id`] over signatures a scan read (borrowed names and
/// type keys), one function at a time, so a host need not build
/// `'static` [`Signature`]s to check a module's set.
#[derive(Debug, Clone, Copy)]
pub struct FunctionSetHasher(u32);

impl FunctionSetHasher {
    /// Starts the id of a set of `count` functions.
    pub fn new(count: usize) -> Self {
        FunctionSetHasher(fnv1a(FNV_OFFSET, &[count as u8]))
    }

    /// Adds the next function: its name, and its inputs' and outputs'
    /// names with their type keys.
    pub fn function<'a, I, O>(&mut self, name: &str, inputs: I, outputs: O)
    where
        I: ExactSizeIterator<Item = (&'a str, u8)>,
        O: ExactSizeIterator<Item = (&'a str, u8)>,
    {
        self.0 = hash_str8(self.0, name);
        self.args(inputs);
        self.args(outputs);
    }

    fn args<'a>(&mut self, args: impl ExactSizeIterator<Item = (&'a str, u8)>) {
        self.0 = fnv1a(self.0, &[args.len() as u8]);
        for (name, key) in args {
            self.0 = fnv1a(hash_str8(self.0, name), &[key]);
        }
    }

    /// The id.
    pub fn finish(self) -> u32 {
        self.0
    }
}

/// The identity of [`SIGNATURES`]: every firmware embeds it, so a check of
/// the built images proves they all present the same functions (one proxy
/// serves them all).
pub const FUNCTION_SET_ID: u32 = function_set_id(&SIGNATURES);
