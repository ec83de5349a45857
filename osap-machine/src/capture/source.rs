//! Where a capture's samples come from: `module.function(args).output`
//! specs, parsed and resolved against the scanned network.

use super::*;

/// A parsed source: `MODULE.FUNCTION[(ARGS)][.OUTPUT]`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SourceSpec {
    /// The source as given.
    pub text: String,
    /// Module key or runtime name.
    pub module: String,
    /// Function name.
    pub function: String,
    /// Arguments, as written.
    pub args: Vec<String>,
    /// One output, or every numeric one.
    pub output: Option<String>,
}

impl SourceSpec {
    /// Parses `MODULE.FUNCTION[(ARG, ..)][.OUTPUT]`.
    pub fn parse(text: &str) -> Result<SourceSpec, CaptureError> {
        let bad = |reason: &str| CaptureError::BadSource {
            source_name: text.to_string(),
            reason: format!(
                "{reason}; write MODULE.FUNCTION[(ARG, ..)][.OUTPUT], e.g. z.analog_read(0).value"
            ),
        };
        let t = text.trim();
        let (head, args, tail) = match t.find('(') {
            Some(open) => {
                let close = t[open..]
                    .find(')')
                    .map(|c| open + c)
                    .ok_or_else(|| bad("no closing parenthesis"))?;
                let inner = &t[open + 1..close];
                let args: Vec<String> = if inner.trim().is_empty() {
                    Vec::new()
                } else {
                    inner.split(',').map(|a| a.trim().to_string()).collect()
                };
                let tail = &t[close + 1..];
                let tail = if tail.is_empty() {
                    None
                } else {
                    Some(
                        tail.strip_prefix('.')
                            .ok_or_else(|| bad("after the arguments comes .OUTPUT or nothing"))?,
                    )
                };
                (&t[..open], args, tail)
            }
            None => (t, Vec::new(), None),
        };
        let mut parts = head.split('.');
        let module = parts.next().unwrap_or("");
        let function = parts.next().ok_or_else(|| bad("no function named"))?;
        let mut output = parts.next();
        if parts.next().is_some() || (output.is_some() && tail.is_some()) {
            return Err(bad("too many dots"));
        }
        if tail.is_some() {
            output = tail;
        }
        let empty = |s: &str| s.trim().is_empty();
        if output.is_some_and(|o| o.contains('.')) {
            return Err(bad("too many dots"));
        }
        if empty(module) || empty(function) || output.is_some_and(empty) {
            return Err(bad("an empty name"));
        }
        if args.iter().any(|a| a.is_empty()) {
            return Err(bad("an empty argument"));
        }
        Ok(SourceSpec {
            text: text.to_string(),
            module: module.to_string(),
            function: function.to_string(),
            args,
            output: output.map(str::to_string),
        })
    }

    /// The series name prefix: `MODULE.FUNCTION` or `MODULE.FUNCTION(ARGS)`.
    pub(super) fn prefix(&self) -> String {
        if self.args.is_empty() {
            format!("{}.{}", self.module, self.function)
        } else {
            format!("{}.{}({})", self.module, self.function, self.args.join(","))
        }
    }
}

/// A source checked against the network: where it is, what it sends.
#[derive(Debug, Clone)]
pub(super) struct Resolved {
    pub(super) spec: SourceSpec,
    pub(super) function: FnRef,
    /// The outputs piped, in host-function input order: the time first (if
    /// the function has one), then the recorded ones.
    pub(super) outputs: Vec<u8>,
    /// Types of the piped outputs.
    pub(super) types: Vec<(String, Type)>,
    /// Whether input 0 of the host function is the time stamp.
    pub(super) stamped: bool,
    /// Argument values for the function's inputs.
    pub(super) args: Vec<(u8, Value<'static>)>,
    /// Series names, one per recorded output.
    pub(super) series: Vec<String>,
}

pub(super) fn is_numeric(t: &Type) -> bool {
    matches!(t, Type::Scalar(_))
}

pub(super) fn found_list(items: impl Iterator<Item = String>) -> String {
    let v: Vec<String> = items.collect();
    if v.is_empty() {
        "none".into()
    } else {
        v.join(", ")
    }
}

/// The value of argument `text` for an input of type `ty`.
pub(super) fn arg_value(
    spec: &SourceSpec,
    name: &str,
    ty: &Type,
    text: &str,
) -> Result<Value<'static>, CaptureError> {
    let bad = |what: String| CaptureError::BadSource {
        source_name: spec.text.clone(),
        reason: format!("argument {text:?} for input {name} ({ty}): {what}"),
    };
    if !matches!(ty, Type::Scalar(_)) {
        return Err(bad("only numeric inputs can be given as arguments".into()));
    }
    parse_value(ty, text).map_err(|e| bad(e.to_string()))
}

