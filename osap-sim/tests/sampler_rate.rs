//! How fast a module can sample in blocks (osap-module's `sample_block`)
//! over its link, in the discrete-event simulator: µs timers, the link
//! models' wire time, USB frames and each node's main-loop latency.
//!
//! A module runs `sample_block` on its timer over `get_position` and
//! `analog_read(0)` (a motor's position and a sensor: 38 bytes a sample),
//! piped to a probe on the host; every block's number and first sample
//! index say what arrived. `blocks_over_a_uart_lose_nothing_at_1_khz`
//! checks that; the ignored `highest_lossless_rate` prints the rates a
//! 1 Mbaud UART (behind a hub on USB, as the plotter's modules) and a
//! direct USB link take:
//!
//! ```text
//! cargo test -p osap-sim --test sampler_rate -- --ignored --nocapture
//! ```

use osap_core::codec::{Reader, Writer};
use osap_core::route::Route;
use osap_core::transport::Transport;
use osap_core::Instant;
use osap_module::board::{Board, IoHw, StepperHw};
use osap_module::functions::{FnId, ModuleFn, ALL};
use osap_module::ports::{ModuleFunction, SamplerFunction};
use osap_module::{Module, ModuleHandle};
use osap_sim::medium::UsbParams;
use osap_sim::probe::ProbePort;
use osap_sim::{LinkModel, Network, NodeSpec, Sim, SimConfig};
use pipes_core::control::{InputMode, OutputMode};
use pipes_core::pipe::PipeConfig;
use pipes_core::{Args, ArgsWriter, Message, MessageKey, Value};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

const S: u64 = 1_000_000_000;

struct Driver;

impl StepperHw for Driver {
    fn set_enable(&mut self, _on: bool) {}
    fn set_microsteps(&mut self, microsteps: u16) -> bool {
        microsteps <= 256
    }
}

struct Pins;

impl IoHw for Pins {
    fn digital_pins(&self) -> u8 {
        8
    }
    fn write_digital(&mut self, _pin: u8, _level: bool) {}
    fn read_digital(&mut self, _pin: u8) -> bool {
        false
    }
    fn pwm_outputs(&self) -> u8 {
        2
    }
    fn write_pwm(&mut self, _channel: u8, _duty: u16) {}
    fn read_pwm(&self, _channel: u8) -> u16 {
        0
    }
    fn analog_inputs(&self) -> u8 {
        1
    }
    fn read_analog(&mut self, _channel: u8) -> u16 {
        40_000
    }
}

/// A board whose clock is the simulated node's: the port sets it on each
/// poll.
struct DesBoard {
    now: Arc<AtomicU64>,
    driver: Driver,
    pins: Pins,
}

impl Board for DesBoard {
    fn stepper(&mut self) -> &mut dyn StepperHw {
        &mut self.driver
    }
    fn io(&mut self) -> Option<&mut dyn IoHw> {
        Some(&mut self.pins)
    }
    fn now(&self) -> Instant {
        Instant::from_micros(self.now.load(Ordering::Relaxed))
    }
}

#[derive(Clone)]
struct Handle(Arc<Mutex<Module<DesBoard>>>);

impl ModuleHandle for Handle {
    type Board = DesBoard;
    fn with<R>(&self, f: impl FnOnce(&mut Module<DesBoard>) -> R) -> Option<R> {
        Some(f(&mut self.0.lock().unwrap()))
    }
}

/// One of the module's function ports, its board's clock kept on the
/// node's.
struct Clocked<P> {
    p: P,
    now: Arc<AtomicU64>,
}

impl<P: osap_core::port::Port> osap_core::port::Port for Clocked<P> {
    fn port_count(&self) -> u16 {
        self.p.port_count()
    }
    fn info(&self, offset: u16) -> osap_core::port::PortInfo<'_> {
        self.p.info(offset)
    }
    fn on_packet(
        &mut self,
        d: osap_core::port::Delivery<'_>,
        tx: &mut osap_core::port::PortTx<'_>,
    ) {
        self.now.store(tx.now().as_micros(), Ordering::Relaxed);
        self.p.on_packet(d, tx);
    }
    fn poll(&mut self, tx: &mut osap_core::port::PortTx<'_>) {
        self.now.store(tx.now().as_micros(), Ordering::Relaxed);
        self.p.poll(tx);
    }
    fn wake_at(&self) -> Option<Instant> {
        self.p.wake_at()
    }
}

fn index(id: FnId) -> u8 {
    ALL.iter().position(|f| *f == id).unwrap() as u8
}

/// What the host received.
#[derive(Debug, Default)]
struct Tally {
    /// Datagrams received.
    datagrams: u64,
    /// Samples received.
    received: u64,
    /// Samples the module took but the host never received.
    lost: u64,
    /// Samples the module took.
    taken: u64,
}

