#!/usr/bin/env bash
# How often clock sync meets its start-up targets across USB, over many
# seeds: chain4, star8 and loop from a cold start, a hot start and with busy
# modules, SEEDS seeds (default 20, from FIRST, default 1) of 40 simulated
# seconds each; prints, per topology and start, the median, 90th percentile
# and worst time until every node stays within 50 µs of the root, and how
# many runs met the target (cold and busy: under 2 s; hot: under 0.5 s).
# TOPOLOGIES (comma-separated) replaces chain4,star8,loop: built-in names
# or TOML topology files, the format the simulated machines read, e.g.
# TOPOLOGIES=chain4,osap-sim/topologies/chain4-hub-root.toml (rows are
# named after each file's `name`).
#
# The binary is built into CARGO_TARGET_DIR (default target); BIN=path runs
# a binary built earlier instead (e.g. a copy from another commit, to compare).
#
#   [TOPOLOGIES=...] [BIN=...] scripts/clock-sync-seeds.sh [SEEDS] [FIRST]
set -euo pipefail
cd "$(dirname "$0")/.."
seeds=${1:-20}
first=${2:-1}
topologies=${TOPOLOGIES:-chain4,star8,loop}
bin=${BIN:-}
if [ -z "$bin" ]; then
  cargo build -q --release -p osap-sim --features plot --bin clock_sync_report
  bin=${CARGO_TARGET_DIR:-target}/release/clock_sync_report
fi
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
for seed in $(seq "$first" $((first + seeds - 1))); do
  "$bin" --minutes 0.67 --seed "$seed" --out "$out/$seed" \
    --topologies "$topologies" --variants cold,hot,busy --jobs 2 2>/dev/null |
    awk -F'|' '/^\| / && !/^\| topology / && !/^\|---/{gsub(/ /,""); print $2, $3, $4}'
done | sort -k1,1 -k2,2 -k3,3g | awk '
  function report(   n, med, p90, met, target) {
    if (count == 0) return
    target = (start == "hot") ? 0.5 : 2.0
    met = 0
    for (i = 1; i <= count; i++) if (t[i] < target) met++
    printf "%-7s %-5s median %6.2f s  p90 %6.2f s  worst %6.2f s  under %.1f s: %d/%d\n",
      topo, start, t[int((count + 1) / 2)], t[int(0.9 * count)], t[count], target, met, count
  }
  {
    if ($1 != topo || $2 != start) { report(); topo = $1; start = $2; count = 0 }
    t[++count] = ($3 == "never") ? 999 : $3
  }
  END { report() }'
