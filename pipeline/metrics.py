"""Mask and flow metrics used in every report (docs/design.md §7), and the scores of an
observation against true instance masks; the scene-level metrics and report rows are
:mod:`pipeline.scene_metrics`.

* **Mask IoU**: objects are matched one-to-one by Hungarian assignment
  (``scipy.optimize.linear_sum_assignment``) on their IoU averaged over the sequence; the IoU of
  each matched pair is averaged over the *true* objects, an unmatched true object counting 0.
  *Initial* IoU is frame 0, *full-sequence* IoU the mean over all frames. *Foreground* IoU
  compares the union of all objects and needs no matching.
* **Flow EPE**: mean Euclidean distance (px at the rendered resolution) between the
  re-simulated and the observed flow over the pixels where either is foreground.
* **Observation scores** (:func:`observation_scores`, issue 36): per-object IoU over the frames
  where either mask is visible, identity switches.

Segmentations are ``(T, H, W)`` integer label maps: object index ``0..n-1`` per pixel and
``-1`` (:data:`pipeline.render.BACKGROUND`) for the floor and background. A ``bool`` array is
accepted wherever a segmentation is, as one foreground "object" (label 0).

Conventions for empty masks (documented choices, used consistently):

* :func:`mask_iou` of two empty masks is **1.0**: both say "nothing here", which is agreement
  (an object hidden in the true and the predicted frame is not an error).
* :func:`flow_epe` with no foreground pixel in either mask is **0.0**: there is no pixel on
  which the two flows disagree.

Example::

    res = sequence_iou(true_seg, pred_seg)    # dict: initial_iou, full_iou, per_frame, ...
    epe = flow_epe(pred_flow, obs_flow, pred_seg[:-1] >= 0, true_seg[:-1] >= 0)
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.stats import bootstrap

BACKGROUND = -1
"""Label of the floor/background in segmentations (same as ``pipeline.render.BACKGROUND``)."""


# --------------------------------------------------------------------------- masks
def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boolean masks of the same shape.

    Args:
        a, b: bool arrays, any (equal) shape.
    Returns:
        ``|a & b| / |a | b|`` in [0, 1]; **1.0 when both masks are empty** (see module docstring).
    Raises:
        ValueError: shapes differ.
    """
    a, b = np.asarray(a, dtype=bool), np.asarray(b, dtype=bool)
    if a.shape != b.shape:
        raise ValueError(f"mask_iou: shapes must be equal, got {a.shape} and {b.shape}")
    union = int(np.count_nonzero(a | b))
    if union == 0:
        return 1.0
    return int(np.count_nonzero(a & b)) / union


def as_labels(seg: np.ndarray, name: str = "seg") -> np.ndarray:
    """A ``(T, H, W)`` segmentation as int64 labels (-1 background); bool -> one object (0).

    Raises:
        ValueError: not 3-D, not integer/bool, or a label below -1.
    """
    seg = np.asarray(seg)
    if seg.ndim != 3:
        raise ValueError(f"{name}: must be (T, H, W), got shape {seg.shape}")
    if seg.dtype == bool:
        return np.where(seg, 0, BACKGROUND).astype(np.int64)
    if not np.issubdtype(seg.dtype, np.integer):
        raise ValueError(f"{name}: must be an integer label map or bool, got dtype {seg.dtype}")
    seg = seg.astype(np.int64)
    if seg.size and seg.min() < BACKGROUND:
        raise ValueError(f"{name}: labels must be >= -1, got {int(seg.min())}")
    return seg


def n_labels(seg: np.ndarray) -> int:
    """Number of objects in a label map: ``max label + 1`` (0 if all background)."""
    return int(seg.max()) + 1 if seg.size else 0


