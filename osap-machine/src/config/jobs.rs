//! What a machine is and how it reads jobs: the top-level `kind`, the
//! `[gcode]` table (the dialect) and the `[work_offsets]` table (CNC work
//! zeros, G54–G59).
//!
//! ```toml
//! kind = "mill"
//!
//! [gcode]
//! dialect = "rs274ngc"          # default by kind
//!
//! [work_offsets]
//! G54 = [20.0, 20.0, -60.0]     # machine coordinates of the work zero
//! G55 = [150.0, 20.0, -60.0]
//! ```

use serde::Deserialize;

use super::{invalid, ConfigError, MachineFile};

/// What the machine is: it chooses defaults (the G-code dialect), and
/// tools that list machines show it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MachineKind {
    /// A 3D printer (an extruder, heaters).
    Printer,
    /// A mill (a spindle, usually a rigid frame and lead or ball screws).
    Mill,
    /// A router (a spindle on a gantry, usually belts or racks).
    Router,
    /// A pen plotter.
    Plotter,
    /// A laser cutter or engraver.
    Laser,
    /// Anything else (the default): a musical instrument, a test rig.
    #[default]
    Other,
}

impl MachineKind {
    /// The G-code dialect a machine of this kind reads unless its
    /// `[gcode] dialect` says otherwise: printers, plotters and lasers
    /// run what Marlin-flavoured tools emit; mills, routers and other
    /// machines RS274/NGC (LinuxCNC, Grbl).
    pub fn default_dialect(self) -> Dialect {
        match self {
            MachineKind::Printer | MachineKind::Plotter | MachineKind::Laser => Dialect::Marlin,
            MachineKind::Mill | MachineKind::Router | MachineKind::Other => Dialect::Rs274ngc,
        }
    }

    /// The kind as written in the machine file.
    pub fn as_str(self) -> &'static str {
        match self {
            MachineKind::Printer => "printer",
            MachineKind::Mill => "mill",
            MachineKind::Router => "router",
            MachineKind::Plotter => "plotter",
            MachineKind::Laser => "laser",
            MachineKind::Other => "other",
        }
    }
}

impl std::fmt::Display for MachineKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// How G-code words are read where controllers differ.
///
/// | word | `marlin` (Marlin, Klipper, RepRapFirmware) | `rs274ngc` (LinuxCNC, Grbl) |
/// |---|---|---|
/// | `G4 P` | milliseconds | seconds |
/// | `G4 S` | seconds | not a word of G4 |
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Dialect {
    /// Marlin's reading, which slicers and most plotter and laser tools
    /// write for.
    Marlin,
    /// The NIST RS274/NGC reading, which LinuxCNC, Grbl and CAM
    /// post-processors for them write for.
    Rs274ngc,
}

impl Dialect {
    /// The dialect as written in the machine file.
    pub fn as_str(self) -> &'static str {
        match self {
            Dialect::Marlin => "marlin",
            Dialect::Rs274ngc => "rs274ngc",
        }
    }
}

impl std::fmt::Display for Dialect {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The `[gcode]` table.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GcodeSettings {
    /// The dialect G-code jobs are read in (default: by the machine's
    /// [`MachineKind`]).
    #[serde(default)]
    pub dialect: Option<Dialect>,
}

/// The `[work_offsets]` table: the work zero of each coordinate system
/// G54–G59 selects, in machine coordinates `[x, y, z]` (mm). A system not
/// given is not set: G54 then means the machine's zero (or
/// `osap run --origin`), and selecting any other is refused.
#[derive(Debug, Clone, Copy, PartialEq, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorkOffsets {
    /// G54 (also the system a program starts in).
    #[serde(default, rename = "G54")]
    pub g54: Option<[f64; 3]>,
    /// G55.
    #[serde(default, rename = "G55")]
    pub g55: Option<[f64; 3]>,
    /// G56.
    #[serde(default, rename = "G56")]
    pub g56: Option<[f64; 3]>,
    /// G57.
    #[serde(default, rename = "G57")]
    pub g57: Option<[f64; 3]>,
    /// G58.
    #[serde(default, rename = "G58")]
    pub g58: Option<[f64; 3]>,
    /// G59.
    #[serde(default, rename = "G59")]
    pub g59: Option<[f64; 3]>,
}

