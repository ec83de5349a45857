//! A machine script: a xylophone player (`examples/machines/xylophone.toml`).
//!
//! Two mallets ride one-DOF axes (x in front of the bars, y behind them),
//! each carriage on its own stepper module; a strike solenoid on each
//! carriage hangs on a digital pin of a small I/O module. Eight bars, one
//! octave, lie at 20 + 22·i mm along both rails.
//!
//! The script homes the mallets, then takes lines on a TCP control socket
//! (127.0.0.1, `--listen` port):
//!
//! ```text
//! note 3        strike bar 3
//! chord 1 5     strike bars 1 and 5 together (one mallet each)
//! rest 250      wait 250 ms
//! quit          stop playing (the script checks the strikes and exits)
//! ```
//!
//! Each note takes the mallet that can strike it soonest (the nearer one,
//! unless it is still striking and the other gets there first), moves it
//! over the bar (`goto_now`), and fires its solenoid with a pulse timed by
//! the modules' synchronized clock (`pulse_at(t, pin, 15 ms)`), a little
//! after the mallet stands there; a chord fires both at the same time.
//!
//! `--feed-self` plays a short tune to its own socket from a child process
//! (this binary with `--play-to ADDR`) and quits after it, so the script
//! runs alone (CI). On simulated modules it then reads the solenoid pins
//! the modules drove and the steps their motors took, and checks that
//! every strike fired, when it was scheduled (the timing error in
//! synchronized µs), over its bar.
//!
//! ```text
//! cargo run -p osap-examples --bin xylophone -- --feed-self --listen 0
//! cargo run -p osap-examples --bin xylophone -- --listen 7878 &
//! printf 'note 0\nchord 2 4\nnote 7\nquit\n' | nc 127.0.0.1 7878
//! ```

use std::error::Error;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Duration;

use clap::Parser;
use osap_host::som::Value;
use osap_machine::config::{MachineFile, Output};
use osap_machine::machine::Link;
use osap_machine::Machine;
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{watch, Mutex};

type BoxError = Box<dyn Error + Send + Sync>;

#[derive(Parser, Debug)]
#[command(about = "Play a xylophone with two mallets, taking notes on a TCP control socket")]
struct Args {
    /// The machine file.
    #[arg(long, default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/machines/xylophone.toml"))]
    machine: PathBuf,
    /// The control socket's port on 127.0.0.1 (0: any free port).
    #[arg(long, default_value_t = 7878)]
    listen: u16,
    /// Play `--tune` to the control socket from a child process, then quit.
    #[arg(long)]
    feed_self: bool,
    /// Send `--tune` to the xylophone whose control socket is at ADDR, then
    /// quit it (no machine here: a client).
    #[arg(long, value_name = "ADDR")]
    play_to: Option<String>,
    /// The tune: commands separated by `;`.
    #[arg(long, default_value = TUNE)]
    tune: String,
    /// Drive hardware over this serial port instead of simulating.
    #[arg(long)]
    port: Option<String>,
    /// The serial port's baud rate (USB CDC ignores it).
    #[arg(long, default_value_t = 115_200)]
    baud: u32,
    /// Drive hardware over a TCP link (e.g. `osap serve`) instead of
    /// simulating.
    #[arg(long)]
    tcp: Option<String>,
}

/// Twinkle, twinkle (C C G G A A G, F F E E D D C), ending on a chord.
const TUNE: &str = "note 0; note 0; note 4; note 4; note 5; note 5; note 4; rest 200; \
                    note 3; note 3; note 2; note 2; note 1; note 1; chord 0 7";

