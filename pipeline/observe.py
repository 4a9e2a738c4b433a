"""Observe a real video: choose the window, the region of motion and the working size, then
compute what the search scores against (pseudo masks split into objects, optical flow).

Resolution (issue 9, item 4): the working image keeps the video's own aspect ratio and is a
**crop to the region of motion**, not a centre crop: a first pass at :data:`DETECT_LONG_SIDE`
px finds where objects move over the window; that box, padded by two object diameters, is grown
to the video's aspect ratio and cut out of the original frames, then resized so that the median
object is at least :data:`MIN_OBJECT_DIAMETER` px across (area >= ~100 px) with the long side
between :data:`MIN_LONG_SIDE` and :data:`MAX_LONG_SIDE` px. Cropping (rather than only raising
the working size) keeps the render small, so the search runs at 100+ evaluations/s, and never
cuts an object out because the box is built from where the objects are.

Window (``start=None``): the 1 s window whose frames show the most *object-sized* motion
(frame differences at 30 fps on a 160 px wide copy of the whole clip; a frame counts up to 1
as its moving area grows to :data:`FULL_MOTION_FRACTION` of the image, and -2 when it
exceeds :data:`MAX_MOVING_FRACTION`, e.g. a hand or a person; frames weigh from 1 at the
window's start down to 0.5 at its end, so that the window starts where the motion starts; the
earliest best window wins).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from pipeline.flow import estimate_flow
from pipeline.perception import find_tracks, object_tracks, still_tracks
from pipeline.segmenter import median_background, shipped
from pipeline.video import (Clip, VideoError, drop_ghosts, hold_resting, label_objects, merge_touching,
                            pseudo_ground_truth, pseudo_masks, read_video, resample)

DETECT_LONG_SIDE = 320
"""px, long side of the detection pass (whole frame)."""
MIN_OBJECT_DIAMETER = 12.0
"""px, smallest median object diameter in the working image (a disc of 12 px is 113 px)."""
MIN_LONG_SIDE, MAX_LONG_SIDE = 160, 384
"""px, bounds of the working image's long side."""
MAX_MOVING_FRACTION = 0.015
"""A frame whose moving area is above this fraction of the image is not object motion."""
FULL_MOTION_FRACTION = 0.005
"""Moving-area fraction at which a frame counts fully as object motion."""


@dataclass
class Observation:
    """A window of a real video, ready to be scored against.

    Attributes:
        frames: ``(T, H, W, 3)`` uint8 RGB at the scene fps, working size (the crop).
        seg: ``(T, H, W)`` int8 pseudo masks of the objects (background subtraction, Hungarian
            tracking, only tracks that move: :func:`keep_objects`; objects that come to rest
            held: :func:`pipeline.video.hold_resting`), -1 background.
        flow: ``(T-1, H, W, 2)`` float32 observed optical flow, px/frame.
        clip: the decoded source window (true fps, crop box in original px).
        start: window start, s; ``auto``: whether it was chosen automatically.
        crop: ``(x, y, w, h)`` in original px; ``size``: working ``(W, H)`` px.
        scene_fps: frames per second of ``frames``.
        flow_method: optical-flow estimator used.
        mask_method: how ``seg`` was made (:data:`MASK_METHODS`).
    """

    frames: np.ndarray
    seg: np.ndarray
    flow: np.ndarray
    clip: Clip
    start: float
    auto: bool
    crop: tuple[int, int, int, int]
    size: tuple[int, int]
    scene_fps: int
    flow_method: str
    mask_method: str = "median"


def _detect_size(orig_w: int, orig_h: int) -> tuple[int, int]:
    s = DETECT_LONG_SIDE / max(orig_w, orig_h)
    return max(2, round(orig_w * s / 2) * 2), max(2, round(orig_h * s / 2) * 2)


