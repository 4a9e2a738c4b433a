"""Pseudo ground-truth masks of real videos: background model, differencing, shadow test,
labelling and tracking objects in the masks, resting objects and ghosts.

Masks of real clips come from background subtraction (docs/design.md §7: *pseudo* ground
truth; every report says so): :func:`pseudo_masks` (foreground per frame),
:func:`label_objects` (objects with ids that stay the same over time), the post-processing of
resting objects (:func:`hold_resting`, :func:`merge_touching`, :func:`drop_ghosts`), and
:func:`pseudo_ground_truth` (all of it on chosen frames of a whole clip). Frames are read by
:mod:`pipeline.video`.

Example::

    clip = read_video("05_phystrack_CaromPuck_HeadOn_240fps.mp4", fps=240, start=0.7,
                      duration=1.0, size=(96, 64))     # pipeline.video
    frames = resample(clip.frames, clip.fps, 30.0, duration=1.0)   # 30 frames
    seg = label_objects(pseudo_masks(frames), max_objects=4)        # (30, 64, 96) int8
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
from scipy import ndimage
from scipy.optimize import linear_sum_assignment

from pipeline.video import VideoError, read_video

BACKGROUND = -1
"""Label of background pixels in segmentation arrays (same as the renderer's floor)."""


def median_area(masks: np.ndarray) -> float:
    """An object's size over a clip: the median, over the frames where it is seen, of its pixel count.

    Args:
        masks: ``(T, H, W)`` bool, one object's mask per frame.

    Returns:
        px (float); 0.0 when the object is seen in no frame.
    """
    areas = np.asarray(masks).sum(axis=(1, 2))
    seen = areas > 0
    return float(np.median(areas[seen])) if seen.any() else 0.0


def track_centroids(mask: np.ndarray) -> np.ndarray:
    """``(T, 2)`` float64 centroid ``(x, y)`` px of a ``(T, H, W)`` bool track per frame, NaN where unseen."""
    out = np.full((len(mask), 2), np.nan)
    for t in range(len(mask)):
        ys, xs = np.nonzero(mask[t])
        if len(xs):
            out[t] = xs.mean(), ys.mean()
    return out


def touches_border(mask: np.ndarray) -> np.ndarray:
    """``(T,)`` bool: per frame, whether a ``(T, H, W)`` bool track has a pixel on the image border."""
    return mask[:, 0, :].any(axis=1) | mask[:, -1, :].any(axis=1) | mask[:, :, 0].any(axis=1) | mask[:, :, -1].any(axis=1)


def _odd(n: float) -> int:
    n = max(1, int(round(n)))
    return n if n % 2 else n + 1


def pseudo_masks(
    frames: np.ndarray,
    method: Literal["median", "mog2"] = "median",
    background: np.ndarray | None = None,
    threshold: float | None = None,
    kernel: int | None = None,
    min_area: int | None = None,
    ghosts: bool = False,
    gain: bool = True,
    shadows: bool = True,
    edge: float = 0.5,
) -> np.ndarray:
    """Foreground masks of objects by background subtraction (pseudo ground truth).

    Steps: fit a background model, mark pixels that differ from it, clean up with a
    morphological opening (removes speckle) then closing (fills small holes), and keep
    the 8-connected components of at least ``min_area`` px. With ``method="median"``
    three refinements follow the difference (one set of defaults for every clip):

    * shadows (``shadows``): a pixel darker than the background by a factor 0.45–0.97
      with nearly the same chromaticity (normalised RGB within 0.06) is a shadow, not
      foreground, unless it touches (3x3) a non-shadow foreground pixel (the blurred rim
      of a dark object looks like a shadow); not in a greyscale clip (:func:`greyscale`:
      without colour the test takes every darker object for a shadow);
    * blurred edges (``edge``): a foreground pixel is kept only where its difference is at
      least ``edge`` times the largest difference within about 3 % of the image side
      (the object's local contrast), i.e. the boundary is put at half contrast, which
      trims motion blur and soft shadows whatever the object's contrast;
    * holes inside a blob are filled (objects are solid; a glass ball or a white disc on
      a light wall differs little from the background in its interior).

    Resting objects: an object that rests in one place for more than half of the fitting
    frames is in the median background and is *not* foreground while it rests (it is
    while it moves). With ``ghosts`` (off by default: it also "repairs" places where a
    person passed and then flags them in every frame) an object that rests in one
    place for most of the fitting frames (so the median holds it) is still found. Where
    the median holds an object that has not arrived yet (or has left), the fitting frames
    show a *ghost*: a foreground blob whose outline has edges in the background image but
    not in the frame (:func:`_ghost_score`). The background of such pixels is replaced by
    the median of the frames in which they were a ghost, i.e. the empty scene, so the
    object is foreground while it rests. This needs fitting frames from both before and
    after the object arrives (spread them over the whole clip).

    Lighting: with ``gain`` each frame's brightness is matched to the background (one
    robust gain per frame, the median ratio of grey levels over unsaturated pixels)
    before the difference, so global flicker does not light up the whole frame.

    Limits: an object resting in most fitting frames is background while it rests (see
    above); coloured shadows, reflections and hands that move are foreground too; a
    static overlay that shows on a few frames (title cards) is foreground on those frames.

    Args:
        frames: ``(T, H, W, 3)`` uint8 RGB.
        method: ``median``: the per-pixel median over the fitting frames is the background,
            foreground where any RGB channel differs by more than ``threshold`` (0–255,
            default 20) after a light blur and gain compensation. ``mog2``: OpenCV's Gaussian-mixture model
            (Zivkovic 2004) fitted on the fitting frames, then applied frozen;
            ``threshold`` is its squared Mahalanobis distance (default 16). MOG2 lets
            anything that covers a pixel for more than ~10 % of the fitting frames into the
            background: give it a longer window. ``ghosts`` and ``gain`` apply to
            ``median`` only.
        background: ``(N, H, W, 3)`` uint8 frames to fit the background model on (e.g. a
            longer window of the same video at the same size, spread over the clip);
            default ``frames``.
        threshold: see ``method``.
        kernel: side of the elliptical structuring element in px (odd); default about 1 %
            of the smaller image side, at least 3.
        min_area: smallest component kept, px; default 0.1 % of the frame, at least 4.
        ghosts: repair the median background where it holds a resting object (see above).
        gain: compensate a per-frame brightness gain (flicker) before differencing.
        shadows: drop shadow pixels (``median`` only, see above).
        edge: fraction of the local contrast at which the boundary is put (``median``
            only); 0 keeps every pixel above ``threshold``.

    Returns:
        ``(T, H, W)`` bool, True on foreground.

    Raises:
        ValueError: bad shapes/dtypes or an unknown method.
    """
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8 or not len(frames):
        raise ValueError(f"frames: must be (T, H, W, 3) uint8, got {frames.shape} {frames.dtype}")
    fit = frames if background is None else np.asarray(background)
    if fit.ndim != 4 or fit.shape[1:] != frames.shape[1:] or fit.dtype != np.uint8 or not len(fit):
        raise ValueError(f"background: must be (N, {', '.join(map(str, frames.shape[1:]))}) "
                         f"uint8, got {fit.shape} {fit.dtype}")
    h, w = frames.shape[1:3]
    kernel = _odd(max(3, 0.01 * min(h, w))) if kernel is None else _odd(kernel)
    min_area = max(4, round(1e-3 * h * w)) if min_area is None else int(min_area)
    element = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (kernel, kernel))

    if method == "median":
        threshold = 20.0 if threshold is None else float(threshold)
        shadows = shadows and not greyscale(fit)   # no chromaticity, no photometric shadow test
        sigma = max(0.5, 0.002 * min(h, w))
        smooth = lambda x: cv2.GaussianBlur(x, (0, 0), sigma).astype(np.float32)  # noqa: E731
        bg = smooth(np.median(fit, axis=0).astype(np.uint8))
        if ghosts and len(fit) >= 3:
            bg = _repair_ghosts(fit, bg, smooth, threshold, gain, element, min_area)
        window = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (_odd(0.03 * min(h, w)),) * 2)
        out = []
        for f in frames:
            d = _difference(smooth(f), bg, gain, shadows, threshold)
            m = _clean(d > threshold, element, min_area)
            if edge > 0:
                local = cv2.dilate(np.where(m, d, 0).astype(np.float32), window)
                m = _clean(m & (d >= np.maximum(threshold, edge * local)), element, min_area)
            out.append(ndimage.binary_fill_holes(m))
        return np.stack(out)
    elif method == "mog2":
        threshold = 16.0 if threshold is None else float(threshold)
        model = cv2.createBackgroundSubtractorMOG2(history=len(fit), varThreshold=threshold,
                                                   detectShadows=False)
        # Seed with the median image: MOG2 otherwise trusts its first frames far more
        # than later ones, and an object in them stays "background" for a long time.
        model.apply(np.median(fit, axis=0).astype(np.uint8), learningRate=1)
        for f in fit:
            model.apply(f, learningRate=-1)
        raw = np.stack([model.apply(f, learningRate=0) > 0 for f in frames])
    else:
        raise ValueError(f"method: must be 'median' or 'mog2', got {method!r}")

    return np.stack([_clean(m, element, min_area) for m in raw])


