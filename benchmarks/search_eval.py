"""Benchmark: candidate evaluations per second of the search (issue 9, item 5).

One evaluation = simulate a candidate scene for T = 30 frames at 30 fps, render its
segmentation (and, with ``flow``, depth and the exact flow) and compute its fitness
(:func:`pipeline.search.fitness`: matched IoU, and ``- lambda * EPE`` with flow) against an
observation (the start scene's clip), as Best@K and CMA-ES do. Timed in one run, on the same
candidates (CMA-ES-like perturbations of a 1-object and a 2-object scene, ``SearchSpace`` with
sigma 0.05):

* ``naive``: per candidate rebuild the MJCF XML, compile it, roll it out and render with a
  fresh ``FrameRenderer`` (private GL context), close it, compute the fitness;
* ``evaluator``: one :class:`pipeline.search.SceneEvaluator` (compile once, edit the model in
  place, reused renderer) and the fitness, in this process;
* ``parallel_fitness2``: :class:`pipeline.search.parallel_eval.ParallelFitness` with 2 worker
  processes: the observation sent to each worker once, the candidates split in halves, only
  the fitness dicts come back (pool start-up not timed).

The evaluator's segmentation is checked equal to the naive path's for every naive candidate
(its flow to within ``flow_max_abs_diff_to_naive_px``: the in-place edited model equals the
compiled one to rounding), and the workers' fitness dicts equal the in-process ones float for
float. Sizes: the working size 192x144, 96x64 and 320x240; with and without flow.
``--compare-lp`` also times the in-process evaluator at the working size in two child
processes, ``LP_NUM_THREADS=0`` (llvmpipe rasterizes in the calling thread, as in the workers)
and Mesa's default (helper threads).

Usage::

    MUJOCO_GL=egl .venv/bin/python benchmarks/search_eval.py --compare-lp   # ~3 min on 2 cores
    MUJOCO_GL=egl .venv/bin/python benchmarks/search_eval.py -n 60 --naive-n 8 --sizes 192x144

Prints a table and the line ``working size 192x144: X evaluations/s (Y x naive)`` and writes
``reports/bench_search_eval.json`` (evaluations/s per path, the ratios to the naive loop, the
load average before and after: the machine may be shared, compare ratios taken in one run).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

import pipeline  # noqa: E402,F401  (MUJOCO_GL before mujoco)

SIZES = ((192, 144), (96, 64), (320, 240))
WORKERS = 2
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


def same_scores(a: list[dict], b: list[dict]) -> bool:
    """Fitness dicts equal float for float (NaN equal to NaN)."""
    return len(a) == len(b) and all(
        x.keys() == y.keys() and all(x[k] == y[k] or (math.isnan(x[k]) and math.isnan(y[k])) for k in x)
        for x, y in zip(a, b))


def measure(sizes, n: int, naive_n: int, pool_workers: int) -> list[dict]:
    """Every measurement of one configuration: naive, evaluator, ParallelFitness."""
    from pipeline.search import SceneEvaluator, SearchConfig, fitness
    from pipeline.search.parallel_eval import ParallelFitness

    runs = []
    for label, scene in scenes().items():
        cands = candidates(scene, n)
        for W, H in sizes:
            for flow in (False, True):
                # observation: the start scene's clip (exact flow when the fitness scores EPE)
                cfg = SearchConfig()
                with SceneEvaluator(scene, W, H) as ev:
                    obs_seg, obs_flow = ev.evaluate(scene, T, flow=flow)
                    fit = lambda clip: fitness(clip[0], clip[1], obs_seg, obs_flow, cfg)  # noqa: E731
                    run = {"scene": label, "width": W, "height": H, "flow": flow}
                    if naive_n:
                        naive_rate, naive_out = rate(lambda c: (lambda clip: (clip, fit(clip)))(
                            naive_evaluate(c, W, H, flow)), cands[:naive_n])
                        run["naive_evals_per_s"] = naive_rate
                    ev.evaluate(scene, T, flow=flow)  # warm-up (first frame compiles shaders)
                    ev_rate, ev_out = rate(lambda c: (lambda clip: (clip, fit(clip)))(ev.evaluate(c, T, flow=flow)),
                                           cands)
                run["evaluator_evals_per_s"] = ev_rate
                if naive_n:
                    run["evaluator_vs_naive"] = ev_rate / naive_rate
                    run["seg_identical_to_naive"] = all(np.array_equal(a[0][0], b[0][0])
                                                        for a, b in zip(naive_out, ev_out))
                    if flow:  # the edited model equals the compiled one to ~1e-16, so flow to ~1e-6 px
                        run["flow_max_abs_diff_to_naive_px"] = max(
                            float(np.abs(a[0][1] - b[0][1]).max()) for a, b in zip(naive_out, ev_out))
                    run["fitness_max_abs_diff_to_naive"] = max(
                        abs(a[1]["fitness"] - b[1]["fitness"]) for a, b in zip(naive_out, ev_out))
                if pool_workers > 1:
                    with ParallelFitness(obs_seg, obs_flow, cfg, workers=pool_workers) as pf:
                        pf.score([scene] * (2 * pool_workers))  # warm-up: start workers, compile
                        t0 = time.perf_counter()
                        scores = pf.score(cands)
                        pf_rate = len(cands) / (time.perf_counter() - t0)
                    key = f"parallel_fitness{pool_workers}"
                    run[f"{key}_evals_per_s"] = pf_rate
                    run[f"{key}_vs_evaluator"] = pf_rate / ev_rate
                    if naive_n:
                        run[f"{key}_vs_naive"] = pf_rate / naive_rate
                    run[f"{key}_identical_to_evaluator"] = same_scores(scores, [o[1] for o in ev_out])
                runs.append(run)
                print(f"{label:10} {W}x{H:<4} {str(flow):5} {run.get('naive_evals_per_s', math.nan):8.1f} "
                      f"{ev_rate:8.1f} {run.get(f'parallel_fitness{pool_workers}_evals_per_s', math.nan):8.1f} "
                      f"{run.get('evaluator_vs_naive', math.nan):10.1f} "
                      f"{run.get(f'parallel_fitness{pool_workers}_vs_naive', math.nan):9.1f}  "
                      f"{run.get('seg_identical_to_naive')!s:10} "
                      f"{run.get(f'parallel_fitness{pool_workers}_identical_to_evaluator')}", flush=True)
    return runs


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-n", type=int, default=60, help="candidates per fast measurement (default 60)")
    ap.add_argument("--naive-n", type=int, default=8, help="candidates for the naive loop (default 8; 0 skips it)")
    ap.add_argument("--workers", type=int, default=WORKERS,
                    help=f"ParallelFitness worker processes (default {WORKERS}; 1 skips it)")
    ap.add_argument("--sizes", nargs="+", default=[f"{w}x{h}" for w, h in SIZES], help="WxH render sizes")
    ap.add_argument("--lp-default", action="store_true",
                    help="leave LP_NUM_THREADS unset in this process (Mesa's default helper threads)")
    ap.add_argument("--compare-lp", action="store_true",
                    help="also time the evaluator at the working size with LP_NUM_THREADS=0 and unset")
    ap.add_argument("--out", default=str(ROOT / "reports" / "bench_search_eval.json"))
    args = ap.parse_args(argv)
    # llvmpipe rasterizes in the calling thread, as in the pool workers (pipeline.parallel):
    # with 2 busy processes on 2 cores its helper threads only add hand-offs (pixels do not
    # depend on it). Read when the EGL display starts (first renderer), so set it here.
    if args.lp_default:
        os.environ.pop("LP_NUM_THREADS", None)
    else:
        os.environ.setdefault("LP_NUM_THREADS", "0")
    sizes = [tuple(int(v) for v in s.lower().split("x")) for s in args.sizes]

    from pipeline import shards
    from pipeline.parallel import available_cores

    report = {"frames": T, "fps": FPS, "cores": available_cores(), "working_size": list(WORKING_SIZE),
              "n": args.n, "naive_n": args.naive_n, "workers": args.workers,
              "load_avg_before": list(os.getloadavg()),
              "lp_num_threads": os.environ.get("LP_NUM_THREADS"), "mujoco_gl": os.environ.get("MUJOCO_GL"),
              "command": " ".join([Path(sys.argv[0]).name, *(argv if argv is not None else sys.argv[1:])])}
    pf = f"parallel_fitness{args.workers}"
    print(f"{'scene':10} {'size':8} {'flow':5} {'naive/s':>8} {'eval/s':>8} {'pf' + str(args.workers) + '/s':>8} "
          f"{'eval/naive':>10} {'pf/naive':>9}  seg==naive pf==eval", flush=True)
    report["runs"] = measure(sizes, args.n, args.naive_n, args.workers)
    if args.compare_lp:
        report["lp_num_threads_check"] = {}
        for name, extra in (("LP_NUM_THREADS=0", []), ("default", ["--lp-default"])):
            with tempfile.TemporaryDirectory() as tmp:
                out = Path(tmp) / "lp.json"
                cmd = [sys.executable, str(Path(__file__).resolve()), "-n", str(args.n), "--naive-n", "0",
                       "--workers", "1", "--sizes", "x".join(map(str, WORKING_SIZE)), "--out", str(out), *extra]
                print(f"in-process evaluator, {name}:", flush=True)
                subprocess.run(cmd, check=True)
                child = json.loads(out.read_text())
            report["lp_num_threads_check"][name] = [
                {k: r[k] for k in ("scene", "width", "height", "flow", "evaluator_evals_per_s")} for r in child["runs"]]
    report["load_avg_after"] = list(os.getloadavg())
    work = [r for r in report["runs"] if (r["width"], r["height"]) == WORKING_SIZE]
    if work:
        keys = ("naive_evals_per_s", "evaluator_evals_per_s", "evaluator_vs_naive", f"{pf}_evals_per_s",
                f"{pf}_vs_naive", f"{pf}_vs_evaluator")
        report["working_size"] = {f"{r['scene']}, {'seg+flow' if r['flow'] else 'seg only'}":
                                  {k: r[k] for k in keys if k in r} for r in work}
        best = {k: v for k, v in report["working_size"].items() if k.endswith("seg only")}
        for label, r in best.items():
            rates = {"evaluator": r["evaluator_evals_per_s"], pf: r.get(f"{pf}_evals_per_s", 0.0)}
            path = max(rates, key=rates.get)
            ratio = f" ({rates[path] / r['naive_evals_per_s']:.1f} x naive)" if "naive_evals_per_s" in r else ""
            line = (f"working size {WORKING_SIZE[0]}x{WORKING_SIZE[1]}: {rates[path]:.1f} evaluations/s{ratio}"
                    f" [{label}, {path}]")
            report.setdefault("summary", []).append(line)
            print(line)
    shards.write_json(args.out, report)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
