//! The checks a [`SimSpec`] passes before either simulator takes it; each
//! message names the module, link or switch and the fix.

use super::graph::{firmware_link, Node};
use super::*;
use crate::clock::ClockSpec;
use osap_core::netresponder::NAME_MAX;
use std::collections::HashMap;

/// What a topology check failed on.
#[derive(Debug, Clone, Copy)]
pub(super) enum Item {
    Module(usize),
    Link(usize),
    Switch(usize),
}

pub(super) struct CheckError {
    pub(super) item: Option<Item>,
    pub(super) message: String,
}

impl CheckError {
    fn file(message: String) -> Self {
        CheckError {
            item: None,
            message,
        }
    }

    fn at(item: Item, message: String) -> Self {
        CheckError {
            item: Some(item),
            message,
        }
    }
}

/// The line (from 1) of `item`'s `[[module]]` or `[[link]]` header in a
/// topology file's `text`.
pub(super) fn item_line(text: &str, item: Item) -> Option<usize> {
    let (header, n) = match item {
        Item::Module(i) => ("[[module]]", i),
        Item::Link(i) => ("[[link]]", i),
        Item::Switch(i) => ("[[switch]]", i),
    };
    text.lines()
        .enumerate()
        .filter(|(_, l)| l.split('#').next().unwrap_or("").trim() == header)
        .nth(n)
        .map(|(line, _)| line + 1)
}

/// The error a bad spec gives, with `context` saying which spec.
pub(super) fn invalid(context: String, message: String) -> SpecError {
    SpecError::Invalid { context, message }
}

impl SimSpec {
    pub(super) fn check(&self) -> Result<(), CheckError> {
        self.check_modules()?;
        self.check_links()?;
        self.check_switches()?;
        self.check_winch().map_err(CheckError::file)?;
        self.check_graph().map_err(CheckError::file)
    }

    fn check_switches(&self) -> Result<(), CheckError> {
        for (i, s) in self.switches.iter().enumerate() {
            let at = |message: String| CheckError::at(Item::Switch(i), message);
            let what = format!("switch {} (on {:?})", i + 1, s.module);
            let stepper = |key: &str, name: &str| -> Result<(), CheckError> {
                match self.module_index(name).map(|m| &self.modules[m]) {
                    None => Err(at(format!(
                        "{what}: {key}: no module is named {name:?}; name one of: {}",
                        self.known_stepper_names()
                    ))),
                    Some(m) if m.kind() != Some(ModuleKind::Stepper) => Err(at(format!(
                        "{what}: {key}: module {name:?} is a {:?}; a switch is on, and over, modules of type \"stepper\" (with a limit input and a motor)",
                        m.type_name
                    ))),
                    Some(_) => Ok(()),
                }
            };
            stepper("module", &s.module)?;
            if let Some(motor) = self
                .module_index(&s.module)
                .and_then(|m| self.modules[m].motor.as_ref())
            {
                let own = match (motor.limit_min, motor.limit_max) {
                    (Some(_), _) => Some("limit_min"),
                    (None, Some(_)) => Some("limit_max"),
                    _ => None,
                };
                if let Some(key) = own {
                    return Err(at(format!(
                        "{what}: module: {:?} already has a switch on its own motor ({key} in its [module.motor]) and a module has one limit input; remove {key} and give that switch as a [[switch]] with terms = [[{:?}, 1.0]]",
                        s.module, s.module
                    )));
                }
            }
            if s.terms.is_empty() {
                return Err(at(format!(
                    "{what}: terms is empty; list [module, coefficient] pairs, e.g. terms = [[\"a\", 0.5], [\"b\", 0.5]]"
                )));
            }
            for (k, (module, coef)) in s.terms.iter().enumerate() {
                let key = format!("terms[{k}]");
                stepper(&key, module)?;
                if !(coef.is_finite() && *coef != 0.0) {
                    return Err(at(format!(
                        "{what}: {key}: coefficient {coef} must be finite and not zero; drop the term or give its weight"
                    )));
                }
                if let Some(first) = s.terms[..k].iter().position(|(m, _)| m == module) {
                    return Err(at(format!(
                        "{what}: {key}: module {module:?} is already terms[{first}]; add the coefficients into one term"
                    )));
                }
            }
            for (key, v) in [("offset", s.offset), ("at", s.at)] {
                if !v.is_finite() {
                    return Err(at(format!("{what}: {key} {v} must be finite")));
                }
            }
            if let Some(bed) = &s.bed {
                for module in bed.modules() {
                    stepper("bed", module)?;
                }
                bed.check().map_err(|e| at(format!("{what}: {e}")))?;
            }
        }
        Ok(())
    }

