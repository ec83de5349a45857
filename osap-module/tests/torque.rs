//! The motor as a torque device (`set_torque`, `torque_off`): refusals,
//! commutation from the shaft, the shaft as the position, and every stop
//! ending the torque with the motor holding where it stands.

use maxl::phase::Coils;
use osap_core::time::Instant;
use osap_module::board::{Board, IoHw, StepperHw};
use osap_module::fault::FaultKind;
use osap_module::stepper::{Mode, StepperError};
use osap_module::torque::ENCODER_LOST;
use osap_module::Module;
use pipes_core::function::CallError;
use pipes_core::FailureCode;
use std::cell::{Cell, RefCell};
use std::rc::Rc;

/// A driver with an encoder (when `shaft` holds a reading) and a coil
/// drive (when `coil_drive`); every `drive_coils` is kept.
#[derive(Default, Clone)]
struct Driver {
    shaft: Rc<Cell<Option<i64>>>,
    coil_drive: bool,
    coils: Rc<RefCell<Vec<Option<Coils>>>>,
}

impl StepperHw for Driver {
    fn set_enable(&mut self, _on: bool) {}
    fn set_microsteps(&mut self, _microsteps: u16) -> bool {
        true
    }
    fn read_shaft(&mut self) -> Option<i64> {
        self.shaft.get()
    }
    fn drive_coils(&mut self, coils: Option<Coils>) -> bool {
        if self.coil_drive {
            self.coils.borrow_mut().push(coils);
        }
        self.coil_drive
    }
}

struct TestBoard {
    driver: Driver,
    now: Rc<Cell<Instant>>,
}

impl Board for TestBoard {
    fn stepper(&mut self) -> &mut dyn StepperHw {
        &mut self.driver
    }
    fn io(&mut self) -> Option<&mut dyn IoHw> {
        None
    }
    fn now(&self) -> Instant {
        self.now.get()
    }
}

/// Full steps per mm of cable on a 12 mm spool: 200 / (2π·12).
const SCALE: f32 = 2.652_582_4;

fn module(shaft: Option<i64>, coil_drive: bool) -> (Module<TestBoard>, Driver, Rc<Cell<Instant>>) {
    let driver = Driver {
        shaft: Rc::new(Cell::new(shaft)),
        coil_drive,
        coils: Rc::default(),
    };
    let now = Rc::new(Cell::new(Instant::from_micros(1_000)));
    let mut m = Module::new(TestBoard {
        driver: driver.clone(),
        now: now.clone(),
    });
    m.set_scale(SCALE).unwrap();
    m.set_microsteps(16).unwrap();
    (m, driver, now)
}

fn refused(e: CallError) -> StepperError {
    match e {
        CallError::Failed(FailureCode::Other(code)) => StepperError::from_code(code).unwrap(),
        other => panic!("not a stepper refusal: {other:?}"),
    }
}

/// The torque the coils give a rotor at `shaft`, a fraction of holding:
/// `b·cos θ − a·sin θ` at electrical angle `θ` (see `osap_module::torque`).
fn torque(c: Coils, shaft: i64) -> f64 {
    let theta = std::f64::consts::FRAC_PI_2 * shaft as f64 / 65_536.0;
    (f64::from(c.b) * theta.cos() - f64::from(c.a) * theta.sin()) / 32_768.0
}

#[test]
fn torque_mode_is_refused_without_its_hardware_or_its_conditions() {
    let (mut m, _, _) = module(Some(0), true);
    assert_eq!(
        refused(m.set_torque(0.2).unwrap_err()),
        StepperError::Disabled
    );
    m.set_enable(true).unwrap();
    for bad in [1.01, -1.5, f32::NAN, f32::INFINITY] {
        assert_eq!(
            refused(m.set_torque(bad).unwrap_err()),
            StepperError::BadValue
        );
    }
    m.halt().unwrap();
    assert_eq!(
        refused(m.set_torque(0.2).unwrap_err()),
        StepperError::Faulted
    );

    // No encoder, or no coil drive: the board cannot.
    for (shaft, drive) in [(None, true), (Some(0), false)] {
        let (mut m, _, _) = module(shaft, drive);
        m.set_enable(true).unwrap();
        assert_eq!(
            refused(m.set_torque(0.2).unwrap_err()),
            StepperError::Unsupported
        );
        assert_eq!(m.stepper.mode(), Mode::Idle);
        assert!(m.add_point(0, 0.0).is_ok(), "position mode still works");
    }
}

