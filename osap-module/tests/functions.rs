//! The module's functions on a module value, through its function ports
//! and as methods, and the firmware's static cell.

use osap_core::clock::TimeMap;
use osap_core::time::{Duration, Instant, SystemInstant};
use osap_module::board::{Board, IoHw, StepperHw};
use osap_module::functions::{FnId, ModuleFn, ALL, SIGNATURES};
use osap_module::{Module, ModuleCell, ModuleHandle, ModulePorts, PORT_COUNT};
use pipes_core::function::{call_direct, CallError};
use pipes_core::Value;
use std::cell::{Cell, RefCell};
use std::collections::HashSet;
use std::rc::Rc;

struct Driver {
    enabled: Rc<Cell<bool>>,
}

impl StepperHw for Driver {
    fn set_enable(&mut self, on: bool) {
        self.enabled.set(on);
    }
    fn set_microsteps(&mut self, microsteps: u16) -> bool {
        microsteps <= 16
    }
}

struct Pins([bool; 4]);

impl IoHw for Pins {
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
    fn read_pwm(&self, _channel: u8) -> u16 {
        0
    }
    fn analog_inputs(&self) -> u8 {
        1
    }
    fn read_analog(&mut self, _channel: u8) -> u16 {
        65_535
    }
}

/// A board made of memory, its clock set by the test.
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

struct Fixture {
    module: Module<TestBoard>,
    enabled: Rc<Cell<bool>>,
    now: Rc<Cell<Instant>>,
}

fn fresh(io: bool) -> Fixture {
    let enabled = Rc::new(Cell::new(true));
    let now = Rc::new(Cell::new(Instant::ZERO));
    let board = TestBoard {
        driver: Driver {
            enabled: enabled.clone(),
        },
        pins: io.then_some(Pins([false; 4])),
        now: now.clone(),
    };
    let module = Module::new(board);
    assert!(!enabled.get(), "a new module disables its driver");
    Fixture {
        module,
        enabled,
        now,
    }
}

/// A host's handle on a module: what function ports hold.
#[derive(Clone)]
struct Shared(Rc<RefCell<Module<TestBoard>>>);

impl Shared {
    fn new(m: Module<TestBoard>) -> Self {
        Shared(Rc::new(RefCell::new(m)))
    }
}

impl ModuleHandle for Shared {
    type Board = TestBoard;
    fn with<R>(&self, f: impl FnOnce(&mut Module<TestBoard>) -> R) -> Option<R> {
        Some(f(&mut self.0.borrow_mut()))
    }
}

/// Calls function `id` bound to `module` as a runtime's port would.
fn call<H: ModuleHandle>(
    module: &H,
    id: FnId,
    inputs: &[Value<'_>],
) -> Result<Vec<Value<'static>>, CallError> {
    let mut f = ModuleFn::new(id, module.clone());
    let mut buf = [0u8; 64];
    let args = call_direct(&mut f, inputs, &mut buf)?;
    Ok(args
        .iter()
        .map(|(_, v)| match v {
            Value::U64(x) => Value::U64(x),
            Value::F32(x) => Value::F32(x),
            Value::U8(x) => Value::U8(x),
            Value::U16(x) => Value::U16(x),
            Value::U32(x) => Value::U32(x),
            Value::I64(x) => Value::I64(x),
            Value::Bool(x) => Value::Bool(x),
            other => panic!("unexpected output {other:?}"),
        })
        .collect())
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
    let mut ports =
        ModulePorts::new(Shared::new(fresh(true).module)).expect("every signature is accepted");
    assert_eq!(ports.ports().len(), PORT_COUNT);
    // sample_block's port stands beside the others, in its slot's place.
    let functions: u16 = ports
        .ports()
        .iter()
        .map(osap_core::port::Port::port_count)
        .sum::<u16>()
        + osap_core::port::Port::port_count(ports.sampler());
    // The block manager and its pools follow the functions.
    let blocks = 1 + osap_module::blocks::BLOCK_SLOTS as u16 * 3;
    assert_eq!(osap_core::port::Port::port_count(ports.blocks()), blocks);
    let all = osap_core::port::Port::port_count(&ports);
    assert_eq!(all, functions + blocks);
    assert_eq!(usize::from(all) + 1, osap_module::PORT_INDICES);
}

