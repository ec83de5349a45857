#!/usr/bin/env bash
# Regenerates the images under docs/ on purpose. The examples and tools
# write to examples-out/ (untracked) unless told otherwise; this script is
# the one place that tells them to write into docs/.
#
#   scripts/doc-images.sh                 # plots and the osap view screenshot
#   scripts/doc-images.sh --clock-sync    # also the clock-sync report (about
#                                         # an hour: 10 simulated minutes per
#                                         # topology)
set -euo pipefail
cd "$(dirname "$0")/.."

cargo run -q -p osap-examples --release --bin plotter -- --out docs/img/plotter.svg
cargo run -q -p osap-examples --release --bin plan_plot -- --out docs/img/plan.svg
cargo run -q -p osap-examples --release --bin corner_deviation -- --out docs/img
# The screenshot comes from osap view's browser test (needs chromium and
# chromium-driver).
OSAP_VIEW_SCREENSHOT="$(pwd)/docs/img/osap-view.png" \
  cargo test -q -p osap-cli --test view the_page_shows -- --nocapture

if [ "${1:-}" = "--clock-sync" ]; then
  cargo run -q --release -p osap-sim --features plot --bin clock_sync_report -- \
    --minutes 10 --out docs/clock-sync \
    --topologies chain4,star8,loop,osap-sim/topologies/uart-chain.toml,osap-sim/topologies/chain4-hub-root.toml
fi
git status --short docs/
