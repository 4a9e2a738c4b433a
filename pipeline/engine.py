"""Compile once, edit in place: the engine of every fit that re-simulates many variants of a
scene (the search's :class:`pipeline.search.SceneEvaluator`, the sampler's filter template and
the discrepancy fit).

Compiling MJCF costs milliseconds; editing a compiled ``mjModel`` costs microseconds. A model
compiled once per *structure* (:func:`structure_key`: shapes in order, effects, static
geometry) is edited per variant:

* effect values (:func:`configure_model`, on a model from :func:`compile_for_fit`): reset the
  fields effects may touch to the base model's (:class:`ModelBase`, :func:`snapshot`), then let
  each effect of :data:`pipeline.effects.REGISTRY` set its own (``Effect.set_model``);
* object shape, size and mass (:func:`set_object_size`, :func:`set_object_mass`), camera
  (:func:`set_camera`);
* then the derived constants (:func:`refresh_constants`).

docs/design.md §10: in-place edits go wrong silently unless ``mujoco.mj_setConst`` runs after mass/size
changes, ``geom_rbound`` / ``geom_aabb`` (and the body BVH) follow the sizes, and
``mj_camlight`` runs before rendering (``pipeline.render.FrameRenderer`` does).
``mj_setConst`` of MuJoCo 3.17 does not refresh ``mjModel.stat`` (mean mass, mean inertia,
mean size, extent), which the compiler computes and the constraint solver and renderer use, so
:func:`set_stat` recomputes it like the compiler. ``tests/test_search.py`` checks that an
edited model equals the recompiled one, ``tests/test_effects.py`` that effect edits equal the
MJCF path.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import mujoco
import numpy as np

from pipeline import geometry
from pipeline.camera import camera_pose
from pipeline.effects import REGISTRY
from pipeline.mjcf import SimOptions, compile_model, object_ids
from pipeline.scene import Camera, Scene

__all__ = ["EDITED_IN_PLACE", "ModelBase", "snapshot", "compile_for_fit", "configure_model", "structure_key", "object_bodies",
           "set_object_size", "set_object_mass", "set_camera", "set_stat", "refresh_constants"]


# --------------------------------------------------------------------------- effects
@dataclass
class ModelBase:
    """Base-model values of every field an effect may edit (copied from a compiled model).

    Attributes:
        density: ``opt.density``, kg/m^3.
        wind: ``opt.wind`` (3,) m/s.
        gravity: ``opt.gravity`` (3,) m/s^2.
        geom_solref: ``(ngeom, 2)``; geom_friction: ``(ngeom, 3)``; geom_fluid: ``(ngeom, 12)``.
    """

    density: float
    wind: np.ndarray
    gravity: np.ndarray
    geom_solref: np.ndarray
    geom_friction: np.ndarray
    geom_fluid: np.ndarray


def snapshot(model: mujoco.MjModel) -> ModelBase:
    """Copy the effect-editable fields of a model compiled without effects."""
    return ModelBase(float(model.opt.density), model.opt.wind.copy(), model.opt.gravity.copy(),
                     model.geom_solref.copy(), model.geom_friction.copy(), model.geom_fluid.copy())


def compile_for_fit(scene: Scene, effects: "list[str] | tuple[str, ...]", options: SimOptions | None = None
                    ) -> tuple[mujoco.MjModel, ModelBase, np.ndarray]:
    """Compile a scene once for fits that edit effect values in place.

    The model is compiled with the structural effects among ``effects`` (at their defaults)
    so that :func:`configure_model` can set any values of ``effects`` afterwards; the
    returned base holds the base model's values (compiled without effects) except for
    ``geom_fluid``, whose compiler-derived ellipsoid terms come from the structural model.

    Args:
        scene: the scene; its own ``effects`` are ignored.
        effects: effect names (known to :data:`pipeline.effects.REGISTRY`).
        options: simulation options (params ``sim``).

    Returns:
        ``(model, base, geoms)``: geoms ``(n,)`` int are the object geom ids in scene order.

    Raises:
        KeyError: an unknown effect name.
        ValueError: MuJoCo rejects the model (``pipeline.mjcf.compile_model``).
    """
    plain = scene.replace(effects=[])
    base_model = compile_model(plain, options)
    base = snapshot(base_model)
    structural = [n for n in effects if REGISTRY[n].structural]
    model = base_model
    if structural:
        model = compile_model(plain.replace(effects=[{"effect": n, "parameters": {}} for n in structural]),
                              options)
        base.geom_fluid = model.geom_fluid.copy()
    _, geoms = object_ids(model, len(scene.objects))
    return model, base, geoms


def configure_model(model: mujoco.MjModel, base: ModelBase, geoms: np.ndarray,
                    effects: Mapping[str, Mapping[str, float]]) -> None:
    """Set a compiled model's effect fields in place: reset them to ``base``, then apply
    ``effects`` (``{name: full parameters}``) in :data:`pipeline.effects.REGISTRY` order.
    Equivalent to rebuilding the MJCF with those effects (checked in ``tests/test_effects.py``).

    Args:
        model: compiled with the same structural effects (``Effect.structural``) present
            (:func:`compile_for_fit`).
        base: :func:`snapshot` of that model.
        geoms: ``(n,)`` int geom ids of the objects.
        effects: effect name -> parameter values (all parameters,
            ``pipeline.effects.resolve_params``).

    Raises:
        KeyError: an unknown effect name.
        ValueError: a structural effect the model was not compiled with.
    """
    model.opt.density = base.density
    model.opt.wind[:] = base.wind
    model.opt.gravity[:] = base.gravity
    model.geom_solref[:] = base.geom_solref
    model.geom_friction[:] = base.geom_friction
    model.geom_fluid[:] = base.geom_fluid
    ellipsoid = bool(model.geom_fluid.size and np.any(model.geom_fluid[geoms, 0] > 0))
    if "magnus_lift" in effects and not ellipsoid:
        raise ValueError("configure_model: magnus_lift is structural: the model must be "
                         "compiled with it when it is among the effects")
    if ellipsoid and not any(REGISTRY[n].structural for n in effects if n in REGISTRY):
        raise ValueError("configure_model: the model was compiled with a structural effect "
                         "(ellipsoid fluid model) that is not among the effects")
    for name in REGISTRY:
        if name in effects:
            REGISTRY[name].set_model(model, effects[name], geoms, base)


# --------------------------------------------------------------------------- structure
EDITED_IN_PLACE = frozenset({"restitution"})
"""Effects whose parameters :class:`pipeline.search.SceneEvaluator` writes into a compiled model
per candidate (``restitution``: the objects' ``solref``), so that the search can vary them: only
their presence is part of :func:`structure_key`."""


def structure_key(scene: Scene) -> tuple:
    """What a compiled model fixes: the shapes in order, the effects with their parameters (of
    those in :data:`EDITED_IN_PLACE` only the name) and the static geometry (``Scene.static``:
    fixed boxes / planes such as ramps and walls, compiled into the worldbody; absent in scenes
    without it), of whose ``restitution`` only whether it is set (its value is edited in place).

    Scenes with equal keys can share one compiled model (e.g. one
    :class:`pipeline.search.SceneEvaluator`).
    """
    effects = tuple((e.effect, () if e.effect in EDITED_IN_PLACE else tuple(sorted(e.parameters.items())))
                    for e in scene.effects)
    # a static geom's restitution is edited in place too (its solref): only whether it has one counts
    static = tuple((g.model_copy(update={"restitution": None}).model_dump_json(), True)
                   if getattr(g, "restitution", None) is not None
                   else g.model_dump_json() if hasattr(g, "model_dump_json") else repr(g)
                   for g in (getattr(scene, "static", None) or ()))
    return tuple(o.shape for o in scene.objects), effects, static


def object_bodies(model: mujoco.MjModel, scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Body ids (n,) and geom ids (n,) int of the scene's objects, found by name (``<shape>_<i>``
    bodies, one geom each), so worldbody geoms (floor, static geometry ``static_<i>``) never
    count as objects. Falls back to bodies ``1..n`` (:func:`pipeline.mjcf.object_ids`).

    Raises:
        ValueError: the fallback finds a body count other than the scene's object count.
    """
    bodies = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name) for name in scene.object_names]
    if any(b <= 0 for b in bodies):
        return object_ids(model, len(scene.objects))
    return np.asarray(bodies), np.asarray([int(model.body_geomadr[b]) for b in bodies])


