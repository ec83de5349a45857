#!/usr/bin/env bash
# Counts Cortex-M0+ cycles of maxl's fixed-point hot paths: builds the probe
# (maxl/cycle-probe, thumbv6m-none-eabi, release, linked into SRAM) and runs
# it on rp2040js's emulated core, which counts cycles per instruction (ALU 1,
# load/store 2, taken branch 2, BL 3, push/pop 1+N, single-cycle MULS).
#
# Needs node and npm; rp2040js 1.4.1 is installed once under
# maxl/cycle-probe/target/rp2040js (ignored by git).
#
# Usage: scripts/maxl-cycles.sh [--disasm]
#   --disasm   also print the disassembly of the per-tick functions
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
probe="$root/maxl/cycle-probe"
js="$probe/target/rp2040js"

command -v node >/dev/null || { echo "error: node is needed" >&2; exit 1; }
if [[ ! -d "$js/node_modules/rp2040js" ]]; then
    mkdir -p "$js"
    (cd "$js" && npm install --silent --no-audit --no-fund rp2040js@1.4.1 >/dev/null)
fi

cd "$probe"
cargo build --quiet --release --target thumbv6m-none-eabi
elf="$probe/target/thumbv6m-none-eabi/release/maxl-cycle-probe"

node "$root/scripts/maxl-cycles.js" "$elf" "$js"

if [[ "${1:-}" == "--disasm" ]]; then
    objdump="$(command -v llvm-objdump || true)"
    if [[ -z "$objdump" ]]; then
        sysroot="$(rustc --print sysroot)"
        objdump="$(ls "$sysroot"/lib/rustlib/*/bin/llvm-objdump 2>/dev/null | head -n 1)"
    fi
    "$objdump" -d --no-show-raw-insn "$elf" \
        --disassemble-symbols=probe_tick,probe_load,probe_step,probe_isr,probe_phase
fi