def label_objects(
    masks: np.ndarray, max_objects: int = 4, gate: float = 0.25, max_gap: int = 3, split: bool = False
) -> np.ndarray:
    """Split foreground masks into objects with ids that stay the same over time.

    Each frame's 8-connected components are matched to the tracks of earlier frames by
    Hungarian assignment (``scipy.optimize.linear_sum_assignment``) on the cost
    ``1 - IoU`` with the track's last mask; components that do not overlap any track fall
    back to centroid distance, accepted up to ``gate`` times the image diagonal (fast
    objects move more than their size between frames). A track unseen for more than
    ``max_gap`` frames ends. Unmatched components start new tracks. Finally the
    ``max_objects`` tracks seen in the most frames (ties: larger total area) are kept, so
    the objects of the scene win over a hand or person that is large but passes briefly,
    and numbered 0, 1, ... in
    order of first appearance (ties: left to right), as objects are named in the scene
    language; the rest become background.

    Args:
        masks: ``(T, H, W)`` bool foreground (e.g. from :func:`pseudo_masks`).
        max_objects: most objects to keep, 1–127.
        gate: largest jump of a track between frames, as a fraction of the image diagonal.
        max_gap: frames a track may go unseen and still be continued.
        split: a component that covers 30 % or more of the last masks of two or more live
            tracks (objects that came into contact) is split among them
            (:func:`split_merged`), so touching objects keep their ids.

    Returns:
        ``(T, H, W)`` int8: object id per pixel, :data:`BACKGROUND` (-1) elsewhere.

    Raises:
        ValueError: bad shape or ``max_objects`` out of range.
    """
    masks = np.asarray(masks)
    if masks.ndim != 3:
        raise ValueError(f"masks: must be (T, H, W), got {masks.shape}")
    if not 1 <= max_objects <= 127:
        raise ValueError(f"max_objects: must be in 1..127 (int8 ids), got {max_objects}")
    T, H, W = masks.shape
    max_jump = gate * math.hypot(H, W)
    raw = np.full((T, H, W), -1, dtype=np.int32)      # track id per pixel, before ranking
    last_mask: list[np.ndarray] = []                  # per track: last seen mask
    last_centre: list[np.ndarray] = []
    last_frame: list[int] = []
    first_seen: list[tuple[int, float]] = []          # (frame, x centroid) of first sighting
    area = []                                         # per track: total px
    seen = []                                         # per track: frames seen

    for t in range(T):
        n, labels, stats, centres = cv2.connectedComponentsWithStats(
            masks[t].astype(np.uint8), connectivity=8)
        if split and last_mask and n > 1:
            live = [k for k in range(len(last_mask)) if t - last_frame[k] <= max_gap + 1]
            labels, n = split_merged(labels, n, [last_mask[k] for k in live])
            stats = np.zeros((n, 5), np.int64)
            stats[:, cv2.CC_STAT_AREA] = np.bincount(labels.ravel(), minlength=n)
            vs, us = np.indices(labels.shape)
            area_n = np.maximum(stats[:, cv2.CC_STAT_AREA], 1)
            centres = np.stack([np.bincount(labels.ravel(), us.ravel(), n) / area_n,
                                np.bincount(labels.ravel(), vs.ravel(), n) / area_n], axis=1)
        comps = range(1, n)
        if not comps:
            continue
        assigned: dict[int, int] = {}
        if last_mask:
            cost = np.full((n - 1, len(last_mask)), np.inf)
            live = [k for k in range(len(last_mask)) if t - last_frame[k] <= max_gap + 1]
            for i in comps:
                ci = labels == i
                for k in live:
                    mk, ck = last_mask[k], last_centre[k]
                    inter = np.count_nonzero(ci & mk)
                    if inter:
                        cost[i - 1, k] = 1 - inter / np.count_nonzero(ci | mk)
                    else:                             # no overlap: cost in (1, 2]
                        dist = float(np.hypot(*(centres[i] - ck)))
                        cost[i - 1, k] = 1 + dist / max_jump if dist <= max_jump else np.inf
            finite = np.where(np.isfinite(cost), cost, 1e6)
            for i, k in zip(*linear_sum_assignment(finite)):
                if np.isfinite(cost[i, k]):
                    assigned[i + 1] = k
        for i in comps:
            k = assigned.get(i)
            if k is None:
                k = len(last_mask)
                last_mask.append(None)
                last_centre.append(None)
                last_frame.append(t)
                first_seen.append((t, float(centres[i][0])))
                area.append(0)
                seen.append(0)
            ci = labels == i
            last_mask[k], last_centre[k], last_frame[k] = ci, centres[i], t
            seen[k] += 1                              # one component per track and frame
            area[k] += int(stats[i, cv2.CC_STAT_AREA])
            raw[t][ci] = k

    rank = np.lexsort((np.array(area, dtype=float), np.array(seen, dtype=float)))
    keep = sorted(rank[::-1][:max_objects],
                  key=lambda k: first_seen[k])
    lookup = np.full(len(area) + 1, BACKGROUND, dtype=np.int8)   # index -1 -> background
    for new, k in enumerate(keep):
        lookup[k] = new
    return lookup[raw]


