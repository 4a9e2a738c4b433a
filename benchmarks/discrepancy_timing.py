"""Benchmark: where the discrepancy workflow's time goes on one hidden-effect dataset.

Wraps the :class:`Workspace` fit calls (``fit_many``, ``fit``, ``refit_each``) with a wall
clock, runs :func:`run_workflow` on 8 clips x 1.5 s at 60 Hz (the speed benchmark's data) and
prints the workflow's progress lines (with the profile fits of each interval) and seconds per
(call, calling function), largest first.

Usage::

    MUJOCO_GL=egl .venv/bin/python benchmarks/discrepancy_timing.py --seed 3002 --effect wind   # ~4 min
"""

from __future__ import annotations

import argparse
import collections
import inspect
import time

from pipeline import discrepancy as D
from pipeline.discrepancy.workspace import Workspace

SECONDS: dict[tuple[str, str], float] = collections.defaultdict(float)
CALLS: collections.Counter = collections.Counter()


def _timed(name: str) -> None:
    orig = getattr(Workspace, name)

    def wrapper(self, *args, **kwargs):
        key = (name, inspect.stack()[1].function)
        t0 = time.perf_counter()
        try:
            return orig(self, *args, **kwargs)
        finally:
            SECONDS[key] += time.perf_counter() - t0
            CALLS[key] += 1

    setattr(Workspace, name, wrapper)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=3002)
    ap.add_argument("--effect", default="wind")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    for name in ("fit_many", "fit", "refit_each", "fit_joint_many"):
        _timed(name)
    cols, _ = D.generate_hidden(args.seed, D.HiddenConfig(n_clips=8, duration=1.5, fps=60), effect=args.effect)
    clips = D.clips_from_columns(cols, f"<hidden seed {args.seed}>")
    t0 = time.perf_counter()
    result = D.run_workflow(clips, D.DiscrepancyConfig(workers=args.workers),
                            log=lambda line: print(f"{time.perf_counter() - t0:7.1f} s  {line}", flush=True))
    print(f"total {result.runtime_s:.1f} s, named {[n['effect'] for n in result.named]}")
    for key, sec in sorted(SECONDS.items(), key=lambda kv: -kv[1]):
        print(f"{sec:8.1f} s  {CALLS[key]:4d}x  {key[0]} from {key[1]}")


if __name__ == "__main__":
    main()
