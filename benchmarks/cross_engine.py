"""The scene writer on another engine's videos (issue 30 item 5, the paper's CLEVRER step): the
model's proposals for clips simulated and rendered by PyBullet (TinyRenderer), scored against
the clips' **true** scenes and instance masks.

Each clip is observed exactly as ``dynamics infer`` observes a video
(:func:`pipeline.reconstruct.observe_window`: window, crop to the region of motion, pseudo masks,
flow), the model is shown the window as the main job shows it
(:func:`pipeline.reconstruct.model_samples`, K samples at the params' temperature / top-p), and
three scenes are scored per clip, as in the paper's table:

* **first sample** (sample 0);
* **Best@K**: the model sample with the best search fitness (strict IoU - lambda * EPE) against the
  observation (never against the truth);
* **Best@K + CMA-ES**: the staged CMA-ES of the main job from that sample
  (:func:`pipeline.search.staged.staged_refine`), the better of it and its start by fitness.

Per scene: **composition** (the multiset of shapes equals the true one's, ``meta.json``),
object count, and the re-simulation's **true-mask IoU**: matched per-object IoU over the frames
where the true object or its match is visible (:func:`pipeline.labels.score_against_labels`;
an unmatched true object scores 0, objects at rest count); and, beside it, the old convention
(mean over all frames of the matched IoU, :func:`pipeline.metrics.sequence_iou`). Perception's
proposals are not used here: the rows measure the model alone (``benchmarks/resim_truth.py``
scores the whole main job). Means with bootstrap 95 % intervals (:func:`pipeline.metrics.mean_ci95`).

Usage (the sets come from ``python -m pipeline.truthsets generate``, see README)::

    MUJOCO_GL=egl python benchmarks/cross_engine.py --sets-only pybullet/dev,pybullet/heldout
    MUJOCO_GL=egl python benchmarks/cross_engine.py --model pipeline/checkpoints/dynamics-wide --limit 4
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

ROOT = Path(__file__).resolve().parents[1]
for p in (ROOT, ROOT / "benchmarks"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

from provenance import tree_id  # noqa: E402
from pipeline.atomic import write_json, write_text  # noqa: E402
from pipeline.infer_report import scene_scores  # noqa: E402
from pipeline.labels import labels_in_window, load_labels, score_against_labels  # noqa: E402
from pipeline.metrics import mean_ci95, sequence_iou  # noqa: E402
from pipeline.params import load_params  # noqa: E402
from pipeline.reconstruct import job_settings, model_samples, observe_window, resolve_model_dir  # noqa: E402
from pipeline.scene import Scene  # noqa: E402
from pipeline.search import EvaluatorPool, best_of_k  # noqa: E402
from pipeline.search.staged import at_width, score_scene, staged_refine  # noqa: E402

ROWS = ("first_sample", "best_of_k", "best_of_k_cmaes")


def true_composition(folder: Path) -> tuple[str, ...]:
    """Sorted shapes of the clip's true dynamic objects (``meta.json`` ``objects``)."""
    meta = json.loads((folder / "meta.json").read_text())
    return tuple(sorted(o["shape"] for o in meta["objects"]))


def composition(scene: Scene | None) -> tuple[str, ...] | None:
    """Sorted shapes of a scene's objects, or None for no scene."""
    return None if scene is None else tuple(sorted(o.shape for o in scene.objects))


def truth_scores(scene: Scene | None, obs, truth: dict, sim) -> dict:
    """A scene's re-simulation against the true masks of the window: ``{strict, all_frames}``
    (0.0 each when there is no scene: nothing re-simulated earns nothing)."""
    if scene is None:
        return {"strict": 0.0, "all_frames": 0.0}
    _, (_, fr) = scene_scores(scene, obs, sim)
    s = score_against_labels(truth, obs, fr.seg)
    ks, seg = labels_in_window(truth, obs)
    return {"strict": float(s["resim_vs_labels"] or 0.0),
            "all_frames": round(float(sequence_iou(seg, fr.seg[ks])["full_iou"]), 4) if len(ks) else 0.0}


def run_clip(folder: Path, params: dict, mdir: Path, k: int, seed: int, cmaes: bool) -> dict:
    """The three rows of one clip (see module docstring)."""
    t0 = time.time()
    job = job_settings(params)
    meta = json.loads((folder / "meta.json").read_text())
    fps = float(meta["params"]["fps"])
    video = folder / "video.mp4"
    obs = observe_window(video, job, fps=fps)
    truth = load_labels(folder / "truth.npz", (int(meta["params"]["width"]), int(meta["params"]["height"])))
    scenes, _ = model_samples(mdir, obs.frames, params, k, seed, obs.scene_fps, obs.duration)
    W, _ = obs.size
    scfg = at_width(job.scfg, W)
    picked: dict[str, Scene | None] = {"first_sample": scenes[0]}
    with EvaluatorPool(*obs.size, job.sim) as pool:
        scores, best = best_of_k(scenes, obs.fit_seg, obs.fit_flow, scfg, job.sim, pool=pool)
        picked["best_of_k"] = None if best is None else scenes[best]
        picked["best_of_k_cmaes"] = picked["best_of_k"]
        if cmaes and best is not None:
            refined, _ = staged_refine(scenes[best], obs.fit_seg, obs.fit_flow, job.scfg, job.sim, seed=seed,
                                       restarts=job.rv.restarts, pool=pool, workers=job.rv.workers)
            f_ref = score_scene(refined, obs.fit_seg, obs.fit_flow, job.scfg, job.sim, pool=pool)["fitness"]
            if f_ref > scores[best]["fitness"]:
                picked["best_of_k_cmaes"] = refined
    want = true_composition(folder)
    row = {"clip": folder.name, "objects_true": len(want), "composition_true": list(want),
           "valid": int(sum(s is not None for s in scenes)), "k": len(scenes)}
    for name in ROWS:
        sc = picked[name]
        got = composition(sc)
        row[name] = {"composition": got == want, "count": got is not None and len(got) == len(want),
                     "written": None if got is None else list(got), **truth_scores(sc, obs, truth, job.sim)}
    row["seconds"] = round(time.time() - t0, 1)
    return row


