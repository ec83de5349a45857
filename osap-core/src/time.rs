//! Typed time: a local instant, a synchronized (system) instant, a duration.
//!
//! Every device counts microseconds on its own free-running counter; clock
//! synchronization maps that local count onto one system time shared by the
//! whole network. Both are plain µs counts on the wire, and mixing them up
//! is exactly the mistake clock sync exists to prevent, so here they are
//! different types:
//!
//! - [`Instant`]: a reading of this device's local counter. Deadlines,
//!   timeouts and link timing use it.
//! - [`SystemInstant`]: a point on the synchronized system clock. Motion
//!   tracks, sample stamps and time replies use it.
//! - [`Duration`]: a span of µs, the same for both.
//!
//! The only way from one instant to the other is a clock's time map
//! ([`crate::clock::TimeMap::system_time`], [`crate::clock::TimeMap::local_time`]).
//!
//! Arithmetic saturates instead of wrapping or panicking: a deadline past the
//! end of time stays at [`Instant::MAX`], and an instant minus a later one is
//! [`Duration::ZERO`]. Time values arrive from the wire, and nothing from the
//! wire may panic a runtime.

use core::fmt;
use core::ops::{Add, AddAssign, Div, Mul, Sub, SubAssign};

/// A span of time, in whole microseconds.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct Duration {
    micros: u64,
}

impl Duration {
    /// No time at all.
    pub const ZERO: Duration = Duration { micros: 0 };
    /// The longest span that can be held.
    pub const MAX: Duration = Duration { micros: u64::MAX };

    /// A span of `micros` microseconds.
    #[inline]
    pub const fn from_micros(micros: u64) -> Duration {
        Duration { micros }
    }

    /// A span of `millis` milliseconds (saturating).
    #[inline]
    pub const fn from_millis(millis: u64) -> Duration {
        Duration {
            micros: millis.saturating_mul(1_000),
        }
    }

    /// A span of `secs` seconds (saturating).
    #[inline]
    pub const fn from_secs(secs: u64) -> Duration {
        Duration {
            micros: secs.saturating_mul(1_000_000),
        }
    }

    /// The span in whole microseconds.
    #[inline]
    pub const fn as_micros(self) -> u64 {
        self.micros
    }

    /// The span in whole milliseconds, rounded down.
    #[inline]
    pub const fn as_millis(self) -> u64 {
        self.micros / 1_000
    }

    /// The span in seconds, as a float.
    #[inline]
    pub fn as_secs_f64(self) -> f64 {
        self.micros as f64 * 1e-6
    }

    /// `self + other`, or `None` on overflow.
    #[inline]
    pub const fn checked_add(self, other: Duration) -> Option<Duration> {
        match self.micros.checked_add(other.micros) {
            Some(micros) => Some(Duration { micros }),
            None => None,
        }
    }

    /// `self - other`, or `None` if `other` is longer.
    #[inline]
    pub const fn checked_sub(self, other: Duration) -> Option<Duration> {
        match self.micros.checked_sub(other.micros) {
            Some(micros) => Some(Duration { micros }),
            None => None,
        }
    }

    /// `self + other`, held at [`Duration::MAX`].
    #[inline]
    pub const fn saturating_add(self, other: Duration) -> Duration {
        Duration {
            micros: self.micros.saturating_add(other.micros),
        }
    }

    /// `self - other`, held at [`Duration::ZERO`].
    #[inline]
    pub const fn saturating_sub(self, other: Duration) -> Duration {
        Duration {
            micros: self.micros.saturating_sub(other.micros),
        }
    }
}

impl From<Duration> for core::time::Duration {
    fn from(d: Duration) -> core::time::Duration {
        core::time::Duration::from_micros(d.micros)
    }
}

impl From<core::time::Duration> for Duration {
    /// Whole microseconds, rounded down and held at [`Duration::MAX`].
    fn from(d: core::time::Duration) -> Duration {
        Duration {
            micros: u64::try_from(d.as_micros()).unwrap_or(u64::MAX),
        }
    }
}

impl Add for Duration {
    type Output = Duration;
    #[inline]
    fn add(self, rhs: Duration) -> Duration {
        self.saturating_add(rhs)
    }
}

impl AddAssign for Duration {
    #[inline]
    fn add_assign(&mut self, rhs: Duration) {
        *self = *self + rhs;
    }
}

