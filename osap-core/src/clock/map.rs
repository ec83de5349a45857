//! The time map: the one way between local and system time.
//!
//! System time is the local counter put through a linear map kept in fixed
//! point (Q32): `system = base_system + Δ + (Δ × rate + min(Δ, slew_len) ×
//! slew) >> 32` with `Δ = local − base_local`. The controller re-bases the
//! map whenever it changes the rate, so system time stays continuous, and
//! since the rate correction is clamped far below 100 %, monotonic.
//!
//! Motion and sensor interrupts need synchronized time at a precise local
//! instant, but must not touch the runtime (it belongs to another task).
//! The runtime task publishes a copy of its [`TimeMap`] after each poll; an
//! interrupt keeps the latest copy and converts its own counter readings
//! with it. The map holds the rate and any slew in progress, so it stays
//! exact between publications, not just at the moment it was taken.

use crate::time::{Instant, SystemInstant};

/// The linear map from a runtime's local counter to system time, as its
/// clock held it when the copy was made. `Copy` and small, for passing to
/// an interrupt.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct TimeMap {
    pub(crate) base_local: Instant,
    /// Signed, so a jump to a source whose time is younger than our
    /// counter can never wrap; reported time is clamped at 0.
    pub(crate) base_system: i64,
    /// Fraction of a µs carried across re-bases (Q32), so that re-basing at
    /// every update never loses time.
    pub(crate) base_frac: u32,
    /// Persistent rate correction: learned feed-forward + integral term.
    pub(crate) rate_q32: i64,
    /// Phase slew: an extra rate applied for `slew_len` µs after
    /// `base_local`, so a measured offset is removed exactly once, however
    /// long it is until the next sample.
    pub(crate) slew_q32: i64,
    pub(crate) slew_len: i64,
}

impl TimeMap {
    /// The identity map: system time equals the local counter (a runtime
    /// that has not synchronised yet).
    pub const IDENTITY: TimeMap = TimeMap {
        base_local: Instant::ZERO,
        base_system: 0,
        base_frac: 0,
        rate_q32: 0,
        slew_q32: 0,
        slew_len: 0,
    };

    /// System time at local time `local` (never below 0).
    pub fn system_time(&self, local: Instant) -> SystemInstant {
        SystemInstant::from_micros(self.system_time_q32(local).0.max(0) as u64)
    }

    /// The earliest local time at which system time reads `system` or
    /// later.
    ///
    /// For scheduling on the local counter (a timer interrupt) something
    /// that is due at a system instant. The map is monotonic, so the answer
    /// is unique; system times before the map's reach give
    /// [`Instant::ZERO`].
    pub fn local_time(&self, system: SystemInstant) -> Instant {
        let target = i128::from(system.as_micros());
        let at = |l: i128| Instant::from_micros(l.clamp(0, i128::from(u64::MAX)) as u64);
        let reads = |l: i128| i128::from(self.system_time_q32(at(l)).0);
        // Start from the rate-free guess and correct by the residual: the
        // rate is within 1 % of one, so each step gains two orders of
        // magnitude; ten cover any 64-bit span. Then settle the last µs
        // either way (the map may skip or repeat a system µs).
        let mut local =
            i128::from(self.base_local.as_micros()) + target - i128::from(self.base_system);
        for _ in 0..10 {
            let err = target - reads(local);
            if err == 0 {
                break;
            }
            local += err;
        }
        for _ in 0..4 {
            if reads(local) < target {
                local += 1;
            } else if local > 0 && reads(local - 1) >= target {
                local -= 1;
            } else {
                break;
            }
        }
        at(local)
    }

    /// Signed system time at `local` as whole µs and a Q32 fraction.
    pub(crate) fn system_time_q32(&self, local: Instant) -> (i64, u32) {
        let delta = local.signed_micros_since(self.base_local);
        let slewed = delta.min(self.slew_len);
        let adjust = i128::from(delta) * i128::from(self.rate_q32)
            + i128::from(slewed) * i128::from(self.slew_q32)
            + i128::from(self.base_frac);
        let whole = i128::from(self.base_system) + i128::from(delta) + (adjust >> 32);
        let whole = whole.clamp(i128::from(i64::MIN), i128::from(i64::MAX)) as i64;
        (whole, adjust as u32)
    }

