"""Builds a stock Ultralytics ONNX export with random weights and 2 classes (goal, obstacle).

Usage:
  make_onnx_ultralytics.py OUT.onnx [--arch yolov8n|yolo11n|yolov10n] [--imgsz 640]
                           [--nms] [--opset 12] [--input IN.f32 --output OUT.f32]

Exactly what a user gets from `yolo export format=onnx` for a 2-class model of that
architecture, except that the weights are random (built from the architecture's yaml; nothing
is downloaded: YOLO_OFFLINE=1). Output layouts:
  - yolov8n, yolo11n: `[1, 4 + 2, N]` (NMS in the consumer's code);
  - yolov10n: end-to-end, `[1, 300, 6]` (x0, y0, x1, y1, score, class; NMS-free head);
  - --nms (YOLOv8/YOLO11): Ultralytics' `export(nms=True)`, also `[1, 300, 6]`.

With --input (a raw float32 [1, 3, IMGSZ, IMGSZ] blob), also writes the PyTorch model's
output for it to --output (raw float32, the export's output layout): the reference an engine
running the ONNX file must match.

Run with the venv of scripts/perception-pyenv.sh --ultralytics.
"""

import argparse
import os
import shutil
import tempfile

os.environ.setdefault("YOLO_OFFLINE", "1")

import torch  # noqa: E402
import yaml  # noqa: E402
from ultralytics import YOLO  # noqa: E402
from ultralytics.nn.tasks import yaml_model_load  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--arch", default="yolov8n", choices=["yolov8n", "yolo11n", "yolov10n"])
    ap.add_argument("--imgsz", type=int, default=640)
    ap.add_argument("--nms", action="store_true")
    ap.add_argument("--opset", type=int, default=12)
    ap.add_argument("--input")
    ap.add_argument("--output")
    a = ap.parse_args()
    out = os.path.abspath(a.out)
    torch.manual_seed(0)
    cfg = yaml_model_load(f"{a.arch}.yaml")
    cfg["nc"] = 2
    with tempfile.TemporaryDirectory() as tmp:
        cfg_path = os.path.join(tmp, f"{a.arch}_2cls.yaml")
        with open(cfg_path, "w") as f:
            yaml.safe_dump(cfg, f)
        model = YOLO(cfg_path)
        model.model.names = {0: "goal", 1: "obstacle"}
        pt = os.path.join(tmp, f"{a.arch}_2cls.pt")
        model.save(pt)
        # Defaults as `yolo export format=onnx` (simplify=True).
        kw = dict(format="onnx", opset=a.opset, imgsz=a.imgsz)
        if a.nms:
            kw["nms"] = True
        exported = YOLO(pt).export(**kw)
        shutil.copyfile(exported, out)
        if a.input:
            import numpy as np

            x = np.fromfile(a.input, dtype=np.float32).reshape(1, 3, a.imgsz, a.imgsz)
            net = YOLO(pt).model.fuse().eval()
            with torch.no_grad():
                y = net(torch.from_numpy(x))
            y = y[0] if isinstance(y, (list, tuple)) else y
            y.numpy().astype(np.float32).tofile(a.output)
    print(out)


if __name__ == "__main__":
    main()
