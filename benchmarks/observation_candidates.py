"""Where the observation loses objects (issue 36): every candidate track of ``hybrid``'s segmenter,
what :func:`pipeline.observe.hybrid_objects` decided about it, and whether it is a true object.

For each rendered clip (``benchmarks/observation_truth.py``'s sets), the clip is observed exactly as
``dynamics infer`` observes it, and the segmenter candidate tracks of the working window are
recorded (``observe(..., candidates=...)``) with the features the decision reads (seen fraction,
travel, own flow, confidence, silhouette stability, fill, aspect, in view). A candidate *is* a true
object when its mean IoU with one, over the frames where either is visible, is at least 0.5
(the benchmark's "found").

It separates two causes of a missed object:

* **no candidate**: the segmenter never gives a track of that object (IoU >= 0.5) - a segmenter
  failure no decision rule can repair;
* **rejected**: a candidate exists and the rules drop it - a rule failure (thresholds in
  ``pipeline/observe.py``).

Usage::

    MUJOCO_GL=egl python benchmarks/observation_candidates.py --splits dev,dev2 --no-generate \\
        --report reports/observation_candidates
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np
from tqdm import tqdm

ROOT = Path(__file__).resolve().parents[1]
for p in (ROOT, ROOT / "benchmarks", ROOT / "scripts"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

from observation_truth import SETS, STILL_M, ensure_set, labelled_still, write_report  # noqa: E402
from realvideo_all import CLIPS, LABELS, REAL, _content  # noqa: E402

from provenance import tree_id  # noqa: E402
from pipeline.flow import flow_config  # noqa: E402
from pipeline.labels import labels_in_window, load_labels  # noqa: E402
from pipeline.observe import observe, scene_rate, truth_in_window  # noqa: E402
from pipeline.params import load_params  # noqa: E402
from pipeline.reconstruct import observation_segmenters, realvideo_config  # noqa: E402
from pipeline.segmenter import shipped  # noqa: E402
from pipeline.video import read_video  # noqa: E402

FOUND = 0.5
"""A candidate is a true object when its mean IoU with it reaches this (the benchmark's "found")."""
DECISIONS = ("mover", "at_rest", "slow", "rejected")
DROPS = ("hand", "part", "rigid_size", "vanishes", "size_class", "max_objects")


def best_match(mask: np.ndarray, truth: np.ndarray) -> tuple[int, float]:
    """The true object a candidate matches best.

    Args:
        mask: ``(T, H, W)`` bool candidate masks; truth: ``(T, H, W)`` int true ids, -1 none.
    Returns:
        ``(id, iou)``: the mean per-frame IoU over the frames where either is visible, and the true
        id that maximises it (``(-1, 0.0)`` when there is no true object).
    """
    best, who = 0.0, -1
    for k in range(int(truth.max()) + 1):
        t = truth == k
        union = (mask | t).sum(axis=(1, 2))
        seen = union > 0
        if seen.any():
            iou = float(((mask & t).sum(axis=(1, 2))[seen] / union[seen]).mean())
            if iou > best:
                best, who = iou, k
    return who, best


def clip_candidates(folder: Path, params: dict, segmenter) -> tuple[list[dict], list[dict]]:
    """Candidates of one rendered clip and its true objects.

    Returns:
        ``(candidates, objects)``: one dict per candidate (features, ``decision``, ``truth``,
        ``iou``) and one per true object in the window (``still``, ``best``: the best candidate IoU).
    """
    rv = realvideo_config(params)
    truth = np.load(folder / "truth.npz", allow_pickle=False)
    found: list[dict] = []
    obs = observe(folder / "video.mp4", float(truth["fps"]), None, rv.fps, rv.duration, flow_config(params),
                  rv.mask_method, rv.max_objects, segmenter, found, fine_scale=rv.fine_scale,
                  rest_segmenter=observation_segmenters(params)[1])
    seg, frames = truth_in_window(truth["seg"], obs)
    pos = truth["pos"][frames]
    still = np.linalg.norm(pos - pos[:1], axis=-1).max(axis=0) < STILL_M
    cands = matched(found, seg)
    shapes = [o["shape"] for o in json.loads((folder / "meta.json").read_text())["objects"]]
    for c in cands:
        c["shape_true"] = shapes[c["truth"]] if c["object"] else None
    ids = [k for k in range(len(still)) if (seg == k).any()]
    return cands, true_objects(cands, ids, [bool(still[k]) for k in ids])


def matched(found: list[dict], truth: np.ndarray | None, frames: np.ndarray | None = None) -> list[dict]:
    """The candidates of ``observe(..., candidates=found)`` without their masks, each with its best
    true match (:func:`best_match` on ``truth``, ``(F, H, W)`` int, against the masks' ``frames``,
    all when None; no truth: no match) and ``object`` (IoU >= :data:`FOUND`); floats rounded."""
    out = []
    for c in found:
        mask = c.pop("mask")
        who, iou = (-1, 0.0) if truth is None else best_match(mask if frames is None else mask[frames], truth)
        out.append({**{k: (round(v, 4) if isinstance(v, float) else v) for k, v in c.items()},
                    "truth": who, "iou": round(iou, 4), "object": iou >= FOUND})
    return out


def true_objects(cands: list[dict], ids: list[int], still: list[bool]) -> list[dict]:
    """One dict per true object ``ids[i]`` (``still[i]``): ``best`` candidate IoU and ``kept``
    (a kept candidate matches it)."""
    return [{"id": k, "still": s, "best": max([c["iou"] for c in cands if c["truth"] == k], default=0.0),
             "kept": any(c["kept"] and c["object"] for c in cands if c["truth"] == k)} for k, s in zip(ids, still)]


def real_candidates(video: Path, fps: float | None, labels_dir: Path, params: dict, segmenter
                    ) -> tuple[list[dict], list[dict]]:
    """Candidates of one real clip in the main job's window (``dynamics infer``'s ``observe``),
    matched on the hand-labelled frames that fall in it (none: every candidate counts as not an
    object). Returns: as :func:`clip_candidates`; still: the labelled centroid moves less than
    ``STILL_LABEL`` of the working frame's diagonal."""
    rv = realvideo_config(params)
    found: list[dict] = []
    obs = observe(video, fps, None, scene_rate(video, fps, rv.fps), rv.duration, flow_config(params),
                  rv.mask_method, rv.max_objects, segmenter, found, fine_scale=rv.fine_scale,
                  rest_segmenter=observation_segmenters(params)[1])
    ks, seg = (np.zeros(0, np.int64), None)
    if labels_dir.is_dir():
        ks, seg = labels_in_window(load_labels(labels_dir, read_video(video, fps=fps, max_frames=1).original_size), obs)
    if not len(ks):
        return matched(found, None), []
    cands = matched(found, seg, ks)
    ids = [k for k in range(int(seg.max()) + 1) if (seg == k).any()]
    return cands, true_objects(cands, ids, [labelled_still(seg, k) for k in ids])


def summarize(rows: list[dict]) -> dict:
    """Counts of one set: candidates by decision and truth, true objects by cause of loss."""
    cands = [c for r in rows for c in r["candidates"]]
    objs = [o for r in rows for o in r["objects"]]
    table = Counter((c["decision"], c["object"]) for c in cands)
    out = {"clips": len(rows), "candidates": len(cands), "objects": len(objs)}
    for d in DECISIONS:
        out[f"{d}: object"] = table[(d, True)]
        out[f"{d}: not"] = table[(d, False)]
    for kind, sel in (("moving", [o for o in objs if not o["still"]]), ("still", [o for o in objs if o["still"]])):
        out[f"{kind} objects"] = len(sel)
        out[f"{kind}: no candidate"] = sum(o["best"] < FOUND for o in sel)
        out[f"{kind}: lost later"] = sum(o["best"] >= FOUND and not o["kept"] for o in sel)
    for reason in DROPS:
        out[f"dropped ({reason}): object"] = sum(c["object"] and c.get("dropped") == reason for c in cands)
    out["kept: not"] = sum(c["kept"] and not c["object"] for c in cands)
    return out


SILHOUETTE = ("ellipse", "polygon", "fill", "elongation")


def silhouette_table(sets: dict[str, list[dict]]) -> list[str]:
    """Markdown rows: quartiles of the silhouette features (:class:`pipeline.image_tracks.Track`)
    of the kept candidates that are objects, by set and true shape; what shape the silhouette
    cue (:func:`pipeline.perception.shape_candidates`) would try first is judged from these."""
    lines = ["| set | true shape | n | " + " | ".join(f"{k} q25 / q50 / q75" for k in SILHOUETTE) + " |",
             "|---" * (3 + len(SILHOUETTE)) + "|"]
    for name, rows in sets.items():
        for shape in ("sphere", "cylinder", "box"):
            sel = [c for r in rows for c in r["candidates"]
                   if c["kept"] and c.get("shape_true") == shape and np.isfinite(c.get("ellipse", np.nan))]
            if not sel:
                continue
            q = [" / ".join(f"{v:.3f}" for v in np.percentile([c[k] for c in sel], [25, 50, 75])) for k in SILHOUETTE]
            lines.append(f"| {name} | {shape} | {len(sel)} | " + " | ".join(q) + " |")
    return lines


def markdown(report: dict) -> str:
    cols = ["clips", "objects", "moving objects", "moving: no candidate", "moving: lost later", "still objects",
            "still: no candidate", "still: lost later", "candidates"] \
        + [f"{d}: {w}" for d in DECISIONS for w in ("object", "not")] + [f"dropped ({r}): object" for r in DROPS] + ["kept: not"]
    lines = ["# Where the observation loses objects: segmenter candidates (issue 36)", "",
             f"Command: `{report['command']}` (tree `{report['commit']}`).", "",
             "A candidate is one segmenter track of `hybrid` (seen in 15 % of the window's frames) before parts, "
             "rigid size, size class and `max_objects` are applied; it *is* an object when its mean IoU with a true "
             f"object reaches {FOUND}. *No candidate*: true objects that no candidate matches at {FOUND} (the "
             "segmenter's loss, no rule can repair it). Decisions (`pipeline.observe.hybrid_objects`): mover, "
             "at rest, slow object, rejected; *rejected: object* counts the rules' losses. *Lost later*: true objects "
             "with a matching candidate that is not inside any returned object (rejected, or dropped afterwards as a "
             "hand, a part, for its size or by `max_objects`); *dropped (filter): object*: matching candidates the rules "
             "accepted and that filter dropped (`hands`, `attached_parts`, `rigid_size`, `vanishes`, the size class of "
             "the movers, `max_objects`); *kept: not*: returned candidates that match no true object. "
             "True objects outside the working crop are not counted here (`observation_truth` counts them as missed).", "",
             "| set | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for name, s in report["summary"].items():
        lines.append(f"| {name} | " + " | ".join(str(s[c]) for c in cols) + " |")
    lines += ["", "## Silhouettes of the kept objects by true shape", "",
              "`ellipse`, `polygon`: IoU of the silhouette with its least-squares ellipse and with its convex polygon "
              "of few corners (`pipeline.image_tracks.silhouette_fit`, upper quartile over the track's whole frames); `fill`: "
              "area over the rotated box; `elongation`: lower quartile of the box's long / short side. True shapes: "
              "`meta.json` (rendered), `tests/fixtures/realvideo/content.yaml` (real).", ""]
    lines += silhouette_table(report["sets"])
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sets", type=Path, default=ROOT / "data/truthsets", help="rendered sets' root")
    ap.add_argument("--only", default="mujoco,pybullet", help="comma list of mujoco, pybullet, real (the 19 "
                    "labelled real clips in the main job's window; matched on the labelled frames in it)")
    ap.add_argument("--splits", default="dev,dev2", help="comma list of rendered splits (dev, dev2, heldout)")
    ap.add_argument("--no-generate", action="store_true", help="use the clips that are there")
    ap.add_argument("--limit", type=int, default=None, help="first N clips per set (quick looks)")
    ap.add_argument("--params", default=None, help="params.yaml (default ./params.yaml)")
    ap.add_argument("--report", type=Path, default=ROOT / "reports/observation_candidates", help="report path stem")
    ap.add_argument("--fine-scale", action=argparse.BooleanOptionalAction, default=None,
                    help="realvideo.fine_scale: fuse the detection pass's segmenter probabilities into the working "
                         "pass's where finer (default: the params' value)")
    ap.add_argument("--segmenter-weights", type=Path, default=None,
                    help="segmenter checkpoint (default: the shipped pipeline/weights/segmenter.pt)")
    args = ap.parse_args(argv)
    params = load_params(args.params)
    if args.fine_scale is not None:
        params.setdefault("realvideo", {})["fine_scale"] = args.fine_scale
    params.setdefault("realvideo", {})["mask_method"] = "hybrid"
    segmenter = shipped(args.segmenter_weights)
    sets: dict[str, list[dict]] = {}
    for (engine, split) in SETS:
        if engine not in args.only.split(",") or split not in args.splits.split(","):
            continue
        folder = ensure_set(args.sets, engine, split, not args.no_generate)
        if not folder.is_dir():
            continue
        rows = []
        for c in tqdm(sorted(p for p in folder.iterdir() if (p / "truth.npz").exists())[: args.limit],
                      desc=f"{engine}/{split}"):
            cands, objs = clip_candidates(c, params, segmenter)
            rows.append({"clip": c.name, "candidates": cands, "objects": objs})
        sets[f"{engine} {split}"] = rows
    if "real" in args.only.split(","):
        rows = []
        for name, rel, fps in tqdm(CLIPS, desc="real"):
            cands, objs = real_candidates(REAL / rel, fps, LABELS / name.split("_")[0], params, segmenter)
            shapes = set(_content().get(name, {}).get("objects", []))
            for c in cands:   # every object of a real clip has one shape (content.yaml)
                c["shape_true"] = next(iter(shapes)) if c["object"] and len(shapes) == 1 else None
            rows.append({"clip": name, "candidates": cands, "objects": objs})
        sets["real (19, main job's window)"] = rows
    commit = tree_id()
    report = {"command": "python benchmarks/observation_candidates.py " + " ".join(argv if argv is not None else sys.argv[1:]),
              "commit": commit, "summary": {k: summarize(v) for k, v in sets.items()}, "sets": sets}
    write_report(args.report, report, markdown(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
