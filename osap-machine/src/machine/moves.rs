//! Motion in machine terms: queued lines and arcs, immediate moves,
//! jogs, dwells, and waiting until the machine stands.

use super::*;

impl Machine {
    pub(crate) fn check_running(&self) -> Result<(), MachineError> {
        match &*self.inner.state.borrow() {
            MachineState::Faulted(r) => Err(MachineError::Faulted(r.clone())),
            MachineState::Stopped => Err(MachineError::Stopped),
            _ => Ok(()),
        }
    }

    /// Checks a target: one coordinate per axis, within travel, homed.
    pub(super) fn check_target(&self, target: &[f64]) -> Result<[f64; MAX_AXES], MachineError> {
        let axes = self.axes();
        if target.len() != axes.len() {
            return Err(MachineError::WrongAxisCount {
                expected: axes.len(),
                axes: axes.join(", "),
                got: target.len(),
            });
        }
        // Where the queue ends: the new move starts there.
        let from = lock_motion(&self.inner.motion).planner.tail();
        let homed = self.inner.homed.lock().unwrap_or_else(|e| e.into_inner());
        let mut out = [0.0; MAX_AXES];
        for (k, (name, &v)) in axes.iter().zip(target).enumerate() {
            let a = &self.inner.cfg.axes[name];
            // An axis the move leaves where it is need not be homed (an
            // extruder pushes filament before x and y home, as on any
            // printer).
            if !homed[k] && v != from[k] {
                return Err(MachineError::NotHomed(name.clone()));
            }
            if !(v.is_finite() && a.min <= v && v <= a.max) {
                return Err(MachineError::OutOfTravel {
                    axis: name.clone(),
                    value: v,
                    min: a.min,
                    max: a.max,
                });
            }
            out[k] = v;
        }
        Ok(out)
    }

    pub(super) fn check_rate(rate: f64) -> Result<f64, MachineError> {
        if rate.is_finite() && rate > 0.0 {
            Ok(rate)
        } else {
            Err(MachineError::BadRate(rate))
        }
    }

    /// Waits until the planner has room for `n` more segments.
    pub(super) async fn wait_for_room(&self, n: usize) -> Result<(), MachineError> {
        let room = maxl::blocks::planner::DEFAULT_CAPACITY - 1;
        self.wait_queued_at_most(room.saturating_sub(n)).await
    }

    /// Segments queued and not yet handed to the motors (a straight move
    /// is one; an arc is one per chord).
    pub fn queued_moves(&self) -> usize {
        lock_motion(&self.inner.motion).planner.stats().pending
    }

    /// How many segments have been queued since start: a mark for
    /// [`Machine::wait_executed`].
    pub fn queued_total(&self) -> u64 {
        lock_motion(&self.inner.motion).planner.stats().queued_total
    }

    /// Waits until the motors have finished the first `mark` segments
    /// queued ([`Machine::queued_total`] when a command was reached), so a
    /// command takes effect where the job put it, without stopping the
    /// motion. Fails if the machine stops meanwhile.
    pub async fn wait_executed(&self, mark: u64) -> Result<(), MachineError> {
        let mut status = self.inner.status.clone();
        loop {
            self.check_running()?;
            if status.borrow_and_update().executed >= mark || self.queued_moves() == 0 {
                return Ok(());
            }
            status.changed().await.map_err(|_| MachineError::Stopped)?;
        }
    }

    /// Waits until at most `n` segments are queued ahead of the motors.
    /// The queue holds thousands of moves; a script that generates motion
    /// without end (a soak, a jog, a sensor-driven path) waits here to stay
    /// a few moves ahead rather than minutes ahead. Fails if the machine
    /// stops meanwhile.
    pub async fn wait_queued_at_most(&self, n: usize) -> Result<(), MachineError> {
        let mut status = self.inner.status.clone();
        loop {
            self.check_running()?;
            if self.queued_moves() <= n {
                return Ok(());
            }
            status.changed().await.map_err(|_| MachineError::Stopped)?;
        }
    }

    /// Queues a straight move to `target` (one coordinate per axis) at up to
    /// `rate` units/s, planned with lookahead after the moves queued before
    /// it. Returns once queued (waiting for room in the queue if needed).
    pub async fn goto_via_queue(
        &self,
        target: impl AsRef<[f64]>,
        rate: f64,
    ) -> Result<(), MachineError> {
        let to = self.check_target(target.as_ref())?;
        let rate = Self::check_rate(rate)?;
        self.wait_for_room(1).await?;
        self.check_running()?;
        let mut m = lock_motion(&self.inner.motion);
        m.planner.line(to, rate)?;
        m.mark_busy();
        Ok(())
    }

