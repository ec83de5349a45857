//! Level and event tracks: tool outputs that change at synchronized
//! times, so a laser's power follows the motion it rides on.
//!
//! A host stamps **level points** (`level_point`: a PWM duty at a
//! synchronized time) and **event points** (`event_point`: a digital pin
//! going high or low at a synchronized time) on the same time base as the
//! motion's control points, and sends them ahead as it sends the motion.
//! The module applies them on its own loop ([`Tracks::poll`], woken at
//! [`Tracks::wake_at`]), so what reaches the output does not wait for the
//! network: the stamp says when.
//!
//! Each level point gives two duties at its stamp: the one the output
//! has reached there (`before`) and the one it leaves with (`after`).
//! Between two points the duty is interpolated linearly from the first's
//! `after` to the second's `before`, as a motion track is between its
//! control points (a ramp: the laser's power following the speed through
//! an acceleration); where `before` and `after` differ the duty steps at
//! the stamp (a laser switched on or off at an exact place on the path).
//! So a host places points where the level's slope changes and the
//! module's ramps are exact between them. Linear interpolation stays
//! within its two ends, so a duty never leaves `0..=1`, and needs no
//! point beyond the next one. While a ramp runs the module writes the
//! output every [`LEVEL_UPDATE_US`]; the duty it writes is the ramp's
//! value at that time.
//!
//! **Bounded.** Each of [`LEVEL_CHANNELS`] PWM outputs queues
//! [`LEVEL_POINTS`] points, and [`EVENT_POINTS`] pin changes wait at once;
//! a full queue refuses the point (`Full`), a stamp already past
//! (`Late`) or before one queued (`OutOfOrder`) is refused too. Nothing
//! is dropped silently.
//!
//! **Stops.** Every stop (`halt`, a backstop, the output watchdog) clears
//! every queued point before it drives the outputs to their safe values
//! ([`crate::io`]), so nothing queued switches a tool back on after a
//! stop. A direct `pwm_write` or `digital_write` wins over the track too:
//! it drops the points queued for its output.
//!
//! **What was applied.** `level_read` reports what the outputs drive
//! (the duty each of the [`LEVEL_CHANNELS`] PWM outputs drives and the
//! level of the first 32 digital pins), stamped with the synchronized
//! time of the read: a pipe source on the module's timer makes a record
//! of what the tool actually did.

use crate::board::IoHw;
use crate::io::IoError;
use maxl::level::{EventTrack, LevelTrack, TimedPushError};
use osap_core::{Duration, Instant, SystemInstant};

/// PWM outputs with a level track: outputs 0 and 1 (the outputs a
/// machine file's tools take).
pub const LEVEL_CHANNELS: usize = 2;
/// Level points each PWM output queues: 64 covers a stream sent 60
/// intervals ahead at one point an interval, as a motion track.
pub const LEVEL_POINTS: usize = 64;
/// Pin changes that wait at once, over all pins.
pub const EVENT_POINTS: usize = 32;
/// How often a running ramp writes its output, µs: 100 µs holds a ramp
/// within 0.3 % of full duty of its line at the steepest ramp a machine
/// makes (a laser's power from rest at 3 000 mm/s² to 100 mm/s).
pub const LEVEL_UPDATE_US: u64 = 100;
/// How far ahead a point may be stamped (60 s), as a scheduled pulse.
pub const MAX_TRACK_LEAD: Duration = Duration::from_secs(60);

/// One level point: the duty (of 65 535) reached at its stamp, and the
/// duty from its stamp on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Level {
    before: u16,
    after: u16,
}

/// A pin change.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
struct Change {
    pin: u8,
    level: bool,
}

/// The level and event tracks' state (the hardware is passed in to each
/// call).
#[derive(Debug, Clone)]
pub struct Tracks {
    levels: [LevelTrack<Level, LEVEL_POINTS>; LEVEL_CHANNELS],
    /// Whether each channel's track has written its output since its last
    /// point was queued (a track with nothing left holds its output).
    active: [bool; LEVEL_CHANNELS],
    events: EventTrack<Change, EVENT_POINTS>,
    /// Local time of the latest write a ramp made.
    last_write: Option<Instant>,
}

