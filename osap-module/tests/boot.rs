//! `enter_bootloader`: the call answers and only arms the reboot; the
//! runtime's loop performs it (through the pulse timer port) once the
//! delay has passed, once; a board without a bootloader refuses with
//! `BootError::Unsupported`, a moving axis with `BootError::Moving`.

use osap_core::clock::TimeMap;
use osap_core::link::LinkGateway;
use osap_core::port::Port;
use osap_core::time::Duration;
use osap_core::time::Instant;
use osap_module::board::{Board, IoHw, StepperHw};
use osap_module::boot::{BootError, BOOTLOADER_DELAY};
use osap_module::functions::{FnId, ModuleFn};
use osap_module::{Module, ModuleHandle, ModulePorts, PORT_INDICES};
use pipes_core::function::{call_direct, CallError};
use std::cell::{Cell, RefCell};
use std::rc::Rc;

struct Driver(Rc<Cell<bool>>);

impl StepperHw for Driver {
    fn set_enable(&mut self, on: bool) {
        self.0.set(on);
    }
    fn set_microsteps(&mut self, _microsteps: u16) -> bool {
        true
    }
}

/// A board whose bootloader entry counts the reboots asked for.
struct BootBoard {
    driver: Driver,
    now: Rc<Cell<Instant>>,
    /// `None`: the board has no bootloader (the trait's defaults).
    reboots: Option<Rc<Cell<u32>>>,
}

impl Board for BootBoard {
    fn stepper(&mut self) -> &mut dyn StepperHw {
        &mut self.driver
    }
    fn io(&mut self) -> Option<&mut dyn IoHw> {
        None
    }
    fn now(&self) -> Instant {
        self.now.get()
    }
    fn has_bootloader(&self) -> bool {
        self.reboots.is_some()
    }
    fn reboot_to_bootloader(&mut self) {
        if let Some(r) = &self.reboots {
            r.set(r.get() + 1);
        }
    }
}

/// The board's default methods, as a board that says nothing about
/// bootloaders has them.
struct PlainBoard(Driver);

impl Board for PlainBoard {
    fn stepper(&mut self) -> &mut dyn StepperHw {
        &mut self.0
    }
    fn io(&mut self) -> Option<&mut dyn IoHw> {
        None
    }
    fn now(&self) -> Instant {
        Instant::ZERO
    }
}

struct Shared<B>(Rc<RefCell<Module<B>>>);

impl<B> Clone for Shared<B> {
    fn clone(&self) -> Self {
        Shared(self.0.clone())
    }
}

impl<B: Board> ModuleHandle for Shared<B> {
    type Board = B;
    fn with<R>(&self, f: impl FnOnce(&mut Module<B>) -> R) -> Option<R> {
        Some(f(&mut self.0.borrow_mut()))
    }
}

/// Calls `enter_bootloader` as its function port would: the outputs it
/// answers with (none), or its refusal.
fn call_enter<B: Board>(module: &Shared<B>) -> Result<usize, CallError> {
    let mut f = ModuleFn::new(FnId::enter_bootloader, module.clone());
    let mut buf = [0u8; 16];
    call_direct(&mut f, &[], &mut buf).map(|outputs| outputs.len())
}

type TestRuntime = osap_core::Runtime<4, 128, PORT_INDICES, 1>;