def summarize(rows: list[dict]) -> dict:
    """Per row: composition, count, strict and all-frames true-mask IoU, each a mean with its
    bootstrap 95 % interval; and the composition by true object count."""
    out: dict = {"clips": len(rows)}
    for name in ROWS:
        out[name] = {key: mean_ci95([float(r[name][key]) for r in rows])
                     for key in ("composition", "count", "strict", "all_frames")}
        out[name]["composition_by_objects"] = {
            int(n): round(float(np.mean([r[name]["composition"] for r in rows if r["objects_true"] == n])), 3)
            for n in sorted({r["objects_true"] for r in rows})}
    out["seconds"] = round(float(np.mean([r["seconds"] for r in rows])), 1) if rows else None
    return out


def markdown(report: dict) -> str:
    lines = ["# The scene writer on another engine's videos (issue 30 item 5)", "",
             f"Command: `{report['command']}` (tree `{report['commit']}`). Clips simulated and rendered by "
             "PyBullet (`pipeline/truthsets`), observed as `dynamics infer` observes a video; the model's samples "
             "only (no perception proposals). Composition: the multiset of shapes equals the true one. True-mask "
             "IoU: matched per-object IoU over the frames where the true object or its match is visible (strict; "
             "an unmatched true object scores 0), and the mean over all frames beside it. Means with bootstrap "
             "95 % intervals.", "",
             "| model | set | clips | row | composition | object count | true-mask IoU (strict) | true-mask IoU "
             "(all frames) | composition by object count | s / clip |",
             "|---|---|---|---|---|---|---|---|---|---|"]

    def cell(v):
        return f"{v['mean']:.3f} [{v['ci95'][0]:.2f}, {v['ci95'][1]:.2f}]"

    for key, s in report["summary"].items():
        model, name = key.split(" | ", 1)
        for row in ROWS:
            r = s[row]
            by = ", ".join(f"{n}: {v:.2f}" for n, v in r["composition_by_objects"].items())
            lines.append(f"| {model} | {name} | {s['clips']} | {row.replace('_', ' ')} | {cell(r['composition'])} | "
                         f"{cell(r['count'])} | {cell(r['strict'])} | {cell(r['all_frames'])} | {by} | "
                         f"{s['seconds']} |")
    return "\n".join(lines) + "\n"


def save_report(stem: Path, script: str, argv: list[str] | None, body: dict, to_markdown) -> dict:
    """Write ``stem.json`` (``command``, ``commit`` and ``body``) and ``stem.md``
    (``to_markdown(report)``), print the Markdown; returns the report. Shared by the benchmarks of
    the scene writer (this one, ``preference_eval.py``, ``preference_real.py``)."""
    commit = tree_id()
    report = {"command": f"python benchmarks/{script} " + " ".join(argv if argv is not None else sys.argv[1:]),
              "commit": commit, **body}
    stem.parent.mkdir(parents=True, exist_ok=True)
    write_json(stem.with_suffix(".json"), report, indent=1)
    text = to_markdown(report)
    write_text(stem.with_suffix(".md"), text)
    print(text)
    return report


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sets", type=Path, default=ROOT / "data/truthsets",
                    help="rendered sets' root (python -m pipeline.truthsets generate writes them)")
    ap.add_argument("--sets-only", default="pybullet/dev", help="comma list of ENGINE/SPLIT folders under --sets")
    ap.add_argument("--model", action="append", default=None,
                    help="model folder (repeatable; default: the one `dynamics infer` uses)")
    ap.add_argument("-k", type=int, default=None, help="samples per clip (default params model.k)")
    ap.add_argument("--no-cmaes", action="store_true", help="skip the CMA-ES row (it is then Best@K's)")
    ap.add_argument("--limit", type=int, default=None, help="first N clips per set")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--params", default=None, help="params.yaml (default ./params.yaml)")
    ap.add_argument("--report", type=Path, default=ROOT / "reports/cross_engine", help="report path stem")
    args = ap.parse_args(argv)
    os.environ.setdefault("LP_NUM_THREADS", "0")
    params = load_params(args.params)
    models = [resolve_model_dir(m, params) for m in (args.model or [None])]
    k = args.k or int(params["model"]["k"])
    sets: dict[str, list[dict]] = {}
    for mdir in models:
        for name in args.sets_only.split(","):
            folder = args.sets / name
            if not folder.is_dir():
                sys.exit(f"{folder}: no rendered set (python -m pipeline.truthsets generate writes it)")
            clips = sorted(p for p in folder.iterdir() if (p / "truth.npz").exists())[: args.limit]
            label = f"{Path(mdir).name} (K={k}) | {name}"
            sets[label] = [run_clip(c, params, Path(mdir), k, args.seed, not args.no_cmaes)
                           for c in tqdm(clips, desc=label)]
    save_report(args.report, "cross_engine.py", argv, {"summary": {k_: summarize(v) for k_, v in sets.items()},
                                                        "sets": sets}, markdown)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
