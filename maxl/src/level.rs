//! Level and event tracks on the motion time base (synchronized time, `u64`
//! µs), bounded and allocation-free.
//!
//! A [`LevelTrack`] holds values that take effect at stamped times (laser
//! power, a solenoid): [`LevelTrack::level`] gives the value in force at `t`,
//! the one with the latest stamp `<= t`. An [`EventTrack`] holds one-shot
//! events (a camera trigger): [`EventTrack::poll`] yields each event once,
//! when its time has come. Neither drops anything silently: a full queue, a
//! stamp in the past or out of order is an error returned by `push`.

/// Why a push was refused. Nothing was stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum TimedPushError {
    /// The queue is full.
    Full,
    /// The stamp is before a stamp already queued (`newest`).
    OutOfOrder {
        /// The newest stamp queued, µs.
        newest: u64,
    },
    /// Level tracks only: a change is already stamped at this exact time.
    Duplicate,
    /// The stamp is already in the past (before the latest `now` given to
    /// `advance`/`poll`, `now`), so it would take effect late.
    Late {
        /// The latest time given, µs.
        now: u64,
    },
}

impl core::fmt::Display for TimedPushError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            TimedPushError::Full => write!(f, "queue full"),
            TimedPushError::OutOfOrder { newest } => {
                write!(f, "stamp before the newest queued stamp {newest} µs")
            }
            TimedPushError::Duplicate => write!(f, "a change is already stamped at that time"),
            TimedPushError::Late { now } => write!(f, "stamp is before now ({now} µs)"),
        }
    }
}

impl core::error::Error for TimedPushError {}

/// A fixed-capacity ring of `(time, value)` in stamp order.
#[derive(Clone, Debug)]
struct Ring<V: Copy, const N: usize> {
    buf: [(u64, V); N],
    head: usize,
    len: usize,
}

impl<V: Copy, const N: usize> Ring<V, N> {
    fn new(fill: V) -> Self {
        Ring {
            buf: [(0, fill); N],
            head: 0,
            len: 0,
        }
    }
    fn get(&self, k: usize) -> (u64, V) {
        self.buf[(self.head + k) % N]
    }
    fn newest(&self) -> Option<u64> {
        (self.len > 0).then(|| self.get(self.len - 1).0)
    }
    fn oldest(&self) -> Option<u64> {
        (self.len > 0).then(|| self.get(0).0)
    }
    fn push(&mut self, t: u64, v: V) -> Result<(), TimedPushError> {
        if self.len == N {
            return Err(TimedPushError::Full);
        }
        self.buf[(self.head + self.len) % N] = (t, v);
        self.len += 1;
        Ok(())
    }
    fn pop(&mut self) -> Option<(u64, V)> {
        if self.len == 0 {
            return None;
        }
        let e = self.buf[self.head];
        self.head = (self.head + 1) % N;
        self.len -= 1;
        Some(e)
    }
    /// The oldest entry, if it is stamped `<= now`.
    fn pop_due(&mut self, now: u64) -> Option<(u64, V)> {
        if self.oldest()? > now {
            return None;
        }
        self.pop()
    }
}

/// Values in force from stamped times; at most `N` pending changes.
#[derive(Clone, Debug)]
pub struct LevelTrack<V: Copy, const N: usize> {
    current: V,
    since: Option<u64>,
    now: u64,
    queue: Ring<V, N>,
}

impl<V: Copy, const N: usize> LevelTrack<V, N> {
    /// A track whose value is `initial` until the first change.
    pub fn new(initial: V) -> Self {
        const { assert!(N >= 1, "a level track needs at least 1 slot") };
        LevelTrack {
            current: initial,
            since: None,
            now: 0,
            queue: Ring::new(initial),
        }
    }

    /// Stamp a change to `value` at `time`.
    pub fn push(&mut self, time: u64, value: V) -> Result<(), TimedPushError> {
        if time < self.now {
            return Err(TimedPushError::Late { now: self.now });
        }
        let newest = self.queue.newest().or(self.since);
        match newest {
            Some(n) if time == n => return Err(TimedPushError::Duplicate),
            Some(n) if time < n => return Err(TimedPushError::OutOfOrder { newest: n }),
            _ => {}
        }
        self.queue.push(time, value)
    }

