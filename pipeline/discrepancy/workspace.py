"""The workspace of a workflow run: clips, noise weights, compiled models (cached) and the
worker pool that fits clips one by one in parallel; held-out scores."""

from __future__ import annotations

import copy
import hashlib
import json
import math
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from pipeline import effects as fx
from pipeline.discrepancy.clip_model import NUISANCE_FRICTION, ClipModel, Weights, clip_residuals_many
from pipeline.discrepancy.config import DiscrepancyConfig, fit_options
from pipeline.discrepancy.fit import Fit, fit_clips, free_mask, single_threaded_blas
from pipeline.discrepancy.noise import estimate_noise
from pipeline.discrepancy.trajectories import Clip, truncate_clip
from pipeline.mjcf import SimOptions


@dataclass
class HeldOut:
    """Cross-validated scores of a model: per clip, chi-square / squared position residual /
    counts when the effects' coefficients come from the other clips (leave one clip out)."""

    chi2: list[float]
    sq_pos: list[float]
    n_res: list[int]
    n_pos: list[int]
    theta: list[dict[str, dict[str, float]]] = field(default_factory=list)

    @property
    def total_chi2(self) -> float:
        """Held-out chi-square summed over clips."""
        return float(sum(self.chi2))

    @property
    def rmse(self) -> float:
        """m, held-out position RMSE over all clips."""
        return math.sqrt(sum(self.sq_pos) / max(sum(self.n_pos), 1))

    def clip_rmse(self, c: int) -> float:
        """m, held-out position RMSE of clip ``c``."""
        return math.sqrt(self.sq_pos[c] / max(self.n_pos[c], 1))


FRICTION_GRID = (0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.8, 1.0, 1.4)
"""Sliding-friction values tried before a base fit's least squares (the residual is not
convex in friction: a wrong start can leave it in a basin where the spin compensates)."""


def _scan_friction(clip: Clip, model: ClipModel, weights: Weights, nuis: np.ndarray,
                   effects: Mapping[str, Mapping[str, float]], cfg: DiscrepancyConfig) -> np.ndarray:
    """Start values with each object's friction set, in turn, to the best of
    :data:`FRICTION_GRID` and the current value (others held); unchanged where friction is
    not fitted."""
    mask = free_mask(clip, tuple(effects), cfg)
    nuis = nuis.copy()
    for i in range(len(clip.tracks)):
        if not mask[i, NUISANCE_FRICTION]:
            continue
        grid = (nuis[i, NUISANCE_FRICTION],) + FRICTION_GRID
        variants = []
        for mu in grid:
            x = nuis.copy()
            x[i, NUISANCE_FRICTION] = mu
            variants.append(x)
        qs = model.simulate_many(variants, [effects] * len(grid))
        chi = [float(r @ r) for r in clip_residuals_many(clip, qs, weights)[0]]
        nuis[i, NUISANCE_FRICTION] = grid[int(np.argmin(chi))]
    return nuis


