"""Scene-level metrics and report rows (docs/design.md §7): composition accuracy, parameter
errors, one row per prediction, summaries and the paper-style Markdown table. The mask and flow
metrics they use are :mod:`pipeline.metrics`.

* **Composition accuracy**: the predicted multiset of shapes equals the true multiset.
* **Parameter errors** (synthetic scenes only): per-field absolute errors after matching.

Example::

    row = scene_report(true_scene, pred_scene, true_seg, obs_flow, pred_seg, pred_flow)
    summary = summarize([row, ...])   # dict: composition_accuracy, initial_iou, ..., epe
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment
from tabulate import tabulate

from pipeline.geometry import extents
from pipeline.metrics import hungarian_match, flow_epe, mean_ci95, pairwise_iou, sequence_iou
from pipeline.scene import Scene

OBJECT_FIELDS = ("position", "orientation", "linear_velocity", "angular_velocity", "size", "mass",
                 "sliding_friction", "rolling_friction", "damping")
"""Per-object fields of :func:`parameter_errors`, averaged over matched objects."""

SCENE_FIELDS = ("camera_position", "camera_pitch", "camera_fov", "gravity")
"""Scene-level fields of :func:`parameter_errors`."""

PARAMETER_UNITS = {
    "position": "m (Euclidean distance)", "orientation": "deg (geodesic angle)",
    "linear_velocity": "m/s (Euclidean)", "angular_velocity": "rad/s (Euclidean)",
    "size": "m (mean absolute error of the 3 full extents)", "mass": "kg",
    "sliding_friction": "1", "rolling_friction": "m", "damping": "N s/m",
    "camera_position": "m (Euclidean, camera centre)", "camera_pitch": "deg", "camera_fov": "deg",
    "gravity": "m/s^2",
}
"""Units of every :func:`parameter_errors` field (for reports)."""

INTERVAL_METRICS = ("composition_accuracy", "initial_iou", "full_iou", "strict_full_iou", "epe")
"""Means of :func:`summarize` that carry a bootstrap 95 % interval (issue 30: the paper-style table
with intervals); :func:`markdown_table` prints them as ``mean [lo, hi]``."""


def defined(value: Any) -> bool:
    """Whether a report value counts in a mean: not None and not NaN (e.g. the EPE of an invalid
    prediction, or a strict IoU with no frame to score)."""
    return value is not None and not (isinstance(value, float) and math.isnan(value))


# --------------------------------------------------------------------------- scenes
def composition_accuracy(true_scenes: Sequence[Scene], pred_scenes: Sequence[Scene | None]) -> float:
    """Fraction of scenes whose predicted multiset of shapes equals the true one.

    Args:
        true_scenes: N true scenes.
        pred_scenes: N predictions; ``None`` (unparseable output) counts as wrong.
    Returns:
        Accuracy in [0, 1]; NaN for N = 0.
    Raises:
        ValueError: the lists differ in length.
    """
    if len(true_scenes) != len(pred_scenes):
        raise ValueError(f"composition_accuracy: {len(true_scenes)} true scenes but {len(pred_scenes)} predictions")
    if not true_scenes:
        return math.nan
    hits = [p is not None and p.composition == t.composition for t, p in zip(true_scenes, pred_scenes)]
    return float(np.mean(hits))


def _quat_angle_deg(q1: Sequence[float], q2: Sequence[float]) -> float:
    """Geodesic angle (deg) between two rotations given as quaternions (q and -q equal).

    Kept as ``2 arccos |q1 . q2|`` rather than :func:`pipeline.rotation.quat_angle`: the
    arccos form loses precision near 0 (up to ~3e-6 deg for orientations 1e-9 apart), and
    switching would change reported numbers (``reports/metrics.json``) beyond round-off."""
    a = np.asarray(q1, dtype=np.float64) / np.linalg.norm(q1)
    b = np.asarray(q2, dtype=np.float64) / np.linalg.norm(q2)
    return float(np.degrees(2.0 * np.arccos(np.clip(abs(float(a @ b)), 0.0, 1.0))))


def match_by_position(true_scene: Scene, pred_scene: Scene) -> list[tuple[int, int]]:
    """Hungarian matching on initial-position distance, only between objects of the same shape.

    Returns:
        ``[(true_index, pred_index), ...]`` sorted by true index; objects whose shape has no
        counterpart stay unmatched.
    """
    pt = np.array([o.position for o in true_scene.objects], dtype=np.float64)
    pp = np.array([o.position for o in pred_scene.objects], dtype=np.float64)
    dist = np.linalg.norm(pt[:, None] - pp[None], axis=-1)
    same = np.array([[a.shape == b.shape for b in pred_scene.objects] for a in true_scene.objects])
    big = 1e6 + dist.max(initial=0.0) * 10
    rows, cols = linear_sum_assignment(np.where(same, dist, big))
    return sorted((int(r), int(c)) for r, c in zip(rows, cols) if same[r, c])


def parameter_errors(true_scene: Scene, pred_scene: Scene, true_seg: np.ndarray | None = None,
                     pred_seg: np.ndarray | None = None) -> dict[str, Any]:
    """Per-field absolute errors of a predicted scene after matching objects (docs/design.md §7).

    Objects are matched by :func:`pipeline.metrics.match_objects` when both segmentations are
    given (pred labels are the predicted scene's object indices, as rendered), else by
    :func:`match_by_position` (same shape only). Object fields are averaged over matched
    pairs; units in :data:`PARAMETER_UNITS`. Sizes are compared as full extents along the body
    axes, so a sphere matched to a box still has a size error. The camera is compared by its
    centre (paper form: (0, -2, height)), pitch and fov.

    Args:
        true_scene, pred_scene: validated scenes.
        true_seg, pred_seg: optional ``(T, H, W)`` label maps of both scenes' renders.
    Returns:
        dict: every name in :data:`OBJECT_FIELDS` (float, NaN when no object matched) and
        :data:`SCENE_FIELDS` (float), plus ``n_true``, ``n_matched`` (int) and ``matches``.
    """
    if true_seg is not None and pred_seg is not None:
        iou = pairwise_iou(true_seg, pred_seg, len(true_scene.objects), len(pred_scene.objects))
        matches = hungarian_match(iou)
    else:
        matches = match_by_position(true_scene, pred_scene)
    per: dict[str, list[float]] = {k: [] for k in OBJECT_FIELDS}
    for i, j in matches:
        a, b = true_scene.objects[i], pred_scene.objects[j]
        per["position"].append(float(np.linalg.norm(np.subtract(a.position, b.position))))
        per["orientation"].append(_quat_angle_deg(a.orientation, b.orientation))
        per["linear_velocity"].append(float(np.linalg.norm(np.subtract(a.linear_velocity, b.linear_velocity))))
        per["angular_velocity"].append(float(np.linalg.norm(np.subtract(a.angular_velocity, b.angular_velocity))))
        per["size"].append(float(np.abs(extents(a.shape, a.size) - extents(b.shape, b.size)).mean()))
        per["mass"].append(abs(a.mass - b.mass))
        per["sliding_friction"].append(abs(a.material.sliding_friction - b.material.sliding_friction))
        per["rolling_friction"].append(abs(a.material.rolling_friction - b.material.rolling_friction))
        per["damping"].append(abs(a.material.damping - b.material.damping))
    out: dict[str, Any] = {k: (float(np.mean(v)) if v else math.nan) for k, v in per.items()}
    ct, cp = true_scene.camera, pred_scene.camera
    out["camera_position"] = float(np.linalg.norm(np.subtract(ct.eye, cp.eye)))
    out["camera_pitch"] = abs(ct.pitch - cp.pitch)
    out["camera_fov"] = abs(ct.fov - cp.fov)
    out["gravity"] = abs(true_scene.gravity - pred_scene.gravity)
    out.update(n_true=len(true_scene.objects), n_matched=len(matches), matches=matches)
    return out


# --------------------------------------------------------------------------- reports
def scene_report(true_scene: Scene | None, pred_scene: Scene | None, true_seg: np.ndarray,
                 obs_flow: np.ndarray | None, pred_seg: np.ndarray | None,
                 pred_flow: np.ndarray | None) -> dict[str, Any]:
    """All metrics of one prediction of one scene (one row of a report).

    An invalid prediction (``pred_scene is None``: unparseable output, or nothing to refine)
    scores composition wrong and IoU 0; its EPE and parameter errors are NaN (left out of
    means, counted in ``n - n_valid``).

    Args:
        true_scene: the true scene (None for real video: no composition/parameter errors).
        pred_scene: the prediction, or None.
        true_seg: ``(T, H, W)`` observed labels (-1 background).
        obs_flow: ``(T-1, H, W, 2)`` observed flow, px, or None (no EPE).
        pred_seg, pred_flow: the prediction's re-simulated labels and flow (None if invalid).
    Returns:
        flat dict: ``valid``, ``composition_correct``, ``initial_iou``, ``full_iou``,
        ``strict_full_iou`` (:func:`pipeline.metrics.sequence_iou`'s ``strict_iou``: no credit for
        frames where an object and its match are both absent; NaN with no visible true object),
        ``foreground_iou_initial``, ``foreground_iou_full``, ``epe`` and
        ``param/<field>`` for every parameter error (NaN if unavailable).
    """
    row: dict[str, Any] = {"valid": pred_scene is not None}
    row["composition_correct"] = bool(
        pred_scene is not None and true_scene is not None and pred_scene.composition == true_scene.composition)
    keys = ("initial_iou", "full_iou", "foreground_iou_initial", "foreground_iou_full")
    if pred_scene is None or pred_seg is None:
        row.update({k: 0.0 for k in keys}, strict_full_iou=0.0, epe=math.nan)
        row.update({f"param/{k}": math.nan for k in OBJECT_FIELDS + SCENE_FIELDS})
        return row
    iou = sequence_iou(true_seg, pred_seg)
    row.update({k: iou[k] for k in keys})
    row["strict_full_iou"] = iou["strict_iou"]
    row["epe"] = (flow_epe(pred_flow, obs_flow, pred_seg[:-1] >= 0, np.asarray(true_seg)[:-1] >= 0)
                  if pred_flow is not None and obs_flow is not None else math.nan)
    if true_scene is not None:
        err = parameter_errors(true_scene, pred_scene, true_seg, pred_seg)
        row.update({f"param/{k}": err[k] for k in OBJECT_FIELDS + SCENE_FIELDS})
    else:
        row.update({f"param/{k}": math.nan for k in OBJECT_FIELDS + SCENE_FIELDS})
    return row


def summarize(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Aggregate :func:`scene_report` rows of one method and split.

    Returns:
        dict: ``n``, ``n_valid``, ``composition_accuracy``, ``initial_iou``, ``full_iou``,
        ``strict_full_iou`` (over the rows where it is defined), ``foreground_iou_initial``, ``foreground_iou`` (full sequence) — means over all rows
        (invalid rows count 0) — and ``epe`` and ``parameter_errors`` (dict per field) —
        means over valid rows with a finite value (NaN when none) — and ``ci95``: for each of
        :data:`INTERVAL_METRICS`, the percentile bootstrap 95 % interval ``[lo, hi]`` of that mean
        over the same per-scene values (:func:`pipeline.metrics.mean_ci95`: 2000 resamples of the
        scenes, seed 0; Efron & Tibshirani 1993, ch. 13), NaN without values.
    """
    def values(key: str, valid_only: bool = False) -> list[float]:
        return [float(r[key]) for r in rows if (r["valid"] or not valid_only) and defined(r[key])]

    def mean(key: str, valid_only: bool = False) -> float:
        vals = values(key, valid_only)
        return float(np.mean(vals)) if vals else math.nan

    sources = {"composition_accuracy": ("composition_correct", False), "initial_iou": ("initial_iou", False),
               "full_iou": ("full_iou", False), "strict_full_iou": ("strict_full_iou", False),
               "foreground_iou_initial": ("foreground_iou_initial", False),
               "foreground_iou": ("foreground_iou_full", False), "epe": ("epe", True)}   # summary key: (row key, valid only)
    return {
        "n": len(rows),
        "n_valid": int(sum(bool(r["valid"]) for r in rows)),
        **{m: mean(*src) for m, src in sources.items()},
        "parameter_errors": {k: mean(f"param/{k}", valid_only=True) for k in OBJECT_FIELDS + SCENE_FIELDS},
        "ci95": {m: mean_ci95(values(*sources[m]))["ci95"] for m in INTERVAL_METRICS},
    }


def markdown_table(summaries: dict[str, dict[str, Any]], labels: dict[str, str], inputs: dict[str, str],
                   split: str) -> str:
    """A paper-style Markdown table of one split.

    Args:
        summaries: method key -> :func:`summarize` output for this split.
        labels: method key -> row label (e.g. ``"Best@32 + CMA-ES"``).
        inputs: method key -> input modality shown in the table (``flow`` / ``rgb`` / ``-``).
        split: split name, for the heading.
    Returns:
        Markdown: a heading and a table with composition accuracy, initial IoU, full-sequence
        IoU (strict: the headline, issue 29 item 7; and all frames: docs/design.md §7),
        foreground IoU and EPE (px) per method; a mean with a ``ci95`` entry in its summary is
        printed ``mean [lo, hi]``.
    """
    def f(x: float, nd: int = 3) -> str:
        return "–" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{nd}f}"

    def cell(s: dict[str, Any], key: str, nd: int = 3) -> str:
        lo, hi = (s.get("ci95") or {}).get(key) or (None, None)
        value = f(s.get(key, math.nan), nd)
        return value if value == "–" or None in (lo, hi) or math.isnan(lo) else f"{value} [{f(lo, nd)}, {f(hi, nd)}]"

    n = max((s["n"] for s in summaries.values()), default=0)
    header = ["Method", "Input", "Composition acc.", "Initial IoU", "Full-sequence IoU (strict)",
              "Full-sequence IoU (all frames)", "Foreground IoU", "EPE (px)", "valid"]
    rows = [[labels.get(key, key), inputs.get(key, "-"), cell(s, "composition_accuracy"), cell(s, "initial_iou"),
             cell(s, "strict_full_iou"), cell(s, "full_iou"), f(s["foreground_iou"]), cell(s, "epe", 2),
             f"{s['n_valid']}/{s['n']}"]
            for key, s in summaries.items()]
    table = tabulate(rows, header, tablefmt="github", disable_numparse=True)  # cells exactly as formatted here
    note = "" if not any(s.get("ci95") for s in summaries.values()) else \
        "\n\n`mean [lo, hi]`: percentile bootstrap 95 % interval over the scenes (2000 resamples)."
    return f"### Split `{split}` (n = {n})\n\n{table}{note}\n"


def json_safe(obj: Any) -> Any:
    """``obj`` with every non-finite float (NaN, ±inf) replaced by None, recursively, so the
    report is strict JSON (``dvc metrics show`` and browsers reject NaN)."""
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    return obj
