//! Heaters on a board made of memory with a thermal model: PID control to
//! a hotend's target, each runaway case cutting the output, stops and the
//! watchdog turning heaters off, and the refusals.
//!
//! The plant is a hotend: a 40 W cartridge in a block of 15 J/K losing
//! 0.1 W/K to a 25 °C room (full power would settle at 425 °C; 210 °C takes
//! 18.5 W), read through a 100 kΩ (25 °C), β 3950 thermistor on a 4.7 kΩ
//! pullup and a 12-bit converter, as on a printer board.

use osap_core::clock::TimeMap;
use osap_core::time::Instant;
use osap_module::board::{Board, IoHw, StepperHw};
use osap_module::fault::FaultKind;
use osap_module::heater::{
    runaway_detail, runaway_parts, HeaterError, HeaterState, RunawayReason, Thermistor,
    CONTROL_PERIOD,
};
use osap_module::io::IoError;
use osap_module::Module;
use pipes_core::function::CallError;
use pipes_core::FailureCode;
use std::cell::{Cell, RefCell};
use std::rc::Rc;

const BETA: f64 = 3950.0;
const R25: f64 = 100_000.0;
const PULLUP: f64 = 4_700.0;
/// The rig's thermistor, as the module takes it.
static T: std::sync::LazyLock<Thermistor> =
    std::sync::LazyLock::new(|| Thermistor::from_beta(BETA as f32, R25 as f32, PULLUP as f32));
/// Klipper's example gains for an E3D-style hotend.
const KP: f32 = 22.2;
const KI: f32 = 1.08;
const KD: f32 = 114.0;

/// One heated block.
#[derive(Clone, Copy)]
struct Block {
    temp: f64,
    power_w: f64,
    capacity: f64,
    loss: f64,
    ambient: f64,
    /// A raw reading forced on its sensor (an open or shorted thermistor).
    sensor: Option<u16>,
}

impl Block {
    fn hotend() -> Self {
        Block {
            temp: 25.0,
            power_w: 40.0,
            capacity: 15.0,
            loss: 0.1,
            ambient: 25.0,
            sensor: None,
        }
    }

    /// Exact over `dt` s at `duty`: C·dT/dt = P·duty − loss·(T − ambient).
    fn advance(&mut self, duty: f64, dt: f64) {
        let settle = self.ambient + self.power_w * duty / self.loss;
        let decay = (-dt * self.loss / self.capacity).exp();
        self.temp = settle + (self.temp - settle) * decay;
    }

    fn raw(&self) -> u16 {
        if let Some(raw) = self.sensor {
            return raw;
        }
        let t = self.temp + 273.15;
        let r = R25 * (BETA * (1.0 / t - 1.0 / 298.15)).exp();
        let f = r / (r + PULLUP);
        ((f * 4095.0).round() as u16) << 4
    }
}

/// Two PWM outputs heating two blocks read by analog inputs 0 and 1: PWM
/// `k` heats block `k`, analog `k` reads it.
struct Plant {
    now: Rc<Cell<Instant>>,
    at: Instant,
    pwm: [u16; 2],
    blocks: [Block; 2],
}

impl Plant {
    fn catch_up(&mut self) {
        let now = self.now.get();
        let dt = (now - self.at).as_micros() as f64 * 1e-6;
        for (b, d) in self.blocks.iter_mut().zip(self.pwm) {
            b.advance(f64::from(d) / 65_535.0, dt);
        }
        self.at = now;
    }
}