/// The zero of a numeric input type (an input not given).
pub(super) fn zero(ty: &Type) -> Option<Value<'static>> {
    let Type::Scalar(s) = ty else { return None };
    Some(match s {
        ScalarType::Bool => Value::Bool(false),
        ScalarType::I8 => Value::I8(0),
        ScalarType::I16 => Value::I16(0),
        ScalarType::I32 => Value::I32(0),
        ScalarType::I64 => Value::I64(0),
        ScalarType::I128 => Value::I128(0),
        ScalarType::U8 => Value::U8(0),
        ScalarType::U16 => Value::U16(0),
        ScalarType::U32 => Value::U32(0),
        ScalarType::U64 => Value::U64(0),
        ScalarType::U128 => Value::U128(0),
        ScalarType::F16 => Value::F16(0),
        ScalarType::F32 => Value::F32(0.0),
        ScalarType::F64 => Value::F64(0.0),
    })
}

/// Checks `spec` against the manager's model: the module (a machine key,
/// then any runtime name), the function, its outputs, its arguments and a
/// free pipe slot.
pub(super) fn resolve(
    spec: &SourceSpec,
    machine_modules: &BTreeMap<String, String>,
    manager: &Manager,
) -> Result<Resolved, CaptureError> {
    let som = manager.som();
    let runtime = match machine_modules.get(&spec.module) {
        Some(r) => r.clone(),
        None => {
            // Runtime 0 is this host: its functions are not sources.
            let hits: Vec<&str> = som
                .runtimes
                .iter()
                .skip(1)
                .map(|r| r.record.name.as_str())
                .filter(|n| *n == spec.module)
                .collect();
            if hits.len() != 1 {
                return Err(CaptureError::UnknownModule {
                    source_name: spec.text.clone(),
                    module: spec.module.clone(),
                    found: found_list(machine_modules.keys().cloned()),
                });
            }
            spec.module.clone()
        }
    };
    let ri = som
        .runtime_index(&runtime)
        .map_err(|_| SomError::NoSuchRuntime(runtime.clone()))?;
    let Some(f) = som.function(ri, &spec.function) else {
        let with_numbers = som.runtimes[ri]
            .functions
            .iter()
            .filter(|f| {
                f.outputs
                    .iter()
                    .any(|o| o.ty().is_some_and(|t| is_numeric(&t)))
            })
            .map(|f| f.name.clone());
        return Err(CaptureError::UnknownFunction {
            source_name: spec.text.clone(),
            module: spec.module.clone(),
            function: spec.function.clone(),
            found: found_list(with_numbers),
        });
    };
    resolve_function(spec, runtime, f)
}

