//! The extruder's flow limit over a G-code job, and the hotend's
//! temperature: each extruding move is held to the flow the extruder
//! allows at the hotend's target then ([`ExtruderKeys::flow_limit`]: the
//! melt model of `[axes.e.model]`, `max_volumetric_speed`), and `osap run
//! --temperature auto|N` replaces the job's hotend targets.
//!
//! [`ExtruderKeys::flow_limit`]: crate::config::ExtruderKeys::flow_limit

use super::{JobError, Move, Program};
use crate::config::{ExtruderKeys, MachineFile, MODEL_FORCE_SHARE};
use crate::gcode::HeaterRole;

/// The hotend's temperature for a job.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum HotendTemperature {
    /// As the job's M104/M109 set it.
    #[default]
    AsJob,
    /// The lowest within the melt model's measured range at which the
    /// job's peak flow stays under the model's limit.
    Auto,
    /// This many °C.
    Celsius(f64),
}

/// An extruding move the flow limit slowed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlowedMove {
    /// Its index in [`Program::moves`].
    pub index: usize,
    /// Its G-code line.
    pub line: usize,
    /// The feed the job asked (held to the machine's velocity), mm/s.
    pub asked: f64,
    /// The feed it runs at, mm/s.
    pub feed: f64,
    /// The flow it asked, mm³/s.
    pub flow: f64,
    /// The limit at the hotend's target then, mm³/s.
    pub limit: f64,
    /// The most time it adds, s: at cruise (path / feed − path / asked);
    /// less where the planner's acceleration keeps it slower anyway.
    pub added_s: f64,
}

/// The hotend temperature a job runs at when `--temperature` set it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HotendChoice {
    /// The target that replaced the job's, °C.
    pub celsius: f64,
    /// Picked from the model (`auto`) rather than given.
    pub auto: bool,
    /// The job's peak flow, mm³/s (held to the machine's velocity).
    pub peak_flow: f64,
    /// The flow limit at `celsius`, mm³/s (`None` without a limit).
    pub limit: Option<f64>,
}

/// An extruding move as the reader placed it: where in the program, and
/// its melt per unit feed.
#[derive(Debug, Clone, Copy)]
pub(super) struct Extruding {
    /// Its index in [`Program::moves`].
    pub index: usize,
    /// Its toolhead path, mm.
    pub path: f64,
    /// Melt flow per mm/s of feed, mm³/mm (filament area · Δe / path).
    pub flow_per_feed: f64,
}

/// Sets the hotend's temperature as `hotend` says, then holds every
/// extruding move of `program` to the flow limit at the hotend's target
/// in effect, recording what it slowed.
pub(super) fn limit_flow(
    cfg: &MachineFile,
    program: &mut Program,
    extruding: &[Extruding],
    hotend: HotendTemperature,
) -> Result<(), JobError> {
    let Some(e) = cfg.extruder().map(|a| &a.extruder) else {
        return Ok(());
    };
    let fastest = cfg.limits.velocity;
    let asked = |x: &Extruding, moves: &[(usize, Move)]| match &moves[x.index].1 {
        Move::Line(_, feed) => feed.min(fastest),
        _ => 0.0,
    };
    let peak_flow = extruding
        .iter()
        .map(|x| asked(x, &program.moves) * x.flow_per_feed)
        .fold(0.0, f64::max);
    // A heater move put first shifts every extruding move by one.
    let mut shift = 0;
    if let Some((celsius, auto)) = chosen_temperature(e, hotend, peak_flow)? {
        shift = set_hotend(cfg, program, celsius, auto)?;
        program.hotend = Some(HotendChoice {
            celsius,
            auto,
            peak_flow,
            limit: e.flow_limit(celsius),
        });
    }
    // The hotend's target at each move, then the limit there.
    let hotend_name = HeaterRole::Hotend.name();
    let mut target: Option<f64> = None;
    let mut next = extruding
        .iter()
        .map(|x| Extruding {
            index: x.index + shift,
            ..*x
        })
        .peekable();
    let mut cold_said = false;
    let mut slowed = Vec::new();
    for i in 0..program.moves.len() {
        if let Move::Heater { name, celsius, .. } = &program.moves[i].1 {
            if name == hotend_name {
                target = Some(*celsius);
            }
        }
        let Some(x) = next.next_if(|x| x.index == i) else {
            continue;
        };
        let line = program.moves[i].0;
        let hotend_c = match (target, &e.model) {
            (Some(t), _) if t > 0.0 => t,
            // Without a target the model's lowest measured temperature
            // gives the lowest limit it vouches for.
            (_, Some(m)) => {
                if !cold_said {
                    cold_said = true;
                    program.warnings.push(format!(
                        "line {line}: extrudes with no hotend target set; its flow is held to \
                         the melt model's limit at {} °C, the lowest it was measured at",
                        m.temp_range[0]
                    ));
                }
                m.temp_range[0]
            }
            (_, None) => 0.0,
        };
        let Some(limit) = e.flow_limit(hotend_c) else {
            continue;
        };
        let want = asked(&x, &program.moves);
        let flow = want * x.flow_per_feed;
        if flow > limit {
            let feed = want * limit / flow;
            if let Move::Line(_, f) = &mut program.moves[i].1 {
                *f = feed;
            }
            slowed.push(SlowedMove {
                index: i,
                line,
                asked: want,
                feed,
                flow,
                limit,
                added_s: x.path / feed - x.path / want,
            });
        }
    }
    program.slowed = slowed;
    Ok(())
}

