"""How much of each true object the segmenter marks (issue 36): per-object foreground recall of the
object segmenter on the rendered truth sets, moving and still objects apart.

For each clip of ``benchmarks/observation_truth.py``'s rendered sets, the whole clip is read at
``--size`` (160x120 by default, the working size of most rendered clips), the segmenter
(:mod:`pipeline.segmenter`) is run on ``--frames`` frames spread over it against the clip's median
background, and for each true object and frame where it covers at least 4 px the fraction of its
pixels marked foreground (probability > :data:`pipeline.observe.FG_THRESHOLD`) is taken; an object's
recall is the mean over those frames. *Still*: the object moves less than
:data:`observation_truth.STILL_M` over the whole clip. This isolates the segmenter from every later
rule: an object the segmenter does not mark cannot be found by ``hybrid``.

Usage::

    python benchmarks/segmenter_recall.py --splits dev,dev2 --report reports/segmenter_recall
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

ROOT = Path(__file__).resolve().parents[1]
for p in (ROOT, ROOT / "benchmarks"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

from observation_truth import SETS, STILL_M, write_report  # noqa: E402

from provenance import tree_id  # noqa: E402
from pipeline.observe import FG_THRESHOLD  # noqa: E402
from pipeline.observe import fused_foreground  # noqa: E402
from pipeline.segmenter import median_background, shipped  # noqa: E402
from pipeline.video import read_video  # noqa: E402


def clip_recall(folder: Path, segmenter, size: tuple[int, int], n_frames: int,
                fine_size: tuple[int, int] | None = None) -> list[dict]:
    """One row per true object of a rendered clip: ``recall`` (mean fraction of its true pixels
    the segmenter marks, over the sampled frames where it covers >= 4 px at ``size``), ``area``
    (median px at ``size``), ``still``, ``shape``, ``pitch_deg``, ``low_contrast``. With
    ``fine_size``, the segmenter also runs on the clip read at that size and its probabilities,
    area-averaged to ``size``, are fused as the observation fuses the detection pass's
    (:func:`pipeline.observe.fused_foreground`: the maximum, except on cast-shadow pixels)."""
    truth = np.load(folder / "truth.npz", allow_pickle=False)
    meta = json.loads((folder / "meta.json").read_text()) if (folder / "meta.json").exists() else {}
    seg = truth["seg"]                                                   # (T, H, W) int8
    frames = read_video(folder / "video.mp4", size=size).frames[: len(seg)]
    idx = np.unique(np.linspace(0, len(frames) - 1, n_frames).round().astype(int))
    fg, _ = segmenter(frames[idx], median_background(frames))
    if fine_size is not None:
        fine = read_video(folder / "video.mp4", size=fine_size).frames[: len(seg)]
        p, _ = segmenter(fine[idx], median_background(fine))
        fg = fused_foreground(fg, np.stack([cv2.resize(q, size, interpolation=cv2.INTER_AREA) for q in p]),
                              frames[idx], median_background(frames))
    pos = truth["pos"]                                                    # (T, n, 3) m
    still = np.linalg.norm(pos - pos[:1], axis=-1).max(axis=0) < STILL_M
    objects = meta.get("objects", [{}] * pos.shape[1])
    # labels + 1 (0 background) at ``size``, once per sampled frame; uint8 holds ids up to 254
    labels = np.stack([cv2.resize((seg[t].astype(np.int16) + 1).astype(np.uint8), size,
                                  interpolation=cv2.INTER_NEAREST) for t in idx])       # (F, h, w)
    rows = []
    for k in range(pos.shape[1]):
        rec, area = [], []
        for j in range(len(idx)):
            m = labels[j] == k + 1
            if m.sum() >= 4:
                rec.append(float((fg[j][m] > FG_THRESHOLD).mean()))
                area.append(int(m.sum()))
        if rec:
            rows.append({"clip": folder.name, "object": k, "still": bool(still[k]), "recall": float(np.mean(rec)),
                         "area": float(np.median(area)), "shape": objects[k].get("shape"),
                         "low_contrast": objects[k].get("low_contrast"),
                         "pitch_deg": meta.get("camera", {}).get("pitch_deg")})
    return rows


def markdown(report: dict) -> str:
    """The report as a markdown table per set, then the still objects the segmenter misses."""
    lines = ["# Segmenter recall of true objects (issue 36)", "",
             f"Command: `{report['command']}` (tree `{report['commit']}`). Size {report['size'][0]}x{report['size'][1]}"
             + (f", fused with the clip segmented at {report['fine_size'][0]}x{report['fine_size'][1]} (per-pixel maximum, not on cast shadows)"
                if report.get("fine_size") else "") + ".", "",
             "Recall: per true object, the mean fraction of its true pixels the segmenter marks, over the sampled "
             "frames where it covers at least 4 px. Missed: recall below 0.5.", "",
             "| set | objects moving / still | recall moving | recall still | missed moving | missed still |",
             "|---|---|---|---|---|---|"]
    for name, rows in report["sets"].items():
        mov = [r["recall"] for r in rows if not r["still"]]
        st = [r["recall"] for r in rows if r["still"]]
        mean = lambda x: f"{np.mean(x):.3f}" if x else "-"  # noqa: E731
        lines.append(f"| {name} | {len(mov)} / {len(st)} | {mean(mov)} | {mean(st)} | "
                     f"{sum(x < 0.5 for x in mov)} | {sum(x < 0.5 for x in st)} |")
    lines += ["", "## Still objects with recall below 0.5", "",
              "| set | clip | object | shape | recall | area px | pitch deg |", "|---|---|---|---|---|---|---|"]
    for name, rows in report["sets"].items():
        for r in rows:
            if r["still"] and r["recall"] < 0.5:
                pitch = f"{r['pitch_deg']:.0f}" if r["pitch_deg"] is not None else "-"
                lines.append(f"| {name} | {r['clip']} | {r['object']} | {r['shape']} | {r['recall']:.3f} | "
                             f"{r['area']:.0f} | {pitch} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sets", type=Path, default=ROOT / "data/truthsets", help="rendered sets' root (made by observation_truth.py)")
    ap.add_argument("--only", default="mujoco,pybullet", help="comma list of mujoco, pybullet")
    ap.add_argument("--splits", default="dev,dev2", help="comma list of rendered splits (dev, dev2, heldout)")
    ap.add_argument("--size", default="160x120", help="WxH px the clips are read at")
    ap.add_argument("--frames", type=int, default=12, help="frames sampled per clip")
    ap.add_argument("--fine-size", default=None,
                    help="WxH px: also segment the clip read at this size and fuse by the maximum "
                         "(as realvideo.fine_scale fuses the detection pass, e.g. 320x240)")
    ap.add_argument("--segmenter-weights", type=Path, default=None, help="checkpoint (default: the shipped weights)")
    ap.add_argument("--report", type=Path, default=ROOT / "reports/segmenter_recall", help="report path stem")
    args = ap.parse_args(argv)
    size = tuple(int(v) for v in args.size.lower().split("x"))
    fine_size = tuple(int(v) for v in args.fine_size.lower().split("x")) if args.fine_size else None
    segmenter = shipped(args.segmenter_weights)
    sets: dict[str, list[dict]] = {}
    for (engine, split) in SETS:
        folder = args.sets / engine / split
        if engine not in args.only.split(",") or split not in args.splits.split(","):
            continue
        if not folder.is_dir():
            print(f"{folder}: missing, skipped (python benchmarks/observation_truth.py --splits {split} makes it)")
            continue
        clips = sorted(p for p in folder.iterdir() if (p / "truth.npz").exists())
        sets[f"{engine} {split}"] = [r for c in tqdm(clips, desc=f"{engine}/{split}")
                                     for r in clip_recall(c, segmenter, size, args.frames, fine_size)]
    commit = tree_id()
    report = {"command": "python benchmarks/segmenter_recall.py " + " ".join(argv if argv is not None else sys.argv[1:]),
              "commit": commit, "size": list(size),
              "fine_size": list(fine_size) if fine_size else None, "frames": args.frames, "sets": sets}
    write_report(args.report, report, markdown(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
