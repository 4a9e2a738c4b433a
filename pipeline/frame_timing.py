"""When the frames were really captured: dropped frames found from the objects' motion.

A video's container says its frames are evenly spaced at its frame rate. Many real videos are not:
a clip recorded at 30 fps and written at 25 fps by dropping every sixth frame (real clip
``dev/06``) still lasts as long, but every fifth frame interval spans two capture intervals. A
ball in flight then jumps twice as far in that interval, and a parabola fitted to evenly spaced
times bends, or the search fits a throw that no gravity explains.

A dropped frame leaves a signature no smooth motion has: in the interval where the frame is
missing, every moving object's image step is the **sum** of its neighbouring steps (the two
capture intervals it spans), where smooth motion makes it about their **mean**.
:func:`dropped_frames` tests both predictions on each moving object's centroid and keeps the
intervals where the sum wins by far for an object and loses for none. :func:`capture_rate` reads
the capture's rate from their spacing, :func:`regular_drops` adds the drops the objects could not
show (a conversion drops regularly), :func:`capture_times` turns them into capture times, and
:func:`nearest_frames` picks the frames nearest a regular time grid at that rate
(:func:`pipeline.video.resample` with repaired times): the observation is evenly spaced again,
with a neighbour standing in for each dropped frame.

Only dropped frames are repaired. A repeated frame (a clip written at a higher rate than captured)
is left to :func:`pipeline.video.resample`, whose regular grid at the scene rate skips repeats
when they alternate.
"""

from __future__ import annotations

import numpy as np

from pipeline.masks import touches_border, track_centroids

GAP_RATIO = 0.1
"""A frame interval is a drop for an object when predicting its step by the sum of the
neighbouring steps errs by less than this share of the error of predicting it by their mean.
The centroid's noise (about half a pixel) is all that separates a true drop from the sum. In the
main job's detection pass ``dev/06``'s three drops read 0.010, 0.019 and 0.064; of the 12 other
real clips tested there (those whose window is at the container's rate) one interval reads below
0.1 (0.091, dev/10, where the glider's mask changes for a frame: :data:`MIN_GAPS` keeps it out),
the next 0.144. On the rendered truth sets no window of 30 frames fires (0 of 360); with every
sixth frame dropped, 48 of 240 fire, on true drops only (objects at rest or slow show none)."""

MIN_GAPS = 2
"""Drops are repaired only when the window shows at least this many: a frame-rate conversion drops
frames regularly, while a single interval that fits the sum can be chance."""

MIN_STEP_PX = 2.0
"""px: neighbouring steps shorter than this (or a tenth of the object's diameter) are centroid
noise, not motion, and the interval is not tested."""


def _centroids(seg: np.ndarray, k: int) -> np.ndarray:
    """``(T, 2)`` centroid ``(x, y)`` px of object ``k`` per frame (:func:`pipeline.masks.track_centroids`);
    NaN also where its mask touches the frame's border (a cut mask's centroid moves with the cut,
    not the object)."""
    mask = seg == k
    out = track_centroids(mask)
    out[touches_border(mask)] = np.nan
    return out


def interval_ratios(seg: np.ndarray) -> dict[int, list[float]]:
    """Per frame interval ``i`` (frame ``i`` to ``i + 1``) of a clip, one ratio per object tested
    there: ``e_sum / e_mean`` (:func:`dropped_frames`), below 1 where the sum of the neighbouring
    steps predicts the step better than their mean. An object is tested where it is seen whole in
    frames ``i - 1 .. i + 2`` and both neighbouring steps are at least :data:`MIN_STEP_PX` (and a
    tenth of its diameter).

    Args:
        seg: ``(T, H, W)`` int object ids, -1 background.
    Returns:
        ``{interval: [ratio, ...]}`` for the tested intervals only.
    """
    seg = np.asarray(seg)
    votes: dict[int, list[float]] = {}
    if seg.ndim != 3 or len(seg) < 4:
        return votes
    for k in range(int(seg.max()) + 1):
        present = (seg == k).reshape(len(seg), -1).sum(axis=1)
        if not present.any():
            continue
        diameter = 2.0 * np.sqrt(np.median(present[present > 0]) / np.pi)
        min_step = max(MIN_STEP_PX, 0.1 * diameter)
        d = np.diff(_centroids(seg, k), axis=0)                  # (T-1, 2), NaN where unseen
        for i in range(1, len(d) - 1):
            a, b, c = d[i - 1], d[i], d[i + 1]
            if not (np.isfinite(a).all() and np.isfinite(b).all() and np.isfinite(c).all()):
                continue
            if min(np.linalg.norm(a), np.linalg.norm(c)) < min_step:
                continue
            e_sum = float(np.linalg.norm(b - (a + c)))
            e_mean = float(np.linalg.norm(b - 0.5 * (a + c)))
            votes.setdefault(i, []).append(e_sum / max(e_mean, 1e-9))
    return votes


