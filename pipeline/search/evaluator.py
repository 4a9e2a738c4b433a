"""Fast re-simulation of candidate scenes (compile once per structure, edit in place).

:class:`SceneEvaluator` compiles the MJCF **once per scene structure** (same shapes in the
same order, same effects, same static geometry) and, for each candidate, edits the
``mjModel`` in place (masses, inertias, sizes, bounding volumes, friction, damping, camera,
gravity, the ``init`` keyframe), then rolls out and renders segmentation and exact flow with
one reused :class:`pipeline.render.FrameRenderer`. DESIGN §10: in-place edits go wrong
silently unless ``mujoco.mj_setConst`` runs after mass/size changes, ``geom_rbound`` /
``geom_aabb`` (and the body BVH) follow the sizes, and ``mj_camlight`` runs before rendering
(``FrameRenderer`` does). ``mj_setConst`` of MuJoCo 3.17 does not refresh ``mjModel.stat``
(mean mass, mean inertia, mean size, extent), which the compiler computes and the constraint
solver and renderer use, so :func:`_set_stat` recomputes it like the compiler.
``tests/test_search.py`` checks fast == naive (rebuild the XML per candidate).
"""

from __future__ import annotations

import mujoco
import numpy as np

from pipeline.camera import camera_pose
from pipeline.mjcf import SimOptions, compile_model, geom_size, initial_state, object_ids
from pipeline.render import FrameRenderer
from pipeline.scene import Scene
from pipeline.simulate import rollout


def structure_key(scene: Scene) -> tuple:
    """What a compiled model fixes: the shapes in order, the effects with their parameters and
    the static geometry (``Scene.static``: fixed boxes / planes such as ramps and walls, compiled
    into the worldbody; absent in scenes without it).

    Scenes with equal keys share one :class:`SceneEvaluator`.
    """
    effects = tuple((e.effect, tuple(sorted(e.parameters.items()))) for e in scene.effects)
    static = tuple(g.model_dump_json() if hasattr(g, "model_dump_json") else repr(g)
                   for g in (getattr(scene, "static", None) or ()))
    return tuple(o.shape for o in scene.objects), effects, static