def pairwise_iou(true_seg: np.ndarray, pred_seg: np.ndarray, n_true: int | None = None,
                 n_pred: int | None = None) -> np.ndarray:
    """IoU of every (true object, predicted object) pair in every frame.

    Args:
        true_seg, pred_seg: ``(T, H, W)`` label maps (int, -1 background) or bool.
        n_true, n_pred: object counts (default: max label + 1); labels at or above the count
            are treated as background.
    Returns:
        ``(T, n_true, n_pred)`` float64; 1.0 where both masks are empty in that frame.
    Raises:
        ValueError: shapes differ or a segmentation is malformed.
    """
    t, p = as_labels(true_seg, "true_seg"), as_labels(pred_seg, "pred_seg")
    if t.shape != p.shape:
        raise ValueError(f"segmentations must have equal shapes, got {t.shape} and {p.shape}")
    nt = n_labels(t) if n_true is None else int(n_true)
    npd = n_labels(p) if n_pred is None else int(n_pred)
    T = t.shape[0]
    t = np.where(t < nt, t, BACKGROUND).reshape(T, -1) + 1  # 0 = background
    p = np.where(p < npd, p, BACKGROUND).reshape(T, -1) + 1
    idx = (np.arange(T)[:, None] * (nt + 1) + t) * (npd + 1) + p
    counts = np.bincount(idx.ravel(), minlength=T * (nt + 1) * (npd + 1)).reshape(T, nt + 1, npd + 1)
    return _counts_iou(counts)


def hungarian_match(iou: np.ndarray) -> list[tuple[int, int]]:
    """Hungarian assignment maximising the sequence-mean IoU of ``iou (T, n_true, n_pred)``."""
    if iou.shape[1] == 0 or iou.shape[2] == 0:
        return []
    rows, cols = linear_sum_assignment(iou.mean(axis=0), maximize=True)
    return sorted((int(r), int(c)) for r, c in zip(rows, cols))


def match_objects(true_seg: np.ndarray, pred_seg: np.ndarray) -> list[tuple[int, int]]:
    """Match true to predicted objects one-to-one (docs/design.md §7).

    Hungarian assignment (``scipy.optimize.linear_sum_assignment``) maximising the IoU
    averaged over the sequence. With unequal counts, ``min(n_true, n_pred)`` pairs are
    returned; the remaining objects are unmatched.

    Args:
        true_seg, pred_seg: ``(T, H, W)`` int8 label maps (-1 background) or bool.
    Returns:
        ``[(true_index, pred_index), ...]`` sorted by true index.
    Raises:
        ValueError: shapes differ or a segmentation is malformed.
    """
    return hungarian_match(pairwise_iou(true_seg, pred_seg))


def _small_labels(seg: np.ndarray, name: str) -> tuple[np.ndarray, int] | None:
    """``seg + 1`` as int16 (0 = background) and the object count, validated as
    :func:`as_labels` does; None when a label does not fit int16."""
    seg = np.asarray(seg)
    if seg.ndim != 3:
        raise ValueError(f"{name}: must be (T, H, W), got shape {seg.shape}")
    if seg.dtype == bool:
        return seg.astype(np.int16), int(seg.any())
    if not np.issubdtype(seg.dtype, np.integer):
        raise ValueError(f"{name}: must be an integer label map or bool, got dtype {seg.dtype}")
    if not seg.size:
        return None
    lo, hi = int(seg.min()), int(seg.max())
    if lo < BACKGROUND:
        raise ValueError(f"{name}: labels must be >= -1, got {lo}")
    if hi >= 2 ** 15 - 1:
        return None
    return seg.astype(np.int16) + np.int16(1), hi + 1


def _label_counts(true_seg: np.ndarray, pred_seg: np.ndarray) -> np.ndarray | None:
    """``(T, n_true + 1, n_pred + 1)`` int64 pixel counts of (true label + 1, pred label + 1)
    per frame, as :func:`pairwise_iou` counts them; None where that general path must run
    (labels that do not fit a small integer code, empty clips).

    Raises:
        ValueError: as :func:`pairwise_iou`.
    """
    a = _small_labels(true_seg, "true_seg")
    b = _small_labels(pred_seg, "pred_seg")
    if np.shape(true_seg) != np.shape(pred_seg):
        raise ValueError(f"segmentations must have equal shapes, got {np.shape(true_seg)} and {np.shape(pred_seg)}")
    if a is None or b is None:
        return None
    (t, nt), (p, npd) = a, b
    k = (nt + 1) * (npd + 1)
    if k >= 2 ** 15:
        return None
    T = t.shape[0]
    if T == 0:
        return None
    code = (t * np.int16(npd + 1) + p).reshape(T, -1)
    return np.stack([np.bincount(code[i], minlength=k) for i in range(T)]).astype(np.int64).reshape(T, nt + 1, npd + 1)


