//! One segment's geometry, its limits and its speed profile (trapezoidal,
//! or jerk-limited), and the junction speed between two segments.
//!
//! # Jerk-limited ramps
//!
//! With a finite jerk `j`, every change of speed from `u` to `w` is an
//! S-shaped ramp whose acceleration rises from 0 at `j`, holds at most
//! `a`, and falls back to 0 at `j`: with `Δv = |w − u|`, it lasts
//! `Δv/a + a/j` when `Δv ≥ a²/j` (it reaches `a`), else `2√(Δv/j)`
//! (it peaks at `√(Δv·j)`). Its speed is point-symmetric about its middle,
//! so it covers `(u + w)/2` times its duration. Every segment starts and
//! ends at zero acceleration, so the acceleration is continuous through
//! every junction; with `j = ∞` the ramps are the trapezoid's, exactly.

// Index loops run over several `[f64; N]` at once.
#![allow(clippy::needless_range_loop)]

use super::limits::{Limits, VectorLimits};
use super::model::AccelModel;

/// Components below this are treated as zero when dividing a limit by a
/// direction component.
const TINY: f64 = 1e-12;

/// A straight segment with its direction-dependent limits and planning state.
#[derive(Clone, Debug)]
pub(crate) struct Segment<const N: usize> {
    pub id: u64,
    pub start: [f64; N],
    pub end: [f64; N],
    /// The change of each axis per unit of `len`: a unit vector over the
    /// toolhead's axes when they move (the others follow in proportion),
    /// else over all axes.
    pub dir: [f64; N],
    /// Length along the toolhead's axes, or over all axes when the
    /// toolhead stands (see [`VectorLimits::path_axes`]).
    pub len: f64,
    /// The toolhead's axes move: the vector limits and the junction's
    /// cornering model apply.
    pub on_path: bool,
    /// The requested feed (mm/s), before the feed scale.
    pub feed: f64,
    /// Largest speed keeping every axis within its speed limit along `dir`.
    pub v_axis: f64,
    /// Largest speed: the scaled feed and `v_axis`.
    pub v_max: f64,
    /// Largest acceleration keeping every axis within its limit along `dir`
    /// (and within the acceleration model's at the speeds reached).
    pub acc: f64,
    /// The acceleration the limits alone allow along `dir`.
    pub acc_cap: f64,
    /// Speed-dependent acceleration from the model (trapezoidal profiles
    /// only); `acc` is then its slowest band's. Boxed: most planners have
    /// no model, and the queue's segments stay small.
    pub bands: Option<Box<AccelBands>>,
    /// Largest jerk keeping every axis within its limit along `dir`
    /// (`f64::INFINITY`: trapezoidal profiles).
    pub jerk: f64,
    /// Largest entry speed the junction with the previous segment allows.
    pub junction_max: f64,
    /// Slowest entry speed reachable at full deceleration from the entry the
    /// running segment fixed, as of the last full replan (0 unless a lower
    /// feed scale leaves the path above its new speed limit for a while).
    pub floor: f64,
    /// Entry-speed bound from the backward pass (reaching rest at the
    /// tail), squared: the passes work in v², as Klipper's, with no root
    /// in their chain.
    pub back2: f64,
    /// Planned entry speed of the acceleration-limited lookahead (before
    /// the minimum cruise ratio's caps), squared.
    pub entry2: f64,
    /// Minimum cruise ratio: the smoothed pass's forward bound on the entry
    /// (v², mm²/s²), `min(junction², previous + 2·a'·L_previous)`.
    pub mcr_fwd: f64,
    /// Minimum cruise ratio: the smoothed entry (v²), the forward bound
    /// limited by reaching the next smoothed entry at `a'`.
    pub mcr_start: f64,
    /// Minimum cruise ratio: the peak (v²) of the smoothed profile's hill
    /// this segment lies on if the smoothed profile rises at its start,
    /// negative if it falls there.
    pub hill: f64,
    /// Square of the largest speed within the segment the minimum cruise
    /// ratio allows (`f64::INFINITY` with the ratio off).
    pub cruise2: f64,
}

