"""Fitness of a re-simulated clip against the observed one, and Best@K (paper)."""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from pipeline.metrics import as_labels, flow_epe, sequence_iou
from pipeline.mjcf import SimOptions
from pipeline.scene import Scene, SceneError
from pipeline.search.config import SearchConfig
from pipeline.search.evaluator import EvaluatorPool


def fitness(pred_seg: np.ndarray, pred_flow: np.ndarray | None, obs_seg: np.ndarray,
            obs_flow: np.ndarray | None, cfg: SearchConfig, prior: float = 0.0) -> dict[str, float]:
    """Fitness of a re-simulated clip: ``IoU − lambda_epe · EPE − prior_weight · prior``.

    Paper: fitness IoU − EPE. With ``cfg.fitness_iou == "strict"`` (default) the IoU is
    :func:`pipeline.metrics.sequence_iou`'s ``strict_iou``: per observed object, the IoU with its
    match over the frames where either is visible, so agreeing that an object is absent earns
    nothing (issue 29 item 7); with ``"all_frames"`` it is the docs/design.md §7 matched
    full-sequence IoU, where such a frame counts 1.0. ``obs_seg`` is a label map (int, -1
    background: rendered ground truth, or pseudo masks split into objects by
    ``pipeline.masks.label_objects``); with ``cfg.penalize_extra`` the IoU is averaged over
    ``max(n_true, n_pred)`` objects instead of the true ones (visible ones for ``strict``),
    so a predicted object that matches nothing costs as much as a missed one (the
    docs/design.md §7 metric ignores extra objects, which would let Best@K prefer candidates
    that add objects). For a bool foreground-only ``obs_seg`` it is the foreground IoU
    (object identities unknown; ``strict``: over the frames where either has foreground).
    With no observed object visible at all the IoU term is 0. EPE is in px at the rendered
    resolution over pixels where either clip is foreground (:func:`pipeline.metrics.flow_epe`),
    or where the observed clip is (``cfg.epe_pixels == "observed"``).
    The returned ``initial_iou`` / ``full_iou`` are the docs/design.md §7 metrics and
    ``strict_iou`` the strict one, all without the extra-object penalty.

    Args:
        pred_seg: ``(T, H, W)`` int8 re-simulated labels.
        pred_flow: ``(T-1, H, W, 2)`` float re-simulated flow, or None.
        obs_seg: ``(T, H, W)`` observed labels (int) or foreground (bool).
        obs_flow: ``(T-1, H, W, 2)`` observed flow, or None (then EPE is NaN and not used).
        cfg: weights ``lambda_epe`` and ``prior_weight``, ``fitness_iou``, ``penalize_extra``.
        prior: penalty value (e.g. mean squared normalised distance to the model's scene).
    Returns:
        dict: ``fitness``, ``initial_iou``, ``full_iou``, ``strict_iou`` (NaN with no visible
        observed object), ``epe`` (px, NaN if not computed; over ``cfg.epe_pixels``), ``prior``.
    """
    obs = np.asarray(obs_seg)
    strict = cfg.fitness_iou == "strict"
    if obs.dtype == bool:
        iou = sequence_iou(obs, np.asarray(pred_seg) >= 0)
        initial, full = iou["foreground_iou_initial"], iou["foreground_iou_full"]
        term = iou["strict_iou"] if strict else full
    else:
        iou = sequence_iou(obs, pred_seg)
        initial, full = iou["initial_iou"], iou["full_iou"]
        if strict:
            term, n_true, n_pred = iou["strict_iou"], iou["n_true_visible"], iou["n_pred_visible"]
        else:
            term, n_true, n_pred = full, iou["n_true"], iou["n_pred"]
        if cfg.penalize_extra and n_true:
            term = term * n_true / max(n_true, n_pred)
    if math.isnan(term):
        term = 0.0
    epe = math.nan
    if pred_flow is not None and obs_flow is not None:
        epe = flow_epe(pred_flow, obs_flow, np.asarray(pred_seg)[:-1] >= 0, as_labels(obs)[:-1] >= 0,
                       over=cfg.epe_pixels)
    f = term - cfg.prior_weight * prior
    if cfg.lambda_epe > 0 and not math.isnan(epe):
        f -= cfg.lambda_epe * epe
    return {"fitness": float(f), "initial_iou": float(initial), "full_iou": float(full),
            "strict_iou": float(iou["strict_iou"]), "epe": float(epe), "prior": float(prior)}