impl Sub for Duration {
    type Output = Duration;
    #[inline]
    fn sub(self, rhs: Duration) -> Duration {
        self.saturating_sub(rhs)
    }
}

impl SubAssign for Duration {
    #[inline]
    fn sub_assign(&mut self, rhs: Duration) {
        *self = *self - rhs;
    }
}

impl Mul<u64> for Duration {
    type Output = Duration;
    #[inline]
    fn mul(self, rhs: u64) -> Duration {
        Duration {
            micros: self.micros.saturating_mul(rhs),
        }
    }
}

impl Div<u64> for Duration {
    type Output = Duration;
    /// Divides the span; dividing by zero gives [`Duration::MAX`] rather
    /// than a panic.
    #[inline]
    fn div(self, rhs: u64) -> Duration {
        Duration {
            micros: self.micros.checked_div(rhs).unwrap_or(u64::MAX),
        }
    }
}

impl fmt::Debug for Duration {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}µs", self.micros)
    }
}

impl fmt::Display for Duration {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} µs", self.micros)
    }
}

/// Defines an instant type on one clock; the two clocks share the arithmetic
/// but not the type, so they cannot be mixed.
macro_rules! instant_type {
    ($(#[$doc:meta])* $name:ident, $what:literal) => {
        $(#[$doc])*
        #[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
        pub struct $name {
            micros: u64,
        }

        impl $name {
            #[doc = concat!("The start of ", $what, " (0 µs).")]
            pub const ZERO: $name = $name { micros: 0 };
            #[doc = concat!("The last representable instant of ", $what, ".")]
            pub const MAX: $name = $name { micros: u64::MAX };

            #[doc = concat!("The instant `micros` µs into ", $what, ".")]
            #[inline]
            pub const fn from_micros(micros: u64) -> $name {
                $name { micros }
            }

            #[doc = concat!("This instant as µs of ", $what, " (its wire form).")]
            #[inline]
            pub const fn as_micros(self) -> u64 {
                self.micros
            }

            /// The time since `earlier`, or [`Duration::ZERO`] if `earlier`
            /// is in fact later.
            #[inline]
            pub const fn saturating_duration_since(self, earlier: $name) -> Duration {
                Duration { micros: self.micros.saturating_sub(earlier.micros) }
            }

            /// The time since `earlier`, or `None` if `earlier` is later.
            #[inline]
            pub const fn checked_duration_since(self, earlier: $name) -> Option<Duration> {
                match self.micros.checked_sub(earlier.micros) {
                    Some(micros) => Some(Duration { micros }),
                    None => None,
                }
            }

            /// The time between `self` and `other`, whichever is later.
            #[inline]
            pub const fn abs_diff(self, other: $name) -> Duration {
                Duration { micros: self.micros.abs_diff(other.micros) }
            }

            /// Signed µs from `other` to `self`: positive if `self` is later.
            /// Differences beyond ±2⁶³ µs wrap (that is 292 000 years).
            #[inline]
            pub const fn signed_micros_since(self, other: $name) -> i64 {
                self.micros.wrapping_sub(other.micros) as i64
            }

            /// `self + d`, or `None` past [`Self::MAX`].
            #[inline]
            pub const fn checked_add(self, d: Duration) -> Option<$name> {
                match self.micros.checked_add(d.micros) {
                    Some(micros) => Some($name { micros }),
                    None => None,
                }
            }

            /// `self - d`, or `None` before [`Self::ZERO`].
            #[inline]
            pub const fn checked_sub(self, d: Duration) -> Option<$name> {
                match self.micros.checked_sub(d.micros) {
                    Some(micros) => Some($name { micros }),
                    None => None,
                }
            }

            /// `self + d`, held at [`Self::MAX`].
            #[inline]
            pub const fn saturating_add(self, d: Duration) -> $name {
                $name { micros: self.micros.saturating_add(d.micros) }
            }

            /// `self - d`, held at [`Self::ZERO`].
            #[inline]
            pub const fn saturating_sub(self, d: Duration) -> $name {
                $name { micros: self.micros.saturating_sub(d.micros) }
            }
        }

        impl Add<Duration> for $name {
            type Output = $name;
            /// Saturates at [`Self::MAX`].
            #[inline]
            fn add(self, d: Duration) -> $name {
                self.saturating_add(d)
            }
        }

        impl AddAssign<Duration> for $name {
            #[inline]
            fn add_assign(&mut self, d: Duration) {
                *self = *self + d;
            }
        }

        impl Sub<Duration> for $name {
            type Output = $name;
            /// Saturates at [`Self::ZERO`].
            #[inline]
            fn sub(self, d: Duration) -> $name {
                self.saturating_sub(d)
            }
        }

        impl SubAssign<Duration> for $name {
            #[inline]
            fn sub_assign(&mut self, d: Duration) {
                *self = *self - d;
            }
        }

        impl Sub for $name {
            type Output = Duration;
            /// The time from `rhs` to `self`; [`Duration::ZERO`] if `rhs` is
            /// later.
            #[inline]
            fn sub(self, rhs: $name) -> Duration {
                self.saturating_duration_since(rhs)
            }
        }

        impl fmt::Debug for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                write!(f, concat!(stringify!($name), "({}µs)"), self.micros)
            }
        }

        impl fmt::Display for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                write!(f, "{} µs", self.micros)
            }
        }
    };
}

