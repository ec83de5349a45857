//! An interface for external planners (e.g. a model-predictive solver) that
//! may be slow: the solver runs in its own thread and the runtime side never
//! waits for it.
//!
//! An [`Optimizer`] computes the point for a synchronized stamp. An
//! [`OptimizerBlock`] owns a thread running it, and two bounded channels
//! (`std::sync::mpsc::sync_channel`): stamps to solve go one way, solved
//! points the other. [`OptimizerBlock::sample`] is non-blocking: it asks for
//! the stamps up to `stamp + lead` (dropping requests the full channel
//! refuses, to retry on the next call), collects whatever the solver has
//! finished, and returns the solver's point for `stamp` if it is there;
//! otherwise it holds the last point it returned and counts a miss. The
//! solver skips requests whose stamp has already been sampled, so a solver
//! that falls behind catches up instead of solving the past.
//!
//! [`OptimizerClass`] is the PIPES class of a three-axis block (class
//! `Optimizer`): a script builds the block around its solver and attaches it
//! with `Manager::define_class`, then pipes a Timer's stamps into
//! `Optimizer.sample` and its outputs on to kinematics or axes, as with the
//! planner. A solver is Rust code, so the class cannot be rebuilt over the
//! network: its constructor `Optimizer()` always fails with
//! [`NOT_REMOTE`]. Failure codes of `sample`: 1 invalid configuration,
//! 2 a stamp before the previous one, 3 the solver thread could not start
//! ([`OptimizerError::code`]).

use std::collections::VecDeque;
use std::fmt;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TryRecvError, TrySendError};
use std::sync::Arc;
use std::thread::{self, JoinHandle};

/// An external planner run in a solver thread.
pub trait Optimizer: Send + 'static {
    /// The point it produces (e.g. `[f64; 3]`).
    type Point: Copy + Send + 'static;

    /// The point for synchronized stamp `stamp_us`, or `None` if it has none
    /// (counted as a failure; the block then holds its last point). May take
    /// as long as it needs: only the solver thread waits.
    fn solve(&mut self, stamp_us: u64) -> Option<Self::Point>;
}

/// Timing of an [`OptimizerBlock`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OptimizerConfig {
    /// Stamp interval (µs, > 0): requests go out for every multiple of it.
    pub interval_us: u64,
    /// How far ahead of the sampled stamp (µs) to request points.
    pub lead_us: u64,
    /// Capacity of each channel (requests and results), > 0.
    pub channel: usize,
}

/// What [`OptimizerBlock::sample`] returns.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sampled<P> {
    /// The point for the stamp, or the last point held.
    pub point: P,
    /// Whether the solver delivered this point for this stamp.
    pub fresh: bool,
}

/// Counters of an [`OptimizerBlock`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct OptimizerStats {
    /// Calls to `sample`.
    pub samples: u64,
    /// Samples answered with the solver's point for the stamp.
    pub hits: u64,
    /// Samples answered with the held point.
    pub misses: u64,
    /// Requests the full request channel refused (retried later).
    pub requests_refused: u64,
    /// Points that arrived after their stamp was sampled.
    pub late: u64,
    /// Requests the solver skipped because their stamp had passed.
    pub skipped: u64,
    /// Requests the solver answered with `None`.
    pub failures: u64,
    /// Whether the solver thread is still running.
    pub solver_alive: bool,
}

/// Why the block refused a call.
#[derive(Debug)]
#[non_exhaustive]
pub enum OptimizerError {
    /// A configuration value is out of range.
    InvalidConfig(&'static str),
    /// A stamp before the previous one.
    StampNotMonotonic {
        /// The refused stamp.
        stamp: u64,
        /// The previous stamp.
        last: u64,
    },
    /// The solver thread could not be started.
    Spawn(std::io::Error),
}

impl fmt::Display for OptimizerError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            OptimizerError::InvalidConfig(why) => write!(f, "invalid optimizer config: {why}"),
            OptimizerError::StampNotMonotonic { stamp, last } => {
                write!(f, "stamp {stamp} µs is before the previous stamp {last} µs")
            }
            OptimizerError::Spawn(e) => write!(f, "cannot start the solver thread: {e}"),
        }
    }
}

impl OptimizerError {
    /// The PIPES failure code.
    pub fn code(&self) -> u8 {
        match self {
            OptimizerError::InvalidConfig(_) => 1,
            OptimizerError::StampNotMonotonic { .. } => 2,
            OptimizerError::Spawn(_) => 3,
        }
    }
}

