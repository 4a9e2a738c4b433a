"""A clip's base model in MuJoCo: the per-object parameters (:data:`NUISANCE`), the scene built
from them, the compiled-once model rolled out in place (:class:`ClipModel`) and the
noise-normalised residuals against the measurements (:func:`clip_residuals`)."""

from __future__ import annotations

import copy
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any, Mapping, Sequence

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from pipeline import effects as fx
from pipeline import engine
from pipeline.rotation import quat_conj, quat_mul, quat_to_mat, quat_to_rotvec, rotvec_to_quat
from pipeline.discrepancy.trajectories import Clip
from pipeline.mjcf import SimOptions, initial_state
from pipeline.scene import Scene
from pipeline.simulate import interpolate_qpos, sample_steps


NUISANCE = ("px", "py", "pz", "vx", "vy", "vz", "rx", "ry", "rz", "wx", "wy", "wz",
            "damping", "friction")
"""Per-object base-model parameters fitted per clip: initial position (m), orientation
perturbation (rotation vector, rad, body frame, relative to the reference orientation),
linear velocity (m/s, world), angular velocity (rad/s, world), ``material.damping``
(freejoint damping, N s/m) and ``material.sliding_friction``."""
# Indices into one object's row of the ``(n, 14)`` parameter array (order of :data:`NUISANCE`).
NUISANCE_POSITION = slice(0, 3)
"""Initial position ``px, py, pz`` (m, world)."""
NUISANCE_VELOCITY = slice(3, 6)
"""Initial linear velocity ``vx, vy, vz`` (m/s, world)."""
NUISANCE_ROTATION = slice(6, 9)
"""Orientation perturbation ``rx, ry, rz`` (rotation vector, rad, body frame, relative to the
reference orientation)."""
NUISANCE_ANGULAR_VELOCITY = slice(9, 12)
"""Initial angular velocity ``wx, wy, wz`` (rad/s, world)."""
NUISANCE_DAMPING = 12
"""``material.damping`` (freejoint damping, N s/m; a scalar column)."""
NUISANCE_FRICTION = 13
"""``material.sliding_friction`` (dimensionless Coulomb coefficient; a scalar column)."""


def clip_scene(clip: Clip, nuis: np.ndarray | None = None, effects: Mapping[str, Mapping[str, float]] | None = None,
               qref: np.ndarray | None = None) -> Scene:
    """Scene of a clip: its objects with the initial state and material of ``nuis``, its static
    geometry (``clip.static``: ramps of a ``dynamics infer`` scene) and the given effects.

    Args:
        clip: the clip (objects, duration, frame rate).
        nuis: ``(n, 14)`` float per-object parameters (:data:`NUISANCE`; SI units), or ``None``
            for placeholders (objects stacked at rest above the floor).
        effects: ``{effect: {parameter: value}}`` written to the scene's ``effects:`` block.
        qref: ``(n, 4)`` reference orientations (w, x, y, z) that ``nuis``' rotation vectors
            perturb; required where ``nuis`` is given.

    Returns:
        The validated :class:`Scene` (duration capped at 60 s, fps at 10000).

    Raises:
        pipeline.scene.SceneError: where the values do not make a valid scene.
    """
    objs = []
    for i, tr in enumerate(clip.tracks):
        if nuis is None:
            pos = [0.0, 0.0, 1.0 + 0.5 * i]
            q, v, w, damping, friction = (1.0, 0.0, 0.0, 0.0), [0.0] * 3, [0.0] * 3, 0.0, 0.5
        else:
            x = nuis[i]
            pos = x[NUISANCE_POSITION].tolist()
            q = tuple(quat_mul(qref[i], rotvec_to_quat(x[NUISANCE_ROTATION])).tolist())
            v, w = x[NUISANCE_VELOCITY].tolist(), x[NUISANCE_ANGULAR_VELOCITY].tolist()
            damping, friction = float(x[NUISANCE_DAMPING]), float(x[NUISANCE_FRICTION])
        objs.append({**tr.spec.scene_dict(), "position": pos, "orientation": q,
                     "linear_velocity": v, "angular_velocity": w,
                     "material": {"sliding_friction": friction, "rolling_friction": 0.0, "damping": damping}})
    duration = float(min(max(clip.times[-1], 1e-3), 60.0))
    data = {"duration": duration, "fps": min(clip.fps, 10000), "gravity": 9.81,
            "camera": {"height": 1.2, "pitch": 35.0, "fov": 45.0}, "objects": objs, "static": list(clip.static),
            "effects": [{"effect": k, "parameters": dict(v)} for k, v in (effects or {}).items()]}
    return Scene.from_dict(data, source=f"clip {clip.name}")


