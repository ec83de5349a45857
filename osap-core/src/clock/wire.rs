//! The clock's wire messages and their codecs: time stamp requests and
//! replies (system messages 0 and 1) and the [`TimeConfig`] layout that the
//! netresponder reads and writes.

use crate::codec::{CodecError, Reader, Writer};
use crate::time::{Instant, SystemInstant};

/// System message code of a time stamp request.
pub const CODE_TIME_REQUEST: u8 = 0;
/// System message code of a time stamp reply.
pub const CODE_TIME_REPLY: u8 = 1;
/// Length of a time stamp request body.
pub const TIME_REQUEST_LEN: usize = 8;
/// Length of a time stamp reply body.
pub const TIME_REPLY_LEN: usize = 17;
/// The tier of a runtime that is not synchronised to anything.
pub const TIER_UNSYNCED: u8 = 255;
/// The tier of a time source.
pub const TIER_ROOT: u8 = 0;
/// Tiers count up to this in holdover, then become [`TIER_UNSYNCED`].
pub const TIER_LIMIT: u8 = 32;

/// The system message code and the body's offset of a time message
/// (request or reply, by its code and body length) that the sending
/// runtime originated, in a whole OSAP packet: its route is one hop to a
/// neighbour (a `link_forward`, or a `bus_forward`, which is two bytes
/// long) and the system message. `None` for any other packet, and for one
/// forwarded for someone else (its pointer is past the first hop).
pub fn own_time_message(packet: &[u8]) -> Option<(u8, usize)> {
    use crate::packet::{Instruction, HEADER_LEN};
    if packet.first() != Some(&(HEADER_LEN as u8)) {
        return None;
    }
    let hop = Instruction::len_from_first_byte(*packet.get(HEADER_LEN)?);
    let at = HEADER_LEN + hop;
    let code = match Instruction::decode(packet.get(at..)?) {
        Ok(Instruction::SystemMsg(code)) => code,
        _ => return None,
    };
    let body = at + 1;
    match (code, packet.len().checked_sub(body)?) {
        (CODE_TIME_REQUEST, TIME_REQUEST_LEN) | (CODE_TIME_REPLY, TIME_REPLY_LEN) => {
            Some((code, body))
        }
        _ => None,
    }
}

/// Whether `packet` (a whole OSAP packet) is a time stamp request its
/// sender originated. A bus drop ends a bare-poll turn on the frame that carries
/// one, so the head's reply is not held back by the drop's next pass.
pub fn is_own_time_request(packet: &[u8]) -> bool {
    matches!(own_time_message(packet), Some((CODE_TIME_REQUEST, _)))
}

/// A time stamp reply: the request's stamp, the responder's time and tier.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimeReply {
    /// The requester's stamp, echoed back: osap-rs sends its local counter
    /// (the wire carries it as a plain u64).
    pub request_time: Instant,
    /// The responder's system time (osap-rs: at the midpoint of its
    /// turnaround).
    pub responder_time: SystemInstant,
    /// The responder's clock tier.
    pub responder_tier: u8,
}

impl TimeReply {
    /// Parses a reply body; a wrong length is an error.
    pub fn decode(body: &[u8]) -> Result<Self, CodecError> {
        let mut r = Reader::new(body);
        let reply = TimeReply {
            request_time: Instant::from_micros(r.u64()?),
            responder_time: SystemInstant::from_micros(r.u64()?),
            responder_tier: r.u8()?,
        };
        if !r.is_empty() {
            return Err(CodecError::Truncated);
        }
        Ok(reply)
    }

    /// Writes a reply body.
    pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), CodecError> {
        w.u64(self.request_time.as_micros())?;
        w.u64(self.responder_time.as_micros())?;
        w.u8(self.responder_tier)
    }
}

/// Version of the [`TimeConfig`] wire layout.
pub const TIME_CONFIG_VERSION: u8 = 1;
/// Encoded length of a [`TimeConfig`].
pub const TIME_CONFIG_LEN: usize = 54;

