//! The runtime's clock: synchronised system time, clock tiers, and the
//! time stamp messages of the system channel.
//!
//! **System time** is a `u64` µs count derived from the runtime's local
//! free-running counter through an offset and a rate correction in fixed
//! point (Q32): `system = base_system + Δ + (Δ × rate) >> 32` with
//! `Δ = local − base_local`. Rate changes re-base the mapping at the current
//! instant, so system time is continuous and, since the rate correction is
//! clamped far below 100 %, monotonic. It only steps on a *hard jump*: the
//! first synchronisation, or an offset beyond `hard_jump_us`.
//!
//! **Synchronisation.** A runtime that is not the root sends a time stamp
//! request (system message 0) on every open link each `interval_us`. After
//! a rejected exchange the next request is dithered by a random amount, so
//! requests search over the phases of whatever schedule a link has (USB
//! frames, a neighbour's main loop); after an accepted one the next goes at
//! exactly the same phase, so a link with such a structure locks on a good
//! phase and keeps delivering clean samples.
//! Neighbours answer with their system time and tier (message 1). Each reply
//! becomes a sample of that neighbour ([`neighbour`]); the controller follows
//! the neighbours of the lowest tier, averaging their estimates: a
//! least-squares fit gives their rate against our oscillator (feed-forward)
//! and their time now, and a PI term on the remaining phase error steers the
//! rate, clamped to `max_rate_ppm`.
//!
//! **Stamps at the wire.** The request carries our local counter when it
//! starts onto the wire (the link's queue delay is added at transmit). The
//! responder stamps when the request arrived (the link's receive stamp) and
//! when the reply starts onto the wire, and sends its system time at the
//! midpoint of the two. Compared with our time at the midpoint of our send
//! and receive, that cancels the responder's turnaround exactly when the two
//! legs take equal time, as NTP's four stamps do, within the three fields the
//! wire format fixes.
//!
//! **Tiers.** The root is tier 0 (configuration; the host by default). A
//! runtime follows only neighbours whose tier is strictly below its own and
//! takes their tier + 1. If none is (the root is gone), it holds over at its
//! learned rate and its tier ages by one per interval up to
//! [`TIER_LIMIT`], then becomes [`TIER_UNSYNCED`]. Because following always
//! points down the tiers, no two runtimes can chase each other: losing the
//! root cannot make time run away. A new root (set by configuration) is
//! followed as soon as its tier is heard.
//!
//! **Authority** ([`authority`]): only neighbours on trusted links are
//! followed, only trusted links may write the clock, and no step is taken
//! while the runtime reports motion queued.

pub mod authority;
mod map;
pub mod neighbour;
mod status;

pub use authority::{Trust, SETTLED_OFFSET_US};
pub use map::TimeMap;
pub use status::{ClockStatus, ClockStatusError, SyncStats, CLOCK_STATUS_LEN, CLOCK_STATUS_LEN_V1};

use crate::codec::{CodecError, Reader, Writer};
use crate::Micros;
use neighbour::{Neighbour, Verdict, ANCHOR_MISSES, FIT_WINDOW_MAX};

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

const Q32: f32 = 4_294_967_296.0;
/// A millisecond, µs.
const MS: u64 = 1000;
/// Exchanges with a new neighbour sent at `DISCOVERY_BURST` × the request
/// rate, to learn its round-trip floor quickly.
const DISCOVERY_SAMPLES: u32 = 64;
/// See [`DISCOVERY_SAMPLES`].
const DISCOVERY_BURST: u64 = 32;
/// Requests in a row without a reply after which a link is taken to have
/// no neighbour and is asked at the plain interval only.
const SILENT_REQUESTS: u32 = 64;
/// While settling, the frequency loop's horizon, s.
const SETTLE_FLL_S: f32 = 0.5;
/// While settling, offsets above this (and above 4× the measurement noise)
/// are stepped, µs.
const SETTLE_STEP_US: f32 = 20.0;
/// Measurement noise (µs) at and above which an offset is slewed over the
/// full 1/kp; below it, proportionally faster.
const SLEW_NOISE_REF_US: f32 = 5.0;
/// Standard deviation of a rate restored by a hot start (fraction): what
/// temperature and ageing may have moved it since it was saved.
const HOT_RATE_SD: f32 = 2e-6;
/// How fast the rate's uncertainty grows without news (fraction per √s):
/// the oscillator wanders.
const RATE_WANDER_PER_SQRT_S: f32 = 5e-8;

/// A time stamp reply: the request's stamp, the responder's time and tier.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimeReply {
    /// The requester's stamp, echoed back (osap-rs sends its local counter).
    pub request_time: u64,
    /// The responder's system time (osap-rs: at the midpoint of its
    /// turnaround).
    pub responder_time: u64,
    /// The responder's clock tier.
    pub responder_tier: u8,
}

