"""Object tracks in the image and their motion in pixels: the first half of the perception
proposals (:mod:`pipeline.perception` lifts them to metric scenes).

1. **Detect and track** (:func:`find_tracks`, :func:`object_tracks`, :func:`still_tracks`):
   labelled masks (background subtraction, :func:`pipeline.masks.pseudo_masks`, connected
   components, frame-to-frame Hungarian assignment, :func:`pipeline.masks.label_objects`, or the
   segmenter's); a track must move somewhere in the window (optical-flow magnitude inside its
   mask), so static clutter that the background model missed is dropped, while an object that
   comes to rest stays a track. Per track: centroid, area, bottom row, rotated bounding box
   (OpenCV ``minAreaRect``) and a silhouette class (circle or rectangle, from the fill ratio of
   the rotated box: ``pi / 4`` for a disc, 1 for a rectangle).
2. **Initial motion** (:func:`initial_motion`): a quadratic fitted in time to the first frames
   of each track, grown until the fit stops explaining the track (a bounce, a collision), gives
   position, velocity and acceleration in px at ``t = 0``; :func:`bounce_restitution` reads the
   restitution of a bounce.
3. **Gravity in the image** (:func:`estimate_view`): gravity shows when some stretch of a track
   (:func:`gravity_motion`) accelerates downwards while speeding up (a fall, a roll down a
   slope): then the view is a *side* view; otherwise objects move in the ground plane and the
   view is *top-down*.

Conventions: pixel coordinates as in :mod:`pipeline.camera` (u right, v down, px); times in s
from the first frame of the window.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

import cv2
import numpy as np

from pipeline.image_measure import fit_flight

CIRCLE_FILL, BOX_FILL = 0.80, 0.93
"""Fill ratios of the rotated box below which a silhouette is surely a disc, above which surely
a rectangle; in between (small or blurred silhouettes) both are tried."""

ELONGATED = 2.0
"""Elongation (:attr:`Track.elongation`) from which a silhouette is not round: no sphere, nor a
disc seen end-on, makes it. A sphere's outline under a pinhole camera is an ellipse of aspect
``1 / cos(theta)``, ``theta`` its centre's angle off the optical axis (the image of a sphere
is a conic: Hartley & Zisserman, *Multiple View Geometry*, 2nd ed.): 1.23 at the corner of a
4:3 view 60 deg wide. Motion blur stretches a moving ball's silhouette along its path only in
its fast frames, and a silhouette of a few pixels is one pixel off either way, so a ratio of 2
in most frames is neither (measured, not tuned: rendered spheres, median ratio <= 1.51 on 80
tracks; real balls, lower quartile 1.03-1.46 on 10 clips; `docs/realvideo.md`)."""



# --------------------------------------------------------------------------------- tracks
@dataclass
class Track:
    """One object followed through the window.

    Attributes:
        label: its id in the segmentation (0, 1, ...).
        frames: ``(N,)`` int frame indices where it is visible.
        centre: ``(N, 2)`` float64 centroid (u, v), px.
        area: ``(N,)`` float64 px.
        bottom: ``(N,)`` float64 lowest row of the mask (largest v), px.
        diameter: median short side of the rotated bounding box over frames not touching the
            border, px (motion blur stretches the long side only).
        size: median ``(long, short)`` side of the rotated box, px.
        angle: rotation of the box's long side from +u towards -v (counter-clockwise as seen),
            deg in (-90, 90].
        fill: median area / (long * short); ``pi/4 = 0.785`` for a disc, 1 for a rectangle.
        elongation: lower quartile of ``long / short`` over the frames not touching the border
            (1.0 where there are none): the ratio in the frames least stretched by motion blur;
            from :data:`ELONGATED` up the silhouette is not round.
        shape: ``"circle"`` or ``"rectangle"`` (fill above the middle of :data:`CIRCLE_FILL` and
            :data:`BOX_FILL`, or elongated).
        moving: the largest flow magnitude inside the mask over the window, px/frame.
        travel: largest distance of the centroid from its first position, px.
        clipped: ``(N,)`` bool, the mask touches the image border in that frame: part of the
            object is outside the view, so its centroid and bottom are biased inwards (None:
            not recorded).
        ellipse: upper quartile over the frames not touching the border of the IoU between the
            silhouette and its least-squares ellipse (:func:`silhouette_fit`): the frames least
            spoiled by blur, occlusion and segmentation error; NaN where not measured. A
            sphere's outline is an ellipse, whatever the view.
        polygon: the same for its convex polygon of few corners (:func:`silhouette_fit`):
            higher than ``ellipse`` for the corners of a box.
        tall: median over the frames not touching the border of the mask's vertical extent
            (rows spanned), px (the median, like ``size``: background subtraction cuts a slowing
            object into crescents, which a lower quartile would read); NaN where there are none.
    """

    label: int
    frames: np.ndarray
    centre: np.ndarray
    area: np.ndarray
    bottom: np.ndarray
    diameter: float
    size: tuple[float, float]
    angle: float
    fill: float
    shape: Literal["circle", "rectangle"]
    moving: float
    travel: float = 0.0
    clipped: np.ndarray | None = None
    elongation: float = 1.0
    ellipse: float = math.nan
    polygon: float = math.nan
    tall: float = math.nan


def whole_frames(track: Track, min_frames: int = 3) -> Track:
    """The track restricted to the frames where its silhouette is not cut by the image border.

    A ball entering from the top edge, or leaving at the bottom, shows a part of itself whose
    centroid lags the true centre by up to a radius; fitted as a parabola, a few such frames
    at the start of a fall double its image acceleration (dev/03: 2776 px/s^2 against 1350
    from the whole frames). Motion fits (:func:`initial_motion`, :func:`gravity_motion`,
    :func:`initial_state_given`, :func:`bounce_restitution`) therefore read whole frames.

    Returns:
        a copy with ``frames``, ``centre``, ``area``, ``bottom``, ``clipped`` of the whole
        frames only; the track itself when fewer than ``min_frames`` frames are whole or
        ``clipped`` is not recorded.
    """
    if track.clipped is None or not track.clipped.any():
        return track
    keep = ~track.clipped
    if int(keep.sum()) < min_frames:
        return track
    return replace(track, frames=track.frames[keep], centre=track.centre[keep], area=track.area[keep],
                   bottom=track.bottom[keep], clipped=track.clipped[keep])


def _box_stats(mask: np.ndarray) -> tuple[float, float, float] | None:
    pts = cv2.findNonZero(mask.astype(np.uint8))
    if pts is None or len(pts) < 3:
        return None
    (_, _), (w, h), ang = cv2.minAreaRect(pts)
    w, h = w + 1.0, h + 1.0  # pixel extents, not centre-to-centre
    if w < h:
        w, h, ang = h, w, ang + 90.0
    ang = -ang  # OpenCV's angle is clockwise in image coordinates (v down)
    ang = (ang + 90.0) % 180.0 - 90.0
    return float(w), float(h), float(ang)


ELLIPSE_FIT = 0.90
"""Ellipse IoU (:attr:`Track.ellipse`) below which a silhouette is not the outline of a sphere.
The image of a sphere under a pinhole camera is an ellipse (a conic; Hartley & Zisserman,
*Multiple View Geometry*, 2nd ed.), so only rasterisation, blur and segmentation error keep the
fit below 1. Measured on the dev and dev2 splits of both engines (`docs/observation.md`, "Shape
from the silhouette"; the held-out splits were not looked at): on the true masks spheres reach
0.93 at the 5th percentile and boxes 0.91 at the 95th; on the observation's own masks the value
lies between the classes' quartiles (spheres 0.91-0.95 at the lower quartile, boxes 0.88-0.90 at
the upper), where real balls also lie (lower quartile 0.93 on 8 tracks)."""

SMALL_SILHOUETTE = 12
"""Short side (px, :attr:`Track.diameter`) below which a silhouette's outline does not tell a ball
from a box: rasterisation alone moves the ellipse IoU across :data:`ELLIPSE_FIT`. Measured on ideal
rasterisations of discs and near-square rectangles at random angles and sub-pixel offsets, no clip
(``benchmarks/silhouette_raster.py``, ``reports/silhouette_raster.md``), sized as this attribute is:
from 13 px on the test errs on at most 1 % of either class in every 1-px bin; 5 % of discs at 12-13 px,
15 % at 7-8 px. (The value 12 came from the benchmark's first version, which sized the contour's box,
1 px tighter; 13 is not yet measured on the clips.)
Real silhouettes add blur and segmentation error, so below it perception tries every shape
(:func:`pipeline.perception.shape_candidates`)."""

POLYGON_EPS = 0.04
"""Douglas-Peucker tolerance of :func:`silhouette_fit`'s polygon, as a fraction of the convex
hull's perimeter: a box's outline (4-6 corners) survives it, an arc is cut into chords."""


def silhouette_fit(mask: np.ndarray) -> tuple[float, float] | None:
    """How well an ellipse and a polygon of few corners explain a silhouette.

    The outer contour's least-squares ellipse (``cv2.fitEllipse``, Fitzgibbon et al. 1996) and
    the Douglas-Peucker simplification of its convex hull at :data:`POLYGON_EPS` of the hull's
    perimeter (``cv2.approxPolyDP``) are filled and compared with the mask.

    Args:
        mask: ``(H, W)`` bool silhouette of one object in one frame.
    Returns:
        ``(ellipse_iou, polygon_iou)`` in [0, 1], or None when the largest contour has fewer
        than 5 points (no ellipse can be fitted).
    """
    m = mask.astype(np.uint8)
    contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return None
    c = max(contours, key=cv2.contourArea)
    if len(c) < 5:
        return None
    area = float(m.sum())
    ell = np.zeros_like(m)
    cv2.ellipse(ell, cv2.fitEllipse(c), 1, -1)
    hull = cv2.convexHull(c)
    poly = np.zeros_like(m)
    cv2.fillPoly(poly, [cv2.approxPolyDP(hull, POLYGON_EPS * cv2.arcLength(hull, True), True)], 1)

    def iou(f: np.ndarray) -> float:
        inter = float((m & f).sum())
        return inter / max(area + float(f.sum()) - inter, 1.0)

    return iou(ell), iou(poly)


def round_silhouette(track: Track) -> bool:
    """Whether a track's silhouette is the outline of a sphere or of a disc seen along its axis:
    an ellipse (:attr:`Track.ellipse` >= :data:`ELLIPSE_FIT`) that is not elongated
    (:data:`ELONGATED`). Where no ellipse was measured (every frame touches the border), the
    rotated box's fill decides, as :attr:`Track.shape` does."""
    if track.elongation >= ELONGATED:
        return False
    if math.isfinite(track.ellipse):
        return track.ellipse >= ELLIPSE_FIT
    return track.fill < 0.5 * (CIRCLE_FILL + BOX_FILL)


