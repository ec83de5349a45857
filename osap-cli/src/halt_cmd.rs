//! `osap halt MACHINE.toml`: every module of the machine halted and every
//! tool switched off, from the network alone ([`osap_machine::halt`]):
//! nothing is set up and no clock is waited for, so it stops a machine
//! another process is running (`osap run … --tcp ADDR` on `osap serve`).

use std::process::ExitCode;
use std::time::{Duration, Instant};

use osap_host::{Host, HostConfig};
use osap_machine::config::Output;
use osap_machine::halt::{HaltReport, ModuleHalt};
use osap_machine::network::{open_links, Entry};

use crate::machine_cmd::{Failure, Target, FAULTED};

/// The halting host's runtime name on the network.
const HOST_NAME: &str = "osap-halt";

/// `osap halt MACHINE`. Exit code 0 when every module confirmed its halt
/// and every tool its off value, 1 when one could not be reached or
/// refused (the lines above say which), 2 when nothing was tried (the
/// machine file, the arguments, no link).
pub(crate) async fn halt(target: Target, started: Instant) -> Result<ExitCode, Failure> {
    let cfg = target.load()?;
    if target.sim {
        return Err(Failure::refused(
            "osap halt --sim: a simulated machine lives in the process that runs it; serve it (`osap serve --sim FILE`) and halt it with --tcp ADDR",
        ));
    }
    let links = target.links()?;
    // This host neither gives nor follows time: a halt needs no clock and
    // must not disturb the machine's.
    let mut config = HostConfig::named(HOST_NAME);
    config.time.root = false;
    let host = Host::start(config).map_err(faulted)?;
    let handles = open_links(&host, &links).await.map_err(faulted)?;
    let entry = Entry::of(&links, &handles);
    let begun = started.elapsed();
    let report = osap_machine::halt::halt(&host, &cfg, entry)
        .await
        .map_err(faulted)?;
    for m in &report.modules {
        println!("{}", module_line(m, begun));
    }
    if report.all_confirmed() {
        println!(
            "halted every module of {} {:.0} ms after start ({:.0} ms for the halt); power-cycle the motors or run `osap home` to move again",
            cfg.name,
            ms(started.elapsed()),
            ms(report.elapsed)
        );
        return Ok(ExitCode::SUCCESS);
    }
    eprintln!("error: {}", unconfirmed(&report));
    Ok(ExitCode::from(FAULTED))
}

fn faulted(e: impl std::fmt::Display) -> Failure {
    Failure {
        code: FAULTED,
        message: format!("cannot halt: {e}"),
    }
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// `  z  halted: "z" at route 0,0,3, found 9 ms, sent 12 ms, confirmed 14 ms
/// after start; tool pen off (pwm 0 at 0.05)`
fn module_line(m: &ModuleHalt, begun: Duration) -> String {
    let at = |d: Option<Duration>| d.map_or(String::from("-"), |d| format!("{:.0}", ms(begun + d)));
    let mut line = match &m.halt {
        Ok(()) => format!(
            "  {}  halted: {:?} at route {}, found {} ms, sent {} ms, confirmed {} ms after start",
            m.key,
            m.runtime.as_deref().unwrap_or("?"),
            route(m),
            at(m.found_after),
            at(m.sent_after),
            at(m.halted_after)
        ),
        Err(e) => format!("  {}  NOT HALTED: {e}", m.key),
    };
    for t in &m.tools {
        let output = match t.output {
            Output::Pwm(ch) => format!("pwm {ch} at {}", t.value),
            Output::Digital(pin) => format!("pin {pin} low"),
        };
        match &t.result {
            Ok(()) => line += &format!("; tool {} off ({output})", t.tool),
            Err(e) => line += &format!("; tool {} NOT OFF ({output}): {e}", t.tool),
        }
    }
    line
}

fn route(m: &ModuleHalt) -> String {
    m.route.as_deref().map_or(String::from("?"), |r| {
        r.iter().map(u8::to_string).collect::<Vec<_>>().join(",")
    })
}

/// Which modules and tools were not confirmed.
fn unconfirmed(report: &HaltReport) -> String {
    let mut names = Vec::new();
    for m in report.modules.iter().filter(|m| !m.confirmed()) {
        if m.halt.is_err() {
            names.push(format!("module {}", m.key));
        }
        for t in m.tools.iter().filter(|t| t.result.is_err()) {
            names.push(format!("tool {}", t.tool));
        }
    }
    format!(
        "not confirmed: {}. They may still run: check the machine, its cables and power, and switch it off if in doubt",
        names.join(", ")
    )
}