impl TimeReply {
    /// Parses a reply body; a wrong length is an error.
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

/// Version of the [`TimeConfig`] wire layout.
pub const TIME_CONFIG_VERSION: u8 = 1;
/// Encoded length of a [`TimeConfig`].
pub const TIME_CONFIG_LEN: usize = 54;

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

/// Where a clock stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum SyncState {
    /// Never synchronised: free-running on the local counter.
    Unsynced = 0,
    /// Following neighbours of a lower tier.
    Synced = 1,
    /// Was synchronised, nothing to follow now: running at the learned rate.
    Holdover = 2,
    /// The time source.
    Root = 3,
}

/// Per-link neighbour state. Only the controller (`sync`) keeps any: a
/// runtime without it answers time requests but follows no one, and its
/// firmware should not carry a few KiB of samples per link for nothing.
#[cfg(feature = "sync")]
type Neighbours<const LINKS: usize> = [Neighbour; LINKS];
#[cfg(not(feature = "sync"))]
type Neighbours<const LINKS: usize> = [Neighbour; 0];

/// The clock of a runtime with up to `LINKS` neighbours.
#[derive(Debug, Clone)]
pub struct Clock<const LINKS: usize> {
    config: TimeConfig,
    base_local: Micros,
    /// Signed, so a jump to a source whose time is younger than our
    /// counter can never wrap; reported time is clamped at 0.
    base_system: i64,
    /// Fraction of a µs carried across re-bases (Q32), so that re-basing at
    /// every update never loses time.
    base_frac: u32,
    /// Persistent rate correction: learned feed-forward + integral term.
    rate_q32: i64,
    /// Phase slew: an extra rate applied for `slew_len` µs after
    /// `base_local`, so a measured offset is removed exactly once, however
    /// long it is until the next sample.
    slew_q32: i64,
    slew_len: i64,
    /// Rate from the fits alone, without the phase terms: what holdover
    /// keeps.
    learned_q32: i64,
    /// The fitted rate has been trusted at least once since following.
    settled: bool,
    /// Variance of `learned_q32` as a fraction (fraction²): how much the
    /// frequency loop should believe a new drift measurement over it.
    rate_var: f32,
    last_steer: Option<Micros>,
    offset_us: f32,
    tier: u8,
    synced: bool,
    following: bool,
    /// Next once-per-interval housekeeping (tier aging), local time.
    next_tick: Option<Micros>,
    rng: u32,
    neighbours: Neighbours<LINKS>,
    stats: SyncStats,
    /// Links followed and taken remote writes from (local configuration).
    trust: Trust,
    /// Motion is queued or running: offsets are slewed, never stepped.
    motion_active: bool,
    /// A step was due under motion and is being slewed instead.
    deferring: bool,
}

impl<const LINKS: usize> Clock<LINKS> {
    /// A clock with the given configuration, not yet synchronised.
    pub fn new(config: TimeConfig) -> Self {
        Clock {
            config,
            base_local: 0,
            base_system: 0,
            base_frac: 0,
            rate_q32: 0,
            slew_q32: 0,
            slew_len: 0,
            learned_q32: 0,
            settled: false,
            rate_var: cold_rate_var(&config),
            last_steer: None,
            offset_us: 0.0,
            tier: if config.root {
                TIER_ROOT
            } else {
                TIER_UNSYNCED
            },
            synced: false,
            following: false,
            next_tick: None,
            rng: 0x9e37_79b9,
            neighbours: core::array::from_fn(|_| Neighbour::default()),
            stats: SyncStats::default(),
            trust: Trust::ALL,
            motion_active: false,
            deferring: false,
        }
    }

    /// Seeds the request dither (use something unique to the runtime, so
    /// neighbours do not dither in step).
    pub fn seed(&mut self, seed: u32) {
        self.rng = seed | 1;
    }

    /// The configuration.
    pub fn config(&self) -> &TimeConfig {
        &self.config
    }

    /// Replaces the configuration after validating it.
    pub fn set_config(&mut self, config: TimeConfig) -> Result<(), TimeConfigError> {
        config.validate()?;
        let was_root = self.config.root;
        self.config = config;
        if config.root {
            self.tier = TIER_ROOT;
            self.following = false;
        } else if was_root {
            // Stepping down: start looking for a source like everyone else.
            self.tier = TIER_UNSYNCED;
        }
        Ok(())
    }

    /// This runtime's clock tier.
    pub fn tier(&self) -> u8 {
        self.tier
    }

    /// Where the clock stands.
    pub fn state(&self) -> SyncState {
        if self.config.root {
            SyncState::Root
        } else if self.following && self.synced {
            SyncState::Synced
        } else if self.synced {
            SyncState::Holdover
        } else {
            SyncState::Unsynced
        }
    }

    /// System time at local time `local` (never below 0).
    pub fn system_time(&self, local: Micros) -> u64 {
        self.system_time_q32(local).0.max(0) as u64
    }

