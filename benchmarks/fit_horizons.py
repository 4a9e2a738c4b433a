"""Benchmark: how well the per-clip fits reach the noise floor, by continuation horizons.

On hidden-effect datasets (8 clips x 1.5 s at 60 Hz, 1 mm / 1 deg noise) every clip is fitted
on its own from the data (``Workspace.fit_each``, screening budget) with the *true* effect
held, once per ``--horizons`` setting. With the right model and a fit that finds its optimum,
chi-square is about the number of residuals (``n``); a clip far above it is a fit that
stalled. Prints per-clip chi-square, total, ``n`` and seconds (one process, one thread).

Usage::

    MUJOCO_GL=egl .venv/bin/python benchmarks/fit_horizons.py            # ~1 min
    MUJOCO_GL=egl .venv/bin/python benchmarks/fit_horizons.py --datasets 3002:wind --horizons 0.5,1 0.2,0.5,1
"""

from __future__ import annotations

import argparse
import time

from pipeline import discrepancy as D
from pipeline import effects as fx
from pipeline.discrepancy.workspace import Workspace
from pipeline.mjcf import SimOptions


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--datasets", nargs="+", default=["3000:quadratic_drag", "3001:none", "3002:wind"],
                    help="SEED:EFFECT of each hidden dataset")
    ap.add_argument("--horizons", nargs="+", default=["0.5,1", "0.2,0.4,0.7,1"],
                    help="comma-separated clip fractions, one setting each")
    args = ap.parse_args()
    options = SimOptions(textured=False)
    for spec in args.datasets:
        seed, effect = spec.split(":")
        cols, truth = D.generate_hidden(int(seed), D.HiddenConfig(n_clips=8, duration=1.5, fps=60),
                                        effect=effect)
        clips = D.clips_from_columns(cols, f"<hidden seed {seed}>")
        held = {truth["effect"]: {**fx.REGISTRY[truth["effect"]].defaults(), **truth["parameters"]}} \
            if truth["effect"] else {}
        for setting in args.horizons:
            horizons = tuple(float(v) for v in setting.split(","))
            ws = Workspace(clips, D.DiscrepancyConfig(workers=1, threads=1, horizons=horizons), options)
            t0 = time.perf_counter()
            with D.single_threaded_blas():
                fit = ws.fit_each(list(range(len(clips))), [D.initial_nuisance(c) for c in clips], held)
            print(f"seed {seed} {effect:15s} horizons {setting:14s} chi2 {fit.rss:9.0f} for n {sum(fit.n_res)}"
                  f"  per clip {[round(x) for x in fit.chi2]}  {time.perf_counter() - t0:5.1f} s", flush=True)


if __name__ == "__main__":
    main()
