//! The simulated diode laser (examples/machines/laser.toml) engraving a
//! LightBurn-style job in virtual time: with `M4` the power its module
//! applies (read back from the module, `level_read`) follows
//! `power × speed / feed` within 2 % of full power at every readback,
//! through the accelerations and the corners, and the laser switches at
//! its place on the path without the motion stopping.

use maxl::blocks::planner::Planner;
use osap_machine::config::MachineFile;
use osap_machine::gcode;
use osap_machine::job::{from_gcode, gcode_options, Move, Program, ToolLevel};
use osap_machine::machine::drive::start_position;
use osap_machine::machine::motion::machine_planner;
use osap_machine::machine::{Machine, INTERVAL_US, MAX_AXES};
use osap_machine::sim::SimOptions;
use osap_sim::machine::virtual_runtime;

fn laser() -> MachineFile {
    MachineFile::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/laser.toml"
    ))
    .unwrap()
}

fn engraving(cfg: &MachineFile) -> Program {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/jobs/engrave.gcode"
    ))
    .unwrap();
    let g = gcode::read_with(&text, &gcode_options(cfg, None)).unwrap();
    from_gcode(cfg, &g, &start_position(cfg)).unwrap()
}

fn pad(p: &[f64]) -> [f64; MAX_AXES] {
    let mut out = [0.0; MAX_AXES];
    out[..p.len()].copy_from_slice(p);
    out
}

/// The job replayed on the machine's planner, as an oracle: each
/// segment's laser level and feed (level 0 along rapids and after `M5`;
/// `S` of 1000; dynamic for `M4`), queued as the job queues them.
fn replay(cfg: &MachineFile, p: &Program, start: &[f64]) -> (Planner<MAX_AXES>, Vec<(f64, f64)>) {
    let mut planner = machine_planner(cfg).unwrap();
    planner.set_position(pad(start)).unwrap();
    let mut per_segment = Vec::new();
    let mut level = 0.0;
    let mut queue = |planner: &mut Planner<MAX_AXES>, to: &[f64], feed: f64, lf: (f64, f64)| {
        let n = planner.line(pad(to), feed).unwrap();
        per_segment.extend(std::iter::repeat_n(lf, n));
    };
    for (_, m) in &p.moves {
        match m {
            Move::Rapid(to) => queue(&mut planner, to, cfg.limits.velocity, (0.0, 1.0)),
            Move::Line(to, f) => queue(&mut planner, to, *f, (level, *f)),
            Move::Tool(None) => level = 0.0,
            Move::Tool(Some(ToolLevel::Dynamic(Some(s)))) => level = s / 1000.0,
            // LightBurn's bare `M4` before the first `S`: full, as an `M3`
            // without `S` is (the job's rapids keep it off until a cut's S).
            Move::Tool(Some(ToolLevel::Dynamic(None))) => level = 1.0,
            Move::Tool(other) => panic!("the job is all M4 S: {other:?}"),
            _ => {}
        }
    }
    (planner, per_segment)
}