/// Most accepted samples a neighbour keeps for its rate fit: the
/// largest `fit_window` a [`TimeConfig`] may ask for.
pub const FIT_WINDOW_MAX: usize = 64;

/// Every tunable of clock synchronisation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimeConfig {
    /// This runtime is the time source (tier 0).
    pub root: bool,
    /// Synchronisation runs at all (requests, steering).
    pub enabled: bool,
    /// Interval between time stamp requests on each open link, µs.
    pub interval_us: u32,
    /// Each interval is lengthened or shortened by up to this, at random, µs
    /// (while bursting, by up to half the burst spacing instead: against a
    /// frame grid every phase is as likely).
    pub dither_us: u32,
    /// On a link where fewer than half the exchanges pass the filters
    /// (a USB link's frame waits), requests go this many times as often
    /// (1..=32), so enough clean samples still arrive; so they do after a
    /// sample refused as far off the fit, to tell a jump soon.
    pub burst: u8,
    /// An offset beyond this is stepped, not slewed, µs.
    pub hard_jump_us: u32,
    /// Phase gain, 1/s: a measured offset is slewed away over 1/`kp`.
    pub kp: f32,
    /// Frequency gain, 1/s: how fast phase drift that the slew does not
    /// explain is turned into a rate correction, while the fitted rate is
    /// not yet trusted (at most all of it per sample).
    pub kf: f32,
    /// Largest rate correction, parts per million (0, 10 000].
    pub max_rate_ppm: f32,
    /// The round-trip floor doubles over this many request intervals when
    /// no shorter round trip comes along (1..=65535): how long a short
    /// round trip is remembered.
    pub rtt_window: u16,
    /// A sample is used only if its round trip is at most this × the
    /// floor (≥ 1) ...
    pub rtt_factor: f32,
    /// ... plus this, µs.
    pub rtt_slack_us: u32,
    /// Accepted samples kept per neighbour for the fit (1..=64).
    pub fit_window: u8,
    /// Samples older than this leave the fit, ms.
    pub fit_max_age_ms: u32,
    /// A sample further from the fit than `residual_sigmas` × the fit's RMS
    /// residual (≥ 1) ...
    pub residual_sigmas: f32,
    /// ... and than this, µs, is rejected as a late stamp.
    pub residual_floor_us: u32,
    /// A neighbour not heard from for this long is not followed, µs.
    pub neighbour_timeout_us: u32,
}

impl Default for TimeConfig {
    fn default() -> Self {
        TimeConfig {
            root: false,
            enabled: true,
            interval_us: 50_000,
            dither_us: 5_000,
            burst: 8,
            hard_jump_us: 1_000,
            kp: 1.0,
            kf: 0.2,
            max_rate_ppm: 500.0,
            rtt_window: 256,
            rtt_factor: 1.0,
            rtt_slack_us: 40,
            fit_window: 64,
            fit_max_age_ms: 30_000,
            residual_sigmas: 4.0,
            residual_floor_us: 8,
            neighbour_timeout_us: 300_000,
        }
    }
}

/// A [`TimeConfig`] that cannot be applied.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum TimeConfigError {
    /// The body is truncated or too long.
    Codec(CodecError),
    /// The layout version is not one this runtime knows.
    Version(u8),
    /// A field is out of its allowed range (named).
    OutOfRange(&'static str),
}

impl core::fmt::Display for TimeConfigError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            TimeConfigError::Codec(e) => write!(f, "time configuration: {e}"),
            TimeConfigError::Version(v) => write!(f, "unknown time configuration version {v}"),
            TimeConfigError::OutOfRange(field) => {
                write!(f, "time configuration field {field} is out of range")
            }
        }
    }
}

impl core::error::Error for TimeConfigError {}

fn finite_at_least(v: f32, min: f32) -> bool {
    v.is_finite() && v >= min
}