/// The temperature `--temperature` asks, and whether the model picked it:
/// `auto` is the lowest whole degree in the model's range that carries
/// `peak_flow` (the range's top when none does).
fn chosen_temperature(
    e: &ExtruderKeys,
    hotend: HotendTemperature,
    peak_flow: f64,
) -> Result<Option<(f64, bool)>, JobError> {
    match hotend {
        HotendTemperature::AsJob => Ok(None),
        HotendTemperature::Celsius(c) => Ok(Some((c, false))),
        HotendTemperature::Auto => {
            let (Some(m), Some(grip)) = (&e.model, e.max_force_n) else {
                return Err(JobError::Temperature(
                    "--temperature auto picks from the melt model: the machine file has no \
                     [axes.e.model] (osap rheo MACHINE --write measures one), so give \
                     --temperature N"
                        .into(),
                ));
            };
            let [lo, hi] = m.temp_range;
            let t = m
                .model()
                .lowest_temperature_for(peak_flow.max(1e-9), MODEL_FORCE_SHARE * grip, (lo, hi))
                .map_or(hi, |t| t.ceil().min(hi));
            Ok(Some((t, true)))
        }
    }
}

/// Sets the hotend to `celsius` in `program`: every non-zero target of the
/// job replaced (a target of 0 turns it off, and stays), or, in a job that
/// never sets it, a wait for it put first. Refuses a temperature the
/// heater cannot hold. Returns the moves put first (0 or 1).
fn set_hotend(
    cfg: &MachineFile,
    program: &mut Program,
    celsius: f64,
    auto: bool,
) -> Result<usize, JobError> {
    let name = HeaterRole::Hotend.name();
    let Some(h) = cfg.heaters.get(name) else {
        return Err(JobError::Temperature(format!(
            "--temperature sets the hotend, but the machine file has no [heaters.{name}]"
        )));
    };
    if !(celsius.is_finite() && celsius > h.min_temp && celsius < h.max_temp) {
        return Err(JobError::Temperature(format!(
            "--temperature {celsius}: the hotend runs between its min_temp {} and max_temp {} °C",
            h.min_temp, h.max_temp
        )));
    }
    if let Some(m) = cfg.extruder().and_then(|a| a.extruder.model.as_ref()) {
        let [lo, hi] = m.temp_range;
        if !auto && !(lo..=hi).contains(&celsius) {
            program.warnings.push(format!(
                "--temperature {celsius}: outside the {lo}–{hi} °C the melt model was measured \
                 at; the flow limit takes the law {}",
                if celsius > hi {
                    format!("at {hi} °C (no higher)")
                } else {
                    "as it extrapolates (lower)".into()
                }
            ));
        }
    }
    let mut found = false;
    for (_, mv) in &mut program.moves {
        if let Move::Heater {
            name: n,
            celsius: c,
            ..
        } = mv
        {
            if n == name && *c > 0.0 {
                *c = celsius;
                found = true;
            }
        }
    }
    if found {
        return Ok(0);
    }
    program.moves.insert(
        0,
        (
            0,
            Move::Heater {
                name: name.into(),
                celsius,
                wait: true,
            },
        ),
    );
    program.warnings.push(format!(
        "the job sets no {name} temperature: --temperature heats it to {celsius} °C and waits before the first move"
    ));
    Ok(1)
}

