"""Truth clips: rendered videos with their true instance masks, states and labels, on disk.

One folder per clip (:data:`CLIP_DIR` inside a set folder), written whole or not at all
(:func:`pipeline.atomic.atomic_dir`):

* ``video.mp4``: RGB frames as a user would feed them to ``dynamics infer`` (fourcc ``mp4v``,
  lossy; the masks refer to the rendered frames before compression).
* ``truth.npz`` (:data:`TRUTH_FIELDS`):

  - ``seg (T, H, W) int8``: true instance id per pixel at video resolution, -1 background,
    ``0..n-1`` objects; the renderer decides occlusion (the visible object owns the pixel).
  - ``fps () float64``: frames per second.
  - ``motion (n,) str``: ``moving`` (moves throughout, or from when it is set moving to the
    end), ``stops`` (moves, then rests over at least the last :data:`REST_TAIL` s),
    ``still`` (rests the whole clip: every frame-to-frame speed below the rest thresholds and
    never more than :data:`STILL_DISPLACEMENT` from its first position).
  - ``enters``, ``leaves (n,) bool``: out of view in the first / last frame and in view in
    another one (in view: some pixel in ``seg``, or the projected centre inside the image).
  - ``pos (T, n, 3) float64``: centres, world frame, m; ``quat (T, n, 4) float64`` (w, x, y, z).
  - ``speed (T, n) float64``: centre speed, m/s (central differences of ``pos``).
  - ``touch (T, n, n) bool``: objects closer than :data:`TOUCH_DISTANCE` (symmetric).
  - ``intrinsics (3, 3) float64``: pinhole K, px (``pipeline.camera`` conventions: pixel
    centres at +0.5, principal point at the image centre).
  - ``extrinsics (4, 4) float64``: world -> camera (OpenCV frame: x right, y down, z forward),
    ``X_cam = E @ [X_world, 1]``.
  - ``engine () str``: ``mujoco`` or ``pybullet``.

* ``meta.json``: engine, seed, index, attempt, params (size, fps, duration), planned
  ``category`` and realised ``tags`` (:data:`pipeline.truthsets.scenario.CATEGORIES`),
  objects (shape, size, mass, colour, low_contrast, role, friction, initial state, labels),
  camera (pitch, yaw, fov in deg, position, distance), floor texture and light.

Example::

    clip = load_clip("/work/truthsets/mujoco/dev/clip-00003")
    clip.seg.shape, clip.motion, clip.meta["tags"]
    uv = clip.project(clip.pos[0])          # (n, 2) px of the centres in frame 0
"""

from __future__ import annotations

import json
import math
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import cv2
import numpy as np

from pipeline.atomic import atomic_dir, json_default
from pipeline.errors import UserError
from pipeline.truthsets.planning import sample_scenario
from pipeline.truthsets.scenario import CATEGORIES, Scenario, project
from pipeline.viz import Mp4Writer

CLIP_DIR = "clip-{:05d}"
"""Folder of clip ``index`` inside a set folder."""
FILES = ("video.mp4", "truth.npz", "meta.json")
"""Files of a complete clip folder."""
TRUTH_FIELDS = ("seg", "fps", "motion", "enters", "leaves", "pos", "quat", "speed", "touch", "intrinsics",
                "extrinsics", "engine")
"""Arrays of ``truth.npz``."""
GENERATOR_VERSION = 1
"""Bumped when the same (engine, seed, index, params) would give a different clip."""

REST_SPEED = 0.01
"""m/s: a centre slower than this between two frames is at rest (if it also turns slowly)."""
REST_SPIN = 0.1
"""rad/s: an orientation turning slower than this between two frames is at rest."""
STILL_DISPLACEMENT = 0.001
"""m: a ``still`` object never leaves its first position by more than this."""
REST_TAIL = 0.2
"""s: a ``stops`` object rests over at least this final part of the clip (3 intervals at least)."""
TOUCH_DISTANCE = 0.001
"""m: two objects closer than this touch."""


class TruthsetError(UserError, ValueError):
    """A truth clip on disk is missing or malformed (one line: file, field, rule)."""


