"""Benchmark: the discrepancy workflow on effect-free data measured at the wrong scale, with and
without the mismatch check (issue 31 item 2).

Each dataset is MuJoCo hidden-effect data with no effect (``generate_hidden(seed,
effect="none")``, the fits' contact, 1 mm / 1 deg noise): one clip of 1.5 s and three clips of
0.8 s per seed, every measured position multiplied by ``--scale`` (a ruler calibrated wrong;
orientations and object sizes as they are). Nothing should be named. The workflow runs twice
per dataset: with ``mismatch_terms: []`` (no check) and with the default ``[scale_error]``.
Prints one line per dataset and writes ``reports/bench_scale_mismatch.json`` (named effects,
seconds, the check's profile).

Usage::

    MUJOCO_GL=egl .venv/bin/python benchmarks/scale_mismatch.py            # ~6 min on 2 cores
    MUJOCO_GL=egl .venv/bin/python benchmarks/scale_mismatch.py --scale 1.05 --seeds 3
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from pipeline import discrepancy as D
from pipeline.shards import write_json


def scaled_clips(seed: int, n_clips: int, duration: float, scale: float) -> list:
    """Effect-free hidden data of ``seed`` with every measured position times ``scale``."""
    cols, truth = D.generate_hidden(seed, D.HiddenConfig(n_clips=n_clips, duration=duration), effect="none")
    assert truth["effect"] is None
    cols = {c: ([scale * v for v in vals] if c in ("x", "y", "z") else vals) for c, vals in cols.items()}
    return D.clips_from_columns(cols, f"<seed {seed} at scale {scale:g}>")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scale", type=float, default=0.93, help="factor on every measured position")
    ap.add_argument("--seed", type=int, default=3100, help="first seed")
    ap.add_argument("--seeds", type=int, default=5, help="number of seeds")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default="reports/bench_scale_mismatch.json")
    args = ap.parse_args()
    rows = []
    for seed in range(args.seed, args.seed + args.seeds):
        for n_clips, duration in ((1, 1.5), (3, 0.8)):
            clips = scaled_clips(seed, n_clips, duration, args.scale)
            row = {"seed": seed, "clips": n_clips, "duration_s": duration}
            for label, terms in (("no_check", ()), ("check", ("scale_error",))):
                t0 = time.perf_counter()
                r = D.run_workflow(clips, D.DiscrepancyConfig(workers=args.workers, mismatch_terms=terms),
                                   log=lambda _m: None)
                row[label] = {"named": [n["effect"] for n in r.named], "seconds": time.perf_counter() - t0,
                              "mismatch": [st.get("mismatch") for st in r.steps]}
            rows.append(row)
            print(f"seed {seed} {n_clips} clip(s): no check {row['no_check']['named']}, "
                  f"check {row['check']['named']}", flush=True)
    summary = {"scale": args.scale, "datasets": len(rows),
               "named_without_check": sum(bool(r["no_check"]["named"]) for r in rows),
               "named_with_check": sum(bool(r["check"]["named"]) for r in rows),
               "seconds_without_check": sum(r["no_check"]["seconds"] for r in rows),
               "seconds_with_check": sum(r["check"]["seconds"] for r in rows)}
    print(f"datasets with an effect named (should be none): without the check {summary['named_without_check']}"
          f"/{len(rows)}, with it {summary['named_with_check']}/{len(rows)}")
    write_json(Path(args.out), {"summary": summary, "rows": rows,
                                "command": "python benchmarks/scale_mismatch.py --scale "
                                           f"{args.scale:g} --seed {args.seed} --seeds {args.seeds}"})


if __name__ == "__main__":
    main()