/// How many leading axes carry the path under `vector` (all for 0).
pub(crate) fn path_axes<const N: usize>(vector: &VectorLimits) -> usize {
    match vector.path_axes {
        0 => N,
        k => k.min(N),
    }
}

/// The largest value `limit[i] / |dir[i]|` keeps within every axis's limit.
pub(crate) fn along<const N: usize>(limit: &[f64; N], dir: &[f64; N]) -> f64 {
    let mut m = f64::INFINITY;
    for i in 0..N {
        let c = dir[i].abs();
        if c > TINY {
            m = m.min(limit[i] / c);
        }
    }
    m
}

impl<const N: usize> Segment<N> {
    /// A segment from `start` to `end` at up to `feed` × `scale`, or `None`
    /// if it is too short to move.
    ///
    /// `Err(())` if the length overflows (finite coordinates far apart).
    pub(crate) fn new(
        id: u64,
        start: [f64; N],
        end: [f64; N],
        feed: f64,
        scale: f64,
        limits: &Limits<N>,
        vector: &VectorLimits,
    ) -> Result<Option<Self>, ()> {
        let mut d = [0.0; N];
        let (mut len2, mut path2) = (0.0, 0.0);
        let k = path_axes::<N>(vector);
        for i in 0..N {
            d[i] = end[i] - start[i];
            len2 += d[i] * d[i];
            if i < k {
                path2 += d[i] * d[i];
            }
        }
        let all = len2.sqrt();
        if !all.is_finite() {
            return Err(());
        }
        if all <= 1e-9 {
            return Ok(None);
        }
        let path = path2.sqrt();
        let on_path = path > 1e-9;
        let len = if on_path { path } else { all };
        for c in d.iter_mut() {
            *c /= len;
        }
        let mut seg = Segment {
            id,
            start,
            end,
            dir: d,
            len,
            on_path,
            feed,
            v_axis: 0.0,
            v_max: 0.0,
            acc: 0.0,
            acc_cap: 0.0,
            bands: None,
            jerk: f64::INFINITY,
            junction_max: 0.0,
            floor: 0.0,
            back2: 0.0,
            entry2: 0.0,
            mcr_fwd: 0.0,
            mcr_start: 0.0,
            hill: 0.0,
            cruise2: f64::INFINITY,
        };
        seg.set_limits(limits, vector, scale);
        Ok(Some(seg))
    }

    /// Sets the speed and acceleration limits along the direction: the
    /// per-axis ones and the vector ones, the feed scaled by `scale`.
    pub(crate) fn set_limits(&mut self, limits: &Limits<N>, vector: &VectorLimits, scale: f64) {
        self.v_axis = along(&limits.max_vel, &self.dir);
        self.acc = along(&limits.max_acc, &self.dir);
        self.jerk = along(&limits.max_jerk, &self.dir);
        if self.on_path {
            self.v_axis = self.v_axis.min(vector.max_speed);
            self.acc = self.acc.min(vector.max_accel);
            self.jerk = self.jerk.min(vector.max_jerk);
        }
        self.acc_cap = self.acc;
        self.bands = None;
        self.scale_feed(scale);
    }

    /// Bounds the acceleration by `model` at the highest speed this segment
    /// can reach: its speed limit, or its junction speed plus a ramp over
    /// its length at the model's acceleration at rest (whichever is lower),
    /// and at least the floor a lowered feed scale left. Uses the current
    /// `junction_max` and `floor`.
    pub(crate) fn apply_model(&mut self, model: &dyn AccelModel<N>) {
        let at_rest = self.acc_cap.min(model.max_accel(&self.dir, &self.dir, 0.0));
        let reach = (self.junction_max * self.junction_max + 2.0 * at_rest * self.len).sqrt();
        let top = self.v_max.max(self.floor).min(reach.max(self.floor));
        // A model that leaves nothing at a speed still has to let the
        // segment move: the file's validation keeps it from coming to this.
        let at = |v: f64| {
            self.acc_cap
                .min(model.max_accel(&self.dir, &self.dir, v))
                .max(1e-9 * self.acc_cap)
        };
        self.acc = at(top);
        self.bands = None;
        if self.jerk.is_infinite() && top > 0.0 {
            // Each band accelerates at what the model gives at its top
            // speed, which holds over the whole band.
            let mut b = AccelBands {
                top: [f64::INFINITY; ACCEL_BANDS],
                accel: [self.acc; ACCEL_BANDS],
            };
            for k in 0..ACCEL_BANDS {
                let edge = top * (k + 1) as f64 / ACCEL_BANDS as f64;
                b.accel[k] = at(edge);
                if k + 1 < ACCEL_BANDS {
                    b.top[k] = edge;
                }
            }
            self.bands = Some(Box::new(b));
        }
    }

