//! Hot start: when to preset the clock from a saved rate, and when to save
//! the rate it learned. Firmware and simulated modules run this same
//! policy after every runtime poll ([`RateKeeper::poll`]).
//!
//! **Preset.** A rate is worth restoring only against the source it was
//! learned from: a different root runs at its own rate. The wire carries
//! no root id, so the source is what a module can see ([`RateSource`]:
//! the link it follows and its tier). At boot the saved record is *armed*;
//! on the first poll after the clock starts following, it is applied
//! (through `Clock::set_rate_ppb`) if the source matches and dropped
//! otherwise, which leaves a cold start. One sample in, the controller has
//! learned nothing a preset would overwrite.
//!
//! **Save.** Only a settled clock's rate is saved, [`SavePolicy::hold`]
//! after it first settled on the source it follows, and only when it differs from the
//! saved one by more than [`SavePolicy::threshold_ppb`] (or the source
//! changed); never twice within [`SavePolicy::min_interval`], nor in
//! the first `min_interval` after boot while a record of the same
//! source exists; and not while motion is queued or running, since a
//! flash write can stall the step generator. That bounds writes to one per `min_interval` of
//! uptime plus at most one per boot on a changed source; with the log's
//! append-until-full sector ([`crate::rate_store`]) the erase cycles a year
//! follow (docs/clock-sync.md, "Hot start").
use osap_core::clock::{Clock, SyncState};
use osap_core::{Duration, Instant};

use crate::rate_store::{RateFlash, RateRecord, RateSource, RateStore, RateStoreError};

/// When a rate is saved.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SavePolicy {
    /// How long the clock must have been settled before its rate is saved:
    /// long enough that the rate is the fitted one, not a transient.
    pub hold: Duration,
    /// Least time between saves (and from boot to the first save when a
    /// record of the same source exists).
    pub min_interval: Duration,
    /// Least change of the rate worth a save, ppb.
    pub threshold_ppb: u32,
}

impl Default for SavePolicy {
    /// Settled for 60 s, at most one save per 10 min, on a change of more
    /// than 0.5 ppm (a quarter of the 2 ppm the clock allows a hot-started
    /// rate to be off).
    fn default() -> Self {
        SavePolicy {
            hold: Duration::from_secs(60),
            min_interval: Duration::from_secs(600),
            threshold_ppb: 500,
        }
    }
}

/// What became of the saved rate at boot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Preset {
    /// Nothing saved: a cold start.
    Nothing,
    /// Waiting for the clock to follow a source.
    Armed,
    /// Applied: a hot start.
    Applied,
    /// Saved against another source (or this runtime is the root): a cold
    /// start.
    Declined,
}

/// What a poll did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HotStartEvent {
    /// The saved rate (ppb) was preset.
    Preset(i32),
    /// The saved rate was learned against another source and is unused.
    Declined(RateSource),
    /// The rate was saved.
    Saved(RateRecord),
}

/// The source `clock` follows now, if it follows one.
pub fn source_of<const L: usize>(clock: &Clock<L>) -> Option<RateSource> {
    let links = clock.followed_links();
    (clock.state() == SyncState::Synced && links != 0).then(|| RateSource {
        link: links.trailing_zeros() as u8,
        tier: clock.tier(),
    })
}

/// The policy's state over one boot.
#[derive(Debug, Clone)]
pub struct HotStart {
    policy: SavePolicy,
    /// The rate on flash: what the preset uses and saves compare with.
    saved: Option<(i32, RateSource)>,
    preset: Preset,
    /// Local time of the first poll.
    boot: Option<Instant>,
    /// When the clock was first settled on the source it follows.
    settled_since: Option<(Instant, RateSource)>,
    last_save: Option<Instant>,
}

impl HotStart {
    /// The policy at boot, with the newest saved record.
    pub fn new(saved: Option<RateRecord>, policy: SavePolicy) -> Self {
        HotStart {
            policy,
            saved: saved.map(|r| (r.rate_ppb, r.source)),
            preset: if saved.is_some() {
                Preset::Armed
            } else {
                Preset::Nothing
            },
            boot: None,
            settled_since: None,
            last_save: None,
        }
    }

    /// What became of the saved rate.
    pub fn preset(&self) -> Preset {
        self.preset
    }

