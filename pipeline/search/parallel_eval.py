"""Evaluate or score many candidate scenes over a process pool (one :class:`EvaluatorPool` per
worker).

A CMA-ES generation (``popsize`` candidates) or the K samples of Best@K are independent, so
they can be split over the cores: each worker process keeps its own compiled models and
renderers (:class:`pipeline.search.evaluator.EvaluatorPool`, cached across calls) and returns
the rendered clips. Results equal :meth:`SceneEvaluator.evaluate` in this process bit for bit
(every evaluation starts from the ``init`` keyframe of a freshly edited model; ``tests/
test_search.py``). Workers are ``spawn``-started with one thread per library
(:func:`pipeline.parallel.make_pool`).

Shipping the clips back costs: at 192x144 a candidate's seg and flow are ~6.5 MB (~13 MB
through the pipe and the unpickling), as long as rendering them. :class:`ParallelFitness` sends
the observation to each worker once (pool initializer) and gets back only the fitness dicts of
:func:`pipeline.search.fitness.fitness`, equal to scoring in this process float for float
(same clips bit for bit, same arithmetic).

Example::

    with ParallelEvaluator(W, H, sim, workers=2) as pe:
        clips = pe.evaluate_many(candidates, T, flow=False)   # [(seg, flow), ...] in order

    with ParallelFitness(obs_seg, obs_flow, cfg, sim, workers=2) as pf:
        scores = pf.score(candidates)                          # [fitness dict, ...] in order
        best, history = cmaes_refine(scene, obs_seg, obs_flow, cfg, sim, scorer=pf)
"""

from __future__ import annotations

import multiprocessing
import uuid
from concurrent.futures import ProcessPoolExecutor
from typing import Sequence

import numpy as np

from pipeline.mjcf import SimOptions
from pipeline.parallel import init_worker, make_pool
from pipeline.scene import Scene
from pipeline.search.config import SearchConfig
from pipeline.search.evaluator import EvaluatorPool
from pipeline.search.fitness import check_observation, fitness

_POOLS: dict = {}
"""Worker-side evaluator pools, by (width, height, options)."""


def _evaluate_chunk(job: tuple) -> list[tuple[np.ndarray, np.ndarray | None]]:
    """Worker: evaluate a chunk of scenes with this process's cached evaluators."""
    width, height, options, scenes, n_frames, flow = job
    key = (width, height, None if options is None else options.model_dump_json())
    pool = _POOLS.get(key)
    if pool is None:
        pool = _POOLS[key] = EvaluatorPool(width, height, options)
    return [pool.evaluate(s, n_frames, flow) for s in scenes]


class _PoolOwner:
    """What both parallel front ends share: an in-process evaluator pool (``workers == 1``) or a
    process pool, closed together; a context manager."""

    _local = None
    _pool = None

    @staticmethod
    def _chunk_bounds(n_items: int, workers: int) -> list[tuple[int, int]]:
        """``min(workers, n_items)`` contiguous ``(start, stop)`` slices covering the items."""
        n = min(workers, n_items)
        bounds = np.linspace(0, n_items, n + 1).round().astype(int)
        return list(zip(bounds[:-1].tolist(), bounds[1:].tolist()))

    def close(self) -> None:
        if self._local is not None:
            self._local.close()
            self._local = None
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class ParallelEvaluator(_PoolOwner):
    """Evaluate lists of candidates over ``workers`` processes.

    Args:
        width, height: render size, px.
        options: simulation options (params ``sim``).
        workers: processes (1 evaluates in this process, no pool).

    Use as a context manager or call :meth:`close`.
    """

    def __init__(self, width: int, height: int, options: SimOptions | None = None, workers: int = 2):
        self.width, self.height, self.options = int(width), int(height), options
        self.workers = max(1, int(workers))
        self._pool = self._local = None
        if self.workers == 1:
            self._local = EvaluatorPool(self.width, self.height, options)
        else:
            self._pool = make_pool(self.workers)

    def evaluate_many(self, scenes: Sequence[Scene], n_frames: int | None = None, flow: bool = True,
                      ) -> list[tuple[np.ndarray, np.ndarray | None]]:
        """``[(seg, flow), ...]`` of :meth:`SceneEvaluator.evaluate` for each scene, in order.

        Raises:
            SceneError, ValueError: a scene does not compile (see :class:`SceneEvaluator`).
        """
        scenes = list(scenes)
        if self._local is not None:
            return [self._local.evaluate(s, n_frames, flow) for s in scenes]
        if not scenes:
            return []
        jobs = [(self.width, self.height, self.options, scenes[a:b], n_frames, flow)
                for a, b in self._chunk_bounds(len(scenes), self.workers)]
        parts = list(self._pool.map(_evaluate_chunk, jobs))
        return [r for part in parts for r in part]



# ------------------------------------------------------------------------ parallel fitness
_FITNESS: dict = {}
"""Worker-side state of :class:`ParallelFitness`: ``token``, ``obs_seg``, ``obs_flow``,
``pool`` (the worker's evaluators)."""