#[test]
fn an_engraving_s_power_follows_its_speed_through_every_corner() {
    let cfg = laser();
    let program = engraving(&cfg);
    virtual_runtime().unwrap().block_on(async {
        let m = Machine::simulate_with(
            &cfg,
            SimOptions::VIRTUAL,
        )
        .await
        .unwrap();
        let start = start_position(&cfg);
        m.set_position(&start).unwrap();
        m.start_recording().await.unwrap();
        let t0 = m.now_us().await.unwrap();
        m.run_program(&program, |_| {}).await.unwrap();
        let rec = m.take_recording(t0).await.unwrap();
        m.stop().await.unwrap();

        // executed.csv's column: the laser's duty at every executed sample.
        assert_eq!(rec.tools.len(), 1);
        assert_eq!(rec.tools[0].0, "laser");
        assert_eq!(rec.tools[0].1.len(), rec.executed.len());
        let readbacks = &rec.tool_readbacks[0].1;

        // The plan replayed, aligned on the stamp the job's first segment
        // began at (the last planned sample still at the start).
        let moving = rec
            .planned
            .iter()
            .position(|s| s.pos.iter().zip(&start).any(|(a, b)| (a - b).abs() > 1e-9))
            .expect("the job moved");
        let us = |t: f64| t0 + (t * 1e6).round() as u64;
        let s0 = us(rec.planned[moving - 1].t);
        let (mut plan, per_segment) = replay(&cfg, &program, &start);
        plan.sample_kin(s0).unwrap();
        // The replay is the plan the machine ran: the same positions at
        // every stamp it sent (to well under a microstep).
        let mut worst_pos = 0.0f64;
        let replay_at = |plan: &mut Planner<MAX_AXES>, t: u64| plan.sample_kin(t).unwrap();
        let mut stamps = rec.planned[moving..].iter().peekable();

        let dt = u64::from(INTERVAL_US);
        let mut worst = (0.0f64, 0.0, 0.0, 0.0);
        let (mut compared, mut in_corners, mut lagged_worst, mut static_worst) =
            (0, 0, 0.0f64, 0.0f64);
        let expected = |plan: &Planner<MAX_AXES>, u: u64| -> (f64, f64, f64) {
            let k = plan.state_at(u as f64);
            let v = (k.vel[0].powi(2) + k.vel[1].powi(2)).sqrt();
            let id = plan.segment_at(u as f64) as usize;
            let (level, feed) = per_segment.get(id).copied().unwrap_or((0.0, 1.0));
            (level * (v / feed).min(1.0), level, v / feed)
        };
        let mut last_sampled = s0;
        for &(t, applied) in readbacks {
            let u = us(t);
            if u <= s0 + dt {
                continue;
            }
            // Sample the replay up to the stamp before u (state_at looks
            // ahead of the last stamp sampled), checking it against the
            // recorded plan on the way.
            while let Some(s) = stamps.peek() {
                let st = us(s.t);
                if st + dt > u {
                    break;
                }
                let k = replay_at(&mut plan, st);
                for (a, b) in k.pos.iter().zip(&s.pos) {
                    worst_pos = worst_pos.max((a - b).abs());
                }
                last_sampled = st;
                stamps.next();
            }
            if plan.is_idle() && u > last_sampled + dt {
                break;
            }
            let (want, level, ratio) = expected(&plan, u);
            let err = (applied - want).abs();
            if err > 0.02 && std::env::var("LASER_DEBUG").is_ok() {
                let id = plan.segment_at(u as f64);
                println!(
                    "{t:.5} u {u} applied {applied:.4} want {want:.4} seg {id} {:?} start {:?}",
                    per_segment.get(id as usize),
                    plan.segment_start(id)
                );
            }
            if err > worst.0 {
                worst = (err, t, applied, want);
            }
            compared += 1;
            if level > 0.0 && ratio < 0.5 {
                in_corners += 1;
            }
            // What a laser 1 ms late, or one without dynamic power, would
            // have applied: the bound must catch both.
            // (within one move, on a ramp: a switch would say nothing of a
            // lag's effect on dynamic power)
            let same = plan.segment_at(u as f64) == plan.segment_at((u - 1_000) as f64);
            if u > last_sampled + 1_000 && same && level > 0.0 {
                let (late, _, _) = expected(&plan, u - 1_000);
                lagged_worst = lagged_worst.max((late - want).abs());
            }
            static_worst = static_worst.max((level - want).abs());
        }
        println!(
            "worst {:.3} % of full power at {:.4} s ({compared} readbacks, {in_corners} below half the feed; replay off by {worst_pos:e} mm; 1 ms late: {lagged_worst:.3}, static: {static_worst:.3})",
            worst.0 * 100.0,
            worst.1
        );
        assert!(worst_pos < 1e-6, "the replay is off the plan by {worst_pos} mm");
        assert!(compared > 10_000, "{compared} readbacks compared");
        assert!(in_corners > 50, "{in_corners} readbacks below half the feed");
        assert!(
            worst.0 <= 0.02,
            "applied {:.4} for {:.4} at {:.4} s: {:.2} % of full power off",
            worst.2,
            worst.3,
            worst.1,
            worst.0 * 100.0
        );
        assert!(lagged_worst > 0.03, "a 1 ms lag would be {lagged_worst}");
        assert!(static_worst > 0.5, "static power would be {static_worst} off");
        println!(
            "worst {:.3} % of full power ({compared} readbacks, {in_corners} below half the feed)",
            worst.0 * 100.0
        );
    });
}

