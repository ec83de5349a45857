//! What one runtime knows about one neighbour's clock.
//!
//! Every time stamp reply from the neighbour on a link becomes a sample: the
//! round trip, and the neighbour's system time against our *local* counter
//! at the midpoint of the exchange. Using the local counter (not our steered
//! system time) keeps the samples independent of our own corrections, so a
//! straight-line fit through them gives the neighbour's rate against our
//! oscillator and its time now.
//!
//! Two filters keep bad samples out of the fit:
//! - **minimum round trip**: a sample whose round trip exceeds the floor
//!   (the lower envelope of recent round trips) by more than `rtt_factor` ×
//!   floor + `rtt_slack_us` was delayed on one leg (queueing, a busy
//!   receiver, a USB frame wait) and its offset is biased by half that delay.
//!   The floor drops to any shorter round trip at once and rises slowly
//!   (doubling over `rtt_window` request intervals), so it follows a path
//!   that got slower without ever trusting a single long exchange;
//! - **residual**: a sample far off the line the others agree on (by more
//!   than `residual_sigmas` × their spread, and at least
//!   `residual_floor_us`) carries a late time stamp (an interrupt preempted
//!   the stamp), which the round trip alone cannot reveal.

use super::wire::{TimeConfig, FIT_WINDOW_MAX};
use crate::time::{Duration, Instant, SystemInstant};

/// Largest standard error of a fitted rate that is trusted as feed-forward
/// (fraction, here 2 ppm): a slope from few or noisy samples would steer
/// worse than the frequency loop does without it.
const MAX_SLOPE_STDERR: f32 = 2e-6;
/// Phase noise aimed for when averaging the newest residuals while the
/// slope is not yet trusted, µs: then the neighbour's time may still bend
/// (it is settling itself) and the newest samples say most.
const PHASE_NOISE_TARGET_US: f32 = 2.0;
/// Largest ratio of the samples' scatter about the fitted line to their
/// scatter from one to the next at which the neighbour's time is taken not
/// to bend: white noise (whole-µs stamps, a late stamp) scatters both
/// alike, a neighbour that moves its time between samples (a hub slewing
/// away the noise of a USB link) only the first.
const BEND_RATIO: f32 = 1.3;
/// Phase noise aimed for on such a link, µs: the phase from one sample
/// moved the clock by 0.45 µs rms every interval, and each hop added its
/// own such steps to its parent's.
const SETTLED_PHASE_NOISE_TARGET_US: f32 = 0.1;
/// Request intervals a fit must span before its slope is trusted as the
/// rate (40 × 50 ms: two seconds).
const TRUSTED_SLOPE_SPAN_INTERVALS: u64 = 40;
/// The same for a full fit window to say the rate is measured (30 × 50 ms:
/// 1.5 s): at two requests an interval it holds 1.6 s.
const FULL_WINDOW_SPAN_INTERVALS: u64 = 30;

/// Rate error (fraction) allowed for between a young fit's samples.
const YOUNG_FIT_RATE: f32 = 200e-6;

/// Buckets of the one-way envelope (with [`ENVELOPE_BUCKET_US`], 3 s).
const ENVELOPE_BUCKETS: usize = 12;
/// Length of one envelope bucket, µs.
pub const ENVELOPE_BUCKET_US: u64 = 250_000;

/// Refused exchanges in a row after which requests leave the anchor's
/// phase and search again: enough that a few unlucky host latencies at a
/// good phase do not lose it.
pub const ANCHOR_MISSES: u8 = 6;
/// Consecutive residual rejections after which the fit is dropped: the
/// neighbour's time really moved (it jumped), so start over.
const RESET_AFTER_REJECTS: u8 = 6;

/// One accepted exchange.
#[derive(Debug, Clone, Copy, Default)]
struct Sample {
    /// Local counter when the request left.
    sent: Instant,
    /// Round trip, µs.
    rtt: u32,
    /// Neighbour time minus our local counter at the exchange's midpoint,
    /// in half microseconds (keeps the midpoint exact).
    y_half: i64,
}

