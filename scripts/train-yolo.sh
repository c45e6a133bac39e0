#!/usr/bin/env bash
# Regenerates perception's own YOLO detector, trained on the synthetic renders:
#   assets/perception/models/foresight-tiny-320.onnx      (stock export, output [1, 6, 2100])
#   assets/perception/models/foresight-tiny-320-e2e.onnx  (NMS inside, output [1, 300, 6])
# (assets/perception/models/README.md says how the committed files were made.)
#
#   scripts/train-yolo.sh            # dataset + training + export + copy (reuses finished steps)
#   FORCE=1 scripts/train-yolo.sh    # train again even if this configuration was trained
#
# Steps: Python from scripts/perception-pyenv.sh --ultralytics; the dataset from
# perception/examples/make_yolo_dataset.rs into ${FORESIGHT_CACHE:-~/.cache/foresight}/yolo-synthetic/
# (kept and reused while its parameters are the same); training and ONNX export by
# perception/tests/python/train_yolo_synthetic.py (CPU, fixed seed, deterministic); the ONNX
# files copied into assets/perception/models/. Parameters (environment, defaults = the
# committed models): YOLO_COUNT, YOLO_SEED, YOLO_VAL_FRACTION, YOLO_EPOCHS, YOLO_IMGSZ,
# YOLO_BATCH, YOLO_TRAIN_SEED, YOLO_THREADS. A 100-scene check set drawn like perception's
# accuracy test is rendered too; the exports are run on it (summary.json). About 22 min on a
# 2-core machine, 20 of them training; seconds when every step is done already.
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
cd "$here"
export FORESIGHT_CACHE=${FORESIGHT_CACHE:-$HOME/.cache/foresight}
count=${YOLO_COUNT:-1000}
seed=${YOLO_SEED:-1}
val_fraction=${YOLO_VAL_FRACTION:-0.2}
epochs=${YOLO_EPOCHS:-30}
imgsz=${YOLO_IMGSZ:-320}
batch=${YOLO_BATCH:-8}
train_seed=${YOLO_TRAIN_SEED:-0}
threads=${YOLO_THREADS:-2}
name=foresight-tiny-$imgsz
models=$here/assets/perception/models
work=$FORESIGHT_CACHE/yolo-synthetic
say() { echo "train-yolo: $*" >&2; }
mkdir -p "$FORESIGHT_CACHE"

[ -f "$here/build/env.mk" ] || { say "build/env.mk missing: running make setup"; make -C "$here" setup; }

say "provisioning Python (scripts/perception-pyenv.sh --ultralytics)"
py=$(bash "$here/scripts/perception-pyenv.sh" --ultralytics | tail -n1)
[ -x "$py" ] || { say "perception-pyenv.sh gave no usable python (got '$py')"; exit 1; }
say "python: $py"

mkdir -p "$work"
data=$work/dataset-n$count-s$seed-v$val_fraction
stamp="count=$count seed=$seed val_fraction=$val_fraction min_pixels=20 scenes=train"
if [ -f "$data/complete.txt" ] && [ "$(cat "$data/complete.txt")" = "$stamp" ]; then
  say "dataset $data is complete ($stamp): reusing it"
else
  say "rendering $count scenes into $data (~70 ms each)"
  rm -rf "$data"
  scripts/cargo.sh run --release -q -p perception --example make_yolo_dataset -- \
    --out "$data" --count "$count" --seed "$seed" --val-fraction "$val_fraction"
fi

# A check set drawn like perception's accuracy test (no object more than 3 % hidden): the
# exports are run on it with onnxruntime, as the Rust detector would, after training.
check=$work/accuracy-test-n100-s7
check_stamp="count=100 seed=7 val_fraction=1 min_pixels=20 scenes=accuracy-test"
if [ -f "$check/complete.txt" ] && [ "$(cat "$check/complete.txt")" = "$check_stamp" ]; then
  say "check set $check is complete: reusing it"
else
  say "rendering the 100-scene check set into $check"
  rm -rf "$check"
  scripts/cargo.sh run --release -q -p perception --example make_yolo_dataset -- \
    --out "$check" --count 100 --seed 7 --val-fraction 1 --scenes accuracy-test
fi

# One training folder per configuration: the parameters, the model yaml and RECIPE, a
# version to bump when train_yolo_synthetic.py changes what it trains (not for changes to
# its reporting), so a finished training is reused.
RECIPE=1
key=$( { echo "recipe=$RECIPE $stamp epochs=$epochs imgsz=$imgsz batch=$batch seed=$train_seed threads=$threads"
         cat perception/tests/python/foresight-yolov8-tiny.yaml; } | sha1sum | cut -c1-12)
run=$work/train-$key
if [ "${FORCE:-0}" != 1 ] && [ -f "$run/summary.json" ] && [ -f "$run/$name.onnx" ]; then
  say "this configuration was trained already ($run): reusing it (FORCE=1 to train again)"
else
  say "training $name for $epochs epochs on CPU ($threads threads) into $run"
  rm -rf "$run"
  mkdir -p "$run"
  "$py" perception/tests/python/train_yolo_synthetic.py --data "$data/data.yaml" --workdir "$run" \
    --epochs "$epochs" --imgsz "$imgsz" --batch "$batch" --seed "$train_seed" --threads "$threads" \
    --extra-eval "$check/data.yaml" 2>&1 | tee "$work/train-$key.log"
fi

mkdir -p "$models"
cp "$run/$name.onnx" "$models/$name.onnx"
say "wrote $models/$name.onnx"
if [ -f "$run/$name-e2e.onnx" ]; then
  cp "$run/$name-e2e.onnx" "$models/$name-e2e.onnx"
  say "wrote $models/$name-e2e.onnx"
else
  rm -f "$models/$name-e2e.onnx"
  say "no NMS-inside export (see e2e_error in $run/summary.json)"
fi

# Sanity check of what was copied: output shapes and the class names in the metadata.
"$py" - "$models/$name.onnx" "$models/$name-e2e.onnx" <<'PY'
import sys, os
import numpy as np
import onnx
for path in sys.argv[1:]:
    if not os.path.exists(path):
        continue
    m = onnx.load(path)
    names = {p.key: p.value for p in m.metadata_props}.get("names")
    line = f"{os.path.basename(path)}: {os.path.getsize(path)} bytes, names {names}"
    try:
        import onnxruntime as ort
        s = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
        i = s.get_inputs()[0]
        out = s.run(None, {i.name: np.zeros(i.shape, np.float32)})
        line += f", input {i.name} {i.shape}, outputs {[o.shape for o in out]} (onnxruntime {ort.__version__})"
    except ImportError:
        line += f", outputs {[[d.dim_value for d in o.type.tensor_type.shape.dim] for o in m.graph.output]} (onnx; no onnxruntime to run it)"
    print("train-yolo: " + line, file=sys.stderr)
PY
say "summary: $run/summary.json"
cat "$run/summary.json"
