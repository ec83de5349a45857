//! Blocks a host makes on the module at run time (see
//! [`pipes_core::manager`]): reflexes that run in the module's own loop
//! instead of a round trip through the host.
//!
//! | class | constructor | block |
//! |---|---|---|
//! | `comparator` | `threshold: f32`, `hysteresis: f32`, `halt: bool` | `(time: u64, value: f32) -> (time: u64, above: bool, crossings: u32)` |
//! | `scale` | `gain: f32`, `offset: f32` | `(time: u64, value: f32) -> (time: u64, value: f32)` |
//! | `lowpass` | `cutoff_hz: f32` | `(time: u64, value: f32) -> (time: u64, value: f32)` |
//! | `limiter` | `min: f32`, `max: f32`, `rate: f32` | `(time: u64, value: f32) -> (time: u64, value: f32)` |
//! | `trigger` | `pin: u8`, `level: bool` | `(at: u64) -> (time: u64, fired: u32)` |
//!
//! Samples are `(time, value)` pairs, as `loadcell_read` and
//! `analog_read` give them (outputs 0 and 1), so blocks chain: a load
//! cell's pipe into a `lowpass`, its pipe into a `comparator`.
//!
//! - **comparator** sends `above` with the time of the sample that crossed
//!   (it starts "on change": each crossing goes down its pipes once). With
//!   `halt`, a rise halts this module's axis in the same loop (the
//!   stepper's emergency stop: the axis stands where its steps put it,
//!   outputs and heaters are left as they are) and records a
//!   [`FaultKind::BlockHalt`](crate::fault::FaultKind::BlockHalt) fault
//!   whose detail is the block's slot.
//! - **lowpass** is first order, by the samples' own time stamps.
//! - **limiter** clamps to `[min, max]` and, unless `rate` is 0, limits
//!   how fast its output moves (units per second).
//! - **trigger** fires once at or after the synchronized time `at`
//!   (within its timer interval, 100 µs unless set otherwise), sets `pin`
//!   to `level` unless `pin` is 255, and sends the time it fired.
//!
//! A constructor refuses an argument that is not finite or is out of range
//! with code [`BAD_ARGUMENT`]. The pools hold [`CAPACITY`] blocks per
//! class; their ports are reserved after the module's functions.

mod signal;

pub use signal::{
    BadArgument, Comparator, Crossing, Limiter, Lowpass, Scale, Trigger, BAD_ARGUMENT, NO_PIN,
};

use crate::functions::NOT_INSTALLED;
use crate::ModuleHandle;
use pipes_core::control::{InputMode, OutputMode};
use pipes_core::export::PipesType;
use pipes_core::function::{CallError, Implementation, Outputs};
use pipes_core::manager::{BlockClass, BlockFactory, BlockName, Blocks, BlocksError};
use pipes_core::signature::{Arg, Signature};
use pipes_core::{FailureCode, Type, Value};

/// Blocks of each class a module holds at once.
pub const CAPACITY: u8 = 2;
/// Classes.
pub const CLASSES: usize = 5;
/// Blocks a module holds at once, all classes together.
pub const BLOCK_SLOTS: usize = CLASSES * CAPACITY as usize;

/// The module's block manager and pool, as a runtime port.
pub type BlockPort<H> = Blocks<
    ModuleBlocks<H>,
    BLOCK_SLOTS,
    { crate::ports::FN_PIPES },
    { crate::ports::FN_QUEUE },
    { crate::ports::FN_STORE },
>;

const U8: Type = <u8 as PipesType>::TYPE;
const U32: Type = <u32 as PipesType>::TYPE;
const U64: Type = <u64 as PipesType>::TYPE;
const F32: Type = <f32 as PipesType>::TYPE;
const BOOL: Type = <bool as PipesType>::TYPE;

const SAMPLE: &[Arg] = &[Arg::new("time", U64), Arg::new("value", F32)];

/// The constructors' and blocks' signatures.
pub mod signature {
    use super::*;