impl Sample {
    /// Local time of the midpoint, relative to `now`, µs.
    fn x(&self, now: Instant) -> f32 {
        self.sent.signed_micros_since(now) as f32 + self.rtt as f32 * 0.5
    }
}

/// Why a sample was not used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Used.
    Accepted,
    /// Round trip too long.
    RejectedRtt,
    /// Too far from the fit.
    RejectedResidual,
    /// Not a reply to one of our requests (stamp in the future).
    Bogus,
}

/// The neighbour's time as seen from here.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    /// Neighbour time minus our local counter, now, µs (relative to
    /// `y_ref_half / 2`).
    pub y_rel: f32,
    /// The reference the estimate is relative to, half µs.
    pub y_ref_half: i64,
    /// Neighbour rate against our local counter (d time / d local − 1), if
    /// enough samples span enough time to fit it.
    pub slope: Option<f32>,
    /// The rate has been measured to the precision a trusted slope needs,
    /// over a full window if not over the span `slope` needs.
    pub rate_measured: bool,
    /// Root-mean-square residual of the fit, µs.
    pub rms: f32,
    /// Sample-to-sample measurement noise, µs.
    pub jitter: f32,
    /// Samples the estimate rests on.
    pub used: u8,
    /// Local send time of the newest sample it rests on.
    pub newest: Instant,
    /// Noise of the phase, µs: `jitter` over the root of the number of
    /// newest samples it averages.
    pub phase_noise: f32,
}

/// Samples and state for the neighbour on one link.
#[derive(Debug, Clone)]
pub struct Neighbour {
    /// Lower envelope of the round trips, µs.
    rtt_floor: f32,
    fit: [Sample; FIT_WINDOW_MAX],
    fit_next: u8,
    fit_len: u8,
    rejects_in_row: u8,
    /// The neighbour's tier in its latest reply.
    pub tier: u8,
    /// Local time of the latest reply.
    pub last_heard: Option<Instant>,
    /// Latest round trip, µs.
    pub last_rtt: u32,
    /// When the next request to this neighbour is due (local time).
    pub next_request: Option<Instant>,
    /// Local send time of the latest accepted exchange: requests keep to
    /// its phase (a link that delivers on a frame grid, like USB, answers
    /// promptly only at some phases), until [`ANCHOR_MISSES`] exchanges in
    /// a row are refused there.
    pub anchor: Option<Instant>,
    /// Exchanges refused since the anchor's.
    pub anchor_misses: u8,
    /// Recent fraction of exchanges accepted (moving average). Starts at 0,
    /// so a new neighbour is sampled in bursts until its round-trip floor
    /// is known.
    pub acceptance: f32,
    /// Round trips seen since the neighbour was (re)discovered.
    pub seen: u32,
    /// Requests sent since the latest reply: a link with no one on it (an
    /// open UART with nothing plugged in) stops being sampled in bursts.
    pub unanswered: u32,
    /// Lower envelope of `their time − our send stamp`, per time bucket:
    /// see [`Neighbour::new_envelope_slope`].
    envelope: [EnvelopeBucket; ENVELOPE_BUCKETS],
    /// The newest bucket whose slope the clock has already used.
    envelope_used: u64,
    /// Which envelope is the prompt one (`true`: `their time − our send
    /// stamp`), and the scatter of its buckets about their line, µs
    /// (infinite until known).
    prompt: (bool, f32),
}

