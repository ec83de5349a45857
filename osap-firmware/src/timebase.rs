//! The arithmetic of a 64-bit time base built on a 32-bit hardware counter,
//! for boards whose time driver is a plain timer (the SAMD51's TC2+TC3 pair
//! as one 32-bit counter at 1 MHz). Kept free of registers so it is tested
//! on the host.
//!
//! ## Half-period counting
//!
//! The counter wraps every 2³² ticks (71.6 minutes at 1 MHz). The driver
//! keeps a `period` count that goes up by one twice per wrap: at the
//! overflow (counter back to 0) and when the counter passes
//! [`HALF`] (a compare channel set to `0x8000_0000`). So an even period
//! means the counter should be in the lower half, an odd one the upper
//! half, and [`now`] joins the two:
//!
//! ```text
//! now = period · 2³¹ + (counter XOR (period & 1) · 2³¹)
//! ```
//!
//! Because each half is told apart by its top bit, a bump that comes late
//! (the counter has already wrapped but the overflow interrupt has not yet
//! run, so `period` is still odd) still gives the right time: the counter's
//! small value has its top bit clear, the XOR sets it, and the sum lands in
//! the next period. Any bump up to half a wrap (35 minutes) late is
//! absorbed, which no interrupt latency comes near. The same scheme is used
//! by embassy-nrf and embassy-stm32.
//!
//! ## Alarms
//!
//! A compare channel matches when the low 32 bits of the counter equal its
//! value, which happens once every wrap. An alarm is armed on the channel
//! only when it is less than [`ARM_LIMIT`] ticks ahead, so the first match
//! is the right one; later ones are left for a period bump to re-check
//! ([`alarm_action`] each time). The interrupt confirms with [`is_due`]
//! before firing, so a stale or early match does nothing.

/// The counter value at which the period is bumped between overflows.
pub const HALF: u32 = 0x8000_0000;

/// Alarms further ahead than this many ticks are not armed on the compare
/// channel yet: a period bump re-checks them (every 2³¹ ticks), and by
/// then they are within reach.
pub const ARM_LIMIT: u64 = 0xC000_0000;

/// The 64-bit time of counter reading `counter` taken while the period
/// count was `period` (see the module docs for why a late bump is fine).
pub const fn now(period: u32, counter: u32) -> u64 {
    ((period as u64) << 31) + (counter ^ ((period & 1) << 31)) as u64
}

/// What to do with an alarm for time `at` when it is `now`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AlarmAction {
    /// The time has come already: fire now (a driver's `set_alarm`
    /// reports "not set" and the queue runs at once).
    Past,
    /// Write this value to the compare channel and enable its interrupt.
    Arm(u32),
    /// Too far ahead for the 32-bit compare: leave it disarmed; a period
    /// bump asks again.
    Defer,
}

/// Whether and how to arm an alarm for `at` at time `now`.
pub const fn alarm_action(now: u64, at: u64) -> AlarmAction {
    if at <= now {
        AlarmAction::Past
    } else if at - now < ARM_LIMIT {
        // Truncation: the compare sees only the counter's 32 bits.
        AlarmAction::Arm(at as u32)
    } else {
        AlarmAction::Defer
    }
}