    /// Apply every change stamped `<= now` and return the value in force.
    /// Later pushes stamped before `now` are refused as `Late`. A `now`
    /// earlier than a previous one changes nothing.
    pub fn advance(&mut self, now: u64) -> V {
        self.now = self.now.max(now);
        while let Some((t, v)) = self.queue.pop_due(self.now) {
            self.current = v;
            self.since = Some(t);
        }
        self.current
    }

    /// The value in force at `t` (latest stamp `<= t`), without applying
    /// anything. For `t` before the last `advance`, this is the value in
    /// force at that `advance`.
    pub fn level(&self, t: u64) -> V {
        let mut v = self.current;
        for k in 0..self.queue.len {
            let (s, x) = self.queue.get(k);
            if s > t {
                break;
            }
            v = x;
        }
        v
    }

    /// Stamp of the next pending change (to arm a timer).
    pub fn next_change(&self) -> Option<u64> {
        self.queue.oldest()
    }

    /// The next pending change, stamp and value: with [`since`](Self::since)
    /// and the value in force, what a ramp between two changes needs.
    pub fn next(&self) -> Option<(u64, V)> {
        (self.queue.len > 0).then(|| self.queue.get(0))
    }

    /// The value in force at the latest `advance`.
    pub fn current(&self) -> V {
        self.current
    }

    /// The stamp of the change in force (`None` before the first, and
    /// after [`clear_to`](Self::clear_to)).
    pub fn since(&self) -> Option<u64> {
        self.since
    }

    /// Drops every pending change and puts `value` in force with no stamp
    /// (a stop): the next change starts afresh. Stamps before the latest
    /// `now` are still refused as `Late`.
    pub fn clear_to(&mut self, value: V) {
        while self.queue.pop().is_some() {}
        self.current = value;
        self.since = None;
    }

    /// Pending changes.
    pub fn pending(&self) -> usize {
        self.queue.len
    }
}

/// An event whose time has come.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Fired<E> {
    /// Its stamp (µs).
    pub time: u64,
    /// How late the poll was (`now − time`, µs).
    pub late_us: u64,
    /// The event.
    pub event: E,
}

/// One-shot events at stamped times; at most `N` pending.
#[derive(Clone, Debug)]
pub struct EventTrack<E: Copy, const N: usize> {
    now: u64,
    queue: Ring<E, N>,
    fired: u64,
}

impl<E: Copy + Default, const N: usize> Default for EventTrack<E, N> {
    fn default() -> Self {
        Self::new(E::default())
    }
}

impl<E: Copy, const N: usize> EventTrack<E, N> {
    /// An empty track; `fill` only initializes unused slots.
    pub fn new(fill: E) -> Self {
        const { assert!(N >= 1, "an event track needs at least 1 slot") };
        EventTrack {
            now: 0,
            queue: Ring::new(fill),
            fired: 0,
        }
    }

    /// Queue `event` at `time`. Events at the same time fire in push order.
    pub fn push(&mut self, time: u64, event: E) -> Result<(), TimedPushError> {
        if time < self.now {
            return Err(TimedPushError::Late { now: self.now });
        }
        if let Some(n) = self.queue.newest() {
            if time < n {
                return Err(TimedPushError::OutOfOrder { newest: n });
            }
        }
        self.queue.push(time, event)
    }

    /// The next event stamped `<= now`, once; `None` when none is due.
    /// A `now` earlier than a previous one is treated as the previous one.
    pub fn poll(&mut self, now: u64) -> Option<Fired<E>> {
        self.now = self.now.max(now);
        let (time, event) = self.queue.pop_due(self.now)?;
        self.fired += 1;
        Some(Fired {
            time,
            late_us: self.now - time,
            event,
        })
    }

    /// Drops every pending event (a stop); the count fired stays.
    pub fn clear(&mut self) {
        while self.queue.pop().is_some() {}
    }

    /// Stamp of the next pending event (to arm a timer).
    pub fn next_time(&self) -> Option<u64> {
        self.queue.oldest()
    }

    /// Pending events.
    pub fn pending(&self) -> usize {
        self.queue.len
    }

    /// Events fired so far.
    pub fn fired(&self) -> u64 {
        self.fired
    }
}
