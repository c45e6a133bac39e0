"""Builds a stock ultralytics YOLOv8n ONNX export with random weights and 2 classes.

Usage: make_onnx_yolov8n_stock.py OUT.onnx [IMGSZ] [INPUT.f32 OUTPUT.f32]

With INPUT.f32 (a raw float32 [1, 3, IMGSZ, IMGSZ] blob), also writes the PyTorch model's
output for it to OUTPUT.f32 (raw float32 [1, 4 + 2, N]), the reference OpenCV must match.

Exactly what a user gets from `yolo export format=onnx opset=12` for a 2-class model,
except that the weights are random (built from the yolov8n.yaml config; nothing is
downloaded: YOLO_OFFLINE=1). Run with the venv of scripts/perception-pyenv.sh --ultralytics.
"""

import os
import shutil
import sys
import tempfile

os.environ.setdefault("YOLO_OFFLINE", "1")

import torch  # noqa: E402
import yaml  # noqa: E402
from ultralytics import YOLO  # noqa: E402
from ultralytics.nn.tasks import yaml_model_load  # noqa: E402


def main() -> None:
    out = os.path.abspath(sys.argv[1])
    imgsz = int(sys.argv[2]) if len(sys.argv) > 2 else 640
    torch.manual_seed(0)
    cfg = yaml_model_load("yolov8n.yaml")
    cfg["nc"] = 2
    with tempfile.TemporaryDirectory() as tmp:
        cfg_path = os.path.join(tmp, "yolov8n_2cls.yaml")
        with open(cfg_path, "w") as f:
            yaml.safe_dump(cfg, f)
        model = YOLO(cfg_path)
        model.model.names = {0: "goal", 1: "obstacle"}
        # Export writes next to the .pt; give it a path in tmp.
        pt = os.path.join(tmp, "yolov8n_2cls.pt")
        model.save(pt)
        # Defaults as `yolo export format=onnx opset=12` (simplify=True: onnxslim folds the
        # dynamic shape arithmetic of the head, which OpenCV 4.6 could not constant-fold).
        exported = YOLO(pt).export(format="onnx", opset=12, imgsz=imgsz)
        shutil.copyfile(exported, out)
        if len(sys.argv) > 4:
            import numpy as np

            x = np.fromfile(sys.argv[3], dtype=np.float32).reshape(1, 3, imgsz, imgsz)
            net = YOLO(pt).model.fuse().eval()
            with torch.no_grad():
                y = net(torch.from_numpy(x))
            y = y[0] if isinstance(y, (list, tuple)) else y
            y.numpy().astype(np.float32).tofile(sys.argv[4])
    print(out)


if __name__ == "__main__":
    main()