/// One bucket of the one-way envelopes, over a [`ENVELOPE_BUCKET_US`] slice
/// of local time: the exchange with the least `their time − our send
/// stamp` (bounded by the delay to them) and the one with the most `their
/// time − our receive stamp` (bounded by the delay back).
#[derive(Debug, Clone, Copy)]
struct EnvelopeBucket {
    /// `sent / ENVELOPE_BUCKET_US`; `u64::MAX` when empty.
    id: u64,
    /// Our send stamp of the `ahead` exchange.
    sent: Instant,
    /// Least `their time − our send stamp`, µs.
    ahead: i64,
    /// Our receive stamp of the `behind` exchange.
    received: Instant,
    /// Most `their time − our receive stamp`, µs.
    behind: i64,
}

const EMPTY_BUCKET: EnvelopeBucket = EnvelopeBucket {
    id: u64::MAX,
    sent: Instant::ZERO,
    ahead: 0,
    received: Instant::ZERO,
    behind: 0,
};

impl Default for Neighbour {
    fn default() -> Self {
        Neighbour {
            rtt_floor: f32::INFINITY,
            fit: [Sample::default(); FIT_WINDOW_MAX],
            fit_next: 0,
            fit_len: 0,
            rejects_in_row: 0,
            tier: super::TIER_UNSYNCED,
            last_heard: None,
            last_rtt: 0,
            next_request: None,
            anchor: None,
            anchor_misses: 0,
            acceptance: 0.0,
            seen: 0,
            unanswered: 0,
            envelope: [EMPTY_BUCKET; ENVELOPE_BUCKETS],
            envelope_used: u64::MAX,
            prompt: (true, f32::INFINITY),
        }
    }
}

impl Neighbour {
    /// Whether the neighbour has replied within the timeout.
    pub fn is_fresh(&self, now: Instant, cfg: &TimeConfig) -> bool {
        self.last_heard
            .is_some_and(|t| now - t <= Duration::from_micros(cfg.neighbour_timeout_us.into()))
    }

    /// The round-trip floor, µs.
    pub fn min_rtt(&self) -> Option<u32> {
        self.rtt_floor.is_finite().then_some(self.rtt_floor as u32)
    }

    fn rtt_limit(&self, cfg: &TimeConfig) -> f32 {
        self.rtt_floor * cfg.rtt_factor + cfg.rtt_slack_us as f32
    }

    fn samples(&self) -> impl Iterator<Item = &Sample> {
        self.fit[..usize::from(self.fit_len)].iter()
    }

