//! A laser's level streamed with the motion: each control-point stamp the
//! motion source samples also gives the laser's module a level point
//! (`level_point`) on the same time base, so the laser's power follows the
//! planned speed (`M4`, dynamic power) and switches on and off at its
//! place on the path (`M3`, `M5`, rapids) without the motion stopping.
//!
//! A job hands the track its tool commands in queue order, each marked
//! with the segment it starts at ([`ToolTrack::command`]). Sampled at
//! stamp `T`, the track places one point in the interval after it,
//! `(T, T + Δt]`, from the plan (which runs a timer lead ahead of the
//! motors):
//! - where a command changes: at the instant the segment it starts with
//!   begins, to the microsecond, stepping from the old command's level to
//!   the new one's there;
//! - else where the planned speed's slope changes last in the interval (a
//!   segment's start, the end of a ramp: [`Planner::speed_breaks`]);
//! - else at `T + Δt`.
//!
//! The module ramps linearly between points, and a trapezoid's speed is
//! linear between its breaks, so dynamic power (`level × speed / feed`)
//! is exact wherever an interval holds at most one break; rapids switch a
//! laser off (as Grbl's laser mode does). A stop turns the track off
//! before anything else ([`ToolTrack::off`]), so a stream that goes on
//! after a stop never lights the laser again.

use std::collections::VecDeque;

use maxl::blocks::planner::Planner;

use super::drive::MAX_AXES;

/// What a tool does from a segment on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToolCommand {
    /// Its level, 0 (off) to 1 (full) of the tool's duty range.
    pub level: f64,
    /// Its power follows the speed along the path: `level × speed / feed`.
    pub dynamic: bool,
    /// The feed its segments were asked at, units/s: dynamic power's full
    /// speed.
    pub feed: f64,
}

impl ToolCommand {
    /// Off.
    pub const OFF: ToolCommand = ToolCommand {
        level: 0.0,
        dynamic: false,
        feed: 0.0,
    };

    /// Its level at `speed` along the path (units/s).
    pub fn level_at(&self, speed: f64) -> f64 {
        if !self.dynamic {
            return self.level;
        }
        if self.feed <= 0.0 {
            return 0.0;
        }
        self.level * (speed / self.feed).clamp(0.0, 1.0)
    }
}

/// A level point for the tool's module: `level_point`'s time and duties.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LevelPoint {
    /// Synchronized µs.
    pub time: u64,
    /// The PWM duty the ramp from the point before reaches at `time`.
    pub before: f32,
    /// The PWM duty from `time` on (a step where it differs).
    pub after: f32,
}

/// The level stream of one tool.
#[derive(Debug, Clone)]
pub struct ToolTrack {
    /// The tool's key in `[tools]`.
    pub name: String,
    /// Its module's key in `[modules]`.
    pub module: String,
    /// Its PWM output.
    pub channel: u8,
    off_duty: f64,
    on_duty: f64,
    /// Axis slots that carry the path (x, y, z): the speed is theirs.
    path_axes: usize,
    /// Commands not yet in force, by the segment they start at.
    commands: VecDeque<(u64, ToolCommand)>,
    /// The command in force at the last point.
    current: ToolCommand,
    /// The last point sent, and how many intervals ago.
    sent: Option<(LevelPoint, u32)>,
}

/// Intervals a tool at rest may go without a point: a point repeated
/// sends nothing ([`ToolTrack::sample`]), but every this many intervals
/// (about 100 ms) one goes out anyway, so that a point the link lost is
/// made good within that time.
pub const REFRESH_INTERVALS: u32 = 49;

impl ToolTrack {
    /// The track of tool `name` on `module`'s PWM output `channel`, with
    /// duties `off_duty` (level 0) and `on_duty` (level 1); the speed is
    /// that of the first `path_axes` axis slots. Off at first.
    pub fn new(
        name: &str,
        module: &str,
        channel: u8,
        (off_duty, on_duty): (f64, f64),
        path_axes: usize,
    ) -> ToolTrack {
        ToolTrack {
            name: name.into(),
            module: module.into(),
            channel,
            off_duty,
            on_duty,
            path_axes: path_axes.clamp(1, MAX_AXES),
            commands: VecDeque::new(),
            current: ToolCommand::OFF,
            sent: None,
        }
    }

    /// From segment `mark` on (the planner's `queued_total` when the job
    /// reached the command: the next segment queued), the tool does `cmd`.
    /// Marks come in queue order; a command at the same mark as the one
    /// before replaces it.
    pub fn command(&mut self, mark: u64, cmd: ToolCommand) {
        if let Some(back) = self.commands.back_mut() {
            if back.0 == mark {
                back.1 = cmd;
                return;
            }
        }
        if self.last_command() != cmd {
            self.commands.push_back((mark, cmd));
        }
    }

