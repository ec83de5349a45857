//! A tachometer on a digital pin: a spindle's hall sensor or encoder
//! gives `pulses_per_rev` pulses a turn, the board counts their rising
//! edges in hardware and latches the time of the newest
//! ([`IoHw::edge_count`]), and the module turns that into a measured
//! speed, so a host waits for a spindle to reach its speed and sees it
//! stall.
//!
//! **Measuring.** Every [`POLL_PERIOD`] the module reads the count and
//! the newest edge's time. New edges since the last read give the speed
//! over whole periods: `Δcount / pulses_per_rev` turns in the time between
//! the two newest edges, so the reading is exact to the edge time stamp
//! (a µs), not to the poll. With no new edge, the speed can be at most
//! one pulse over the time since the newest edge: the reading falls to
//! that bound, so a spindle that stops reads falling at once, and reads 0
//! after [`STOPPED_AFTER`] without an edge.
//!
//! `tach_read` reports the speed with the synchronized time of the edge
//! it was measured at (or of the poll that lowered it): as an "on change"
//! pipe source it streams every new measurement.

use crate::board::IoHw;
use crate::io::IoError;
use osap_core::{Duration, Instant};

/// How often the count is read: at 24 000 rpm and one pulse a turn, 4
/// pulses a read; slow enough to cost nothing, fast enough that a stall
/// reads within a few ms.
pub const POLL_PERIOD: Duration = Duration::from_micros(10_000);

/// How long without an edge until the speed reads 0: one pulse in 0.5 s
/// is under 120 rpm at one pulse a turn, below any spindle's speed.
pub const STOPPED_AFTER: Duration = Duration::from_micros(500_000);

/// The most pulses a turn a tachometer may give.
pub const MAX_PULSES_PER_REV: u16 = 1_000;

/// The newest speed measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Speed {
    /// When it was measured: the edge it ends at, or the poll that
    /// lowered it, local time.
    pub at: Instant,
    /// Turns a minute.
    pub rpm: f32,
}

/// The tachometer's state (the hardware is passed in to each call).
#[derive(Debug, Clone, Default)]
pub struct Tach {
    /// (pin, pulses a turn), once set up.
    setup: Option<(u8, u16)>,
    /// The count at setup: the first edge after it starts the first
    /// whole period.
    baseline: u32,
    /// The count and newest edge's time at the last read that saw an edge
    /// (`None` until an edge after setup).
    last: Option<(u32, Instant)>,
    speed: Option<Speed>,
    next_poll: Option<Instant>,
}

impl Tach {
    /// No tachometer set up.
    pub const fn new() -> Self {
        Tach {
            setup: None,
            baseline: 0,
            last: None,
            speed: None,
            next_poll: None,
        }
    }

    /// Counts `pulses_per_rev` pulses a turn on digital pin `pin` from
    /// local time `now`: `NoSuchPin` for a pin the board lacks,
    /// `NoCounter` for one its hardware cannot count on, `BadValue` for 0
    /// or more than [`MAX_PULSES_PER_REV`] pulses a turn.
    pub fn setup(
        &mut self,
        hw: &mut dyn IoHw,
        pin: u8,
        pulses_per_rev: u16,
        now: Instant,
    ) -> Result<(), IoError> {
        if pin >= hw.digital_pins() {
            return Err(IoError::NoSuchPin);
        }
        if pulses_per_rev == 0 || pulses_per_rev > MAX_PULSES_PER_REV {
            return Err(IoError::BadValue);
        }
        let (count, _) = hw.edge_count(pin).ok_or(IoError::NoCounter)?;
        self.setup = Some((pin, pulses_per_rev));
        // The newest edge so far may be from long ago: the first edge
        // after setup starts the first whole period.
        self.baseline = count;
        self.last = None;
        self.speed = Some(Speed { at: now, rpm: 0.0 });
        self.next_poll = Some(now + POLL_PERIOD);
        Ok(())
    }