impl WorkOffsets {
    /// The six systems in order, G54 first.
    pub fn all(&self) -> [Option<[f64; 3]>; 6] {
        [self.g54, self.g55, self.g56, self.g57, self.g58, self.g59]
    }
}

impl MachineFile {
    /// The dialect G-code jobs are read in: `[gcode] dialect`, else the
    /// default of the machine's `kind`.
    pub fn dialect(&self) -> Dialect {
        self.gcode
            .dialect
            .unwrap_or_else(|| self.kind.default_dialect())
    }
}

/// Checks `[work_offsets]`: every coordinate finite.
pub(super) fn validate(file: &MachineFile) -> Result<(), ConfigError> {
    for (k, offset) in file.work_offsets.all().iter().enumerate() {
        let Some(p) = offset else { continue };
        for (axis, v) in ["x", "y", "z"].iter().zip(p) {
            if !v.is_finite() {
                return Err(invalid(
                    format!("work_offsets.G{}", 54 + k),
                    format!(
                        "{axis} is {v}; give the work zero's machine coordinates [x, y, z] in mm"
                    ),
                ));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mill_with(extra_top: &str, tables: &str) -> Result<MachineFile, ConfigError> {
        let text = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../examples/machines/mill.toml"
        ))
        .unwrap()
        .replacen("kind = \"mill\"", extra_top, 1);
        MachineFile::parse(&format!("{text}\n{tables}\n"))
    }

    #[test]
    fn dialect_defaults_by_kind_and_can_be_set() {
        assert_eq!(
            mill_with("kind = \"mill\"", "").unwrap().dialect(),
            Dialect::Rs274ngc
        );
        for (kind, want) in [
            ("printer", Dialect::Marlin),
            ("plotter", Dialect::Marlin),
            ("laser", Dialect::Marlin),
            ("router", Dialect::Rs274ngc),
            ("other", Dialect::Rs274ngc),
        ] {
            let f = mill_with(&format!("kind = \"{kind}\""), "").unwrap();
            assert_eq!(f.kind.as_str(), kind);
            assert_eq!(f.dialect(), want, "{kind}");
        }
        // No kind at all: other, and today's reading.
        let f = mill_with("", "").unwrap();
        assert_eq!(
            (f.kind, f.dialect()),
            (MachineKind::Other, Dialect::Rs274ngc)
        );
        let f = mill_with("kind = \"mill\"", "[gcode]\ndialect = \"marlin\"").unwrap();
        assert_eq!(f.dialect(), Dialect::Marlin);
    }

    #[test]
    fn bad_keys_are_named() {
        let e = mill_with("kind = \"lathe\"", "").unwrap_err().to_string();
        assert!(e.contains("lathe") && e.contains("printer"), "{e}");
        let e = mill_with("kind = \"mill\"", "[gcode]\ndialect = \"fanuc\"")
            .unwrap_err()
            .to_string();
        assert!(e.contains("fanuc") && e.contains("rs274ngc"), "{e}");
        let e = mill_with("kind = \"mill\"", "[gcode]\nflavor = \"marlin\"")
            .unwrap_err()
            .to_string();
        assert!(e.contains("flavor"), "{e}");
        let e = mill_with("kind = \"mill\"", "[work_offsets]\nG60 = [0.0, 0.0, 0.0]")
            .unwrap_err()
            .to_string();
        assert!(e.contains("G60") && e.contains("G59"), "{e}");
        let e = mill_with("kind = \"mill\"", "[work_offsets]\nG55 = [0.0, nan, 0.0]").unwrap_err();
        assert_eq!(e.key(), Some("work_offsets.G55"), "{e}");
        let e = mill_with("kind = \"mill\"", "[work_offsets]\nG55 = [0.0, 1.0]")
            .unwrap_err()
            .to_string();
        assert!(e.contains("G55") || e.contains("work_offsets"), "{e}");
    }

    #[test]
    fn work_offsets_are_read_in_order() {
        let f = mill_with(
            "kind = \"mill\"",
            "[work_offsets]\nG54 = [20.0, 20.0, -60.0]\nG56 = [150.0, 20.0, -60.0]",
        )
        .unwrap();
        assert_eq!(
            f.work_offsets.all(),
            [
                Some([20.0, 20.0, -60.0]),
                None,
                Some([150.0, 20.0, -60.0]),
                None,
                None,
                None
            ]
        );
    }
}
