//! `osap rheo --write`: the fitted model into `[axes.e.model]` of the
//! machine file, every other line and comment kept.

use std::path::Path;

use toml_edit::{value, Array, DocumentMut, Item, Table};

use super::{RheoError, RheoFit};
use crate::config::MachineFile;

/// The `[axes.e.model]` table for `fit`, rounded to what the fit
/// resolves.
fn model_table(fit: &RheoFit, fitted_from: Option<&str>) -> Table {
    let m = &fit.melt.model;
    let round = |v: f64, digits: i32| {
        let s = 10f64.powi(digits);
        (v * s).round() / s
    };
    let mut t = Table::new();
    t["flow_k"] = value(round(m.flow_k, 4));
    t["flow_n"] = value(round(m.flow_n, 4));
    t["temp_coeff"] = value(round(m.temp_coeff, 5));
    t["t_ref"] = value(round(m.t_ref, 1));
    t["response_ms"] = value(round(fit.lag.tau_s * 1000.0, 1));
    let mut range = Array::new();
    range.push(round(fit.temp_range[0], 1));
    range.push(round(fit.temp_range[1], 1));
    t["temp_range"] = value(range);
    if let Some(run) = fitted_from {
        t["fitted_from"] = value(run);
    }
    t
}

/// The `[axes.e.model]` table for `fit`, as lines of TOML (what
/// [`write_model`] writes).
pub fn model_lines(fit: &RheoFit, fitted_from: Option<&str>) -> Vec<String> {
    let mut doc = DocumentMut::new();
    let mut e = Table::new();
    e.set_implicit(true);
    e.insert("model", Item::Table(model_table(fit, fitted_from)));
    let mut axes = Table::new();
    axes.set_implicit(true);
    axes.insert("e", Item::Table(e));
    doc.insert("axes", Item::Table(axes));
    doc.to_string().lines().map(str::to_string).collect()
}

/// Sets `[axes.e.model]` of the machine file at `path` to `fit` (replacing
/// an earlier model), keeping the rest of the file as it is; refused when
/// the result would not load. Returns notes for the user: `[axes.e]` keys
/// kept that still override or cap the model.
pub fn write_model(
    path: &Path,
    fit: &RheoFit,
    fitted_from: Option<&str>,
) -> Result<Vec<String>, RheoError> {
    let io = |e: std::io::Error| RheoError::Refused(format!("{}: {e}", path.display()));
    let text = std::fs::read_to_string(path).map_err(io)?;
    let mut doc: DocumentMut = text
        .parse()
        .map_err(|e| RheoError::Refused(format!("{}: {e}", path.display())))?;
    let e = doc
        .get_mut("axes")
        .and_then(|a| a.get_mut("e"))
        .and_then(Item::as_table_mut)
        .ok_or_else(|| RheoError::Refused(format!("{}: no [axes.e] table", path.display())))?;
    e.insert("model", Item::Table(model_table(fit, fitted_from)));
    let out = doc.to_string();
    let cfg = MachineFile::parse(&out)
        .and_then(|c| c.validate().map(|_| c))
        .map_err(|e| RheoError::Refused(format!("the file with the model would not load: {e}")))?;
    std::fs::write(path, out).map_err(io)?;
    let mut notes = Vec::new();
    if let Some(x) = cfg.extruder().map(|a| &a.extruder) {
        if let Some(k) = x.pressure_advance {
            notes.push(format!(
                "axes.e.pressure_advance = {k} is kept and overrides the model's {:.3} s; delete it to take pressure advance from the model",
                fit.lag.tau_s
            ));
        }
        if let Some(q) = x.max_volumetric_speed {
            notes.push(format!(
                "axes.e.max_volumetric_speed = {q} is kept and caps the flow wherever the model allows more; delete it to print from the model alone"
            ));
        }
    }
    Ok(notes)
}
