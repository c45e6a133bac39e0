"""The reference decode: Ultralytics' own prediction of an ONNX model on one image.

Usage: ultralytics_predict.py MODEL.onnx IMAGE.png OUT.json [CONF] [IOU]

Ultralytics letterboxes the image to the model's input size, runs the ONNX file through
ONNX Runtime, decodes, applies NMS (for [1, 4+C, N] exports) and maps the boxes back to the
image's pixels. Writes [{"class": i, "score": s, "xyxy": [x0, y0, x1, y1]}, ...], best first.
Run with the venv of scripts/perception-pyenv.sh --ultralytics.
"""

import json
import os
import sys

os.environ.setdefault("YOLO_OFFLINE", "1")

from ultralytics import YOLO  # noqa: E402


def main() -> None:
    model, image, out = sys.argv[1:4]
    conf = float(sys.argv[4]) if len(sys.argv) > 4 else 0.25
    iou = float(sys.argv[5]) if len(sys.argv) > 5 else 0.45
    m = YOLO(model, task="detect")
    r = m.predict(image, conf=conf, iou=iou, verbose=False)[0]
    boxes = [
        {"class": int(c), "score": float(s), "xyxy": [float(v) for v in b]}
        for b, s, c in zip(r.boxes.xyxy.tolist(), r.boxes.conf.tolist(), r.boxes.cls.tolist())
    ]
    boxes.sort(key=lambda b: -b["score"])
    with open(out, "w") as f:
        json.dump(boxes, f)


if __name__ == "__main__":
    main()
