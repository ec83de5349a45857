//! Kinematics: round trips over random reachable points, known values,
//! Kaos reducing to CoreXY, singular and unreachable points, non-finite
//! inputs, the Jacobian helper and the PIPES wire API.

mod common;

use core::f64::consts::{FRAC_PI_2, PI};

use common::wire_api;
use maxl::blocks::kinematics::{
    Cartesian, CartesianBlock, CoreXy, CoreXyBlock, FiveBar, FiveBarBlock, FiveBarMode, Kaos,
    KaosBlock, KinError, Kinematics, Scara, ScaraBlock, Side, FAIL_BAD_PARAMETER, FAIL_NON_FINITE,
    FAIL_OTHER_MODE, FAIL_OVERFLOW, FAIL_SINGULAR, FAIL_UNREACHABLE,
};
use nalgebra::{Matrix2, Vector2, Vector3};
use pipes_core::class::PipesClass;
use pipes_core::export::INPUT_DECODE_FAILED;
use pipes_core::function::CallError;
use pipes_core::Value;
use proptest::prelude::*;

/// Round-trip tolerance in work units (mm) for arms of ~100 mm in f64.
const TOL: f64 = 1e-9;

fn v2(x: f64, y: f64) -> Vector2<f64> {
    Vector2::new(x, y)
}

fn v3(x: f64, y: f64, z: f64) -> Vector3<f64> {
    Vector3::new(x, y, z)
}

fn scara(elbow: Side) -> Scara {
    Scara::new(120.0, 80.0, elbow, 0.05).unwrap()
}

fn fivebar() -> FiveBar {
    FiveBar::new(80.0, 100.0, 150.0, FiveBarMode::OUTWARD, 0.05).unwrap()
}

/// One of each mechanism, as 3-axis kinematics.
fn mechanisms() -> [Box<dyn Kinematics<3>>; 5] {
    [
        Box::new(Cartesian::identity()),
        Box::new(CoreXy::new(1.0).unwrap()),
        Box::new(Kaos::new(30.0, 1.0).unwrap()),
        Box::new(scara(Side::Left)),
        Box::new(fivebar()),
    ]
}

/// Angle difference wrapped to (−π, π].
fn angle_diff(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(2.0 * PI);
    if d > PI {
        d - 2.0 * PI
    } else {
        d
    }
}

const NON_FINITE: [f64; 3] = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY];

#[test]
fn corexy_known_values() {
    let k = CoreXy::new(1.0).unwrap();
    assert_eq!(
        Kinematics::<3>::inverse(&k, &v3(3.0, 1.0, 7.0)).unwrap(),
        v3(4.0, 2.0, 7.0)
    );
    assert_eq!(
        Kinematics::<3>::forward(&k, &v3(4.0, 2.0, 7.0)).unwrap(),
        v3(3.0, 1.0, 7.0)
    );
    // Motor A alone moves the tool along +x+y, motor B alone along +x−y.
    let s = CoreXy::new(80.0).unwrap();
    assert_eq!(
        Kinematics::<2>::forward(&s, &v2(160.0, 0.0)).unwrap(),
        v2(1.0, 1.0)
    );
    assert_eq!(
        Kinematics::<2>::forward(&s, &v2(0.0, 160.0)).unwrap(),
        v2(1.0, -1.0)
    );
    assert_eq!(
        Kinematics::<2>::inverse(&s, &v2(1.0, 0.5)).unwrap(),
        v2(120.0, 40.0)
    );
}

#[test]
fn cartesian_scale_and_offset() {
    let c = Cartesian::new(v3(80.0, -100.0, 400.0), v3(5.0, 0.0, -2.0)).unwrap();
    let q = Kinematics::<3>::inverse(&c, &v3(1.0, 2.0, 0.5)).unwrap();
    assert_eq!(q, v3(85.0, -200.0, 198.0));
    assert_eq!(Kinematics::<3>::forward(&c, &q).unwrap(), v3(1.0, 2.0, 0.5));
    let id = Cartesian::identity();
    assert_eq!(
        Kinematics::<2>::inverse(&id, &v2(-3.5, 9.0)).unwrap(),
        v2(-3.5, 9.0)
    );
    assert!(matches!(
        Cartesian::new(v3(1.0, 0.0, 1.0), v3(0.0, 0.0, 0.0)),
        Err(KinError::BadParameter(_))
    ));
    assert!(matches!(
        Cartesian::new(v3(1.0, 1.0, 1.0), v3(0.0, f64::NAN, 0.0)),
        Err(KinError::BadParameter(_))
    ));
    // Finite inputs whose result overflows are refused, not passed on.
    let big = Cartesian::new(v3(1e300, 1.0, 1.0), v3(0.0, 0.0, 0.0)).unwrap();
    assert_eq!(
        Kinematics::<3>::inverse(&big, &v3(1e10, 0.0, 0.0)),
        Err(KinError::Overflow)
    );
}

