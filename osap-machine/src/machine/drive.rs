//! From machine coordinates to what each motor is sent, and back.
//!
//! The planner works in machine coordinates (the axes, in the file's
//! order). Each motor `i` is sent `m_i = s_i · q_i(p) − o_i`: `q` is the
//! kinematics' joint coordinate for the machine position `p` (cartesian: the
//! axis's own coordinate), `s_i` is −1 for an inverted motor, and `o_i` is
//! an offset chosen so that re-defining where the machine is (homing,
//! [`Drive::rebase`]) never moves a motor. At start every motor reads 0
//! (where the module booted) and the machine takes itself to be at
//! [`start_position`].

use maxl::blocks::bedlevel::BedMesh;
use maxl::blocks::kinematics::{CoreXy, FiveBar, FiveBarMode, KinError, Planar, Scara, Side};
use nalgebra::Vector2;

use crate::config::{Kinematics, MachineFile, Side as FileSide};

/// The most axes a machine plans together.
pub const MAX_AXES: usize = 6;

/// What moves one motor.
#[derive(Debug, Clone, PartialEq)]
enum Source {
    /// A cartesian axis: the machine coordinate in this slot.
    Axis(usize),
    /// Joint 0 or 1 of the xy mechanism.
    Joint(usize),
}

/// One driven motor.
#[derive(Debug, Clone)]
pub struct DriveMotor {
    /// The motor's key in `[motors]`.
    pub name: String,
    /// The module's key in `[modules]`.
    pub module: String,
    /// Full steps per motor unit.
    pub full_steps_per_unit: f64,
    /// Microsteps per full step.
    pub microsteps: u16,
    /// Enable the driver at start.
    pub enable: bool,
    /// For a motor that never stops turning (an extruder's): the period,
    /// in motor units, its positions may be sent modulo. A module's track
    /// wraps every 65 536 microsteps, so a position sent less a whole
    /// number of periods moves the motor the same, and stays small
    /// enough for the wire's `f32` to carry to a fraction of a microstep
    /// after any length of filament.
    pub wrap: Option<f64>,
    sign: f64,
    source: Source,
}

/// The machine's mapping from coordinates to motor positions.
pub struct Drive {
    axes: Vec<String>,
    motors: Vec<DriveMotor>,
    planar: Option<Box<dyn Planar + Send + Sync>>,
    offsets: Vec<f64>,
    /// A bed mesh, added to z (slot 2) under the tool's x and y (the
    /// axes after z follow unchanged).
    mesh: Option<BedMesh>,
    /// Slots 0 and 1 hold the mechanism's joint coordinates themselves
    /// (an arm homing its joints), not x and y; no mesh applies.
    joint_space: bool,
}

impl std::fmt::Debug for Drive {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Drive")
            .field("axes", &self.axes)
            .field("motors", &self.motors)
            .field("planar", &self.planar.is_some())
            .field("offsets", &self.offsets)
            .field("mesh", &self.mesh.is_some())
            .field("joint_space", &self.joint_space)
            .finish()
    }
}

/// Where a machine takes itself to be before it is homed: 0 on every axis
/// whose travel includes 0, else the axis's `min`.
pub fn start_position(cfg: &MachineFile) -> Vec<f64> {
    cfg.axis_names()
        .iter()
        .map(|name| {
            let a = &cfg.axes[*name];
            if a.min <= 0.0 && 0.0 <= a.max {
                0.0
            } else {
                a.min
            }
        })
        .collect()
}

fn side(s: FileSide) -> Side {
    match s {
        FileSide::Left => Side::Left,
        FileSide::Right => Side::Right,
    }
}