    /// This segment's profile from `v0` to `v1`.
    pub(crate) fn profile(&self, v0: f64, v1: f64) -> Profile {
        match &self.bands {
            Some(b) => Profile::plan_banded(self.len, v0, v1, self.v_cap(), b),
            None => Profile::plan_jerk(self.len, v0, v1, self.v_cap(), self.acc, self.jerk),
        }
    }

    /// The speed limit within the minimum cruise ratio's cap.
    pub(crate) fn v_cap(&self) -> f64 {
        if self.cruise2 < self.v_max * self.v_max {
            self.cruise2.sqrt()
        } else {
            self.v_max
        }
    }

    /// The change of v² (mm²/s²) over the segment at the smoothed pass's
    /// acceleration `acc · (1 − ratio)`.
    pub(crate) fn mcr_delta(&self, ratio: f64) -> f64 {
        2.0 * self.acc * (1.0 - ratio) * self.len
    }

    /// Sets the speed limit to the feed scaled by `k`, within the axes'.
    pub(crate) fn scale_feed(&mut self, k: f64) {
        self.v_max = (self.feed * k).min(self.v_axis);
    }

    /// [`Segment::bound`], squared.
    #[inline]
    pub(crate) fn bound2(&self) -> f64 {
        let b = self.bound();
        b * b
    }

    /// The square of the speed reachable at the far end from speed² `v2`
    /// at one end (no root for a trapezoid).
    #[inline]
    pub(crate) fn reach2(&self, v2: f64) -> f64 {
        if self.bands.is_none() && self.jerk == f64::INFINITY {
            return v2 + 2.0 * self.acc * self.len;
        }
        let r = self.reach_shaped(v2.sqrt());
        r * r
    }

    /// The entry-speed bound of the backward pass: the junction's, raised
    /// to the floor a feed-scale change may leave.
    pub(crate) fn bound(&self) -> f64 {
        self.junction_max.max(self.floor)
    }

    /// The speed an S-curve or banded ramp from `v` reaches at the far end.
    #[inline(never)]
    fn reach_shaped(&self, v: f64) -> f64 {
        match &self.bands {
            Some(b) => b.reach(v, self.len),
            None => ramp_reach(v, self.len, self.acc, self.jerk),
        }
    }