impl IoHw for Plant {
    fn digital_pins(&self) -> u8 {
        4
    }
    fn write_digital(&mut self, _pin: u8, _level: bool) {}
    fn read_digital(&mut self, _pin: u8) -> bool {
        false
    }
    fn pwm_outputs(&self) -> u8 {
        2
    }
    fn write_pwm(&mut self, channel: u8, duty: u16) {
        self.catch_up();
        self.pwm[usize::from(channel)] = duty;
    }
    fn read_pwm(&self, channel: u8) -> u16 {
        self.pwm[usize::from(channel)]
    }
    fn analog_inputs(&self) -> u8 {
        3
    }
    fn read_analog(&mut self, channel: u8) -> u16 {
        self.catch_up();
        self.blocks
            .get(usize::from(channel))
            .map_or(0x8000, Block::raw)
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
    plant: Option<PlantRef>,
    now: Rc<Cell<Instant>>,
}

/// The plant as the module's `IoHw` (the test keeps a handle to change it).
struct PlantRef(Rc<RefCell<Plant>>);

impl IoHw for PlantRef {
    fn digital_pins(&self) -> u8 {
        self.0.borrow().digital_pins()
    }
    fn write_digital(&mut self, pin: u8, level: bool) {
        self.0.borrow_mut().write_digital(pin, level)
    }
    fn read_digital(&mut self, pin: u8) -> bool {
        self.0.borrow_mut().read_digital(pin)
    }
    fn pwm_outputs(&self) -> u8 {
        self.0.borrow().pwm_outputs()
    }
    fn write_pwm(&mut self, channel: u8, duty: u16) {
        self.0.borrow_mut().write_pwm(channel, duty)
    }
    fn read_pwm(&self, channel: u8) -> u16 {
        self.0.borrow().read_pwm(channel)
    }
    fn analog_inputs(&self) -> u8 {
        self.0.borrow().analog_inputs()
    }
    fn read_analog(&mut self, channel: u8) -> u16 {
        self.0.borrow_mut().read_analog(channel)
    }
}

impl Board for TestBoard {
    fn stepper(&mut self) -> &mut dyn StepperHw {
        &mut self.driver
    }
    fn io(&mut self) -> Option<&mut dyn IoHw> {
        self.plant.as_mut().map(|p| p as &mut dyn IoHw)
    }
    fn now(&self) -> Instant {
        self.now.get()
    }
}

struct Rig {
    m: Module<TestBoard>,
    plant: Rc<RefCell<Plant>>,
    now: Rc<Cell<Instant>>,
}

impl Rig {
    fn new() -> Rig {
        let now = Rc::new(Cell::new(Instant::ZERO));
        let plant = Rc::new(RefCell::new(Plant {
            now: now.clone(),
            at: Instant::ZERO,
            pwm: [0; 2],
            blocks: [Block::hotend(); 2],
        }));
        let board = TestBoard {
            driver: Driver,
            plant: Some(PlantRef(plant.clone())),
            now: now.clone(),
        };
        let mut m = Module::new(board);
        m.publish_time(TimeMap::IDENTITY);
        Rig { m, plant, now }
    }

    /// Heater `index` on PWM `index` and analog `index`, a hotend's
    /// settings: 0..300 °C, Klipper's example gains, default runaway.
    fn hotend(index: u8) -> Rig {
        let mut r = Rig::new();
        r.configure(index);
        r
    }

    fn configure(&mut self, index: u8) {
        let m = &mut self.m;
        m.heater_sensor(index, index, T.a, T.b, T.c, T.pullup_ohms)
            .unwrap();
        m.heater_output(index, index, 1.0).unwrap();
        m.heater_limits(index, 0.0, 300.0).unwrap();
        m.heater_gains(index, KP, KI, KD).unwrap();
    }

    fn secs(&self) -> f64 {
        self.now.get().as_micros() as f64 * 1e-6
    }

    fn temp(&self, index: usize) -> f64 {
        self.plant.borrow().blocks[index].temp
    }

    fn block(&self, index: usize) -> std::cell::RefMut<'_, Block> {
        std::cell::RefMut::map(self.plant.borrow_mut(), |p| &mut p.blocks[index])
    }

    fn pwm(&self, index: usize) -> u16 {
        self.plant.borrow().pwm[index]
    }

    /// Runs the module's timer work as the pulse timer port does, at each
    /// of its wake-ups, until `secs`; `each` sees every control period.
    fn run_until(&mut self, secs: f64, mut each: impl FnMut(&mut Rig)) {
        let end = Instant::from_micros((secs * 1e6).round() as u64);
        loop {
            let wake = [self.m.heaters.wake_at(), self.m.watchdog.deadline()]
                .into_iter()
                .flatten()
                .min();
            let Some(wake) = wake.filter(|w| *w <= end) else {
                self.now.set(end);
                return;
            };
            let wake = wake.max(self.now.get());
            self.now.set(wake);
            let system = self.m.system_now();
            self.m.poll_watchdog(wake);
            self.m.poll_io(wake, system);
            let before = self.m.heaters.wake_at();
            self.m.poll_heaters(wake);
            if self.m.heaters.wake_at() != before {
                each(self);
            }
        }
    }

