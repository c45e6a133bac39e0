#!/usr/bin/env bash
# Runs cargo with the environment the Makefile gives it (target dir, LIBTORCH, rpath), for
# developers who want plain cargo commands: `scripts/cargo.sh test --release -p rt-core`.
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
[ -f "$here/build/env.mk" ] || bash "$here/scripts/setup.sh"
while IFS= read -r line; do
  case "$line" in
    [A-Z_]*:=*) k=${line%% :=*}; v=${line#*:= }; export "$k=$v" ;;
  esac
done < "$here/build/env.mk"
export FORESIGHT_CACHE=${FORESIGHT_CACHE:-$HOME/.cache/foresight}
# One target folder per checkout path (see the Makefile).
key=$(printf '%s' "$here" | sha1sum | cut -c1-12)
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$FORESIGHT_CACHE/target-$key}
export LIBTORCH_BYPASS_VERSION_CHECK=1
exec cargo "$@"
