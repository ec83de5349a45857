//! Acceleration limits that depend on speed and direction: a model of what
//! the machine's motors can give (see [`AccelModel`]).

use core::fmt::Debug;

/// The largest acceleration a machine can give, by direction and speed:
/// for a machine of steppers, the torque each motor has left at the speed
/// it turns, over what the move's masses and rotors need.
///
/// The planner asks for each segment, moving along its direction, at the
/// highest speed the segment can reach (its speed limit, or what its
/// junction speed plus a full-acceleration ramp allows), and uses the answer
/// as the segment's acceleration within its limits; and for each corner,
/// accelerating along the velocity change at the slower neighbour's speed
/// limit. Because a motor's torque only falls with speed, the answer holds
/// at every speed the segment reaches.
pub trait AccelModel<const N: usize>: Send + Sync + Debug {
    /// The largest acceleration (units/s², ≥ 0) along `accel` (a unit
    /// vector) while moving along `motion` (a unit vector, the path's
    /// direction) at up to `speed` units/s.
    fn max_accel(&self, motion: &[f64; N], accel: &[f64; N], speed: f64) -> f64;
}