    fn fault(&mut self) -> (u64, u8, u32, u32) {
        self.m.get_fault().unwrap()
    }
}

fn heater_error(e: HeaterError) -> Result<(), CallError> {
    Err(CallError::Failed(FailureCode::Other(e.code())))
}

#[test]
fn the_thermistor_reads_its_beta_model() {
    let t = *T;
    for want in [0.0, 25.0, 60.0, 110.0, 210.0, 280.0] {
        let mut b = Block::hotend();
        b.temp = want;
        let got = f64::from(t.celsius(b.raw()));
        // The 12-bit converter's step at the hottest, 0.4 °C at 280 °C.
        assert!((got - want).abs() < 0.4, "{want} °C read as {got}");
    }
    // The ends of the scale have no temperature (ln 0, ln ∞): each comes
    // out at absolute zero or not a number, outside any heater's limits.
    for raw in [0, 65_535] {
        let c = t.celsius(raw);
        assert!(c.is_nan() || c <= -273.0, "{raw} read as {c} °C");
    }
}

/// The Steinhart–Hart coefficients through three (°C, Ω) points, solved
/// in f64 as a host does.
fn steinhart_hart(points: [(f64, f64); 3]) -> [f64; 3] {
    let l: Vec<f64> = points.iter().map(|p| p.1.ln()).collect();
    let y: Vec<f64> = points.iter().map(|p| 1.0 / (p.0 + 273.15)).collect();
    let g2 = (y[1] - y[0]) / (l[1] - l[0]);
    let g3 = (y[2] - y[0]) / (l[2] - l[0]);
    let c = (g3 - g2) / (l[2] - l[1]) / (l[0] + l[1] + l[2]);
    let b = g2 - c * (l[0] * l[0] + l[0] * l[1] + l[1] * l[1]);
    let a = y[0] - (b + c * l[0] * l[0]) * l[0];
    [a, b, c]
}

#[test]
fn the_thermistor_reads_a_steinhart_hart_curve_through_its_points() {
    // EPCOS 100K B57560G104F's datasheet points, on a 4.7 kΩ pullup.
    let points = [(25.0, 100_000.0), (150.0, 1_641.9), (250.0, 226.15)];
    let [a, b, c] = steinhart_hart(points);
    assert!(c > 0.0, "the fit has a cubic term: {c}");
    let t = Thermistor {
        a: a as f32,
        b: b as f32,
        c: c as f32,
        pullup_ohms: PULLUP as f32,
    };
    assert!(t.is_valid());
    for (want, ohms) in points {
        // The exact reading of that resistance, rounded to the converter.
        let raw = (65_535.0 * ohms / (ohms + PULLUP)).round() as u16;
        let got = f64::from(t.celsius(raw));
        // A 16-bit step at 250 °C (226 Ω on 4.7 kΩ) is 0.01 °C; the
        // rest is f32.
        assert!(
            (got - want).abs() < 0.02,
            "{ohms} Ω read as {got} °C, not {want}"
        );
    }
    // The same thermistor as a Beta model through its 25 °C and 150 °C
    // points reads 250 °C nearly 4 °C off: the curve is why tables exist.
    let beta = (1.0 / 298.15 - 1.0 / 423.15) / (100_000.0f64 / 1_641.9).ln();
    let b = Thermistor::from_beta((1.0 / beta) as f32, 1e5, PULLUP as f32);
    let raw = (65_535.0 * 226.15 / (226.15 + PULLUP)).round() as u16;
    let off = f64::from(b.celsius(raw)) - 250.0;
    assert!(off.abs() > 2.0, "a Beta model would do: {off}");
}