    /// Signed system time at `local` as whole µs and a Q32 fraction.
    fn system_time_q32(&self, local: Micros) -> (i64, u32) {
        self.time_map().system_time_q32(local)
    }

    /// A copy of the local-to-system mapping as it stands, for an
    /// interrupt that needs system time without the runtime.
    pub fn time_map(&self) -> TimeMap {
        TimeMap {
            base_local: self.base_local,
            base_system: self.base_system,
            base_frac: self.base_frac,
            rate_q32: self.rate_q32,
            slew_q32: self.slew_q32,
            slew_len: self.slew_len,
        }
    }

    /// Current rate correction against the local counter, ppb (the
    /// persistent part: what a hot start should restore).
    pub fn rate_ppb(&self) -> i32 {
        // Integer arithmetic: no soft-float on a Cortex-M0+ just to report.
        ((self.rate_q32.saturating_mul(1_000_000_000)) >> 32) as i32
    }

    /// Sets the rate correction (a hot start from a persisted
    /// [`rate_ppb`](Self::rate_ppb)), keeping system time continuous at
    /// local time `now`. Clamped to `max_rate_ppm`.
    pub fn set_rate_ppb(&mut self, now: Micros, ppb: i32) {
        // 2^32 / 10^9 ≈ 281 475 / 2^16 (relative error 2e-7).
        let q = (i64::from(ppb) * 281_475 + (1 << 15)) >> 16;
        let max = (self.config.max_rate_ppm * 4294.967) as i64;
        let q = q.clamp(-max, max);
        self.rebase(now, q);
        self.learned_q32 = q;
        self.rate_var = HOT_RATE_SD * HOT_RATE_SD;
    }

    /// A snapshot for monitoring.
    pub fn status(&self) -> ClockStatus {
        let followed = self.followed();
        let (mut following, mut last, mut min) = (0u8, 0u32, u32::MAX);
        for n in self.neighbours.iter().filter(|n| Some(n.tier) == followed) {
            following += 1;
            last = n.last_rtt;
            min = min.min(n.min_rtt().unwrap_or(u32::MAX));
        }
        ClockStatus {
            tier: self.tier,
            state: self.state(),
            offset_ns: (self.offset_us * 1000.0) as i64,
            rate_ppb: self.rate_ppb(),
            following,
            last_rtt_us: last,
            min_rtt_us: if min == u32::MAX { 0 } else { min },
            stats: self.stats,
            settled: self.is_settled(),
            motion_active: self.motion_active,
        }
    }

    /// The links (a bit per link index below 64) whose neighbours the
    /// clock follows now; 0 when it follows no one. With the tier, this
    /// tells a rate saved across a reboot was learned against the same
    /// source.
    pub fn followed_links(&self) -> u64 {
        let followed = self.followed();
        self.neighbours
            .iter()
            .take(64)
            .enumerate()
            .filter(|(_, n)| followed.is_some() && Some(n.tier) == followed)
            .fold(0, |mask, (i, _)| mask | 1 << i)
    }

    /// When the clock next needs a poll (local time): a request due on some
    /// link, or the once-per-interval tier housekeeping.
    pub fn next_request(&self) -> Option<Micros> {
        let links = self.neighbours.iter().filter_map(|n| n.next_request);
        links.chain(self.next_tick).min()
    }

