//! `#[pipes_core::function]` and `#[pipes_core::class]`: generated
//! signatures, native calls, and the generated implementations driven over a
//! two-runtime in-memory network (the harness in `common`).

use core::cell::RefCell;
use core::sync::atomic::{AtomicU16, Ordering};

mod common;

use std::ops::{Deref, DerefMut};

use common::{ok, returned, to_b, Net, TestFn};
use osap_core::port::Port;
use osap_core::route::Route;
use pipes_core::class::{ClassPort, Member, PipesClass, CLASS_PORT_TYPE};
use pipes_core::control::{ControlError, Reply, ReplyBody, Request, ANY_SLOT};
use pipes_core::function::{Implementation, PipesFunction, FUNCTION_PORT_TYPE};
use pipes_core::pipe::PipeConfig;
use pipes_core::signature::{Arg, Signature};
use pipes_core::{PipesType, ScalarType, Type, Value};

/// An expected signature, with borrowed lists.
struct Sig<'a> {
    name: &'a str,
    inputs: &'a [Arg],
    outputs: &'a [Arg],
}

fn check(sig: &Signature, want: Sig<'_>) {
    assert_eq!(sig.name, want.name);
    assert_eq!(sig.inputs, want.inputs, "{}", want.name);
    assert_eq!(sig.outputs, want.outputs, "{}", want.name);
}

const fn s(t: ScalarType) -> Type {
    Type::Scalar(t)
}

// ---- free functions -------------------------------------------------------

/// No inputs, two outputs.
#[pipes_core::function(outputs = "time, in_bounds")]
fn get_comparator_reading() -> (u64, bool) {
    (1234, true)
}

/// Two inputs, one (non-tuple) output.
#[pipes_core::function(outputs = "sum")]
pub fn add(a: f32, b: f32) -> f32 {
    a + b
}

/// Inputs and outputs of several types.
#[pipes_core::function(outputs = "quot, rem, negative, wide")]
fn mixed(n: i32, d: u8, flip: bool, scale: f64) -> (i32, u8, bool, i128) {
    let n = if flip { -n } else { n };
    let d = i32::from(d);
    (
        n / d,
        (n.rem_euclid(d)) as u8,
        n < 0,
        (f64::from(n) * scale) as i128,
    )
}

static LAST_LEVEL: AtomicU16 = AtomicU16::new(0);

/// Unit output: no outputs.
#[pipes_core::function]
fn set_level(level: u16) {
    LAST_LEVEL.store(level, Ordering::Relaxed);
}

/// Strings in and out, a renamed signature, a one-element tuple.
#[pipes_core::function(name = "greeting_length", outputs = "len")]
fn strlen(text: &str) -> (u32,) {
    (text.len() as u32,)
}

/// Explicit `()` return, every integer width in.
#[pipes_core::function(outputs = "")]
#[allow(clippy::too_many_arguments, clippy::unused_unit)]
fn widths(a: i8, b: i16, c: i64, d: i128, e: u16, f: u32, g: u64, h: u128) -> () {
    let _ = (a, b, c, d, e, f, g, h);
}

#[test]
fn functions_stay_callable() {
    assert_eq!(get_comparator_reading(), (1234, true));
    assert_eq!(add(1.0, 2.0), 3.0);
    assert_eq!(mixed(7, 2, true, 1.5), (-3, 1, true, -10));
    assert_eq!(strlen("héllo"), (6,));
    widths(0, 0, 0, 0, 0, 0, 0, 0);
}

