//! The clock's status as the netresponder reports it (key 0x0c): tier,
//! state, offset, rate, round trips and sample counts.

use super::SyncState;
use crate::codec::{CodecError, Reader, Writer};

/// Counts of what the synchroniser did with its samples.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SyncStats {
    /// Replies received.
    pub samples: u32,
    /// Samples used.
    pub accepted: u32,
    /// Rejected: round trip too long.
    pub rejected_rtt: u32,
    /// Rejected: too far from the fit (a late stamp).
    pub rejected_residual: u32,
    /// Replies that were not answers to our requests.
    pub bogus: u32,
    /// Hard jumps of system time.
    pub jumps: u32,
    /// Time claims ignored because they came over a link this runtime does
    /// not trust: replies of a lower tier than ours, and remote writes of
    /// the time configuration or clock rate (see [`Trust`](super::Trust)).
    pub untrusted: u32,
    /// Times a hard jump was due while motion was queued and the offset
    /// was slewed at the rate clamp instead (counted once per episode).
    pub deferred_steps: u32,
}

/// A snapshot of the clock, readable over the netresponder.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClockStatus {
    /// Current tier.
    pub tier: u8,
    /// Current state.
    pub state: SyncState,
    /// Latest estimate of the followed neighbours' time minus ours, ns.
    pub offset_ns: i64,
    /// Current rate correction against the local counter, parts per billion.
    pub rate_ppb: i32,
    /// Neighbours followed (those of the best tier).
    pub following: u8,
    /// Latest round trip to a followed neighbour, µs.
    pub last_rtt_us: u32,
    /// Smallest recent round trip to a followed neighbour, µs.
    pub min_rtt_us: u32,
    /// Sample counts.
    pub stats: SyncStats,
    /// Fit for motion: the root, or following with a trusted fitted rate,
    /// an offset within [`SETTLED_OFFSET_US`](super::SETTLED_OFFSET_US) and
    /// no deferred step outstanding.
    pub settled: bool,
    /// The runtime reports queued or running motion (time steps are
    /// deferred and slewed while it does).
    pub motion_active: bool,
}

/// Encoded length of a [`ClockStatus`].
pub const CLOCK_STATUS_LEN: usize = 1 + 1 + 8 + 4 + 1 + 4 + 4 + 6 * 4 + 1 + 2 * 4;

/// Encoded length of the first layout (before `flags`, `untrusted` and
/// `deferred_steps` were appended), which [`ClockStatus::decode`] still
/// reads.
pub const CLOCK_STATUS_LEN_V1: usize = 1 + 1 + 8 + 4 + 1 + 4 + 4 + 6 * 4;

/// A clock status that cannot be read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum ClockStatusError {
    /// The body is truncated or too long.
    Codec(CodecError),
    /// The state byte is not one this runtime knows.
    State(u8),
}

impl core::fmt::Display for ClockStatusError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ClockStatusError::Codec(e) => write!(f, "clock status: {e}"),
            ClockStatusError::State(s) => write!(f, "clock status: unknown state {s}"),
        }
    }
}

impl core::error::Error for ClockStatusError {}

impl From<CodecError> for ClockStatusError {
    fn from(e: CodecError) -> Self {
        ClockStatusError::Codec(e)
    }
}

const FLAG_SETTLED: u8 = 1;
const FLAG_MOTION: u8 = 2;

impl ClockStatus {
    /// Writes the status in its wire layout.
    pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), CodecError> {
        w.u8(self.tier)?;
        w.u8(self.state as u8)?;
        w.i64(self.offset_ns)?;
        w.u32(self.rate_ppb as u32)?;
        w.u8(self.following)?;
        w.u32(self.last_rtt_us)?;
        w.u32(self.min_rtt_us)?;
        let s = &self.stats;
        for v in [
            s.samples,
            s.accepted,
            s.rejected_rtt,
            s.rejected_residual,
            s.bogus,
            s.jumps,
        ] {
            w.u32(v)?;
        }
        let flags = if self.settled { FLAG_SETTLED } else { 0 }
            | if self.motion_active { FLAG_MOTION } else { 0 };
        w.u8(flags)?;
        w.u32(s.untrusted)?;
        w.u32(s.deferred_steps)
    }

    /// Parses a status. The first layout (a runtime built before the
    /// appended fields) reads as not settled, with those counters at 0.
    pub fn decode(body: &[u8]) -> Result<Self, ClockStatusError> {
        let mut r = Reader::new(body);
        let tier = r.u8()?;
        let state = match r.u8()? {
            0 => SyncState::Unsynced,
            1 => SyncState::Synced,
            2 => SyncState::Holdover,
            3 => SyncState::Root,
            s => return Err(ClockStatusError::State(s)),
        };
        let mut status = ClockStatus {
            tier,
            state,
            offset_ns: r.i64()?,
            rate_ppb: r.u32()? as i32,
            following: r.u8()?,
            last_rtt_us: r.u32()?,
            min_rtt_us: r.u32()?,
            stats: SyncStats {
                samples: r.u32()?,
                accepted: r.u32()?,
                rejected_rtt: r.u32()?,
                rejected_residual: r.u32()?,
                bogus: r.u32()?,
                jumps: r.u32()?,
                untrusted: 0,
                deferred_steps: 0,
            },
            settled: false,
            motion_active: false,
        };
        if r.is_empty() {
            return Ok(status);
        }
        let flags = r.u8()?;
        status.settled = flags & FLAG_SETTLED != 0;
        status.motion_active = flags & FLAG_MOTION != 0;
        status.stats.untrusted = r.u32()?;
        status.stats.deferred_steps = r.u32()?;
        if !r.is_empty() {
            return Err(ClockStatusError::Codec(CodecError::Truncated));
        }
        Ok(status)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn example() -> ClockStatus {
        ClockStatus {
            tier: 2,
            state: SyncState::Synced,
            offset_ns: -1_500,
            rate_ppb: 42_000,
            following: 1,
            last_rtt_us: 310,
            min_rtt_us: 298,
            stats: SyncStats {
                samples: 1200,
                accepted: 1150,
                rejected_rtt: 40,
                rejected_residual: 9,
                bogus: 1,
                jumps: 1,
                untrusted: 7,
                deferred_steps: 2,
            },
            settled: true,
            motion_active: true,
        }
    }

    #[test]
    fn round_trip_and_the_first_layout() {
        let s = example();
        let mut buf = [0u8; 64];
        let mut w = Writer::new(&mut buf);
        s.encode(&mut w).unwrap();
        let n = w.len();
        assert_eq!(n, CLOCK_STATUS_LEN);
        assert_eq!(ClockStatus::decode(&buf[..n]), Ok(s));
        // A runtime of the first layout: no flags, no new counters.
        let old = ClockStatus::decode(&buf[..CLOCK_STATUS_LEN_V1]).unwrap();
        assert!(!old.settled && !old.motion_active);
        assert_eq!(old.stats.untrusted, 0);
        assert_eq!(old.tier, 2);
        // Anything else is an error, never a panic.
        for len in (0..n).filter(|&l| l != CLOCK_STATUS_LEN_V1) {
            assert!(ClockStatus::decode(&buf[..len]).is_err(), "length {len}");
        }
        buf[1] = 9;
        assert_eq!(
            ClockStatus::decode(&buf[..n]),
            Err(ClockStatusError::State(9))
        );
    }
}