    /// Takes in one reply: `sent` is our local counter when the request
    /// left, `received` when the reply arrived, `their_time` the
    /// neighbour's system time at the midpoint of its turnaround.
    pub fn add(
        &mut self,
        sent: Instant,
        received: Instant,
        their_time: SystemInstant,
        tier: u8,
        cfg: &TimeConfig,
        prior_slope: f32,
    ) -> Verdict {
        let Some(rtt) = received.checked_duration_since(sent) else {
            return Verdict::Bogus;
        };
        let rtt = u32::try_from(rtt.as_micros()).unwrap_or(u32::MAX);
        let their_time = their_time.as_micros();
        if tier != self.tier {
            // It started following someone else (or stopped): its time may
            // have jumped, so earlier samples describe another timescale.
            self.forget_timescale();
        }
        self.tier = tier;
        self.last_rtt = rtt;
        self.seen = self.seen.saturating_add(1);
        self.unanswered = 0;
        // The floor forgets with time, not with samples: bursts of requests
        // must not loosen it faster.
        let elapsed = self.last_heard.map_or(0, |t| (received - t).as_micros()) as f32;
        let horizon = f32::from(cfg.rtt_window.max(1)) * cfg.interval_us as f32;
        let rise = self.rtt_floor * elapsed / horizon + 0.01;
        self.rtt_floor = (self.rtt_floor + rise).min(rtt as f32);
        self.last_heard = Some(received);
        self.add_to_envelope(sent, received, their_time);
        if rtt as f32 > self.rtt_limit(cfg) {
            return Verdict::RejectedRtt;
        }
        // 2 × (their time − our counter at the midpoint), exactly.
        let y_half = (2 * their_time as i128 - 2 * sent.as_micros() as i128 - i128::from(rtt))
            .clamp(i64::MIN as i128, i64::MAX as i128) as i64;
        let sample = Sample { sent, rtt, y_half };
        let at = sent + Duration::from_micros(u64::from(rtt / 2));
        if let Some(est) = self.estimate(at, cfg, prior_slope) {
            let predicted = est.y_rel;
            let actual = y_half.saturating_sub(est.y_ref_half) as f32 * 0.5;
            let mut limit = (est.rms * cfg.residual_sigmas).max(cfg.residual_floor_us as f32);
            if est.used < 3 {
                // Too few to know their scatter: allow what the round-trip
                // band lets through, and a rate not yet learned. A young fit
                // must still refuse a neighbour that stepped its time (it
                // does while it settles), or both timescales end up in one
                // line and its slope is off by tens of ppm for seconds.
                let newest = self.samples().map(|s| s.sent).max().unwrap_or(sent);
                let age = (sent - newest).as_micros() as f32;
                let band = self.rtt_limit(cfg) - self.rtt_floor;
                limit = limit.max(band + YOUNG_FIT_RATE * age);
            }
            if (actual - predicted).abs() > limit {
                self.rejects_in_row += 1;
                if self.rejects_in_row < RESET_AFTER_REJECTS {
                    return Verdict::RejectedResidual;
                }
                self.fit_len = 0;
                self.fit_next = 0;
            }
        }
        self.rejects_in_row = 0;
        let window = usize::from(cfg.fit_window).clamp(1, FIT_WINDOW_MAX);
        self.fit[usize::from(self.fit_next)] = sample;
        self.fit_next = ((usize::from(self.fit_next) + 1) % window) as u8;
        self.fit_len = (usize::from(self.fit_len) + 1).min(window) as u8;
        Verdict::Accepted
    }

