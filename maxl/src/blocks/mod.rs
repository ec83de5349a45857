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
pub mod timer;