    /// The command the tool ends on once everything queued has run.
    pub fn last_command(&self) -> ToolCommand {
        self.commands.back().map_or(self.current, |c| c.1)
    }

    /// The tool at `level` from the next point on, whatever was queued (a
    /// script's `Tool::set`).
    pub fn set_now(&mut self, level: f64) {
        self.commands.clear();
        let cmd = ToolCommand {
            level,
            dynamic: false,
            feed: 0.0,
        };
        // Mark 0: in force for every segment from here.
        self.commands.push_back((0, cmd));
    }

    /// Drops the commands queued for segments not yet run (the planner
    /// dropped them: a new move replaces them); the one in force stays.
    pub fn drop_queued(&mut self) {
        self.commands.clear();
    }

    /// Off from the next point on, and nothing queued (a stop).
    pub fn off(&mut self) {
        self.set_now(0.0);
    }

    /// The command in force for segment `id`.
    fn command_at(&self, id: u64) -> ToolCommand {
        self.commands
            .iter()
            .rev()
            .find(|(mark, _)| *mark <= id)
            .map_or(self.current, |c| c.1)
    }

    fn duty(&self, level: f64) -> f32 {
        (self.off_duty + level * (self.on_duty - self.off_duty)).clamp(0.0, 1.0) as f32
    }

    /// The speed along the path at synchronized `t_us` as planned.
    fn speed(&self, planner: &Planner<MAX_AXES>, t_us: u64) -> f64 {
        let kin = planner.state_at(t_us as f64);
        kin.vel[..self.path_axes]
            .iter()
            .map(|v| v * v)
            .sum::<f64>()
            .sqrt()
    }