    /// [`Machine::goto_via_queue`]: a queued straight line.
    pub async fn line(&self, target: impl AsRef<[f64]>, rate: f64) -> Result<(), MachineError> {
        self.goto_via_queue(target, rate).await
    }

    /// Queues an arc in the xy plane around `center` (x, y) to `target`
    /// (other axes move linearly), chorded within 2 µm.
    pub async fn arc(
        &self,
        target: impl AsRef<[f64]>,
        center: [f64; 2],
        clockwise: bool,
        rate: f64,
    ) -> Result<(), MachineError> {
        let to = self.check_target(target.as_ref())?;
        let rate = Self::check_rate(rate)?;
        if self.axes().len() < 2 {
            return Err(MachineError::Unsupported(
                "arcs need two axes (x and y)".into(),
            ));
        }
        let arc = PlanArc {
            end: to,
            plane: (0, 1),
            center,
            clockwise,
            chord_tolerance: 0.002,
        };
        // The arc's bulge must stay within travel too.
        let tail = lock_motion(&self.inner.motion).planner.tail();
        let chords = arc.chords(tail)?;
        let n = target.as_ref().len();
        for p in &chords {
            self.check_target(&p[..n])?;
        }
        self.wait_for_room(chords.len()).await?;
        self.check_running()?;
        let mut m = lock_motion(&self.inner.motion);
        m.planner.arc(&arc, rate)?;
        m.mark_busy();
        Ok(())
    }

    /// Waits until every queued move has run and the motors stand, then
    /// `seconds` longer.
    pub async fn dwell(&self, seconds: f64) -> Result<(), MachineError> {
        self.idle().await?;
        if seconds.is_finite() && seconds > 0.0 {
            tokio::time::sleep(Duration::from_secs_f64(seconds)).await;
        }
        Ok(())
    }

    /// Holds the path where it comes to rest for `seconds`: waits until
    /// the planner has run every queued move to its end (a timer lead
    /// ahead of the motors), then the moves queued next start `seconds`
    /// after that end, on the synchronized clock. A dwell at a place on the
    /// path (a pen settling) without the stop-and-go of [`Machine::dwell`]:
    /// the stream never stops, so no timer lead is lost.
    pub async fn hold_path(&self, seconds: f64) -> Result<(), MachineError> {
        let mut status = self.inner.status.clone();
        loop {
            self.check_running()?;
            let s = *status.borrow_and_update();
            if lock_motion(&self.inner.motion).is_idle() && !s.busy && s.rest_stamp != 0 {
                break;
            }
            status.changed().await.map_err(|_| MachineError::Stopped)?;
        }
        let mut m = lock_motion(&self.inner.motion);
        let last = m.planner.last_stamp().unwrap_or(0);
        let end = m.planner.rest_since().unwrap_or(last as f64);
        let hold = (seconds.max(0.0) * 1e6).round();
        let start = ((end + hold).ceil() as u64).max(last);
        m.planner.start(start)?;
        Ok(())
    }

    /// Moves to `target` now and waits until the machine stands there:
    /// moves still queued are stopped first (a controlled stop).
    pub async fn goto_now(&self, target: impl AsRef<[f64]>, rate: f64) -> Result<(), MachineError> {
        let to = self.check_target(target.as_ref())?;
        let rate = Self::check_rate(rate)?;
        self.check_running()?;
        {
            let mut m = lock_motion(&self.inner.motion);
            m.halt_path()?;
            m.planner.line(to, rate)?;
            m.mark_busy();
        }
        self.idle().await
    }

    /// Waits until every queued move has run and the motors stand at the
    /// end. Woken by the motion source's reports, not by polling; fails if
    /// the machine faults meanwhile.
    pub async fn idle(&self) -> Result<(), MachineError> {
        let mut status = self.inner.status.clone();
        let mut state = self.inner.state.subscribe();
        let rest = loop {
            self.check_running()?;
            let s = *status.borrow_and_update();
            let idle = lock_motion(&self.inner.motion).is_idle();
            if idle && !s.busy && s.rest_stamp != 0 {
                break s.rest_stamp;
            }
            tokio::select! {
                r = status.changed() => r.map_err(|_| MachineError::Stopped)?,
                r = state.changed() => r.map_err(|_| MachineError::Stopped)?,
            }
        };
        self.wait_motors_past(rest).await?;
        self.check_running()
    }