#[test]
fn functions_drive_the_module() {
    let Fixture {
        module: mut m,
        enabled,
        now,
    } = fresh(true);
    assert_eq!(
        m.add_point(0, 0.0),
        Err(CallError::Failed(pipes_core::FailureCode::Other(6))),
        "disabled"
    );
    m.set_enable(true).unwrap();
    assert!(enabled.get());
    assert_eq!(
        m.set_microsteps(32),
        Err(CallError::Failed(pipes_core::FailureCode::Other(10))),
        "the driver cannot"
    );
    m.set_microsteps(2).unwrap();
    m.publish_time(TimeMap::IDENTITY);
    let iv = 2048u64;
    for k in 0..4 {
        m.add_point(k * iv, 0.0).unwrap();
    }
    for k in 4..12 {
        m.add_point(k * iv, 1.0).unwrap();
    }
    let mut local = 0;
    while local < 30 * iv {
        m.fill_step_word(Instant::from_micros(local));
        local += 160;
    }
    let (steps, up, down, overruns) = m.get_steps().unwrap();
    assert_eq!((steps, up, down, overruns), (160, 160, 0, 0));
    let (_, pos) = m.get_position().unwrap();
    assert!((pos - 1.0).abs() < 1e-6, "{pos}");
    let (mode, queued, enabled, faults) = m.get_status().unwrap();
    assert_eq!((mode, queued, enabled, faults), (3, 12, true, 0));
    let (points, refused, last, filled) = m.get_counters().unwrap();
    assert_eq!((points, refused, last, filled), (12, 1, 6, 0));
    // The limit switch: its level at boot counts no edge; an edge
    // reports its own time stamp.
    m.limit_initial(true);
    assert_eq!(m.read_limit().unwrap(), (0, true, 0));
    now.set(Instant::from_micros(77_000));
    m.limit_changed(Instant::from_micros(70_000), false);
    assert_eq!(m.read_limit().unwrap(), (70_000, false, 1));
    // I/O: a read carries the synchronized time of the read.
    m.digital_write(2, true).unwrap();
    assert_eq!(m.digital_read(2).unwrap(), (77_000, true));
    assert_eq!(
        m.digital_read(9),
        Err(CallError::Failed(pipes_core::FailureCode::Other(1)))
    );
    assert_eq!(m.analog_read(0).unwrap(), (77_000, 1.0));
    m.pulse(1, 100).unwrap();
    assert_eq!(
        m.pwm_write(0, 2.0),
        Err(CallError::Failed(pipes_core::FailureCode::Other(2)))
    );
    m.halt().unwrap();
    assert_eq!(m.get_status().unwrap().0, 4);
}

#[test]
fn io_functions_fail_cleanly_without_io_hardware() {
    let mut m = fresh(false).module;
    assert_eq!(
        m.digital_write(0, true),
        Err(CallError::Failed(pipes_core::FailureCode::Other(4)))
    );
    assert_eq!(
        m.analog_read(0),
        Err(CallError::Failed(pipes_core::FailureCode::Other(4)))
    );
    assert!(m.get_status().is_ok());
}

#[test]
fn step_words_follow_a_new_time_map_at_once() {
    let mut m = fresh(false).module;
    m.publish_time(TimeMap::IDENTITY);
    let last_tick = |m: &mut Module<TestBoard>, local| {
        m.fill_step_word(local);
        m.get_position().unwrap().0
    };
    assert_eq!(
        last_tick(&mut m, Instant::from_micros(1_000_000)),
        1_000_150
    );
    // A rate of +400 ppm since local 0: the next word, well within the
    // anchor's span, must use it, not the anchor taken under the old map.
    let mut clock: osap_core::clock::Clock<1> = osap_core::clock::Clock::new(Default::default());
    clock.set_rate_ppb(Instant::ZERO, 400_000);
    let map = clock.time_map();
    m.publish_time(map);
    assert_eq!(
        last_tick(&mut m, Instant::from_micros(1_000_160)),
        (map.system_time(Instant::from_micros(1_000_160)) + Duration::from_micros(150)).as_micros()
    );
    assert_eq!(
        map.system_time(Instant::from_micros(1_000_160)),
        SystemInstant::from_micros(1_000_560)
    );
}

