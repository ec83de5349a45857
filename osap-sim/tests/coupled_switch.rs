//! Limit switches over several motors (`[[switch]]`): a CoreXY machine's
//! endstops, wired to one module's limit input but pressed by a sum of two
//! belt motors' positions.
//!
//! On a hub with steppers a, b and c, the host streams a and b through a
//! y move (a and b opposite) and then an x move (both the same way, one
//! starting later). Two switches watch them: "y" on a's input (a is one of
//! its motors), pressed while y = (a − b)/2 ≥ 6, and "x" on c's input (c's
//! own motor never moves, so c stands the whole time), pressed while
//! 10 + (a + b)/2 ≤ 2. What each module's `read_limit` reports over the
//! network is checked against the crossings of the two motors' recorded
//! step edges: the count of edges, the level, and the time stamp, which is
//! the tick of the crossing step on the switch module's own clock.

use osap_core::clock::TimeMap;
use osap_core::Instant as LocalInstant;
use osap_host::netrunner::{Netrunner, SyncGoal};
use osap_host::som::{FnRef, Manager, Value};
use osap_host::{Host, HostConfig};
use osap_sim::machine::{self, SharedModule, SimMachine, TimeMode};
use osap_sim::topology::{SimSpec, SwitchSpec};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The control-point interval, µs (the largest a module takes, so the
/// whole stream fits the module's queue of 64 points).
const IV: u64 = 16_384;

/// The switches over a and b.
const TOPOLOGY: &str = r#"
name = "coupled"

[[module]]
name = "hub"
type = "hub"
rate_ppm = -20.0

[[module]]
name = "a"
type = "stepper"
rate_ppm = 45.0

[[module]]
name = "b"
type = "stepper"
rate_ppm = -60.0

[[module]]
name = "c"
type = "stepper"
rate_ppm = 25.0

[[link]]
a = "host"
b = "hub"
kind = "usb"

[[link]]
a = "hub"
b = "a"
kind = "uart"

[[link]]
a = "hub"
b = "b"
kind = "uart"

[[link]]
a = "hub"
b = "c"
kind = "uart"

# y = (a - b) / 2, on a's input: pressed at y >= 6.
[[switch]]
module = "a"
terms = [["a", 0.5], ["b", -0.5]]
at = 6.0
pressed_below = false

# x = 10 + (a + b) / 2, on c's input: pressed at x <= 2.
[[switch]]
module = "c"
terms = [["a", 0.5], ["b", 0.5]]
offset = 10.0
at = 2
pressed_below = true
"#;

/// a's and b's positions (mm) at control points k, piecewise linear.
const A: &[(u64, f64)] = &[
    (0, 0.0),
    (2, 0.0),
    (12, 8.0),
    (20, 8.0),
    (35, -4.0),
    (48, -4.0),
];
const B: &[(u64, f64)] = &[
    (0, 0.0),
    (2, 0.0),
    (12, -8.0),
    (27, -8.0),
    (42, -20.0),
    (48, -20.0),
];
/// Between the y move and the x move.
const MIDDLE: u64 = 16;

fn profile(knots: &[(u64, f64)], k: u64) -> f64 {
    for w in knots.windows(2) {
        let ((k0, p0), (k1, p1)) = (w[0], w[1]);
        if k <= k1 {
            return p0 + (p1 - p0) * (k - k0) as f64 / (k1 - k0) as f64;
        }
    }
    knots.last().map_or(0.0, |k| k.1)
}

/// `read_limit` on `module`: (time, level, edges).
async fn read_limit(m: &Manager, module: &str) -> (u64, bool, u32) {
    let out = call(m, module, "read_limit", &[]).await;
    match out[..] {
        [Value::U64(t), Value::Bool(level), Value::U32(n)] => (t, level, n),
        _ => panic!("read_limit returned {out:?}"),
    }
}

async fn call(
    m: &Manager,
    module: &str,
    function: &str,
    args: &[Value<'static>],
) -> Vec<Value<'static>> {
    m.function(&FnRef::new(module, function))
        .unwrap()
        .call(args)
        .await
        .unwrap_or_else(|e| panic!("{module}.{function}: {e}"))
}

/// A switch's edges from the motors' step edges: (instant, new level).
fn crossings(switch: &SwitchSpec, steps: &[(Instant, &str, f64)]) -> Vec<(Instant, bool)> {
    let mut at = [("a", 0.0), ("b", 0.0)];
    let position = |at: &[(&str, f64); 2], m: &str| at.iter().find(|p| p.0 == m).unwrap().1;
    let mut level = !switch.pressed(|m| position(&at, m));
    let mut edges = Vec::new();
    for &(t, module, p) in steps {
        at.iter_mut().find(|q| q.0 == module).unwrap().1 = p;
        let now = !switch.pressed(|m| position(&at, m));
        if now != level {
            level = now;
            edges.push((t, level));
        }
    }
    edges
}

/// What a module was seen to hold, every ms: its time maps and its limit
/// edge count, each with the local time first seen.
#[derive(Default)]
struct Watched {
    maps: Vec<(LocalInstant, TimeMap)>,
    edges: Vec<(LocalInstant, u32)>,
}

/// Watches a module until `stop`.
fn watch(module: SharedModule, stop: Arc<AtomicBool>) -> tokio::task::JoinHandle<Watched> {
    tokio::spawn(async move {
        let mut seen = Watched::default();
        while !stop.load(Ordering::Relaxed) {
            let (now, map, edges) = module.lock(|m| (m.local_now(), m.time, m.limit.edges));
            if seen.maps.last().is_none_or(|s| s.1 != map) {
                seen.maps.push((now, map));
            }
            if seen.edges.last().is_none_or(|s| s.1 != edges) {
                seen.edges.push((now, edges));
            }
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
        seen
    })
}

/// The synchronized times the maps in force from local `local` on (for
/// 20 ms, so the one the edge was stamped on is among them) give it.
fn stamps(maps: &[(LocalInstant, TimeMap)], local: LocalInstant) -> Vec<u64> {
    let first = maps.partition_point(|s| s.0 <= local).saturating_sub(1);
    let last = maps.partition_point(|s| s.0 <= local + osap_core::Duration::from_millis(20));
    maps[first..(last + 1).min(maps.len())]
        .iter()
        .map(|s| s.1.system_time(local).as_micros())
        .collect()
}

#[test]
fn a_switch_over_two_motors_trips_when_their_sum_crosses() {
    // In virtual time the edge reaches the module at its first turn after
    // it (a module watching a moving motor takes one every 1 ms), seen by
    // the watcher within its 1 ms.
    machine::virtual_runtime()
        .unwrap()
        .block_on(two_motor_switches(TimeMode::Virtual, 3_000));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_switch_over_two_motors_trips_in_real_time() {
    // The same on the system's clock, two threads: the modules' tasks run
    // in parallel, so the merge's horizon rule is what keeps stamps exact.
    // Delivery waits for the threads too (a loaded 2-core machine).
    two_motor_switches(TimeMode::RealTime, 50_000).await;
}

/// Runs the moves in `mode`; each edge must reach its module within
/// `delivered_us` local µs of its stamp (as the watcher sees it).
async fn two_motor_switches(mode: TimeMode, delivered_us: u64) {
    let topology = SimSpec::parse(TOPOLOGY).unwrap();
    let host = Host::start(HostConfig::named("h")).unwrap();
    let sim = SimMachine::start_with(&host, &topology, mode)
        .await
        .unwrap();
    let nr = Netrunner::new(&host).await.unwrap();
    for name in ["a", "b", "c"] {
        let route = sim.route_to(name).unwrap();
        nr.wait_synchronised(&route, SyncGoal::default())
            .await
            .unwrap();
    }
    let mut m = Manager::new(&host).await.unwrap();
    m.refresh().await.unwrap();

    // At boot: y = 0 and x = 10, both released (high), no edges.
    for name in ["a", "c"] {
        assert_eq!(read_limit(&m, name).await, (0, true, 0), "{name} at boot");
    }
    let modules: Vec<SharedModule> = ["a", "b", "c"]
        .iter()
        .map(|n| sim.module(n).unwrap().module().unwrap())
        .collect();
    let stop = Arc::new(AtomicBool::new(false));
    let watchers: Vec<_> = modules
        .iter()
        .map(|s| watch(s.clone(), stop.clone()))
        .collect();

    for name in ["a", "b"] {
        call(&m, name, "set_enable", &[Value::Bool(true)]).await;
        call(&m, name, "set_interval", &[Value::U32(IV as u32)]).await;
    }
    let now = host.system_time().await.unwrap().as_micros();
    let t0 = (now + 1_000_000).next_multiple_of(IV);
    let last = A.last().unwrap().0;
    for k in 0..=last {
        let t = Value::U64(t0 + k * IV);
        for (name, knots) in [("a", A), ("b", B)] {
            let p = Value::F32(profile(knots, k) as f32);
            call(&m, name, "add_point", &[t.clone(), p]).await;
        }
    }
    assert!(
        host.system_time().await.unwrap().as_micros() < t0,
        "the stream fell behind"
    );

    // Between the moves: the y move pressed y once; x (c) stayed released.
    while host.system_time().await.unwrap().as_micros() < t0 + MIDDLE * IV {
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    let (_, level, n) = read_limit(&m, "a").await;
    assert_eq!((level, n), (false, 1), "y pressed once by the y move");
    assert_eq!(
        read_limit(&m, "c").await,
        (0, true, 0),
        "a y move does not touch x"
    );

    while host.system_time().await.unwrap().as_micros() < t0 + (last + 4) * IV {
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let y_read = read_limit(&m, "a").await;
    let x_read = read_limit(&m, "c").await;
    stop.store(true, Ordering::Relaxed);
    let mut watched = Vec::new();
    for w in watchers {
        watched.push(w.await.unwrap());
    }

    // Every step of a and b, at true time.
    let mut steps: Vec<(Instant, &str, f64, LocalInstant)> = Vec::new();
    for (i, name) in ["a", "b"].into_iter().enumerate() {
        let clock = sim.module(name).unwrap().clock();
        let edges = modules[i].lock(|m| m.board().motor().edges().to_vec());
        assert!(edges.len() > 1000, "{name} made {} steps", edges.len());
        steps.extend(
            edges
                .iter()
                .map(|e| (clock.instant_at(e.local), name, e.position, e.local)),
        );
    }
    steps.sort_by_key(|s| s.0);
    for (s, end) in modules.iter().zip([-4.0, -20.0]) {
        let p = s.lock(|m| m.board().motor().position());
        assert!((p - end).abs() < 1e-9, "{p} mm, not {end}");
    }
    let plain: Vec<(Instant, &str, f64)> = steps.iter().map(|s| (s.0, s.1, s.2)).collect();

    for (switch, name, index, read, expected_edges) in [
        (&topology.switches[0], "a", 0, y_read, 3),
        (&topology.switches[1], "c", 2, x_read, 1),
    ] {
        let edges = crossings(switch, &plain);
        assert_eq!(edges.len(), expected_edges, "{name}: {edges:?}");
        let (hit, level, n) = read;
        assert_eq!(n as usize, edges.len(), "{name}: edges counted");
        let (at, want_level) = *edges.last().unwrap();
        assert_eq!(level, want_level, "{name}: level");
        // The crossing step's tick on the switch module's own clock,
        // stamped on its time map: exact but for 1 µs of converting
        // between the two clocks and 1 µs of the map's rounding.
        let module = sim.module(name).unwrap();
        let local = module.clock().local_at(at);
        let candidates = stamps(&watched[index].maps, local);
        let nearest = candidates.iter().map(|&s| s.abs_diff(hit)).min().unwrap();
        // At true time: the crossing step's host time, off by the switch
        // module's clock sync error (in virtual time deliveries fall on
        // 1 ms timer ticks, so sync is coarser than in real time: a few
        // hundred µs).
        let (_, stepper, _, step_local) = steps.iter().find(|s| s.0 == at).unwrap();
        let truth = sim
            .module(stepper)
            .unwrap()
            .host_time_at(*step_local)
            .as_micros();
        eprintln!(
            "switch on {name}: {} edges, last at {hit} (level {level}): {nearest} µs from the crossing step's tick on its clock, {:+} µs from its true time",
            n,
            hit as i64 - truth as i64
        );
        assert!(nearest <= 2, "{name}: {hit} vs {candidates:?}");
        // Each edge reached the module soon after its time.
        for (k, (t, _)) in edges.iter().enumerate() {
            let local = module.clock().local_at(*t);
            let seen = watched[index]
                .edges
                .iter()
                .find(|e| e.1 as usize > k)
                .expect("the watcher saw the edge")
                .0;
            eprintln!(
                "  edge {k} seen {} µs after its time",
                seen.signed_micros_since(local)
            );
            let (seen, local) = (seen.as_micros(), local.as_micros());
            assert!(
                seen + 1_000 >= local && seen <= local + delivered_us,
                "{name}: edge {k} at {local} seen at {seen}"
            );
        }
        assert!(hit.abs_diff(truth) < 2_000, "{name}: {hit} vs {truth}");
    }
    sim.stop().await.unwrap();
}

#[test]
fn switches_are_read_from_toml_and_checked() {
    let t = SimSpec::parse(TOPOLOGY).unwrap();
    assert_eq!(t.switches.len(), 2);
    assert_eq!(
        t.switches[1],
        SwitchSpec::new("c", &[("a", 0.5), ("b", 0.5)], 10.0, 2.0, true)
    );
    // Serialised and read back, the same.
    let text = toml::to_string(&t).unwrap();
    assert_eq!(SimSpec::parse(&text).unwrap(), t);

    let err = |extra: &str| {
        SimSpec::parse(&format!("{TOPOLOGY}\n{extra}"))
            .unwrap_err()
            .to_string()
    };
    let e =
        err("[[switch]]\nmodule = \"q\"\nterms = [[\"a\", 1.0]]\nat = 0.0\npressed_below = true");
    assert!(
        e.contains("switch 3") && e.contains("module: no module is named \"q\""),
        "{e}"
    );
    let line = format!("{TOPOLOGY}\n").lines().count() + 1;
    assert!(
        e.contains(&format!("line {line}")),
        "the line of its [[switch]] ({line}): {e}"
    );
    let e =
        err("[[switch]]\nmodule = \"hub\"\nterms = [[\"a\", 1.0]]\nat = 0.0\npressed_below = true");
    assert!(e.contains("is a \"hub\""), "{e}");
    let e = err("[[switch]]\nmodule = \"b\"\nterms = []\nat = 0.0\npressed_below = true");
    assert!(e.contains("terms is empty"), "{e}");
    let e = err("[[switch]]\nmodule = \"b\"\nterms = [[\"a\", 1.0], [\"hub\", 1.0]]\nat = 0.0\npressed_below = true");
    assert!(e.contains("terms[1]") && e.contains("\"hub\""), "{e}");
    let e = err("[[switch]]\nmodule = \"b\"\nterms = [[\"a\", 1.0], [\"a\", 1.0]]\nat = 0.0\npressed_below = true");
    assert!(
        e.contains("terms[1]") && e.contains("already terms[0]"),
        "{e}"
    );
    let e =
        err("[[switch]]\nmodule = \"b\"\nterms = [[\"a\", 0.0]]\nat = 0.0\npressed_below = true");
    assert!(e.contains("terms[0]: coefficient 0"), "{e}");
    let e =
        err("[[switch]]\nmodule = \"b\"\nterms = [[\"a\", 1.0]]\nat = nan\npressed_below = true");
    assert!(e.contains("at NaN must be finite"), "{e}");
    let e = err("[[switch]]\nmodule = \"b\"\nterms = [[\"a\", 1.0]]\nat = 0.0");
    assert!(e.contains("pressed_below"), "{e}");
    // A module has one limit input: not both its motor's and a [[switch]].
    let own = TOPOLOGY.replace(
        "name = \"c\"\ntype = \"stepper\"\nrate_ppm = 25.0\n",
        "name = \"c\"\ntype = \"stepper\"\nrate_ppm = 25.0\n[module.motor]\nlimit_min = -1.0\n",
    );
    let e = SimSpec::parse(&own).unwrap_err().to_string();
    assert!(
        e.contains("switch 2 (on \"c\")") && e.contains("limit_min"),
        "{e}"
    );
}
