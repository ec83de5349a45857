//! The JSON a bridge sends: a machine's info, state and events, a call's
//! values, a job's summary. Clients in any language read these.

use std::collections::BTreeMap;

use osap_machine::{Machine, MachineEvent, MachineState};
use serde::Serialize;
use serde_json::{json, Value as Json};

/// `osap/NAME/info`'s reply.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct Info {
    /// The machine file's name.
    pub name: String,
    /// The machine file's `kind` (`other` where it has none).
    pub kind: String,
    /// Its modules, by their `[modules]` keys (the names calls use).
    pub modules: Vec<String>,
    /// Its axes, in order.
    pub axes: Vec<String>,
    /// Its tools.
    pub tools: Vec<String>,
    /// Its state now (as in [`state_name`]).
    pub state: String,
}

/// A state's name: `idle`, `moving`, `homing`, `faulted` or `stopped`.
pub fn state_name(state: &MachineState) -> &'static str {
    match state {
        MachineState::Idle => "idle",
        MachineState::Moving => "moving",
        MachineState::Homing => "homing",
        MachineState::Faulted(_) => "faulted",
        MachineState::Stopped => "stopped",
    }
}

/// The machine's info.
pub fn info(machine: &Machine) -> Info {
    let cfg = machine.config();
    Info {
        name: cfg.name.clone(),
        kind: cfg.kind.as_str().into(),
        modules: machine.modules().keys().cloned().collect(),
        axes: machine.axes(),
        tools: cfg.tools.keys().cloned().collect(),
        state: state_name(&machine.state()).into(),
    }
}

/// `osap/NAME/state`'s message at synchronized time `t_us`.
pub fn state(machine: &Machine, t_us: u64) -> Json {
    let axes = machine.axes();
    let position: BTreeMap<&str, f64> = axes
        .iter()
        .map(String::as_str)
        .zip(machine.position())
        .collect();
    let homed: BTreeMap<&str, bool> = axes
        .iter()
        .map(String::as_str)
        .zip(machine.homed())
        .collect();
    let s = machine.state();
    let mut out = json!({
        "t": t_us as f64 * 1e-6,
        "state": state_name(&s),
        "position": position,
        "homed": homed,
    });
    if let MachineState::Faulted(reason) = s {
        out["reason"] = reason.into();
    }
    out
}

/// One machine event as `osap/NAME/events` publishes it: a `kind` of
/// `fault`, `limit`, `link_lost`, `refused`, `homed`, `state` or `stop`,
/// and its fields. Times are synchronized seconds.
pub fn event(e: &MachineEvent) -> Json {
    match e {
        MachineEvent::Fault {
            module,
            kind,
            detail,
            time,
            reason,
        } => json!({
            "kind": "fault",
            "module": module,
            "fault": kind.name(),
            "detail": detail,
            "t": *time as f64 * 1e-6,
            "reason": reason,
        }),
        MachineEvent::Limit {
            module,
            time,
            pressed,
            expected,
        } => json!({
            "kind": "limit",
            "module": module,
            "t": *time as f64 * 1e-6,
            "pressed": pressed,
            "expected": expected,
        }),
        MachineEvent::LinkLost { module } => json!({ "kind": "link_lost", "module": module }),
        MachineEvent::Refused {
            module,
            count,
            reason,
        } => json!({ "kind": "refused", "module": module, "count": count, "reason": reason }),
        MachineEvent::Homed { axis } => json!({ "kind": "homed", "axis": axis }),
        MachineEvent::State(s) => {
            let mut out = json!({ "kind": "state", "state": state_name(s) });
            if let MachineState::Faulted(reason) = s {
                out["reason"] = reason.as_str().into();
            }
            out
        }
        MachineEvent::Stop(report) => json!({
            "kind": "stop",
            "reason": report.reason,
            "confirmed": report.confirmed,
            "unreachable": report
                .unreachable
                .iter()
                .map(|u| json!({ "module": u.module, "error": u.error.to_string() }))
                .collect::<Vec<_>>(),
        }),
    }
}

/// A call's argument as the text `osap call` would take for it: numbers
/// and bools bare, strings as they are; `None` for arrays, objects and
/// null.
pub fn argument_text(v: &Json) -> Option<String> {
    match v {
        Json::Bool(b) => Some(b.to_string()),
        Json::Number(n) => Some(n.to_string()),
        Json::String(s) => Some(s.clone()),
        _ => None,
    }
}

/// `osap/NAME/job`'s reply.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct JobSummary {
    /// The planned motion time, s.
    pub planned_s: f64,
    /// The time the job took, s (machine time: virtual on a `--fast`
    /// simulation), heater waits included.
    pub executed_s: f64,
    /// Every fault that stopped the job, in words; empty when it ran.
    pub faults: Vec<String>,
    /// The largest following error per axis, mm.
    pub following_error: BTreeMap<String, f64>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_and_arguments_are_plain_json() {
        use osap_host::som::{value_json, Value};
        assert_eq!(value_json(&Value::I32(-4)), json!(-4));
        assert_eq!(value_json(&Value::U64(7)), json!(7));
        assert_eq!(value_json(&Value::F64(0.5)), json!(0.5));
        assert_eq!(value_json(&Value::F64(f64::NAN)), Json::Null);
        assert_eq!(value_json(&Value::Bool(true)), json!(true));
        assert_eq!(value_json(&Value::Utf8("a".into())), json!("a"));
        assert_eq!(argument_text(&json!(1024)), Some("1024".into()));
        assert_eq!(argument_text(&json!(-1.5)), Some("-1.5".into()));
        assert_eq!(argument_text(&json!("on")), Some("on".into()));
        assert_eq!(argument_text(&json!([1])), None);
        assert_eq!(argument_text(&Json::Null), None);
    }

    #[test]
    fn events_name_their_kind() {
        let e = event(&MachineEvent::Homed { axis: "x".into() });
        assert_eq!(e, json!({ "kind": "homed", "axis": "x" }));
        let e = event(&MachineEvent::State(MachineState::Faulted("limit".into())));
        assert_eq!(e["kind"], "state");
        assert_eq!(e["state"], "faulted");
        assert_eq!(e["reason"], "limit");
        let e = event(&MachineEvent::LinkLost { module: "a".into() });
        assert_eq!(e["kind"], "link_lost");
    }
}