#[test]
fn signatures_from_rust_types_and_names() {
    check(
        get_comparator_reading::SIGNATURE,
        Sig {
            name: "get_comparator_reading",
            inputs: &[],
            outputs: &[
                Arg::new("time", s(ScalarType::U64)),
                Arg::new("in_bounds", s(ScalarType::Bool)),
            ],
        },
    );
    check(
        add::SIGNATURE,
        Sig {
            name: "add",
            inputs: &[
                Arg::new("a", s(ScalarType::F32)),
                Arg::new("b", s(ScalarType::F32)),
            ],
            outputs: &[Arg::new("sum", s(ScalarType::F32))],
        },
    );
    check(
        mixed::SIGNATURE,
        Sig {
            name: "mixed",
            inputs: &[
                Arg::new("n", s(ScalarType::I32)),
                Arg::new("d", s(ScalarType::U8)),
                Arg::new("flip", s(ScalarType::Bool)),
                Arg::new("scale", s(ScalarType::F64)),
            ],
            outputs: &[
                Arg::new("quot", s(ScalarType::I32)),
                Arg::new("rem", s(ScalarType::U8)),
                Arg::new("negative", s(ScalarType::Bool)),
                Arg::new("wide", s(ScalarType::I128)),
            ],
        },
    );
    check(
        set_level::SIGNATURE,
        Sig {
            name: "set_level",
            inputs: &[Arg::new("level", s(ScalarType::U16))],
            outputs: &[],
        },
    );
    check(
        strlen::SIGNATURE,
        Sig {
            name: "greeting_length",
            inputs: &[Arg::new("text", Type::Utf8)],
            outputs: &[Arg::new("len", s(ScalarType::U32))],
        },
    );
    let w = widths::SIGNATURE;
    let types: Vec<&str> = w.inputs.iter().map(|a| a.ty.name()).collect();
    assert_eq!(
        types,
        ["i8", "i16", "i64", "i128", "u16", "u32", "u64", "u128"]
    );
    assert!(w.outputs.is_empty());
    for sig in [
        get_comparator_reading::SIGNATURE,
        add::SIGNATURE,
        mixed::SIGNATURE,
        set_level::SIGNATURE,
        strlen::SIGNATURE,
        w,
    ] {
        sig.check().unwrap();
    }
    // The implementation reports the same static.
    assert!(core::ptr::eq(add::pipes().signature(), add::SIGNATURE));
    assert_eq!(<f32 as PipesType>::TYPE, s(ScalarType::F32));
}

#[test]
fn generated_implementations_plug_into_pipes_function() {
    let f = PipesFunction::<_, 2, 2, 64>::new(get_comparator_reading::pipes()).unwrap();
    assert_eq!(f.signature().name, "get_comparator_reading");
    let f = PipesFunction::<_, 1, 1, 32>::new(add {}).unwrap();
    assert_eq!(f.info(0).type_name, FUNCTION_PORT_TYPE);
    assert_eq!(f.info(0).name, "add");
}

// ---- a class --------------------------------------------------------------

/// Says whether the last value fed in lies within bounds.
#[derive(Debug, PartialEq)]
struct Comparator {
    lower: f32,
    upper: f32,
    value: f32,
    now_us: u64,
    ticks: u32,
}

#[pipes_core::class]
impl Comparator {
    /// A comparator of values against `lower..=upper`.
    #[constructor]
    fn new(lower: f32, upper: f32) -> Self {
        Comparator {
            lower,
            upper,
            value: 0.0,
            now_us: 0,
            ticks: 0,
        }
    }

    fn setup(&mut self, lower: f32, upper: f32) {
        self.lower = lower;
        self.upper = upper;
    }

    fn feed(&mut self, value: f32) {
        self.value = value;
    }

    /// When the state last ticked, and whether the value
    /// lies within the bounds.
    ///
    ///     indented example line
    #[outputs = "time, in_bounds"]
    fn reading(&mut self) -> (u64, bool) {
        (self.now_us, self._within())
    }

    #[outputs = "lower, upper"]
    fn bounds(&self) -> (f32, f32) {
        (self.lower, self.upper)
    }

    fn _within(&self) -> bool {
        (self.lower..=self.upper).contains(&self.value)
    }

    /// Not a member: no receiver.
    fn default_bounds() -> (f32, f32) {
        (0.0, 1.0)
    }

    #[loop_hook]
    fn tick(&mut self, now: pipes_core::time::SystemInstant) {
        self.now_us = now.as_micros();
        self.ticks += 1;
    }
}

