//! A firmware that never installed its board: every function fails with
//! one clear code, and the step generator makes no steps.

use osap_module::functions::{self as f, NOT_INSTALLED};
use osap_module::{fill_step_word, limit_changed};
use pipes_core::function::CallError;

#[test]
fn every_function_refuses_before_install() {
    let refused = Err(CallError::Failed(NOT_INSTALLED));
    assert_eq!(f::add_point(0, 0.0), refused);
    assert_eq!(f::set_enable(true), refused);
    assert_eq!(f::get_position().map(|_| ()), refused);
    assert_eq!(f::digital_write(0, true), refused);
    assert_eq!(fill_step_word(0), 0);
    limit_changed(0, true);
    assert_eq!(f::read_limit().map(|_| ()), refused);
}
