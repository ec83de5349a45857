#!/bin/sh
# The RP2040 firmware's linker (named in .cargo/config.toml): the shared
# UF2 wrapper with the RP2040's family id and its 16 MiB XIP flash window.
exec "$(dirname "$0")/../uf2-link/link.sh" \
    --family rp2040 --flash 0x10000000..0x11000000 -- "$@"
