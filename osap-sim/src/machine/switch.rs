//! Limit switches over several motors ([`SwitchSpec`], `[[switch]]` in a
//! topology file).
//!
//! A CoreXY machine homes x on a switch wired to one module's limit input,
//! but x = (a + b) / 2 moves both belt motors. Such a switch is pressed
//! while a linear form of carriage positions, `Σ coef·position + offset`,
//! is at or below `at` (or at or above it).
//!
//! How it runs: every `stepper` whose motor some switch watches publishes,
//! after each run of step words it clocks out, the time of each step (as an
//! [`Instant`], common to all modules' clocks) and where it left the
//! carriage, on a board shared by the machine ([`Positions`]), with how far
//! its words are clocked. The module whose limit input the switch is on
//! ([`Input`]) merges those samples in time order, up to the earliest time
//! every watched motor is known up to, and turns each change of its input's
//! level into an edge stamped with the crossing step's time on its own
//! clock; the edges reach the module as the firmware's edge interrupt
//! delivers them ([`osap_module::Module::limit_changed`], at the module's
//! first poll at or after the edge).
//!
//! # Timing
//!
//! An edge's time stamp is the tick of the step that made the form cross
//! (the same as a switch on the module's own motor), to within 1 µs of
//! converting that step's time to the switch module's clock: the horizon
//! rule below makes sure no step is ever applied late. Motors clock their
//! words a step-generator lead (2.28 ms) ahead, and a module watching a
//! moving motor takes a turn every 1 ms, so an edge is normally known
//! before it is due and delivered on time; at worst (a motor's task
//! starved), it is delivered at the first turn after every watched motor
//! clocked its words past it, still with its exact time stamp.
//!
//! The horizon: a moving motor is known up to the end of its newest
//! clocked word; a standing one (whose words are empty until a call at its
//! next poll changes that) up to now, except while it is polling, when it
//! is known only up to the words it has clocked (its poll may start it
//! moving from the clock reading it took). A motor that stops running is
//! standing.

use super::DriftClock;
use crate::topology::{BedContact, BedSurface, SimSpec, SwitchSpec};
use osap_core::Instant as LocalInstant;
use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};
use tokio::sync::Notify;

/// Most samples a feed keeps for a switch module that does not read them
/// (one that is not running): the oldest go first.
const FEED_CAP: usize = 1 << 16;

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Where the carriages of watched motors are, shared by a machine's
/// modules: one track per module (empty for modules no switch watches).
pub(crate) struct Positions {
    tracks: Vec<Mutex<Track>>,
}

struct Track {
    /// The carriage after the newest step published.
    position: f64,
    /// The end of the newest word clocked out (the next word's first tick).
    clocked: Instant,
    /// Whether the axis stands (its words stay empty until its next poll).
    standing: bool,
    /// Whether the module is between reading its clock for a poll and
    /// publishing what that poll decided.
    busy: bool,
    /// One per module whose input watches this motor.
    feeds: Vec<Feed>,
}

struct Feed {
    input: usize,
    samples: VecDeque<(Instant, f64)>,
    wake: Arc<Notify>,
}

impl Positions {
    /// The board for `topology`'s switches (`None` without any), waking
    /// module `i`'s task through `wakes[i]`.
    pub(crate) fn new(
        topology: &SimSpec,
        wakes: &[Arc<Notify>],
        epoch: Instant,
    ) -> Option<Arc<Positions>> {
        if topology.switches.is_empty() {
            return None;
        }
        let tracks: Vec<Mutex<Track>> = topology
            .modules
            .iter()
            .map(|_| {
                Mutex::new(Track {
                    position: 0.0,
                    clocked: epoch,
                    standing: true,
                    busy: false,
                    feeds: Vec::new(),
                })
            })
            .collect();
        for (input, _) in topology.modules.iter().enumerate() {
            for term in watched(topology, input) {
                lock(&tracks[term]).feeds.push(Feed {
                    input,
                    samples: VecDeque::new(),
                    wake: wakes[input].clone(),
                });
            }
        }
        Some(Arc::new(Positions { tracks }))
    }

    /// Whether some switch watches module `m`'s motor.
    fn watched(&self, m: usize) -> bool {
        self.tracks
            .get(m)
            .is_some_and(|t| !lock(t).feeds.is_empty())
    }

    /// Module `m` stopped running: its motor stands.
    pub(crate) fn stopped(&self, m: usize) {
        if let Some(t) = self.tracks.get(m) {
            let mut t = lock(t);
            t.standing = true;
            t.busy = false;
        }
    }
}

/// The modules whose motors the switches on module `input` watch, each
/// once, in the order they are first named.
fn watched(topology: &SimSpec, input: usize) -> Vec<usize> {
    let name = &topology.modules[input].name;
    let mut terms = Vec::new();
    for s in topology.switches.iter().filter(|s| &s.module == name) {
        let bed = s
            .bed
            .iter()
            .flat_map(|b| b.x_terms.iter().chain(&b.y_terms));
        for (module, _) in s.terms.iter().chain(bed) {
            if let Some(i) = topology.module_index(module) {
                if !terms.contains(&i) {
                    terms.push(i);
                }
            }
        }
    }
    terms
}

