//! From a YOLO output tensor to boxes in the original image's pixels: which of the two
//! output layouts a model has, the letterbox geometry, the two decoders, and class-aware NMS.
//!
//! - **Anchors** `[1, 4 + C, N]` (stock YOLOv8 / YOLO11 exports): per anchor `cx, cy, w, h`
//!   in network pixels and one score per class; our code keeps the best class, thresholds and
//!   runs class-aware NMS.
//! - **End-to-end** `[1, N, 6]` (NMS-free exports: YOLOv10, YOLO26, `export(nms=True)`): per
//!   row `x0, y0, x1, y1, score, class`; the model already suppressed duplicates, so only the
//!   threshold applies.

/// A decoded box in original image pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RawBox {
    /// Model class index.
    pub class: usize,
    /// Class score.
    pub score: f32,
    /// `[x0, y0, x1, y1]` (px).
    pub xyxy: [f32; 4],
}

/// Letterbox geometry: `network = original · scale + pad`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Letterbox {
    /// Scale factor.
    pub scale: f32,
    /// Horizontal padding (px).
    pub pad_x: f32,
    /// Vertical padding (px).
    pub pad_y: f32,
}

impl Letterbox {
    /// The letterbox of a `w × h` image into a `size × size` input (centred, as ultralytics).
    pub fn new(w: i32, h: i32, size: i32) -> Self {
        let scale = (size as f32 / w as f32).min(size as f32 / h as f32);
        let nw = (w as f32 * scale).round();
        let nh = (h as f32 * scale).round();
        Self {
            scale,
            pad_x: ((size as f32 - nw) / 2.0).floor(),
            pad_y: ((size as f32 - nh) / 2.0).floor(),
        }
    }

    /// A network-pixel box `[x0, y0, x1, y1]` in original pixels.
    pub fn to_original(&self, xyxy: [f32; 4]) -> [f32; 4] {
        [
            (xyxy[0] - self.pad_x) / self.scale,
            (xyxy[1] - self.pad_y) / self.scale,
            (xyxy[2] - self.pad_x) / self.scale,
            (xyxy[3] - self.pad_y) / self.scale,
        ]
    }
}

/// How a model's output is laid out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutputLayout {
    /// `[1, 4 + classes, anchors]`, channels-major: boxes and per-class scores, NMS by us.
    Anchors {
        /// `4 + classes`.
        channels: usize,
        /// Number of anchors.
        anchors: usize,
    },
    /// `[1, rows, 6]`: `x0, y0, x1, y1, score, class` per row, NMS done by the model.
    EndToEnd {
        /// Number of rows (the model's maximum detections).
        rows: usize,
    },
}

impl OutputLayout {
    /// Identifies the layout of an output of shape `dims` for a model of `classes` classes.
    /// `end_to_end` is the model's own statement (Ultralytics' `end2end` / `nms` metadata)
    /// when it makes one; it decides the one ambiguous case (`[1, 6, 6]` with 2 classes).
    ///
    /// # Errors
    /// A message naming the shape when it fits neither layout.
    pub fn identify(
        dims: &[i64],
        classes: usize,
        end_to_end: Option<bool>,
    ) -> Result<Self, String> {
        let [1, a, b] = *dims else {
            return Err(format!(
                "the output has shape {dims:?}; expected [1, 4 + classes, N] (YOLOv8/YOLO11) or [1, N, 6] (end-to-end, NMS-free)"
            ));
        };
        let anchors = a == 4 + classes as i64 && b > 0;
        let e2e = b == 6 && a > 0;
        match (anchors, e2e, end_to_end) {
            (true, true, Some(true)) | (false, true, _) => Ok(Self::EndToEnd { rows: a as usize }),
            (true, _, _) => Ok(Self::Anchors {
                channels: a as usize,
                anchors: b as usize,
            }),
            (false, false, _) => Err(format!(
                "the output has shape {dims:?}; with {classes} classes expected [1, {}, N] (YOLOv8/YOLO11) or [1, N, 6] (end-to-end, NMS-free)",
                4 + classes
            )),
        }
    }

    /// Number of floats the output holds.
    pub fn len(&self) -> usize {
        match *self {
            Self::Anchors { channels, anchors } => channels * anchors,
            Self::EndToEnd { rows } => rows * 6,
        }
    }