#[test]
fn pid_heats_a_hotend_to_its_target_and_holds_it_within_two_degrees() {
    let mut r = Rig::hotend(0);
    r.m.heater_target(0, 210.0).unwrap();
    let mut reached = None;
    let mut band = (f64::MAX, f64::MIN);
    let mut peak = 0.0f64;
    let mut duty = (0.0, 0);
    r.run_until(400.0, |r| {
        let t = r.temp(0);
        peak = peak.max(t);
        if reached.is_none() && t >= 208.0 {
            reached = Some(r.secs());
        }
        if reached.is_some_and(|at| r.secs() > at + 60.0) {
            band = (band.0.min(t), band.1.max(t));
            duty = (
                duty.0 + f64::from(r.m.heater_read(0).unwrap().3),
                duty.1 + 1,
            );
        }
    });
    let reached = reached.expect("never reached 208 °C");
    // At full power from 25 °C, the block takes 84 s to reach 208 °C
    // (−τ·ln(1 − 183/400), τ = 150 s): the PID may take longer, not less,
    // and not much longer.
    assert!((84.0..130.0).contains(&reached), "reached at {reached} s");
    assert!(peak < 214.0, "overshoot to {peak}");
    assert!(
        band.0 > 208.0 && band.1 < 212.0,
        "held between {band:?} from a minute after reaching it"
    );
    let (time, temp, target, power, state) = r.m.heater_read(0).unwrap();
    // The latest reading was the period at 400 s.
    assert_eq!(time, r.now.get().as_micros());
    assert_eq!(time % CONTROL_PERIOD.as_micros(), 0);
    assert!((f64::from(temp) - 210.0).abs() < 1.0, "{temp}");
    assert_eq!((target, state), (210.0, HeaterState::Holding as u8));
    // Holding 210 °C takes 18.5 W of 40: a mean duty of 0.4625 (each
    // period's dithers by the derivative of the converter's steps).
    let mean = duty.0 / f64::from(duty.1);
    assert!((mean - 0.4625).abs() < 0.005, "mean duty {mean}");
    assert!((0.0..=1.0).contains(&power));
    assert!(r.m.heater_read(1).unwrap().4 == HeaterState::Off as u8);
    assert_eq!(r.fault().3, 0, "no fault");
}

#[test]
fn a_heater_that_does_not_heat_is_cut_after_check_gain_time() {
    let mut r = Rig::hotend(0);
    // The cartridge's wire is broken: the module drives it, nothing heats.
    r.block(0).power_w = 0.0;
    r.m.heater_target(0, 210.0).unwrap();
    r.run_until(19.9, |_| {});
    assert_eq!(r.pwm(0), 65_535, "full power while it tries");
    assert_eq!(r.m.heater_read(0).unwrap().4, HeaterState::Heating as u8);
    r.run_until(21.0, |_| {});
    assert_eq!(r.pwm(0), 0, "cut");
    let (time, code, detail, count) = r.fault();
    assert_eq!(code, FaultKind::HeaterRunaway.code());
    assert_eq!(detail, runaway_detail(0, RunawayReason::NotHeating));
    assert_eq!(runaway_parts(detail), (0, Some(RunawayReason::NotHeating)));
    // The first reading came at 0 s; the check fails at the first reading
    // at or past 20 s.
    assert_eq!((time, count), (20_000_000, 1));
    assert_eq!(r.m.heater_read(0).unwrap().4, HeaterState::Faulted as u8);
}