#[test]
fn kaos_reduces_to_corexy_at_45_degrees() {
    for scale in [1.0, 0.5, 80.0] {
        let kaos = Kaos::new(45.0, scale).unwrap();
        let core = CoreXy::new(scale).unwrap();
        for (x, y) in [
            (0.0, 0.0),
            (1.0, 0.0),
            (0.0, 1.0),
            (123.4, -56.7),
            (-300.0, 250.0),
        ] {
            let p = v2(x, y);
            let a = Kinematics::<2>::inverse(&kaos, &p).unwrap();
            let b = Kinematics::<2>::inverse(&core, &p).unwrap();
            assert!((a - b).norm() <= 1e-12 * (1.0 + b.norm()), "{a} vs {b}");
            let fa = Kinematics::<2>::forward(&kaos, &b).unwrap();
            assert!((fa - p).norm() <= 1e-12 * (1.0 + p.norm()), "{fa} vs {p}");
        }
    }
}

#[test]
fn kaos_known_values_at_30_degrees() {
    let k = Kaos::new(30.0, 1.0).unwrap();
    let r2 = 2f64.sqrt();
    let (s, c) = (0.5, 3f64.sqrt() / 2.0);
    let q = Kinematics::<2>::inverse(&k, &v2(2.0, 1.0)).unwrap();
    let want = v2(r2 * (2.0 * c + s), r2 * (2.0 * c - s));
    assert!((q - want).norm() < 1e-12, "{q} vs {want}");
    // Motor A alone moves the tool square to belt B (b = const), at 90° − θ.
    let p = Kinematics::<2>::forward(&k, &v2(1.0, 0.0)).unwrap();
    assert!((p.y / p.x - 60f64.to_radians().tan()).abs() < 1e-12);
    for bad in [0.0, 90.0, -10.0, 120.0, f64::NAN] {
        assert!(matches!(
            Kaos::new(bad, 1.0),
            Err(KinError::BadParameter(_))
        ));
    }
    assert!(matches!(
        Kaos::new(30.0, 0.0),
        Err(KinError::BadParameter(_))
    ));
}

#[test]
fn scara_known_values() {
    let arm = Scara::new(100.0, 100.0, Side::Right, 0.01).unwrap();
    // Elbow at (100, 0), forearm straight up: tool at (100, 100).
    let p = Kinematics::<2>::forward(&arm, &v2(0.0, FRAC_PI_2)).unwrap();
    assert!((p - v2(100.0, 100.0)).norm() < 1e-12);
    let q = Kinematics::<2>::inverse(&arm, &v2(100.0, 100.0)).unwrap();
    assert!((q - v2(0.0, FRAC_PI_2)).norm() < 1e-12, "{q}");
    // The other elbow: shoulder up at 90°, elbow angle −90°.
    let left = Scara::new(100.0, 100.0, Side::Left, 0.01).unwrap();
    let q = Kinematics::<2>::inverse(&left, &v2(100.0, 100.0)).unwrap();
    assert!((q - v2(FRAC_PI_2, -FRAC_PI_2)).norm() < 1e-12, "{q}");
    // Right elbow really is right of the shoulder-to-tool line.
    let e = arm.elbow_point(v2(0.0, FRAC_PI_2));
    let t = v2(100.0, 100.0);
    assert!(t.x * e.y - t.y * e.x < 0.0);
}

