#!/usr/bin/env bash
# Counts Cortex-M0+ cycles of osap-module's step-word path (fill_step_word,
# what a firmware's step interrupt calls for each word of 16 ticks): builds
# the probe (osap-module/cycle-probe, thumbv6m-none-eabi, release, linked
# into SRAM) and runs it on rp2040js's emulated core, as
# scripts/maxl-cycles.sh does for maxl.
#
# Needs node and npm; rp2040js 1.4.1 is installed once under
# osap-module/cycle-probe/target/rp2040js (ignored by git).
#
# Usage: scripts/module-cycles.sh [--disasm]
#   --disasm   also print the disassembly of the measured call
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
probe="$root/osap-module/cycle-probe"
js="$probe/target/rp2040js"

command -v node >/dev/null || { echo "error: node is needed" >&2; exit 1; }
if [[ ! -d "$js/node_modules/rp2040js" ]]; then
    mkdir -p "$js"
    (cd "$js" && npm install --silent --no-audit --no-fund rp2040js@1.4.1 >/dev/null)
fi

cd "$probe"
cargo build --quiet --release --target thumbv6m-none-eabi
elf="$probe/target/thumbv6m-none-eabi/release/osap-module-cycle-probe"

node "$root/scripts/module-cycles.js" "$elf" "$js"

if [[ "${1:-}" == "--disasm" ]]; then
    objdump="$(command -v llvm-objdump || true)"
    if [[ -z "$objdump" ]]; then
        sysroot="$(rustc --print sysroot)"
        objdump="$(ls "$sysroot"/lib/rustlib/*/bin/llvm-objdump 2>/dev/null | head -n 1)"
    fi
    "$objdump" -d --no-show-raw-insn "$elf" --disassemble-symbols=probe_fill
fi
