#!/bin/sh
# The firmwares' shared linker, run by each firmware's own link.sh (named
# in its .cargo/config.toml) as
#     uf2-link/link.sh --family <UF2 family id> --flash <start>..<end> -- <rustc's args>
# Builds the uf2-link wrapper on first use (or when its source changed),
# then hands it those arguments.
set -eu
here=$(cd "$(dirname "$0")" && pwd)
host=$(rustc -vV | sed -n 's/^host: //p')
bin="$here/target/$host/release/uf2-link"
stale=0
[ -x "$bin" ] || stale=1
for src in "$here/Cargo.toml" "$here/src"/*.rs; do
    if [ "$src" -nt "$bin" ]; then stale=1; fi
done
if [ "$stale" = 1 ]; then
    # A separate target dir and workspace: no lock shared with the outer
    # build. Drop the outer cargo's jobserver so the inner one makes its own.
    env -u CARGO_MAKEFLAGS -u MAKEFLAGS -u MFLAGS \
        cargo build --release --quiet --locked \
        --manifest-path "$here/Cargo.toml" --target "$host" \
        --target-dir "$here/target" >&2
fi
exec "$bin" "$@"