#[test]
fn scara_unreachable_and_singular_points() {
    let arm = scara(Side::Right); // reach 40..200 mm
    let inv = |x, y| Kinematics::<2>::inverse(&arm, &v2(x, y));
    assert_eq!(inv(200.1, 0.0), Err(KinError::Unreachable));
    assert_eq!(inv(0.0, 39.9), Err(KinError::Unreachable));
    assert_eq!(inv(0.0, 0.0), Err(KinError::Unreachable));
    // Fully stretched and folded, exactly and within the 0.05 rad margin.
    assert_eq!(inv(200.0, 0.0), Err(KinError::Singular));
    assert_eq!(inv(0.0, -40.0), Err(KinError::Singular));
    let near = |b: f64| (120f64.powi(2) + 80f64.powi(2) + 2.0 * 120.0 * 80.0 * b.cos()).sqrt();
    assert_eq!(inv(near(0.049), 0.0), Err(KinError::Singular));
    assert_eq!(inv(near(PI - 0.049), 0.0), Err(KinError::Singular));
    assert!(inv(near(0.051), 0.0).is_ok());
    assert!(inv(near(PI - 0.051), 0.0).is_ok());
    // A zero margin still refuses the exactly singular points.
    let zero = Scara::new(100.0, 100.0, Side::Right, 0.0).unwrap();
    assert_eq!(
        Kinematics::<2>::inverse(&zero, &v2(0.0, 200.0)),
        Err(KinError::Singular)
    );
    // Forward works everywhere, singular configurations included.
    let p = Kinematics::<2>::forward(&arm, &v2(0.3, 0.0)).unwrap();
    assert!((p.norm() - 200.0).abs() < 1e-12);
    for bad in [
        Scara::new(0.0, 1.0, Side::Left, 0.1),
        Scara::new(1.0, f64::INFINITY, Side::Left, 0.1),
        Scara::new(1.0, 1.0, Side::Left, -0.1),
        Scara::new(1.0, 1.0, Side::Left, FRAC_PI_2),
    ] {
        assert!(matches!(bad, Err(KinError::BadParameter(_))));
    }
}

#[test]
fn fivebar_known_configuration() {
    // Square arms: motors at (±40, 0), proximal 100, distal 150.
    let fb = fivebar();
    // A symmetric point on the axis: elbows mirror each other.
    let q = Kinematics::<2>::inverse(&fb, &v2(0.0, 200.0)).unwrap();
    assert!((angle_diff(q.x, PI - q.y)).abs() < 1e-12, "{q}");
    let (el, er) = fb.elbows(q);
    assert!((el - v2(-40.0, 0.0)).norm() - 100.0 < 1e-12);
    assert!(((el - v2(0.0, 200.0)).norm() - 150.0).abs() < 1e-9);
    assert!(((er - v2(0.0, 200.0)).norm() - 150.0).abs() < 1e-9);
    assert!(
        el.x < -40.0 && er.x > 40.0,
        "elbows bent outwards: {el} {er}"
    );
    let p = Kinematics::<2>::forward(&fb, &q).unwrap();
    assert!((p - v2(0.0, 200.0)).norm() < TOL);
}

#[test]
fn fivebar_unreachable_singular_and_other_mode() {
    let fb = fivebar();
    let inv = |x, y| Kinematics::<2>::inverse(&fb, &v2(x, y));
    // Beyond reach of both arms (250 mm from a motor).
    assert_eq!(inv(0.0, 300.0), Err(KinError::Unreachable));
    // At full stretch of the left arm: base, elbow and tool in line.
    let dir = v2(0.6, 0.8);
    let p = v2(-40.0, 0.0) + dir * 250.0;
    assert_eq!(inv(p.x, p.y), Err(KinError::Singular));
    // The tool on a motor: the arm's circle about the tool is centred there.
    assert_eq!(inv(-40.0, 0.0), Err(KinError::Singular));
    // Just below the motors the outward elbows put the tool on the other
    // side of the elbow line: reachable only in the other assembly mode.
    assert_eq!(inv(0.0, -50.0), Err(KinError::OtherMode));
    let flipped = FiveBar::new(
        80.0,
        100.0,
        150.0,
        FiveBarMode {
            left_elbow: Side::Right,
            right_elbow: Side::Left,
            tool: Side::Right,
        },
        0.05,
    )
    .unwrap();
    let q = Kinematics::<2>::inverse(&flipped, &v2(0.0, -200.0)).unwrap();
    let p = Kinematics::<2>::forward(&flipped, &q).unwrap();
    assert!((p - v2(0.0, -200.0)).norm() < TOL);
    // Forward: with distal links this long the elbows always meet; coincident
    // elbows leave the tool anywhere on a circle.
    let a = 0.4f64.acos();
    assert_eq!(
        Kinematics::<2>::forward(&fb, &v2(a, PI - a)),
        Err(KinError::Singular)
    );
    // Short distal links: motors at (±100, 0), proximal 100, distal 60.
    let short = FiveBar::new(200.0, 100.0, 60.0, FiveBarMode::OUTWARD, 0.05).unwrap();
    // Elbows 400 mm apart: the distal links cannot meet.
    assert_eq!(
        Kinematics::<2>::forward(&short, &v2(PI, 0.0)),
        Err(KinError::Unreachable)
    );
    // Elbows just under 120 mm apart: the distal links are nearly in line.
    let a = 0.4001f64.acos();
    assert_eq!(
        Kinematics::<2>::forward(&short, &v2(a, PI - a)),
        Err(KinError::Singular)
    );
    // Elbows 100 mm apart at the same height: a well-conditioned tool point.
    let a = 0.5f64.acos();
    let p = Kinematics::<2>::forward(&short, &v2(a, PI - a)).unwrap();
    assert!(
        (p - v2(0.0, 100.0 * a.sin() + 33.166247903554)).norm() < 1e-9,
        "{p}"
    );
}