instant_type!(
    /// A reading of this device's local µs counter: free-running since boot,
    /// never stepped, never shared. Deadlines, timeouts and link timing are
    /// local instants. Turn one into system time only through a clock's
    /// [`TimeMap`](crate::clock::TimeMap).
    Instant,
    "the local counter"
);

instant_type!(
    /// A point on the synchronized system clock, the one time the whole
    /// network agrees on (µs). Motion tracks, sample stamps and time replies
    /// are system instants. Get one from a local [`Instant`] only through a
    /// clock's [`TimeMap`](crate::clock::TimeMap).
    SystemInstant,
    "system time"
);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arithmetic_saturates_instead_of_panicking() {
        let t = Instant::from_micros(10);
        assert_eq!(t - Duration::from_micros(20), Instant::ZERO);
        assert_eq!(Instant::MAX + Duration::from_micros(1), Instant::MAX);
        assert_eq!(t - Instant::from_micros(30), Duration::ZERO);
        assert_eq!(Instant::from_micros(30) - t, Duration::from_micros(20));
        assert_eq!(
            Duration::from_micros(5) - Duration::from_micros(9),
            Duration::ZERO
        );
        assert_eq!(Duration::MAX + Duration::from_micros(1), Duration::MAX);
        assert_eq!(Duration::from_micros(9) / 0, Duration::MAX);
        assert_eq!(Duration::from_micros(9) * 3, Duration::from_micros(27));
    }

    #[test]
    fn checked_forms_report_overflow() {
        let t = SystemInstant::from_micros(10);
        assert_eq!(t.checked_sub(Duration::from_micros(11)), None);
        assert_eq!(
            t.checked_add(Duration::from_micros(1)),
            Some(SystemInstant::from_micros(11))
        );
        assert_eq!(
            SystemInstant::MAX.checked_add(Duration::from_micros(1)),
            None
        );
        assert_eq!(
            t.checked_duration_since(SystemInstant::from_micros(11)),
            None
        );
        assert_eq!(Duration::MAX.checked_add(Duration::from_micros(1)), None);
        assert_eq!(Duration::ZERO.checked_sub(Duration::from_micros(1)), None);
    }

    #[test]
    fn signed_difference_has_a_sign() {
        let a = Instant::from_micros(100);
        let b = Instant::from_micros(250);
        assert_eq!(b.signed_micros_since(a), 150);
        assert_eq!(a.signed_micros_since(b), -150);
        assert_eq!(a.abs_diff(b), Duration::from_micros(150));
        assert_eq!(b.abs_diff(a), Duration::from_micros(150));
    }

    #[test]
    fn units_convert() {
        assert_eq!(Duration::from_millis(3).as_micros(), 3_000);
        assert_eq!(Duration::from_secs(2).as_millis(), 2_000);
        assert_eq!(Duration::from_secs(u64::MAX), Duration::MAX);
        let std: core::time::Duration = Duration::from_micros(1_500).into();
        assert_eq!(std, core::time::Duration::from_micros(1_500));
        assert_eq!(
            Duration::from(core::time::Duration::from_nanos(2_999)),
            Duration::from_micros(2)
        );
    }

    #[test]
    fn formats_say_which_clock() {
        extern crate std;
        use std::format;
        assert_eq!(format!("{:?}", Instant::from_micros(7)), "Instant(7µs)");
        assert_eq!(
            format!("{:?}", SystemInstant::from_micros(7)),
            "SystemInstant(7µs)"
        );
        assert_eq!(format!("{}", Duration::from_micros(7)), "7 µs");
    }
}
