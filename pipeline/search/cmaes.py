"""CMA-ES refinement of a scene on the fitness, object types fixed (paper)."""

from __future__ import annotations

import math
import time
from typing import Any, Callable, Sequence

import numpy as np

from pipeline.mjcf import SimOptions
from pipeline.scene import Scene
from pipeline.search.config import SearchConfig
from pipeline.search.evaluator import EvaluatorPool, SceneEvaluator
from pipeline.search.fitness import check_observation, fitness
from pipeline.search.space import SearchSpace


def cmaes_refine(scene: Scene, obs_seg: np.ndarray, obs_flow: np.ndarray | None, cfg: SearchConfig,
                 options: SimOptions | None = None, seed: int = 0,
                 callback: Callable[[dict], None] | None = None,
                 pool: EvaluatorPool | None = None,
                 scorer: Callable[[Sequence[Scene], SearchConfig, Sequence[float]], list[dict[str, float]]] | None = None,
                 ) -> tuple[Scene, list[dict[str, Any]]]:
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
        scorer: scores the start and each generation instead of this process's evaluator:
            ``scorer(scenes, cfg, priors) -> [fitness dict, ...]`` in order, as
            :func:`fitness` of each scene's clip against this observation with ``prior``
            (e.g. a :class:`pipeline.search.parallel_eval.ParallelFitness` opened on ``obs_seg``,
            ``obs_flow``: the generation over worker processes). With a scorer that equals
            :func:`fitness` the result is the same as without (``pool`` is then unused).
    Returns:
        ``(best_scene, history)``; history has one dict per iteration (0 = the start):
        ``iteration``, ``best_fitness`` (best so far), ``mean_fitness`` (of the iteration's
        finite scores), ``best_full_iou``, ``best_strict_iou``, ``best_epe`` (of the best so
        far), ``evaluations`` (cumulative), ``seconds`` (cumulative wall time).
    """
    import cma

    T, H, W = check_observation(obs_seg, obs_flow)
    space = SearchSpace(scene, cfg.free, cfg.ranges)
    need_flow = obs_flow is not None and cfg.lambda_epe > 0
    t0 = time.perf_counter()
    history: list[dict[str, Any]] = []
    own = scorer is None and pool is None
    ev = None if scorer is not None else SceneEvaluator(scene, W, H, options) if pool is None else pool.get(scene)
    try:
        def score_all(xs: list[np.ndarray]) -> list[dict[str, float]]:
            xs = [np.asarray(x)[: space.dim] for x in xs]   # a padding coordinate (1-D search) is unused
            cands = [space.decode(x) if space.dim else scene for x in xs]
            priors = [space.prior(x) for x in xs]
            if scorer is not None:
                return list(scorer(cands, cfg, priors))
            out = []
            for cand, prior in zip(cands, priors):
                seg, flow = ev.evaluate(cand, T, flow=need_flow)
                out.append(fitness(seg, flow, obs_seg, obs_flow, cfg, prior=prior))
            return out

        best_x = space.x0.copy()
        best = score_all([best_x])[0]
        evaluations = 1

        def log(it: int, mean: float) -> None:
            entry = {"iteration": it, "best_fitness": best["fitness"], "mean_fitness": mean,
                     "best_full_iou": best["full_iou"],
                     "best_strict_iou": best.get("strict_iou", float("nan")), "best_epe": best["epe"],
                     "evaluations": evaluations, "seconds": round(time.perf_counter() - t0, 3)}
            history.append(entry)
            if callback is not None:
                callback(entry)

        log(0, best["fitness"])
        if space.dim and cfg.iterations > 0:
            opts = {"popsize": cfg.popsize, "bounds": [0.0, 1.0], "seed": int(seed) % (2**31 - 2) + 1,
                    "verbose": -9, "maxiter": cfg.iterations, "tolfun": 0.0, "tolfunhist": 0.0,
                    "tolflatfitness": cfg.iterations + 1, "tolx": 0.0}
            # cma needs 2 dimensions at least: a single free parameter (a restitution alone) gets a
            # second, unused one
            x0 = space.x0.tolist() + ([0.5] if space.dim == 1 else [])
            es = cma.CMAEvolutionStrategy(x0, cfg.sigma, opts)
            for it in range(1, cfg.iterations + 1):
                xs = es.ask()
                results = score_all([np.asarray(x) for x in xs])
                evaluations += len(xs)
                losses = [-r["fitness"] if math.isfinite(r["fitness"]) else 1e6 for r in results]
                es.tell(xs, losses)
                i = int(np.argmin(losses))
                if results[i]["fitness"] > best["fitness"]:
                    best, best_x = results[i], np.array(xs[i], dtype=np.float64)  # a copy: cma repairs its solutions in place in tell()
                finite = [r["fitness"] for r in results if math.isfinite(r["fitness"])]
                log(it, float(np.mean(finite)) if finite else -math.inf)
    finally:
        if own:
            ev.close()
    return (space.decode(best_x[: space.dim]) if space.dim else scene), history