impl From<OptimizerError> for pipes_core::function::CallError {
    fn from(e: OptimizerError) -> Self {
        pipes_core::function::CallError::Failed(e.code().into())
    }
}

impl core::error::Error for OptimizerError {
    fn source(&self) -> Option<&(dyn core::error::Error + 'static)> {
        match self {
            OptimizerError::Spawn(e) => Some(e),
            _ => None,
        }
    }
}

/// Counters the solver thread updates.
#[derive(Default)]
struct Shared {
    /// The newest sampled stamp + 1 (0: none yet): stamps below it are past.
    now: AtomicU64,
    skipped: AtomicU64,
    failures: AtomicU64,
    alive: AtomicBool,
}

/// Runs an [`Optimizer`] in its own thread; `sample` never blocks.
pub struct OptimizerBlock<P> {
    cfg: OptimizerConfig,
    requests: SyncSender<u64>,
    results: Receiver<(u64, P)>,
    shared: Arc<Shared>,
    ready: VecDeque<(u64, P)>,
    last: P,
    next_request: Option<u64>,
    last_stamp: Option<u64>,
    stats: OptimizerStats,
    // Dropping the block detaches the thread; it ends at its next request.
    _thread: JoinHandle<()>,
}

impl<P> fmt::Debug for OptimizerBlock<P> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("OptimizerBlock")
            .field("cfg", &self.cfg)
            .field("stats", &self.stats())
            .finish()
    }
}

impl<P> OptimizerBlock<P> {
    /// The counters.
    pub fn stats(&self) -> OptimizerStats {
        let mut s = self.stats;
        s.skipped = self.shared.skipped.load(Ordering::Relaxed);
        s.failures = self.shared.failures.load(Ordering::Relaxed);
        s.solver_alive = self.shared.alive.load(Ordering::Relaxed);
        s
    }
}

impl<P: Copy + Send + 'static> OptimizerBlock<P> {
    /// Starts `solver` in a thread; `initial` is held until its first point.
    pub fn new<O>(solver: O, initial: P, cfg: OptimizerConfig) -> Result<Self, OptimizerError>
    where
        O: Optimizer<Point = P>,
    {
        if cfg.interval_us == 0 {
            return Err(OptimizerError::InvalidConfig("interval_us must be > 0"));
        }
        if cfg.channel == 0 {
            return Err(OptimizerError::InvalidConfig("channel must be > 0"));
        }
        let (req_tx, req_rx) = sync_channel::<u64>(cfg.channel);
        let (res_tx, res_rx) = sync_channel::<(u64, P)>(cfg.channel);
        let shared = Arc::new(Shared::default());
        shared.alive.store(true, Ordering::SeqCst);
        let sh = shared.clone();
        let thread = thread::Builder::new()
            .name("maxl-optimizer".into())
            .spawn(move || solver_loop(solver, req_rx, res_tx, sh))
            .map_err(OptimizerError::Spawn)?;
        Ok(OptimizerBlock {
            cfg,
            requests: req_tx,
            results: res_rx,
            shared,
            ready: VecDeque::new(),
            last: initial,
            next_request: None,
            last_stamp: None,
            stats: OptimizerStats::default(),
            _thread: thread,
        })
    }

    /// The configuration.
    pub fn config(&self) -> OptimizerConfig {
        self.cfg
    }

    /// The point for `stamp` if the solver has it, else the last point held.
    /// Never waits for the solver. Stamps must not decrease.
    pub fn sample(&mut self, stamp: u64) -> Result<Sampled<P>, OptimizerError> {
        if let Some(last) = self.last_stamp {
            if stamp < last {
                return Err(OptimizerError::StampNotMonotonic { stamp, last });
            }
        }
        self.last_stamp = Some(stamp);
        self.shared
            .now
            .store(stamp.saturating_add(1), Ordering::Relaxed);
        self.stats.samples += 1;
        self.request_up_to(stamp);
        self.collect(stamp);
        while let Some(&(s, _)) = self.ready.front() {
            if s >= stamp {
                break;
            }
            self.ready.pop_front();
        }
        match self.ready.front() {
            Some(&(s, p)) if s == stamp => {
                self.ready.pop_front();
                self.last = p;
                self.stats.hits += 1;
                Ok(Sampled {
                    point: p,
                    fresh: true,
                })
            }
            _ => {
                self.stats.misses += 1;
                Ok(Sampled {
                    point: self.last,
                    fresh: false,
                })
            }
        }
    }

    /// Sends requests for the stamps up to `stamp + lead` not yet asked for.
    fn request_up_to(&mut self, stamp: u64) {
        let iv = self.cfg.interval_us;
        // The first stamp after `stamp` on the interval grid: `stamp` itself
        // is being sampled now, too late to ask for.
        let first = (stamp / iv).saturating_add(1).saturating_mul(iv);
        let mut next = self.next_request.map_or(first, |n| n.max(first));
        let until = stamp.saturating_add(self.cfg.lead_us);
        while next <= until {
            match self.requests.try_send(next) {
                Ok(()) => next = next.saturating_add(iv),
                Err(TrySendError::Full(_)) => {
                    self.stats.requests_refused += 1;
                    break;
                }
                Err(TrySendError::Disconnected(_)) => break,
            }
            if next == u64::MAX {
                break;
            }
        }
        self.next_request = Some(next);
    }

    /// Moves the solver's finished points for stamps from `now` on into
    /// `ready`, in stamp order (older ones count as late).
    fn collect(&mut self, now: u64) {
        loop {
            match self.results.try_recv() {
                Ok((s, p)) if s >= now => {
                    // Requests go out in order and are solved in order.
                    if self.ready.back().is_some_and(|&(b, _)| b >= s) {
                        continue;
                    }
                    self.ready.push_back((s, p));
                }
                Ok(_) => self.stats.late += 1,
                Err(TryRecvError::Empty) | Err(TryRecvError::Disconnected) => break,
            }
        }
    }
}