#[test]
fn the_coils_lead_the_shaft_and_the_position_is_the_shaft() {
    let (mut m, d, now) = module(Some(3 * 65_536 + 1_000), true);
    m.set_enable(true).unwrap();
    m.set_torque(0.25).unwrap();
    assert_eq!(m.get_status().unwrap().0, Mode::Torque as u8);
    assert_eq!(
        refused(m.add_point(4096, 0.0).unwrap_err()),
        StepperError::WrongMode
    );
    // The shaft turns on its own (a load pulls it): each commutation sets
    // the coils for a quarter of holding torque where the shaft is now.
    for (k, shaft) in [-200_000i64, -65_536, 7, 123_456, 9_000_001]
        .into_iter()
        .enumerate()
    {
        d.shaft.set(Some(shaft));
        now.set(Instant::from_micros(2_000 + 200 * k as u64));
        m.commutate(now.get());
        let c = d.coils.borrow().last().copied().flatten().unwrap();
        let t = torque(c, shaft);
        assert!((t - 0.25).abs() < 1e-4, "{shaft}: {t}");
        let (at, pos) = m.get_position().unwrap();
        assert_eq!(at, now.get().as_micros());
        let want = shaft as f64 / 65_536.0 / f64::from(SCALE);
        assert!((f64::from(pos) - want).abs() < 1e-4, "{pos} vs {want}");
    }
    // A negative torque: the current behind the rotor.
    m.set_torque(-0.5).unwrap();
    let c = d.coils.borrow().last().copied().flatten().unwrap();
    assert!((torque(c, 9_000_001) + 0.5).abs() < 1e-4);
    // No steps are made: the step words are empty.
    assert_eq!(m.fill_step_word(now.get()), 0);
    assert_eq!(m.get_steps().unwrap().0, 0);
}

/// A way to end the torque.
type Stop = fn(&mut Module<TestBoard>);

#[test]
fn every_stop_ends_the_torque_and_the_motor_holds_where_the_shaft_is() {
    // 2.5 full steps past zero: 40 microsteps at 16.
    let shaft = 2 * 65_536 + 32_768;
    let stops: [(&str, Stop); 4] = [
        ("torque_off", |m| m.torque_off().unwrap()),
        ("halt", |m| m.halt().unwrap()),
        ("set_enable", |m| m.set_enable(false).unwrap()),
        ("watchdog", |m| {
            m.set_output_watchdog(10).unwrap();
            m.poll_watchdog(Instant::from_micros(1_000 + 10_001));
        }),
    ];
    for (name, stop) in stops {
        let (mut m, d, _) = module(Some(shaft), true);
        m.set_enable(true).unwrap();
        m.set_torque(0.8).unwrap();
        stop(&mut m);
        assert_eq!(m.torque.fraction(), None, "{name}");
        assert_eq!(d.coils.borrow().last(), Some(&None), "{name}: coils kept");
        assert!(!m.stepper.is_torque(), "{name}");
        // The step position is the shaft's microstep.
        assert_eq!(m.get_steps().unwrap().0, 40, "{name}");
        let (_, pos) = m.get_position().unwrap();
        assert!((pos - 2.5 / SCALE).abs() < 1e-6, "{name}: {pos}");
        // A later commutation drives nothing.
        let n = d.coils.borrow().len();
        m.commutate(Instant::from_micros(90_000));
        assert_eq!(d.coils.borrow().len(), n, "{name}");
    }
    // After torque_off a stream starts where the shaft stood.
    let (mut m, _, _) = module(Some(shaft), true);
    m.set_enable(true).unwrap();
    m.set_torque(0.8).unwrap();
    m.torque_off().unwrap();
    assert_eq!(m.stepper.mode(), Mode::Idle);
    m.add_point(4096, 2.5 / SCALE).unwrap();
    m.add_point(8192, 2.5 / SCALE).unwrap();
}

#[test]
fn a_lost_encoder_halts_the_axis_with_a_fault() {
    let (mut m, d, _) = module(Some(65_536), true);
    m.set_enable(true).unwrap();
    m.set_torque(0.3).unwrap();
    d.shaft.set(None);
    m.commutate(Instant::from_micros(5_000));
    assert_eq!(m.torque.fraction(), None);
    assert_eq!(m.stepper.mode(), Mode::Halted);
    let (_, code, detail, _) = m.get_fault().unwrap();
    assert_eq!((code, detail), (FaultKind::Halted.code(), ENCODER_LOST));
    assert_eq!(d.coils.borrow().last(), Some(&None));
}