def choose_start(video, fps: float | None, scene_fps: int, duration: float) -> float:
    """Start (s) of the ``duration`` window with the most object-sized motion (module docstring).

    Raises:
        VideoError: unreadable video, or shorter than ``duration``.
    """
    probe = read_video(video, fps=fps, max_frames=1)
    W0, H0 = probe.original_size
    small = read_video(video, fps=fps, size=(160, max(2, round(160 * H0 / W0))))
    frames = small.frames
    total = len(frames) / small.fps
    if total + 0.5 / small.fps < duration:
        raise VideoError(f"{video}: only {total:.3f} s long at {small.fps:g} fps, need {duration:g} s")
    at = resample(frames, small.fps, scene_fps)
    grey = at.astype(np.int16).max(axis=-1)
    moving = np.abs(np.diff(grey, axis=0)) > 25
    frac = moving.mean(axis=(1, 2))
    score = np.where(frac > MAX_MOVING_FRACTION, -2.0, np.minimum(frac, FULL_MOTION_FRACTION) / FULL_MOTION_FRACTION)
    n = max(1, round(duration * scene_fps))
    if len(score) < n:
        return 0.0
    # n frames: n - 1 differences, weighted from 1 at the window's start down to 0.5 at its
    # end, so that the window starts where the motion starts: the scene's state at t = 0 has
    # to explain the rest (a push in the middle of the window cannot be explained)
    sums = np.correlate(score, np.linspace(1.0, 0.5, max(1, n - 1)), mode="valid")
    last = max(0, math.floor((total - duration) * scene_fps + 1e-6))
    sums = sums[: last + 1]
    return float(np.argmax(sums)) / scene_fps


MASK_METHODS = ("median", "mog2", "segmenter", "hybrid")
"""``realvideo.mask_method``: background subtraction (``median``, ``mog2``:
:func:`pipeline.video.pseudo_masks`), the learned segmenter alone (``segmenter``,
:mod:`pipeline.segmenter`) or the segmenter checked by motion (``hybrid``, :func:`hybrid_objects`)."""
LEARNED = ("segmenter", "hybrid")
"""Mask methods that see objects at rest (their tracks are kept whether they move or not)."""

FG_THRESHOLD = 0.5
"""Segmenter foreground probability above which a pixel belongs to an object."""


def segment_objects(frames: np.ndarray, context: np.ndarray, method: str, max_objects: int) -> np.ndarray:
    """Masks of the objects in ``frames``, split into tracks (before :func:`keep_objects`).

    ``median`` / ``mog2``: background subtraction against ``context``
    (:func:`pipeline.video.pseudo_masks`), then :func:`pipeline.video.label_objects`.
    ``segmenter``: the learned segmenter's foreground (:mod:`pipeline.segmenter`, with the
    median of ``context`` as the background it compares against) minus its contact pixels
    (where two objects touch), tracked by :func:`pipeline.video.label_objects`; the contact
    pixels are then given to the nearest track (within 3 px).

    Args:
        frames: ``(T, H, W, 3)`` uint8 RGB; context: ``(N, H, W, 3)`` uint8 frames of the same
            video spread over the clip (the background model's).
        method: one of :data:`MASK_METHODS`.
    Returns:
        ``(T, H, W)`` int8 track ids, -1 background.
    Raises:
        ValueError: unknown method.
    """
    if method not in MASK_METHODS:
        raise ValueError(f"realvideo.mask_method: must be one of {', '.join(MASK_METHODS)}, got {method!r}")
    if method not in LEARNED:
        masks = pseudo_masks(frames, method=method, background=context)
        return label_objects(masks, max_objects=max_objects)
    if method == "hybrid":
        return hybrid_objects(frames, context, max_objects)
    fg, contact = shipped()(frames, median_background(context))
    return _segmenter_tracks(fg > FG_THRESHOLD, contact > 0.5, max_objects)


def _segmenter_tracks(fg: np.ndarray, contact: np.ndarray, max_objects: int) -> np.ndarray:
    """Tracks of segmenter foreground ``(T, H, W) bool`` split at its ``contact`` pixels (bool)."""
    h, w = fg.shape[1:3]
    min_area = max(4, round(1e-3 * h * w))
    core = fg & ~contact
    core = np.stack([_keep_components(c, min_area) for c in core])
    seg = label_objects(core, max_objects=max_objects)
    out = seg.copy()
    for t in range(len(seg)):
        if not (fg[t] & (seg[t] < 0)).any() or not (seg[t] >= 0).any():
            continue
        dist, (iy, ix) = ndimage.distance_transform_edt(seg[t] < 0, return_indices=True)
        grow = fg[t] & (seg[t] < 0) & (dist <= 3)
        out[t][grow] = seg[t][iy[grow], ix[grow]]
    return out