#[test]
fn two_modules_in_one_process_are_independent() {
    let (a, b) = (
        Shared::new(fresh(false).module),
        Shared::new(fresh(false).module),
    );
    call(&a, FnId::set_enable, &[Value::Bool(true)]).unwrap();
    call(&a, FnId::set_scale, &[Value::F32(100.0)]).unwrap();
    // b is untouched: still disabled, so it refuses points.
    assert_eq!(
        call(&b, FnId::add_point, &[Value::U64(0), Value::F32(0.0)]),
        Err(CallError::Failed(pipes_core::FailureCode::Other(6)))
    );
    call(&a, FnId::add_point, &[Value::U64(0), Value::F32(0.0)]).unwrap();
    let status = |h: &Shared| call(h, FnId::get_status, &[]).unwrap();
    assert_eq!(status(&a)[2], Value::Bool(true));
    assert_eq!(status(&a)[1], Value::U16(1));
    assert_eq!(status(&b)[2], Value::Bool(false));
    assert_eq!(status(&b)[1], Value::U16(0));
    let counters = |h: &Shared| call(h, FnId::get_counters, &[]).unwrap();
    assert_eq!(counters(&a)[0], Value::U32(1));
    assert_eq!(counters(&b)[1], Value::U32(1), "b counted its refusal");
    // Wrong input types are an error, not a panic.
    assert!(call(&a, FnId::add_point, &[Value::Bool(true)]).is_err());
    assert!(call(&a, FnId::add_point, &[]).is_err());
}

struct Limp;

impl StepperHw for Limp {
    fn set_enable(&mut self, _on: bool) {}
    fn set_microsteps(&mut self, _microsteps: u16) -> bool {
        false
    }
}

fn zero() -> Instant {
    Instant::ZERO
}

#[test]
fn a_firmware_cell_refuses_until_installed() {
    use osap_module::board::{NoIo, Parts};
    static CELL: ModuleCell<Parts<Limp, NoIo>> = ModuleCell::new();
    let refused = Err(CallError::Failed(pipes_core::FailureCode::from_code(
        osap_module::functions::NOT_INSTALLED,
    )));
    assert_eq!(
        call(&&CELL, FnId::add_point, &[Value::U64(0), Value::F32(0.0)]).map(|_| ()),
        refused
    );
    assert_eq!(call(&&CELL, FnId::read_limit, &[]).map(|_| ()), refused);
    assert_eq!(CELL.fill_step_word(Instant::ZERO), 0);
    CELL.limit_changed(Instant::ZERO, true);
    CELL.install(Parts {
        stepper: Limp,
        io: None,
        clock: zero,
        bootloader: None,
    });
    call(&&CELL, FnId::set_enable, &[Value::Bool(true)]).unwrap();
    CELL.limit_changed(Instant::from_micros(5), true);
    assert_eq!(
        call(&&CELL, FnId::read_limit, &[]).unwrap(),
        vec![Value::U64(5), Value::Bool(true), Value::U32(1)]
    );
    assert_eq!(
        call(
            &&CELL,
            FnId::digital_write,
            &[Value::U8(0), Value::Bool(true)]
        ),
        Err(CallError::Failed(pipes_core::FailureCode::Other(4))),
        "no I/O hardware"
    );
    assert_eq!(
        call(&&CELL, FnId::set_microsteps, &[Value::U16(2)]),
        Err(CallError::Failed(pipes_core::FailureCode::Other(10))),
        "the driver has no mode pins"
    );
}

