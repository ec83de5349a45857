//! The runtime's clock: synchronised system time, clock tiers, and the
//! time stamp messages of the system channel.
//!
//! **System time** ([`SystemInstant`]) is the runtime's local free-running
//! counter ([`Instant`]) put through the [`TimeMap`]: an offset and a rate
//! correction in fixed point. Rate changes re-base the map at the current
//! instant, so system time is continuous and monotonic. It only steps on a
//! *hard jump*: the first synchronisation, or an offset beyond
//! `hard_jump_us`.
//!
//! The module's parts: [`wire`] holds the messages and the configuration
//! layout, [`map`](TimeMap) the local-to-system map, this file the
//! controller's state and scheduling, `steer` what the controller does
//! with each reply, [`neighbour`] the per-link filters and fits, and
//! [`authority`] who may move the clock.
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
mod steer;
#[cfg(test)]
mod tests;
pub mod wire;

pub use authority::{Trust, SETTLED_OFFSET_US};
pub use map::TimeMap;
pub use status::{ClockStatus, ClockStatusError, SyncStats, CLOCK_STATUS_LEN, CLOCK_STATUS_LEN_V1};
pub use wire::*;

use crate::time::{Duration, Instant, SystemInstant};
use neighbour::Neighbour;

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

/// Where the controller stands: one value, so no combination of flags can
/// say two things at once.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Phase {
    /// The time source (configuration): tier 0, follows no one.
    Root,
    /// Never synchronised and following no one: free-running on the local
    /// counter.
    Free,
    /// Following a lower tier but not yet stepped onto its time.
    Acquiring(Lock),
    /// Following a lower tier and synchronised to it.
    Locked(Lock),
    /// Was synchronised; nothing lower to follow now, so running at the
    /// learned rate.
    Holdover,
}

/// How far a clock that follows a lower tier has come.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(crate) struct Lock {
    /// The fitted rate has been trusted at least once since following.
    pub(crate) settled: bool,
    /// A step was due under motion and is being slewed instead.
    pub(crate) deferring: bool,
    /// The rate has been measured since following, without the fitted
    /// slope being trusted as the rate: by a fit over a full window that
    /// spans less than a trusted slope must (requests two an interval), or
    /// by the one-way envelopes to within what the fit takes over from
    /// (5 ppm: over a link whose exchanges split their round trip unevenly,
    /// USB frames, the fit's scatter may keep its slope from ever being
    /// trusted). Only says whether the clock is settled; steers nothing.
    pub(crate) rate_known: bool,
}

impl Phase {
    /// Following a lower tier (acquiring or locked).
    fn lock(&self) -> Option<Lock> {
        match *self {
            Phase::Acquiring(l) | Phase::Locked(l) => Some(l),
            _ => None,
        }
    }

    /// The follow state, to update in place.
    fn lock_mut(&mut self) -> Option<&mut Lock> {
        match self {
            Phase::Acquiring(l) | Phase::Locked(l) => Some(l),
            _ => None,
        }
    }

    /// Has been stepped onto a source's time (locked, or holding over).
    fn synced(&self) -> bool {
        matches!(self, Phase::Locked(_) | Phase::Holdover)
    }
}

/// The clock of a runtime with up to `LINKS` neighbours.
#[derive(Debug, Clone)]
pub struct Clock<const LINKS: usize> {
    config: TimeConfig,
    /// The local-to-system map the controller steers.
    map: TimeMap,
    /// Rate from the fits alone, without the phase terms: what holdover
    /// keeps.
    learned_q32: i64,
    /// Where the controller stands.
    phase: Phase,
    /// Variance of `learned_q32` as a fraction (fraction²): how much the
    /// frequency loop should believe a new drift measurement over it.
    rate_var: f32,
    last_steer: Option<Instant>,
    offset_us: f32,
    tier: u8,
    /// Next once-per-interval housekeeping (tier aging), local time.
    next_tick: Option<Instant>,
    rng: u32,
    neighbours: Neighbours<LINKS>,
    stats: SyncStats,
    /// Links followed and taken remote writes from (local configuration).
    trust: Trust,
    /// Motion is queued or running: offsets are slewed, never stepped.
    motion_active: bool,
}

impl<const LINKS: usize> Clock<LINKS> {
    /// A clock with the given configuration, not yet synchronised.
    pub fn new(config: TimeConfig) -> Self {
        Clock {
            config,
            map: TimeMap::IDENTITY,
            learned_q32: 0,
            phase: if config.root {
                Phase::Root
            } else {
                Phase::Free
            },
            rate_var: cold_rate_var(&config),
            last_steer: None,
            offset_us: 0.0,
            tier: if config.root {
                TIER_ROOT
            } else {
                TIER_UNSYNCED
            },
            next_tick: None,
            rng: 0x9e37_79b9,
            neighbours: core::array::from_fn(|_| Neighbour::default()),
            stats: SyncStats::default(),
            trust: Trust::ALL,
            motion_active: false,
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
            self.phase = Phase::Root;
        } else if was_root {
            // Stepping down: start looking for a source like everyone else.
            self.tier = TIER_UNSYNCED;
            self.phase = Phase::Free;
        }
        Ok(())
    }

