//! Outputs with a safe state: the safe values a module keeps, where it
//! applies them (`halt`, a backstop, the output watchdog), and what feeds
//! the watchdog (calls and pipe datagrams through the module's ports, not
//! its own timer's runs).

use osap_core::clock::TimeMap;
use osap_core::codec::Writer;
use osap_core::link::LinkGateway;
use osap_core::route::Route;
use osap_core::time::Instant;
use osap_core::transport::Transport;
use osap_core::Runtime;
use osap_module::board::{Board, IoHw, StepperHw};
use osap_module::fault::FaultKind;
use osap_module::functions::{FnId, ALL};
use osap_module::io::IoError;
use osap_module::ports::FN_PIPES;
use osap_module::{Module, ModuleHandle, ModulePort, ModulePorts, PORT_INDICES};
use pipes_core::control::{ControlKey, InputMode, Request};
use pipes_core::function::CallError;
use pipes_core::{ArgsWriter, FailureCode, MessageKey, Value};
use std::cell::{Cell, RefCell};
use std::rc::Rc;

struct Driver;

impl StepperHw for Driver {
    fn set_enable(&mut self, _on: bool) {}
    fn set_microsteps(&mut self, _microsteps: u16) -> bool {
        true
    }
}

/// Four digital pins and two PWM outputs, as the RP2040 and SAMD51 boards
/// have; every write is kept.
#[derive(Default)]
struct Pins {
    digital: [bool; 4],
    pwm: [u16; 2],
    writes: Vec<(char, u8, u16)>,
}

