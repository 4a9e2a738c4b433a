"""Optical flow: estimators and the colour coding used to look at flow.

Flow convention (docs/design.md §3): forward flow from frame ``t`` to ``t + 1``, in pixels,
``flow[..., 0] = u`` is the displacement along image x (columns, to the right) and
``flow[..., 1] = v`` along image y (rows, downwards).

Estimators (params ``flow.method``):

- ``dis``: OpenCV's Dense Inverse Search (Kroeger et al., ECCV 2016), the default.
- ``farneback``: OpenCV's polynomial-expansion flow (Farnebäck, SCIA 2003).
- ``raft``: RAFT (Teed & Deng, ECCV 2020), written and trained here (``pipeline.raft``); weights
  from ``raft_weights`` (a released ``raft-small.pth`` / ``raft-things.pth`` or the shipped
  ``pipeline/weights/raft-small-dynamics.pth`` when null).
- ``gt``: the simulator's exact flow, written by the render stage; nothing to estimate here.

Example::

    flow = estimate_flow(frames)              # (T-1, H, W, 2) float32, px
    flow = flow_of(frames, FlowConfig(method="raft"))   # the params section decides
    rgb = flow_to_rgb(flow, max_magnitude=8)  # (T-1, H, W, 3) uint8, Middlebury colours
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from pipeline.params import typed_section

RAFT_ITERS = 6
"""RAFT's GRU updates per frame pair by default (``flow.raft_iters``). The paper evaluates with 12;
with the weights trained here the flow has converged after 4: the foreground EPE on the synthetic
test split is 0.329-0.330 px for 4, 6, 8 and 12 updates, and on the PyBullet truth sets (every 6th
pair) 1.642 px at 6 against 1.685 at 12, while a pair at 160x120 takes about 45 ms instead of 80
on 2 cores (README, optical flow section; ``reports/flow_epe.md``)."""

METHODS = ("dis", "farneback", "raft", "gt")
"""Values of ``flow.method``; ``gt`` is the render stage's exact flow."""

DIS_PRESETS = {
    "ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
    "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
    "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
}
"""OpenCV DIS presets by name (speed/accuracy trade-off)."""


