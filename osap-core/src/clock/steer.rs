//! What the controller does with each time stamp reply: file it with its
//! neighbour, learn the rate, and step or slew the time map.

use super::neighbour::{Verdict, ANCHOR_MISSES};
use super::*;

/// Rate variance (fraction², here (5 ppm)²) below which the envelope's
/// rough slope no longer adds anything the fit does not.
const ENVELOPE_RATE_VAR_LIMIT: f32 = 5e-6 * 5e-6;

/// Over a bursting link, a fit whose newest sample is older than this is
/// stale: the one-way envelope is followed instead.
const ENVELOPE_STALE: Duration = Duration::from_secs(2);

/// Variance of a trusted fitted rate (see the fit's standard-error bound).
const MAX_SLOPE_VAR: f32 = 2e-6 * 2e-6;

impl<const LINKS: usize> Clock<LINKS> {
    /// Takes in a time stamp reply that arrived on `link` at local time
    /// `received` (the link's wire stamp when it has one), then steers.
    pub fn on_reply(&mut self, link: usize, reply: &TimeReply, received: Instant) {
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
    fn learn_rate_from_envelope(&mut self, link: usize, now: Instant) -> bool {
        if !matches!(self.phase, Phase::Locked(_)) {
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
        if self.rate_var <= ENVELOPE_RATE_VAR_LIMIT {
            self.set_lock(|l| l.rate_known = true);
        }
        self.learned_q32 = rate;
        let (slew_q32, left) = (self.map.slew_q32, self.map.slew_left(now));
        self.map.rebase(now, rate);
        if left > 0 {
            self.map.slew_q32 = slew_q32;
            self.map.slew_len = left;
        }
        true
    }

    fn clamp_rate(&self, fraction: f32) -> i64 {
        let max = self.config.max_rate_ppm * 1e-6;
        round(fraction.clamp(-max, max) * Q32)
    }

    /// Steers the time map toward the followed tier at local time `now`:
    /// measures the offset, then steps it away or learns the rate from it
    /// and slews it away.
    fn steer(&mut self, now: Instant) {
        let Some(tier) = self.followed() else {
            return;
        };
        let Some(m) = self.measure(now, tier) else {
            return;
        };
        self.offset_us = m.offset;
        if self.step_if_due(now, &m) {
            return;
        }
        let learned = self.learn_rate(now, &m);
        self.last_steer = Some(now);
        self.learned_q32 = self.clamp_rate(learned);
        self.map.rebase(now, self.learned_q32);
        self.start_slew(m.offset, m.slew_noise, learned);
    }

    /// The followed tier's offset from our system time at `now`, averaged
    /// over its fresh neighbours, with the noise of the measurement and the
    /// mean of any trusted fitted rates.
    fn measure(&self, now: Instant, tier: u8) -> Option<Measurement> {
        let (own, own_rest) = self.map.own_y_half(now);
        let prior = self.learned_q32 as f32 / Q32;
        let settled = self.phase.lock().is_some_and(|l| l.settled);
        let (mut offset_sum, mut offsets) = (0f32, 0u8);
        let (mut slope_sum, mut slopes) = (0f32, 0u8);
        let mut rate_measured = false;
        let (mut noise, mut slew_noise) = (0f32, 0f32);
        for n in self.neighbours.iter() {
            if n.tier != tier || !n.is_fresh(now, &self.config) {
                continue;
            }
            let est = n.estimate(now, &self.config, prior);
            rate_measured |= est.is_some_and(|e| e.rate_measured);
            if let Some(slope) = est.and_then(|e| e.slope) {
                slope_sum += slope;
                slopes += 1;
            }
            let fit = est.map(|e| {
                let offset = e.y_ref_half.saturating_sub(own) as f32 * 0.5 + e.y_rel - own_rest;
                (offset, e.jitter, e.phase_noise)
            });
            let envelope = n
                .envelope_offset(now, prior, &self.config)
                .map(|(v, rel, sigma)| {
                    let offset =
                        v.saturating_mul(2).saturating_sub(own) as f32 * 0.5 + rel - own_rest;
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
            let stale = est.is_none_or(|e| now - e.newest > ENVELOPE_STALE);
            let (offset, jitter, phase_noise) = match (fit, envelope) {
                (Some(f), Some(e))
                    if bursting && (stale || !settled || (f.0 - e.0).abs() > 3.0 * (f.1 + e.1)) =>
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
            return None;
        }
        Some(Measurement {
            offset,
            noise,
            slew_noise,
            slope: (slopes > 0).then(|| slope_sum / f32::from(slopes)),
            rate_measured,
        })
    }

    /// Steps the measured offset away if it calls for a jump and motion
    /// allows one (then returns true). Records that the fitted rate is
    /// trusted, and whether a due step is being deferred.
    fn step_if_due(&mut self, now: Instant, m: &Measurement) -> bool {
        let synced = self.phase.synced();
        let Some(lock) = self.phase.lock() else {
            return false;
        };
        // Still settling (the fitted rate has never been trusted): this is
        // the first synchronisation, and a clear offset is stepped away
        // rather than slewed at the rate clamp for a second.
        let settling = !lock.settled && m.offset.abs() > (4.0 * m.noise).max(SETTLE_STEP_US);
        if m.slope.is_some() {
            self.set_lock(|l| l.settled = true);
        }
        if m.rate_measured {
            self.set_lock(|l| l.rate_known = true);
        }
        let jump = !synced || settling || m.offset.abs() > self.config.hard_jump_us as f32;
        if !jump {
            self.set_lock(|l| l.deferring = false);
            return false;
        }
        if !self.may_step() {
            return false;
        }
        self.map.rebase(now, self.learned_q32);
        self.map.step(round(m.offset));
        if let Phase::Acquiring(l) = self.phase {
            self.phase = Phase::Locked(l);
        }
        self.offset_us = 0.0;
        self.last_steer = Some(now);
        self.stats.jumps = self.stats.jumps.wrapping_add(1);
        true
    }

    /// Updates the follow state in place (no-op when not following).
    pub(super) fn set_lock(&mut self, f: impl FnOnce(&mut Lock)) {
        if let Some(l) = self.phase.lock_mut() {
            f(l);
        }
    }

    /// The rate our system time needs, from a trusted fit when there is
    /// one, else from the drift the last slew does not explain.
    fn learn_rate(&mut self, now: Instant, m: &Measurement) -> f32 {
        let cfg = self.config;
        let mut learned = self.learned_q32 as f32 / Q32;
        if let Some(slope) = m.slope {
            // A trusted fit of the neighbours' rate against our counter is
            // exactly the rate our system time needs.
            learned = slope;
            self.rate_var = self.rate_var.min(MAX_SLOPE_VAR);
        } else if let Some(last) = self.last_steer {
            // Frequency loop: what the last slew does not explain of the
            // offset is drift, i.e. rate error. Over short gaps take kf of it
            // per second; over long ones at most all of it.
            let dt = (now - last).as_micros() as f32 * 1e-6;
            let drift = m.offset - self.slew_remaining(now);
            if dt > 0.0 {
                // While settling, learn fast (half a second); afterwards
                // the fit leads and this only trims, over 1/kf.
                let settled = self.phase.lock().is_some_and(|l| l.settled);
                let horizon = if settled {
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
                let meas_sd = m.noise.max(0.5) * 1e-6 * core::f32::consts::SQRT_2 / dt;
                let kalman = self.rate_var / (self.rate_var + meas_sd * meas_sd);
                let gain = kalman.min(dt / dt.max(horizon));
                learned += gain * drift * 1e-6 / dt;
                self.rate_var *= 1.0 - gain;
            }
        }
        learned
    }

    /// Removes `offset` by slewing, then runs at the learned rate again: a
    /// slew, not a rate held until the next sample, since samples may be
    /// seconds apart. Precise measurements are acted on within one
    /// interval; noisy ones over up to 1/kp; never faster than the clamp
    /// leaves room for. A step deferred under motion is slewed whatever
    /// kp says, as fast as the clamp allows.
    fn start_slew(&mut self, offset: f32, slew_noise: f32, learned: f32) {
        let cfg = self.config;
        let deferring = self.phase.lock().is_some_and(|l| l.deferring);
        if cfg.kp > 0.0 || deferring {
            let max = cfg.max_rate_ppm * 1e-6;
            let room = (max - learned.abs()).max(0.1 * max);
            let settle = if deferring {
                0.0
            } else {
                (1e6 / cfg.kp) * (slew_noise / SLEW_NOISE_REF_US).min(1.0)
            };
            let duration_us = settle.max(cfg.interval_us as f32).max(offset.abs() / room);
            self.map.slew_q32 = round(offset / duration_us * Q32);
            self.map.slew_len = duration_us as i64;
        }
    }

    /// The part of the current slew not yet applied at `now`, µs.
    fn slew_remaining(&self, now: Instant) -> f32 {
        self.map.slew_left(now) as f32 * self.map.slew_q32 as f32 / Q32
    }
}

/// One steering measurement of the followed tier.
struct Measurement {
    /// Their time minus ours, µs.
    offset: f32,
    /// The largest measurement jitter among the neighbours used, µs.
    noise: f32,
    /// The largest phase noise among them, µs: sets how slowly to slew.
    slew_noise: f32,
    /// The mean trusted fitted rate, if any neighbour has one.
    slope: Option<f32>,
    /// Some neighbour's rate is measured (its estimate's `rate_measured`).
    rate_measured: bool,
}
