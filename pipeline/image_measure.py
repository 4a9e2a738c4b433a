"""Physical quantities measured on an observation's image tracks, to hold against what a clip
states (issue 29 item 8: physical truth where a clip gives it): gravity from a free fall, the
direction of motion on an incline.

A ball in free flight traces a parabola in the image: with the camera's image plane vertical and
the ball moving in a plane parallel to it, its image row is ``y(t) = y0 + vy t + (g / 2) t^2 / s``
where ``s`` is the scale in m per px in that plane. So a clip with a true frame rate and a known
scale (a ruler in the ball's plane, or a scale the clip's source states) gives ``g`` from the
observation alone, before anything is fitted to it; and a clip whose observation is wrong gives a
wrong ``g``. Bounces split the flight into arcs (:func:`flight_arcs`), each fitted on its own.

An object moving along an incline seen from the side moves along the incline's image line, so
the angle of its centroid path in the image (:func:`path_angle`) can be held against the
incline's edge read on a frame.

Usage::

    t, x, y = image_track(obs_seg, crop, size, source_frames, source_fps)
    fit = fit_gravity(t, y, m_per_px)          # dict: g, arcs, ...
    angle = path_angle(x, y)                   # deg above the image horizontal
"""

from __future__ import annotations

import math

import numpy as np

MIN_ARC_SAMPLES = 5
"""Fewest frames an arc needs to be fitted (a parabola has 3 parameters; 5 leave 2 for the residual)."""


def moving_label(seg: np.ndarray) -> int:
    """The object of ``seg (T, H, W)`` (int ids, -1 background) whose centroid travels farthest
    from where it is first seen, px (the one a clip's free fall or incline is about); 0 when none
    is seen in two frames."""
    best, far = 0, -1.0
    for k in range(int(seg.max()) + 1 if seg.size else 0):
        c = [np.argwhere(f == k).mean(axis=0) for f in seg if (f == k).any()]
        if len(c) >= 2:
            d = float(np.linalg.norm(np.asarray(c) - c[0], axis=1).max())
            if d > far:
                best, far = k, d
    return best