/// The xy mechanism of a machine file, if it has one.
pub fn mechanism(cfg: &MachineFile) -> Result<Option<Box<dyn Planar + Send + Sync>>, KinError> {
    Ok(match &cfg.kinematics {
        Kinematics::Cartesian {} => None,
        Kinematics::CoreXy { .. } => Some(Box::new(CoreXy::new(1.0)?)),
        Kinematics::Scara {
            l1,
            l2,
            elbow,
            margin_deg,
            ..
        } => Some(Box::new(Scara::new(
            *l1,
            *l2,
            side(*elbow),
            margin_deg.to_radians(),
        )?)),
        Kinematics::FiveBar {
            span,
            l1,
            l2,
            left_elbow,
            right_elbow,
            tool,
            margin_deg,
            ..
        } => Some(Box::new(FiveBar::new(
            *span,
            *l1,
            *l2,
            FiveBarMode {
                left_elbow: side(*left_elbow),
                right_elbow: side(*right_elbow),
                tool: side(*tool),
            },
            margin_deg.to_radians(),
        )?)),
    })
}

/// Why a drive could not be built: the file key and the fix.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum DriveError {
    /// More axes than the planner plans together.
    #[error("axes: {} axes ({}); a machine plans at most {MAX_AXES} together", .0.len(), .0.join(", "))]
    TooManyAxes(Vec<String>),
    /// The kinematics could not be built.
    #[error("kinematics: {0}")]
    Kinematics(KinError),
    /// A motor the axes or kinematics name is not in `[motors]`.
    #[error("motors.{0}: no such motor")]
    NoMotor(String),
    /// The start position is outside what the kinematics reach.
    #[error("the start position {at:?} is outside the kinematics: {cause}")]
    StartOutside {
        /// The start position, axis order.
        at: Vec<f64>,
        /// Why the kinematics refused it.
        cause: KinError,
    },
    /// A bed mesh on a machine whose axes do not begin x, y, z.
    #[error("bed_mesh: a bed mesh needs axes x, y and z; this machine has {}", .0.join(", "))]
    MeshNeedsXyz(Vec<String>),
    /// The position with the mesh applied is outside the kinematics.
    #[error("bed_mesh: {0}")]
    MeshOutside(KinError),
}

impl Drive {
    /// The drive of a validated machine file, with every motor at 0 while
    /// the machine stands at `at` (axis order).
    pub fn new(cfg: &MachineFile, at: &[f64]) -> Result<Drive, DriveError> {
        let axes: Vec<String> = cfg.axis_names().iter().map(|s| s.to_string()).collect();
        if axes.len() > MAX_AXES {
            return Err(DriveError::TooManyAxes(axes));
        }
        let planar = mechanism(cfg).map_err(DriveError::Kinematics)?;
        let mut motors = Vec::new();
        let mut add = |name: &str, source: Source| -> Result<(), DriveError> {
            let m = cfg
                .motors
                .get(name)
                .ok_or_else(|| DriveError::NoMotor(name.to_string()))?;
            let continuous = match source {
                Source::Axis(slot) => cfg
                    .axes
                    .get(cfg.axis_names()[slot])
                    .is_some_and(|a| a.kind == crate::config::AxisKind::Extruder),
                Source::Joint(_) => false,
            };
            // As the module computes its scale: in f32.
            let per_unit = f64::from(m.full_steps_per_unit as f32) * f64::from(m.microsteps);
            motors.push(DriveMotor {
                name: name.to_string(),
                module: m.module.clone(),
                full_steps_per_unit: m.full_steps_per_unit,
                microsteps: m.microsteps,
                enable: m.enable,
                wrap: continuous.then(|| 65_536.0 / per_unit),
                sign: if m.invert { -1.0 } else { 1.0 },
                source,
            });
            Ok(())
        };
        if planar.is_some() {
            for (j, name) in cfg.kinematics.motors().iter().enumerate() {
                add(name, Source::Joint(j))?;
            }
        }
        for (slot, axis) in axes.iter().enumerate() {
            if let Some(motor) = cfg.motor_for_axis(axis) {
                add(motor, Source::Axis(slot))?;
            }
        }
        let mut drive = Drive {
            offsets: vec![0.0; motors.len()],
            axes,
            motors,
            planar,
            mesh: None,
            joint_space: false,
        };
        let zeros = vec![0.0; drive.motors.len()];
        drive
            .rebase(at, &zeros)
            .map_err(|cause| DriveError::StartOutside {
                at: at.to_vec(),
                cause,
            })?;
        Ok(drive)
    }

