"""Rollouts and per-frame traces (DESIGN.md §3).

A rollout starts from the MJCF keyframe ``init`` and records, at every video frame
``t_k = k / fps`` (k = 0 .. n_frames-1), each object's pose and world-frame velocity (the state
after exactly ``k * steps_per_frame`` physics steps: ``pipeline.mjcf.frame_timestep`` makes the
frame interval a whole number of steps, so each row is the state at its stamped time), plus
every contact that occurred since the previous frame (collisions are often shorter than a
frame, so contacts are gathered at every physics step, not only at frame times).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

from pipeline.mjcf import SimOptions, compile_model, object_ids
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


def rollout(
    model: mujoco.MjModel,
    n_objects: int,
    n_frames: int,
    fps: float,
    data: mujoco.MjData | None = None,
    record_contacts: bool = True,
) -> Trace:
    """Simulate from the ``init`` keyframe and sample states at the video frame times.

    Frame k is the state after ``round(t_k / timestep)`` physics steps. For a model built by
    ``pipeline.mjcf`` the timestep divides the frame interval (``pipeline.mjcf.frame_timestep``),
    so that count is exactly ``k * steps_per_frame`` and the state is the one at ``t_k``; MJCF
    text from elsewhere whose timestep does not divide it is off by at most half a timestep.

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
    qpos = np.zeros((n_frames, n_objects, 7))
    qvel = np.zeros((n_frames, n_objects, 6))
    contacts: list[list[Contact]] = []
    force = np.zeros(6)
    geom_body = [_body_name(model, g) for g in range(model.ngeom)]  # contact pair names, by geom id
    step = 0
    for k, t in enumerate(times):
        seen: dict[tuple[str, str], Contact] = {}
        target = int(round(t / model.opt.timestep))
        if not record_contacts and target > step:
            mujoco.mj_step(model, data, target - step)  # the same steps, one call
            step = target
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
        if k == 0 and record_contacts:  # contacts present in the initial state
            mujoco.mj_forward(model, data)
            for c in range(data.ncon):
                con = data.contact[c]
                a, b = sorted((geom_body[con.geom1], geom_body[con.geom2]))
                mujoco.mj_contactForce(model, data, c, force)
                seen.setdefault((a, b), Contact(a, b, tuple(float(x) for x in con.pos), float(force[0])))
        qpos[k], qvel[k] = read_state(model, data, n_objects)
        contacts.append(list(seen.values()))
    return Trace(times, qpos, qvel, contacts, names, mujoco_warnings(data))


def simulate(scene: Scene, options: SimOptions | None = None) -> tuple[mujoco.MjModel, Trace]:
    """Compile and roll out a scene over its ``duration`` at its ``fps``."""
    model = compile_model(scene, options)
    return model, rollout(model, len(scene.objects), scene.n_frames, scene.fps)
