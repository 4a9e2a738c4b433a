"""Test-time refinement: re-simulate candidate scenes, score them against the video, refine.

Paper (ΔYNAMICS, DESIGN.md preamble): Best@K sampling, then CMA-ES (popsize 128, 100
iterations) on the fitness *IoU − EPE* with the object types fixed. Here:

* :class:`SceneEvaluator` compiles the MJCF **once per scene structure** (same shapes in the
  same order, same effects) and, for each candidate, edits the ``mjModel`` in place (masses,
  inertias, sizes, bounding volumes, friction, damping, camera, gravity, the ``init``
  keyframe), then rolls out and renders segmentation and exact flow with one reused
  :class:`pipeline.render.FrameRenderer`. DESIGN §10: in-place edits go wrong silently unless
  ``mujoco.mj_setConst`` runs after mass/size changes, ``geom_rbound`` / ``geom_aabb`` (and the
  body BVH) follow the sizes, and ``mj_camlight`` runs before rendering (``FrameRenderer``
  does). ``mj_setConst`` of MuJoCo 3.17 does not refresh ``mjModel.stat`` (mean mass, mean
  inertia, mean size, extent), which the compiler computes and the constraint solver and
  renderer use, so :func:`_set_stat` recomputes it like the compiler. ``tests/test_search.py``
  checks fast == naive (rebuild the XML per candidate).
* :func:`fitness`: ``full_iou − lambda_epe · EPE − prior_weight · prior``.
* :func:`best_of_k`: score K sampled scenes (None = parse error, fitness −inf).
* :func:`cmaes_refine`: CMA-ES (``cma`` library) over a normalised vector of the free fields
  (:class:`SearchConfig`), object types fixed.

DESIGN §10 warns that mask fitness does not identify metric state (camera, depth and size
trade off) nor mass and friction: those stay fixed by default, and reports keep
reconstruction (IoU, EPE) and parameter recovery apart.

Example::

    cfg = SearchConfig(**params["search"])
    scores, best = best_of_k(candidates, obs_seg, obs_flow, cfg, SimOptions(**params["sim"]))
    refined, history = cmaes_refine(candidates[best], obs_seg, obs_flow, cfg, sim, seed=0)
"""

from __future__ import annotations

import copy
import math
import time
from collections import Counter
from typing import Any, Callable, Iterable, Literal, Sequence, get_args

import mujoco
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from pipeline.camera import camera_pose
from pipeline.metrics import as_labels, flow_epe, sequence_iou
from pipeline.mjcf import SimOptions, compile_model, geom_size, initial_state, object_ids
from pipeline.render import FrameRenderer
from pipeline.scene import Scene, SceneError
from pipeline.simulate import rollout

FreeField = Literal["position", "linear_velocity", "angular_velocity", "yaw", "size", "camera",
                    "mass", "friction", "damping"]
FREE_FIELDS: tuple[str, ...] = get_args(FreeField)
"""Field groups CMA-ES may search (``search.free``)."""


