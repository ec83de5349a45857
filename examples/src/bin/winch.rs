//! A machine script: a cable winch (`osap-sim/topologies/winch.toml`), its
//! motors used as torque devices, its mass following a figure-eight.
//!
//! A 1 kg mass hangs in a 1 m × 1 m vertical frame on four cables, one from
//! each corner, each wound on a 12 mm spool on a stepper module's motor
//! with a shaft encoder. The script (the host) closes the loop, as the
//! thesis's winch did with plain calls:
//!
//! 1. it powers the motors (they hold where their brakes held them) and
//!    arms each module's output watchdog, so that if the script stops the
//!    torque ends and the motors hold;
//! 2. every cycle it reads the four cable lengths (`get_position`: in
//!    torque mode, the shaft's position, in mm of cable), finds the mass
//!    where the four cables' circles meet (least squares, each cable's
//!    stretch under its last tension added), and its velocity;
//! 3. it asks for the force that follows the figure-eight: the path's
//!    acceleration plus a PD on the error, plus gravity, all times the
//!    mass;
//! 4. it shares that force among the cables, each at least `MIN_TENSION`
//!    (a cable only pulls): a base tension on every cable plus the
//!    least-norm correction, clamped;
//! 5. it sends each motor the torque that gives its tension, plus its
//!    spool's inertia and friction along the path (`set_torque`, as a
//!    fraction of the motor's holding torque).
//!
//! It checks the mass's true position (the simulator's) against the path
//! and fails if the error's rms or maximum is past `--max-rms-mm` or
//! `--max-mm`. Then `torque_off` ends the torque: the motors hold the mass
//! where it is.
//!
//! ```text
//! cargo run -p osap-examples --bin winch -- --fast
//! ```
//!
//! Without `--fast` it runs in real time, where the simulated modules'
//! commutation is only as regular as the host's scheduler (see
//! `docs/winch.md`: on a loaded machine the mass is lost).

use std::error::Error;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::Parser;
use futures_util::future::join_all;
use osap_host::som::{FnRef, FunctionHandle, Manager, Value};
use osap_host::{Host, HostConfig};
use osap_sim::machine::{SimMachine, TimeMode};
use osap_sim::topology::WinchSpec;
use osap_sim::SimSpec;

type BoxError = Box<dyn Error>;

#[derive(Parser, Debug)]
#[command(
    about = "Drive a simulated cable winch's mass along a figure-eight, motors as torque devices"
)]
struct Args {
    /// The simulated winch (a topology with a `[winch]`).
    #[arg(long, default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/../osap-sim/topologies/winch.toml"))]
    topology: PathBuf,
    /// Run in virtual time (as fast as the host computes it).
    #[arg(long)]
    fast: bool,
    /// The figure-eight's width, mm.
    #[arg(long, default_value_t = 300.0)]
    width_mm: f64,
    /// Its height, mm.
    #[arg(long, default_value_t = 150.0)]
    height_mm: f64,
    /// Seconds per lap.
    #[arg(long, default_value_t = 8.0)]
    period_s: f64,
    /// Laps.
    #[arg(long, default_value_t = 2)]
    laps: u32,
    /// Fail if the tracking error's rms is past this, mm.
    #[arg(long, default_value_t = 1.2)]
    max_rms_mm: f64,
    /// Fail if the tracking error is ever past this, mm.
    #[arg(long, default_value_t = 3.0)]
    max_mm: f64,
}

/// The control loop's period, s.
const CYCLE_S: f64 = 0.005;
/// The path's stiffness and damping, 1/s² and 1/s: a 3.2 Hz loop,
/// damping ratio 0.8, slow enough for the loop's latency (a read and a write
/// over USB and a UART, 10 ms a cycle).
const KP: f64 = 400.0;
const KD: f64 = 32.0;
/// The least a cable is asked to pull, N (a slack cable loses its spool's
/// turns and its length).
const MIN_TENSION: f64 = 2.0;
/// The most, N: 0.36 N·m on a 12 mm spool, 80 % of the motor's holding.
const MAX_TENSION: f64 = 30.0;
/// The tension every cable starts from before the force is shared, N.
const BASE_TENSION: f64 = 8.0;
/// Seconds the phase speeds up (and slows down) over at each end.
const RAMP_S: f64 = 2.0;
/// How long upstream may be quiet before a module ends its torque, ms.
const WATCHDOG_MS: u32 = 100;