# -- helpers of pseudo_masks / label_objects, and pseudo ground truth of a whole clip --


def split_merged(labels: np.ndarray, n: int, previous: list[np.ndarray], share: float = 0.3
                 ) -> tuple[np.ndarray, int]:
    """Split connected components that swallowed two or more earlier objects.

    Rigid objects keep their image area from one frame to the next, while the boundary between
    them moves with them, so a component owning two earlier objects ``a`` and ``b`` is cut along
    the level set of ``dist_a - dist_b`` (Euclidean distance transforms of their earlier masks)
    that gives ``a`` its share ``area_a / (area_a + area_b)`` of the pixels; one owning three or
    more gives each pixel to the nearest earlier mask.

    Args:
        labels: ``(H, W)`` int32 component ids, 0 background, ``1..n-1`` components
            (``cv2.connectedComponents``).
        n: number of labels including the background.
        previous: ``(H, W)`` bool masks of the objects in an earlier frame (None: skipped).
        share: a component owns an earlier object when it covers at least this fraction of
            the object's mask.
    Returns:
        ``(labels, n)``: a copy where each component owning two or more earlier objects is cut
        into one part per object, the new parts numbered ``n, n+1, ...``; ``n`` updated.
    """
    out = labels.copy()
    previous = [m for m in previous if m is not None and m.any()]
    if len(previous) < 2:
        return out, n
    # (n_previous, n) px of each earlier mask inside each component
    cover = np.stack([np.bincount(labels[m], minlength=n)[:n] for m in previous])
    need = share * np.array([np.count_nonzero(m) for m in previous])
    for i in np.flatnonzero((cover[:, 1:] >= need[:, None]).sum(axis=0) >= 2) + 1:
        ci = labels == i
        owners = [m for m, c, r in zip(previous, cover[:, i], need) if c >= r]
        dist = np.stack([ndimage.distance_transform_edt(~m) for m in owners])
        if len(owners) == 2:
            vs, us = np.nonzero(ci)
            d = dist[0][vs, us] - dist[1][vs, us]
            areas = [np.count_nonzero(m) for m in owners]
            k = int(round(len(d) * areas[0] / sum(areas)))
            order = np.argsort(d, kind="stable")
            who = np.zeros(ci.shape, np.int64)
            who[vs[order[k:]], us[order[k:]]] = 1
        else:
            who = dist.argmin(axis=0)
        for j in range(1, len(owners)):
            part = ci & (who == j)
            if part.any():
                out[part] = n
                n += 1
    return out, n