/// A watched motor's side: what its step generator publishes.
#[derive(Clone)]
pub(crate) struct Publisher {
    board: Arc<Positions>,
    module: usize,
    clock: DriftClock,
    /// Steps clocked since the last publication: (time, carriage after).
    samples: Vec<(Instant, f64)>,
}

impl Publisher {
    /// Module `module`'s publisher, if a switch watches its motor; it booted
    /// with its clock `clock`, standing, carriage at `position`.
    pub(crate) fn new(
        board: &Arc<Positions>,
        module: usize,
        clock: DriftClock,
        position: f64,
    ) -> Option<Publisher> {
        if !board.watched(module) {
            return None;
        }
        let p = Publisher {
            board: board.clone(),
            module,
            clock,
            samples: Vec::new(),
        };
        let boot = clock.instant_at(clock.now());
        let mut t = lock(&p.board.tracks[module]);
        if t.position != position {
            t.position = position;
            for f in &mut t.feeds {
                push(f, (boot, position));
            }
        }
        t.clocked = t.clocked.max(boot);
        t.standing = true;
        t.busy = false;
        drop(t);
        Some(p)
    }

    /// The module is about to read its clock for a poll.
    pub(crate) fn begin_poll(&self) {
        lock(&self.board.tracks[self.module]).busy = true;
    }

    /// The instant of local time `local` on this module's clock.
    pub(crate) fn instant_at(&self, local: LocalInstant) -> Instant {
        self.clock.instant_at(local)
    }

    /// A step at `at` left the carriage at `position`.
    pub(crate) fn step(&mut self, at: Instant, position: f64) {
        self.samples.push((at, position));
    }

    /// Publishes the steps so far, the words clocked up to local `next`,
    /// and (after a poll) whether the axis stands, which ends the poll.
    /// A motor that starts moving wakes the modules watching it.
    pub(crate) fn publish(&mut self, next: LocalInstant, standing: Option<bool>) {
        let clocked = self.clock.instant_at(next);
        let mut t = lock(&self.board.tracks[self.module]);
        if let Some(&(_, p)) = self.samples.last() {
            t.position = p;
        }
        for f in &mut t.feeds {
            for &s in &self.samples {
                push(f, s);
            }
        }
        self.samples.clear();
        t.clocked = t.clocked.max(clocked);
        if let Some(standing) = standing {
            let started = t.standing && !standing;
            t.standing = standing;
            t.busy = false;
            if started {
                for f in &t.feeds {
                    f.wake.notify_one();
                }
            }
        }
    }
}

fn push(f: &mut Feed, sample: (Instant, f64)) {
    if f.samples.len() >= FEED_CAP {
        f.samples.pop_front();
    }
    f.samples.push_back(sample);
}

/// One switch on an input, its terms as slots of the input's motors.
#[derive(Clone)]
struct Switch {
    terms: Vec<(usize, f64)>,
    offset: f64,
    at: f64,
    pressed_below: bool,
    /// A bed probe's contact, its forms over slots.
    bed: Option<BedSlots>,
}

/// A [`BedContact`] whose forms name slots of the input's motors.
#[derive(Clone)]
struct BedSlots {
    x: Vec<(usize, f64)>,
    x_offset: f64,
    y: Vec<(usize, f64)>,
    y_offset: f64,
    surface: BedSurface,
}

fn form(terms: &[(usize, f64)], offset: f64, positions: &[f64]) -> f64 {
    offset
        + terms
            .iter()
            .map(|&(slot, coef)| coef * positions[slot])
            .sum::<f64>()
}

impl Switch {
    fn pressed(&self, positions: &[f64]) -> bool {
        let v = self.offset
            + self
                .terms
                .iter()
                .map(|&(slot, coef)| coef * positions[slot])
                .sum::<f64>();
        let at = self.at
            + self.bed.as_ref().map_or(0.0, |b| {
                b.surface.height(
                    form(&b.x, b.x_offset, positions),
                    form(&b.y, b.y_offset, positions),
                )
            });
        if self.pressed_below {
            v <= at
        } else {
            v >= at
        }
    }
}

/// A module's limit input driven by switches over motors ([`SwitchSpec`]):
/// pulled up (`true`) while every switch on it is released, low while any
/// is pressed (switches wired in parallel).
#[derive(Clone)]
pub(crate) struct Input {
    board: Arc<Positions>,
    module: usize,
    clock: DriftClock,
    /// The watched motors' modules, by slot.
    terms: Vec<usize>,
    /// Their carriages, as merged up to `until`.
    positions: Vec<f64>,
    /// Their samples taken from the board but not yet merged.
    backlog: Vec<VecDeque<(Instant, f64)>>,
    switches: Vec<Switch>,
    level: bool,
    /// How far the samples are merged.
    until: Instant,
    /// Edges not yet delivered: (local time, new level).
    pending: VecDeque<(LocalInstant, bool)>,
    /// Whether a watched motor moved, or was not yet known up to now, at
    /// the last merge: the module then takes a turn every refill period.
    active: bool,
}

