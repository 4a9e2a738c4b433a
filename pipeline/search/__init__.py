"""Test-time refinement: re-simulate candidate scenes, score them against the video, refine.

Paper (ΔYNAMICS, docs/design.md preamble): Best@K sampling, then CMA-ES (popsize 128, 100
iterations) on the fitness *IoU − EPE* with the object types fixed. Here:

* :class:`SceneEvaluator` compiles the MJCF **once per scene structure** (same shapes in the
  same order, same effects) and, for each candidate, edits the ``mjModel`` in place (masses,
  inertias, sizes, bounding volumes, friction, damping, camera, gravity, the ``init``
  keyframe) with the compile-once engine (:mod:`pipeline.engine`, which says what in-place
  edits must refresh), then rolls out and renders segmentation and exact flow with one reused
  :class:`pipeline.render.FrameRenderer`. ``tests/test_search.py`` checks fast == naive
  (rebuild the XML per candidate).
* :func:`fitness`: ``IoU − lambda_epe · EPE − prior_weight · prior`` (IoU: strict by default).
* :func:`best_of_k`: score K sampled scenes (None = parse error, fitness −inf).
* :func:`cmaes_refine`: CMA-ES (``cma`` library) over a normalised vector of the free fields
  (:class:`SearchConfig`), object types fixed.

docs/design.md §10 warns that mask fitness does not identify metric state (camera, depth and size
trade off) nor mass and friction: those stay fixed by default, and reports keep
reconstruction (IoU, EPE) and parameter recovery apart.

Example::

    cfg, sim = typed_section(params, "search", SearchConfig), typed_section(params, "sim", SimOptions)
    scores, best = best_of_k(candidates, obs_seg, obs_flow, cfg, sim)
    refined, history = cmaes_refine(candidates[best], obs_seg, obs_flow, cfg, sim, seed=0)

Package layout: :mod:`.config` (SearchConfig, SearchRanges, FREE_FIELDS), :mod:`.evaluator`
(SceneEvaluator, EvaluatorPool, evaluate_scene; ``structure_key`` from :mod:`pipeline.engine`), :mod:`.fitness` (fitness,
best_of_k), :mod:`.observations` (Observations, samples_by_scene, parse_sample,
at_clip_timing), :mod:`.space` (SearchSpace, floor_height), :mod:`.cmaes` (cmaes_refine),
:mod:`.parallel_eval` (ParallelEvaluator: candidates over a process pool), :mod:`.baseline`
(baseline_scene), :mod:`.plot` (plot_history). Everything is re-exported
here, so ``from pipeline.search import X`` and ``search.X`` work as before the split.
"""

from pipeline.search.baseline import baseline_scene
from pipeline.search.cmaes import cmaes_refine
from pipeline.search.config import FREE_FIELDS, FreeField, SearchConfig, SearchRanges
from pipeline.engine import structure_key
from pipeline.search.evaluator import EvaluatorPool, SceneEvaluator, evaluate_scene
from pipeline.search.fitness import SHAPE_DOF, best_index, best_of_k, fitness, simplest_within
from pipeline.search.observations import Observations, at_clip_timing, parse_sample, samples_by_scene
from pipeline.search.parallel_eval import ParallelEvaluator
from pipeline.search.plot import plot_history
from pipeline.search.space import SearchSpace, floor_height

__all__ = [
    "FREE_FIELDS", "EvaluatorPool", "FreeField", "Observations", "ParallelEvaluator", "SceneEvaluator",
    "SHAPE_DOF", "SearchConfig", "SearchRanges", "SearchSpace", "at_clip_timing", "baseline_scene", "best_index", "best_of_k", "cmaes_refine",
    "evaluate_scene", "fitness", "floor_height", "parse_sample", "plot_history", "samples_by_scene", "simplest_within",
    "structure_key",
]
