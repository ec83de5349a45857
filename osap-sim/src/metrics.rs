//! Clock-sync metrics: every node's synchronised time against the root's,
//! sampled at the same true instants.
//!
//! The simulator samples `runtime.system_time(local_now)` of every node at
//! a fixed period of true time and stores each node's error against the
//! root's system time at that instant, each node's clock tier, and how far
//! each node's rate correction is from the one its oscillator needs. Nothing
//! here knows how the controller works: these are the numbers a perfect
//! external observer would measure.
//!
//! Each node also has a *parent*: its neighbour one hop closer to the root
//! on a shortest path (breadth-first from the root, ties to the link added
//! first). A node's *hop error* is its error minus its parent's, which
//! isolates what one link (a UART, a USB CDC link) contributes.

/// A summary of absolute errors, µs.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Stats {
    /// Number of values.
    pub count: usize,
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Largest.
    pub max: f64,
    /// Mean.
    pub mean: f64,
}

impl Stats {
    /// Stats of the absolute values of `values` (nearest-rank percentiles).
    /// All zero if there are none.
    pub fn of_abs(values: impl IntoIterator<Item = f64>) -> Stats {
        let mut v: Vec<f64> = values.into_iter().map(f64::abs).collect();
        if v.is_empty() {
            return Stats::default();
        }
        v.sort_by(f64::total_cmp);
        let rank = |p: f64| v[((p * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1];
        Stats {
            count: v.len(),
            p50: rank(0.50),
            p99: rank(0.99),
            max: v[v.len() - 1],
            mean: v.iter().sum::<f64>() / v.len() as f64,
        }
    }
}

/// The clock-sync figures of one run, as the benchmark reports them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SyncSummary {
    /// When every non-root node was within 50 µs of the root for good, s.
    pub converged_50us_s: Option<f64>,
    /// When every non-root node was within 10 µs of the root for good, s.
    pub converged_10us_s: Option<f64>,
    /// Start of the steady-state window the stats cover, s: the 50 µs
    /// convergence time, or half the run if there is none.
    pub window_from_s: f64,
    /// Whether the window starts at convergence (false: at half the run).
    pub window_after_convergence: bool,
    /// |error| against the root, pooled over all non-root nodes.
    pub error: Stats,
    /// |hop error| pooled over every hop over a UART (`None`: no such hop).
    pub uart_hops: Option<Stats>,
    /// |hop error| pooled over every hop over USB CDC.
    pub usb_hops: Option<Stats>,
}

/// A node's way to the root, for hop errors.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Parent {
    /// The parent node.
    pub node: usize,
    /// Type name of the link to it (`uart`, `usb_cdc`, …).
    pub link_type: &'static str,
    /// Hops from the root (1 for the root's neighbours).
    pub depth: usize,
}

/// The sampled errors of one run.
#[derive(Debug, Clone, PartialEq)]
pub struct Metrics {
    /// Node names, by node index.
    pub names: Vec<String>,
    /// Index of the reference (root) node.
    pub root: usize,
    /// Each node's parent toward the root (`None` for the root and for
    /// nodes not connected to it).
    pub parents: Vec<Option<Parent>>,
    /// Sample times, true seconds.
    pub times_s: Vec<f64>,
    /// `error_us[node][k]`: node's system time minus the root's at sample
    /// `k`, µs.
    pub error_us: Vec<Vec<f64>>,
    /// `tier[node][k]`: node's clock tier at sample `k`.
    pub tier: Vec<Vec<u8>>,
    /// `rate_error_ppm[node][k]`: node's rate correction minus the one
    /// its oscillator needs to run at the root's rate, at sample `k`, ppm
    /// (the root's is 0). Empty for metrics pushed without rates.
    pub rate_error_ppm: Vec<Vec<f64>>,
}

impl Metrics {
    /// Empty metrics for these nodes.
    pub fn new(names: Vec<String>, root: usize, parents: Vec<Option<Parent>>) -> Self {
        let n = names.len();
        Metrics {
            names,
            root,
            parents,
            times_s: Vec::new(),
            error_us: vec![Vec::new(); n],
            tier: vec![Vec::new(); n],
            rate_error_ppm: vec![Vec::new(); n],
        }
    }

    /// Appends each node's rate error (ppm, see
    /// [`rate_error_ppm`](Self::rate_error_ppm)) for the newest sample.
    pub fn push_rate_errors(&mut self, errors_ppm: &[f64]) {
        for (series, e) in self.rate_error_ppm.iter_mut().zip(errors_ppm) {
            series.push(*e);
        }
    }