    /// The links (a bit per link index, among those set in `open`) on which
    /// a time stamp request is due now; schedules their next ones. Also ages
    /// the tier once per interval. The root and disabled clocks never
    /// request.
    pub fn due_requests(&mut self, now: Micros, open: u64) -> u64 {
        if self.config.root || !self.config.enabled {
            self.next_tick = None;
            for n in self.neighbours.iter_mut() {
                n.next_request = None;
            }
            return 0;
        }
        let interval = u64::from(self.config.interval_us);
        match self.next_tick {
            Some(t) if now < t => {}
            Some(_) => {
                self.select(now, true);
                self.next_tick = Some(now + interval);
            }
            None => self.next_tick = Some(now + interval),
        }
        let mut due = 0u64;
        for i in 0..self.neighbours.len().min(64) {
            if open & (1 << i) == 0 {
                self.neighbours[i].next_request = None;
                continue;
            }
            let scheduled = self.neighbours[i].next_request;
            if scheduled.is_some_and(|t| now < t) {
                continue;
            }
            due |= 1 << i;
            let n = &mut self.neighbours[i];
            n.unanswered = n.unanswered.saturating_add(1);
            let burst = if n.unanswered > SILENT_REQUESTS || !self.trust.trusts(i) {
                // (An untrusted link is asked only to notice, and count,
                // a neighbour that claims a lower tier.)
                // Nobody answers: ask at the plain rate, so an idle link
                // costs next to nothing until a neighbour appears.
                1
            } else if n.seen < DISCOVERY_SAMPLES {
                // Discovery: find the round-trip floor in a fraction of a
                // second (a few kilobytes, once per neighbour).
                DISCOVERY_BURST
            } else if n.acceptance < 0.5 || n.doubting() {
                // Few exchanges pass (USB frames), or the last was far off
                // the fit: its time may have jumped, and the fit should
                // know within milliseconds, not after six intervals.
                u64::from(self.config.burst.max(1))
            } else {
                1
            };
            // Bursts keep to whole milliseconds, so a kept phase stays put
            // against a 1 ms frame grid (USB full and high speed).
            let interval = if interval >= 2 * MS {
                (interval / burst / MS).max(1) * MS
            } else {
                interval / burst
            };
            // Keep to the phase of the latest accepted exchange; without
            // one, search with dither. At the plain rate a request a host
            // timer woke late (by up to its millisecond grain) moved the
            // anchor by that much, and the next phase point may then be
            // that little from now: take the one after (bursts keep every
            // point: they hunt for a good phase against USB frames).
            let next = match self.neighbours[i].anchor {
                Some(a) if a <= now => {
                    let grain = if burst == 1 { MS.min(interval / 4) } else { 0 };
                    a + (now - a + grain) / interval * interval + interval
                }
                _ => {
                    // Search over half a spacing either way when bursting:
                    // any phase against a frame grid is equally likely.
                    // (|dither| < interval_us and the burst spacing is at
                    // most half of it: the product stays below 2^63.)
                    let d = if burst > 1 {
                        self.dither() * (interval / 2) as i64
                            / i64::from(self.config.dither_us.max(1))
                    } else {
                        self.dither()
                    };
                    now.saturating_add(interval).saturating_add_signed(d)
                }
            };
            self.neighbours[i].next_request = Some(next);
        }
        due
    }

    /// A random offset in `[-dither_us, dither_us]`, µs.
    fn dither(&mut self) -> i64 {
        // xorshift32: cheap, and only needs to break phase locking.
        let mut x = self.rng;
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        self.rng = x;
        let dither = i64::from(self.config.dither_us);
        (i64::from(x) % (2 * dither + 1)) - dither
    }

    /// Forgets the neighbour on `link` (its link closed).
    pub fn forget(&mut self, link: usize) {
        if let Some(n) = self
            .neighbours
            .get_mut(link)
            .filter(|n| n.last_heard.is_some())
        {
            n.reset();
        }
    }

    /// The lowest tier among neighbours heard from recently, if any.
    fn best_tier(&self, now: Micros) -> Option<u8> {
        self.neighbours
            .iter()
            .enumerate()
            .filter(|(i, n)| {
                self.trust.trusts(*i) && n.is_fresh(now, &self.config) && n.tier < TIER_LIMIT
            })
            .map(|(_, n)| n.tier)
            .min()
    }

    /// The tier being followed, if following.
    fn followed(&self) -> Option<u8> {
        (self.following && self.tier > 0 && self.tier < TIER_LIMIT).then(|| self.tier - 1)
    }

    /// Chooses whom to follow. `age` is set once per request interval: it
    /// is then that a runtime with nothing lower to follow ages its tier.
    fn select(&mut self, now: Micros, age: bool) {
        if self.config.root {
            self.tier = TIER_ROOT;
            self.following = false;
            return;
        }
        match self.best_tier(now) {
            Some(best) if best < self.tier && best + 1 < TIER_LIMIT => {
                if !self.following {
                    self.last_steer = None;
                    self.settled = false;
                }
                self.tier = best + 1;
                self.following = true;
            }
            _ => {
                if self.following {
                    // Holdover: keep the learned rate, drop the phase terms.
                    self.rebase(now, self.learned_q32);
                    self.following = false;
                }
                if age && self.tier != TIER_UNSYNCED {
                    self.tier = if self.tier + 1 >= TIER_LIMIT {
                        TIER_UNSYNCED
                    } else {
                        self.tier + 1
                    };
                }
            }
        }
    }

