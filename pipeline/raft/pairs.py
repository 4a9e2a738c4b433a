"""Procedural FlyingChairs-style image pairs with exact flow, for training RAFT here.

FlyingChairs (Dosovitskiy et al., "FlowNet", ICCV 2015) pastes textured objects on a
textured background and moves every layer by its own affine transform; the flow follows in closed
form. No chair models or photo collections can be downloaded here, so the layers are made
procedurally: smooth noise, stripes, checkers and blobs in random colours, cut into ellipses and
polygons; and, where a *texture bank* is given (:func:`texture_bank`: frames of real videos),
half the layers are random crops of real frames, as FlyingChairs pastes Flickr photos.

For a layer moved by the affine map ``x' = A x + b`` (pixels), a pixel ``x`` of image 1 that
shows the layer moves to ``A x + b`` in image 2, so its flow is ``(A - I) x + b``. Image 1 shows
every layer at its place; image 2 shows every layer warped by its map, composited in the same
order (later layers on top). The flow of a pixel is that of the topmost layer covering it in
image 1 (as in FlyingChairs, pixels that become occluded keep their flow).

Example::

    rng = np.random.default_rng(0)
    img1, img2, flow = chairs_pair(rng, height=128, width=192)
    # img1, img2: (128, 192, 3) uint8; flow: (128, 192, 2) float32 px (u, v)
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from pipeline.video import read_video


PHOTO_FRACTION = 0.5
"""Share of layers cut from the texture bank when one is given."""


def texture_bank(paths: list[str | Path], per_video: int = 24, size: tuple[int, int] = (192, 144)) -> np.ndarray:
    """Frames of real videos to cut chairs-pair layers from.

    Args:
        paths: video files (anything :func:`pipeline.video.read_video` decodes).
        per_video: frames taken per video, evenly spaced over its length.
        size: ``(width, height)`` px of the stored frames (centre crop, then ``INTER_AREA``).

    Returns:
        ``(N, height, width, 3)`` uint8 RGB, ``N = per_video * len(paths)`` (fewer for short videos).

    Raises:
        pipeline.video.VideoError: a file that cannot be decoded.
        ValueError: no paths.
    """
    if not paths:
        raise ValueError("texture_bank: no video paths")
    out = []
    for path in paths:
        frames = read_video(path, size=size).frames
        idx = np.unique(np.linspace(0, len(frames) - 1, per_video).round().astype(int))
        out.append(frames[idx])
    return np.concatenate(out)


def _photo(rng: np.random.Generator, bank: np.ndarray, h: int, w: int) -> np.ndarray:
    """A random crop of a random bank frame, resized to ``(h, w, 3)`` float32, flipped at random."""
    img = bank[int(rng.integers(len(bank)))]
    H, W = img.shape[:2]
    zoom = rng.uniform(0.35, 1.0)
    ch, cw = max(8, int(H * zoom)), max(8, int(min(W, H * zoom * w / h)))
    y0, x0 = int(rng.integers(H - ch + 1)), int(rng.integers(W - cw + 1))
    tex = cv2.resize(img[y0:y0 + ch, x0:x0 + cw], (w, h), interpolation=cv2.INTER_LINEAR).astype(np.float32)
    if rng.random() < 0.5:
        tex = tex[:, ::-1]
    if rng.random() < 0.5:
        tex = tex[::-1]
    return np.ascontiguousarray(tex)


def _texture(rng: np.random.Generator, h: int, w: int, bank: np.ndarray | None = None) -> np.ndarray:
    """A random ``(h, w, 3)`` float32 texture in [0, 255]: a crop of a bank frame (share
    :data:`PHOTO_FRACTION` when ``bank`` is given), else smooth noise, stripes, a checker or
    blobs, in one or two random colours, with fine noise on top."""
    if bank is not None and len(bank) and rng.random() < PHOTO_FRACTION:
        return _photo(rng, bank, h, w)
    kind = rng.integers(4)
    if kind == 0:      # smooth noise at a random scale
        cells = int(rng.integers(2, 16))
        base = cv2.resize(rng.random((cells, max(cells * w // max(h, 1), 2))).astype(np.float32), (w, h),
                          interpolation=cv2.INTER_CUBIC)
    elif kind == 1:    # stripes at a random angle and period
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        theta, period = rng.uniform(0, np.pi), rng.uniform(4, 24)
        base = 0.5 + 0.5 * np.sin(2 * np.pi * (xx * np.cos(theta) + yy * np.sin(theta)) / period)
    elif kind == 2:    # checker
        yy, xx = np.mgrid[0:h, 0:w]
        sq = int(rng.integers(3, 20))
        base = ((xx // sq + yy // sq) % 2).astype(np.float32)
        base = cv2.GaussianBlur(base, (0, 0), rng.uniform(0.3, 1.0))
    else:              # blobs
        base = np.zeros((h, w), np.float32)
        for _ in range(int(rng.integers(5, 30))):
            c = (int(rng.integers(w)), int(rng.integers(h)))
            cv2.circle(base, c, int(rng.integers(2, max(3, min(h, w) // 4))), float(rng.random()), -1)
        base = cv2.GaussianBlur(base, (0, 0), 1.0)
    base = np.clip(base, 0, 1)[..., None]
    c0, c1 = rng.uniform(0, 255, 3), rng.uniform(0, 255, 3)
    tex = c0 * (1 - base) + c1 * base
    tex += rng.normal(0, rng.uniform(0, 8), tex.shape)
    return np.clip(tex, 0, 255).astype(np.float32)


def _shape_mask(rng: np.random.Generator, h: int, w: int, size: float) -> np.ndarray:
    """A ``(h, w)`` float32 {0, 1} mask of an ellipse or polygon about ``size`` px across,
    at a random place."""
    mask = np.zeros((h, w), np.float32)
    cx, cy = rng.uniform(0, w), rng.uniform(0, h)
    if rng.random() < 0.5:
        axes = (max(1, int(size / 2 * rng.uniform(0.5, 1))), max(1, int(size / 2 * rng.uniform(0.5, 1))))
        cv2.ellipse(mask, (int(cx), int(cy)), axes, float(rng.uniform(0, 180)), 0, 360, 1.0, -1)
    else:
        n = int(rng.integers(3, 9))
        ang = np.sort(rng.uniform(0, 2 * np.pi, n))
        rad = size / 2 * rng.uniform(0.4, 1.0, n)
        pts = np.stack([cx + rad * np.cos(ang), cy + rad * np.sin(ang)], axis=1).astype(np.int32)
        cv2.fillPoly(mask, [pts], 1.0)
    return mask


def _affine(rng: np.random.Generator, h: int, w: int, max_shift: float, max_rot: float,
            max_scale: float) -> np.ndarray:
    """A random ``(2, 3)`` affine map about a random centre: rotation (rad), scale, shift (px)."""
    rot, scale = rng.uniform(-max_rot, max_rot), np.exp(rng.uniform(-max_scale, max_scale))
    centre = np.array([rng.uniform(0, w), rng.uniform(0, h)])
    R = scale * np.array([[np.cos(rot), -np.sin(rot)], [np.sin(rot), np.cos(rot)]])
    shift = rng.uniform(-max_shift, max_shift, 2)
    return np.hstack([R, (centre - R @ centre + shift)[:, None]])


def _affine_flow(M: np.ndarray, xx: np.ndarray, yy: np.ndarray) -> np.ndarray:
    """``(H, W, 2)`` flow ``(A - I) x + b`` of the ``(2, 3)`` affine map ``M = [A | b]`` at pixel
    coordinates ``xx, yy`` (``(H, W)``, px)."""
    return np.stack([(M[0, 0] - 1) * xx + M[0, 1] * yy + M[0, 2],
                     M[1, 0] * xx + (M[1, 1] - 1) * yy + M[1, 2]], axis=-1)


def chairs_pair(rng: np.random.Generator, height: int = 128, width: int = 192, max_shift: float = 10.0,
                n_objects: tuple[int, int] = (1, 6), textures: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One procedural image pair and its exact forward flow (module docstring).

    Args:
        rng: the random generator (all randomness comes from it).
        height, width: image size, px.
        max_shift: largest translation of a layer, px (the background gets a third of it).
        n_objects: inclusive range of foreground layers.
        textures: optional ``(N, H, W, 3)`` uint8 bank (:func:`texture_bank`) to cut layers from.

    Returns:
        ``img1, img2``: ``(height, width, 3)`` uint8 RGB; ``flow``: ``(height, width, 2)``
        float32 px, ``(u, v)`` = (x, y) displacement from image 1 to image 2.
    """
    h, w = height, width
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    img1, img2 = _texture(rng, h, w, textures), np.empty((h, w, 3), np.float32)
    M = _affine(rng, h, w, max_shift / 3, 0.05, 0.05)
    img2[:] = cv2.warpAffine(img1, M, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    flow = _affine_flow(M, xx, yy)
    for _ in range(int(rng.integers(n_objects[0], n_objects[1] + 1))):
        size = rng.uniform(0.08, 0.6) * min(h, w)
        mask, tex = _shape_mask(rng, h, w, size), _texture(rng, h, w, textures)
        M = _affine(rng, h, w, max_shift, 0.2, 0.15)
        inside = mask > 0.5
        img1[inside] = tex[inside]
        flow[inside] = _affine_flow(M, xx, yy)[inside]
        warped_mask = cv2.warpAffine(mask, M, (w, h), flags=cv2.INTER_LINEAR)[..., None]
        warped_tex = cv2.warpAffine(tex, M, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        img2 = img2 * (1 - warped_mask) + warped_tex * warped_mask
    # image 1's object edges are hard; soften both alike so edges do not tell the frames apart
    img1 = cv2.GaussianBlur(img1, (0, 0), 0.5)
    img2 = cv2.GaussianBlur(img2.astype(np.float32), (0, 0), 0.5)
    return (np.clip(np.rint(img1), 0, 255).astype(np.uint8), np.clip(np.rint(img2), 0, 255).astype(np.uint8),
            flow.astype(np.float32))


def _object_texture(rng: np.random.Generator, h: int, w: int, bank: np.ndarray | None) -> np.ndarray:
    """What a small real object looks like: one flat colour under a soft linear shading across the
    frame (a ball, a puck, a painted block), or a procedural or real texture one time in three."""
    if rng.random() < 1 / 3:
        return _texture(rng, h, w, bank)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    theta = rng.uniform(0, 2 * np.pi)
    ramp = (xx * np.cos(theta) + yy * np.sin(theta)) / max(h, w)
    tex = rng.uniform(0, 255, 3) * (1 + rng.uniform(-0.6, 0.6) * ramp)[..., None]
    tex += rng.normal(0, rng.uniform(0, 3), tex.shape)
    return np.clip(tex, 0, 255).astype(np.float32)


def _motion_blur(img: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """``img`` averaged along the segment ``[-shift/2, shift/2]`` (px): the smear of an exposure
    during which the object moves by ``shift``."""
    n = int(np.ceil(np.linalg.norm(shift))) + 1
    if n <= 2:
        return img
    acc = np.zeros_like(img)
    for s in np.linspace(-0.5, 0.5, n):
        M = np.float32([[1, 0, s * shift[0]], [0, 1, s * shift[1]]])
        acc += cv2.warpAffine(img, M, (img.shape[1], img.shape[0]), flags=cv2.INTER_LINEAR)
    return acc / n


def still_camera_pair(rng: np.random.Generator, height: int = 128, width: int = 192, max_shift: float = 10.0,
                      n_objects: tuple[int, int] = (1, 4), textures: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A pair as a fixed camera films it: the background is the same image in both frames (zero
    flow) and a few *small* objects move over it, as in real clips of a ball or a puck.

    Chairs pairs (:func:`chairs_pair`) move the background too and draw objects of 8-60 % of the
    frame; real clips show a still scene and objects of a few pixels (4-30 px at RAFT's working
    size), often flat-coloured and smeared by the exposure. Here:

    - the background is a texture or, given ``textures``, a real frame half the time
      (:func:`_texture`), identical in both images;
    - ``n_objects`` objects, each ``size`` px across with ``log(size)`` uniform on
      ``[log 3, log(0.35 min(h, w))]``, flat-coloured with a shading ramp two times in three
      (:func:`_object_texture`), moved by an affine map about their own centre (rotation up to
      0.3 rad, scale up to 5 %, shift up to ``max_shift``);
    - a third of the objects are smeared in both images along their motion
      (:func:`_motion_blur`, over 30-100 % of the shift), the way a 1/30 s exposure smears a thrown ball.

    The flow is exact for the unsmeared layers (module docstring): ``(A - I) x + b`` on the pixels
    of image 1 that show an object, 0 elsewhere.

    Args and returns: as :func:`chairs_pair`.
    """
    h, w = height, width
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    bg = _texture(rng, h, w, textures)
    img1, img2 = bg.copy(), bg.copy()
    flow = np.zeros((h, w, 2), np.float64)
    for _ in range(int(rng.integers(n_objects[0], n_objects[1] + 1))):
        size = float(np.exp(rng.uniform(np.log(3.0), np.log(max(4.0, 0.35 * min(h, w))))))
        mask = _shape_mask(rng, h, w, size)
        if mask.sum() == 0:
            continue
        cy, cx = np.argwhere(mask > 0.5).mean(axis=0)
        rot, scale = rng.uniform(-0.3, 0.3), np.exp(rng.uniform(-0.05, 0.05))
        R = scale * np.array([[np.cos(rot), -np.sin(rot)], [np.sin(rot), np.cos(rot)]])
        shift = rng.uniform(-max_shift, max_shift, 2)
        centre = np.array([cx, cy])
        M = np.hstack([R, (centre - R @ centre + shift)[:, None]])
        tex = _object_texture(rng, h, w, textures)
        inside = mask > 0.5
        flow[inside] = _affine_flow(M, xx, yy)[inside]
        m1, t1 = mask[..., None], tex * mask[..., None]
        m2 = cv2.warpAffine(mask, M, (w, h), flags=cv2.INTER_LINEAR)[..., None]
        t2 = cv2.warpAffine(tex, M, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT) * m2
        if rng.random() < 1 / 3:
            smear = shift * rng.uniform(0.3, 1.0)
            m1, m2 = (_motion_blur(m[..., 0], smear)[..., None] for m in (m1, m2))
            t1, t2 = (_motion_blur(t, smear) for t in (t1, t2))
        img1 = img1 * (1 - m1) + t1
        img2 = img2 * (1 - m2) + t2
    img1 = cv2.GaussianBlur(img1.astype(np.float32), (0, 0), 0.5)
    img2 = cv2.GaussianBlur(img2.astype(np.float32), (0, 0), 0.5)
    return (np.clip(np.rint(img1), 0, 255).astype(np.uint8), np.clip(np.rint(img2), 0, 255).astype(np.uint8),
            flow.astype(np.float32))