/// The winch as the script knows it: from the topology's `[winch]`.
struct Winch {
    anchors: Vec<[f64; 2]>,
    /// Each cable's length with its shaft at 0 (at boot), m.
    lengths0: Vec<f64>,
    radius: Vec<f64>,
    /// Spool and rotor inertia, kg·m².
    inertia: Vec<f64>,
    friction: Vec<f64>,
    viscous: Vec<f64>,
    mass: f64,
    gravity: f64,
    stiffness: f64,
    holding: f64,
    steps_per_rev: f64,
    start: [f64; 2],
}

impl Winch {
    fn new(w: &WinchSpec) -> Winch {
        Winch {
            anchors: w.spools.iter().map(|s| s.anchor).collect(),
            lengths0: w.spools.iter().map(|s| dist(s.anchor, w.start)).collect(),
            radius: w.spools.iter().map(|s| s.radius_mm * 1e-3).collect(),
            inertia: w
                .spools
                .iter()
                .map(|s| s.inertia_kgm2 + w.model.rotor_inertia_kgm2)
                .collect(),
            friction: w.spools.iter().map(|s| s.friction_nm).collect(),
            viscous: w.spools.iter().map(|s| s.viscous_nms).collect(),
            mass: w.mass_kg,
            gravity: w.gravity,
            stiffness: w.cable_stiffness_n_per_m,
            holding: w.model.holding_torque_nm,
            steps_per_rev: w.model.steps_per_rev,
            start: w.start,
        }
    }

    /// Full steps per mm of cable on spool `i`: what `set_scale` takes, so
    /// that positions are mm of cable paid out.
    fn scale(&self, i: usize) -> f64 {
        self.steps_per_rev / (2.0 * std::f64::consts::PI * self.radius[i] * 1e3)
    }

    /// The mass where the cables' lengths put it (least squares, from
    /// `guess`).
    fn locate(&self, lengths: &[f64], guess: [f64; 2]) -> [f64; 2] {
        let mut p = guess;
        for _ in 0..4 {
            // Gauss–Newton on Σ (|p − a| − L)²: J rows are (p − a)/|p − a|.
            let (mut jtj, mut jtr) = ([[0.0; 2]; 2], [0.0; 2]);
            for (a, l) in self.anchors.iter().zip(lengths) {
                let d = dist(*a, p);
                let g = [(p[0] - a[0]) / d, (p[1] - a[1]) / d];
                let r = d - l;
                for i in 0..2 {
                    jtr[i] += g[i] * r;
                    for j in 0..2 {
                        jtj[i][j] += g[i] * g[j];
                    }
                }
            }
            let det = jtj[0][0] * jtj[1][1] - jtj[0][1] * jtj[1][0];
            if det.abs() < 1e-12 {
                break;
            }
            p[0] -= (jtj[1][1] * jtr[0] - jtj[0][1] * jtr[1]) / det;
            p[1] -= (jtj[0][0] * jtr[1] - jtj[1][0] * jtr[0]) / det;
        }
        p
    }

    /// Unit vectors from the mass at `p` to each anchor.
    fn units(&self, p: [f64; 2]) -> Vec<[f64; 2]> {
        self.anchors
            .iter()
            .map(|a| {
                let d = dist(*a, p);
                [(a[0] - p[0]) / d, (a[1] - p[1]) / d]
            })
            .collect()
    }

