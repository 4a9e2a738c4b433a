"""Hidden-effect data: measured trajectories simulated with one effect from the library (or
none) at a random strength, plus noise; the truth is returned apart."""

from __future__ import annotations

import math
from typing import Any

import mujoco
import numpy as np
from pydantic import Field

from pipeline import effects as fx
from pipeline.discrepancy.config import DISCREPANCY_DECIMALS, DiscrepancyConfig, StrictModel, fit_options
from pipeline.discrepancy.trajectories import QUAT_COLUMNS, SPEC_COLUMNS, TABLE_COLUMNS
from pipeline.mjcf import SimOptions, compile_model
from pipeline.rotation import quat_mul, rotvec_to_quat
from pipeline.scene import Scene
from pipeline.simulate import sample_qpos


HIDDEN_KINDS = ("throw", "spin_slide", "throw", "roll")
"""Clip kinds of hidden-effect data, cycled: a light spinning sphere thrown so it flies, lands
and rolls; a heavier sphere pushed along the floor, sliding and spinning about the vertical;
a sphere rolling with some spin about the vertical."""


DEFAULT_STRENGTHS: dict[str, dict[str, tuple[float, float]]] = {
    "quadratic_drag": {"density": (3.0, 12.0)},
    "wind": {"speed": (2.0, 5.0)},
    "restitution": {"e": (0.4, 0.85)},
    "floor_tilt": {"tilt": (1.5, 5.0)},
    "magnus_lift": {"lift": (0.6, 2.0)},
    "torsional_friction": {"mu_torsion": (0.005, 0.03)},
}
"""Per effect, per parameter ``[low, high]`` of the hidden strength's uniform draw (``wind`` and
``floor_tilt``: the magnitude, m/s and deg); the default of both generators' ``strengths``."""


class HiddenConfig(StrictModel):
    """Hidden-effect data (params section ``measure_hidden``).

    Attributes:
        effect: ``random`` (uniform over the library and ``none``), ``none`` or an effect name.
        n_clips: clips per data set (kinds cycle through ``kinds``).
        kinds: clip kinds, from ``throw``, ``spin_slide``, ``roll`` (:data:`HIDDEN_KINDS`).
        duration: s per clip. fps: samples per second.
        noise_position: m, Gaussian noise on each coordinate.
        noise_angle: deg, Gaussian noise on each rotation-vector component of the orientation.
        orientation: write measured orientations (``qw..qz``).
        strengths: per effect, per parameter ``[low, high]`` of the uniform draw; for
            ``wind`` and ``floor_tilt`` the range is the magnitude (``speed`` m/s, ``tilt``
            deg) and the direction is uniform.
    """

    effect: str = "random"
    n_clips: int = Field(3, ge=1)
    duration: float = Field(0.8, gt=0, le=10)
    fps: int = Field(60, ge=5, le=1000)
    noise_position: float = Field(0.001, ge=0)
    noise_angle: float = Field(1.0, ge=0)
    orientation: bool = True
    kinds: tuple[str, ...] = HIDDEN_KINDS
    strengths: dict[str, dict[str, tuple[float, float]]] = DEFAULT_STRENGTHS

    def model_post_init(self, _ctx: Any) -> None:
        if not self.kinds or any(k not in ("throw", "spin_slide", "roll") for k in self.kinds):
            raise ValueError(f"kinds: each must be throw, spin_slide or roll, got {list(self.kinds)}")
        if self.effect not in ("random", "none") and self.effect not in fx.EFFECTS:
            raise ValueError(f"effect: must be random, none or one of {', '.join(fx.EFFECTS)}, got {self.effect!r}")


def draw_effect(rng: np.random.Generator, cfg: HiddenConfig, effect: str | None = None
                ) -> tuple[str | None, dict[str, float]]:
    """Draw the hidden effect and its strength.

    Args:
        rng: random generator (consumed: the effect if ``random``, then its parameters).
        cfg: ``effect`` and ``strengths`` ranges.
        effect: overrides ``cfg.effect`` (``random``, ``none`` or a name).

    Returns:
        ``(name or None, parameters)``: the fitted parameters of the effect drawn uniformly in
        their ``strengths`` range (units of ``ParamSpec.unit``); ``wind`` and ``floor_tilt``
        as a magnitude in its range (m/s, deg) in a uniform direction (``wind_x``/``wind_y``,
        ``tilt_x``/``tilt_y``).
    """
    name = effect or cfg.effect
    if name == "random":
        name = str(rng.choice(["none", *fx.EFFECTS]))
    if name == "none":
        return None, {}
    ranges = cfg.strengths.get(name, {})
    if name == "wind":
        speed, ang = rng.uniform(*ranges.get("speed", (2.0, 5.0))), rng.uniform(0, 2 * math.pi)
        return name, {"wind_x": speed * math.cos(ang), "wind_y": speed * math.sin(ang)}
    if name == "floor_tilt":
        tilt, ang = rng.uniform(*ranges.get("tilt", (1.5, 5.0))), rng.uniform(0, 2 * math.pi)
        return name, {"tilt_x": tilt * math.cos(ang), "tilt_y": tilt * math.sin(ang)}
    params = {}
    for p, spec in fx.REGISTRY[name].parameters.items():
        if spec.fit:
            lo, hi = ranges.get(p, (spec.default, spec.default))
            params[p] = float(rng.uniform(lo, hi))
    return name, params


