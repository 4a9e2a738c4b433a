"""Measurement noise of a clip, estimated from the data alone (no model)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipeline.discrepancy.trajectories import Clip
from pipeline.rotation import quat_conj, quat_mul, quat_to_rotvec


def local_quadratic(t: np.ndarray, y: np.ndarray, half: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre-sample residuals of quadratic fits over sliding windows of ``2 half + 1`` samples.

    Args:
        t: ``(T,)`` s. y: ``(T, d)`` values.

    Returns:
        ``(centres (K,), scaled residuals (K, d), slopes (K, d))``: residual of the centre
        sample divided by ``sqrt(1 - h)`` (``h``: its hat-matrix diagonal), so that its
        variance is the noise variance for any smooth signal; slope = fitted derivative.
    """
    T = len(t)
    w = 2 * half + 1
    if T < w:
        return np.zeros(0, int), np.zeros((0, y.shape[1])), np.zeros((0, y.shape[1]))
    centres = np.arange(half, T - half)
    res = np.empty((len(centres), y.shape[1]))
    slope = np.empty_like(res)
    for j, k in enumerate(centres):
        tt = t[k - half:k + half + 1] - t[k]
        A = np.stack([np.ones(w), tt, tt * tt], 1)
        pinv = np.linalg.pinv(A)
        coef = pinv @ y[k - half:k + half + 1]
        h = float((A @ pinv)[half, half])
        res[j] = (y[k] - coef[0]) / math.sqrt(max(1.0 - h, 1e-9))
        slope[j] = coef[1]
    return centres, res, slope


@dataclass
class Noise:
    """Measurement noise of one clip, estimated from the data alone.

    Attributes:
        position: m, standard deviation per observed coordinate.
        angle: rad, standard deviation per rotation-vector component (``None``: no
            orientation data).
        n_position, n_angle: number of values the estimates rest on.
    """

    position: float
    angle: float | None
    n_position: int
    n_angle: int


def estimate_noise(clip: Clip, floor_position: float = 1e-5, floor_angle: float = 1e-4) -> Noise:
    """Estimate the measurement noise of a clip without any model.

    Position: residual of each sample from a quadratic fitted to it and its 4 neighbours
    (scaled by ``1/sqrt(1-h)``), pooled over observed coordinates and objects; sigma =
    1.4826 * median absolute residual (a robust scale: impacts spoil only a few windows).
    Orientation (measured ``q exp(n)``, ``n`` per body axis): the differences of consecutive
    body-frame rotation increments ``log(q_k^-1 q_k+1)`` equal ``n_k+2 - 2 n_k+1 + n_k`` (to
    first order) plus angular acceleration times dt^2, so sigma = 1.4826 * MAD / sqrt(6).

    Args:
        clip: the clip.
        floor_position: m, smallest value returned (noise-free synthetic data).
        floor_angle: rad, likewise.

    Returns:
        :class:`Noise`.
    """
    pos_res, ang_res = [], []
    for tr in clip.tracks:
        _, res, _ = local_quadratic(tr.t, tr.pos[:, tr.axes])
        pos_res.append(res.ravel())
        if tr.quat is not None and len(tr.t) >= 3:
            inc = quat_to_rotvec(quat_mul(quat_conj(tr.quat[:-1]), tr.quat[1:]))
            ang_res.append(((inc[1:] - inc[:-1]) / math.sqrt(6.0)).ravel())
    pr = np.concatenate(pos_res) if pos_res else np.zeros(0)
    sp = 1.4826 * float(np.median(np.abs(pr))) if pr.size else floor_position
    sa, na = None, 0
    if ang_res:
        ar = np.concatenate(ang_res)
        na = ar.size
        sa = max(1.4826 * float(np.median(np.abs(ar - np.median(ar)))), floor_angle)
    return Noise(max(sp, floor_position), sa, int(pr.size), na)