/// The bars: eight, one octave.
const NOTES: [&str; 8] = ["C", "D", "E", "F", "G", "A", "B", "C'"];
/// Where bar `i` is along both rails, mm.
fn bar(i: usize) -> f64 {
    20.0 + 22.0 * i as f64
}
/// The mallets: (axis, tool whose output is its solenoid).
const MALLETS: [(&str, &str); 2] = [("x", "mallet_x"), ("y", "mallet_y")];
/// How long a strike drives its solenoid, µs.
const STRIKE_US: u32 = 15_000;
/// How far ahead of now a strike is scheduled, µs: room for the call to
/// reach the module.
const STRIKE_LEAD_US: u64 = 20_000;
/// How long a mallet rests after its strike before it moves again, µs.
const RECOIL_US: u64 = 20_000;
/// Mallet travel speed, mm/s.
const TRAVEL: f64 = 400.0;
/// The most timing error (µs) and distance from the bar (mm) a strike may
/// have for the check to pass. 10 ms is about where an ear starts to hear
/// two strikes of a chord apart; the simulated modules, sharing the host's
/// cores in real time, wake a few ms late when the host is busy.
const MAX_TIMING_ERROR_US: i64 = 10_000;
const MAX_OFF_BAR_MM: f64 = 0.1;

/// A mallet: its axis and solenoid.
struct Mallet {
    axis: String,
    /// The axis's index in machine positions.
    k: usize,
    /// The solenoid's module (a key of `[modules]`) and pin.
    module: String,
    pin: u8,
    /// When its last strike ends, synchronized µs.
    busy_until: u64,
    velocity: f64,
    acceleration: f64,
}

impl Mallet {
    /// Roughly how long the mallet takes to travel `d` mm.
    fn travel_us(&self, d: f64) -> u64 {
        let (v, a) = (self.velocity.min(TRAVEL), self.acceleration);
        let s = if d < v * v / a {
            2.0 * (d / a).sqrt()
        } else {
            d / v + v / a
        };
        (s * 1e6) as u64
    }
}

/// A strike, as scheduled.
struct Strike {
    note: usize,
    mallet: usize,
    /// Synchronized µs.
    at: u64,
}

struct Player {
    machine: Machine,
    mallets: Vec<Mallet>,
    strikes: Vec<Strike>,
}

impl Player {
    fn new(machine: Machine) -> Result<Player, BoxError> {
        let cfg = machine.config();
        let axes = machine.axes();
        let mut mallets = Vec::new();
        for (axis, tool) in MALLETS {
            let t = cfg
                .tools
                .get(tool)
                .ok_or_else(|| format!("the machine file has no [tools.{tool}]"))?;
            let Output::Digital(pin) = t.output else {
                return Err(format!("tools.{tool}: the solenoid needs a digital output").into());
            };
            let a = &cfg.axes[axis];
            mallets.push(Mallet {
                axis: axis.to_string(),
                k: axes
                    .iter()
                    .position(|n| n == axis)
                    .ok_or_else(|| format!("the machine has no axis {axis}"))?,
                module: t.module.clone(),
                pin,
                busy_until: 0,
                velocity: a.velocity,
                acceleration: a.acceleration,
            });
        }
        Ok(Player {
            machine,
            mallets,
            strikes: Vec::new(),
        })
    }

    /// Runs one command line; the reply.
    async fn command(&mut self, line: &str) -> Result<String, BoxError> {
        let words: Vec<&str> = line.split_whitespace().collect();
        let numbers = |w: &[&str]| -> Result<Vec<usize>, BoxError> {
            w.iter()
                .map(|n| match n.parse::<usize>() {
                    Ok(i) if i < NOTES.len() => Ok(i),
                    _ => Err(format!("{n:?} is not a bar (0 to {})", NOTES.len() - 1).into()),
                })
                .collect()
        };
        match words.as_slice() {
            ["note", n] => self.play(&numbers(&[n])?).await,
            ["chord", a, b] => self.play(&numbers(&[a, b])?).await,
            ["rest", ms] => {
                let ms: u64 = ms.parse().map_err(|_| format!("rest {ms:?}: give ms"))?;
                tokio::time::sleep(Duration::from_millis(ms.min(10_000))).await;
                Ok(format!("rested {ms} ms"))
            }
            _ => Err("unknown command; use note N, chord A B, rest MS or quit".into()),
        }
    }