def _hidden_object(rng: np.random.Generator, kind: str, index: int) -> dict[str, Any]:
    """Scene object (dict) of a hidden-effect clip of ``kind``."""
    u = rng.uniform
    heading = u(0, 2 * math.pi)
    hdir = np.array([math.cos(heading), math.sin(heading), 0.0])
    if kind == "throw":
        r = u(0.02, 0.035)
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        v = hdir * u(1.0, 2.5) + np.array([0, 0, u(0.5, 2.5)])
        return {"shape": "sphere", "size": {"radius": r}, "mass": u(0.004, 0.02),
                "position": [u(-0.3, 0.3), u(-0.3, 0.3), u(0.3, 0.7)], "linear_velocity": v.tolist(),
                "angular_velocity": (axis * u(30, 80)).tolist(),
                "material": {"sliding_friction": u(0.3, 0.7), "rolling_friction": 0.0, "damping": 0.0}}
    if kind == "roll":
        r = u(0.02, 0.04)
        v = hdir * u(0.5, 1.5)
        w = np.cross([0, 0, 1.0], v) / r + np.array([0, 0, u(-30, 30)])
        return {"shape": "sphere", "size": {"radius": r}, "mass": u(0.005, 0.05),
                "position": [u(-0.3, 0.3), u(-0.3, 0.3), r], "linear_velocity": v.tolist(),
                "angular_velocity": w.tolist(),
                "material": {"sliding_friction": u(0.3, 0.7), "rolling_friction": 0.0, "damping": 0.0}}
    # spin_slide: a sphere pushed along the floor without rolling, spinning about the vertical.
    # (Not a box or cylinder: MuJoCo's flat-face contacts make a sliding, spinning box or
    # cylinder ill-conditioned: a 1e-5 m change of its initial height or a 1e-4 change of its
    # friction moved it by up to 10 mm within 1 s, so no fit reaches the noise.)
    r = u(0.025, 0.045)
    return {"shape": "sphere", "size": {"radius": r}, "mass": u(0.03, 0.2), "position": [u(-0.3, 0.3), u(-0.3, 0.3), r],
            "linear_velocity": (hdir * u(1.0, 2.0)).tolist(),
            "angular_velocity": [0.0, 0.0, float(u(20, 50) * rng.choice([-1, 1]))],
            "material": {"sliding_friction": u(0.15, 0.4), "rolling_friction": 0.0, "damping": 0.0}}


def generate_hidden(seed: int, cfg: HiddenConfig | None = None, options: SimOptions | None = None,
                    effect: str | None = None, fit: DiscrepancyConfig | None = None
                    ) -> tuple[dict[str, list], dict[str, Any]]:
    """Measured trajectories generated with one hidden effect (or none) plus noise.

    Every clip is simulated by the same MuJoCo bridge as the workflow (scene -> MJCF ->
    MuJoCo) with the drawn effect at the drawn strength, sampled at ``fps``, and corrupted by
    Gaussian position noise and orientation noise (``q exp(n)``, ``n`` per axis).

    Args:
        seed: random seed (clips, effect, strength, noise).
        cfg: settings.
        options: simulation options (params ``sim``), with the base contact of the workflow's
            fits (:func:`pipeline.discrepancy.config.fit_options` of ``fit``, default
            settings when ``None``): the data's base model is the one the workflow fits.
        effect: overrides ``cfg.effect`` (``none``, a name, or ``random``).
        fit: the workflow settings whose contact the data share.

    Returns:
        ``(columns, truth)``: ``columns`` maps each table column (:data:`TABLE_COLUMNS`,
        :data:`QUAT_COLUMNS` if ``orientation``, :data:`SPEC_COLUMNS`) to a list of values;
        ``truth`` is ``{seed, effect, parameters, clips: [{clip, kind, scene}]}`` and must be
        stored apart from the measurements.
    """
    cfg = cfg or HiddenConfig()
    options = fit_options(options, fit or DiscrepancyConfig())
    rng = np.random.default_rng(seed)
    name, params = draw_effect(rng, cfg, effect)
    cols: dict[str, list] = {c: [] for c in TABLE_COLUMNS + (QUAT_COLUMNS if cfg.orientation else ()) + SPEC_COLUMNS}
    truth: dict[str, Any] = {"seed": seed, "effect": name, "parameters": params, "clips": []}
    times = np.arange(int(round(cfg.duration * cfg.fps)) + 1) / cfg.fps
    for c in range(cfg.n_clips):
        kind = cfg.kinds[c % len(cfg.kinds)]
        obj = _hidden_object(rng, kind, c)
        scene = Scene.from_dict({"duration": cfg.duration, "fps": cfg.fps, "camera": {"height": 1.2},
                                 "objects": [obj],
                                 "effects": [{"effect": name, "parameters": params}] if name else []})
        model = compile_model(scene, options)
        qpos = sample_qpos(model, mujoco.MjData(model), 1, times)[:, 0]
        clip_id = f"clip_{c:02d}_{kind}"
        obj_name = f"{obj['shape']}_0"
        pos = qpos[:, :3] + rng.normal(0.0, cfg.noise_position, (len(times), 3))
        quat = quat_mul(qpos[:, 3:], rotvec_to_quat(rng.normal(0.0, math.radians(cfg.noise_angle), (len(times), 3))))
        for k, t in enumerate(times):
            cols["clip"].append(clip_id)
            cols["object"].append(obj_name)
            cols["t"].append(float(t))
            for j, a in enumerate("xyz"):
                cols[a].append(float(pos[k, j]))
            if cfg.orientation:
                for j, a in enumerate(QUAT_COLUMNS):
                    cols[a].append(float(quat[k, j]))
            cols["shape"].append(obj["shape"])
            for key in ("radius", "width", "depth", "height"):
                cols[key].append(obj["size"].get(key))
            cols["mass"].append(float(obj["mass"]))
        truth["clips"].append({"clip": clip_id, "kind": kind, "object": obj,
                               "scene": scene.to_yaml(DISCREPANCY_DECIMALS)})
    return cols, truth
