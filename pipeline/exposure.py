"""The camera's exposure: object masks swept over the time the shutter is open (motion blur).

A camera integrates light over its exposure time ``E`` (s), so a moving object's silhouette in a
frame is the region it covers during ``[t - E/2, t + E/2]``, not its outline at the instant
``t``: a ball falling at 3 m/s seen at 30 fps with the shutter open half a frame smears over 5
cm. Background subtraction and a segmenter see that smear. The simulator renders one instant
per frame, so a re-simulation of a fast object is thinner than the observation whatever its
trajectory (real drops: observed silhouettes 1.2-1.5 times the simulated ball's area,
docs/realvideo.md). The scene's ``camera.exposure`` (s, 0 = an instantaneous shutter, the
default) closes that gap in the masks the search scores.

Model (linear motion blur, the standard first-order model, e.g. Brostow & Essa, "Image-based
motion blur for stop motion animation", SIGGRAPH 2001): between frames an object's image moves
along the straight line joining its mask centroids, so the swept mask at frame ``t`` is the
union of the mask translated along the half-segment back to frame ``t - 1`` and the half-segment
forward to frame ``t + 1``, each over the fraction ``E * fps / 2`` of it. Piecewise-linear, so
a bounce between two frames sweeps back the way it came and forward the new way. Rotation and
perspective change within the exposure are ignored. Masks only: the RGB render and the exact
flow stay instantaneous.
"""

from __future__ import annotations

import math

import numpy as np

MAX_SHIFTS = 24
"""Most translated copies per half-segment: a step of at most 1 px up to a 24 px sweep, coarser beyond."""


def _shifted(mask: np.ndarray, dv: int, du: int) -> np.ndarray:
    """``mask (H, W) bool`` translated by ``(dv, du)`` whole px, no wrap-around."""
    H, W = mask.shape
    out = np.zeros_like(mask)
    if abs(dv) >= H or abs(du) >= W:
        return out
    out[max(dv, 0):H + min(dv, 0), max(du, 0):W + min(du, 0)] = \
        mask[max(-dv, 0):H + min(-dv, 0), max(-du, 0):W + min(-du, 0)]
    return out


def _centroids(seg: np.ndarray, k: int) -> list[np.ndarray | None]:
    out = []
    for frame in seg:
        v, u = np.nonzero(frame == k)
        out.append(np.array([v.mean(), u.mean()]) if len(v) else None)
    return out


def expose(seg: np.ndarray, exposure_frames: float) -> np.ndarray:
    """Object masks as a camera with a finite exposure records them (module docstring).

    Args:
        seg: ``(T, H, W)`` int8 object ids, -1 background, one instant per frame (a render).
        exposure_frames: the exposure as a fraction of the frame interval (``exposure * fps``),
            in [0, 1]; 0 returns ``seg`` unchanged.
    Returns:
        ``(T, H, W)`` int8: every object's mask swept along its centroid's path over
        ``[t - E/2, t + E/2]``; pixels an object covers at the instant keep their label, swept
        pixels take the first object (lowest id) that sweeps them. An object seen in one frame
        only, or not seen in the neighbouring frames, is not swept on that side (mirrored from
        the other side where it has one).
    Raises:
        ValueError: ``exposure_frames`` outside [0, 1] or ``seg`` not 3-D.
    """
    seg = np.asarray(seg)
    if seg.ndim != 3:
        raise ValueError(f"seg: must be (T, H, W), got shape {seg.shape}")
    if not 0.0 <= exposure_frames <= 1.0 or not math.isfinite(exposure_frames):
        raise ValueError(f"exposure_frames: must be in [0, 1] (exposure * fps), got {exposure_frames}")
    if exposure_frames == 0.0 or seg.size == 0:
        return seg
    out = seg.copy()
    T = len(seg)
    half = exposure_frames / 2.0
    for k in range(int(seg.max()) + 1):
        cs = _centroids(seg, k)
        for t in range(T):
            if cs[t] is None:
                continue
            back = cs[t - 1] - cs[t] if t > 0 and cs[t - 1] is not None else None
            fwd = cs[t + 1] - cs[t] if t + 1 < T and cs[t + 1] is not None else None
            back = -fwd if back is None and fwd is not None else back
            fwd = -back if fwd is None and back is not None else fwd
            if back is None:
                continue
            mask = seg[t] == k
            swept = np.zeros_like(mask)
            for d in (back, fwd):
                reach = half * d
                n = min(MAX_SHIFTS, int(math.ceil(float(np.abs(reach).max()))))
                for s in np.linspace(0.0, 1.0, n + 1)[1:]:
                    dv, du = np.round(s * reach).astype(int)
                    swept |= _shifted(mask, int(dv), int(du))
            out[t][swept & (out[t] < 0)] = k
    return out