# --------------------------------------------------------------------------- in-place edits
def set_object_size(model: mujoco.MjModel, body: int, geom: int, shape: str, size: Any) -> None:
    """Write a primitive's size into body ``body`` with its one geom ``geom``, in place: geom
    ``size``, ``geom_aabb``, ``geom_rbound`` and the body's BVH box (``bvh_aabb``), as the
    compiler sets them (:mod:`pipeline.geometry`). The geom type must already be ``shape``.
    Run :func:`refresh_constants` afterwards.

    Args:
        model: compiled model.
        body, geom: ids.
        shape, size: scene-language primitive (``pipeline.geometry``).
    """
    gs = geometry.geom_size(shape, size)
    model.geom_size[geom, : len(gs)] = gs
    half = geometry.half_extents(shape, size)
    model.geom_aabb[geom] = [0.0, 0.0, 0.0, *half]  # centre, half sizes (geom frame)
    model.geom_rbound[geom] = geometry.bounding_radius(shape, size)
    model.bvh_aabb[model.body_bvhadr[body]] = [0.0, 0.0, 0.0, *half]  # one geom per body


def set_object_mass(model: mujoco.MjModel, body: int, shape: str, size: Any, mass: float) -> None:
    """Write a solid primitive's mass (kg) and principal inertia (:func:`pipeline.geometry.
    principal_inertia`) into ``body``, in place. Run :func:`refresh_constants` afterwards."""
    model.body_mass[body] = mass
    model.body_inertia[body] = geometry.principal_inertia(shape, size, mass)


def set_camera(model: mujoco.MjModel, cam: int, camera: Camera) -> None:
    """Write a scene-language camera into camera ``cam`` (pose and ``fovy``), in place, as
    ``pipeline.mjcf`` places it (``xyaxes = (right, up)``; MuJoCo's camera looks along -z).
    Run :func:`refresh_constants` (``cam_pos0``, ``cam_mat0``) before tracking modes matter."""
    pose = camera_pose(camera)
    mat = np.stack([pose.right, pose.up, np.cross(pose.right, pose.up)], axis=1)  # MuJoCo: x right, y up, z back
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, mat.reshape(-1))
    model.cam_pos[cam] = pose.eye
    model.cam_quat[cam] = quat
    model.cam_fovy[cam] = camera.fov


def set_stat(model: mujoco.MjModel, data: mujoco.MjData) -> None:
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


def refresh_constants(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """After in-place edits of masses, sizes, poses (``qpos0``) or cameras: ``mj_setConst``
    (``invweight0``, ``M0``, subtree masses, ``cam_pos0`` / ``cam_mat0``, ``dof_length``,
    bounding volumes), kinematics at ``qpos0`` and :func:`set_stat`. ``data`` is scratch
    (its state is overwritten)."""
    mujoco.mj_setConst(model, data)
    data.qpos[:] = model.qpos0
    mujoco.mj_kinematics(model, data)
    set_stat(model, data)