/// How the module sends its samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Path {
    /// `sample_block`: a block of samples a datagram.
    Blocks,
    /// Each function on its own timer and pipe: a datagram a sample of
    /// each (captures before blocks).
    PerSample,
}

/// The two sources: a motor's position and a sensor.
const SOURCES: [FnId; 2] = [FnId::get_position, FnId::analog_read];

/// A push of `values` to inputs 0.. (a pipe datagram, raw).
fn push(values: &[Value<'_>]) -> Vec<u8> {
    let mut buf = [0u8; 128];
    let h = Transport::Raw.encode(&mut buf).unwrap();
    let mut w = Writer::new(&mut buf[h..]);
    let mut a = ArgsWriter::message(&mut w, MessageKey::PipeDatagram).unwrap();
    for (i, v) in values.iter().enumerate() {
        a.push(i as u8, v).unwrap();
    }
    a.finish().unwrap();
    let n = h + w.len();
    buf[..n].to_vec()
}

/// Runs the sources every `period_us` for `seconds` on module `m1` of
/// `net`, piped to a probe on the host along `route` (the links from the
/// module to the host; `to_m1` the links back), and tallies what arrived.
fn run(
    net: &Network,
    route: &[u8],
    to_m1: &[u8],
    path: Path,
    period_us: u32,
    seconds: f64,
) -> Tally {
    let mut sim = Sim::new(net, SimConfig::seeded(7)).unwrap();
    let host = sim.node_index("host").unwrap();
    let m1 = sim.node_index("m1").unwrap();
    let probe = sim.node_mut(host).add_port(Box::new(ProbePort::default()));
    let now = Arc::new(AtomicU64::new(0));
    let module = Handle(Arc::new(Mutex::new(Module::new(DesBoard {
        now: now.clone(),
        driver: Driver,
        pins: Pins,
    }))));
    let to_m1 = Route::through_links(to_m1).unwrap();
    let to_host = Route::through_links(route).unwrap();
    let mut pushes = Vec::new();
    match path {
        Path::Blocks => {
            let mut f = SamplerFunction::new(ModuleFn::new(FnId::sample_block, module)).unwrap();
            let mut pipe = PipeConfig::new(to_host, probe, 20_000);
            for k in 0..4 {
                pipe.map(k, k).unwrap();
            }
            f.set_pipe(0, pipe).unwrap();
            f.set_output_mode(OutputMode::OnChange);
            f.set_input_mode(InputMode::OnTimer(period_us));
            let port = sim.node_mut(m1).add_port(Box::new(Clocked { p: f, now }));
            let mut values: Vec<Value<'_>> = Vec::new();
            for id in SOURCES {
                values.extend([Value::U8(index(id)), Value::U8(0)]);
            }
            values.extend([
                Value::U8(255),
                Value::U8(0),
                Value::U32(20_000),
                Value::U32(1),
            ]);
            pushes.push((port, push(&values)));
        }
        Path::PerSample => {
            for id in SOURCES {
                let mut f = ModuleFunction::new(ModuleFn::new(id, module.clone())).unwrap();
                let outputs = osap_module::functions::SIGNATURES[id as usize]
                    .outputs
                    .len();
                let mut pipe = PipeConfig::new(to_host, probe, 20_000);
                for k in 0..outputs as u8 {
                    pipe.map(k, k).unwrap();
                }
                f.set_pipe(0, pipe).unwrap();
                f.set_input_mode(InputMode::OnTimer(period_us));
                let inputs = osap_module::functions::SIGNATURES[id as usize].inputs.len();
                let clocked = Clocked {
                    p: f,
                    now: now.clone(),
                };
                let port = sim.node_mut(m1).add_port(Box::new(clocked));
                if inputs > 0 {
                    pushes.push((port, push(&[Value::U8(0)])));
                }
            }
        }
    }
    for (port, payload) in &pushes {
        sim.node_mut(host)
            .port_mut::<ProbePort>(0)
            .unwrap()
            .queue(to_m1, *port, 20_000, payload);
    }
    sim.wake(host, S / 10);
    sim.run_for((seconds * S as f64) as u64);

    let mut t = Tally::default();
    let got = &sim.node(host).port::<ProbePort>(0).unwrap().received;
    match path {
        Path::Blocks => {
            let mut next_first = 0u64;
            for d in got {
                let Some(args) = datagram(&d.payload) else {
                    continue;
                };
                let (Some(Value::U32(seq)), Some(Value::U32(first)), Some(Value::Array(a))) =
                    (args.get(0), args.get(1), args.get(3))
                else {
                    continue;
                };
                if seq == 0 {
                    continue;
                }
                let mut r = Reader::new(a.bytes());
                let mut n = 0u64;
                while !r.is_empty() {
                    r.u32().unwrap();
                    for _ in SOURCES {
                        Args::decode(&mut r).unwrap();
                    }
                    n += 1;
                }
                t.datagrams += 1;
                t.lost += u64::from(first) - next_first;
                t.received += n;
                next_first = u64::from(first) + n;
            }
            let sampler = sim
                .node(m1)
                .port::<Clocked<SamplerFunction<Handle>>>(0)
                .unwrap();
            let taken = sampler
                .p
                .implementation()
                .module()
                .with(|m| m.sampler.taken());
            // The samples after the last block received are in the open
            // block, or in blocks still on their way, or lost at the end:
            // counted to the last block received, as a host counts them
            // before its closing call.
            assert!(u64::from(taken.unwrap()) >= next_first);
            t.taken = next_first;
        }
        Path::PerSample => {
            // A sample is one datagram of each source; the pair's rarer one
            // says how many whole samples arrived.
            let mut per = [0u64; SOURCES.len()];
            let runs: Vec<u64> = (0..SOURCES.len())
                .map(|k| {
                    let f = sim.node(m1).port::<Clocked<ModuleFunction<Handle>>>(k);
                    u64::from(f.unwrap().p.stats().runs)
                })
                .collect();
            for d in got {
                if datagram(&d.payload).is_some() {
                    let k = usize::from((d.source_port - 2) / 3);
                    if k < per.len() {
                        per[k] += 1;
                    }
                }
            }
            t.datagrams = per.iter().sum();
            t.taken = *runs.iter().min().unwrap();
            t.received = *per.iter().min().unwrap();
            t.lost = t.taken.saturating_sub(t.received);
        }
    }
    t
}

/// A raw pipe datagram's arguments.
fn datagram(payload: &[u8]) -> Option<Args<'_>> {
    let (Transport::Raw, body) = Transport::decode(payload).ok()? else {
        return None;
    };
    let msg = Message::parse(body).ok()?;
    (msg.key == MessageKey::PipeDatagram).then_some(msg.args)
}