    /// `comparator(threshold, hysteresis, halt)`.
    pub static COMPARATOR_NEW: Signature = Signature {
        name: "comparator",
        inputs: &[
            Arg::new("threshold", F32),
            Arg::new("hysteresis", F32),
            Arg::new("halt", BOOL),
        ],
        outputs: &[],
    };
    /// A comparator block.
    pub static COMPARATOR: Signature = Signature {
        name: "comparator",
        inputs: SAMPLE,
        outputs: &[
            Arg::new("time", U64),
            Arg::new("above", BOOL),
            Arg::new("crossings", U32),
        ],
    };
    /// `scale(gain, offset)`.
    pub static SCALE_NEW: Signature = Signature {
        name: "scale",
        inputs: &[Arg::new("gain", F32), Arg::new("offset", F32)],
        outputs: &[],
    };
    /// A scale block.
    pub static SCALE: Signature = Signature {
        name: "scale",
        inputs: SAMPLE,
        outputs: SAMPLE,
    };
    /// `lowpass(cutoff_hz)`.
    pub static LOWPASS_NEW: Signature = Signature {
        name: "lowpass",
        inputs: &[Arg::new("cutoff_hz", F32)],
        outputs: &[],
    };
    /// A low-pass block.
    pub static LOWPASS: Signature = Signature {
        name: "lowpass",
        inputs: SAMPLE,
        outputs: SAMPLE,
    };
    /// `limiter(min, max, rate)`.
    pub static LIMITER_NEW: Signature = Signature {
        name: "limiter",
        inputs: &[
            Arg::new("min", F32),
            Arg::new("max", F32),
            Arg::new("rate", F32),
        ],
        outputs: &[],
    };
    /// A limiter block.
    pub static LIMITER: Signature = Signature {
        name: "limiter",
        inputs: SAMPLE,
        outputs: SAMPLE,
    };
    /// `trigger(pin, level)`.
    pub static TRIGGER_NEW: Signature = Signature {
        name: "trigger",
        inputs: &[Arg::new("pin", U8), Arg::new("level", BOOL)],
        outputs: &[],
    };
    /// A trigger block.
    pub static TRIGGER: Signature = Signature {
        name: "trigger",
        inputs: &[Arg::new("at", U64)],
        outputs: &[Arg::new("time", U64), Arg::new("fired", U32)],
    };
}

/// How often a trigger checks its time, µs.
pub const TRIGGER_INTERVAL_US: u32 = 100;

/// The classes, by index.
pub static BLOCK_CLASSES: [BlockClass; CLASSES] = [
    class(
        &signature::COMPARATOR_NEW,
        &signature::COMPARATOR,
        InputMode::OnAnyFresh,
        OutputMode::OnChange,
    ),
    class(
        &signature::SCALE_NEW,
        &signature::SCALE,
        InputMode::OnAnyFresh,
        OutputMode::Always,
    ),
    class(
        &signature::LOWPASS_NEW,
        &signature::LOWPASS,
        InputMode::OnAnyFresh,
        OutputMode::Always,
    ),
    class(
        &signature::LIMITER_NEW,
        &signature::LIMITER,
        InputMode::OnAnyFresh,
        OutputMode::Always,
    ),
    class(
        &signature::TRIGGER_NEW,
        &signature::TRIGGER,
        InputMode::OnTimer(TRIGGER_INTERVAL_US),
        OutputMode::OnChange,
    ),
];

const fn class(
    constructor: &'static Signature,
    block: &'static Signature,
    input_mode: InputMode,
    output_mode: OutputMode,
) -> BlockClass {
    BlockClass {
        constructor,
        block,
        capacity: CAPACITY,
        input_mode,
        output_mode,
    }
}

/// What a block is, with its state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Kind {
    /// A comparator.
    Comparator(Comparator),
    /// A scale.
    Scale(Scale),
    /// A low-pass filter.
    Lowpass(Lowpass),
    /// A limiter.
    Limiter(Limiter),
    /// A trigger.
    Trigger(Trigger),
}

impl Kind {
    /// Class `class` built from its constructor's inputs.
    pub fn construct(class: usize, inputs: &[Value<'_>]) -> Result<Kind, BadArgument> {
        use Value::{Bool, F32 as F, U8 as B};
        Ok(match (class, inputs) {
            (0, [F(t), F(h), Bool(halt)]) => Kind::Comparator(Comparator::new(*t, *h, *halt)?),
            (1, [F(g), F(o)]) => Kind::Scale(Scale::new(*g, *o)?),
            (2, [F(f)]) => Kind::Lowpass(Lowpass::new(*f)?),
            (3, [F(lo), F(hi), F(r)]) => Kind::Limiter(Limiter::new(*lo, *hi, *r)?),
            (4, [B(pin), Bool(level)]) => Kind::Trigger(Trigger::new(*pin, *level)),
            _ => return Err(BadArgument),
        })
    }

    fn signature(&self) -> &'static Signature {
        let index = match self {
            Kind::Comparator(_) => 0,
            Kind::Scale(_) => 1,
            Kind::Lowpass(_) => 2,
            Kind::Limiter(_) => 3,
            Kind::Trigger(_) => 4,
        };
        BLOCK_CLASSES[index].block
    }
}

/// A block on one module: what a slot of the pool runs.
#[derive(Debug, Clone)]
pub struct ModuleBlock<H> {
    name: BlockName,
    slot: u8,
    kind: Kind,
    module: H,
}

impl<H> ModuleBlock<H> {
    /// What the block is, with its state.
    pub fn kind(&self) -> &Kind {
        &self.kind
    }
}

