//! `osap rheo --write`: the fitted model into `[axes.e.model]` of the
//! machine file, every other line and comment kept.

use std::path::Path;

use toml_edit::{value, Array, DocumentMut, Item, Table};

use super::{RheoError, RheoFit};
use crate::config::MachineFile;

/// The `[axes.e.model]` table for `fit`, as lines of TOML.
pub fn model_lines(fit: &RheoFit, fitted_from: Option<&str>) -> Vec<String> {
    let m = &fit.melt.model;
    let mut lines = vec![
        "[axes.e.model]".to_string(),
        format!("flow_k = {:.4}", m.flow_k),
        format!("flow_n = {:.4}", m.flow_n),
        format!("temp_coeff = {:.5}", m.temp_coeff),
        format!("t_ref = {:.1}", m.t_ref),
        format!("response_ms = {:.1}", fit.lag.tau_s * 1000.0),
        format!(
            "temp_range = [{:.1}, {:.1}]",
            fit.temp_range[0], fit.temp_range[1]
        ),
    ];
    if let Some(run) = fitted_from {
        lines.push(format!("fitted_from = {run:?}"));
    }
    lines
}

/// Sets `[axes.e.model]` of the machine file at `path` to `fit` (replacing
/// an earlier model), keeping the rest of the file as it is; refused when
/// the result would not load.
pub fn write_model(path: &Path, fit: &RheoFit, fitted_from: Option<&str>) -> Result<(), RheoError> {
    let io = |e: std::io::Error| RheoError::Refused(format!("{}: {e}", path.display()));
    let text = std::fs::read_to_string(path).map_err(io)?;
    let mut doc: DocumentMut = text
        .parse()
        .map_err(|e| RheoError::Refused(format!("{}: {e}", path.display())))?;
    let m = &fit.melt.model;
    let mut t = Table::new();
    let round = |v: f64, digits: i32| {
        let s = 10f64.powi(digits);
        (v * s).round() / s
    };
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
    let e = doc
        .get_mut("axes")
        .and_then(|a| a.get_mut("e"))
        .and_then(Item::as_table_mut)
        .ok_or_else(|| RheoError::Refused(format!("{}: no [axes.e] table", path.display())))?;
    e.insert("model", Item::Table(t));
    let out = doc.to_string();
    MachineFile::parse(&out)
        .and_then(|c| c.validate().map(|_| c))
        .map_err(|e| RheoError::Refused(format!("the file with the model would not load: {e}")))?;
    std::fs::write(path, out).map_err(io)
}