def _counts_iou(counts: np.ndarray) -> np.ndarray:
    """:func:`pairwise_iou` from the label-pair counts of :func:`_label_counts`."""
    inter = counts[:, 1:, 1:].astype(np.float64)
    area_t = counts[:, 1:, :].sum(axis=2).astype(np.float64)
    area_p = counts[:, :, 1:].sum(axis=1).astype(np.float64)
    union = area_t[:, :, None] + area_p[:, None, :] - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(union > 0, inter / np.maximum(union, 1.0), 1.0)


def sequence_iou(true_seg: np.ndarray, pred_seg: np.ndarray) -> dict[str, Any]:
    """Mask IoU of a re-simulated clip against the observed one (docs/design.md §7).

    Args:
        true_seg: ``(T, H, W)`` observed labels (int8, -1 background; bool = foreground only,
            one object).
        pred_seg: ``(T, H, W)`` re-simulated labels, same convention.
    Returns:
        dict with

        * ``initial_iou`` (float): frame-0 IoU, matched objects averaged over true objects;
        * ``full_iou`` (float): the same averaged over all T frames;
        * ``per_frame`` ((T,) float64): the matched IoU per frame;
        * ``foreground_iou_initial`` / ``foreground_iou_full`` (float): IoU of the union of
          objects at frame 0 / averaged over frames (no matching);
        * ``matches``: the ``(true, pred)`` pairs used;
        * ``n_true``, ``n_pred`` (int): object counts (max label + 1);
        * ``strict_iou`` (float): the full-sequence IoU without free credit (issue 29 item 7):
          per true object, the IoU with its match averaged over the frames where the object or
          its match is visible (:func:`track_iou`; objects matched on that IoU, an unmatched one
          counts 0), averaged over the true objects visible in some frame; NaN when none is;
        * ``n_true_visible``, ``n_pred_visible`` (int): the objects visible in some frame.

        ``full_iou`` keeps the docs/design.md §7 convention: a frame where a true object and its
        match are both absent counts 1.0. With no true object at all, ``per_frame`` is the
        foreground IoU (1.0 where the prediction is empty too).
    Raises:
        ValueError: shapes differ or a segmentation is malformed.
    """
    counts = _label_counts(true_seg, pred_seg)
    if counts is None:  # labels too many for the small-integer path: the general one
        t, p = as_labels(true_seg, "true_seg"), as_labels(pred_seg, "pred_seg")
        iou = pairwise_iou(t, p)
        fg_t, fg_p = t >= 0, p >= 0
        inter = np.count_nonzero(fg_t & fg_p, axis=(1, 2))
        union = np.count_nonzero(fg_t | fg_p, axis=(1, 2))
        strict = _strict_iou(_general_counts(t, p))
    else:  # the same integers as above, from one histogram of (true, pred) label pairs per frame
        iou = _counts_iou(counts)
        inter = counts[:, 1:, 1:].sum(axis=(1, 2))
        union = counts[0].sum() - counts[:, 0, 0]
        strict = _strict_iou(counts)
    matches = hungarian_match(iou)
    nt = iou.shape[1]
    fg = np.where(union > 0, inter / np.maximum(union, 1), 1.0)
    if nt == 0:
        per_frame = fg.astype(np.float64)
    else:
        per_frame = np.zeros(iou.shape[0], dtype=np.float64)
        for i, j in matches:
            per_frame += iou[:, i, j]
        per_frame /= nt
    return {
        "initial_iou": float(per_frame[0]) if len(per_frame) else math.nan,
        "full_iou": float(per_frame.mean()) if len(per_frame) else math.nan,
        "per_frame": per_frame,
        "foreground_iou_initial": float(fg[0]) if len(fg) else math.nan,
        "foreground_iou_full": float(fg.mean()) if len(fg) else math.nan,
        "matches": matches,
        "n_true": nt,
        "n_pred": int(iou.shape[2]),
        "strict_iou": strict[0],
        "n_true_visible": strict[1],
        "n_pred_visible": strict[2],
    }