    /// Takes in a time stamp reply that arrived on `link` at local time
    /// `received` (the link's wire stamp when it has one), then steers.
    pub fn on_reply(&mut self, link: usize, reply: &TimeReply, received: Micros) {
        self.stats.samples = self.stats.samples.wrapping_add(1);
        if !self.trust.trusts(link) {
            // Not a source this runtime may follow, whatever it claims; a
            // claim that would have been followed is counted.
            if reply.responder_tier < self.tier {
                self.count_untrusted();
            }
            return;
        }
        let config = self.config;
        let prior = self.learned_q32 as f32 / Q32;
        let Some(n) = self.neighbours.get_mut(link) else {
            return;
        };
        let verdict = n.add(
            reply.request_time,
            received,
            reply.responder_time,
            reply.responder_tier,
            &config,
            prior,
        );
        // Hold a phase only once the floor is known: early exchanges are
        // accepted against a floor that is still too high.
        if verdict == Verdict::Accepted && n.seen >= 16 {
            n.anchor = Some(reply.request_time);
            n.anchor_misses = 0;
        } else if verdict == Verdict::RejectedRtt {
            n.anchor_misses = n.anchor_misses.saturating_add(1);
            if n.anchor_misses >= ANCHOR_MISSES {
                n.anchor = None;
            }
        }
        let hit = if verdict == Verdict::Accepted {
            1.0
        } else {
            0.0
        };
        n.acceptance += 0.1 * (hit - n.acceptance);
        let s = &mut self.stats;
        let counter = match verdict {
            Verdict::Accepted => &mut s.accepted,
            Verdict::RejectedRtt => &mut s.rejected_rtt,
            Verdict::RejectedResidual => &mut s.rejected_residual,
            Verdict::Bogus => &mut s.bogus,
        };
        *counter = counter.wrapping_add(1);
        if config.root || !config.enabled {
            return;
        }
        self.select(received, false);
        let bucket = self.learn_rate_from_envelope(link, received);
        if (verdict == Verdict::Accepted || bucket) && self.followed() == Some(reply.responder_tier)
        {
            self.steer(received);
        }
    }

    /// While the rate is not yet known to a few ppm, takes a new rate
    /// measurement from the followed neighbour's one-way envelope
    /// ([`Neighbour::new_envelope_slope`]), once per finished bucket, weighed
    /// against what is known; the slew under way goes on. Returns whether a
    /// bucket of the followed neighbour's envelopes finished (the clock then
    /// steers, whether or not the exchange passed the filters).
    fn learn_rate_from_envelope(&mut self, link: usize, now: Micros) -> bool {
        if !self.synced {
            return false;
        }
        let Some(tier) = self.followed() else {
            return false;
        };
        let Some(n) = self.neighbours.get_mut(link).filter(|n| n.tier == tier) else {
            return false;
        };
        let Some(fit) = n.new_envelope_slope(now) else {
            return false;
        };
        let Some((slope, stderr)) = fit.filter(|_| self.rate_var > ENVELOPE_RATE_VAR_LIMIT) else {
            return true;
        };
        // Successive slopes share most of their buckets: count each as
        // worth a quarter of its stated precision.
        let var = 4.0 * stderr * stderr;
        let learned = self.learned_q32 as f32 / Q32;
        let gain = self.rate_var / (self.rate_var + var);
        let rate = self.clamp_rate(learned + gain * (slope - learned));
        self.rate_var *= 1.0 - gain;
        self.learned_q32 = rate;
        let (slew_q32, left) = (
            self.slew_q32,
            self.slew_len - now.wrapping_sub(self.base_local) as i64,
        );
        self.rebase(now, rate);
        if left > 0 {
            self.slew_q32 = slew_q32;
            self.slew_len = left;
        }
        true
    }

    fn clamp_rate(&self, fraction: f32) -> i64 {
        let max = self.config.max_rate_ppm * 1e-6;
        round(fraction.clamp(-max, max) * Q32)
    }

    /// Re-bases the mapping at local time `now` with a new rate and no
    /// slew, keeping system time continuous.
    fn rebase(&mut self, now: Micros, rate_q32: i64) {
        (self.base_system, self.base_frac) = self.system_time_q32(now);
        self.base_local = now;
        self.rate_q32 = rate_q32;
        self.slew_q32 = 0;
        self.slew_len = 0;
    }

    /// Our system time minus our local counter at `now`, in half µs.
    fn own_y_half(&self, now: Micros) -> i64 {
        self.system_time_q32(now)
            .0
            .wrapping_sub(now as i64)
            .saturating_mul(2)
    }

