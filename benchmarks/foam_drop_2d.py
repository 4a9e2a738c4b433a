"""Two Tracker-style 2-D exports of a light foam ball's drop (0.4 g, r 15.5 mm, quadratic air
drag, 1 m at 30 fps, 19 samples, 3 mm noise; the file's vertical origin such that the floor is at
y = -24.5 mm and the lowest centre near -9 mm), simulated by the independent integrator
(``pipeline/discrepancy/independent.py``): one bounces (e = 0.5), one stops dead. Each is read
as a Tracker export (the floor estimated under the bounce, ``readers.bounce_floor``) and run
through the workflow; prints the floor found and what is named.

    MUJOCO_GL=egl python benchmarks/foam_drop_2d.py [--out-dir outputs/foam_drop_2d]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from pipeline import discrepancy as D  # noqa: E402
from pipeline.atomic import write_text  # noqa: E402
from pipeline.discrepancy.independent import simulate_sphere  # noqa: E402

RADIUS, MASS, FLOOR = 0.0155, 0.0004, -0.009 - 0.0155
"""m, kg, and the floor's height in the file's frame, m (the centre touches it at -9 mm)."""
AIR = 1.2 * 0.47 * math.pi / 2.4
"""kg/m^3: a smooth sphere (C_d 0.47) in air of 1.2 kg/m^3, in the project's drag units."""


def export(path: Path, e: float, seed: int) -> None:
    """Write the drop (restitution ``e``) as a tab-separated ``t y x`` file."""
    rng = np.random.default_rng(seed)
    t = np.arange(19) / 30.0
    tr = simulate_sphere([0.0, 0.0, 1.0 + RADIUS], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], RADIUS, MASS, 0.5, t,
                         air_density=AIR, restitution=e)
    y = tr.positions[:, 2] + FLOOR + rng.normal(0.0, 0.003, len(t))
    x = tr.positions[:, 0] + rng.normal(0.0, 0.003, len(t))
    write_text(path, "t\ty\tx\n" + "".join(f"{a:.6f}\t{b:.6f}\t{c:.6f}\n" for a, b, c in zip(t, y, x)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out-dir", type=Path, default=Path("outputs/foam_drop_2d"))
    args = ap.parse_args()
    for name, e, seed in (("foam_bounce_e05", 0.5, 0), ("foam_dead", 0.0, 1)):
        path = args.out_dir / f"{name}.txt"
        export(path, e, seed)
        clips = D.read_trajectories([path], {name: {"sphere_0": {"radius": RADIUS, "mass": MASS}}})
        result = D.run_workflow(clips, D.DiscrepancyConfig(recording=False), log=lambda *_: None)
        named = ", ".join(f"{n['effect']} ({', '.join(f'{k}={v:.3g}' for k, v in n['parameters'].items())})"
                          for n in result.named) or "none"
        print(f"{name}: floor at {-clips[0].z_offset * 1e3:.1f} mm (truth {FLOOR * 1e3:.1f}); base RMSE "
              f"{result.base.rmse * 1e3:.2f} mm, noise {result.noise[0].position * 1e3:.2f} mm; named: {named}")


if __name__ == "__main__":
    main()