    /// When every non-root node's rate correction was within `within_ppm`
    /// of the rate its oscillator needs from then on up to `until_s`: its
    /// clock knew its rate (from a hot start's preset, or learned) over
    /// that window. `None` if a node was outside at `until_s` (or the
    /// run's end, if sooner), or no rates were sampled.
    pub fn rate_known_time(&self, within_ppm: f64, until_s: f64) -> Option<f64> {
        let end = self.times_s.partition_point(|&t| t <= until_s);
        self.followers()
            .map(|i| {
                let series = self.rate_error_ppm[i].get(..end)?;
                let last_bad = series.iter().rposition(|e| e.abs() > within_ppm);
                match last_bad {
                    None => self.times_s.first().copied(),
                    Some(k) if k + 1 < end => Some(self.times_s[k + 1]),
                    Some(_) => None,
                }
            })
            .try_fold(0.0, |worst: f64, t| Some(worst.max(t?)))
    }

    /// Appends one sample: each node's system time and tier at `time_s`.
    pub fn push(&mut self, time_s: f64, system_us: &[u64], tiers: &[u8]) {
        let root = system_us[self.root] as i128;
        self.times_s.push(time_s);
        for (i, &s) in system_us.iter().enumerate() {
            self.error_us[i].push((s as i128 - root) as f64);
            self.tier[i].push(tiers[i]);
        }
    }

    /// Number of nodes.
    pub fn node_count(&self) -> usize {
        self.names.len()
    }

    /// Number of samples.
    pub fn sample_count(&self) -> usize {
        self.times_s.len()
    }

    /// The index of the node named `name`.
    pub fn node(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    /// Every node but the root.
    pub fn followers(&self) -> impl Iterator<Item = usize> + '_ {
        (0..self.node_count()).filter(move |&i| i != self.root)
    }

    /// The first sample index at or after `from_s`.
    pub fn index_at(&self, from_s: f64) -> usize {
        self.times_s.partition_point(|&t| t < from_s)
    }

    /// The largest |error| over all non-root nodes, per sample.
    pub fn worst_abs(&self) -> Vec<f64> {
        (0..self.sample_count())
            .map(|k| {
                self.followers()
                    .map(|i| self.error_us[i][k].abs())
                    .fold(0.0, f64::max)
            })
            .collect()
    }

    /// A node's error minus its parent's, per sample (`None` for the root
    /// and unconnected nodes).
    pub fn hop_error(&self, node: usize) -> Option<Vec<f64>> {
        let p = self.parents.get(node)?.as_ref()?;
        Some(
            self.error_us[node]
                .iter()
                .zip(&self.error_us[p.node])
                .map(|(a, b)| a - b)
                .collect(),
        )
    }

    /// The time from which on `series` stays within `within_us` (in
    /// absolute value) to the end of the run: the first sample time after
    /// the last violation. `None` if the last sample violates it or there
    /// are no samples.
    pub fn settle_time(&self, series: &[f64], within_us: f64) -> Option<f64> {
        let last_bad = series.iter().rposition(|e| e.abs() > within_us);
        let first_good = last_bad.map_or(0, |k| k + 1);
        self.times_s.get(first_good).copied()
    }

    /// When node `node` converged to within `within_us` of the root for the
    /// rest of the run.
    pub fn convergence_time(&self, node: usize, within_us: f64) -> Option<f64> {
        self.settle_time(&self.error_us[node], within_us)
    }

    /// When every non-root node had converged to within `within_us` for the
    /// rest of the run.
    pub fn worst_convergence_time(&self, within_us: f64) -> Option<f64> {
        self.settle_time(&self.worst_abs(), within_us)
    }

    /// |error| stats of `node` from `from_s` on.
    pub fn node_stats(&self, node: usize, from_s: f64) -> Stats {
        let k = self.index_at(from_s);
        Stats::of_abs(self.error_us[node][k..].iter().copied())
    }

    /// |error| stats pooled over all non-root nodes from `from_s` on.
    pub fn pooled_stats(&self, from_s: f64) -> Stats {
        let k = self.index_at(from_s);
        Stats::of_abs(
            self.followers()
                .flat_map(|i| self.error_us[i][k..].iter().copied()),
        )
    }

