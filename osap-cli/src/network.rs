//! What the network commands print: scans as trees with link counters and
//! functions, routes named by runtime, bus roles, latency percentiles.

use crate::*;

pub(crate) async fn scan(c: &Connection, retries: u8) -> Result<ScanReport, String> {
    let options = ScanOptions {
        timeout: c.timeout,
        retries,
        ..ScanOptions::default()
    };
    let bar = ProgressBar::new_spinner();
    bar.set_style(
        ProgressStyle::with_template("{spinner} scanning: {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    bar.enable_steady_tick(Duration::from_millis(100));
    let report = netrunner::scan_with_progress(&c.host, &options, |found, queued| {
        bar.set_message(format!("{found} runtimes found, {queued} to visit"));
    })
    .await
    .map_err(|e| e.to_string());
    bar.finish_and_clear();
    report
}

/// A route given as link indices ("0,2" or "0 2"), if `target` is one.
pub(crate) fn parse_route(target: &str) -> Option<Result<Route, String>> {
    let parts: Vec<&str> = target
        .split(|c: char| c == ',' || c.is_whitespace())
        .filter(|p| !p.is_empty())
        .collect();
    if parts.is_empty() || !parts.iter().all(|p| p.chars().all(|c| c.is_ascii_digit())) {
        return None;
    }
    let links: Result<Vec<u8>, _> = parts.iter().map(|p| p.parse::<u8>()).collect();
    Some(match links {
        Ok(l) => Route::through_links(&l).map_err(|e| format!("bad route {target}: {e}")),
        Err(_) => Err(format!("bad route {target}: link indices are 0..=63")),
    })
}

/// The route to `target`: parsed, or found by name in a scan.
/// `off`, `head:N` or `drop:D`, as `osap bus` takes it.
pub(crate) fn parse_bus_role(text: &str) -> Result<BusRole, String> {
    let address = |n: &str, what: &str| {
        n.parse::<u8>()
            .ok()
            .filter(|d| (1..=254).contains(d))
            .ok_or_else(|| format!("{what} {n:?} must be a number from 1 to 254"))
    };
    match text.split_once(':') {
        None if text == "off" => Ok(BusRole::Off),
        Some(("head", n)) => Ok(BusRole::Head {
            max_drop: address(n, "the highest drop")?,
        }),
        Some(("drop", n)) => Ok(BusRole::Drop(address(n, "the drop address")?)),
        _ => Err(format!(
            "{text:?} is not a bus role: use off, head:N (polls drops 1..=N) or drop:D"
        )),
    }
}

/// A role as `osap bus` names it.
pub(crate) fn bus_role_text(role: BusRole) -> String {
    match role {
        BusRole::Off => "off (point to point)".into(),
        BusRole::Head { max_drop } => format!("the bus head, polling drops 1 to {max_drop}"),
        BusRole::Drop(d) => format!("drop {d} on its bus"),
    }
}

/// What `osap bus` says when the runtime does not take the role.
pub(crate) fn bus_error(e: HostError, route: &Route, link: u8) -> String {
    use osap_core::netresponder::Status;
    match e {
        HostError::Remote {
            status: Status::Refused,
            ..
        } => format!(
            "the runtime at {route} cannot give link {link} a bus role: only a module \
             firmware's UART can take one (USB links and simulated links cannot)"
        ),
        HostError::Remote {
            status: Status::NoSuchIndex,
            ..
        } => format!("the runtime at {route} has no link {link}"),
        HostError::Remote {
            status: Status::UnknownKey,
            ..
        } => format!(
            "the runtime at {route} does not know bus roles: update its firmware (osap flash)"
        ),
        e => e.to_string(),
    }
}

pub(crate) fn percentile(sorted: &[Duration], p: f64) -> Duration {
    let i = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

/// Scans, prints the tree (and `listing` after it), writes the map to
/// `output` if given; exit code 2 when the map is partial. An open link
/// where nothing was heard and nothing answered (an unwired UART) has no
/// neighbour: the tree marks it, and it leaves the map whole.
pub(crate) async fn scan_and_print(
    c: &Connection,
    retries: u8,
    output: Option<PathBuf>,
    listing: &str,
    verbose: bool,
) -> Result<ExitCode, String> {
    let report = scan(c, retries).await?;
    print!("{}", report.map.tree());
    if verbose {
        print!("{}", link_counter_listing(c, &report.map).await?);
    }
    let lone = report
        .map
        .runtimes
        .iter()
        .flat_map(|r| &r.links)
        .filter(|l| l.no_neighbour())
        .count();
    let lone = match lone {
        0 => String::new(),
        1 => " (1 open link with no neighbour)".to_string(),
        n => format!(" ({n} open links with no neighbour)"),
    };
    println!(
        "{} runtimes, {} links{lone}, scanned in {:.1} ms",
        report.map.runtimes.len(),
        report.map.links.len(),
        report.elapsed.as_secs_f64() * 1e3
    );
    print!("{listing}");
    if let Some(path) = output {
        std::fs::write(&path, report.map.to_json())
            .map_err(|e| format!("cannot write {}: {e}", path.display()))?;
        println!("map written to {}", path.display());
    }
    if report.failures.is_empty() {
        Ok(ExitCode::SUCCESS)
    } else {
        eprintln!("unreachable:");
        for f in &report.failures {
            eprintln!(
                "  {}: {}",
                describe_route(&report.map, &f.route, &f.route_drops),
                f.error
            );
        }
        eprintln!(
            "the map is partial: {} request(s) failed (exit code 2); check the cables \
             and power of what is listed, or raise --timeout-ms and --retries for slow links",
            report.failures.len()
        );
        Ok(ExitCode::from(2))
    }
}

/// Where a failure's route leads, in the map's terms: `the runtime behind
/// hub's link 2 (route 0,0,2)`, `the runtime behind hub1's link 1 drop 3
/// (route 0,1,1)`, or the runtime's name if it is on the map. `drops` is
/// per hop the drop where it crosses a bus (empty: none does): the drops
/// of one bus share their link indices.
pub(crate) fn describe_route(map: &NetworkMap, route: &[u8], drops: &[Option<u8>]) -> String {
    let path = |route: &[u8], drops: &[Option<u8>]| -> Vec<(u8, Option<u8>)> {
        route
            .iter()
            .enumerate()
            .map(|(i, &l)| (l, drops.get(i).copied().flatten()))
            .collect()
    };
    let path = path(route, drops);
    let hops = route
        .iter()
        .map(u8::to_string)
        .collect::<Vec<_>>()
        .join(",");
    if let Some(r) = map.runtimes.iter().find(|r| r.path() == path) {
        return format!("{} (route {hops})", r.name);
    }
    match path.split_last() {
        Some(((link, drop), parent)) => match map.runtimes.iter().find(|r| r.path() == parent) {
            Some(p) => {
                let drop = drop.map_or(String::new(), |d| format!(" drop {d}"));
                format!(
                    "the runtime behind {}'s link {link}{drop} (route {hops})",
                    p.name
                )
            }
            None => format!("route {hops}"),
        },
        None => "this host".to_string(),
    }
}

/// Every link's counters, one link a line:
/// `x link 0 (uart): in 1203 (0 dropped), out 1180 (0 expired, 0 closed,
/// 0 failed); wire: 1203 frames, 0 bad, 0 dropped in, 0 dropped out,
/// 0 disconnects`.
pub(crate) async fn link_counter_listing(
    c: &Connection,
    map: &NetworkMap,
) -> Result<String, String> {
    let runner = Netrunner::new(&c.host).await.map_err(|e| e.to_string())?;
    let mut out = String::from("link counters:\n");
    for r in &map.runtimes {
        for l in &r.links {
            let line = match runner.link_counters(&r.route(), l.index).await {
                Ok(k) => {
                    let wire = match k.gateway {
                        Some(g) => format!(
                            "wire: {} frames, {} bad, {} dropped in, {} dropped out, {} disconnects",
                            g.frames, g.frame_errors, g.rx_dropped, g.tx_dropped, g.disconnects
                        ),
                        None => "wire: not counted by this link".into(),
                    };
                    format!(
                        "in {} ({} dropped), out {} ({} expired, {} closed, {} failed); {wire}",
                        k.received, k.rx_dropped, k.sent, k.expired, k.closed, k.send_errors
                    )
                }
                Err(e) => format!("counters unavailable: {e}"),
            };
            out.push_str(&format!(
                "  {} link {} ({}): {line}\n",
                r.name, l.index, l.type_name
            ));
        }
    }
    Ok(out)
}

/// Every runtime's functions, one signature a line, followed by the
/// function's summary (the first sentence of its docs) after `  # ` if it
/// sent one: `x: add_point(time: u64, position: f32)  # Queues a ..`,
/// `x: get_position() -> (time: u64, position: f32)  # Where ..`.
pub(crate) fn function_listing(som: &osap_host::som::Som) -> String {
    let mut out = String::new();
    for rt in &som.runtimes {
        for f in &rt.functions {
            out.push_str(&format!("{}: {}", rt.record.name, signature_line(f)));
            if !f.summary.is_empty() {
                out.push_str("  # ");
                out.push_str(&f.summary);
            }
            out.push('\n');
        }
    }
    out
}

/// `name(input: type, ..) -> (output: type, ..)` (no `->` without
/// outputs): a function as `osap scan -f` and `osap describe` print it.
pub(crate) fn signature_line(f: &osap_host::som::model::SomFunction) -> String {
    let args = |a: &[osap_host::som::model::SomArg]| {
        a.iter()
            .map(|a| format!("{}: {}", a.name, a.type_name))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let mut line = format!("{}({})", f.name, args(&f.inputs));
    if !f.outputs.is_empty() {
        line.push_str(&format!(" -> ({})", args(&f.outputs)));
    }
    line
}

#[cfg(test)]
mod tests {
    use super::describe_route;
    use osap_host::map::{NetworkMap, RuntimeRecord, MAP_VERSION};

    fn runtime(name: &str, route: &[u8], drops: &[Option<u8>]) -> RuntimeRecord {
        RuntimeRecord {
            name: name.into(),
            type_name: "stepper".into(),
            version: "0.1.0".into(),
            build: 3,
            function_set: 0,
            packet_size: 256,
            tier: 1,
            route: route.to_vec(),
            route_drops: drops.to_vec(),
            route_mtu: 256,
            links: Vec::new(),
            ports: Vec::new(),
        }
    }

    #[test]
    fn a_failed_drop_is_named_by_its_drop_not_by_a_neighbour_on_its_bus() {
        let map = NetworkMap {
            version: MAP_VERSION,
            runtimes: vec![
                runtime("h", &[], &[]),
                runtime("hub", &[0], &[]),
                runtime("a1", &[0, 1], &[None, Some(1)]),
            ],
            links: Vec::new(),
        };
        // Drop 3 has a1's link indices; it is not a1.
        assert_eq!(
            describe_route(&map, &[0, 1], &[None, Some(3)]),
            "the runtime behind hub's link 1 drop 3 (route 0,1)"
        );
        assert_eq!(
            describe_route(&map, &[0, 1], &[None, Some(1)]),
            "a1 (route 0,1)"
        );
        assert_eq!(
            describe_route(&map, &[0, 2], &[]),
            "the runtime behind hub's link 2 (route 0,2)"
        );
    }
}
