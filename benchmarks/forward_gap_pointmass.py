"""Independent check of the one-clip forward gap on the shared ping-pong drop (issue 10).

A plain point mass (scipy ``solve_ivp``, no MuJoCo, no project code) with no drag, linear
drag ``a = -g - c v`` or quadratic drag ``a = -g - c * 0.5 * C_D * A * v|v| / m`` (C_D 0.47,
A = pi r^2; c is then an air density, kg/m^3) is fitted (``least_squares``) to the vertical
track's first 60 % (the workflow's ``discrepancy.forward_split``) and forecast over the rest,
and fitted to the whole clip for comparison. It shows whether *any* of these laws, fitted on
the first part, forecasts the rest of this clip: if none does, the workflow cannot either.

    python benchmarks/forward_gap_pointmass.py [--split 0.6] [--skip 0]

``--skip N`` drops the first N samples (the ball may still be held at the start).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import least_squares
from tabulate import tabulate

CLIP = Path(__file__).resolve().parents[1] / ".." / "shared/data/real/trajectories/kseuro_balldrop_white_pingpong.txt"
MASS, RADIUS, G, CD = 0.0028, 0.0201, 9.81, 0.47   # SOURCES.md: m = 2.80 g, r = 20.1 mm


def simulate(p: np.ndarray, t: np.ndarray, law: str) -> np.ndarray:
    """Height z(t) (m) at times ``t`` (s, increasing) from ``p = (z0 m, v0 m/s, c)``."""
    area = np.pi * RADIUS ** 2

    def rhs(_, y):
        v = y[1]
        drag = {"none": 0.0, "linear": p[2] * v, "quadratic": p[2] * 0.5 * CD * area * v * abs(v) / MASS}[law]
        return [v, -G - drag]

    return solve_ivp(rhs, (t[0], t[-1]), [p[0], p[1]], t_eval=t, rtol=1e-10, atol=1e-12).y[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--split", type=float, default=0.6)
    ap.add_argument("--skip", type=int, default=0)
    a = ap.parse_args()
    d = np.loadtxt(CLIP, skiprows=1)        # columns t, y (up), x
    t, z = d[a.skip:, 0], d[a.skip:, 1]
    n_fit = int(np.sum(t <= t[0] + a.split * (t[-1] - t[0])))
    print(f"{CLIP.name}: {len(t)} samples, fit on the first {n_fit} (t <= {t[n_fit - 1]:.3f} s), forecast {len(t) - n_fit}")
    rows = []
    for law in ("none", "linear", "quadratic"):
        hi = 1e-12 if law == "none" else np.inf
        bounds = ([-np.inf, -np.inf, 0.0], [np.inf, np.inf, hi])
        p0 = [z[0], 0.0, 0.0 if law == "none" else 0.1]
        part = least_squares(lambda p: simulate(p, t[:n_fit], law) - z[:n_fit], p0, bounds=bounds)
        fore = simulate(part.x, t, law)[n_fit:] - z[n_fit:]
        whole = least_squares(lambda p: simulate(p, t, law) - z, part.x, bounds=bounds)
        rows.append([law, f"{part.x[2]:.3f}", f"{1e3 * np.sqrt(np.mean(fore ** 2)):.2f}", f"{whole.x[2]:.3f}",
                     f"{1e3 * np.sqrt(np.mean(whole.fun ** 2)):.2f}"])
    print(tabulate(rows, ["law", "c fitted on the first part", "forecast RMSE (mm)", "c on the whole clip",
                          "whole-clip RMSE (mm)"], tablefmt="github", disable_numparse=True))


if __name__ == "__main__":
    main()
