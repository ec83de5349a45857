//! A load cell on the module: a 24-bit bridge converter of the HX711
//! kind, read over two digital pins (data and clock), with tare and
//! scale, so the force on a filament (or a spindle, a probe) streams from
//! the module like any other reading.
//!
//! **Reading.** The converter runs by itself (10 or 80 samples a second)
//! and pulls its data line low when a sample is ready. The module polls
//! the data line every [`POLL_PERIOD`] from the runtime's loop
//! ([`LoadCell::poll`] at [`LoadCell::wake_at`]); when it is low, it
//! clocks the sample out MSB first on 24 clock pulses and gives a 25th
//! (channel A, gain 128 for the next sample). The clock line is never
//! held high between pulses: an HX711 powers down when its clock stays
//! high for 60 µs, so the whole read runs in one piece of work.
//!
//! **Wiring.** A converter drives its data line high after the 25th pulse
//! until its next sample. A line still low then is not driven (unwired,
//! or held low): the sample is dropped and `loadcell_read` fails with
//! `NoConverter`. A converter that gives no sample for [`SILENT_AFTER`]
//! (unpowered, or its line held high) fails it with `Silent`. Neither
//! passes off a dead cell's zeros as a force.
//!
//! **Tare and scale.** `loadcell_tare(samples)` averages the next
//! `samples` readings as the zero; `loadcell_scale(newtons_per_count)`
//! sets the scale. A reading is then `(raw − tare) · newtons_per_count`.
//! `loadcell_read` reports the newest sample, its time, the raw counts,
//! the samples read so far and whether a tare is under way: as a pipe
//! source with output mode "on change" it streams every sample.

use crate::board::IoHw;
use osap_core::{Duration, Instant};

/// How often the data line is polled while the cell is set up: under a
/// third of the 80-a-second converter's period, so a sample waits at most
/// 1 ms to be read.
pub const POLL_PERIOD: Duration = Duration::from_micros(1_000);

/// How long without a sample before `loadcell_read` says the converter
/// is silent: five periods of a 10-a-second converter.
pub const SILENT_AFTER: Duration = Duration::from_micros(500_000);

/// The most samples a tare may average (at 80 a second, 12.5 s).
pub const MAX_TARE_SAMPLES: u16 = 1_000;

/// Why a load-cell call was refused: the failure code a caller sees.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
#[non_exhaustive]
pub enum LoadCellError {
    /// No such digital pin on this board, or data and clock on one pin.
    NoSuchPin = 1,
    /// A value out of range: a scale not finite or zero, a tare of 0 or
    /// more than [`MAX_TARE_SAMPLES`] samples.
    BadValue = 2,
    /// The load cell is not set up: `loadcell_setup` first.
    NotConfigured = 3,
    /// The I/O hardware was never installed (a firmware without it).
    NoHardware = 4,
    /// The data line stayed low after a read: no converter drives it.
    NoConverter = 5,
    /// No sample for [`SILENT_AFTER`]: the converter is off or unwired.
    Silent = 6,
}

impl LoadCellError {
    /// Every load-cell error, in code order.
    pub const ALL: [LoadCellError; 6] = [
        LoadCellError::NoSuchPin,
        LoadCellError::BadValue,
        LoadCellError::NotConfigured,
        LoadCellError::NoHardware,
        LoadCellError::NoConverter,
        LoadCellError::Silent,
    ];

    /// The failure code.
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// The error with failure code `code`; `None` for a code that is not a
    /// load-cell error.
    pub fn from_code(code: u8) -> Option<LoadCellError> {
        Self::ALL.into_iter().find(|e| e.code() == code)
    }
}

impl core::fmt::Display for LoadCellError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            LoadCellError::NoSuchPin => "no such digital pin, or data and clock on one pin",
            LoadCellError::BadValue => "a value out of range",
            LoadCellError::NotConfigured => "the load cell is not set up",
            LoadCellError::NoHardware => "the I/O hardware was never installed",
            LoadCellError::NoConverter => "no converter drives the data line",
            LoadCellError::Silent => "the converter gives no samples",
        })
    }
}

impl From<LoadCellError> for pipes_core::FailureCode {
    fn from(e: LoadCellError) -> Self {
        pipes_core::FailureCode::Other(e.code())
    }
}

impl From<LoadCellError> for pipes_core::function::CallError {
    fn from(e: LoadCellError) -> Self {
        pipes_core::function::CallError::Failed(e.into())
    }
}

/// A tare under way.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Tare {
    want: u16,
    got: u16,
    sum: i64,
}

/// The newest sample: what `loadcell_read` reports.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reading {
    /// When the module read it, local time.
    pub at: Instant,
    /// The converter's counts, sign-extended.
    pub raw: i32,
    /// `(raw − tare) · newtons_per_count`.
    pub force: f32,
}

/// The load cell and its converter.
#[derive(Debug, Clone, Default)]
pub struct LoadCell {
    /// (data pin, clock pin).
    pins: Option<(u8, u8)>,
    tare: i32,
    newtons_per_count: f32,
    taring: Option<Tare>,
    newest: Option<Reading>,
    samples: u32,
    next_poll: Option<Instant>,
    /// The last sample, or the setup: when the converter last answered.
    answered_at: Instant,
    /// The data line was seen undriven since setup.
    undriven: bool,
}

