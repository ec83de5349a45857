//! The motor as a torque device: `set_torque` and `torque_off`.
//!
//! A stepper's torque follows the angle between its coils' current vector
//! and its rotor: with the current `I` at electrical angle `φ` and the
//! rotor at `θ`, it is `T_hold·(I/I_rated)·sin(φ − θ)` (the rotor is pulled
//! towards `φ`, hardest a full step, 90° electrical, away). So a module
//! that reads its shaft from an encoder and keeps the current one full
//! step ahead of it (or behind, for a negative torque) at a fraction `f`
//! of the rated current gets `f·T_hold` at any angle: the commutation a
//! brushless drive does, here from maxl's sine table
//! ([`maxl::phase::PhaseOut`]). At speed the driver's supply cannot push
//! the full current through the coils' back-EMF and inductance, and the
//! torque falls as `maxl::motor::StepperModel` describes.
//!
//! The board supplies the shaft angle ([`StepperHw::read_shaft`]) and
//! drives the coils ([`StepperHw::drive_coils`]); a board without either
//! refuses the mode ([`StepperError::Unsupported`]). The firmware calls
//! [`Module::commutate`] from a periodic timer; each call reads the shaft, sets the coils, and keeps
//! the reading for `get_position`, which in torque mode reports where the
//! shaft is (the cable length a winch reads), not where steps put it.
//!
//! Safe by default: the torque ends, and the step input takes the coils
//! back holding the shaft where it stands, on `torque_off`, `halt`,
//! `set_enable`, a comparator's halt, the output watchdog, and a lost
//! encoder (the axis then halts too). Holding is the motor's safe state
//! for a hanging load: a torque of zero would let it fall.
//!
//! [`StepperHw::read_shaft`]: crate::board::StepperHw::read_shaft
//! [`StepperHw::drive_coils`]: crate::board::StepperHw::drive_coils

use crate::board::Board;
use crate::fault::FaultKind;
use crate::stepper::StepperError;
use crate::Module;
use maxl::phase::{Coils, PhaseOut};
use maxl::Fx;
use osap_core::Instant;

/// One full step, 90° electrical, in Q16.16 full steps: how far ahead of
/// the rotor the current is put.
const QUARTER: i64 = 1 << 16;

/// The detail of the [`FaultKind::Halted`] fault a lost encoder records
/// (`halt` records 0).
pub const ENCODER_LOST: u32 = 1;

/// The torque request: what `set_torque` asked for, while the motor is a
/// torque device.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Torque {
    /// The fraction of the holding torque, `-1..=1`; `None` in position
    /// mode.
    fraction: Option<f32>,
    /// Commutations since boot.
    commutations: u32,
}

impl Torque {
    /// The fraction of holding torque asked for; `None` in position mode.
    pub fn fraction(&self) -> Option<f32> {
        self.fraction
    }

    /// Commutations since boot.
    pub fn commutations(&self) -> u32 {
        self.commutations
    }
}

/// The coils for `fraction` of the holding torque with the shaft at
/// `shaft` (Q16.16 full steps): the current a full step ahead of the
/// rotor for a positive torque, behind for a negative one, at `|fraction|`
/// of the rated current.
pub fn coils_for(shaft: i64, fraction: f32) -> Coils {
    let ahead = if fraction >= 0.0 { QUARTER } else { -QUARTER };
    // The quadrant and angle are the low 18 bits: wrapping is exact.
    let angle = Fx(shaft.wrapping_add(ahead) as i32);
    let size = if fraction < 0.0 { -fraction } else { fraction };
    let peak = (size.min(1.0) * 32_768.0 + 0.5) as u16;
    PhaseOut::new(peak).coils(angle)
}

impl<B: Board> Module<B> {
    /// `set_torque`: see the function table.
    pub(crate) fn torque_request(&mut self, fraction: f32) -> Result<(), StepperError> {
        if !(fraction.is_finite() && (-1.0..=1.0).contains(&fraction)) {
            return Err(StepperError::BadValue);
        }
        if self.torque.fraction.is_none() {
            let shaft = self
                .board
                .stepper()
                .read_shaft()
                .ok_or(StepperError::Unsupported)?;
            let now = self.system_now();
            self.stepper.enter_torque(now, shaft)?;
            if !self
                .board
                .stepper()
                .drive_coils(Some(coils_for(shaft, 0.0)))
            {
                self.stepper.leave_torque();
                return Err(StepperError::Unsupported);
            }
        }
        self.torque.fraction = Some(fraction);
        let now = self.board.now();
        self.commutate(now);
        Ok(())
    }

    /// In torque mode, reads the shaft and sets the coils for the torque
    /// asked for (see the module docs); nothing in position mode. The
    /// firmware calls it from a periodic timer at local time `now`: the
    /// current falls behind a turning rotor by the angle it turns in a
    /// period (at 1 kHz and 1 rev/s, 18° electrical, 5 % of the torque
    /// at worst). A shaft that cannot be read
    /// ends the torque and halts the axis, recording a
    /// [`FaultKind::Halted`] fault with detail [`ENCODER_LOST`].
    pub fn commutate(&mut self, now: Instant) {
        let Some(fraction) = self.torque.fraction else {
            return;
        };
        match self.board.stepper().read_shaft() {
            Some(shaft) => {
                let at = self.time.system_time(now);
                self.stepper.read_shaft(at, shaft);
                self.board
                    .stepper()
                    .drive_coils(Some(coils_for(shaft, fraction)));
                self.torque.commutations = self.torque.commutations.wrapping_add(1);
            }
            None => {
                self.end_torque();
                self.stepper.halt();
                let at = self.time.system_time(now);
                self.fault.record(at, FaultKind::Halted, ENCODER_LOST, true);
            }
        }
    }

    /// Ends torque mode, if on: the step input takes the coils back,
    /// holding the shaft where it was last read, and the axis rests there.
    pub fn end_torque(&mut self) {
        if self.torque.fraction.take().is_some() {
            self.board.stepper().drive_coils(None);
            self.stepper.leave_torque();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `T ∝ b·cos θ − a·sin θ` for a rotor at electrical angle `θ`.
    fn torque(c: Coils, shaft: i64) -> f64 {
        let theta = core::f64::consts::FRAC_PI_2 * shaft as f64 / 65_536.0;
        (f64::from(c.b) * theta.cos() - f64::from(c.a) * theta.sin()) / 32_768.0
    }

    #[test]
    fn the_current_leads_the_rotor_by_a_full_step_at_any_angle() {
        // Across four electrical periods, both signs, and negative turns:
        // the torque is the fraction asked for within the table's error.
        for fraction in [1.0f32, 0.5, 0.1, -0.3, -1.0, 0.0] {
            for k in -300..300 {
                let shaft = k * 3_511 - 40 * 65_536;
                let t = torque(coils_for(shaft, fraction), shaft);
                assert!(
                    (t - f64::from(fraction)).abs() < 2e-4,
                    "{fraction} at {shaft}: {t}"
                );
            }
        }
    }
}
