#!/usr/bin/env bash
# Checks that every firmware presents the same PIPES functions, so one
# proxy serves every board: reads the function-set id each release ELF
# embeds (section .osap_function_set, osap_module::FUNCTION_SET_ID) and
# compares them with each other and with the id the host computes from
# osap-module's signatures. Build the firmwares first (.ci/run does).
set -euo pipefail
cd "$(dirname "$0")/.."

objcopy=$(ls "$(rustc --print sysroot)"/lib/rustlib/*/bin/llvm-objcopy 2>/dev/null | head -n1 || true)
if [ -z "$objcopy" ]; then
  echo "llvm-objcopy not found: rustup component add llvm-tools" >&2
  exit 1
fi

host_id=$(cargo run -q -p osap-module --example function_set_id)
echo "host (osap-module SIGNATURES): $host_id"

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
status=0
for elf in \
  firmware-rp2040/target/thumbv6m-none-eabi/release/firmware-rp2040 \
  firmware-samd51/target/thumbv7em-none-eabihf/release/firmware-samd51; do
  if [ ! -f "$elf" ]; then
    echo "$elf: not built" >&2
    status=1
    continue
  fi
  "$objcopy" --dump-section .osap_function_set="$tmp/id" "$elf" "$tmp/elf"
  # Four bytes, little-endian.
  id=$(od -An -tx4 --endian=little "$tmp/id" | tr -d ' \n')
  id="0x$id"
  echo "$elf: $id"
  if [ "$id" != "$host_id" ]; then
    echo "  differs from the host's $host_id" >&2
    status=1
  fi
done
[ "$status" = 0 ] && echo "function sets match"
exit "$status"