def _invalid_score(error: str) -> dict[str, Any]:
    return {"valid": False, "fitness": -math.inf, "initial_iou": math.nan, "full_iou": math.nan,
            "strict_iou": math.nan, "epe": math.nan, "prior": 0.0, "error": error}


def check_observation(obs_seg: np.ndarray, obs_flow: np.ndarray | None) -> tuple[int, int, int]:
    """``(T, H, W)`` of an observed clip: ``obs_seg (T, H, W)`` integer labels (-1 background),
    ``obs_flow (T-1, H, W, 2)`` float px or None.

    Raises:
        ValueError: a shape that does not fit (one line naming the array).
    """
    seg = np.asarray(obs_seg)
    if seg.ndim != 3:
        raise ValueError(f"obs_seg: must be (T, H, W), got shape {seg.shape}")
    T, H, W = seg.shape
    if obs_flow is not None and np.shape(obs_flow) != (T - 1, H, W, 2):
        raise ValueError(f"obs_flow: must be {(T - 1, H, W, 2)} to match obs_seg, got {np.shape(obs_flow)}")
    return T, H, W


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
        ``full_iou``, ``strict_iou``, ``epe``, ``prior``, ``error``) and the index of the highest fitness
        (first on ties), or None when no candidate is valid.
    """
    T, H, W = check_observation(obs_seg, obs_flow)
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
    return scores, best_index([s["fitness"] for s in scores])


def best_index(fitness: Sequence[float]) -> int | None:
    """Best@K's pick among scored samples: the index of the highest fitness, the first on ties;
    None when there is none or every one is ``-inf`` (no valid sample). Best@k of the first ``k``
    of K samples (drawn independently) is ``best_index(fitness[:k])``."""
    fit = [float(f) for f in fitness]
    return int(np.argmax(fit)) if fit and max(fit) > -math.inf else None


SHAPE_DOF = {"sphere": 1, "cylinder": 4, "box": 6}
"""Shape parameters of an object that its silhouette must explain: sizes, plus the orientation
that matters up to the shape's symmetry (a cylinder's axis: 2; a box: 3; a sphere: none)."""


def simplest_within(candidates: Sequence[Scene | None], scores: Sequence[dict[str, Any]], best: int,
                    margin: float, silhouette_ranks: Sequence[int | None] | None = None) -> int:
    """The Best@K pick with a parsimony rule for shapes: among the valid candidates of the same
    structure as the best one (as many objects and static geoms) whose fitness is within
    ``margin`` of the best, the one whose shapes the silhouettes favour most (lowest
    ``silhouette_ranks``, :func:`pipeline.perception.silhouette_rank` summed over the objects),
    then the one with the fewest shape parameters (:data:`SHAPE_DOF` summed over the objects),
    then the highest fitness. When the re-simulation cannot tell two shapes apart, the image
    evidence it did not use decides first (a hexagonal outline is a box's corners, not a
    cylinder's), and where that cannot tell either (a ball and a disc seen along its axis give
    the same round silhouette) the one with fewer parameters is taken (Occam's razor; the
    generic-viewpoint assumption, Freeman, Nature 1994: a disc whose axis points at the camera
    is an accidental view).

    Args:
        candidates: the scenes scored (None = invalid); scores: :func:`best_of_k`'s dicts;
        best: index of the highest fitness; margin: fitness (dimensionless, as the fitness).
        silhouette_ranks: per candidate, how far its shapes are from the silhouettes' first
            choices (0 = all agree), or None for a candidate whose shapes were not read from the
            silhouettes (a model sample): it counts as disagreeing on every object. None for
            the whole argument: no silhouette evidence, parameters decide.
    Returns:
        the index picked (``best`` when ``margin`` is 0 or no other candidate is that close).
    """
    if margin <= 0 or candidates[best] is None:
        return best
    ref = candidates[best]

    def same_structure(c: Scene) -> bool:
        return len(c.objects) == len(ref.objects) and len(c.static) == len(ref.static)

    def dof(c: Scene) -> int:
        return sum(SHAPE_DOF[o.shape] for o in c.objects)

    def rank(i: int) -> int:
        if silhouette_ranks is None:
            return 0
        r = silhouette_ranks[i]
        return len(candidates[i].objects) if r is None else int(r)

    close = [i for i, (c, s) in enumerate(zip(candidates, scores))
             if c is not None and s["valid"] and s["fitness"] >= scores[best]["fitness"] - margin and same_structure(c)]
    return min(close, key=lambda i: (rank(i), dof(candidates[i]), -scores[i]["fitness"], i))
