"""Where the embarrassingly parallel work runs: a local process pool or a Ray cluster.

The data stages (sample_configs, compile_mjcf, render, flow, events), the search stages
(best_of_k, cmaes) and the hidden-effect benchmark split their work into chunks of scenes
(:func:`chunks`) and map a top-level function over them with :func:`parallel_map`, which
yields the results in chunk order. Params ``compute`` (:class:`ComputeConfig`) pick the
backend:

* ``local`` (default): a ``spawn`` process pool of ``workers`` processes on this machine
  (``null``: every available core); 1 worker runs in this process.
* ``ray``: every chunk is a Ray task (``max_retries`` :data:`RAY_MAX_RETRIES`: a chunk whose
  worker process dies is run again); ``address`` null starts or joins a local Ray instance,
  ``auto`` or ``ray://host:port`` joins a cluster; ``workers`` caps the tasks in flight (null:
  as many as the cluster takes). A task runs in the driver's working directory (stage paths
  are relative to the workspace: on a cluster, a shared file system at the same path on every
  node). Ray is imported here only, never by a stage.

Each scene's randomness comes from ``(seed, scene index)`` (or the scene id) and no state
carries from one scene to the next, so the outputs do not depend on the backend or the number
of workers (``tests/test_render.py``, ``tests/test_parallel.py``: sha256-identical shards).
A chunk function that writes a shard itself writes it temp-then-rename, so a retried chunk
leaves exactly one complete shard.

Workers are started with the ``spawn`` method: a forked child would inherit the parent's
EGL/OpenGL state, which is not fork-safe. Each worker keeps its own GL context and
``MjrContext`` objects (``pipeline.render.shared_gl``) for all the chunks it renders.

``compute`` is not a dependency of any stage in dvc.yaml because it changes no output.

Example::

    compute = compute_from_params(p)          # ComputeConfig(backend='local', workers=2, ...)
    for rows in parallel_map(render_chunk, chunks(table, 10), compute):
        ...
"""

from __future__ import annotations

import multiprocessing
import os
from collections import deque
from concurrent.futures import Executor, ProcessPoolExecutor
from typing import Any, Callable, Iterable, Iterator, Literal, Sequence, TypeVar

import cv2
from pydantic import BaseModel, ConfigDict, Field, field_validator
from tqdm import tqdm

from pipeline.params import typed_section

T = TypeVar("T")
R = TypeVar("R")

BACKENDS = ("local", "ray")
RAY_MAX_RETRIES = 3
"""Times Ray runs a chunk again after its worker process died (system failures only: an
exception raised by the chunk function is not retried, it fails the map)."""

WORKER_ENV = {"OMP_NUM_THREADS": "1", "LP_NUM_THREADS": "0"}
"""Environment of every worker, set before it imports a library (see :func:`init_worker`)."""


