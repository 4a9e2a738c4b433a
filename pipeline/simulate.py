"""Rollouts and per-frame traces (docs/design.md §3).

A rollout starts from the MJCF keyframe ``init`` and records, at every video frame
``t_k = k / fps`` (k = 0 .. n_frames-1), each object's pose and world-frame velocity (the state
after exactly ``k * steps_per_frame`` physics steps: ``pipeline.mjcf.frame_timestep`` makes the
frame interval a whole number of steps, so each row is the state at its stamped time), plus
every contact that occurred since the previous frame (collisions are often shorter than a
frame, so contacts are gathered at every physics step, not only at frame times).

Sampling a rollout at given times is one rule for the whole project (:func:`sample_steps`,
:func:`interpolate_qpos`): a time on the step grid (within :data:`SNAP_STEPS` steps) is the
state after that many steps; a time between two steps is the linear interpolation of the two
states around it (quaternions: normalised lerp).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

from pipeline.mjcf import SimOptions, compile_model
from pipeline.scene import Scene


@dataclass
class Contact:
    """A contact between two named geoms' bodies (``floor`` or ``<shape>_<i>``) seen during the
    interval (t_{k-1}, t_k]: first position (m, world) and peak normal force (N)."""

    a: str
    b: str
    position: tuple[float, float, float]
    force: float


@dataclass
class Trace:
    """Per-frame states of a rollout.

    Attributes:
        t: (T,) float64 frame times, s.
        qpos: (T, n, 7) float64: position x, y, z (m, world) and quaternion w, x, y, z.
        qvel: (T, n, 6) float64: linear velocity (m/s) and angular velocity (rad/s), both in
            the world frame.
        contacts: T lists of :class:`Contact` (contacts during (t_{k-1}, t_k]).
        names: n object names.
        warnings: MuJoCo's warnings raised during the rollout (:func:`mujoco_warnings`), e.g.
            ``BADQACC x1`` (MuJoCo then resets the state silently); empty when none.
    """

    t: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray
    contacts: list[list[Contact]] = field(default_factory=list)
    names: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    @property
    def position(self) -> np.ndarray:
        """(T, n, 3) float64 centre of mass positions, m."""
        return self.qpos[..., :3]


class SimulationError(RuntimeError):
    """A rollout diverged: MuJoCo reset an unstable state, or a state is not finite."""


def check_rollout(data: mujoco.MjData, trace: "Trace") -> None:
    """Raise if the rollout that used ``data`` and made ``trace`` diverged.

    MuJoCo does not raise on an unstable simulation: it warns (``mjWARN_BADQACC``: bad
    acceleration) and silently resets the state, so the trace would look valid.

    Raises:
        SimulationError: a divergence warning was raised or a state is not finite (one line).
    """
    bad = data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number
    if bad:
        raise SimulationError(f"simulation diverged: MuJoCo reset an unstable state {bad} time(s)")
    if not (np.isfinite(trace.qpos).all() and np.isfinite(trace.qvel).all()):
        raise SimulationError("simulation diverged: non-finite state")


def mujoco_warnings(data: mujoco.MjData) -> list[str]:
    """MuJoCo's own warnings counted in ``data`` (``mjData.warning``; MuJoCo docs, "mjtWarning"):
    bad qacc/qpos/qvel (after which MuJoCo resets the state silently), contact or constraint
    buffer overflow, ... as ``["BADQACC x1", ...]``."""
    out = []
    for name, w in mujoco.mjtWarning.__members__.items():
        if name == "mjNWARNING":
            continue
        info = data.warning[int(w)]
        if info.number > 0:
            out.append(f"{name.removeprefix('mjWARN_')} x{info.number}")
    return out


def frame_times(n_frames: int, fps: float) -> np.ndarray:
    """(n_frames,) float64 times of the video frames, s."""
    return np.arange(n_frames, dtype=np.float64) / float(fps)


SNAP_STEPS = 1e-9
"""Times within this many physics steps of a step (``|t / dt - round(t / dt)| <= 1e-9``)
count as on the step grid (:func:`sample_steps`): frame times ``k / fps`` computed in floating
point land within ~1e-12 steps of their step for any clip the project simulates."""


def sample_steps(times: np.ndarray, timestep: float) -> tuple[np.ndarray, np.ndarray]:
    """Where each sample time falls on the physics step grid: the project's one rule for
    sampling a rollout at given times.

    With ``s = t / dt``: if ``|s - round(s)| <= SNAP_STEPS`` the state at ``t`` is the state
    after ``k = round(s)`` steps (``frac = 1``; exact for frame times on the grid, e.g. every
    frame of a model from ``pipeline.mjcf``); otherwise ``k = ceil(s)`` and the state at ``t``
    is the linear interpolation between the states after ``k - 1`` and ``k`` steps with weight
    ``frac = 1 - (k - s)`` in (0, 1) on step ``k`` (:func:`interpolate_qpos`). ``t = 0`` is the
    initial state (``k = 0``, ``frac = 1``).

    Args:
        times: ``(T,)`` sample times, s, >= 0 (from the initial state).
        timestep: physics timestep ``dt``, s, > 0.
    Returns:
        ``(steps, frac)``: ``(T,)`` int64 step counts ``k`` and ``(T,)`` float64 weights in
        (0, 1].
    Raises:
        ValueError: a negative or non-finite time, or a timestep that is not > 0.
    """
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    dt = float(timestep)
    if not dt > 0 or not np.isfinite(dt):
        raise ValueError(f"timestep: must be > 0, got {timestep}")
    if t.size and not (np.isfinite(t).all() and t.min() >= 0):
        bad = t[~(np.isfinite(t) & (t >= 0))][0]
        raise ValueError(f"times: must be finite and >= 0, got {bad}")
    s = t / dt
    nearest = np.rint(s)
    on_grid = np.abs(s - nearest) <= SNAP_STEPS
    steps = np.where(on_grid, nearest, np.ceil(s)).astype(np.int64)
    frac = np.where(on_grid, 1.0, 1.0 - (steps - s))
    return steps, frac


def interpolate_qpos(prev: np.ndarray, cur: np.ndarray, frac: np.ndarray | float) -> np.ndarray:
    """Free-body poses between two physics steps (the rule of :func:`sample_steps`).

    Positions are interpolated linearly, ``prev + frac (cur - prev)``; quaternions by
    normalised lerp, ``normalise((1 - frac) q_prev + frac sign q_cur)`` with ``sign = -1`` when
    ``q_prev . q_cur < 0`` (the shorter arc). Where ``frac == 1`` the result is ``cur`` exactly.
    The lerp's error against the true state is at most ``|a| dt^2 / 8`` for a constant
    acceleration ``a`` over the step (linear interpolation of a parabola).

    Args:
        prev, cur: ``(..., 7)`` float poses (x, y, z m; quaternion w, x, y, z) after ``k - 1``
            and ``k`` steps.
        frac: weight on ``cur``, broadcastable to ``prev.shape[:-1]``, in [0, 1].
    Returns:
        ``(..., 7)`` float64.
    """
    prev = np.asarray(prev, dtype=np.float64)
    cur = np.asarray(cur, dtype=np.float64)
    f = np.broadcast_to(np.asarray(frac, dtype=np.float64), prev.shape[:-1])[..., None]
    out = prev + f * (cur - prev)
    qa, qb = prev[..., 3:], cur[..., 3:]
    sign = np.where(np.sum(qa * qb, -1, keepdims=True) < 0, -1.0, 1.0)
    qq = (1 - f) * qa + f * sign * qb
    out[..., 3:] = qq / np.linalg.norm(qq, axis=-1, keepdims=True)
    return np.where(f >= 1.0, cur, out)


def sample_qpos(model: mujoco.MjModel, data: mujoco.MjData, n: int, times: np.ndarray) -> np.ndarray:
    """Simulate from the model's ``init`` keyframe and sample the free bodies' poses at
    ``times`` by the rule of :func:`sample_steps` (on the step grid: the state itself;
    between steps: :func:`interpolate_qpos` of the two states around ``t``).

    Args:
        model: compiled model whose first ``n`` bodies after the world are free bodies.
        data: ``MjData`` of ``model`` (reset here).
        n: number of free bodies.
        times: ``(T,)`` non-decreasing sample times, s, >= 0.
    Returns:
        ``qpos (T, n, 7)`` float64 (x, y, z m; quaternion w, x, y, z).
    Raises:
        ValueError: negative or non-finite times (:func:`sample_steps`).
    """
    steps, frac = sample_steps(times, float(model.opt.timestep))
    reset_to_scene(model, data)
    out = np.empty((len(steps), n, 7))
    prev = cur = data.qpos[: 7 * n].copy()
    step = 0
    for k, (target, f) in enumerate(zip(steps, frac)):
        if step < target:
            if target - 1 > step:
                mujoco.mj_step(model, data, int(target - 1 - step))
            prev = data.qpos[: 7 * n].copy()
            mujoco.mj_step(model, data)
            step = int(target)
            cur = data.qpos[: 7 * n].copy()
        out[k] = interpolate_qpos(prev.reshape(n, 7), cur.reshape(n, 7), f) if f < 1.0 else cur.reshape(n, 7)
    return out


def reset_to_scene(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """Reset ``data`` to the ``init`` keyframe (the scene's initial state) and run forward."""
    mujoco.mj_resetDataKeyframe(model, data, 0)
    mujoco.mj_forward(model, data)


def read_state(model: mujoco.MjModel, data: mujoco.MjData, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Current ``qpos (n, 7)`` and world-frame ``qvel (n, 6)`` of the n free bodies."""
    qpos = data.qpos[: 7 * n].reshape(n, 7).copy()
    qvel = data.qvel[: 6 * n].reshape(n, 6).copy()
    for i in range(n):
        R = data.xmat[i + 1].reshape(3, 3)
        qvel[i, 3:] = R @ qvel[i, 3:]  # body-frame angular velocity -> world frame
    return qpos, qvel


def _body_name(model: mujoco.MjModel, geom: int) -> str:
    body = model.geom_bodyid[geom]
    return "floor" if body == 0 else mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, body)


def _advance(model: mujoco.MjModel, data: mujoco.MjData, step: int, target: int, record_contacts: bool,
             seen: dict[tuple[str, str], Contact], geom_body: list[str], force: np.ndarray) -> int:
    """Step ``data`` from ``step`` to ``target`` steps; with ``record_contacts`` gather every
    step's contacts into ``seen`` (first position, peak normal force). Returns ``target``
    (or ``step`` if already past it)."""
    if not record_contacts and target > step:
        mujoco.mj_step(model, data, target - step)  # the same steps, one call
        return target
    while step < target:
        mujoco.mj_step(model, data)
        step += 1
        if record_contacts:
            for c in range(data.ncon):
                con = data.contact[c]
                a, b = sorted((geom_body[con.geom1], geom_body[con.geom2]))
                mujoco.mj_contactForce(model, data, c, force)
                fn = float(force[0])
                prev = seen.get((a, b))
                if prev is None:
                    seen[(a, b)] = Contact(a, b, tuple(float(x) for x in con.pos), fn)
                elif fn > prev.force:
                    prev.force = fn
    return step


def rollout(
    model: mujoco.MjModel,
    n_objects: int,
    n_frames: int,
    fps: float,
    data: mujoco.MjData | None = None,
    record_contacts: bool = True,
) -> Trace:
    """Simulate from the ``init`` keyframe and sample states at the video frame times.

    Frame k is sampled at ``t_k = k / fps`` by :func:`sample_steps`: for a model built by
    ``pipeline.mjcf`` the timestep divides the frame interval (``pipeline.mjcf.frame_timestep``),
    so every frame is on the step grid and is the state after exactly ``k * steps_per_frame``
    steps. MJCF text from elsewhere whose timestep does not divide the frame interval gets the
    linear interpolation of the two states around ``t_k`` (:func:`interpolate_qpos`; world-frame
    velocities interpolated linearly), with the contacts up to the later step.

    Args:
        model: compiled scene model (``pipeline.mjcf.compile_model``).
        n_objects: number of free bodies (scene objects).
        n_frames: number of frames T.
        fps: frames per second.
        data: optional ``MjData`` to reuse.
        record_contacts: gather contacts at every step (False: step in one call, faster).
    Returns:
        :class:`Trace` with T frames (and MuJoCo's warnings).
    """
    data = data or mujoco.MjData(model)
    reset_to_scene(model, data)
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in range(1, n_objects + 1)]
    times = frame_times(n_frames, fps)
    steps, frac = sample_steps(times, model.opt.timestep)
    qpos = np.zeros((n_frames, n_objects, 7))
    qvel = np.zeros((n_frames, n_objects, 6))
    contacts: list[list[Contact]] = []
    force = np.zeros(6)
    geom_body = [_body_name(model, g) for g in range(model.ngeom)]  # contact pair names, by geom id
    step = 0
    for k in range(n_frames):
        seen: dict[tuple[str, str], Contact] = {}
        target, between = int(steps[k]), bool(frac[k] < 1.0)
        step = _advance(model, data, step, target - 1 if between else target, record_contacts, seen, geom_body,
                        force)
        if between:  # off the step grid: interpolate between the states around t_k
            prev_qpos, prev_qvel = read_state(model, data, n_objects)
            step = _advance(model, data, step, target, record_contacts, seen, geom_body, force)
        if k == 0 and record_contacts:  # contacts present in the initial state
            mujoco.mj_forward(model, data)
            for c in range(data.ncon):
                con = data.contact[c]
                a, b = sorted((geom_body[con.geom1], geom_body[con.geom2]))
                mujoco.mj_contactForce(model, data, c, force)
                seen.setdefault((a, b), Contact(a, b, tuple(float(x) for x in con.pos), float(force[0])))
        qpos[k], qvel[k] = read_state(model, data, n_objects)
        if between:
            qpos[k] = interpolate_qpos(prev_qpos, qpos[k], frac[k])
            qvel[k] = prev_qvel + frac[k] * (qvel[k] - prev_qvel)
        contacts.append(list(seen.values()))
    return Trace(times, qpos, qvel, contacts, names, mujoco_warnings(data))


def simulate(scene: Scene, options: SimOptions | None = None) -> tuple[mujoco.MjModel, Trace]:
    """Compile and roll out a scene over its ``duration`` at its ``fps``."""
    model = compile_model(scene, options)
    return model, rollout(model, len(scene.objects), scene.n_frames, scene.fps)