    /// Reads the count at local time `now` and updates the speed.
    pub fn poll(&mut self, hw: &mut dyn IoHw, now: Instant) {
        let Some((pin, ppr)) = self.setup else {
            return;
        };
        self.next_poll = Some(now + POLL_PERIOD);
        let Some((count, edge)) = hw.edge_count(pin) else {
            return;
        };
        let Some((last_count, last_edge)) = self.last else {
            if count != self.baseline {
                self.last = Some((count, edge));
            }
            return;
        };
        let pulses = count.wrapping_sub(last_count);
        let turns_per_pulse = 1.0 / f32::from(ppr);
        if pulses > 0 {
            let span = edge.saturating_duration_since(last_edge).as_micros();
            self.last = Some((count, edge));
            if span > 0 {
                let rpm = pulses as f32 * turns_per_pulse * 60e6 / span as f32;
                self.speed = Some(Speed { at: edge, rpm });
            }
            return;
        }
        // No edge: at most one pulse over the time since the newest.
        let quiet = now.saturating_duration_since(last_edge);
        let bound = if quiet >= STOPPED_AFTER {
            0.0
        } else {
            turns_per_pulse * 60e6 / quiet.as_micros().max(1) as f32
        };
        if let Some(s) = &mut self.speed {
            if bound < s.rpm {
                *s = Speed {
                    at: now,
                    rpm: bound,
                };
            }
        }
    }

    /// When [`poll`](Self::poll) next has work, local time (`None`: not
    /// set up).
    pub fn wake_at(&self) -> Option<Instant> {
        self.next_poll
    }

    /// The newest speed: `NoCounter` until set up.
    pub fn speed(&self) -> Result<Speed, IoError> {
        self.speed.ok_or(IoError::NoCounter)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pin whose counter a test advances: pulses at a steady rate.
    struct Counter {
        count: u32,
        edge: Instant,
    }

    impl IoHw for Counter {
        fn digital_pins(&self) -> u8 {
            4
        }
        fn write_digital(&mut self, _pin: u8, _level: bool) {}
        fn read_digital(&mut self, _pin: u8) -> bool {
            false
        }
        fn pwm_outputs(&self) -> u8 {
            0
        }
        fn write_pwm(&mut self, _channel: u8, _duty: u16) {}
        fn read_pwm(&self, _channel: u8) -> u16 {
            0
        }
        fn analog_inputs(&self) -> u8 {
            0
        }
        fn read_analog(&mut self, _channel: u8) -> u16 {
            0
        }
        fn edge_count(&mut self, pin: u8) -> Option<(u32, Instant)> {
            (pin == 2).then_some((self.count, self.edge))
        }
    }

    fn at(us: u64) -> Instant {
        Instant::from_micros(us)
    }

    #[test]
    fn measures_whole_periods_and_falls_when_the_pulses_stop() {
        let mut hw = Counter {
            count: 7,
            edge: at(1),
        };
        let mut t = Tach::new();
        assert_eq!(t.speed(), Err(IoError::NoCounter));
        assert_eq!(t.setup(&mut hw, 1, 2, at(10)), Err(IoError::NoCounter));
        assert_eq!(t.setup(&mut hw, 9, 2, at(10)), Err(IoError::NoSuchPin));
        assert_eq!(t.setup(&mut hw, 2, 0, at(10)), Err(IoError::BadValue));
        t.setup(&mut hw, 2, 2, at(10)).unwrap();
        assert_eq!(t.speed().unwrap().rpm, 0.0);
        // 18 000 rpm at 2 pulses a turn: a pulse every 1 666.7 µs. The
        // first edge after setup starts the first period.
        let period = 1_666.667;
        let edge = |n: u32| at(20_000 + (f64::from(n) * period) as u64);
        hw.count = 8;
        hw.edge = edge(0);
        t.poll(&mut hw, at(30_000));
        hw.count = 14;
        hw.edge = edge(6);
        t.poll(&mut hw, at(40_000));
        let s = t.speed().unwrap();
        assert_eq!(s.at, edge(6));
        assert!((s.rpm - 18_000.0).abs() < 18_000.0 * 1e-3, "{s:?}");
        // The pulses stop: the bound (one pulse since the newest edge)
        // lowers the speed at each poll, then it reads 0.
        t.poll(&mut hw, at(70_000));
        let s = t.speed().unwrap();
        let quiet = 70_000.0 - (20_000.0 + 6.0 * period).floor();
        assert!((f64::from(s.rpm) - 0.5 * 60e6 / quiet).abs() < 1.0, "{s:?}");
        assert_eq!(s.at, at(70_000));
        t.poll(&mut hw, at(20_000 + 600_000));
        assert_eq!(t.speed().unwrap().rpm, 0.0);
        // A wrapped counter still counts.
        hw.count = u32::MAX;
        hw.edge = at(700_000);
        t.poll(&mut hw, at(700_001));
        hw.count = 2;
        hw.edge = at(700_000 + 3 * 1_000);
        t.poll(&mut hw, at(710_000));
        let rpm = t.speed().unwrap().rpm;
        assert!((rpm - 30_000.0).abs() < 1.0, "{rpm}");
    }
}