    /// Tensions that pull the mass at `p` with `force`: `BASE_TENSION` on
    /// each, plus the least-norm correction, within the bounds.
    fn tensions(&self, p: [f64; 2], force: [f64; 2]) -> Vec<f64> {
        let u = self.units(p);
        let base: Vec<f64> = vec![BASE_TENSION; u.len()];
        let mut w = force;
        for (ui, t) in u.iter().zip(&base) {
            w[0] -= ui[0] * t;
            w[1] -= ui[1] * t;
        }
        // t = base + Aᵀ (A Aᵀ)⁻¹ w, A's columns the unit vectors.
        let mut aat = [[0.0; 2]; 2];
        for ui in &u {
            for i in 0..2 {
                for j in 0..2 {
                    aat[i][j] += ui[i] * ui[j];
                }
            }
        }
        let det = aat[0][0] * aat[1][1] - aat[0][1] * aat[1][0];
        let y = [
            (aat[1][1] * w[0] - aat[0][1] * w[1]) / det,
            (aat[0][0] * w[1] - aat[1][0] * w[0]) / det,
        ];
        u.iter()
            .zip(&base)
            .map(|(ui, t)| (t + ui[0] * y[0] + ui[1] * y[1]).clamp(MIN_TENSION, MAX_TENSION))
            .collect()
    }
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// The figure-eight: position, velocity and acceleration at `t` s after
/// it starts; its phase speeds up over `RAMP_S`, runs the laps, and slows
/// down over `RAMP_S` to stand at the centre.
struct Path {
    centre: [f64; 2],
    half: [f64; 2],
    omega: f64,
    cruise: f64,
}

impl Path {
    fn new(centre: [f64; 2], args: &Args) -> Path {
        let omega = 2.0 * std::f64::consts::PI / args.period_s;
        Path {
            centre,
            half: [args.width_mm * 0.5e-3, args.height_mm * 0.5e-3],
            omega,
            cruise: f64::from(args.laps) * args.period_s - RAMP_S,
        }
    }

    /// Seconds from start to standing again.
    fn duration(&self) -> f64 {
        2.0 * RAMP_S + self.cruise
    }

    /// The phase and its two derivatives.
    fn phase(&self, t: f64) -> (f64, f64, f64) {
        let (w, r, c) = (self.omega, RAMP_S, self.cruise);
        if t <= 0.0 {
            (0.0, 0.0, 0.0)
        } else if t < r {
            (w * t * t / (2.0 * r), w * t / r, w / r)
        } else if t <= r + c {
            (w * (t - r / 2.0), w, 0.0)
        } else if t < 2.0 * r + c {
            let s = t - r - c;
            (
                w * (r / 2.0 + c) + w * (s - s * s / (2.0 * r)),
                w * (1.0 - s / r),
                -w / r,
            )
        } else {
            (w * (r + c), 0.0, 0.0)
        }
    }