impl TimeConfig {
    /// Checks every field against its allowed range.
    pub fn validate(&self) -> Result<(), TimeConfigError> {
        let checks: [(bool, &'static str); 12] = [
            (self.interval_us >= 1_000, "interval_us"),
            (self.dither_us < self.interval_us, "dither_us"),
            ((1..=32).contains(&self.burst), "burst"),
            (finite_at_least(self.kp, 0.0) && self.kp <= 100.0, "kp"),
            (finite_at_least(self.kf, 0.0) && self.kf <= 100.0, "kf"),
            (
                self.max_rate_ppm.is_finite()
                    && self.max_rate_ppm > 0.0
                    && self.max_rate_ppm <= 10_000.0,
                "max_rate_ppm",
            ),
            (self.rtt_window >= 1, "rtt_window"),
            (finite_at_least(self.rtt_factor, 1.0), "rtt_factor"),
            (
                (1..=FIT_WINDOW_MAX as u8).contains(&self.fit_window),
                "fit_window",
            ),
            (self.fit_max_age_ms >= 1, "fit_max_age_ms"),
            (
                finite_at_least(self.residual_sigmas, 1.0),
                "residual_sigmas",
            ),
            (
                self.neighbour_timeout_us >= self.interval_us,
                "neighbour_timeout_us",
            ),
        ];
        match checks.iter().find(|(ok, _)| !ok) {
            Some((_, field)) => Err(TimeConfigError::OutOfRange(field)),
            None => Ok(()),
        }
    }

    /// Writes the configuration in its wire layout.
    pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), CodecError> {
        w.u8(TIME_CONFIG_VERSION)?;
        w.u8(u8::from(self.root) | u8::from(self.enabled) << 1)?;
        w.u32(self.interval_us)?;
        w.u32(self.dither_us)?;
        w.u8(self.burst)?;
        w.u32(self.hard_jump_us)?;
        w.f32(self.kp)?;
        w.f32(self.kf)?;
        w.f32(self.max_rate_ppm)?;
        w.u16(self.rtt_window)?;
        w.f32(self.rtt_factor)?;
        w.u32(self.rtt_slack_us)?;
        w.u8(self.fit_window)?;
        w.u32(self.fit_max_age_ms)?;
        w.f32(self.residual_sigmas)?;
        w.u32(self.residual_floor_us)?;
        w.u32(self.neighbour_timeout_us)
    }

    /// Parses and validates a configuration.
    pub fn decode(body: &[u8]) -> Result<Self, TimeConfigError> {
        let mut r = Reader::new(body);
        let c = TimeConfigError::Codec;
        let version = r.u8().map_err(c)?;
        if version != TIME_CONFIG_VERSION {
            return Err(TimeConfigError::Version(version));
        }
        let flags = r.u8().map_err(c)?;
        let config = TimeConfig {
            root: flags & 1 != 0,
            enabled: flags & 2 != 0,
            interval_us: r.u32().map_err(c)?,
            dither_us: r.u32().map_err(c)?,
            burst: r.u8().map_err(c)?,
            hard_jump_us: r.u32().map_err(c)?,
            kp: r.f32().map_err(c)?,
            kf: r.f32().map_err(c)?,
            max_rate_ppm: r.f32().map_err(c)?,
            rtt_window: r.u16().map_err(c)?,
            rtt_factor: r.f32().map_err(c)?,
            rtt_slack_us: r.u32().map_err(c)?,
            fit_window: r.u8().map_err(c)?,
            fit_max_age_ms: r.u32().map_err(c)?,
            residual_sigmas: r.f32().map_err(c)?,
            residual_floor_us: r.u32().map_err(c)?,
            neighbour_timeout_us: r.u32().map_err(c)?,
        };
        if !r.is_empty() {
            return Err(TimeConfigError::Codec(CodecError::Truncated));
        }
        config.validate()?;
        Ok(config)
    }
}
