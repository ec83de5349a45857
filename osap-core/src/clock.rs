//! The runtime's clock: tiers, the time-controller configuration, and the
//! time stamp messages of the system channel.
//!
//! Time stamp requests and replies are system messages (code 0 and 1). A
//! runtime answers every request with its system time and clock tier; replies
//! it receives become [`TimeSample`]s, the raw material of clock sync.
//!
//! [`TimeConfig`] holds every tunable of the synchronisation controller and
//! is readable and writable over the netresponder.

use crate::codec::{CodecError, Reader, Writer};
use crate::Micros;

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

/// A time stamp reply: the request's stamp, the responder's time and tier.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimeReply {
    /// The requester's clock when it sent the request, echoed back.
    pub request_time: u64,
    /// The responder's system time when it replied.
    pub responder_time: u64,
    /// The responder's clock tier.
    pub responder_tier: u8,
}

impl TimeReply {
    /// Parses a reply body; extra trailing bytes are an error.
    pub fn decode(body: &[u8]) -> Result<Self, CodecError> {
        let mut r = Reader::new(body);
        let reply = TimeReply {
            request_time: r.u64()?,
            responder_time: r.u64()?,
            responder_tier: r.u8()?,
        };
        if !r.is_empty() {
            return Err(CodecError::Truncated);
        }
        Ok(reply)
    }

    /// Writes a reply body.
    pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), CodecError> {
        w.u64(self.request_time)?;
        w.u64(self.responder_time)?;
        w.u8(self.responder_tier)
    }
}

/// One round trip to a neighbour, measured when its reply arrived.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimeSample {
    /// Local system time when the reply arrived.
    pub at: Micros,
    /// Round-trip time in µs.
    pub rtt: u64,
    /// Neighbour's time minus ours, assuming symmetric legs, in µs.
    pub offset: i64,
    /// Neighbour's tier.
    pub tier: u8,
}

impl TimeSample {
    /// Computes a sample from a reply received at local system time `now`.
    /// Returns `None` if the echoed stamp is in our future (not our request).
    pub fn from_reply(reply: &TimeReply, now: Micros) -> Option<Self> {
        let rtt = now.checked_sub(reply.request_time)?;
        let midpoint = reply.request_time + rtt / 2;
        let offset = (reply.responder_time as i128 - midpoint as i128)
            .clamp(i64::MIN as i128, i64::MAX as i128) as i64;
        Some(TimeSample {
            at: now,
            rtt,
            offset,
            tier: reply.responder_tier,
        })
    }
}

/// Version of the [`TimeConfig`] wire layout.
pub const TIME_CONFIG_VERSION: u8 = 1;
/// Encoded length of a [`TimeConfig`].
pub const TIME_CONFIG_LEN: usize = 31;

/// Tunables of clock synchronisation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimeConfig {
    /// This runtime is a time source (tier 0).
    pub root: bool,
    /// Synchronisation runs at all.
    pub enabled: bool,
    /// Interval between time stamp requests to each open link, µs.
    pub interval_us: u32,
    /// An offset larger than this is corrected by a jump, not slewed, µs.
    pub hard_jump_us: u32,
    /// Proportional gain of the rate controller.
    pub kp: f32,
    /// Integral gain of the rate controller.
    pub ki: f32,
    /// Largest rate correction the controller may apply, parts per million.
    pub max_rate_ppm: f32,
    /// Weight of a new offset sample in the smoothed offset (0, 1].
    pub offset_alpha: f32,
    /// Samples whose RTT exceeds the window's minimum by this factor are
    /// rejected as delayed (≥ 1).
    pub outlier_rtt_factor: f32,
    /// Number of recent samples kept per neighbour for minimum-RTT filtering.
    pub rtt_window: u8,
}

impl Default for TimeConfig {
    fn default() -> Self {
        TimeConfig {
            root: false,
            enabled: true,
            interval_us: 50_000,
            hard_jump_us: 10_000,
            kp: 0.5,
            ki: 0.05,
            max_rate_ppm: 500.0,
            offset_alpha: 0.25,
            outlier_rtt_factor: 1.5,
            rtt_window: 8,
        }
    }
}

/// A [`TimeConfig`] that cannot be applied.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimeConfigError {
    /// The body is truncated or too long.
    Codec(CodecError),
    /// The layout version is not one this runtime knows.
    Version(u8),
    /// A field is out of its allowed range (named).
    OutOfRange(&'static str),
}

