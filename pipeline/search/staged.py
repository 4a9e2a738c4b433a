"""Staged CMA-ES for real videos: camera and pose first, then velocities, then size and material,
then pose and velocity again, then a restitution effect's ``e`` (and a bumper's), then the sizes
with the camera's exposure (motion blur, :mod:`pipeline.exposure`), in search boxes that scale
with the objects and the camera distance, with restarts (issue 9).

One joint CMA-ES over every field in a fixed box (:func:`pipeline.search.cmaes.cmaes_refine`
with the params' ``search.ranges``) suits the synthetic scenes, whose objects are 20-40 cm seen
from 1-2 m. A 4 cm ball seen from 30 cm needs boxes a hundred times smaller, and a pose error
hides every velocity gain, so here each stage searches a few field groups in a box scaled to
the scene (:func:`scaled_ranges`) and starts from the previous stage's best; the first stage
(the most multimodal: camera, positions, yaw) runs ``restarts`` times with different seeds.
The fitness is the paper's ``IoU - lambda * EPE`` (:func:`pipeline.search.fitness.fitness`),
with ``lambda`` given per px of a 96 px wide image and rescaled to the working width so that
the same motion weighs the same at any resolution.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from pipeline.camera import camera_pose
from pipeline.geometry import bounding_radius
from pipeline.mjcf import SimOptions
from pipeline.scene import Scene
from pipeline.search.cmaes import cmaes_refine
from pipeline.search.config import SearchConfig, SearchRanges
from pipeline.search.evaluator import EvaluatorPool
from pipeline.search.fitness import best_of_k
from pipeline.search.parallel_eval import ParallelFitness
from pipeline.search.space import SearchSpace

STAGES: tuple[tuple[str, ...], ...] = (
    ("camera", "position", "yaw"),
    ("linear_velocity", "angular_velocity"),
    ("size", "friction"),
    ("position", "linear_velocity"),
    ("restitution",),
    ("size", "exposure"),
)
"""Field groups per stage (see :data:`pipeline.search.config.FREE_FIELDS`). A stage with no
parameter in the scene (``restitution`` without a restitution effect) is skipped. The exposure
is searched last, with the sizes (a blurred silhouette is otherwise fitted by a larger object):
in a stage of its own the earlier stages draw the same samples as without it, so a clip whose
camera is sharp ends where it did (with it in the size stage, the extra dimension alone moved
real clips by up to 0.14 against their hand labels, both ways)."""

REFERENCE_WIDTH = 96
"""px: ``search.lambda_epe`` is per px of an image this wide (the small profile's renders)."""


def at_width(cfg: SearchConfig, width: int) -> SearchConfig:
    """``cfg`` with ``lambda_epe`` (given per px of a :data:`REFERENCE_WIDTH` px wide image)
    rescaled to an image ``width`` px wide: the same motion is ``width / 96`` times more px there,
    so it weighs the same in the fitness at any resolution. The one place this scaling is done."""
    return cfg.model_copy(update={"lambda_epe": cfg.lambda_epe * REFERENCE_WIDTH / width})


def scaled_ranges(scene: Scene) -> SearchRanges:
    """Search box scaled to a scene: with ``L`` the median bounding radius of its objects (m),
    ``D`` the mean camera-to-object distance (m) and ``v`` the largest initial speed (m/s):
    positions ``+-(2 L + 0.05 D)``, velocities ``+-(0.3 v + 4 L / s)``, spin ``+-(2 / L)`` rad/s
    capped at 20, camera height / position ``+-0.1 D``, camera angles ``+-8`` deg, fov ``+-10``
    deg, sizes ``x/ 1.5``, friction ``+-0.4``."""
    L = float(np.median([bounding_radius(o.shape, o.size) for o in scene.objects]))
    eye = camera_pose(scene.camera).eye
    D = float(np.mean([np.linalg.norm(np.asarray(o.position) - eye) for o in scene.objects]))
    v = max(float(np.linalg.norm(o.linear_velocity)) for o in scene.objects)
    return SearchRanges(position=2 * L + 0.05 * D, linear_velocity=0.3 * v + 4 * L,
                        angular_velocity=min(20.0, 2.0 / max(L, 1e-3)), yaw=45.0, size_factor=1.5,
                        mass_factor=3.0, friction=0.4, damping=0.5, camera_height=0.1 * D,
                        camera_position=0.1 * D, camera_angle=8.0, fov=10.0)


def staged_refine(scene: Scene, obs_seg: np.ndarray, obs_flow: np.ndarray | None, cfg: SearchConfig,
                  options: SimOptions | None = None, seed: int = 0, restarts: int = 2,
                  stages: tuple[tuple[str, ...], ...] = STAGES, pool: EvaluatorPool | None = None,
                  callback: Callable[[dict], None] | None = None, workers: int = 1,
                  ) -> tuple[Scene, list[dict[str, Any]]]:
    """Refine a scene stage by stage (module docstring).

    Args:
        scene: start (e.g. the Best@K pick).
        obs_seg: ``(T, H, W)`` int8 observed labels (-1 background).
        obs_flow: ``(T-1, H, W, 2)`` float observed flow, px, or None.
        cfg: ``popsize``, ``iterations`` (per stage and restart), ``sigma``, ``lambda_epe`` (per
            px at :data:`REFERENCE_WIDTH`), ``prior_weight``, ``penalize_extra``; ``free`` and
            ``ranges`` are replaced per stage.
        options: simulation options.
        seed: base seed; restart ``r`` of stage ``s`` uses ``seed + 1000 s + r``.
        restarts: CMA-ES runs of the first stage (the best is kept).
        stages: field groups per stage.
        pool: evaluators to reuse (same render size).
        callback: called with each history entry.
        workers: processes scoring each CMA-ES generation; above 1, one
            :class:`pipeline.search.parallel_eval.ParallelFitness` (the observation sent to each
            worker once) serves every stage and restart, with the same result as 1.
    Returns:
        ``(best_scene, history)``: history entries as :func:`cmaes_refine`'s, with ``stage``
        and ``restart`` added and ``evaluations`` / ``seconds`` cumulative over all stages.
    """
    T, H, W = np.shape(obs_seg)
    lam = at_width(cfg, W).lambda_epe
    own = pool is None
    pool = pool or EvaluatorPool(W, H, options)
    scorer = ParallelFitness(obs_seg, obs_flow, cfg, options, workers) if workers > 1 else None
    history: list[dict[str, Any]] = []
    evals, secs = 0, 0.0
    best = scene
    try:
        for s, free in enumerate(stages):
            stage_cfg = cfg.model_copy(update={"free": tuple(free), "ranges": scaled_ranges(best),
                                               "lambda_epe": lam})
            if not SearchSpace(best, stage_cfg.free, stage_cfg.ranges).dim:
                continue
            runs = []
            for r in range(restarts if s == 0 else 1):
                refined, hist = cmaes_refine(best, obs_seg, obs_flow, stage_cfg, options,
                                             seed=seed + 1000 * s + r, pool=pool, scorer=scorer)
                for h in hist:
                    entry = {**h, "stage": s, "restart": r, "evaluations": evals + h["evaluations"],
                             "seconds": round(secs + h["seconds"], 3)}
                    history.append(entry)
                    if callback is not None:
                        callback(entry)
                evals += hist[-1]["evaluations"]
                secs += hist[-1]["seconds"]
                runs.append((hist[-1]["best_fitness"], refined))
            best = max(runs, key=lambda fr: fr[0])[1]
    finally:
        if scorer is not None:
            scorer.close()
        if own:
            pool.close()
    return best, history


def score_scene(scene: Scene, obs_seg: np.ndarray, obs_flow: np.ndarray | None, cfg: SearchConfig,
                options: SimOptions | None = None, pool: EvaluatorPool | None = None) -> dict[str, Any]:
    """Fitness terms of one scene with the width-scaled ``lambda`` of :func:`staged_refine`."""
    scores, _ = best_of_k([scene], obs_seg, obs_flow, at_width(cfg, np.shape(obs_seg)[2]), options, pool=pool)
    return scores[0]
