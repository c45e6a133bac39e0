#!/usr/bin/env bash
# Installs everything Foresight needs to build and run, from the package registries only.
# Idempotent: each step checks before it acts, so `make setup` is cheap the second time.
#
# What it installs:
#   1. Debian packages: clang/libclang (bindgen + the opencv binding generator), OpenCV 4.6
#      headers and libraries, pkg-config, iproute2 (network namespaces for the ROS 2 and
#      xArm SDK tests).
#   2. A Python virtual environment holding torch==2.13.0, which ships the libtorch that
#      the `tch 0.26` crate links against (tch cannot download libtorch here).
#      TORCH_VARIANT=cpu (default): torch without its CUDA dependency wheels, plus the two
#      small CUDA runtime wheels libtorch_cpu.so still needs (≈1.2 GB instead of ≈4.7 GB).
#      TORCH_VARIANT=cuda: the full wheel with its CUDA libraries, for GPU training.
#   3. ONNX Runtime for perception's YOLO detector: the PyPI `onnxruntime` wheel (its
#      libonnxruntime.so, loaded at run time by the `ort` crate's load-dynamic; ort 2.0.0-rc.15
#      with api-22 needs ONNX Runtime >= 1.22), installed without dependencies into the same venv.
#   4. The run-recording readers: the `mcap` and `mcap-ros2-support` Python packages (the
#      independent reader of the runs' MCAP files in the system tests), `rosbags` (the
#      independent rosbag2 reader of a run folder) and matplotlib (the README's picture of a
#      recording).
#   5. build/env.mk: the LIBTORCH path and the ONNX Runtime library path that the Makefile
#      exports to every cargo call (perception bakes the latter in as its default), so that
#      nothing is rebuilt because a variable changed.
#
# Caches live outside the clone (FORESIGHT_CACHE, default ~/.cache/foresight) so that
# repeated CI runs reuse them; nothing depends on them existing.
set -euo pipefail

here=$(cd "$(dirname "$0")/.." && pwd)
cache=${FORESIGHT_CACHE:-$HOME/.cache/foresight}
variant=${TORCH_VARIANT:-cpu}
torch_version=2.13.0
venv="$cache/venv-torch-$torch_version-$variant"

say() { printf '\033[1m[setup]\033[0m %s\n' "$*"; }

# ---- 1. Debian packages ------------------------------------------------------------------
apt_pkgs=(clang libclang-dev libopencv-dev pkg-config iproute2 util-linux python3-venv
          libfontconfig1-dev libfreetype-dev fonts-dejavu-core)
missing=()
for p in "${apt_pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  say "installing Debian packages: ${missing[*]}"
  sudo=""; [ "$(id -u)" -eq 0 ] || sudo="sudo"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
else
  say "Debian packages present"
fi

# ---- 2. Python venv with torch ---------------------------------------------------------------
py=${PYTHON:-python3}
if [ ! -x "$venv/bin/python" ]; then
  say "creating virtual environment $venv"
  mkdir -p "$cache"
  "$py" -m venv "$venv"
  # pip pinned like every other package (issue 41 item 6): the same resolver on every machine.
  "$venv/bin/python" -m pip install -q "pip==26.3"
fi
have=$("$venv/bin/python" - <<'PY' 2>/dev/null || true
import importlib.metadata as m
try: print(m.version("torch"))
except Exception: pass
PY
)
if [ "${have%%+*}" != "$torch_version" ]; then
  say "installing torch==$torch_version ($variant) into the venv (a few minutes the first time)"
  if [ "$variant" = "cuda" ]; then
    "$venv/bin/python" -m pip install -q "torch==$torch_version"
  else
    "$venv/bin/python" -m pip install -q --no-deps "torch==$torch_version" \
      nvidia-cuda-runtime==13.0.96 nvidia-cuda-cupti==13.0.85
  fi
else
  say "torch $have present"
