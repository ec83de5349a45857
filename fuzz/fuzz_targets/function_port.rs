//! Feeds arbitrary control-port payloads to two PIPES functions in a
//! runtime and checks that nothing panics, the runtime never holds more
//! than its slots, and its stack empties once every deadline has passed.
//!
//! The runtime (ports: function `mix` at 1..=3, function `vec` at 4..=6)
//! has one link; pipes and replies to that link are drained. Input: a
//! sequence of records `[flags][len][bytes...]`:
//! - bits 0–1: how the bytes travel: 0 as a whole packet on the link,
//!   1 as a request (`[1][seq: u16]` + bytes) to a control port, 2 raw
//!   (`[0]` + bytes, a pipe datagram) to a control port, 3 as they are
//!   (transport header included) to any of the six port indices;
//! - bit 2: which function (for modes 1 and 2);
//! - bits 3–7: advance the clock by that many × 50 µs (timers fire, pipes
//!   flush).
//!
//! The functions start in different modes (`vec` on a 1 ms timer, on-change
//! outputs) and `mix` with a pipe to `vec`, so datagrams flow between them
//! from the first call; requests may rewire everything.
#![no_main]

use libfuzzer_sys::fuzz_target;
use osap_core::link::queue::QueueLink;
use osap_core::packet::Instruction;
use osap_core::port::Port;
use osap_core::route::Route;
use osap_core::Runtime;
use pipes_core::control::{InputMode, OutputMode};
use pipes_core::function::{CallError, Implementation, Outputs, PipesFunction};
use pipes_core::pipe::{PipeConfig, PipeDelivery};
use pipes_core::signature::{Arg, Signature};
use pipes_core::{ScalarType, Type, Value};

static MIX: Signature = Signature {
    name: "mix",
    inputs: &[
        Arg::new("x", Type::Scalar(ScalarType::F32)),
        Arg::new("n", Type::Scalar(ScalarType::U16)),
        Arg::new("s", Type::Utf8),
    ],
    outputs: &[
        Arg::new("y", Type::Scalar(ScalarType::F64)),
        Arg::new("m", Type::Scalar(ScalarType::U32)),
    ],
};

static VEC: Signature = Signature {
    name: "vec",
    inputs: &[
        Arg::new("v", Type::Array(ScalarType::I16)),
        Arg::new("k", Type::Scalar(ScalarType::F64)),
    ],
    outputs: &[Arg::new("sum", Type::Scalar(ScalarType::I64))],
};

/// Exercises every branch a body can take: success, its own failure, an
/// output of the wrong type, a missing output.
struct Body {
    sig: &'static Signature,
}

impl Implementation for Body {
    fn signature(&self) -> &'static Signature {
        self.sig
    }
    fn call(&mut self, inputs: &[Value<'_>], out: &mut Outputs<'_>) -> Result<(), CallError> {
        match inputs {
            [Value::F32(x), Value::U16(n), Value::Utf8(s)] => {
                if x.is_nan() {
                    return Err(CallError::Failed(pipes_core::FailureCode::Other(7)));
                }
                out.set(0, &Value::F64(f64::from(*x) * s.len() as f64))?;
                match n % 4 {
                    // Missing output.
                    0 => Ok(()),
                    // Wrong type: a string for a u32.
                    1 => out.set(1, &Value::utf8(s.as_str())),
                    _ => out.set(1, &Value::U32(u32::from(*n))),
                }
            }
            [Value::Array(v), Value::F64(k)] => {
                let mut sum = 0i64;
                for e in v.iter() {
                    if let Value::I16(x) = e {
                        sum = sum.wrapping_add(i64::from(x));
                    }
                }
                // A float that does not fit an i64 is refused by the table.
                out.set(0, &Value::F64(*k + sum as f64))
            }
            _ => Err(CallError::Failed(pipes_core::FailureCode::from_code(0xff))),
        }
    }
}

type Fun = PipesFunction<Body, 2, 2, 64>;

const MTU: usize = 128;

fn wrap(dst: u16, transport: &[u8], body: &[u8], out: &mut [u8; MTU]) -> Option<usize> {
    let mut payload = [0u8; MTU];
    let n = transport.len() + body.len();
    payload
        .get_mut(..transport.len())?
        .copy_from_slice(transport);
    payload.get_mut(transport.len()..n)?.copy_from_slice(body);
    let route = Route::through_links(&[0]).ok()?;
    route
        .write_packet(
            out,
            Instruction::PortHandle { src: 1, dst },
            5_000,
            MTU as u16,
            payload.get(..n)?,
        )
        .ok()
}

fuzz_target!(|data: &[u8]| {
    let mut rt: Runtime<8, MTU, 8, 1> = match Runtime::new("fuzz", "rt") {
        Ok(rt) => rt,
        Err(_) => return,
    };
    let (Ok(mut mix), Ok(mut vec)) = (Fun::new(Body { sig: &MIX }), Fun::new(Body { sig: &VEC }))
    else {
        return;
    };
    // mix.y → vec.k, local.
    let pipe = PipeConfig::new(Route::local(), 5, 1_000)
        .with_delivery(PipeDelivery::BestEffort)
        .with(0, 1);
    if let Ok(p) = pipe {
        let _ = mix.set_pipe(0, p);
    }
    vec.set_input_mode(InputMode::OnTimer(1_000));
    vec.set_output_mode(OutputMode::OnChange);
    let mut ports: [Fun; 2] = [mix, vec];
    let mut links = [QueueLink::<16, MTU>::new()];
    let mut now = osap_core::Instant::ZERO;
    let mut seq = 0u16;
    let mut rest = data;
    while let [flags, len, tail @ ..] = rest {
        let len = (*len as usize).min(tail.len());
        let (bytes, next) = tail.split_at(len);
        rest = next;
        let control = if flags & 4 == 0 { 1 } else { 4 };
        let mut buf = [0u8; MTU];
        let n = match flags & 3 {
            0 => {
                let n = bytes.len().min(MTU);
                buf[..n].copy_from_slice(&bytes[..n]);
                Some(n)
            }
            1 => {
                seq = seq.wrapping_add(1);
                let [lo, hi] = seq.to_le_bytes();
                wrap(control, &[1, lo, hi], bytes, &mut buf)
            }
            2 => wrap(control, &[0], bytes, &mut buf),
            _ => {
                let dst = 1 + u16::from(flags >> 3) % 6;
                wrap(dst, &[], bytes, &mut buf)
            }
        };
        if let Some(n) = n {
            links[0].inject(&buf[..n]);
        }
        now += osap_core::Duration::from_micros(u64::from(flags >> 3) * 50);
        rt.poll(now, &mut ports, &mut links);
        assert!(rt.stack().len() <= rt.stack().capacity());
        while links[0].take_sent().is_some() {}
        for f in &ports {
            assert_eq!(f.port_count(), 3);
        }
    }
    // Pipes and timers keep going, but the stack drains: every packet
    // either leaves on the link or expires.
    for _ in 0..20 {
        now += osap_core::Duration::from_millis(70);
        rt.poll(now, &mut ports, &mut links);
        while links[0].take_sent().is_some() {}
        assert!(rt.stack().len() <= rt.stack().capacity());
    }
});