    /// The level point for the interval after stamp `stamp` (`interval_us`
    /// long), from `planner` just after it sampled `stamp`.
    ///
    /// Where nothing changes (no command, no break in the speed's slope,
    /// the same duty before and after as the last point sent) it gives
    /// the last point sent again, which the tool function does not send
    /// on: the module's ramp from that point to the next one is flat, as
    /// the level is. Every [`REFRESH_INTERVALS`] a new one goes out all
    /// the same.
    pub fn sample(
        &mut self,
        planner: &Planner<MAX_AXES>,
        stamp: u64,
        interval_us: u64,
    ) -> LevelPoint {
        let end = stamp + interval_us;
        let breaks = planner.speed_breaks(stamp as f64, end as f64);
        // Where a command changes (at a segment's start), else the last
        // break, else the interval's end; never before or at `stamp`.
        let change = breaks
            .iter()
            .find(|b| b.2 && self.command_at(b.1) != self.command_at(b.1.wrapping_sub(1)));
        let at_break = change.or(breaks.last());
        let time = at_break.map_or(end, |b| (b.0.ceil() as u64).clamp(stamp + 1, end));
        let v = self.speed(planner, time);
        let was = self.current;
        let before = self.duty(self.current.level_at(v));
        let id = planner.segment_at(time as f64);
        let now = self.command_at(id);
        while self.commands.front().is_some_and(|c| c.0 <= id) {
            self.commands.pop_front();
        }
        self.current = now;
        let point = LevelPoint {
            time,
            before,
            after: self.duty(now.level_at(v)),
        };
        if let Some((last, age)) = &mut self.sent {
            // A break in the speed's slope bends only a dynamic level.
            let bends = change.is_some() || (at_break.is_some() && (was.dynamic || now.dynamic));
            let flat = !bends && point.before == last.after && point.after == last.after;
            if flat && *age < REFRESH_INTERVALS {
                *age += 1;
                return *last;
            }
        }
        self.sent = Some((point, 0));
        point
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use maxl::blocks::planner::Limits;

    const DT: u64 = 2048;

    fn planner() -> Planner<MAX_AXES> {
        let limits = Limits::new([200.0; MAX_AXES], [2000.0; MAX_AXES], 0.02).unwrap();
        Planner::new(limits).unwrap()
    }

    fn at(x: f64, y: f64) -> [f64; MAX_AXES] {
        let mut p = [0.0; MAX_AXES];
        p[0] = x;
        p[1] = y;
        p
    }

    fn speed(p: &Planner<MAX_AXES>, t: f64) -> f64 {
        let k = p.state_at(t);
        (k.vel[0].powi(2) + k.vel[1].powi(2)).sqrt()
    }

    /// A rapid, then a dynamic cut of two lines at 50 mm/s round a
    /// corner, then off: the laser is off through the rapid, steps on
    /// where the cut begins (between stamps, to the µs), and between its
    /// points the module's linear ramp is the planned power within 0.1 %
    /// of full, through the corner and every ramp.
    #[test]
    fn a_cut_switches_where_it_begins_and_its_ramps_follow_the_speed() {
        let mut p = planner();
        let mut t = ToolTrack::new("laser", "l", 0, (0.0, 1.0), 3);
        t.command(p.stats().queued_total, ToolCommand::OFF);
        p.line(at(10.0, 0.0), 200.0).unwrap();
        let cut = ToolCommand {
            level: 0.8,
            dynamic: true,
            feed: 50.0,
        };
        t.command(p.stats().queued_total, cut);
        p.line(at(10.0, 20.0), 50.0).unwrap();
        p.line(at(30.0, 20.0), 50.0).unwrap();
        // Off where the cut ends, into a rapid that does not stop there.
        t.command(p.stats().queued_total, ToolCommand::OFF);
        p.line(at(50.0, 0.0), 200.0).unwrap();
        // Sampled as the motion function samples: each stamp, then its
        // point; the plan's truth at every µs kept for the check.
        // Only the points the module receives: the tool function drops
        // a point repeated.
        let mut points: Vec<LevelPoint> = Vec::new();
        let mut truth = Vec::new();
        let mut stamp = 4096;
        let mut stamps = 0;
        while stamp < 1_500_000 {
            p.sample_kin(stamp).unwrap();
            let q = t.sample(&p, stamp, DT);
            stamps += 1;
            let repeated = points.last() == Some(&q);
            if !repeated {
                assert!(q.time > stamp && q.time <= stamp + DT, "{q:?} at {stamp}");
            }
            let mut u = stamp + 1;
            while u <= stamp + DT {
                let id = p.segment_at(u as f64);
                let on = id == 1 || id == 2;
                truth.push((
                    u,
                    if on {
                        0.8 * speed(&p, u as f64) / 50.0
                    } else {
                        0.0
                    },
                ));
                u += 7;
            }
            if !repeated {
                points.push(q);
            }
            stamp += DT;
        }
        // Off, and standing still after the job: a point each refresh.
        let rest = points.iter().filter(|q| q.time > 1_000_000).count();
        let due = (1_500_000 - 1_000_000) / (DT as usize * (REFRESH_INTERVALS as usize + 1));
        assert!(rest.abs_diff(due) <= 1, "{rest} points at rest, {due} due");
        assert!(points.len() < stamps, "{} of {stamps}", points.len());
        let steps: Vec<_> = points.iter().filter(|q| q.before != q.after).collect();
        assert_eq!(steps.len(), 2, "{steps:?}");
        // On where segment 1 began, off where segment 3 began, both
        // between stamps, at speed.
        for (step, id) in steps.iter().zip([1, 3]) {
            let began = p.segment_start(id).unwrap().0;
            assert_eq!(step.time, began.ceil() as u64);
            assert!(step.time % DT != 0, "{step:?}");
        }
        assert!(steps[0].after > 0.05 && steps[1].before > 0.05, "{steps:?}");
        assert_eq!(steps[1].after, 0.0);
        // The module's ramp between points against the plan.
        let mut worst = 0.0f64;
        for (u, want) in truth {
            let i = points.partition_point(|q| q.time <= u);
            let (Some(a), Some(b)) = (i.checked_sub(1).map(|j| points[j]), points.get(i)) else {
                continue;
            };
            let f = (u - a.time) as f64 / (b.time - a.time) as f64;
            let got = f64::from(a.after) + f * f64::from(b.before - a.after);
            worst = worst.max((got - want).abs());
        }
        assert!(worst < 1e-3, "worst {worst}");
        assert!(points.iter().any(|q| (q.after - 0.8).abs() < 1e-6));
    }

    #[test]
    fn a_stop_turns_it_off_at_the_next_point_and_drops_what_waits() {
        let mut p = planner();
        let mut t = ToolTrack::new("laser", "l", 0, (0.1, 0.9), 3);
        let on = ToolCommand {
            level: 1.0,
            dynamic: false,
            feed: 0.0,
        };
        t.command(0, on);
        p.line(at(10.0, 0.0), 10.0).unwrap();
        p.sample_kin(2048).unwrap();
        let q = t.sample(&p, 2048, DT);
        assert!((q.after - 0.9).abs() < 1e-6, "{q:?}");
        t.command(1, ToolCommand::OFF);
        t.off();
        t.command(2, on);
        t.off();
        p.sample_kin(4096).unwrap();
        let q = t.sample(&p, 4096, DT);
        assert!(
            (q.before - 0.9).abs() < 1e-6 && (q.after - 0.1).abs() < 1e-6,
            "{q:?}"
        );
        assert_eq!(t.last_command(), ToolCommand::OFF);
    }
}