def hybrid_objects(frames: np.ndarray, context: np.ndarray, max_objects: int) -> np.ndarray:
    """Background subtraction first, completed by the segmenter (``mask_method: hybrid``).

    Background subtraction (:func:`pipeline.video.pseudo_masks`, tracked and filtered as the
    ``median`` method does: :func:`keep_objects`) is what holds on real video, but it marks only
    what moves, as crescents where an object is slow. The segmenter (:mod:`pipeline.segmenter`)
    gives whole silhouettes of objects moving or at rest, but on real video it also marks scenery
    (rulers, holders, a keyboard). So:

    * each moving track of background subtraction is kept; in each frame the segmenter's
      tracks' masks that overlap its mask (by at least 30 % of the component) replace the mask when
      they cover at least 60 % of it (the segmenter agrees: its silhouette is whole, and split
      where two objects touch), else are added to it;
    * a segmenter track that no kept track overlaps is added when it is compact (rotated box at
      most 3:1, at least half full) and its median area is within 1/16..16 times the movers'
      median (objects of one scene are of one size class: a ruler or a desk edge is not), or when
      its centroid travels at least half its diameter (a mover background subtraction missed):
      this is how **objects at rest** are found.

    Movers first, then the added tracks (movers before objects at rest, larger first), at most
    ``max_objects``.

    Returns:
        ``(T, H, W)`` int8 object ids, -1 background.
    """
    fg, contact = shipped()(frames, median_background(context))
    fg = fg > FG_THRESHOLD
    sg = _segmenter_tracks(fg, contact > 0.5, 16)
    T = len(frames)
    bs = label_objects(pseudo_masks(frames, background=context), max_objects=max_objects)
    bs, _ = keep_objects(hold_resting(bs), None, max_objects)
    out = np.full(sg.shape, -1, np.int8)
    n = int(bs.max()) + 1
    for t in range(T):
        for k in range(n):
            mk = bs[t] == k
            if not mk.any():
                continue
            hit = np.zeros_like(mk)
            for j in np.unique(sg[t][mk]):
                cm = sg[t] == j
                if j >= 0 and (cm & mk).sum() >= 0.3 * cm.sum():
                    hit |= cm
            mask = hit if (hit & mk).sum() >= 0.6 * mk.sum() else (hit | mk)
            out[t][mask & (out[t] < 0)] = k
    extra_move, extra_rest = [], []
    tracks = find_tracks(sg, None, min_frames=max(3, int(0.15 * T)))
    movers = [float(np.median((bs == k).sum(axis=(1, 2))[(bs == k).any(axis=(1, 2))])) for k in range(n)]
    for tr in tracks:
        m = sg == tr.label
        if (m & (out >= 0)).sum() > 0.2 * m.sum():
            continue
        if tr.travel >= 0.5 * tr.diameter:
            extra_move.append(tr)
        elif tr.size[0] <= 3.0 * tr.size[1] and tr.fill >= 0.5:
            ref = float(np.median(movers)) if movers else None
            if ref is None or ref / 16 <= float(np.median(tr.area)) <= 16 * ref:
                extra_rest.append(tr)
    extra = sorted(extra_move, key=lambda t: -len(t.frames)) + sorted(extra_rest, key=lambda t: -float(np.median(t.area)))
    for tr in extra[: max(0, max_objects - n)]:
        out[(sg == tr.label) & (out < 0)] = n
        n += 1
    return out