    fn steer(&mut self, now: Micros) {
        let Some(tier) = self.followed() else {
            return;
        };
        let own = self.own_y_half(now);
        let prior = self.learned_q32 as f32 / Q32;
        let (mut offset_sum, mut offsets) = (0f32, 0u8);
        let (mut slope_sum, mut slopes) = (0f32, 0u8);
        let (mut noise, mut slew_noise) = (0f32, 0f32);
        for n in self.neighbours.iter() {
            if n.tier != tier || !n.is_fresh(now, &self.config) {
                continue;
            }
            let est = n.estimate(now, &self.config, prior);
            if let Some(slope) = est.and_then(|e| e.slope) {
                slope_sum += slope;
                slopes += 1;
            }
            let fit = est.map(|e| {
                let offset = e.y_ref_half.saturating_sub(own) as f32 * 0.5 + e.y_rel;
                (offset, e.jitter, e.phase_noise)
            });
            let envelope = n
                .envelope_offset(now, prior, &self.config)
                .map(|(v, rel, sigma)| {
                    let offset = v.saturating_mul(2).saturating_sub(own) as f32 * 0.5 + rel;
                    (offset, sigma, sigma)
                });
            // Over a link where most exchanges wait (USB frames), the few
            // clean ones are not symmetric, and while requests are held at
            // a phase their bias drifts with it; the prompt envelope's does
            // not. There the envelope is followed while settling, when the
            // fit has heard nothing clean for a while, and when the two
            // disagree by more than their noises allow. (Acceptance starts
            // at 0: it says something once the discovery burst has run.)
            let bursting = n.seen >= DISCOVERY_SAMPLES && n.acceptance < 0.5;
            let stale = est.is_none_or(|e| now.saturating_sub(e.newest) > ENVELOPE_STALE_US);
            let (offset, jitter, phase_noise) = match (fit, envelope) {
                (Some(f), Some(e))
                    if bursting
                        && (stale || !self.settled || (f.0 - e.0).abs() > 3.0 * (f.1 + e.1)) =>
                {
                    e
                }
                (Some(f), _) => f,
                (None, Some(e)) => e,
                (None, None) => continue,
            };
            offset_sum += offset;
            offsets += 1;
            noise = noise.max(jitter);
            slew_noise = slew_noise.max(phase_noise);
        }
        let offset = offset_sum / f32::from(offsets.max(1));
        // Garbage from the wire can make the sums overflow; never steer on it.
        if offsets == 0 || !offset.is_finite() || !slope_sum.is_finite() {
            return;
        }
        self.offset_us = offset;
        // Still settling (the fitted rate has never been trusted): this is
        // the first synchronisation, and a clear offset is stepped away
        // rather than slewed at the rate clamp for a second.
        let settling = !self.settled && offset.abs() > (4.0 * noise).max(SETTLE_STEP_US);
        if slopes > 0 {
            self.settled = true;
        }
        let jump = !self.synced || settling || offset.abs() > self.config.hard_jump_us as f32;
        if !jump {
            self.deferring = false;
        } else if self.may_step() {
            self.rebase(now, self.learned_q32);
            self.base_system = self.base_system.saturating_add(round(offset));
            self.synced = true;
            self.offset_us = 0.0;
            self.last_steer = Some(now);
            self.stats.jumps = self.stats.jumps.wrapping_add(1);
            return;
        }
        let cfg = self.config;
        let mut learned = self.learned_q32 as f32 / Q32;
        if slopes > 0 {
            // A trusted fit of the neighbours' rate against our counter is
            // exactly the rate our system time needs.
            learned = slope_sum / f32::from(slopes);
            self.rate_var = self.rate_var.min(MAX_SLOPE_VAR);
        } else if let Some(last) = self.last_steer {
            // Frequency loop: what the last slew does not explain of the
            // offset is drift, i.e. rate error. Over short gaps take kf of it
            // per second; over long ones at most all of it.
            let dt = now.saturating_sub(last) as f32 * 1e-6;
            let drift = offset - self.slew_remaining(now);
            if dt > 0.0 {
                // While settling, learn fast (half a second); afterwards
                // the fit leads and this only trims, over 1/kf.
                let horizon = if self.settled {
                    1.0 / cfg.kf.max(1e-3)
                } else {
                    SETTLE_FLL_S
                };
                // Believe the measurement only as far as its noise allows
                // against what is already known of the rate: two offsets
                // `noise` apart over `dt` say little about a rate known to a
                // ppm (a hot start, or a long fit), much about one not known
                // at all (a cold start).
                self.rate_var += RATE_WANDER_PER_SQRT_S * RATE_WANDER_PER_SQRT_S * dt;
                let meas_sd = noise.max(0.5) * 1e-6 * core::f32::consts::SQRT_2 / dt;
                let kalman = self.rate_var / (self.rate_var + meas_sd * meas_sd);
                let gain = kalman.min(dt / dt.max(horizon));
                learned += gain * drift * 1e-6 / dt;
                self.rate_var *= 1.0 - gain;
            }
        }
        self.last_steer = Some(now);
        self.learned_q32 = self.clamp_rate(learned);
        self.rebase(now, self.learned_q32);
        // Remove the offset by slewing, then run at the learned rate again: a
        // slew, not a rate held until the next sample, since samples may be
        // seconds apart. Precise measurements are acted on within one
        // interval; noisy ones over up to 1/kp; never faster than the clamp
        // leaves room for. A step deferred under motion is slewed whatever
        // kp says, as fast as the clamp allows.
        if cfg.kp > 0.0 || self.deferring {
            let max = cfg.max_rate_ppm * 1e-6;
            let room = (max - learned.abs()).max(0.1 * max);
            let settle = if self.deferring {
                0.0
            } else {
                (1e6 / cfg.kp) * (slew_noise / SLEW_NOISE_REF_US).min(1.0)
            };
            let duration_us = settle.max(cfg.interval_us as f32).max(offset.abs() / room);
            self.slew_q32 = round(offset / duration_us * Q32);
            self.slew_len = duration_us as i64;
        }
    }

