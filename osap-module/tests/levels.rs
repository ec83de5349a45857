//! Level and event tracks: PWM duties ramped or stepped at stamped times
//! and pin changes at stamped times, applied by the module's own loop
//! (`poll_io`, woken at `io_wake_at`), bounded queues that refuse, and
//! every stop clearing what waits before the safe values go out.

use osap_core::time::{Instant, SystemInstant};
use osap_module::board::{Board, IoHw, StepperHw};
use osap_module::io::IoError;
use osap_module::levels::{EVENT_POINTS, LEVEL_POINTS, LEVEL_UPDATE_US};
use osap_module::Module;
use pipes_core::function::CallError;
use pipes_core::FailureCode;
use std::cell::Cell;
use std::rc::Rc;

struct Driver;

impl StepperHw for Driver {
    fn set_enable(&mut self, _on: bool) {}
    fn set_microsteps(&mut self, _microsteps: u16) -> bool {
        true
    }
}

/// Four digital pins and two PWM outputs, as the RP2040 and SAMD51 boards
/// have; every write is kept with its local time.
#[derive(Default)]
struct Pins {
    digital: [bool; 4],
    pwm: [u16; 2],
    writes: Vec<(u64, char, u8, u16)>,
    now: Rc<Cell<Instant>>,
}

impl IoHw for Pins {
    fn digital_pins(&self) -> u8 {
        4
    }
    fn write_digital(&mut self, pin: u8, level: bool) {
        self.digital[usize::from(pin)] = level;
        let t = self.now.get().as_micros();
        self.writes.push((t, 'd', pin, u16::from(level)));
    }
    fn read_digital(&mut self, pin: u8) -> bool {
        self.digital[usize::from(pin)]
    }
    fn pwm_outputs(&self) -> u8 {
        2
    }
    fn write_pwm(&mut self, channel: u8, duty: u16) {
        self.pwm[usize::from(channel)] = duty;
        let t = self.now.get().as_micros();
        self.writes.push((t, 'p', channel, duty));
    }
    fn read_pwm(&self, channel: u8) -> u16 {
        self.pwm.get(usize::from(channel)).copied().unwrap_or(0)
    }
    fn analog_inputs(&self) -> u8 {
        0
    }
    fn read_analog(&mut self, _channel: u8) -> u16 {
        0
    }
}

struct TestBoard {
    driver: Driver,
    pins: Pins,
    now: Rc<Cell<Instant>>,
}

impl Board for TestBoard {
    fn stepper(&mut self) -> &mut dyn StepperHw {
        &mut self.driver
    }
    fn io(&mut self) -> Option<&mut dyn IoHw> {
        Some(&mut self.pins)
    }
    fn now(&self) -> Instant {
        self.now.get()
    }
}

/// A module whose clocks read the same (identity time map), at `t = 0`.
fn module() -> (Module<TestBoard>, Rc<Cell<Instant>>) {
    let now = Rc::new(Cell::new(Instant::ZERO));
    let board = TestBoard {
        driver: Driver,
        pins: Pins {
            now: now.clone(),
            ..Pins::default()
        },
        now: now.clone(),
    };
    (Module::new(board), now)
}

/// Runs the module's loop as a runtime would: to each wake-up it asks
/// for, up to `until` µs.
fn run_until(m: &mut Module<TestBoard>, now: &Cell<Instant>, until: u64) {
    loop {
        let t = now.get();
        m.poll_io(t, SystemInstant::from_micros(t.as_micros()));
        let next = m.io_wake_at(t, SystemInstant::from_micros(t.as_micros()));
        match next {
            Some(w) if w.as_micros() <= until => now.set(if w > t {
                w
            } else {
                Instant::from_micros(t.as_micros() + 1)
            }),
            _ => {
                now.set(Instant::from_micros(until));
                let t = now.get();
                m.poll_io(t, SystemInstant::from_micros(until));
                return;
            }
        }
    }
}

fn io_refusal(e: IoError) -> CallError {
    CallError::Failed(FailureCode::Other(e.code()))
}

