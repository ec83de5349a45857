//! The discrete-event simulator ([`crate::Sim`]) runs the [`SimSpec`] the
//! simulated machines ([`crate::machine`]) run, lowered into its network.
//!
//! [`Network::from_spec`] (or `Network::try_from(&spec)`) lowers a spec,
//! [`Network::load`] a topology file (`osap-sim/topologies/*.toml`) and
//! [`Network::from_toml`] a string; [`Scenario::from_spec`] also takes the
//! spec's `seed`. The spec is checked as the machines check it, then:
//!
//! | TOML | discrete-event simulator |
//! |---|---|
//! | the host (`"host"` in a link) | node `host`, node 0: a [`NodeKind::Host`] (`[host] kind = "mcu"`: an MCU), the clock root unless a module has `root = true`, an ideal clock (`[host] clock = "drawn"`: one drawn from the seed), busy spells with `[host] busy = true` |
//! | `[[module]]` | an [`NodeKind::Mcu`] node of the same name, node `i + 1` for the `i`-th module; `root = true` makes it the clock root, `busy = true` gives it [`BusyModel::MOTOR`] |
//! | `rate_ppm`, `offset_us`, `wander_ppm`, `wander_period_s` | its oscillator, fixed; the wander's phase is drawn from the seed (the machines start it at phase 0). `clock = "drawn"` draws the whole oscillator from the seed instead ([`ClockSpec::MCU`]) |
//! | `type` | where a `stepper`'s links go (below); otherwise nothing: every module runs the simulator's plain runtime (no functions, no board) |
//! | `[module.motor]`, `[module.io]` | ignored: the simulator has no boards |
//! | `kind = "usb"` | [`LinkModel::UsbCdc`] ([`UsbParams`] defaults) whose end A, the USB host, is the end named `host`, else `a` (as on the machines) |
//! | `kind = "uart"`, `"rs485"` | [`LinkModel::Uart`], [`LinkModel::Rs485`] at `baud` ([`UartParams`] defaults otherwise) |
//! | `kind = "memory"` | the simulator has no instant link; the closest is a UDP link ([`LinkModel::Udp`]) with no latency at 10 Gbit/s: packets whole, in order, never lost, stamped when read. Scans see the type name `udp`, not `memory` |
//! | `mtu`, `name` | the link's MTU and instance name |
//! | `loss` | the link's frame loss (uart, rs485, usb) |
//! | `jitter_us` | a UART's extra latency per frame, uniform in `[0, jitter_us]` µs |
//! | `corrupt_per_byte` | a UART's byte corruption |
//! | `zero_latency = true` | every link becomes the `memory` model above (and `loss`, `jitter_us`, `corrupt_per_byte` are refused) |
//! | `seed` | not part of a [`Network`]: [`Scenario::from_spec`] runs with it (the `clock_sync_report` binary takes `--seed` instead) |
//! | `sync = false` | refused: every simulated node runs clock sync, which is what the simulator measures |
//!
//! The keys `root`, `busy`, `clock`, `loss`, `jitter_us`, `corrupt_per_byte`
//! and the `[host]` table are for the discrete-event simulator only: the
//! real-time simulated machines accept and ignore them.
//!
//! # Link indices
//!
//! Each node's link indices are those the machine gives it: the host's and a
//! `hub`'s follow the order their links are listed in the file, from 0; a
//! `stepper` has the module firmware's two links, its `usb` link at index 0
//! and its `uart`/`rs485` link at index 1, whatever their order in the file,
//! and the one the file leaves out is there and never opens (an
//! [`Unconnected`](super::Unconnected) gateway: a closed
//! `usb_cdc` at 0 or `uart` at 1), so a stepper reached over its UART has
//! that UART at index 1 in both simulators. The host's indices are its own
//! in the simulator; on a machine they are the [`osap_host::Host`]'s, in
//! the same order after any links it already had
//! ([`SimMachine::host_links`](crate::machine::SimMachine::host_links)).

use super::{NetLink, Network};
use crate::busy::BusyModel;
use crate::clock::{ClockSpec, Param};
use crate::error::SimError;
use crate::medium::{IpParams, LinkModel, Side, UartParams, UsbParams};
use crate::node::{NodeKind, NodeSpec};
use crate::rng::Dist;
use crate::scenario::Scenario;
use crate::topology::graph::firmware_link;
use crate::topology::{
    ClockSource, LinkKind, LinkSpec, ModuleKind, ModuleSpec, SimSpec, FIRMWARE_LINKS, HOST,
};
use std::path::Path;

/// The stand-in for a `memory` link: UDP with no latency at 10 Gbit/s.
fn memory(mtu: u16) -> LinkModel {
    LinkModel::Udp(IpParams {
        latency: Dist::ZERO,
        mtu,
        ..IpParams::LOOPBACK
    })
}

fn link_model(zero_latency: bool, l: &LinkSpec) -> Result<LinkModel, SimError> {
    let mtu = l.mtu();
    if zero_latency {
        if l.loss.is_some() || l.jitter_us.is_some() || l.corrupt_per_byte.is_some() {
            return Err(SimError::config(format!(
                "link {} - {}: zero_latency makes every link instant; remove loss, jitter_us and corrupt_per_byte",
                l.a, l.b
            )));
        }
        return Ok(memory(mtu));
    }
    let loss = l.loss.unwrap_or(0.0);
    let uart = || UartParams {
        baud: l.baud(),
        mtu,
        loss,
        jitter: l.jitter_us.map_or(Dist::ZERO, |j| Dist::uniform(0.0, j)),
        corrupt_per_byte: l.corrupt_per_byte.unwrap_or(0.0),
        ..UartParams::default()
    };
    Ok(match l.kind {
        LinkKind::Usb => LinkModel::UsbCdc(UsbParams {
            mtu,
            loss,
            ..UsbParams::default()
        }),
        LinkKind::Uart => LinkModel::Uart(uart()),
        LinkKind::Rs485 => LinkModel::Rs485(uart()),
        LinkKind::Memory => memory(mtu),
    })
}