    /// The same drive following a bed mesh: z (the axis named z, which
    /// must come after x and y) is raised by the mesh's height under x, y.
    /// The motors keep their positions at `at` (motor positions `m`).
    pub fn with_mesh(mut self, mesh: BedMesh, at: &[f64], m: &[f64]) -> Result<Drive, DriveError> {
        if self.axes.len() < 3 || self.axes[..3] != ["x", "y", "z"] {
            return Err(DriveError::MeshNeedsXyz(self.axes));
        }
        self.mesh = Some(mesh);
        self.rebase(at, m).map_err(DriveError::MeshOutside)?;
        Ok(self)
    }

    /// Replaces the bed mesh (or drops it) keeping the offsets: the same
    /// motor positions then read as another machine z.
    pub(crate) fn set_mesh(&mut self, mesh: Option<BedMesh>) {
        self.mesh = mesh;
    }

    /// The bed mesh followed, if any.
    pub fn mesh(&self) -> Option<&BedMesh> {
        self.mesh.as_ref()
    }

    /// The axis names, in slot order.
    pub fn axes(&self) -> &[String] {
        &self.axes
    }

    /// The driven motors, in the order of [`Drive::motor_positions`].
    pub fn motors(&self) -> &[DriveMotor] {
        &self.motors
    }

    /// Whether slots 0 and 1 are the mechanism's joints
    /// ([`Drive::set_joint_space`]).
    pub fn joint_space(&self) -> bool {
        self.joint_space
    }

    /// Plans in the mechanism's joint space (`true`: slots 0 and 1 are
    /// its two joint coordinates, radians, sent to the motors as they are)
    /// or in machine coordinates. The offsets stay, so the same motor
    /// positions read as the joints they are in either space: an arm
    /// homes its joints, and its machine position follows from them. No
    /// effect without a mechanism (cartesian).
    pub fn set_joint_space(&mut self, on: bool) {
        self.joint_space = on && self.planar.is_some();
    }

    /// The mechanism's joint coordinates of xy `(x, y)`, if it has a
    /// mechanism.
    pub fn inverse_xy(&self, x: f64, y: f64) -> Option<Result<[f64; 2], KinError>> {
        let k = self.planar.as_ref()?;
        Some(k.inverse_xy(Vector2::new(x, y)).map(|q| [q[0], q[1]]))
    }

    /// The tool's xy at the mechanism's joint coordinates `q`, if it has a
    /// mechanism.
    pub fn forward_xy(&self, q: [f64; 2]) -> Option<Result<[f64; 2], KinError>> {
        let k = self.planar.as_ref()?;
        Some(k.forward_xy(Vector2::new(q[0], q[1])).map(|p| [p[0], p[1]]))
    }

    /// Joint coordinates of machine position `p`.
    fn joints(&self, p: &[f64]) -> Result<Option<Vector2<f64>>, KinError> {
        match &self.planar {
            None => Ok(None),
            Some(k) => {
                let xy = Vector2::new(p[0], p.get(1).copied().unwrap_or(0.0));
                if !(xy.x.is_finite() && xy.y.is_finite()) {
                    return Err(KinError::NonFinite);
                }
                if self.joint_space {
                    return Ok(Some(xy));
                }
                k.inverse_xy(xy).map(Some)
            }
        }
    }

