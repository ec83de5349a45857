#!/usr/bin/env bash
# Builds the osap-core size probe (osap-core/size-probe: a minimal module
# runtime with one framed UART link and the netresponder) for the two
# Cortex-M targets and prints its text/data/bss per target.
#
# Two variants: `minimal` (netresponder, answers time requests, no clock
# controller) and `sync` (with osap-core's clock-synchronisation controller).
# Fails if the minimal thumbv6m-none-eabi .text exceeds the budget (17 KiB,
# or $OSAP_TEXT_BUDGET bytes). It was 16 KiB until issue 39: stamping time
# messages sent over buses (they were never stamped) and the responder's
# sub-µs midpoint took the minimal build to 16 936 B (docs/performance.md).
#
# Usage: scripts/size-report.sh [--symbols N]
#   --symbols N   also list the N largest symbols per target
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
probe="$root/osap-core/size-probe"
budget="${OSAP_TEXT_BUDGET:-17408}"
targets=(thumbv6m-none-eabi thumbv7em-none-eabihf)
bin=osap-size-probe

symbols=0
if [[ "${1:-}" == "--symbols" ]]; then
    symbols="${2:?--symbols needs a count}"
fi

# llvm-size and llvm-nm come with the llvm-tools rustup component (listed in
# rust-toolchain.toml). Run from the probe so its toolchain file applies.
cd "$probe"
sysroot="$(rustc --print sysroot)"
find_tool() {
    local t
    for t in "$sysroot"/lib/rustlib/*/bin/"$1"; do
        if [[ -x "$t" ]]; then
            echo "$t"
            return 0
        fi
    done
    echo "error: $1 not found under $sysroot/lib/rustlib/*/bin;" \
        "install it with: rustup component add llvm-tools" >&2
    return 1
}
llvm_size="$(find_tool llvm-size)"
llvm_nm="$(find_tool llvm-nm)"

status=0
printf '%-24s %-8s %8s %8s %8s\n' target variant text data bss
for variant in minimal sync; do
for target in "${targets[@]}"; do
    features=()
    [[ "$variant" == sync ]] && features=(--features sync)
    cargo build --quiet --release --target "$target" "${features[@]}"
    elf="$probe/target/$target/release/$bin"
    # Berkeley format: text data bss dec hex filename
    read -r text data bss _ < <("$llvm_size" -B "$elf" | tail -n 1)
    printf '%-24s %-8s %8d %8d %8d\n' "$target" "$variant" "$text" "$data" "$bss"
    if [[ "$symbols" -gt 0 ]]; then
        # awk, not head: head would close the pipe early and, under
        # pipefail, fail the script with SIGPIPE.
        "$llvm_nm" --size-sort --reverse-sort -S --demangle "$elf" \
            | awk -v n="$symbols" 'NR <= n { print "    " $0 }'
    fi
    # The budget is for the minimal module (netresponder, no sync controller).
    if [[ "$variant" == minimal && "$target" == thumbv6m-none-eabi && "$text" -gt "$budget" ]]; then
        echo "error: minimal $target text is $text bytes, over the budget of $budget" >&2
        status=1
    fi
done
done
if [[ $status -eq 0 ]]; then
    echo "minimal thumbv6m-none-eabi text is within the budget of $budget bytes"
fi
exit $status
