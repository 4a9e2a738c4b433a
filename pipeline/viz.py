"""Looking at results: side-by-side videos, rerun recordings, curves.

Everything here takes plain arrays (no :class:`~pipeline.scene.Scene`), so any stage can show
anything: rendered or real frames, masks, depth, flow, 3D poses and per-frame metrics.
Every file is written atomically (temporary sibling, then rename).

- :func:`side_by_side_mp4`: columns of equal-length videos in one mp4, labelled;
  :class:`Mp4Writer` the same, streamed a frame or a chunk of frames at a time.
- :func:`record_clip`: a rerun ``.rrd`` recording (open with ``rerun FILE.rrd``), written
  headless; ``rerun`` is imported only here, lazily.
- :func:`plot_curves`: line plots to PNG with matplotlib's Agg canvas (no pyplot state).

Example::

    side_by_side_mp4("out/compare.mp4", [rgb, mask_overlay(rgb, seg), flow_to_rgb(flow)],
                     ["rgb", "seg", "flow"], fps=30)
    record_clip("out/scene.rrd", rgb=rgb, seg=seg, positions=pos, quaternions=quat,
                objects=[{"name": "sphere_0", "shape": "sphere", "size": {"radius": 0.1}}],
                camera={"K": K, "rotation": R, "translation": t}, fps=30)
"""

from __future__ import annotations

import functools
import io
from pathlib import Path
from typing import Any, Mapping, Sequence

import cv2
import numpy as np

from pipeline.flow import flow_to_rgb
from pipeline.atomic import AtomicWriter, atomic_path, replace_path, temp_file_for, write_bytes

PALETTE = np.array([
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
    (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207),
], dtype=np.uint8)
"""RGB colour of object id ``i`` is ``PALETTE[i % 10]`` (matplotlib's tab10), in every view."""

RDF_FROM_MUJOCO_CAMERA = np.diag([1.0, -1.0, -1.0])
"""Axis change from a MuJoCo camera frame (x right, y up, looks along -z) to rerun's RDF
camera frame (x right, y down, looks along +z): ``R_world_rdf = R_world_mj @ this``."""


def rdf_rotation_from_mujoco(rotation: np.ndarray) -> np.ndarray:
    """World-from-camera rotation of a MuJoCo camera, re-expressed for rerun's RDF frame.

    MuJoCo's camera frame (``data.cam_xmat``, column ``i`` = camera axis ``i`` in world
    coordinates) has x right, y up and looks along -z (OpenGL). A pinhole image has its
    origin top-left with y down, and rerun's ``ViewCoordinates.RDF`` camera looks along +z:
    flip the camera's y and z axes.

    Args:
        rotation: ``(..., 3, 3)`` world-from-camera rotation(s), MuJoCo convention.

    Returns:
        ``(..., 3, 3)`` world-from-camera rotation(s), RDF convention.
    """
    return np.asarray(rotation, dtype=np.float64) @ RDF_FROM_MUJOCO_CAMERA


# ---------------------------------------------------------------------------------------
# Overlays and mp4
# ---------------------------------------------------------------------------------------


def mask_overlay(rgb: np.ndarray, seg: np.ndarray, alpha: float = 0.5) -> np.ndarray:
    """Tint each object's pixels with its palette colour.

    Args:
        rgb: ``(..., H, W, 3)`` uint8.
        seg: ``(..., H, W)`` integer object ids, ``-1`` (or any negative) = background.
        alpha: opacity of the tint, 0–1.

    Returns:
        ``(..., H, W, 3)`` uint8, background unchanged.

    Raises:
        ValueError: the shapes do not match.
    """
    rgb, seg = np.asarray(rgb), np.asarray(seg)
    if rgb.shape[-1:] != (3,) or rgb.shape[:-1] != seg.shape:
        raise ValueError(f"rgb {rgb.shape} and seg {seg.shape}: must be (..., H, W, 3) and "
                         "(..., H, W)")
    ids = seg.astype(np.int64)
    fg = ids >= 0
    tint = PALETTE[np.where(fg, ids, 0) % len(PALETTE)].astype(np.float32)
    out = rgb.astype(np.float32)
    out[fg] = (1 - alpha) * out[fg] + alpha * tint[fg]
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def mask_colours(seg: np.ndarray) -> np.ndarray:
    """Each object's palette colour on black: ``mask_overlay(np.zeros(...), seg, alpha=1.0)``
    pixel for pixel, without its float temporaries (~4 bytes per pixel instead of ~60; the
    ``masks.mp4`` preview of ``dynamics simulate``).

    Args:
        seg: ``(..., H, W)`` integer object ids, ``-1`` (or any negative) = background.

    Returns:
        ``(..., H, W, 3)`` uint8: ``PALETTE[id % 10]`` on objects, 0 on the background.
    """
    seg = np.asarray(seg)
    out = PALETTE[np.where(seg >= 0, seg, 0) % len(PALETTE)]
    out[seg < 0] = 0
    return out


