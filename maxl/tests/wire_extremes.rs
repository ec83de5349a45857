//! Every block's wire members take whatever a pipe or a caller sends:
//! extreme stamps, NaN, infinities, huge and negative numbers, in any
//! order. None may panic (a panic in a member takes the host runtime down);
//! each answers with outputs or a failure code.

use maxl::blocks::bedlevel::{BedMeshBlock, BedPlaneBlock};
use maxl::blocks::chirp::ChirpBlock;
use maxl::blocks::interp::InterpolatorBlock;
use maxl::blocks::kinematics::{CoreXy, CoreXyBlock, FiveBarBlock, KaosBlock, ScaraBlock};
use maxl::blocks::onedof::OneDofBlock;
use maxl::blocks::planner::PlannerBlock;
use maxl::blocks::timer::TimerBlock;
use osap_core::time::SystemInstant;

const STAMPS: [u64; 7] = [0, 1, 1024, 2048 * 1000, 1 << 40, u64::MAX - 1, u64::MAX];
const F32S: [f32; 9] = [
    0.0,
    -1.0,
    1.5,
    1e30,
    -1e30,
    f32::MAX,
    f32::NAN,
    f32::INFINITY,
    f32::NEG_INFINITY,
];
const F64S: [f64; 7] = [
    0.0,
    -3.0,
    10.0,
    1e300,
    f64::NAN,
    f64::INFINITY,
    f64::NEG_INFINITY,
];

#[test]
fn timer_members() {
    for (iv, lead) in [(1024, 3072), (16384, 32768), (256, 512)] {
        let mut t = TimerBlock::new(iv, lead).unwrap();
        let _ = t.tick();
        for &now in &STAMPS {
            t.set_now(SystemInstant::from_micros(now));
            for _ in 0..3 {
                let _ = t.tick();
            }
            let _ = t.status();
        }
        // Time going backwards, then a reset.
        t.set_now(SystemInstant::from_micros(5));
        let _ = t.tick();
        t.reset();
        let _ = t.tick();
    }
    for (iv, lead) in [(0, 0), (1000, 1), (u32::MAX, u32::MAX), (1024, 0)] {
        let _ = TimerBlock::new(iv, lead);
    }
}

#[test]
fn onedof_members() {
    let mut a = OneDofBlock::new(20.0, 200.0, 80.0, 1.0, 1024).unwrap();
    let _ = a.move_to(1.0);
    for &stamp in &STAMPS {
        let _ = a.sample(stamp);
        for &x in &F32S {
            let _ = a.move_to(x);
            let _ = a.velocity(x);
            let _ = a.set_home(x);
            let _ = a.set_position(x);
            let _ = a.home(-1, x);
            let _ = a.home(1, x);
            let _ = a.home(0, x);
            let _ = a.sample(stamp);
            let _ = a.limit_hit(stamp);
        }
        let _ = a.stop();
        let _ = a.status();
    }
    for &x in &F32S {
        let _ = OneDofBlock::new(x, x, x, x, 1024);
        let _ = OneDofBlock::new(1.0, 1.0, 1.0, 0.0, 777);
    }
}

#[test]
fn chirp_members() {
    for &x in &F32S {
        let _ = ChirpBlock::new(x, 10.0, 1.0, 1.0, false);
        let _ = ChirpBlock::new(1.0, 10.0, x, x, true);
    }
    let mut c = ChirpBlock::new(1.0, 100.0, 2.0, 1.0, true).unwrap();
    for &at in &STAMPS {
        c.start(at);
        for &stamp in &STAMPS {
            let _ = c.sample(stamp);
            let _ = c.done();
        }
        for &x in &F32S {
            let _ = c.set_center(x);
            let _ = c.set_fade(x);
        }
    }
}

#[test]
fn interpolator_members() {
    let mut i = InterpolatorBlock::new(1024, 16).unwrap();
    for &stamp in &STAMPS {
        for &x in &F64S {
            let _ = i.push(stamp, x, 1.0, -x);
            let _ = i.push(stamp.wrapping_add(1024), x, x, x);
        }
        let _ = i.eval(stamp);
        let _ = i.vel(stamp);
        let _ = i.span();
    }
    i.clear();
    for (iv, cap) in [(0, 0), (1024, 0), (1000, 16), (u32::MAX, u32::MAX)] {
        let _ = InterpolatorBlock::new(iv, cap);
    }
}