#[test]
fn get_fault_reports_refusals_backstops_overruns_limits_and_halts() {
    use osap_module::fault::FaultKind;
    let Fixture {
        module: mut m, now, ..
    } = fresh(false);
    m.publish_time(TimeMap::IDENTITY);
    assert_eq!(m.get_fault().unwrap(), (0, 0, 0, 0), "none yet");
    // A refused point: disabled (code 6), at the module's time.
    now.set(Instant::from_micros(5_000));
    assert_eq!(
        m.add_point(0, 0.0),
        Err(CallError::Failed(pipes_core::FailureCode::Other(6)))
    );
    assert_eq!(
        m.get_fault().unwrap(),
        (5_000, FaultKind::Refused.code(), 6, 1)
    );
    m.set_enable(true).unwrap();
    // A stream cut off mid-motion: the backstop, with the upstream's quiet
    // time since the last point was accepted (at 10 000).
    let iv = 2048u64;
    now.set(Instant::from_micros(10_000));
    for k in 0..3 {
        m.add_point(k * iv, 0.0).unwrap();
    }
    for k in 3..10 {
        m.add_point(k * iv, (k - 2) as f32 * 0.5).unwrap();
    }
    let mut local = 0;
    while local < 40 * iv {
        m.fill_step_word(Instant::from_micros(local));
        local += 160;
    }
    let (time, code, quiet, count) = m.get_fault().unwrap();
    assert_eq!((code, count), (FaultKind::Backstop.code(), 2));
    assert!(
        time > 5 * iv && u64::from(quiet) == time - 10_000,
        "{time} {quiet}"
    );
    // The refusals behind it count but keep their cause.
    assert_eq!(
        m.add_point(50 * iv, 0.0),
        Err(CallError::Failed(pipes_core::FailureCode::Other(4)))
    );
    assert_eq!(
        m.get_fault().unwrap(),
        (time, FaultKind::Backstop.code(), quiet, 3)
    );
    // A limit press (the input reads low) is a fault; its release is not.
    m.limit_changed(Instant::from_micros(100_000), false);
    assert_eq!(
        m.get_fault().unwrap(),
        (100_000, FaultKind::LimitHit.code(), 1, 4)
    );
    m.limit_changed(Instant::from_micros(101_000), true);
    assert_eq!(m.get_fault().unwrap().3, 4);
    // A halt.
    now.set(Instant::from_micros(200_000));
    m.halt().unwrap();
    assert_eq!(
        m.get_fault().unwrap(),
        (200_000, FaultKind::Halted.code(), 0, 5)
    );
    // A move faster than the step rate sends steps late: each word that
    // sent some records the running count.
    m.set_enable(false).unwrap();
    m.set_enable(true).unwrap();
    m.set_microsteps(16).unwrap();
    let t0 = 300 * iv;
    now.set(Instant::from_micros(t0));
    let (_, here) = m.get_position().unwrap();
    for k in 0..3 {
        m.add_point(t0 + k * iv, here).unwrap();
    }
    // 1 unit per interval: 1280 microsteps in 2048 µs, 6x the tick rate.
    for k in 3..8 {
        m.add_point(t0 + k * iv, here + (k - 2) as f32).unwrap();
    }
    // Ending at rest: no backstop fault.
    for k in 8..12 {
        m.add_point(t0 + k * iv, here + 5.0).unwrap();
    }
    let mut local = t0;
    let mut late_words = 0;
    while local < t0 + 40 * iv {
        let late = m.get_steps().unwrap().3;
        m.fill_step_word(Instant::from_micros(local));
        let now_late = m.get_steps().unwrap().3;
        if now_late != late {
            late_words += 1;
            let (_, code, detail, _) = m.get_fault().unwrap();
            assert_eq!(
                (code, u64::from(detail)),
                (FaultKind::StepOverrun.code(), now_late)
            );
        }
        local += 160;
    }
    let (_, code, detail, count) = m.get_fault().unwrap();
    let (_, up, down, late) = m.get_steps().unwrap();
    assert_eq!((up, down), (6_400, 0), "no step lost");
    // 6 400 steps over 5 intervals of 2 048 µs, 1 024 ticks: at most one
    // step a tick went out on time.
    assert!(late >= 6_400 - 1_024, "{late}");
    assert_eq!(code, FaultKind::StepOverrun.code());
    assert_eq!(u64::from(detail), late, "the running count");
    assert_eq!(count, 5 + late_words);
    assert!(late_words > 1);
}

