"""Trains Foresight's tiny YOLOv8 on the synthetic renders and exports it to ONNX.

Run by scripts/train-yolo.sh with the perception venv (scripts/perception-pyenv.sh
--ultralytics) on a dataset written by perception/examples/make_yolo_dataset.rs:

    python perception/tests/python/train_yolo_synthetic.py --data DIR/data.yaml \
        --workdir DIR/runs --epochs 30 --imgsz 320 --batch 8 --seed 0 --extra-eval CHECK/data.yaml

CPU only, fixed seed, deterministic algorithms, no data-loader worker processes, no pretrained
weights (trained from scratch; YOLO_OFFLINE=1, nothing is downloaded). Writes into --workdir:
  foresight-tiny-<imgsz>.onnx      stock export (opset 12, simplified): output [1, 4 + 2, N]
  foresight-tiny-<imgsz>-e2e.onnx  NMS inside the graph (`nms=True`): output [1, 300, 6] =
                                   x0, y0, x1, y1, score, class in input pixels
  summary.json                     versions, times, val metrics, sizes, output shapes, and
                                   each export run with onnxruntime the way the Rust detector
                                   runs it (letterbox, threshold 0.25, class-aware NMS 0.45)
                                   on the val images (and --extra-eval sets): objects found,
                                   false positives, box-edge errors in 1280x720 pixels

`--evaluate-only A.onnx B.onnx` skips training and prints that check for existing exports.
Ultralytics' own RAM cache warning about determinism does not apply here: with cache="ram"
its mosaic draws from the whole dataset, not from the load-order buffer (two 1-epoch runs
gave bit-identical weights).
"""

import argparse
import json
import os
import platform
import shutil
import sys
import time
from pathlib import Path

# Before ultralytics / torch are imported: no hub access, two intra-op threads (ultralytics
# otherwise sets OMP_NUM_THREADS=1 and resets torch to cpu_count - 1 threads), settings and
# fonts kept out of the home folder.
os.environ["YOLO_OFFLINE"] = "1"
os.environ.setdefault("OMP_NUM_THREADS", "2")


def parse_args():
    here = Path(__file__).resolve().parent
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", required=True, type=Path, help="data.yaml of the dataset")
    p.add_argument("--workdir", required=True, type=Path, help="runs and exports go here")
    p.add_argument("--model", type=Path, default=here / "foresight-yolov8-tiny.yaml")
    p.add_argument("--name", default=None, help="basename of the exports (foresight-tiny-<imgsz>)")
    p.add_argument("--imgsz", type=int, default=320)
    p.add_argument("--epochs", type=int, default=30)
    p.add_argument("--batch", type=int, default=8)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=2, help="torch intra-op threads")
    p.add_argument("--mosaic", type=float, default=1.0)
    p.add_argument("--close-mosaic", type=int, default=10)
    p.add_argument("--scale", type=float, default=0.25, help="random scale augmentation (±)")
    p.add_argument("--warmup-epochs", type=float, default=1.0)
    p.add_argument("--optimizer", default="auto", help="ultralytics optimizer (auto: AdamW for short runs)")
    p.add_argument("--lr0", type=float, default=0.01, help="initial learning rate (ignored by optimizer=auto)")
    p.add_argument("--lrf", type=float, default=0.01, help="final learning rate as a fraction of the first")
    p.add_argument("--init", type=Path, default=None,
                   help="start from these weights (a best.pt of an earlier run) instead of from scratch")
    p.add_argument("--rect", action="store_true",
                   help="Ultralytics rect=True batches (no mosaic, no shuffling); used for fine-tuning")
    p.add_argument("--patience", type=int, default=100)
    p.add_argument("--cache", default="ram", help="ram | disk | none")
    p.add_argument("--val-each-epoch", action="store_true",
                   help="validate after every epoch (default: after the last one only; ~15 %% faster)")
    p.add_argument("--no-e2e", action="store_true", help="skip the NMS-inside export")
    p.add_argument("--extra-eval", type=Path, action="append", default=[], metavar="DATA_YAML",
                   help="another dataset whose val images the exports are also run on (repeatable)")
    p.add_argument("--evaluate-only", type=Path, nargs="+", metavar="ONNX",
                   help="no training: run these exports on --data (and --extra-eval) and print the results")
    return p.parse_args()


