//! Tests of the per-link filters and fits ([`super`]).

use super::*;

fn cfg() -> TimeConfig {
    TimeConfig::default()
}

/// A neighbour whose clock runs `ppm` fast and is `offset` µs ahead of
/// our counter, exchanged with a symmetric `rtt`.
fn feed(n: &mut Neighbour, count: u64, ppm: f64, offset: f64, rtt: u64) {
    for i in 0..count {
        let sent = 1_000_000 + i * 50_000;
        let mid = sent as f64 + rtt as f64 / 2.0;
        let theirs = mid + offset + mid * ppm * 1e-6;
        n.add(
            Instant::from_micros(sent),
            Instant::from_micros(sent + rtt),
            SystemInstant::from_micros(theirs.round() as u64),
            0,
            &cfg(),
            0.0,
        );
    }
}

#[test]
fn fits_offset_and_rate() {
    let mut n = Neighbour::default();
    // Under two seconds of samples: a line, but its slope is not yet
    // trusted as the rate.
    feed(&mut n, 16, 50.0, 1234.0, 100);
    let e = n
        .estimate(Instant::from_micros(1_000_000 + 16 * 50_000), &cfg(), 0.0)
        .unwrap();
    assert_eq!(e.slope, None);
    let mut n = Neighbour::default();
    feed(&mut n, 48, 50.0, 1234.0, 100);
    let now = 1_000_000 + 48 * 50_000;
    let e = n.estimate(Instant::from_micros(now), &cfg(), 0.0).unwrap();
    let slope = e.slope.unwrap();
    assert!((slope - 50e-6).abs() < 0.5e-6, "slope {slope}");
    let y = e.y_ref_half as f64 * 0.5 + f64::from(e.y_rel);
    let truth = 1234.0 + now as f64 * 50e-6;
    assert!((y - truth).abs() < 1.0, "y {y} truth {truth}");
}

#[test]
fn long_round_trips_are_rejected() {
    let mut n = Neighbour::default();
    feed(&mut n, 8, 0.0, 0.0, 100);
    assert_eq!(
        n.add(
            Instant::from_micros(2_000_000),
            Instant::from_micros(2_000_400),
            SystemInstant::from_micros(2_000_200),
            0,
            &cfg(),
            0.0
        ),
        Verdict::RejectedRtt
    );
}

#[test]
fn late_stamps_are_rejected_by_residual() {
    let mut n = Neighbour::default();
    feed(&mut n, 8, 0.0, 500.0, 100);
    // Same round trip, but their time is 40 µs late.
    let sent = 2_000_000;
    assert_eq!(
        n.add(
            Instant::from_micros(sent),
            Instant::from_micros(sent + 100),
            SystemInstant::from_micros(sent + 50 + 500 + 40),
            0,
            &cfg(),
            0.0
        ),
        Verdict::RejectedResidual
    );
    // A real jump persists: after a few rejections the fit starts over.
    let mut last = Verdict::Accepted;
    for i in 1..=RESET_AFTER_REJECTS as u64 {
        let sent = 2_000_000 + i * 50_000;
        last = n.add(
            Instant::from_micros(sent),
            Instant::from_micros(sent + 100),
            SystemInstant::from_micros(sent + 50 + 5_000),
            0,
            &cfg(),
            0.0,
        );
    }
    assert_eq!(last, Verdict::Accepted);
}

#[test]
fn replies_from_the_future_are_bogus() {
    let mut n = Neighbour::default();
    assert_eq!(
        n.add(
            Instant::from_micros(10),
            Instant::from_micros(5),
            SystemInstant::ZERO,
            0,
            &cfg(),
            0.0
        ),
        Verdict::Bogus
    );
}

/// A USB-like link: the way to the neighbour is prompt (20 µs plus a
/// software latency of mean 75 µs), the way back waits for the next
/// 1 ms frame. Their clock runs 60 ppm fast and 5 ms ahead. Returns
/// the neighbour, our local time at the end, the envelopes' latest
/// slope and the largest error of a single exchange's midpoint.
fn usb_like(seconds: u64) -> (Neighbour, Instant, f64, f64) {
    extern crate std;
    let (offset, rate) = (5_000.0, 60e-6);
    let theirs = |t: f64| t + offset + t * rate;
    let mut rng = 0x2545_f491_u32;
    let mut exp = |mean: f64| {
        rng ^= rng << 13;
        rng ^= rng >> 17;
        rng ^= rng << 5;
        -mean * ((f64::from(rng) + 1.0) / 4_294_967_297.0).ln()
    };
    let mut n = Neighbour::default();
    let (mut biggest_midpoint_error, mut slope) = (0f64, f64::NAN);
    let mut sent = 1_000_000u64;
    while sent < 1_000_000 + seconds * 1_000_000 {
        let up = 20.0 + exp(75.0);
        let turnaround = 30.0;
        let ready = sent as f64 + up + turnaround + exp(50.0);
        let received = (ready / 1000.0).ceil() * 1000.0 + 15.0;
        let their_time = theirs(sent as f64 + up + turnaround / 2.0);
        let received = received as u64;
        n.add(
            Instant::from_micros(sent),
            Instant::from_micros(received),
            SystemInstant::from_micros(their_time as u64),
            0,
            &cfg(),
            rate as f32,
        );
        let midpoint = (sent + received) as f64 / 2.0;
        let error = their_time - theirs(midpoint);
        biggest_midpoint_error = biggest_midpoint_error.max(error.abs());
        if let Some(Some((s, _))) = n.new_envelope_slope(Instant::from_micros(received)) {
            slope = f64::from(s);
        }
        // Requests search over the frame's phases (as the clock's
        // dither does while few exchanges pass).
        sent += 5_500 + exp(1_000.0).min(1_000.0) as u64;
    }
    (n, Instant::from_micros(sent), slope, biggest_midpoint_error)
}