fn solver_loop<O: Optimizer>(
    mut solver: O,
    requests: Receiver<u64>,
    results: SyncSender<(u64, O::Point)>,
    shared: Arc<Shared>,
) {
    // Marks the solver dead however the loop ends, also by a panic in solve.
    struct Alive(Arc<Shared>);
    impl Drop for Alive {
        fn drop(&mut self) {
            self.0.alive.store(false, Ordering::SeqCst);
        }
    }
    let _alive = Alive(shared.clone());
    while let Ok(stamp) = requests.recv() {
        let now = shared.now.load(Ordering::Relaxed);
        if stamp < now {
            shared.skipped.fetch_add(1, Ordering::Relaxed);
            continue;
        }
        match solver.solve(stamp) {
            Some(p) => {
                if results.send((stamp, p)).is_err() {
                    return;
                }
            }
            None => {
                shared.failures.fetch_add(1, Ordering::Relaxed);
            }
        }
    }
}

/// Failure code of the `Optimizer` constructor: the block is built by a
/// script around its solver, not over the network.
pub const NOT_REMOTE: u8 = 9;

/// A three-axis [`OptimizerBlock`] as the PIPES class `Optimizer` (see the
/// module docs).
#[derive(Debug)]
pub struct OptimizerClass(pub OptimizerBlock<[f64; 3]>);

#[pipes_core::class(name = "Optimizer")]
impl OptimizerClass {
    /// The constructor `Optimizer()`: always refused with [`NOT_REMOTE`].
    #[constructor]
    pub fn remote_new() -> Result<OptimizerClass, pipes_core::function::CallError> {
        Err(pipes_core::function::CallError::Failed(
            pipes_core::FailureCode::from_code(NOT_REMOTE),
        ))
    }

    /// `Optimizer.sample`: the stamp, the point for it (or the one held,
    /// `fresh` false) in `f32` like the blocks it pipes into
    /// ([`OptimizerBlock::sample`]).
    #[outputs = "stamp, x, y, z, fresh"]
    pub fn sample(&mut self, stamp: u64) -> Result<(u64, f32, f32, f32, bool), OptimizerError> {
        let s = self.0.sample(stamp)?;
        let [x, y, z] = s.point;
        Ok((stamp, x as f32, y as f32, z as f32, s.fresh))
    }

    /// `Optimizer.stats`: samples, hits and misses so far, and whether the
    /// solver still runs.
    #[outputs = "samples, hits, misses, solver_alive"]
    pub fn stats(&self) -> (u64, u64, u64, bool) {
        let s = self.0.stats();
        (s.samples, s.hits, s.misses, s.solver_alive)
    }
}