impl TimeConfig {
    /// Checks every field against its allowed range.
    pub fn validate(&self) -> Result<(), TimeConfigError> {
        let bad = TimeConfigError::OutOfRange;
        if self.interval_us < 1_000 {
            return Err(bad("interval_us"));
        }
        if !(self.kp.is_finite() && self.kp >= 0.0) {
            return Err(bad("kp"));
        }
        if !(self.ki.is_finite() && self.ki >= 0.0) {
            return Err(bad("ki"));
        }
        if !(self.max_rate_ppm.is_finite()
            && self.max_rate_ppm > 0.0
            && self.max_rate_ppm <= 10_000.0)
        {
            return Err(bad("max_rate_ppm"));
        }
        if !(self.offset_alpha > 0.0 && self.offset_alpha <= 1.0) {
            return Err(bad("offset_alpha"));
        }
        if !(self.outlier_rtt_factor.is_finite() && self.outlier_rtt_factor >= 1.0) {
            return Err(bad("outlier_rtt_factor"));
        }
        if self.rtt_window == 0 || self.rtt_window > 32 {
            return Err(bad("rtt_window"));
        }
        Ok(())
    }

    /// Writes the configuration in its wire layout.
    pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), CodecError> {
        w.u8(TIME_CONFIG_VERSION)?;
        w.u8(u8::from(self.root) | u8::from(self.enabled) << 1)?;
        w.u32(self.interval_us)?;
        w.u32(self.hard_jump_us)?;
        w.f32(self.kp)?;
        w.f32(self.ki)?;
        w.f32(self.max_rate_ppm)?;
        w.f32(self.offset_alpha)?;
        w.f32(self.outlier_rtt_factor)?;
        w.u8(self.rtt_window)
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
            hard_jump_us: r.u32().map_err(c)?,
            kp: r.f32().map_err(c)?,
            ki: r.f32().map_err(c)?,
            max_rate_ppm: r.f32().map_err(c)?,
            offset_alpha: r.f32().map_err(c)?,
            outlier_rtt_factor: r.f32().map_err(c)?,
            rtt_window: r.u8().map_err(c)?,
        };
        if !r.is_empty() {
            return Err(TimeConfigError::Codec(CodecError::Truncated));
        }
        config.validate()?;
        Ok(config)
    }
}

/// The runtime's clock: its configuration and current tier.
///
/// System time is the local clock until synchronisation is running; the
/// controller that disciplines it lives with the clock-sync code.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Clock {
    config: TimeConfig,
}

impl Clock {
    /// A clock with the given configuration.
    pub fn new(config: TimeConfig) -> Self {
        Clock { config }
    }

    /// The configuration.
    pub fn config(&self) -> &TimeConfig {
        &self.config
    }

    /// Replaces the configuration after validating it.
    pub fn set_config(&mut self, config: TimeConfig) -> Result<(), TimeConfigError> {
        config.validate()?;
        self.config = config;
        Ok(())
    }

    /// This runtime's clock tier.
    pub fn tier(&self) -> u8 {
        if self.config.root {
            TIER_ROOT
        } else {
            TIER_UNSYNCED
        }
    }

    /// System time at local time `local`.
    pub fn system_time(&self, local: Micros) -> Micros {
        local
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_round_trip_and_validation() {
        let cfg = TimeConfig {
            root: true,
            ..TimeConfig::default()
        };
        let mut buf = [0u8; 64];
        let mut w = Writer::new(&mut buf);
        cfg.encode(&mut w).unwrap();
        assert_eq!(w.len(), TIME_CONFIG_LEN);
        let n = w.len();
        assert_eq!(TimeConfig::decode(&buf[..n]), Ok(cfg));
        assert_eq!(
            TimeConfig::decode(&buf[..n - 1]),
            Err(TimeConfigError::Codec(CodecError::Truncated))
        );
        let bad = TimeConfig {
            offset_alpha: f32::NAN,
            ..cfg
        };
        assert_eq!(
            bad.validate(),
            Err(TimeConfigError::OutOfRange("offset_alpha"))
        );
    }

    #[test]
    fn sample_assumes_symmetric_legs() {
        let reply = TimeReply {
            request_time: 1_000,
            responder_time: 5_050,
            responder_tier: 0,
        };
        let s = TimeSample::from_reply(&reply, 1_100).unwrap();
        assert_eq!(s.rtt, 100);
        assert_eq!(s.offset, 4_000);
        assert!(TimeSample::from_reply(&reply, 999).is_none());
    }
}