#[test]
fn non_finite_inputs_are_errors() {
    for k in mechanisms() {
        for bad in NON_FINITE {
            for i in 0..3 {
                let mut p = v3(0.0, 150.0, 1.0);
                p[i] = bad;
                assert_eq!(k.inverse(&p), Err(KinError::NonFinite), "inverse {p}");
                assert_eq!(k.forward(&p), Err(KinError::NonFinite), "forward {p}");
            }
        }
    }
}

#[test]
fn jacobian_matches_the_analytic_one() {
    let arm = scara(Side::Right);
    let q = v2(0.4, 1.1);
    let j = Kinematics::<2>::jacobian(&arm, &q).unwrap();
    let (l1, l2) = arm.links();
    let (a, ab) = (q.x, q.x + q.y);
    let want = Matrix2::new(
        -l1 * a.sin() - l2 * ab.sin(),
        -l2 * ab.sin(),
        l1 * a.cos() + l2 * ab.cos(),
        l2 * ab.cos(),
    );
    assert!((j - want).norm() < 1e-6 * want.norm(), "{j} vs {want}");
    // CoreXY: q̇ = (ẋ + ẏ, ẋ − ẏ)·s.
    let core = CoreXy::new(2.0).unwrap();
    let qd = Kinematics::<2>::joint_velocity(&core, &v2(1.0, 1.0), &v2(3.0, 1.0)).unwrap();
    assert!((qd - v2(8.0, 4.0)).norm() < 1e-6, "{qd}");
    // Round trip: J·q̇ gives the work velocity back.
    let p = Kinematics::<2>::forward(&arm, &q).unwrap();
    let v = v2(10.0, -5.0);
    let qd = Kinematics::<2>::joint_velocity(&arm, &p, &v).unwrap();
    assert!((want * qd - v).norm() < 1e-5, "{qd}");
    assert_eq!(
        Kinematics::<2>::joint_velocity(&arm, &p, &v2(f64::NAN, 0.0)),
        Err(KinError::NonFinite)
    );
}