    /// Strikes `notes` (one, or two together).
    async fn play(&mut self, notes: &[usize]) -> Result<String, BoxError> {
        if notes.len() == 2 && notes[0] == notes[1] {
            return Err("a chord needs two different bars".into());
        }
        let m = &self.machine;
        let pos = m.position();
        let now = m.now_us().await?;
        // Which mallet strikes which note: whichever can strike soonest.
        let ready = |k: usize, note: usize| {
            let mallet = &self.mallets[k];
            let free = mallet.busy_until.saturating_sub(now);
            free + mallet.travel_us((bar(note) - pos[mallet.k]).abs())
        };
        let pairs: Vec<(usize, usize)> = match *notes {
            [n] => vec![(n, if ready(0, n) <= ready(1, n) { 0 } else { 1 })],
            [a, b] => {
                if ready(0, a).max(ready(1, b)) <= ready(1, a).max(ready(0, b)) {
                    vec![(a, 0), (b, 1)]
                } else {
                    vec![(a, 1), (b, 0)]
                }
            }
            _ => return Err("one note or two".into()),
        };
        // Wait for the mallets still striking, then move them over the bars.
        let free_at = pairs
            .iter()
            .map(|&(_, k)| self.mallets[k].busy_until)
            .max()
            .unwrap_or(0);
        if free_at > now {
            tokio::time::sleep(Duration::from_micros(free_at - now)).await;
        }
        let mut target = pos.clone();
        for &(note, k) in &pairs {
            target[self.mallets[k].k] = bar(note);
        }
        if target.iter().zip(&pos).any(|(t, p)| (t - p).abs() > 1e-6) {
            m.goto_now(&target, TRAVEL).await?;
        }
        // Strike: a pulse at one synchronized time, a little ahead.
        let at = m.now_us().await? + STRIKE_LEAD_US;
        let mut reply = Vec::new();
        for &(note, k) in &pairs {
            let mallet = &mut self.mallets[k];
            m.call(
                &mallet.module,
                "pulse_at",
                &[Value::U64(at), Value::U8(mallet.pin), Value::U32(STRIKE_US)],
            )
            .await?;
            mallet.busy_until = at + u64::from(STRIKE_US) + RECOIL_US;
            self.strikes.push(Strike {
                note,
                mallet: k,
                at,
            });
            reply.push(format!(
                "{} ({}) with mallet {} at {:.1} mm",
                note,
                NOTES[note],
                mallet.axis,
                bar(note)
            ));
        }
        let played = format!("played {} at t = {at} µs", reply.join(" and "));
        println!("{played}");
        Ok(played)
    }
}

/// Serves one control connection until it closes or quits.
async fn serve(
    stream: TcpStream,
    player: Arc<Mutex<Player>>,
    quit: watch::Sender<bool>,
) -> Result<(), BoxError> {
    let (read, mut write) = stream.into_split();
    let mut lines = BufReader::new(read).lines();
    while let Some(line) = lines.next_line().await? {
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        if line == "quit" {
            write.write_all(b"bye\n").await?;
            quit.send_replace(true);
            return Ok(());
        }
        let reply = match player.lock().await.command(line).await {
            Ok(r) => r,
            Err(e) => format!("error: {e}"),
        };
        write.write_all(format!("{reply}\n").as_bytes()).await?;
    }
    Ok(())
}