class ComputeConfig(BaseModel):
    """Params ``compute``: where :func:`parallel_map` runs the chunks.

    Attributes:
        backend: ``local`` (process pool on this machine) or ``ray`` (Ray tasks).
        address: Ray only: null starts or joins a local Ray instance; ``auto`` joins the
            cluster this machine belongs to; ``ray://host:port`` (Ray client) or ``host:port``
            joins a given cluster. Ignored by ``local``.
        workers: ``local``: processes (default 2, the default profile's; null: every available
            core); ``ray``: tasks in flight
            at once (null: as many as the cluster schedules) and the CPUs of a local Ray
            instance this process starts (null: every available core).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    backend: Literal["local", "ray"] = "local"
    address: str | None = None
    workers: int | None = Field(default=2, ge=1, strict=True)

    @field_validator("workers", mode="before")
    @classmethod
    def _check_workers(cls, value: Any) -> Any:
        if value is None or (type(value) is int and value >= 1):
            return value
        raise ValueError("must be a positive integer or null")

    @field_validator("address")
    @classmethod
    def _check_address(cls, value: str | None) -> str | None:
        if value is None or value == "auto":
            return value
        host, sep, port = value.removeprefix("ray://").rpartition(":")
        if not (sep and host and port.isdigit()):
            raise ValueError(f"must be null, auto, ray://host:port or host:port, got {value!r}")
        return value

    @property
    def n_workers(self) -> int:
        """Worker processes of the local backend (``workers``, or every available core)."""
        return self.workers or available_cores()


def compute_from_params(params: dict[str, Any], source: str | None = None) -> ComputeConfig:
    """The :class:`ComputeConfig` of params section ``compute`` (defaults when it is missing).

    Raises:
        ParamsError: one line naming the bad key, e.g. ``params.yaml: compute.backend: must be
            one of local, ray, got 'x'``.
    """
    return typed_section(params, "compute", ComputeConfig, source, unknown="unknown key (known: {known})")


def available_cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def chunks(items: Sequence[T], size: int) -> list[Sequence[T]]:
    """Consecutive slices of ``items`` of at most ``size`` elements (the last may be shorter).

    Raises:
        ValueError: ``size`` is not positive.
    """
    if size <= 0:
        raise ValueError(f"chunk size must be > 0, got {size}")
    return [items[i:i + size] for i in range(0, len(items), size)]


def map_shards(fn: Callable[[Any], list[R]], groups: Iterable[Sequence[T]], task: Callable[[int, Sequence[T]], Any],
               size: int, compute: ComputeConfig | int | None = None,
               desc: str | None = None) -> Iterator[tuple[int, list[R]]]:
    """Map ``fn`` over chunks of every input shard's items; yield each shard's rows once complete.

    The shape of the sharded stages (compile_mjcf, best_of_k, cmaes): the items of input shard
    ``i`` (``groups[i]``) are cut into :func:`chunks` of ``size`` (an empty shard is one empty
    chunk, so its output shard is still written), each chunk becomes ``task(i, chunk)``,
    :func:`parallel_map` runs ``fn`` on the tasks (a tqdm bar ``desc`` counts chunks), and the
    rows of all chunks of a shard are concatenated in order.

    Args:
        fn: top-level function (picklable) of one task, returning a list of rows.
        groups: per input shard, its items (read lazily, in order, before any task runs).
        task: ``(shard index, chunk of items) -> task`` given to ``fn``.
        size: items per chunk.
        compute: backend (see :func:`parallel_map`).
        desc: progress-bar label (the stage name).

    Yields:
        ``(shard index, rows)`` in shard order.
    """
    tasks, owner = [], []  # chunks of items and the shard each belongs to
    for i, items in enumerate(groups):
        for part in chunks(items, size) or [[]]:
            tasks.append(task(i, part))
            owner.append(i)
    rows: list[R] = []
    results = parallel_map(fn, tasks, compute)
    for k, part in enumerate(tqdm(results, total=len(tasks), desc=desc, unit="chunk")):
        rows += part
        if k + 1 == len(tasks) or owner[k + 1] != owner[k]:  # the shard is complete
            yield owner[k], rows
            rows = []


def init_worker() -> None:
    """Worker set-up: one thread per library (the pool already fills the cores).

    ``LP_NUM_THREADS=0``: Mesa llvmpipe rasterizes in the calling thread instead of handing
    every draw to its own threads; with more busy processes than cores those hand-offs wait
    for the scheduler and rendering slowed ~2x. Pixels do not depend on it.
    """
    for key, value in WORKER_ENV.items():
        os.environ.setdefault(key, value)  # LP_NUM_THREADS is read when the worker's EGL display starts
    try:
        cv2.setNumThreads(1)  # DIS flow is bit-identical for any thread count
    except ImportError:
        pass


def make_pool(workers: int) -> ProcessPoolExecutor:
    """A ``spawn`` process pool of ``workers`` workers, set up as :func:`parallel_map`'s (for
    callers that run several maps on one pool)."""
    return ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=init_worker)


def parallel_map(fn: Callable[[T], R], items: Iterable[T], compute: ComputeConfig | int | None = None,
                 pool: Executor | None = None) -> Iterator[R]:
    """``map(fn, items)`` on the configured backend, results yielded in input order.

    Args:
        fn: a module-level function of one argument (a chunk of scenes); its argument and
            result must be picklable. It must not depend on which worker runs it, and a chunk
            that writes files must write them temp-then-rename (Ray may run it again).
        items: the chunks of work.
        compute: a :class:`ComputeConfig`, or an int: that many local processes (default:
            ``ComputeConfig()``, 2 local processes). Local with 1 worker (or a single item)
            runs everything in this process, no pool.
        pool: an open local pool to use instead (``compute`` is then ignored).
    Yields:
        ``fn(item)`` for each item, in order.
    Raises:
        whatever ``fn`` raises (the first failing chunk in order); with Ray, a chunk whose
        worker died more than :data:`RAY_MAX_RETRIES` times raises ``ray.exceptions.WorkerCrashedError``.
    """
    items = list(items)
    if pool is not None:
        yield from pool.map(fn, items)
        return
    if compute is None or isinstance(compute, int):
        compute = ComputeConfig(workers=compute)
    if compute.backend == "ray":
        yield from _ray_map(fn, items, compute)
        return
    workers = compute.n_workers
    if workers <= 1 or len(items) <= 1:
        for item in items:
            yield fn(item)
        return
    with make_pool(min(workers, len(items))) as local_pool:
        yield from local_pool.map(fn, items)


# ------------------------------------------------------------------------------------- Ray
_RAY_ADDRESS: list = []
"""The ``address`` this process's Ray connection was opened with (empty: not opened here)."""


