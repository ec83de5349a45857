//! How the discrete-event simulator runs the host and the modules' clocks:
//! the `[host]` table and a module's `clock` key.

use crate::node::NodeKind;
use serde::{Deserialize, Serialize};

/// Where a node's oscillator comes from in the discrete-event simulator
/// (`clock` of a `[[module]]` or of `[host]`). DES only: the simulated
/// machines always use a module's `rate_ppm`, `offset_us` and wander, and
/// the host's own clock.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ClockSource {
    /// `"fixed"` (the default): a module's `rate_ppm`, `offset_us`,
    /// `wander_ppm` and `wander_period_s`; for the host an ideal clock (the
    /// reference the simulated machines' module clocks are relative to).
    #[default]
    Fixed,
    /// `"drawn"`: drawn from the run's seed as a crystal of the node's kind
    /// ([`ClockSpec::MCU`](crate::clock::ClockSpec::MCU): booted up to 10 s before true time 0, ±100 ppm,
    /// wandering by U[0.5, 1.5] ppm over U[120, 600] s; a host of kind
    /// `"host"` [`ClockSpec::HOST`](crate::clock::ClockSpec::HOST): ±50 ppm), so each seed gives other
    /// clocks.
    Drawn,
}

/// How the discrete-event simulator runs the host: the `[host]` table of a
/// topology file. DES only: the simulated machines attach to a real
/// [`osap_host::Host`] and ignore it.
///
/// ```toml
/// [host]
/// kind = "host"      # "host" (a PC process) or "mcu" (a microcontroller)
/// clock = "fixed"    # "fixed": an ideal clock; "drawn": from the seed
/// busy = false       # busy spells (BusyModel::MOTOR)
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HostSpec {
    /// A PC process ([`NodeKind::Host`], the default: main-loop latency
    /// 10 µs + Exp(40 µs)) or a microcontroller ([`NodeKind::Mcu`]: U[2, 20]
    /// µs), to measure links without a PC's latency.
    #[serde(default = "host_kind", skip_serializing_if = "is_host_kind")]
    pub kind: NodeKind,
    /// Its oscillator (default `"fixed"`: an ideal clock).
    #[serde(default, skip_serializing_if = "is_default")]
    pub clock: ClockSource,
    /// Busy spells ([`BusyModel::MOTOR`](crate::busy::BusyModel::MOTOR)).
    #[serde(default, skip_serializing_if = "is_default")]
    pub busy: bool,
}

fn host_kind() -> NodeKind {
    NodeKind::Host
}

fn is_host_kind(kind: &NodeKind) -> bool {
    *kind == NodeKind::Host
}

fn is_default<T: Default + PartialEq>(v: &T) -> bool {
    *v == T::default()
}

impl Default for HostSpec {
    fn default() -> Self {
        HostSpec {
            kind: NodeKind::Host,
            clock: ClockSource::Fixed,
            busy: false,
        }
    }
}