def _keep_components(mask: np.ndarray, min_area: int) -> np.ndarray:
    """The 8-connected components of ``mask`` with at least ``min_area`` px (bool)."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    keep = np.flatnonzero(stats[:, cv2.CC_STAT_AREA] >= min_area)
    return np.isin(labels, keep[keep > 0])


def _masks(frames: np.ndarray, context: np.ndarray, method: str, max_objects: int) -> np.ndarray:
    return segment_objects(frames, context, method, max_objects)


def keep_objects(seg: np.ndarray, flow: np.ndarray, max_objects: int, still: bool = False
                 ) -> tuple[np.ndarray, list]:
    """Pseudo masks of the objects only. With ``still`` (masks from the segmenter, which sees
    objects at rest too) the tracks of :func:`still_tracks` are kept, moving or not. Otherwise
    (background subtraction) tracks that touch all along are merged
    (:func:`merge_touching`), ghosts of resting objects dropped (:func:`drop_ghosts`), then the
    tracks :func:`pipeline.perception.object_tracks` accepts
    (they move, they are not slivers) are kept, renumbered 0..n-1 in order of first appearance;
    everything else becomes background.

    Returns:
        ``(seg, tracks)``: ``(T, H, W)`` int8 labels and the kept
        :class:`pipeline.perception.Track` s (with their labels before renumbering).
    """
    if still:
        tracks = still_tracks(seg, max_objects)
    else:
        seg = drop_ghosts(merge_touching(seg))
        tracks = object_tracks(seg, flow, max_objects)
    lut = np.full(int(seg.max()) + 2, -1, dtype=np.int8)
    for new, t in enumerate(tracks):
        lut[t.label] = new
    return lut[seg.astype(np.int64)], tracks  # index -1 (background) -> lut[-1] = -1


def motion_crop(seg: np.ndarray, diameter: float, scale: float, orig_size: tuple[int, int]
                ) -> tuple[int, int, int, int]:
    """Crop box of the region of motion, in original px.

    Args:
        seg: ``(T, h, w)`` int8 labels of the detection pass, objects only (:func:`keep_objects`).
        diameter: median object diameter in the detection pass, px (the padding is two of them).
        scale: original px per detection px.
        orig_size: ``(W, H)`` of the video, px.
    Returns:
        ``(x, y, w, h)``: the box of everything the objects cover over the window, padded, grown
        to the aspect ratio of the video and shifted (then clipped) to lie inside the frame.
    """
    W0, H0 = orig_size
    fg = seg >= 0
    if not fg.any():
        return (0, 0, W0, H0)
    vs, us = np.nonzero(fg.any(axis=0))
    pad = 2.0 * diameter * scale
    x0, x1 = us.min() * scale - pad, (us.max() + 1) * scale + pad
    y0, y1 = vs.min() * scale - pad, (vs.max() + 1) * scale + pad
    aspect = W0 / H0
    w, h = x1 - x0, y1 - y0
    if w / h < aspect:
        w = h * aspect
    else:
        h = w / aspect
    w, h = min(w, W0), min(h, H0)
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    x = min(max(cx - w / 2, 0.0), W0 - w)
    y = min(max(cy - h / 2, 0.0), H0 - h)
    return (int(round(x)), int(round(y)), int(round(w)), int(round(h)))


def working_size(crop: tuple[int, int, int, int], diameter: float) -> tuple[int, int]:
    """``(W, H)`` px of the working image for a crop (module docstring); even sizes."""
    _, _, w, h = crop
    long_side = max(w, h)
    want = long_side * MIN_OBJECT_DIAMETER / max(diameter, 1e-6)
    L = int(min(max(want, MIN_LONG_SIDE), MAX_LONG_SIDE))
    s = L / long_side
    return max(2, round(w * s / 2) * 2), max(2, round(h * s / 2) * 2)


def observe(video, fps: float | None, start: float | None, scene_fps: int, duration: float,
            flow_method: str = "dis", flow_preset: str = "medium", mask_method: str = "median",
            max_objects: int = 4) -> Observation:
    """Read a window of a real video at its working crop and size; pseudo masks and flow.

    Args:
        video: video file.
        fps: true frame rate (overrides the container's), or None.
        start: window start, s; None chooses it (:func:`choose_start`).
        scene_fps: frame rate of the result (the scene's), frames per second.
        duration: window length, s.
        flow_method, flow_preset: optical flow (``pipeline.flow.estimate_flow``); ``gt`` means
            DIS here (a real video has no simulator truth).
        mask_method: background model of the pseudo masks (``pipeline.video.pseudo_masks``).
        max_objects: objects kept by the tracker.
    Raises:
        VideoError: unreadable video or window past its end.
    """
    auto = start is None
    if auto:
        start = choose_start(video, fps, scene_fps, duration)
    probe = read_video(video, fps=fps, max_frames=1)
    W0, H0 = probe.original_size
    dsize = _detect_size(W0, H0)
    span = duration + 1.0 / scene_fps

    def window(size, crop):
        clip = read_video(video, fps=fps, start=start, duration=span, size=size, crop=crop)
        if clip.duration + 0.5 / clip.fps < duration:
            raise VideoError(f"{video}: only {clip.duration:.3f} s after start={start:g} s, need {duration:g} s")
        ctx = read_video(video, fps=fps, size=size, crop=crop, max_frames=int(20 * clip.fps))
        step = max(1, len(ctx.frames) // 120)
        return clip, resample(clip.frames, clip.fps, scene_fps, duration), ctx.frames[::step]

    full = (0, 0, W0, H0)
    _, det_frames, det_ctx = window(dsize, full)
    det_seg = _masks(det_frames, det_ctx, mask_method, max_objects)
    det_flow = estimate_flow(det_frames, method="dis", preset="fast")
    learned = mask_method in LEARNED
    det_seg, tracks = keep_objects(det_seg if learned else hold_resting(det_seg), det_flow, max_objects, learned)
    scale = W0 / dsize[0]
    diameter = float(np.median([t.diameter for t in tracks])) if tracks else 0.05 * dsize[1]
    crop = motion_crop(det_seg, diameter, scale, (W0, H0))
    size = working_size(crop, diameter * scale)
    clip, frames, ctx = window(size, crop)
    seg = _masks(frames, ctx, mask_method, max_objects)
    method = "dis" if flow_method == "gt" else flow_method
    flow = estimate_flow(frames, method=method, preset=flow_preset)
    seg, _ = keep_objects(seg if learned else hold_resting(seg), flow, max_objects, learned)
    return Observation(frames, seg, flow, clip, float(start), auto, clip.crop, size, scene_fps, method, mask_method)


def original_frames(obs: Observation, video, fps: float | None, height: int = 320) -> np.ndarray:
    """The window's frames cut from the original video at the working crop, ``height`` px high
    (for people: contact sheets, side-by-side video), at the scene fps. ``(T, height, W', 3)``."""
    x, y, w, h = obs.crop
    s = height / h
    size = (max(2, round(w * s / 2) * 2), height)
    clip = read_video(video, fps=fps, start=obs.start, duration=len(obs.frames) / obs.scene_fps + 1.0 / obs.scene_fps,
                      size=size, crop=obs.crop)
    return resample(clip.frames, clip.fps, obs.scene_fps, len(obs.frames) / obs.scene_fps)


def observe_frames(video, fps: float | None, frame_indices, size: tuple[int, int] | None = None,
                   max_objects: int = 4, mask_method: str = "median") -> np.ndarray:
    """The observation's masks of chosen source frames of a whole clip (for scoring against hand
    labels, which are spread over the clip rather than one window): the same masks as
    :func:`observe`, tracked over the whole clip at ``size`` (at most :data:`MAX_LONG_SIDE` px long,
    scaled up to ``size``; :func:`pipeline.video.pseudo_ground_truth` or the segmenter),
    keeping the tracks that are objects (seen in 4 tracked frames or more, the centroid travels half
    a diameter, a median area within 1/4..4 times that of the track seen longest, the
    ``max_objects`` seen longest; no flow over the whole clip, so no flow check).

    Returns:
        ``(len(frame_indices), H, W)`` int8 object ids, -1 background.
    Raises:
        VideoError: unreadable video or a frame index out of range.
    """
    def objects(seg: np.ndarray) -> np.ndarray:
        tracks = sorted((t for t in find_tracks(seg, None, min_frames=4) if t.travel >= 0.5 * t.diameter),
                        key=lambda t: -len(t.frames))
        if tracks:   # sizes relative to the track seen longest (a hand or a person passes briefly)
            ref = float(np.median(tracks[0].area))
            tracks = [t for t in tracks if 0.25 * ref <= float(np.median(t.area)) <= 4.0 * ref]
        tracks = tracks[:max_objects]
        lut = np.full(int(seg.max()) + 2, -1, dtype=np.int8)
        for new, t in enumerate(tracks):
            lut[t.label] = new
        return lut[seg.astype(np.int64)]

    # at most the working size's upper bound (MAX_LONG_SIDE), labels scaled up to ``size``
    probe = read_video(video, fps=fps, max_frames=1)
    W, H = size or probe.original_size
    s = min(1.0, MAX_LONG_SIDE / max(W, H))
    work = (max(2, round(W * s / 2) * 2), max(2, round(H * s / 2) * 2))
    if mask_method not in LEARNED:
        out = pseudo_ground_truth(video, fps, frame_indices, work, max_objects=max_objects, keep=objects,
                                  method=mask_method, crop=(0, 0, *probe.original_size))
        return upscale(out, (W, H)) if (W, H) != work else out
    # the segmenter sees objects at rest too: every track seen often enough is kept (still_tracks)
    clip = read_video(video, fps=fps, size=work, crop=(0, 0, *probe.original_size))
    n = len(clip.frames)
    wanted = [int(i) for i in frame_indices]
    bad = [i for i in wanted if not 0 <= i < n]
    if bad:
        raise VideoError(f"{video}: frame_indices {bad} outside 0..{n - 1}")
    tracked = sorted(set(range(0, n, max(1, n // 200))) | set(wanted))
    fit = np.unique(np.linspace(0, n - 1, min(n, 150)).round().astype(int))
    seg = segment_objects(clip.frames[tracked], clip.frames[fit], mask_method, max_objects)
    seg, _ = keep_objects(seg, None, max_objects, still=True)
    where = {t: k for k, t in enumerate(tracked)}
    out = seg[[where[i] for i in wanted]]
    return upscale(out, (W, H)) if (W, H) != work else out


def source_frames(obs: Observation) -> np.ndarray:
    """``(T,)`` int64 source-frame indices (0-based, as decoded) of the window's frames:
    ``start_frame + rint(k * fps / scene_fps)`` (:func:`pipeline.video.resample`)."""
    T = len(obs.frames)
    return obs.clip.start_frame + np.rint(np.arange(T) * (obs.clip.fps / obs.scene_fps)).astype(np.int64)


def truth_in_window(seg: np.ndarray, obs: Observation) -> tuple[np.ndarray, np.ndarray]:
    """True labels of a whole clip as the observation sees them: the window's source frames, cut
    to the working crop and resized (nearest) to the working size.

    Args:
        seg: ``(N, H0, W0)`` int labels of every source frame at the original size, -1 background.
        obs: the observation (:func:`observe`).
    Returns:
        ``(seg, frames)``: ``(T, H, W)`` int8 labels and ``(T,)`` int64 source-frame indices.
    Raises:
        ValueError: ``seg`` does not cover the window or has another frame size than the video.
    """
    seg = np.asarray(seg)
    idx = source_frames(obs)
    W0, H0 = obs.clip.original_size
    if seg.ndim != 3 or seg.shape[1:] != (H0, W0) or idx[-1] >= len(seg):
        raise ValueError(f"seg: must be (>= {idx[-1] + 1}, {H0}, {W0}) labels of the whole clip, got {seg.shape}")
    x, y, w, h = obs.crop
    return upscale(seg[idx, y:y + h, x:x + w].astype(np.int8), obs.size), idx


def upscale(seg: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Nearest-neighbour resize of ``(T, H, W)`` labels to ``size = (W', H')``."""
    return np.stack([cv2.resize(s.astype(np.int16), size, interpolation=cv2.INTER_NEAREST) for s in seg]).astype(seg.dtype)
