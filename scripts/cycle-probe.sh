#!/usr/bin/env bash
# Shared by scripts/maxl-cycles.sh and scripts/module-cycles.sh: builds a
# cycle probe (a standalone no_std crate, thumbv6m-none-eabi, release,
# linked into SRAM), installs rp2040js 1.4.1 once under the probe's target/
# (ignored by git), and runs the report script on the probe's ELF.
#
# Usage: scripts/cycle-probe.sh PROBE_DIR CRATE_NAME REPORT_JS [--disasm SYMBOLS]
#   SYMBOLS   comma-separated functions to disassemble after the report
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
probe="$1"
name="$2"
report="$3"
js="$probe/target/rp2040js"

command -v node >/dev/null || { echo "error: node is needed" >&2; exit 1; }
if [[ ! -d "$js/node_modules/rp2040js" ]]; then
    mkdir -p "$js"
    (cd "$js" && npm install --silent --no-audit --no-fund rp2040js@1.4.1 >/dev/null)
fi

cd "$probe"
cargo build --quiet --release --target thumbv6m-none-eabi
elf="$probe/target/thumbv6m-none-eabi/release/$name"

node "$report" "$elf" "$js"

if [[ "${4:-}" == "--disasm" ]]; then
    objdump="$(command -v llvm-objdump || true)"
    if [[ -z "$objdump" ]]; then
        sysroot="$(rustc --print sysroot)"
        objdump="$(ls "$sysroot"/lib/rustlib/*/bin/llvm-objdump 2>/dev/null | head -n 1)"
    fi
    "$objdump" -d --no-show-raw-insn "$elf" --disassemble-symbols="$5"
fi
