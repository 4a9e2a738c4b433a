"""Measurement noise of a clip, estimated from the data alone (no model)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scipy.stats import chi2

from pipeline.discrepancy.trajectories import MIN_SAMPLES, Clip, Track
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


OUTLIER_NEIGHBOURS = 6
"""Samples on either side of a sample (the six nearest, at least one on each side) through which
:func:`find_outliers` fits the quadratic that predicts it."""
OUTLIER_SMOOTH_P = 1e-3
"""Tail probability below which the neighbours' own quadratic fit is not smooth (a bounce or
another outlier among them): the sample is then kept."""


def find_outliers(t: np.ndarray, y: np.ndarray, sigma: float, threshold: float) -> np.ndarray:
    """Isolated outliers of a smooth track, found without any model.

    Each interior sample is predicted by a least-squares quadratic through its
    :data:`OUTLIER_NEIGHBOURS` nearest neighbours (itself left out, at least one on each side).
    It is an outlier when, on some coordinate, it lies more than ``threshold`` prediction
    standard deviations ``s sqrt(1 + a^T (A^T A)^-1 a)`` from that prediction (``s`` the
    larger of ``sigma`` and the neighbours' scatter about their quadratic) while the
    neighbours themselves fit the quadratic within the noise (on every coordinate their
    chi-square, 3 degrees of freedom, below its :data:`OUTLIER_SMOOTH_P` tail quantile): a spike in smooth motion. A bounce, a kink or a
    second outlier among the neighbours spoils their fit, so such a sample is kept (a bounce's
    lowest sample lies on the arm it belongs to; a V through it is no quadratic). Applied
    twice, so that of two outliers close together the second is found once the first is out.

    Args:
        t: ``(T,)`` s, strictly increasing. y: ``(T, d)`` positions, m.
        sigma: m, noise standard deviation per coordinate (robust estimate).
        threshold: prediction standard deviations (e.g. 6).

    Returns:
        ``(T,)`` bool, True for an outlier.
    """
    T = len(t)
    out = np.zeros(T, bool)
    w = OUTLIER_NEIGHBOURS
    if T < w + 1 or sigma <= 0 or threshold <= 0:
        return out
    smooth = float(chi2.isf(OUTLIER_SMOOTH_P, w - 3))
    for _ in range(2):
        keep = np.flatnonzero(~out)
        found = False
        for j in range(1, len(keep) - 1):
            lo = int(np.clip(j - w // 2, 0, len(keep) - 1 - w))
            nb = [i for i in range(lo, lo + w + 1) if i != j][:w]
            if j - nb[0] < 1 or nb[-1] - j < 1:
                continue
            k, idx = keep[j], keep[nb]
            tt = t[idx] - t[k]
            A = np.stack([np.ones(w), tt, tt * tt], 1)
            coef, *_ = np.linalg.lstsq(A, y[idx], rcond=None)
            ss = np.sum((A @ coef - y[idx]) ** 2, axis=0)                     # per coordinate
            if float(np.max(ss)) / sigma ** 2 > smooth:
                continue
            # the larger of the noise and the neighbours' own scatter about their quadratic
            scale = np.maximum(sigma, np.sqrt(ss / (w - 3)))
            sd = scale * math.sqrt(1.0 + float(np.linalg.inv(A.T @ A)[0, 0]))
            if bool(np.any(np.abs(y[k] - coef[0]) > threshold * sd)):
                out[k] = found = True
        if not found:
            break
    return out


def drop_outliers(clip: Clip, threshold: float) -> tuple[Clip, dict[str, list[float]]]:
    """The clip without the outliers :func:`find_outliers` finds in its tracks' observed
    coordinates (noise from :func:`estimate_noise` of the clip as given).

    Args:
        clip: the clip. threshold: prediction standard deviations (0: nothing is dropped).

    Returns:
        ``(clip, dropped)``: the cleaned clip (the input is not modified; unchanged and the same
        object where nothing is dropped) and ``{object: [times of the dropped samples, s]}``
        for the objects that lost samples. A track keeps at least
        :data:`pipeline.discrepancy.trajectories.MIN_SAMPLES` samples (else nothing is dropped
        from it).
    """
    if threshold <= 0:
        return clip, {}
    sigma = estimate_noise(clip).position
    tracks, dropped = [], {}
    for tr in clip.tracks:
        bad = find_outliers(tr.t, tr.pos[:, tr.axes], sigma, threshold)
        if not bad.any() or (~bad).sum() < MIN_SAMPLES:
            tracks.append(tr)
            continue
        keep = ~bad
        dropped[tr.object] = [float(x) for x in tr.t[bad]]
        tracks.append(Track(tr.object, tr.t[keep], tr.pos[keep], None if tr.quat is None else tr.quat[keep],
                            tr.axes, tr.spec))
    if not dropped:
        return clip, {}
    return Clip(clip.name, clip.source, tracks, clip.t0, clip.z_offset, clip.static), dropped
