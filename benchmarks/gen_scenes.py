"""Benchmark: synthetic scene generation, scenes per second per stage (issue 8, item 5).

Runs the five data stages (sample_configs, compile_mjcf, render, flow, events) for N scenes
exactly as ``dvc repro`` does (``python stages/<stage>.py`` in a scratch workspace whose
params.yaml is this repo's with ``sample.n_train = N``, the other splits 0, and
``compute.workers`` set), once per worker count, and times each stage wall-clock (interpreter
and pool start-up included: ~1-2 s per stage, fixed). Scene generation = the five stages.

``--baseline DIR`` also runs the stages of another checkout (e.g. the code before issue 8:
``git archive HEAD pipeline stages | tar -x -C DIR``) with one worker, for a before/after
ratio measured in the same run. ``--legacy`` times the previous render path (a new
``mujoco.Renderer`` per scene, three draws per frame) against the current one in this process
on ``--legacy-n`` scenes and checks that the frames are identical.

Usage::

    MUJOCO_GL=egl .venv/bin/python benchmarks/gen_scenes.py                 # N=200, workers 1 and 2
    MUJOCO_GL=egl .venv/bin/python benchmarks/gen_scenes.py -n 1000 --workers 2 --legacy

Prints a table and writes ``reports/bench_gen_scenes.json``: per run, seconds and scenes/s per
stage and in total, and the load average before it (the machine may be shared: compare ratios
taken in one run).
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

import numpy as np  # noqa: E402

import pipeline  # noqa: E402,F401  (MUJOCO_GL before mujoco)
from pipeline.atomic import write_text  # noqa: E402


# --------------------------------------------------------------------------- the render path before issue 8
def legacy_render(mjcf: str, n: int, T: int, fps: float, W: int, H: int):
    """The render path before issue 8: a fresh ``mujoco.Renderer`` per scene and three draws per
    frame (rgb, segmentation, depth). Returns ``(rgb, seg, depth)`` as the old FrameRenderer."""
    from pipeline.mjcf import compile_model
    from pipeline.render import reference_frames
    from pipeline.simulate import rollout

    model = compile_model(mjcf)
    return reference_frames(model, rollout(model, n, T, fps).qpos, W, H)


# --------------------------------------------------------------------------- driver
STAGES = ("sample_configs", "compile_mjcf", "render", "flow", "events")


def run_stages(n: int, workers: int, params: dict, code: Path, workdir: Path) -> dict:
    """Run the data stages of checkout ``code`` for ``n`` scenes with ``workers`` processes in
    ``workdir``; seconds per stage."""
    import shutil
    import subprocess

    import yaml

    if workdir.exists():
        shutil.rmtree(workdir)
    workdir.mkdir(parents=True)
    p = dict(params)
    p["sample"] = {**params["sample"], "n_train": n, "n_val": 0, "n_test": 0, "n_test_comp": 0}
    p["compute"] = {"workers": workers}
    write_text(workdir / "params.yaml", yaml.safe_dump(p, sort_keys=False))
    env = {**os.environ, "PYTHONPATH": str(code), "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    out = {"workers": workers, "code": str(code), "load_avg_before": list(os.getloadavg()), "stages": {}}
    for stage in STAGES:
        t = time.perf_counter()
        proc = subprocess.run([sys.executable, str(code / "stages" / f"{stage}.py")], cwd=workdir, env=env,
                              capture_output=True, text=True)
        secs = time.perf_counter() - t
        if proc.returncode:
            raise RuntimeError(f"{code}/stages/{stage}.py failed:\n{proc.stderr[-3000:]}")
        out["stages"][stage] = {"s": secs, "scenes_per_s": n / secs}
    out["total_s"] = sum(v["s"] for v in out["stages"].values())
    out["scenes_per_s"] = n / out["total_s"]
    return out


def run_legacy(n: int, seed: int, params: dict) -> dict:
    """Time the old render path against the new one on the same ``n`` scenes, in this process."""
    from pipeline.mjcf import SimOptions, to_xml
    from pipeline.render import render_mjcf
    from pipeline.params import typed_section
    from pipeline.sample_config import SampleConfig
    from pipeline.sampler import SampleChunk, sample_chunk
    from pipeline.scene import Decimals

    W, H = int(params["render"]["width"]), int(params["render"]["height"])
    cfg = typed_section(params, "sample", SampleConfig, required=True, overrides={
        "n_train": n, "n_val": 0, "n_test": 0, "n_test_comp": 0, "width": W, "height": H})
    options = typed_section(params, "sim", SimOptions, required=True)
    decimals = typed_section(params, "scene.decimals", Decimals, required=True)
    scenes, _ = sample_chunk(SampleChunk(cfg, seed, 0, n, decimals, options))
    items = [(to_xml(s, options), len(s.objects), s.n_frames, s.fps) for _, _, s in scenes]
    t = time.perf_counter()
    old = [legacy_render(*it, W, H) for it in items]
    t_old = time.perf_counter() - t
    t = time.perf_counter()
    new = [render_mjcf(*it, W, H)[1] for it in items]
    t_new = time.perf_counter() - t
    same = all(np.array_equal(o[0], f.rgb) and np.array_equal(o[1], f.seg) and np.array_equal(o[2], f.depth)
               for o, f in zip(old, new))
    return {"n": n, "legacy_s": t_old, "legacy_scenes_per_s": n / t_old, "new_s": t_new,
            "new_scenes_per_s": n / t_new, "speedup": t_old / t_new, "identical_frames": same}


def _line(label: str, r: dict) -> str:
    cells = "  ".join(f"{k} {v['scenes_per_s']:6.1f}" for k, v in r["stages"].items())
    return (f"{label:>10}: {cells}  | total {r['scenes_per_s']:5.2f} scenes/s ({r['total_s']:.1f} s; "
            f"load before {r['load_avg_before'][0]:.2f})")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-n", type=int, default=200, help="scenes per run (default 200)")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="worker counts to run (default 1 2)")
    ap.add_argument("--baseline", type=Path, help="checkout with older pipeline/ and stages/ to run with 1 worker")
    ap.add_argument("--legacy", action="store_true", help="also time the old render path in this process")
    ap.add_argument("--legacy-n", type=int, default=50, help="scenes for --legacy (default 50)")
    ap.add_argument("--params", default=str(ROOT / "params.yaml"))
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/bench_gen_scenes"))
    ap.add_argument("--out", default=str(ROOT / "reports" / "bench_gen_scenes.json"))
    args = ap.parse_args(argv)

    from pipeline import shards
    from pipeline.parallel import available_cores
    from pipeline.params import load_params

    params = load_params(args.params)
    report = {"n": args.n, "cores": available_cores(), "render": params["render"], "flow": params["flow"],
              "command": " ".join([Path(sys.argv[0]).name, *(argv if argv is not None else sys.argv[1:])]),
              "runs": []}
    if args.baseline:
        r = run_stages(args.n, 1, params, args.baseline.resolve(), args.workdir / "baseline")
        r["label"] = "baseline"
        report["runs"].append(r)
        print(_line("baseline", r), flush=True)
    for w in args.workers:
        r = run_stages(args.n, w, params, ROOT, args.workdir / f"workers{w}")
        r["label"] = f"workers {w}"
        report["runs"].append(r)
        print(_line(f"workers {w}", r), flush=True)
    base = report["runs"][0]
    for r in report["runs"][1:]:
        r["speedup_vs_first"] = base["total_s"] / r["total_s"]
        print(f"{r['label']}: {r['speedup_vs_first']:.2f}x the scenes/s of {base['label']}")
    if args.legacy:
        leg = run_legacy(args.legacy_n, 0, params)
        report["legacy_render"] = leg
        print(f"render only, one process, {leg['n']} scenes: legacy {leg['legacy_scenes_per_s']:.2f} scenes/s, "
              f"new {leg['new_scenes_per_s']:.2f} scenes/s ({leg['speedup']:.2f}x); identical frames: "
              f"{leg['identical_frames']}")
    shards.write_json(args.out, report)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
