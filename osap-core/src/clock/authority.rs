//! Clock authority: which neighbours a runtime may take its time from, and
//! what a time correction may do to motion under way.
//!
//! **Trust.** A runtime follows only neighbours on links it trusts, and
//! takes remote writes of its time configuration and clock rate only from
//! those links (or from a port of its own). Replies and writes from other
//! links are ignored and counted in [`SyncStats::untrusted`]. The trusted
//! set is local configuration ([`Clock::set_trust`]): it is not part of
//! [`TimeConfig`](super::TimeConfig), so no remote peer can grant itself
//! trust. A module trusts all its links (it sits inside the machine); a host
//! trusts none until told (see osap-host's `HostConfig::trust`).
//!
//! **Motion.** While the runtime reports queued or running motion
//! ([`Clock::set_motion_active`]) its system time never steps: an offset
//! that would be a hard jump is slewed away instead, at a rate whose total
//! stays within `max_rate_ppm` (at most a tenth of it beyond, when the
//! learned rate alone sits at the clamp). An axis evaluating its spline
//! against such a clock moves at most that fraction faster or slower than
//! planned, so the limits the backstop enforces hold.

use super::{Clock, SyncStats};

/// Offset (µs) within which a following clock counts as settled.
pub const SETTLED_OFFSET_US: f32 = 50.0;

/// The links (a bit per link index, 0..64) whose neighbours a clock follows
/// and takes remote clock writes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Trust {
    links: u64,
}

impl Trust {
    /// Every link: a module's default, all its links lead into its machine.
    pub const ALL: Trust = Trust { links: u64::MAX };
    /// No link: a root that takes no orders, or a host not told whom to
    /// follow.
    pub const NONE: Trust = Trust { links: 0 };

    /// The links whose bits are set in `mask`.
    pub const fn links(mask: u64) -> Trust {
        Trust { links: mask }
    }

    /// This set and link `index` (indices from 64 on do not exist).
    pub const fn with_link(self, index: u8) -> Trust {
        match 1u64.checked_shl(index as u32) {
            Some(bit) => Trust {
                links: self.links | bit,
            },
            None => self,
        }
    }

    /// This set without link `index`.
    pub const fn without_link(self, index: u8) -> Trust {
        match 1u64.checked_shl(index as u32) {
            Some(bit) => Trust {
                links: self.links & !bit,
            },
            None => self,
        }
    }

    /// Whether link `index` is trusted.
    pub const fn trusts(&self, index: usize) -> bool {
        index < 64 && self.links & (1 << index) != 0
    }

    /// The set as a bit mask.
    pub const fn mask(&self) -> u64 {
        self.links
    }
}

impl Default for Trust {
    fn default() -> Self {
        Trust::ALL
    }
}

impl<const LINKS: usize> Clock<LINKS> {
    /// The links this clock follows and takes remote writes from.
    pub fn trust(&self) -> Trust {
        self.trust
    }

    /// Sets the trusted links. A neighbour on a link that loses trust is
    /// forgotten at once, so it stops being followed.
    pub fn set_trust(&mut self, trust: Trust) {
        let lost = self.trust.mask() & !trust.mask();
        self.trust = trust;
        for link in (0..self.neighbours.len().min(64)).filter(|i| lost & (1 << i) != 0) {
            self.forget(link);
        }
    }

    /// Whether a remote write of the clock's configuration or rate that
    /// arrived on `link` ([`ARRIVED_LOCALLY`](crate::netresponder::ARRIVED_LOCALLY)
    /// for a port of this runtime) may be applied; a refused one is
    /// counted as untrusted.
    pub fn admits_write_from(&mut self, link: u8) -> bool {
        let admitted =
            link == crate::netresponder::ARRIVED_LOCALLY || self.trust.trusts(usize::from(link));
        if !admitted {
            self.count_untrusted();
        }
        admitted
    }

    /// Tells the clock whether motion is queued or running on this runtime
    /// (call before every poll). While it is, time never steps.
    pub fn set_motion_active(&mut self, active: bool) {
        self.motion_active = active;
    }