def hold_resting(seg: np.ndarray, border: int = 1, min_frames: int = 1) -> np.ndarray:
    """Keep objects that come to rest visible: background subtraction loses an object as soon
    as it stops where it then stays (the background model learns it there), so a track that
    vanishes for good away from the image border is held at its last mask until the end,
    unless an object that was not in the frame where it vanished appears within two of its
    sizes in the next 3 frames (a track the tracker split: the object moved on under another
    id; an object it hit was there together with it). A track seen in fewer than
    ``min_frames`` frames is not held.

    Args:
        seg: ``(T, H, W)`` int8 object ids, -1 background (:func:`label_objects`).
        border: a last mask within this many px of the border means the object left the frame
            (not held).
        min_frames: frames a track must be seen in to be held. The main job's window
            (consecutive frames at the scene rate, :func:`pipeline.observe.observe`) uses 3: a hand
            that flicks through the view for two frames, held, became a still ghost for the rest
            of the clip and a third object (dev/07); its speed when it vanishes would say nothing
            (a carom striker stops dead at the impact, 05). Sparse frames spread over a whole clip
            (:func:`pseudo_ground_truth`) keep 1: two samples there can be a second apart.
    Returns:
        ``(T, H, W)`` int8, a copy; held pixels never overwrite another object.
    """
    seg = np.array(seg, copy=True)
    T, H, W = seg.shape
    present = (seg.reshape(T, -1)[:, :, None] == np.arange(int(seg.max()) + 1)).any(axis=1)  # (T, n)
    for k in range(int(seg.max()) + 1):
        seen = np.flatnonzero((seg == k).reshape(T, -1).any(axis=1))
        if len(seen) < max(1, min_frames) or seen[-1] >= T - 1:
            continue
        last = seg[seen[-1]] == k
        vs, us = np.nonzero(last)
        if vs.min() < border or us.min() < border or vs.max() >= H - border or us.max() >= W - border:
            continue
        # a track the tracker split: another object shows up next to where this one vanished
        # within a few frames (the same object under a new id), so this one did not stop
        centre, reach = np.array([vs.mean(), us.mean()]), 2.0 * max(np.ptp(vs), np.ptp(us), 1) + 2.0
        newcomers = [j for j in range(present.shape[1]) if j != k and not present[seen[-1], j]
                     and present[seen[-1] + 1: seen[-1] + 4, j].any()]
        after = seg[seen[-1] + 1: seen[-1] + 4]
        others = np.argwhere(np.isin(after, newcomers))
        if len(others) and np.min(np.hypot(*(others[:, 1:] - centre).T)) <= reach:
            continue
        for t in range(seen[-1] + 1, T):
            seg[t][last & (seg[t] < 0)] = k
    return seg


def merge_touching(seg: np.ndarray, fraction: float = 0.8) -> np.ndarray:
    """Merge tracks that touch (masks within 1 px) in at least ``fraction`` of the frames where
    both are seen: one object split in two by the background subtraction (two faces of a box
    lit differently, a highlight), not two objects, which touch only when they collide.
    ``(T, H, W)`` int8 in and out (merged ids take the lower id)."""
    seg = np.array(seg, copy=True)
    n = int(seg.max()) + 1
    kernel = np.ones((3, 3), np.uint8)
    for i in range(n):
        for j in range(i + 1, n):
            both = touching = 0
            for t in range(len(seg)):
                mi, mj = seg[t] == i, seg[t] == j
                if mi.any() and mj.any():
                    both += 1
                    touching += bool((cv2.dilate(mi.astype(np.uint8), kernel) & mj).any())
            if both and touching >= fraction * both:
                seg[seg == j] = i
    return seg


def drop_ghosts(seg: np.ndarray, overlap: float = 0.3) -> np.ndarray:
    """Drop the ghosts of objects that come to rest: where an object stops for good, the median
    background learns it, so before it arrives the empty floor there differs from the
    background and shows up as a blob that does not move. A track whose centroid travels less
    than its diameter (``2 sqrt(median area / pi)``) and covers at least ``overlap`` of the last
    mask of a track that moved at least its diameter is such a ghost.

    Args:
        seg: ``(T, H, W)`` int8 object ids, -1 background.
        overlap: fraction of the mover's last mask the ghost must cover.
    Returns:
        ``(T, H, W)`` int8, a copy with ghost pixels set to -1.
    """
    seg = np.array(seg, copy=True)
    stats = {}
    for k in range(int(seg.max()) + 1):
        frames = [t for t in range(len(seg)) if (seg[t] == k).any()]
        if not frames:
            continue
        centres = np.array([np.argwhere(seg[t] == k).mean(axis=0) for t in frames])
        areas = [np.count_nonzero(seg[t] == k) for t in frames]
        diameter = 2.0 * math.sqrt(float(np.median(areas)) / math.pi)
        travel = float(np.linalg.norm(centres - centres[0], axis=1).max())
        stats[k] = (frames[-1], travel >= diameter)
    for g, (_, moved) in stats.items():
        if moved:
            continue
        covered = (seg == g).any(axis=0)
        for o, (last_t, o_moved) in stats.items():
            last = seg[last_t] == o
            if o != g and o_moved and (covered & last).sum() >= overlap * max(last.sum(), 1):
                seg[seg == g] = BACKGROUND
                break
    return seg