    /// |hop error| stats pooled over every hop whose link is of type
    /// `link_type`, from `from_s` on (`None` if there is no such hop).
    pub fn hop_stats(&self, link_type: &str, from_s: f64) -> Option<Stats> {
        let k = self.index_at(from_s);
        let hops: Vec<usize> = (0..self.node_count())
            .filter(|&i| {
                self.parents[i]
                    .as_ref()
                    .is_some_and(|p| p.link_type == link_type)
            })
            .collect();
        if hops.is_empty() {
            return None;
        }
        let mut values = Vec::new();
        for i in hops {
            if let Some(h) = self.hop_error(i) {
                values.extend_from_slice(&h[k..]);
            }
        }
        Some(Stats::of_abs(values))
    }

    /// Convergence, and steady-state stats from convergence to 50 µs on (or
    /// over the second half of the run if it never converged).
    pub fn summary(&self) -> SyncSummary {
        let converged_50us_s = self.worst_convergence_time(50.0);
        let end = self.times_s.last().copied().unwrap_or(0.0);
        let window_from_s = converged_50us_s.unwrap_or(end / 2.0);
        SyncSummary {
            converged_50us_s,
            converged_10us_s: self.worst_convergence_time(10.0),
            window_from_s,
            window_after_convergence: converged_50us_s.is_some(),
            error: self.pooled_stats(window_from_s),
            uart_hops: self.hop_stats("uart", window_from_s),
            usb_hops: self.hop_stats("usb_cdc", window_from_s),
        }
    }

    /// The first sample time at which every node had a tier other than
    /// `unsynced` (255) and kept it to the end, if any.
    pub fn all_tiered_time(&self, unsynced: u8) -> Option<f64> {
        let last_bad = (0..self.sample_count())
            .rev()
            .find(|&k| self.tier.iter().any(|t| t[k] == unsynced));
        self.times_s.get(last_bad.map_or(0, |k| k + 1)).copied()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn synthetic() -> Metrics {
        let parents = vec![
            None,
            Some(Parent {
                node: 0,
                link_type: "usb_cdc",
                depth: 1,
            }),
            Some(Parent {
                node: 1,
                link_type: "uart",
                depth: 2,
            }),
        ];
        let mut m = Metrics::new(vec!["r".into(), "h".into(), "m".into()], 0, parents);
        for k in 0..100u64 {
            let r = 1_000_000 + k * 10;
            let h = if k < 30 { r + 1000 } else { r + 20 };
            let m2 = if k == 60 { h + 40 } else { h + 2 };
            m.push(k as f64 / 10.0, &[r, h, m2], &[0, 1, 2]);
        }
        m
    }

    #[test]
    fn rate_known_is_when_the_slowest_follower_stays_within() {
        let mut m = synthetic();
        assert_eq!(m.rate_known_time(1.0, 10.0), None, "no rates sampled");
        for k in 0..100 {
            // h learns by sample 12; m is within at 40 but strays once
            // more at 70.
            let h = if k < 12 { 30.0 } else { 0.5 };
            let m2 = if k < 40 || k == 70 { -20.0 } else { 0.2 };
            m.push_rate_errors(&[0.0, h, m2]);
        }
        assert_eq!(m.rate_known_time(1.0, 10.0), Some(7.1));
        // Up to 6.5 s, m's stray at 7.0 s is outside the window.
        assert_eq!(m.rate_known_time(1.0, 6.5), Some(4.0));
        assert_eq!(m.rate_known_time(1.0, 3.0), None);
        assert_eq!(m.rate_known_time(25.0, 10.0), Some(1.2));
        assert_eq!(m.rate_known_time(35.0, 10.0), Some(0.0));
        assert_eq!(m.rate_known_time(0.1, 10.0), None);
    }

    #[test]
    fn convergence_and_stats() {
        let m = synthetic();
        assert_eq!(m.convergence_time(1, 50.0), Some(3.0));
        // Node m has a spike of 60 at sample 60.
        assert_eq!(m.convergence_time(2, 50.0), Some(6.1));
        assert_eq!(m.worst_convergence_time(10.0), None);
        let s = m.node_stats(1, 3.0);
        assert_eq!((s.count, s.p50, s.max), (70, 20.0, 20.0));
        let uart = m.hop_stats("uart", 3.0).unwrap();
        assert_eq!((uart.p50, uart.max), (2.0, 40.0));
        assert!(m.hop_stats("tcp", 0.0).is_none());
        assert_eq!(m.all_tiered_time(255), Some(0.0));
        let s = m.summary();
        assert_eq!(s.converged_50us_s, Some(6.1));
        assert!(s.window_after_convergence);
        assert_eq!(s.usb_hops.map(|h| h.max), Some(20.0));
    }
}
