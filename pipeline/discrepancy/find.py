"""Find: the motion phase of every measured sample and the residual segments where a model
leaves the measurements beyond their noise."""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy import ndimage
from scipy.stats import chi2

from pipeline.discrepancy.config import DiscrepancyConfig
from pipeline.discrepancy.noise import Noise, local_quadratic
from pipeline.discrepancy.trajectories import Clip, Track
from pipeline.rotation import quat_conj, quat_mul, quat_to_mat, quat_to_rotvec


PHASES = ("flight", "contact", "sliding", "rolling", "rest")


def _velocities(tr: Track) -> np.ndarray:
    """``(T, 3)`` m/s velocity from local quadratic fits (ends: nearest window)."""
    centres, _, slope = local_quadratic(tr.t, tr.pos)
    if not len(centres):
        return np.gradient(tr.pos, tr.t, axis=0)
    v = np.empty_like(tr.pos)
    idx = np.clip(np.arange(len(tr.t)), centres[0], centres[-1]) - centres[0]
    v[:] = slope[idx]
    return v


def _measured_omega(tr: Track) -> np.ndarray:
    """``(T, 3)`` rad/s world-frame angular velocity from measured orientations."""
    inc = quat_to_rotvec(quat_mul(tr.quat[1:], quat_conj(tr.quat[:-1]))) / np.diff(tr.t)[:, None]
    w = np.empty((len(tr.t), 3))
    w[0], w[-1] = inc[0], inc[-1]
    w[1:-1] = 0.5 * (inc[1:] + inc[:-1])
    return w


def motion_phases(clip: Clip, sim_qpos: np.ndarray, sim_omega: np.ndarray, noise: Noise,
                  cfg: DiscrepancyConfig) -> list[np.ndarray]:
    """Motion phase of every measured sample: flight, contact, sliding, rolling or rest.

    On the floor = the object's lowest point (measured centre minus its support height for
    the measured orientation, or the fitted base model's where none is measured) within
    ``max(contact_tolerance, 3 sigma)`` of z = 0. Contact = an impact: arriving on the floor,
    or a minimum of height where the vertical velocity turns from down to up (bounces shorter
    than a frame), plus the samples on either side. Rest = on the floor slower than
    ``rest_speed``. Rolling = on the floor with the contact point's slip speed
    ``|v + omega x (-h z)|`` below ``max(rest_speed, 0.2 |v|)`` (omega measured, else from the
    fitted base model); sliding otherwise. Flight = not on the floor.

    Args:
        clip: measured clip.
        sim_qpos: ``(T, n, 7)`` base-model states at ``clip.times``.
        sim_omega: ``(T, n, 3)`` base-model angular velocities, rad/s.
        noise: the clip's noise estimate.
        cfg: thresholds.

    Returns:
        Per track an array ``(T_i,)`` of phase names.
    """
    out = []
    tol = max(cfg.contact_tolerance, 3.0 * noise.position)
    for i, tr in enumerate(clip.tracks):
        idx = np.searchsorted(clip.times, tr.t)
        quat = tr.quat if tr.quat is not None else sim_qpos[idx, i, 3:]
        omega = _measured_omega(tr) if tr.quat is not None else sim_omega[idx, i]
        hc = tr.spec.support_height(quat_to_mat(quat))
        z = tr.pos[:, 2] if tr.axes[2] else sim_qpos[idx, i, 2]
        h = z - hc
        v = _velocities(tr)
        on = h < tol
        speed = np.linalg.norm(v[:, tr.axes], axis=1)
        slip_v = v + np.cross(omega, np.stack([np.zeros_like(hc), np.zeros_like(hc), -hc], 1))
        slip = np.linalg.norm(slip_v[:, :2], axis=1)
        phase = np.where(~on, "flight", np.where(speed < cfg.rest_speed, "rest",
                         np.where(slip < np.maximum(cfg.rest_speed, 0.2 * speed), "rolling", "sliding")))
        phase = phase.astype(object)
        hit = np.zeros(len(tr.t), bool)       # impacts: arriving on the floor, or a bounce at k
        hit[1:] = on[1:] & ~on[:-1]
        hit[1:-1] |= ((h[1:-1] <= h[:-2]) & (h[1:-1] <= h[2:]) & (v[:-2, 2] < -cfg.rest_speed)
                      & (v[2:, 2] > cfg.rest_speed)
                      & (h[1:-1] < tol + np.abs(v[:-2, 2]) * (tr.t[1:-1] - tr.t[:-2])))
        phase[sliding_window_view(np.pad(hit, 1), 3).any(axis=1)] = "contact"   # and the samples on either side
        out.append(phase.astype(str))
    return out