#[test]
fn class_signatures() {
    assert_eq!(Comparator::NAME, "Comparator");
    check(
        Comparator::CONSTRUCTOR,
        Sig {
            name: "Comparator",
            inputs: &[
                Arg::new("lower", s(ScalarType::F32)),
                Arg::new("upper", s(ScalarType::F32)),
            ],
            outputs: &[],
        },
    );
    let names: Vec<&str> = Comparator::MEMBERS.iter().map(|s| s.name).collect();
    assert_eq!(
        names,
        [
            "Comparator.setup",
            "Comparator.feed",
            "Comparator.reading",
            "Comparator.bounds"
        ]
    );
    assert_eq!(
        Comparator::MEMBERS[2].outputs,
        &[
            Arg::new("time", s(ScalarType::U64)),
            Arg::new("in_bounds", s(ScalarType::Bool)),
        ]
    );
    assert_eq!(Comparator::member_index("reading"), Some(2));
    assert_eq!(Comparator::member_index("_within"), None);
    assert_eq!(Comparator::member_index("default_bounds"), None);
    assert_eq!(Comparator::member_index("tick"), None);
    // The impl block is intact.
    let mut c = Comparator::new(0.0, 1.0);
    c.feed(0.5);
    assert!(c._within());
    assert_eq!(Comparator::default_bounds(), (0.0, 1.0));
    let state = RefCell::new(c);
    assert!(Member::new(&state, 4).is_none());
    let m = Member::by_name(&state, "bounds").unwrap();
    assert_eq!(m.index(), 3);
    assert_eq!(m.signature().name, "Comparator.bounds");
    let port = ClassPort::<Comparator>::new(&state).unwrap();
    assert_eq!(port.constructor_signature(), Comparator::CONSTRUCTOR);
    assert_eq!(port.info(0).type_name, CLASS_PORT_TYPE);
    assert_eq!(port.info(0).name, "Comparator");
}

// ---- the network ----------------------------------------------------------

/// A boxed implementation, so every function port has the same type.
fn boxed<const PIPES: usize>(imp: impl Implementation + 'static) -> Box<dyn TestFn> {
    struct Dyn(Box<dyn Implementation>);
    impl Implementation for Dyn {
        fn signature(&self) -> &'static Signature {
            self.0.signature()
        }
        fn call(
            &mut self,
            inputs: &[Value<'_>],
            outputs: &mut pipes_core::function::Outputs<'_>,
        ) -> Result<(), pipes_core::function::CallError> {
            self.0.call(inputs, outputs)
        }
        fn docs(&self) -> &'static str {
            self.0.docs()
        }
    }
    Box::new(PipesFunction::<_, PIPES, 2, 64>::new(Dyn(Box::new(imp))).unwrap())
}

/// A: host (1), get_comparator_reading (2), add (3, its pipe 4), mixed
/// (5), set_level (6), strlen (7). B: the class port (1), then its members
/// setup (2), feed (3), reading (4), bounds (5). Only `add` has a pipe
/// slot: the test runtime has 8 port indices. A link 0 ↔ B link 0.
struct World {
    net: Net,
    state: &'static RefCell<Comparator>,
}

impl Deref for World {
    type Target = Net;
    fn deref(&self) -> &Net {
        &self.net
    }
}

impl DerefMut for World {
    fn deref_mut(&mut self) -> &mut Net {
        &mut self.net
    }
}

const READING_PORT: u16 = 2;
const ADD_PORT: u16 = 3;
const MIXED_PORT: u16 = 5;
const LEVEL_PORT: u16 = 6;
const STRLEN_PORT: u16 = 7;
const CLASS_PORT: u16 = 1;
const SETUP_PORT: u16 = 2;
const FEED_PORT: u16 = 3;
const CLASS_READING_PORT: u16 = 4;
const BOUNDS_PORT: u16 = 5;

impl World {
    fn new() -> World {
        let state: &'static RefCell<Comparator> =
            Box::leak(Box::new(RefCell::new(Comparator::new(0.0, 1.0))));
        let member = |name| -> Box<dyn TestFn> {
            let m = Member::by_name(state, name).unwrap();
            Box::new(PipesFunction::<_, 0, 1, 64>::new(m).unwrap())
        };
        let net = Net::new(
            vec![
                boxed::<0>(get_comparator_reading::pipes()),
                boxed::<1>(add::pipes()),
                boxed::<0>(mixed::pipes()),
                boxed::<0>(set_level::pipes()),
                boxed::<0>(strlen::pipes()),
            ],
            vec![
                Box::new(ClassPort::<Comparator>::new(state).unwrap()),
                member("setup"),
                member("feed"),
                member("reading"),
                member("bounds"),
            ],
        );
        World { net, state }
    }
}

