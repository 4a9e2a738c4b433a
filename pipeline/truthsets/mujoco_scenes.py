"""Truth clips simulated and rendered by MuJoCo with the project's own machinery.

A :class:`~pipeline.truthsets.scenario.Scenario` becomes a scene-language
:class:`~pipeline.scene.Scene` (6-DoF camera, objects with their materials) plus a
:class:`~pipeline.mjcf.Appearance` (floor texture, object colours, light, headlight), is built by
:func:`pipeline.mjcf.build_mjcf`, rolled out by :func:`pipeline.simulate.rollout` (timestep
1/600 s) and rendered by :class:`pipeline.render.FrameRenderer` (RGB and segmentation: the
renderer's object ids are the truth masks).

Engine specifics: contacts are MuJoCo's soft contacts (default ``solref``; no bounce, so a
scenario's ``restitution`` is not used); rolling friction is MuJoCo's rolling coefficient (m);
floors ``noise`` and ``stripes`` are generated PNG textures (:func:`floor_image`); shadows
(``look.shadows``) cost ~15x per RGB frame. Camera pitch 0-89 deg (0 side view, 89 top-down).
"""

from __future__ import annotations

import mujoco
import numpy as np

from pipeline.mjcf import Appearance, SimOptions, build_mjcf, object_ids
from pipeline.render import FrameRenderer, GLResources, camera_matrices
from pipeline.scene import Scene
from pipeline.scene_look import appearance_of
from pipeline.simulate import check_rollout, rollout
from pipeline.truthsets.common import Accept, Rollout, TOUCH_DISTANCE
from pipeline.truthsets.scenario import EngineLimits, Scenario

NAME = "mujoco"
SALT = 1
"""First entry of every random seed of this engine's clips."""
LIMITS = EngineLimits(pitch=(0.0, 89.0),
                      floor_kinds={"checker": 0.35, "gradient": 0.1, "flat": 0.15, "noise": 0.25, "stripes": 0.15},
                      p_shadows=0.25)


def to_scene(sc: Scenario) -> Scene:
    """The scene-language scene of a scenario (no effects, gravity 9.81 m/s^2)."""
    objects = [{"shape": o.shape, "size": dict(o.size), "mass": o.mass, "position": o.position.tolist(),
                "orientation": (o.quat / np.linalg.norm(o.quat)).tolist(),
                "linear_velocity": o.linear_velocity.tolist(), "angular_velocity": o.angular_velocity.tolist(),
                "material": {"sliding_friction": o.friction, "rolling_friction": o.rolling_friction, "damping": 0.0}}
               for o in sc.objects]
    cam = sc.camera.camera()
    return Scene.from_dict({"duration": sc.duration, "fps": int(sc.fps), "gravity": 9.81,
                            "camera": cam.model_dump(exclude_none=True), "objects": objects},
                           source=f"scenario {sc.category}")


def appearance(sc: Scenario) -> Appearance:
    """The MJCF look of a scenario."""
    return appearance_of(sc.look, tuple(o.rgb for o in sc.objects))


def compile_scenario(sc: Scenario) -> mujoco.MjModel:
    """Build and compile the MJCF of a scenario (the floor PNG travels as an asset)."""
    opt = SimOptions(offscreen_size=max(640, sc.width, sc.height))
    root = build_mjcf(to_scene(sc), opt, appearance(sc))
    return mujoco.MjModel.from_xml_string(root.to_xml_string(), root.get_assets())


def touching(model: mujoco.MjModel, data: mujoco.MjData, geoms: np.ndarray, qpos: np.ndarray) -> np.ndarray:
    """(T, n, n) bool: object geoms closer than ``TOUCH_DISTANCE`` in each frame's pose."""
    T, n = qpos.shape[:2]
    out = np.zeros((T, n, n), dtype=bool)
    fromto = np.zeros(6)
    for t in range(T):
        data.qpos[: 7 * n] = qpos[t].reshape(-1)
        mujoco.mj_kinematics(model, data)
        for a in range(n):
            for b in range(a + 1, n):
                d = mujoco.mj_geomDistance(model, data, int(geoms[a]), int(geoms[b]), 0.01, fromto)
                out[t, a, b] = out[t, b, a] = d < TOUCH_DISTANCE
    return out


def run(sc: Scenario, accept: Accept | None = None) -> Rollout | None:
    """Simulate a scenario; if ``accept(pos, quat, touch)`` (or no ``accept``), render it.

    Returns:
        the :class:`~pipeline.truthsets.common.Rollout`, or None when not accepted.
    Raises:
        pipeline.simulate.SimulationError: the simulation diverged.
    """
    model = compile_scenario(sc)
    n = len(sc.objects)
    data = mujoco.MjData(model)
    trace = rollout(model, n, sc.n_frames, sc.fps, data=data, record_contacts=False)
    check_rollout(data, trace)
    _, geoms = object_ids(model, n)
    touch = touching(model, mujoco.MjData(model), geoms, trace.qpos)
    pos, quat = trace.qpos[..., :3].copy(), trace.qpos[..., 3:].copy()
    if accept is not None and not accept(pos, quat, touch):
        return None
    with GLResources() as gl, FrameRenderer(model, sc.width, sc.height, gl) as renderer:
        frames = renderer.render(trace.qpos, rgb=True, seg=True, depth=False, flow=False)
        renderer.set_pose(trace.qpos[0])
        K, R, t = camera_matrices(model, renderer.data, sc.width, sc.height)
    E = np.eye(4)
    E[:3, :3], E[:3, 3] = R, t
    return Rollout(rgb=frames.rgb, seg=frames.seg, pos=pos, quat=quat, touch=touch, intrinsics=K, extrinsics=E)
