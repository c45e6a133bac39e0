#!/usr/bin/env bash
# Int8 (QDQ) static quantization of a YOLO ONNX export for ONNX Runtime (issue 32 item 5),
# calibrated on frames of the synthetic camera:
#
#   scripts/quantize-yolo.sh                 # the bundled model: assets/perception/models/
#                                            #   foresight-tiny-320.onnx -> foresight-tiny-320-int8.onnx
#   scripts/quantize-yolo.sh IN.onnx OUT.onnx   # another stock YOLOv8/YOLO11 export
#
# Steps: Python from scripts/perception-pyenv.sh --ultralytics (onnx, OpenCV; onnxruntime and
# its quantization tool come from make setup's venv, onnxruntime==1.31.1); 64 calibration
# frames rendered by perception/examples/make_yolo_dataset.rs (training-scene distribution,
# seed 2026 — not a seed of any evaluation set: the val split of seed 1, the check set of
# seed 7, the accuracy tests' own generator) into
# ${FORESIGHT_CACHE:-~/.cache/foresight}/yolo-synthetic/calib-int8-n64-s2026 (kept and reused);
# then perception/tests/python/quantize_yolo.py (what it quantizes and what it leaves in float
# is in its docstring). Idempotent: the same inputs give the same bytes (the bundled file's
# sha256 is in assets/perception/models/README.md); OUT is replaced only when it changes.
# ~10 s when the frames are rendered already.
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
cd "$here"
export FORESIGHT_CACHE=${FORESIGHT_CACHE:-$HOME/.cache/foresight}
models=$here/assets/perception/models
in=${1:-$models/foresight-tiny-320.onnx}
out=${2:-$models/foresight-tiny-320-int8.onnx}
count=64
seed=2026
say() { echo "quantize-yolo: $*" >&2; }
[ -f "$in" ] || { say "no model $in"; exit 1; }
mkdir -p "$FORESIGHT_CACHE"

py=$(bash "$here/scripts/perception-pyenv.sh" --ultralytics | tail -n1)
[ -x "$py" ] || { say "perception-pyenv.sh gave no usable python (got '$py')"; exit 1; }

calib=$FORESIGHT_CACHE/yolo-synthetic/calib-int8-n$count-s$seed
stamp="count=$count seed=$seed val_fraction=0 min_pixels=20 scenes=train"
mkdir -p "$FORESIGHT_CACHE/yolo-synthetic"
exec 8>"$FORESIGHT_CACHE/yolo-synthetic/.calib-int8.lock"
flock 8
if [ -f "$calib/complete.txt" ] && [ "$(cat "$calib/complete.txt")" = "$stamp" ]; then
  say "calibration frames $calib are complete: reusing them"
else
  say "rendering $count calibration frames into $calib"
  rm -rf "$calib"
  scripts/cargo.sh run --release -q -p perception --example make_yolo_dataset -- \
    --out "$calib" --count "$count" --seed "$seed" --val-fraction 0
fi

tmp=$(mktemp --suffix=.onnx)
trap 'rm -f "$tmp"' EXIT
"$py" perception/tests/python/quantize_yolo.py --model "$in" --calibration "$calib/images" \
  --out "$tmp" --max-images "$count" 2> >(grep -v -E "^WARNING|Please consider|quantization/|^$" >&2)
if [ -f "$out" ] && cmp -s "$tmp" "$out"; then
  say "$out is up to date"
else
  mkdir -p "$(dirname "$out")"
  cp "$tmp" "$out.tmp.$$" && mv -f "$out.tmp.$$" "$out"
  say "wrote $out"
fi
sha256sum "$out" >&2
