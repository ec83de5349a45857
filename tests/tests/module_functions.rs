//! The firmware's function set over the wire: the module logic of
//! `osap-module` (what every board's firmware runs) carried by a host
//! runtime, scanned and called from another host exactly as a script
//! would call a module on a USB cable.

use osap_host::link::memory;
use osap_host::som::{FnRef, Manager, SomError, Value};
use osap_host::{Host, HostConfig};
use osap_module::board::Parts;
use osap_module::board::{IoHw, StepperHw};
use osap_module::functions::SIGNATURES;
use osap_module::{ModuleCell, ModulePorts};
use pipes_core::control::ControlError;
use std::sync::OnceLock;
use std::time::Instant;

fn clock() -> osap_core::Instant {
    static START: OnceLock<Instant> = OnceLock::new();
    osap_core::Instant::from_micros(START.get_or_init(Instant::now).elapsed().as_micros() as u64)
}

struct Driver;

impl StepperHw for Driver {
    fn set_enable(&mut self, _on: bool) {}
    fn set_microsteps(&mut self, microsteps: u16) -> bool {
        microsteps <= 16
    }
}

struct Board([bool; 8]);

impl IoHw for Board {
    fn digital_pins(&self) -> u8 {
        8
    }
    fn write_digital(&mut self, pin: u8, level: bool) {
        self.0[usize::from(pin)] = level;
    }
    fn read_digital(&mut self, pin: u8) -> bool {
        self.0[usize::from(pin)]
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
    fn read_analog(&mut self, channel: u8) -> u16 {
        u16::from(channel) * 1000
    }
}

fn call_failed(e: SomError) -> u8 {
    match e {
        SomError::Remote {
            error: ControlError::CallFailed(code),
            ..
        } => code.code(),
        other => panic!("expected a failure code, got {other}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_module_is_scanned_and_called_over_the_wire() {
    static MODULE: ModuleCell<Parts<Driver, Board>> = ModuleCell::new();
    MODULE.install(Parts {
        stepper: Driver,
        io: Some(Board([false; 8])),
        clock,
        bootloader: None,
    });
    let module = Host::start(HostConfig::named("stepper-0")).unwrap();
    let (functions, sampler, _blocks) = ModulePorts::new(&MODULE).unwrap().into_parts();
    let mut sampler = Some(sampler);
    for port in functions {
        // A host holds only ports with indices: the pulse timer (none) is
        // left out, so pulses here would not end. sample_block's port
        // stands where its slot is.
        if let osap_module::ModulePort::Sampler(_) = port {
            if let Some(s) = sampler.take() {
                module.attach_port(Box::new(s)).await.unwrap();
            }
        } else if osap_core::port::Port::port_count(&port) > 0 {
            module.attach_port(Box::new(port)).await.unwrap();
        }
    }
    let h = Host::start(HostConfig::named("script")).unwrap();
    memory::connect(&h, &module).await.unwrap();

    let mut m = Manager::new(&h).await.unwrap();
    let report = m.refresh().await.unwrap();
    assert!(
        report.function_failures.is_empty(),
        "{:?}",
        report.function_failures
    );
    let rt = m
        .som()
        .runtimes
        .iter()
        .find(|r| r.record.name == "stepper-0")
        .expect("the module is found");
    // Every function, with its argument names and types, as declared.
    assert_eq!(rt.functions.len(), SIGNATURES.len());
    for sig in SIGNATURES {
        let f = rt
            .functions
            .iter()
            .find(|f| f.name == sig.name)
            .unwrap_or_else(|| panic!("{} not found", sig.name));
        let names = |args: &[osap_host::som::model::SomArg]| {
            args.iter().map(|a| a.name.clone()).collect::<Vec<_>>()
        };
        let want = |args: &[pipes_core::signature::Arg]| {
            args.iter().map(|a| a.name.to_string()).collect::<Vec<_>>()
        };
        assert_eq!(names(&f.inputs), want(sig.inputs), "{}", sig.name);
        assert_eq!(names(&f.outputs), want(sig.outputs), "{}", sig.name);
    }

    let f = |name: &str| m.function(&FnRef::new("stepper-0", name)).unwrap();
    // Refusals come back as their codes.
    let e = f("add_point")
        .call(&[Value::U64(0), Value::F32(0.0)])
        .await
        .unwrap_err();
    assert_eq!(call_failed(e), 6, "disabled");
    f("set_enable").call(&[Value::Bool(true)]).await.unwrap();
    let e = f("set_microsteps")
        .call(&[Value::U16(32)])
        .await
        .unwrap_err();
    assert_eq!(call_failed(e), 10);
    // A short stream, then the step words a step interrupt would take.
    let iv = 2048u64;
    for k in 0..12u64 {
        let p = if k < 4 { 0.0 } else { 0.5 };
        f("add_point")
            .call(&[Value::U64(k * iv), Value::F32(p)])
            .await
            .unwrap();
    }
    let mut local = 0;
    while local < 40 * iv {
        MODULE.fill_step_word(osap_core::Instant::from_micros(local));
        local += 160;
    }
    let steps = f("get_steps").call(&[]).await.unwrap();
    assert_eq!(steps[0], Value::I64(40));
    let status = f("get_status").call(&[]).await.unwrap();
    assert_eq!(status[1], Value::U16(12));
    // I/O, and a time-stamped read.
    f("digital_write")
        .call(&[Value::U8(5), Value::Bool(true)])
        .await
        .unwrap();
    let read = f("digital_read").call(&[Value::U8(5)]).await.unwrap();
    assert_eq!(read[1], Value::Bool(true));
    let analog = f("analog_read").call(&[Value::U8(2)]).await.unwrap();
    assert_eq!(analog[1], Value::F32(2000.0 / 65535.0));
    let e = f("pwm_write")
        .call(&[Value::U8(7), Value::F32(0.5)])
        .await
        .unwrap_err();
    assert_eq!(call_failed(e), 1, "no such output");
    f("halt").call(&[]).await.unwrap();
    let status = f("get_status").call(&[]).await.unwrap();
    assert_eq!(status[0], Value::U8(4), "halted");
}