fi
torch_dir=$(echo "$venv"/lib/python3*/site-packages/torch)
[ -f "$torch_dir/lib/libtorch_cpu.so" ] || { echo "setup: $torch_dir has no lib/libtorch_cpu.so" >&2; exit 1; }
# tch skips its own version check when LIBTORCH is set: check it here.
got=$(sed -n "s/^__version__ = '\(.*\)'/\1/p" "$torch_dir/version.py")
[ "${got%%+*}" = "$torch_version" ] || { echo "setup: torch at $torch_dir is $got, tch 0.26 needs $torch_version" >&2; exit 1; }
# Directories holding the CUDA runtime libraries that libtorch_cpu.so needs at load time.
nvidia_libs=$(find "$venv"/lib/python3*/site-packages/nvidia -maxdepth 3 -type d -name lib 2>/dev/null | sort | tr '\n' ':' | sed 's/:$//')

# ---- 3. ONNX Runtime ----------------------------------------------------------------------
ort_version=1.31.1
have_ort=$("$venv/bin/python" - <<'PY' 2>/dev/null || true
import importlib.metadata as m
try: print(m.version("onnxruntime"))
except Exception: pass
PY
)
if [ "$have_ort" != "$ort_version" ]; then
  say "installing onnxruntime==$ort_version (its shared library, for perception's YOLO detector)"
  "$venv/bin/python" -m pip install -q --no-deps "onnxruntime==$ort_version"
else
  say "onnxruntime $have_ort present"
fi
ort_lib=$(ls "$venv"/lib/python3*/site-packages/onnxruntime/capi/libonnxruntime.so.* 2>/dev/null | head -n1)
[ -f "$ort_lib" ] || { echo "setup: the onnxruntime wheel has no capi/libonnxruntime.so.*" >&2; exit 1; }

# ---- 4. Run-recording readers ------------------------------------------------------------------
# The `mcap` Python package is the independent reader the system tests check every run's
# MCAP file with (tests/scripts/check_mcap.py, CDR decoded by mcap-ros2-support);
# matplotlib draws the README's picture of a recording (tests/scripts/render_mcap.py).
# flatbuffers and protobuf are what the onnxruntime wheel (installed without its dependencies
# above) declares besides numpy and packaging (which matplotlib brings): installed here, in the
# same resolver run, so that pip reports no broken dependency (issue 32 item 4).
# rosbags is the independent rosbag2 reader that opens a run folder as a bag (metadata.yaml and
# the channels' offered QoS; tests/scripts/check_bag.py).
py_pkgs=(mcap==1.6.0 mcap-ros2-support==0.6.0 matplotlib==3.11.2 flatbuffers==25.12.19 protobuf==6.33.6 rosbags==0.11.9)
missing_py=$("$venv/bin/python" - "${py_pkgs[@]}" <<'PY' 2>/dev/null || true
import importlib.metadata as m, sys
for spec in sys.argv[1:]:
    name, want = spec.split("==")
    try:
        ok = m.version(name) == want
    except Exception:
        ok = False
    if not ok:
        print(spec)
PY
)
if [ -n "$missing_py" ]; then
  say "installing $(echo $missing_py) (run-recording readers) into the venv"
  # --no-warn-conflicts: pip's own after-install report would list torch's requirements, which
  # step 2 leaves out on purpose (libtorch only, --no-deps) and which would read as an ERROR on
  # every fresh machine (issue 41 item 6). The check below is that report with exactly this one
  # exception: any other broken requirement still stops the set-up.
  # shellcheck disable=SC2086
  "$venv/bin/python" -m pip install -q --no-warn-conflicts \
    -c "$here/scripts/python-constraints.txt" $missing_py
else
  say "mcap readers present"
fi
"$venv/bin/python" "$here/scripts/check_venv.py" \
  || { echo "setup: the venv $venv has broken requirements (above)" >&2; exit 1; }

# ---- 5. build/env.mk ---------------------------------------------------------------------------
mkdir -p "$here/build"
cat > "$here/build/env.mk.tmp" <<MK
# Written by scripts/setup.sh; do not edit.
FORESIGHT_VENV := $venv
LIBTORCH := $torch_dir
FORESIGHT_TORCH_RPATH := $torch_dir/lib:$nvidia_libs
FORESIGHT_ORT_DYLIB := $ort_lib
MK
mv "$here/build/env.mk.tmp" "$here/build/env.mk"
say "ready (LIBTORCH=$torch_dir, ONNX Runtime $ort_lib)"
