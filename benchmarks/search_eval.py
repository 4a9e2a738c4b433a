"""Benchmark: candidate evaluations per second of the search (issue 9, item 5).

One evaluation = simulate a candidate scene for T = 30 frames at 30 fps and render its
segmentation (and, with ``flow``, depth and the exact flow), as Best@K and CMA-ES do. Timed in
one run, on the same candidates (CMA-ES-like perturbations of a 1-object and a 2-object scene,
``SearchSpace`` with sigma 0.05):

* ``naive``: per candidate rebuild the MJCF XML, compile it, roll it out and render with a
  fresh ``FrameRenderer`` (private GL context), then close it;
* ``evaluator``: one :class:`pipeline.search.SceneEvaluator` (compile once, edit the model in
  place, reused renderer), in this process;
* ``pool2``: :class:`pipeline.search.ParallelEvaluator` with 2 worker processes (each with its
  own evaluator), candidates split in halves (pool start-up not timed).

The evaluator's segmentation is checked equal to the naive path's for every naive candidate
(its flow to within ``flow_max_abs_diff_to_naive_px``: the in-place edited model equals the
compiled one to rounding), and the pool's clips equal the evaluator's bit for bit. Sizes: the working size 192x144 and 96x64, 320x240; with and without flow.

Usage::

    MUJOCO_GL=egl .venv/bin/python benchmarks/search_eval.py            # ~2 min on 2 cores
    MUJOCO_GL=egl .venv/bin/python benchmarks/search_eval.py -n 60 --naive-n 8

Prints a table and writes ``reports/bench_search_eval.json`` (evaluations/s per path, the
ratios to the naive loop, the load average before the run: the machine may be shared, compare
ratios taken in one run).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

# llvmpipe rasterizes in the calling thread, as in the pool workers (pipeline.parallel): with
# 2 cores its helper threads only add hand-offs (pixels do not depend on it)
os.environ.setdefault("LP_NUM_THREADS", "0")

import numpy as np  # noqa: E402

import pipeline  # noqa: E402,F401  (MUJOCO_GL before mujoco)

SIZES = ((192, 144), (96, 64), (320, 240))
WORKING_SIZE = (192, 144)
T, FPS = 30, 30


def scenes():
    """The 1-object and 2-object start scenes (1 s at 30 fps, objects big in view)."""
    from pipeline.scene import Scene

    cam = {"height": 1.0, "pitch": 35.0, "fov": 45.0}
    box = {"shape": "box", "size": {"width": 0.25, "depth": 0.2, "height": 0.15}, "mass": 0.8,
           "position": [-0.2, -0.8, 0.075], "linear_velocity": [0.6, 0.3, 0.0]}
    ball = {"shape": "sphere", "size": {"radius": 0.1}, "mass": 0.3, "position": [0.2, -0.7, 0.3],
            "linear_velocity": [-0.4, 0.0, 1.0], "material": {"sliding_friction": 0.3, "damping": 0.05}}
    return {"1 object": Scene.from_dict({"duration": T / FPS, "fps": FPS, "camera": cam, "objects": [ball]}),
            "2 objects": Scene.from_dict({"duration": T / FPS, "fps": FPS, "camera": cam, "objects": [box, ball]})}


def candidates(scene, n: int, seed: int = 0) -> list:
    """``n`` CMA-ES-like candidates: the default free fields perturbed by N(0, 0.05) in the
    normalised search space."""
    from pipeline.search import SearchConfig, SearchSpace

    cfg = SearchConfig()
    space = SearchSpace(scene, cfg.free, cfg.ranges)
    rng = np.random.default_rng(seed)
    return [space.decode(space.x0 + cfg.sigma * rng.standard_normal(space.dim)) for _ in range(n)]


def naive_evaluate(scene, W: int, H: int, flow: bool):
    """Rebuild the XML, compile, roll out, render with a fresh renderer (private GL context)."""
    from pipeline.mjcf import compile_model, to_xml
    from pipeline.render import FrameRenderer
    from pipeline.simulate import rollout

    model = compile_model(to_xml(scene))
    trace = rollout(model, len(scene.objects), T, FPS, record_contacts=False)
    with FrameRenderer(model, W, H) as r:
        frames = r.render(trace.qpos, rgb=False, seg=True, depth=False, flow=flow)
    return frames.seg, frames.flow


def rate(fn, items) -> tuple[float, list]:
    t0 = time.perf_counter()
    out = [fn(c) for c in items]
    return len(items) / (time.perf_counter() - t0), out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-n", type=int, default=60, help="candidates per fast measurement (default 60)")
    ap.add_argument("--naive-n", type=int, default=8, help="candidates for the naive loop (default 8)")
    ap.add_argument("--no-pool", action="store_true", help="skip the 2-process pool measurement")
    ap.add_argument("--out", default=str(ROOT / "reports" / "bench_search_eval.json"))
    args = ap.parse_args(argv)

    from pipeline import shards
    from pipeline.parallel import available_cores
    from pipeline.search import ParallelEvaluator, SceneEvaluator

    report = {"frames": T, "fps": FPS, "cores": available_cores(), "working_size": list(WORKING_SIZE),
              "n": args.n, "naive_n": args.naive_n, "load_avg_before": list(os.getloadavg()),
              "lp_num_threads": os.environ.get("LP_NUM_THREADS"), "mujoco_gl": os.environ.get("MUJOCO_GL"),
              "command": " ".join([Path(sys.argv[0]).name, *(argv if argv is not None else sys.argv[1:])]),
              "runs": []}
    pools: dict = {}
    print(f"{'scene':10} {'size':8} {'flow':5} {'naive/s':>8} {'eval/s':>8} {'pool2/s':>8} "
          f"{'eval/naive':>10} {'pool2/naive':>11}  seg==naive pool==eval", flush=True)
    for label, scene in scenes().items():
        cands = candidates(scene, args.n)
        for W, H in SIZES:
            for flow in (False, True):
                naive_rate, naive_out = rate(lambda c: naive_evaluate(c, W, H, flow), cands[: args.naive_n])
                with SceneEvaluator(scene, W, H) as ev:
                    ev.evaluate(scene, T, flow=flow)  # warm-up (first frame compiles shaders)
                    ev_rate, ev_out = rate(lambda c: ev.evaluate(c, T, flow=flow), cands)
                run = {"scene": label, "width": W, "height": H, "flow": flow,
                       "naive_evals_per_s": naive_rate, "evaluator_evals_per_s": ev_rate,
                       "evaluator_vs_naive": ev_rate / naive_rate,
                       "seg_identical_to_naive": all(np.array_equal(a[0], b[0]) for a, b in zip(naive_out, ev_out))}
                if flow:  # the edited model equals the compiled one to ~1e-16, so flow to ~1e-6 px
                    run["flow_max_abs_diff_to_naive_px"] = max(float(np.abs(a[1] - b[1]).max()) for a, b in
                                                               zip(naive_out, ev_out))
                if not args.no_pool:
                    pe = pools.get((W, H))
                    if pe is None:
                        pe = pools[(W, H)] = ParallelEvaluator(W, H, workers=2)
                    pe.evaluate_many([scene, scene], T, flow=flow)  # warm-up: start workers, compile
                    t0 = time.perf_counter()
                    pool_out = pe.evaluate_many(cands, T, flow=flow)
                    run["pool2_evals_per_s"] = len(cands) / (time.perf_counter() - t0)
                    run["pool2_vs_naive"] = run["pool2_evals_per_s"] / naive_rate
                    run["pool2_identical_to_evaluator"] = all(
                        np.array_equal(a[0], b[0]) and (not flow or np.array_equal(a[1], b[1]))
                        for a, b in zip(pool_out, ev_out))
                report["runs"].append(run)
                print(f"{label:10} {W}x{H:<4} {str(flow):5} {naive_rate:8.1f} {ev_rate:8.1f} "
                      f"{run.get('pool2_evals_per_s', float('nan')):8.1f} {run['evaluator_vs_naive']:10.1f} "
                      f"{run.get('pool2_vs_naive', float('nan')):11.1f}  {run['seg_identical_to_naive']!s:10} "
                      f"{run.get('pool2_identical_to_evaluator')}", flush=True)
    for pe in pools.values():
        pe.close()
    work = [r for r in report["runs"] if (r["width"], r["height"]) == WORKING_SIZE and not r["flow"]]
    report["working_size_seg_only"] = {
        r["scene"]: {k: r[k] for k in ("naive_evals_per_s", "evaluator_evals_per_s", "evaluator_vs_naive",
                                       "pool2_evals_per_s", "pool2_vs_naive") if k in r} for r in work}
    report["load_avg_after"] = list(os.getloadavg())
    shards.write_json(args.out, report)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