    fn known_stepper_names(&self) -> String {
        let names: Vec<String> = self
            .modules
            .iter()
            .filter(|m| m.kind() == Some(ModuleKind::Stepper))
            .map(|m| format!("{:?}", m.name))
            .collect();
        if names.is_empty() {
            "(no stepper modules)".into()
        } else {
            names.join(", ")
        }
    }

    fn check_modules(&self) -> Result<(), CheckError> {
        if self.modules.is_empty() {
            return Err(CheckError::file(
                "no modules: add at least one [[module]]".into(),
            ));
        }
        let mut names: HashMap<&str, usize> = HashMap::new();
        let mut root: Option<usize> = None;
        for (i, m) in self.modules.iter().enumerate() {
            let at = |message: String| CheckError::at(Item::Module(i), message);
            let what = format!("module {} ({:?})", i + 1, m.name);
            check_name(&what, "name", &m.name).map_err(at)?;
            check_name(&what, "type", &m.type_name).map_err(at)?;
            if m.name == HOST {
                return Err(at(format!(
                    "{what}: the name {HOST:?} is reserved for the host runtime; rename the module"
                )));
            }
            if let Some(first) = names.insert(&m.name, i) {
                return Err(at(format!(
                    "{what}: module {} is also named {:?}; give each module its own name",
                    first + 1,
                    m.name
                )));
            }
            let Some(kind) = m.kind() else {
                let hint = if m.type_name == "axis" {
                    " (an \"axis\" is now a \"stepper\": its [module.axis] table becomes [module.motor])"
                } else {
                    ""
                };
                return Err(at(format!(
                    "{what}: unknown type {:?}; a simulated module is \"stepper\" (the module firmware) or \"hub\" (a router without functions){hint}",
                    m.type_name
                )));
            };
            ClockSpec::fixed(m.offset_us, m.rate_ppm)
                .validate(&m.name)
                .map_err(|e| at(e.to_string()))?;
            if !(m.wander_ppm.is_finite() && (0.0..=10_000.0).contains(&m.wander_ppm)) {
                return Err(at(format!("{what}: wander_ppm must be within [0, 10000]")));
            }
            if !(m.wander_period_s.is_finite() && m.wander_period_s > 0.0) {
                return Err(at(format!("{what}: wander_period_s must be positive")));
            }
            if kind != ModuleKind::Stepper && m.dangling_uart {
                return Err(at(format!(
                    "{what}: dangling_uart is for modules of type \"stepper\" (the firmware's UART), not {:?}",
                    m.type_name
                )));
            }
            if kind != ModuleKind::Stepper && (m.motor.is_some() || m.io.is_some()) {
                return Err(at(format!(
                    "{what}: [module.motor] and [module.io] are for modules of type \"stepper\", not {:?}",
                    m.type_name
                )));
            }
            if let Some(motor) = &m.motor {
                motor.check().map_err(|e| at(format!("{what}: {e}")))?;
            }
            if let Some(io) = &m.io {
                io.check().map_err(|e| at(format!("{what}: {e}")))?;
            }
            if let Some(boot) = &m.bootloader {
                if kind != ModuleKind::Stepper {
                    return Err(at(format!(
                        "{what}: [module.bootloader] is for modules of type \"stepper\" (the module firmware), not {:?}",
                        m.type_name
                    )));
                }
                boot.check().map_err(|e| at(format!("{what}: {e}")))?;
                let shared = self.modules[..i]
                    .iter()
                    .position(|o| o.bootloader.as_ref().is_some_and(|b| b.drive == boot.drive));
                if let Some(first) = shared {
                    return Err(at(format!(
                        "{what}: [module.bootloader] drive {} is module {}'s too; give each module its own drive directory",
                        boot.drive.display(),
                        first + 1
                    )));
                }
            }
            if m.root {
                if let Some(first) = root {
                    return Err(at(format!(
                        "{what}: module {} ({:?}) is already the clock root; set root = true on one module at most",
                        first + 1,
                        self.modules[first].name
                    )));
                }
                root = Some(i);
            }
        }
        Ok(())
    }

