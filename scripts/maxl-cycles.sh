#!/usr/bin/env bash
# Counts Cortex-M0+ cycles of maxl's fixed-point hot paths: builds the probe
# (maxl/cycle-probe) and runs it on rp2040js's emulated core
# (scripts/cycle-probe.sh, scripts/cycle-probe.js).
#
# Needs node and npm. Usage: scripts/maxl-cycles.sh [--disasm]
#   --disasm   also print the disassembly of the per-tick functions
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
args=()
[[ "${1:-}" == "--disasm" ]] && args=(--disasm probe_tick,probe_load,probe_step,probe_isr,probe_phase)
exec "$root/scripts/cycle-probe.sh" "$root/maxl/cycle-probe" maxl-cycle-probe \
    "$root/scripts/maxl-cycles.js" "${args[@]}"
