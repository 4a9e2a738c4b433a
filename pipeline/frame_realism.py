"""What real camera frames show and the project's renders do not, added to the segmenter's training
batches (issue 36).

The object segmenter (:mod:`pipeline.segmenter`) is trained on randomised MuJoCo renders: a floor,
1-4 primitives, nothing else. On real clips it then marks scenery as objects (rulers, rails,
shelves, holders, printed legends) and its difference channel lights up where the camera shakes or
the exposure drifts. This module draws, per training image:

* **static scenery** (:func:`draw_scenery`): long bars across the frame with tick marks (rulers,
  rails, table edges), large boards entering from a border (shelves, backdrops), printed text,
  and large flat polygons. Scenery is part of the background: it is drawn into the RGB channels
  only (the median background holds it too, so its difference is ~0) and its pixels are
  background in the targets. It is drawn behind the objects (where no object is) or, sometimes,
  in front of them (an occluder);
* **difference-channel noise** (:func:`camera_noise`): a global exposure change between the frame
  and the background (the difference grows with the intensity), a sub-pixel camera shake (the
  difference grows with the image gradient), defocus blur and sensor noise;
* **zoom-out** (:func:`zoom_out`): the frame shrunk into a reflect-padded canvas, so objects appear
  down to ~1/3 of their rendered size (real balls after the working crop are 5-25 px).

For the model's training clips (the ``render`` stage, ``render.camera_effects``),
:func:`camera_effects` degrades a rendered uint8 clip as a camera records it: defocus and
camera-shake blur, an exposure drift, sensor noise and JPEG compression.

Conventions are :func:`pipeline.segmenter.network_input`'s: ``x`` is ``(B, 4, H, W)`` float32,
RGB / 255 - 0.5 then the largest RGB difference / 255; ``y`` is ``(B, 2, H, W)`` float32 targets
(foreground, contact). All functions work in place on numpy arrays and draw from a
``numpy.random.Generator``, so a seeded run is repeatable.
"""

from __future__ import annotations

import string

import cv2
import numpy as np

P_SCENERY = 0.5
"""Probability that a training image gets 1-4 pieces of static scenery."""
P_IN_FRONT = 0.3
"""Probability that a piece of scenery is drawn in front of the objects (an occluder)."""
P_NOISE = 0.5
"""Probability that a training image gets difference-channel noise and blur."""
P_ZOOM_OUT = 0.25
"""Probability that a training image is shrunk by 1-2.5x into a reflect-padded canvas."""