proptest! {
    #[test]
    fn corexy_and_kaos_round_trip(
        x in -1e4f64..1e4, y in -1e4f64..1e4, z in -100f64..100.0,
        angle in 1f64..89.0, scale in 0.01f64..1000.0,
    ) {
        let p = v3(x, y, z);
        let core = CoreXy::new(scale).unwrap();
        let kaos = Kaos::new(angle, scale).unwrap();
        let mechs: [&dyn Kinematics<3>; 2] = [&core, &kaos];
        for k in mechs {
            let q = k.inverse(&p).unwrap();
            prop_assert_eq!(q.z, z);
            let back = k.forward(&q).unwrap();
            prop_assert!((back - p).norm() <= 1e-9 * (1.0 + p.norm()), "{} vs {}", back, p);
        }
    }

    #[test]
    fn scara_round_trip(
        phi in -PI..PI, b in 0.06f64..(PI - 0.06), right in any::<bool>(), z in -10f64..10.0,
    ) {
        let (l1, l2) = (120.0f64, 80.0f64);
        let r = (l1 * l1 + l2 * l2 + 2.0 * l1 * l2 * b.cos()).sqrt();
        let p = v3(r * phi.cos(), r * phi.sin(), z);
        let side = if right { Side::Right } else { Side::Left };
        let arm = scara(side);
        let q = Kinematics::<3>::inverse(&arm, &p).unwrap();
        prop_assert!((q.y.abs() - b).abs() < 1e-6, "elbow {} vs {}", q.y, b);
        prop_assert_eq!(q.y > 0.0, right);
        let back = Kinematics::<3>::forward(&arm, &q).unwrap();
        prop_assert!((back - p).norm() < TOL, "{} vs {}", back, p);
        // And joints → work → joints.
        let q2 = Kinematics::<3>::inverse(&arm, &back).unwrap();
        prop_assert!(angle_diff(q2.x, q.x).abs() < 1e-9 && (q2.y - q.y).abs() < 1e-9);
    }

    #[test]
    fn fivebar_round_trip(x in -250f64..250.0, y in -250f64..300.0) {
        let fb = fivebar();
        let p = v2(x, y);
        match Kinematics::<2>::inverse(&fb, &p) {
            Ok(q) => {
                let back = Kinematics::<2>::forward(&fb, &q).unwrap();
                prop_assert!((back - p).norm() < TOL, "{} vs {}", back, p);
            }
            Err(e) => prop_assert!(matches!(
                e,
                KinError::Unreachable | KinError::Singular | KinError::OtherMode
            )),
        }
    }

    #[test]
    fn fivebar_joint_round_trip(a in -PI..PI, b in -PI..PI) {
        let fb = fivebar();
        let q = v2(a, b);
        if let Ok(p) = Kinematics::<2>::forward(&fb, &q) {
            let q2 = Kinematics::<2>::inverse(&fb, &p).unwrap();
            prop_assert!(angle_diff(q2.x, a).abs() < 1e-9 && angle_diff(q2.y, b).abs() < 1e-9,
                "{} vs {}", q2, q);
        }
    }

    #[test]
    fn no_panics_on_any_input(
        x in prop::num::f64::ANY, y in prop::num::f64::ANY, z in prop::num::f64::ANY,
    ) {
        let p = v3(x, y, z);
        for k in mechanisms() {
            for v in [k.inverse(&p), k.forward(&p)].into_iter().flatten() {
                prop_assert!(v.iter().all(|c| c.is_finite()));
            }
        }
    }
}

#[test]
fn fivebar_covers_a_useful_area() {
    // The OUTWARD mode above the motors reaches most of a 200 × 120 mm
    // drawing area centred at (0, 170).
    let fb = fivebar();
    let (mut ok, mut all) = (0, 0);
    for i in 0..=40 {
        for j in 0..=24 {
            let p = v2(-100.0 + 5.0 * f64::from(i), 110.0 + 5.0 * f64::from(j));
            all += 1;
            if Kinematics::<2>::inverse(&fb, &p).is_ok() {
                ok += 1;
            }
        }
    }
    assert!(ok * 10 >= all * 9, "{ok} of {all}");
}

#[test]
fn wire_signatures() {
    let members = |class: &str| {
        vec![
            format!(
                "{class}.inverse(stamp: u64, x: f32, y: f32, z: f32) -> (stamp: u64, a: f32, b: f32, c: f32)"
            ),
            format!("{class}.forward(a: f32, b: f32, c: f32) -> (x: f32, y: f32, z: f32)"),
        ]
    };
    let expect =
        |class: &'static str, ctor: &str| (class, format!("{class}({ctor}) -> ()"), members(class));
    assert_eq!(
        wire_api::<CartesianBlock>(),
        expect(
            "Cartesian",
            "scale_x: f32, scale_y: f32, scale_z: f32, offset_x: f32, offset_y: f32, offset_z: f32"
        )
    );
    assert_eq!(wire_api::<CoreXyBlock>(), expect("CoreXY", "scale: f32"));
    assert_eq!(
        wire_api::<KaosBlock>(),
        expect("Kaos", "angle_deg: f32, scale: f32")
    );
    assert_eq!(
        wire_api::<ScaraBlock>(),
        expect(
            "Scara",
            "shoulder: f32, forearm: f32, elbow_right: bool, margin: f32"
        )
    );
    assert_eq!(
        wire_api::<FiveBarBlock>(),
        expect(
            "FiveBar",
            "span: f32, proximal: f32, distal: f32, left_elbow_left: bool, \
             right_elbow_left: bool, tool_left: bool, margin: f32"
        )
    );
    assert_eq!(ScaraBlock::member_index("forward"), Some(1));
}