    /// Re-bases the map at local time `now` with a new rate and no slew,
    /// keeping system time continuous.
    pub(crate) fn rebase(&mut self, now: Instant, rate_q32: i64) {
        (self.base_system, self.base_frac) = self.system_time_q32(now);
        self.base_local = now;
        self.rate_q32 = rate_q32;
        self.slew_q32 = 0;
        self.slew_len = 0;
    }

    /// Steps system time by `offset_us` (a hard jump).
    pub(crate) fn step(&mut self, offset_us: i64) {
        self.base_system = self.base_system.saturating_add(offset_us);
    }

    /// µs of the current slew still to run at `now`.
    pub(crate) fn slew_left(&self, now: Instant) -> i64 {
        let elapsed = now.signed_micros_since(self.base_local);
        self.slew_len - elapsed.clamp(0, self.slew_len)
    }

    /// Our system time minus our local counter at `now`: whole half µs,
    /// and the rest below that, µs (in [0, 0.5)). The rest matters: a
    /// neighbour's time is compared with our map as it runs, not with its
    /// readings in whole µs.
    pub(crate) fn own_y_half(&self, now: Instant) -> (i64, f32) {
        let (whole, frac) = self.system_time_q32(now);
        let half = whole
            .wrapping_sub(now.as_micros() as i64)
            .saturating_mul(2)
            .saturating_add(i64::from(frac >> 31));
        (half, (frac & 0x7fff_ffff) as f32 / 4_294_967_296.0)
    }

    /// System time at the midpoint of local times `a` and `b`, to the
    /// nearest µs (never below 0): the responder's time for a time stamp
    /// reply, whose two stamps are whole µs of the local counter.
    pub(crate) fn midpoint_rounded(&self, a: Instant, b: Instant) -> SystemInstant {
        let q = |l: Instant| {
            let (whole, frac) = self.system_time_q32(l);
            (i128::from(whole) << 32) + i128::from(frac)
        };
        // Mean of the two, plus half a µs, floored: rounded to nearest.
        let mid = (q(a) + q(b) + (1i128 << 32)) >> 33;
        SystemInstant::from_micros(mid.clamp(0, i128::from(i64::MAX)) as u64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(rate_ppm: i64, slew_ppm: i64, slew_len: i64) -> TimeMap {
        let q = |ppm: i64| (ppm << 32) / 1_000_000;
        TimeMap {
            base_local: Instant::from_micros(1_000),
            base_system: 5_000_000,
            base_frac: 0,
            rate_q32: q(rate_ppm),
            slew_q32: q(slew_ppm),
            slew_len,
        }
    }

    #[test]
    fn local_time_inverts_system_time() {
        for m in [
            TimeMap::IDENTITY,
            map(250, 0, 0),
            map(-480, 300, 2_000_000),
            map(9_000, -900, 10),
        ] {
            for l in [0u64, 1_000, 1_001, 77_777, 3_000_000, 86_400_000_000] {
                let local = Instant::from_micros(l);
                let system = m.system_time(local);
                if system == SystemInstant::ZERO {
                    continue; // clamped: not invertible
                }
                let back = m.local_time(system);
                // The earliest local µs that reads `system`: `local` itself
                // unless the one before reads the same.
                assert!(back <= local, "{m:?}: {local:?} -> {system:?} -> {back:?}");
                assert_eq!(m.system_time(back), system, "{m:?}: {local:?}");
                if back > Instant::ZERO {
                    let before = back - crate::time::Duration::from_micros(1);
                    assert!(m.system_time(before) < system, "{m:?}: {local:?}");
                }
            }
        }
    }

    #[test]
    fn a_reply_midpoint_is_rounded_below_the_microsecond() {
        // Half a µs of offset in the map's fraction: the two readings in
        // whole µs (5_000_001 and 5_000_004), their difference halved in
        // whole µs, gave 5_000_002; the map itself says 5_000_003.0.
        let mut m = map(0, 0, 0);
        m.base_frac = 1 << 31;
        let mid = m.midpoint_rounded(Instant::from_micros(1_001), Instant::from_micros(1_004));
        assert_eq!(mid, SystemInstant::from_micros(5_000_003));
        let one = m.midpoint_rounded(Instant::from_micros(1_000), Instant::from_micros(1_000));
        assert_eq!(one, SystemInstant::from_micros(5_000_001));
    }

    #[test]
    fn before_the_map_reaches_is_zero() {
        assert_eq!(map(0, 0, 0).local_time(SystemInstant::ZERO), Instant::ZERO);
    }
}