def residual_segments(clip: Clip, qpos: np.ndarray, noise: Noise, phases: Sequence[np.ndarray],
                      cfg: DiscrepancyConfig) -> list[dict[str, Any]]:
    """Time ranges where the model's residual exceeds the measurement noise.

    Samples are flagged in windows of ``segment_window`` consecutive samples whose summed
    squared residual over sigma^2 exceeds the chi-square quantile ``1 - segment_p`` (degrees
    of freedom: window length times observed coordinates, or 3 for orientation), so both
    single outliers and small systematic offsets that persist are found; runs of flagged
    samples of at least ``min_segment_samples`` form a segment. ``threshold`` is the RMS
    residual at which a window is flagged.

    Args:
        clip: measured clip.
        qpos: ``(T, n, 7)`` model states at ``clip.times``.
        noise: the clip's noise.
        phases: per track phase names (:func:`motion_phases`).
        cfg: thresholds.

    Returns:
        Dicts ``{clip, object, channel ('position' | 'orientation'), t_start, t_end (s, clip
        time), n_samples, phase (most frequent), phases ({phase: count}), max (m or deg),
        rms (m or deg), threshold (m or deg)}``.
    """
    segs = []
    for i, tr in enumerate(clip.tracks):
        idx = np.searchsorted(clip.times, tr.t)
        chans = [("position", np.linalg.norm((qpos[idx, i, :3] - tr.pos)[:, tr.axes], axis=1),
                  noise.position, int(tr.axes.sum()), 1.0)]
        if tr.quat is not None and noise.angle:
            err = np.linalg.norm(quat_to_rotvec(quat_mul(quat_conj(qpos[idx, i, 3:]), tr.quat)), axis=1)
            chans.append(("orientation", err, noise.angle, 3, 180.0 / math.pi))
        for name, e, sigma, dof, unit in chans:
            w = min(cfg.segment_window, len(e))
            thr = sigma * math.sqrt(chi2.isf(cfg.segment_p, w * dof) / w)
            z = (e / sigma) ** 2
            hot = sliding_window_view(z, w).sum(axis=1) > chi2.isf(cfg.segment_p, w * dof)  # window k..k+w-1
            flag = sliding_window_view(np.pad(hot, w - 1), w).any(axis=1)   # every sample of a flagged window
            runs, _ = ndimage.label(flag)
            for (run,) in ndimage.find_objects(runs):
                k, j = run.start, run.stop - 1
                if j - k + 1 >= cfg.min_segment_samples:
                    ph, counts = np.unique(phases[i][k:j + 1], return_counts=True)
                    segs.append({"clip": clip.name, "object": tr.object, "channel": name,
                                 "t_start": round(float(tr.t[k] + clip.t0), 4),
                                 "t_end": round(float(tr.t[j] + clip.t0), 4), "n_samples": int(j - k + 1),
                                 "phase": str(ph[np.argmax(counts)]),
                                 "phases": {str(p): int(c) for p, c in zip(ph, counts)},
                                 "max": float(e[k:j + 1].max() * unit),
                                 "rms": float(np.sqrt(np.mean(e[k:j + 1] ** 2)) * unit),
                                 "threshold": float(thr * unit)})
                k = j + 1
    return segs
