//! The critical section: BASEPRI, not PRIMASK.
//!
//! Entering a critical section raises BASEPRI to [`CS_PRIORITY`], masking
//! every interrupt except those at the top priority (0x00), where only the
//! step tick interrupt ([`crate::steps`]) runs. So no critical section
//! anywhere (the module logic's, embassy's, the time driver's) delays a
//! step edge; the tick interrupt in turn takes no critical section and
//! shares only lock-free atomics.
//!
//! Cortex-M4 erratum 837070 (a BASEPRI raise may let one more interrupt in)
//! is avoided as usual: the write is done with PRIMASK set.

use cortex_m::register::{basepri, basepri_max, primask};

/// BASEPRI inside a critical section: masks priorities 0x20 and lower
/// (the SAMD51 has 3 priority bits, the top three of the byte).
pub(crate) const CS_PRIORITY: u8 = 0x20;

struct BasepriCriticalSection;
critical_section::set_impl!(BasepriCriticalSection);

// SAFETY: single core; every interrupt that takes a critical section runs
// at priority 0x20 or lower, so with BASEPRI at 0x20 none of them can
// preempt the holder. The previous BASEPRI is restored on release, so
// sections nest.
unsafe impl critical_section::Impl for BasepriCriticalSection {
    unsafe fn acquire() -> u32 {
        let old = u32::from(basepri::read());
        let was_active = primask::read().is_active();
        cortex_m::interrupt::disable();
        // Only raises the masking level (BASEPRI_MAX).
        basepri_max::write(CS_PRIORITY);
        if was_active {
            // SAFETY: interrupts were enabled on entry; re-enabling them
            // now only ends the PRIMASK window used for the erratum.
            unsafe { cortex_m::interrupt::enable() };
        }
        old
    }

    unsafe fn release(old: u32) {
        // SAFETY: restores the level acquire() found.
        unsafe { basepri::write(old as u8) };
    }
}
