"""Benchmark: wall time of one discrepancy workflow run on hidden-effect data, for comparing two
trees back to back (run it in each, one after the other, on the same machine).

Generates ``--clips`` clips of ``--duration`` s at 60 Hz with the hidden ``--effect`` (seed
``--seed``), runs :func:`pipeline.discrepancy.run_workflow` with ``--workers`` processes and
prints its progress lines, the seconds, and what it named; writes a JSON (named effects,
coefficients, intervals, shown gap, final chi-square per clip, seconds) so that two trees'
results can be compared for equality.

Usage (the 1.11x of this stop's README: the tree before it, then this one)::

    cd OLD_TREE && PYTHONPATH=. python benchmarks/workflow_time.py --out /tmp/old.json
    python benchmarks/workflow_time.py --out /tmp/new.json
"""

from __future__ import annotations

import argparse
import json
import time

from pipeline import discrepancy as D


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=3002)
    ap.add_argument("--effect", default="wind")
    ap.add_argument("--clips", type=int, default=4)
    ap.add_argument("--duration", type=float, default=1.0, help="s per clip")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default="workflow_time.json")
    args = ap.parse_args()
    cols, _ = D.generate_hidden(args.seed, D.HiddenConfig(n_clips=args.clips, duration=args.duration, fps=60),
                                effect=args.effect)
    clips = D.clips_from_columns(cols, f"<hidden seed {args.seed}>")
    t0 = time.perf_counter()
    result = D.run_workflow(clips, D.DiscrepancyConfig(workers=args.workers),
                            log=lambda line: print(f"{time.perf_counter() - t0:7.1f} s  {line}", flush=True))
    seconds = time.perf_counter() - t0
    print(f"{seconds:.1f} s, named {[n['effect'] for n in result.named]}")
    with open(args.out, "w") as f:
        json.dump({"seconds": seconds, "named": result.named, "gap": result.gap, "final_chi2": result.final.chi2,
                   "args": vars(args)}, f, indent=1, default=float)


if __name__ == "__main__":
    main()