    /// The lowest speed this segment can slow to from `v` (0 if it can
    /// stop within it).
    pub(crate) fn reach_down(&self, v: f64) -> f64 {
        if let Some(b) = &self.bands {
            return b.reach_down(v, self.len);
        }
        if self.jerk.is_infinite() {
            return (v * v - 2.0 * self.acc * self.len).max(0.0).sqrt();
        }
        let fits = |u: f64| ramp_distance(u, v, self.acc, self.jerk) <= self.len;
        if fits(0.0) {
            return 0.0;
        }
        // The distance need not grow monotonically as the end speed falls
        // (a short ramp to a stop is slow): bisect to a speed that fits.
        let (mut lo, mut hi) = (0.0, v);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if fits(mid) {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        hi
    }
}

/// The cruise speed of a profile over `len` from `v0` to `v1` within
/// `v_max`: the highest whose two ramps (`ramps(vc)`, their length, which
/// grows with `vc`) fit, found by bisection below `reach(max(v0, v1))`.
/// An entry above `v_max` (a lowered feed scale) slows to `v_max` (or
/// straight to `v1`, if higher).
fn cruise_speed(
    len: f64,
    v0: f64,
    v1: f64,
    v_max: f64,
    ramps: impl Fn(f64) -> f64,
    reach: impl Fn(f64) -> f64,
) -> f64 {
    if v0 > v_max {
        return v_max.max(v1);
    }
    let lo = v0.max(v1);
    let hi = v_max.max(lo);
    if ramps(hi) <= len {
        return hi;
    }
    let (mut lo, mut hi) = (lo, reach(lo).min(hi));
    if ramps(hi) <= len {
        lo = hi;
    }
    while hi - lo > 1e-12 * hi.max(1.0) {
        let mid = 0.5 * (lo + hi);
        if ramps(mid) <= len {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo
}

/// How many speed bands a speed-dependent acceleration is split into.
pub const ACCEL_BANDS: usize = 6;

/// A speed-dependent acceleration as bands: `accel[k]` up to speed
/// `top[k]` (ascending; the last band's top is infinite). A ramp through
/// them is trapezoidal within each band.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AccelBands {
    /// Each band's top speed.
    pub top: [f64; ACCEL_BANDS],
    /// Each band's acceleration.
    pub accel: [f64; ACCEL_BANDS],
}

impl AccelBands {
    /// The band holding speed `v` (a speed on an edge belongs below).
    fn band(&self, v: f64) -> usize {
        self.top
            .iter()
            .position(|&t| v <= t)
            .unwrap_or(ACCEL_BANDS - 1)
    }

    /// The bands' pieces between speeds `lo < hi`: (from, to, accel).
    fn pieces(&self, lo: f64, hi: f64) -> impl Iterator<Item = (f64, f64, f64)> + '_ {
        let first = self.band(lo);
        (first..ACCEL_BANDS).map_while(move |k| {
            let from = if k == first { lo } else { self.top[k - 1] };
            (from < hi).then(|| (from, self.top[k].min(hi), self.accel[k]))
        })
    }

    /// The distance a ramp between speeds `u` and `w` covers.
    pub fn distance(&self, u: f64, w: f64) -> f64 {
        let (lo, hi) = if u < w { (u, w) } else { (w, u) };
        self.pieces(lo, hi)
            .map(|(a, b, acc)| (b * b - a * a) / (2.0 * acc))
            .sum()
    }

    /// The time a ramp between speeds `u` and `w` takes.
    pub fn time(&self, u: f64, w: f64) -> f64 {
        let (lo, hi) = if u < w { (u, w) } else { (w, u) };
        self.pieces(lo, hi).map(|(a, b, acc)| (b - a) / acc).sum()
    }

    /// The highest speed a ramp from `v` reaches within `len`.
    pub fn reach(&self, mut v: f64, mut len: f64) -> f64 {
        let mut k = self.band(v);
        loop {
            let acc = self.accel[k];
            let top = self.top[k];
            let need = (top * top - v * v) / (2.0 * acc);
            if k + 1 >= ACCEL_BANDS || need >= len {
                return (v * v + 2.0 * acc * len).sqrt();
            }
            len -= need.max(0.0);
            v = top;
            k += 1;
        }
    }

    /// The lowest speed a ramp down from `v` reaches within `len` (0 if it
    /// stops).
    pub fn reach_down(&self, mut v: f64, mut len: f64) -> f64 {
        let mut k = self.band(v);
        loop {
            let acc = self.accel[k];
            let bottom = if k == 0 { 0.0 } else { self.top[k - 1] };
            let need = (v * v - bottom * bottom) / (2.0 * acc);
            if k == 0 || need >= len {
                return (v * v - 2.0 * acc * len).max(0.0).sqrt();
            }
            len -= need.max(0.0);
            v = bottom;
            k -= 1;
        }
    }

    /// Distance, speed and acceleration `tau` into a ramp from `u` to `w`.
    fn at(&self, u: f64, w: f64, tau: f64) -> (f64, f64, f64) {
        if u == w {
            return (u * tau.max(0.0), u, 0.0);
        }
        let up = w > u;
        let (mut v, mut s, mut t) = (u, 0.0, tau.max(0.0));
        let mut k = self.band(u);
        loop {
            let acc = self.accel[k];
            // The speed where this band's piece ends.
            let end = if up {
                self.top[k].min(w)
            } else {
                (if k == 0 { 0.0 } else { self.top[k - 1] }).max(w)
            };
            let dt = (end - v).abs() / acc;
            let sign = if up { 1.0 } else { -1.0 };
            if t <= dt || end == w {
                let t = t.min(dt);
                return (
                    s + v * t + 0.5 * sign * acc * t * t,
                    v + sign * acc * t,
                    sign * acc,
                );
            }
            s += (end * end - v * v).abs() / (2.0 * acc);
            t -= dt;
            v = end;
            k = if up { k + 1 } else { k - 1 };
        }
    }
}

/// The duration of a ramp between two speeds `dv` apart at acceleration
/// `acc` and jerk `jerk` (see the module docs).
pub(crate) fn ramp_time(dv: f64, acc: f64, jerk: f64) -> f64 {
    if jerk.is_infinite() {
        dv / acc
    } else if dv * jerk >= acc * acc {
        dv / acc + acc / jerk
    } else {
        2.0 * (dv / jerk).sqrt()
    }
}

/// The distance a ramp from speed `u` to `w` covers.
pub(crate) fn ramp_distance(u: f64, w: f64, acc: f64, jerk: f64) -> f64 {
    if jerk.is_infinite() {
        (w * w - u * u).abs() / (2.0 * acc)
    } else {
        0.5 * (u + w) * ramp_time((w - u).abs(), acc, jerk)
    }
}

/// The highest speed a ramp from `v` reaches within `len`.
pub(crate) fn ramp_reach(v: f64, len: f64, acc: f64, jerk: f64) -> f64 {
    if jerk.is_infinite() {
        return (v * v + 2.0 * acc * len).sqrt();
    }
    // Reaching `acc` (Δv ≥ a²/j = 2c): (w² − v²)/2a + (v + w)·c/a = len.
    let c = acc * acc / (2.0 * jerk);
    let w = -c + ((v - c) * (v - c) + 2.0 * acc * len).sqrt();
    if w - v >= 2.0 * c {
        return w;
    }
    // Short of `acc`: with u = √Δv, (2v + u²)·u = len·√j. The left side is
    // convex and increasing, so Newton from above converges monotonically.
    let (p, q) = (2.0 * v, len * jerk.sqrt());
    let mut u = q.cbrt();
    if p > 0.0 {
        u = u.min(q / p);
    }
    for _ in 0..30 {
        let f = u * u * u + p * u - q;
        let next = u - f / (3.0 * u * u + p);
        // Stop once it no longer falls (or is not a number).
        if next.partial_cmp(&u) != Some(core::cmp::Ordering::Less) || next <= 0.0 {
            break;
        }
        u = next;
    }
    v + u * u
}

/// Distance, speed and acceleration `tau` into a jerk-limited ramp from
/// `u` to `w` (finite `jerk`), clamped to the ramp.
fn ramp_at(u: f64, w: f64, acc: f64, jerk: f64, tau: f64) -> (f64, f64, f64) {
    let dv = (w - u).abs();
    if dv == 0.0 {
        return (u * tau.max(0.0), u, 0.0);
    }
    let sg = if w > u { 1.0 } else { -1.0 };
    let (t1, t2, ap) = if dv * jerk >= acc * acc {
        (acc / jerk, dv / acc - acc / jerk, acc)
    } else {
        let ap = (dv * jerk).sqrt();
        (ap / jerk, 0.0, ap)
    };
    let total = 2.0 * t1 + t2;
    let tau = tau.clamp(0.0, total);
    let j = sg * jerk;
    if tau < t1 {
        (
            u * tau + j * tau * tau * tau / 6.0,
            u + 0.5 * j * tau * tau,
            j * tau,
        )
    } else if tau < t1 + t2 {
        let (v1, s1) = (u + 0.5 * j * t1 * t1, u * t1 + j * t1 * t1 * t1 / 6.0);
        let d = tau - t1;
        (
            s1 + v1 * d + 0.5 * sg * ap * d * d,
            v1 + sg * ap * d,
            sg * ap,
        )
    } else {
        // Counted back from the ramp's end, where the speed is `w`.
        let r = total - tau;
        let length = 0.5 * (u + w) * total;
        (
            length - (w * r - j * r * r * r / 6.0),
            w - 0.5 * j * r * r,
            j * r,
        )
    }
}

/// Largest speed through the corner from `prev` into `next`.
///
/// With `θ` the angle between the reversed incoming direction and the
/// outgoing one (180° straight on, 0 a reversal) and `a_c` the acceleration
/// allowed along the direction of the velocity change (the per-axis limits
/// along it, and the vector limit), the speed is the smallest of:
/// - junction deviation: the corner is treated as a circular arc tangent to
///   both segments whose closest point lies `δ` from the corner, of radius
///   `δ·sin(θ/2)/(1 − sin(θ/2))`, and the speed keeps its centripetal
///   acceleration at `a_c` (skipped within 0.08° of straight, so `δ = 0`
///   still runs straight through collinear chords);
/// - centripetal (Klipper's): the arc tangent to both segments no further
///   than half the shorter one from the corner, of radius
///   `½·min(L_prev, L_next)·tan(θ/2)`, again at `a_c`. On a chain of chords
///   along a curve this radius is at most the radius of the circle through
///   the three points around the junction, so `v²/R ≤ a_c` at any chord
///   length;
/// - a reversal (θ = 0) gives 0 from both: `sin(θ/2)` is computed as
///   `|u_prev + u_next| / 2`, exactly 0 there;
/// - both segments' speed limits;
/// - each axis's velocity change within `max_jump`.
pub(crate) fn junction_speed<const N: usize>(
    prev: &Segment<N>,
    next: &Segment<N>,
    limits: &Limits<N>,
    vector: &VectorLimits,
    model: Option<&dyn AccelModel<N>>,
) -> f64 {
    if prev.on_path != next.on_path {
        // Into or out of a move of the following axes alone (a
        // retraction): the two are measured on different lengths, so they
        // meet at rest, as Klipper's extruder-only moves do.
        return 0.0;
    }
    // The corner's geometry is the toolhead's (or, between two moves of
    // the following axes alone, theirs); the following axes' velocity
    // change is held to their `max_jump` below.
    let k = if next.on_path {
        path_axes::<N>(vector)
    } else {
        N
    };
    let mut dot = 0.0;
    let mut w = [0.0; N];
    let mut jump = [0.0; N];
    let (mut wn2, mut sn2) = (0.0, 0.0);
    for i in 0..N {
        jump[i] = next.dir[i] - prev.dir[i];
        if i >= k {
            continue;
        }
        dot += prev.dir[i] * next.dir[i];
        w[i] = jump[i];
        wn2 += w[i] * w[i];
        let s = next.dir[i] + prev.dir[i];
        sn2 += s * s;
    }
    let mut v = prev.v_max.min(next.v_max);
    if wn2 > 0.0 {
        let wn = wn2.sqrt();
        // |u_next − u_prev| = 2·cos(θ/2), |u_next + u_prev| = 2·sin(θ/2),
        // both without cancellation near straight.
        let cos_half = 0.5 * wn;
        let sin_half = 0.5 * sn2.sqrt();
        let unit = w.map(|c| c / wn);
        let mut a = along(&limits.max_acc, &unit);
        if next.on_path {
            a = a.min(vector.max_accel);
        }
        if let Some(m) = model {
            a = a.min(m.max_accel(&next.dir, &unit, v));
        }
        // Centripetal: ½·min(L)·tan(θ/2).
        let mut r = 0.5 * prev.len.min(next.len) * sin_half / cos_half;
        if -dot > -0.999_999 {
            // Junction deviation; 1 − sin(θ/2) = cos²(θ/2)/(1 + sin(θ/2)).
            let r_jd =
                limits.junction_deviation * sin_half * (1.0 + sin_half) / (cos_half * cos_half);
            r = r.min(r_jd);
        }
        v = v.min((a * r).sqrt());
    }
    // The per-axis jump: |v · Δdir_i| ≤ max_jump_i.
    v = v.min(along(&limits.max_jump, &jump));
    v.max(0.0)
}

/// A segment's speed profile: a ramp from the entry to the cruise speed,
/// a cruise, and a ramp to the exit speed. The ramps are trapezoidal
/// (constant acceleration) with `jerk` infinite, else jerk-limited (see the
/// module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Profile {
    /// Entry speed (mm/s).
    pub entry: f64,
    /// Cruise (peak) speed (mm/s).
    pub cruise: f64,
    /// Exit speed (mm/s).
    pub exit: f64,
    /// Acceleration magnitude used in the ramps (mm/s²): their peak when
    /// they are long enough to reach it.
    pub accel: f64,
    /// Jerk of the ramps (mm/s³); `f64::INFINITY` for a trapezoid.
    pub jerk: f64,
    /// Speed-dependent acceleration of the ramps, if any (then `accel` is
    /// its slowest band's).
    pub bands: Option<AccelBands>,
    /// Segment length (mm).
    pub length: f64,
    /// Duration of the first ramp, from the entry to the cruise speed (s):
    /// accelerating, or decelerating when the segment is entered above its
    /// speed limit (after [`super::Planner::set_feed_scale`] lowered it while
    /// the path ran faster).
    pub t_acc: f64,
    /// Duration at cruise speed (s).
    pub t_cruise: f64,
    /// Duration of the decelerating ramp (s).
    pub t_dec: f64,
    d_acc: f64,
    d_cruise: f64,
}