    fn check_links(&self) -> Result<(), CheckError> {
        for (i, l) in self.links.iter().enumerate() {
            let at = |message: String| CheckError::at(Item::Link(i), message);
            let what = format!("link {} ({} – {})", i + 1, l.a, l.b);
            for end in [&l.a, &l.b] {
                if self.node(end).is_none() {
                    return Err(at(format!(
                        "{what}: no module is named {end:?}; add a [[module]] named so, or name one of: {}",
                        self.known_names()
                    )));
                }
            }
            if l.a == l.b {
                return Err(at(format!(
                    "{what}: a link must join two different runtimes"
                )));
            }
            if let Some(baud) = l.baud {
                if !l.kind.has_baud() {
                    return Err(at(format!(
                        "{what}: baud applies to uart and rs485 links, not {:?}; remove it",
                        l.kind.type_name()
                    )));
                }
                if !(1_200..=50_000_000).contains(&baud) {
                    return Err(at(format!(
                        "{what}: baud {baud} must be within 1200..=50000000"
                    )));
                }
            }
            if let Some(mtu) = l.mtu {
                if !(16..=MODULE_MTU as u16).contains(&mtu) {
                    return Err(at(format!(
                        "{what}: mtu {mtu} must be within 16..={MODULE_MTU} (a module's packet size)"
                    )));
                }
            }
            let probability = |key: &str, p: Option<f64>| match p {
                Some(p) if !(0.0..=1.0).contains(&p) => Err(at(format!(
                    "{what}: {key} {p} must be a probability within [0, 1]"
                ))),
                _ => Ok(()),
            };
            probability("loss", l.loss)?;
            probability("corrupt_per_byte", l.corrupt_per_byte)?;
            if l.loss.is_some() && l.kind == LinkKind::Memory {
                return Err(at(format!(
                    "{what}: a memory link loses nothing; remove loss"
                )));
            }
            for (key, set) in [
                ("jitter_us", l.jitter_us.is_some()),
                ("corrupt_per_byte", l.corrupt_per_byte.is_some()),
            ] {
                if set && !l.kind.has_baud() {
                    return Err(at(format!(
                        "{what}: {key} applies to uart and rs485 links, not {:?}; remove it",
                        l.kind.type_name()
                    )));
                }
            }
            if let Some(j) = l.jitter_us {
                if !(j.is_finite() && (0.0..=1e9).contains(&j)) {
                    return Err(at(format!(
                        "{what}: jitter_us {j} must be within [0, 1e9] µs"
                    )));
                }
            }
            if l.name.len() > NAME_MAX {
                return Err(at(format!(
                    "{what}: its name is {} bytes long; names are at most {NAME_MAX} bytes",
                    l.name.len()
                )));
            }
        }
        // A stepper has the firmware's two links: USB (0) and a UART (1).
        for spec in &self.modules {
            if spec.kind() != Some(ModuleKind::Stepper) {
                continue;
            }
            let mut taken: [Option<usize>; FIRMWARE_LINKS] = [None; FIRMWARE_LINKS];
            for (i, l) in self.links.iter().enumerate() {
                if l.a != spec.name && l.b != spec.name {
                    continue;
                }
                let Some(index) = firmware_link(l.kind) else {
                    return Err(CheckError::at(
                        Item::Link(i),
                        format!(
                            "link {} ({} – {}): a {:?} link cannot reach stepper {:?}: the module firmware has a usb link (its link 0) and a uart/rs485 link (its link 1)",
                            i + 1,
                            l.a,
                            l.b,
                            l.kind.type_name(),
                            spec.name
                        ),
                    ));
                };
                if let Some(first) = taken[index] {
                    return Err(CheckError::at(
                        Item::Link(i),
                        format!(
                            "link {} ({} – {}): stepper {:?} already has its {} link (link {}): the module firmware has {FIRMWARE_LINKS} links, one usb and one uart/rs485; join further modules through a hub",
                            i + 1,
                            l.a,
                            l.b,
                            spec.name,
                            if index == 0 { "usb" } else { "uart/rs485" },
                            first + 1
                        ),
                    ));
                }
                taken[index] = Some(i);
            }
            if let (true, Some(i)) = (spec.dangling_uart, taken[1]) {
                return Err(CheckError::at(
                    Item::Link(i),
                    format!(
                        "link {} ({} – {}): stepper {:?} has dangling_uart = true, so nothing may join its uart/rs485 link; remove one or the other",
                        i + 1,
                        self.links[i].a,
                        self.links[i].b,
                        spec.name
                    ),
                ));
            }
        }
        Ok(())
    }