class SearchRanges(BaseModel):
    """Half-widths of the search box around the starting scene (params ``search.ranges``).

    Attributes:
        position: m, per coordinate (z is kept at or above the height where the object
            touches the floor, :func:`floor_height`).
        linear_velocity: m/s, per component.
        angular_velocity: rad/s, per component.
        yaw: deg, rotation of the object about world z.
        size_factor: sizes vary in ``[s / f, s * f]`` (searched in log space).
        mass_factor: masses vary in ``[m / f, m * f]`` (log space).
        friction: sliding friction (dimensionless), kept >= 0.
        damping: freejoint damping, kept >= 0.
        camera_height: m (paper camera form).
        camera_position: m per coordinate (6-DoF camera form).
        camera_angle: deg, pitch (and yaw/roll of a 6-DoF camera).
        fov: deg, vertical field of view.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    position: float = Field(0.25, ge=0)
    linear_velocity: float = Field(1.0, ge=0)
    angular_velocity: float = Field(5.0, ge=0)
    yaw: float = Field(45.0, ge=0, le=180)
    size_factor: float = Field(1.5, ge=1)
    mass_factor: float = Field(3.0, ge=1)
    friction: float = Field(0.5, ge=0)
    damping: float = Field(0.5, ge=0)
    camera_height: float = Field(0.15, ge=0)
    camera_position: float = Field(0.15, ge=0)
    camera_angle: float = Field(5.0, ge=0)
    fov: float = Field(8.0, ge=0)


class SearchConfig(BaseModel):
    """Params section ``search`` (test-time refinement).

    Attributes:
        k: samples per scene considered by Best@K (the first ``k`` by sample index; paper 32).
        popsize: CMA-ES population per iteration (paper 128).
        iterations: CMA-ES iterations (paper 100). Evaluations per scene:
            ``1 + popsize * iterations``.
        sigma: initial CMA-ES step size in the normalised [0, 1] search space.
        lambda_epe: weight of the flow EPE (1/px at the rendered resolution) in the fitness;
            1 is the paper's IoU − EPE (measured in px at its 480x320, where the same motion
            is 5x more px than at 96x64).
        prior_weight: weight of the mean squared normalised distance to the starting scene
            (the model's prediction), a prior against drifting where masks do not constrain.
        free: field groups searched (see :data:`FREE_FIELDS`); mass, friction and damping are
            not identified by masks (DESIGN §10) and stay fixed by default.
        ranges: the search box (:class:`SearchRanges`).
        penalize_extra: in the fitness, predicted objects that match no observed object count
            as IoU 0 (see :func:`fitness`).
        splits: dataset splits the best_of_k / cmaes stages process.

    Defaults are the small profile: 1 + 8 x 6 = 49 evaluations, ~3-4 s per scene at 96x64 on
    2 cores. ``sigma`` 0.05 and ``lambda_epe`` 1 did best in a sweep on perturbed synthetic
    scenes with DIS flow (sigma 0.03-0.1, lambda 0.05-2); ``prior_weight`` 5-20 made no
    difference there beyond noise, so it is off.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    k: int = Field(4, ge=1)
    popsize: int = Field(8, ge=2)
    iterations: int = Field(6, ge=0)
    sigma: float = Field(0.05, gt=0, le=1)
    lambda_epe: float = Field(1.0, ge=0)
    prior_weight: float = Field(0.0, ge=0)
    free: tuple[FreeField, ...] = ("position", "linear_velocity", "yaw", "size", "camera")
    ranges: SearchRanges = SearchRanges()
    penalize_extra: bool = True
    splits: tuple[str, ...] = ("test", "test_comp")


# --------------------------------------------------------------------------- evaluator
def structure_key(scene: Scene) -> tuple:
    """What a compiled model fixes: the shapes in order and the effects with their parameters.

    Scenes with equal keys share one :class:`SceneEvaluator`.
    """
    effects = tuple((e.effect, tuple(sorted(e.parameters.items()))) for e in scene.effects)
    return tuple(o.shape for o in scene.objects), effects


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
        self.bodies, self.geoms = object_ids(self.model, self.n)
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


def at_clip_timing(scene: Scene, n_frames: int, fps: int | None) -> Scene:
    """The scene on the observed clip's time base: ``fps`` and ``duration = n_frames / fps``.

    The frame rate and length of a video are known, not inferred (as in the main job), so a
    candidate that states other values is re-timed before it is scored. ``fps=None`` keeps
    the scene's own rate.
    """
    fps = int(fps or scene.fps)
    duration = n_frames / fps
    if scene.fps == fps and abs(scene.duration - duration) < 1e-9:
        return scene
    return scene.replace(fps=fps, duration=duration)


def samples_by_scene(rows: Any, splits: Iterable[str] | None = None,
                     k: int | None = None) -> dict[str, list[dict[str, Any]]]:
    """Prediction rows (``paths.predictions``) grouped by scene, sorted by ``sample``.

    Args:
        rows: a ``pyarrow.Table`` or list of dicts with scene_id, split, sample, scene, ...
        splits: keep only these splits (default all).
        k: keep the first ``k`` samples of each scene (default all).
    Returns:
        ``{scene_id: [row, ...]}`` in order of first appearance.
    """
    if hasattr(rows, "to_pylist"):
        rows = rows.to_pylist()
    keep = None if splits is None else set(splits)
    out: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        if keep is None or r["split"] in keep:
            out.setdefault(r["scene_id"], []).append(r)
    return {sid: sorted(rs, key=lambda r: r["sample"])[:k] for sid, rs in out.items()}


def parse_sample(row: dict[str, Any]) -> Scene | None:
    """The scene of a prediction row (None when the model's output did not parse)."""
    if not row.get("scene"):
        return None
    return Scene.from_yaml(row["scene"], source=f"{row.get('scene_id', '<prediction>')}/sample {row.get('sample')}")


class Observations:
    """Observed clips of the synthetic dataset, by scene id.

    Segmentation: the render stage's ``seg`` (rendered ground truth, ``paths.video``); flow:
    the flow stage's ``flow`` (estimated from RGB by params ``flow.method``, ``paths.flow``);
    frame rate: the video shard's ``fps`` attribute. Only scene-id arrays are read up front.

    Args:
        video_dir, flow_dir: stage directories (``paths.video``, ``paths.flow``).
    Raises:
        ShardError: a directory or shard is missing or unreadable.
    """

    def __init__(self, video_dir, flow_dir):
        from pipeline import shards

        self._video: dict[str, tuple[Any, int]] = {}
        self._flow: dict[str, tuple[Any, int]] = {}
        for _, group in shards.iter_array_shards(video_dir):
            for j, sid in enumerate(shards.scene_ids_of(group)):
                self._video[sid] = (group, j)
        for _, group in shards.iter_array_shards(flow_dir):
            for j, sid in enumerate(shards.scene_ids_of(group)):
                self._flow[sid] = (group, j)
        self.video_dir, self.flow_dir = video_dir, flow_dir

    def __contains__(self, sid: str) -> bool:
        return sid in self._video

    @property
    def frame_size(self) -> tuple[int, int]:
        """``(width, height)`` px of the clips (of the first shard; every shard is rendered alike)."""
        if not self._video:
            raise ValueError(f"{self.video_dir}: no scenes")
        group, _ = next(iter(self._video.values()))
        shape = group["seg"].shape  # (N, T, H, W)
        return int(shape[3]), int(shape[2])

    def get(self, sid: str) -> tuple[np.ndarray, np.ndarray, int | None]:
        """``seg (T, H, W) int8``, ``flow (T-1, H, W, 2) float32`` px and fps (None if unknown).

        Raises:
            ShardError: the scene is missing from the video or flow shards.
        """
        from pipeline.shards import ShardError

        if sid not in self._video:
            raise ShardError(f"{self.video_dir}: no scene {sid!r}")
        if sid not in self._flow:
            raise ShardError(f"{self.flow_dir}: no scene {sid!r}")
        vg, i = self._video[sid]
        fg, j = self._flow[sid]
        fps = vg.attrs.get("fps")
        return (np.asarray(vg["seg"][i], dtype=np.int8), np.asarray(fg["flow"][j], dtype=np.float32),
                int(fps) if fps else None)


# --------------------------------------------------------------------------- fitness
def fitness(pred_seg: np.ndarray, pred_flow: np.ndarray | None, obs_seg: np.ndarray,
            obs_flow: np.ndarray | None, cfg: SearchConfig, prior: float = 0.0) -> dict[str, float]:
    """Fitness of a re-simulated clip: ``IoU − lambda_epe · EPE − prior_weight · prior``.

    Paper: fitness IoU − EPE. The IoU is the matched full-sequence IoU
    (:func:`pipeline.metrics.sequence_iou`) when ``obs_seg`` is a label map (int, -1
    background: rendered ground truth, or pseudo masks split into objects by
    ``pipeline.video.label_objects``); with ``cfg.penalize_extra`` it is averaged over
    ``max(n_true, n_pred)`` objects instead of the true ones, so a predicted object that
    matches nothing costs as much as a missed one (the DESIGN §7 metric ignores extra objects,
    which would let Best@K prefer candidates that add objects). For a bool foreground-only
    ``obs_seg`` it is the foreground IoU (object identities unknown). EPE is in px at the
    rendered resolution over pixels where either clip is foreground
    (:func:`pipeline.metrics.flow_epe`). The returned ``initial_iou`` / ``full_iou`` are the
    DESIGN §7 metrics, without the extra-object penalty.

    Args:
        pred_seg: ``(T, H, W)`` int8 re-simulated labels.
        pred_flow: ``(T-1, H, W, 2)`` float re-simulated flow, or None.
        obs_seg: ``(T, H, W)`` observed labels (int) or foreground (bool).
        obs_flow: ``(T-1, H, W, 2)`` observed flow, or None (then EPE is NaN and not used).
        cfg: weights ``lambda_epe`` and ``prior_weight``.
        prior: penalty value (e.g. mean squared normalised distance to the model's scene).
    Returns:
        dict: ``fitness``, ``initial_iou``, ``full_iou``, ``epe`` (px, NaN if not computed),
        ``prior``.
    """
    obs = np.asarray(obs_seg)
    iou = sequence_iou(obs, pred_seg)
    if obs.dtype == bool:
        initial, full = iou["foreground_iou_initial"], iou["foreground_iou_full"]
        term = full
    else:
        initial, full = iou["initial_iou"], iou["full_iou"]
        n_true, n_pred = iou["n_true"], iou["n_pred"]
        term = full * n_true / max(n_true, n_pred) if cfg.penalize_extra and n_true else full
    epe = math.nan
    if pred_flow is not None and obs_flow is not None:
        epe = flow_epe(pred_flow, obs_flow, np.asarray(pred_seg)[:-1] >= 0, as_labels(obs)[:-1] >= 0)
    f = term - cfg.prior_weight * prior
    if cfg.lambda_epe > 0 and not math.isnan(epe):
        f -= cfg.lambda_epe * epe
    return {"fitness": float(f), "initial_iou": float(initial), "full_iou": float(full),
            "epe": float(epe), "prior": float(prior)}


def _invalid_score(error: str) -> dict[str, Any]:
    return {"valid": False, "fitness": -math.inf, "initial_iou": math.nan, "full_iou": math.nan,
            "epe": math.nan, "prior": 0.0, "error": error}


def _check_obs(obs_seg: np.ndarray, obs_flow: np.ndarray | None) -> tuple[int, int, int]:
    seg = np.asarray(obs_seg)
    if seg.ndim != 3:
        raise ValueError(f"obs_seg: must be (T, H, W), got shape {seg.shape}")
    T, H, W = seg.shape
    if obs_flow is not None and np.shape(obs_flow) != (T - 1, H, W, 2):
        raise ValueError(f"obs_flow: must be {(T - 1, H, W, 2)} to match obs_seg, got {np.shape(obs_flow)}")
    return T, H, W


# --------------------------------------------------------------------------- Best@K
def best_of_k(candidates: Sequence[Scene | None], obs_seg: np.ndarray, obs_flow: np.ndarray | None,
              cfg: SearchConfig, options: SimOptions | None = None,
              pool: EvaluatorPool | None = None) -> tuple[list[dict[str, Any]], int | None]:
    """Score K candidate scenes against an observed clip and pick the best (paper: Best@K).

    Candidates of one structure share one compiled model (:class:`EvaluatorPool`). All
    candidates are scored (slice to ``cfg.k`` before calling if needed).

    Args:
        candidates: parsed samples; ``None`` is a parse error (fitness −inf).
        obs_seg: ``(T, H, W)`` observed labels (int8, -1 background) or bool foreground;
            fixes T and the render size.
        obs_flow: ``(T-1, H, W, 2)`` observed flow, px, or None.
        cfg: fitness weights.
        options: simulation options (params ``sim``).
        pool: evaluators to reuse across calls (same render size); default: a private pool.
    Returns:
        ``(scores, best)``: one dict per candidate (``valid``, ``fitness``, ``initial_iou``,
        ``full_iou``, ``epe``, ``prior``, ``error``) and the index of the highest fitness
        (first on ties), or None when no candidate is valid.
    """
    T, H, W = _check_obs(obs_seg, obs_flow)
    own = pool is None
    pool = pool or EvaluatorPool(W, H, options)
    if (pool.width, pool.height) != (W, H):
        raise ValueError(f"pool renders {pool.width}x{pool.height}, observation is {W}x{H}")
    need_flow = obs_flow is not None and cfg.lambda_epe > 0
    scores: list[dict[str, Any]] = []
    try:
        for c in candidates:
            if c is None:
                scores.append(_invalid_score("parse error"))
                continue
            try:
                ev = pool.get(c)
            except (SceneError, ValueError) as exc:
                scores.append(_invalid_score(str(exc)))
                continue
            seg, flow = ev.evaluate(c, T, flow=need_flow)
            scores.append({"valid": True, **fitness(seg, flow, obs_seg, obs_flow, cfg), "error": None})
    finally:
        if own:
            pool.close()
    fit = [s["fitness"] for s in scores]
    best = int(np.argmax(fit)) if fit and max(fit) > -math.inf else None
    return scores, best


# --------------------------------------------------------------------------- CMA-ES
class SearchSpace:
    """Normalised search vector of a scene: each free parameter mapped to [0, 1].

    Parameter ``p`` with bounds ``[lo, hi]`` around the start value is ``x = (p − lo) / (hi −
    lo)``; sizes and masses are searched in log space; yaw is a rotation of the starting
    orientation about world z (deg). Bounds are clipped to what the scene language accepts
    (pitch in [-89, 89], fov in (1, 179), friction/damping >= 0) and z to at least the
    object's floor contact height (:func:`floor_height`; no start inside the floor), so every
    vector decodes to a valid scene. Parameters with an empty range are left out.

    Args:
        scene: the starting scene (its structure stays fixed).
        free: field groups to search (see :data:`FREE_FIELDS`).
        ranges: half-widths of the box.
    """

    def __init__(self, scene: Scene, free: Iterable[str], ranges: SearchRanges):
        self.scene = scene
        self._base = scene.model_dump()
        self.names: list[str] = []
        self._path: list[tuple] = []
        self._kind: list[str] = []
        lo, hi, x0 = [], [], []
        free = set(free)
        bad = free - set(FREE_FIELDS)
        if bad:
            raise ValueError(f"search.free: unknown field(s) {sorted(bad)}, must be among {FREE_FIELDS}")

        def add(name: str, path: tuple, value: float, low: float, high: float, kind: str = "lin") -> None:
            if kind == "log":
                value, low, high = math.log(value), math.log(low), math.log(high)
            if not high > low:
                return
            self.names.append(name)
            self._path.append(path)
            self._kind.append(kind)
            lo.append(low)
            hi.append(high)
            x0.append((value - low) / (high - low))

        r = ranges
        for i, o in enumerate(scene.objects):
            pre = f"objects[{i}]"
            if "position" in free:
                for k, axis in enumerate("xyz"):
                    v = o.position[k]
                    # z: not below the floor contact height (an object starts on or above the floor)
                    low = min(max(v - r.position, floor_height(o)), v) if axis == "z" else v - r.position
                    add(f"{pre}.position.{axis}", ("objects", i, "position", k), v, low, v + r.position)
            if "linear_velocity" in free:
                for k, axis in enumerate("xyz"):
                    v = o.linear_velocity[k]
                    add(f"{pre}.linear_velocity.{axis}", ("objects", i, "linear_velocity", k), v,
                        v - r.linear_velocity, v + r.linear_velocity)
            if "angular_velocity" in free:
                for k, axis in enumerate("xyz"):
                    v = o.angular_velocity[k]
                    add(f"{pre}.angular_velocity.{axis}", ("objects", i, "angular_velocity", k), v,
                        v - r.angular_velocity, v + r.angular_velocity)
            if "yaw" in free:
                add(f"{pre}.yaw", ("objects", i, "yaw"), 0.0, -r.yaw, r.yaw, "yaw")
            if "size" in free:
                for key, v in o.size.model_dump().items():
                    add(f"{pre}.size.{key}", ("objects", i, "size", key), v, v / r.size_factor,
                        v * r.size_factor, "log")
            if "mass" in free:
                add(f"{pre}.mass", ("objects", i, "mass"), o.mass, o.mass / r.mass_factor,
                    o.mass * r.mass_factor, "log")
            if "friction" in free:
                v = o.material.sliding_friction
                add(f"{pre}.material.sliding_friction", ("objects", i, "material", "sliding_friction"), v,
                    max(0.0, v - r.friction), v + r.friction)
            if "damping" in free:
                v = o.material.damping
                add(f"{pre}.material.damping", ("objects", i, "material", "damping"), v,
                    max(0.0, v - r.damping), v + r.damping)
        if "camera" in free:
            cam = scene.camera
            if cam.is_six_dof:
                for k, axis in enumerate("xyz"):
                    v = cam.position[k]
                    add(f"camera.position.{axis}", ("camera", "position", k), v, v - r.camera_position,
                        v + r.camera_position)
                for key in ("yaw", "roll"):
                    v = getattr(cam, key) or 0.0
                    add(f"camera.{key}", ("camera", key), v, v - r.camera_angle, v + r.camera_angle)
            else:
                v = cam.height
                add("camera.height", ("camera", "height"), v, max(0.05, v - r.camera_height), v + r.camera_height)
            v = cam.pitch
            add("camera.pitch", ("camera", "pitch"), v, max(-89.0, v - r.camera_angle), min(89.0, v + r.camera_angle))
            v = cam.fov
            add("camera.fov", ("camera", "fov"), v, max(1.5, v - r.fov), min(178.5, v + r.fov))
        self.lo, self.hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
        self.x0 = np.clip(np.asarray(x0, dtype=np.float64), 0.0, 1.0)

    @property
    def dim(self) -> int:
        return len(self.names)

    def decode(self, x: np.ndarray) -> Scene:
        """The scene of a normalised vector ``x (dim,)`` in [0, 1] (clipped).

        Raises:
            SceneError: only if the starting scene itself was invalid.
        """
        x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
        values = self.lo + x * (self.hi - self.lo)
        d = copy.deepcopy(self._base)
        for path, kind, v in zip(self._path, self._kind, values):
            if kind == "log":
                v = math.exp(v)
            if kind == "yaw":
                obj = d[path[0]][path[1]]
                obj["orientation"] = tuple(_yaw_quat(math.radians(v), obj["orientation"]))
                continue
            target = d
            for key in path[:-1]:
                target = target[key]
            if isinstance(target, tuple):  # vectors are tuples in model_dump
                parent = d
                for key in path[:-2]:
                    parent = parent[key]
                lst = list(target)
                lst[path[-1]] = float(v)
                parent[path[-2]] = tuple(lst)
            else:
                target[path[-1]] = float(v)
        return Scene.from_dict(d, source="<search>")

    def prior(self, x: np.ndarray) -> float:
        """Mean squared normalised distance of ``x`` to the starting vector."""
        return float(np.mean((np.asarray(x) - self.x0) ** 2)) if self.dim else 0.0


def floor_height(obj) -> float:
    """Height (m) of an object's centre when its lowest point touches the floor z = 0, for its
    orientation: the half extent along world z of the rotated primitive."""
    R = np.zeros(9)
    q = np.asarray(obj.orientation, dtype=np.float64)
    mujoco.mju_quat2Mat(R, q / np.linalg.norm(q))
    axis_z = R.reshape(3, 3)[2]  # world z expressed in body axes (row 2 of R)
    half = _half_extents(obj)
    if obj.shape == "sphere":
        return float(half[0])
    if obj.shape == "cylinder":
        r, h = half[0], half[2]
        return float(abs(axis_z[2]) * h + r * math.sqrt(max(0.0, 1.0 - axis_z[2] ** 2)))
    return float(np.abs(axis_z) @ half)


def _yaw_quat(angle: float, q: Sequence[float]) -> np.ndarray:
    """Quaternion (w, x, y, z) of rotating orientation ``q`` by ``angle`` rad about world z."""
    rz = np.array([math.cos(angle / 2.0), 0.0, 0.0, math.sin(angle / 2.0)])
    out = np.zeros(4)
    mujoco.mju_mulQuat(out, rz, np.asarray(q, dtype=np.float64) / np.linalg.norm(q))
    return out


def cmaes_refine(scene: Scene, obs_seg: np.ndarray, obs_flow: np.ndarray | None, cfg: SearchConfig,
                 options: SimOptions | None = None, seed: int = 0,
                 callback: Callable[[dict], None] | None = None,
                 pool: EvaluatorPool | None = None) -> tuple[Scene, list[dict[str, Any]]]:
    """Refine a scene by CMA-ES on :func:`fitness`, object types fixed (paper).

    Searches the free fields of ``cfg.free`` in the normalised box of :class:`SearchSpace`
    with ``cma.CMAEvolutionStrategy`` (bounds [0, 1], ``popsize``, ``sigma``), for exactly
    ``cfg.iterations`` iterations. The starting scene is evaluated first, so the result is
    never worse than the start. Deterministic for a given ``seed``.

    Args:
        scene: starting scene (e.g. the Best@K pick).
        obs_seg: ``(T, H, W)`` observed labels (int8) or bool foreground.
        obs_flow: ``(T-1, H, W, 2)`` observed flow, px, or None.
        cfg: search parameters.
        options: simulation options (params ``sim``).
        seed: random seed (any int; mapped to ``cma``'s positive seeds).
        callback: called with each history entry (progress display).
        pool: evaluators to reuse across scenes (same render size); default: a private one.
    Returns:
        ``(best_scene, history)``; history has one dict per iteration (0 = the start):
        ``iteration``, ``best_fitness`` (best so far), ``mean_fitness`` (of the iteration's
        finite scores), ``best_full_iou``, ``best_epe`` (of the best so far), ``evaluations``
        (cumulative), ``seconds`` (cumulative wall time).
    """
    import cma

    T, H, W = _check_obs(obs_seg, obs_flow)
    space = SearchSpace(scene, cfg.free, cfg.ranges)
    need_flow = obs_flow is not None and cfg.lambda_epe > 0
    t0 = time.perf_counter()
    history: list[dict[str, Any]] = []
    ev = SceneEvaluator(scene, W, H, options) if pool is None else pool.get(scene)
    try:
        def score(x: np.ndarray) -> dict[str, float]:
            cand = space.decode(x) if space.dim else scene
            seg, flow = ev.evaluate(cand, T, flow=need_flow)
            return fitness(seg, flow, obs_seg, obs_flow, cfg, prior=space.prior(x))

        best_x = space.x0.copy()
        best = score(best_x)
        evaluations = 1

        def log(it: int, mean: float) -> None:
            entry = {"iteration": it, "best_fitness": best["fitness"], "mean_fitness": mean,
                     "best_full_iou": best["full_iou"], "best_epe": best["epe"],
                     "evaluations": evaluations, "seconds": round(time.perf_counter() - t0, 3)}
            history.append(entry)
            if callback is not None:
                callback(entry)

        log(0, best["fitness"])
        if space.dim and cfg.iterations > 0:
            opts = {"popsize": cfg.popsize, "bounds": [0.0, 1.0], "seed": int(seed) % (2**31 - 2) + 1,
                    "verbose": -9, "maxiter": cfg.iterations, "tolfun": 0.0, "tolfunhist": 0.0,
                    "tolflatfitness": cfg.iterations + 1, "tolx": 0.0}
            es = cma.CMAEvolutionStrategy(space.x0.tolist(), cfg.sigma, opts)
            for it in range(1, cfg.iterations + 1):
                xs = es.ask()
                results = [score(np.asarray(x)) for x in xs]
                evaluations += len(xs)
                losses = [-r["fitness"] if math.isfinite(r["fitness"]) else 1e6 for r in results]
                es.tell(xs, losses)
                i = int(np.argmin(losses))
                if results[i]["fitness"] > best["fitness"]:
                    best, best_x = results[i], np.asarray(xs[i], dtype=np.float64)
                finite = [r["fitness"] for r in results if math.isfinite(r["fitness"])]
                log(it, float(np.mean(finite)) if finite else -math.inf)
    finally:
        if pool is None:
            ev.close()
    return (space.decode(best_x) if space.dim else scene), history


# --------------------------------------------------------------------------- baseline
def baseline_scene(configs: Any, split: str = "train") -> Scene:
    """The trivial baseline: the most common composition of the training split with the mean
    parameters of the training scenes of that composition, per shape slot.

    Slots: a scene's objects sorted by shape (stable, so same-shape objects keep their scene
    order); slot j of the baseline averages slot j of every training scene with the winning
    composition. Vectors are averaged component-wise; orientations by the normalised mean of
    sign-aligned quaternions; the camera per field (paper form when every scene uses it, else
    the 6-DoF form); duration and fps take the most common value. Ties between compositions go
    to the lexicographically smallest.

    Args:
        configs: a ``pyarrow.Table`` / list of rows with columns ``scene`` (YAML) and
            ``split``, or a list of :class:`Scene` / YAML strings (all used).
        split: split to learn from when rows carry one.
    Returns:
        the baseline :class:`Scene` (no effects).
    Raises:
        ValueError: no scene of that split.
    """
    scenes = _scenes_of(configs, split)
    if not scenes:
        raise ValueError(f"baseline_scene: no scene of split {split!r}")
    counts = Counter(s.composition for s in scenes)
    comp = min(counts, key=lambda c: (-counts[c], c))
    group = [s for s in scenes if s.composition == comp]
    slots = [sorted(s.objects, key=lambda o: o.shape) for s in group]  # stable sort
    objects = []
    for j, shape in enumerate(comp):
        objs = [sl[j] for sl in slots]
        dumps = [o.model_dump() for o in objs]
        mean = lambda key: [float(np.mean([d[key][k] for d in dumps])) for k in range(3)]  # noqa: E731
        qs = np.array([o.orientation for o in objs], dtype=np.float64)
        qs /= np.linalg.norm(qs, axis=1, keepdims=True)
        qs *= np.where(qs @ qs[0] < 0, -1.0, 1.0)[:, None]
        q = qs.mean(axis=0)
        q = q / np.linalg.norm(q) if np.linalg.norm(q) > 1e-9 else np.array([1.0, 0.0, 0.0, 0.0])
        objects.append({
            "shape": shape,
            "size": {k: float(np.mean([d["size"][k] for d in dumps])) for k in dumps[0]["size"]},
            "mass": float(np.mean([o.mass for o in objs])),
            "position": mean("position"), "orientation": q.tolist(),
            "linear_velocity": mean("linear_velocity"), "angular_velocity": mean("angular_velocity"),
            "material": {k: float(np.mean([d["material"][k] for d in dumps])) for k in dumps[0]["material"]},
        })
    cams = [s.camera for s in group]
    if all(not c.is_six_dof for c in cams):
        camera = {"height": float(np.mean([c.height for c in cams]))}
    else:
        camera = {"position": np.mean([c.eye for c in cams], axis=0).tolist(),
                  "yaw": float(np.mean([c.yaw or 0.0 for c in cams])),
                  "roll": float(np.mean([c.roll or 0.0 for c in cams]))}
    camera.update(pitch=float(np.mean([c.pitch for c in cams])), fov=float(np.mean([c.fov for c in cams])))
    mode = lambda xs: Counter(xs).most_common(1)[0][0]  # noqa: E731
    return Scene.from_dict({
        "duration": mode([s.duration for s in group]), "fps": mode([s.fps for s in group]),
        "gravity": float(np.mean([s.gravity for s in group])), "camera": camera, "objects": objects,
    }, source="<baseline>")


def _scenes_of(configs: Any, split: str) -> list[Scene]:
    if hasattr(configs, "to_pylist"):
        configs = configs.to_pylist()
    out = []
    for item in configs:
        if isinstance(item, Scene):
            out.append(item)
        elif isinstance(item, str):
            out.append(Scene.from_yaml(item))
        elif isinstance(item, dict):
            if item.get("split", split) == split and item.get("scene"):
                out.append(Scene.from_yaml(item["scene"], source=str(item.get("scene_id", "<configs>"))))
        else:
            raise TypeError(f"baseline_scene: cannot read a scene from {type(item).__name__}")
    return out


# --------------------------------------------------------------------------- reports
def plot_history(histories: Sequence[Sequence[dict[str, Any]]], title: str = "CMA-ES") -> bytes:
    """PNG of CMA-ES progress averaged over scenes: best-so-far and population-mean fitness
    and the best-so-far full-sequence IoU against the iteration.

    Args:
        histories: per scene, the ``history`` list of :func:`cmaes_refine`.
        title: figure title.
    Returns:
        PNG bytes (matplotlib, Agg backend), to write atomically.
    """
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    histories = [h for h in histories if h]
    fig, (ax_f, ax_i) = plt.subplots(1, 2, figsize=(9, 3.4))
    if histories:
        n_it = min(len(h) for h in histories)

        def mean_of(key: str) -> np.ndarray:
            vals = np.array([[e[key] for e in h[:n_it]] for h in histories], dtype=np.float64)
            vals[~np.isfinite(vals)] = np.nan
            return np.nanmean(vals, axis=0) if np.isfinite(vals).any() else np.full(n_it, np.nan)

        it = np.arange(n_it)
        ax_f.plot(it, mean_of("best_fitness"), "o-", label="best so far")
        ax_f.plot(it, mean_of("mean_fitness"), "s--", alpha=0.7, label="population mean")
        ax_i.plot(it, mean_of("best_full_iou"), "o-", color="tab:green")
        ax_f.legend(fontsize=8)
        evals = np.mean([h[n_it - 1]["evaluations"] for h in histories])
        fig.suptitle(f"{title}: mean over {len(histories)} scenes, {evals:.0f} evaluations each", fontsize=10)
    else:
        for ax in (ax_f, ax_i):
            ax.text(0.5, 0.5, "no scene was refined", ha="center", va="center", transform=ax.transAxes)
        fig.suptitle(title, fontsize=10)
    ax_f.set(xlabel="iteration", ylabel="fitness (IoU − λ·EPE)")
    ax_i.set(xlabel="iteration", ylabel="full-sequence IoU of the best")
    for ax in (ax_f, ax_i):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return buf.getvalue()