impl Default for Tracks {
    fn default() -> Self {
        Tracks::new()
    }
}

/// A track's refusal as the I/O family's code.
fn refusal(e: TimedPushError) -> IoError {
    match e {
        TimedPushError::Full => IoError::Full,
        TimedPushError::Late { .. } => IoError::Late,
        // A second point at one stamp is out of order too: the track
        // cannot hold two values for one time.
        _ => IoError::OutOfOrder,
    }
}

const IDLE: Level = Level {
    before: 0,
    after: 0,
};

/// A duty (a fraction, `0..=1`) of 65 535.
fn raw_duty(duty: f32) -> Result<u16, IoError> {
    if !(0.0..=1.0).contains(&duty) {
        return Err(IoError::BadValue);
    }
    Ok((duty * 65_535.0 + 0.5) as u16)
}

impl Tracks {
    /// Nothing queued.
    pub fn new() -> Self {
        Tracks {
            levels: core::array::from_fn(|_| LevelTrack::new(IDLE)),
            active: [false; LEVEL_CHANNELS],
            events: EventTrack::new(Change::default()),
            last_write: None,
        }
    }

    /// Queues a point on PWM output `channel` at synchronized `time`: the
    /// ramp from the point before reaches `before` there, and the output
    /// leaves it at `after` (fractions, `0..=1`; a step where they differ).
    /// `system_now` is the synchronized time now. The caller checks that
    /// no heater drives the output.
    #[allow(clippy::too_many_arguments)]
    pub fn level_point(
        &mut self,
        hw: &dyn IoHw,
        system_now: SystemInstant,
        time: SystemInstant,
        channel: u8,
        before: f32,
        after: f32,
    ) -> Result<(), IoError> {
        if channel >= hw.pwm_outputs() || usize::from(channel) >= LEVEL_CHANNELS {
            return Err(IoError::NoSuchPin);
        }
        let level = Level {
            before: raw_duty(before)?,
            after: raw_duty(after)?,
        };
        if time > system_now + MAX_TRACK_LEAD {
            return Err(IoError::BadValue);
        }
        let track = &mut self.levels[usize::from(channel)];
        track.push(time.as_micros(), level).map_err(refusal)?;
        self.active[usize::from(channel)] = true;
        Ok(())
    }

    /// Queues digital pin `pin` going to `level` at synchronized `time`.
    pub fn event_point(
        &mut self,
        hw: &dyn IoHw,
        system_now: SystemInstant,
        time: SystemInstant,
        pin: u8,
        level: bool,
    ) -> Result<(), IoError> {
        if pin >= hw.digital_pins() {
            return Err(IoError::NoSuchPin);
        }
        if time > system_now + MAX_TRACK_LEAD {
            return Err(IoError::BadValue);
        }
        self.events
            .push(time.as_micros(), Change { pin, level })
            .map_err(refusal)
    }

    /// Drops every queued point (a stop, before the safe values go out).
    pub fn clear(&mut self) {
        for t in self.levels.iter_mut() {
            t.clear_to(IDLE);
        }
        self.active = [false; LEVEL_CHANNELS];
        self.events.clear();
    }

    /// Drops the points queued for PWM output `channel` (a direct write
    /// wins over its track).
    pub fn clear_channel(&mut self, channel: u8) {
        if let Some(t) = self.levels.get_mut(usize::from(channel)) {
            t.clear_to(IDLE);
            self.active[usize::from(channel)] = false;
        }
    }

    /// Drops the changes queued for digital pin `pin` (a direct write wins
    /// over its track): the others keep their order.
    pub fn clear_pin(&mut self, pin: u8) {
        let mut kept: EventTrack<Change, EVENT_POINTS> = EventTrack::new(Change::default());
        while let Some(t) = self.events.next_time() {
            // `poll` at a pending stamp yields that event: move each one over.
            if let Some(f) = self.events.poll(t) {
                if f.event.pin != pin {
                    // Same stamps, same order, same capacity: cannot fail.
                    let _ = kept.push(f.time, f.event);
                }
            }
        }
        self.events = kept;
    }

