"""Truth for a video, when there is some: hand labels or true instance masks, read for scoring only
(``dynamics infer --labels``, issue 36). The search never reads them: it fits the observation.

Two formats:

* a **folder of PNG label images** named by source frame index (``0042.png``: frame 42, 0-based as
  decoded), uint8, 0 background and 1..n the objects (``scripts/label_masks.py`` writes them; any
  size, scaled to the video's frame with nearest-neighbour);
* an **npz file** with ``seg`` ``(N, H, W)`` int labels of every source frame from frame 0, -1
  background (``truth.npz`` of :mod:`pipeline.truthsets`).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from pipeline.errors import UserError
from pipeline.metrics import observation_scores
from pipeline.observe import Observation, source_frames, upscale


class LabelsError(UserError, ValueError):
    """Labels that cannot be read or do not fit the video."""


def load_labels(path: str | Path, original_size: tuple[int, int]) -> dict[int, np.ndarray]:
    """Read labels (module docstring) at the video's size.

    Args:
        path: PNG folder or npz file.
        original_size: ``(W0, H0)`` of the video's frames, px.
    Returns:
        ``{source frame index: (H0, W0) int8 labels, -1 background}``.
    Raises:
        LabelsError: missing path, no label in it, an unreadable file or a bad ``seg``.
    """
    path = Path(path)
    W0, H0 = original_size
    if path.is_dir():
        out = {}
        for png in sorted(path.glob("*.png")):
            if not png.stem.isdigit():
                continue
            img = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
            if img is None or img.ndim != 2:
                raise LabelsError(f"{png}: not a single-channel label image")
            lab = img.astype(np.int16) - 1
            out[int(png.stem)] = cv2.resize(lab, (W0, H0), interpolation=cv2.INTER_NEAREST).astype(np.int8)
        if not out:
            raise LabelsError(f"{path}: no label image named by frame index (e.g. 0042.png)")
        return out
    if not path.is_file():
        raise LabelsError(f"{path}: no such labels file or folder")
    try:
        with np.load(path, allow_pickle=False) as z:
            seg = np.asarray(z["seg"])
    except Exception as exc:   # noqa: BLE001 - any unreadable file is one error
        raise LabelsError(f"{path}: seg: cannot read ({exc})") from None
    if seg.ndim != 3 or not np.issubdtype(seg.dtype, np.integer):
        raise LabelsError(f"{path}: seg: must be (N, H, W) integer labels, got {seg.shape} {seg.dtype}")
    if seg.shape[1:] != (H0, W0):
        seg = np.stack([cv2.resize(s.astype(np.int16), (W0, H0), interpolation=cv2.INTER_NEAREST) for s in seg])
    return {i: s.astype(np.int8) for i, s in enumerate(seg)}


def labels_in_window(labels: dict[int, np.ndarray], obs: Observation) -> tuple[np.ndarray, np.ndarray]:
    """The labelled frames of the observation's window, as the observation sees them.

    Returns:
        ``(k, seg)``: ``(F,)`` int64 window frame indices that have a label and ``(F, H, W)`` int8
        labels cut to the working crop and resized (nearest) to the working size.
    """
    idx = source_frames(obs)
    ks = np.asarray([k for k, i in enumerate(idx) if int(i) in labels], dtype=np.int64)
    if not len(ks):
        return ks, np.zeros((0, obs.size[1], obs.size[0]), np.int8)
    x, y, w, h = obs.crop
    seg = np.stack([labels[int(idx[k])][y:y + h, x:x + w] for k in ks])
    return ks, upscale(seg, obs.size)


def score_against_labels(labels: dict[int, np.ndarray], obs: Observation, resim_seg: np.ndarray) -> dict:
    """The re-simulation and the observation, each scored against the labels on the window's
    labelled frames (:func:`pipeline.metrics.observation_scores`), and the re-simulation against the
    observation with the same metric on the same frames, so the three numbers compare.

    Args:
        labels: :func:`load_labels`.
        obs: the observation; resim_seg: ``(T, H, W)`` int8 re-simulated labels at the working size.
    Returns:
        dict with ``frames`` (window frame indices), ``resim_vs_labels``, ``observation_vs_labels``,
        ``resim_vs_observation`` (matched IoU each, None without labelled frames), ``n_labelled``.
    """
    ks, seg = labels_in_window(labels, obs)
    if not len(ks):
        return {"frames": [], "n_labelled": 0, "resim_vs_labels": None, "observation_vs_labels": None,
                "resim_vs_observation": None,
                "note": "no labelled frame inside the window"}

    def iou(true, pred):
        v = observation_scores(true, pred)["matched_iou"]
        return None if v != v else round(float(v), 4)

    return {"frames": ks.tolist(), "n_labelled": int(len(ks)),
            "resim_vs_labels": iou(seg, resim_seg[ks]), "observation_vs_labels": iou(seg, obs.seg[ks]),
            "resim_vs_observation": iou(obs.seg[ks], resim_seg[ks])}