def letterbox(bgr, size):
    """The Rust detector's preprocessing (perception/src/yolo): scale to fit, INTER_LINEAR,
    centred grey (114) padding, RGB, 0..1, NCHW."""
    import cv2
    import numpy as np

    h, w = bgr.shape[:2]
    scale = min(size / w, size / h)
    nw, nh = round(w * scale), round(h * scale)
    px, py = (size - nw) // 2, (size - nh) // 2
    img = cv2.resize(bgr, (nw, nh), interpolation=cv2.INTER_LINEAR)
    img = cv2.copyMakeBorder(img, py, size - nh - py, px, size - nw - px, cv2.BORDER_CONSTANT, value=(114, 114, 114))
    blob = img[:, :, ::-1].transpose(2, 0, 1)[None].astype(np.float32) / 255.0
    return np.ascontiguousarray(blob), scale, px, py


def iou_matrix(a, b):
    import numpy as np

    if len(a) == 0 or len(b) == 0:
        return np.zeros((len(a), len(b)))
    x0 = np.maximum(a[:, None, 0], b[None, :, 0])
    y0 = np.maximum(a[:, None, 1], b[None, :, 1])
    x1 = np.minimum(a[:, None, 2], b[None, :, 2])
    y1 = np.minimum(a[:, None, 3], b[None, :, 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    area = lambda r: (r[:, 2] - r[:, 0]) * (r[:, 3] - r[:, 1])  # noqa: E731
    return inter / (area(a)[:, None] + area(b)[None, :] - inter)


def evaluate_onnx(path, data_yaml, imgsz, conf=0.25, nms_iou=0.45):
    """Runs an exported model with onnxruntime the way the Rust detector does (letterbox,
    threshold, class-aware NMS for the stock output) on the val images and compares the boxes
    with the labels in full-resolution pixels. None when onnxruntime is missing."""
    try:
        import onnxruntime as ort
    except ImportError:
        return None
    import cv2
    import numpy as np
    import yaml

    data = yaml.safe_load(Path(data_yaml).read_text())
    root = Path(data.get("path") or Path(data_yaml).parent)
    images = sorted((root / data["val"]).glob("*.png"))
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 2
    sess = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    inp = sess.get_inputs()[0].name
    n_gt = [0, 0]
    found = [0, 0]
    wrong_class = 0
    false_pos = 0
    edge_err, ious, times = [], [], []
    for im_path in images:
        bgr = cv2.imread(str(im_path))
        H, W = bgr.shape[:2]
        blob, scale, px, py = letterbox(bgr, imgsz)
        t = time.perf_counter()
        out = sess.run(None, {inp: blob})[0][0]
        times.append(time.perf_counter() - t)
        if out.shape[0] == 4 + 2:  # stock [6, N]: cx, cy, w, h, class scores
            scores = out[4:].max(0)
            cls = out[4:].argmax(0)
            keep = scores > conf
            b, scores, cls = out[:4, keep].T, scores[keep], cls[keep]
            xyxy = np.stack([b[:, 0] - b[:, 2] / 2, b[:, 1] - b[:, 3] / 2, b[:, 0] + b[:, 2] / 2, b[:, 1] + b[:, 3] / 2], 1)
            order = np.argsort(-scores)
            kept = []
            for i in order:
                if all(cls[k] != cls[i] or iou_matrix(xyxy[i:i + 1], xyxy[k:k + 1])[0, 0] <= nms_iou for k in kept):
                    kept.append(i)
            xyxy, scores, cls = xyxy[kept], scores[kept], cls[kept]
        else:  # end-to-end [300, 6]: x0, y0, x1, y1, score, class
            keep = out[:, 4] > conf
            xyxy, scores, cls = out[keep, :4], out[keep, 4], out[keep, 5].astype(int)
        pred = (xyxy - np.array([px, py, px, py])) / scale
        gt, gt_cls = [], []
        lab = root / "labels" / im_path.parent.name / (im_path.stem + ".txt")
        for line in lab.read_text().split("\n"):
            if line.strip():
                c, cx, cy, w, h = map(float, line.split())
                gt.append([(cx - w / 2) * W, (cy - h / 2) * H, (cx + w / 2) * W, (cy + h / 2) * H])
                gt_cls.append(int(c))
        gt = np.array(gt).reshape(-1, 4)
        m = iou_matrix(gt, pred)
        used = set()
        for g in np.argsort(-m.max(1) if m.size else np.zeros(len(gt))):
            n_gt[gt_cls[g]] += 1
            if m.size == 0:
                continue
            cands = [j for j in np.argsort(-m[g]) if j not in used and m[g, j] >= 0.5]
            if not cands:
                continue
            j = cands[0]
            used.add(j)
            if cls[j] != gt_cls[g]:
                wrong_class += 1
                continue
            found[gt_cls[g]] += 1
            ious.append(m[g, j])
            edge_err.extend(np.abs(pred[j] - gt[g]).tolist())
        false_pos += len(pred) - len(used)
    e = np.array(edge_err) if edge_err else np.zeros(1)
    q = lambda v, p: round(float(np.percentile(v, p)), 3)  # noqa: E731
    return {
        "images": len(images),
        "conf": conf,
        "recall_goal": f"{found[0]}/{n_gt[0]}",
        "recall_obstacle": f"{found[1]}/{n_gt[1]}",
        "wrong_class": wrong_class,
        "false_positives": false_pos,
        "edge_error_px_full_res": {"median": q(e, 50), "p95": q(e, 95), "max": q(e, 100)},
        "iou": {"p5": q(ious, 5), "median": q(ious, 50)} if ious else None,
        "ms_per_image_onnxruntime_2_threads": round(1e3 * float(np.median(times)), 2) if times else None,
    }


def main():
    args = parse_args()
    if args.evaluate_only:
        for path in args.evaluate_only:
            for data in [args.data, *args.extra_eval]:
                r = evaluate_onnx(path, data, args.imgsz)
                print(json.dumps({"model": str(path), "data": str(data), **(r or {"error": "no onnxruntime"})}))
        return
    name = args.name or f"foresight-tiny-{args.imgsz}"
    workdir = args.workdir.resolve()
    workdir.mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("YOLO_CONFIG_DIR", str(workdir / "ultralytics-config"))

    import torch
    import ultralytics
    import ultralytics.utils.torch_utils as tu
    from ultralytics import YOLO

    torch.set_num_threads(args.threads)
    # select_device() calls torch.set_num_threads(NUM_THREADS) = min(8, cpu_count - 1): 1 here.
    tu.NUM_THREADS = args.threads

    def keep_threads(_trainer):
        torch.set_num_threads(args.threads)
        print(f"train_yolo_synthetic: torch threads = {torch.get_num_threads()}", flush=True)

    model = YOLO(str(args.init or args.model), task="detect")
    model.add_callback("on_pretrain_routine_end", keep_threads)
    run_dir = workdir / name
    t0 = time.monotonic()
    model.train(
        data=str(args.data.resolve()),
        epochs=args.epochs,
        imgsz=args.imgsz,
        batch=args.batch,
        device="cpu",
        workers=0,
        seed=args.seed,
        deterministic=True,
        pretrained=False,
        amp=False,
        plots=False,
        cache=False if args.cache == "none" else args.cache,
        mosaic=args.mosaic,
        close_mosaic=args.close_mosaic,
        scale=args.scale,
        warmup_epochs=args.warmup_epochs,
        optimizer=args.optimizer,
        lr0=args.lr0,
        lrf=args.lrf,
        rect=args.rect,
        patience=args.patience,
        val=args.val_each_epoch,
        project=str(workdir),
        name=name,
        exist_ok=True,
        verbose=True,
    )
    train_s = time.monotonic() - t0
    best = run_dir / "weights" / "best.pt"
    print(f"train_yolo_synthetic: training took {train_s:.0f} s; best weights {best}", flush=True)

    # Val metrics of the weights that are exported.
    trained = YOLO(str(best))
    m = trained.val(data=str(args.data.resolve()), imgsz=args.imgsz, batch=args.batch, device="cpu",
                    workers=0, plots=False, split="val", project=str(workdir), name=f"{name}-val",
                    exist_ok=True)
    metrics = {
        "mAP50": float(m.box.map50),
        "mAP50-95": float(m.box.map),
        "precision": float(m.box.mp),
        "recall": float(m.box.mr),
        "per_class_mAP50-95": {trained.names[int(c)]: float(v) for c, v in zip(m.box.ap_class_index, m.box.maps[m.box.ap_class_index])},
    }
    print(f"train_yolo_synthetic: val {json.dumps(metrics)}", flush=True)

    exports = {}
    stock = Path(trained.export(format="onnx", imgsz=args.imgsz, opset=12, simplify=True, dynamic=False,
                                device="cpu"))
    exports["stock"] = shutil.copyfile(stock, workdir / f"{name}.onnx")
    e2e_error = None
    if not args.no_e2e:
        try:
            e2e = Path(YOLO(str(best)).export(format="onnx", imgsz=args.imgsz, opset=12, simplify=True,
                                              dynamic=False, nms=True, conf=0.25, iou=0.45, device="cpu"))
            exports["e2e"] = shutil.copyfile(e2e, workdir / f"{name}-e2e.onnx")
        except Exception as e:  # an ultralytics without `nms` export support
            e2e_error = f"{type(e).__name__}: {e}"
            print(f"train_yolo_synthetic: NMS-inside export failed: {e2e_error}", file=sys.stderr)

    import onnx

    files = {}
    for kind, path in exports.items():
        g = onnx.load(str(path))

        def shape(v):
            return [d.dim_value if d.HasField("dim_value") else d.dim_param for d in v.type.tensor_type.shape.dim]

        files[kind] = {
            "file": Path(path).name,
            "bytes": Path(path).stat().st_size,
            "opset": max(o.version for o in g.opset_import if o.domain in ("", "ai.onnx")),
            "inputs": {i.name: shape(i) for i in g.graph.input},
            "outputs": {o.name: shape(o) for o in g.graph.output},
            "names": {p.key: p.value for p in g.metadata_props}.get("names"),
            "val_onnxruntime": evaluate_onnx(path, args.data, args.imgsz),
            "extra_eval_onnxruntime": {str(d): evaluate_onnx(path, d, args.imgsz) for d in args.extra_eval},
        }
        print(f"train_yolo_synthetic: {kind} export {json.dumps(files[kind])}", flush=True)
    summary = {
        "dataset": str(args.data.resolve()),
        "model_yaml": args.model.name,
        "init": str(args.init) if args.init else None,
        "rect": args.rect,
        "lr0": args.lr0,
        "lrf": args.lrf,
        "imgsz": args.imgsz,
        "epochs": args.epochs,
        "batch": args.batch,
        "seed": args.seed,
        "mosaic": args.mosaic,
        "close_mosaic": args.close_mosaic,
        "scale": args.scale,
        "warmup_epochs": args.warmup_epochs,
        "optimizer": args.optimizer,
        "torch_threads": args.threads,
        "val_each_epoch": args.val_each_epoch,
        "train_wall_s": round(train_s, 1),
        "parameters": sum(p.numel() for p in trained.model.parameters()),
        "val": metrics,
        "exports": files,
        "e2e_error": e2e_error,
        "versions": {
            "ultralytics": ultralytics.__version__,
            "torch": torch.__version__,
            "onnx": onnx.__version__,
            "python": platform.python_version(),
        },
        "cpu": f"{os.cpu_count()} logical CPUs",
    }
    (workdir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