def dropped_frames(seg: np.ndarray, min_gaps: int = MIN_GAPS, votes: dict[int, list[float]] | None = None
                   ) -> list[int]:
    """Frame intervals of a clip in which a captured frame is missing.

    Interval ``i`` (from frame ``i`` to ``i + 1``) is tested on every moving object
    (:func:`interval_ratios`): with ``e_sum = |d[i] - (d[i-1] + d[i+1])|`` and
    ``e_mean = |d[i] - (d[i-1] + d[i+1]) / 2|`` (``d`` the centroid's steps), the interval is a
    drop when ``e_sum < GAP_RATIO * e_mean`` for some object and ``e_sum <= e_mean`` for every
    tested one.

    Args:
        seg: ``(T, H, W)`` int object ids, -1 background, frames as the container spaces them.
        min_gaps: fewer drops than this in the clip are not trusted (:data:`MIN_GAPS`): none is
            returned.
        votes: :func:`interval_ratios` of ``seg`` when the caller has them already (None: computed).
    Returns:
        ascending interval indices ``i`` in ``0 .. T-2``; empty when none (or too few) is found.
    """
    votes = interval_ratios(seg) if votes is None else votes
    gaps = sorted(i for i, r in votes.items() if min(r) < GAP_RATIO and max(r) <= 1.0)
    return gaps if len(gaps) >= min_gaps else []


def regular_drops(gaps: list[int], n_intervals: int, fps: float, rate: float,
                  votes: dict[int, list[float]] | None = None) -> list[int]:
    """All the drops of a regular frame-rate conversion, from those found (:func:`dropped_frames`).

    Writing a ``rate`` capture at ``fps`` drops one frame every ``P = fps / (rate - fps)``
    container intervals (5 for 30 fps at 25), so a drop the objects could not show (at a bounce,
    near the top of an arc, with the object behind the border) still happened: one is put every
    ``P`` intervals before the first drop found, after the last, and between two found ``k P``
    apart; an interval whose tested objects all say no drop (every ratio of
    :func:`interval_ratios` above 1) takes none, its neighbour within one interval does.

    Args:
        gaps: drops found, ascending; n_intervals: frame intervals of the clip; fps: the
            container's rate; rate: the capture's (:func:`capture_rate`); votes:
            :func:`interval_ratios` of the clip (None: no interval says no).
    Returns:
        ascending interval indices, ``gaps`` among them.
    """
    if not gaps or rate <= fps:
        return sorted(gaps)
    period = fps / (rate - fps)
    votes = votes or {}

    def no_drop(i: int) -> bool:
        return i in votes and min(votes[i]) > 1.0

    out = set(gaps)

    def put(x: float) -> None:
        i = int(round(x))
        for j in (i, i - 1, i + 1):
            if 0 <= j < n_intervals and not no_drop(j) and all(abs(j - g) >= 0.5 * period for g in out):
                out.add(j)
                return

    anchors = sorted(gaps)
    x = anchors[0] - period
    while x > -0.5:
        put(x)
        x -= period
    for a, b in zip(anchors, anchors[1:]):
        k = int(round((b - a) / period))
        for j in range(1, k):
            put(a + j * (b - a) / k)
    x = anchors[-1] + period
    while x < n_intervals - 0.5:
        put(x)
        x += period
    return sorted(out)