def find_tracks(seg: np.ndarray, flow: np.ndarray | None = None, min_frames: int = 2,
                min_motion: float = 0.5) -> list[Track]:
    """Per-object statistics of a labelled clip.

    Args:
        seg: ``(T, H, W)`` int8 object ids, -1 background (``pipeline.masks.label_objects``).
        flow: ``(T-1, H, W, 2)`` float optical flow, px/frame, or None (no motion check).
        min_frames: drop tracks seen in fewer frames.
        min_motion: drop tracks whose largest flow magnitude inside the mask (95th percentile
            per frame) never exceeds this, px/frame: static clutter, not an object.
    Returns:
        tracks ordered by label.
    """
    seg = np.asarray(seg)
    T, H, W = seg.shape
    tracks = []
    for label in range(int(seg.max()) + 1):
        frames, centre, area, bottom, boxes, moving, clipped, fits = [], [], [], [], [], 0.0, [], []
        for t in range(T):
            m = seg[t] == label
            n = int(m.sum())
            if n == 0:
                continue
            vs, us = np.nonzero(m)
            frames.append(t)
            centre.append((us.mean() + 0.5, vs.mean() + 0.5))
            area.append(float(n))
            bottom.append(float(vs.max()) + 1.0)
            touches = us.min() == 0 or vs.min() == 0 or us.max() == W - 1 or vs.max() == H - 1
            clipped.append(bool(touches))
            box = None if touches else _box_stats(m)
            if box is not None:
                boxes.append((*box, n, float(vs.max() - vs.min() + 1)))
                fit = silhouette_fit(m)
                if fit is not None:
                    fits.append(fit)
            if flow is not None and t < len(flow):
                mag = np.hypot(flow[t][m][:, 0], flow[t][m][:, 1])
                moving = max(moving, float(np.percentile(mag, 95)))
        if len(frames) < min_frames or (flow is not None and moving < min_motion):
            continue
        if boxes:
            b = np.asarray(boxes)
            long_, short = float(np.median(b[:, 0])), float(np.median(b[:, 1]))
            fill = float(np.median(b[:, 3] / (b[:, 0] * b[:, 1])))
            tall = float(np.median(b[:, 4]))
            elongation = float(np.percentile(b[:, 0] / b[:, 1], 25))
            # angle: circular median over the frames with the largest area (least blur)
            ang = float(np.median(b[:, 2]))
        else:
            a = float(np.median(area))
            long_ = short = 2.0 * math.sqrt(a / math.pi)
            fill, ang, elongation, tall = math.pi / 4, 0.0, 1.0, math.nan
        shape = "circle" if fill < 0.5 * (CIRCLE_FILL + BOX_FILL) and elongation < ELONGATED else "rectangle"
        tracks.append(Track(label, np.asarray(frames), np.asarray(centre, dtype=np.float64),
                            np.asarray(area), np.asarray(bottom), short, (long_, short), ang, fill,
                            shape, moving,
                            float(np.linalg.norm(np.asarray(centre) - centre[0], axis=1).max()),
                            np.asarray(clipped, dtype=bool), elongation,
                            *(np.percentile(np.asarray(fits), 75, axis=0).tolist() if fits else (math.nan, math.nan)),
                            tall))
    return tracks