#[test]
fn late_steps_wait_behind_a_fresh_fault_then_report_the_whole_count() {
    use osap_module::fault::{FaultKind, FAULT_HOLD};
    let Fixture {
        module: mut m, now, ..
    } = fresh(false);
    m.publish_time(TimeMap::IDENTITY);
    m.set_enable(true).unwrap();
    m.set_microsteps(16).unwrap();
    let iv = 2048u64;
    let t0 = 10 * iv;
    now.set(Instant::from_micros(t0));
    for k in 0..3 {
        m.add_point(t0 + k * iv, 0.0).unwrap();
    }
    // 1 unit per interval: 1 280 microsteps in 2 048 µs, 6x the tick rate.
    for k in 3..8 {
        m.add_point(t0 + k * iv, (k - 2) as f32).unwrap();
    }
    for k in 8..12 {
        m.add_point(t0 + k * iv, 5.0).unwrap();
    }
    // The limit switch is pressed as the move starts.
    let pressed = t0 + 2 * iv + 500;
    m.limit_changed(Instant::from_micros(pressed), false);
    let hold_ends = pressed + FAULT_HOLD.as_micros();
    let mut local = t0;
    let mut first_report = None;
    while local < t0 + 60 * iv {
        m.fill_step_word(Instant::from_micros(local));
        let (time, code, detail, _) = m.get_fault().unwrap();
        if local < hold_ends {
            assert_eq!(
                (time, code),
                (pressed, FaultKind::LimitHit.code()),
                "the press is the record for {} µs",
                FAULT_HOLD.as_micros()
            );
        } else {
            assert_eq!(code, FaultKind::StepOverrun.code());
            first_report.get_or_insert((time, detail));
        }
        local += 160;
    }
    let (_, up, _, late) = m.get_steps().unwrap();
    assert_eq!(up, 6_400);
    assert!(late >= 6_400 - 1_024, "{late}");
    // Made at the first word after the hold, with every late step.
    let (time, detail) = first_report.expect("the late steps were reported");
    assert!((hold_ends..hold_ends + 160).contains(&time), "{time}");
    assert_eq!(u64::from(detail), late);
    // The press and one late-step record.
    assert_eq!(m.get_fault().unwrap().3, 2);
}

/// The table index of `id`, as `sample_block` takes it.
fn index(id: FnId) -> u8 {
    ALL.iter().position(|f| *f == id).unwrap() as u8
}

/// One source's outputs in a record: (index, value as printed).
type Outputs = Vec<(u8, String)>;

/// A block's records: per record its offset and each source's outputs.
fn records(bytes: &[u8], sources: usize) -> Vec<(u32, Vec<Outputs>)> {
    let mut r = osap_core::codec::Reader::new(bytes);
    let mut out = Vec::new();
    while !r.is_empty() {
        let offset = r.u32().unwrap();
        let lists = (0..sources)
            .map(|_| {
                let args = pipes_core::Args::decode(&mut r).unwrap();
                args.iter().map(|(i, v)| (i, format!("{v:?}"))).collect()
            })
            .collect();
        out.push((offset, lists));
    }
    out
}