def _put_label(frame: np.ndarray, text: str) -> None:
    """Write ``text`` top-left on an RGB frame, white on a black outline, in place."""
    scale = max(0.3, frame.shape[0] / 400)
    thick = max(1, round(scale))
    (_, text_h), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    org = (3, text_h + 4)                                 # baseline below the text's top
    cv2.putText(frame, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), thick + 2,
                cv2.LINE_AA)
    cv2.putText(frame, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), thick,
                cv2.LINE_AA)


class Mp4Writer(AtomicWriter):
    """Streaming side-by-side mp4 (MPEG-4 Part 2, fourcc ``mp4v``): frames are encoded as they
    come, so memory does not grow with the clip's length.

    Columns of equal height are placed side by side, each labelled top-left (labels are drawn
    on copies, never on the input). The encoder writes a temporary sibling ``.<name>.XXXX.mp4``
    of ``path`` (OpenCV picks the container from the name), renamed onto ``path`` by
    :meth:`close`; :meth:`abort` (or an exception inside ``with``) removes it, so ``path`` is
    either the whole video or untouched.

    Example::

        with Mp4Writer("out/rgb.mp4", ["rgb", "seg"], fps=30) as video:
            for a in range(0, T, 32):
                video.write([rgb[a:a + 32], mask_overlay(rgb[a:a + 32], seg[a:a + 32])])

    Args:
        path: output file (``.mp4``); its directory is created.
        labels: one short text per column (may be empty strings).
        fps: playback rate, frames per second.

    Raises:
        ValueError: no labels (no columns) or ``fps <= 0``.
    """

    def __init__(self, path: str | Path, labels: Sequence[str], fps: float) -> None:
        if not labels:
            raise ValueError("columns: must hold at least one video, got none")
        if not fps > 0:
            raise ValueError(f"fps: must be > 0, got {fps}")
        self.path = Path(path)
        self.labels = list(labels)
        self.fps = float(fps)
        self.frames = 0
        """Frames written so far."""
        self._tmp: Path | None = None
        self._writer: cv2.VideoWriter | None = None
        self._shape: tuple[int, tuple[int, ...]] | None = None  # H and the column widths

    def write(self, columns: Sequence[np.ndarray]) -> None:
        """Append one frame (each column ``(H, W_i, 3)``) or a chunk of ``k`` frames (each
        column ``(k, H, W_i, 3)``), uint8 RGB. The first call fixes ``H`` and the widths; the
        frame is ``sum(W_i)`` wide and ``H`` high, an odd total width or height padded with one
        black column/row (the codec needs even sizes).

        Raises:
            ValueError: column count differs from the labels, a column is not uint8 RGB, the
                columns disagree in length or height, a size differs from the first call's, or
                the writer was closed.
            OSError: the encoder could not be opened for this path.
        """
        if len(columns) != len(self.labels):
            raise ValueError(f"labels: must have one per column ({len(columns)}), got {len(self.labels)}")
        if self._shape is not None and self._writer is None:
            raise ValueError(f"{self.path}: must not be written after close or abort")
        cols = [np.asarray(c) for c in columns]
        if cols and cols[0].ndim == 3:
            cols = [c[None] if c.ndim == 3 else c for c in cols]
        for i, c in enumerate(cols):
            if c.ndim != 4 or c.shape[-1] != 3 or c.dtype != np.uint8:
                raise ValueError(f"columns[{i}]: must be (T, H, W, 3) uint8, got {c.shape} {c.dtype}")
            if c.shape[:2] != cols[0].shape[:2]:
                raise ValueError(f"columns[{i}]: must have (T, H) = {cols[0].shape[:2]} like "
                                 f"columns[0], got {c.shape[:2]}")
        shape = (cols[0].shape[1], tuple(c.shape[2] for c in cols))
        if self._shape is None:
            self._open(*shape)
        elif shape != self._shape:
            raise ValueError(f"columns: must keep height and widths {self._shape} of the first frames, "
                             f"got {shape}")
        H, W = self._shape[0], sum(self._shape[1])
        size = (W + W % 2, H + H % 2)
        for t in range(cols[0].shape[0]):
            frame = np.zeros((size[1], size[0], 3), dtype=np.uint8)
            x = 0
            for c, label in zip(cols, self.labels):
                tile = c[t].copy()                     # never draw on the input
                if label:
                    _put_label(tile, label)
                frame[:H, x:x + tile.shape[1]] = tile
                x += tile.shape[1]
            self._writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
            self.frames += 1

    def _open(self, height: int, widths: tuple[int, ...]) -> None:
        """Open the encoder on a temporary sibling of ``path`` for frames of this size."""
        W = sum(widths)
        size = (W + W % 2, height + height % 2)
        self._tmp = temp_file_for(self.path, suffix=".mp4")  # OpenCV picks the container from the name
        self._writer = cv2.VideoWriter(str(self._tmp), cv2.VideoWriter_fourcc(*"mp4v"), self.fps, size)
        if not self._writer.isOpened():
            self.abort()
            raise OSError(f"{self.path}: cannot open an mp4v video writer")
        self._shape = (height, widths)

    def close(self) -> Path:
        """Finish the video and rename it onto ``path``. Returns ``path``.

        Raises:
            ValueError: nothing was written (the frame size is unknown).
        """
        if self._writer is None:
            self.abort()
            raise ValueError(f"{self.path}: no frames written")
        self._writer.release()
        self._writer = None
        replace_path(self._tmp, self.path)
        self._tmp = None
        return self.path

    def abort(self) -> None:
        """Stop and remove the temporary file; ``path`` stays as it was."""
        if self._writer is not None:
            self._writer.release()
            self._writer = None
        if self._tmp is not None:
            self._tmp.unlink(missing_ok=True)
            self._tmp = None