/// The failure code a wire member's error reports.
fn code<T>(r: Result<T, KinError>) -> Result<T, CallError> {
    r.map_err(CallError::from)
}

#[test]
fn wire_constructor_and_members() {
    let block = ScaraBlock::construct(&[
        Value::F32(100.0),
        Value::F32(100.0),
        Value::Bool(true),
        Value::F32(0.01),
    ])
    .unwrap();
    assert_eq!(
        block.kinematics(),
        &Scara::new(100.0, 100.0, Side::Right, 0.01f32.into()).unwrap()
    );
    let (stamp, a, b, c) = block.inverse(123_456, 100.0, 100.0, 2.5).unwrap();
    assert_eq!(stamp, 123_456);
    assert!(a.abs() < 1e-6 && (b - FRAC_PI_2 as f32).abs() < 1e-6);
    assert_eq!(c, 2.5);
    let (x, y, z) = block.forward(a, b, c).unwrap();
    assert!((x - 100.0).abs() < 1e-4 && (y - 100.0).abs() < 1e-4 && z == 2.5);
    fn failed<T>(code: u8) -> Result<T, CallError> {
        Err(CallError::Failed(code.into()))
    }
    assert_eq!(
        code(block.inverse(1, 500.0, 0.0, 0.0)),
        failed(FAIL_UNREACHABLE)
    );
    assert_eq!(
        code(block.inverse(1, 200.0, 0.0, 0.0)),
        failed(FAIL_SINGULAR)
    );
    assert_eq!(
        code(block.inverse(1, f32::NAN, 0.0, 0.0)),
        failed(FAIL_NON_FINITE)
    );
    assert_eq!(
        code(block.forward(0.0, 0.0, f32::INFINITY)),
        failed(FAIL_NON_FINITE)
    );
    // A missing or wrongly typed constructor input is the machinery's
    // decode failure.
    assert_eq!(
        ScaraBlock::construct(&[Value::F32(1.0)]).err(),
        Some(CallError::Failed(pipes_core::FailureCode::from_code(
            INPUT_DECODE_FAILED
        )))
    );

    // Invalid parameters: the constructor refuses them with code 5.
    assert!(matches!(
        ScaraBlock::wire_new(-1.0, 100.0, true, 0.01),
        Err(KinError::BadParameter(_))
    ));
    let refused = |r: Result<(), CallError>| r.err();
    let bad = Some(CallError::Failed(pipes_core::FailureCode::from_code(
        FAIL_BAD_PARAMETER,
    )));
    assert_eq!(
        refused(
            ScaraBlock::construct(&[
                Value::F32(-1.0),
                Value::F32(100.0),
                Value::Bool(true),
                Value::F32(0.01),
            ])
            .map(drop)
        ),
        bad
    );
    assert_eq!(
        refused(CoreXyBlock::construct(&[Value::F32(0.0)]).map(drop)),
        bad
    );
    assert_eq!(
        refused(KaosBlock::construct(&[Value::F32(90.0), Value::F32(1.0)]).map(drop)),
        bad
    );
    let cart = |sx: f32| {
        let mut v = [const { Value::F32(1.0) }; 6];
        v[0] = Value::F32(sx);
        CartesianBlock::construct(&v)
    };
    assert_eq!(refused(cart(0.0).map(drop)), bad);
    let fivebar = |span: f32| {
        FiveBarBlock::construct(&[
            Value::F32(span),
            Value::F32(100.0),
            Value::F32(150.0),
            Value::Bool(true),
            Value::Bool(false),
            Value::Bool(true),
            Value::F32(0.05),
        ])
    };
    assert_eq!(refused(fivebar(f32::NAN).map(drop)), bad);

    let core = CoreXyBlock::construct(&[Value::F32(1.0)]).unwrap();
    assert_eq!(core.inverse(7, 3.0, 1.0, 0.0), Ok((7, 4.0, 2.0, 0.0)));
    assert_eq!(core.forward(4.0, 2.0, 0.0), Ok((3.0, 1.0, 0.0)));
    // Finite f32 inputs whose joints exceed f32 range.
    let big = CoreXyBlock::wire_new(1e30).unwrap();
    assert_eq!(code(big.inverse(0, 1e30, 1e30, 0.0)), failed(FAIL_OVERFLOW));

    let kaos = KaosBlock::construct(&[Value::F32(45.0), Value::F32(1.0)]).unwrap();
    let (_, a, b, _) = kaos.inverse(0, 3.0, 1.0, 0.0).unwrap();
    assert!((a - 4.0).abs() < 1e-6 && (b - 2.0).abs() < 1e-6);

    let fb = fivebar(80.0).unwrap();
    assert_eq!(fb.kinematics(), &wire_test_fivebar());
    let (s, a, b, c) = fb.inverse(99, 10.0, 180.0, -1.0).unwrap();
    assert_eq!((s, c), (99, -1.0));
    let (x, y, _) = fb.forward(a, b, c).unwrap();
    assert!((x - 10.0).abs() < 1e-3 && (y - 180.0).abs() < 1e-3);
    assert_eq!(
        code(fb.inverse(0, 0.0, -50.0, 0.0)),
        failed(FAIL_OTHER_MODE)
    );

    let cart = CartesianBlock::construct(&[
        Value::F32(2.0),
        Value::F32(2.0),
        Value::F32(1.0),
        Value::F32(1.0),
        Value::F32(0.0),
        Value::F32(0.0),
    ])
    .unwrap();
    assert_eq!(cart.inverse(5, 1.0, 2.0, 3.0), Ok((5, 3.0, 4.0, 3.0)));
    assert_eq!(cart.forward(3.0, 4.0, 3.0), Ok((1.0, 2.0, 3.0)));
}