    /// Call after every runtime poll at local time `now`. Presets `clock`
    /// when it first follows the saved rate's source; returns the event,
    /// and in `save` the rate and source to save now, if one is due.
    pub fn poll<const L: usize>(
        &mut self,
        now: Instant,
        clock: &mut Clock<L>,
    ) -> (Option<HotStartEvent>, Option<(i32, RateSource)>) {
        let boot = *self.boot.get_or_insert(now);
        if clock.config().root {
            // The root's rate is its own: nothing to restore or save.
            if self.preset == Preset::Armed {
                self.preset = Preset::Declined;
            }
            return (None, None);
        }
        let source = source_of(clock);
        let mut event = None;
        if let (Preset::Armed, Some(src), Some((ppb, saved))) = (self.preset, source, self.saved) {
            if src == saved {
                clock.set_rate_ppb(now, ppb);
                self.preset = Preset::Applied;
                event = Some(HotStartEvent::Preset(ppb));
            } else {
                self.preset = Preset::Declined;
                event = Some(HotStartEvent::Declined(saved));
            }
        }
        // The hold runs from the first settled poll on this source; a
        // moment unsettled (a noisy USB exchange) does not restart it,
        // losing or changing the source does.
        let Some(src) = source else {
            self.settled_since = None;
            return (event, None);
        };
        if self.settled_since.is_some_and(|(_, s)| s != src) {
            self.settled_since = None;
        }
        if !clock.is_settled() {
            return (event, None);
        }
        let (since, _) = *self.settled_since.get_or_insert((now, src));
        if now - since < self.policy.hold {
            return (event, None);
        }
        if clock.motion_active() {
            // A flash write stalls the program (on the RP2040 every write
            // runs with execute-in-place off): wait for the axis to stand.
            return (event, None);
        }
        let rate = clock.rate_ppb();
        let waited = |from: Instant| now - from >= self.policy.min_interval;
        let due = match self.saved {
            Some((ppb, saved)) if saved == src => {
                rate.abs_diff(ppb) > self.policy.threshold_ppb
                    && waited(self.last_save.unwrap_or(boot))
            }
            // Nothing saved for this source: once settled, unless a save
            // was made this boot less than min_interval ago.
            _ => self.last_save.is_none_or(waited),
        };
        (event, due.then_some((rate, src)))
    }

    /// Tells the policy that a save was attempted at `now`; `saved` is the
    /// rate and source now on flash if it succeeded. A failed save is not
    /// retried before `min_interval`.
    pub fn saved(&mut self, now: Instant, saved: Option<(i32, RateSource)>) {
        self.last_save = Some(now);
        if saved.is_some() {
            self.saved = saved;
        }
    }
}

/// The rate store and the policy together: what a module runs.
pub struct RateKeeper<F> {
    store: RateStore<F>,
    policy: HotStart,
}

impl<F> core::fmt::Debug for RateKeeper<F> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("RateKeeper")
            .field("preset", &self.policy.preset())
            .finish_non_exhaustive()
    }
}

impl<F: RateFlash> RateKeeper<F> {
    /// Opens the rate log in `flash` and arms its newest record.
    pub fn open(flash: F, policy: SavePolicy) -> Self {
        let store = RateStore::open(flash);
        let policy = HotStart::new(store.newest(), policy);
        RateKeeper { store, policy }
    }

    /// The store.
    pub fn store(&self) -> &RateStore<F> {
        &self.store
    }

    /// The flash, back.
    pub fn into_inner(self) -> F {
        self.store.into_inner()
    }

    /// What became of the saved rate.
    pub fn preset(&self) -> Preset {
        self.policy.preset()
    }

