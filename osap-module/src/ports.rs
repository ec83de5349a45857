//! The module's ports, for the firmware's runtime: one PIPES function port
//! per module function, and a port with no index of its own that ends and
//! starts timed pulses from the runtime's loop, runs the heaters' control
//! period ([`crate::heater`]), fires the output watchdog
//! ([`crate::watchdog`]) and performs an armed reboot into the bootloader
//! (see [`crate::boot`]).
//!
//! The function ports feed the output watchdog: a call or a pipe datagram
//! that reaches a function (whether it runs, or fails) feeds it; a run the
//! function's own timer makes does not.

use crate::blocks::{block_port, BlockPort, BLOCK_SLOTS};
use crate::functions::{FnId, ModuleFn, ALL};
use crate::ModuleHandle;
use osap_core::port::{Delivery, Port, PortInfo, PortTx};
use osap_core::{Instant, SystemInstant};
use pipes_core::function::PipesFunction;
use pipes_core::manager::BlocksError;
use pipes_core::signature::SignatureError;

/// Pipe slots of each module function.
pub const FN_PIPES: usize = 2;
/// Datagrams each pipe queues.
pub const FN_QUEUE: usize = 2;
/// Byte size of each function's input stores and output buffer (the
/// largest message, `get_steps`'s four 64-bit outputs, takes 42).
pub const FN_STORE: usize = 48;

/// A module function as a runtime port.
pub type ModuleFunction<H> = PipesFunction<ModuleFn<H>, FN_PIPES, FN_QUEUE, FN_STORE>;

/// The largest outputs `sample_block` writes, as an argument list: the
/// count, then with its index and type key each of `seq`, `first` and
/// `session` (`u32`), `time` (`u64`), and `samples` with its length and a
/// full block.
const SAMPLER_OUTPUTS: usize = 1 + 3 * (2 + 4) + (2 + 8) + (2 + 2 + crate::sampler::BLOCK_BYTES);

/// Byte size of `sample_block`'s stores, output buffer and queued
/// datagrams: its outputs with a full block of
/// [`crate::sampler::BLOCK_BYTES`], and as a datagram the transport and
/// message keys before them (227 bytes; a packet of 237 over two hops,
/// within a module's 256).
pub const SAMPLER_STORE: usize = SAMPLER_OUTPUTS + 2;
/// Datagrams each of `sample_block`'s pipes queues: at 1 kHz a block
/// closes every 9 ms or so, so two cover a port busy for 18 ms.
pub const SAMPLER_QUEUE: usize = 2;

/// `sample_block` as a runtime port: a module function with buffers
/// large enough for a block (see [`crate::sampler`]).
pub type SamplerFunction<H> = PipesFunction<ModuleFn<H>, FN_PIPES, SAMPLER_QUEUE, SAMPLER_STORE>;

/// Where `sample_block` stands in the array of function ports: its port
/// is held beside them ([`ModulePorts`]), so the array's elements stay the
/// size of a plain function's (the sampler's buffers are four times
/// larger). Serves no port index itself.
#[derive(Debug, Clone, Copy, Default)]
pub struct SamplerSlot;

impl Port for SamplerSlot {
    fn port_count(&self) -> u16 {
        0
    }

    fn info(&self, _offset: u16) -> PortInfo<'_> {
        PortInfo {
            type_name: "",
            name: "",
        }
    }

    fn on_packet(&mut self, _delivery: Delivery<'_>, _tx: &mut PortTx<'_>) {}

    fn poll(&mut self, _tx: &mut PortTx<'_>) {}
}

/// The timer for pulses and for an armed reboot into the bootloader:
/// serves no port index; the runtime polls it and wakes for it.
#[derive(Debug)]
pub struct PulseTimer<H> {
    module: H,
    /// The (local, system) time of the latest poll: where `wake_at` places
    /// scheduled starts on the local clock.
    last: (Instant, SystemInstant),
}

impl<H: ModuleHandle> PulseTimer<H> {
    /// The pulse timer of the module `module` reaches.
    pub fn new(module: H) -> Self {
        PulseTimer {
            module,
            last: (Instant::ZERO, SystemInstant::ZERO),
        }
    }
}