impl LoadCell {
    /// A load cell not yet set up (scale 1: forces in counts).
    pub fn new() -> Self {
        LoadCell {
            newtons_per_count: 1.0,
            ..LoadCell::default()
        }
    }

    /// The converter's data line is digital pin `data`, its clock `clock`;
    /// the clock goes low at local time `now`. Forgets the newest sample,
    /// any tare under way and any wiring fault seen (the tare and scale
    /// stay).
    pub fn setup(
        &mut self,
        hw: &mut dyn IoHw,
        data: u8,
        clock: u8,
        now: Instant,
    ) -> Result<(), LoadCellError> {
        let pins = hw.digital_pins();
        if data >= pins || clock >= pins || data == clock {
            return Err(LoadCellError::NoSuchPin);
        }
        hw.write_digital(clock, false);
        self.pins = Some((data, clock));
        self.newest = None;
        self.taring = None;
        self.next_poll = Some(Instant::ZERO);
        self.answered_at = now;
        self.undriven = false;
        Ok(())
    }

    /// Averages the next `samples` readings as the zero.
    pub fn tare(&mut self, samples: u16) -> Result<(), LoadCellError> {
        if self.pins.is_none() {
            return Err(LoadCellError::NotConfigured);
        }
        if samples == 0 || samples > MAX_TARE_SAMPLES {
            return Err(LoadCellError::BadValue);
        }
        self.taring = Some(Tare {
            want: samples,
            got: 0,
            sum: 0,
        });
        Ok(())
    }

    /// Newtons per count (negative for a cell mounted the other way).
    pub fn set_scale(&mut self, newtons_per_count: f32) -> Result<(), LoadCellError> {
        if !(newtons_per_count.is_finite() && newtons_per_count != 0.0) {
            return Err(LoadCellError::BadValue);
        }
        self.newtons_per_count = newtons_per_count;
        if let Some(r) = &mut self.newest {
            r.force = (r.raw - self.tare) as f32 * newtons_per_count;
        }
        Ok(())
    }

    /// The newest sample; `None` before the first.
    pub fn newest(&self) -> Option<Reading> {
        self.newest
    }

    /// Samples read since setup.
    pub fn samples(&self) -> u32 {
        self.samples
    }

    /// Whether a tare is under way.
    pub fn taring(&self) -> bool {
        self.taring.is_some()
    }

    /// Whether the cell is set up.
    pub fn is_set_up(&self) -> bool {
        self.pins.is_some()
    }

    /// Whether a converter answers, at local time `now`: `NoConverter`
    /// once its data line was seen undriven (until set up again), `Silent`
    /// after
    /// [`SILENT_AFTER`] without a sample.
    pub fn check(&self, now: Instant) -> Result<(), LoadCellError> {
        if self.pins.is_none() {
            return Err(LoadCellError::NotConfigured);
        }
        if self.undriven {
            return Err(LoadCellError::NoConverter);
        }
        if now.saturating_duration_since(self.answered_at) > SILENT_AFTER {
            return Err(LoadCellError::Silent);
        }
        Ok(())
    }

    /// When [`poll`](Self::poll) next has work, local time.
    pub fn wake_at(&self) -> Option<Instant> {
        self.pins.and(self.next_poll)
    }

    /// Reads a sample if the converter has one, at local time `now`.
    /// Returns whether it read one.
    pub fn poll(&mut self, hw: &mut dyn IoHw, now: Instant) -> bool {
        let Some((data, clock)) = self.pins else {
            return false;
        };
        if self.next_poll.is_some_and(|at| at > now) {
            return false;
        }
        self.next_poll = Some(now + POLL_PERIOD);
        if hw.read_digital(data) {
            return false;
        }
        let mut raw: u32 = 0;
        // Each bit is valid 0.1 µs after the clock rises: read it while
        // the clock is high.
        for _ in 0..24 {
            hw.write_digital(clock, true);
            hw.hold_pulse();
            raw = raw << 1 | u32::from(hw.read_digital(data));
            hw.write_digital(clock, false);
            hw.hold_pulse();
        }
        // The 25th pulse: channel A, gain 128, for the next sample.
        hw.write_digital(clock, true);
        hw.hold_pulse();
        hw.write_digital(clock, false);
        hw.hold_pulse();
        // A converter now drives its line high until the next sample.
        if !hw.read_digital(data) {
            self.undriven = true;
            return false;
        }
        self.answered_at = now;
        // Sign-extend the 24-bit two's complement.
        let raw = ((raw << 8) as i32) >> 8;
        self.samples = self.samples.wrapping_add(1);
        if let Some(t) = &mut self.taring {
            t.sum += i64::from(raw);
            t.got += 1;
            if t.got >= t.want {
                self.tare = (t.sum / i64::from(t.got)) as i32;
                self.taring = None;
            }
        }
        self.newest = Some(Reading {
            at: now,
            raw,
            force: (raw - self.tare) as f32 * self.newtons_per_count,
        });
        true
    }
}