def side_by_side_mp4(
    path: str | Path,
    columns: Sequence[np.ndarray],
    labels: Sequence[str],
    fps: float,
) -> Path:
    """Write videos side by side into one mp4 (MPEG-4 Part 2, fourcc ``mp4v``): the whole clip
    in one call through :class:`Mp4Writer`.

    Args:
        path: output file (``.mp4``); its directory is created. Written atomically.
        columns: videos of the same length and height, each ``(T, H, W_i, 3)`` uint8 RGB
            (e.g. ``mask_overlay(rgb, seg)`` or ``flow_to_rgb(flow)``).
        labels: one short text per column, drawn top-left of it (may be empty strings).
        fps: playback rate, frames per second.

    Returns:
        ``path``. The frame is ``sum(W_i)`` wide and ``H`` high; an odd total width or
        height is padded with one black column/row (the codec needs even sizes).

    Raises:
        ValueError: no columns, label count mismatch, or mismatched shapes/dtypes.
        OSError: the encoder could not be opened for this path.
    """
    if not columns:
        raise ValueError("columns: must hold at least one video, got none")
    if len(labels) != len(columns):
        raise ValueError(f"labels: must have one per column ({len(columns)}), got {len(labels)}")
    with Mp4Writer(path, labels, fps) as video:
        video.write(columns)
    return Path(path)