fn duty(m: &Module<TestBoard>, channel: usize) -> f64 {
    f64::from(m.board().pins.pwm[channel]) / 65_535.0
}

#[test]
fn a_ramp_is_followed_between_points_and_a_step_lands_on_its_stamp() {
    let (mut m, now) = module();
    // A laser's power: 0 at 1 ms, ramping to 0.8 at 3 ms, holding to 4 ms
    // and on to 4.5 ms, then off there at once.
    m.level_point(1_000, 0, 0.0, 0.0).unwrap();
    m.level_point(3_000, 0, 0.8, 0.8).unwrap();
    m.level_point(4_000, 0, 0.8, 0.8).unwrap();
    m.level_point(4_500, 0, 0.8, 0.0).unwrap();
    // Sampled along the way: within one update period's change of the
    // ramp's line (0.8 over 2 ms: 0.04 per 100 µs).
    let per_update = 0.8 / 2_000.0 * LEVEL_UPDATE_US as f64;
    for t in (1_000..=3_000).step_by(250) {
        run_until(&mut m, &now, t);
        let want = 0.8 * (t - 1_000) as f64 / 2_000.0;
        let got = duty(&m, 0);
        assert!(
            got <= want + 1e-4 && got >= want - per_update - 1e-4,
            "at {t} µs: {got} for {want}"
        );
    }
    run_until(&mut m, &now, 4_499);
    assert!((duty(&m, 0) - 0.8).abs() < 1e-4);
    run_until(&mut m, &now, 5_000);
    assert_eq!(duty(&m, 0), 0.0);
    // The step was written at its stamp, not at the next update.
    let off = m
        .board()
        .pins
        .writes
        .iter()
        .rev()
        .find(|w| w.1 == 'p' && w.3 == 0)
        .unwrap();
    assert_eq!(off.0, 4_500, "{:?}", m.board().pins.writes);
    // And once the last point is out, the loop has nothing to wake for.
    let t = now.get();
    assert_eq!(
        m.io_wake_at(t, SystemInstant::from_micros(t.as_micros())),
        None
    );
    // What was applied reads back, time-stamped.
    let (time, pwm0, pwm1, _) = m.level_read().unwrap();
    assert_eq!((time, pwm0, pwm1), (5_000, 0.0, 0.0));
}

#[test]
fn events_switch_pins_at_their_stamps() {
    let (mut m, now) = module();
    m.event_point(2_000, 1, true).unwrap();
    m.event_point(2_000, 3, true).unwrap();
    m.event_point(7_777, 1, false).unwrap();
    run_until(&mut m, &now, 10_000);
    let pins: Vec<_> = m
        .board()
        .pins
        .writes
        .iter()
        .filter(|w| w.1 == 'd')
        .copied()
        .collect();
    assert_eq!(
        pins,
        [(2_000, 'd', 1, 1), (2_000, 'd', 3, 1), (7_777, 'd', 1, 0)]
    );
    let (_, _, _, levels) = m.level_read().unwrap();
    assert_eq!(levels, 0b1000);
}