    fn check_graph(&self) -> Result<(), String> {
        let adjacency = self.adjacency();
        for (i, m) in self.modules.iter().enumerate() {
            let indices: std::collections::BTreeSet<usize> =
                adjacency[i + 1].iter().map(|h| h.index).collect();
            let n = indices.len();
            if n > MODULE_LINKS {
                return Err(format!(
                    "module {:?} has {n} links; a simulated module has at most {MODULE_LINKS}",
                    m.name
                ));
            }
        }
        for bus in &self.buses {
            let what = format!("[[bus]] with head {:?}", bus.head);
            if bus.drops.is_empty() || bus.drops.len() > 254 {
                return Err(format!("{what}: list 1 to 254 drops"));
            }
            if bus.baud == 0 {
                return Err(format!("{what}: baud must be above 0"));
            }
            for (name, _) in bus.stations() {
                match self.node(name) {
                    Some(Node::Module(_)) => {}
                    Some(Node::Host) => {
                        return Err(format!(
                            "{what}: the host cannot be on a bus; put a hub module at its head"
                        ))
                    }
                    None => {
                        return Err(format!(
                            "{what}: no module is named {name:?}; name one of: {}",
                            self.known_names()
                        ))
                    }
                }
            }
        }
        let host_links = adjacency[0].len();
        if host_links == 0 {
            return Err(format!(
                "no link joins a module to the host: add a [[link]] with a = {HOST:?}"
            ));
        }
        if host_links > MAX_HOST_LINKS {
            return Err(format!(
                "{host_links} links join the host; at most {MAX_HOST_LINKS} can"
            ));
        }
        let paths = self.paths();
        for (i, m) in self.modules.iter().enumerate() {
            if paths[i].is_none() {
                return Err(format!(
                    "module {:?} is not connected to the host through any links",
                    m.name
                ));
            }
        }
        Ok(())
    }

    fn known_names(&self) -> String {
        std::iter::once(HOST)
            .chain(self.modules.iter().map(|m| m.name.as_str()))
            .map(|n| format!("{n:?}"))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

fn check_name(what: &str, field: &str, value: &str) -> Result<(), String> {
    if value.is_empty() {
        return Err(format!("{what}: its {field} is empty"));
    }
    if value.len() > NAME_MAX {
        return Err(format!(
            "{what}: its {field} {value:?} is {} bytes long; names are at most {NAME_MAX} bytes",
            value.len()
        ));
    }
    Ok(())
}