    /// `x = cx + A sin φ`, `y = cy + B sin 2φ`, with their derivatives.
    fn at(&self, t: f64) -> ([f64; 2], [f64; 2], [f64; 2]) {
        let (ph, dph, ddph) = self.phase(t);
        let [a, b] = self.half;
        let (s1, c1, s2, c2) = (ph.sin(), ph.cos(), (2.0 * ph).sin(), (2.0 * ph).cos());
        let pos = [self.centre[0] + a * s1, self.centre[1] + b * s2];
        let vel = [a * c1 * dph, 2.0 * b * c2 * dph];
        let acc = [
            a * (c1 * ddph - s1 * dph * dph),
            2.0 * b * (c2 * ddph - 2.0 * s2 * dph * dph),
        ];
        (pos, vel, acc)
    }
}

/// One module's two functions the loop uses.
struct Motor {
    read: FunctionHandle,
    torque: FunctionHandle,
}

async fn call(
    m: &Manager,
    module: &str,
    function: &str,
    args: &[Value<'static>],
) -> Result<(), BoxError> {
    m.function(&FnRef::new(module, function))?
        .call(args)
        .await
        .map_err(|e| format!("{module}.{function}: {e}"))?;
    Ok(())
}

/// Cable paid out on each spool since boot, m (four reads at once).
async fn read_lengths(motors: &[Motor]) -> Result<Vec<f64>, BoxError> {
    let reads = motors.iter().map(|m| m.read.call(&[]));
    let mut out = Vec::with_capacity(motors.len());
    for r in join_all(reads).await {
        match r?.get(1) {
            Some(Value::F32(mm)) => out.push(f64::from(*mm) * 1e-3),
            other => return Err(format!("get_position answered {other:?}").into()),
        }
    }
    Ok(out)
}

/// Sends each motor its fraction of holding torque (all at once).
async fn send_torques(motors: &[Motor], fractions: &[f64]) -> Result<(), BoxError> {
    let args: Vec<[Value<'static>; 1]> = fractions
        .iter()
        .map(|f| [Value::F32(f.clamp(-1.0, 1.0) as f32)])
        .collect();
    let sends = motors.iter().zip(&args).map(|(m, a)| m.torque.call(a));
    for r in join_all(sends).await {
        r?;
    }
    Ok(())
}

/// The tracking error's summary, mm.
#[derive(Default)]
struct Errors {
    sum_sq: f64,
    n: usize,
    max: f64,
}

impl Errors {
    fn add(&mut self, e: f64) {
        self.sum_sq += e * e;
        self.n += 1;
        self.max = self.max.max(e);
    }

    fn rms(&self) -> f64 {
        (self.sum_sq / self.n.max(1) as f64).sqrt()
    }
}

async fn run(args: Args) -> Result<(), BoxError> {
    let spec = SimSpec::load(&args.topology)?;
    let winch = Winch::new(
        spec.winch
            .as_ref()
            .ok_or_else(|| format!("{}: no [winch]", args.topology.display()))?,
    );
    let names: Vec<String> = spec
        .winch
        .iter()
        .flat_map(|w| w.spools.iter().map(|s| s.module.clone()))
        .collect();
    let host = Host::start(HostConfig::named("winch"))?;
    let time = if args.fast {
        TimeMode::Virtual
    } else {
        TimeMode::RealTime
    };
    let sim = SimMachine::start_with(&host, &spec, time).await?;
    let mut m = Manager::new(&host).await?;
    let report = m.refresh().await?;
    if !report.scan_failures.is_empty() {
        return Err(format!("scan: {:?}", report.scan_failures).into());
    }
    let plant = sim.winch().ok_or("the simulator has no winch")?.clone();

    // Cable lengths in mm, 16 microsteps (the step input holds with them
    // before and after the torque), powered, watched.
    for (i, name) in names.iter().enumerate() {
        call(&m, name, "set_microsteps", &[Value::U16(16)]).await?;
        call(&m, name, "set_scale", &[Value::F32(winch.scale(i) as f32)]).await?;
        call(&m, name, "set_enable", &[Value::Bool(true)]).await?;
        call(&m, name, "set_output_watchdog", &[Value::U32(WATCHDOG_MS)]).await?;
    }
    let motors: Vec<Motor> = names
        .iter()
        .map(|n| -> Result<Motor, BoxError> {
            Ok(Motor {
                read: m.function(&FnRef::new(n, "get_position"))?,
                torque: m.function(&FnRef::new(n, "set_torque"))?,
            })
        })
        .collect::<Result<_, _>>()?;
    println!(
        "winch: {} cables, {:.2} kg, figure-eight {:.0} × {:.0} mm, {} laps of {:.1} s",
        names.len(),
        winch.mass,
        args.width_mm,
        args.height_mm,
        args.laps,
        args.period_s
    );

    let path = Path::new(winch.start, &args);
    let settle = 1.0;
    let clock = tokio::time::Instant::now();
    let wall = std::time::Instant::now();
    let mut tensions = vec![BASE_TENSION; names.len()];
    let mut p_est = winch.start;
    let mut v_est = [0.0; 2];
    let mut last: Option<(f64, [f64; 2])> = None;
    let (mut errors, mut est_errors) = (Errors::default(), Errors::default());
    let mut cycles = 0u32;
    let mut ticker = tokio::time::interval(Duration::from_secs_f64(CYCLE_S));
    ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let total = settle + path.duration() + 0.5;
    loop {
        ticker.tick().await;
        let t = clock.elapsed().as_secs_f64();
        if t > total {
            break;
        }
        let paid = read_lengths(&motors).await?;
        let now = clock.elapsed().as_secs_f64();
        // Each cable's straight length: its free length plus its stretch
        // under the tension it was last asked for.
        let lengths: Vec<f64> = (0..paid.len())
            .map(|i| winch.lengths0[i] + paid[i] + tensions[i] / winch.stiffness)
            .collect();
        p_est = winch.locate(&lengths, p_est);
        if let Some((t0, p0)) = last {
            let dt = now - t0;
            if dt > 0.0 {
                // A first-order filter of 10 ms over the encoder's 5 µm.
                let k = (dt / 0.010).min(1.0);
                for i in 0..2 {
                    v_est[i] += ((p_est[i] - p0[i]) / dt - v_est[i]) * k;
                }
            }
        }
        last = Some((now, p_est));

        let (pr, vr, ar) = path.at(now - settle);
        let mut force = [0.0; 2];
        for i in 0..2 {
            let e = pr[i] - p_est[i];
            let de = vr[i] - v_est[i];
            force[i] = winch.mass * (ar[i] + KP * e + KD * de);
        }
        force[1] += winch.mass * winch.gravity;
        tensions = winch.tensions(p_est, force);
        // Each spool's torque: its tension, plus what its inertia and
        // friction take to follow the path's cable speed.
        let u = winch.units(pr);
        let fractions: Vec<f64> = (0..tensions.len())
            .map(|i| {
                let r = winch.radius[i];
                let l = dist(winch.anchors[i], pr);
                let ud = u[i][0] * vr[0] + u[i][1] * vr[1];
                let ua = u[i][0] * ar[0] + u[i][1] * ar[1];
                let v2 = vr[0] * vr[0] + vr[1] * vr[1];
                // The cable pays out at −u·v; its acceleration adds the
                // turning of u.
                let speed = -ud / r;
                let accel = (-ua + (v2 - ud * ud) / l) / r;
                let torque = -r * tensions[i]
                    + winch.inertia[i] * accel
                    + winch.friction[i] * (speed / 0.01).tanh()
                    + winch.viscous[i] * speed;
                torque / winch.holding
            })
            .collect();
        send_torques(&motors, &fractions).await?;
        cycles += 1;

        if now >= settle && now <= settle + path.duration() {
            let truth = plant.now().position();
            errors.add(dist(truth, pr) * 1e3);
            est_errors.add(dist(p_est, pr) * 1e3);
        }
    }
    let machine_s = clock.elapsed().as_secs_f64();

    // The torque ends: each motor holds where its shaft is.
    for name in &names {
        call(&m, name, "torque_off", &[]).await?;
    }
    let held = plant.now().position();
    tokio::time::sleep(Duration::from_millis(500)).await;
    let after = plant.now().position();
    println!(
        "control: {cycles} cycles in {machine_s:.2} s machine time ({:.1} ms each), {:.2} s wall",
        machine_s / f64::from(cycles.max(1)) * 1e3,
        wall.elapsed().as_secs_f64()
    );
    println!(
        "tracking error (true mass to path): rms {:.2} mm, max {:.2} mm",
        errors.rms(),
        errors.max
    );
    println!(
        "estimate to path (what the loop saw): rms {:.2} mm, max {:.2} mm",
        est_errors.rms(),
        est_errors.max
    );
    println!(
        "torque off: the motors hold; the mass moved {:.2} mm in 0.5 s",
        dist(held, after) * 1e3
    );
    if errors.n == 0 {
        return Err("no cycle fell within the path".into());
    }
    if errors.rms() > args.max_rms_mm || errors.max > args.max_mm {
        return Err(format!(
            "tracking error past its bounds: rms {:.2} mm (at most {}), max {:.2} mm (at most {})",
            errors.rms(),
            args.max_rms_mm,
            errors.max,
            args.max_mm
        )
        .into());
    }
    Ok(())
}

fn main() -> ExitCode {
    let args = Args::parse();
    if args.fast {
        return osap_examples::run_virtual(run(args));
    }
    osap_examples::init_logging();
    let runtime = match tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
    {
        Ok(r) => r,
        Err(e) => {
            eprintln!("error: cannot start the runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    osap_examples::exit_code(runtime.block_on(run(args)))
}
