#!/bin/sh
# The SAMD51 firmware's linker (named in .cargo/config.toml): the shared
# UF2 wrapper with the SAMD51's family id and its program flash window,
# after the 16 KiB UF2 bootloader and before the name block (memory.x).
exec "$(dirname "$0")/../uf2-link/link.sh" \
    --family samd51 --flash 0x4000..0x7e000 -- "$@"
