"""Process pool for the data stages (sample_configs, compile_mjcf, render, flow, events).

Every stage splits its scenes into chunks (:func:`chunks`), maps a top-level function over
them with :func:`parallel_map`, and gets the results back in chunk order. Each scene's
randomness comes from ``(seed, scene index)`` and no state carries from one scene to the
next, so the outputs do not depend on the number of workers (``tests/test_render.py``
compares 1 and 2 workers).

Workers are started with the ``spawn`` method: a forked child would inherit the parent's
EGL/OpenGL state, which is not fork-safe. Each worker keeps its own GL context and
``MjrContext`` objects (``pipeline.render.shared_gl``) for all the chunks it renders.

The worker count comes from params ``compute.workers`` (:func:`workers_from_params`; default:
every core this process may use). It is not a dependency of any stage in dvc.yaml because it
changes no output.

Example::

    for rows in parallel_map(render_chunk, chunks(table, 10), workers=2):
        ...
"""

from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import Executor, ProcessPoolExecutor
from typing import Any, Callable, Iterable, Iterator, Sequence, TypeVar

T = TypeVar("T")
R = TypeVar("R")


def available_cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def workers_from_params(params: dict[str, Any]) -> int:
    """Worker processes for a data stage: params ``compute.workers`` (an int >= 1), or all
    available cores when the key is missing or null.

    Raises:
        ValueError: ``compute.workers`` is not a positive integer.
    """
    value = (params.get("compute") or {}).get("workers")
    if value is None:
        return available_cores()
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"params.yaml: compute.workers: must be a positive integer or null, got {value!r}")
    return value


def chunks(items: Sequence[T], size: int) -> list[Sequence[T]]:
    """Consecutive slices of ``items`` of at most ``size`` elements (the last may be shorter)."""
    if size <= 0:
        raise ValueError(f"chunk size must be > 0, got {size}")
    return [items[i:i + size] for i in range(0, len(items), size)]


def _init_worker() -> None:
    """Worker set-up: one thread per library (the pool already fills the cores).

    ``LP_NUM_THREADS=0``: Mesa llvmpipe rasterizes in the calling thread instead of handing
    every draw to its own threads; with more busy processes than cores those hand-offs wait
    for the scheduler and rendering slowed ~2x. Pixels do not depend on it.
    """
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    os.environ.setdefault("LP_NUM_THREADS", "0")  # read when the worker's EGL display starts
    try:
        import cv2

        cv2.setNumThreads(1)  # DIS flow is bit-identical for any thread count
    except ImportError:
        pass


def make_pool(workers: int) -> ProcessPoolExecutor:
    """A ``spawn`` process pool of ``workers`` workers, set up as :func:`parallel_map`'s (for
    callers that run several maps on one pool, e.g. ``benchmarks/gen_scenes.py``)."""
    return ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_init_worker)


def parallel_map(fn: Callable[[T], R], items: Iterable[T], workers: int,
                 pool: Executor | None = None) -> Iterator[R]:
    """``map(fn, items)`` over a process pool, results yielded in input order as they complete.

    Args:
        fn: a module-level function (pickled by name) of one argument; its argument and result
            must be picklable.
        items: the chunks of work.
        workers: processes; 1 (or a single item) runs everything in this process, no pool.
        pool: an open pool to use instead of starting one (``workers`` is then ignored).
    Yields:
        ``fn(item)`` for each item, in order.
    """
    items = list(items)
    if pool is not None:
        yield from pool.map(fn, items)
        return
    if workers <= 1 or len(items) <= 1:
        for item in items:
            yield fn(item)
        return
    with make_pool(min(workers, len(items))) as pool:
        yield from pool.map(fn, items)