    /// The neighbour's time against our local counter at local time `now`,
    /// from the samples that pass the current round-trip limit and are not
    /// too old. Until enough samples span enough time to fit a slope, the
    /// line through them runs at `prior_slope` (the clock's learned rate).
    pub fn estimate(&self, now: Instant, cfg: &TimeConfig, prior_slope: f32) -> Option<Estimate> {
        let limit = self.rtt_limit(cfg);
        let max_age = Duration::from_millis(cfg.fit_max_age_ms.into());
        let usable = |s: &&Sample| s.rtt as f32 <= limit && now - s.sent <= max_age;
        let newest = self.samples().filter(usable).max_by_key(|s| s.sent)?;
        let y_ref_half = newest.y_half;
        let newest_sent = newest.sent;
        // Means first, then centred sums: f32 keeps sub-µs precision because
        // every value is relative to `now` and to the newest sample.
        // Weighted least squares: a sample whose round trip sits on the
        // floor is trusted fully; one at the edge of the band counts a fifth.
        let band = (limit - self.rtt_floor).max(1.0);
        let weight = |s: &Sample| {
            let excess = (s.rtt as f32 - self.rtt_floor).max(0.0) / band;
            1.0 / (1.0 + 4.0 * excess * excess)
        };
        let (mut n, mut sw, mut sx, mut sv) = (0u8, 0f32, 0f32, 0f32);
        let (mut first, mut last) = (u64::MAX, 0u64);
        for s in self.samples().filter(usable) {
            let w = weight(s);
            n += 1;
            sw += w;
            sx += w * s.x(now);
            sv += w * s.y_half.saturating_sub(y_ref_half) as f32 * 0.5;
            first = first.min(s.sent.as_micros());
            last = last.max(s.sent.as_micros());
        }
        let count = f32::from(n);
        let (mx, mv) = (sx / sw, sv / sw);
        let (mut sxx, mut sxy) = (0f32, 0f32);
        for s in self.samples().filter(usable) {
            let (w, dx) = (weight(s), s.x(now) - mx);
            sxx += w * dx * dx;
            sxy += w * dx * (s.y_half.saturating_sub(y_ref_half) as f32 * 0.5 - mv);
        }
        // Unweighted spread, for the slope's standard error below.
        let sxx = sxx * count / sw;
        let sxy = sxy * count / sw;
        // A slope needs points spread over at least two request intervals.
        let span = last - first;
        let fitted = n >= 3 && span >= 2 * u64::from(cfg.interval_us) && sxx > 0.0;
        let b = if fitted { sxy / sxx } else { prior_slope };
        let mut sq = 0f32;
        for s in self.samples().filter(usable) {
            let r = s.y_half.saturating_sub(y_ref_half) as f32 * 0.5 - (mv + b * (s.x(now) - mx));
            sq += r * r;
        }
        let rms = libm_sqrt(sq / count);
        // Noise of one sample: the scatter between successive residuals,
        // which a slowly bending neighbour time does not inflate (at least
        // the µs quantisation of every stamp).
        let len = usize::from(self.fit_len);
        let residual = |s: &Sample| {
            s.y_half.saturating_sub(y_ref_half) as f32 * 0.5 - (mv + b * (s.x(now) - mx))
        };
        let (mut prev, mut diffs, mut dsq) = (None, 0u32, 0f32);
        for k in 0..len {
            let s = &self.fit[(usize::from(self.fit_next) + k) % len];
            if !usable(&s) {
                continue;
            }
            let r = residual(s);
            if let Some(p) = prev {
                let d: f32 = r - p;
                dsq += d * d;
                diffs += 1;
            }
            prev = Some(r);
        }
        let jitter = if diffs >= 2 {
            libm_sqrt(dsq / (2.0 * diffs as f32)).max(0.5)
        } else {
            // Too few to tell: assume the worst the round-trip band allows.
            ((limit - self.rtt_floor) * 0.5).max(0.5)
        };
        // Standard error of the slope; a slope from fewer than 8 samples is
        // never trusted (a few points can fit a line by chance).
        let noise = rms.max(jitter);
        let stderr = noise / libm_sqrt(sxx.max(1.0)) * libm_sqrt(count / (count - 2.0).max(1.0));
        // Trusted only over two seconds or more: over less, a neighbour
        // slewing its own time (as it does while it settles) reads as a rate
        // tens of ppm off, which would then be carried on after the slew.
        let precise = fitted && n >= 8 && stderr <= MAX_SLOPE_STDERR;
        let interval = u64::from(cfg.interval_us);
        let slope = (precise && span >= TRUSTED_SLOPE_SPAN_INTERVALS * interval).then_some(b);
        // A full window may span less: requests can run in two phases an
        // interval (a burst's last ones and the phase after it, each the
        // other's anchor), which fills it twice as fast, and then its slope
        // is never trusted. Its rate is still measured, and says the clock
        // is settled; the controller goes on steering without it.
        let full = usize::from(n) >= usize::from(cfg.fit_window).clamp(1, FIT_WINDOW_MAX);
        let rate_measured =
            slope.is_some() || (precise && full && span >= FULL_WINDOW_SPAN_INTERVALS * interval);
        // The line is a long average; the phase now comes from the newest
        // samples' residuals, as many as the noise needs, so a neighbour
        // whose own time bends is followed closely. While the slope is not
        // trusted, or the residuals' scatter about the line is more than
        // `BEND_RATIO` times their scatter from one to the next (the
        // neighbour's time moves between samples: a hub that follows a
        // noisy USB estimate), that is one sample on a clean link: a long
        // average would trail the neighbour. Otherwise the scatter is the
        // stamps' own, white, and the newest residuals are fitted with a
        // short line of their own read at `now`, over enough of them to
        // bring the phase's noise to `SETTLED_PHASE_NOISE_TARGET_US` (a
        // line's end is twice as noisy as a mean: four times the samples;
        // a line, so a neighbour slewing its time in a ramp is not
        // trailed).
        let fine = slope.is_some() && rms <= BEND_RATIO * jitter;
        let wanted = if fine {
            4.0 * (jitter / SETTLED_PHASE_NOISE_TARGET_US)
                * (jitter / SETTLED_PHASE_NOISE_TARGET_US)
        } else {
            (jitter / PHASE_NOISE_TARGET_US) * (jitter / PHASE_NOISE_TARGET_US)
        };
        let take = (wanted as usize).clamp(1, usize::from(n));
        let (mut taken, mut sr, mut srx, mut sx1, mut sxx1) = (0usize, 0f32, 0f32, 0f32, 0f32);
        for back in 1..=len {
            if taken == take {
                break;
            }
            let s = &self.fit[(usize::from(self.fit_next) + 2 * len - back) % len];
            if !usable(&s) {
                continue;
            }
            let (x, r) = (s.x(now), residual(s));
            sr += r;
            srx += r * x;
            sx1 += x;
            sxx1 += x * x;
            taken += 1;
        }
        let k = taken.max(1) as f32;
        let (mr, mx1) = (sr / k, sx1 / k);
        let var_x = sxx1 / k - mx1 * mx1;
        // The short line's value at now (x = 0), and its noise there. (x
        // is within the fit's few seconds: µs² sums stay well inside f32.)
        let (phase, phase_noise) = if fine && taken >= 3 && var_x > 0.0 {
            let b1 = (srx / k - mr * mx1) / var_x;
            let spread = 1.0 / k + mx1 * mx1 / (var_x * k);
            (mr - b1 * mx1, jitter * libm_sqrt(spread))
        } else {
            (mr, jitter / libm_sqrt(k))
        };
        Some(Estimate {
            y_rel: mv - b * mx + phase,
            y_ref_half,
            slope,
            rate_measured,
            rms,
            jitter,
            used: n,
            newest: newest_sent,
            phase_noise,
        })
    }