/// The five-bar the wire test's constructor inputs describe.
fn wire_test_fivebar() -> FiveBar {
    let mode = FiveBarMode {
        left_elbow: Side::Left,
        right_elbow: Side::Right,
        tool: Side::Left,
    };
    FiveBar::new(80.0, 100.0, 150.0, mode, 0.05f32.into()).unwrap()
}

/// Deterministic sweep over the arms' working areas: the largest round-trip
/// error in f64 and through the f32 wire members (printed with
/// `--nocapture` for docs/kinematics.md).
#[test]
fn round_trip_error_sweep() {
    let arm = scara(Side::Right);
    let fb = fivebar();
    let arm_block = ScaraBlock::new(arm);
    let fb_block = FiveBarBlock::new(fb);
    let (mut n_arm, mut n_fb) = (0, 0);
    let (mut e_arm, mut e_fb, mut w_arm, mut w_fb) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for i in 0..=200 {
        for j in 0..=200 {
            let p = v2(-200.0 + 2.0 * f64::from(i), -200.0 + 2.5 * f64::from(j));
            if let Ok(q) = Kinematics::<2>::inverse(&arm, &p) {
                n_arm += 1;
                e_arm = e_arm.max((Kinematics::<2>::forward(&arm, &q).unwrap() - p).norm());
                let (_, a, b, _) = arm_block.inverse(0, p.x as f32, p.y as f32, 0.0).unwrap();
                let (x, y, _) = arm_block.forward(a, b, 0.0).unwrap();
                w_arm = w_arm.max((v2(x.into(), y.into()) - p).norm());
            }
            if let Ok(q) = Kinematics::<2>::inverse(&fb, &p) {
                n_fb += 1;
                e_fb = e_fb.max((Kinematics::<2>::forward(&fb, &q).unwrap() - p).norm());
                if let Ok((_, a, b, _)) = fb_block.inverse(0, p.x as f32, p.y as f32, 0.0) {
                    if let Ok((x, y, _)) = fb_block.forward(a, b, 0.0) {
                        w_fb = w_fb.max((v2(x.into(), y.into()) - p).norm());
                    }
                }
            }
        }
    }
    println!("scara: {n_arm} points, f64 max error {e_arm:.3e} mm, f32 wire {w_arm:.3e} mm");
    println!("fivebar: {n_fb} points, f64 max error {e_fb:.3e} mm, f32 wire {w_fb:.3e} mm");
    assert!(n_arm > 10_000 && n_fb > 5_000);
    assert!(e_arm < TOL && e_fb < TOL);
    assert!(w_arm < 1e-3 && w_fb < 1e-3);
}
