"""Benchmark: the render stage's work and CMA-ES evaluations per second on each ``compute``
backend (issue 13, item 5): local 1 worker, local 2 workers, ray 2 workers (a local Ray
instance this script starts with 2 CPUs).

* Render: ``-n`` sampled scenes (params.yaml's ``sample``/``render``/``sim``), compiled to MJCF
  here, then simulated and rendered (rgb, seg, depth, gt flow; what ``stages/render.py`` does per
  scene, without the shard write) in chunks of ``--chunk`` scenes through
  :func:`pipeline.parallel.parallel_map`. Scenes/s = scenes / wall time of the map.
* CMA-ES: ``--search-scenes`` scenes, each refined by :func:`pipeline.search.cmaes_refine`
  (params ``search``, with ``--popsize`` x ``--iterations``) from its true scene against its
  own rendered clip, chunks of ``--search-chunk`` scenes per task (as ``stages/cmaes.py``).
  Evaluations/s = evaluations / wall time of the map.

The wall time of a map includes starting the local pool (spawn + imports) and, for Ray, the
first tasks' worker start-up; connecting to Ray (starting the local instance) is measured
apart (``ray_init_s``), once. Prints ratios against local 1 worker and writes
``reports/bench_scale.json`` (with the load average before each run: the machine may be shared).

Usage::

    MUJOCO_GL=egl .venv/bin/python benchmarks/scale.py            # -n 48 --search-scenes 8
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import pipeline  # noqa: E402,F401  (MUJOCO_GL before mujoco)
from pipeline.atomic import write_text  # noqa: E402

BACKENDS = {"local1": {"backend": "local", "workers": 1}, "local2": {"backend": "local", "workers": 2},
            "ray2": {"backend": "ray", "address": None, "workers": 2}}


def render_chunk(task: tuple[list[tuple[str, int, int, float]], int, int]) -> int:
    """Simulate and render ``([(mjcf, n_objects, n_frames, fps), ...], W, H)``; returns the count."""
    from pipeline.render import render_mjcf

    scenes, W, H = task
    for mjcf, n, T, fps in scenes:
        render_mjcf(mjcf, n, T, fps, W, H)
    return len(scenes)


def search_chunk(task: tuple) -> int:
    """CMA-ES on ``([(seed, scene, obs_seg, obs_flow), ...], search config, sim options)``;
    returns the evaluations spent."""
    from pipeline.search import EvaluatorPool, cmaes_refine

    scenes, cfg, sim = task
    evaluations = 0
    W, H = scenes[0][2].shape[2], scenes[0][2].shape[1]
    with EvaluatorPool(W, H, sim) as pool:
        for seed, scene, seg, flow in scenes:
            _, history = cmaes_refine(scene, seg, flow, cfg, sim, pool=pool, seed=seed)
            evaluations += history[-1]["evaluations"]
    return evaluations


def make_inputs(args, p: dict):
    """Render tasks and search tasks for ``args`` from params ``p``."""
    from pipeline.mjcf import SimOptions, to_xml
    from pipeline.parallel import chunks
    from pipeline.params import typed_section
    from pipeline.render import render_scene
    from pipeline.sample_config import SampleConfig
    from pipeline.sampler import SampleChunk, sample_chunk
    from pipeline.search import SearchConfig

    W, H = int(p["render"]["width"]), int(p["render"]["height"])
    cfg = typed_section(p, "sample", SampleConfig, required=True, overrides={
        "n_train": args.n, "n_val": 0, "n_test": 0, "n_test_comp": 0, "width": W, "height": H})
    sim = typed_section(p, "sim", SimOptions, required=True)
    scenes = [s for _, _, s in sample_chunk(SampleChunk(cfg, int(p.get("seed", 0)), 0, args.n, None, sim))[0]]
    rows = [(to_xml(s, sim), len(s.objects), s.n_frames, s.fps) for s in scenes]
    render_tasks = [(list(part), W, H) for part in chunks(rows, args.chunk)]
    search_cfg = typed_section(p, "search", SearchConfig,
                               overrides={"popsize": args.popsize, "iterations": args.iterations})
    targets = []
    for i, s in enumerate(scenes[:args.search_scenes]):
        _, frames = render_scene(s, W, H, sim)
        targets.append((i, s, frames.seg, frames.flow))
    search_tasks = [(list(part), search_cfg, sim) for part in chunks(targets, args.search_chunk)]
    return render_tasks, search_tasks


PAPER_SCENES = 400_000
"""Synthetic training scenes of the paper."""
REAL_EVALUATIONS = 235 * 128 * 100
"""235 real videos x CMA-ES popsize 128 x 100 iterations = 3,008,000 re-simulations."""
NODE_CORES = 16
NODES = (1, 8, 64)


def cost_model(run: dict) -> dict:
    """Wall time (h) and core-hours for the paper's workloads on 1, 8 and 64 nodes of
    :data:`NODE_CORES` cores, from ``run``'s measured rates per worker (one worker = one core),
    assuming linear scaling over cores (the tasks are independent; see docs/scale.md)."""
    workers = run["compute"]["workers"]
    out = {}
    for work, total, rate in (("render_400k_scenes", PAPER_SCENES, run["scenes_per_s"] / workers),
                              ("cmaes_235_videos", REAL_EVALUATIONS, run["evaluations_per_s"] / workers)):
        core_hours = total / rate / 3600
        out[work] = {"per_core_per_s": rate, "core_hours": core_hours,
                     "wall_hours": {n: core_hours / (n * NODE_CORES) for n in NODES}}
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-n", type=int, default=48, help="scenes rendered per backend")
    parser.add_argument("--chunk", type=int, default=8, help="scenes per render task")
    parser.add_argument("--search-scenes", type=int, default=8, help="scenes refined per backend")
    parser.add_argument("--search-chunk", type=int, default=2, help="scenes per CMA-ES task")
    parser.add_argument("--popsize", type=int, default=8)
    parser.add_argument("--iterations", type=int, default=4)
    parser.add_argument("--backends", nargs="+", default=list(BACKENDS), choices=list(BACKENDS))
    parser.add_argument("--out", default="reports/bench_scale.json")
    args = parser.parse_args(argv)

    from pipeline.parallel import ComputeConfig, parallel_map, ray_connect, ray_shutdown
    from pipeline.params import load_params

    p = load_params(ROOT / "params.yaml")
    render_tasks, search_tasks = make_inputs(args, p)
    results = {}
    for name in args.backends:
        compute = ComputeConfig(**BACKENDS[name])
        run = {"compute": compute.model_dump(), "load_before": os.getloadavg()[0]}
        if compute.backend == "ray":
            t = time.perf_counter()
            ray_connect(compute)
            run["ray_init_s"] = time.perf_counter() - t
        t = time.perf_counter()
        n = sum(parallel_map(render_chunk, render_tasks, compute))
        run["render_s"] = time.perf_counter() - t
        run["scenes_per_s"] = n / run["render_s"]
        t = time.perf_counter()
        evaluations = sum(parallel_map(search_chunk, search_tasks, compute))
        run["search_s"] = time.perf_counter() - t
        run["evaluations"] = evaluations
        run["evaluations_per_s"] = evaluations / run["search_s"]
        if compute.backend == "ray":
            ray_shutdown()
        results[name] = run
        print(f"{name:7s} render {n} scenes {run['render_s']:6.1f} s = {run['scenes_per_s']:5.2f} scenes/s; "
              f"cmaes {evaluations} evals {run['search_s']:6.1f} s = {run['evaluations_per_s']:6.1f} evals/s",
              flush=True)
    base = results.get("local1")
    if base:
        for name, run in results.items():
            run["render_ratio"] = run["scenes_per_s"] / base["scenes_per_s"]
            run["search_ratio"] = run["evaluations_per_s"] / base["evaluations_per_s"]
            print(f"{name:7s} vs local1: render x{run['render_ratio']:.2f}, cmaes x{run['search_ratio']:.2f}")
    basis = "local1" if "local1" in results else next(iter(results))  # one dedicated core: the per-core rate
    model = cost_model(results[basis])
    print(f"cost model from {basis} (per-core rate), nodes of {NODE_CORES} cores, linear scaling assumed:")
    for work, m in model.items():
        walls = ", ".join(f"{n} node(s) {m['wall_hours'][n]:.2f} h" for n in NODES)
        print(f"  {work}: {m['per_core_per_s']:.2f}/s per core, {m['core_hours']:.0f} core-hours; wall {walls}")
    report = {"command": "python benchmarks/scale.py " + " ".join(argv if argv is not None else sys.argv[1:]),
              "cores": len(os.sched_getaffinity(0)), "n_scenes": args.n, "chunk": args.chunk,
              "search_scenes": args.search_scenes, "popsize": args.popsize, "iterations": args.iterations,
              "render_size": [int(p["render"]["width"]), int(p["render"]["height"])], "runs": results,
              "cost_model": {"basis": basis, "node_cores": NODE_CORES, **model}}
    out = ROOT / args.out
    write_text(out, json.dumps(report, indent=2))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