    /// This runtime's clock tier.
    pub fn tier(&self) -> u8 {
        self.tier
    }

    /// Where the clock stands.
    pub fn state(&self) -> SyncState {
        match self.phase {
            Phase::Root => SyncState::Root,
            Phase::Locked(_) => SyncState::Synced,
            Phase::Holdover => SyncState::Holdover,
            Phase::Free | Phase::Acquiring(_) => SyncState::Unsynced,
        }
    }

    /// System time at local time `local` (never below 0).
    pub fn system_time(&self, local: Instant) -> SystemInstant {
        self.map.system_time(local)
    }

    /// A copy of the local-to-system map as it stands, for an interrupt
    /// that needs system time without the runtime.
    pub fn time_map(&self) -> TimeMap {
        self.map
    }

    /// Current rate correction against the local counter, ppb (the
    /// persistent part: what a hot start should restore).
    pub fn rate_ppb(&self) -> i32 {
        // Integer arithmetic: no soft-float on a Cortex-M0+ just to report.
        ((self.map.rate_q32.saturating_mul(1_000_000_000)) >> 32) as i32
    }

    /// Sets the rate correction (a hot start from a persisted
    /// [`rate_ppb`](Self::rate_ppb)), keeping system time continuous at
    /// local time `now`. Clamped to `max_rate_ppm`.
    pub fn set_rate_ppb(&mut self, now: Instant, ppb: i32) {
        // 2^32 / 10^9 ≈ 281 475 / 2^16 (relative error 2e-7).
        let q = (i64::from(ppb) * 281_475 + (1 << 15)) >> 16;
        let max = (self.config.max_rate_ppm * 4294.967) as i64;
        let q = q.clamp(-max, max);
        self.map.rebase(now, q);
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
            .enumerate()
            .filter(|(i, n)| *i < 64 && followed.is_some() && Some(n.tier) == followed)
            .fold(0, |mask, (i, _)| mask | 1 << i)
    }

    /// When the clock next needs a poll (local time): a request due on some
    /// link, or the once-per-interval tier housekeeping.
    pub fn next_request(&self) -> Option<Instant> {
        let links = self.neighbours.iter().filter_map(|n| n.next_request);
        links.chain(self.next_tick).min()
    }

    /// The links (a bit per link index, among those set in `open`) on which
    /// a time stamp request is due now; schedules their next ones. Also ages
    /// the tier once per interval. The root and disabled clocks never
    /// request.
    pub fn due_requests(&mut self, now: Instant, open: u64) -> u64 {
        if self.config.root || !self.config.enabled {
            self.next_tick = None;
            for n in self.neighbours.iter_mut() {
                n.next_request = None;
            }
            return 0;
        }
        let interval = u64::from(self.config.interval_us);
        let tick = Duration::from_micros(interval);
        match self.next_tick {
            Some(t) if now < t => {}
            Some(_) => {
                self.select(now, true);
                self.next_tick = Some(now + tick);
            }
            None => self.next_tick = Some(now + tick),
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
                    let periods = ((now - a).as_micros() + grain) / interval + 1;
                    a + Duration::from_micros(interval) * periods
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
                    let at = now
                        .as_micros()
                        .saturating_add(interval)
                        .saturating_add_signed(d);
                    Instant::from_micros(at)
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
    fn best_tier(&self, now: Instant) -> Option<u8> {
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
        let following = self.phase.lock().is_some();
        (following && self.tier > 0 && self.tier < TIER_LIMIT).then(|| self.tier - 1)
    }

    /// Chooses whom to follow. `age` is set once per request interval: it
    /// is then that a runtime with nothing lower to follow ages its tier.
    fn select(&mut self, now: Instant, age: bool) {
        if self.config.root {
            self.tier = TIER_ROOT;
            self.phase = Phase::Root;
            return;
        }
        match self.best_tier(now) {
            Some(best) if best < self.tier && best + 1 < TIER_LIMIT => {
                if self.phase.lock().is_none() {
                    // Following anew: the rate must be earned again.
                    self.last_steer = None;
                    self.phase = if self.phase.synced() {
                        Phase::Locked(Lock::default())
                    } else {
                        Phase::Acquiring(Lock::default())
                    };
                }
                self.tier = best + 1;
            }
            _ => {
                if let Some(synced) = self.phase.lock().map(|_| self.phase.synced()) {
                    // Holdover: keep the learned rate, drop the phase terms.
                    self.map.rebase(now, self.learned_q32);
                    self.phase = if synced { Phase::Holdover } else { Phase::Free };
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
}

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
