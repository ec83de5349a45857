//! The module's ports, for the firmware's runtime: one PIPES function port
//! per module function, and a port with no index of its own that ends and
//! starts timed pulses from the runtime's loop.

use crate::functions::{ModuleFn, ALL};
use crate::with;
use osap_core::port::{Delivery, Port, PortInfo, PortTx};
use osap_core::Micros;
use pipes_core::function::PipesFunction;
use pipes_core::signature::SignatureError;

/// Pipe slots of each module function.
pub const FN_PIPES: usize = 2;
/// Datagrams each pipe queues.
pub const FN_QUEUE: usize = 2;
/// Byte size of each function's input stores and output buffer (the
/// largest message, `get_steps`'s four 64-bit outputs, takes 42).
pub const FN_STORE: usize = 48;

/// A module function as a runtime port.
pub type ModuleFunction = PipesFunction<ModuleFn, FN_PIPES, FN_QUEUE, FN_STORE>;

/// The timer for pulses: serves no port index; the runtime polls it and
/// wakes for it.
#[derive(Debug, Default)]
pub struct PulseTimer {
    /// The (local, system) time of the latest poll: where `wake_at` places
    /// scheduled starts on the local clock.
    last: (Micros, u64),
}

impl Port for PulseTimer {
    fn port_count(&self) -> u16 {
        0
    }

    fn info(&self, _offset: u16) -> PortInfo<'_> {
        PortInfo {
            type_name: "pulse_timer",
            name: "",
        }
    }

    fn on_packet(&mut self, _delivery: Delivery<'_>, _tx: &mut PortTx<'_>) {}

    fn poll(&mut self, tx: &mut PortTx<'_>) {
        let (now, system) = (tx.now(), tx.system_time());
        self.last = (now, system);
        with(|m| {
            if let Some(hw) = m.io_hw.as_deref_mut() {
                m.io.poll(hw, now, system);
            }
        });
    }

    fn wake_at(&self) -> Option<Micros> {
        let (now, system) = self.last;
        with(|m| m.io.wake_at(now, system)).flatten()
    }
}

/// One of the module's ports.
#[allow(clippy::large_enum_variant)]
pub enum ModulePort {
    /// A module function.
    Function(ModuleFunction),
    /// The pulse timer.
    Timer(PulseTimer),
}

impl core::fmt::Debug for ModulePort {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ModulePort::Function(func) => write!(f, "Function({})", func.signature().name),
            ModulePort::Timer(t) => write!(f, "{t:?}"),
        }
    }
}

macro_rules! delegate {
    ($self:ident, $p:ident => $e:expr) => {
        match $self {
            ModulePort::Function($p) => $e,
            ModulePort::Timer($p) => $e,
        }
    };
}

impl Port for ModulePort {
    fn port_count(&self) -> u16 {
        delegate!(self, p => p.port_count())
    }
    fn info(&self, offset: u16) -> PortInfo<'_> {
        delegate!(self, p => p.info(offset))
    }
    fn clear_to_receive(&self, offset: u16) -> bool {
        delegate!(self, p => p.clear_to_receive(offset))
    }
    fn on_packet(&mut self, delivery: Delivery<'_>, tx: &mut PortTx<'_>) {
        delegate!(self, p => p.on_packet(delivery, tx))
    }
    fn poll(&mut self, tx: &mut PortTx<'_>) {
        delegate!(self, p => p.poll(tx))
    }
    fn wake_at(&self) -> Option<Micros> {
        delegate!(self, p => p.wake_at())
    }
}

/// How many ports a module has: its functions and the pulse timer.
pub const PORT_COUNT: usize = ALL.len() + 1;

/// How many port indices the module's ports take, port 0 (the
/// netresponder) included: size the runtime's `PORTS` to at least this, or
/// the functions numbered past it are listed by a scan but can never reply.
pub const PORT_INDICES: usize = 1 + ALL.len() * (1 + FN_PIPES);

/// Every port of the module, to hand to `Runtime::poll`.
pub struct ModulePorts {
    ports: [ModulePort; PORT_COUNT],
}

impl core::fmt::Debug for ModulePorts {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_list().entries(self.ports.iter()).finish()
    }
}

impl ModulePorts {
    /// The module's ports. The signatures are fixed, and the crate's tests
    /// check that every one is accepted, so this fails only on a build
    /// whose functions were changed untested.
    pub fn new() -> Result<Self, SignatureError> {
        let mut error = None;
        let ports = core::array::from_fn(|i| match ALL.get(i) {
            Some(f) => match ModuleFunction::new(*f) {
                Ok(func) => ModulePort::Function(func),
                Err(e) => {
                    error = Some(e);
                    ModulePort::Timer(PulseTimer::default())
                }
            },
            None => ModulePort::Timer(PulseTimer::default()),
        });
        match error {
            Some(e) => Err(e),
            None => Ok(ModulePorts { ports }),
        }
    }

    /// The ports, in the order the runtime numbers them.
    pub fn ports(&mut self) -> &mut [ModulePort] {
        &mut self.ports
    }

    /// The ports, each on its own (for a runtime that holds ports one by
    /// one, such as a host's).
    pub fn into_ports(self) -> [ModulePort; PORT_COUNT] {
        self.ports
    }
}