impl<H: ModuleHandle> Port for PulseTimer<H> {
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
        let due = self.module.with(|m| {
            m.poll_watchdog(now);
            m.poll_io(now, system);
            m.poll_boot(now);
            let due = |at: Option<Instant>| at.is_some_and(|at| at <= now);
            (
                due(m.heaters.wake_at()),
                due(m.loadcell.wake_at()),
                due(m.tach.wake_at()),
            )
        });
        let (heaters_due, loadcell_due, tach_due) = due.unwrap_or((false, false, false));
        // A tachometer's count: two register reads.
        if tach_due {
            self.module.with(|m| m.poll_tach(now));
        }
        // A load-cell sample (25 clock pulses, about 25 µs) in a critical
        // section of its own, like each heater below; none without one.
        if loadcell_due {
            self.module.with(|m| m.poll_loadcell(now));
        }
        // Each heater's period (an ADC read and soft-float maths on a
        // Cortex-M0+, about 80 µs) in a critical section of its own, so the
        // step interrupt waits for one piece of work at a time.
        if heaters_due {
            for index in 0..crate::heater::HEATERS as u8 {
                self.module.with(|m| m.poll_heater(now, index));
            }
        }
    }

    fn wake_at(&self) -> Option<Instant> {
        let (now, system) = self.last;
        self.module
            .with(|m| {
                let io = m.io_wake_at(now, system);
                let heaters = m.heaters.wake_at();
                let loadcell = m.loadcell.wake_at();
                let tach = m.tach.wake_at();
                [
                    io,
                    m.boot.due_at(),
                    m.watchdog.deadline(),
                    heaters,
                    loadcell,
                    tach,
                ]
                .into_iter()
                .flatten()
                .min()
            })
            .flatten()
    }
}

/// One of the module's ports.
#[allow(clippy::large_enum_variant)]
pub enum ModulePort<H> {
    /// A module function.
    Function(ModuleFunction<H>),
    /// The pulse timer.
    Timer(PulseTimer<H>),
    /// Where `sample_block` stands: its port is [`ModulePorts`]'s own.
    Sampler(SamplerSlot),
}

impl<H: ModuleHandle + core::fmt::Debug> core::fmt::Debug for ModulePort<H> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ModulePort::Function(func) => write!(f, "Function({})", func.signature().name),
            ModulePort::Timer(t) => write!(f, "{t:?}"),
            ModulePort::Sampler(_) => f.write_str("Sampler"),
        }
    }
}

macro_rules! delegate {
    ($self:ident, $p:ident => $e:expr) => {
        match $self {
            ModulePort::Function($p) => $e,
            ModulePort::Timer($p) => $e,
            ModulePort::Sampler($p) => $e,
        }
    };
}

impl<H: ModuleHandle> Port for ModulePort<H> {
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
        match self {
            ModulePort::Function(f) => {
                let heard = |f: &ModuleFunction<H>| {
                    let s = f.stats();
                    (s.calls, s.datagrams, s.run_errors)
                };
                let before = heard(f);
                f.on_packet(delivery, tx);
                if heard(f) != before {
                    let now = tx.now();
                    f.implementation().module().with(|m| m.feed_watchdog(now));
                }
            }
            ModulePort::Timer(t) => t.on_packet(delivery, tx),
            ModulePort::Sampler(s) => s.on_packet(delivery, tx),
        }
    }
    fn poll(&mut self, tx: &mut PortTx<'_>) {
        delegate!(self, p => p.poll(tx))
    }
    fn wake_at(&self) -> Option<Instant> {
        delegate!(self, p => p.wake_at())
    }
}

/// How many ports a module has: its functions and the pulse timer.
pub const PORT_COUNT: usize = ALL.len() + 1;

/// How many port indices the module's ports take, port 0 (the
/// netresponder) included: size the runtime's `PORTS` to at least this, or
/// the ports numbered past it are listed by a scan but can never reply.
/// The functions come first, then the block manager and its pools'
/// reserved ports ([`crate::blocks`]).
pub const PORT_INDICES: usize = 1 + ALL.len() * (1 + FN_PIPES) + 1 + BLOCK_SLOTS * (1 + FN_PIPES);

/// Every port of one module: itself a port that holds the others (the
/// functions, then the block port), so a firmware hands `Runtime::poll`
/// just this (`core::slice::from_mut(&mut ports)`).
pub struct ModulePorts<H: ModuleHandle> {
    module: H,
    ports: [ModulePort<H>; PORT_COUNT],
    sampler: SamplerFunction<H>,
    blocks: BlockPort<H>,
}

impl<H: ModuleHandle + core::fmt::Debug> core::fmt::Debug for ModulePorts<H> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ModulePorts")
            .field("functions", &self.ports)
            .field("sampler", &self.sampler)
            .field("blocks", &self.blocks)
            .finish()
    }
}

/// A block pool whose classes do not add up to its slots cannot be built:
/// the sizes are constants ([`crate::blocks::BLOCK_SLOTS`]) the crate's
/// tests build, so only a class signature beyond the limits can fail here.
fn blocks_error(e: BlocksError) -> SignatureError {
    match e {
        BlocksError::Signature(s) => s,
        _ => SignatureError::TooManyArgs,
    }
}