def net_shift(track: Track, k: int = 3) -> float:
    """Net displacement of a track from its start to its end, in diameters: the distance between
    the mean centroid of its first ``k`` and of its last ``k`` frames, over
    :attr:`Track.diameter`. An object that moves keeps its displacement (``net`` close to
    ``travel / diameter``); the outline of scenery at rest that a mover passes in front of shifts
    while it is occluded and comes back (``net`` close to 0 while ``travel`` is not).

    Returns:
        float >= 0; 0.0 for a track seen in fewer than ``2 * k`` frames.
    """
    if len(track.frames) < 2 * k:
        return 0.0
    shift = track.centre[-k:].mean(axis=0) - track.centre[:k].mean(axis=0)
    return float(np.hypot(*shift) / max(track.diameter, 1e-6))


def object_tracks(seg: np.ndarray, flow: np.ndarray | None, max_objects: int = 4) -> list[Track]:
    """The tracks that are objects: seen in at least 30 % of the frames (4 at least), moving
    somewhere (:func:`find_tracks`; and the centroid travels at least half a diameter: blobs
    that flicker in place, lighting changes, are not objects), at least 35 % of the largest
    one's median area (reflections, shadows and flicker are smaller), seen whole (not cut by
    the image border) in 5 frames at least, the fewest a parabola is fitted to
    (:func:`initial_motion`) — a hand or arm reaching in from outside the view is cut by the
    border nearly throughout (dev/07) — unless no other track is left; the ``max_objects``
    largest; ordered by first appearance, then left to right."""
    T = len(seg)
    tracks = [t for t in find_tracks(seg, flow, min_frames=max(4, int(0.3 * T)))
              if t.travel >= 0.5 * t.diameter]
    whole = [t for t in tracks if t.clipped is None or int((~t.clipped).sum()) >= 5]
    if whole:
        tracks = whole
    if tracks:
        big = max(float(np.median(t.area)) for t in tracks)
        tracks = [t for t in tracks if float(np.median(t.area)) >= 0.35 * big]
    tracks = sorted(tracks, key=lambda t: -float(np.sum(t.area)))[:max_objects]
    return sorted(tracks, key=lambda t: (int(t.frames[0]), float(t.centre[0, 0])))