def _clean(raw: np.ndarray, element: np.ndarray, min_area: int) -> np.ndarray:
    """Opening, closing, then the 8-connected components of >= ``min_area`` px (bool)."""
    m = cv2.morphologyEx(raw.astype(np.uint8), cv2.MORPH_OPEN, element)
    m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, element)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    keep = np.flatnonzero(stats[:, cv2.CC_STAT_AREA] >= min_area)
    return np.isin(labels, keep[keep > 0])


def _grey(img: np.ndarray) -> np.ndarray:
    """``(H, W)`` float32 luma of a float RGB image."""
    return img @ np.array([0.299, 0.587, 0.114], np.float32)


def _differs(frame: np.ndarray, bg: np.ndarray, threshold: float, gain: bool) -> np.ndarray:
    """Pixels of a smoothed float RGB frame that differ from the background (bool).

    With ``gain`` the frame is first divided by its brightness gain against ``bg``: the
    median grey-level ratio over pixels that are neither dark nor saturated in either.
    """
    return _difference(frame, bg, gain, False, threshold) > threshold


GREY_SPREAD, GREY_SHARE = 2, 0.99
""":func:`greyscale`: a clip is greyscale when at least ``GREY_SHARE`` of its pixels have their three
channels within ``GREY_SPREAD`` (0-255) of each other (a monochrome camera's frames decoded to RGB
differ by rounding only)."""


def greyscale(frames: np.ndarray) -> bool:
    """Whether ``frames`` are greyscale (:data:`GREY_SPREAD`, :data:`GREY_SHARE`): high-speed and
    machine-vision cameras often record one channel (real clip dev/01, a 1000 fps free fall).

    There :func:`shadow_like`'s chromaticity test is vacuous (every pixel has the same, grey, one),
    so every object darker than what is behind it by the shadow factor reads as its own shadow: a
    steel ball over a lighter strip, a grey puck on a white table. :func:`pseudo_masks` then skips
    the pixel shadow test; the track-level tests that also ask for the background's texture
    (:func:`pipeline.observe.cast_shadow_pairs`, ``lone_shadows``) still apply.

    Args:
        frames: ``(..., H, W, 3)`` uint8 RGB.
    Returns:
        bool; False for an empty array.
    """
    frames = np.asarray(frames)
    if not frames.size:
        return False
    spread = frames.max(axis=-1).astype(np.int16) - frames.min(axis=-1)
    return bool(np.count_nonzero(spread <= GREY_SPREAD) >= GREY_SHARE * spread.size)


def shadow_like(frame: np.ndarray, bg: np.ndarray) -> np.ndarray:
    """Pixels that look like a cast shadow on the background: darker (0.45-0.97 times its RGB
    sum) with the same chromaticity (largest difference of ``(r, g, b) / (r + g + b)`` below 0.06),
    the photometric shadow model of Cucchiara et al., "Detecting moving objects, ghosts, and
    shadows in video streams", TPAMI 2003, in RGB.

    Args:
        frame: ``(..., H, W, 3)`` RGB, any real dtype (0-255); bg: ``(H, W, 3)`` the background.
    Returns:
        ``(..., H, W)`` bool.
    """
    frame, bg = np.asarray(frame), np.asarray(bg)
    frame, bg = (x if np.issubdtype(x.dtype, np.floating) else x.astype(np.float32) for x in (frame, bg))
    sf, sb = frame.sum(-1) + 1e-3, bg.sum(-1) + 1e-3
    ratio = sf / sb
    chroma = np.abs(frame / sf[..., None] - bg / sb[..., None]).max(-1)
    return (ratio > 0.45) & (ratio < 0.97) & (chroma < 0.06)


def skin_like(frames: np.ndarray) -> np.ndarray:
    """Pixels whose colour is a human skin tone by two published rules at once: the YCrCb box
    Cr 133-173, Cb 77-127 of Chai and Ngan, "Face segmentation using skin-color map in videophone
    applications", IEEE TCSVT 1999 (OpenCV's 8-bit YCrCb, ``cv2.COLOR_RGB2YCrCb``), and the RGB rule
    of Kovac, Peer and Solina, "Human skin colour clustering for face detection", EUROCON 2003
    (uniform daylight: R > 95, G > 40, B > 20, max - min > 15, |R - G| > 15, R > G, R > B). Either
    alone passes dark reds (a maroon ball of RGB 108, 37, 50 passes the box; the RGB rule alone takes
    many oranges and pinks); a pixel must pass both. Wood and orange still do: one cue, never the only one.

    Args:
        frames: ``(..., H, W, 3)`` uint8 RGB.
    Returns:
        ``(..., H, W)`` bool.
    """
    frames = np.asarray(frames, np.uint8)
    ycc = cv2.cvtColor(np.ascontiguousarray(frames.reshape(-1, frames.shape[-2], 3)),
                       cv2.COLOR_RGB2YCrCb).reshape(frames.shape)
    cr, cb = ycc[..., 1], ycc[..., 2]
    box = (cr >= 133) & (cr <= 173) & (cb >= 77) & (cb <= 127)
    r, g, b = (frames[..., k].astype(np.int16) for k in range(3))
    spread = np.maximum(np.maximum(r, g), b) - np.minimum(np.minimum(r, g), b)
    rgb = (r > 95) & (g > 40) & (b > 20) & (spread > 15) & (np.abs(r - g) > 15) & (r > g) & (r > b)
    return box & rgb