    fn add_to_envelope(&mut self, sent: Instant, received: Instant, their_time: u64) {
        let id = sent.as_micros() / ENVELOPE_BUCKET_US;
        let diff = |ours: Instant| {
            (their_time as i128 - ours.as_micros() as i128)
                .clamp(i64::MIN as i128, i64::MAX as i128) as i64
        };
        let (ahead, behind) = (diff(sent), diff(received));
        let slot = &mut self.envelope[(id % ENVELOPE_BUCKETS as u64) as usize];
        if slot.id != id {
            *slot = EnvelopeBucket {
                id,
                sent,
                ahead,
                received,
                behind,
            };
            return;
        }
        if ahead < slot.ahead {
            (slot.sent, slot.ahead) = (sent, ahead);
        }
        if behind > slot.behind {
            (slot.received, slot.behind) = (received, behind);
        }
    }

    /// The neighbour's rate against our local counter (fraction) and its
    /// standard error, from the one-way envelopes of the last few seconds,
    /// once per finished bucket: `None` when no bucket has finished since
    /// the last call (so the fits run four times a second, not on every
    /// reply), or below four finished buckets.
    ///
    /// `their time − our send stamp` is their time at our send plus the
    /// delay to them; its least value in a quarter second sits on the
    /// smallest delay, so that envelope's slope is their rate whatever the
    /// way back does (and `their time − our receive stamp`, at its most,
    /// likewise for the way back). On USB, where replies are clean only when
    /// they happen to catch a frame, one direction is prompt: this measures
    /// the rate long before the round-trip filter lets enough exchanges
    /// through to fit it. The two envelopes' slopes are weighed by their
    /// precision, and their error is at least half their disagreement; the
    /// less scattered envelope is taken as the prompt one for
    /// [`Neighbour::envelope_offset`]. `Some(None)`: a bucket finished, but
    /// fewer than four are there to fit.
    pub fn new_envelope_slope(&mut self, now: Instant) -> Option<Option<(f32, f32)>> {
        let current = now.as_micros() / ENVELOPE_BUCKET_US;
        let oldest = current.saturating_sub(ENVELOPE_BUCKETS as u64);
        let usable = |b: &&EnvelopeBucket| b.id != u64::MAX && b.id < current && b.id >= oldest;
        let newest = self.envelope.iter().filter(usable).map(|b| b.id).max()?;
        if newest == self.envelope_used {
            return None;
        }
        self.envelope_used = newest;
        let buckets = || self.envelope.iter().filter(usable);
        let ahead = line_fit(buckets().map(|b| (b.sent, b.ahead)));
        let behind = line_fit(buckets().map(|b| (b.received, b.behind)));
        let (is_ahead, (slope, stderr, sigma)) = match (ahead, behind) {
            (Some(a), Some(b)) => {
                self.prompt = if a.1 <= b.1 {
                    (true, a.2)
                } else {
                    (false, b.2)
                };
                // Both measure the same rate: weigh them by their
                // precision, and where they disagree by more than that
                // claims (a few buckets can line up by chance), believe
                // the disagreement.
                let (va, vb) = (a.1 * a.1, b.1 * b.1);
                let slope = (a.0 * vb + b.0 * va) / (va + vb).max(f32::MIN_POSITIVE);
                let half_gap = 0.5 * (a.0 - b.0);
                let var = (va * vb / (va + vb).max(f32::MIN_POSITIVE)).max(half_gap * half_gap);
                return Some(Some((slope, libm_sqrt(var))));
            }
            (Some(a), None) => (true, a),
            (None, Some(b)) => (false, b),
            (None, None) => return Some(None),
        };
        self.prompt = (is_ahead, sigma);
        Some(Some((slope, stderr)))
    }

