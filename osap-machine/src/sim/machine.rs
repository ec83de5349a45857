//! A [`Machine`] on simulated modules: the machine file's own simulated
//! machine ([`super::spec`]) started under a host, and what only a
//! simulated machine can answer (where its carriage really is).

use std::any::Any;
use std::future::Future;
use std::pin::Pin;
use std::time::Instant;

use osap_host::{Host, HostConfig};
use osap_sim::machine::board::melt::MeltStats;
use osap_sim::machine::board::rotor::Rotor;
use osap_sim::machine::DriftClock;
use osap_sim::machine::{SimMachine, TimeMode};
use osap_sim::topology::{MeltSpec, SimSpec};

use crate::config::MachineFile;
use crate::machine::{Machine, MachineError, Underneath, HOST_NAME};
use crate::network::Entry;

/// When a simulated motor stalled and when it held again (`None`: still
/// stalled), on the host's clock.
pub type StallSpan = (Instant, Option<Instant>);

/// One simulated motor's stalls ([`Machine::sim_stalls`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SimStalls {
    /// The motor's key in `[motors]`.
    pub motor: String,
    /// How many times it stalled.
    pub stalls: usize,
    /// Full steps it was sent while stalled (the carriage did not move).
    pub lost_full_steps: f64,
}

/// Options of [`Machine::simulate_with`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SimOptions {
    /// Real time, or virtual time (the caller runs on
    /// [`osap_sim::machine::virtual_runtime`]).
    pub time: TimeMode,
}

impl SimOptions {
    /// In virtual time: the caller runs on
    /// [`osap_sim::machine::virtual_runtime`], and a long job takes a
    /// fraction of its duration, the same for the same seed.
    pub const VIRTUAL: SimOptions = SimOptions {
        time: TimeMode::Virtual,
    };
}

/// The simulated machine kept under a [`Machine`], stopped with it, and
/// whether it runs in virtual time.
struct Simulated(SimMachine, bool);

impl Underneath for Simulated {
    fn stop(self: Box<Self>) -> Pin<Box<dyn Future<Output = Result<(), MachineError>> + Send>> {
        Box::pin(async move { self.0.stop().await.map_err(MachineError::from) })
    }

    fn as_any(&self) -> &dyn Any {
        self
    }

    fn reproducible(&self) -> bool {
        self.1
    }
}

impl Machine {
    /// The machine on simulated modules, derived from the machine file
    /// (its `[sim]` section), in real time.
    pub async fn simulate(cfg: &MachineFile) -> Result<Machine, MachineError> {
        Self::simulate_with(cfg, SimOptions::default()).await
    }

    /// [`Machine::simulate`] with options (virtual time).
    pub async fn simulate_with(
        cfg: &MachineFile,
        options: SimOptions,
    ) -> Result<Machine, MachineError> {
        cfg.validate()?;
        let spec = super::spec(cfg).map_err(|e| MachineError::Unsupported(e.to_string()))?;
        Self::simulate_on(cfg, &spec, options).await
    }

    /// [`Machine::simulate_with`] on a simulation of the caller's: the
    /// machine file's machine in a world that differs from the file, such
    /// as [`super::spec`]'s with a switch taken away (a broken wire) or
    /// moved (one pressed at start).
    pub async fn simulate_on(
        cfg: &MachineFile,
        spec: &SimSpec,
        options: SimOptions,
    ) -> Result<Machine, MachineError> {
        cfg.validate()?;
        let host = Host::start(HostConfig::named(HOST_NAME))?;
        let virtual_time = matches!(options.time, TimeMode::Virtual);
        let sim = SimMachine::start_with(&host, spec, options.time).await?;
        Self::start(
            cfg,
            host,
            Vec::new(),
            Entry::Host,
            Some(Box::new(Simulated(sim, virtual_time))),
        )
        .await
    }

    /// The simulated machine underneath, when simulated: runs `f` on it.
    pub fn with_sim<R>(&self, f: impl FnOnce(&SimMachine) -> R) -> Option<R> {
        self.with_underneath(|u| u.as_any().downcast_ref::<Simulated>().map(|s| f(&s.0)))
            .flatten()
    }

    /// Where the simulated machine's carriage really is on `axis`, axis
    /// units, from its motors' steps (not from the plan): what a dial
    /// gauge on the real machine would read. `None` when the machine is
    /// not simulated, for an axis it does not have, or for scara and
    /// fivebar x and y (not linear in the motors).
    pub fn sim_axis_position(&self, axis: &str) -> Option<f64> {
        let form = super::axis_form(self.config(), axis).ok()?;
        self.with_sim(|s| {
            form.value(|module| {
                s.module(module)
                    .and_then(|sm| sm.module())
                    .map_or(f64::NAN, |sm| sm.lock(|mm| mm.board().motor().position()))
            })
        })
        .filter(|v| v.is_finite())
    }