def still_tracks(seg: np.ndarray, max_objects: int) -> list:
    """Tracks of segmenter masks that are objects, moving or at rest: seen in at least 15 % of the
    frames (3 at least: objects enter and leave), the ``max_objects`` largest; ordered by first appearance, then left to
    right (as :func:`object_tracks`)."""
    T = len(seg)
    tracks = find_tracks(seg, None, min_frames=max(3, int(0.15 * T)))
    tracks = sorted(tracks, key=lambda t: -float(np.sum(t.area)))[:max_objects]
    return sorted(tracks, key=lambda t: (int(t.frames[0]), float(t.centre[0, 0])))


# --------------------------------------------------------------------------------- motion
@dataclass
class Motion:
    """Quadratic motion of a track's first segment, at the window's ``t = 0``.

    Attributes:
        p0: ``(2,)`` position (u, v) at t = 0, px (extrapolated if the track starts later).
        v0: ``(2,)`` velocity, px/s.
        a: ``(2,)`` acceleration, px/s^2.
        n: frames used; ``t_end``: time of the last of them, s; ``rms``: fit residual, px.
        a_sd: standard deviation of ``a`` from the fit residual, px/s^2 (0 when not computed).
    """

    p0: np.ndarray
    v0: np.ndarray
    a: np.ndarray
    n: int
    t_end: float
    rms: float
    a_sd: float = 0.0


def jitter(track: Track) -> float:
    """Robust estimate of the noise of a track's centroid, px (Euclidean, both axes).

    From second differences of consecutive frames: a smooth motion (constant acceleration)
    gives equal ones, white noise of standard deviation ``s`` per axis spreads them with
    standard deviation ``sqrt(6) s``; the spread is the median absolute deviation (x 1.4826), so
    a few bounces or hits do not count. 0 with fewer than 5 consecutive frames.
    """
    if len(track.frames) < 5:
        return 0.0
    run = np.flatnonzero(np.diff(track.frames) != 1)
    d2 = track.centre[2:] - 2 * track.centre[1:-1] + track.centre[:-2]
    ok = np.ones(len(d2), bool)
    for g in run:   # a gap: the second differences across it are not of consecutive frames
        ok[max(0, g - 1):g + 1] = False
    d2 = d2[ok]
    if len(d2) < 3:
        return 0.0
    mad = np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0)
    return float(np.linalg.norm(1.4826 * mad / math.sqrt(6.0)))