/// host –USB– hub –UART at `baud`– m1, as the plotter's modules.
fn behind_hub(baud: u32) -> Network {
    Network::new("uart")
        .with_node(NodeSpec::host("host"))
        .with_node(NodeSpec::mcu("hub"))
        .with_node(NodeSpec::mcu("m1"))
        .with_link("host", "hub", LinkModel::usb_cdc())
        .with_link("hub", "m1", LinkModel::uart(baud))
}

/// host –USB– m1.
fn on_usb() -> Network {
    Network::new("usb")
        .with_node(NodeSpec::host("host"))
        .with_node(NodeSpec::mcu("m1"))
        .with_link("host", "m1", LinkModel::UsbCdc(UsbParams::default()))
}

#[test]
fn blocks_over_a_uart_lose_nothing_at_1_khz() {
    let t = run(
        &behind_hub(1_000_000),
        &[0, 0],
        &[0, 1],
        Path::Blocks,
        1_000,
        2.0,
    );
    // 1.9 s of samples at 1 kHz, five to a block.
    assert!(t.taken >= 1_850, "{t:?}");
    assert_eq!(t.lost, 0, "{t:?}");
    assert_eq!(t.received, t.taken, "{t:?}");
    assert_eq!(t.datagrams, t.received / 5, "{t:?}");
}

#[test]
#[ignore = "a table for docs/performance.md"]
fn highest_lossless_rate() {
    let periods = [
        1_000, 800, 667, 571, 500, 400, 333, 250, 200, 167, 125, 100, 80, 67, 50, 40, 30, 20,
    ];
    let cases: [(&str, Network, &[u8], &[u8]); 3] = [
        ("UART 1 Mbaud", behind_hub(1_000_000), &[0, 0], &[0, 1]),
        ("UART 2 Mbaud", behind_hub(2_000_000), &[0, 0], &[0, 1]),
        ("USB", on_usb(), &[0], &[0]),
    ];
    for (name, net, route, to_m1) in &cases {
        for path in [Path::PerSample, Path::Blocks] {
            for &p in &periods {
                let t = run(net, route, to_m1, path, p, 3.0);
                println!(
                    "{name:13} {path:9?} {:6.0} Hz: taken {:6}, received {:6}, lost {:6} ({:.2} %), {} datagrams",
                    1e6 / f64::from(p),
                    t.taken,
                    t.received,
                    t.lost,
                    100.0 * t.lost as f64 / t.taken.max(1) as f64,
                    t.datagrams
                );
            }
        }
    }
}