#[test]
fn the_call_answers_then_the_loop_reboots_after_the_delay_once() {
    let now = Rc::new(Cell::new(Instant::from_micros(5_000)));
    let enabled = Rc::new(Cell::new(false));
    let reboots = Rc::new(Cell::new(0));
    let module = Shared(Rc::new(RefCell::new(Module::new(BootBoard {
        driver: Driver(enabled.clone()),
        now: now.clone(),
        reboots: Some(reboots.clone()),
    }))));
    module.with(|m| {
        m.publish_time(TimeMap::IDENTITY);
        m.set_enable(true).unwrap();
    });
    assert!(enabled.get());

    let mut runtime = TestRuntime::new("stepper", "s").unwrap();
    let mut ports = ModulePorts::new(module.clone()).unwrap();
    let mut links: [&mut dyn LinkGateway; 0] = [];
    // The runtime's loop, and when the pulse timer port (the last port)
    // asks it to wake.
    let mut poll = |at: Instant| {
        now.set(at);
        let result = runtime.poll(at, ports.ports(), &mut links);
        let timer = ports.ports().last().and_then(|p| p.wake_at());
        (result.wake_at, timer)
    };
    assert_eq!(
        poll(Instant::from_micros(5_000)).1,
        None,
        "nothing armed, nothing to wake for"
    );

    // The call answers (no outputs) and the board has been told nothing.
    assert_eq!(call_enter(&module), Ok(0));
    assert_eq!(reboots.get(), 0);
    let due = Instant::from_micros(5_000) + BOOTLOADER_DELAY;
    assert_eq!(module.with(|m| m.boot.due_at()), Some(Some(due)));

    // The loop wakes for it, and does nothing before it is due (the answer
    // leaves on its link meanwhile).
    let (wake, timer) = poll(Instant::from_micros(5_001));
    assert_eq!(timer, Some(due));
    assert!(wake.is_some_and(|w| w <= due), "{wake:?}");
    let just_before = due - Duration::from_micros(1);
    assert_eq!(poll(just_before).1, Some(due));
    assert_eq!(reboots.get(), 0);
    assert!(enabled.get(), "still running until the reboot");

    // A second call meanwhile does not push the reboot back.
    now.set(just_before);
    assert_eq!(call_enter(&module), Ok(0));
    assert_eq!(module.with(|m| m.boot.due_at()), Some(Some(due)));

    // Due: the driver is let go, then the board reboots, once.
    assert_eq!(poll(due).1, None);
    assert_eq!(reboots.get(), 1);
    assert!(!enabled.get(), "the driver is disabled before the reboot");
    poll(due + Duration::from_secs(1));
    assert_eq!(reboots.get(), 1, "told once");
}

#[test]
fn a_board_without_a_bootloader_refuses_with_its_named_code() {
    let enabled = Rc::new(Cell::new(false));
    let module = Shared(Rc::new(RefCell::new(Module::new(PlainBoard(Driver(
        enabled,
    ))))));
    assert_eq!(
        call_enter(&module),
        Err(CallError::Failed(pipes_core::FailureCode::from_code(
            BootError::Unsupported.code()
        )))
    );
    assert_eq!(BootError::Unsupported.code(), 1);
    assert_eq!(
        module.with(|m| m.boot.due_at()),
        Some(None),
        "nothing armed"
    );
    let named = osap_module::failure::failure("enter_bootloader", 1).unwrap();
    assert_eq!(named.name, "Unsupported");
    assert!(named.reason.contains("BOOTSEL"), "{named}");

    // The same through a firmware's Parts without a bootloader entry.
    use osap_module::board::{NoIo, Parts};
    struct Limp;
    impl StepperHw for Limp {
        fn set_enable(&mut self, _on: bool) {}
        fn set_microsteps(&mut self, _m: u16) -> bool {
            false
        }
    }
    let parts = Shared(Rc::new(RefCell::new(Module::new(Parts::<Limp, NoIo> {
        stepper: Limp,
        io: None,
        clock: || Instant::ZERO,
        bootloader: None,
    }))));
    assert_eq!(
        call_enter(&parts),
        Err(CallError::Failed(pipes_core::FailureCode::from_code(
            BootError::Unsupported.code()
        )))
    );
}

#[test]
fn a_moving_axis_refuses() {
    let now = Rc::new(Cell::new(Instant::ZERO));
    let reboots = Rc::new(Cell::new(0));
    let module = Shared(Rc::new(RefCell::new(Module::new(BootBoard {
        driver: Driver(Rc::new(Cell::new(false))),
        now: now.clone(),
        reboots: Some(reboots.clone()),
    }))));
    module.with(|m| {
        m.publish_time(TimeMap::IDENTITY);
        m.set_enable(true).unwrap();
        let iv = 2048u64;
        for k in 0..4 {
            m.add_point(k * iv, 0.0).unwrap();
        }
        for k in 4..8 {
            m.add_point(k * iv, 1.0).unwrap();
        }
    });
    assert_eq!(
        call_enter(&module),
        Err(CallError::Failed(pipes_core::FailureCode::from_code(
            BootError::Moving.code()
        )))
    );
    let named = osap_module::failure::failure("enter_bootloader", 2).unwrap();
    assert_eq!(named.name, "Moving");
    // Halted, it stands: the request is taken.
    module.with(|m| m.halt().unwrap());
    assert_eq!(call_enter(&module), Ok(0));
    module.with(|m| m.poll_boot(Instant::ZERO + BOOTLOADER_DELAY));
    assert_eq!(reboots.get(), 1);
}