def _object_bodies(model: mujoco.MjModel, scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Body ids (n,) and geom ids (n,) of the scene's objects, found by name (``<shape>_<i>``
    bodies, one geom each), so worldbody geoms (floor, static geometry ``static_<i>``) never
    count as objects. Falls back to bodies ``1..n`` (:func:`pipeline.mjcf.object_ids`).
    """
    bodies = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name) for name in scene.object_names]
    if any(b <= 0 for b in bodies):
        return object_ids(model, len(scene.objects))
    return np.asarray(bodies), np.asarray([int(model.body_geomadr[b]) for b in bodies])


def body_inertia(obj) -> np.ndarray:
    """Principal moments of inertia (3,) kg m^2 of a solid primitive about its body axes.

    Uniform density solids (MuJoCo compiler, "inertia from geoms"): sphere ``2/5 m r^2``;
    cylinder ``m (3 r^2 + h^2) / 12`` (x, y) and ``m r^2 / 2`` (z); box of full extents
    (w, d, h): ``m (d^2 + h^2) / 12``, ``m (w^2 + h^2) / 12``, ``m (w^2 + d^2) / 12``.
    """
    m, s = obj.mass, obj.size
    if obj.shape == "sphere":
        return np.full(3, 0.4 * m * s.radius ** 2)
    if obj.shape == "cylinder":
        ixx = m * (3.0 * s.radius ** 2 + s.height ** 2) / 12.0
        return np.array([ixx, ixx, 0.5 * m * s.radius ** 2])
    w, d, h = s.width, s.depth, s.height
    return m / 12.0 * np.array([d * d + h * h, w * w + h * h, w * w + d * d])


def _half_extents(obj) -> np.ndarray:
    """Axis-aligned half extents (3,) m of a primitive in its geom frame (``geom_aabb``)."""
    g = geom_size(obj)
    if obj.shape == "sphere":
        return np.full(3, g[0])
    if obj.shape == "cylinder":
        return np.array([g[0], g[0], g[1]])
    return np.asarray(g, dtype=np.float64)


def _set_stat(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """Recompute ``model.stat`` as MuJoCo's compiler does (``setStat`` in engine_setconst.c).

    Needs ``data`` at ``qpos0`` after ``mj_kinematics`` and ``model.dof_M0`` from
    ``mj_setConst``. Covers bodies, joints and geoms (the scene models have no sites/flexes).
    """
    pts, rad = [], []
    for b in range(1, model.nbody):
        pts += [data.xpos[b], data.xipos[b]]
        rad += [0.0, 0.0]
    for j in range(model.njnt):
        pts.append(data.xanchor[j])
        rad.append(0.0)
    for g in range(model.ngeom):
        r = float(model.geom_rbound[g])
        if r <= 0 and model.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE:
            sx, sy = model.geom_size[g, :2]
            r = max(sx, sy) * 0.1 if (sx or sy) else 1.0
        pts.append(data.geom_xpos[g])
        rad.append(r)
    pts, rad = np.asarray(pts), np.asarray(rad)[:, None]
    lo, hi = (pts - rad).min(axis=0), (pts + rad).max(axis=0)
    model.stat.center[:] = (lo + hi) / 2.0
    if hi[0] > lo[0]:
        model.stat.extent = max(1e-5, float((hi - lo).max()))
    size = np.zeros(model.nbody)
    for j in range(model.njnt):
        b = model.jnt_bodyid[j]
        size[b] = max(size[b], float(np.linalg.norm(data.xipos[b] - data.xanchor[j])))
    for b in range(1, model.nbody):
        for g in range(model.body_geomadr[b], model.body_geomadr[b] + model.body_geomnum[b]):
            if model.geom_rbound[g] > 0:
                size[b] = max(size[b], model.geom_rbound[g] + float(np.linalg.norm(data.xipos[b] - data.geom_xpos[g])))
    if model.nbody > 1:
        model.stat.meansize = float(np.maximum(size[1:], 1e-5).mean())
        model.stat.meanmass = float(model.body_mass[1:].mean())
    model.stat.extent = max(model.stat.extent, 2.0 * model.stat.meansize)
    if model.nv:
        model.stat.meaninertia = float(model.dof_M0.mean())


class SceneEvaluator:
    """Re-simulate and render candidate scenes of one structure fast (compile once).

    Args:
        structure_scene: any scene of the structure (shapes in order, effects).
        width, height: render size, px (the observed video's).
        options: simulation options (params ``sim``).
    Raises:
        SceneError: an effect of the scene is unknown (from the MJCF builder).
        ValueError: MuJoCo rejects the model.

    Use as a context manager or call :meth:`close` (it owns a ``mujoco.Renderer``).
    """

    def __init__(self, structure_scene: Scene, width: int, height: int, options: SimOptions | None = None):
        self.key = structure_key(structure_scene)
        self.width, self.height = int(width), int(height)
        self.model = compile_model(structure_scene, options)
        self.n = len(structure_scene.objects)
        self.bodies, self.geoms = _object_bodies(self.model, structure_scene)
        # The floor plane is drawn as a grid of size[2]-spaced quads (MuJoCo docs, "geom/size":
        # plane), 200 x 200 = 40,000 quads for the 10 m floor at 0.1 m: ~70 % of a segmentation
        # pass at 192x144. A plane's third size is only that rendering spacing (planes are
        # infinite for collisions), and the evaluator draws no RGB, so one quad does: seg and
        # depth are the same plane.
        for g in range(self.model.ngeom):
            if self.model.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE and self.model.geom_bodyid[g] == 0:
                self.model.geom_size[g, 2] = max(float(self.model.geom_size[g, 2]),
                                                 2.0 * float(self.model.geom_size[g, :2].max()))
        g = np.asarray(self.model.opt.gravity, dtype=np.float64)
        # gravity direction is fixed by the structure (an effect may tilt it)
        self._gdir = g / np.linalg.norm(g) if np.linalg.norm(g) > 0 else np.array([0.0, 0.0, -1.0])
        self._cam = int(mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_CAMERA, "main"))
        self._sim_data = mujoco.MjData(self.model)
        self._const_data = mujoco.MjData(self.model)
        self.renderer = FrameRenderer(self.model, self.width, self.height)

    def close(self) -> None:
        self.renderer.close()

    def __enter__(self) -> "SceneEvaluator":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def set_scene(self, scene: Scene) -> None:
        """Write a candidate's parameters into the compiled model (in place).

        Raises:
            ValueError: the scene's structure differs from the evaluator's.
        """
        if structure_key(scene) != self.key:
            raise ValueError(f"scene structure {structure_key(scene)} differs from the evaluator's {self.key}")
        m = self.model
        m.opt.gravity[:] = self._gdir * scene.gravity
        qpos, qvel = initial_state(scene)
        for i, obj in enumerate(scene.objects):
            b, g = self.bodies[i], self.geoms[i]
            size = geom_size(obj)
            m.geom_size[g, : len(size)] = size
            half = _half_extents(obj)
            m.geom_aabb[g] = [0.0, 0.0, 0.0, *half]  # centre, half sizes (geom frame)
            m.geom_rbound[g] = half[0] if obj.shape == "sphere" else float(np.linalg.norm(half))
            m.bvh_aabb[m.body_bvhadr[b]] = [0.0, 0.0, 0.0, *half]  # one geom per body
            m.body_mass[b] = obj.mass
            m.body_inertia[b] = body_inertia(obj)
            m.body_pos[b] = qpos[7 * i: 7 * i + 3]
            m.body_quat[b] = qpos[7 * i + 3: 7 * i + 7]
            m.geom_friction[g, 0] = obj.material.sliding_friction  # [1] torsional: as compiled
            # pipeline.mjcf compiles a frictionless object with condim 1 (a zero-friction cone
            # with condim > 1 is degenerate): follow it when the friction crosses zero
            m.geom_condim[g] = 6 if obj.material.sliding_friction > 0 else 1
            m.geom_friction[g, 2] = obj.material.rolling_friction
            dof = m.body_dofadr[b]
            m.dof_damping[dof: dof + 6] = obj.material.damping
        m.qpos0[: len(qpos)] = qpos
        m.qpos_spring[: len(qpos)] = qpos
        m.key_qpos[0, : len(qpos)] = qpos
        m.key_qvel[0, : len(qvel)] = qvel
        pose = camera_pose(scene.camera)
        mat = np.stack([pose.right, pose.up, np.cross(pose.right, pose.up)], axis=1)  # MuJoCo: x right, y up, z back
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, mat.reshape(-1))
        m.cam_pos[self._cam] = pose.eye
        m.cam_quat[self._cam] = quat
        m.cam_fovy[self._cam] = scene.camera.fov
        d = self._const_data
        mujoco.mj_setConst(m, d)  # invweight0, M0, subtree masses, cam_pos0/mat0, dof_length
        d.qpos[:] = m.qpos0
        mujoco.mj_kinematics(m, d)
        _set_stat(m, d)

    def evaluate(self, scene: Scene, n_frames: int | None = None, flow: bool = True,
                 ) -> tuple[np.ndarray, np.ndarray | None]:
        """Simulate and render one candidate.

        Args:
            scene: candidate with this evaluator's structure.
            n_frames: frames T to produce (default ``scene.n_frames``; pass the observed
                clip's T), at ``scene.fps``.
            flow: also render depth and compute the exact flow (skip when it is not scored).
        Returns:
            ``seg (T, H, W) int8`` (object index, -1 background) and ``flow (T-1, H, W, 2)
            float32`` px (None when ``flow`` is False).
        """
        self.set_scene(scene)
        T = scene.n_frames if n_frames is None else int(n_frames)
        trace = rollout(self.model, self.n, T, scene.fps, data=self._sim_data, record_contacts=False)
        frames = self.renderer.render(trace.qpos, rgb=False, seg=True, depth=False, flow=flow)
        return frames.seg, frames.flow


def evaluate_scene(scene: Scene, width: int, height: int, n_frames: int | None = None,
                   options: SimOptions | None = None, flow: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """One-off :meth:`SceneEvaluator.evaluate` (compiles, renders, closes)."""
    with SceneEvaluator(scene, width, height, options) as ev:
        return ev.evaluate(scene, n_frames, flow)


class EvaluatorPool:
    """:class:`SceneEvaluator` objects keyed by structure, reused across scenes.

    Keeps at most ``max_size`` evaluators (least recently used closed first): each holds a
    renderer. Use as a context manager or call :meth:`close`.

    Args:
        width, height: render size, px.
        options: simulation options (params ``sim``).
        max_size: most evaluators kept open.
    """

    def __init__(self, width: int, height: int, options: SimOptions | None = None, max_size: int = 8):
        self.width, self.height, self.options, self.max_size = int(width), int(height), options, max_size
        self._pool: dict[tuple, SceneEvaluator] = {}

    def get(self, scene: Scene) -> SceneEvaluator:
        """The evaluator of ``scene``'s structure (compiled on first use).

        Raises:
            SceneError, ValueError: the scene does not compile (see :class:`SceneEvaluator`).
        """
        key = structure_key(scene)
        ev = self._pool.pop(key, None)
        if ev is None:
            ev = SceneEvaluator(scene, self.width, self.height, self.options)
            while len(self._pool) >= self.max_size:
                self._pool.pop(next(iter(self._pool))).close()
        self._pool[key] = ev  # most recently used last
        return ev

    def evaluate(self, scene: Scene, n_frames: int | None = None, flow: bool = True):
        """:meth:`SceneEvaluator.evaluate` with the pooled evaluator of the scene's structure."""
        return self.get(scene).evaluate(scene, n_frames, flow)

    def close(self) -> None:
        for ev in self._pool.values():
            ev.close()
        self._pool.clear()

    def __enter__(self) -> "EvaluatorPool":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