@dataclass
class Rollout:
    """What an engine returns for one scenario (see the module docstring for the fields)."""

    rgb: np.ndarray            # (T, H, W, 3) uint8
    seg: np.ndarray            # (T, H, W) int8
    pos: np.ndarray            # (T, n, 3) float64, m
    quat: np.ndarray           # (T, n, 4) float64
    touch: np.ndarray          # (T, n, n) bool
    intrinsics: np.ndarray     # (3, 3) float64
    extrinsics: np.ndarray     # (4, 4) float64


@dataclass
class TruthClip:
    """A truth clip in memory (fields as ``truth.npz``, module docstring); ``rgb (T, H, W, 3)
    uint8`` is the rendered video (None when loaded without it); ``meta`` is meta.json."""

    seg: np.ndarray
    fps: float
    motion: np.ndarray
    enters: np.ndarray
    leaves: np.ndarray
    pos: np.ndarray
    quat: np.ndarray
    speed: np.ndarray
    touch: np.ndarray
    intrinsics: np.ndarray
    extrinsics: np.ndarray
    engine: str
    meta: dict[str, Any] = field(default_factory=dict)
    rgb: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return int(self.seg.shape[0])

    @property
    def n_objects(self) -> int:
        return int(self.pos.shape[1])

    def project(self, points: np.ndarray) -> np.ndarray:
        """World points (..., 3) m -> pixel coordinates (..., 2) through the true camera."""
        return project(points, self.intrinsics, self.extrinsics)[0]


# ---------------------------------------------------------------------------------------------
# Labels from the truth
# ---------------------------------------------------------------------------------------------