def fit_tolerance(track: Track) -> float:
    """RMS residual (px) below which one parabola explains a stretch of a track:
    ``max(0.75 px, 6 % of the diameter, 2 x jitter)``. The last term (:func:`jitter`) is 0 for
    clean tracks; a noisy one (a ball bouncing in place on a table seen from above, a blurred
    silhouette: dev/05) otherwise fits no stretch longer than a few frames, and its velocity
    would be read from three or four of them."""
    return max(0.75, 0.06 * track.diameter, 2.0 * jitter(track))


def initial_motion(track: Track, fps: float, min_frames: int = 5) -> Motion:
    """Fit ``p(t) = p0 + v0 t + a t^2 / 2`` to the first stretch of a track that one parabola
    explains.

    The window starts at the earliest frame (within the first third of the track) from which
    at least ``min_frames`` frames fit one parabola with an RMS residual below
    :func:`fit_tolerance`, and is the longest such window from there: the fit skips a release
    by hand at the start and stops at the first bounce or collision. The parabola is then
    evaluated at the window's ``t = 0``. Fewer than ``min_frames`` frames: a straight line (no
    acceleration); fewer than 3: at rest.
    """
    t = track.frames / fps
    p = track.centre
    N = len(t)
    if N < 3:
        return Motion(p[0].copy(), np.zeros(2), np.zeros(2), N, float(t[-1]), 0.0)
    tol = fit_tolerance(track)

    def fit(i: int, j: int, degree: int = 2) -> tuple[np.ndarray, float]:
        tt = t[i:j]
        cols = [np.ones(j - i), tt] + ([0.5 * tt ** 2] if degree == 2 else [])
        A = np.stack(cols, axis=1)
        coef, *_ = np.linalg.lstsq(A, p[i:j], rcond=None)
        rms = float(np.sqrt(np.mean(np.sum((A @ coef - p[i:j]) ** 2, axis=1))))
        if degree == 1:
            coef = np.vstack([coef, np.zeros((1, 2))])
        return coef, rms

    def search(tol: float) -> Motion | None:
        if N >= min_frames:  # a parabola through the very first frames
            for j in range(N, min_frames - 1, -1):
                coef, rms = fit(0, j)
                if rms <= tol:
                    return Motion(coef[0], coef[1], coef[2], j, float(t[j - 1]), rms)
        if N >= 3 and track.frames[min(N, 4) - 1] - track.frames[0] == min(N, 4) - 1:
            # too few frames before the first event (a hit, a bounce) for a curvature: a line
            # through the first 3-4 frames (at rest, or moving steadily) if it explains them
            n = min(N, 4)
            coef, rms = fit(0, n, degree=1)
            if rms > tol and n == 4:
                n = 3
                coef, rms = fit(0, n, degree=1)
            if rms <= tol:
                return Motion(coef[0], coef[1], coef[2], n, float(t[n - 1]), rms)
        if N >= min_frames:
            for i in range(1, max(2, N // 3 + 1)):
                for j in range(N, i + min_frames - 1, -1):
                    coef, rms = fit(i, j)
                    if rms <= tol:
                        return Motion(coef[0], coef[1], coef[2], j - i, float(t[j - 1]), rms)
        return None

    m = search(tol)
    if m is None:  # no parabola fits 5 frames: a line through the first ones
        n = min(N, 4)
        coef, rms = fit(0, n, degree=1)
        m = Motion(coef[0], coef[1], coef[2], n, float(t[n - 1]), rms)
    return m


def gravity_motion(track: Track, fps: float, min_frames: int = 6) -> Motion | None:
    """The stretch of a track that shows gravity best: among all windows of at least
    ``min_frames`` consecutive visible frames that one parabola fits (RMS below
    :func:`fit_tolerance`), the one whose downward image acceleration is largest at its lower
    95 % bound (a free fall or a roll down a slope anywhere in the window, not only at its
    start; long windows win over short noisy ones). ``v0`` is the
    velocity at the window's middle frame (its direction tells speeding up from slowing down);
    ``p0`` the parabola at ``t = 0``. None if no window fits.
    """
    t = track.frames / fps
    p = track.centre
    N = len(t)
    tol = fit_tolerance(track)
    best = None
    for i in range(0, N - min_frames + 1):
        for j in range(i + min_frames, N + 1):
            if track.frames[j - 1] - track.frames[i] != j - 1 - i:  # a gap: not consecutive
                break
            tt = t[i:j]
            A = np.stack([np.ones(j - i), tt, 0.5 * tt ** 2], axis=1)
            coef, *_ = np.linalg.lstsq(A, p[i:j], rcond=None)
            rms = float(np.sqrt(np.mean(np.sum((A @ coef - p[i:j]) ** 2, axis=1))))
            if rms > tol:
                break
            n = j - i
            # lower confidence bound of the downward acceleration: the curvature of a least-squares
            # parabola through n equally spaced points has sd ~ sigma * sqrt(720 / (n^5 - 5 n^3 +
            # 4 n)) / dt^2 (regression on orthogonal polynomials), sigma >= 0.3 px of noise
            sd = max(rms, 0.3) * math.sqrt(720.0 / (n ** 5 - 5 * n ** 3 + 4 * n)) * fps ** 2
            score = float(coef[2][1]) - 2.0 * sd
            if best is None or score > best[4]:
                best = (i, j, coef, rms, score)
    if best is None:
        return None
    i, j, coef, rms, score = best
    tm = t[(i + j - 1) // 2]
    return Motion(coef[0], coef[1] + coef[2] * tm, coef[2], j - i, float(t[j - 1]), rms,
                  a_sd=float(coef[2][1] - score) / 2.0)


FLIGHT_MIN_SAMPLES = 8
"""Fewest samples :func:`flight_gravity` must keep to replace the gravity window's curvature: more
than the :func:`gravity_motion` window's 6, so the joint fit reads more of the flight than one
window does."""


def flight_gravity(track: Track, fps: float, min_samples: int = FLIGHT_MIN_SAMPLES) -> Motion | None:
    """Image acceleration of gravity from every free-flight arc of a falling track at once.

    :func:`gravity_motion` reads one window: the stretch whose downward curvature is largest at
    its lower 95 % bound. For a detection that is right, but as an estimate it is biased upward
    (the largest of many noisy windows is picked) and it reads 6 of a flight's 15-30 samples:
    on the real clips dev/02-dev/08 its curvature is 4-32 % above that of all arcs together, and
    the scale a side view takes from it (:func:`pipeline.perception.side_scale`) is as far off.
    A ball in free flight has one acceleration in every arc between bounces, so all arcs are
    fitted at once with one shared curvature, each moving sideways at a constant speed
    (:func:`pipeline.image_measure.fit_flight`, with the track's :func:`fit_tolerance` to trim
    the samples in a hand or blurred); a track it does not explain is no flight (None).

    Args:
        track: a track (whole frames, :func:`whole_frames`); fps: its frame rate, 1/s.
        min_samples: fewest samples the fit must keep.
    Returns:
        a :class:`Motion` whose ``a`` is ``(0, g_v)`` (px/s^2, image down positive; the
        simulator's only acceleration in flight is gravity, straight down), ``a_sd`` the
        standard deviation of ``g_v`` from the residual, ``n`` the samples kept, ``rms`` their
        residual (px), ``t_end`` the last kept sample's time (s), ``p0`` and ``v0`` the first
        kept arc's vertical state at t = 0 (``u`` of its first sample, no horizontal velocity:
        :func:`initial_state_given` gives the state); None with fewer than ``min_samples`` kept
        samples or a singular fit.
    """
    t = track.frames / fps
    fit = fit_flight(t, track.centre[:, 1], fit_tolerance(track), min_samples, x=track.centre[:, 0])
    if fit is None:
        return None
    first = int(fit["kept"][0])
    return Motion(np.array([float(track.centre[first, 0]), fit["v0"]]), np.array([0.0, fit["vel0"]]),
                  np.array([0.0, fit["a"]]), fit["n"], float(t[fit["kept"][-1]]), fit["rms"], a_sd=fit["a_sd"])


def gravity_evidence(track: Track, fps: float) -> Motion | None:
    """Where a track shows gravity: its :func:`gravity_motion` window, or, when no stretch of
    consecutive visible frames is long enough for one, its :func:`flight_gravity` fit over every
    sample. A small object crossing a busy background is lost in some frames (real clip dev/07:
    a ball 4 px wide thrown across a picture on the wall, seen in 16 of 27 frames, never in 6 in
    a row); its flight is still one parabola through the frames where it is seen, and the joint
    fit, which counts a gap in frames, reads it.

    Args:
        track: a track (whole frames, :func:`whole_frames`); fps: its frame rate, 1/s.
    Returns:
        the :class:`Motion` of :func:`gravity_motion`, else that of :func:`flight_gravity`
        (acceleration straight down), else None.
    """
    m = gravity_motion(track, fps)
    return m if m is not None else flight_gravity(track, fps)


def initial_state_given(track: Track, fps: float, a: np.ndarray, min_frames: int = 4) -> Motion:
    """Position and velocity at ``t = 0`` when the acceleration ``a (2,)`` px/s^2 is known
    (from :func:`gravity_motion`): ``p - a t^2 / 2`` is fitted by a line on the earliest stretch
    of at least ``min_frames`` frames that it explains within :func:`fit_tolerance`, grown as far as it goes (skips a release by hand, stops at the first bounce).
    When a bounce comes before ``min_frames`` frames (the window starts just before an impact),
    the line goes through the frames before it (2 at least).
    """
    t = track.frames / fps
    q = track.centre - 0.5 * np.outer(t ** 2, a)
    N = len(t)
    tol = fit_tolerance(track)

    def fit(i: int, j: int) -> tuple[np.ndarray, float]:
        A = np.stack([np.ones(j - i), t[i:j]], axis=1)
        coef, *_ = np.linalg.lstsq(A, q[i:j], rcond=None)
        return coef, float(np.sqrt(np.mean(np.sum((A @ coef - q[i:j]) ** 2, axis=1))))

    # a window that starts just before a bounce: the frames down to the first lowest point are
    # the only ones that hold the state at t = 0 (a later arc, extrapolated back, lies under
    # the floor). A bounce is a clear turn, faster than a quarter diameter per frame both ways.
    step = np.diff(track.centre[:, 1])
    fast = max(1.0, 0.25 * track.diameter)
    turn = next((i for i in range(1, len(step)) if step[i - 1] > fast and step[i] < -fast), None)
    if turn is not None and turn + 1 < min_frames and track.frames[turn] - track.frames[0] == turn:
        n = turn + 1
        coef, rms = fit(0, n)
        if rms > tol and n > 2:   # the lowest sample is already after the impact
            n -= 1
            coef, rms = fit(0, n)
        return Motion(coef[0], coef[1], np.asarray(a, dtype=np.float64), n, float(t[n - 1]), rms)
    for i in range(0, max(1, N - min_frames + 1)):
        best = None
        for j in range(i + min_frames, N + 1):
            coef, rms = fit(i, j)
            if rms > tol:
                break
            best = (j, coef, rms)
        if best is not None:
            j, coef, rms = best
            return Motion(coef[0], coef[1], np.asarray(a, dtype=np.float64), j - i, float(t[j - 1]), rms)
    coef, rms = fit(0, min(N, 2) if N >= 2 else 1) if N >= 2 else (np.stack([track.centre[0], np.zeros(2)]), 0.0)
    return Motion(coef[0], coef[1], np.asarray(a, dtype=np.float64), min(N, 2), float(t[min(N, 2) - 1]), rms)


@dataclass
class Bounce:
    """The first bounce of a falling track (:func:`first_bounce`).

    Attributes:
        e: coefficient of restitution, clamped to [0.2, 0.95].
        t: impact time from the window's first frame, s.
        v: image row of the centroid at the impact, px (may lie below the image: a floor out of
            view).
    """

    e: float
    t: float
    v: float


def bounce_restitution(track: Track, fps: float) -> float | None:
    """Coefficient of restitution at the first bounce of a falling track (:func:`first_bounce`),
    or None."""
    b = first_bounce(track, fps)
    return None if b is None else b.e


def speed_after_bounce(track: Track, fps: float, min_samples: int = FLIGHT_MIN_SAMPLES) -> float | None:
    """Sideways image speed of a falling track after its first bounce, when the bounce changed it.

    No force acts sideways in flight, so a ball's sideways speed is constant within an arc; a
    bounce changes it only through friction at the contact, which a ball's spin drives (a
    backspinning ball comes back: dev/04's red ball, -35 px/s before its first bounce and +30
    after). The arcs are fitted together (:func:`pipeline.image_measure.fit_flight`, each moving
    sideways at its own speed); the change between the first two is kept when it exceeds twice
    its standard error (a line's slope over an arc of ``n`` samples spanning ``T`` s with the
    fit's residual ``s`` has standard error ``s sqrt(12 / n) / T``).

    Args:
        track: a track (whole frames, :func:`whole_frames`); fps: its frame rate, 1/s.
        min_samples: fewest samples the flight fit must keep.
    Returns:
        the sideways speed (px/s, image ``u``) of the second arc, or None: no flight fit, fewer
        than two arcs, or a change within the noise.
    """
    fit = fit_flight(track.frames / fps, track.centre[:, 1], fit_tolerance(track), min_samples,
                     x=track.centre[:, 0])
    if fit is None or len(fit["arcs"]) < 2:
        return None
    a0, a1 = fit["arcs"][0], fit["arcs"][1]
    noise = max(fit["rms"], 0.5)    # px: a centroid is not better than half a pixel

    def sd(arc: dict) -> float:
        return noise * math.sqrt(12.0 / arc["n"]) / max(arc["t1"] - arc["t0"], 1.0 / fps)

    if abs(a1["x_speed"] - a0["x_speed"]) <= 2.0 * math.hypot(sd(a0), sd(a1)):
        return None
    return float(a1["x_speed"])


def first_bounce(track: Track, fps: float) -> Bounce | None:
    """The first bounce of a falling track that can be measured, or None.

    A lowest sample ``b`` is one where the vertical image velocity turns from down (+v) to up;
    bounces are taken in order, and one with too few samples around it (a window that starts
    just before an impact) is passed over, as is one whose two arcs do not fall into it and rise
    out of it (a glitch of the track: a hand's blob taken for the ball for a frame or two, dev/02,
    where such a turn hid the bounces after it). The impact lies next to ``b``, before or after it
    (frames may be missing around it: a ball cut by the image border, :func:`whole_frames`),
    so both splits are tried: up to 6
    samples before the impact and up to 7 after it (until the next bounce) are fitted jointly
    by two parabolas ``v(t)`` with one shared curvature (gravity), and the split with the
    smaller residual is kept. The bounce instant is where the two parabolas meet, and ``e =
    |v_after'(t_b)| / |v_before'(t_b)|`` (vertical speeds just after and before the impact,
    Newton's experimental law). Needs 3 samples on each side; ``e`` clamped to [0.2, 0.95].
    """
    if len(track.frames) < 6:
        return None
    t = track.frames / fps
    v = track.centre[:, 1]
    vv = np.diff(v) / np.diff(t)
    turns = [i for i in range(1, len(vv)) if vv[i - 1] > 0 and vv[i] < 0]
    if not turns:
        return None
    for k, b in enumerate(turns):  # b: index (into the track) of a lowest point seen
        previous = turns[k - 1] + 1 if k else 0   # after the previous bounce
        after_end = turns[k + 1] if k + 1 < len(turns) else len(v) - 1
        best = None
        for split in (b + 1, b):  # the lowest sample before the impact, or after it
            pre = np.arange(max(previous, split - 6), split)
            post = np.arange(split, min(after_end + 1, split + 7))
            if len(pre) < 3 or len(post) < 3:
                continue
            tt = np.concatenate([t[pre], t[post]])
            side = np.concatenate([np.zeros(len(pre)), np.ones(len(post))])
            A = np.stack([0.5 * tt ** 2, (1 - side) * tt, 1 - side, side * tt, side], axis=1)
            y = np.concatenate([v[pre], v[post]])
            coef, *_ = np.linalg.lstsq(A, y, rcond=None)
            rms = float(np.sqrt(np.mean((A @ coef - y) ** 2)))
            if best is None or rms < best[0]:
                best = (rms, coef)
        if best is None:
            continue   # too few samples around this bounce: the next one
        acc, b1, c1, b2, c2 = best[1]
        if abs(b1 - b2) < 1e-9:
            continue   # parallel arcs: no impact between them
        tb = (c2 - c1) / (b1 - b2)   # where the two arcs meet: the floor
        before, after = acc * tb + b1, acc * tb + b2
        if before <= 0 or after >= 0:
            continue   # not falling into it and rising out of it: no bounce (a glitch of the track)
        return Bounce(float(np.clip(-after / before, 0.2, 0.95)), float(tb),
                      float(0.5 * acc * tb ** 2 + b1 * tb + c1))
    return None


View = Literal["side", "top"]


def gravity_vote(track: Track, m: Motion) -> bool:
    """Does this motion show gravity: a fall (acceleration within ~37 deg of image down and
    strong) or a speed-up with a downward component (rolling/sliding down a slope)?"""
    a, v = m.a, m.v0
    na, nv = float(np.linalg.norm(a)), float(np.linalg.norm(v))
    if m.n < 5 or na < 4.0 * track.diameter:  # |a| / diameter < 4 s^-2: no clear acceleration
        return False
    if a[1] - 2.0 * m.a_sd <= 0:  # downward acceleration not significant (95 %)
        return False
    falling = a[1] > 0.8 * na
    speeding_down = a[1] > 0.05 * na and float(a @ v) > 0.3 * na * nv
    return bool(falling or speeding_down)


def estimate_view(tracks: list[Track], gravity: list[Motion | None]) -> tuple[View, list[bool]]:
    """``"side"`` when some track shows gravity in its :func:`gravity_evidence` (see
    :func:`gravity_vote`), else ``"top"``; and per track whether it shows gravity."""
    shows = [g is not None and gravity_vote(t, g) for t, g in zip(tracks, gravity)]
    return ("side" if any(shows) else "top"), shows