def contact_sheet(path: str | Path, rows: Sequence[np.ndarray], labels: Sequence[str],
                  n_columns: int = 6, title: str = "") -> Path:
    """A PNG grid: one row per video, ``n_columns`` frames spread evenly over time.

    Args:
        path: output ``.png``; written atomically.
        rows: videos ``(T, H, W, 3)`` uint8 RGB of the same T, H and W (e.g. observed frames
            with masks drawn over them, re-simulated frames).
        labels: one text per row, drawn on its first tile.
        n_columns: frames per row; each tile is labelled with its frame index.
        title: optional line of text above the grid.
    Returns:
        ``path``.
    Raises:
        ValueError: no rows, or rows of different shapes.
    """
    path = Path(path)
    if not rows:
        raise ValueError("rows: must hold at least one video, got none")
    rows = [np.asarray(r) for r in rows]
    if any(r.shape != rows[0].shape or r.dtype != np.uint8 or r.ndim != 4 for r in rows):
        raise ValueError(f"rows: must all be (T, H, W, 3) uint8 of one shape, got {[r.shape for r in rows]}")
    T, H, W = rows[0].shape[:3]
    idx = np.unique(np.linspace(0, T - 1, min(n_columns, T)).round().astype(int))
    grid = []
    for r, label in zip(rows, labels):
        tiles = []
        for j, t in enumerate(idx):
            tile = r[t].copy()
            _put_label(tile, f"{label}  t={t}" if j == 0 and label else f"t={t}")
            tiles.append(np.pad(tile, ((2, 2), (2, 2), (0, 0)), constant_values=255))
        grid.append(np.concatenate(tiles, axis=1))
    img = np.concatenate(grid, axis=0)
    if title:
        bar = np.full((max(24, H // 8), img.shape[1], 3), 255, dtype=np.uint8)
        scale = max(0.4, bar.shape[0] / 40)
        cv2.putText(bar, title, (4, bar.shape[0] - 6), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0),
                    max(1, round(scale)), cv2.LINE_AA)
        img = np.concatenate([bar, img], axis=0)
    with atomic_path(path, suffix=".png") as tmp:
        if not cv2.imwrite(str(tmp), cv2.cvtColor(img, cv2.COLOR_RGB2BGR)):
            raise OSError(f"{path}: cannot write PNG")
    return path


# ---------------------------------------------------------------------------------------
# Rerun
# ---------------------------------------------------------------------------------------


def _xyzw(quaternions_wxyz: np.ndarray) -> np.ndarray:
    """Scene quaternions ``(w, x, y, z)`` -> rerun's ``(x, y, z, w)``."""
    return np.roll(np.asarray(quaternions_wxyz, dtype=np.float32), -1, axis=-1)


def _primitive(rr: Any, obj: Mapping[str, Any], centre: np.ndarray, quat_xyzw: np.ndarray,
               colour: np.ndarray) -> Any:
    """The rerun archetype drawing one object at one pose."""
    shape, size = obj["shape"], obj["size"]
    common = dict(centers=[centre], quaternions=[rr.Quaternion(xyzw=quat_xyzw)],
                  colors=[colour], labels=[obj["name"]], fill_mode="solid")
    if shape == "sphere":
        return rr.Ellipsoids3D(half_sizes=[[size["radius"]] * 3], **common)
    if shape == "cylinder":                               # axis along the body z
        if hasattr(rr, "Cylinders3D"):
            return rr.Cylinders3D(lengths=[size["height"]], radii=[size["radius"]], **common)
        d = 2 * size["radius"]
        return rr.Boxes3D(sizes=[[d, d, size["height"]]], **common)
    if shape == "box":                                    # width x, depth y, height z
        return rr.Boxes3D(sizes=[[size["width"], size["depth"], size["height"]]], **common)
    raise ValueError(f"objects: {obj['name']}: shape must be sphere, cylinder or box, "
                     f"got {shape!r}")


def record_clip(
    path: str | Path,
    rgb: np.ndarray | None = None,
    seg: np.ndarray | None = None,
    flow: np.ndarray | None = None,
    depth: np.ndarray | None = None,
    positions: np.ndarray | None = None,
    quaternions: np.ndarray | None = None,
    objects: Sequence[Mapping[str, Any]] = (),
    camera: Mapping[str, Any] | None = None,
    scalars: Mapping[str, np.ndarray] | None = None,
    fps: float = 30.0,
    app_id: str = "dynamics",
    flow_max_magnitude: float | None = None,
) -> Path:
    """Write a rerun recording of one clip (headless; open it with ``rerun PATH``).

    Entities (one per stream), on timelines ``frame`` (index) and ``time`` (s = index / fps):

    - ``world``: view coordinates right-handed, z up (the scene's world frame).
    - ``world/objects/<name>``: each object as a solid primitive at its pose per frame —
      sphere: ``Ellipsoids3D``; cylinder: ``Cylinders3D`` (axis along body z; a box if the
      installed rerun lacks it); box: ``Boxes3D`` (width along x, depth y, height z).
    - ``world/camera``: ``Transform3D`` (world from camera) + ``Pinhole`` (``K``, RDF).
    - ``world/camera/rgb`` | ``seg`` | ``depth`` | ``flow``: images in that camera, so
      rerun projects them into the 3D view. ``seg`` is logged as a ``SegmentationImage``
      of ``id + 1`` (0 = background) with an annotation context naming the objects;
      ``flow`` as the Middlebury colour coding, ``flow[t]`` (``t -> t + 1``) at frame ``t``.
    - ``metrics/<key>``: each scalar series, value ``k`` at frame ``k``.

    Args:
        path: output ``.rrd`` file; written atomically.
        rgb: ``(T, H, W, 3)`` uint8.
        seg: ``(T, H, W)`` int object ids, -1 background.
        flow: ``(T-1, H, W, 2)`` float px (forward flow).
        depth: ``(T, H, W)`` float depth along the optical axis, m.
        positions: ``(T, n, 3)`` object centres, m, world frame.
        quaternions: ``(T, n, 4)`` object orientations ``(w, x, y, z)`` (scene convention;
            converted to rerun's ``(x, y, z, w)``).
        objects: ``n`` dicts ``{"name": str, "shape": "sphere"|"cylinder"|"box", "size":
            {...}}`` with sizes as in the scene language (full extents or radius, m).
        camera: ``{"K": (3, 3) px intrinsics (pixel origin top-left), "rotation":
            (3, 3) or (T, 3, 3) world-from-camera rotation in rerun's RDF camera frame
            (x right, y down, looking along +z; use :func:`rdf_rotation_from_mujoco` for a
            MuJoCo camera), "translation": (3,) or (T, 3) camera position, m,
            "resolution": optional (W, H) px, default from the images}``.
        scalars: per-frame metrics by name, each ``(K,)`` with ``K <= T``.
        fps: frames per second of the clip (for the ``time`` timeline).
        app_id: rerun application id.
        flow_max_magnitude: px at full colour saturation (see
            :func:`~pipeline.flow.flow_to_rgb`); ``None`` = the clip's maximum.

    Returns:
        ``path``.

    Raises:
        ValueError: inconsistent shapes, objects without poses, or an unknown shape.
    """
    import rerun as rr                                    # lazy: heavy, only for viewing

    path = Path(path)
    n = len(objects)
    if (positions is None) != (quaternions is None):
        raise ValueError("positions and quaternions: give both or neither")
    if n and positions is None:
        raise ValueError(f"objects: {n} objects given without positions/quaternions")
    if positions is not None:
        positions, quaternions = np.asarray(positions), np.asarray(quaternions)
        if positions.shape[1:] != (n, 3) or quaternions.shape != (*positions.shape[:2], 4):
            raise ValueError(f"positions {positions.shape}, quaternions {quaternions.shape}: "
                             f"must be (T, {n}, 3) and (T, {n}, 4) for {n} objects")
    for obj in objects:
        if obj.get("shape") not in ("sphere", "cylinder", "box"):
            raise ValueError(f"objects: {obj.get('name')}: shape must be sphere, cylinder or "
                             f"box, got {obj.get('shape')!r}")
    series = {k: np.atleast_1d(np.asarray(v, dtype=np.float64)) for k, v in (scalars or {}).items()}
    lengths = [len(a) for a in (rgb, seg, depth, positions) if a is not None]
    if flow is not None:
        lengths.append(len(flow) + 1)
    T = max(lengths + [len(v) for v in series.values()], default=0)

    recording = rr.RecordingStream(app_id)
    stream = recording.binary_stream()
    log = functools.partial(recording.log, strict=True)  # our bugs raise instead of warning

    log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    if seg is not None:                                   # class id = object id + 1
        names = [o["name"] for o in objects] or \
            [f"object_{i}" for i in range(int(np.max(seg, initial=-1)) + 1)]
        log("world/camera/seg", rr.AnnotationContext(
            [(0, "background", (0, 0, 0))]
            + [(i + 1, name, tuple(int(c) for c in PALETTE[i % len(PALETTE)]))
               for i, name in enumerate(names)]), static=True)

    image_hw = next((a.shape[1:3] for a in (rgb, seg, depth, flow) if a is not None), None)
    if camera is not None:
        K = np.asarray(camera["K"], dtype=np.float64)
        if K.shape != (3, 3):
            raise ValueError(f"camera.K: must be (3, 3), got {K.shape}")
        resolution = camera.get("resolution")
        if resolution is None and image_hw is not None:
            resolution = (image_hw[1], image_hw[0])
        log("world/camera", rr.Pinhole(image_from_camera=K, resolution=resolution,
                                       camera_xyz=rr.ViewCoordinates.RDF), static=True)
        rotation = np.asarray(camera["rotation"], dtype=np.float64)
        translation = np.asarray(camera["translation"], dtype=np.float64)
        if rotation.ndim == 2 and translation.ndim == 1:
            log("world/camera", rr.Transform3D(translation=translation, mat3x3=rotation),
                static=True)

    flow_rgb = None if flow is None else flow_to_rgb(flow, flow_max_magnitude)
    if depth is not None:
        depth = np.asarray(depth, dtype=np.float32)
    for t in range(T):
        recording.set_time("frame", sequence=t)
        recording.set_time("time", duration=t / fps)
        if camera is not None and (rotation.ndim == 3 or translation.ndim == 2):
            log("world/camera", rr.Transform3D(
                translation=translation[t] if translation.ndim == 2 else translation,
                mat3x3=rotation[t] if rotation.ndim == 3 else rotation))
        if rgb is not None and t < len(rgb):
            log("world/camera/rgb", rr.Image(rgb[t]))
        if seg is not None and t < len(seg):
            log("world/camera/seg",
                rr.SegmentationImage((np.asarray(seg[t], np.int16) + 1).astype(np.uint8)))
        if depth is not None and t < len(depth):
            log("world/camera/depth", rr.DepthImage(depth[t], meter=1.0))
        if flow_rgb is not None and t < len(flow_rgb):
            log("world/camera/flow", rr.Image(flow_rgb[t]))
        if positions is not None and t < len(positions):
            quat = _xyzw(quaternions[t])
            for i, obj in enumerate(objects):
                log(f"world/objects/{obj['name']}", _primitive(
                    rr, obj, positions[t, i], quat[i], PALETTE[i % len(PALETTE)]))
        for key, values in series.items():
            if t < len(values) and np.isfinite(values[t]):
                log(f"metrics/{key}", rr.Scalars(values[t]))

    data = stream.read(flush=True) or b""
    recording.disconnect()
    write_bytes(path, data)
    return path


def recording_entities(path: str | Path) -> list[str]:
    """Entity paths of the first recording in an ``.rrd`` file (for tests and checks).

    Raises:
        ValueError: the file is not a readable rerun recording.
    """
    from rerun.chunk import RrdReader

    try:
        summary = RrdReader(path).store().summary()
    except Exception as exc:                              # rerun raises assorted types
        raise ValueError(f"{path}: not a readable rerun recording: {exc}") from None
    return sorted({line.split()[0] for line in summary.splitlines() if line.strip()})


# ---------------------------------------------------------------------------------------
# Curves
# ---------------------------------------------------------------------------------------


def plot_curves(
    path_png: str | Path,
    series: Mapping[str, tuple[np.ndarray, np.ndarray]],
    title: str = "",
    xlabel: str = "",
    ylabel: str = "",
    logy: bool = False,
) -> Path:
    """Line plot of named ``(x, y)`` series, saved as PNG (matplotlib Agg, no pyplot).

    Args:
        path_png: output file; written atomically.
        series: legend label -> ``(x, y)`` arrays of equal length.
        title, xlabel, ylabel: text on the plot (put units in the axis labels).
        logy: logarithmic y axis (e.g. losses).

    Returns:
        ``path_png``.

    Raises:
        ValueError: a series' x and y differ in length.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.4, 4.0), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    for label, (x, y) in series.items():
        x, y = np.asarray(x), np.asarray(y)
        if x.shape != y.shape:
            raise ValueError(f"series[{label!r}]: x {x.shape} and y {y.shape} must match")
        ax.plot(x, y, label=label, marker="." if len(x) < 30 else None)
    if logy:
        ax.set_yscale("log")
    ax.set(title=title, xlabel=xlabel, ylabel=ylabel)
    ax.grid(alpha=0.3)
    if series:
        ax.legend()
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return write_bytes(path_png, buf.getvalue())