def speeds(pos: np.ndarray, quat: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Speeds from frame states.

    Args:
        pos: (T, n, 3) m; quat: (T, n, 4) w, x, y, z; fps: frames per second.
    Returns:
        ``speed (T, n)`` m/s (central differences, one-sided at the ends), ``step (T-1, n)`` m/s
        and ``spin (T-1, n)`` rad/s between consecutive frames.
    """
    T = pos.shape[0]
    speed = np.linalg.norm(np.gradient(pos, axis=0), axis=-1) * fps if T > 1 else np.zeros(pos.shape[:2])
    step = np.linalg.norm(np.diff(pos, axis=0), axis=-1) * fps
    dots = np.abs(np.sum(quat[1:] * quat[:-1], axis=-1)) / (
        np.linalg.norm(quat[1:], axis=-1) * np.linalg.norm(quat[:-1], axis=-1))
    spin = 2.0 * np.arccos(np.clip(dots, -1.0, 1.0)) * fps
    return speed, step, spin


def motion_labels(pos: np.ndarray, quat: np.ndarray, fps: float) -> np.ndarray:
    """(n,) ``<U6`` label per object: ``still``, ``stops`` or ``moving`` (module docstring)."""
    T, n = pos.shape[:2]
    _, step, spin = speeds(pos, quat, fps)
    rest = (step < REST_SPEED) & (spin < REST_SPIN)              # (T-1, n)
    tail = max(3, int(math.ceil(REST_TAIL * fps)))
    labels = []
    for k in range(n):
        displaced = float(np.linalg.norm(pos[:, k] - pos[0, k], axis=-1).max())
        if rest[:, k].all() and displaced < STILL_DISPLACEMENT:
            labels.append("still")
        elif T - 1 >= tail and rest[-tail:, k].all():
            labels.append("stops")
        else:
            labels.append("moving")
    return np.asarray(labels, dtype="<U6")


def in_view(seg: np.ndarray, pos: np.ndarray, K: np.ndarray, E: np.ndarray) -> np.ndarray:
    """(T, n) bool: the object owns a pixel, or its projected centre lies in the image."""
    T, H, W = seg.shape
    n = pos.shape[1]
    uv, z = project(pos, K, E)
    centre = (z > 0) & (uv[..., 0] >= 0) & (uv[..., 0] < W) & (uv[..., 1] >= 0) & (uv[..., 1] < H)
    return centre | pixel_counts(seg, n).astype(bool)


def pixel_counts(seg: np.ndarray, n: int) -> np.ndarray:
    """(T, n) int64 pixels per object per frame."""
    T = seg.shape[0]
    flat = seg.reshape(T, -1).astype(np.int64) + 1
    counts = np.stack([np.bincount(f, minlength=n + 1) for f in flat])
    return counts[:, 1:n + 1]


def discs(pos: np.ndarray, radius: np.ndarray, K: np.ndarray, E: np.ndarray
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Projected bounding discs: centres (T, n, 2) px, radii (T, n) px, depths (T, n) m."""
    uv, z = project(pos, K, E)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(z > 1e-6, K[1, 1] * np.asarray(radius)[None, :] / z, np.inf)
    return uv, r, z


def occlusions(seg: np.ndarray, pos: np.ndarray, radius: np.ndarray, K: np.ndarray, E: np.ndarray,
               overlap: float = 0.6) -> list[dict]:
    """Occlusion events: frames where two objects' bounding discs overlap strongly (centre
    distance below ``overlap`` x the sum of their radii) and their masks share a border.

    Returns:
        one dict per pair with such frames: ``front``, ``back`` (object indices by depth at the
        first such frame), ``first``, ``last`` (frame indices), ``frames`` (count).
    """
    T, H, W = seg.shape
    n = pos.shape[1]
    uv, r, z = discs(pos, radius, K, E)
    events = []
    for a in range(n):
        for b in range(a + 1, n):
            close = (np.linalg.norm(uv[:, a] - uv[:, b], axis=-1) < overlap * (r[:, a] + r[:, b])) & \
                    (z[:, a] > 0) & (z[:, b] > 0)
            frames = [t for t in np.flatnonzero(close) if _adjacent(seg[t], a, b)]
            if frames:
                front, back = (a, b) if z[frames[0], a] < z[frames[0], b] else (b, a)
                events.append({"front": front, "back": back, "first": int(frames[0]), "last": int(frames[-1]),
                               "frames": len(frames)})
    return events


def _adjacent(seg: np.ndarray, a: int, b: int) -> bool:
    """Masks ``a`` and ``b`` of one frame (H, W) share a 4-neighbour border."""
    ma, mb = seg == a, seg == b
    if not ma.any() or not mb.any():
        return False
    return bool((ma[:, 1:] & mb[:, :-1]).any() or (ma[:, :-1] & mb[:, 1:]).any()
                or (ma[1:] & mb[:-1]).any() or (ma[:-1] & mb[1:]).any())


def visibility_problem(seg: np.ndarray, pos: np.ndarray, radius: np.ndarray, K: np.ndarray, E: np.ndarray,
                       min_pixels: float) -> str | None:
    """Why the clip fails the visibility rule, or None: every object in full view (bounding
    disc inside the image) and not overlapping another object's disc covers at least
    ``min_pixels``, and every object covers that many in at least three frames."""
    T, H, W = seg.shape
    n = pos.shape[1]
    counts = pixel_counts(seg, n)
    uv, r, z = discs(pos, radius, K, E)
    inside = (z > 0) & (uv[..., 0] - r >= 0) & (uv[..., 1] - r >= 0) & (uv[..., 0] + r <= W) & (uv[..., 1] + r <= H)
    for k in range(n):
        if (counts[:, k] >= min_pixels).sum() < 3:
            return f"object {k} covers {min_pixels:.0f} px in fewer than 3 frames"
        free = inside[:, k].copy()
        for j in range(n):
            if j != k:
                free &= np.linalg.norm(uv[:, k] - uv[:, j], axis=-1) >= r[:, k] + r[:, j]
        small = np.flatnonzero(free & (counts[:, k] < min_pixels))
        if small.size:
            return f"object {k} covers {counts[small[0], k]} px in frame {small[0]} (in view, unoccluded)"
    return None


def realised_tags(motion: np.ndarray, enters: np.ndarray, leaves: np.ndarray, touch: np.ndarray,
                  occluded: list[dict]) -> list[str]:
    """Categories that happened in a clip, in :data:`CATEGORIES` order."""
    n = len(motion)
    found = {
        "moving": bool((motion == "moving").any()),
        "stopping": bool((motion == "stops").any()),
        "at_rest": bool((motion == "still").any()) and bool((motion != "still").any()),
        "entering_leaving": bool(enters.any() or leaves.any()),
        "touching": bool(touch[:, ~np.eye(n, dtype=bool)].any()) if n > 1 else False,
        "occluding": bool(occluded),
    }
    return [c for c in CATEGORIES if found[c]]


# ---------------------------------------------------------------------------------------------
# Generation
# ---------------------------------------------------------------------------------------------


def category_of(seed: int, index: int) -> str:
    """Category of clip ``index``: the categories in a seed-dependent order, cycled, so that
    any six consecutive indices cover all of them."""
    order = np.random.default_rng([7919, seed]).permutation(len(CATEGORIES))
    return CATEGORIES[int(order[index % len(CATEGORIES)])]


def generate_clip(engine: Any, seed: int, index: int, width: int = 320, height: int = 240, fps: int = 30,
                  duration: float = 2.0, max_attempts: int = 80) -> TruthClip:
    """Draw, simulate and render clip ``index`` of split ``seed`` with ``engine`` until its
    planned category happened in view and every object is visible (module
    :mod:`pipeline.truthsets.__main__` for the seed convention). Deterministic in (engine, seed,
    index, width, height, fps, duration): attempt ``a`` draws from
    ``default_rng([engine.SALT, seed, index, a])``.

    Args:
        engine: :mod:`pipeline.truthsets.mujoco_scenes` or :mod:`pipeline.truthsets.pybullet_scenes`
            (``NAME``, ``SALT``, ``LIMITS``, ``run(scenario, accept)``).
    Raises:
        RuntimeError: no attempt succeeded.
    """
    category = category_of(seed, index)
    last = "no attempt"
    for attempt in range(max_attempts):
        rng = np.random.default_rng([engine.SALT, seed, index, attempt])
        sc = sample_scenario(rng, category, engine.LIMITS, width, height, fps, duration)
        radius = np.array([o.radius for o in sc.objects])

        def accept(pos: np.ndarray, quat: np.ndarray, touch: np.ndarray) -> bool:
            motion = motion_labels(pos, quat, fps)
            if category == "moving":
                return bool((motion == "moving").any())
            if category == "stopping":
                return bool((motion == "stops").any())
            if category == "at_rest":
                return bool((motion == "still").any() and (motion != "still").any())
            if category == "touching":
                n = pos.shape[1]
                return bool(touch[:, ~np.eye(n, dtype=bool)].any())
            return True   # entering_leaving and occluding need the masks

        roll = engine.run(sc, accept)
        if roll is None:
            last = f"{category} did not happen"
            continue
        clip = _truth(engine.NAME, sc, roll, radius)
        problem = visibility_problem(roll.seg, roll.pos, radius, roll.intrinsics, roll.extrinsics, sc.min_pixels)
        if problem is not None:
            last = problem
            continue
        if category not in clip.meta["tags"]:
            last = f"{category} did not happen in view"
            continue
        clip.meta.update({"engine": engine.NAME, "seed": seed, "index": index, "attempt": attempt})
        clip.meta = {k: clip.meta[k] for k in ("engine", "seed", "index", "attempt", *[
            k for k in clip.meta if k not in ("engine", "seed", "index", "attempt")])}
        return clip
    raise RuntimeError(f"{engine.NAME} seed {seed} clip {index}: no attempt of {max_attempts} succeeded "
                       f"(last: {last})")


def _truth(engine: str, sc: Scenario, roll: Rollout, radius: np.ndarray) -> TruthClip:
    """Labels, tags and meta of a rendered scenario."""
    fps = float(sc.fps)
    motion = motion_labels(roll.pos, roll.quat, fps)
    speed, _, _ = speeds(roll.pos, roll.quat, fps)
    seen = in_view(roll.seg, roll.pos, roll.intrinsics, roll.extrinsics)
    enters = ~seen[0] & seen.any(axis=0)
    leaves = seen.any(axis=0) & ~seen[-1]
    occ = occlusions(roll.seg, roll.pos, radius, roll.intrinsics, roll.extrinsics)
    tags = realised_tags(motion, enters, leaves, roll.touch, occ)
    floor, light = sc.look.to_meta()
    objects = []
    for k, o in enumerate(sc.objects):
        d = {"name": f"{o.shape}_{k}", **o.to_meta(), "motion": str(motion[k]), "enters": bool(enters[k]),
             "leaves": bool(leaves[k])}
        objects.append(d)
    n = len(sc.objects)
    pairs = [[a, b] for a in range(n) for b in range(a + 1, n) if roll.touch[:, a, b].any()]
    meta = {"params": {"width": sc.width, "height": sc.height, "fps": sc.fps, "duration": sc.duration,
                       "generator": GENERATOR_VERSION},
            "category": sc.category, "tags": tags, "objects": objects, "camera": sc.camera.to_meta(),
            "floor": floor, "light": light, "touching_pairs": pairs, "occlusions": occ}
    return TruthClip(seg=roll.seg, fps=fps, motion=motion, enters=enters, leaves=leaves, pos=roll.pos,
                     quat=roll.quat, speed=speed, touch=roll.touch, intrinsics=roll.intrinsics,
                     extrinsics=roll.extrinsics, engine=engine, meta=meta, rgb=roll.rgb)


# ---------------------------------------------------------------------------------------------
# On disk
# ---------------------------------------------------------------------------------------------


def write_clip(folder: str | Path, clip: TruthClip) -> Path:
    """Write a clip folder (video.mp4, truth.npz, meta.json) atomically: it appears whole,
    replacing any folder of that name. Returns ``folder``.

    Raises:
        ValueError: ``clip.rgb`` is missing.
    """
    if clip.rgb is None:
        raise ValueError(f"{folder}: rgb: must be the rendered frames to write video.mp4, got None")
    folder = Path(folder)
    with atomic_dir(folder) as tmp:
        with Mp4Writer(tmp / "video.mp4", [""], clip.fps) as video:
            video.write([clip.rgb])
        np.savez_compressed(tmp / "truth.npz", **{name: _array(clip, name) for name in TRUTH_FIELDS})
        (tmp / "meta.json").write_text(json.dumps(clip.meta, indent=2, default=json_default) + "\n")
    return folder


def _array(clip: TruthClip, name: str) -> np.ndarray:
    value = getattr(clip, name)
    if name == "fps":
        return np.asarray(value, dtype=np.float64)
    if name == "engine":
        return np.asarray(value, dtype="<U16")
    return np.asarray(value)


_EXPECTED = {   # field -> (ndim, dtype kind test, description)
    "seg": (3, lambda a: a.dtype == np.int8, "(T, H, W) int8"),
    "fps": (0, lambda a: a.dtype.kind == "f", "a float scalar"),
    "motion": (1, lambda a: a.dtype.kind == "U", "(n,) str"),
    "enters": (1, lambda a: a.dtype == bool, "(n,) bool"),
    "leaves": (1, lambda a: a.dtype == bool, "(n,) bool"),
    "pos": (3, lambda a: a.dtype.kind == "f" and a.shape[-1] == 3, "(T, n, 3) float"),
    "quat": (3, lambda a: a.dtype.kind == "f" and a.shape[-1] == 4, "(T, n, 4) float"),
    "speed": (2, lambda a: a.dtype.kind == "f", "(T, n) float"),
    "touch": (3, lambda a: a.dtype == bool, "(T, n, n) bool"),
    "intrinsics": (2, lambda a: a.shape == (3, 3) and a.dtype.kind == "f", "(3, 3) float"),
    "extrinsics": (2, lambda a: a.shape == (4, 4) and a.dtype.kind == "f", "(4, 4) float"),
    "engine": (0, lambda a: a.dtype.kind == "U", "a str scalar"),
}


def clip_complete(folder: str | Path) -> bool:
    """The folder holds every file of a clip (:data:`FILES`)."""
    folder = Path(folder)
    return all((folder / f).is_file() for f in FILES)


def load_clip(folder: str | Path, rgb: bool = False) -> TruthClip:
    """Read a clip folder.

    Args:
        folder: a clip folder (``<set>/clip-00000``).
        rgb: also decode video.mp4 into ``rgb (T, H, W, 3) uint8`` (lossy, as written).
    Raises:
        TruthsetError: a file is missing or unreadable, or a field is missing or malformed
            (the message names the file and the field).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise TruthsetError(f"{folder}: must be a clip folder (video.mp4, truth.npz, meta.json), got no folder")
    path = folder / "truth.npz"
    if not path.is_file():
        raise TruthsetError(f"{path}: missing (a clip folder holds {', '.join(FILES)})")
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {}
            for name in TRUTH_FIELDS:
                if name not in npz.files:
                    raise TruthsetError(f"{path}: {name}: missing (fields: {', '.join(npz.files) or 'none'})")
                arrays[name] = npz[name]
    except TruthsetError:
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as exc:
        raise TruthsetError(f"{path}: cannot be read as .npz ({type(exc).__name__}: "
                            f"{str(exc).splitlines()[0] if str(exc) else 'corrupt'})") from None
    for name, (ndim, ok, what) in _EXPECTED.items():
        a = arrays[name]
        if a.ndim != ndim or not ok(a):
            raise TruthsetError(f"{path}: {name}: must be {what}, got {a.shape} {a.dtype}")
    T, H, W = arrays["seg"].shape
    n = arrays["motion"].shape[0]
    for name, shape in (("pos", (T, n, 3)), ("quat", (T, n, 4)), ("speed", (T, n)), ("touch", (T, n, n)),
                        ("enters", (n,)), ("leaves", (n,))):
        if arrays[name].shape != shape:
            raise TruthsetError(f"{path}: {name}: must be {shape} (T frames of seg, n objects of motion), "
                                f"got {arrays[name].shape}")
    bad = sorted(set(arrays["motion"].tolist()) - {"moving", "stops", "still"})
    if bad:
        raise TruthsetError(f"{path}: motion: must be moving, stops or still, got {bad[0]!r}")
    meta_path = folder / "meta.json"
    try:
        meta = json.loads(meta_path.read_text())
    except FileNotFoundError:
        raise TruthsetError(f"{meta_path}: missing (a clip folder holds {', '.join(FILES)})") from None
    except (OSError, ValueError) as exc:
        raise TruthsetError(f"{meta_path}: cannot be read as JSON ({exc})") from None
    clip = TruthClip(seg=arrays["seg"], fps=float(arrays["fps"]), motion=arrays["motion"], enters=arrays["enters"],
                     leaves=arrays["leaves"], pos=arrays["pos"], quat=arrays["quat"], speed=arrays["speed"],
                     touch=arrays["touch"], intrinsics=arrays["intrinsics"], extrinsics=arrays["extrinsics"],
                     engine=str(arrays["engine"]), meta=meta)
    if rgb:
        clip.rgb = read_video(folder / "video.mp4", (T, H, W))
    return clip


def read_video(path: Path, shape: tuple[int, int, int]) -> np.ndarray:
    """Decode an mp4 into ``(T, H, W, 3) uint8`` RGB.

    Raises:
        TruthsetError: missing, unreadable, or not ``shape`` (T, H, W).
    """
    if not path.is_file():
        raise TruthsetError(f"{path}: missing (a clip folder holds {', '.join(FILES)})")
    cap = cv2.VideoCapture(str(path))
    frames = []
    try:
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            frames.append(cv2.cvtColor(frame, cv2.COLOR_BGR2RGB))
    finally:
        cap.release()
    if not frames:
        raise TruthsetError(f"{path}: cannot be decoded (no frames)")
    rgb = np.stack(frames)
    if rgb.shape[:3] != tuple(shape):
        raise TruthsetError(f"{path}: frames: must be {tuple(shape)} (T, H, W of truth.npz seg), got {rgb.shape[:3]}")
    return rgb


Accept = Callable[[np.ndarray, np.ndarray, np.ndarray], bool]
"""``accept(pos (T, n, 3), quat (T, n, 4), touch (T, n, n)) -> bool``: an engine's ``run`` renders
only rollouts that it accepts."""