def image_track(seg: np.ndarray, crop, size, source_frames: np.ndarray, source_fps: float,
                label: int | None = None, times: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The centroid of one observed object over the window, in px of the original frame.

    Args:
        seg: ``(T, H, W)`` int object ids at the working size, -1 background (``observation.npz``).
        crop: ``[x, y, w, h]`` px of the original frame the working frames were cut from.
        size: ``[W, H]`` working size, px.
        source_frames: ``(T,)`` int source-frame index of each working frame.
        source_fps: the clip's true frame rate, frames per second.
        label: the object; None takes :func:`moving_label`'s.
        times: ``(T,)`` s since the first frame, when the window's frames were picked by capture time
            (``observation.npz`` ``times``, :func:`pipeline.observe.retimed`); None: from the
            source-frame indices and the rate.
    Returns:
        ``(t, x, y)``: ``(N,)`` float64 s since the window's first frame (from the source-frame
        indices and the true rate), and the centroid's column and row in original px (pixel
        centres at integer + 0.5), over the N frames where the object is seen whole (a mask that
        touches the border of the working frame is cut, and its centroid biased: left out; so is a
        mask identical to the frame before, which background subtraction's
        :func:`pipeline.masks.hold_resting` held rather than measured).
    Raises:
        ValueError: no object in ``seg``.
    """
    seg = np.asarray(seg)
    if not seg.size or not (seg >= 0).any():
        raise ValueError("seg: no observed object")
    cx0, cy0, cw, ch = (float(v) for v in crop)
    W, H = (float(v) for v in size)

    def track(k: int):
        ts, xs, ys = [], [], []
        for i in range(len(seg)):
            if i and np.array_equal(seg[i] == k, seg[i - 1] == k):   # held (hold_resting), not measured
                continue
            rr, cc = np.nonzero(seg[i] == k)
            if rr.size and rr.min() > 0 and cc.min() > 0 and rr.max() < seg.shape[1] - 1 \
                    and cc.max() < seg.shape[2] - 1:   # cut by the frame's edge: its centroid is biased
                ts.append(float(times[i]) if times is not None else
                          (int(source_frames[i]) - int(source_frames[0])) / float(source_fps))
                xs.append(cx0 + (cc.mean() + 0.5) * cw / W)
                ys.append(cy0 + (rr.mean() + 0.5) * ch / H)
        return np.array(ts), np.array(xs), np.array(ys)

    return track(moving_label(seg) if label is None else label)


def flight_arcs(t: np.ndarray, y: np.ndarray) -> list[np.ndarray]:
    """Indices of the free-flight arcs of an image-row track ``y (N,)`` (rows grow downward) at
    times ``t (N,)``: the track is cut after every bounce, a sample lower in the image than both
    neighbours (a local maximum of ``y``) where the motion turns from falling to rising, and
    where more than 3 frame intervals pass between two samples. The bounce frame itself (the ball
    in contact, deformed) belongs to neither arc. Arcs shorter than :data:`MIN_ARC_SAMPLES` are
    dropped.

    Returns:
        list of ``(n,)`` int64 index arrays, in time order.
    """
    t, y = np.asarray(t, float), np.asarray(y, float)
    if len(t) < MIN_ARC_SAMPLES:
        return []
    dt = np.median(np.diff(t))
    spans, start = [], 0
    for i in range(1, len(y)):
        if t[i] - t[i - 1] > 3.0 * dt:                              # frames missing: a new arc
            spans.append((start, i))
            start = i
        elif i < len(y) - 1 and y[i] >= y[i - 1] and y[i] > y[i + 1]:   # a bounce
            spans.append((start, i))                                 # the contact frame is in neither arc
            start = i + 1
    spans.append((start, len(y)))
    arcs = [np.arange(a, b) for a, b in spans if b - a >= MIN_ARC_SAMPLES]
    return arcs


def fit_gravity(t: np.ndarray, y: np.ndarray, m_per_px: float) -> dict:
    """Gravity from an image-row track of a ball in free flight (module docstring).

    Each arc (:func:`flight_arcs`) is fitted by least squares with ``y = a + b t + c t^2``
    (``numpy.polyfit``); its ``g = 2 c m_per_px``. The clip's value is the mean of the arcs'
    weighted by their samples.

    Args:
        t: ``(N,)`` s; y: ``(N,)`` image rows, px (down); m_per_px: scale in the ball's plane, m/px.
    Returns:
        dict: ``g`` (m/s^2, NaN when no arc has :data:`MIN_ARC_SAMPLES` samples), ``arcs``
        (per arc: ``samples``, ``t0``, ``t1`` (s), ``g`` (m/s^2), ``rms_px`` (fit residual)).
    """
    t, y = np.asarray(t, float), np.asarray(y, float)
    arcs = []
    for idx in flight_arcs(t, y):
        c2, c1, c0 = np.polyfit(t[idx] - t[idx[0]], y[idx], 2)
        res = y[idx] - np.polyval([c2, c1, c0], t[idx] - t[idx[0]])
        arcs.append({"samples": int(len(idx)), "t0": float(t[idx[0]]), "t1": float(t[idx[-1]]),
                     "g": float(2.0 * c2 * m_per_px), "rms_px": float(np.sqrt(np.mean(res ** 2)))})
    n = sum(a["samples"] for a in arcs)
    g = sum(a["g"] * a["samples"] for a in arcs) / n if n else math.nan
    return {"g": float(g), "arcs": arcs}


FLIGHT_OUTLIER = 2.5
"""A sample whose residual exceeds this many tolerances leaves the joint fit of :func:`fit_flight`
(a ball still in the hand, a blurred or merged silhouette): about 3 sigma of a track's noise, as
the tolerance (:func:`pipeline.image_tracks.fit_tolerance`) is about 2 sigma where its jitter
term leads."""


def fit_flight(t: np.ndarray, y: np.ndarray, tol: float, min_samples: int = 8,
               x: np.ndarray | None = None) -> dict | None:
    """One image acceleration for every free-flight arc of a track at once.

    A ball in free flight has the same acceleration in every arc between bounces, so the arcs
    (:func:`flight_arcs`) are fitted together by least squares with one shared curvature and an
    intercept and slope per arc: ``y = c_k + b_k t + a t^2 / 2`` for arc ``k`` (the model of
    :func:`pipeline.image_tracks.first_bounce`, over the whole track). With the columns ``x``
    given, each arc also moves along them at its own constant speed, ``x = d_k + e_k t`` (no
    force acts sideways in flight; a bounce may change the speed), and a sample's residual is
    the distance between it and the fit in the image. Samples that do not fit are trimmed one at
    a time, worst first, while a residual exceeds ``FLIGHT_OUTLIER * tol``; an arc left with
    fewer than 3 samples leaves the fit.

    Args:
        t: ``(N,)`` s, increasing; y: ``(N,)`` image rows, px (down); tol: residual of a good
            fit, px; min_samples: fewest samples the fit must keep; x: ``(N,)`` image columns,
            px, or None (rows only).
    Returns:
        dict: ``a`` (px/s^2, down positive), ``a_sd`` (its standard deviation from the residual,
        px/s^2), ``n`` (samples kept), ``rms`` (px), ``kept`` (``(n,)`` int64 indices into ``t``),
        ``v0`` (px) and ``vel0`` (px/s): the first kept arc's row and vertical velocity
        extrapolated to ``t = 0``, ``arcs``: per arc kept, in time order, ``t0``, ``t1`` (s, its
        first and last kept sample), ``n`` (samples) and ``x_speed`` (px/s along ``x``; None
        without ``x``); None with fewer than ``min_samples`` kept samples or a singular fit.
    """
    t, y = np.asarray(t, float), np.asarray(y, float)
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    arcs = flight_arcs(t / dt, y)   # in frame intervals: a gap is counted in frames
    if not arcs or sum(len(a) for a in arcs) < min_samples:
        return None
    idx = np.concatenate(arcs)
    arc_of = np.concatenate([np.full(len(a), k) for k, a in enumerate(arcs)])
    keep = np.ones(len(idx), bool)
    while True:
        live = np.bincount(arc_of[keep], minlength=len(arcs)) >= 3
        use = keep & live[arc_of]
        if int(use.sum()) < min_samples:
            return None
        tt = t[idx[use]]
        cols = [0.5 * tt ** 2]
        for k in np.flatnonzero(live):
            on = (arc_of[use] == k).astype(np.float64)
            cols += [on, on * tt]
        A = np.stack(cols, axis=1)
        coef, _, rank, _ = np.linalg.lstsq(A, y[idx[use]], rcond=None)
        if rank < A.shape[1]:
            return None
        res = A @ coef - y[idx[use]]
        dist = np.abs(res)
        cx = None
        if x is not None:   # the same arcs, a line each: every column but the curvature's
            cx, *_ = np.linalg.lstsq(A[:, 1:], np.asarray(x, float)[idx[use]], rcond=None)
            dist = np.hypot(res, A[:, 1:] @ cx - np.asarray(x, float)[idx[use]])
        worst = int(np.argmax(dist))
        if dist[worst] <= FLIGHT_OUTLIER * tol:
            break
        keep[np.flatnonzero(use)[worst]] = False
    dof = len(res) - A.shape[1]
    a_sd = math.inf if dof <= 0 else float(np.sqrt(np.sum(res ** 2) / dof * np.linalg.inv(A.T @ A)[0, 0]))
    live_arcs = np.flatnonzero(live)
    arcs_out = [{"t0": float(t[idx[use & (arc_of == k)]][0]), "t1": float(t[idx[use & (arc_of == k)]][-1]),
                 "n": int((use & (arc_of == k)).sum()),
                 "x_speed": None if cx is None else float(cx[2 * j + 1])} for j, k in enumerate(live_arcs)]
    return {"a": float(coef[0]), "a_sd": a_sd, "n": int(len(res)), "rms": float(np.sqrt(np.mean(res ** 2))),
            "kept": idx[use].astype(np.int64), "v0": float(coef[1]), "vel0": float(coef[2]), "arcs": arcs_out}


def path_angle(x: np.ndarray, y: np.ndarray) -> float:
    """Angle of a centroid path in the image, deg in [0, 90]: the principal direction of the
    points ``(x, y) (N,)`` px (total least squares, the largest singular vector of the centred
    points) against the image rows, unsigned (a path rising to the left or to the right gives
    the same angle). NaN with fewer than 3 points or no spread."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    if len(x) < 3:
        return math.nan
    pts = np.stack([x - x.mean(), y - y.mean()], axis=1)
    if not np.any(pts):
        return math.nan
    _, _, vt = np.linalg.svd(pts, full_matrices=False)
    dx, dy = vt[0]
    return float(math.degrees(math.atan2(abs(dy), abs(dx))))
