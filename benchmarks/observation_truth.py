"""The observation measured against the truth (issue 36): the masks the search fits, split into
objects, scored against true instance masks before anything is fitted to them.

Three kinds of truth:

* **MuJoCo renders** (``pipeline.truthsets``, randomised floor textures, colours, light and camera
  pitch 0-90 deg) with the renderer's instance masks;
* **PyBullet scenes** (``pipeline.truthsets``, simulated and rendered by another engine, TinyRenderer
  masks);
* **hand-labelled real frames** (``tests/fixtures/realvideo``: the six shared clips and the thirteen
  of ``shared/data/real/dev``).

Each rendered set has a development split (seed 0) and a **held-out** split (seed 1) that is
reported apart: nothing was tuned on it. A second development split (``dev2``, seed 2, only with
``--splits dev2``) is fresh data for checking a rule chosen after ``dev`` has been looked at.

Rendered clips are observed exactly as ``dynamics infer`` observes a video
(:func:`pipeline.observe.observe` with the ``realvideo`` params: window, crop, working size, masks,
tracks); the true masks of the window's source frames are cut to the same crop and resized
(nearest) to the working size. Real clips are scored on their labelled frames with
:func:`pipeline.observe.observe_frames` (the same masks and tracks over the whole clip at the
labels' size).

Metrics (:func:`pipeline.metrics.observation_scores`): matched per-object mask IoU over the frames
where either the object or its match is visible (an unmatched true object scores 0, and so does one
that the working crop cuts out), object count right, identity switches, moving and still objects apart (still: the true object moves < 5 mm in
the window; on real labels < 2 % of the frame diagonal over the labelled frames).

Usage::

    MUJOCO_GL=egl python benchmarks/observation_truth.py --mask-method hybrid,segmenter,median
                                                                    # generates missing sets first
    MUJOCO_GL=egl python benchmarks/observation_truth.py --only real --report /tmp/obs
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

ROOT = Path(__file__).resolve().parents[1]
for p in (ROOT, ROOT / "benchmarks", ROOT / "scripts"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

from provenance import tree_id  # noqa: E402
from pipeline.atomic import write_json, write_text  # noqa: E402
from pipeline.flow import flow_config  # noqa: E402
from pipeline.metrics import observation_scores  # noqa: E402
from pipeline.observe import observe, truth_in_window, without_scenery  # noqa: E402
from pipeline.params import load_params  # noqa: E402
from pipeline.reconstruct import observation_segmenters, realvideo_config  # noqa: E402
from pipeline.segmenter import shipped  # noqa: E402

SETS = {("mujoco", "dev"): (0, 24), ("mujoco", "heldout"): (1, 12),
        ("pybullet", "dev"): (0, 24), ("pybullet", "heldout"): (1, 12),
        ("mujoco", "dev2"): (2, 24), ("pybullet", "dev2"): (2, 24)}
"""(engine, split) -> (seed, clips) of the rendered sets."""

STILL_M = 0.005
"""m, a true object that moves less than this in the window is *still*."""
STILL_LABEL = 0.02
"""fraction of the frame diagonal: a labelled object whose centroid moves less is *still*."""


def ensure_set(root: Path, engine: str, split: str, generate: bool = True) -> Path:
    """The folder of one rendered set, generated (``python -m pipeline.truthsets``) if missing."""
    seed, n = SETS[(engine, split)]
    out = root / engine / split
    if not generate:
        return out
    subprocess.run([sys.executable, "-m", "pipeline.truthsets", "generate", "--engine", engine, "--n", str(n),
                    "--seed", str(seed), "--out", str(out)], check=True, cwd=ROOT)
    return out


def rendered_clip(folder: Path, params: dict, segmenter=None) -> dict:
    """Observe one rendered clip as ``dynamics infer`` does (``segmenter``: that of the learned
    mask methods, None: the shipped one) and score it against its truth."""
    rv = realvideo_config(params)
    fcfg = flow_config(params)
    truth = np.load(folder / "truth.npz", allow_pickle=False)
    t0 = time.perf_counter()
    obs = observe(folder / "video.mp4", float(truth["fps"]), None, rv.fps, rv.duration, fcfg,
                  rv.mask_method, rv.max_objects, segmenter, fine_scale=rv.fine_scale,
                  rest_segmenter=observation_segmenters(params)[1])
    if rv.scenery == "drop":   # as the main job does with realvideo.scenery: drop
        obs = without_scenery(obs)[0]
    seconds = time.perf_counter() - t0
    seg, frames = truth_in_window(truth["seg"], obs)
    pos = truth["pos"][frames]                                              # (T, n, 3) m
    still = np.linalg.norm(pos - pos[:1], axis=-1).max(axis=0) < STILL_M     # (n,)
    s = observation_scores(seg, obs.seg, still)
    # an object the working crop cuts out is missed, not absent: it counts 0
    whole = truth["seg"][frames]
    for k in range(len(still)):
        if (whole == k).any() and not (seg == k).any():
            s["per_object"].append({"true": k, "pred": None, "iou": 0.0, "frames": 0, "still": bool(still[k]),
                                    "outside_crop": True})
    objs = s["per_object"]
    s["n_true"] = len(objs)
    s["count_right"] = s["n_true"] == s["n_pred"]
    s["matched_iou"] = float(np.mean([o["iou"] for o in objs])) if objs else math.nan
    for key, sel in (("moving_iou", [o for o in objs if not o["still"]]), ("still_iou", [o for o in objs if o["still"]])):
        s[key] = float(np.mean([o["iou"] for o in sel])) if sel else math.nan
    st = [o for o in objs if o["still"]]
    s["still_found"] = float(np.mean([o["iou"] >= 0.5 for o in st])) if st else math.nan
    meta = json.loads((folder / "meta.json").read_text()) if (folder / "meta.json").exists() else {}
    return {"clip": folder.name, "seconds": round(seconds, 2), "tags": meta.get("tags", meta.get("categories", [])),
            **{k: v for k, v in s.items() if k != "per_object"}, "per_object": s["per_object"]}


def labelled_still(true: np.ndarray, k: int) -> bool:
    """Whether labelled object ``k`` is *still*: seen in at least two of the ``(F, H, W)`` int
    label frames, its centroid never moves more than :data:`STILL_LABEL` of their diagonal."""
    c = [np.argwhere(t == k).mean(axis=0) for t in true if (t == k).any()]
    diag = math.hypot(*true.shape[1:])
    return len(c) >= 2 and float(np.linalg.norm(np.asarray(c) - c[0], axis=1).max()) < STILL_LABEL * diag


def write_report(stem: Path, report: dict, text: str) -> None:
    """Write ``stem.json`` (the report) and ``stem.md`` (``text``) atomically and print the text."""
    stem.parent.mkdir(parents=True, exist_ok=True)
    write_json(stem.with_suffix(".json"), report, indent=1)
    write_text(stem.with_suffix(".md"), text)
    print(text)


def real_clip(name: str, spec: dict, fixtures: Path, video_dir: Path, params: dict, segmenter=None) -> dict:
    """Score the observation of one real clip on its hand-labelled frames (``segmenter``: as in
    :func:`rendered_clip`)."""
    from pipeline.observe import observe_frames
    idx = sorted(int(i) for i in spec["frames"])
    folder = fixtures / name
    labels = np.stack([cv2.imread(str(folder / f"{i:04d}.png"), cv2.IMREAD_UNCHANGED) for i in idx])
    true = labels.astype(np.int16) - 1                                        # 0 background -> -1
    size = (labels.shape[2], labels.shape[1])
    t0 = time.perf_counter()
    rv = realvideo_config(params)
    pred = observe_frames(video_dir / spec["file"], spec.get("fps"), idx, size,
                          max_objects=rv.max_objects, mask_method=rv.mask_method, segmenter=segmenter,
                          rest_segmenter=observation_segmenters(params)[1])
    seconds = time.perf_counter() - t0
    still = [labelled_still(true, k) for k in range(len(spec["objects"]))]
    s = observation_scores(true.astype(np.int8), pred, still)
    return {"clip": name, "seconds": round(seconds, 2), "frames": idx,
            **{k: v for k, v in s.items() if k != "per_object"}, "per_object": s["per_object"]}


def summarize(rows: list[dict]) -> dict:
    """Means over clips and objects of one set."""
    objs = [o for r in rows for o in r["per_object"]]
    still = [o for o in objs if o["still"]]
    moving = [o for o in objs if not o["still"]]

    def m(xs):
        return round(float(np.mean(xs)), 3) if len(xs) else None

    return {"clips": len(rows), "objects": len(objs), "matched_iou": m([o["iou"] for o in objs]),
            "clip_mean_iou": m([r["matched_iou"] for r in rows if not math.isnan(r["matched_iou"])]),
            "moving_iou": m([o["iou"] for o in moving]), "still_iou": m([o["iou"] for o in still]),
            "still_objects": len(still), "still_found": m([o["iou"] >= 0.5 for o in still]),
            "count_right": m([r["count_right"] for r in rows]),
            "id_switches": int(sum(r["id_switches"] for r in rows)),
            "seconds_per_clip": m([r["seconds"] for r in rows]),
            "clips_at_0.8": int(sum(r["matched_iou"] >= 0.8 for r in rows if not math.isnan(r["matched_iou"])))}


def markdown(report: dict) -> str:
    """The committed report's text."""
    runs = report.get("runs") or [{"command": report["command"], "commit": report["commit"], "sets": list(report["sets"])}]
    made = ["Command: " + "; ".join(f"`{r['command']}` (tree `{r['commit']}`)" + (f" for {', '.join(r['sets'])}" if len(runs) > 1 else "")
                                    for r in runs) + f" ({report['method']}).", ""]
    lines = ["# Observation against the truth (issue 36)", "", *made,
             "Matched IoU: per true object, the mean per-frame IoU with its Hungarian match over the frames where "
             "either is visible (unmatched: 0), averaged over objects. Still: moves < 5 mm in the window (rendered) or "
             "< 2 % of the diagonal over the labelled frames (real). Found: IoU >= 0.5. Count right: as many tracks "
             "as true objects visible. Time: the whole observation (window choice, crop, masks, tracks, flow) per "
             "clip on this machine.", "",
             "| set | clips | objects | matched IoU | moving IoU | still IoU | still found | count right | ID switches "
             "| clips >= 0.8 | s / clip |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, s in report["summary"].items():
        lines.append(f"| {name} | {s['clips']} | {s['objects']} | {s['matched_iou']} | {s['moving_iou']} | "
                     f"{s['still_iou']} ({s['still_objects']}) | {s['still_found']} | {s['count_right']} | "
                     f"{s['id_switches']} | {s['clips_at_0.8']} | {s['seconds_per_clip']} |")
    for name, rows in report["sets"].items():
        if "real" not in name or "(default)" not in name:
            continue
        lines += ["", f"## {name}: per clip", "", "| clip | matched IoU | objects (true/found) | still IoU |",
                  "|---|---|---|---|"]
        lines += [f"| {r['clip']} | {r['matched_iou']:.3f} | {r['n_true']}/{r['n_pred']} | "
                  f"{'' if math.isnan(r['still_iou']) else round(r['still_iou'], 3)} |" for r in rows]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sets", type=Path, default=ROOT / "data/truthsets", help="rendered sets' root (generated if missing)")
    ap.add_argument("--only", default="mujoco,pybullet,real", help="comma list of mujoco, pybullet, real")
    ap.add_argument("--mask-method", default=None,
                    help="comma list of realvideo.mask_method values to compare (median, mog2, segmenter, hybrid); "
                         "default: the params' one")
    ap.add_argument("--splits", default="dev,heldout",
                    help="comma list of rendered splits (dev: look and choose; heldout: report, never choose on; "
                         "dev2: a second development split)")
    ap.add_argument("--no-generate", action="store_true", help="use the clips that are there")
    ap.add_argument("--limit", type=int, default=None, help="first N clips per rendered set (quick looks)")
    ap.add_argument("--params", default=None, help="params.yaml (default ./params.yaml)")
    ap.add_argument("--report", type=Path, default=ROOT / "reports/observation_truth", help="report path stem")
    ap.add_argument("--fine-scale", action=argparse.BooleanOptionalAction, default=None,
                    help="realvideo.fine_scale: fuse the detection pass's segmenter probabilities into the working "
                         "pass's where finer (default: the params' value)")
    ap.add_argument("--segmenter-weights", type=Path, default=None,
                    help="segmenter checkpoint to score (default: the shipped pipeline/weights/segmenter.pt)")
    ap.add_argument("--scenery", choices=("keep", "drop"), default=None,
                    help="realvideo.scenery for the rendered clips: drop leaves out the objects at rest no mover "
                         "touches, as the main job then does (default: the params' value)")
    ap.add_argument("--update", action="store_true",
                    help="replace only this run's rows in the existing report (REPORT.json), keep the others with "
                         "the command and tree that made them")
    args = ap.parse_args(argv)
    segmenter = shipped(args.segmenter_weights)
    params = load_params(args.params)
    if args.fine_scale is not None:
        params.setdefault("realvideo", {})["fine_scale"] = args.fine_scale
    if args.scenery is not None:
        params.setdefault("realvideo", {})["scenery"] = args.scenery
    default = realvideo_config(params).mask_method
    methods = args.mask_method.split(",") if args.mask_method else [default]
    only = set(args.only.split(","))
    sets: dict[str, list[dict]] = {}
    for method in methods:
        params.setdefault("realvideo", {})["mask_method"] = method
        tag = f"{method}{' (default)' if method == default else ''}: "
        for (engine, split) in SETS:
            if engine not in only or split not in args.splits.split(","):
                continue
            folder = ensure_set(args.sets, engine, split, not args.no_generate)
            if not folder.is_dir():
                continue
            clips = sorted(p for p in folder.iterdir() if (p / "truth.npz").exists())[: args.limit]
            sets[f"{tag}{engine} {split}"] = [rendered_clip(c, params, segmenter) for c in tqdm(clips, desc=f"{method} {engine}/{split}")]
        if "real" in only:
            from label_masks import FIXTURES, load_spec, spec_video_dir
            for name, spec_file in (("real shared (6)", FIXTURES / "labels.yaml"),
                                    ("real dev (13)", FIXTURES / "labels_dev.yaml")):
                if not spec_file.exists():
                    continue
                specs = load_spec(spec_file)
                vdir = spec_video_dir(spec_file)
                rows = []
                for clip in tqdm(sorted(specs), desc=f"{method} {name}"):
                    spec = specs[clip]
                    if not all((FIXTURES / clip / f"{int(i):04d}.png").exists() for i in spec["frames"]):
                        print(f"{clip}: label PNGs missing, skipped (python scripts/label_masks.py --spec {spec_file})")
                        continue
                    rows.append(real_clip(clip, spec, FIXTURES, vdir, params, segmenter))
                sets[f"{tag}{name}"] = rows
    commit = tree_id()
    report = {"command": "python benchmarks/observation_truth.py " + " ".join(argv if argv is not None else sys.argv[1:]),
              "commit": commit, "method": f"mask methods {', '.join(methods)}; default realvideo.mask_method={default}; "
                        f"realvideo.fine_scale={realvideo_config(params).fine_scale}, "
                        f"realvideo.scenery={realvideo_config(params).scenery}",
              "summary": {k: summarize(v) for k, v in sets.items()}, "sets": sets}
    report["runs"] = [{"command": report["command"], "commit": commit, "sets": list(sets)}]
    if args.update:
        report = updated(load_report(args.report.with_suffix(".json")), report)
    write_report(args.report, report, markdown(report))
    return 0


def load_report(path: Path) -> dict:
    """A report written by this command; ``runs`` (which command and tree made which rows) is
    filled in for reports written before it existed. Raises ``SystemExit`` naming the file when
    it is missing or not such a report."""
    try:
        old = json.loads(path.read_text())
        old["sets"], old["summary"]
    except (OSError, ValueError, KeyError) as e:
        raise SystemExit(f"{path}: not a report of benchmarks/observation_truth.py to update ({e})")
    old.setdefault("runs", [{"command": old.get("command", "?"), "commit": old.get("commit", "?"), "sets": list(old["sets"])}])
    return old


def updated(old: dict, new: dict) -> dict:
    """``old`` with ``new``'s rows put in their place (rows of ``old`` that ``new`` also has are
    replaced, in place; new rows are appended) and ``new``'s run added to ``runs``; a run left with
    no row is dropped. ``command``/``commit``/``method`` become the latest run's."""
    sets = {k: new["sets"].get(k, v) for k, v in old["sets"].items()}
    sets.update({k: v for k, v in new["sets"].items() if k not in sets})
    runs = [{**r, "sets": [k for k in r["sets"] if k not in new["sets"]]} for r in old["runs"]]
    runs = [r for r in runs if r["sets"]] + new["runs"]
    return {**new, "sets": sets, "summary": {k: summarize(v) for k, v in sets.items()}, "runs": runs}


if __name__ == "__main__":
    raise SystemExit(main())