impl IoHw for Pins {
    fn digital_pins(&self) -> u8 {
        4
    }
    fn write_digital(&mut self, pin: u8, level: bool) {
        self.digital[usize::from(pin)] = level;
        self.writes.push(('d', pin, u16::from(level)));
    }
    fn read_digital(&mut self, pin: u8) -> bool {
        self.digital[usize::from(pin)]
    }
    fn pwm_outputs(&self) -> u8 {
        2
    }
    fn write_pwm(&mut self, channel: u8, duty: u16) {
        self.pwm[usize::from(channel)] = duty;
        self.writes.push(('p', channel, duty));
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

fn module(io: bool) -> (Module<TestBoard>, Rc<Cell<Instant>>) {
    let now = Rc::new(Cell::new(Instant::ZERO));
    let board = TestBoard {
        driver: Driver,
        pins: io.then(Pins::default),
        now: now.clone(),
    };
    let mut m = Module::new(board);
    m.publish_time(TimeMap::IDENTITY);
    (m, now)
}

fn pins(m: &Module<TestBoard>) -> &Pins {
    m.board().pins.as_ref().unwrap()
}

fn io_error(e: IoError) -> Result<(), CallError> {
    Err(CallError::Failed(FailureCode::Other(e.code())))
}

/// The plotter's pen servo: 0.05 is pen up.
const PEN_UP: f32 = 0.05;
const PEN_UP_RAW: u16 = 3_277;

#[test]
fn safe_values_are_validated_as_writes_are() {
    let (mut m, _) = module(true);
    assert_eq!(m.set_safe_pwm(2, 0.0), io_error(IoError::NoSuchPin));
    assert_eq!(m.set_safe_pwm(255, 0.0), io_error(IoError::NoSuchPin));
    for bad in [f32::NAN, -0.01, 1.01, f32::INFINITY] {
        assert_eq!(m.set_safe_pwm(0, bad), io_error(IoError::BadValue));
    }
    assert_eq!(m.set_safe_digital(4, true), io_error(IoError::NoSuchPin));
    assert_eq!(m.set_safe_pwm(1, 1.0), Ok(()));
    assert_eq!(m.set_safe_pwm(0, PEN_UP), Ok(()));
    assert_eq!(m.set_safe_digital(3, true), Ok(()));
    assert_eq!(m.io.safe_pwm(0), PEN_UP_RAW);
    assert_eq!(m.io.safe_pwm(1), 65_535);
    assert!(m.io.safe_digital(3) && !m.io.safe_digital(2));
    // Setting a safe value writes nothing: the output keeps its value.
    assert!(pins(&m).writes.is_empty());
    assert_eq!(m.io.safe_applied(), 0);

    let (mut bare, _) = module(false);
    assert_eq!(bare.set_safe_pwm(0, 0.0), io_error(IoError::NoHardware));
    assert_eq!(
        bare.set_safe_digital(0, false),
        io_error(IoError::NoHardware)
    );
    // A board without I/O still halts (nothing to make safe).
    assert_eq!(bare.halt(), Ok(()));
}

#[test]
fn halt_applies_every_safe_value_at_once() {
    let (mut m, now) = module(true);
    m.set_safe_pwm(0, PEN_UP).unwrap();
    m.set_safe_digital(1, true).unwrap();
    // A laser on PWM 1 (safe 0 by default), a spindle relay on pin 0, a
    // solenoid pulsing on pin 2, another scheduled on pin 3... and pin 3 is
    // otherwise never written.
    m.pwm_write(0, 0.1).unwrap();
    m.pwm_write(1, 0.8).unwrap();
    m.digital_write(0, true).unwrap();
    m.digital_write(1, false).unwrap();
    m.pulse(2, 5_000_000).unwrap();
    m.pulse_at(1_000_000, 3, 1_000).unwrap();
    assert_eq!(pins(&m).digital, [true, false, true, false]);
    now.set(Instant::from_micros(10_000));
    m.halt().unwrap();
    let p = pins(&m);
    assert_eq!(p.pwm, [PEN_UP_RAW, 0]);
    assert_eq!(p.digital, [false, true, false, false]);
    assert_eq!(m.io.safe_applied(), 1);
    assert_eq!(
        m.get_fault().unwrap(),
        (10_000, FaultKind::Halted.code(), 0, 1)
    );
    // The pulses are gone: nothing runs or waits.
    let system = m.system_now();
    assert_eq!(m.io_wake_at(Instant::from_micros(10_000), system), None);
    let writes = pins(&m).writes.len();
    m.poll_io(Instant::from_micros(2_000_000), system);
    assert_eq!(pins(&m).writes.len(), writes, "no pulse starts or ends");
    // A halt again is safe and does it again.
    m.halt().unwrap();
    assert_eq!(m.io.safe_applied(), 2);
    assert_eq!(pins(&m).pwm, [PEN_UP_RAW, 0]);
}

#[test]
fn pins_never_driven_are_left_alone() {
    let (mut m, _) = module(true);
    // Pin 2 is read as an input; only pin 0 and PWM 1 are outputs.
    m.digital_write(0, true).unwrap();
    m.pwm_write(1, 0.5).unwrap();
    m.digital_read(2).unwrap();
    m.halt().unwrap();
    let touched: Vec<(char, u8)> = pins(&m).writes.iter().map(|w| (w.0, w.1)).collect();
    assert_eq!(touched, [('d', 0), ('p', 1), ('p', 1), ('d', 0)]);
    // A safe value makes an output one, written at the next stop.
    m.set_safe_digital(2, true).unwrap();
    m.halt().unwrap();
    assert_eq!(pins(&m).digital, [false, false, true, false]);
}

#[test]
fn the_watchdog_is_off_at_boot_and_fires_at_its_timeout_not_before() {
    let (mut m, now) = module(true);
    m.set_safe_pwm(0, PEN_UP).unwrap();
    m.pwm_write(1, 1.0).unwrap();
    assert_eq!(m.watchdog.deadline(), None, "off at boot");
    m.poll_watchdog(Instant::from_micros(3_600_000_000));
    assert_eq!(pins(&m).pwm, [0, 65_535], "a bare module keeps its outputs");

    now.set(Instant::from_micros(1_000_000));
    m.set_output_watchdog(500).unwrap();
    assert_eq!(m.watchdog.deadline(), Some(Instant::from_micros(1_500_000)));
    m.poll_watchdog(Instant::from_micros(1_499_999));
    assert_eq!(pins(&m).pwm, [0, 65_535], "not a µs before");
    assert_eq!(m.get_fault().unwrap().3, 0);
    m.poll_watchdog(Instant::from_micros(1_500_000));
    assert_eq!(pins(&m).pwm, [PEN_UP_RAW, 0], "at its timeout");
    assert_eq!(
        m.get_fault().unwrap(),
        (1_500_000, FaultKind::OutputWatchdog.code(), 500_000, 1)
    );
    // Fired, it stays fired: nothing more happens until a call feeds it.
    m.poll_watchdog(Instant::from_micros(9_000_000));
    assert_eq!((m.io.safe_applied(), m.get_fault().unwrap().3), (1, 1));
    // Fed, it counts again; the outputs stay safe until written.
    m.feed_watchdog(Instant::from_micros(9_000_000));
    assert_eq!(pins(&m).pwm, [PEN_UP_RAW, 0]);
    assert_eq!(m.watchdog.deadline(), Some(Instant::from_micros(9_500_000)));
    // Off again.
    m.set_output_watchdog(0).unwrap();
    m.poll_watchdog(Instant::from_micros(99_000_000));
    assert_eq!(m.watchdog.fires(), 1);
}

#[test]
fn a_backstop_makes_the_outputs_safe_and_a_clean_stop_does_not() {
    let (mut m, now) = module(true);
    m.set_enable(true).unwrap();
    m.pwm_write(1, 0.7).unwrap();
    let iv = 2048u64;
    now.set(Instant::from_micros(1_000));
    // A stream that ends at rest: no fault, the laser stays as written.
    for k in 0..4 {
        m.add_point(k * iv, 0.0).unwrap();
    }
    for k in 4..8 {
        m.add_point(k * iv, 0.25).unwrap();
    }
    let mut local = 0;
    while local < 30 * iv {
        m.fill_step_word(Instant::from_micros(local));
        local += 160;
    }
    assert_eq!(pins(&m).pwm[1], 45_875);
    assert_eq!(m.io.safe_applied(), 0);
    // One cut off mid-motion: the backstop brakes it, and the laser goes
    // off with it.
    let t0 = 40 * iv;
    for k in 0..3 {
        m.add_point(t0 + k * iv, 0.25).unwrap();
    }
    for k in 3..8 {
        m.add_point(t0 + k * iv, 0.25 + (k - 2) as f32 * 0.5)
            .unwrap();
    }
    let mut local = t0;
    while local < t0 + 30 * iv {
        m.fill_step_word(Instant::from_micros(local));
        local += 160;
    }
    assert_eq!(m.get_fault().unwrap().1, FaultKind::Backstop.code());
    assert_eq!(pins(&m).pwm[1], 0);
    assert_eq!(m.io.safe_applied(), 1);
}

/// A host's handle on a module, as function ports hold it.
#[derive(Clone)]
struct Shared(Rc<RefCell<Module<TestBoard>>>);

impl ModuleHandle for Shared {
    type Board = TestBoard;
    fn with<R>(&self, f: impl FnOnce(&mut Module<TestBoard>) -> R) -> Option<R> {
        Some(f(&mut self.0.borrow_mut()))
    }
}

/// A module's runtime and ports, as a firmware runs them, polled at times
/// the test sets.
struct Node {
    runtime: Runtime<16, 256, PORT_INDICES, 1>,
    ports: ModulePorts<Shared>,
    module: Shared,
    now: Rc<Cell<Instant>>,
    seq: u16,
}

/// The runtime index of function `id`'s control port.
fn port_of(id: FnId) -> u16 {
    let i = ALL.iter().position(|f| *f == id).unwrap() as u16;
    1 + i * (1 + FN_PIPES as u16)
}

impl Node {
    fn new() -> Self {
        let (m, now) = module(true);
        let module = Shared(Rc::new(RefCell::new(m)));
        Node {
            runtime: Runtime::new("stepper", "a").unwrap(),
            ports: ModulePorts::new(module.clone()).unwrap(),
            module,
            now,
            seq: 0,
        }
    }

    /// Polls the runtime at local time `us`.
    fn poll(&mut self, us: u64) -> Option<Instant> {
        let now = Instant::from_micros(us);
        self.now.set(now);
        let mut links: [&mut dyn LinkGateway; 0] = [];
        let r = self.runtime.poll(now, self.ports.ports(), &mut links);
        self.module
            .with(|m| m.publish_time(self.runtime.time_map()));
        r.wake_at
    }

    /// Delivers `body` (after its transport header) to function `id` at
    /// local time `us`, from this runtime's port 0.
    fn send(&mut self, us: u64, id: FnId, transport: Transport, body: &[u8]) {
        let mut payload = vec![0u8; 256];
        let h = transport.encode(&mut payload).unwrap();
        payload[h..h + body.len()].copy_from_slice(body);
        payload.truncate(h + body.len());
        let now = Instant::from_micros(us);
        self.runtime
            .send(now, 0, &Route::local(), port_of(id), 50_000, &payload)
            .unwrap();
        self.poll(us);
    }

    /// Calls function `id` with `args` at local time `us`.
    fn call(&mut self, us: u64, id: FnId, args: &[Value<'_>]) {
        let mut buf = vec![0u8; 200];
        let mut w = Writer::new(&mut buf);
        w.u8(ControlKey::Call.to_u8()).unwrap();
        let mut a = ArgsWriter::new(&mut w).unwrap();
        for (i, v) in args.iter().enumerate() {
            a.push(i as u8, v).unwrap();
        }
        a.finish().unwrap();
        let n = w.len();
        self.seq += 1;
        self.send(us, id, Transport::Request(self.seq), &buf[..n]);
    }

    /// Sends function `id` a pipe datagram with `args` at local time `us`.
    fn datagram(&mut self, us: u64, id: FnId, args: &[Value<'_>]) {
        let mut buf = vec![0u8; 200];
        let mut w = Writer::new(&mut buf);
        let mut a = ArgsWriter::message(&mut w, MessageKey::PipeDatagram).unwrap();
        for (i, v) in args.iter().enumerate() {
            a.push(i as u8, v).unwrap();
        }
        a.finish().unwrap();
        let n = w.len();
        self.send(us, id, Transport::Raw, &buf[..n]);
    }

    fn pwm(&self) -> [u16; 2] {
        self.module.0.borrow().board().pins.as_ref().unwrap().pwm
    }

    fn fired(&self) -> u32 {
        self.module.0.borrow().watchdog.fires()
    }
}

#[test]
fn calls_and_datagrams_feed_the_watchdog_and_timer_runs_do_not() {
    let mut n = Node::new();
    n.poll(0);
    n.call(
        1_000,
        FnId::set_safe_pwm,
        &[Value::U8(0), Value::F32(PEN_UP)],
    );
    n.call(2_000, FnId::pwm_write, &[Value::U8(0), Value::F32(0.1)]);
    assert_eq!(n.pwm(), [6_554, 0]);
    n.call(10_000, FnId::set_output_watchdog, &[Value::U32(500)]);
    // The runtime wakes for the watchdog's deadline (or sooner).
    let deadline = n.module.with(|m| m.watchdog.deadline()).unwrap();
    assert_eq!(deadline, Some(Instant::from_micros(510_000)));
    assert!(n.poll(20_000) <= deadline);

    // A get_status poll at 400 ms feeds it: the deadline moves to 900 ms.
    n.call(400_000, FnId::get_status, &[]);
    n.poll(899_999);
    assert_eq!(n.fired(), 0, "fed at 400 ms");
    // A pipe datagram into pwm_write at 850 ms feeds it too.
    n.datagram(850_000, FnId::pwm_write, &[Value::U8(0), Value::F32(0.2)]);
    assert_eq!(n.pwm(), [13_107, 0]);
    // A refused call reached the module as well: it feeds.
    n.call(1_300_000, FnId::pwm_write, &[Value::U8(9), Value::F32(0.2)]);
    n.poll(1_799_999);
    assert_eq!((n.fired(), n.pwm()), (0, [13_107, 0]));

    // A get_status poll at 1.7 s: the deadline is 2.2 s.
    n.call(1_700_000, FnId::get_status, &[]);
    // get_fault set to run on its own timer every 10 ms (a source, as a
    // machine sets it up) runs, but says nothing of upstream; nor does the
    // request that set its mode (not a call).
    let mut buf = vec![0u8; 16];
    let mut w = Writer::new(&mut buf);
    Request::SetInputMode(InputMode::OnTimer(10_000))
        .encode(&mut w)
        .unwrap();
    let len = w.len();
    n.send(
        1_750_000,
        FnId::get_fault,
        Transport::Request(99),
        &buf[..len],
    );
    let mut t = 1_750_000;
    while t < 2_199_000 {
        t += 1_000;
        n.poll(t);
    }
    n.poll(2_199_999);
    assert_eq!(n.fired(), 0);
    let runs = match &n.ports.ports()[ALL.iter().position(|f| *f == FnId::get_fault).unwrap()] {
        ModulePort::Function(f) => f.stats().runs,
        ModulePort::Timer(_) | ModulePort::Sampler(_) => unreachable!("a function port"),
    };
    assert!(runs >= 40, "get_fault ran on its timer: {runs}");
    n.poll(2_200_000);
    assert_eq!(n.fired(), 1, "500 ms after the last call");
    assert_eq!(n.pwm(), [PEN_UP_RAW, 0]);
    let (time, code, detail, _) = n.module.0.borrow_mut().get_fault().unwrap();
    assert_eq!(code, FaultKind::OutputWatchdog.code());
    assert_eq!(detail, 500_000);
    assert_eq!(time, 2_200_000);
    // Fired, it waits for a call; the pen stays up until written.
    n.poll(5_000_000);
    assert_eq!(n.fired(), 1);
    n.call(5_000_000, FnId::get_status, &[]);
    assert_eq!(n.pwm(), [PEN_UP_RAW, 0]);
    n.poll(5_500_000);
    assert_eq!(n.fired(), 2, "armed again by the call");
}