def _difference(frame: np.ndarray, bg: np.ndarray, gain: bool, shadows: bool,
                threshold: float) -> np.ndarray:
    """``(H, W)`` float32 largest RGB difference of a smoothed frame from the background.

    ``gain``: divide the frame by its brightness gain first (see :func:`_differs`).
    ``shadows``: 0 on shadow pixels (see :func:`pseudo_masks`) that do not touch a
    non-shadow pixel differing by more than ``threshold``.
    """
    if gain:
        gf, gb = _grey(frame), _grey(bg)
        ok = (gb > 20) & (gb < 235) & (gf > 10) & (gf < 245)
        if np.count_nonzero(ok) > 0.1 * ok.size:
            g = float(np.clip(np.median(gf[ok] / gb[ok]), 0.5, 2.0))
            frame = frame / g
    d = np.abs(frame - bg).max(axis=-1)
    if shadows:
        shadow = shadow_like(frame, bg)
        solid = ((d > threshold) & ~shadow).astype(np.uint8)
        shadow &= ~(cv2.dilate(solid, np.ones((3, 3), np.uint8)) > 0)
        d = np.where(shadow, 0, d)
    return d.astype(np.float32)


def _gradient(grey: np.ndarray) -> np.ndarray:
    return cv2.magnitude(cv2.Sobel(grey, cv2.CV_32F, 1, 0), cv2.Sobel(grey, cv2.CV_32F, 0, 1))


def _ghost_score(component: np.ndarray, frame_grad: np.ndarray, bg_grad: np.ndarray) -> float:
    """Share of the edge strength on a blob's outline that is in the frame, 0..1.

    A real object has its edges in the frame (score near 1); a ghost, a place where the
    background model holds an object that the frame does not show, has them in the
    background image (score near 0).
    """
    m = component.astype(np.uint8)
    ring = (cv2.dilate(m, None) > 0) & ~(cv2.erode(m, None) > 0)
    f, b = float(frame_grad[ring].mean()), float(bg_grad[ring].mean())
    return f / (f + b + 1e-6)


def _repair_ghosts(fit: np.ndarray, bg: np.ndarray, smooth, threshold: float, gain: bool,
                   element: np.ndarray, min_area: int, ghost_score: float = 0.35,
                   min_share: float = 0.05) -> np.ndarray:
    """Median background with its ghosts replaced by the empty scene (see pseudo_masks).

    A pixel that is inside a ghost blob (:func:`_ghost_score` below ``ghost_score``) in at
    least ``min_share`` of the fitting frames (and at least 2) gets the median of those
    frames as background.
    """
    bg_grad = _gradient(_grey(bg))
    flags = np.zeros(fit.shape[:3], dtype=bool)
    for t, f in enumerate(fit):
        fs = smooth(f)
        m = _clean(_differs(fs, bg, threshold, gain), element, min_area)
        n, labels = cv2.connectedComponents(m.astype(np.uint8), connectivity=8)
        if n < 2:
            continue
        frame_grad = _gradient(_grey(fs))
        for i in range(1, n):
            comp = labels == i
            if _ghost_score(comp, frame_grad, bg_grad) < ghost_score:
                flags[t] |= comp
    count = flags.sum(axis=0)
    fix = count >= max(2, min_share * len(fit))
    if not fix.any():
        return bg
    ys, xs = np.nonzero(fix)
    values = np.stack([smooth(f)[ys, xs] for f in fit])            # (N, P, 3)
    values[~flags[:, ys, xs]] = np.nan
    out = bg.copy()
    out[ys, xs] = np.nanmedian(values, axis=0)
    return out