fn module_clock(m: &ModuleSpec) -> ClockSpec {
    match m.clock {
        ClockSource::Fixed => ClockSpec {
            offset_us: Param::Fixed(m.offset_us),
            rate_ppm: Param::Fixed(m.rate_ppm),
            wander_ppm: Param::Fixed(m.wander_ppm),
            wander_period_s: Param::Fixed(m.wander_period_s),
        },
        ClockSource::Drawn => ClockSpec::MCU,
    }
}

fn busy(on: bool) -> Option<BusyModel> {
    on.then_some(BusyModel::MOTOR)
}

impl Network {
    /// The discrete-event network a machine topology describes (see the
    /// [module docs](self) for how each key maps). Fails if the machine
    /// topology is invalid, sets `sync = false`, has an RS-485 bus
    /// (`[[bus]]`: not modelled here), or asks for something the
    /// simulator refuses (a node name with whitespace, more than 16 links
    /// on the host).
    pub fn from_spec(m: &SimSpec) -> Result<Network, SimError> {
        m.validate().map_err(|e| SimError::config(e.to_string()))?;
        if !m.sync {
            return Err(SimError::config(format!(
                "topology {:?}: sync = false: the discrete-event simulator always runs clock sync",
                m.name
            )));
        }
        if let Some(bus) = m.buses.first() {
            // Drops reached only over the bus would be islands here, and
            // a clock-sync figure of such a network would be wrong.
            return Err(SimError::config(format!(
                "topology {:?}: the discrete-event simulator models no RS-485 bus ([[bus]] \
                 with head {:?}); run it as a simulated machine",
                m.name, bus.head
            )));
        }
        let mut t = Network::new(if m.name.is_empty() { "custom" } else { &m.name });
        let mut host = match m.host.kind {
            NodeKind::Host => NodeSpec::host(HOST),
            NodeKind::Mcu => NodeSpec::mcu(HOST),
        }
        .with_root(!m.modules.iter().any(|x| x.root))
        .with_busy(busy(m.host.busy));
        if m.host.clock == ClockSource::Fixed {
            host.clock = ClockSpec::IDEAL;
        }
        t.add_node(host);
        for spec in &m.modules {
            t.add_node(
                NodeSpec::mcu(&spec.name)
                    .with_root(spec.root)
                    .with_clock(module_clock(spec))
                    .with_busy(busy(spec.busy)),
            );
        }
        let is_stepper = |name: &str| {
            m.module_index(name)
                .is_some_and(|i| m.modules[i].kind() == Some(ModuleKind::Stepper))
        };
        for l in &m.links {
            let (a, b) = if l.kind == LinkKind::Usb && l.b == HOST {
                (&l.b, &l.a)
            } else {
                (&l.a, &l.b)
            };
            let mut link = NetLink::new(a, b, link_model(m.zero_latency, l)?).named(&l.name);
            for (side, end) in [(Side::A, a), (Side::B, b)] {
                if let Some(index) = firmware_link(l.kind).filter(|_| is_stepper(end)) {
                    link = link.at(side, index);
                }
            }
            t.add_link_spec(link);
        }
        // A stepper always has the firmware's links; one the file leaves
        // out is there and never opens, as on the machines.
        for spec in m.modules.iter().filter(|s| is_stepper(&s.name)) {
            for index in 0..FIRMWARE_LINKS {
                let taken = m.links.iter().any(|l| {
                    (l.a == spec.name || l.b == spec.name) && firmware_link(l.kind) == Some(index)
                });
                if !taken {
                    let model = if index == 0 {
                        LinkModel::usb_cdc()
                    } else {
                        LinkModel::Uart(UartParams::default())
                    };
                    t.add_unconnected(&spec.name, index, model);
                }
            }
        }
        t.validate()?;
        Ok(t)
    }

    /// Reads a TOML topology file ([`SimSpec::load`]) and converts it
    /// ([`from_spec`](Self::from_spec)); an unnamed one is named after
    /// the file.
    pub fn load(path: impl AsRef<Path>) -> Result<Network, SimError> {
        let path = path.as_ref();
        let m = SimSpec::load(path).map_err(|e| SimError::config(e.to_string()))?;
        let mut t = Network::from_spec(&m)
            .map_err(|e| SimError::config(format!("{}: {}", path.display(), message(e))))?;
        if m.name.is_empty() {
            if let Some(stem) = path.file_stem() {
                t.name = stem.to_string_lossy().into_owned();
            }
        }
        Ok(t)
    }

    /// Parses a TOML topology ([`SimSpec::parse`]) and converts it
    /// ([`from_spec`](Self::from_spec)).
    pub fn from_toml(text: &str) -> Result<Network, SimError> {
        let m = SimSpec::parse(text).map_err(|e| SimError::config(e.to_string()))?;
        Network::from_spec(&m)
    }
}

fn message(e: SimError) -> String {
    match e {
        SimError::Config(m) | SimError::Output(m) => m,
    }
}

impl TryFrom<&SimSpec> for Network {
    type Error = SimError;

    fn try_from(m: &SimSpec) -> Result<Network, SimError> {
        Network::from_spec(m)
    }
}

impl Scenario {
    /// A scenario of the discrete-event network `m` describes
    /// ([`Network::from_spec`]), seeded with its `seed`.
    pub fn from_spec(m: &SimSpec) -> Result<Scenario, SimError> {
        Ok(Scenario::new(Network::from_spec(m)?).seed(m.seed))
    }
}
