"""Benchmark: seconds per dataset of the discrepancy workflow (issue 10, item 4).

A dataset is 8 clips x 1.5 s at 60 Hz of hidden-effect data (``HiddenConfig(n_clips=8,
duration=1.5, fps=60)``, 1 mm / 1 deg noise). Each dataset is run, in one process run of this
script, with

* ``serial``: one process, every candidate fully fitted (``workers=1``, ``screen_gain=0``:
  the workflow as it was before the speed work);
* ``fast``: the per-clip fits in a pool of ``--workers`` processes and the linearised screen
  (``screen_gain`` 10, the default) in front of the full candidate fits.

Both must name the same effects (checked; the pool alone changes no number, the screen only
skips candidates that would not have been named). Prints a table and the line
``fast: X s per dataset (Y x serial)``, writes ``reports/bench_discrepancy_speed.json`` with the
seconds, the ratios, the named effects and the load average before and after (the machine may
be shared: compare the ratio taken in one run).

Usage::

    MUJOCO_GL=egl .venv/bin/python benchmarks/discrepancy_speed.py               # ~6 min on 2 cores
    MUJOCO_GL=egl .venv/bin/python benchmarks/discrepancy_speed.py --effects none --skip-serial
    MUJOCO_GL=egl .venv/bin/python benchmarks/discrepancy_speed.py --skip-serial --timestep-ab 0.0025
    MUJOCO_GL=egl .venv/bin/python benchmarks/discrepancy_speed.py --skip-serial --jac-refresh-ab 1
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from pipeline import discrepancy as D
from pipeline.shards import write_json


def run_once(seed: int, effect: str, cfg: D.DiscrepancyConfig, log: bool = False) -> dict:
    """Generate the dataset of ``seed``/``effect`` (on the default settings' model, whatever
    ``cfg`` fits with) and time one workflow run on it; with ``log``, print the workflow's log
    lines with the seconds since its start (where a dataset's time goes, phase by phase)."""
    hidden = D.HiddenConfig(n_clips=8, duration=1.5, fps=60)
    cols, truth = D.generate_hidden(seed, hidden, effect=effect)
    clips = D.clips_from_columns(cols, f"<hidden seed {seed}>")
    t0 = time.perf_counter()

    def say(line: str) -> None:
        print(f"  {time.perf_counter() - t0:7.1f} s | {line}", flush=True)

    result = D.run_workflow(clips, cfg, log=say if log else None)
    return {"seconds": time.perf_counter() - t0, "named": [n["effect"] for n in result.named],
            "truth": truth["effect"], "gap_before_mm": 1e3 * result.gap["before"],
            "gap_after_mm": 1e3 * result.gap["after"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--effects", default="quadratic_drag,none,wind",
                    help="comma-separated hidden effects, one dataset each")
    ap.add_argument("--seed", type=int, default=3000, help="seed of the first dataset")
    ap.add_argument("--workers", type=int, default=2, help="processes of the fast path")
    ap.add_argument("--skip-serial", action="store_true", help="time the fast path only")
    ap.add_argument("--timestep-ab", type=float, default=None, metavar="DT",
                    help="also time each dataset with the fits' step bounded by DT s (discrepancy.timestep), "
                         "same data, alternating with the default in one run: the ratio is the A/B")
    ap.add_argument("--jac-refresh-ab", type=int, default=None, metavar="N",
                    help="also time each dataset with discrepancy.jac_refresh N (1: a finite-difference Jacobian "
                         "on every least-squares iteration), same data, in one run: the ratio is the A/B")
    ap.add_argument("--log", action="store_true",
                    help="print the workflow's log with the seconds since its start (the time per phase)")
    ap.add_argument("--out", default="reports/bench_discrepancy_speed.json")
    args = ap.parse_args()
    ab = {k: v for k, v in (("timestep", args.timestep_ab), ("jac_refresh", args.jac_refresh_ab)) if v is not None}
    load0 = os.getloadavg()
    rows = []
    for i, effect in enumerate(e.strip() for e in args.effects.split(",") if e.strip()):
        seed = args.seed + i
        row = {"seed": seed, "effect": effect,
               "fast": run_once(seed, effect, D.DiscrepancyConfig(workers=args.workers), args.log)}
        if ab:
            row["fast_ab"] = run_once(seed, effect, D.DiscrepancyConfig(workers=args.workers, **ab))
            row["ab_ratio"] = row["fast_ab"]["seconds"] / row["fast"]["seconds"]
            row["ab_same_named"] = row["fast_ab"]["named"] == row["fast"]["named"]
            print(f"{effect:16s} {ab}: {row['fast_ab']['seconds']:6.1f} s named "
                  f"{row['fast_ab']['named']} ({row['ab_ratio']:.2f}x the default's time)", flush=True)
        if not args.skip_serial:
            row["serial"] = run_once(seed, effect, D.DiscrepancyConfig(workers=1, screen_gain=0.0))
            row["ratio"] = row["serial"]["seconds"] / row["fast"]["seconds"]
            row["same_named"] = row["serial"]["named"] == row["fast"]["named"]
        rows.append(row)
        print(f"{effect:16s} fast {row['fast']['seconds']:6.1f} s named {row['fast']['named']}"
              + (f" | serial {row['serial']['seconds']:6.1f} s named {row['serial']['named']} "
                 f"({row['ratio']:.1f}x)" if "serial" in row else ""), flush=True)
    fast = [r["fast"]["seconds"] for r in rows]
    summary = {"datasets": len(rows), "fast_mean_s": sum(fast) / len(fast), "fast_max_s": max(fast),
               "workers": args.workers, "load_before": load0, "load_after": os.getloadavg(),
               "cpu_count": os.cpu_count()}
    if ab:
        t_ab = [r["fast_ab"]["seconds"] for r in rows]
        summary.update(ab_settings=ab, ab_mean_s=sum(t_ab) / len(t_ab), ab_ratio=sum(t_ab) / sum(fast),
                       ab_same_named=all(r["ab_same_named"] for r in rows))
        if args.timestep_ab:
            summary["ab_timestep"] = args.timestep_ab
    if not args.skip_serial:
        serial = [r["serial"]["seconds"] for r in rows]
        summary.update(serial_mean_s=sum(serial) / len(serial), ratio=sum(serial) / sum(fast),
                       same_named=all(r["same_named"] for r in rows))
    write_json(Path(args.out), {"summary": summary, "rows": rows,
                                "command": "python benchmarks/discrepancy_speed.py " + " ".join(
                                    f"--{k.replace('_', '-')}" + ("" if v is True else f" {v}")
                                    for k, v in vars(args).items() if v not in (False, None))})
    print(f"fast: {summary['fast_mean_s']:.1f} s per dataset (max {summary['fast_max_s']:.1f} s)"
          + (f" ({summary['ratio']:.1f}x serial, {summary['serial_mean_s']:.1f} s)" if "ratio" in summary else "")
          + f"; load {load0[0]:.1f} -> {summary['load_after'][0]:.1f}; wrote {args.out}")


if __name__ == "__main__":
    main()