impl Profile {
    /// The fastest profile over `len` from `v0` to `v1` within `v_max` and
    /// `acc`. The caller guarantees `v1` is reachable from `v0`; rounding
    /// beyond that is absorbed.
    ///
    /// An entry above `v_max` (a lowered feed scale) first decelerates to
    /// `v_max` (or straight to `v1` if that is higher), then cruises.
    pub fn plan(len: f64, v0: f64, v1: f64, v_max: f64, acc: f64) -> Self {
        let vc = if v0 > v_max {
            v_max.max(v1)
        } else {
            let peak = ((2.0 * acc * len + v0 * v0 + v1 * v1) * 0.5).sqrt();
            v_max.min(peak).max(v0).max(v1)
        };
        let d_acc = (vc * vc - v0 * v0).abs() / (2.0 * acc);
        let d_dec = (vc * vc - v1 * v1) / (2.0 * acc);
        let d_cruise = (len - d_acc - d_dec).max(0.0);
        let t_cruise = if vc > 0.0 { d_cruise / vc } else { 0.0 };
        Profile {
            entry: v0,
            cruise: vc,
            exit: v1,
            accel: acc,
            jerk: f64::INFINITY,
            bands: None,
            length: len,
            t_acc: (vc - v0).abs() / acc,
            t_cruise,
            t_dec: (vc - v1) / acc,
            d_acc,
            d_cruise,
        }
    }