#[test]
fn planner_members() {
    let mut p = PlannerBlock::new(300.0, 300.0, 20.0, 3000.0, 3000.0, 500.0, 0.01, 1e9).unwrap();
    for &x in &F64S {
        let _ = p.line(x, 1.0, 0.0, 50.0);
        let _ = p.line(1.0, 1.0, 0.0, x);
        let _ = p.arc(x, 0.0, 0.0, 5.0, 5.0, true, 50.0);
        let _ = p.arc(10.0, 0.0, 0.0, x, 0.0, false, x);
        let _ = p.set_position(x, x, x);
        let _ = p.set_feed_scale(x);
    }
    for &stamp in &STAMPS {
        let _ = p.start(stamp);
        let _ = p.sample(stamp);
        let _ = p.status();
        let _ = p.line(5.0, 5.0, 0.0, 50.0);
        let _ = p.halt();
    }
    for &x in &F64S {
        let _ = PlannerBlock::new(x, 1.0, 1.0, 1.0, 1.0, 1.0, x, x);
    }
}

#[test]
fn kinematics_members() {
    let corexy = CoreXyBlock::new(CoreXy::new(1.0).unwrap());
    let kaos = KaosBlock::wire_new(30.0, 1.0).unwrap();
    let scara = ScaraBlock::wire_new(100.0, 80.0, true, 0.05).unwrap();
    let fivebar = FiveBarBlock::wire_new(50.0, 80.0, 100.0, true, false, true, 0.05).unwrap();
    for &stamp in &STAMPS {
        for &x in &F32S {
            for &y in &[0.0f32, 30.0, f32::NAN, -1e30] {
                let _ = corexy.inverse(stamp, x, y, x);
                let _ = corexy.forward(x, y, x);
                let _ = kaos.inverse(stamp, x, y, 0.0);
                let _ = kaos.forward(x, y, 0.0);
                let _ = scara.inverse(stamp, x, y, 0.0);
                let _ = scara.forward(x, y, 0.0);
                let _ = fivebar.inverse(stamp, x, y, 0.0);
                let _ = fivebar.forward(x, y, 0.0);
            }
        }
    }
    for &x in &F32S {
        let _ = KaosBlock::wire_new(x, x);
        let _ = ScaraBlock::wire_new(x, 1.0, false, x);
        let _ = FiveBarBlock::wire_new(x, x, 1.0, false, false, false, x);
    }
}

#[test]
fn bed_members() {
    let mut plane = BedPlaneBlock::new();
    for &x in &F32S {
        let _ = plane.add_probe(x, 1.0, x);
        let _ = plane.add_probe(1.0, x, 2.0);
    }
    let _ = plane.fit();
    let _ = plane.plane();
    for &x in &F32S {
        let _ = plane.set_plane(x, 0.0, x);
        let _ = plane.apply(1, x, x, x);
        let _ = plane.unapply(x, 0.0, x);
    }
    plane.clear();
    let _ = plane.fit();

    let mut mesh = BedMeshBlock::new(0.0, 0.0, 10.0, 10.0, 3, 3).unwrap();
    for ix in [0u16, 1, 2, 3, u16::MAX] {
        for iy in [0u16, 2, u16::MAX] {
            for &z in &F32S {
                let _ = mesh.set_probe(ix, iy, z);
            }
        }
    }
    let _ = mesh.stats();
    for &x in &F32S {
        let _ = mesh.apply(u64::MAX, x, x, x);
        let _ = mesh.unapply(x, x, x);
    }
    mesh.clear();
    for &x in &F32S {
        let _ = BedMeshBlock::new(x, x, x, x, 2, 2);
        let _ = BedMeshBlock::new(0.0, 0.0, 1.0, 1.0, u16::MAX, u16::MAX);
    }
}