    /// Stops motion: every axis decelerates within its limits along the
    /// path and queued moves are dropped. Returns once the motors stand
    /// (homing and probing stop a seek this way; [`Machine::halt`] also
    /// halts every module and switches every tool off).
    pub(crate) async fn stop_motion(&self) -> Result<(), MachineError> {
        {
            let mut m = lock_motion(&self.inner.motion);
            m.halt_path()?;
            m.mark_busy();
        }
        let mut status = self.inner.status.clone();
        loop {
            let s = *status.borrow_and_update();
            if lock_motion(&self.inner.motion).is_idle() && !s.busy {
                break;
            }
            status.changed().await.map_err(|_| MachineError::Stopped)?;
        }
        let rest = status.borrow().rest_stamp;
        self.wait_motors_past(rest).await
    }

    /// Sleeps until the motors have run the points up to stamp `rest`: a
    /// module evaluates a point two intervals after its stamp.
    pub(super) async fn wait_motors_past(&self, rest: u64) -> Result<(), MachineError> {
        let done = rest + 2 * u64::from(INTERVAL_US);
        let now = self.now_us().await?;
        if done > now {
            tokio::time::sleep(Duration::from_micros(done - now)).await;
        }
        self.confirm_motors_report().await
    }

    /// Waits for a status report from every motor module sent after now:
    /// the time alone says the motion should have run, a report says the
    /// module was there to run it. A module silent for the link-loss time
    /// faults the machine, as the watchdog would.
    pub(super) async fn confirm_motors_report(&self) -> Result<(), MachineError> {
        let since = tokio::time::Instant::now();
        let deadline = since + LINK_LOST_AFTER;
        let keys: Vec<String> = lock_motion(&self.inner.motion)
            .drive
            .motors()
            .iter()
            .map(|m| m.module.clone())
            .collect();
        loop {
            self.check_running()?;
            let silent = {
                let r = monitor::lock(&self.inner.reports);
                keys.iter()
                    .find(|k| r.seen.get(*k).is_none_or(|s| s.2 < since))
                    .cloned()
            };
            let Some(key) = silent else {
                return Ok(());
            };
            if tokio::time::Instant::now() >= deadline {
                let _ = self.inner.events.send(MachineEvent::LinkLost {
                    module: key.clone(),
                });
                let reason = format!("module {key} stopped answering");
                self.fault_and_stop(reason.clone());
                return Err(MachineError::Faulted(reason));
            }
            // Reports come every status period; look again at half that.
            tokio::time::sleep(Duration::from_micros(u64::from(STATUS_PERIOD_US / 2))).await;
        }
    }

    /// Moves one axis by `delta` and waits until it stands. A homed axis
    /// stays within its travel; an axis not yet homed moves relative to
    /// wherever it is (the machine cannot know its travel then: watch it).
    pub async fn jog(&self, axis: &str, delta: f64, rate: f64) -> Result<(), MachineError> {
        let k = self
            .axes()
            .iter()
            .position(|a| a == axis)
            .ok_or_else(|| MachineError::UnknownAxis(axis.into()))?;
        let rate = Self::check_rate(rate)?;
        if !delta.is_finite() {
            return Err(MachineError::OutOfTravel {
                axis: axis.into(),
                value: delta,
                min: f64::NEG_INFINITY,
                max: f64::INFINITY,
            });
        }
        self.check_running()?;
        self.idle().await?;
        let homed = self.inner.homed.lock().unwrap_or_else(|e| e.into_inner())[k];
        {
            let mut m = lock_motion(&self.inner.motion);
            let mut to = m.planner.tail();
            to[k] += delta;
            if homed {
                let a = &self.inner.cfg.axes[axis];
                if !(a.min..=a.max).contains(&to[k]) {
                    return Err(MachineError::OutOfTravel {
                        axis: axis.into(),
                        value: to[k],
                        min: a.min,
                        max: a.max,
                    });
                }
            }
            m.planner.line(to, rate)?;
            m.mark_busy();
        }
        self.idle().await
    }
}