class FlowConfig(BaseModel):
    """Section ``flow`` of params.yaml.

    Attributes:
        method: ``dis`` | ``farneback`` | ``raft`` | ``gt`` (simulator truth, copied from the
            render; real videos, which have none, use ``dis``).
        preset: DIS preset, ``ultrafast`` | ``fast`` | ``medium`` (ignored by other methods).
        raft_weights: RAFT checkpoint file (the authors' ``raft-small.pth`` / ``raft-things.pth``
            or one trained here); ``None`` = the shipped ``pipeline/weights/raft-small-dynamics.pth``.
            A relative path is relative to the params file's folder.
        raft_iters: RAFT's GRU updates per frame pair (:data:`RAFT_ITERS`; 12 in the paper's evaluation).
        max_magnitude: flow magnitude (px) shown at full colour saturation by
            :func:`flow_to_rgb` (default 4 px, the model's inputs); ``None`` scales every call by
            its own maximum.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    method: Literal["dis", "farneback", "raft", "gt"] = "dis"
    preset: Literal["ultrafast", "fast", "medium"] = "medium"
    raft_weights: str | None = None
    raft_iters: int = Field(default=RAFT_ITERS, ge=1, le=32)
    max_magnitude: float | None = Field(default=4.0, gt=0, allow_inf_nan=False)

    @property
    def estimator(self) -> Literal["dis", "farneback", "raft"]:
        """The estimator that runs on frames: ``method``, except ``gt`` (no truth exists for
        frames that were not rendered, e.g. a real video), which falls back to ``dis``."""
        return "dis" if self.method == "gt" else self.method


# ---------------------------------------------------------------------------------------
# Colour coding
# ---------------------------------------------------------------------------------------

# Segment lengths of the Middlebury colour wheel, chosen for perceptual uniformity:
# red-yellow, yellow-green, green-cyan, cyan-blue, blue-magenta, magenta-red.
# Baker, Scharstein, Lewis, Roth, Black, Szeliski: "A Database and Evaluation Methodology
# for Optical Flow", IJCV 92(1), 2011 (colour coding of their flowToColor / colorcode.cpp).
_WHEEL_SEGMENTS = (("RY", 15), ("YG", 6), ("GC", 4), ("CB", 11), ("BM", 13), ("MR", 6))


def _colour_wheel() -> np.ndarray:
    """The Middlebury colour wheel: ``(55, 3)`` float RGB in [0, 255], hue going round."""
    ry, yg, gc, cb, bm, mr = (n for _, n in _WHEEL_SEGMENTS)
    wheel = np.zeros((ry + yg + gc + cb + bm + mr, 3))
    i = 0
    wheel[i:i + ry, 0] = 255
    wheel[i:i + ry, 1] = np.floor(255 * np.arange(ry) / ry)
    i += ry
    wheel[i:i + yg, 0] = 255 - np.floor(255 * np.arange(yg) / yg)
    wheel[i:i + yg, 1] = 255
    i += yg
    wheel[i:i + gc, 1] = 255
    wheel[i:i + gc, 2] = np.floor(255 * np.arange(gc) / gc)
    i += gc
    wheel[i:i + cb, 1] = 255 - np.floor(255 * np.arange(cb) / cb)
    wheel[i:i + cb, 2] = 255
    i += cb
    wheel[i:i + bm, 2] = 255
    wheel[i:i + bm, 0] = np.floor(255 * np.arange(bm) / bm)
    i += bm
    wheel[i:i + mr, 2] = 255 - np.floor(255 * np.arange(mr) / mr)
    wheel[i:i + mr, 0] = 255
    return wheel


_WHEEL = _colour_wheel()


def flow_to_rgb(flow: np.ndarray, max_magnitude: float | None = None) -> np.ndarray:
    """Colour-code flow with the Middlebury colour wheel (Baker et al., IJCV 2011).

    Hue gives the direction of motion, saturation its magnitude: zero flow is white,
    ``+x`` (rightwards) is red, ``+y`` (downwards) yellow-orange, ``-x`` cyan, ``-y``
    blue, exactly as the Middlebury ``flowToColor`` code, except that magnitudes above
    ``max_magnitude`` are clipped to full saturation (the original darkens them).

    Args:
        flow: ``(..., H, W, 2)`` float flow in px, ``(u, v)`` = (x, y) displacement.
            Non-finite values are shown as zero flow (white).
        max_magnitude: magnitude (px) shown at full saturation; ``None`` uses the largest
            magnitude in this call (all leading dimensions together), so a whole clip
            shares one scale.

    Returns:
        ``(..., H, W, 3)`` uint8 RGB.

    Raises:
        ValueError: ``flow`` does not end in a dimension of size 2, or ``max_magnitude <= 0``.
    """
    flow = np.asarray(flow)
    if flow.ndim < 3 or flow.shape[-1] != 2:
        raise ValueError(f"flow: must have shape (..., H, W, 2), got {flow.shape}")
    if max_magnitude is not None and not max_magnitude > 0:
        raise ValueError(f"max_magnitude: must be > 0, got {max_magnitude}")
    u = np.nan_to_num(flow[..., 0].astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    v = np.nan_to_num(flow[..., 1].astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    mag = np.hypot(u, v)
    scale = float(mag.max(initial=0.0)) if max_magnitude is None else float(max_magnitude)
    rad = np.clip(mag / max(scale, np.finfo(np.float64).eps), 0.0, 1.0)

    n = len(_WHEEL)
    angle = np.arctan2(-v, -u) / np.pi                 # in [-1, 1]; +x maps to 1
    fk = (angle + 1) / 2 * (n - 1)                     # fractional index into the wheel
    k0 = np.floor(fk).astype(np.int64)
    k1 = (k0 + 1) % n
    frac = (fk - k0)[..., None]
    col = (1 - frac) * _WHEEL[k0] / 255 + frac * _WHEEL[k1] / 255
    col = 1 - rad[..., None] * (1 - col)               # desaturate towards white
    return np.round(col * 255).astype(np.uint8)


# ---------------------------------------------------------------------------------------
# Estimators
# ---------------------------------------------------------------------------------------


def _grey(frames: np.ndarray) -> np.ndarray:
    """``(T, H, W, 3)`` uint8 RGB -> ``(T, H, W)`` uint8 luma (ITU-R BT.601 weights)."""
    weights = np.array([0.299, 0.587, 0.114], dtype=np.float32)
    return np.clip(np.rint(frames.astype(np.float32) @ weights), 0, 255).astype(np.uint8)


def estimate_flow(
    frames: np.ndarray,
    method: Literal["dis", "farneback", "raft"] = "dis",
    preset: Literal["ultrafast", "fast", "medium"] = "medium",
    raft_weights: str | Path | None = None,
    raft_iters: int = RAFT_ITERS,
) -> np.ndarray:
    """Forward optical flow between consecutive frames.

    Args:
        frames: ``(T, H, W, 3)`` uint8 RGB, ``T >= 2``.
        method: ``dis`` (OpenCV DIS, default), ``farneback`` or ``raft``. ``gt`` is not an
            estimator: the simulator's flow comes from the render stage.
        preset: DIS preset name (see :data:`DIS_PRESETS`); ignored by the others.
        raft_weights: RAFT checkpoint (None: the shipped weights); ``raft`` only.
        raft_iters: RAFT's GRU updates per pair; ``raft`` only.

    Returns:
        ``(T-1, H, W, 2)`` float32 flow in px: ``flow[t, y, x] = (u, v)`` moves pixel
        ``(x, y)`` of frame ``t`` to ``(x + u, y + v)`` in frame ``t + 1``.

    Raises:
        ValueError: bad shape/dtype, fewer than two frames, or an unknown method/preset.
        pipeline.raft.estimator.RaftWeightsError: ``raft`` with a missing or foreign checkpoint.
    """
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8:
        raise ValueError(f"frames: must be (T, H, W, 3) uint8, got {frames.shape} {frames.dtype}")
    if len(frames) < 2:
        raise ValueError(f"frames: need at least 2 frames, got {len(frames)}")
    if method == "raft":
        from pipeline.raft.estimator import RaftFlow   # torch is imported only when RAFT is used
        return RaftFlow.from_file(raft_weights, iters=raft_iters)(frames)
    grey = _grey(frames)
    out = np.empty((len(frames) - 1, *frames.shape[1:3], 2), dtype=np.float32)
    if method == "dis":
        if preset not in DIS_PRESETS:
            raise ValueError(f"preset: must be one of {sorted(DIS_PRESETS)}, got {preset!r}")
        dis = cv2.DISOpticalFlow_create(DIS_PRESETS[preset])
        for t in range(len(out)):
            out[t] = dis.calc(grey[t], grey[t + 1], None)
    elif method == "farneback":
        for t in range(len(out)):
            out[t] = cv2.calcOpticalFlowFarneback(
                grey[t], grey[t + 1], None, pyr_scale=0.5, levels=3, winsize=15,
                iterations=3, poly_n=5, poly_sigma=1.2, flags=0)
    elif method == "gt":
        raise ValueError("method: 'gt' flow comes from the render stage, not from frames")
    else:
        raise ValueError(f"method: must be one of ('dis', 'farneback', 'raft'), got {method!r}")
    return out


def flow_config(params) -> FlowConfig:
    """The validated ``flow`` section of ``params`` (:class:`pipeline.params.Params`), with a
    relative ``raft_weights`` made relative to the params file's folder.

    Raises:
        pipeline.params.ParamsError: the section is missing or invalid.
    """
    cfg = typed_section(params, "flow", FlowConfig, required=True)
    root = getattr(params, "root", None)
    if cfg.raft_weights is not None and root is not None and not Path(cfg.raft_weights).is_absolute():
        cfg = cfg.model_copy(update={"raft_weights": str(Path(root) / cfg.raft_weights)})
    return cfg


def flow_of(frames: np.ndarray, cfg: FlowConfig) -> np.ndarray:
    """:func:`estimate_flow` with the settings of a ``flow`` params section
    (:attr:`FlowConfig.estimator`: ``gt`` falls back to DIS).

    Args:
        frames: ``(T, H, W, 3)`` uint8 RGB.
        cfg: the section (:func:`flow_config` resolves its weights path).

    Returns:
        ``(T-1, H, W, 2)`` float32 px.
    """
    return estimate_flow(frames, method=cfg.estimator, preset=cfg.preset,
                         raft_weights=cfg.raft_weights, raft_iters=cfg.raft_iters)