impl Input {
    /// Module `module`'s input, if switches are on it; booted now on
    /// `clock`, its level from where the carriages are.
    pub(crate) fn new(
        board: &Arc<Positions>,
        topology: &SimSpec,
        module: usize,
        clock: DriftClock,
    ) -> Option<Input> {
        let name = &topology.modules[module].name;
        let specs: Vec<&SwitchSpec> = topology
            .switches
            .iter()
            .filter(|s| &s.module == name)
            .collect();
        if specs.is_empty() {
            return None;
        }
        let terms = watched(topology, module);
        let slot_of = |m: &str| {
            let i = topology.module_index(m)?;
            terms.iter().position(|&t| t == i)
        };
        let slots = |ts: &[(String, f64)]| -> Vec<(usize, f64)> {
            ts.iter()
                .filter_map(|(m, coef)| Some((slot_of(m)?, *coef)))
                .collect()
        };
        let switches = specs
            .iter()
            .map(|s| Switch {
                terms: s
                    .terms
                    .iter()
                    .filter_map(|(m, coef)| Some((slot_of(m)?, *coef)))
                    .collect(),
                offset: s.offset,
                at: s.at,
                pressed_below: s.pressed_below,
                bed: s.bed.as_ref().map(|b: &BedContact| BedSlots {
                    x: slots(&b.x_terms),
                    x_offset: b.x_offset,
                    y: slots(&b.y_terms),
                    y_offset: b.y_offset,
                    surface: b.surface,
                }),
            })
            .collect();
        let positions = terms
            .iter()
            .map(|&t| {
                let mut track = lock(&board.tracks[t]);
                // What came before this boot is history.
                if let Some(f) = track.feeds.iter_mut().find(|f| f.input == module) {
                    f.samples.clear();
                }
                track.position
            })
            .collect();
        let mut input = Input {
            board: board.clone(),
            module,
            clock,
            backlog: terms.iter().map(|_| VecDeque::new()).collect(),
            terms,
            positions,
            switches,
            level: true,
            until: clock.instant_at(clock.now()),
            pending: VecDeque::new(),
            active: false,
        };
        input.level = input.level_now();
        Some(input)
    }

    fn level_now(&self) -> bool {
        !self.switches.iter().any(|s| s.pressed(&self.positions))
    }

    /// The input's level as merged so far.
    pub(crate) fn level(&self) -> bool {
        self.level
    }

    /// Merges what the watched motors published, as far as all of them
    /// are known, at local `now`; level changes become pending edges.
    pub(crate) fn merge(&mut self, now: LocalInstant) {
        let now_at = self.clock.instant_at(now);
        let mut horizon: Option<Instant> = None;
        let mut moving = false;
        for (slot, &t) in self.terms.iter().enumerate() {
            let mut track = lock(&self.board.tracks[t]);
            if let Some(f) = track.feeds.iter_mut().find(|f| f.input == self.module) {
                self.backlog[slot].extend(f.samples.drain(..));
            }
            let known = if track.standing && !track.busy {
                track.clocked.max(now_at)
            } else {
                track.clocked
            };
            moving |= !track.standing;
            horizon = Some(horizon.map_or(known, |h| h.min(known)));
        }
        let horizon = horizon.unwrap_or(now_at).max(self.until);
        // Merge in time order; steps at the same instant together.
        while let Some(t) = self
            .backlog
            .iter()
            .filter_map(|b| b.front().map(|s| s.0))
            .filter(|&t| t < horizon)
            .min()
        {
            for (slot, b) in self.backlog.iter_mut().enumerate() {
                while let Some(&(_, p)) = b.front().filter(|s| s.0 == t) {
                    self.positions[slot] = p;
                    b.pop_front();
                }
            }
            let level = self.level_now();
            if level != self.level {
                self.level = level;
                // A step older than what is merged (none, by the horizon
                // rule) would count from there.
                let at = t.max(self.until);
                self.pending.push_back((self.clock.local_at(at), level));
            }
        }
        self.until = horizon;
        self.active = moving || horizon < now_at;
    }

    /// Takes the edges due by local `now`, oldest first.
    pub(crate) fn take_edges(
        &mut self,
        now: LocalInstant,
    ) -> impl Iterator<Item = (LocalInstant, bool)> + '_ {
        let due = self.pending.iter().take_while(|e| e.0 <= now).count();
        self.pending.drain(..due)
    }

    /// When the input next needs a turn, after a merge at local `now`: its
    /// next pending edge, or a refill period on while a watched motor moves.
    pub(crate) fn next_turn(
        &self,
        now: LocalInstant,
        refill: osap_core::Duration,
    ) -> Option<LocalInstant> {
        let edge = self.pending.front().map(|e| e.0);
        let refill = self.active.then_some(now + refill);
        [edge, refill].into_iter().flatten().min()
    }
}

/// The time of tick `k` of a word whose first tick is at `word`.
pub(crate) fn tick_instant(word: Instant, k: u32, tick_us: u32) -> Instant {
    word + Duration::from_micros(u64::from(k * tick_us))
}