    /// The motor positions (motor units) for machine position `p`.
    pub fn motor_positions(&self, p: &[f64]) -> Result<Vec<f64>, KinError> {
        let meshed;
        let p = match &self.mesh {
            Some(mesh) if p.len() >= 3 && !self.joint_space => {
                let z = mesh
                    .apply(p[0], p[1], p[2])
                    .map_err(|_| KinError::NonFinite)?;
                meshed = [&[p[0], p[1], z][..], &p[3..]].concat();
                &meshed[..]
            }
            _ => p,
        };
        let q = self.joints(p)?;
        Ok(self
            .motors
            .iter()
            .zip(&self.offsets)
            .map(|(m, o)| {
                let joint = match m.source {
                    Source::Axis(slot) => p.get(slot).copied().unwrap_or(0.0),
                    Source::Joint(j) => q.map_or(0.0, |q| q[j]),
                };
                m.sign * joint - o
            })
            .collect())
    }

    /// The machine position of motor positions `m` (the inverse of
    /// [`Drive::motor_positions`]).
    pub fn machine_position(&self, m: &[f64]) -> Result<Vec<f64>, KinError> {
        let mut p = vec![0.0; self.axes.len()];
        let mut q = Vector2::zeros();
        for ((motor, o), v) in self.motors.iter().zip(&self.offsets).zip(m) {
            let joint = (v + o) * motor.sign;
            match motor.source {
                Source::Axis(slot) => p[slot] = joint,
                Source::Joint(j) => q[j] = joint,
            }
        }
        if let Some(k) = self.planar.as_ref().filter(|_| !self.joint_space) {
            let xy = k.forward_xy(q)?;
            if !(xy.x.is_finite() && xy.y.is_finite()) {
                return Err(KinError::Overflow);
            }
            p[0] = xy.x;
            if p.len() > 1 {
                p[1] = xy.y;
            }
        } else if self.joint_space {
            p[0] = q[0];
            if p.len() > 1 {
                p[1] = q[1];
            }
        }
        if let (Some(mesh), true) = (&self.mesh, p.len() >= 3 && !self.joint_space) {
            p[2] = mesh
                .unapply(p[0], p[1], p[2])
                .map_err(|_| KinError::NonFinite)?;
        }
        Ok(p)
    }

    /// Re-defines where the machine is: from now on, machine position `p`
    /// is where the motors stand at `m` (so no motor moves).
    pub fn rebase(&mut self, p: &[f64], m: &[f64]) -> Result<(), KinError> {
        self.offsets = vec![0.0; self.motors.len()];
        let raw = self.motor_positions(p)?;
        self.offsets = raw.iter().zip(m).map(|(r, m)| r - m).collect();
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plotter() -> MachineFile {
        MachineFile::load(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../examples/machines/plotter.toml"
        ))
        .unwrap()
    }

    #[test]
    fn corexy_round_trips_and_inverts() {
        let cfg = plotter();
        let d = Drive::new(&cfg, &start_position(&cfg)).unwrap();
        assert_eq!(d.axes(), ["x", "y"]);
        let m = d.motor_positions(&[10.0, 5.0]).unwrap();
        // a = x + y; b is inverted: −(x − y).
        assert!(
            (m[0] - 15.0).abs() < 1e-12 && (m[1] + 5.0).abs() < 1e-12,
            "{m:?}"
        );
        let p = d.machine_position(&m).unwrap();
        assert!((p[0] - 10.0).abs() < 1e-12 && (p[1] - 5.0).abs() < 1e-12);
    }

    #[test]
    fn rebase_keeps_the_motors_where_they_are() {
        let cfg = plotter();
        let mut d = Drive::new(&cfg, &[0.0, 0.0]).unwrap();
        let m = d.motor_positions(&[20.0, 30.0]).unwrap();
        d.rebase(&[0.0, 0.0], &m).unwrap();
        let again = d.motor_positions(&[0.0, 0.0]).unwrap();
        for (a, b) in m.iter().zip(&again) {
            assert!((a - b).abs() < 1e-12);
        }
        // A 1 mm move in x after rebasing moves each belt by 1 mm.
        let moved = d.motor_positions(&[1.0, 0.0]).unwrap();
        assert!((moved[0] - m[0] - 1.0).abs() < 1e-12);
        assert!((moved[1] - m[1] + 1.0).abs() < 1e-12);
    }

