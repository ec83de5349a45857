#!/bin/sh
# The RP2040 firmware's cargo runner (named in .cargo/config.toml), so
# `cargo run --release` copies <elf>.uf2 onto the board's boot drive.
exec "$(dirname "$0")/../uf2-link/link.sh" flash --family rp2040 -- "$@"
