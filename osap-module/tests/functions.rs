//! The module's functions on an installed module (the global state one
//! firmware has), and the ports a runtime holds.

use osap_core::clock::TimeMap;
use osap_module::board::{IoHw, StepperHw};
use osap_module::functions::{self as f, SIGNATURES};
use osap_module::{fill_step_word, install, limit_changed, publish_time, ModulePorts, PORT_COUNT};
use pipes_core::function::CallError;
use std::collections::HashSet;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Mutex;

/// The module is one global: the tests that install it take turns.
static TURN: Mutex<()> = Mutex::new(());
static NOW: AtomicU64 = AtomicU64::new(0);
static ENABLED: AtomicBool = AtomicBool::new(false);

fn clock() -> u64 {
    NOW.load(Ordering::SeqCst)
}

struct Driver;

impl StepperHw for Driver {
    fn set_enable(&mut self, on: bool) {
        ENABLED.store(on, Ordering::SeqCst);
    }
    fn set_microsteps(&mut self, microsteps: u16) -> bool {
        microsteps <= 16
    }
}

struct Board([bool; 4]);

impl IoHw for Board {
    fn digital_pins(&self) -> u8 {
        4
    }
    fn write_digital(&mut self, pin: u8, level: bool) {
        self.0[usize::from(pin)] = level;
    }
    fn read_digital(&mut self, pin: u8) -> bool {
        self.0[usize::from(pin)]
    }
    fn pwm_outputs(&self) -> u8 {
        1
    }
    fn write_pwm(&mut self, _channel: u8, _duty: u16) {}
    fn analog_inputs(&self) -> u8 {
        1
    }
    fn read_analog(&mut self, _channel: u8) -> u16 {
        65_535
    }
}

fn fresh(io: bool) {
    NOW.store(0, Ordering::SeqCst);
    let driver: &'static mut (dyn StepperHw + Send) = Box::leak(Box::new(Driver));
    let board: Option<&'static mut (dyn IoHw + Send)> = if io {
        Some(Box::leak(Box::new(Board([false; 4]))))
    } else {
        None
    };
    install(driver, board, clock);
}

#[test]
fn the_function_set_is_whole_and_unique() {
    let names: HashSet<_> = SIGNATURES.iter().map(|s| s.name).collect();
    assert_eq!(names.len(), SIGNATURES.len(), "duplicate names");
    for s in SIGNATURES {
        s.check().unwrap_or_else(|e| panic!("{}: {e:?}", s.name));
    }
    for name in [
        "add_point",
        "get_position",
        "set_enable",
        "read_limit",
        "halt",
        "pulse",
        "analog_read",
    ] {
        assert!(names.contains(name), "{name} missing");
    }
    let mut ports = ModulePorts::new().expect("every signature is accepted");
    assert_eq!(ports.ports().len(), PORT_COUNT);
    let indices: u16 = ports
        .ports()
        .iter()
        .map(osap_core::port::Port::port_count)
        .sum();
    assert_eq!(usize::from(indices) + 1, osap_module::PORT_INDICES);
}

#[test]
fn functions_drive_the_installed_module() {
    let _turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
    fresh(true);
    assert_eq!(f::add_point(0, 0.0), Err(CallError::Failed(6)), "disabled");
    f::set_enable(true).unwrap();
    assert!(ENABLED.load(Ordering::SeqCst));
    assert_eq!(
        f::set_microsteps(32),
        Err(CallError::Failed(10)),
        "the driver cannot"
    );
    f::set_microsteps(2).unwrap();
    publish_time(TimeMap::IDENTITY);
    let iv = 2048u64;
    for k in 0..4 {
        f::add_point(k * iv, 0.0).unwrap();
    }
    for k in 4..12 {
        f::add_point(k * iv, 1.0).unwrap();
    }
    let mut local = 0;
    while local < 30 * iv {
        fill_step_word(local);
        local += 160;
    }
    let (steps, up, down, overruns) = f::get_steps().unwrap();
    assert_eq!((steps, up, down, overruns), (160, 160, 0, 0));
    let (_, pos) = f::get_position().unwrap();
    assert!((pos - 1.0).abs() < 1e-6, "{pos}");
    let (mode, queued, enabled, faults) = f::get_status().unwrap();
    assert_eq!((mode, queued, enabled, faults), (3, 12, true, 0));
    let (points, refused, last, filled) = f::get_counters().unwrap();
    assert_eq!((points, refused, last, filled), (12, 1, 6, 0));
    // The limit switch: its level at boot counts no edge; an edge
    // reports its own time stamp.
    osap_module::limit_initial(true);
    assert_eq!(f::read_limit().unwrap(), (0, true, 0));
    NOW.store(77_000, Ordering::SeqCst);
    limit_changed(70_000, false);
    assert_eq!(f::read_limit().unwrap(), (70_000, false, 1));
    // I/O: a read carries the synchronized time of the read.
    f::digital_write(2, true).unwrap();
    assert_eq!(f::digital_read(2).unwrap(), (77_000, true));
    assert_eq!(f::digital_read(9), Err(CallError::Failed(1)));
    assert_eq!(f::analog_read(0).unwrap(), (77_000, 1.0));
    f::pulse(1, 100).unwrap();
    assert_eq!(f::pwm_write(0, 2.0), Err(CallError::Failed(2)));
    f::halt().unwrap();
    assert_eq!(f::get_status().unwrap().0, 4);
}

#[test]
fn io_functions_fail_cleanly_without_io_hardware() {
    let _turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
    fresh(false);
    assert_eq!(f::digital_write(0, true), Err(CallError::Failed(4)));
    assert_eq!(f::analog_read(0), Err(CallError::Failed(4)));
    assert!(f::get_status().is_ok());
}

#[test]
fn step_words_follow_a_new_time_map_at_once() {
    let _turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
    fresh(false);
    publish_time(TimeMap::IDENTITY);
    let last_tick = |local| {
        fill_step_word(local);
        f::get_position().unwrap().0
    };
    assert_eq!(last_tick(1_000_000), 1_000_150);
    // A rate of +400 ppm since local 0: the next word, well within the
    // anchor's span, must use it, not the anchor taken under the old map.
    let mut clock: osap_core::clock::Clock<1> = osap_core::clock::Clock::new(Default::default());
    clock.set_rate_ppb(0, 400_000);
    let map = clock.time_map();
    publish_time(map);
    assert_eq!(last_tick(1_000_160), map.system_time(1_000_160) + 150);
    assert_eq!(map.system_time(1_000_160), 1_000_560);
}
