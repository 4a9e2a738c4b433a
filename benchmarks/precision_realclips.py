"""What the canonical text's precision is worth on real clips (issue 35): each scene the main job
wrote, scored as written (6 significant digits) and as the old fixed decimals would have
written it (1 mm, 1 cm/s, 0.1 deg: ``Scene.to_yaml(Decimals())``), against the same pseudo
ground truth.

Reads the folders of a ``scripts/realvideo_all.py`` run (``summary.json``, and per clip
``metrics.json`` and ``scene.yaml``), observes each clip again exactly as ``dynamics infer``
did (same window, crop, pseudo masks; :func:`pipeline.observe.observe`), and re-simulates both
texts of the scene at the working size. The scene as written must score what ``metrics.json``
says (checked). Writes ``reports/precision_realclips.{json,md}``.

Usage::

    python scripts/realvideo_all.py --out outputs/realvideo_all
    MUJOCO_GL=egl python benchmarks/precision_realclips.py --runs outputs/realvideo_all
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from pipeline.atomic import write_json, write_text
from pipeline.flow import flow_config
from pipeline.geometry import bounding_radius
from pipeline.metrics import sequence_iou
from pipeline.mjcf import SimOptions
from pipeline.observe import observe
from pipeline.params import load_params, typed_section
from pipeline.reconstruct import observation_segmenters, realvideo_config
from pipeline.render import render_scene
from pipeline.scene import Decimals, load_scene


def score(scene, obs_seg: np.ndarray, sim: SimOptions) -> float:
    """Full (strict) IoU of a scene's re-simulated masks against ``obs_seg (T, H, W) int8``."""
    T, H, W = obs_seg.shape
    _, fr = render_scene(scene, W, H, options=sim, rgb=False, depth=False, flow=False)
    return float(sequence_iou(obs_seg, fr.seg)["full_iou"])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=Path, default=Path("outputs/realvideo_all"), help="a realvideo_all.py output folder")
    ap.add_argument("--params", default=None, help="params.yaml (default ./params.yaml)")
    ap.add_argument("--report", type=Path, default=Path("reports/precision_realclips"), help="report path stem")
    args = ap.parse_args(argv)
    params = load_params(args.params)
    rv = realvideo_config(params)
    fcfg = flow_config(params)
    sim = typed_section(params, "sim", SimOptions, required=True)
    rows = []
    segmenter, rest_segmenter = observation_segmenters(params)
    for r in json.loads((args.runs / "summary.json").read_text()):
        folder = args.runs / r["clip"]
        if "error" in r or not (folder / "scene.yaml").exists():
            continue
        m = json.loads((folder / "metrics.json").read_text())
        # the scene rate the main job used (realvideo.fps, or higher for a short clip: observe.scene_rate)
        obs = observe(m["video"], r["fps"], None, int(m["window"]["fps"]), rv.duration, fcfg, rv.mask_method,
                      rv.max_objects, segmenter, fine_scale=rv.fine_scale, rest_segmenter=rest_segmenter)
        scene = load_scene(folder / "scene.yaml")
        new = score(scene, obs.seg, sim)
        old = score(scene.rounded(Decimals()), obs.seg, sim)
        row = {"clip": r["clip"], "iou_written": round(new, 4), "iou_old_decimals": round(old, 4),
               "change": round(new - old, 4), "metrics_iou": m["best_of_k_cmaes"]["full_iou"],
               "smallest_object_m": round(min(bounding_radius(o.shape, o.size) for o in scene.objects), 4),
               "fastest_m_s": round(max(float(np.linalg.norm(o.linear_velocity)) for o in scene.objects), 3)}
        assert abs(row["iou_written"] - row["metrics_iou"]) < 1e-3, row   # scored as written
        print(json.dumps(row), file=sys.stderr, flush=True)
        rows.append(row)
    ch = np.asarray([r["change"] for r in rows])
    lines = ["| clip | smallest object (bounding radius, m) | fastest (m/s) | IoU as written (6 significant digits) "
             "| IoU at the old fixed decimals | change |", "|---|---|---|---|---|---|"]
    lines += [f"| {r['clip']} | {r['smallest_object_m']} | {r['fastest_m_s']} | {r['iou_written']:.4f} | "
              f"{r['iou_old_decimals']:.4f} | {r['change']:+.4f} |" for r in rows]
    summary = {"clips": len(rows), "mean_change": round(float(ch.mean()), 4),
               "median_change": round(float(np.median(ch)), 4), "max_change": round(float(ch.max()), 4),
               "min_change": round(float(ch.min()), 4), "clips_better": int((ch > 0).sum()),
               "clips_worse": int((ch < 0).sum())}
    lines += ["", f"{summary['clips']} clips: mean change {summary['mean_change']:+.4f} IoU (median "
              f"{summary['median_change']:+.4f}), largest "
              f"{summary['max_change']:+.4f}, smallest {summary['min_change']:+.4f}; better on {summary['clips_better']}, "
              f"worse on {summary['clips_worse']}.", "",
              f"Re-run: `python scripts/realvideo_all.py --out {args.runs}` then "
              f"`MUJOCO_GL=egl python benchmarks/precision_realclips.py --runs {args.runs}`"]
    write_json(args.report.with_suffix(".json"), {"summary": summary, "rows": rows})
    write_text(args.report.with_suffix(".md"), "# Canonical-text precision on real clips\n\n" + "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
