"""IoU of the pseudo ground-truth masks against the hand labels of the real clips.

For each clip of ``tests/fixtures/realvideo/labels.yaml``: pseudo masks of the labelled
source frames (:func:`pipeline.masks.pseudo_ground_truth`, background fitted over the whole
clip, ``max_objects`` = number of labelled objects) against the label PNGs. Two scores per
frame, averaged per clip: foreground IoU (any object vs background) and per-object IoU
after Hungarian matching of pseudo objects to labelled ones (an unmatched labelled object
scores 0). Writes ``reports/realvideo/pseudo_mask_iou.json``.

Usage: ``python scripts/pseudo_mask_report.py [--out PATH]``
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from label_masks import FIXTURES, load_spec, real_video_dir  # noqa: E402

from pipeline.atomic import write_json  # noqa: E402
from pipeline.masks import pseudo_ground_truth  # noqa: E402


def frame_scores(pred: np.ndarray, label: np.ndarray) -> tuple[float, float]:
    """(foreground IoU, mean per-object IoU after Hungarian matching) of one frame.

    ``pred``: int ids, -1 background; ``label``: uint8, 0 background, 1..n objects. A frame
    where label and prediction are both empty is no evidence of a good mask: both scores are
    NaN there (no free credit, docs/design.md §7) and the clip means skip it; a prediction on an empty
    label scores 0.
    """
    a, b = pred >= 0, label > 0
    union = np.count_nonzero(a | b)
    if not union:
        return math.nan, math.nan
    fg = np.count_nonzero(a & b) / union
    objs = [k for k in range(1, int(label.max()) + 1) if (label == k).any()]
    ids = [k for k in range(int(pred.max()) + 1) if (pred == k).any()]
    if not objs:
        return fg, 0.0
    iou = np.zeros((len(objs), len(ids)))
    for i, o in enumerate(objs):
        for j, k in enumerate(ids):
            lo, pk = label == o, pred == k
            iou[i, j] = np.count_nonzero(lo & pk) / np.count_nonzero(lo | pk)
    best = np.zeros(len(objs))
    if ids:
        r, c = linear_sum_assignment(-iou)
        best[r] = iou[r, c]
    return fg, float(best.mean())


def clip_scores(clip: str, spec: dict, video_dir: Path | None = None,
                fixtures: Path = FIXTURES) -> dict:
    """Per-frame and mean IoUs of one clip's pseudo masks against its labels."""
    video_dir = video_dir or real_video_dir()
    idx = sorted(int(i) for i in spec["frames"])
    labels = np.stack([cv2.imread(str(fixtures / clip / f"{i:04d}.png"), cv2.IMREAD_UNCHANGED)
                       for i in idx])
    size = (labels.shape[2], labels.shape[1])
    seg = pseudo_ground_truth(video_dir / spec["file"], spec.get("fps"), idx, size,
                              max_objects=len(spec["objects"]))
    scores = np.asarray([frame_scores(p, lab) for p, lab in zip(seg, labels)], dtype=np.float64)   # (F, 2)
    fg, obj = scores[:, 0], scores[:, 1]
    return {"frames": idx, "size": list(size), "objects": spec["objects"],
            "foreground_iou": [None if np.isnan(v) else round(float(v), 4) for v in fg],
            "object_iou": [None if np.isnan(v) else round(float(v), 4) for v in obj],
            "mean_foreground_iou": round(float(np.nanmean(fg)), 4) if not np.isnan(fg).all() else None,
            "mean_object_iou": round(float(np.nanmean(obj)), 4) if not np.isnan(obj).all() else None}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "reports/realvideo/pseudo_mask_iou.json")
    args = ap.parse_args(argv)
    specs = load_spec()
    report = {"what": "pseudo masks (pipeline.masks.pseudo_ground_truth) vs hand labels "
                      "(tests/fixtures/realvideo)", "clips": {}}
    for clip in sorted(specs):
        report["clips"][clip] = clip_scores(clip, specs[clip])
        r = report["clips"][clip]
        print(f"{clip}: foreground IoU {r['mean_foreground_iou']:.3f}, "
              f"object IoU {r['mean_object_iou']:.3f}", flush=True)
    write_json(args.out, report, indent=1)


if __name__ == "__main__":
    main()