/// The xylophone: home, play what the socket says, check the strikes.
async fn run(args: Args) -> Result<(), BoxError> {
    let cfg = MachineFile::load(&args.machine)?;
    let links: Vec<Link> = args
        .port
        .iter()
        .map(|p| Link::Serial {
            path: p.clone(),
            baud: args.baud,
        })
        .chain(args.tcp.iter().map(|a| Link::Tcp(a.clone())))
        .collect();
    let started = std::time::Instant::now();
    let m = if links.is_empty() {
        Machine::simulate(&cfg).await?
    } else {
        Machine::connect(&cfg, &links).await?
    };
    println!(
        "xylophone up after {:.1} s: mallets on axes {}",
        started.elapsed().as_secs_f64(),
        m.axes().join(", ")
    );
    let mut events = m.events();
    tokio::spawn(async move {
        use osap_machine::MachineEvent as E;
        while let Ok(e) = events.recv().await {
            match e {
                E::Homed { .. } | E::State(_) => {}
                E::Limit { pressed: false, .. } | E::Limit { expected: true, .. } => {}
                e => println!("event: {e:?}"),
            }
        }
    });
    m.home().await?;
    println!("homed: mallets at {:?} mm", m.position());

    let listener = TcpListener::bind(("127.0.0.1", args.listen)).await?;
    let addr = listener.local_addr()?;
    println!("listening on {addr}: note N, chord A B, rest MS, quit");
    let player = Arc::new(Mutex::new(Player::new(m.clone())?));
    let (quit, mut quitting) = watch::channel(false);
    let mut feeder = if args.feed_self {
        let mut child = std::process::Command::new(std::env::current_exe()?)
            .args(["--play-to", &addr.to_string(), "--tune", &args.tune])
            .spawn()?;
        Some(tokio::task::spawn_blocking(move || child.wait()))
    } else {
        None
    };
    let playing = std::time::Instant::now();
    loop {
        tokio::select! {
            accepted = listener.accept() => {
                let (stream, peer) = accepted?;
                let (player, quit) = (player.clone(), quit.clone());
                tokio::spawn(async move {
                    if let Err(e) = serve(stream, player, quit).await {
                        eprintln!("control connection {peer}: {e}");
                    }
                });
            }
            _ = quitting.changed() => break,
            status = async { feeder.as_mut().expect("guarded").await }, if feeder.is_some() => {
                feeder = None;
                let status = status??;
                if !status.success() {
                    return Err(format!("the tune player failed ({status})").into());
                }
            }
        }
    }
    if let Some(f) = feeder {
        let status = f.await??;
        if !status.success() {
            return Err(format!("the tune player failed ({status})").into());
        }
    }
    let played = playing.elapsed().as_secs_f64();

    // Let the last strike end, then check them on the simulated modules.
    let player = player.lock().await;
    let end = player
        .mallets
        .iter()
        .map(|k| k.busy_until)
        .max()
        .unwrap_or(0);
    let now = m.now_us().await?;
    if end > now {
        tokio::time::sleep(Duration::from_micros(end - now)).await;
    }
    println!("played {} strikes in {played:.1} s", player.strikes.len());
    let checked = check(&m, &cfg, &player);
    m.clone().stop().await?;
    checked
}