def _init_fitness_worker(token: str, width: int, height: int, options: SimOptions | None,
                         obs_seg: np.ndarray, obs_flow: np.ndarray | None) -> None:
    """Worker set-up (pool initializer): :func:`pipeline.parallel.init_worker`'s thread limits,
    then keep the observation and an evaluator pool for every later job."""
    init_worker()
    _FITNESS.clear()
    _FITNESS.update(token=token, obs_seg=obs_seg, obs_flow=obs_flow,
                    pool=EvaluatorPool(width, height, options))


def _score_scenes(scenes: Sequence[Scene], priors: Sequence[float], cfg: SearchConfig, pool,
                  obs_seg: np.ndarray, obs_flow: np.ndarray | None) -> list[dict[str, float]]:
    """:func:`fitness` of each scene (evaluated with ``pool``) against the observation."""
    T = int(np.shape(obs_seg)[0])
    need_flow = obs_flow is not None and cfg.lambda_epe > 0
    out = []
    for scene, prior in zip(scenes, priors):
        seg, flow = pool.evaluate(scene, T, need_flow)
        out.append(fitness(seg, flow, obs_seg, obs_flow, cfg, prior=prior))
    return out


def _score_chunk(job: tuple) -> list[dict[str, float]]:
    """Worker: score a chunk of scenes against the observation this worker was started with."""
    token, scenes, priors, cfg = job
    if _FITNESS.get("token") != token:
        raise RuntimeError("ParallelFitness worker holds another observation")
    return _score_scenes(scenes, priors, cfg, _FITNESS["pool"], _FITNESS["obs_seg"], _FITNESS["obs_flow"])


class ParallelFitness(_PoolOwner):
    """Score lists of candidate scenes against one observation over ``workers`` processes.

    Each worker gets the observation once, when it starts, and keeps its own compiled models
    and renderers; a call sends the scenes (and the config) and gets back one small fitness
    dict per scene (:func:`pipeline.search.fitness.fitness`), never the clips. The scores equal
    scoring in this process float for float (``tests/test_search.py``). The flow is rendered
    only when it is scored (``obs_flow`` given and ``cfg.lambda_epe > 0``).

    Args:
        obs_seg: ``(T, H, W)`` observed labels (int8, -1 background) or bool foreground; fixes
            T and the render size.
        obs_flow: ``(T-1, H, W, 2)`` observed flow, px, or None.
        cfg: default fitness weights (a call may pass its own, e.g. a stage's).
        options: simulation options (params ``sim``).
        workers: processes (1 scores in this process, no pool).

    Use as a context manager or call :meth:`close`. The object is itself a ``scorer`` for
    :func:`pipeline.search.cmaes.cmaes_refine`: ``pf(scenes, cfg, priors)``.
    """

    def __init__(self, obs_seg: np.ndarray, obs_flow: np.ndarray | None, cfg: SearchConfig | None = None,
                 options: SimOptions | None = None, workers: int = 2):
        T, H, W = check_observation(obs_seg, obs_flow)
        self.n_frames, self.height, self.width = T, H, W
        self.obs_seg, self.obs_flow = np.asarray(obs_seg), (None if obs_flow is None else np.asarray(obs_flow))
        self.cfg, self.options = cfg or SearchConfig(), options
        self.workers = max(1, int(workers))
        self._token = uuid.uuid4().hex
        self._pool = self._local = None
        if self.workers == 1:
            self._local = EvaluatorPool(W, H, options)
        else:
            self._pool = ProcessPoolExecutor(
                max_workers=self.workers, mp_context=multiprocessing.get_context("spawn"),
                initializer=_init_fitness_worker,
                initargs=(self._token, W, H, options, self.obs_seg, self.obs_flow))

    def score(self, scenes: Sequence[Scene], cfg: SearchConfig | None = None,
              priors: Sequence[float] | None = None) -> list[dict[str, float]]:
        """``fitness(...)`` of each scene, in order: dicts ``fitness``, ``initial_iou``,
        ``full_iou``, ``strict_iou``, ``epe``, ``prior``.

        Args:
            scenes: candidates (any structures; each worker compiles a structure once).
            cfg: fitness weights (default: the constructor's).
            priors: the ``prior`` value of each scene (default 0).
        Raises:
            SceneError, ValueError: a scene does not compile (see :class:`SceneEvaluator`).
        """
        scenes = list(scenes)
        cfg = cfg or self.cfg
        priors = [0.0] * len(scenes) if priors is None else [float(p) for p in priors]
        if len(priors) != len(scenes):
            raise ValueError(f"{len(priors)} priors for {len(scenes)} scenes")
        if self._local is not None:
            return _score_scenes(scenes, priors, cfg, self._local, self.obs_seg, self.obs_flow)
        if self._pool is None:
            raise RuntimeError("ParallelFitness used after close")
        if not scenes:
            return []
        jobs = [(self._token, scenes[a:b], priors[a:b], cfg)
                for a, b in self._chunk_bounds(len(scenes), self.workers)]
        return [r for part in self._pool.map(_score_chunk, jobs) for r in part]

    __call__ = score

