"""Fast re-simulation of candidate scenes (compile once per structure, edit in place).

:class:`SceneEvaluator` compiles the MJCF **once per scene structure**
(:func:`pipeline.engine.structure_key`: same shapes in the same order, same effects, same
static geometry) and, for each candidate, edits the ``mjModel`` in place with the engine's
functions (:mod:`pipeline.engine`: masses, inertias, sizes, bounding volumes, camera, then the
derived constants and ``mjModel.stat``; here also friction, damping, gravity, the contact
``solref`` of a ``restitution`` effect and of a static geom's ``restitution``, and the ``init``
keyframe), then rolls out and renders segmentation and exact flow with one reused
:class:`pipeline.render.FrameRenderer`. ``tests/test_search.py`` checks fast == naive (rebuild
the XML per candidate).
"""

from __future__ import annotations

import mujoco
import numpy as np

from pipeline.effects import REGISTRY, resolve_params, restitution_solref
from pipeline.exposure import expose
from pipeline.engine import (EDITED_IN_PLACE, object_bodies, refresh_constants, set_camera, set_object_mass,
                             set_object_size, structure_key)
from pipeline.mjcf import SimOptions, compile_model, initial_state
from pipeline.render import FrameRenderer
from pipeline.scene import Scene
from pipeline.simulate import rollout


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
        self.bodies, self.geoms = object_bodies(self.model, structure_scene)
        self._static_geoms = [mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, name)
                              for name in structure_scene.static_names]
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
            set_object_size(m, b, g, obj.shape, obj.size)
            set_object_mass(m, b, obj.shape, obj.size, obj.mass)
            m.body_pos[b] = qpos[7 * i: 7 * i + 3]
            m.body_quat[b] = qpos[7 * i + 3: 7 * i + 7]
            m.geom_friction[g, 0] = obj.material.sliding_friction  # [1] torsional: as compiled
            # pipeline.mjcf compiles a frictionless object with condim 1 (a zero-friction cone
            # with condim > 1 is degenerate): follow it when the friction crosses zero
            m.geom_condim[g] = 6 if obj.material.sliding_friction > 0 else 1
            m.geom_friction[g, 2] = obj.material.rolling_friction
            dof = m.body_dofadr[b]
            m.dof_damping[dof: dof + 6] = obj.material.damping
        for g, geom in zip(scene.static, self._static_geoms):   # a springy stop's bounce (pipeline.mjcf)
            if g.restitution is not None:
                m.geom_solref[geom] = restitution_solref(g.restitution, float(m.opt.timestep))
        for fx in scene.effects:   # the effects structure_key leaves out of the structure
            if fx.effect in EDITED_IN_PLACE:
                REGISTRY[fx.effect].set_model(m, resolve_params(fx.effect, fx.parameters, "<search>"), self.geoms, None)
        m.qpos0[: len(qpos)] = qpos
        m.qpos_spring[: len(qpos)] = qpos
        m.key_qpos[0, : len(qpos)] = qpos
        m.key_qvel[0, : len(qvel)] = qvel
        set_camera(m, self._cam, scene.camera)
        refresh_constants(m, self._const_data)  # invweight0, M0, subtree masses, cam_pos0/mat0, stat

    def evaluate(self, scene: Scene, n_frames: int | None = None, flow: bool = True,
                 ) -> tuple[np.ndarray, np.ndarray | None]:
        """Simulate and render one candidate.

        Args:
            scene: candidate with this evaluator's structure.
            n_frames: frames T to produce (default ``scene.n_frames``; pass the observed
                clip's T), at ``scene.fps``.
            flow: also render depth and compute the exact flow (skip when it is not scored).
        Returns:
            ``seg (T, H, W) int8`` (object index, -1 background; swept over the camera's
            exposure, :func:`pipeline.exposure.expose`) and ``flow (T-1, H, W, 2) float32`` px
            (None when ``flow`` is False).
        """
        self.set_scene(scene)
        T = scene.n_frames if n_frames is None else int(n_frames)
        trace = rollout(self.model, self.n, T, scene.fps, data=self._sim_data, record_contacts=False)
        frames = self.renderer.render(trace.qpos, rgb=False, seg=True, depth=False, flow=flow)
        return expose(frames.seg, scene.exposure_frames), frames.flow


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