#[test]
fn full_late_and_out_of_order_points_are_refused() {
    let (mut m, now) = module();
    for k in 0..LEVEL_POINTS as u64 {
        m.level_point(1_000 + k, 1, 0.5, 0.5).unwrap();
    }
    assert_eq!(
        m.level_point(10_000, 1, 0.5, 0.5),
        Err(io_refusal(IoError::Full))
    );
    // The other output has a queue of its own.
    m.level_point(1_000, 0, 0.5, 0.5).unwrap();
    assert_eq!(
        m.level_point(999, 0, 0.5, 0.5),
        Err(io_refusal(IoError::OutOfOrder))
    );
    assert_eq!(
        m.level_point(1_000, 0, 0.5, 0.5),
        Err(io_refusal(IoError::OutOfOrder))
    );
    for k in 0..EVENT_POINTS as u64 {
        m.event_point(1_000 + k, 0, k % 2 == 0).unwrap();
    }
    assert_eq!(
        m.event_point(5_000, 0, true),
        Err(io_refusal(IoError::Full))
    );
    run_until(&mut m, &now, 20_000);
    assert_eq!(
        m.level_point(19_999, 0, 0.5, 0.5),
        Err(io_refusal(IoError::Late))
    );
    assert_eq!(
        m.event_point(19_999, 0, true),
        Err(io_refusal(IoError::Late))
    );
    assert_eq!(
        m.level_point(30_000, 2, 0.5, 0.5),
        Err(io_refusal(IoError::NoSuchPin))
    );
    assert_eq!(
        m.level_point(30_000, 0, 0.5, 1.5),
        Err(io_refusal(IoError::BadValue))
    );
    assert_eq!(
        m.level_point(61_000_000, 0, 0.5, 0.5),
        Err(io_refusal(IoError::BadValue))
    );
    assert_eq!(
        m.event_point(30_000, 4, true),
        Err(io_refusal(IoError::NoSuchPin))
    );
}

#[test]
fn a_halt_clears_what_waits_and_leaves_the_safe_values() {
    let (mut m, now) = module();
    m.set_safe_pwm(0, 0.0).unwrap();
    m.level_point(1_000, 0, 1.0, 1.0).unwrap();
    m.level_point(3_000, 0, 1.0, 1.0).unwrap();
    m.level_point(5_000, 0, 1.0, 0.5).unwrap();
    m.event_point(4_000, 2, true).unwrap();
    run_until(&mut m, &now, 2_000);
    assert_eq!(duty(&m, 0), 1.0);
    m.halt().unwrap();
    assert_eq!(duty(&m, 0), 0.0);
    assert_eq!(m.tracks.pending_levels(0), 0);
    assert_eq!(m.tracks.pending_events(), 0);
    // Nothing queued before the stop comes back after it.
    run_until(&mut m, &now, 10_000);
    assert_eq!(duty(&m, 0), 0.0);
    assert!(!m.board().pins.digital[2]);
    // A new stream after the stop starts afresh.
    m.level_point(11_000, 0, 0.25, 0.25).unwrap();
    run_until(&mut m, &now, 12_000);
    assert!((duty(&m, 0) - 0.25).abs() < 1e-4);
}

#[test]
fn the_output_watchdog_clears_the_tracks() {
    let (mut m, now) = module();
    m.set_output_watchdog(5).unwrap();
    m.level_point(1_000, 1, 0.6, 0.6).unwrap();
    m.level_point(9_000, 1, 0.6, 0.9).unwrap();
    run_until(&mut m, &now, 2_000);
    assert!((duty(&m, 1) - 0.6).abs() < 1e-4);
    now.set(Instant::from_micros(6_000));
    m.poll_watchdog(now.get());
    assert_eq!(duty(&m, 1), 0.0);
    run_until(&mut m, &now, 12_000);
    assert_eq!(
        duty(&m, 1),
        0.0,
        "a queued point came back after the watchdog"
    );
}

#[test]
fn a_direct_write_wins_over_the_track() {
    let (mut m, now) = module();
    m.level_point(1_000, 0, 0.4, 0.4).unwrap();
    m.event_point(1_000, 0, true).unwrap();
    m.event_point(1_000, 1, true).unwrap();
    m.pwm_write(0, 0.1).unwrap();
    m.digital_write(0, false).unwrap();
    run_until(&mut m, &now, 2_000);
    assert!((duty(&m, 0) - 0.1).abs() < 1e-4);
    assert!(!m.board().pins.digital[0]);
    assert!(m.board().pins.digital[1], "the other pin's change stays");
}

#[test]
fn a_heaters_output_takes_no_levels() {
    let (mut m, _now) = module();
    m.heater_output(0, 1, 1.0).unwrap();
    assert_eq!(
        m.level_point(1_000, 1, 0.5, 0.5),
        Err(io_refusal(IoError::HeaterOutput))
    );
}