    /// The part of the current slew not yet applied at `now`, µs.
    fn slew_remaining(&self, now: Micros) -> f32 {
        let elapsed = now.wrapping_sub(self.base_local) as i64;
        let left = (self.slew_len - elapsed.clamp(0, self.slew_len)) as f32;
        left * self.slew_q32 as f32 / Q32
    }
}

/// Rate variance (fraction², here (5 ppm)²) below which the envelope's
/// rough slope no longer adds anything the fit does not.
const ENVELOPE_RATE_VAR_LIMIT: f32 = 5e-6 * 5e-6;

/// Over a bursting link, a fit whose newest sample is older than this is
/// stale: the one-way envelope is followed instead, µs.
const ENVELOPE_STALE_US: u64 = 2_000_000;

/// Variance of a trusted fitted rate (see the fit's standard-error bound).
const MAX_SLOPE_VAR: f32 = 2e-6 * 2e-6;

/// The rate's variance before anything is known: uniform over the clamp.
fn cold_rate_var(config: &TimeConfig) -> f32 {
    let max = config.max_rate_ppm * 1e-6;
    max * max / 3.0
}

/// Rounds to the nearest integer (`f32::round` needs `std`).
fn round(v: f32) -> i64 {
    if v >= 0.0 {
        (v + 0.5) as i64
    } else {
        (v - 0.5) as i64
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
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
            kp: f32::NAN,
            ..cfg
        };
        assert_eq!(bad.validate(), Err(TimeConfigError::OutOfRange("kp")));
        let bad = TimeConfig {
            dither_us: 60_000,
            ..cfg
        };
        assert_eq!(
            bad.validate(),
            Err(TimeConfigError::OutOfRange("dither_us"))
        );
    }

    #[test]
    fn a_link_nobody_answers_is_asked_at_the_plain_rate() {
        let cfg = TimeConfig::default();
        let mut c: Clock<1> = Clock::new(cfg);
        let mut now = 0;
        let mut sent = std::vec::Vec::new();
        while now < 2_000_000 {
            if c.due_requests(now, 1) != 0 {
                sent.push(now);
            }
            now += 100;
        }
        // A discovery burst first, then one request per interval.
        let burst = sent.iter().filter(|&&t| t < 100_000).count();
        assert!(
            burst >= SILENT_REQUESTS as usize,
            "{burst} requests in the burst"
        );
        let late: std::vec::Vec<_> = sent.iter().filter(|&&t| t > 500_000).collect();
        for w in late.windows(2) {
            let gap = w[1] - w[0];
            assert!(
                gap + u64::from(2 * cfg.dither_us) >= u64::from(cfg.interval_us),
                "requests {gap} µs apart with no one answering"
            );
        }
        assert!(late.len() < 40, "{} requests in 1.5 s", late.len());
    }

    #[test]
    fn a_copied_map_reads_as_the_clock_does() {
        let mut c: Clock<1> = Clock::new(TimeConfig::default());
        assert_eq!(c.time_map(), TimeMap::IDENTITY);
        c.set_rate_ppb(1_000_000, 73_000);
        // A slew in progress as well, so both terms of the map are used.
        c.slew_q32 = 1 << 22;
        c.slew_len = 250_000;
        let map = c.time_map();
        for t in [
            0, 999_999, 1_000_000, 1_100_000, 1_250_000, 1_250_001, 9_000_000,
        ] {
            assert_eq!(map.system_time(t), c.system_time(t), "at {t}");
        }
    }

    #[test]
    fn mapping_is_continuous_across_rate_changes() {
        let mut c: Clock<1> = Clock::new(TimeConfig::default());
        assert_eq!(c.system_time(1_000_000), 1_000_000);
        c.set_rate_ppb(1_000_000, 100_000); // +100 ppm
        assert_eq!(c.system_time(1_000_000), 1_000_000);
        assert_eq!(c.system_time(2_000_000), 2_000_100);
        c.set_rate_ppb(2_000_000, -50_000);
        assert_eq!(c.system_time(2_000_000), 2_000_100);
        assert_eq!(c.system_time(3_000_000), 3_000_050);
        assert!((c.rate_ppb() + 50_000).abs() < 5);
    }

    #[test]
    fn rate_is_clamped() {
        let mut c: Clock<1> = Clock::new(TimeConfig::default());
        c.set_rate_ppb(0, 900_000_000);
        assert!((c.rate_ppb() - 500_000).abs() < 50);
    }

    /// A neighbour at tier 0 whose clock is `offset` ahead and `ppm` fast;
    /// exchanges with a symmetric round trip. Returns our error after each
    /// exchange, µs.
    #[cfg(feature = "sync")]
    fn follow(c: &mut Clock<2>, offset: f64, ppm: f64, steps: u64) -> f64 {
        let mut err = 0.0;
        for i in 0..steps {
            let sent = 10_000 + i * 50_000;
            let rtt = 200;
            let mid = sent as f64 + rtt as f64 / 2.0;
            let theirs = mid + offset + mid * ppm * 1e-6;
            let reply = TimeReply {
                request_time: sent,
                responder_time: theirs.round() as u64,
                responder_tier: 0,
            };
            c.on_reply(0, &reply, sent + rtt);
            let now = sent + rtt;
            let truth = now as f64 + offset + now as f64 * ppm * 1e-6;
            err = c.system_time(now) as f64 - truth;
            if std::env::var_os("CLOCK_DEBUG").is_some() {
                std::println!("{i} err {err:.2} rate {} off {}", c.rate_ppb(), c.offset_us);
            }
        }
        err
    }

    #[test]
    #[cfg(feature = "sync")]
    fn converges_on_offset_and_rate() {
        let mut c: Clock<2> = Clock::new(TimeConfig::default());
        let err = follow(&mut c, 12_345.0, 80.0, 60);
        assert_eq!(c.tier(), 1);
        assert_eq!(c.state(), SyncState::Synced);
        assert!(err.abs() < 2.0, "error {err} µs after 3 s");
        assert!(
            (c.rate_ppb() - 80_000).abs() < 2_000,
            "rate {}",
            c.rate_ppb()
        );
        assert_eq!(c.status().stats.jumps, 1);
    }

    #[test]
    #[cfg(feature = "sync")]
    fn a_sample_far_off_the_fit_brings_the_next_request_forward() {
        let mut c: Clock<2> = Clock::new(TimeConfig::default());
        // Past discovery, every exchange accepted: one request an interval,
        // at the phase of the latest.
        follow(&mut c, 0.0, 0.0, 80);
        let now = 10_000 + 80 * 50_000;
        c.next_tick = Some(now + 1_000_000);
        assert_eq!(c.due_requests(now, 0b1), 0b1);
        assert_eq!(c.neighbours[0].next_request, Some(now + 50_000));
        // Its time seems to have moved by 40 µs: refused, and asked again
        // within a burst spacing rather than an interval.
        let reply = TimeReply {
            request_time: now,
            responder_time: now + 100 + 40,
            responder_tier: 0,
        };
        c.on_reply(0, &reply, now + 200);
        assert_eq!(c.status().stats.rejected_residual, 1);
        let due = now + 50_000;
        assert_eq!(c.due_requests(due, 0b1), 0b1);
        let next = c.neighbours[0].next_request.unwrap();
        assert!(next - due <= 6_000, "next request {} µs later", next - due);
        // Accepted again: back to the interval.
        let reply = TimeReply {
            request_time: due,
            responder_time: due + 100,
            responder_tier: 0,
        };
        c.on_reply(0, &reply, due + 200);
        assert_eq!(c.due_requests(next, 0b1), 0b1);
        assert_eq!(c.neighbours[0].next_request, Some(due + 50_000));
    }

    #[test]
    fn the_widest_configured_dither_cannot_overflow() {
        let cfg = TimeConfig {
            interval_us: u32::MAX,
            dither_us: u32::MAX - 1,
            ..TimeConfig::default()
        };
        let mut c: Clock<2> = Clock::new(cfg);
        c.seed(0xdead_beef);
        // Link 1 past discovery and clean: requests at the interval, with
        // the configured dither; link 0 bursting: half the burst spacing.
        c.neighbours[1].seen = 100;
        c.neighbours[1].acceptance = 1.0;
        let mut now = 0;
        for _ in 0..64 {
            c.due_requests(now, 0b11);
            now = c.next_request().unwrap_or(now + 1).max(now + 1);
        }
    }

    #[test]
    #[cfg(feature = "sync")]
    fn tier_ages_in_holdover_and_never_follows_upward() {
        let mut c: Clock<2> = Clock::new(TimeConfig::default());
        follow(&mut c, 0.0, 0.0, 5);
        assert_eq!(c.tier(), 1);
        // The neighbour falls silent: after the timeout, each request round
        // ages the tier until it reads as unsynced.
        let mut now = 10_000 + 5 * 50_000 + 400_000;
        let mut rounds = 0;
        while c.tier() != TIER_UNSYNCED {
            c.next_tick = Some(now);
            assert_eq!(c.due_requests(now, 0b1), 0b1);
            assert_eq!(c.state(), SyncState::Holdover);
            now += 50_000;
            rounds += 1;
            assert!(rounds < 64, "tier never gave up");
        }
        // A neighbour at a higher tier than ours is never followed.
        let reply = TimeReply {
            request_time: now,
            responder_time: now + 5_000,
            responder_tier: 3,
        };
        let before = c.system_time(now + 100);
        c.tier = 2;
        c.on_reply(0, &reply, now + 100);
        assert_eq!(c.tier(), 2);
        assert_eq!(c.system_time(now + 100), before);
    }
}