#[test]
fn a_heater_that_falls_from_its_target_is_cut_once_its_error_passes_max_error() {
    let mut r = Rig::hotend(0);
    r.m.heater_target(0, 210.0).unwrap();
    r.run_until(250.0, |_| {});
    assert_eq!(r.m.heater_read(0).unwrap().4, HeaterState::Holding as u8);
    // The cartridge fails while holding: the block cools.
    r.block(0).power_w = 0.0;
    // The error below 205 °C the module sums, from the true temperature at
    // each of its readings: when it passes 120 °C·s, the cut is due.
    let mut error = 0.0;
    let mut due = None;
    let mut cut = None;
    r.run_until(300.0, |r| {
        let t = r.temp(0);
        if t < 205.0 {
            error += (205.0 - t) * 0.1;
        }
        if due.is_none() && error >= 120.0 {
            due = Some(r.secs());
        }
        if cut.is_none() && r.pwm(0) == 0 && r.m.heater_read(0).unwrap().4 == 4 {
            cut = Some(r.secs());
        }
    });
    let (due, cut) = (due.unwrap(), cut.unwrap());
    // About 18 s after the failure; one reading either way for the
    // converter's steps.
    assert!((cut - due).abs() <= 0.11, "cut at {cut} s, due at {due} s");
    assert!((265.0..272.0).contains(&cut), "{cut}");
    let (_, code, detail, _) = r.fault();
    assert_eq!(code, FaultKind::HeaterRunaway.code());
    assert_eq!(detail, runaway_detail(0, RunawayReason::FellFromTarget));
    assert_eq!(r.pwm(0), 0);
}

#[test]
fn an_open_or_shorted_sensor_cuts_the_heater_and_clearing_needs_a_sane_one() {
    // Heater 1 (PWM 1, analog 1): the detail names it.
    let mut r = Rig::hotend(1);
    r.m.heater_target(1, 210.0).unwrap();
    r.run_until(30.0, |_| {});
    assert!(r.pwm(1) > 30_000);
    r.block(1).sensor = Some(4095 << 4);
    r.run_until(30.1, |_| {});
    assert_eq!(r.pwm(1), 0, "cut at the next reading");
    let (time, code, detail, _) = r.fault();
    assert_eq!((time, code), (30_100_000, FaultKind::HeaterRunaway.code()));
    assert_eq!(detail, runaway_detail(1, RunawayReason::SensorOpen));
    assert_eq!(detail, 0x0301);
    // Still open: no clearing, no target.
    assert_eq!(r.m.heater_clear(1), heater_error(HeaterError::SensorFault));
    assert_eq!(
        r.m.heater_target(1, 200.0),
        heater_error(HeaterError::Faulted)
    );
    assert_eq!(r.m.heater_power(1, 0.5), heater_error(HeaterError::Faulted));
    r.run_until(40.0, |_| {});
    assert_eq!(r.pwm(1), 0);
    r.block(1).sensor = None;
    r.m.heater_clear(1).unwrap();
    assert_eq!(r.m.heater_read(1).unwrap().4, HeaterState::Off as u8);
    // A short (a pinched wire) reads near zero.
    r.m.heater_target(1, 210.0).unwrap();
    r.run_until(45.0, |_| {});
    assert!(r.pwm(1) > 0);
    r.block(1).sensor = Some(0);
    r.run_until(45.1, |_| {});
    assert_eq!(r.pwm(1), 0);
    assert_eq!(r.fault().2, runaway_detail(1, RunawayReason::SensorShort));
    // Below min_temp reads as open: a thermistor half out of its block in
    // a cold room. Checked while the heater is off, too.
    r.block(1).sensor = None;
    r.m.heater_clear(1).unwrap();
    r.m.heater_target(1, 0.0).unwrap();
    r.m.heater_limits(1, 15.0, 300.0).unwrap();
    r.block(1).temp = 10.0;
    r.block(1).ambient = 10.0;
    r.run_until(46.0, |_| {});
    let (_, _, detail, count) = r.fault();
    assert_eq!(detail, runaway_detail(1, RunawayReason::SensorOpen));
    assert_eq!(count, 3);
    assert_eq!(r.m.heater_clear(1), heater_error(HeaterError::SensorFault));
}