#[test]
fn the_prompt_envelope_gives_rate_and_offset_where_round_trips_do_not() {
    let (n, now, slope, midpoint_error) = usb_like(4);
    // Single exchanges are off by up to half a frame ...
    assert!(midpoint_error > 200.0, "midpoint error {midpoint_error}");
    // ... the envelopes give the rate ...
    assert!((slope - 60e-6).abs() < 3e-6, "slope {slope}");
    // ... and, projected at it, the offset.
    let (whole, rest, sigma) = n.envelope_offset(now, 60e-6, &cfg()).unwrap();
    let y = whole as f64 + f64::from(rest);
    let truth = 5_000.0 + now.as_micros() as f64 * 60e-6;
    assert!((y - truth).abs() < 10.0, "envelope {y} truth {truth}");
    assert!(sigma < 10.0, "scatter {sigma}");
}

/// A neighbour `offset` µs ahead and `ppm` fast whose every stamp is
/// whole µs: our send and receive stamps floored, its reply rounded.
/// Returns the truth at `now` and the estimate there, µs.
fn whole_us_stamps(count: u64, ppm: f64, offset: f64) -> (f64, f64) {
    let mut n = Neighbour::default();
    let at = |i: u64| 1_000_000.0 + i as f64 * 50_000.0 + (i * 7_919 % 1_000) as f64 * 0.001;
    let theirs = |l: f64| l + offset + l * ppm * 1e-6;
    for i in 0..count {
        let sent = at(i);
        let received = sent + 187.3;
        let mid = theirs(0.5 * (sent + received));
        n.add(
            Instant::from_micros(sent as u64),
            Instant::from_micros(received as u64),
            SystemInstant::from_micros(mid.round() as u64),
            0,
            &cfg(),
            0.0,
        );
    }
    let now = at(count) as u64;
    let e = n.estimate(Instant::from_micros(now), &cfg(), 0.0).unwrap();
    assert!(e.slope.is_some(), "{e:?}");
    (
        theirs(now as f64) - now as f64,
        e.y_ref_half as f64 * 0.5 + f64::from(e.y_rel),
    )
}

#[test]
fn a_settled_phase_averages_the_stamps_whole_microseconds_away() {
    extern crate std;
    // One sample's phase scatters by 0.3-0.45 µs rms from its whole-µs
    // stamps (here our two stamps floored, its reply rounded); the short
    // line through the newest residuals must scatter far less. Our floored
    // stamps also bias every sample by half a µs, which the responder's
    // own floored stamps cancel on the wire (not modelled here): the
    // scatter about the mean error is what the filter decides.
    let errors: std::vec::Vec<f64> = (0..24u64)
        .map(|k| {
            let (truth, got) =
                whole_us_stamps(64 + k, 37.0 + k as f64 * 3.1, 1234.37 + k as f64 * 0.13);
            got - truth
        })
        .collect();
    let mean = errors.iter().sum::<f64>() / errors.len() as f64;
    let sd =
        (errors.iter().map(|e| (e - mean) * (e - mean)).sum::<f64>() / errors.len() as f64).sqrt();
    std::eprintln!("phase error: mean {mean:.3} µs, sd {sd:.3} µs");
    assert!(sd < 0.15, "phase scatters by {sd} µs: {errors:?}");
    assert!((mean - 0.5).abs() < 0.15, "mean {mean} µs");
}

/// Requests in two phases an interval, 7 ms apart (a burst's last request
/// and the phase after it, each the other's anchor, as bus32's hubs ran):
/// the full window spans 1.6 s, less than the two seconds a slope needs to
/// be trusted as the rate, but the rate counts as measured.
#[test]
fn a_full_window_of_requests_two_an_interval_measures_the_rate() {
    let feed_pairs = |count: u64| {
        let mut n = Neighbour::default();
        let mut now = 0;
        for i in 0..count {
            let sent = 1_000_000 + (i / 2) * 50_000 + (i % 2) * 7_000;
            let mid = sent as f64 + 50.0;
            let theirs = mid + 800.0 + mid * 40e-6;
            n.add(
                Instant::from_micros(sent),
                Instant::from_micros(sent + 100),
                SystemInstant::from_micros(theirs.round() as u64),
                0,
                &cfg(),
                0.0,
            );
            now = sent + 100;
        }
        n.estimate(Instant::from_micros(now), &cfg(), 0.0).unwrap()
    };
    let e = feed_pairs(70);
    assert_eq!(usize::from(e.used), FIT_WINDOW_MAX);
    assert_eq!(
        e.slope, None,
        "a slope over 1.6 s is not trusted as the rate"
    );
    assert!(e.rate_measured);
    // Half that window (0.8 s) does not measure it.
    let e = feed_pairs(32);
    assert!(!e.rate_measured);
    // Requests one an interval: a trusted slope over 2 s measures it too.
    let mut n = Neighbour::default();
    feed(&mut n, 48, 40.0, 800.0, 100);
    let e = n
        .estimate(Instant::from_micros(1_000_000 + 48 * 50_000), &cfg(), 0.0)
        .unwrap();
    assert!(e.slope.is_some() && e.rate_measured);
}
