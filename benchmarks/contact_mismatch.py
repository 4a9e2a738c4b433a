"""How well the discrepancy workflow's base model fits data WITHOUT any effect that come from the
independent integrator (``pipeline/discrepancy/independent.py``: impulse bounces, exact
Coulomb friction, RK4), for several base contacts: the contact time constant of the fits and
MuJoCo's friction cone. A base model that cannot fit effect-free data leaves a gap that some
effect will be named for.

    MUJOCO_GL=egl python benchmarks/contact_mismatch.py [--seeds 5000 5006] [--out reports/bench_contact_mismatch.json]

Prints, per setting and clip, the converged per-clip base fit's position RMSE (mm) and
chi-square per residual (1 = the noise), and writes them as JSON.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from pipeline import discrepancy as D
from pipeline.atomic import write_json
from pipeline.discrepancy.independent import IndependentConfig, generate_independent

SETTINGS = [(0.02, "pyramidal"), (0.005, "pyramidal"), (0.0034, "pyramidal"),
            (0.02, "elliptic"), (0.005, "elliptic"), (0.0034, "elliptic")]
"""(contact_timeconst s, friction_cone): the scenes' contact (0.02 s, pyramidal), the workflow's
default since issue 31 (0.005 s, elliptic), and twice the 1/600 s step."""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[5000, 5006])
    ap.add_argument("--out", default="reports/bench_contact_mismatch.json")
    args = ap.parse_args()
    data = IndependentConfig(outlier_rate=0.0, drop_rate=0.0, noise_position=0.0005, noise_angle=0.5)
    rows = []
    t0 = time.perf_counter()
    for timeconst, cone in SETTINGS:
        cfg = D.DiscrepancyConfig(workers=1, threads=1, contact_timeconst=timeconst, friction_cone=cone)
        for seed in args.seeds:
            cols, _ = generate_independent(seed, data, effect="none")
            clips = D.clips_from_columns(cols, f"<independent seed {seed}>")
            ws = D.Workspace(clips, cfg, None)
            with D.single_threaded_blas():
                fit = ws.fit_each(list(range(len(clips))), [D.initial_nuisance(c) for c in clips], {}, converge=True)
            for c, clip in enumerate(clips):
                row = {"contact_timeconst": timeconst, "friction_cone": cone, "seed": seed, "clip": clip.name,
                       "rmse_mm": 1e3 * float(np.sqrt(fit.sq_pos[c] / fit.n_pos[c])),
                       "chi2_per_residual": float(fit.chi2[c] / fit.n_res[c])}
                rows.append(row)
                print(f"{timeconst:7.4f} s {cone:9s} seed {seed} {clip.name:20s} RMSE {row['rmse_mm']:6.2f} mm  "
                      f"chi2/n {row['chi2_per_residual']:8.1f}", flush=True)
    summary = {f"{tc:g} s, {cone}": {"max_chi2_per_residual": max(r["chi2_per_residual"] for r in rows
                                                                 if r["contact_timeconst"] == tc and r["friction_cone"] == cone)}
               for tc, cone in SETTINGS}
    write_json(args.out, {"command": "python benchmarks/contact_mismatch.py " + " ".join(
        ["--seeds", *map(str, args.seeds), "--out", args.out]), "noise_position_m": data.noise_position,
        "summary": summary, "rows": rows, "runtime_s": time.perf_counter() - t0})
    for k, v in summary.items():
        print(f"{k}: worst clip chi2/n {v['max_chi2_per_residual']:.1f}")


if __name__ == "__main__":
    main()
