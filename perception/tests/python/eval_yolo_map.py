#!/usr/bin/env python3
"""mAP of one or more ONNX YOLO exports on a synthetic YOLO dataset, through Ultralytics'
validator (the numbers of assets/perception/models/README.md): each model is run by ONNX
Runtime on the CPU at its own input size (letterboxed square, grey padding, as perception's
detector does), confidence 0.001, NMS IoU 0.7, Ultralytics' COCO-style 101-point mAP.

    eval_yolo_map.py --data DATASET/data.yaml MODEL.onnx [MODEL.onnx ...]

Prints one JSON line per model: {"model", "data", "map50", "map50_95", "precision",
"recall", "per_class": {name: {"map50", "map50_95"}}}. Needs the Python of
scripts/perception-pyenv.sh --ultralytics.
"""

import argparse
import json
import os
import sys
from pathlib import Path


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, type=Path, help="dataset yaml (its val split is evaluated)")
    ap.add_argument("models", nargs="+", type=Path)
    args = ap.parse_args()
    os.environ.setdefault("YOLO_OFFLINE", "1")
    from ultralytics import YOLO

    for m in args.models:
        import onnx

        dims = onnx.load(str(m), load_external_data=False).graph.input[0].type.tensor_type.shape.dim
        imgsz = dims[2].dim_value or 640
        r = YOLO(str(m), task="detect").val(
            data=str(args.data), imgsz=imgsz, batch=1, device="cpu", conf=0.001, iou=0.7,
            plots=False, verbose=False, workers=0,
        )
        names = r.names
        per_class = {}
        for i, c in enumerate(r.box.ap_class_index):
            per_class[names[int(c)]] = {
                "map50": round(float(r.box.ap50[i]), 4),
                "map50_95": round(float(r.box.ap[i]), 4),
            }
        print(
            json.dumps(
                {
                    "model": str(m),
                    "data": str(args.data),
                    "map50": round(float(r.box.map50), 4),
                    "map50_95": round(float(r.box.map), 4),
                    "precision": round(float(r.box.mp), 4),
                    "recall": round(float(r.box.mr), 4),
                    "per_class": per_class,
                }
            ),
            flush=True,
        )


if __name__ == "__main__":
    sys.exit(main())