    /// The neighbour's time minus our local counter at `now`, µs (a whole
    /// part and the rest), from the prompt one-way envelope of the last half
    /// second, projected to `now` at `slope` (their rate against our
    /// counter) and corrected by half the floor of the two envelopes over
    /// the last three seconds; with the scatter of the prompt envelope, µs.
    /// `None` while the envelopes hold nothing recent.
    ///
    /// On USB only a few exchanges a second catch a frame and pass the
    /// round-trip filter, and those are not symmetric; the prompt direction
    /// sits on its least delay within every quarter second whatever the
    /// frames do, so this follows the neighbour without waiting for them.
    /// Until the envelopes have been fitted the scatter is taken as an
    /// eighth of the round-trip band; over the first half second the two
    /// envelopes' extremes are the same set, and either side gives their
    /// midpoint.
    pub fn envelope_offset(
        &self,
        now: Instant,
        slope: f32,
        cfg: &TimeConfig,
    ) -> Option<(i64, f32, f32)> {
        let (prompt_ahead, sigma) = self.prompt;
        // Until the envelopes' scatter is known, assume what the round-trip
        // band allows (over the first buckets both sides give the same).
        let sigma = if sigma.is_finite() {
            sigma
        } else {
            0.125 * (self.rtt_limit(cfg) - self.rtt_floor).max(1.0)
        };
        let current = now.as_micros() / ENVELOPE_BUCKET_US;
        let oldest = current.saturating_sub(ENVELOPE_BUCKETS as u64 - 1);
        // Every bucket's two extremes, projected to `now` at `slope`,
        // relative to the first bucket's `ahead`: the least `ahead` and the
        // most `behind` over the whole window (their difference is the
        // sum of the two directions' least delays: a round-trip floor that
        // no single exchange needs to reach), and the prompt one's over the
        // newest two buckets.
        let mut reference = None;
        let (mut ahead, mut behind, mut recent) = (f32::INFINITY, f32::NEG_INFINITY, None::<f32>);
        for b in self.envelope.iter() {
            if b.id == u64::MAX || b.id < oldest || b.id > current {
                continue;
            }
            let r = *reference.get_or_insert(b.ahead);
            let at = |t: Instant| slope * now.signed_micros_since(t) as f32;
            let a = b.ahead.saturating_sub(r) as f32 + at(b.sent);
            let h = b.behind.saturating_sub(r) as f32 + at(b.received);
            ahead = ahead.min(a);
            behind = behind.max(h);
            if b.id + 1 >= current {
                recent = Some(match (recent, prompt_ahead) {
                    (None, true) => a,
                    (None, false) => h,
                    (Some(v), true) => v.min(a),
                    (Some(v), false) => v.max(h),
                });
            }
        }
        let (reference, recent) = (reference?, recent?);
        let floor = (ahead - behind).max(0.0).min(self.rtt_floor);
        let rel = if prompt_ahead {
            recent - 0.5 * floor
        } else {
            recent + 0.5 * floor
        };
        Some((reference, rel, sigma))
    }