class Workspace:
    """Clips, noise weights and compiled models (one per clip and effect set, cached)."""

    def __init__(self, clips: Sequence[Clip], cfg: DiscrepancyConfig, options: SimOptions, gravity: float = 9.81):
        self.clips = list(clips)
        self.cfg = cfg
        self.options = fit_options(options, cfg)   # the base contact of the fits
        self.gravity = gravity
        self.noise = [estimate_noise(c) for c in self.clips]
        self.weights = [Weights(n.position, n.angle) for n in self.noise]
        self._models: dict[tuple[int, tuple[str, ...]], ClipModel] = {}
        self._horizon_models: dict[tuple[int, float, tuple[str, ...]], tuple[Clip, ClipModel] | None] = {}
        self._fits: dict[bytes, Fit] = {}   # per-clip fits of fit_each, by their arguments
        self._stages: dict[bytes, np.ndarray] = {}   # their early horizons' results (resume points)
        self._pool = None
        self._cost: dict[int, int] = {}   # rollouts of each clip's latest per-clip fit (pool scheduling)
        self.workers = 1
        """Processes fitting clips (:meth:`start_pool`; 1 without a pool)."""

    def model(self, c: int, effects: Iterable[str]) -> ClipModel:
        """The :class:`ClipModel` of clip ``c`` with ``effects`` (compiled on first use, cached
        per clip and effect set)."""
        key = (c, tuple(e for e in fx.REGISTRY if e in set(effects)))
        if key not in self._models:
            self._models[key] = ClipModel(self.clips[c], key[1], self.options, self.gravity, self.cfg.threads)
        return self._models[key]

    def horizon(self, c: int, frac: float, effects: Iterable[str]) -> tuple[Clip, ClipModel] | None:
        """Clip ``c`` cut to the first ``frac`` of its duration and its :class:`ClipModel`
        (compiled on first use, cached per clip, fraction and effect set); ``frac >= 1``: the
        whole clip and :meth:`model`; ``None`` where the cut keeps too few samples."""
        if frac >= 1.0:
            return self.clips[c], self.model(c, effects)
        names = tuple(e for e in fx.REGISTRY if e in set(effects))
        key = (c, float(frac), names)
        if key not in self._horizon_models:
            sub = truncate_clip(self.clips[c], frac * float(self.clips[c].times[-1]))
            self._horizon_models[key] = None if sub is None else \
                (sub, ClipModel(sub, names, self.options, self.gravity, self.cfg.threads))
        return self._horizon_models[key]

    def fit(self, idx: Sequence[int], starts: Sequence[np.ndarray], effects: Mapping[str, Mapping[str, float]],
            fit_effects: bool = True, with_ci: bool = False, max_nfev: int | None = None,
            converge: bool = False, fixed: Sequence[tuple[str, str]] = ()) -> Fit:
        """:func:`fit_clips` on the clips ``idx``."""
        return fit_clips([self.clips[c] for c in idx], [self.model(c, effects) for c in idx],
                         [self.weights[c] for c in idx], starts, effects, self.cfg, fit_effects, with_ci, max_nfev,
                         converge, fixed)

    def fit_each(self, idx: Sequence[int], starts: Sequence[np.ndarray],
                 effects: Mapping[str, Mapping[str, float]], max_nfev: int | None = None,
                 converge: bool = False) -> Fit:
        """Fit every clip on its own with the effects' values held (no shared parameters),
        merged into one :class:`Fit` (k counts every clip's parameters).

        Each clip is fitted by continuation over the time horizon (:meth:`fit_clip`). The
        clips are independent, so with a worker pool (:meth:`start_pool`) they are fitted in
        parallel; the result is the same to the last bit (each clip's fit runs the same
        arithmetic in whichever process). A clip's fit is deterministic in its arguments, so
        it is kept and reused when the same fit is asked for again (e.g. the current model
        from the data after naming, then as the next step's baseline)."""
        return self.fit_many([(idx, starts, effects)], max_nfev, converge)[0]

    def fit_many(self, requests: Sequence[tuple[Sequence[int], Sequence[np.ndarray], Mapping[str, Mapping[str, float]]]],
                 max_nfev: int | None = None, converge: bool = False) -> list[Fit]:
        """:meth:`fit_each` of several ``(idx, starts, effects)`` requests, their per-clip fits
        in one pool map (8 clips of uneven cost on 2 workers leave one idle at the end of
        each map; more jobs per map keep both busy). Same result to the last bit as one
        :meth:`fit_each` per request."""
        jobs = [[(c, start, {e: dict(p) for e, p in effects.items()}, max_nfev, converge)
                 for c, start in zip(idx, starts)] for idx, starts, effects in requests]
        keys = [[_job_key(job) for job in group] for group in jobs]
        todo: dict[bytes, tuple] = {}
        for group, group_keys in zip(jobs, keys):
            todo.update((key, job) for key, job in zip(group_keys, group) if key not in self._fits)
        # a fit whose early horizons were run before (same clip, start, effects and cap; e.g. the
        # base model converged, then at the screening budget) resumes after them
        todo_jobs = [job + (self._resume_point(*job[:4]),) for job in todo.values()]
        if self._pool is not None and len(todo) > 1:
            done = self._map(_pool_fit_clip, todo_jobs, [self._cost.get(job[0], 0) for job in todo_jobs])
        else:
            done = [self.fit_clip(*job) for job in todo_jobs]
        for job, fit in zip(todo_jobs, done):
            self._cost[job[0]] = fit.nfev
            for k, nuis in fit.stages.items():
                self._stages[_stage_key(job[0], job[1], job[2], job[3], k)] = nuis
            fit.stages = {}
        self._fits.update(zip(todo, done))
        out = []
        for (_, _, effects), group_keys in zip(requests, keys):
            parts = [copy.deepcopy(self._fits[key]) for key in group_keys]
            out.append(Fit({e: dict(p) for e, p in effects.items()}, [p.nuisance[0] for p in parts],
                           [p.chi2[0] for p in parts], [p.sq_pos[0] for p in parts], [p.n_res[0] for p in parts],
                           [p.n_pos[0] for p in parts], k=sum(p.k for p in parts), nfev=sum(p.nfev for p in parts),
                           status=min((p.status for p in parts), default=-2),
                           iterations=sum(p.iterations for p in parts),
                           converged=bool(parts) and all(p.converged or p.status == -2 for p in parts)))
        return out

    def _resume_point(self, c: int, start: np.ndarray, effects: Mapping[str, Mapping[str, float]],
                      max_nfev: int | None) -> tuple[int, np.ndarray] | None:
        """``(k, nuisance)``: the latest early horizon ``k`` (index into ``cfg.horizons``, not the
        last) already fitted for these arguments and its fitted parameters, else ``None``."""
        for k in range(len(self.cfg.horizons) - 2, -1, -1):
            nuis = self._stages.get(_stage_key(c, start, effects, max_nfev, k))
            if nuis is not None:
                return k, nuis
        return None

    def fit_clip(self, c: int, start: np.ndarray, effects: Mapping[str, Mapping[str, float]],
                 max_nfev: int | None = None, converge: bool = False,
                 resume: tuple[int, np.ndarray] | None = None) -> Fit:
        """Fit clip ``c`` alone (effects held) by continuation over the time horizon
        (``cfg.horizons``: first the opening fraction of the clip, then longer, warm-starting
        each from the last), so that late contacts do not pull the initial state into a wrong
        basin. With ``converge`` the last horizon (the whole clip) runs to the tolerance
        ``cfg.ftol``.

        Args:
            c: clip index. start: ``(n, 14)`` starting values (:data:`NUISANCE`).
            effects: ``{effect: parameters}`` held. max_nfev: screening cap.
            resume: ``(k, nuisance)``: horizons ``0..k`` were fitted before with these
                arguments (the early horizons do not depend on ``converge``) and ended at
                ``nuisance``; continue from there (the same arithmetic as running them again,
                so the same result to the last bit).

        Returns:
            a one-clip :class:`Fit` (the last horizon's), with ``stages``: ``{k: nuisance}``
            after each early horizon it ran (:meth:`fit_many` keeps them as resume points)."""
        part, stages, first = None, {}, 0
        if resume is not None:
            first, start = resume[0] + 1, resume[1].copy()
        for k, frac in enumerate(self.cfg.horizons):
            if k < first:
                continue
            cut = self.horizon(c, frac, effects)
            if cut is None:
                continue
            sub, model = cut
            start = _scan_friction(sub, model, self.weights[c], start, effects, self.cfg)
            last = frac >= self.cfg.horizons[-1]
            part = fit_clips([sub], [model], [self.weights[c]], [start], effects, self.cfg,
                             fit_effects=False, max_nfev=None if (converge and last) else max_nfev,
                             converge=converge and last)
            start = part.nuisance[0]
            if not last:
                stages[k] = start.copy()
        assert part is not None  # the last horizon is the whole clip (cfg.horizons ends at 1)
        part.stages = stages
        return part

    def refit_each(self, idx: Sequence[int], starts: Sequence[np.ndarray],
                   effects: Mapping[str, Mapping[str, float]] | Sequence[Mapping[str, Mapping[str, float]]],
                   max_nfev: int | None = None, converge: bool = False) -> list[Fit]:
        """Warm-started fits of each clip alone from ``starts`` (effects held; one horizon,
        no friction scan): ``[ws.fit([c], [start], effects, fit_effects=False, ...)]`` for the
        clips ``idx``, in parallel when a pool is running (same result to the last bit).
        ``effects`` is one ``{effect: parameters}`` for every clip, or a list of them, one per
        clip of ``idx``."""
        per_clip = [effects] * len(idx) if isinstance(effects, Mapping) else list(effects)
        return self.fit_joint_many([dict(idx=[c], starts=[start], effects={e: dict(p) for e, p in eff.items()},
                                         fit_effects=False, max_nfev=max_nfev, converge=converge)
                                    for c, start, eff in zip(idx, starts, per_clip)])

    def fit_joint_many(self, requests: Sequence[Mapping[str, Any]]) -> list[Fit]:
        """Several independent :meth:`fit` calls (joint fits of clips with shared
        coefficients), each ``request`` the keyword arguments of :meth:`fit` (``idx``,
        ``starts``, ``effects`` and any of ``fit_effects``, ``with_ci``, ``max_nfev``,
        ``converge``, ``fixed``). With a worker pool they run in parallel, one per worker with
        one rollout thread each (a joint fit in this process rolls out on ``cfg.threads`` but
        runs its least-squares algebra, residuals and model edits on one core); the same
        result to the last bit (:func:`simulate_clips` is deterministic in its models and
        states whatever the thread count)."""
        jobs = [dict(req) for req in requests]
        if self._pool is not None and len(jobs) > 1:
            return self._map(_pool_fit_joint, jobs, [sum(self._cost.get(c, 0) for c in job["idx"]) for job in jobs])
        return [self.fit(**job) for job in jobs]

    def _map(self, fn, jobs: Sequence[Any], costs: Sequence[float]) -> list[Any]:
        """``[fn(job) for job in jobs]`` on the pool, the jobs handed out longest expected
        ``costs`` first (longest-processing-time-first scheduling, Graham 1969: the last job
        of a map, while the other workers idle, is a short one); results in the jobs' order
        (each job is deterministic, so the order changes no number)."""
        order = sorted(range(len(jobs)), key=lambda j: -costs[j])
        done = list(self._pool.map(fn, [jobs[j] for j in order]))
        out: list[Any] = [None] * len(jobs)
        for j, result in zip(order, done):
            out[j] = result
        return out

    def start_pool(self, workers: int) -> None:
        """Fit clips in ``workers`` processes (:meth:`fit_each`); each worker holds its own
        copy of this workspace with one rollout thread, made once. No-op for ``workers`` < 2,
        fewer than two clips, or inside a daemonic process (a multiprocessing pool's worker,
        which may not have children). Pair with :meth:`close`."""
        if workers < 2 or len(self.clips) < 2 or self._pool is not None:
            return
        if multiprocessing.current_process().daemon:   # a pool worker itself: no children allowed
            return

        cfg = self.cfg.model_copy(update={"threads": 1, "workers": 1})
        self.workers = min(workers, len(self.clips))
        self._pool = ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"),
                                         initializer=_pool_init,
                                         initargs=(self.clips, cfg, self.options, self.gravity))

    def close(self) -> None:
        """Shut the worker pool down (if any)."""
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
            self._pool = None
            self.workers = 1


