#!/usr/bin/env bash
# Counts Cortex-M0+ cycles of osap-module's step-word path (fill_step_word,
# what a firmware's step interrupt calls for each word of 16 ticks): builds
# the probe (osap-module/cycle-probe) and runs it on rp2040js's emulated
# core (scripts/cycle-probe.sh, scripts/cycle-probe.js).
#
# Needs node and npm. Usage: scripts/module-cycles.sh [--disasm]
#   --disasm   also print the disassembly of the measured call
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
args=()
[[ "${1:-}" == "--disasm" ]] && args=(--disasm probe_fill)
exec "$root/scripts/cycle-probe.sh" "$root/osap-module/cycle-probe" osap-module-cycle-probe \
    "$root/scripts/module-cycles.js" "${args[@]}"
