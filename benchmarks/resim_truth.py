"""The main job measured against the truth on rendered scenes (issue 36): ``dynamics infer`` on the
rendered clips of ``pipeline.truthsets`` (MuJoCo and PyBullet, the sets of
``benchmarks/observation_truth.py``), its re-simulation and its observation each scored against the
true instance masks of every window frame.

Each clip runs the main job as a user runs it (:func:`pipeline.reconstruct.reconstruct`: window,
observation, the shipped model's samples and perception's proposals, Best@K, CMA-ES) with the
clip's true frame rate and ``labels`` = its ``truth.npz``; the search never reads the truth, which
is only scored against afterwards (``metrics.json: against_labels``, matched per-object IoU over
the frames where either the true object or its match is visible, an unmatched true object 0:
:func:`pipeline.metrics.observation_scores`). True objects at rest count like the others.

Usage::

    MUJOCO_GL=egl python benchmarks/resim_truth.py --mask-method median,hybrid --limit 12
    MUJOCO_GL=egl python benchmarks/resim_truth.py --sets-only pybullet/dev --report /tmp/resim
"""

from __future__ import annotations

import argparse
from collections import Counter
import copy
import math
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

ROOT = Path(__file__).resolve().parents[1]
for p in (ROOT, ROOT / "benchmarks"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

from cross_engine import composition, true_composition  # noqa: E402

from provenance import tree_id  # noqa: E402
from pipeline.atomic import write_json, write_text  # noqa: E402
from pipeline.params import load_params  # noqa: E402
from pipeline.reconstruct import realvideo_config, reconstruct  # noqa: E402
from pipeline.scene import Scene  # noqa: E402
from pipeline.video import VideoError  # noqa: E402

SETS = ("mujoco/dev", "mujoco/heldout", "pybullet/dev", "pybullet/heldout")


def run_clip(folder: Path, params: dict, work: Path) -> dict:
    """The main job on one rendered clip, scored against its true masks. A clip the main job
    refuses (``VideoError``: nothing seen in its window) scores 0 against the truth, observation
    and re-simulation alike, with no object written (every true object is unmatched)."""
    truth = np.load(folder / "truth.npz", allow_pickle=False)
    n_true = int(truth["seg"].max()) + 1
    t0 = time.perf_counter()
    try:
        m = reconstruct(folder / "video.mp4", work / folder.name, params, fps=float(truth["fps"]),
                        labels=folder / "truth.npz")
    except VideoError as exc:
        return {"clip": folder.name, "resim_vs_truth": 0.0, "observation_vs_truth": 0.0, "objects_true": n_true,
                "objects_written": 0, "shapes_true": list(true_composition(folder)), "shapes_written": [],
                "objects_observed": 0, "seconds": round(time.perf_counter() - t0, 1), "best_of_k_label": None,
                "error": str(exc)}
    a = m["against_labels"]
    written = Scene.from_yaml((work / folder.name / "scene.yaml").read_text())
    return {"clip": folder.name, "resim_vs_truth": a["resim_vs_labels"], "observation_vs_truth": a["observation_vs_labels"],
            "objects_true": n_true, "objects_written": len(written.objects),
            "shapes_true": list(true_composition(folder)), "shapes_written": list(composition(written)),
            "objects_observed": m.get("objects_observed"), "seconds": m["seconds"],
            "best_of_k_label": m["best_of_k_label"]}


def summarize(rows: list[dict]) -> dict:
    def mean(key):
        xs = [r[key] for r in rows if r.get(key) is not None and not math.isnan(r[key])]
        return round(float(np.mean(xs)), 3) if xs else None
    return {"clips": len(rows), "resim_vs_truth": mean("resim_vs_truth"),
            "count_right": round(float(np.mean([r["objects_written"] == r["objects_true"] for r in rows])), 3) if rows else None,
            "composition_right": round(float(np.mean([r["shapes_written"] == r["shapes_true"] for r in rows])), 3)
            if rows else None,
            "shapes_right": round(sum(sum((Counter(r["shapes_true"]) & Counter(r["shapes_written"])).values())
                                      for r in rows) / max(sum(len(r["shapes_true"]) for r in rows), 1), 3)
            if rows else None,
            "observation_vs_truth": mean("observation_vs_truth"), "seconds": mean("seconds")}


def markdown(report: dict) -> str:
    lines = ["# The main job against the truth on rendered scenes (issue 36)", "",
             f"Command: `{report['command']}` (tree `{report['commit']}`). Matched per-object IoU against the "
             "true masks of every window frame (unmatched true objects, at rest included, score 0); the search "
             "fits the observation and never reads the truth.", "",
             "Composition: the multiset of shapes written equals the true one (`meta.json`). Shapes right: the "
             "true objects whose shape is written, over all true objects (the multisets' intersection, summed over "
             "the clips, over the true count).", "",
             "| mask method | set | clips | re-simulation vs truth | observation vs truth | objects written = true | "
             "composition right | shapes right | s / clip |",
             "|---|---|---|---|---|---|---|---|---|"]
    for key, s in report["summary"].items():
        method, name = key.split(": ", 1)
        lines.append(f"| {method} | {name} | {s['clips']} | {s['resim_vs_truth']} | {s['observation_vs_truth']} | "
                     f"{s['count_right']} | {s.get('composition_right')} | {s.get('shapes_right')} | {s['seconds']} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sets", type=Path, default=ROOT / "data/truthsets",
                    help="rendered sets' root (python benchmarks/observation_truth.py generates them)")
    ap.add_argument("--sets-only", default="mujoco/dev,pybullet/dev", help=f"comma list of {', '.join(SETS)}")
    ap.add_argument("--mask-method", default=None, help="comma list of realvideo.mask_method values (default: the params')")
    ap.add_argument("--limit", type=int, default=None, help="first N clips per set")
    ap.add_argument("--params", default=None, help="params.yaml (default ./params.yaml)")
    ap.add_argument("--report", type=Path, default=ROOT / "reports/resim_truth", help="report path stem")
    args = ap.parse_args(argv)
    base = load_params(args.params)
    default = realvideo_config(base).mask_method
    methods = args.mask_method.split(",") if args.mask_method else [default]
    sets: dict[str, list[dict]] = {}
    work = Path(tempfile.mkdtemp(prefix="resim_truth_"))
    try:
        for method in methods:
            params = copy.deepcopy(base)
            params.setdefault("realvideo", {})["mask_method"] = method
            for name in args.sets_only.split(","):
                folder = args.sets / name
                if not folder.is_dir():
                    sys.exit(f"{folder}: no rendered set (python benchmarks/observation_truth.py generates it)")
                clips = sorted(p for p in folder.iterdir() if (p / "truth.npz").exists())[: args.limit]
                sets[f"{method}: {name}"] = [run_clip(c, params, work) for c in tqdm(clips, desc=f"{method} {name}")]
                shutil.rmtree(work, ignore_errors=True)
                work.mkdir()
    finally:
        shutil.rmtree(work, ignore_errors=True)
    commit = tree_id()
    report = {"command": "python benchmarks/resim_truth.py " + " ".join(argv if argv is not None else sys.argv[1:]),
              "commit": commit, "summary": {k: summarize(v) for k, v in sets.items()}, "sets": sets}
    args.report.parent.mkdir(parents=True, exist_ok=True)
    write_json(args.report.with_suffix(".json"), report, indent=1)
    write_text(args.report.with_suffix(".md"), markdown(report))
    print(markdown(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