_ROLLOUTS: dict[int, Any] = {}


def _rollout_runner(nthread: int):
    """A persistent ``mujoco.rollout.Rollout`` with ``nthread`` threads (0: calling thread)."""
    if nthread not in _ROLLOUTS:
        _ROLLOUTS[nthread] = mj_rollout.Rollout(nthread=nthread)
    return _ROLLOUTS[nthread]


class ClipModel:
    """A clip's scene compiled once for a set of effects; every evaluation edits copies of the
    model in place (effect values via :func:`pipeline.effects.configure_model`, per-object
    damping and friction) and rolls them out from the initial state with
    ``mujoco.rollout`` (many variants per call, e.g. a finite-difference Jacobian, on
    ``threads`` threads). Positions are interpolated linearly between the two physics steps
    around each sample time (quaternions: normalised lerp).

    Args:
        clip: the clip.
        effects: names of the effects present (values are set per call).
        options: simulation options (params ``sim``).
        gravity: m/s^2.
        threads: rollout threads (1: the calling thread).
    """

    def __init__(self, clip: Clip, effects: Sequence[str], options: SimOptions, gravity: float = 9.81,
                 threads: int = 1):
        self.clip = clip
        self.effects = tuple(effects)
        scene = clip_scene(clip).replace(gravity=gravity)
        self.model, self.base, self.geoms = engine.compile_for_fit(scene, self.effects, options)
        self.threads = max(1, int(threads))
        self.datas = [mujoco.MjData(self.model) for _ in range(self.threads)]
        self.pool: list[mujoco.MjModel] = [self.model]
        self.n = len(clip.tracks)
        self.times = clip.times
        self.qref = np.array([tr.quat[0] if tr.quat is not None else np.array([1.0, 0, 0, 0])
                              for tr in clip.tracks])
        # the rule of pipeline.simulate.sample_steps: step k (and k - 1 with weight 1 - frac)
        self._k, self._frac = sample_steps(self.times, float(self.model.opt.timestep))
        self.nstep = int(self._k.max())
        self._spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        self._nstate = mujoco.mj_stateSize(self.model, self._spec)

    def _configure(self, m: mujoco.MjModel, nuis: np.ndarray, effect_values: Mapping[str, Mapping[str, float]]) -> None:
        engine.configure_model(m, self.base, self.geoms, effect_values)
        m.geom_friction[self.geoms, 0] = nuis[:, NUISANCE_FRICTION]
        m.dof_damping[: 6 * self.n] = np.repeat(nuis[:, NUISANCE_DAMPING], 6)

    def orientations(self, nuis: np.ndarray) -> np.ndarray:
        """``(..., n, 4)`` initial quaternions (w, x, y, z) of per-object parameters
        ``nuis (..., n, 14)``: the reference orientation rotated by the perturbation
        ``x[NUISANCE_ROTATION]`` (one rotation call for any batch of variants)."""
        return quat_mul(self.qref, rotvec_to_quat(nuis[..., NUISANCE_ROTATION]))

    def initial(self, nuis: np.ndarray, quats: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """MuJoCo ``qpos (7n,)``, ``qvel (6n,)`` of per-object parameters ``nuis (n, 14)``
        (angular velocity converted to the body frame by ``pipeline.mjcf.initial_state``);
        ``quats (n, 4)``: their :meth:`orientations` where already computed."""
        quats = self.orientations(nuis) if quats is None else quats
        objs = [SimpleNamespace(position=x[NUISANCE_POSITION], orientation=quats[i],
                                linear_velocity=x[NUISANCE_VELOCITY], angular_velocity=x[NUISANCE_ANGULAR_VELOCITY])
                for i, x in enumerate(nuis)]
        return initial_state(SimpleNamespace(objects=objs))

    def prepare(self, nuis_list: Sequence[np.ndarray],
                effects_list: Sequence[Mapping[str, Mapping[str, float]]]) -> tuple[list[mujoco.MjModel], np.ndarray]:
        """Configure one model copy per variant (per-object parameters ``(n, 14)`` and effect
        values) and compute its initial MuJoCo state.

        Returns:
            ``(models, init)``: ``B`` configured ``MjModel`` copies (owned by this object, valid
            until its next ``prepare``) and ``init (B, nstate)`` full-physics initial states.
        """
        B = len(nuis_list)
        while len(self.pool) < B:
            self.pool.append(copy.copy(self.model))
        models, init = [], np.zeros((B, self._nstate))
        d = self.datas[0]
        quats = self.orientations(np.asarray(nuis_list, dtype=np.float64).reshape(B, self.n, -1)) if B else None
        for b, (nuis, eff) in enumerate(zip(nuis_list, effects_list)):
            m = self.pool[b]
            self._configure(m, nuis, eff)
            models.append(m)
            qpos, qvel = self.initial(nuis, quats[b])
            mujoco.mj_resetData(m, d)
            d.qpos[: 7 * self.n], d.qvel[: 6 * self.n] = qpos, qvel
            mujoco.mj_getState(m, d, init[b], self._spec)
        return models, init

    def split(self, init: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(qpos (B, nstep+1, nq), qvel (B, nstep+1, nv))`` of this model's rollout states
        ``state (B, >= nstep, nstate)`` (``mjSTATE_FULLPHYSICS``) after ``init (B, nstate)``."""
        nq, nv = self.model.nq, self.model.nv
        full = np.concatenate([init[:, None], state[:, : max(self.nstep, 1)]], 1)
        return full[..., 1:1 + nq], full[..., 1 + nq:1 + nq + nv]

    def run(self, nuis_list: Sequence[np.ndarray], effects_list: Sequence[Mapping[str, Mapping[str, float]]]
            ) -> tuple[np.ndarray, np.ndarray]:
        """Roll out variants: per variant ``(n, 14)`` parameters and effect values.

        Returns:
            ``(qpos (B, nstep+1, nq), qvel (B, nstep+1, nv))`` after 0..nstep physics steps.
        """
        models, init = self.prepare(nuis_list, effects_list)
        runner = _rollout_runner(self.threads if self.threads > 1 else 0)
        state, _ = runner.rollout(models, self.datas, init, nstep=max(self.nstep, 1))
        return self.split(init, state)

    def sample(self, qpos: np.ndarray) -> np.ndarray:
        """``(B, nstep+1, nq)`` per-step qpos -> ``(B, T, n, 7)`` at the sample times."""
        B = qpos.shape[0]
        cur = qpos[:, self._k].reshape(B, len(self.times), -1, 7)[:, :, : self.n]
        prev = qpos[:, np.maximum(self._k - 1, 0)].reshape(B, len(self.times), -1, 7)[:, :, : self.n]
        return interpolate_qpos(prev, cur, self._frac[None, :, None])

    def simulate_many(self, nuis_list: Sequence[np.ndarray],
                      effects_list: Sequence[Mapping[str, Mapping[str, float]]]) -> np.ndarray:
        """``qpos (B, T, n, 7)`` at the clip's sample times for B variants (:func:`simulate_clips`
        with this clip alone, on this model's threads)."""
        return simulate_clips([(self, nuis_list, effects_list)], self.threads)[0]

    def simulate(self, nuis: np.ndarray, effect_values: Mapping[str, Mapping[str, float]]) -> np.ndarray:
        """``qpos (T, n, 7)`` at the clip's sample times for per-object parameters
        ``nuis (n, 14)`` (:data:`NUISANCE`) and effect values ``{name: parameters}``."""
        return self.simulate_many([nuis], [effect_values])[0]

    def trace(self, nuis: np.ndarray, effect_values: Mapping[str, Mapping[str, float]]
              ) -> tuple[np.ndarray, np.ndarray]:
        """World-frame angular velocity ``(T, n, 3)`` (rad/s) and ``qpos (T, n, 7)`` at the sample
        times, both by the rule of :func:`pipeline.simulate.sample_steps` (angular velocity:
        each step's body-frame ``qvel`` rotated to the world, then interpolated linearly)."""
        qpos, qvel = self.run([nuis], [effect_values])
        T = len(self.times)

        def omega_at(steps: np.ndarray) -> np.ndarray:
            q = qpos[0, steps, : 7 * self.n].reshape(T, self.n, 7)[..., 3:]
            w_body = qvel[0, steps, : 6 * self.n].reshape(T, self.n, 6)[..., 3:]
            return np.einsum("tnij,tnj->tni", quat_to_mat(q), w_body)

        f = self._frac[:, None, None]
        cur = omega_at(self._k)
        omega = np.where(f >= 1.0, cur, omega_at(np.maximum(self._k - 1, 0)) * (1.0 - f) + cur * f)
        return omega, _measured(self.sample(qpos), [effect_values])[0]


def _measured(qpos: np.ndarray, effects_list: Sequence[Mapping[str, Mapping[str, float]]]) -> np.ndarray:
    """``qpos (B, T, n, 7)`` of B variants as measured: each variant's positions through
    ``Effect.measure`` of its effects (``scale_error``: x (1 + scale)); in place, returned."""
    for b, effects in enumerate(effects_list):
        for name, params in effects.items():
            cls = fx.REGISTRY.get(name)
            if cls is not None and cls.measure.__func__ is not fx.Effect.measure.__func__:
                qpos[b, ..., :3] = cls.measure(qpos[b, ..., :3], params)
    return qpos


def simulate_clips(requests: Sequence[tuple["ClipModel", Sequence[np.ndarray],
                                           Sequence[Mapping[str, Mapping[str, float]]]]],
                   threads: int = 1) -> list[np.ndarray]:
    """Roll out the variants of several clips together: one ``mujoco.rollout`` call per group of
    models with the same size signature (``MjModel.signature``), on ``threads`` threads, so
    that the clips of a joint fit (each one rollout per evaluation) keep every core busy.

    Each rollout is the same deterministic computation from its own model and initial state
    as in :meth:`ClipModel.simulate_many`, so the result is the same to the last bit; a
    shorter clip in a group is stepped on to the longest one's ``nstep`` and its states are
    cut at its own.

    Args:
        requests: per request, a :class:`ClipModel` (each at most once), its variants'
            parameters ``(n, 14)`` and effect values.
        threads: rollout threads (1: the calling thread).

    Returns:
        per request, ``qpos (B, T, n, 7)`` at that clip's sample times.
    """
    prepared = [cm.prepare(list(nl), list(el)) for cm, nl, el in requests]
    groups: dict[tuple[int, int], list[int]] = {}
    for i, (cm, _, _) in enumerate(requests):
        if len(prepared[i][0]):
            groups.setdefault((int(cm.model.signature), cm._nstate), []).append(i)
    out: list[np.ndarray | None] = [None] * len(requests)
    runner = _rollout_runner(threads if threads > 1 else 0)
    for members in groups.values():
        first = requests[members[0]][0]
        while len(first.datas) < max(threads, 1):
            first.datas.append(mujoco.MjData(first.model))
        models = [m for i in members for m in prepared[i][0]]
        init = np.concatenate([prepared[i][1] for i in members])
        nstep = max(max(requests[i][0].nstep, 1) for i in members)
        state, _ = runner.rollout(models, first.datas[: max(threads, 1)], init, nstep=nstep)
        at = 0
        for i in members:
            cm, b = requests[i][0], len(prepared[i][0])
            out[i] = _measured(cm.sample(cm.split(prepared[i][1], state[at:at + b])[0]), requests[i][2])
            at += b
    return [o if o is not None else np.zeros((0, len(r[0].times), r[0].n, 7)) for o, r in zip(out, requests)]


@dataclass
class Weights:
    """Noise model of a clip: residuals are divided by these (m, rad)."""

    position: float
    angle: float | None


def clip_residuals(clip: Clip, qpos: np.ndarray, weights: Weights) -> tuple[np.ndarray, np.ndarray]:
    """Noise-normalised residuals of a clip and its raw position residuals.

    Args:
        clip: measured clip.
        qpos: ``(T, n, 7)`` simulated at ``clip.times``.
        weights: noise standard deviations.

    Returns:
        ``(r, d)``: ``r`` flat vector (observed position coordinates / sigma_p, then
        orientation rotation-vector error / sigma_angle where measured); ``d`` flat raw
        position residuals (m) of the observed coordinates.
    """
    r, d = clip_residuals_many(clip, np.asarray(qpos)[None], weights)
    return r[0], d[0]


def clip_residuals_many(clip: Clip, qpos: np.ndarray, weights: Weights) -> tuple[np.ndarray, np.ndarray]:
    """:func:`clip_residuals` of ``B`` rollouts at once (one rotation call for all of them: the
    finite-difference Jacobian's variants; the same numbers as one at a time).

    Args:
        clip: measured clip.
        qpos: ``(B, T, n, 7)`` simulated at ``clip.times``.
        weights: noise standard deviations (m, rad).

    Returns:
        ``(r (B, m), d (B, k))`` float64: per rollout the noise-normalised residuals and the raw
        position residuals (m), laid out as in :func:`clip_residuals`.
    """
    qpos = np.asarray(qpos, dtype=np.float64)
    B = qpos.shape[0]
    parts, raw = [], []
    for i, tr in enumerate(clip.tracks):
        idx = np.searchsorted(clip.times, tr.t)
        diff = (qpos[:, idx, i, :3] - tr.pos[None])[:, :, tr.axes]
        raw.append(diff.reshape(B, -1))
        parts.append(diff.reshape(B, -1) / weights.position)
        if tr.quat is not None and weights.angle:
            meas = np.broadcast_to(tr.quat[None], (B,) + tr.quat.shape)
            err = quat_to_rotvec(quat_mul(quat_conj(qpos[:, idx, i, 3:]), meas))
            parts.append(err.reshape(B, -1) / weights.angle)
    return np.concatenate(parts, axis=1), np.concatenate(raw, axis=1)
