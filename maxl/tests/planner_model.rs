//! Planning with a speed-dependent acceleration model (`AccelModel`): a
//! model whose acceleration falls with speed, as a stepper's torque does.
//! Every sampled acceleration stays within what the model gives at the
//! sampled speed, every profile covers its segment, the plan ends where it
//! was sent, and it runs faster than a constant acceleration safe at the
//! top speed, slower than one the model gives only at rest; a constant
//! model plans exactly the trapezoid at that acceleration.

mod common;

use std::sync::Arc;

use common::rng::XorShiftStar;
use maxl::blocks::planner::{AccelModel, Limits, Planner, VectorLimits};

/// `a0 · max(0.15, 1 − v/v0)` in any direction.
#[derive(Debug)]
struct Falling {
    a0: f64,
    v0: f64,
}

impl AccelModel<3> for Falling {
    fn max_accel(&self, _motion: &[f64; 3], _accel: &[f64; 3], speed: f64) -> f64 {
        self.a0 * (1.0 - speed / self.v0).max(0.15)
    }
}

fn planner(accel: f64, model: Option<Arc<dyn AccelModel<3>>>) -> Planner<3> {
    let limits = Limits::new([400.0; 3], [accel; 3], 0.02).unwrap();
    let vector = VectorLimits::new(300.0, accel).unwrap();
    let mut p = Planner::with_vector_limits(limits, vector, 4096).unwrap();
    p.set_accel_model(model);
    p
}

fn path(seed: u64) -> Vec<([f64; 3], f64)> {
    let mut rng = XorShiftStar(seed);
    let (mut q, mut h) = ([0.0; 3], 0.0f64);
    (0..200)
        .map(|_| {
            h += (rng.next() - 0.5) * 2.0;
            let l = 0.2 + 60.0 * rng.next().powi(2);
            q = [q[0] + l * h.cos(), q[1] + l * h.sin(), 0.0];
            (q, 50.0 + 250.0 * rng.next())
        })
        .collect()
}

fn run(p: &mut Planner<3>, path: &[([f64; 3], f64)]) -> f64 {
    for (q, f) in path {
        p.line(*q, *f).unwrap();
    }
    p.plan().duration_us() * 1e-6
}

#[test]
fn a_falling_model_is_kept_and_pays_off() {
    let model = Arc::new(Falling {
        a0: 8000.0,
        v0: 400.0,
    });
    for seed in [1, 2, 3] {
        let route = path(seed);
        let mut p = planner(1e6, Some(model.clone()));
        let modelled = run(&mut p, &route);
        let plan = p.plan();
        for s in &plan.segments {
            let pr = &s.profile;
            let d = pr.at(pr.duration()).0;
            assert!((d - pr.length).abs() <= 1e-9 * (1.0 + pr.length), "{pr:?}");
        }
        for w in plan.segments.windows(2) {
            assert!(
                (w[0].profile.exit - w[1].profile.entry).abs() <= 1e-9 * (1.0 + w[0].profile.exit)
            );
        }
        // Sampled: every acceleration within the model's at that speed.
        let mut t = 0;
        let last = loop {
            let k = p.sample_kin(t).unwrap();
            let v = k.vel.iter().map(|x| x * x).sum::<f64>().sqrt();
            let a = k.acc.iter().map(|x| x * x).sum::<f64>().sqrt();
            let allowed = model.max_accel(&[1.0, 0.0, 0.0], &[1.0, 0.0, 0.0], v);
            assert!(
                a <= allowed * (1.0 + 1e-9),
                "t {t}: |a| {a} at |v| {v} (allowed {allowed})"
            );
            if p.is_idle() {
                break k;
            }
            t += 500;
        };
        assert_eq!(last.pos, route.last().unwrap().0);
        // Against constant accelerations: safe at the top speed (300 mm/s
        // gives 2000 mm/s²) and at rest (8000).
        let safe = run(
            &mut planner(model.max_accel(&[0.0; 3], &[0.0; 3], 300.0), None),
            &route,
        );
        let rest = run(&mut planner(8000.0, None), &route);
        eprintln!("seed {seed}: model {modelled:.3} s, constant safe {safe:.3} s, constant at rest {rest:.3} s");
        assert!(modelled < 0.9 * safe, "{modelled} vs {safe}");
        assert!(modelled > rest, "{modelled} vs {rest}");
    }
}

#[test]
fn a_constant_model_plans_the_trapezoid() {
    #[derive(Debug)]
    struct Constant(f64);
    impl AccelModel<3> for Constant {
        fn max_accel(&self, _: &[f64; 3], _: &[f64; 3], _: f64) -> f64 {
            self.0
        }
    }
    let route = path(7);
    let banded = run(&mut planner(1e6, Some(Arc::new(Constant(3000.0)))), &route);
    let plain = run(&mut planner(3000.0, None), &route);
    assert!(
        (banded - plain).abs() <= 1e-9 * plain,
        "{banded} vs {plain}"
    );
}
