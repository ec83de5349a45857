//! The load cell's driver against a converter that behaves as an HX711's
//! datasheet says: data low when a sample is ready, one bit per clock
//! rising edge MSB first, a 25th edge for channel A / gain 128, and a
//! power-down if the clock stays high 60 µs (which the driver never
//! does: the test counts the edges and watches the clock's level between
//! calls).

use std::cell::{Cell, RefCell};
use std::rc::Rc;

use osap_core::{Duration, Instant};
use osap_module::board::{Board, IoHw, StepperHw};
use osap_module::loadcell::{LoadCellError, POLL_PERIOD};
use osap_module::Module;
use pipes_core::function::CallError;
use pipes_core::FailureCode;

/// An HX711 with a queue of samples to hand out, on pins 2 (data) and 3
/// (clock) of a four-pin board.
#[derive(Default)]
struct Hx711 {
    /// Samples ready to be read, oldest first (24-bit two's complement).
    ready: Vec<i32>,
    shifting: Option<(u32, u8)>,
    clock: bool,
    edges: u32,
    /// Clock pulses seen with no sample ready (a driver fault).
    stray: u32,
    /// The data line held low: no converter on it (a pull-down).
    held_low: bool,
}

impl Hx711 {
    fn rising(&mut self) {
        self.edges += 1;
        self.shifting = match self.shifting {
            None if self.ready.is_empty() => {
                self.stray += 1;
                None
            }
            None => Some(((self.ready.remove(0) as u32) & 0xff_ffff, 1)),
            Some((s, e)) if e < 24 => Some((s, e + 1)),
            Some(_) => None,
        };
    }

    fn data(&self) -> bool {
        if self.held_low {
            return false;
        }
        match self.shifting {
            Some((s, e)) => (s >> (24 - u32::from(e))) & 1 == 1,
            None => self.ready.is_empty(),
        }
    }
}

#[derive(Clone, Default)]
struct Pins(Rc<RefCell<Hx711>>);

impl IoHw for Pins {
    fn digital_pins(&self) -> u8 {
        4
    }
    fn write_digital(&mut self, pin: u8, level: bool) {
        if pin == 3 {
            let mut h = self.0.borrow_mut();
            if level && !h.clock {
                h.rising();
            }
            h.clock = level;
        }
    }
    fn read_digital(&mut self, pin: u8) -> bool {
        pin == 2 && self.0.borrow().data()
    }
    fn pwm_outputs(&self) -> u8 {
        2
    }
    fn write_pwm(&mut self, _channel: u8, _duty: u16) {}
    fn read_pwm(&self, _channel: u8) -> u16 {
        0
    }
    fn analog_inputs(&self) -> u8 {
        3
    }
    fn read_analog(&mut self, _channel: u8) -> u16 {
        0
    }
}

struct Driver;

impl StepperHw for Driver {
    fn set_enable(&mut self, _on: bool) {}
    fn set_microsteps(&mut self, _microsteps: u16) -> bool {
        true
    }
}

struct TestBoard {
    driver: Driver,
    pins: Option<Pins>,
    now: Rc<Cell<Instant>>,
}

impl Board for TestBoard {
    fn stepper(&mut self) -> &mut dyn StepperHw {
        &mut self.driver
    }
    fn io(&mut self) -> Option<&mut dyn IoHw> {
        self.pins.as_mut().map(|p| p as &mut dyn IoHw)
    }
    fn now(&self) -> Instant {
        self.now.get()
    }
}

fn refused(e: LoadCellError) -> Result<(), CallError> {
    Err(CallError::Failed(FailureCode::Other(e.code())))
}

fn rig() -> (Module<TestBoard>, Rc<RefCell<Hx711>>) {
    let (m, chip, _) = rig_with_clock();
    (m, chip)
}

/// The rig with the board's clock to set.
fn rig_with_clock() -> (Module<TestBoard>, Rc<RefCell<Hx711>>, Rc<Cell<Instant>>) {
    let pins = Pins::default();
    let chip = pins.0.clone();
    let now = Rc::new(Cell::new(Instant::ZERO));
    let m = Module::new(TestBoard {
        driver: Driver,
        pins: Some(pins),
        now: now.clone(),
    });
    (m, chip, now)
}