/// Checks every strike on the simulated modules: the solenoid's pin went
/// high when the strike was scheduled (synchronized time, as the host
/// clock saw it) for `STRIKE_US`, with its mallet over the bar.
fn check(m: &Machine, cfg: &MachineFile, player: &Player) -> Result<(), BoxError> {
    let report = m.with_sim(|sim| -> Result<(i64, f64), BoxError> {
        let mut worst_us = 0i64;
        let mut worst_mm = 0.0f64;
        let mut rows = Vec::new();
        for (k, mallet) in player.mallets.iter().enumerate() {
            let name = osap_machine::sim::module_name(cfg, &mallet.module)
                .ok_or("no such module")?;
            let io = sim.module(name).ok_or("no simulated module")?;
            let writes = io
                .module()
                .ok_or("no module logic")?
                .lock(|mm| mm.board().pins().writes().to_vec());
            let pin: Vec<_> = writes.iter().filter(|w| w.pin == mallet.pin).collect();
            // The mallet's carriage, from its motor's steps.
            let form = osap_machine::sim::axis_form(cfg, &mallet.axis)?;
            let motors: Vec<_> = form
                .terms
                .iter()
                .map(|(name, _)| {
                    let sm = sim.module(name).ok_or("no simulated motor module")?;
                    let edges = sm
                        .module()
                        .ok_or("no module logic")?
                        .lock(|mm| mm.board().motor().edges().to_vec());
                    let timed: Vec<(u64, f64)> = edges
                        .iter()
                        .map(|e| (sm.host_time_at(e.local).as_micros(), e.position))
                        .collect();
                    Ok::<_, BoxError>((name.clone(), timed))
                })
                .collect::<Result<_, _>>()?;
            let at_time = |t: u64| {
                form.value(|module| {
                    motors
                        .iter()
                        .find(|(n, _)| n == module)
                        .map_or(f64::NAN, |(_, e)| {
                            let i = e.partition_point(|s| s.0 <= t);
                            if i == 0 {
                                0.0
                            } else {
                                e[i - 1].1
                            }
                        })
                })
            };
            let strikes: Vec<&Strike> = player.strikes.iter().filter(|s| s.mallet == k).collect();
            let rises: Vec<_> = pin
                .iter()
                .enumerate()
                .filter(|(_, w)| w.level)
                .map(|(i, w)| (w.local, pin.get(i + 1).map(|f| f.local)))
                .collect();
            if rises.len() != strikes.len() {
                return Err(format!(
                    "mallet {}: {} strikes scheduled, the solenoid fired {} times",
                    mallet.axis,
                    strikes.len(),
                    rises.len()
                )
                .into());
            }
            for (s, (rise, fall)) in strikes.iter().zip(&rises) {
                let struck = io.host_time_at(*rise).as_micros();
                let error = struck as i64 - s.at as i64;
                // The pulse's end, against its scheduled end.
                let end = s.at + u64::from(STRIKE_US);
                let end_error = fall.map_or(i64::MAX, |f| io.host_time_at(f).as_micros() as i64 - end as i64);
                let over = at_time(struck);
                let off = (over - bar(s.note)).abs();
                rows.push((s.at, format!(
                    "  {:<2} ({:<2}) mallet {}: scheduled {} µs, struck {} µs, error {:+} µs, released {:+} µs off, mallet at {:.3} mm (bar {:.1})",
                    s.note,
                    NOTES[s.note],
                    mallet.axis,
                    s.at,
                    struck,
                    error,
                    end_error,
                    over,
                    bar(s.note)
                )));
                worst_us = worst_us.max(error.abs()).max(end_error.saturating_abs());
                worst_mm = worst_mm.max(off);
            }
        }
        rows.sort();
        for (_, row) in rows {
            println!("{row}");
        }
        Ok((worst_us, worst_mm))
    });
    let Some(report) = report else {
        println!("(on hardware: strikes not checked)");
        return Ok(());
    };
    let (worst_us, worst_mm) = report?;
    println!(
        "checked {} strikes: all fired, timing error at most {worst_us} µs, mallets within {worst_mm:.3} mm of their bars",
        player.strikes.len()
    );
    if worst_us > MAX_TIMING_ERROR_US {
        return Err(format!("a strike was {worst_us} µs off its time").into());
    }
    if worst_mm > MAX_OFF_BAR_MM {
        return Err(format!("a mallet struck {worst_mm:.3} mm off its bar").into());
    }
    Ok(())
}

/// The client: sends the tune, line by line, then `quit`.
async fn play_to(addr: &str, tune: &str) -> Result<(), BoxError> {
    let stream = TcpStream::connect(addr).await?;
    let (read, mut write) = stream.into_split();
    let mut replies = BufReader::new(read).lines();
    let lines = tune
        .split(';')
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .chain(["quit"]);
    for line in lines {
        write.write_all(format!("{line}\n").as_bytes()).await?;
        let reply = replies
            .next_line()
            .await?
            .ok_or("the xylophone closed the connection")?;
        println!("tune: {line} -> {reply}");
        if reply.starts_with("error") {
            return Err(format!("{line}: {reply}").into());
        }
    }
    Ok(())
}

fn main() -> ExitCode {
    osap_examples::init_logging();
    let args = Args::parse();
    let result = if let Some(addr) = args.play_to.clone() {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .map_err(BoxError::from)
            .and_then(|rt| rt.block_on(play_to(&addr, &args.tune)))
    } else {
        tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .map_err(BoxError::from)
            .and_then(|rt| rt.block_on(run(args)))
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("xylophone: {e}");
            ExitCode::FAILURE
        }
    }
}