#[test]
fn signatures_over_the_network() {
    let mut w = World::new();
    for (port, sig) in [
        (READING_PORT, get_comparator_reading::SIGNATURE),
        (ADD_PORT, add::SIGNATURE),
        (MIXED_PORT, mixed::SIGNATURE),
        (LEVEL_PORT, set_level::SIGNATURE),
        (STRLEN_PORT, strlen::SIGNATURE),
    ] {
        let body = w.ask(Route::local(), port, &Request::GetSignature);
        let ReplyBody::Signature(v) = ok(&body) else {
            panic!()
        };
        assert!(sig.matches(&v), "{}", sig.name);
    }
    for (port, sig) in [
        (CLASS_PORT, Comparator::CONSTRUCTOR),
        (SETUP_PORT, Comparator::MEMBERS[0]),
        (FEED_PORT, Comparator::MEMBERS[1]),
        (CLASS_READING_PORT, Comparator::MEMBERS[2]),
        (BOUNDS_PORT, Comparator::MEMBERS[3]),
    ] {
        let body = w.ask(to_b(), port, &Request::GetSignature);
        let ReplyBody::Signature(v) = ok(&body) else {
            panic!()
        };
        assert!(sig.matches(&v), "{}", sig.name);
    }
}

#[test]
fn rpc_calls_of_generated_functions() {
    let mut w = World::new();
    let body = w.call(Route::local(), READING_PORT, &[]);
    assert_eq!(returned(&body), [Value::U64(1234), Value::Bool(true)]);

    // Inputs are converted to the declared types before the call: an i32 3
    // arrives as f32 3.0.
    let body = w.call(
        Route::local(),
        ADD_PORT,
        &[(0, Value::F32(1.5)), (1, Value::I32(3))],
    );
    assert_eq!(returned(&body), [Value::F32(4.5)]);

    let body = w.call(
        Route::local(),
        MIXED_PORT,
        &[
            (0, Value::I32(7)),
            (1, Value::U8(2)),
            (2, Value::Bool(true)),
            (3, Value::F64(1.5)),
        ],
    );
    assert_eq!(
        returned(&body),
        [
            Value::I32(-3),
            Value::U8(1),
            Value::Bool(true),
            Value::I128(-10)
        ]
    );

    let body = w.call(Route::local(), LEVEL_PORT, &[(0, Value::U16(700))]);
    assert!(returned(&body).is_empty());
    assert_eq!(LAST_LEVEL.load(Ordering::Relaxed), 700);

    let body = w.call(Route::local(), STRLEN_PORT, &[(0, Value::utf8("héllo"))]);
    assert_eq!(returned(&body), [Value::U32(6)]);
    // ascii converts to utf8.
    let body = w.call(Route::local(), STRLEN_PORT, &[(0, Value::ascii("hey"))]);
    assert_eq!(returned(&body), [Value::U32(3)]);

    // A value that does not convert is refused before the function runs.
    let body = w.call(
        Route::local(),
        ADD_PORT,
        &[(0, Value::F32(1.0)), (1, Value::Bool(true))],
    );
    assert!(matches!(
        Reply::parse(&body).unwrap().result,
        Err(ControlError::Convert { index: 1, .. })
    ));
}

#[test]
fn class_over_the_network() {
    let mut w = World::new();
    // The loop hook runs on every poll of B.
    w.steps(3);
    let ticks = w.state.borrow().ticks;
    assert!(ticks >= 3, "{ticks}");

    let body = w.call(to_b(), BOUNDS_PORT, &[]);
    assert_eq!(returned(&body), [Value::F32(0.0), Value::F32(1.0)]);

    // Members share the state.
    let body = w.call(to_b(), FEED_PORT, &[(0, Value::F32(2.5))]);
    assert!(returned(&body).is_empty());
    let body = w.call(to_b(), CLASS_READING_PORT, &[]);
    let out = returned(&body);
    assert_eq!(out[1], Value::Bool(false));
    let Value::U64(t) = out[0] else { panic!() };
    assert!(t > 0, "the hook stored the time");

    let body = w.call(
        to_b(),
        SETUP_PORT,
        &[(0, Value::F32(2.0)), (1, Value::F32(3.0))],
    );
    assert!(returned(&body).is_empty());
    let body = w.call(to_b(), CLASS_READING_PORT, &[]);
    assert_eq!(returned(&body)[1], Value::Bool(true));

    // Calling the class port runs the constructor: a fresh state.
    let body = w.call(
        to_b(),
        CLASS_PORT,
        &[(0, Value::F32(-1.0)), (1, Value::F32(1.0))],
    );
    assert!(returned(&body).is_empty());
    {
        let s = w.state.borrow();
        assert_eq!((s.lower, s.upper, s.value), (-1.0, 1.0, 0.0));
    }
    let body = w.call(to_b(), BOUNDS_PORT, &[]);
    assert_eq!(returned(&body), [Value::F32(-1.0), Value::F32(1.0)]);
}