    /// Presses the limit switch of simulated module `module` (its
    /// `[modules]` key) now, as its edge interrupt would: the module's own
    /// logic records the edge, time-stamped on its clock. For a stuck or
    /// mis-wired switch, or a crash, in a test. `false` when the machine is
    /// not simulated or has no such running module.
    pub fn sim_press_limit(&self, module: &str) -> bool {
        let Some(key) = self.modules().get(module).map(|m| m.runtime.clone()) else {
            return false;
        };
        self.with_sim(|s| {
            let sm = s.module(&key)?;
            let now = sm.local_now();
            sm.module()?.lock(|mm| mm.limit_changed(now, false));
            Some(())
        })
        .flatten()
        .is_some()
    }

    /// `f` on each simulated motor's rotor (the motors with
    /// `[motors.NAME.model]`) and its module's clock, with its `[motors]`
    /// key.
    fn each_rotor<R>(&self, mut f: impl FnMut(&Rotor, DriftClock) -> R) -> Vec<(String, R)> {
        let cfg = self.config();
        let mut out = Vec::new();
        for (key, motor) in cfg.motors.iter().filter(|(_, m)| m.model.is_some()) {
            let Some(name) = super::module_name(cfg, &motor.module) else {
                continue;
            };
            let found = self
                .with_sim(|s| {
                    let sm = s.module(name)?.module()?;
                    sm.lock(|mm| {
                        let clock = mm.board().clock();
                        mm.board().motor().rotor().map(|r| f(r, clock))
                    })
                })
                .flatten();
            out.extend(found.map(|r| (key.clone(), r)));
        }
        out
    }

    /// The simulated motors' stalls so far: for each motor simulated with
    /// its datasheet values (`[motors.NAME.model]`), its `[motors]` key,
    /// how many times it stalled and the full steps it lost. Empty when
    /// the machine is not simulated or no motor has a model.
    pub fn sim_stalls(&self) -> Vec<SimStalls> {
        self.each_rotor(|r, _| {
            (
                r.stalls().len(),
                r.stalls().iter().map(|s| s.lost_full_steps).sum(),
            )
        })
        .into_iter()
        .map(|(motor, (stalls, lost_full_steps))| SimStalls {
            motor,
            stalls,
            lost_full_steps,
        })
        .collect()
    }

    /// When each simulated motor with a model was stalled: per `[motors]`
    /// key, (start, end) on the host's clock ([`osap_host::clock::now`]'s);
    /// `None` for a stall still going on. Empty when not simulated.
    pub fn sim_stall_spans(&self) -> Vec<(String, Vec<StallSpan>)> {
        self.each_rotor(|r, clock| {
            r.stalls()
                .iter()
                .map(|st| {
                    (
                        clock.instant_at(st.local),
                        st.end.map(|e| clock.instant_at(e)),
                    )
                })
                .collect()
        })
    }

    /// What the simulated melt behind the extruder did so far (its peak
    /// force, its slips), with the melt's own law; `None` when the
    /// machine is not simulated or simulates no melt (`[sim.axes.e]`).
    pub fn sim_melt(&self) -> Option<(MeltSpec, MeltStats)> {
        self.with_sim(|s| {
            s.modules().iter().find_map(|sm| {
                sm.module()?.lock(|mm| {
                    mm.board()
                        .pins()
                        .melt()
                        .map(|melt| (melt.spec().clone(), melt.stats()))
                })
            })
        })
        .flatten()
    }

    /// Puts a load of `nm` N·m on the simulated spindle of tool `tool`
    /// from now on (a cut; past its drive's torque limit, a stall), as a
    /// test's hook into the physics. `false` when the machine is not
    /// simulated or the tool has no simulated spindle (a `tach` and
    /// `[sim.spindles.NAME]`).
    pub fn sim_load_spindle(&self, tool: &str, nm: f64) -> bool {
        self.with_spindle_pins(tool, |pins| pins.load_spindle(nm))
            .unwrap_or(false)
    }

    /// The simulated spindle's true speed now, rpm (what the tachometer's
    /// pulses follow); `None` when there is none.
    pub fn sim_spindle_rpm(&self, tool: &str) -> Option<f64> {
        self.with_spindle_pins(tool, |pins| pins.spindle_rpm())
            .flatten()
    }

    /// `f` on the pins of tool `tool`'s simulated module.
    fn with_spindle_pins<R>(
        &self,
        tool: &str,
        f: impl FnOnce(&mut osap_sim::machine::board::Pins) -> R,
    ) -> Option<R> {
        let cfg = self.config();
        let name = super::module_name(cfg, &cfg.tools.get(tool)?.module)?;
        self.with_sim(|s| {
            let sm = s.module(name)?.module()?;
            Some(sm.lock(|mm| f(mm.board_mut().pins_mut())))
        })
        .flatten()
    }
}