#[test]
fn open_loop_power_is_capped_and_cut_at_max_temp() {
    let mut r = Rig::new();
    r.configure(0);
    r.m.heater_output(0, 0, 0.8).unwrap();
    r.m.heater_limits(0, 0.0, 250.0).unwrap();
    r.m.heater_power(0, 1.0).unwrap();
    r.run_until(1.0, |_| {});
    assert_eq!(r.pwm(0), 52_428, "capped at max_power 0.8");
    assert_eq!(r.m.heater_read(0).unwrap().4, HeaterState::Power as u8);
    let mut cut_at = None;
    r.run_until(400.0, |r| {
        if cut_at.is_none() && r.pwm(0) == 0 {
            cut_at = Some(r.temp(0));
        }
    });
    let t = cut_at.expect("never cut");
    // 32 W heats the block at most 2.1 °C/s: a 100 ms period passes
    // 250 °C by 0.21 °C at most, and the converter's step is 0.2 °C.
    assert!((249.8..250.5).contains(&t), "cut at {t} °C");
    assert_eq!(r.fault().2, runaway_detail(0, RunawayReason::OverTemp));
    // A target leaves power mode (once cleared and cool).
    r.run_until(600.0, |_| {});
    r.m.heater_clear(0).unwrap();
    r.m.heater_power(0, 0.3).unwrap();
    r.m.heater_target(0, 100.0).unwrap();
    r.run_until(601.0, |_| {});
    assert_eq!(r.m.heater_read(0).unwrap().2, 100.0);
    assert_ne!(r.m.heater_read(0).unwrap().4, HeaterState::Power as u8);
}

#[test]
fn the_watchdog_and_every_halt_turn_heaters_off() {
    let mut r = Rig::hotend(0);
    r.configure(1);
    r.m.heater_target(0, 210.0).unwrap();
    r.m.heater_power(1, 0.5).unwrap();
    // Neither safe values nor writes reach a heater's output.
    assert_eq!(
        r.m.set_safe_pwm(0, 1.0),
        Err(CallError::Failed(FailureCode::Other(
            IoError::HeaterOutput.code()
        )))
    );
    assert_eq!(
        r.m.pwm_write(1, 1.0),
        Err(CallError::Failed(FailureCode::Other(5)))
    );
    r.m.set_output_watchdog(1_000).unwrap();
    r.run_until(0.95, |_| {});
    assert!(r.pwm(0) > 0 && r.pwm(1) > 0);
    r.run_until(1.0, |_| {});
    assert_eq!((r.pwm(0), r.pwm(1)), (0, 0), "the watchdog fired");
    assert_eq!(r.fault().1, FaultKind::OutputWatchdog.code());
    for i in 0..2 {
        let (_, _, target, power, state) = r.m.heater_read(i).unwrap();
        assert_eq!((target, power, state), (0.0, 0.0, 0));
    }
    // They stay off, and a host that comes back heats again.
    r.run_until(5.0, |_| {});
    assert_eq!((r.pwm(0), r.pwm(1)), (0, 0));
    r.m.feed_watchdog(r.now.get());
    r.m.set_output_watchdog(0).unwrap();
    r.m.heater_target(0, 210.0).unwrap();
    r.m.heater_power(1, 0.5).unwrap();
    r.run_until(6.0, |_| {});
    assert!(r.pwm(0) > 0 && r.pwm(1) > 0);
    r.m.halt().unwrap();
    assert_eq!((r.pwm(0), r.pwm(1)), (0, 0), "halted");
    r.run_until(8.0, |_| {});
    assert_eq!((r.pwm(0), r.pwm(1)), (0, 0));
    assert_eq!(r.m.heater_read(0).unwrap().2, 0.0);
    assert_eq!(r.fault().1, FaultKind::Halted.code());
}

