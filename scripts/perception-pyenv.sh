#!/usr/bin/env bash
# Provisions (idempotently) the Python tools perception's tests use to build ONNX models:
# a venv under ${FORESIGHT_CACHE:-~/.cache/foresight}/venv-perception that reuses the torch of
# the venv scripts/setup.sh made (FORESIGHT_VENV in build/env.mk) through a .pth file instead
# of installing torch again (4.7 GB), plus `onnx` and, with `--ultralytics`, ultralytics and a
# torchvision matching torch 2.13.0. Prints the venv's python on the last line of stdout.
#
#   scripts/perception-pyenv.sh                # onnx only (small test graphs)
#   scripts/perception-pyenv.sh --ultralytics  # + ultralytics (stock YOLOv8n export)
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
cache=${FORESIGHT_CACHE:-$HOME/.cache/foresight}
venv=$cache/venv-perception
want_ul=0
[ "${1:-}" = "--ultralytics" ] && want_ul=1

torch_venv=${FORESIGHT_VENV:-}
if [ -z "$torch_venv" ] && [ -f "$here/build/env.mk" ]; then
  torch_venv=$(sed -n 's/^FORESIGHT_VENV := //p' "$here/build/env.mk")
fi

exec 9>"$cache/.perception-pyenv.lock"
flock 9

if [ ! -x "$venv/bin/python" ]; then
  base=python3
  [ -n "$torch_venv" ] && [ -x "$torch_venv/bin/python" ] && base="$torch_venv/bin/python"
  "$base" -m venv "$venv" >&2
fi
site=$("$venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
if [ -n "$torch_venv" ] && [ -d "$torch_venv" ]; then
  tsite=$("$torch_venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
  # Rewritten only when it changes, and then by rename: tests run this script while other
  # tests' Python processes start, and a .pth caught truncated mid-write hides torch from
  # them ("No module named 'torch'", the flake of CI stop 34).
  if [ "$(cat "$site/foresight-torch.pth" 2>/dev/null || true)" != "$tsite" ]; then
    echo "$tsite" > "$site/foresight-torch.pth.tmp.$$"
    mv -f "$site/foresight-torch.pth.tmp.$$" "$site/foresight-torch.pth"
  fi
fi

start=$(date +%s)
if ! "$venv/bin/python" -c 'import onnx, numpy' 2>/dev/null; then
  "$venv/bin/pip" install --quiet "onnx==1.17.0" "numpy<2.3" >&2
fi
if [ "$want_ul" = 1 ] && ! "$venv/bin/python" -c 'import ultralytics, torchvision' 2>/dev/null; then
  # torch was installed with --no-deps by setup.sh: add the pure-Python packages it imports.
  "$venv/bin/pip" install --quiet typing_extensions filelock sympy networkx jinja2 fsspec >&2
  tv=$("$venv/bin/python" - <<'PY'
from importlib.metadata import version
major, minor = (int(x) for x in version("torch").split("+")[0].split(".")[:2])
# torchvision 0.(minor+15) pairs with torch 2.minor
print(f"torchvision==0.{minor + 15}.*")
PY
)
  # No deps for torchvision (it would pull another torch); the rest of ultralytics' needs normally.
  "$venv/bin/pip" install --quiet --no-deps "$tv" >&2
  "$venv/bin/pip" install --quiet "ultralytics==8.3.*" "onnxslim" >&2
  installed_ul=1
fi
if [ "${installed_ul:-0}" = 1 ] && ! "$venv/bin/python" -c 'import torch, torchvision, ultralytics' 2>/dev/null; then
  echo "perception-pyenv: $venv cannot import torch, torchvision and ultralytics after provisioning" >&2
  "$venv/bin/python" -c 'import torch, torchvision, ultralytics' >&2 || true
  exit 1
fi
end=$(date +%s)
[ $((end - start)) -gt 1 ] && echo "perception-pyenv: provisioning took $((end - start)) s" >&2
echo "$venv/bin/python"