    #[test]
    fn a_bed_mesh_raises_z_under_the_tool_and_reads_back() {
        let cfg = MachineFile::load(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../examples/machines/mill.toml"
        ))
        .unwrap();
        let mesh = crate::mesh::load(&cfg.bed_mesh_path().unwrap()).unwrap();
        let d = Drive::new(&cfg, &[0.0; 3])
            .unwrap()
            .with_mesh(mesh, &[0.0; 3], &[0.0; 3])
            .unwrap();
        // The mesh rises 0.15 mm from x = 20 to x = 280 (at y = 20).
        let a = d.motor_positions(&[20.0, 20.0, -10.0]).unwrap();
        let b = d.motor_positions(&[280.0, 20.0, -10.0]).unwrap();
        assert!((b[2] - a[2] - 0.15).abs() < 1e-12, "{a:?} {b:?}");
        let back = d.machine_position(&b).unwrap();
        assert!((back[2] + 10.0).abs() < 1e-12 && (back[0] - 280.0).abs() < 1e-12);
        // Where the machine stood when the mesh was applied, no motor moved.
        assert_eq!(d.motor_positions(&[0.0; 3]).unwrap(), vec![0.0; 3]);
    }

    /// A five-axis mill with a tool carousel: x, y, z, a, b, c, one motor
    /// each; a seventh axis is more than the planner plans together.
    fn axes_machine(names: &[&str]) -> String {
        let mut t = String::from("name = \"six\"\n[limits]\nvelocity = 50.0\nacceleration = 500.0\njunction_deviation = 0.01\n");
        for n in names {
            t += &format!(
                "[modules.{n}]\nname = \"{n}\"\n[motors.{n}]\nmodule = \"{n}\"\nfull_steps_per_unit = 40.0\nmicrosteps = 8\n[axes.{n}]\nmotor = \"{n}\"\nmin = -100.0\nmax = 100.0\nvelocity = 50.0\nacceleration = 500.0\njerk = 10000.0\n"
            );
        }
        t
    }

    #[test]
    fn six_axes_drive_and_plan_together_and_a_seventh_is_refused() {
        let six = MachineFile::parse(&axes_machine(&["x", "y", "z", "a", "b", "c"])).unwrap();
        let d = Drive::new(&six, &[0.0; 6]).unwrap();
        assert_eq!(d.axes(), ["x", "y", "z", "a", "b", "c"]);
        let m = d.motor_positions(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]).unwrap();
        assert_eq!(m, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        let mut p = crate::machine::motion::machine_planner(&six).unwrap();
        assert_eq!(p.vector_limits().path_axes, 3);
        p.line([10.0, 0.0, 0.0, 30.0, 20.0, 90.0], 40.0).unwrap();
        // The feed is the toolhead's: 10 mm of x at 40 mm/s (the rotaries
        // follow, c at 9 units per mm of path, within its 50).
        let seg = &p.plan().segments[0];
        assert!((seg.profile.length - 10.0).abs() < 1e-12);
        assert!((seg.profile.cruise - 50.0 / 9.0).abs() < 1e-9, "{seg:?}");
        let seven =
            MachineFile::parse(&axes_machine(&["x", "y", "z", "a", "b", "c", "u"])).unwrap();
        assert!(matches!(
            Drive::new(&seven, &[0.0; 7]),
            Err(DriveError::TooManyAxes(a)) if a.len() == 7
        ));
    }

    #[test]
    fn start_is_zero_inside_travel_else_min() {
        let cfg = MachineFile::load(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../examples/machines/mill.toml"
        ))
        .unwrap();
        assert_eq!(start_position(&cfg), vec![0.0, 0.0, 0.0]);
        let d = Drive::new(&cfg, &start_position(&cfg)).unwrap();
        assert_eq!(d.motor_positions(&[0.0; 3]).unwrap(), vec![0.0; 3]);
        // y is inverted.
        assert_eq!(
            d.motor_positions(&[1.0, 2.0, 3.0]).unwrap(),
            vec![1.0, -2.0, 3.0]
        );
    }
}