    /// As [`Profile::plan`], with ramps limited to `jerk` (`f64::INFINITY`:
    /// exactly [`Profile::plan`]). The cruise speed is the highest whose
    /// two ramps fit in `len`; a `v1` the caller's lookahead made reachable
    /// within rounding is absorbed as there.
    pub fn plan_jerk(len: f64, v0: f64, v1: f64, v_max: f64, acc: f64, jerk: f64) -> Self {
        if jerk.is_infinite() {
            return Profile::plan(len, v0, v1, v_max, acc);
        }
        let ramps = |vc: f64| ramp_distance(v0, vc, acc, jerk) + ramp_distance(vc, v1, acc, jerk);
        let vc = cruise_speed(len, v0, v1, v_max, ramps, |v| ramp_reach(v, len, acc, jerk));
        let d_acc = ramp_distance(v0, vc, acc, jerk);
        let d_dec = ramp_distance(vc, v1, acc, jerk);
        let d_cruise = (len - d_acc - d_dec).max(0.0);
        Profile {
            entry: v0,
            cruise: vc,
            exit: v1,
            accel: acc,
            jerk,
            bands: None,
            length: len,
            t_acc: ramp_time((vc - v0).abs(), acc, jerk),
            t_cruise: if vc > 0.0 { d_cruise / vc } else { 0.0 },
            t_dec: ramp_time(vc - v1, acc, jerk),
            d_acc,
            d_cruise,
        }
    }