def _ray_task(fn: Callable[[T], R], item: T, cwd: str) -> R:
    """A Ray task: worker set-up as in the local pool, the driver's working directory ``cwd``
    (stage paths are relative to the workspace; on a cluster it must be on a file system every
    node mounts at the same path), then ``fn(item)``."""
    init_worker()
    os.chdir(cwd)
    return fn(item)


def ray_connect(compute: ComputeConfig):
    """Connect this process to Ray as ``compute`` says (once; a different address reconnects).

    ``address`` null: join the local instance ``ray start`` left (``RAY_ADDRESS`` or the latest
    one on this machine), else start one with ``workers`` CPUs (null: every core) and no
    dashboard. Workers get :data:`WORKER_ENV` and this process's ``MUJOCO_GL``.

    Returns:
        the ``ray`` module, initialised.
    Raises:
        ConnectionError: ``address`` names a cluster that cannot be reached.
    """
    import ray

    if ray.is_initialized():
        if _RAY_ADDRESS and _RAY_ADDRESS[0] == compute.address:
            return ray
        ray.shutdown()
    env = {**WORKER_ENV, **{k: os.environ[k] for k in ("MUJOCO_GL", "PYOPENGL_PLATFORM") if k in os.environ}}
    kwargs = {"include_dashboard": False, "runtime_env": {"env_vars": env}, "logging_level": "WARNING"}
    if compute.address is None:
        try:
            ray.init(address=None, num_cpus=compute.n_workers, **kwargs)
        except ValueError:  # a local instance exists (num_cpus is refused when joining one): join it
            ray.init(address=None, **kwargs)
    else:
        ray.init(address=compute.address, **kwargs)
    _RAY_ADDRESS[:] = [compute.address]
    return ray


def ray_shutdown() -> None:
    """Disconnect from Ray (and stop the local instance this process started, if any)."""
    if _RAY_ADDRESS:
        import ray

        ray.shutdown()
        _RAY_ADDRESS.clear()


def _ray_map(fn: Callable[[T], R], items: list[T], compute: ComputeConfig) -> Iterator[R]:
    """:func:`parallel_map` on Ray: one task (1 CPU, :data:`RAY_MAX_RETRIES` retries) per item,
    at most ``compute.workers`` in flight, results in input order."""
    if not items:
        return
    ray = ray_connect(compute)
    name = getattr(fn, "__name__", "chunk")
    task = ray.remote(num_cpus=1, max_retries=RAY_MAX_RETRIES)(_ray_task).options(name=name)
    fn_ref, cwd = ray.put(fn), os.getcwd()  # the function is shipped once, not with every chunk
    limit = compute.workers or len(items)
    todo = iter(items)
    pending = deque(task.remote(fn_ref, item, cwd) for _, item in zip(range(limit), todo))
    while pending:
        result = ray.get(pending.popleft())
        for item in todo:  # keep `limit` in flight
            pending.append(task.remote(fn_ref, item, cwd))
            break
        yield result