#[test]
fn sample_block_batches_stamped_numbered_samples() {
    let Fixture {
        module: mut m, now, ..
    } = fresh(true);
    let (pos, analog) = (index(FnId::get_position), index(FnId::analog_read));
    // 1 kHz for 100 ms: get_position and analog_read(0) each time.
    let mut blocks = Vec::new();
    for k in 0..100u64 {
        now.set(Instant::from_micros(1_000 + 1_000 * k));
        let out = m
            .sample_block(pos, 0, analog, 0, 255, 0, 20_000, 7)
            .unwrap();
        if out.0 > 0
            && blocks
                .last()
                .is_none_or(|b: &(u32, u32, u64, _, u32)| b.0 != out.0)
        {
            blocks.push(out);
        }
    }
    // A record: 4 bytes of offset, 17 of get_position (a count, then
    // index, type key and value of a u64 and an f32), 17 of analog_read:
    // 38, so five to a block of 192 bytes.
    assert_eq!(blocks.len(), 20);
    for (k, (seq, first, time, block, session)) in blocks.iter().enumerate() {
        assert_eq!((*seq, *session), (k as u32 + 1, 7));
        assert_eq!(*first, 5 * k as u32);
        assert_eq!(*time, 1_000 + 1_000 * u64::from(*first));
        let recs = records(block.bytes(), 2);
        let offsets: Vec<u32> = recs.iter().map(|r| r.0).collect();
        assert_eq!(offsets, [0, 1_000, 2_000, 3_000, 4_000]);
        for (offset, lists) in &recs {
            // analog_read stamps its own sample: the block's time plus
            // the record's offset, and reads full scale.
            let t = time + u64::from(*offset);
            assert_eq!(
                lists[1],
                [
                    (0, format!("{:?}", Value::U64(t))),
                    (1, format!("{:?}", Value::F32(1.0)))
                ]
            );
            assert_eq!(lists[0].len(), 2, "get_position's time and position");
        }
    }
    // At 100 Hz a block closes by age: its first sample 20 ms old.
    let mut firsts = Vec::new();
    for k in 0..10u64 {
        now.set(Instant::from_micros(200_000 + 10_000 * k));
        let (seq, first, _, block, _) = m.sample_block(pos, 0, 255, 0, 255, 0, 20_000, 8).unwrap();
        if seq > 0 && firsts.last().is_none_or(|f: &(u32, u32, usize)| f.0 != seq) {
            firsts.push((seq, first, records(block.bytes(), 1).len()));
        }
    }
    // A new session: numbering from 1 again.
    assert_eq!(firsts, [(1, 0, 3), (2, 3, 3), (3, 6, 3)]);
    // Latency 0 closes the open block (sample 9) without a sample.
    let (seq, first, _, block, _) = m.sample_block(pos, 0, 255, 0, 255, 0, 0, 8).unwrap();
    assert_eq!((seq, first, records(block.bytes(), 1).len()), (4, 9, 1));
    // Again: nothing open, nothing new.
    assert_eq!(m.sample_block(pos, 0, 255, 0, 255, 0, 0, 8).unwrap().0, 4);
    assert_eq!(m.sampler.taken(), 10);
}

#[test]
fn sample_block_takes_only_read_functions() {
    let Fixture { module: mut m, .. } = fresh(true);
    let bad = CallError::Failed(pipes_core::FailureCode::Other(1));
    for id in [FnId::sample_block, FnId::add_point, FnId::halt, FnId::pulse] {
        assert_eq!(
            m.sample_block(index(id), 0, 255, 0, 255, 0, 20_000, 1),
            Err(bad),
            "{id:?}"
        );
    }
    assert_eq!(m.sample_block(255, 0, 255, 0, 255, 0, 20_000, 1), Err(bad));
    assert_eq!(m.sample_block(200, 0, 255, 0, 255, 0, 20_000, 1), Err(bad));
    // A source that fails (no analog input 3) leaves an empty list.
    let analog = index(FnId::analog_read);
    m.sample_block(analog, 3, 255, 0, 255, 0, 20_000, 2)
        .unwrap();
    let (_, _, _, block, _) = m.sample_block(analog, 3, 255, 0, 255, 0, 0, 2).unwrap();
    assert_eq!(records(block.bytes(), 1), [(0, vec![vec![]])]);
}
