#!/usr/bin/env bash
# End-to-end test of the RP2040 firmware on an emulated RP2040: builds the
# release firmware (ELF + UF2), installs the emulator bridge's pinned node
# packages, and runs the Rust tests that scan, rename, call, sync and
# drive the emulated module, and see `enter_bootloader` answer and then
# call the boot ROM's reset_to_usb_boot (tests/tests/emulator.rs). One stage binds
# the stepper proxy generated from a *simulated* scan
# (proxygen/tests/generated_small_machine/, checked against a live
# simulated scan by proxygen's small_machine.rs) to the firmware, unchanged, and runs
# one control-point sequence through it on the emulated module and on a
# simulated stepper: the step counts must be equal. Another drives digital
# pin 0 (GP10) with a square wave at 800 and 200 Hz and checks the speed
# tach_read measures from the firmware's edge counts.
#
# The emulator runs at half pace, and the test's host clock with it
# (OSAP_EMULATOR_SLOWDOWN=1 for real time; see tests/tests/emulator.rs).
#
# Needs node (20 or later) and npm. Usage: scripts/emulator-test.sh
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
command -v node >/dev/null || { echo "error: node is needed (the emulator is rp2040js)" >&2; exit 1; }

echo "-- firmware (release)"
(cd "$root/firmware-rp2040" && cargo build --release)

echo "-- emulator bridge packages"
(cd "$root/firmware-rp2040/emulator" && npm ci --silent --no-audit --no-fund)

echo "-- end-to-end test"
cd "$root"
cargo test -p osap-tests --test emulator -- --ignored --nocapture