def _digest(start: np.ndarray, *fields: Any) -> bytes:
    """SHA-256 of a per-clip fit's start values and its other (JSON-able) arguments."""
    h = hashlib.sha256(np.ascontiguousarray(start, dtype=float).tobytes())
    h.update(json.dumps(list(fields), sort_keys=True).encode())
    return h.digest()


def _stage_key(c: int, start: np.ndarray, effects: Mapping[str, Mapping[str, float]], max_nfev: int | None,
               k: int) -> bytes:
    """Digest of a per-clip fit's early horizon ``k`` (:meth:`Workspace.fit_clip`): its clip,
    start, effects and screening cap (not ``converge``, which only acts on the last horizon)."""
    return _digest(start, c, effects, max_nfev, k)


def _job_key(job: tuple) -> bytes:
    """Digest of a per-clip fit's arguments ``(clip, start, effects, max_nfev, converge)``."""
    c, start, effects, max_nfev, converge = job
    return _digest(start, c, effects, max_nfev, converge)


_POOL_WS: "Workspace | None" = None


def _pool_init(clips: Sequence[Clip], cfg: DiscrepancyConfig, options: SimOptions, gravity: float) -> None:
    """Worker start: its own :class:`Workspace` (models compiled on first use, then cached)."""
    global _POOL_WS
    _POOL_WS = Workspace(clips, cfg, options, gravity)


def _pool_fit_clip(job: tuple) -> Fit:
    with single_threaded_blas():
        return _POOL_WS.fit_clip(*job)


def _pool_fit_joint(job: Mapping[str, Any]) -> Fit:
    with single_threaded_blas():
        return _POOL_WS.fit(**job)