/// Checks `spec` against function `f` of `runtime`: its outputs, its
/// arguments and a free pipe slot.
pub(super) fn resolve_function(
    spec: &SourceSpec,
    runtime: String,
    f: &SomFunction,
) -> Result<Resolved, CaptureError> {
    let outs: Vec<(String, Option<Type>, String)> = f
        .outputs
        .iter()
        .map(|o| (o.name.clone(), o.ty(), o.type_name.clone()))
        .collect();
    let time = outs
        .iter()
        .position(|(n, t, _)| n == "time" && *t == Some(Type::Scalar(ScalarType::U64)));
    let chosen: Vec<usize> = match &spec.output {
        Some(name) => {
            let i = outs.iter().position(|o| &o.0 == name).ok_or_else(|| {
                CaptureError::UnknownOutput {
                    source_name: spec.text.clone(),
                    output: name.clone(),
                    found: found_list(outs.iter().map(|o| format!("{}: {}", o.0, o.2))),
                }
            })?;
            if !outs[i].1.as_ref().is_some_and(is_numeric) {
                return Err(CaptureError::NotNumeric {
                    source_name: spec.text.clone(),
                    output: name.clone(),
                    type_name: outs[i].2.clone(),
                });
            }
            vec![i]
        }
        None => {
            let v: Vec<usize> = (0..outs.len())
                .filter(|i| Some(*i) != time && outs[*i].1.as_ref().is_some_and(is_numeric))
                .collect();
            if v.is_empty() {
                return match outs.iter().enumerate().find(|(i, _)| Some(*i) != time) {
                    Some((_, o)) => Err(CaptureError::NotNumeric {
                        source_name: spec.text.clone(),
                        output: o.0.clone(),
                        type_name: o.2.clone(),
                    }),
                    None => Err(CaptureError::BadSource {
                        source_name: spec.text.clone(),
                        reason: format!("{} has no output to record", spec.function),
                    }),
                };
            }
            v
        }
    };
    // The time first, so the host function finds it at input 0.
    let piped: Vec<usize> = time.into_iter().chain(chosen.iter().copied()).collect();
    if piped.len() > 8 {
        return Err(CaptureError::BadSource {
            source_name: spec.text.clone(),
            reason: "more than 7 numeric outputs: name one with .OUTPUT".into(),
        });
    }
    let mut types = Vec::new();
    let mut outputs = Vec::new();
    for &i in &piped {
        let ty = outs[i].1.ok_or_else(|| CaptureError::NotNumeric {
            source_name: spec.text.clone(),
            output: outs[i].0.clone(),
            type_name: outs[i].2.clone(),
        })?;
        types.push((outs[i].0.clone(), ty));
        outputs.push(u8::try_from(i).map_err(|_| CaptureError::BadSource {
            source_name: spec.text.clone(),
            reason: "output index beyond 255".into(),
        })?);
    }
    if spec.args.len() > f.inputs.len() {
        return Err(CaptureError::BadSource {
            source_name: spec.text.clone(),
            reason: format!(
                "{} arguments, but {} takes {}",
                spec.args.len(),
                spec.function,
                f.inputs.len()
            ),
        });
    }
    let mut args = Vec::new();
    for (i, input) in f.inputs.iter().enumerate() {
        let ty = input.ty().ok_or_else(|| CaptureError::BadSource {
            source_name: spec.text.clone(),
            reason: format!(
                "input {} has a type this build does not know ({})",
                input.name, input.type_name
            ),
        })?;
        let v = match spec.args.get(i) {
            Some(text) => arg_value(spec, &input.name, &ty, text)?,
            None => zero(&ty).ok_or_else(|| CaptureError::BadSource {
                source_name: spec.text.clone(),
                reason: format!(
                    "input {} is a {ty}: only functions with numeric inputs are sampled",
                    input.name
                ),
            })?,
        };
        args.push((u8::try_from(i).unwrap_or(u8::MAX), v));
    }
    if f.pipes.len() >= usize::from(f.pipe_slots) {
        return Err(CaptureError::NoFreeSlot {
            source_name: spec.text.clone(),
            slots: f.pipe_slots,
        });
    }
    let prefix = spec.prefix();
    let series = chosen
        .iter()
        .map(|&i| format!("{prefix}.{}", outs[i].0))
        .collect();
    Ok(Resolved {
        spec: spec.clone(),
        function: FnRef::new(runtime, spec.function.clone()),
        outputs,
        types,
        stamped: time.is_some(),
        args,
        series,
    })
}
