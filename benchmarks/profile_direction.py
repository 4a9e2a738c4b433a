"""Benchmark: the direction along which a two-parameter effect (wind, floor tilt) is profiled.

For the wind and floor-tilt trials of the hidden-effect benchmark (``HiddenConfig()`` defaults:
3 clips x 0.8 s at 60 Hz; effect trial ``i`` has seed ``1000 + i`` and cycles through the
effect library, so wind trials are 1001, 1007, ... and tilt trials 1003, 1009, ...), the base
model is fitted (converged, as the workflow does) and the direction of the effect's best
non-null grid point is found two ways:

* ``held``: the clips' parameters held at the base optimum (the rule before this script);
* ``screen``: the linearised screen (:func:`pipeline.discrepancy.screen_candidates`, each
  clip's parameters refitted to first order at each grid point: variable projection), the
  rule of :func:`pipeline.discrepancy.profile._profile_axis` now.

Prints, per trial, both directions and their angle to the true one (deg; grid directions are
45 deg apart, so 22.5 deg is the best a grid point can do in general), and writes
``reports/bench_profile_direction.json``.

Usage::

    MUJOCO_GL=egl .venv/bin/python benchmarks/profile_direction.py            # ~5 min on 2 cores
    MUJOCO_GL=egl .venv/bin/python benchmarks/profile_direction.py --trials 12
"""

from __future__ import annotations

import argparse
import itertools
import math
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from pipeline import discrepancy as D
from pipeline import effects as fx
from pipeline.discrepancy.fit import initial_nuisance, single_threaded_blas
from pipeline.mjcf import SimOptions
from pipeline.shards import write_json

KEYS = {"wind": ("wind_x", "wind_y"), "floor_tilt": ("tilt_x", "tilt_y")}


def held_direction(ws: D.Workspace, idx: list[int], base: D.Fit, name: str) -> dict[str, float]:
    """The rule before: the best non-null point of the effect's grid (full product) with every
    clip's parameters held at the base optimum."""
    cls = fx.REGISTRY[name]
    keys = KEYS[name]
    grids = [cls.parameters[k].grid for k in keys]
    cands = [{**cls.defaults(), **dict(zip(keys, v))} for v in itertools.product(*grids)
             if not all(a == g[0] for a, g in zip(v, grids))]
    total = np.zeros(len(cands))
    for c in idx:
        qs = ws.model(c, [name]).simulate_many([base.nuisance[c]] * len(cands), [{name: p} for p in cands])
        total += [float(r @ r) for r in D.clip_residuals_many(ws.clips[c], qs, ws.weights[c])[0]]
    return cands[int(np.argmin(total))]


def angle(a, b) -> float:
    """Unsigned angle between two 2-vectors, deg."""
    d = math.degrees(math.atan2(a[1], a[0]) - math.atan2(b[1], b[0])) % 360.0
    return min(d, 360.0 - d)


def one_trial(args: tuple[int, str]) -> dict:
    seed, effect = args
    cols, truth = D.generate_hidden(seed, None, None, effect=effect)
    clips = D.clips_from_columns(cols, f"<hidden seed {seed}>")
    ws = D.Workspace(clips, D.DiscrepancyConfig(workers=1, threads=1), SimOptions().model_copy(update={"textured": False}))
    idx = list(range(len(clips)))
    with single_threaded_blas():
        base = ws.fit_each(idx, [initial_nuisance(c) for c in clips], {}, converge=True)
        screen = D.screen_candidates(ws, idx, base, [effect])[effect]["best"]
        held = held_direction(ws, idx, base, effect)
    keys = KEYS[effect]
    true = [truth["parameters"][k] for k in keys]
    return {"seed": seed, "effect": effect, "truth": true, "held": [held[k] for k in keys],
            "screen": [screen[k] for k in keys], "held_off_deg": angle([held[k] for k in keys], true),
            "screen_off_deg": angle([screen[k] for k in keys], true)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=10, help="trials per effect (wind, floor tilt)")
    ap.add_argument("--seed", type=int, default=1000, help="seed of the benchmark's first effect trial")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default="reports/bench_profile_direction.json")
    args = ap.parse_args()
    library = list(fx.REGISTRY)
    jobs = [(args.seed + library.index(e) + len(library) * i, e) for e in KEYS for i in range(args.trials)]
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(one_trial, jobs))
    for r in rows:
        print(f"{r['effect']:10s} seed {r['seed']}  truth ({r['truth'][0]:6.2f}, {r['truth'][1]:6.2f})  "
              f"held {r['held']} {r['held_off_deg']:5.0f} deg   screen {r['screen']} {r['screen_off_deg']:5.0f} deg")
    summary = {}
    for e in KEYS:
        sub = [r for r in rows if r["effect"] == e]
        summary[e] = {k: {"median_deg": float(np.median([r[f"{k}_off_deg"] for r in sub])),
                          "within_30_deg": sum(r[f"{k}_off_deg"] <= 30 for r in sub), "trials": len(sub)}
                      for k in ("held", "screen")}
        print(f"{e}: held median {summary[e]['held']['median_deg']:.0f} deg, <= 30 deg in "
              f"{summary[e]['held']['within_30_deg']}/{len(sub)}; screen median {summary[e]['screen']['median_deg']:.0f} "
              f"deg, <= 30 deg in {summary[e]['screen']['within_30_deg']}/{len(sub)}")
    write_json(Path(args.out), {"summary": summary, "rows": rows,
                                "command": f"python benchmarks/profile_direction.py --trials {args.trials} "
                                           f"--seed {args.seed} --jobs {args.jobs}"})


if __name__ == "__main__":
    main()