fn sample(inputs: &[Value<'_>]) -> Result<(u64, f32), CallError> {
    match inputs {
        [Value::U64(t), Value::F32(v)] => Ok((*t, *v)),
        _ => Err(CallError::Failed(FailureCode::InputDecodeFailed)),
    }
}

impl<H: ModuleHandle> Implementation for ModuleBlock<H> {
    fn signature(&self) -> &'static Signature {
        self.kind.signature()
    }

    fn name(&self) -> &str {
        self.name.as_str()
    }

    /// The class's description (`osap describe` shows it for each block).
    fn docs(&self) -> &'static str {
        match self.kind {
            Kind::Comparator(_) => "A comparator block: sends `above` when its input rises past `threshold` or falls below `threshold - hysteresis`, stamped with the crossing sample's time, once per crossing (on change).\n\nMade with `halt`, a rise halts this module's axis in the same loop (outputs and heaters are left as they are) and records a BlockHalt fault.",
            Kind::Scale(_) => "A scale block: `gain * value + offset`, the sample's time passed through.",
            Kind::Lowpass(_) => "A first-order low-pass block at `cutoff_hz`, by the samples' own time stamps; the first sample passes through.",
            Kind::Limiter(_) => "A limiter block: clamps to `[min, max]` and, unless `rate` is 0, moves at most `rate` units a second by the samples' time stamps.",
            Kind::Trigger(_) => "A trigger block: fires once at or after the synchronized time `at` (checked every 100 µs unless its input mode says otherwise), sets `pin` to `level` unless `pin` is 255, and sends the time it fired and how often it has.",
        }
    }

    fn call(&mut self, inputs: &[Value<'_>], outputs: &mut Outputs<'_>) -> Result<(), CallError> {
        let not_installed = CallError::Failed(FailureCode::Other(NOT_INSTALLED));
        let pair = |outputs: &mut Outputs<'_>, t: u64, v: f32| {
            outputs.set(0, &Value::U64(t))?;
            outputs.set(1, &Value::F32(v))
        };
        match &mut self.kind {
            Kind::Comparator(c) => {
                let (t, v) = sample(inputs)?;
                if c.sample(t, v) == Crossing::Rose && c.halt {
                    let slot = self.slot;
                    self.module
                        .with(|m| m.halt_by_block(slot))
                        .ok_or(not_installed)?;
                }
                let (at, above, n) = c.outputs();
                outputs.set(0, &Value::U64(at))?;
                outputs.set(1, &Value::Bool(above))?;
                outputs.set(2, &Value::U32(n))
            }
            Kind::Scale(s) => {
                let (t, v) = sample(inputs)?;
                pair(outputs, t, s.apply(v))
            }
            Kind::Lowpass(l) => {
                let (t, v) = sample(inputs)?;
                pair(outputs, t, l.apply(t, v))
            }
            Kind::Limiter(l) => {
                let (t, v) = sample(inputs)?;
                pair(outputs, t, l.apply(t, v))
            }
            Kind::Trigger(tr) => {
                let [Value::U64(at)] = inputs else {
                    return Err(CallError::Failed(FailureCode::InputDecodeFailed));
                };
                let now = self
                    .module
                    .with(|m| m.system_now().as_micros())
                    .ok_or(not_installed)?;
                if tr.run(*at, now) {
                    if let Some((pin, level)) = tr.pin {
                        self.module
                            .with(|m| m.digital_write(pin, level))
                            .ok_or(not_installed)??;
                    }
                }
                let (time, fired) = tr.outputs();
                outputs.set(0, &Value::U64(time))?;
                outputs.set(1, &Value::U32(fired))
            }
        }
    }

    /// A sample block's refusals are the I/O's (`digital_write` for a
    /// trigger's pin).
    fn failures(&self) -> &'static [pipes_core::failure::Failure] {
        match self.kind {
            Kind::Trigger(_) => crate::functions::FnId::digital_write.failures(),
            _ => &[],
        }
    }
}

/// The module's block classes, bound to one module.
#[derive(Debug, Clone)]
pub struct ModuleBlocks<H> {
    module: H,
}

impl<H: ModuleHandle> ModuleBlocks<H> {
    /// The classes of the module `module` reaches.
    pub fn new(module: H) -> Self {
        ModuleBlocks { module }
    }
}

impl<H: ModuleHandle> BlockFactory for ModuleBlocks<H> {
    type Block = ModuleBlock<H>;

    fn classes(&self) -> &'static [BlockClass] {
        &BLOCK_CLASSES
    }

    fn make(
        &mut self,
        class: usize,
        slot: u8,
        name: BlockName,
        inputs: &[Value<'_>],
    ) -> Result<ModuleBlock<H>, CallError> {
        let kind = Kind::construct(class, inputs)
            .map_err(|_| CallError::Failed(FailureCode::Other(BAD_ARGUMENT)))?;
        Ok(ModuleBlock {
            name,
            slot,
            kind,
            module: self.module.clone(),
        })
    }
}

/// The module's block port: the manager and its pools.
pub fn block_port<H: ModuleHandle>(module: H) -> Result<BlockPort<H>, BlocksError> {
    Blocks::new(ModuleBlocks::new(module))
}