    /// Forgets the samples and envelopes (not the round-trip floor): the
    /// neighbour's time jumped.
    fn forget_timescale(&mut self) {
        self.fit_len = 0;
        self.fit_next = 0;
        self.envelope = [EMPTY_BUCKET; ENVELOPE_BUCKETS];
        self.envelope_used = u64::MAX;
        self.prompt = (true, f32::INFINITY);
    }

    /// Forgets everything (the link closed or changed peer).
    pub fn reset(&mut self) {
        *self = Neighbour::default();
    }

    /// Whether the latest sample was refused as too far from the fit: the
    /// neighbour's time may have jumped, which a few more exchanges tell.
    pub fn doubting(&self) -> bool {
        self.rejects_in_row > 0
    }

    /// Whether anything is known (a request was sent or a reply heard).
    pub fn is_active(&self) -> bool {
        self.last_heard.is_some() || self.next_request.is_some()
    }
}

/// Least-squares slope of `(local µs, µs)` points, its standard error and
/// the points' scatter about the line;
/// `None` below four points or when they do not spread in time.
fn line_fit(points: impl Iterator<Item = (Instant, i64)> + Clone) -> Option<(f32, f32, f32)> {
    let (x0, y0) = points.clone().next()?;
    let rel = |(x, y): (Instant, i64)| {
        (
            x.signed_micros_since(x0) as f32,
            y.saturating_sub(y0) as f32,
        )
    };
    let (mut n, mut sx, mut sy) = (0u8, 0f32, 0f32);
    for (x, y) in points.clone().map(rel) {
        n += 1;
        sx += x;
        sy += y;
    }
    if n < 4 {
        return None;
    }
    let count = f32::from(n);
    let (mx, my) = (sx / count, sy / count);
    let (mut sxx, mut sxy) = (0f32, 0f32);
    for (x, y) in points.clone().map(rel) {
        sxx += (x - mx) * (x - mx);
        sxy += (x - mx) * (y - my);
    }
    if sxx <= 0.0 {
        return None;
    }
    let slope = sxy / sxx;
    let mut sq = 0f32;
    for (x, y) in points.map(rel) {
        let r = y - (my + slope * (x - mx));
        sq += r * r;
    }
    // At least a microsecond of scatter: the stamps are whole µs.
    let sigma = libm_sqrt(sq / (count - 2.0)).max(1.0);
    let stderr = sigma / libm_sqrt(sxx);
    (slope.is_finite() && stderr.is_finite()).then_some((slope, stderr, sigma))
}

/// Square root without `std` (Newton's method; plenty for an RMS).
fn libm_sqrt(v: f32) -> f32 {
    if v <= 0.0 || !v.is_finite() {
        return 0.0;
    }
    let mut x = if v > 1.0 { v } else { 1.0 };
    for _ in 0..20 {
        x = 0.5 * (x + v / x);
    }
    x
}

#[cfg(test)]
#[path = "neighbour_tests.rs"]
mod tests;