def pseudo_ground_truth(
    path: str | Path,
    fps: float | None,
    frame_indices,
    size: tuple[int, int] | None = None,
    *,
    max_objects: int = 4,
    method: Literal["median", "mog2"] = "median",
    step: int | None = None,
    max_fit: int = 150,
    crop: tuple[int, int, int, int] | None = None,
    hold_rest: bool = True,
    keep=None,
    **mask_kwargs,
) -> np.ndarray:
    """Pseudo ground-truth segmentation of chosen source frames of a whole clip.

    Reads the whole clip (cut to ``crop``, resized to ``size``), fits the median
    background (:func:`pseudo_masks`) on up to ``max_fit`` frames spread evenly over it,
    makes masks of every ``step``-th frame plus the asked ones, tracks them with
    :func:`label_objects` (so ids and the ``max_objects`` kept tracks are decided over the
    whole clip, not per frame: the tracks seen in the most tracked frames win) and
    returns the asked frames, with ids renumbered 0..n-1 in order of first appearance
    among them. This is the method checked against hand labels
    (``tests/test_realvideo_masks.py``); call it with the working crop and size to get
    pseudo ground truth of a window.

    Resting objects: an object that rests in one place for more than half of the clip is
    part of the median background, so it vanishes from the masks where it stops (e.g. the
    struck puck of the PhysTrack carom clip); with ``hold_rest`` a track that vanishes for
    good away from the image border is held at its last mask (:func:`hold_resting`), tracks
    that touch all along are merged (:func:`merge_touching`) and the ghosts a resting object
    leaves in the background are dropped (:func:`drop_ghosts`).

    Args:
        path: video file.
        fps: true frame rate (frames per second) when the container's is wrong; ``None``
            trusts the container. Frame indices do not depend on it.
        frame_indices: source frame indices (0-based, as decoded) to return.
        size: ``(width, height)`` of the output in px; ``None`` keeps the crop's size.
        crop: ``(x, y, width, height)`` box in original px cut out before resizing (as
            :func:`read_video`, clipped to the frame); default the largest centred box of
            the aspect ratio of ``size`` (the whole frame when ``size`` is ``None``).
        max_objects: objects kept by :func:`label_objects`.
        method: background model of :func:`pseudo_masks`.
        step: tracking stride in source frames; default so that about 200 frames are
            tracked.
        max_fit: most frames to fit the background on.
        hold_rest: hold objects that come to rest, merge split tracks, drop ghosts (the same
            post-processing as the main job's pseudo masks, ``pipeline.observe.keep_objects``).
        keep: optional function ``(T', H, W) int8 -> (T', H, W) int8`` applied to the tracked
            frames last (e.g. keep only tracks that are objects, :func:`pipeline.observe.observe_frames`).
        **mask_kwargs: more keyword arguments of :func:`pseudo_masks`
            (``threshold``, ``kernel``, ``min_area``, ``ghosts``, ``gain``, ``shadows``,
            ``edge``).

    Returns:
        ``(len(frame_indices), H, W)`` int8 (``(W, H)`` = ``size``, or the crop's size):
        object id per pixel, :data:`BACKGROUND` (-1) elsewhere; ids are the same object
        in every returned frame, numbered 0, 1, ... in order of first appearance in the
        returned frames (ties: left to right), at most ``max_objects`` of them.

    Raises:
        VideoError: unreadable video, or a frame index out of range.
    """
    clip = read_video(path, fps=fps, size=size, crop=crop)
    n = len(clip.frames)
    wanted = [int(i) for i in frame_indices]
    bad = [i for i in wanted if not 0 <= i < n]
    if bad:
        raise VideoError(f"{path}: frame_indices {bad} outside 0..{n - 1}")
    step = max(1, n // 200) if step is None else max(1, int(step))
    tracked = sorted(set(range(0, n, step)) | set(wanted))
    fit = np.unique(np.linspace(0, n - 1, min(n, max_fit)).round().astype(int))
    masks = pseudo_masks(clip.frames[tracked], method=method, background=clip.frames[fit],
                         **mask_kwargs)
    seg = label_objects(masks, max_objects=max_objects)
    if hold_rest:
        seg = drop_ghosts(merge_touching(hold_resting(seg)))
    if keep is not None:
        seg = keep(seg)
    where = {t: k for k, t in enumerate(tracked)}
    out = seg[[where[i] for i in wanted]]
    return _renumber(out)


def _renumber(seg: np.ndarray) -> np.ndarray:
    """Ids of an int8 ``(T, H, W)`` labelling renumbered 0.. in order of first appearance
    (frame, then x centroid of that frame); background stays -1."""
    order = []
    for s in seg:
        ids = [k for k in np.unique(s) if k >= 0 and k not in order]
        ids.sort(key=lambda k: np.nonzero(s == k)[1].mean())
        order += ids
    lookup = np.full(int(seg.max()) + 2, BACKGROUND, dtype=np.int8)
    for new, k in enumerate(order):
        lookup[k] = new
    return lookup[seg]


COLOUR_SEPARATION = 3.0
"""Fisher separation (centre distance / pooled within-cluster std of the chromaticity) above which
a component's two colour clusters are two objects (:func:`cut_by_colour`)."""
COLOUR_MIN_DISTANCE = 0.08
"""Least distance between two objects' chromaticities ``(r, g, b) / (r + g + b)`` (:func:`cut_by_colour`)."""
COLOUR_DARK = 60
"""Pixels with ``r + g + b`` below this (of 765) have no reliable chromaticity: they are not
clustered and go to the nearest clustered pixel (:func:`cut_by_colour`)."""


COLOUR_UNION_SOLIDITY = 0.94
"""A component is cut by colour only when its solidity (holes filled) is below this: two convex
objects that touch form a waist, one object of several colours (a Rubik's cube, a labelled can) is
convex. Measured on touching pairs of the dev renders (0.81-0.93) against a Rubik's cube on real
video (0.965-0.978) and a checkered ball (0.954) (:func:`cut_by_colour`)."""


def solidity(mask: np.ndarray) -> float:
    """Pixel area of a ``(H, W)`` mask over the area of its convex hull (1 for a convex shape).

    The hull is that of the pixel centres, grown by half a pixel all round (half its perimeter
    added), so a convex pixel blob scores ~1 at any size.
    """
    pts = cv2.findNonZero(np.asarray(mask, np.uint8))
    if pts is None or len(pts) < 3:
        return 1.0
    hull = cv2.convexHull(pts)
    return float(np.count_nonzero(mask)) / (cv2.contourArea(hull) + 0.5 * cv2.arcLength(hull, True) + 1.0)


KMEANS_SEED = 0
"""Seed of OpenCV's RNG before each k-means of :func:`cut_by_colour`. ``cv2.kmeans`` picks its
k-means++ centres with the calling thread's RNG (``cv::theRNG``), whose state carries over from every
earlier call in that thread: unseeded, the cut of a component (and so the objects the observation
reports) depended on what the process had observed before and on which thread ran it (a PyBullet
clip gave one object alone and none after 60 other clips, ``docs/observation.md``)."""


def majority_smooth(part: np.ndarray, lit: np.ndarray) -> np.ndarray:
    """3x3 majority vote between two labels, blind to their numbering.

    Each ``lit`` pixel takes the label that more of its lit 3x3 neighbours (itself included) carry,
    and keeps its own on a tie; unlit pixels are 0. Swapping labels 1 and 2 swaps the result, which
    a median filter of the label image does not do (it orders 0 < 1 < 2, so at the edge, where the
    window holds 0s, label 1 wins ties that label 2 loses): with it, the cut depended on which
    cluster k-means happened to number first.

    Args:
        part: ``(H, W)`` uint8, 1 or 2 on ``lit`` pixels.
        lit: ``(H, W)`` bool.
    Returns:
        ``(H, W)`` uint8, 0 off ``lit``.
    """
    box = np.ones((3, 3), np.float32)
    votes = [cv2.filter2D(((part == k) & lit).astype(np.float32), -1, box, borderType=cv2.BORDER_CONSTANT)
             for k in (1, 2)]
    out = np.where(votes[0] > votes[1], 1, np.where(votes[1] > votes[0], 2, part))
    return np.where(lit, out, 0).astype(np.uint8)


def cut_by_colour(mask: np.ndarray, frame: np.ndarray, min_area: int, min_share: float = 0.15,
                  coherent: float = 0.85) -> np.ndarray:
    """Cut each connected component of a foreground mask that holds two objects of clearly
    different colours (two touching objects that a foreground map cannot separate).

    Per component that is not convex (:data:`COLOUR_UNION_SOLIDITY`): two-cluster k-means (``cv2.kmeans``) of its pixels' chromaticity
    ``(r, g, b) / (r + g + b)``, which shading (a factor on all three) does not change; the
    component is two objects when both clusters hold ``min_share`` of it and ``min_area`` px,
    their centres are :data:`COLOUR_MIN_DISTANCE` apart and :data:`COLOUR_SEPARATION` pooled
    standard deviations apart (Fisher's criterion), and each cluster is one spatial region (its
    largest 4-connected part holds ``coherent`` of it: a checkered or striped object, whose
    colours interleave, is not cut). The pixels of either part that touch the other are removed,
    so the two parts are separate components; a tracker gives them back (nearest part). The
    k-means is seeded (:data:`KMEANS_SEED`), so the same input gives the same cut in any process,
    and the clusters are smoothed by a vote blind to their numbering (:func:`majority_smooth`),
    so the cut does not depend on which one k-means numbers first.

    Args:
        mask: ``(H, W)`` bool foreground.
        frame: ``(H, W, 3)`` uint8 RGB.
        min_area: px; components smaller than twice this are left alone.
    Returns:
        ``(H, W)`` bool: ``mask`` with the cut pixels removed.
    """
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    out = mask.copy()
    big = [i for i in range(1, n) if stats[i, cv2.CC_STAT_AREA] >= 2 * min_area]
    if not big:
        return out
    rgb = frame.astype(np.float32)
    total = rgb.sum(axis=-1)
    chroma = rgb / np.maximum(total, 1.0)[..., None]
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 20, 1e-3)
    for i in big:
        x, y, w, h = stats[i, :4]
        comp = labels[y:y + h, x:x + w] == i
        if solidity(ndimage.binary_fill_holes(comp)) >= COLOUR_UNION_SOLIDITY:
            continue                                            # convex: one object, however coloured
        lit = comp & (total[y:y + h, x:x + w] >= COLOUR_DARK)
        if lit.sum() < 2 * min_area:
            continue
        feats = np.ascontiguousarray(chroma[y:y + h, x:x + w][lit])
        cv2.setRNGSeed(KMEANS_SEED)   # k-means++ draws from the thread's RNG: same input, same cut
        _, assign, centres = cv2.kmeans(feats, 2, None, crit, 2, cv2.KMEANS_PP_CENTERS)
        assign = assign.ravel()
        sizes = np.bincount(assign, minlength=2)
        if sizes.min() < max(min_area, min_share * len(feats)):
            continue
        dist = float(np.linalg.norm(centres[0] - centres[1]))
        spread = math.sqrt(float(sum(((feats[assign == k] - centres[k]) ** 2).sum() for k in range(2))) / len(feats))
        if dist < COLOUR_MIN_DISTANCE or dist < COLOUR_SEPARATION * max(spread, 1e-6):
            continue
        part = np.zeros(comp.shape, np.uint8)                   # 0 none, 1 / 2 the clusters
        part[lit] = assign + 1
        part = majority_smooth(part, lit)
        if (comp & (part == 0)).any():                          # dark pixels: nearest lit part
            _, (iy, ix) = ndimage.distance_transform_edt(part == 0, return_indices=True)
            part = np.where(comp, part[iy, ix], 0)
        ok = True
        for k in (1, 2):
            pk = (part == k).astype(np.uint8)
            m, lk = cv2.connectedComponents(pk, connectivity=4)
            if m < 2 or np.bincount(lk[pk > 0]).max() < coherent * pk.sum():
                ok = False
                break
        if not ok:
            continue
        near = [cv2.dilate((part == k).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0 for k in (1, 2)]
        seam = ((part == 1) & near[1]) | ((part == 2) & near[0])
        out[y:y + h, x:x + w][seam] = False
    return out
