//! Host motion blocks (`std`): each is a plain Rust type usable directly from
//! a script and, through `#[pipes_core::class]`, a PIPES class a host runtime
//! runs and pipes to and from modules.

pub mod bedlevel;
pub mod chirp;
pub mod interp;
pub mod kinematics;
pub mod onedof;
pub mod optimizer;
pub mod planner;
pub mod pressure_advance;
pub mod shaper;
pub mod timer;

use std::collections::VecDeque;

/// The points stamped `first`, `first + step`, `first + 2·step` and
/// `first + 3·step` in a history ordered by stamp, if all four are held:
/// the control points of one spline segment.
fn four_points<T: Copy>(history: &VecDeque<(u64, T)>, first: u64, step: u64) -> Option<[T; 4]> {
    let i = history.binary_search_by_key(&first, |&(t, _)| t).ok()?;
    let mut out = [history[i].1; 4];
    for (k, slot) in out.iter_mut().enumerate() {
        let &(t, x) = history.get(i + k)?;
        if t != first + k as u64 * step {
            return None;
        }
        *slot = x;
    }
    Some(out)
}