# --------------------------------------------------------------------------- flow
def flow_epe(flow_pred: np.ndarray, flow_obs: np.ndarray, fg_pred: np.ndarray, fg_obs: np.ndarray,
             over: str = "union") -> float:
    """Mean end-point error between re-simulated and observed flow over the foreground.

    Args:
        flow_pred: ``(T-1, H, W, 2)`` float re-simulated forward flow, px at the rendered
            resolution (``flow[..., 0]`` = u along x, ``[..., 1]`` = v along y).
        flow_obs: ``(T-1, H, W, 2)`` float observed flow (float16 from the flow stage is fine);
            NaN marks a pixel whose observed flow is not to be trusted (skipped:
            :attr:`pipeline.observe.Observation.fit_flow`).
        fg_pred, fg_obs: ``(T-1, H, W)`` bool foreground of frames ``0..T-2`` (the frames the
            flow starts from), e.g. ``seg[:-1] >= 0``.
        over: ``"union"`` (the metric, docs/design.md §7): pixels where ``fg_pred | fg_obs``;
            ``"observed"``: pixels where ``fg_obs`` only (the observed motion left unexplained;
            a predicted object away from it cannot dilute the mean; the search's
            ``epe_pixels``).
    Returns:
        Mean of ``||flow_pred - flow_obs||_2`` over those pixels, px; **0.0 if there is none**
        (see module docstring).
    Raises:
        ValueError: shapes disagree, or ``over`` is neither.
    """
    fp, fo = np.asarray(flow_pred), np.asarray(flow_obs)
    mp, mo = np.asarray(fg_pred, dtype=bool), np.asarray(fg_obs, dtype=bool)
    if fp.shape != fo.shape or fp.ndim != 4 or fp.shape[-1] != 2:
        raise ValueError(f"flow_epe: flows must both be (T-1, H, W, 2), got {fp.shape} and {fo.shape}")
    if mp.shape != fp.shape[:-1] or mo.shape != fp.shape[:-1]:
        raise ValueError(f"flow_epe: masks must be {fp.shape[:-1]}, got {mp.shape} and {mo.shape}")
    if over not in ("union", "observed"):
        raise ValueError(f"flow_epe: over must be 'union' or 'observed', got {over!r}")
    idx = np.flatnonzero(mo if over == "observed" else mp | mo)  # the pixels of fp[mask], in order
    obs = fo.reshape(-1, 2)[idx].astype(np.float64)
    trusted = np.isfinite(obs).all(axis=-1)        # NaN: an observed flow not to be trusted there
    if not trusted.all():
        idx, obs = idx[trusted], obs[trusted]
    if not idx.size:
        return 0.0
    d = fp.reshape(-1, 2)[idx].astype(np.float64) - obs
    return float(np.sqrt((d * d).sum(axis=-1)).mean())