def _bar(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """uint8 (h, w) mask of a long band across the frame (ruler, rail, table edge), tick marks cut out."""
    m = np.zeros((h, w), np.uint8)
    ang = rng.uniform(-0.5, 0.5) if rng.random() < 0.7 else rng.uniform(0, np.pi)
    c = np.array([rng.uniform(0, w), rng.uniform(0, h)])
    d = np.array([np.cos(ang), np.sin(ang)]) * 2 * (w + h)
    thick = int(rng.integers(2, max(3, h // 8)))
    p0, p1 = (c - d).astype(int), (c + d).astype(int)
    cv2.line(m, tuple(p0.tolist()), tuple(p1.tolist()), 1, thick)
    if thick >= 4 and rng.random() < 0.6:                       # tick marks of a ruler
        step = int(rng.integers(3, 9))
        normal = np.array([-np.sin(ang), np.cos(ang)])
        for s in np.arange(-2 * (w + h), 2 * (w + h), step):
            a = c + np.array([np.cos(ang), np.sin(ang)]) * s + normal * thick * 0.5
            b = a - normal * thick * rng.uniform(0.2, 0.6)
            cv2.line(m, tuple(a.astype(int).tolist()), tuple(b.astype(int).tolist()), 2, 1)
    return m


def _board(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """uint8 (h, w) mask of a large quadrilateral entering from a border (shelf, backdrop, holder)."""
    m = np.zeros((h, w), np.uint8)
    side = rng.integers(4)
    depth = rng.uniform(0.15, 0.5)
    a, b = sorted(rng.uniform(0, 1, 2))
    b = max(b, a + 0.3)
    if side in (0, 1):                                          # top / bottom
        y0 = 0 if side == 0 else h - 1
        y1 = depth * h if side == 0 else h - 1 - depth * h
        pts = [(a * w, y0), (b * w, y0), (b * w + rng.normal(0, 0.1 * w), y1), (a * w + rng.normal(0, 0.1 * w), y1)]
    else:                                                       # left / right
        x0 = 0 if side == 2 else w - 1
        x1 = depth * w if side == 2 else w - 1 - depth * w
        pts = [(x0, a * h), (x0, b * h), (x1, b * h + rng.normal(0, 0.1 * h)), (x1, a * h + rng.normal(0, 0.1 * h))]
    cv2.fillPoly(m, [np.array(pts, np.int32)], 1)
    return m


def _text(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """uint8 (h, w) mask of a line of printed text (legends, labels, scale numbers)."""
    m = np.zeros((h, w), np.uint8)
    chars = string.ascii_letters + string.digits + " .:-"
    txt = "".join(rng.choice(list(chars), size=int(rng.integers(3, 14))))
    scale = rng.uniform(0.25, 0.8)
    org = (int(rng.uniform(-0.2, 0.8) * w), int(rng.uniform(0.1, 1.0) * h))
    cv2.putText(m, txt, org, int(rng.choice([cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_PLAIN])), scale, 1,
                int(rng.integers(1, 3)), cv2.LINE_AA)
    return m


def _polygon(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """uint8 (h, w) mask of a large flat irregular polygon (a mat, a sheet of paper, a patch of wall)."""
    m = np.zeros((h, w), np.uint8)
    c = np.array([rng.uniform(0, w), rng.uniform(0, h)])
    r = rng.uniform(0.25, 0.6) * min(h, w)
    ang = np.sort(rng.uniform(0, 2 * np.pi, int(rng.integers(4, 9))))
    rad = r * rng.uniform(0.6, 1.4, len(ang))
    pts = c + np.stack([np.cos(ang) * rad, np.sin(ang) * rad], axis=1) * np.array([1.0, rng.uniform(0.2, 1.0)])
    cv2.fillPoly(m, [pts.astype(np.int32)], 1)
    return m


KINDS = {"bar": (_bar, 0.4), "board": (_board, 0.25), "text": (_text, 0.2), "polygon": (_polygon, 0.15)}
"""Scenery kinds: (mask drawer, probability)."""


def draw_scenery(x: np.ndarray, y: np.ndarray, rng: np.random.Generator, p: float = P_SCENERY) -> None:
    """Draw static scenery into a batch, in place (module docstring).

    Args:
        x: ``(B, 4, H, W)`` float32 network inputs.
        y: ``(B, 2, H, W)`` float32 targets; scenery drawn in front of an object clears its pixels.
        rng: random generator.
        p: probability per image.
    """
    B, _, H, W = x.shape
    names = list(KINDS)
    probs = np.array([KINDS[k][1] for k in names])
    for b in range(B):
        if rng.random() >= p:
            continue
        for _ in range(int(rng.integers(1, 5))):
            kind = names[rng.choice(len(names), p=probs / probs.sum())]
            m = KINDS[kind][0](H, W, rng)
            if not m.any():
                continue
            base = rng.uniform(0.05, 0.95, 3) if rng.random() < 0.7 else np.full(3, rng.uniform(0.05, 0.95))
            # a linear shading ramp across the frame and a darker colour for marks (ticks: label 2)
            gy, gx = np.mgrid[0:H, 0:W].astype(np.float32)
            ramp = 1 + rng.uniform(-0.3, 0.3) * (gx / W - 0.5) + rng.uniform(-0.3, 0.3) * (gy / H - 0.5)
            colour = np.clip(base[:, None, None] * ramp[None], 0, 1)
            marks = np.clip(base * rng.uniform(0.1, 0.5), 0, 1) if rng.random() < 0.8 else 1 - base
            colour = np.where((m == 2)[None], marks[:, None, None], colour)
            front = rng.random() < P_IN_FRONT
            where = (m > 0) if front else (m > 0) & (y[b, 0] < 0.5)
            x[b, :3][:, where] = colour[:, where] - 0.5
            x[b, 3][where] = np.abs(rng.normal(0, 0.01, int(where.sum())))
            if front:
                y[b][:, where] = 0.0


def camera_noise(x: np.ndarray, rng: np.random.Generator, p: float = P_NOISE) -> None:
    """Exposure change, camera shake, defocus blur and sensor noise, in place (module docstring).

    Args:
        x: ``(B, 4, H, W)`` float32 network inputs.
        rng: random generator.
        p: probability per image.
    """
    for b in range(len(x)):
        if rng.random() >= p:
            continue
        rgb = np.ascontiguousarray(x[b, :3].transpose(1, 2, 0)) + 0.5
        lum = rgb.mean(axis=-1)
        if rng.random() < 0.5:                                  # exposure: |g - 1| * intensity
            x[b, 3] = np.maximum(x[b, 3], rng.uniform(0.0, 0.1) * lum)
        if rng.random() < 0.5:                                  # shake of s px: ~ s * |gradient|
            gx = cv2.Sobel(lum, cv2.CV_32F, 1, 0, ksize=3) / 8
            gy = cv2.Sobel(lum, cv2.CV_32F, 0, 1, ksize=3) / 8
            x[b, 3] = np.maximum(x[b, 3], rng.uniform(0.2, 1.2) * np.hypot(gx, gy))
        if rng.random() < 0.5:                                  # defocus / motion-free blur
            rgb = cv2.GaussianBlur(rgb, (0, 0), rng.uniform(0.5, 1.5))
        rgb = rgb + rng.normal(0, rng.uniform(0.0, 0.04), rgb.shape).astype(np.float32)
        x[b, :3] = np.clip(rgb, 0, 1).transpose(2, 0, 1) - 0.5


def zoom_out(x: np.ndarray, y: np.ndarray, rng: np.random.Generator, p: float = P_ZOOM_OUT,
             factor: tuple[float, float] = (1.0, 2.5)) -> None:
    """Shrink images by ``factor`` into a reflect-padded canvas of the same size, in place.

    The reflected copies of objects are objects in the targets too, so inputs and targets agree.

    Args:
        x: ``(B, 4, H, W)`` float32 network inputs.
        y: ``(B, 2, H, W)`` float32 targets.
        rng: random generator.
        p: probability per image.
        factor: range of the shrink factor.
    """
    B, _, H, W = x.shape
    for b in range(B):
        if rng.random() >= p:
            continue
        f = rng.uniform(*factor)
        h, w = max(8, int(H / f)), max(8, int(W / f))
        top, left = int(rng.integers(0, H - h + 1)), int(rng.integers(0, W - w + 1))
        xs = cv2.resize(np.ascontiguousarray(x[b].transpose(1, 2, 0)), (w, h), interpolation=cv2.INTER_AREA)
        ys = cv2.resize(np.ascontiguousarray(y[b].transpose(1, 2, 0)), (w, h), interpolation=cv2.INTER_NEAREST)
        pad = (top, H - h - top, left, W - w - left)
        x[b] = cv2.copyMakeBorder(xs, *pad, cv2.BORDER_REFLECT_101).reshape(H, W, -1).transpose(2, 0, 1)
        y[b] = cv2.copyMakeBorder(ys, *pad, cv2.BORDER_REFLECT_101).reshape(H, W, -1).transpose(2, 0, 1)


def realism(x: np.ndarray, y: np.ndarray, rng: np.random.Generator) -> None:
    """All three, in place, in the order zoom-out, scenery, camera noise."""
    zoom_out(x, y, rng)
    draw_scenery(x, y, rng)
    camera_noise(x, rng)


# --------------------------------------------------------------------------- rendered clips
CAMERA_BLUR_SIGMA = (0.3, 1.2)
"""px: range of the defocus blur's Gaussian sigma (:func:`camera_effects`)."""
CAMERA_MOTION_BLUR = (2, 5)
"""px: range of the length of the camera-shake motion blur kernel."""
CAMERA_GAIN = (0.85, 1.15)
"""Range of the exposure gain the clip drifts to from 1 over its length (auto-exposure)."""
CAMERA_NOISE_STD = (1.0, 6.0)
"""Grey levels: range of the standard deviation of the per-frame sensor noise."""
CAMERA_JPEG_QUALITY = (35, 90)
"""Range of the JPEG quality the frames are compressed at (a phone's video codec)."""


def camera_effects(rgb: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A rendered clip as a camera would have recorded it (issue 30: training frames that look
    like real ones): per clip, each with probability 1/2, a defocus blur
    (:data:`CAMERA_BLUR_SIGMA`), a motion blur of a camera shake (a line kernel of
    :data:`CAMERA_MOTION_BLUR` px at a random angle), an exposure drift (the gain moves linearly
    from 1 to a value in :data:`CAMERA_GAIN` over the clip) and JPEG compression
    (:data:`CAMERA_JPEG_QUALITY`); always sensor noise (Gaussian, fresh in every frame, sigma in
    :data:`CAMERA_NOISE_STD`). Only the pixels change: the clip's truth (masks, depth, flow) is
    the rendered one.

    Args:
        rgb: ``(T, H, W, 3)`` uint8 RGB frames.
        rng: the clip's random generator (a seeded one repeats the clip exactly).
    Returns:
        ``(T, H, W, 3)`` uint8, a new array.
    Raises:
        ValueError: not a ``(T, H, W, 3)`` uint8 array.
    """
    if rgb.ndim != 4 or rgb.shape[-1] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"camera_effects: rgb must be (T, H, W, 3) uint8, got {rgb.shape} {rgb.dtype}")
    T = len(rgb)
    blur = float(rng.uniform(*CAMERA_BLUR_SIGMA)) if rng.random() < 0.5 else 0.0
    kernel = None
    if rng.random() < 0.5:
        n = int(rng.integers(CAMERA_MOTION_BLUR[0], CAMERA_MOTION_BLUR[1] + 1))
        kernel = np.zeros((n, n), np.float32)
        kernel[n // 2] = 1.0
        rot = cv2.getRotationMatrix2D(((n - 1) / 2, (n - 1) / 2), float(rng.uniform(0, 180)), 1.0)
        kernel = cv2.warpAffine(kernel, rot, (n, n))
        kernel /= max(float(kernel.sum()), 1e-6)
    gain_end = float(rng.uniform(*CAMERA_GAIN)) if rng.random() < 0.5 else 1.0
    quality = int(rng.integers(CAMERA_JPEG_QUALITY[0], CAMERA_JPEG_QUALITY[1] + 1)) if rng.random() < 0.5 else None
    noise = float(rng.uniform(*CAMERA_NOISE_STD))
    out = np.empty_like(rgb)
    for t in range(T):
        f = rgb[t].astype(np.float32)
        if blur > 0:
            f = cv2.GaussianBlur(f, (0, 0), blur)
        if kernel is not None:
            f = cv2.filter2D(f, -1, kernel, borderType=cv2.BORDER_REFLECT_101)
        f *= 1.0 + (gain_end - 1.0) * (t / max(T - 1, 1))
        f += rng.normal(0.0, noise, f.shape).astype(np.float32)
        frame = np.clip(np.rint(f), 0, 255).astype(np.uint8)
        if quality is not None:
            _, buf = cv2.imencode(".jpg", cv2.cvtColor(frame, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])
            frame = cv2.cvtColor(cv2.imdecode(buf, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
        out[t] = frame
    return out