/// Whether an alarm for `at` is due at `now` (the compare interrupt checks
/// this before firing, so spurious or stale matches are harmless).
pub const fn is_due(now: u64, at: u64) -> bool {
    at <= now
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A model of the hardware: a free-running counter and a period count
    /// whose bumps may be applied late, as an interrupt would.
    struct Model {
        ticks: u64,
        period: u32,
    }

    impl Model {
        fn counter(&self) -> u32 {
            self.ticks as u32
        }

        /// Applies every bump due by now (the interrupt ran).
        fn catch_up(&mut self) {
            self.period = (self.ticks >> 31) as u32;
        }
    }

    #[test]
    fn counts_through_many_wraps() {
        let mut m = Model {
            ticks: 0,
            period: 0,
        };
        // Steps that do not divide a wrap, across several wraps.
        let step = 0x1234_5679u64;
        while m.ticks < 5 << 32 {
            m.catch_up();
            assert_eq!(now(m.period, m.counter()), m.ticks);
            m.ticks += step;
        }
    }

    #[test]
    fn wraparound_edges() {
        // Just before and at the overflow, with the interrupts on time.
        assert_eq!(now(1, 0xFFFF_FFFF), 0xFFFF_FFFF);
        assert_eq!(now(2, 0), 1 << 32);
        assert_eq!(now(2, 1), (1 << 32) + 1);
        // The half-way bump.
        assert_eq!(now(0, HALF - 1), u64::from(HALF) - 1);
        assert_eq!(now(1, HALF), u64::from(HALF));
        // Far along: period 2·10⁶ is ≈ 136 years at 1 MHz.
        assert_eq!(now(2_000_000, 5), (2_000_000u64 << 31) + 5);
    }

    #[test]
    fn late_overflow_interrupt() {
        // The counter wrapped, but the overflow interrupt has not bumped
        // the period from 1 to 2 yet: the time still moves forward.
        for counter in [0u32, 1, 1000, 0x7FFF_FFFF] {
            assert_eq!(now(1, counter), (1u64 << 32) + u64::from(counter));
        }
        // The same at the half-way bump: counter past HALF, period even.
        assert_eq!(now(2, HALF + 7), (2u64 << 31) + u64::from(HALF) + 7);
        // And seen through the model: bumps up to half a wrap late.
        let mut m = Model {
            ticks: 0,
            period: 0,
        };
        let mut last = 0;
        while m.ticks < 3 << 32 {
            let t = now(m.period, m.counter());
            assert_eq!(t, m.ticks, "period {} counter {:#x}", m.period, m.counter());
            assert!(t >= last);
            last = t;
            m.ticks += 0x0765_4321;
            // Catch up only every third step (late interrupts).
            if (m.ticks / 0x0765_4321).is_multiple_of(3) {
                m.catch_up();
            }
        }
    }

    #[test]
    fn alarms_across_the_wrap() {
        let now_t = 0xFFFF_FF00u64;
        let at = (1u64 << 32) + 0x100;
        assert_eq!(alarm_action(now_t, at), AlarmAction::Arm(0x100));
        // The compare matches when the counter first reads 0x100, which is
        // after the wrap: the time then is `at` exactly.
        assert_eq!(now(2, 0x100), at);
        assert!(is_due(now(2, 0x100), at));
        assert!(!is_due(now(1, 0xFFFF_FFFF), at));
        // A stale match of the same low bits one wrap earlier is not due.
        assert!(!is_due(0x100, at));
    }

    #[test]
    fn alarms_in_the_past_fire_at_once() {
        assert_eq!(alarm_action(1000, 1000), AlarmAction::Past);
        assert_eq!(alarm_action(1000, 999), AlarmAction::Past);
        assert_eq!(alarm_action(1000, 0), AlarmAction::Past);
        assert_eq!(alarm_action(1000, 1001), AlarmAction::Arm(1001));
        assert!(is_due(1000, 1000));
        assert!(!is_due(999, 1000));
    }

    #[test]
    fn far_alarms_are_deferred_until_a_period_bump_brings_them_near() {
        let start = 0x1_2345_6789u64;
        let at = start + ARM_LIMIT + 10;
        assert_eq!(alarm_action(start, at), AlarmAction::Defer);
        assert_eq!(alarm_action(start, start + ARM_LIMIT), AlarmAction::Defer);
        assert_eq!(
            alarm_action(start, start + ARM_LIMIT - 1),
            AlarmAction::Arm((start + ARM_LIMIT - 1) as u32)
        );
        // Re-checked at each period bump (every 2³¹ ticks): the first bump
        // after `start` is at most 2³¹ later, and then the alarm is less
        // than ARM_LIMIT ahead.
        let next_bump = (start >> 31).saturating_add(1) << 31;
        assert!(next_bump - start <= 1 << 31);
        assert_eq!(alarm_action(next_bump, at), AlarmAction::Arm(at as u32));
        // However far ahead, an alarm is never armed on a stale low word.
        let never = u64::MAX;
        assert_eq!(alarm_action(start, never), AlarmAction::Defer);
    }
}