impl Program {
    /// The seconds the flow limit added at cruise, summed over
    /// [`Program::slowed`].
    pub fn flow_limit_added_s(&self) -> f64 {
        self.slowed.iter().map(|s| s.added_s).sum()
    }

    /// This program with the flow limit's feeds put back as the job asked
    /// (to plan how long it would take unlimited).
    pub fn without_flow_limit(&self) -> Program {
        let mut p = self.clone();
        for s in &self.slowed {
            if let Some((_, Move::Line(_, feed))) = p.moves.get_mut(s.index) {
                *feed = s.asked;
            }
        }
        p.slowed.clear();
        p
    }

    /// Writes [`Program::slowed`] as CSV to `path`: `line`, `asked_mm_s`,
    /// `feed_mm_s`, `flow_mm3_s`, `limit_mm3_s`, `added_s`.
    pub fn write_slowed_csv(&self, path: &std::path::Path) -> std::io::Result<()> {
        use std::io::Write;
        let mut w = std::io::BufWriter::new(std::fs::File::create(path)?);
        writeln!(
            w,
            "line,asked_mm_s,feed_mm_s,flow_mm3_s,limit_mm3_s,added_s"
        )?;
        for s in &self.slowed {
            writeln!(
                w,
                "{},{:.3},{:.3},{:.3},{:.3},{:.4}",
                s.line, s.asked, s.feed, s.flow, s.limit, s.added_s
            )?;
        }
        w.flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::job::from_gcode_with;

    /// The example printer with its hand-tuned flow cap and pressure
    /// advance replaced by a melt model: 20 N at 5 mm³/s and 210 °C,
    /// measured from 195 to 235 °C; grip 40 N, so the limit is the flow
    /// needing 32 N.
    fn modelled() -> MachineFile {
        let text = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../examples/machines/printer.toml"
        ))
        .unwrap();
        let text: String = text
            .lines()
            .filter(|l| {
                !l.starts_with("max_volumetric_speed") && !l.starts_with("pressure_advance")
            })
            .map(|l| format!("{l}\n"))
            .collect();
        let text = text.replace(
            "[axes.e.loadcell]",
            "[axes.e.model]\nflow_k = 8.0\nflow_n = 0.6\ntemp_coeff = 0.02\nt_ref = 210.0\n\
             response_ms = 45.0\ntemp_range = [195.0, 235.0]\n\n[axes.e.loadcell]",
        );
        MachineFile::parse(&text).unwrap()
    }

    /// The model's limit at `t` °C, written out: (32 / (8 e^(−0.02 (t − 210))))^(1/0.6).
    fn limit_at(t: f64) -> f64 {
        (32.0 / (8.0 * (-0.02 * (t - 210.0)).exp())).powf(1.0 / 0.6)
    }

    /// Lines of 0.45 × 0.2 mm beads (0.09 mm³ per mm) at 20 mm/s (1.8
    /// mm³/s), 100 mm/s (9 mm³/s) and 200 mm/s (18 mm³/s), relative E.
    fn job(heat: &str) -> crate::gcode::Job {
        let e_per_mm = 0.09 / (std::f64::consts::PI * 1.75 * 1.75 / 4.0);
        let text = format!(
            "{heat}G28\nM83\nG1 X50 Y50 Z0.2 F9000\n\
             G1 X60 E{e} F1200\nG1 X70 E{e} F6000\nG1 X80 E{e} F12000\nM104 S0\n",
            e = 10.0 * e_per_mm
        );
        crate::gcode::read(&text).unwrap()
    }

    fn build(cfg: &MachineFile, heat: &str, hotend: HotendTemperature) -> Program {
        let start = crate::machine::drive::start_position(cfg);
        from_gcode_with(cfg, &job(heat), &start, hotend).unwrap()
    }

    #[test]
    fn moves_over_the_models_limit_are_slowed_to_it_at_the_hotends_target() {
        let cfg = modelled();
        // 210 °C: the limit is 10.08 mm³/s, so only the 18 mm³/s move.
        let p = build(&cfg, "M109 S210\n", HotendTemperature::AsJob);
        assert!((limit_at(210.0) - 10.079).abs() < 1e-3);
        assert_eq!(p.slowed.len(), 1, "{:?}", p.slowed);
        let s = p.slowed[0];
        assert_eq!(s.line, 7);
        assert!((s.flow - 18.0).abs() < 1e-6, "{}", s.flow);
        assert!((s.limit - limit_at(210.0)).abs() < 1e-9);
        assert!(
            (s.feed * s.flow / s.asked - limit_at(210.0)).abs() < 1e-9,
            "{}",
            s.feed
        );
        assert!((s.feed - limit_at(210.0) / 0.09).abs() < 1e-4, "{}", s.feed);
        assert!((s.added_s - (10.0 / s.feed - 10.0 / 200.0)).abs() < 1e-12);
        let Move::Line(_, feed) = &p.moves[s.index].1 else {
            panic!("{:?}", p.moves[s.index]);
        };
        assert_eq!(*feed, s.feed);
        // 190 °C: the limit falls to 6.7 mm³/s and catches the 9 too.
        let cold = build(&cfg, "M109 S190\n", HotendTemperature::AsJob);
        assert_eq!(
            cold.slowed.iter().map(|s| s.line).collect::<Vec<_>>(),
            [6, 7]
        );
        assert!((cold.slowed[0].limit - limit_at(190.0)).abs() < 1e-9);
        // Without the limit the feeds are the job's again, and it plans
        // quicker.
        let back = p.without_flow_limit();
        let start = crate::machine::drive::start_position(&cfg);
        let (limited_s, unlimited_s) = (
            p.planned_seconds(&cfg, &start).unwrap(),
            back.planned_seconds(&cfg, &start).unwrap(),
        );
        assert!(
            limited_s > unlimited_s + 0.005,
            "{limited_s} vs {unlimited_s}"
        );
        assert!(back.slowed.is_empty());
        assert!(matches!(back.moves[s.index].1, Move::Line(_, f) if f == 200.0));
    }

    #[test]
    fn auto_picks_the_lowest_temperature_that_carries_the_jobs_peak_flow() {
        let cfg = modelled();
        let p = build(&cfg, "M104 S150\nM109 S210\n", HotendTemperature::Auto);
        let h = p.hotend.unwrap();
        assert!(h.auto);
        assert!((h.peak_flow - 18.0).abs() < 1e-6, "{}", h.peak_flow);
        // 18 mm³/s needs 210 + ln((8·18^0.6)/32)/0.02 = 227.8 °C: 228.
        assert_eq!(h.celsius, 228.0);
        assert!(limit_at(228.0) >= 18.0 && limit_at(227.0) < 18.0);
        assert!(p.slowed.is_empty(), "{:?}", p.slowed);
        // Every non-zero hotend target replaced; the end's S0 stays.
        let targets: Vec<f64> = p
            .moves
            .iter()
            .filter_map(|(_, m)| match m {
                Move::Heater { name, celsius, .. } if name == "hotend" => Some(*celsius),
                _ => None,
            })
            .collect();
        assert_eq!(targets, [228.0, 228.0, 0.0]);
    }

    #[test]
    fn a_peak_the_range_cannot_carry_prints_at_its_top_slowed() {
        let cfg = modelled();
        let text = "M109 S210\nG28\nM83\nG1 X50 Y50 Z0.2 F9000\nG1 X150 E30 F18000\n";
        let job = crate::gcode::read(text).unwrap();
        let start = crate::machine::drive::start_position(&cfg);
        let p = from_gcode_with(&cfg, &job, &start, HotendTemperature::Auto).unwrap();
        assert_eq!(p.hotend.unwrap().celsius, 235.0);
        assert_eq!(p.slowed.len(), 1);
        assert!((p.slowed[0].limit - limit_at(235.0)).abs() < 1e-9);
    }

    #[test]
    fn a_given_temperature_replaces_the_jobs_and_its_limit_follows() {
        let cfg = modelled();
        let p = build(&cfg, "M109 S210\n", HotendTemperature::Celsius(200.0));
        assert_eq!(p.hotend.unwrap().celsius, 200.0);
        assert!((p.slowed[0].limit - limit_at(200.0)).abs() < 1e-9);
        // Above the measured range the limit stays at the range's top.
        let hot = build(&cfg, "M109 S210\n", HotendTemperature::Celsius(260.0));
        assert!(hot
            .warnings
            .iter()
            .any(|w| w.contains("outside the 195–235")));
        assert!(hot.slowed.is_empty() || (hot.slowed[0].limit - limit_at(235.0)).abs() < 1e-9);
        // A job that never heats is heated first.
        let p = build(&cfg, "", HotendTemperature::Celsius(215.0));
        assert_eq!(
            p.moves[0].1,
            Move::Heater {
                name: "hotend".into(),
                celsius: 215.0,
                wait: true
            }
        );
        assert!(p.slowed.iter().all(|s| p.moves[s.index].0 == s.line));
    }

    #[test]
    fn temperatures_that_cannot_be_set_are_refused() {
        let cfg = modelled();
        let start = crate::machine::drive::start_position(&cfg);
        for c in [300.0, 3.0] {
            let e =
                from_gcode_with(&cfg, &job(""), &start, HotendTemperature::Celsius(c)).unwrap_err();
            assert!(e.to_string().contains("max_temp 290"), "{e}");
        }
        let plain = MachineFile::load(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../examples/machines/printer.toml"
        ))
        .unwrap();
        let e = from_gcode_with(&plain, &job(""), &start, HotendTemperature::Auto).unwrap_err();
        assert!(e.to_string().contains("osap rheo MACHINE --write"), "{e}");
    }

    #[test]
    fn extruding_with_no_target_is_held_to_the_lowest_measured_limit() {
        let cfg = modelled();
        let p = build(&cfg, "", HotendTemperature::AsJob);
        assert!(p.warnings.iter().any(|w| w.contains("no hotend target")));
        assert!((p.slowed[0].limit - limit_at(195.0)).abs() < 1e-9);
    }

    #[test]
    fn the_hand_set_cap_still_holds_without_a_model() {
        let plain = MachineFile::load(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../examples/machines/printer.toml"
        ))
        .unwrap();
        let p = build(&plain, "M109 S210\n", HotendTemperature::AsJob);
        assert_eq!(p.slowed.len(), 1);
        assert_eq!(p.slowed[0].limit, 15.0);
        // With both, the lower holds.
        let mut both = modelled();
        both.axes
            .get_mut("e")
            .unwrap()
            .extruder
            .max_volumetric_speed = Some(5.0);
        let p = build(&both, "M109 S210\n", HotendTemperature::AsJob);
        assert_eq!(
            p.slowed.iter().map(|s| s.limit).collect::<Vec<_>>(),
            [5.0, 5.0]
        );
    }

    #[test]
    fn a_program_runs_its_extrusion_from_where_the_extruder_stands() {
        let cfg = modelled();
        let p = build(&cfg, "M109 S210\n", HotendTemperature::AsJob);
        // Read for an extruder 100 mm along, the job extrudes from there.
        let mut start = crate::machine::drive::start_position(&cfg);
        let k = p.e_slot.unwrap();
        start[k] = 100.0;
        let along =
            from_gcode_with(&cfg, &job("M109 S210\n"), &start, HotendTemperature::AsJob).unwrap();
        assert_eq!(along.e_start, 100.0);
        assert!((along.extruded_mm() - p.extruded_mm()).abs() < 1e-9);
        assert!(along.extruded_mm() > 1.0);
        let moved = p.with_e_start(p.e_start + 250.0);
        assert_eq!(moved.e_start, p.e_start + 250.0);
        assert!((moved.extruded_mm() - p.extruded_mm()).abs() < 1e-9);
        for ((_, a), (_, b)) in p.moves.iter().zip(&moved.moves) {
            if let (Move::Line(pa, _), Move::Line(pb, _)) = (a, b) {
                assert!((pb[k] - pa[k] - 250.0).abs() < 1e-9);
                assert_eq!(pa[..k], pb[..k]);
            }
        }
    }

    #[test]
    fn pressure_advance_comes_from_the_models_response_unless_given() {
        let cfg = modelled();
        let e = &cfg.extruder().unwrap().extruder;
        assert_eq!(e.pressure_advance_s(), 0.045);
        let mut given = e.clone();
        given.pressure_advance = Some(0.02);
        assert_eq!(given.pressure_advance_s(), 0.02);
    }
}
