"""Builds a stock ultralytics YOLOv8n ONNX export with random weights and 2 classes.

Usage: make_onnx_yolov8n_stock.py OUT.onnx [IMGSZ]

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
        exported = YOLO(pt).export(format="onnx", opset=12, imgsz=imgsz, simplify=False, dynamic=False)
        shutil.copyfile(exported, out)
    print(out)


if __name__ == "__main__":
    main()