STANDARD_RATES = (24.0, 25.0, 30.0, 48.0, 50.0, 60.0, 90.0, 100.0, 120.0, 240.0)
"""fps: the capture rates of cameras and video standards (film 24, PAL 25/50, NTSC 30/60, phones'
slow motion 120/240; 29.97 and 59.94 are within 0.1 % of 30 and 60). A rate read from a few drops is
snapped to the nearest of them within :data:`SNAP_TOLERANCE`."""

SNAP_TOLERANCE = 0.15
"""Relative distance within which :func:`capture_rate` snaps to a standard rate: a drop missed where
the object was not measurable (a bounce, the border) lengthens the spacing read, so a 30 fps capture
written at 25 fps with drops found 5 and 10 intervals apart reads 27.5 fps."""


def capture_rate(gaps: list[int], fps: float) -> float:
    """Frames per second of the capture behind a container at ``fps`` with frames dropped in the
    intervals ``gaps`` (:func:`dropped_frames`, at least two): a frame-rate conversion drops one
    frame every ``P`` container intervals, so ``P + 1`` captures span ``P`` container intervals
    (30 fps written at 25 fps: ``P = 5``, 30 fps). ``P`` is the median spacing of the drops, each
    spacing first divided by its multiple of the shortest (a drop missed where the object was not
    measurable, at a bounce or behind the border, doubles one spacing); the rate is then snapped to
    the nearest of :data:`STANDARD_RATES` above ``fps`` within :data:`SNAP_TOLERANCE`.

    Raises:
        ValueError: fewer than two gaps, or ``fps`` not positive.
    """
    if not fps > 0:
        raise ValueError(f"fps: must be > 0, got {fps}")
    if len(gaps) < 2:
        raise ValueError(f"gaps: need at least two to space them, got {list(gaps)}")
    spacing = np.diff(sorted(gaps)).astype(np.float64)
    period = float(np.median(spacing / np.maximum(np.rint(spacing / spacing.min()), 1.0)))
    rate = fps * (period + 1.0) / period
    above = [r for r in STANDARD_RATES if r > fps * 1.001 and abs(r / rate - 1.0) <= SNAP_TOLERANCE]
    return min(above, key=lambda r: abs(r / rate - 1.0)) if above else rate


def capture_times(n: int, gaps: list[int], rate: float) -> np.ndarray:
    """Capture times of ``n`` frames with one frame missing in each interval of ``gaps``, captured
    at ``rate`` frames per second (:func:`capture_rate`).

    Args:
        n: frames; gaps: interval indices (:func:`dropped_frames`); rate: the capture's rate, fps.
    Returns:
        ``(n,)`` float64 s since the first frame: ``(i + drops before frame i) / rate``.
    Raises:
        ValueError: ``rate`` not positive or a gap outside ``0 .. n-2``.
    """
    if not rate > 0:
        raise ValueError(f"rate: must be > 0, got {rate}")
    if any(not 0 <= g <= n - 2 for g in gaps):
        raise ValueError(f"gaps: must lie in 0..{n - 2}, got {list(gaps)}")
    skipped = np.zeros(n, dtype=np.int64)
    for g in gaps:
        skipped[g + 1:] += 1
    return (np.arange(n) + skipped) / float(rate)


def nearest_frames(times: np.ndarray, dst_fps: float, count: int) -> np.ndarray:
    """``(count,)`` int64 index of the frame captured nearest each time ``k / dst_fps`` of a regular
    grid (:func:`pipeline.video.resample` with repaired capture times ``times``, ``(n,)`` s,
    ascending). At the capture's own rate every grid time has its frame, except a dropped one,
    whose neighbour stands in for it (one frame shown twice, a time error of one capture interval,
    where the container's timing carries every later frame one interval late).

    Raises:
        ValueError: the grid runs past the last capture by more than half a grid step.
    """
    times = np.asarray(times, dtype=np.float64)
    if len(times) < 2:
        return np.zeros(count, dtype=np.int64)
    grid = np.arange(count) / float(dst_fps)
    if grid[-1] > times[-1] + 0.5 / dst_fps:
        raise ValueError(f"times: frames captured over {times[-1]:.3f} s, need {grid[-1]:.3f} s")
    right = np.clip(np.searchsorted(times, grid), 1, len(times) - 1)
    left = right - 1
    return np.where(grid - times[left] <= times[right] - grid, left, right).astype(np.int64)