impl<H: ModuleHandle> ModulePorts<H> {
    /// The ports of the module `module` reaches. The signatures are fixed,
    /// and the crate's tests check that every one is accepted, so this
    /// fails only on a build whose functions were changed untested.
    pub fn new(module: H) -> Result<Self, SignatureError> {
        let mut error = None;
        let ports = core::array::from_fn(|i| match ALL.get(i) {
            Some(FnId::sample_block) => ModulePort::Sampler(SamplerSlot),
            Some(f) => match ModuleFunction::new(ModuleFn::new(*f, module.clone())) {
                Ok(func) => ModulePort::Function(func),
                Err(e) => {
                    error = Some(e);
                    ModulePort::Timer(PulseTimer::new(module.clone()))
                }
            },
            None => ModulePort::Timer(PulseTimer::new(module.clone())),
        });
        if let Some(e) = error {
            return Err(e);
        }
        let sampler = SamplerFunction::new(ModuleFn::new(FnId::sample_block, module.clone()))?;
        let blocks = block_port(module.clone()).map_err(blocks_error)?;
        Ok(ModulePorts {
            module,
            ports,
            sampler,
            blocks,
        })
    }

    /// The module the ports reach (to publish the runtime's time map).
    pub fn module(&self) -> &H {
        &self.module
    }

    /// The functions and the pulse timer, in the order the runtime numbers
    /// them (`sample_block` stands as a [`ModulePort::Sampler`]: its port is
    /// [`sampler`](Self::sampler); the block port follows them).
    pub fn ports(&mut self) -> &mut [ModulePort<H>] {
        &mut self.ports
    }

    /// `sample_block`'s port.
    pub fn sampler(&mut self) -> &mut SamplerFunction<H> {
        &mut self.sampler
    }

    /// The block manager and its pool.
    pub fn blocks(&mut self) -> &mut BlockPort<H> {
        &mut self.blocks
    }

    /// The functions, `sample_block`'s port and the block port, each on
    /// its own (for a runtime that holds ports one by one, such as the
    /// simulator's): the functions first, with `sample_block`'s port where
    /// the [`ModulePort::Sampler`] stands, then the block port.
    pub fn into_parts(
        self,
    ) -> (
        [ModulePort<H>; PORT_COUNT],
        SamplerFunction<H>,
        BlockPort<H>,
    ) {
        (self.ports, self.sampler, self.blocks)
    }
}

impl<H: ModuleHandle> ModulePorts<H> {
    /// Every port in the order the runtime numbers them, with its first
    /// offset and its count.
    fn each(&mut self) -> impl Iterator<Item = (u16, u16, &mut dyn Port)> {
        let mut base = 0u16;
        let mut sampler = Some(&mut self.sampler as &mut dyn Port);
        self.ports
            .iter_mut()
            .map(move |p| match p {
                ModulePort::Sampler(slot) => sampler.take().unwrap_or(slot as &mut dyn Port),
                p => p as &mut dyn Port,
            })
            .chain(core::iter::once(&mut self.blocks as &mut dyn Port))
            .map(move |p| {
                let n = p.port_count();
                let at = base;
                base += n;
                (at, n, p)
            })
    }

    /// The port holding `offset`, with its first offset.
    fn locate(&self, offset: u16) -> Option<(&dyn Port, u16)> {
        let mut base = 0u16;
        let all = self
            .ports
            .iter()
            .map(|p| match p {
                ModulePort::Sampler(_) => &self.sampler as &dyn Port,
                p => p as &dyn Port,
            })
            .chain(core::iter::once(&self.blocks as &dyn Port));
        for p in all {
            let n = p.port_count();
            if offset < base + n {
                return Some((p, base));
            }
            base += n;
        }
        None
    }
}

impl<H: ModuleHandle> Port for ModulePorts<H> {
    fn port_count(&self) -> u16 {
        // Fixed by the build: every function's ports and the pools'.
        (PORT_INDICES - 1) as u16
    }

    fn info(&self, offset: u16) -> PortInfo<'_> {
        match self.locate(offset) {
            Some((p, base)) => p.info(offset - base),
            None => PortInfo {
                type_name: "",
                name: "",
            },
        }
    }

    fn clear_to_receive(&self, offset: u16) -> bool {
        self.locate(offset)
            .is_none_or(|(p, base)| p.clear_to_receive(offset - base))
    }

    fn on_packet(&mut self, delivery: Delivery<'_>, tx: &mut PortTx<'_>) {
        let target = self.each().find(|(base, n, _)| delivery.offset < base + n);
        if let Some((base, n, p)) = target {
            let d = Delivery {
                offset: delivery.offset - base,
                ..delivery
            };
            let _ = tx.with_sub(base, n, |tx| p.on_packet(d, tx));
        }
    }

    fn poll(&mut self, tx: &mut PortTx<'_>) {
        for (base, n, p) in self.each() {
            let _ = tx.with_sub(base, n, |tx| p.poll(tx));
        }
    }

    fn wake_at(&self) -> Option<Instant> {
        let functions = self.ports.iter().filter_map(|p| p.wake_at());
        functions
            .chain(self.sampler.wake_at())
            .chain(self.blocks.wake_at())
            .min()
    }
}