/// The switches cost the motion nothing: the job runs in the time it was
/// planned to, with no stop per layer; and a laser with a settle time
/// holds the path that long where it comes to rest at each switch, and
/// not a timer lead more.
#[test]
fn the_engraving_runs_in_its_planned_time() {
    let plain = planned_and_run(laser());
    assert!((29.0..32.0).contains(&plain), "{plain} s");
    let mut settling = laser();
    settling.tools.get_mut("laser").unwrap().settle_ms = 50;
    let held = planned_and_run(settling);
    // 40 switches, each now a stop where the path ends and a 50 ms hold.
    assert!(held > plain + 40.0 * 0.05, "{held} s against {plain} s");
}

/// Runs the engraving on `cfg`: checks it took what was planned, and
/// returns the planned seconds.
fn planned_and_run(cfg: MachineFile) -> f64 {
    let program = engraving(&cfg);
    let planned = program
        .planned_seconds(&cfg, &start_position(&cfg))
        .unwrap();
    virtual_runtime().unwrap().block_on(async {
        let m = Machine::simulate_with(&cfg, SimOptions::VIRTUAL)
            .await
            .unwrap();
        m.set_position(start_position(&cfg)).unwrap();
        let t0 = tokio::time::Instant::now();
        m.run_program(&program, |_| {}).await.unwrap();
        let took = t0.elapsed().as_secs_f64();
        m.stop().await.unwrap();
        // The run ends a timer lead and two intervals after the plan, waits
        // for a status report from every motor (they come every 50 ms) and
        // 20 ms for the last reports: nothing else. A stop per switch
        // would cost 86 ms each, and the job switches the laser 40 times.
        let overhead = (f64::from(osap_machine::machine::LEAD_US) + 2.0 * f64::from(INTERVAL_US))
            * 1e-6
            + 0.02;
        let extra = took - planned - overhead;
        assert!(
            (-0.005..0.055).contains(&extra),
            "took {took:.3} s, planned {planned:.3} s: {extra:.3} s more than a run's ends"
        );
        let switches = program
            .moves
            .iter()
            .filter(|(_, m)| matches!(m, Move::Tool(_)))
            .count();
        assert_eq!(switches, 40);
    });
    planned
}

/// A halt in the middle of a cut: the laser goes off with the stop and
/// stays off, though the motion stream goes on afterwards (the points it
/// had queued for the cut are dropped on the module and the stream's are
/// off).
#[test]
fn a_halt_mid_cut_puts_the_laser_out_for_good() {
    let cfg = laser();
    let program = engraving(&cfg);
    virtual_runtime().unwrap().block_on(async {
        let m = Machine::simulate_with(&cfg, SimOptions::VIRTUAL)
            .await
            .unwrap();
        m.set_position(start_position(&cfg)).unwrap();
        m.start_recording().await.unwrap();
        let t0 = m.now_us().await.unwrap();
        let job = {
            let (m, p) = (m.clone(), program.clone());
            tokio::spawn(async move { m.run_program(&p, |_| {}).await })
        };
        // 3 s in: the frame is being cut.
        tokio::time::sleep(std::time::Duration::from_secs(3)).await;
        job.abort();
        let halted_at = m.now_us().await.unwrap();
        m.halt().await.unwrap();
        let stopped_at = m.now_us().await.unwrap();
        tokio::time::sleep(std::time::Duration::from_millis(500)).await;
        let rec = m.take_recording(t0).await.unwrap();
        m.stop().await.unwrap();
        let readbacks = &rec.tool_readbacks[0].1;
        let secs = |us: u64| (us - t0) as f64 * 1e-6;
        let on_before = readbacks
            .iter()
            .filter(|(t, d)| *t < secs(halted_at) && *d > 0.1)
            .count();
        assert!(
            on_before > 500,
            "the laser was on for {on_before} readbacks"
        );
        let after: Vec<_> = readbacks
            .iter()
            .filter(|(t, _)| *t >= secs(stopped_at))
            .collect();
        assert!(
            after.len() > 400,
            "{} readbacks after the stop",
            after.len()
        );
        assert!(
            after.iter().all(|(_, d)| *d == 0.0),
            "lit after the stop: {:?}",
            after.iter().find(|(_, d)| *d != 0.0)
        );
    });
}
