"""Builds a tiny ONNX model, with the `onnx` package, whose output is known exactly and that
has the structure of a stock YOLOv8 head, including its `Mul` of the boxes [1,4,N] by a
strides constant [1,N] (which OpenCV 4.6 cannot broadcast).

Usage: make_onnx_yolo_toy.py SPEC.json OUT.onnx

SPEC = {"imgsz": 640, "stride": 32, "num_classes": 2, "strides": [N floats],
        "anchors": [{"index": i, "box": [cx, cy, w, h], "scores": [p0, p1, ...]}, ...]}
Boxes are in network-input pixels. Every other anchor has a zero box and scores ~4.5e-5.

Graph: images -> Conv(zero weights, kernel = stride = `stride`) -> Reshape [1, 4+C, N]
-> Split(4, C) -> boxes + BOX/strides -> Mul(strides [1, N]) ; Sigmoid(cls + LOGITS)
-> Concat(axis 1) -> output0 [1, 4+C, N].
"""

import json
import math
import sys

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper


def main() -> None:
    spec = json.load(open(sys.argv[1]))
    out = sys.argv[2]
    s = int(spec["imgsz"])
    k = int(spec["stride"])
    c = int(spec["num_classes"])
    g = s // k
    n = g * g
    strides = np.asarray(spec["strides"], dtype=np.float32).reshape(1, n)
    box = np.zeros((1, 4, n), dtype=np.float32)
    logits = np.full((1, c, n), -10.0, dtype=np.float32)
    for a in spec["anchors"]:
        i = int(a["index"])
        box[0, :, i] = np.asarray(a["box"], dtype=np.float32) / strides[0, i]
        for j, p in enumerate(a["scores"]):
            logits[0, j, i] = math.log(p / (1.0 - p))
    inits = [
        numpy_helper.from_array(np.zeros((4 + c, 3, k, k), dtype=np.float32), "W"),
        numpy_helper.from_array(np.asarray([1, 4 + c, n], dtype=np.int64), "shape"),
        numpy_helper.from_array(box, "BOX"),
        numpy_helper.from_array(logits, "LOGITS"),
        numpy_helper.from_array(strides, "strides"),
    ]
    nodes = [
        helper.make_node("Conv", ["images", "W"], ["conv"], kernel_shape=[k, k], strides=[k, k]),
        helper.make_node("Reshape", ["conv", "shape"], ["flat"]),
        helper.make_node("Split", ["flat"], ["raw_box", "raw_cls"], axis=1, split=[4, c]),
        helper.make_node("Add", ["raw_box", "BOX"], ["grid_box"]),
        helper.make_node("Mul", ["grid_box", "strides"], ["dbox"], name="/model.22/Mul_2"),
        helper.make_node("Add", ["raw_cls", "LOGITS"], ["cls_logits"]),
        helper.make_node("Sigmoid", ["cls_logits"], ["cls"]),
        helper.make_node("Concat", ["dbox", "cls"], ["output0"], axis=1),
    ]
    graph = helper.make_graph(
        nodes,
        "yolo_toy",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, s, s])],
        [helper.make_tensor_value_info("output0", TensorProto.FLOAT, [1, 4 + c, n])],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 12)])
    model.ir_version = 7
    onnx.checker.check_model(model)
    onnx.save(model, out)
    print(out)


if __name__ == "__main__":
    main()