# --------------------------------------------------------------------------- observation vs truth
def track_iou(true_seg: np.ndarray, pred_seg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-object IoU of every (true, predicted) pair over the frames where either is visible.

    Unlike :func:`pairwise_iou` (which the search uses, and where a frame with both masks empty
    counts 1.0), a frame where neither object is visible is *skipped*: no free credit for
    agreeing on absence (issue 36). Frames where only one of the two is visible count 0.

    Args:
        true_seg, pred_seg: ``(T, H, W)`` int label maps (-1 background) or bool, same shape.
    Returns:
        ``(iou, frames)``: ``iou`` ``(n_true, n_pred)`` float64, the mean per-frame IoU over the
        frames where either is visible (0.0 if neither ever is); ``frames`` ``(n_true, n_pred)``
        int64, how many frames that is.
    Raises:
        ValueError: shapes differ or a segmentation is malformed.
    """
    counts = _label_counts(true_seg, pred_seg)
    if counts is None:
        counts = _general_counts(as_labels(true_seg, "true_seg"), as_labels(pred_seg, "pred_seg"))
    return _counts_track_iou(counts)


def _general_counts(t: np.ndarray, p: np.ndarray) -> np.ndarray:
    """:func:`_label_counts` for any int64 labels ``t``, ``p`` ``(T, H, W)`` (-1 background):
    ``(T, n_true + 1, n_pred + 1)`` int64 pixel counts, without the small-integer code."""
    nt, npd = n_labels(t), n_labels(p)
    T = t.shape[0]
    code = ((t + 1) * (npd + 1) + (p + 1)).reshape(T, -1)
    return np.stack([np.bincount(c, minlength=(nt + 1) * (npd + 1)) for c in code]) \
        .reshape(T, nt + 1, npd + 1) if T else np.zeros((0, nt + 1, npd + 1), np.int64)


def _counts_track_iou(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`track_iou` from the ``(T, n_true + 1, n_pred + 1)`` label-pair counts of
    :func:`_label_counts`."""
    inter = counts[:, 1:, 1:].astype(np.float64)
    area_t = counts[:, 1:, :].sum(axis=2).astype(np.float64)     # (T, nt)
    area_p = counts[:, :, 1:].sum(axis=1).astype(np.float64)     # (T, np)
    union = area_t[:, :, None] + area_p[:, None, :] - inter
    either = union > 0
    per_frame = np.where(either, inter / np.maximum(union, 1.0), 0.0)
    frames = either.sum(axis=0)
    iou = np.where(frames > 0, per_frame.sum(axis=0) / np.maximum(frames, 1), 0.0)
    return iou, frames.astype(np.int64)


def match_tracks(iou: np.ndarray, visible_true: Sequence[int], visible_pred: Sequence[int]) -> dict[int, int]:
    """One-to-one match of the visible true and predicted objects, Hungarian assignment
    (``scipy.optimize.linear_sum_assignment``) maximising the summed :func:`track_iou`.

    Args:
        iou: ``(n_true, n_pred)`` float per-object IoU (:func:`track_iou`).
        visible_true, visible_pred: labels of the objects seen in at least one frame.
    Returns:
        true label -> predicted label, for the matched pairs.
    """
    vt, vp = list(visible_true), list(visible_pred)
    if not vt or not vp:
        return {}
    rows, cols = linear_sum_assignment(iou[np.ix_(vt, vp)], maximize=True)
    return {vt[a]: vp[b] for a, b in zip(rows, cols)}


def _strict_iou(counts: np.ndarray) -> tuple[float, int, int]:
    """``(strict_iou, n_true, n_pred)`` of :func:`sequence_iou` from label-pair counts: the mean
    over the true objects visible in any frame of their matched :func:`track_iou` (0 when
    unmatched), NaN when no true object is visible; ``n_true`` / ``n_pred`` count the visible
    objects."""
    iou, _ = _counts_track_iou(counts)
    vis_t = np.flatnonzero(counts[:, 1:, :].sum(axis=(0, 2)) > 0)
    vis_p = np.flatnonzero(counts[:, :, 1:].sum(axis=(0, 1)) > 0)
    pairs = match_tracks(iou, vis_t, vis_p)
    if not len(vis_t):
        return math.nan, 0, len(vis_p)
    return float(sum(iou[i, j] for i, j in pairs.items()) / len(vis_t)), len(vis_t), len(vis_p)


def identity_switches(true_seg: np.ndarray, pred_seg: np.ndarray, min_iou: float = 0.5) -> int:
    """Identity switches of a tracker against the truth (CLEAR MOT, Bernardin & Stiefelhagen 2008).

    In each frame true and predicted objects are matched by Hungarian assignment on that
    frame's IoU, keeping pairs with IoU >= ``min_iou``; a switch is a true object matched to a
    different predicted id than at its previous match.

    Args:
        true_seg, pred_seg: ``(T, H, W)`` label maps (-1 background), same shape.
        min_iou: smallest per-frame IoU of a match.
    Returns:
        the number of switches, >= 0.
    """
    iou = pairwise_iou(true_seg, pred_seg)                       # (T, nt, np); both-empty = 1
    t, p = as_labels(true_seg, "true_seg"), as_labels(pred_seg, "pred_seg")
    nt, npd = iou.shape[1:]
    vis_t = np.stack([(t == k).any(axis=(1, 2)) for k in range(nt)], axis=1) if nt else np.zeros((len(t), 0), bool)
    vis_p = np.stack([(p == k).any(axis=(1, 2)) for k in range(npd)], axis=1) if npd else np.zeros((len(p), 0), bool)
    last: dict[int, int] = {}
    switches = 0
    for f in range(iou.shape[0]):
        m = np.where(vis_t[f][:, None] & vis_p[f][None, :], iou[f], 0.0)
        if not m.size:
            continue
        for i, j in zip(*linear_sum_assignment(m, maximize=True)):
            if m[i, j] >= min_iou:
                switches += int(i in last and last[i] != j)
                last[int(i)] = int(j)
    return switches


def observation_scores(true_seg: np.ndarray, pred_seg: np.ndarray,
                       still: Sequence[bool] | None = None, found_iou: float = 0.5) -> dict[str, Any]:
    """An observation (masks split into objects) scored against true instance masks (issue 36).

    True and predicted objects are matched one-to-one by Hungarian assignment
    (``scipy.optimize.linear_sum_assignment``) on :func:`track_iou`, the per-object IoU over
    the frames where either is visible; an unmatched true object scores 0. A true object
    that is never visible in these frames is not counted.

    Args:
        true_seg: ``(T, H, W)`` true labels (-1 background); the frames may be a sparse set
            (hand-labelled frames) as long as ``pred_seg`` holds the same frames.
        pred_seg: ``(T, H, W)`` observed labels, same shape.
        still: per true object (index = label), whether it is at rest in these frames; None
            means unknown (every object reported as moving).
        found_iou: a true object is *found* when its matched IoU reaches this.
    Returns:
        dict: ``matched_iou`` (mean over visible true objects, NaN if there is none),
        ``per_object`` (list of dicts: ``true``, ``pred`` (None if unmatched), ``iou``,
        ``frames``, ``still``), ``n_true`` / ``n_pred`` (objects visible in the frames),
        ``count_right`` (bool), ``id_switches`` (:func:`identity_switches`), and
        ``moving_iou`` / ``still_iou`` / ``still_found`` (fraction of still objects found,
        NaN when there is none) reported apart.
    Raises:
        ValueError: shapes differ or a segmentation is malformed.
    """
    t, p = as_labels(true_seg, "true_seg"), as_labels(pred_seg, "pred_seg")
    if t.shape != p.shape:
        raise ValueError(f"segmentations must have equal shapes, got {t.shape} and {p.shape}")
    iou, frames = track_iou(t, p)
    nt, npd = iou.shape
    vis_t = [k for k in range(nt) if (t == k).any()]
    vis_p = [k for k in range(npd) if (p == k).any()]
    pairs = match_tracks(iou, vis_t, vis_p)
    still = [False] * nt if still is None else [bool(s) for s in still] + [False] * max(0, nt - len(still))
    rows = []
    for k in vis_t:
        j = pairs.get(k)
        rows.append({"true": k, "pred": j, "iou": float(iou[k, j]) if j is not None else 0.0,
                     "frames": int(frames[k, j]) if j is not None else int((t == k).any(axis=(1, 2)).sum()),
                     "still": still[k]})

    def mean(xs):
        return float(np.mean(xs)) if len(xs) else math.nan

    still_rows = [r for r in rows if r["still"]]
    return {
        "matched_iou": mean([r["iou"] for r in rows]),
        "per_object": rows,
        "n_true": len(vis_t), "n_pred": len(vis_p), "count_right": len(vis_t) == len(vis_p),
        "id_switches": identity_switches(t, p),
        "moving_iou": mean([r["iou"] for r in rows if not r["still"]]),
        "still_iou": mean([r["iou"] for r in still_rows]),
        "still_found": mean([r["iou"] >= found_iou for r in still_rows]),
    }


# --------------------------------------------------------------------------- intervals

def mean_ci95(values: Sequence[float], n_resamples: int = 2000, seed: int = 0) -> dict[str, Any]:
    """Mean of per-scene values with a percentile bootstrap 95 % interval
    (``scipy.stats.bootstrap``, ``method="percentile"``; Efron & Tibshirani 1993, ch. 13).

    Args:
        values: ``(N,)`` per-scene numbers (e.g. 0/1 hits or IoUs).
        n_resamples, seed: bootstrap resamples and their seed (deterministic).
    Returns:
        ``{"mean": float, "ci95": [lo, hi], "n": N}``, rounded to 3 decimals; with fewer than
        two values (or all equal) the interval is the mean itself; ``mean`` is NaN for no values.
    """
    x = np.asarray(values, dtype=np.float64)
    if x.size == 0:
        return {"mean": float("nan"), "ci95": [float("nan"), float("nan")], "n": 0}
    m = float(x.mean())
    if x.size < 2 or np.all(x == x[0]):
        return {"mean": round(m, 3), "ci95": [round(m, 3), round(m, 3)], "n": int(x.size)}
    res = bootstrap((x,), np.mean, n_resamples=n_resamples, method="percentile", random_state=seed)
    lo, hi = res.confidence_interval
    return {"mean": round(m, 3), "ci95": [round(float(lo), 3), round(float(hi), 3)], "n": int(x.size)}