    /// The duty PWM output `channel`'s track puts out at synchronized
    /// `t`, of 65 535, applying the points due; `None` when the track has
    /// nothing to say (no point has come due since it was last cleared).
    fn duty_at(&mut self, channel: usize, t: u64) -> Option<u16> {
        let track = &mut self.levels[channel];
        let now = track.advance(t);
        let since = track.since()?;
        Some(match track.next() {
            Some((t1, next)) if t1 > since && next.before != now.after => {
                let f = (t - since) as f64 / (t1 - since) as f64;
                let (a, b) = (f64::from(now.after), f64::from(next.before));
                (a + f * (b - a) + 0.5) as u16
            }
            _ => now.after,
        })
    }

    /// Applies every point due at local time `now` (synchronized
    /// `system_now`): pin changes whose time has come, and each PWM
    /// output's level (its ramp's value now).
    pub fn poll(&mut self, hw: &mut dyn IoHw, now: Instant, system_now: SystemInstant) {
        let t = system_now.as_micros();
        while let Some(f) = self.events.poll(t) {
            hw.write_digital(f.event.pin, f.event.level);
        }
        for channel in 0..LEVEL_CHANNELS {
            // Every track learns the time (so a point stamped before it is
            // `Late`); only one with points writes its output.
            let duty = self.duty_at(channel, t);
            if !self.active[channel] {
                continue;
            }
            if let Some(duty) = duty {
                // Only a change is written: the loop may poll far more
                // often than the duty moves.
                if hw.read_pwm(channel as u8) != duty {
                    hw.write_pwm(channel as u8, duty);
                }
                if self.levels[channel].pending() == 0 {
                    // The last point is out: the output holds it.
                    self.active[channel] = false;
                }
            }
        }
        self.last_write = Some(now);
    }

    /// When [`poll`](Self::poll) next has work, local time, given the
    /// local time `now` and synchronized `system_now`: the next pin change,
    /// the next level point, and while a ramp runs, the next update.
    pub fn wake_at(&self, now: Instant, system_now: SystemInstant) -> Option<Instant> {
        let at = |t: u64| now + (SystemInstant::from_micros(t) - system_now);
        let events = self.events.next_time().map(at);
        let levels = self
            .levels
            .iter()
            .zip(self.active)
            .filter(|(_, active)| *active)
            .filter_map(|(track, _)| {
                let next = track.next().map(|(t, _)| at(t));
                let ramping = track.since().is_some()
                    && track
                        .next()
                        .is_some_and(|(_, l)| l.before != track.current().after);
                let update = ramping.then(|| {
                    self.last_write
                        .map_or(now, |w| w + Duration::from_micros(LEVEL_UPDATE_US))
                });
                [next, update].into_iter().flatten().min()
            });
        events.into_iter().chain(levels).min()
    }

    /// Points queued on PWM output `channel` (0 past [`LEVEL_CHANNELS`]).
    pub fn pending_levels(&self, channel: u8) -> usize {
        self.levels
            .get(usize::from(channel))
            .map_or(0, LevelTrack::pending)
    }

    /// Pin changes queued.
    pub fn pending_events(&self) -> usize {
        self.events.pending()
    }
}

/// What `level_read` reports: the duty of PWM outputs 0 and 1 (fractions)
/// and the level of the first 32 digital pins (bit `k` is pin `k`), as the
/// board's outputs drive them now.
pub fn applied(hw: &mut dyn IoHw) -> ([f32; LEVEL_CHANNELS], u32) {
    let mut duty = [0.0; LEVEL_CHANNELS];
    for (channel, d) in duty.iter_mut().enumerate() {
        *d = f32::from(hw.read_pwm(channel as u8)) / 65_535.0;
    }
    let mut pins = 0u32;
    for pin in 0..hw.digital_pins().min(32) {
        if hw.read_digital(pin) {
            pins |= 1 << pin;
        }
    }
    (duty, pins)
}
