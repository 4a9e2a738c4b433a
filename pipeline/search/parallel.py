"""Evaluate many candidate scenes over a process pool (one :class:`EvaluatorPool` per worker).

A CMA-ES generation (``popsize`` candidates) or the K samples of Best@K are independent, so
they can be split over the cores: each worker process keeps its own compiled models and
renderers (:class:`pipeline.search.evaluator.EvaluatorPool`, cached across calls) and returns
the rendered clips. Results equal :meth:`SceneEvaluator.evaluate` in this process bit for bit
(every evaluation starts from the ``init`` keyframe of a freshly edited model; ``tests/
test_search.py``). Workers are ``spawn``-started with one thread per library
(:func:`pipeline.parallel.make_pool`).

Example::

    with ParallelEvaluator(W, H, sim, workers=2) as pe:
        clips = pe.evaluate_many(candidates, T, flow=False)   # [(seg, flow), ...] in order
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from pipeline.mjcf import SimOptions
from pipeline.scene import Scene

_POOLS: dict = {}
"""Worker-side evaluator pools, by (width, height, options)."""


def _evaluate_chunk(job: tuple) -> list[tuple[np.ndarray, np.ndarray | None]]:
    """Worker: evaluate a chunk of scenes with this process's cached evaluators."""
    from pipeline.search.evaluator import EvaluatorPool

    width, height, options, scenes, n_frames, flow = job
    key = (width, height, None if options is None else options.model_dump_json())
    pool = _POOLS.get(key)
    if pool is None:
        pool = _POOLS[key] = EvaluatorPool(width, height, options)
    return [pool.evaluate(s, n_frames, flow) for s in scenes]


class ParallelEvaluator:
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
            from pipeline.search.evaluator import EvaluatorPool

            self._local = EvaluatorPool(self.width, self.height, options)
        else:
            from pipeline.parallel import make_pool

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
        n = min(self.workers, len(scenes))
        bounds = np.linspace(0, len(scenes), n + 1).round().astype(int)
        jobs = [(self.width, self.height, self.options, scenes[a:b], n_frames, flow)
                for a, b in zip(bounds[:-1], bounds[1:])]
        parts = list(self._pool.map(_evaluate_chunk, jobs))
        return [r for part in parts for r in part]

    def close(self) -> None:
        if self._local is not None:
            self._local.close()
            self._local = None
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def __enter__(self) -> "ParallelEvaluator":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
