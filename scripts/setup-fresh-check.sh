#!/usr/bin/env bash
# Runs scripts/setup.sh as a new user meets it: in a clone of this checkout's HEAD, with an empty
# FORESIGHT_CACHE and a fresh HOME (empty pip cache). Fails when set-up fails or when its output
# holds ERROR or WARNING (issue 41 item 6). Leaves nothing behind.
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT
git clone -q "$here" "$scratch/clone"
mkdir -p "$scratch/home"
log="$scratch/setup.log"
if ! (cd "$scratch/clone" && env HOME="$scratch/home" FORESIGHT_CACHE="$scratch/cache" \
      bash scripts/setup.sh) >"$log" 2>&1; then
  cat "$log"; echo "setup-fresh-check: set-up failed" >&2; exit 1
fi
cat "$log"
if grep -nE 'ERROR|WARNING' "$log"; then
  echo "setup-fresh-check: set-up printed the lines above" >&2; exit 1
fi
echo "setup-fresh-check: clean ($(wc -l <"$log") lines, no ERROR, no WARNING)"
