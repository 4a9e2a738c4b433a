"""Benchmark: how far a sliding ball lifts off the floor under the discrepancy fits' contact.

A ball that slides on a rigid floor stays on it. MuJoCo's convex contact model does not quite:
the friction of a soft contact at a large slip pushes the bodies apart a little (MuJoCo
documentation, "Computation": the soft, convex contact model trades exact complementarity for
a unique solution, so sliding contacts can separate slightly). With the fits' stiff contact
(``discrepancy.contact_timeconst`` 0.005 s, critically damped, elliptic cone;
:func:`pipeline.discrepancy.config.fit_options`) at the params timestep of 1/600 s, that is
three steps per time constant, and the lift is measured here, against the timestep, the
integrator, the friction and the slip speed, and with the friction dimensions of the floor
contact given their own, softer time constant (an MJCF ``pair`` with ``solreffriction``). It also measures the rebound and the sinking of a
ball dropped from 1 m (restitution 0 in the base model: a critically damped contact).

Each row simulates one scene (``pipeline.scene``, compiled by ``pipeline.mjcf.compile_model``
with the fits' options), a solid ball of radius 3 cm and 20 g started on the floor with a
horizontal velocity and no spin (sliding), or dropped from rest. Printed as a table and written
to ``reports/bench_sliding_hop.json``; runs in seconds.

Usage::

    MUJOCO_GL=egl .venv/bin/python benchmarks/sliding_hop.py
"""

from __future__ import annotations

import argparse
from pathlib import Path

import mujoco

from pipeline.discrepancy.config import DiscrepancyConfig, fit_options
from pipeline.mjcf import SimOptions, build_mjcf, initial_state
from pipeline.scene import Scene
from pipeline.shards import write_json

RADIUS, MASS = 0.03, 0.02
V_AT = 0.05
"""s, when the ball's horizontal speed is reported: a ball sliding on the floor slows by
``mu g`` (Coulomb), ``v = v0 - mu g t`` until it rolls at ``5/7 v0`` (after ``2 v0 / (7 mu g)``,
0.087 s for 1.5 m/s and mu 0.5)."""


def ball_run(timestep: float, integrator: str, mu: float, speed: float, height: float | None,
             duration: float = 0.6, friction_timeconst: float | None = None) -> dict[str, float]:
    """Lift (max height of the ball's bottom above the floor after first contact, mm) and sink
    (deepest penetration, mm) of one ball run: sliding at ``speed`` m/s from the floor
    (``height`` None) or dropped from ``height`` m. ``friction_timeconst``: the floor contact
    as an explicit MJCF ``pair`` whose friction dimensions get their own ``solreffriction``
    (that time constant, critically damped; the normal keeps the fits' contact), instead of
    the geoms' contact."""
    z0 = RADIUS if height is None else height
    scene = Scene.from_dict({"duration": duration, "fps": 60, "gravity": 9.81,
                             "camera": {"height": 1.2, "pitch": 35.0, "fov": 45.0},
                             "objects": [{"shape": "sphere", "size": {"radius": RADIUS}, "mass": MASS,
                                          "position": [0.0, 0.0, z0], "linear_velocity": [speed, 0.0, 0.0],
                                          "material": {"sliding_friction": mu}}]})
    options = fit_options(SimOptions(timestep=timestep, integrator=integrator), DiscrepancyConfig())
    root = build_mjcf(scene, options)
    if friction_timeconst is not None:
        ball = root.find("geom", f"{scene.object_names[0]}_geom")
        root.contact.add("exclude", body1="world", body2=ball.parent)
        root.contact.add("pair", geom1="floor", geom2=ball, condim=6, friction=[mu, mu, 0.0, 0.0, 0.0],
                         solref=list(options.object_solref), solreffriction=[friction_timeconst, 1.0])
    model = mujoco.MjModel.from_xml_string(root.to_xml_string())
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = initial_state(scene)
    mujoco.mj_forward(model, data)
    landed, lift, sink, v_at = False, 0.0, 0.0, None
    for k in range(int(round(duration / model.opt.timestep))):
        mujoco.mj_step(model, data)
        landed = landed or data.ncon > 0
        if landed:
            gap = float(data.qpos[2]) - RADIUS
            lift, sink = max(lift, gap), min(sink, gap)
        if v_at is None and (k + 1) * model.opt.timestep >= V_AT - 1e-9:
            v_at = float(data.qvel[0])
    return {"lift_mm": 1e3 * lift, "sink_mm": -1e3 * sink, "v_at_mps": v_at}


def coulomb(v0: float, mu: float, g: float = 9.81) -> float:
    """m/s, the horizontal speed at :data:`V_AT` of a solid ball started sliding at ``v0`` without
    spin: ``max(v0 - mu g t, 5/7 v0)``."""
    return max(v0 - mu * g * V_AT, 5.0 / 7.0 * v0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="reports/bench_sliding_hop.json")
    args = ap.parse_args()
    rows = []
    cases = ([("slide", 1 / 600, "implicitfast", 0.5, v, None) for v in (0.5, 1.0, 1.5, 2.5)]
             + [("slide", 1 / 600, "implicitfast", mu, 1.5, None) for mu in (0.1, 1.0)]
             + [("slide", ts, "implicitfast", 0.5, 1.5, None) for ts in (1 / 1200, 1 / 2400)]
             + [("slide", 1 / 600, integ, 0.5, 1.5, None) for integ in ("Euler", "RK4")]
             + [("drop 1 m", ts, "implicitfast", 0.5, 0.0, 1.0) for ts in (1 / 600, 1 / 1200, 1 / 2400)])
    cases = [(*c, None) for c in cases] + [("slide", 1 / 600, "implicitfast", 0.5, v, None, tc)
                                           for tc in (0.01, 0.02) for v in (1.5, 2.5)]
    print(f"{'run':9s} {'timestep':>9s} {'integrator':>12s} {'mu':>4s} {'v m/s':>6s} {'friction tc':>12s} "
          f"{'lift mm':>8s} {'sink mm':>8s} {'v(0.05 s)':>9s} {'Coulomb':>8s}")
    for kind, ts, integ, mu, v, h, tc in cases:
        r = ball_run(ts, integ, mu, v, h, friction_timeconst=tc)
        rows.append({"run": kind, "timestep": ts, "integrator": integ, "mu": mu, "speed": v,
                     "friction_timeconst": tc, "v_at_coulomb_mps": coulomb(v, mu) if h is None else None, **r})
        print(f"{kind:9s} {f'1/{round(1 / ts)}':>9s} {integ:>12s} {mu:4.1f} {v:6.1f} "
              f"{'contact' if tc is None else f'pair {tc:g} s':>12s} {r['lift_mm']:8.2f} {r['sink_mm']:8.2f} "
              f"{r['v_at_mps']:9.3f} {coulomb(v, mu) if h is None else float('nan'):8.3f}")
    write_json(Path(args.out), {"rows": rows, "radius_m": RADIUS, "mass_kg": MASS,
                                "contact": "fit_options(SimOptions(timestep, integrator), DiscrepancyConfig())",
                                "command": "python benchmarks/sliding_hop.py"})
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