#[test]
fn samples_are_read_bit_by_bit_tared_and_scaled() {
    let (mut m, chip) = rig();
    m.loadcell_setup(2, 3).unwrap();
    assert_eq!(m.loadcell.wake_at(), Some(Instant::ZERO));
    // Nothing ready: a poll reads nothing and clocks nothing.
    m.poll_loadcell(Instant::ZERO);
    assert_eq!(m.loadcell_read().unwrap(), (0, 0.0, 0, 0, false));
    assert_eq!(chip.borrow().edges, 0);
    // The tare: four samples around 84 000 counts.
    m.loadcell_tare(4).unwrap();
    let mut now = Instant::ZERO;
    for raw in [84_000, 84_002, 83_998, 84_004] {
        chip.borrow_mut().ready.push(raw);
        now += POLL_PERIOD;
        m.poll_loadcell(now);
        assert!(!chip.borrow().clock, "the clock rests low");
    }
    let (_, _, raw, samples, taring) = m.loadcell_read().unwrap();
    assert_eq!((raw, samples, taring), (84_004, 4, false));
    assert_eq!(
        chip.borrow().edges,
        4 * 25,
        "24 data edges and one gain edge a sample"
    );
    assert_eq!(chip.borrow().stray, 0);
    // 2 000 counts a newton; 20 N on the cell.
    m.loadcell_scale(1.0 / 2_000.0).unwrap();
    chip.borrow_mut().ready.push(84_001 + 40_000);
    now += POLL_PERIOD;
    m.poll_loadcell(now);
    let (time, force, raw, samples, _) = m.loadcell_read().unwrap();
    assert_eq!((raw, samples), (124_001, 5));
    assert!((force - 20.0).abs() < 1e-4, "{force}");
    assert_eq!(
        time,
        now.as_micros(),
        "stamped when read (identity time map)"
    );
    // A negative reading (a pull) sign-extends.
    chip.borrow_mut().ready.push(84_001 - 1_000_000);
    now += POLL_PERIOD;
    m.poll_loadcell(now);
    let (_, force, raw, _, _) = m.loadcell_read().unwrap();
    assert_eq!(raw, 84_001 - 1_000_000);
    assert!((force + 500.0).abs() < 1e-3, "{force}");
    // Polled again before its period: nothing is read even if ready.
    chip.borrow_mut().ready.push(1);
    m.poll_loadcell(now + Duration::from_micros(10));
    assert_eq!(m.loadcell_read().unwrap().3, 6);
    m.poll_loadcell(now + POLL_PERIOD);
    assert_eq!(m.loadcell_read().unwrap().3, 7);
}

#[test]
fn bad_calls_are_refused_by_name() {
    let (mut m, _) = rig();
    assert_eq!(m.loadcell_tare(10), refused(LoadCellError::NotConfigured));
    assert!(m.loadcell_read().is_err());
    assert_eq!(m.loadcell_setup(2, 2), refused(LoadCellError::NoSuchPin));
    assert_eq!(m.loadcell_setup(4, 3), refused(LoadCellError::NoSuchPin));
    m.loadcell_setup(2, 3).unwrap();
    assert_eq!(m.loadcell_tare(0), refused(LoadCellError::BadValue));
    assert_eq!(m.loadcell_tare(1_001), refused(LoadCellError::BadValue));
    for s in [0.0, f32::NAN, f32::INFINITY] {
        assert_eq!(m.loadcell_scale(s), refused(LoadCellError::BadValue));
    }
    m.loadcell_scale(-0.5).unwrap();
    let mut bare = Module::new(TestBoard {
        driver: Driver,
        pins: None,
        now: Rc::default(),
    });
    assert_eq!(
        bare.loadcell_setup(0, 1),
        refused(LoadCellError::NoHardware)
    );
}

/// A data line no converter drives, held low by a pull-down, looks ready
/// at every poll and shifts out zeros: the driver sees it still low after
/// the 25th pulse, drops the sample and says so, until set up again.
#[test]
fn a_data_line_no_converter_drives_is_reported_not_read_as_zero() {
    let (mut m, chip) = rig();
    chip.borrow_mut().held_low = true;
    m.loadcell_setup(2, 3).unwrap();
    m.poll_loadcell(Instant::ZERO);
    assert_eq!(chip.borrow().edges, 25, "one read was tried");
    assert_eq!(
        m.loadcell_read(),
        Err(refused(LoadCellError::NoConverter).unwrap_err())
    );
    m.poll_loadcell(Instant::ZERO + POLL_PERIOD);
    assert_eq!(m.loadcell.samples(), 0, "no zeros taken as samples");
    // Wired again and set up again: it reads.
    chip.borrow_mut().held_low = false;
    m.loadcell_setup(2, 3).unwrap();
    chip.borrow_mut().ready.push(1_234);
    m.poll_loadcell(Instant::ZERO + POLL_PERIOD * 2);
    assert_eq!(m.loadcell_read().unwrap().2, 1_234);
}

/// A converter that gives no sample (unpowered, or its line pulled high)
/// is silent: reads fail after half a second without one, and a sample
/// ends it.
#[test]
fn a_converter_with_no_samples_is_reported_silent() {
    let (mut m, chip, now) = rig_with_clock();
    m.loadcell_setup(2, 3).unwrap();
    now.set(Instant::ZERO + Duration::from_micros(499_000));
    m.poll_loadcell(now.get());
    assert!(m.loadcell_read().is_ok(), "not silent yet");
    now.set(Instant::ZERO + Duration::from_micros(501_000));
    assert_eq!(
        m.loadcell_read(),
        Err(refused(LoadCellError::Silent).unwrap_err())
    );
    chip.borrow_mut().ready.push(7);
    m.poll_loadcell(now.get());
    assert_eq!(m.loadcell_read().unwrap().2, 7);
}