    /// As [`Profile::plan`], with the ramps' acceleration in speed bands.
    pub fn plan_banded(len: f64, v0: f64, v1: f64, v_max: f64, bands: &AccelBands) -> Self {
        let ramps = |vc: f64| bands.distance(v0, vc) + bands.distance(vc, v1);
        let vc = cruise_speed(len, v0, v1, v_max, ramps, |v| bands.reach(v, len));
        let d_acc = bands.distance(v0, vc);
        let d_dec = bands.distance(vc, v1);
        let d_cruise = (len - d_acc - d_dec).max(0.0);
        Profile {
            entry: v0,
            cruise: vc,
            exit: v1,
            accel: bands.accel[ACCEL_BANDS - 1],
            jerk: f64::INFINITY,
            bands: Some(*bands),
            length: len,
            t_acc: bands.time(v0, vc),
            t_cruise: if vc > 0.0 { d_cruise / vc } else { 0.0 },
            t_dec: bands.time(vc, v1),
            d_acc,
            d_cruise,
        }
    }

    /// Total duration (s).
    pub fn duration(&self) -> f64 {
        self.t_acc + self.t_cruise + self.t_dec
    }

    /// Distance, speed and acceleration along the segment `tau` seconds after
    /// its start (clamped to the segment).
    pub fn at(&self, tau: f64) -> (f64, f64, f64) {
        let tau = tau.max(0.0);
        if self.jerk.is_finite() {
            return self.at_jerk(tau);
        }
        if let Some(b) = &self.bands {
            return self.at_banded(b, tau);
        }
        let a = self.accel;
        let (s, v, acc) = if tau < self.t_acc {
            // The first ramp decelerates when entered above the cruise speed.
            let a1 = if self.cruise < self.entry { -a } else { a };
            (
                self.entry * tau + 0.5 * a1 * tau * tau,
                self.entry + a1 * tau,
                a1,
            )
        } else if tau < self.t_acc + self.t_cruise {
            (
                self.d_acc + self.cruise * (tau - self.t_acc),
                self.cruise,
                0.0,
            )
        } else if tau < self.duration() {
            let td = tau - self.t_acc - self.t_cruise;
            (
                self.d_acc + self.d_cruise + self.cruise * td - 0.5 * a * td * td,
                self.cruise - a * td,
                -a,
            )
        } else {
            (self.length, self.exit, 0.0)
        };
        (s.clamp(0.0, self.length), v.max(0.0), acc)
    }
}