    /// Whether motion was last reported queued or running.
    pub fn motion_active(&self) -> bool {
        self.motion_active
    }

    /// Whether the clock is fit for motion now: the root, or following
    /// with a measured rate (a trusted fitted slope, a full fit window's,
    /// or the one-way envelopes' to 5 ppm), within [`SETTLED_OFFSET_US`] and
    /// with no step deferred.
    pub fn is_settled(&self) -> bool {
        if self.config.root {
            return true;
        }
        matches!(self.phase, super::Phase::Locked(l) if (l.settled || l.rate_known) && !l.deferring)
            && self.offset_us.abs() <= SETTLED_OFFSET_US
    }

    pub(super) fn count_untrusted(&mut self) {
        let s: &mut SyncStats = &mut self.stats;
        s.untrusted = s.untrusted.wrapping_add(1);
    }

    /// Decides whether an offset the controller would step away may be
    /// stepped now: not while motion is queued. A refusal starts (and
    /// counts) a deferral; the caller slews instead.
    pub(super) fn may_step(&mut self) -> bool {
        if !self.motion_active {
            self.set_lock(|l| l.deferring = false);
            return true;
        }
        if self.phase.lock().is_some_and(|l| !l.deferring) {
            self.set_lock(|l| l.deferring = true);
            self.stats.deferred_steps = self.stats.deferred_steps.wrapping_add(1);
        }
        false
    }
}

#[cfg(all(test, feature = "sync"))]
mod tests {
    extern crate std;
    use super::super::{SyncState, TimeConfig, TimeReply, TIER_UNSYNCED};
    use super::*;
    use crate::time::{Instant, SystemInstant};

    /// One exchange on `link` at local `sent` with a tier-`tier` neighbour
    /// whose time is `theirs(local)`; a symmetric 200 µs round trip.
    /// Returns the local time the reply arrived.
    fn exchange(
        c: &mut Clock<2>,
        link: usize,
        tier: u8,
        sent: u64,
        theirs: impl Fn(f64) -> f64,
    ) -> u64 {
        let rtt = 200;
        let mid = sent as f64 + rtt as f64 / 2.0;
        let reply = TimeReply {
            request_time: Instant::from_micros(sent),
            responder_time: SystemInstant::from_micros(theirs(mid).round() as u64),
            responder_tier: tier,
        };
        c.on_reply(link, &reply, Instant::from_micros(sent + rtt));
        sent + rtt
    }

    #[test]
    fn an_untrusted_link_is_never_followed_and_its_claims_are_counted() {
        let mut c: Clock<2> = Clock::new(TimeConfig::default());
        c.set_trust(Trust::NONE.with_link(1));
        for i in 0..40u64 {
            let t = exchange(&mut c, 0, 0, 10_000 + i * 50_000, |l| l + 3.7e9);
            assert_eq!(
                c.system_time(Instant::from_micros(t)),
                SystemInstant::from_micros(t),
                "moved by an untrusted root"
            );
        }
        assert_eq!(c.tier(), TIER_UNSYNCED);
        assert_eq!(c.state(), SyncState::Unsynced);
        assert_eq!(c.status().stats.untrusted, 40);
        assert_eq!(c.status().stats.jumps, 0);
        // The trusted link is followed.
        let mut t = 0;
        for i in 0..40u64 {
            t = exchange(&mut c, 1, 0, 3_000_000 + i * 50_000, |l| l + 1_000.0);
        }
        assert_eq!(c.tier(), 1);
        assert!(
            (c.system_time(Instant::from_micros(t)).as_micros() as f64 - (t as f64 + 1_000.0))
                .abs()
                < 3.0
        );
        // Trust withdrawn: the neighbour is forgotten and no longer moves
        // the clock.
        c.set_trust(Trust::NONE);
        let before = c.status().stats;
        let t = exchange(&mut c, 1, 0, 6_000_000, |l| l + 9_000.0);
        assert_eq!(c.status().stats.untrusted, before.untrusted + 1);
        assert_eq!(c.status().stats.jumps, before.jumps);
        assert!(
            (c.system_time(Instant::from_micros(t)).as_micros() as f64 - (t as f64 + 1_000.0))
                .abs()
                < 10.0
        );
    }