    /// Call after every runtime poll at local time `now`: presets `clock`
    /// or saves its rate as the policy says. A failed save is the error
    /// (the event of the same poll, a preset, is then not reported).
    pub fn poll<const L: usize>(
        &mut self,
        now: Instant,
        clock: &mut Clock<L>,
    ) -> Result<Option<HotStartEvent>, RateStoreError<F::Error>> {
        let (event, due) = self.policy.poll(now, clock);
        let Some((rate, source)) = due else {
            return Ok(event);
        };
        match self.store.append(rate, source) {
            Ok(record) => {
                self.policy.saved(now, Some((rate, source)));
                Ok(Some(HotStartEvent::Saved(record)))
            }
            Err(e) => {
                self.policy.saved(now, None);
                Err(e)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rate_store::RamRateFlash;
    use osap_core::clock::{TimeConfig, TimeReply};
    use osap_core::SystemInstant;

    type Sector = RamRateFlash<256>;

    const POLICY: SavePolicy = SavePolicy {
        hold: Duration::from_secs(1),
        min_interval: Duration::from_secs(10),
        threshold_ppb: 500,
    };

    /// A module's clock and a tier-0 neighbour on `link` whose time runs
    /// `ppm` fast against our oscillator: one exchange every 50 ms, the
    /// keeper polled after each.
    struct Bench {
        clock: Clock<2>,
        link: usize,
        ppm: f64,
        /// Local time of the next request.
        sent: u64,
        events: std::vec::Vec<(u64, HotStartEvent)>,
    }

    extern crate std;

    impl Bench {
        fn new(link: usize, ppm: f64) -> Self {
            Bench {
                clock: Clock::new(TimeConfig::default()),
                link,
                ppm,
                sent: 10_000,
                events: std::vec::Vec::new(),
            }
        }

        /// Exchanges and polls until local time `until`.
        fn run<F: RateFlash>(&mut self, keeper: &mut RateKeeper<F>, until: u64)
        where
            F::Error: core::fmt::Debug,
        {
            while self.sent < until {
                let rtt = 200;
                let mid = self.sent as f64 + rtt as f64 / 2.0;
                let reply = TimeReply {
                    request_time: Instant::from_micros(self.sent),
                    responder_time: SystemInstant::from_micros(
                        (mid * (1.0 + self.ppm * 1e-6) + 1_000.0) as u64,
                    ),
                    responder_tier: 0,
                };
                let now = self.sent + rtt;
                self.clock
                    .on_reply(self.link, &reply, Instant::from_micros(now));
                if let Some(e) = keeper
                    .poll(Instant::from_micros(now), &mut self.clock)
                    .unwrap()
                {
                    self.events.push((now, e));
                }
                self.sent += 50_000;
            }
        }

        fn saves(&self) -> std::vec::Vec<(u64, RateRecord)> {
            self.events
                .iter()
                .filter_map(|&(t, e)| match e {
                    HotStartEvent::Saved(r) => Some((t, r)),
                    _ => None,
                })
                .collect()
        }
    }

    #[test]
    fn saves_once_settled_for_the_hold_and_not_before() {
        let mut sector = Sector::erased();
        let mut keeper = RateKeeper::open(&mut sector, POLICY);
        assert_eq!(keeper.preset(), Preset::Nothing);
        let mut b = Bench::new(0, 20.0);
        // Settling takes seconds; nothing is saved while it does.
        let mut settled_at = None;
        while b.sent < 8_000_000 {
            let until = b.sent + 1;
            b.run(&mut keeper, until);
            if settled_at.is_none() && b.clock.is_settled() {
                settled_at = Some(b.sent);
            }
        }
        let settled_at = settled_at.expect("settled");
        let saves = b.saves();
        assert_eq!(saves.len(), 1, "{saves:?}");
        let (at, r) = saves[0];
        assert!(
            at >= settled_at - 50_000 + POLICY.hold.as_micros(),
            "saved at {at}"
        );
        assert!(
            at <= settled_at + POLICY.hold.as_micros() + 100_000,
            "saved at {at}"
        );
        assert_eq!(r.source, RateSource { link: 0, tier: 1 });
        // The clock's rate makes a 20 ppm fast neighbour's time.
        assert!((r.rate_ppb - 20_000).abs() < 1_000, "{r:?}");
        let _ = keeper.into_inner();
        assert_eq!(RateStore::open(&mut sector).newest(), Some(r));
    }

    #[test]
    fn threshold_and_interval_bound_the_saves() {
        let mut sector = Sector::erased();
        let mut keeper = RateKeeper::open(&mut sector, POLICY);
        let mut b = Bench::new(0, 20.0);
        b.run(&mut keeper, 60_000_000);
        // A steady rate: one save in a minute, however long it runs.
        assert_eq!(b.saves().len(), 1);
        // The oscillator moves by 2 ppm: saved again (a save may catch
        // the rate on its way), never sooner than min_interval after the
        // last save.
        b.ppm = 22.0;
        b.run(&mut keeper, 120_000_000);
        let saves = b.saves();
        assert!((2..=3).contains(&saves.len()), "{saves:?}");
        for w in saves.windows(2) {
            assert!(
                w[1].0 - w[0].0 >= POLICY.min_interval.as_micros(),
                "{saves:?}"
            );
        }
        let last = saves.last().unwrap().1;
        assert!((last.rate_ppb - 22_000).abs() < 500, "{saves:?}");
        // A move below the threshold: no save.
        let n = saves.len();
        b.ppm = 22.2;
        b.run(&mut keeper, 200_000_000);
        assert_eq!(b.saves().len(), n);
        assert_eq!(keeper.store().erases(), 0);
    }

    #[test]
    fn a_reboot_presets_the_saved_rate_at_the_first_follow() {
        let mut sector = Sector::erased();
        let mut keeper = RateKeeper::open(&mut sector, POLICY);
        let mut b = Bench::new(1, -35.0);
        b.run(&mut keeper, 10_000_000);
        let saved = b.saves()[0].1;
        assert_eq!(saved.source, RateSource { link: 1, tier: 1 });
        let _ = keeper.into_inner();

        // Reboot: a fresh clock, the same source.
        let mut keeper = RateKeeper::open(&mut sector, POLICY);
        assert_eq!(keeper.preset(), Preset::Armed);
        let mut b = Bench::new(1, -35.0);
        b.run(&mut keeper, 10_001);
        assert_eq!(keeper.preset(), Preset::Applied);
        assert_eq!(b.events[0].1, HotStartEvent::Preset(saved.rate_ppb));
        assert!((b.clock.rate_ppb() - saved.rate_ppb).abs() < 2);
        // The same rate: no save within the minimum interval of boot.
        b.run(&mut keeper, 9_000_000);
        assert!(b.clock.is_settled());
        assert!(b.saves().is_empty());
    }

    #[test]
    fn another_source_is_a_cold_start_and_gets_its_own_record() {
        let mut sector = Sector::erased();
        let mut keeper = RateKeeper::open(&mut sector, POLICY);
        let mut b = Bench::new(0, 40.0);
        b.run(&mut keeper, 10_000_000);
        assert_eq!(b.saves().len(), 1);
        let _ = keeper.into_inner();

        // Reboot onto link 1: the record of link 0 is not used.
        let mut keeper = RateKeeper::open(&mut sector, POLICY);
        let mut b = Bench::new(1, -10.0);
        b.run(&mut keeper, 10_001);
        assert_eq!(keeper.preset(), Preset::Declined);
        assert_eq!(
            b.events[0].1,
            HotStartEvent::Declined(RateSource { link: 0, tier: 1 })
        );
        assert!(b.clock.rate_ppb().abs() < 1_000, "{}", b.clock.rate_ppb());
        // Once settled it saves the new source's rate without waiting for
        // the minimum interval.
        b.run(&mut keeper, 10_000_000);
        let saves = b.saves();
        assert_eq!(saves.len(), 1);
        assert_eq!(saves[0].1.source, RateSource { link: 1, tier: 1 });
        assert!((saves[0].1.rate_ppb + 10_000).abs() < 1_000);
    }

    #[test]
    fn the_root_neither_presets_nor_saves() {
        let mut sector = Sector::erased();
        {
            let mut store = RateStore::open(&mut sector);
            store
                .append(5_000, RateSource { link: 0, tier: 1 })
                .unwrap();
        }
        let mut keeper = RateKeeper::open(&mut sector, POLICY);
        let mut clock: Clock<2> = Clock::new(TimeConfig {
            root: true,
            ..TimeConfig::default()
        });
        for t in 0..100u64 {
            assert_eq!(
                keeper.poll(Instant::from_micros(t * 1_000_000), &mut clock),
                Ok(None)
            );
        }
        assert_eq!(keeper.preset(), Preset::Declined);
        assert_eq!(clock.rate_ppb(), 0);
        let _ = keeper.into_inner();
        assert_eq!(sector.writes, 1);
    }

    #[test]
    fn a_failed_save_is_reported_and_not_retried_at_once() {
        let mut sector = Sector::erased();
        sector.fail = true;
        let mut keeper = RateKeeper::open(&mut sector, POLICY);
        let mut clock: Clock<2> = Clock::new(TimeConfig::default());
        let mut errors = 0;
        let mut sent = 10_000;
        let mut attempts = std::vec::Vec::new();
        while sent < 20_000_000 {
            let reply = TimeReply {
                request_time: Instant::from_micros(sent),
                responder_time: SystemInstant::from_micros(
                    ((sent + 100) as f64 * (1.0 + 20e-6)) as u64,
                ),
                responder_tier: 0,
            };
            clock.on_reply(0, &reply, Instant::from_micros(sent + 200));
            if keeper
                .poll(Instant::from_micros(sent + 200), &mut clock)
                .is_err()
            {
                errors += 1;
                attempts.push(sent + 200);
            }
            sent += 50_000;
        }
        // Settled after a few seconds plus the hold: one attempt, then
        // none for min_interval.
        assert_eq!(errors, 2, "{attempts:?}");
        assert!(attempts[0] < 10_000_000);
        assert!(attempts[1] - attempts[0] >= POLICY.min_interval.as_micros());
        assert!(attempts[1] - attempts[0] < POLICY.min_interval.as_micros() + 100_000);
    }

    #[test]
    fn no_save_while_motion_is_queued() {
        let mut sector = Sector::erased();
        let mut keeper = RateKeeper::open(&mut sector, POLICY);
        let mut b = Bench::new(0, 20.0);
        // Motion queued once synchronised (not yet settled).
        b.run(&mut keeper, 1_000_000);
        assert!(!b.clock.is_settled());
        b.clock.set_motion_active(true);
        b.run(&mut keeper, 30_000_000);
        assert!(b.clock.is_settled());
        assert!(b.saves().is_empty());
        // The axis stands: saved at the next poll.
        b.clock.set_motion_active(false);
        b.run(&mut keeper, 30_100_000);
        assert_eq!(b.saves().len(), 1);
        assert!(b.saves()[0].0 <= 30_060_200);
    }
}
