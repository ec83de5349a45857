#!/usr/bin/env bash
# proxygen's starter, as a new user makes it: generate proxies and a
# starter crate from a simulated scan, build the crate against this
# workspace's crates (its own target dir: the starter is not a member),
# and run it on the same simulated machine. Its proxies must bind to every
# device the scan found.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
topology="$root/osap-sim/topologies/small-machine.toml"
cargo run -q -p proxygen -- --sim "$topology" --starter "$dir/my-machine" \
  --osap-host "$root/osap-host" --osap-sim "$root/osap-sim"
# The workspace's versions of every dependency.
cp Cargo.lock "$dir/my-machine/"
CARGO_TARGET_DIR="$root/target/starter" cargo build -q --manifest-path "$dir/my-machine/Cargo.toml"
out=$("$root/target/starter/debug/my-machine" --sim "$topology")
echo "$out"
echo "$out" | grep -q "runtimes found"
# One "NAME: TYPE VERSION" line per bound device.
bound=$(echo "$out" | grep -c '^".*": ')
[ "$bound" -ge 3 ] || { echo "only $bound devices bound"; exit 1; }
echo "starter: built and bound $bound devices"
# RUST_LOG reaches the starter's log (the host's manager logs at debug).
log=$(RUST_LOG=osap_host=debug "$root/target/starter/debug/my-machine" --sim "$topology" 2>&1 >/dev/null)
echo "$log" | grep -q DEBUG || { echo "RUST_LOG=osap_host=debug logged nothing in the starter"; exit 1; }
echo "starter: RUST_LOG works"