#[test]
fn bad_arguments_are_refused_with_their_codes() {
    use HeaterError as E;
    let mut r = Rig::new();
    let m = &mut r.m;
    assert_eq!(
        m.heater_sensor(2, 0, T.a, T.b, T.c, T.pullup_ohms),
        heater_error(E::NoSuchHeater)
    );
    assert_eq!(
        m.heater_sensor(0, 3, T.a, T.b, T.c, T.pullup_ohms),
        heater_error(E::NoSuchPin)
    );
    // A resistance that rises with temperature somewhere from 1 Ω to
    // 100 MΩ (b ≤ 0, or a c so negative that the curve turns), a value
    // not finite, a pullup not positive.
    for (a, b, c, p) in [
        (T.a, 0.0, 0.0, T.pullup_ohms),
        (T.a, -T.b, 0.0, T.pullup_ohms),
        (T.a, T.b, -T.b / 1000.0, T.pullup_ohms),
        (f32::NAN, T.b, T.c, T.pullup_ohms),
        (T.a, T.b, f32::INFINITY, T.pullup_ohms),
        (T.a, T.b, T.c, -1.0),
        (T.a, T.b, T.c, 0.0),
    ] {
        assert_eq!(m.heater_sensor(0, 0, a, b, c, p), heater_error(E::BadValue));
    }
    assert_eq!(m.heater_output(0, 2, 1.0), heater_error(E::NoSuchPin));
    for p in [0.0, 1.01, f32::NAN] {
        assert_eq!(m.heater_output(0, 0, p), heater_error(E::BadValue));
    }
    assert_eq!(m.heater_limits(0, 300.0, 300.0), heater_error(E::BadValue));
    assert_eq!(
        m.heater_limits(0, 0.0, f32::INFINITY),
        heater_error(E::BadValue)
    );
    assert_eq!(
        m.heater_gains(0, 22.0, -1.0, 100.0),
        heater_error(E::BadValue)
    );
    assert_eq!(
        m.heater_runaway(0, 5.0, 0.0, 2.0, 20.0),
        heater_error(E::BadValue)
    );
    assert_eq!(
        m.heater_runaway(0, -1.0, 120.0, 2.0, 20.0),
        heater_error(E::BadValue)
    );
    assert_eq!(
        m.heater_runaway(0, 5.0, 120.0, 2.0, 7200.0),
        heater_error(E::BadValue)
    );
    assert_eq!(
        m.heater_runaway(1, 5.0, 120.0, 2.0, 60.0),
        Ok(()),
        "a bed's"
    );
    assert_eq!(m.heater_read(2).map(|_| ()), heater_error(E::NoSuchHeater));
    assert_eq!(m.heater_clear(2), heater_error(E::NoSuchHeater));
    // Unconfigured: nothing runs; a target of 0 is always taken.
    assert_eq!(m.heater_target(0, 200.0), heater_error(E::NotConfigured));
    assert_eq!(m.heater_power(0, 0.5), heater_error(E::NotConfigured));
    assert_eq!(m.heater_target(0, 0.0), Ok(()));
    assert_eq!(m.heaters.wake_at(), None, "nothing to poll");
    m.heater_sensor(0, 0, T.a, T.b, T.c, T.pullup_ohms).unwrap();
    m.heater_output(0, 0, 1.0).unwrap();
    m.heater_limits(0, 0.0, 300.0).unwrap();
    assert_eq!(
        m.heater_target(0, 200.0),
        heater_error(E::NotConfigured),
        "no gains"
    );
    m.heater_gains(0, KP, KI, KD).unwrap();
    for t in [300.0, 400.0, -5.0, f32::NAN] {
        assert_eq!(m.heater_target(0, t), heater_error(E::BadValue), "{t}");
    }
    assert_eq!(m.heater_power(0, 1.5), heater_error(E::BadValue));
    assert_eq!(m.heater_output(1, 0, 1.0), heater_error(E::InUse));
    m.heater_target(0, 200.0).unwrap();
    assert_eq!(m.heater_limits(0, 0.0, 280.0), heater_error(E::Busy));
    assert_eq!(m.heater_output(0, 1, 1.0), heater_error(E::Busy));
    assert_eq!(m.heater_gains(0, 1.0, 1.0, 1.0), heater_error(E::Busy));
    // The PWM output belongs to the heater now.
    assert_eq!(
        m.pwm_write(0, 0.5),
        Err(CallError::Failed(FailureCode::Other(
            IoError::HeaterOutput.code()
        )))
    );
    assert_eq!(m.pwm_write(1, 0.5), Ok(()));

    let now = Rc::new(Cell::new(Instant::ZERO));
    let mut bare = Module::new(TestBoard {
        driver: Driver,
        plant: None,
        now,
    });
    assert_eq!(
        bare.heater_sensor(0, 0, T.a, T.b, T.c, T.pullup_ohms),
        heater_error(E::NoHardware)
    );
    assert_eq!(bare.heater_target(0, 0.0), heater_error(E::NoHardware));
    assert_eq!(bare.heater_read(0).map(|r| r.4), Ok(0));
}
