"""The scene-writing model on a profile's synthetic test splits (issue 30): what it writes before
any search, for one or more checkpoints on the same scenes.

For every test scene, ``K`` constrained samples at the checkpoint's temperature / top-p (paper:
0.1 / 0.9) from the scene's model input (flow + first RGB frame, exactly as the ``predict``
stage reads it). Per split, with bootstrap 95 % intervals over scenes (2,000 resamples):

* ``composition``: the first sample's multiset of shapes equals the truth's (the paper's
  composition accuracy);
* ``count``: the first sample has the right number of objects;
* ``composition_any_of_k``: one of the K samples has the right composition (an upper bound of what
  Best@K can pick by re-simulation; not the paper's Best@K, which picks by fitness);
* ``valid``: samples that decode to a scene;
* ``ramp``: the first sample writes a ramp exactly when the scene has one (``<ramp>``, profiles with
  ``sample.p_ramp > 0``), and ``ramp_recall``: of the scenes with a ramp, those whose first sample
  writes one (a checkpoint without ramp fields never does);
* the same composition by true object count.

A checkpoint decodes with its own codec, so checkpoints trained with other token ranges are
compared on the same videos. Writes ``REPORT.json`` and ``REPORT.md``.

    MUJOCO_GL=egl python benchmarks/model_eval.py --params PROFILE --models pipeline/checkpoints/dynamics-tiny DIR2 \\
        --labels shipped new --report reports/model_eval
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pipeline import model as M  # noqa: E402
from pipeline import shards  # noqa: E402
from pipeline.atomic import write_text  # noqa: E402
from pipeline.codec import RAMP_TOKEN, composition_of, split_completion  # noqa: E402
from pipeline.params import load_params, path_of  # noqa: E402


def bootstrap(hits: np.ndarray, n: int = 2000, seed: int = 0) -> list[float]:
    """95 % percentile interval of the mean of 0/1 ``hits`` (bootstrap over scenes)."""
    if len(hits) == 0:
        return [float("nan"), float("nan")]
    rng = np.random.default_rng(seed)
    means = hits[rng.integers(0, len(hits), size=(n, len(hits)))].mean(axis=1)
    return [round(float(np.percentile(means, 2.5)), 3), round(float(np.percentile(means, 97.5)), 3)]


def evaluate(model_dir: Path, params: dict, splits: list[str], k: int, limit: int | None) -> dict:
    """Per split: composition / count / any-of-K / valid, with intervals and by object count."""
    cfg = M.checkpoint_config(model_dir, M.ModelConfig.from_params(params))
    model, tok = M.load_model(model_dir)
    codec, _ = M.load_codec(model_dir)
    rows = [r for r in shards.read_table(path_of(params, "examples")).to_pylist() if r["split"] in splits]
    out = {}
    for split in splits:
        sel = [r for r in rows if r["split"] == split][:limit]
        if not sel:
            continue
        frames = M.read_inputs(path_of(params, "flow"), path_of(params, "video"), cfg, [r["scene_id"] for r in sel])
        comp, count, anyk, valid, n_true, ramp, has_ramp = [], [], [], 0, [], [], []
        for i, r in enumerate(sel):
            truth = composition_of(r["target"].split())
            samples = M.generate(model, tok, frames[r["scene_id"]], cfg, codec, k=k, seed=i)
            answers = [split_completion(s)[1] for s in samples]
            written = [None if a is None else composition_of(a) for a in answers]
            valid += sum(M.to_scene(s, codec)[0] is not None for s in samples)
            comp.append(written[0] == truth)
            count.append(written[0] is not None and len(written[0]) == len(truth))
            anyk.append(any(w == truth for w in written))
            n_true.append(len(truth))
            has_ramp.append(RAMP_TOKEN in r["target"].split())
            ramp.append(answers[0] is not None and (RAMP_TOKEN in answers[0]) == has_ramp[-1])
        comp, count, anyk, n_true, ramp, has_ramp = map(np.asarray, (comp, count, anyk, n_true, ramp, has_ramp))
        wrote = ramp & has_ramp
        out[split] = {"scenes": len(sel), "k": k,
                      "composition": round(float(comp.mean()), 3), "composition_ci95": bootstrap(comp),
                      "count": round(float(count.mean()), 3), "count_ci95": bootstrap(count),
                      "composition_any_of_k": round(float(anyk.mean()), 3), "valid": f"{valid}/{len(sel) * k}",
                      "ramp": round(float(ramp.mean()), 3), "ramp_ci95": bootstrap(ramp),
                      "ramp_scenes": int(has_ramp.sum()),
                      "ramp_recall": round(float(wrote[has_ramp].mean()), 3) if has_ramp.any() else None,
                      "composition_by_objects": {int(n): round(float(comp[n_true == n].mean()), 3)
                                                 for n in sorted(set(n_true.tolist()))}}
    return out


def markdown(results: dict, params_path: str, k: int) -> str:
    lines = ["# The scene-writing model on synthetic test splits\n",
             f"Command: `python benchmarks/model_eval.py --params {params_path} ...` (first of K = {k} constrained "
             "samples at the checkpoint's temperature and top-p; 95 % bootstrap intervals over scenes).\n",
             "| model | split | scenes | composition (first sample) | object count | composition in any of K | valid "
             "| composition by object count | ramp right (scenes with one) | ramp recall |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for label, res in results.items():
        for split, r in res.items():
            by = ", ".join(f"{n}: {v:.2f}" for n, v in r["composition_by_objects"].items())
            lines.append(f"| {label} | {split} | {r['scenes']} | {r['composition']:.3f} {r['composition_ci95']} | "
                         f"{r['count']:.3f} {r['count_ci95']} | {r['composition_any_of_k']:.3f} | {r['valid']} | {by} | "
                         f"{r.get('ramp', float('nan')):.3f} ({r.get('ramp_scenes', 0)}) | "
                         f"{'-' if r.get('ramp_recall') is None else format(r['ramp_recall'], '.3f')} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--params", required=True, help="profile whose test splits (paths.examples/flow/video) are used")
    ap.add_argument("--models", nargs="+", required=True, help="checkpoint folders")
    ap.add_argument("--labels", nargs="*", default=None, help="a name per checkpoint (default: folder names)")
    ap.add_argument("--splits", default="test,test_comp")
    ap.add_argument("-k", type=int, default=4)
    ap.add_argument("--limit", type=int, default=None, help="first N scenes per split")
    ap.add_argument("--report", type=Path, default=ROOT / "reports" / "model_eval", help="report path stem")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    params = load_params(args.params)
    labels = args.labels or [Path(m).name for m in args.models]
    results = {}
    for label, model_dir in zip(labels, args.models):
        results[label] = evaluate(Path(model_dir), params, args.splits.split(","), args.k, args.limit)
        print(label, json.dumps(results[label]), flush=True)
    args.report.parent.mkdir(parents=True, exist_ok=True)
    write_text(args.report.with_suffix(".json"), json.dumps({"params": args.params, "models": dict(zip(labels, args.models)),
                                                             "results": results}, indent=1) + "\n")
    write_text(args.report.with_suffix(".md"), markdown(results, args.params, args.k))
    return 0


if __name__ == "__main__":
    sys.exit(main())