impl Profile {
    /// [`Profile::at`] for jerk-limited ramps.
    fn at_jerk(&self, tau: f64) -> (f64, f64, f64) {
        let (a, j) = (self.accel, self.jerk);
        let (s, v, acc) = if tau < self.t_acc {
            ramp_at(self.entry, self.cruise, a, j, tau)
        } else if tau < self.t_acc + self.t_cruise {
            (
                self.d_acc + self.cruise * (tau - self.t_acc),
                self.cruise,
                0.0,
            )
        } else if tau < self.duration() {
            let (s, v, acc) = ramp_at(
                self.cruise,
                self.exit,
                a,
                j,
                tau - self.t_acc - self.t_cruise,
            );
            (self.d_acc + self.d_cruise + s, v, acc)
        } else {
            (self.length, self.exit, 0.0)
        };
        (s.clamp(0.0, self.length), v.max(0.0), acc)
    }
}

impl Profile {
    /// [`Profile::at`] for banded ramps.
    fn at_banded(&self, b: &AccelBands, tau: f64) -> (f64, f64, f64) {
        let (s, v, acc) = if tau < self.t_acc {
            b.at(self.entry, self.cruise, tau)
        } else if tau < self.t_acc + self.t_cruise {
            (
                self.d_acc + self.cruise * (tau - self.t_acc),
                self.cruise,
                0.0,
            )
        } else if tau < self.duration() {
            let (s, v, acc) = b.at(self.cruise, self.exit, tau - self.t_acc - self.t_cruise);
            (self.d_acc + self.d_cruise + s, v, acc)
        } else {
            (self.length, self.exit, 0.0)
        };
        (s.clamp(0.0, self.length), v.max(0.0), acc)
    }
}