    #[test]
    fn remote_writes_need_a_trusted_link() {
        let mut c: Clock<2> = Clock::new(TimeConfig::default());
        assert!(c.admits_write_from(0), "a module trusts every link");
        c.set_trust(Trust::links(0b10));
        assert!(!c.admits_write_from(0));
        assert!(c.admits_write_from(1));
        assert!(c.admits_write_from(crate::netresponder::ARRIVED_LOCALLY));
        assert!(!c.admits_write_from(200));
        assert_eq!(c.status().stats.untrusted, 2);
        assert!(!Trust::ALL.trusts(64));
        assert_eq!(Trust::NONE.with_link(70), Trust::NONE);
        assert_eq!(Trust::ALL.without_link(3).mask(), !(1 << 3));
    }

    /// Follows a neighbour 1 ms ahead until settled, then the neighbour's
    /// time jumps 5 ms ahead; returns the clock and the local time.
    fn settled_then_jump(motion: bool) -> (Clock<2>, u64, impl Fn(f64) -> f64) {
        let mut c: Clock<2> = Clock::new(TimeConfig::default());
        let before = |l: f64| l + 1_000.0 + l * 20e-6;
        let mut sent = 10_000;
        while sent < 5_000_000 {
            exchange(&mut c, 0, 0, sent, before);
            sent += 50_000;
        }
        assert!(c.status().settled, "{:?}", c.status());
        c.set_motion_active(motion);
        let after = |l: f64| l + 6_000.0 + l * 20e-6;
        (c, sent, after)
    }

    #[test]
    fn no_step_under_motion_the_offset_is_slewed_within_the_clamp() {
        let (mut c, mut sent, after) = settled_then_jump(true);
        let jumps = c.status().stats.jumps;
        let max = f64::from(c.config().max_rate_ppm) * 1e-6;
        let (mut last_local, mut last_sys) =
            (sent, c.system_time(Instant::from_micros(sent)).as_micros());
        let mut caught_up = None;
        while sent < 40_000_000 {
            let t = exchange(&mut c, 0, 0, sent, &after);
            // System time advances at the oscillator rate (20 ppm here)
            // plus at most the clamp, never by a step: by no more than the
            // one µs that readings in whole µs may add.
            for local in [t, sent + 25_000] {
                let sys = c.system_time(Instant::from_micros(local));
                let span = (local - last_local) as f64;
                let rate = (sys.as_micros() as f64 - last_sys as f64) / span - 1.0;
                assert!(
                    rate.abs() <= 20e-6 + max * 1.01 + 1.0 / span,
                    "rate {rate} at {local}"
                );
                (last_local, last_sys) = (local, sys.as_micros());
            }
            if caught_up.is_none()
                && (c.system_time(Instant::from_micros(t)).as_micros() as f64 - after(t as f64))
                    .abs()
                    < 20.0
            {
                caught_up = Some(t);
            }
            sent += 50_000;
        }
        let s = c.status();
        assert_eq!(s.stats.jumps, jumps, "stepped under motion");
        assert_eq!(s.stats.deferred_steps, 1);
        // 5 ms at up to 500 ppm: about 10 s.
        let took = caught_up.expect("never caught up") - 5_000_000;
        std::eprintln!("5 ms slewed away in {:.2} s", took as f64 * 1e-6);
        assert!((9_000_000..16_000_000).contains(&took), "took {took} µs");
        assert!(s.settled, "{s:?}");
    }

    #[test]
    fn without_motion_a_jump_is_stepped() {
        let (mut c, mut sent, after) = settled_then_jump(false);
        let jumps = c.status().stats.jumps;
        let mut t = sent;
        while sent < 6_000_000 {
            t = exchange(&mut c, 0, 0, sent, &after);
            sent += 50_000;
        }
        let s = c.status();
        assert_eq!(s.stats.jumps, jumps + 1);
        assert_eq!(s.stats.deferred_steps, 0);
        assert!(
            (c.system_time(Instant::from_micros(t)).as_micros() as f64 - after(t as f64)).abs()
                < 20.0
        );
    }
}