    /// Whether the output holds nothing.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Decodes a `[1, 4 + C, N]` output (row-major `channels × n`): best class per anchor,
/// threshold, optional per-anchor box scale (see [`crate::onnx_patch`]), back to original
/// pixels through the letterbox.
pub fn decode(
    output: &[f32],
    channels: usize,
    n: usize,
    threshold: f32,
    box_scale: Option<&[f32]>,
    lb: Letterbox,
) -> Vec<RawBox> {
    let mut out = Vec::new();
    if channels <= 4 || output.len() < channels * n {
        return out;
    }
    for a in 0..n {
        let (mut best, mut score) = (0, f32::NEG_INFINITY);
        for c in 0..channels - 4 {
            let s = output[(4 + c) * n + a];
            if s > score {
                score = s;
                best = c;
            }
        }
        if score.is_nan() || score < threshold {
            continue;
        }
        let k = box_scale.and_then(|s| s.get(a).copied()).unwrap_or(1.0);
        let cx = output[a] * k;
        let cy = output[n + a] * k;
        let w = output[2 * n + a] * k;
        let h = output[3 * n + a] * k;
        let xyxy = lb.to_original([cx - w / 2.0, cy - h / 2.0, cx + w / 2.0, cy + h / 2.0]);
        if xyxy.iter().all(|v| v.is_finite()) {
            out.push(RawBox {
                class: best,
                score,
                xyxy,
            });
        }
    }
    out
}

/// Decodes an end-to-end `[1, rows, 6]` output (`x0, y0, x1, y1, score, class` in network
/// pixels): threshold, back to original pixels. Rows with a class index outside
/// `0..classes` or non-finite values are skipped (a padded row of an NMS-free export has
/// score 0 and never passes a positive threshold).
pub fn decode_end_to_end(
    output: &[f32],
    rows: usize,
    classes: usize,
    threshold: f32,
    lb: Letterbox,
) -> Vec<RawBox> {
    let mut out = Vec::new();
    for r in output.chunks_exact(6).take(rows) {
        let score = r[4];
        if !score.is_finite() || score < threshold || !r.iter().all(|v| v.is_finite()) {
            continue;
        }
        let class = r[5].round();
        if class < 0.0 || class as usize >= classes || (r[5] - class).abs() > 1e-3 {
            continue;
        }
        out.push(RawBox {
            class: class as usize,
            score,
            xyxy: lb.to_original([r[0], r[1], r[2], r[3]]),
        });
    }
    out
}

/// Intersection over union of two `xyxy` boxes.
pub fn iou(a: &[f32; 4], b: &[f32; 4]) -> f32 {
    let iw = (a[2].min(b[2]) - a[0].max(b[0])).max(0.0);
    let ih = (a[3].min(b[3]) - a[1].max(b[1])).max(0.0);
    let inter = iw * ih;
    let area = |r: &[f32; 4]| (r[2] - r[0]).max(0.0) * (r[3] - r[1]).max(0.0);
    let union = area(a) + area(b) - inter;
    if union <= 0.0 { 0.0 } else { inter / union }
}

/// Class-aware non-maximum suppression: highest score first; a box is dropped when it
/// overlaps an already kept box *of the same class* by more than `iou_threshold`.
pub fn nms(mut boxes: Vec<RawBox>, iou_threshold: f32) -> Vec<RawBox> {
    boxes.sort_by(|a, b| b.score.total_cmp(&a.score));
    let mut kept: Vec<RawBox> = Vec::new();
    for b in boxes {
        if kept
            .iter()
            .all(|k| k.class != b.class || iou(&k.xyxy, &b.xyxy) <= iou_threshold)
        {
            kept.push(b);
        }
    }
    kept
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn letterbox_of_720p_into_640_and_320() {
        let lb = Letterbox::new(1280, 720, 640);
        assert_eq!((lb.scale, lb.pad_x, lb.pad_y), (0.5, 0.0, 140.0));
        let lb = Letterbox::new(1280, 720, 320);
        assert_eq!((lb.scale, lb.pad_x, lb.pad_y), (0.25, 0.0, 70.0));
        assert_eq!(
            lb.to_original([10.0, 80.0, 20.0, 90.0]),
            [40.0, 40.0, 80.0, 80.0]
        );
    }

    #[test]
    fn decode_thresholds_scales_and_unletterboxes() {
        // 2 classes, 3 anchors; channels-major.
        let n = 3;
        let mut out = vec![0.0f32; 6 * n];
        let set = |out: &mut Vec<f32>, a: usize, b: [f32; 4], s: [f32; 2]| {
            for (c, v) in b.iter().chain(s.iter()).enumerate() {
                out[c * n + a] = *v;
            }
        };
        set(&mut out, 0, [10.0, 20.0, 4.0, 2.0], [0.9, 0.1]);
        set(&mut out, 1, [50.0, 50.0, 10.0, 10.0], [0.1, 0.2]);
        set(&mut out, 2, [30.0, 40.0, 2.0, 2.0], [0.3, 0.6]);
        let lb = Letterbox {
            scale: 0.5,
            pad_x: 0.0,
            pad_y: 140.0,
        };
        let boxes = decode(&out, 6, n, 0.25, Some(&[8.0, 8.0, 16.0]), lb);
        assert_eq!(boxes.len(), 2);
        assert_eq!(boxes[0].class, 0);
        // anchor 0: cx 80, cy 160, w 32, h 16 in network px → original: x (64..96)/0.5, y (152-140..168-140)/0.5
        assert_eq!(boxes[0].xyxy, [128.0, 24.0, 192.0, 56.0]);
        assert_eq!(boxes[1].class, 1);
        assert_eq!(boxes[1].score, 0.6);
        assert_eq!(boxes[1].xyxy, [928.0, 968.0, 992.0, 1032.0]);
    }

    #[test]
    fn end_to_end_rows_threshold_and_unletterbox_without_nms() {
        let lb = Letterbox::new(1280, 720, 320); // scale 0.25, pad_y 70
        #[rustfmt::skip]
        let out = [
            10.0, 80.0, 20.0, 90.0, 0.9, 1.0,   // kept: obstacle
            11.0, 81.0, 21.0, 91.0, 0.8, 1.0,   // overlapping, same class: kept (no NMS)
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0,       // padding row
            5.0, 5.0, 9.0, 9.0, 0.95, 7.0,      // class out of range: skipped
            5.0, 5.0, 9.0, f32::NAN, 0.95, 0.0, // non-finite: skipped
            100.0, 170.0, 110.0, 180.0, 0.3, 0.0, // goal
        ];
        let b = decode_end_to_end(&out, 6, 2, 0.25, lb);
        assert_eq!(b.len(), 3, "{b:?}");
        assert_eq!(b[0].class, 1);
        assert_eq!(b[0].xyxy, [40.0, 40.0, 80.0, 80.0]);
        assert_eq!(b[2].class, 0);
        assert_eq!(b[2].xyxy, [400.0, 400.0, 440.0, 440.0]);
        // Fewer rows than the slice holds: only `rows` are read.
        assert_eq!(decode_end_to_end(&out, 1, 2, 0.25, lb).len(), 1);
    }

    #[test]
    fn layouts_are_told_apart_by_shape_and_class_count() {
        assert_eq!(
            OutputLayout::identify(&[1, 6, 8400], 2, None),
            Ok(OutputLayout::Anchors {
                channels: 6,
                anchors: 8400
            })
        );
        assert_eq!(
            OutputLayout::identify(&[1, 300, 6], 2, None),
            Ok(OutputLayout::EndToEnd { rows: 300 })
        );
        assert_eq!(
            OutputLayout::identify(&[1, 84, 8400], 80, Some(false)),
            Ok(OutputLayout::Anchors {
                channels: 84,
                anchors: 8400
            })
        );
        // The one ambiguous shape follows the model's own statement.
        assert_eq!(
            OutputLayout::identify(&[1, 6, 6], 2, Some(true)),
            Ok(OutputLayout::EndToEnd { rows: 6 })
        );
        assert!(matches!(
            OutputLayout::identify(&[1, 6, 6], 2, None),
            Ok(OutputLayout::Anchors { .. })
        ));
        let e = OutputLayout::identify(&[1, 7, 8400], 2, None).unwrap_err();
        assert!(e.contains("[1, 6, N]") && e.contains("[1, 7, 8400]"), "{e}");
        assert!(OutputLayout::identify(&[6, 8400], 2, None).is_err());
        assert!(OutputLayout::identify(&[2, 6, 8400], 2, None).is_err());
    }

    #[test]
    fn nms_is_class_aware() {
        let b = |class, score, x: f32| RawBox {
            class,
            score,
            xyxy: [x, 0.0, x + 10.0, 10.0],
        };
        let kept = nms(
            vec![
                b(0, 0.5, 1.0),
                b(0, 0.9, 0.0),
                b(1, 0.8, 0.0),
                b(0, 0.7, 50.0),
            ],
            0.45,
        );
        assert_eq!(kept.len(), 3);
        assert_eq!(kept[0].score, 0.9);
        assert!(kept.iter().any(|k| k.class == 1));
        assert!(
            !kept.iter().any(|k| k.score == 0.5),
            "overlapping same-class box survived"
        );
        assert!((iou(&[0.0, 0.0, 10.0, 10.0], &[5.0, 0.0, 15.0, 10.0]) - 1.0 / 3.0).abs() < 1e-6);
    }
}