#[test]
fn dataflow_from_a_function_into_a_class_member() {
    let mut w = World::new();
    // add's output → feed's input 0, on B.
    let pipe = PipeConfig::new(to_b(), FEED_PORT, 10_000)
        .with(0, 0)
        .unwrap();
    let body = w.ask(
        Route::local(),
        ADD_PORT,
        &Request::SetPipe {
            slot: ANY_SLOT,
            pipe,
        },
    );
    assert_eq!(ok(&body), ReplyBody::PipeSet(0));
    let body = w.call(
        Route::local(),
        ADD_PORT,
        &[(0, Value::F32(0.25)), (1, Value::F32(0.5))],
    );
    assert_eq!(returned(&body), [Value::F32(0.75)]);
    w.steps(4);
    assert_eq!(w.state.borrow().value, 0.75);
    let body = w.call(to_b(), CLASS_READING_PORT, &[]);
    assert_eq!(returned(&body)[1], Value::Bool(true));
}

// ---- functions and classes that can fail ------------------------------------

#[pipes_core::function(outputs = "root")]
fn checked_sqrt(x: f32) -> Result<f32, pipes_core::function::CallError> {
    if x < 0.0 {
        return Err(pipes_core::function::CallError::Failed(
            pipes_core::FailureCode::Other(7),
        ));
    }
    Ok(x.sqrt())
}

/// A failure with its own type, turned into a code.
struct OutOfRange;

impl From<OutOfRange> for pipes_core::function::CallError {
    fn from(_: OutOfRange) -> Self {
        pipes_core::function::CallError::Failed(pipes_core::FailureCode::Other(9))
    }
}

struct Gauge {
    full: u16,
    level: u16,
}

#[pipes_core::class]
impl Gauge {
    #[constructor]
    fn new(full: u16) -> Result<Self, OutOfRange> {
        if full == 0 {
            return Err(OutOfRange);
        }
        Ok(Gauge { full, level: 0 })
    }

    #[outputs = "level, fraction"]
    fn fill(&mut self, by: u16) -> Result<(u16, f32), OutOfRange> {
        let level = self.level.checked_add(by).filter(|l| *l <= self.full);
        self.level = level.ok_or(OutOfRange)?;
        Ok((self.level, f32::from(self.level) / f32::from(self.full)))
    }
}

#[test]
fn failures_of_functions_members_and_constructors_reach_the_caller() {
    let state: &'static RefCell<Gauge> =
        Box::leak(Box::new(RefCell::new(Gauge { full: 10, level: 0 })));
    let mut net = Net::new(
        vec![boxed::<0>(checked_sqrt::pipes())],
        vec![
            Box::new(ClassPort::<Gauge>::new(state).unwrap()),
            Box::new(
                PipesFunction::<_, 0, 1, 64>::new(Member::by_name(state, "fill").unwrap()).unwrap(),
            ),
        ],
    );
    let failed = |body: &[u8]| Reply::parse(body).unwrap().result.err();
    // The generated signatures see through the Result.
    assert_eq!(checked_sqrt::SIGNATURE.outputs[0].ty, f32::TYPE);
    assert_eq!(Gauge::MEMBERS[0].outputs.len(), 2);

    let body = net.call(Route::local(), 2, &[(0, Value::F32(6.25))]);
    assert_eq!(returned(&body), [Value::F32(2.5)]);
    let body = net.call(Route::local(), 2, &[(0, Value::F32(-1.0))]);
    assert_eq!(
        failed(&body),
        Some(ControlError::CallFailed(pipes_core::FailureCode::Other(7)))
    );

    let body = net.call(to_b(), 2, &[(0, Value::U16(4))]);
    assert_eq!(returned(&body), [Value::U16(4), Value::F32(0.4)]);
    let body = net.call(to_b(), 2, &[(0, Value::U16(7))]);
    assert_eq!(
        failed(&body),
        Some(ControlError::CallFailed(pipes_core::FailureCode::Other(9)))
    );
    assert_eq!(
        state.borrow().level,
        4,
        "a failed member left the state as it was"
    );

    // A refused constructor keeps the old state.
    let body = net.call(to_b(), 1, &[(0, Value::U16(0))]);
    assert_eq!(
        failed(&body),
        Some(ControlError::CallFailed(pipes_core::FailureCode::Other(9)))
    );
    assert_eq!(state.borrow().full, 10);
    let body = net.call(to_b(), 1, &[(0, Value::U16(20))]);
    assert!(returned(&body).is_empty());
    assert_eq!((state.borrow().full, state.borrow().level), (20, 0));
}

/// A status report as a list of arguments: the names and types come from
/// the fields.
#[derive(Debug, PartialEq, pipes_core::PipesArgs)]
struct Status {
    mode: u8,
    queued: u16,
    enabled: bool,
    r#faults: u32,
}

#[derive(Debug, PartialEq, pipes_core::PipesArgs)]
struct NoArgs {}

#[test]
fn derived_args_name_and_type_each_field_in_order() {
    use pipes_core::export::PipesArgs;
    let t = |s| Type::Scalar(s);
    assert_eq!(
        Status::ARGS,
        [
            Arg::new("mode", t(ScalarType::U8)),
            Arg::new("queued", t(ScalarType::U16)),
            Arg::new("enabled", t(ScalarType::Bool)),
            Arg::new("faults", t(ScalarType::U32)),
        ]
    );
    let values = [
        Value::U8(2),
        Value::U16(5),
        Value::Bool(true),
        Value::U32(9),
    ];
    let s = Status::from_values(&values).unwrap();
    assert_eq!(
        s,
        Status {
            mode: 2,
            queued: 5,
            enabled: true,
            faults: 9
        }
    );
    let back: Vec<Value<'_>> = (0..4).map_while(|i| s.value(i)).collect();
    assert_eq!(back, values);
    assert_eq!(s.value(4), None);
    // A missing or mistyped value is the decode failure.
    let decode = pipes_core::function::CallError::Failed(pipes_core::FailureCode::from_code(
        pipes_core::export::INPUT_DECODE_FAILED,
    ));
    assert_eq!(Status::from_values(&values[..3]), Err(decode));
    let wrong = [
        Value::U16(2),
        Value::U16(5),
        Value::Bool(true),
        Value::U32(9),
    ];
    assert_eq!(Status::from_values(&wrong), Err(decode));
    assert!(NoArgs::ARGS.is_empty());
    assert_eq!(NoArgs::from_values(&[]), Ok(NoArgs {}));
    assert!(<() as PipesArgs>::ARGS.is_empty());
}

#[test]
fn doc_comments_are_the_docs() {
    assert_eq!(add::pipes().docs(), "Two inputs, one (non-tuple) output.");
    assert_eq!(
        strlen::pipes().docs(),
        "Strings in and out, a renamed signature, a one-element tuple."
    );
    assert_eq!(
        Comparator::CONSTRUCTOR_DOCS,
        "A comparator of values against `lower..=upper`."
    );
    let reading = Comparator::member_index("reading").unwrap();
    assert_eq!(
        Comparator::MEMBER_DOCS[reading],
        "When the state last ticked, and whether the value\nlies within the bounds.\n\n    \
         indented example line"
    );
    // Undocumented members have empty docs, in member order.
    assert_eq!(Comparator::MEMBER_DOCS.len(), Comparator::MEMBERS.len());
    assert_eq!(Comparator::MEMBER_DOCS[0], "");
}

#[test]
fn docs_over_the_network() {
    use pipes_core::failure::SignatureParts;
    let mut w = World::new();
    let both = SignatureParts::SUMMARY.with(SignatureParts::DOCS);
    let mut read = |route: Route, port: u16, parts: SignatureParts| {
        let body = w.ask(route, port, &Request::Describe(parts));
        let ReplyBody::Signature(v) = ok(&body) else {
            panic!()
        };
        (v.summary().map(str::to_owned), v.docs().map(str::to_owned))
    };
    assert_eq!(
        read(Route::local(), ADD_PORT, both),
        (
            Some("Two inputs, one (non-tuple) output.".into()),
            Some("Two inputs, one (non-tuple) output.".into())
        )
    );
    assert_eq!(
        read(to_b(), CLASS_READING_PORT, SignatureParts::SUMMARY),
        (
            Some(
                "When the state last ticked, and whether the value lies within the bounds.".into()
            ),
            None
        )
    );
    assert_eq!(
        read(to_b(), CLASS_PORT, SignatureParts::DOCS),
        (
            None,
            Some("A comparator of values against `lower..=upper`.".into())
        )
    );
    assert_eq!(
        read(to_b(), SETUP_PORT, both),
        (Some(String::new()), Some(String::new()))
    );
}
