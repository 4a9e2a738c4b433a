"""Real videos: read a window, fix the frame rate, crop and resize as frames are read.

docs/design.md §9: a reader must accept an fps override (the 240 fps PhysTrack clips carry a
container rate of 29.97), crop/resize to the model resolution, and select a 1 s window.
Pseudo ground-truth masks of the frames read here are made in :mod:`pipeline.masks`.

Example::

    clip = read_video("05_phystrack_CaromPuck_HeadOn_240fps.mp4", fps=240, start=0.7,
                      duration=1.0, size=(96, 64))     # 240 frames of 96x64
    frames = resample(clip.frames, clip.fps, 30.0, duration=1.0)   # 30 frames

All errors about the user's file are :class:`VideoError` with a one-line message naming it.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path
import os
import sys

import cv2
import numpy as np

from pipeline.errors import UserError


class VideoError(UserError, ValueError):
    """A video cannot be read as asked. ``str(err)`` is one line: ``<file>: <reason>``."""


class VideoWarning(UserWarning):
    """A video was read only in part (truncated or corrupt file). ``str(w)`` is one line naming
    the file and how many frames were decoded; ``dynamics`` prints it as ``warning: ...``."""


@dataclass(frozen=True)
class Clip:
    """A window of a video, decoded.

    Attributes:
        frames: ``(T, H, W, 3)`` uint8 RGB.
        fps: true frame rate of ``frames`` (the override if one was given, else the
            container's), frames per second.
        source: the file it was read from.
        original_size: ``(width, height)`` of the video in px.
        crop: ``(x, y, width, height)`` of the crop in original px, before resizing
            (the whole frame when no ``size`` was asked for).
        start_frame: index of ``frames[0]`` in the video.
        container_fps: frame rate the container declares (may be wrong).
    """

    frames: np.ndarray
    fps: float
    source: Path
    original_size: tuple[int, int]
    crop: tuple[int, int, int, int]
    start_frame: int
    container_fps: float

    @property
    def duration(self) -> float:
        """Length of the clip in s (``T / fps``)."""
        return len(self.frames) / self.fps


def centre_crop_box(width: int, height: int, aspect: float) -> tuple[int, int, int, int]:
    """Largest centred box of aspect ratio ``aspect`` (width / height) inside a frame.

    Returns:
        ``(x, y, w, h)`` in px.
    """
    if width / height > aspect:                       # too wide: cut the sides
        w, h = max(1, round(height * aspect)), height
    else:                                             # too tall: cut top and bottom
        w, h = width, max(1, round(width / aspect))
    return (width - w) // 2, (height - h) // 2, w, h


def _open_capture(path: Path) -> cv2.VideoCapture:
    """``cv2.VideoCapture`` through FFmpeg (the backend that opens every video OpenCV reads by
    default here), then, if FFmpeg cannot open the file, through OpenCV's other backends, with
    the process's stderr (file descriptor 2) sent to /dev/null while opening: OpenCV's own AVI
    parser prints lines such as "Unexpected element. Expected: LIST" for a damaged header and
    its log a "can't be used to capture by name" warning, which would follow our one-line error.
    Decoding messages are silenced by ``OPENCV_FFMPEG_LOGLEVEL`` (``pipeline/__init__.py``)."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
            cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
            if not cap.isOpened():
                cap.release()
                cap = cv2.VideoCapture(str(path))
            return cap
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def declared_length(path: str | Path) -> tuple[int, float]:
    """``(frames, fps)`` the container declares (either may be 0 when it does not say, and
    either may be wrong: :func:`read_video` counts what decodes); ``(0, 0.0)`` for a file that
    does not open. No frame is decoded."""
    cap = _open_capture(Path(path))
    try:
        return int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0), float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
    finally:
        cap.release()


def read_video(
    path: str | Path,
    fps: float | None = None,
    start: float = 0.0,
    duration: float | None = None,
    size: tuple[int, int] | None = None,
    max_frames: int | None = None,
    crop: tuple[int, int, int, int] | None = None,
) -> Clip:
    """Decode a window of a video file as RGB frames.

    Frames are taken at the source rate (use :func:`resample` to change it). With ``size``,
    each frame is centre-cropped to the target aspect ratio, then resized with
    ``cv2.INTER_AREA`` as it is read, so a long 1080p clip never sits in memory at full size.

    Args:
        path: any file OpenCV/FFmpeg can decode.
        fps: true frame rate (frames per second) when the container's is wrong (e.g. 240
            for the PhysTrack clips); ``None`` trusts the container.
        start: time of the first frame in s, on the true time line (frame
            ``round(start * fps)``).
        duration: length of the window in s (``round(duration * fps)`` frames); ``None``
            reads to the end. A window running past the end is cut short.
        size: ``(width, height)`` of the output frames in px; ``None`` keeps the original.
        max_frames: read at most this many frames.
        crop: ``(x, y, width, height)`` box in original px to cut out before resizing
            (e.g. the region of motion, :func:`pipeline.perception.motion_crop`); default
            the largest centred box of the aspect ratio of ``size``. It is clipped to the
            frame.

    Returns:
        A :class:`Clip` with at least one frame.

    Raises:
        VideoError: the file is missing, cannot be decoded, has no usable frame rate and
            no override, or ``start`` lies past its end; or an argument is out of range.

    Warns:
        VideoWarning: decoding stopped before the frame count the container declares (a
            truncated or corrupt file); the frames up to there are returned.
    """
    path = Path(path)
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise VideoError(f"{path}: fps: must be > 0, got {fps}")
    if not (math.isfinite(start) and start >= 0):
        raise VideoError(f"{path}: start: must be >= 0 s, got {start}")
    if duration is not None and not (math.isfinite(duration) and duration > 0):
        raise VideoError(f"{path}: duration: must be > 0 s, got {duration}")
    if max_frames is not None and max_frames < 1:
        raise VideoError(f"{path}: max_frames: must be >= 1, got {max_frames}")
    if size is not None and (len(size) != 2 or min(size) < 1):
        raise VideoError(f"{path}: size: must be (width, height) >= 1 px, got {size}")
    if not path.exists():
        raise VideoError(f"{path}: no such file")
    if not path.is_file():
        raise VideoError(f"{path}: not a file")

    cap = _open_capture(path)
    try:
        if not cap.isOpened():
            raise VideoError(f"{path}: cannot open as a video")
        container_fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        true_fps = fps if fps is not None else container_fps
        if not (math.isfinite(true_fps) and true_fps > 0):
            raise VideoError(f"{path}: container has no frame rate; pass fps")
        first = round(start * true_fps)
        count = None if duration is None else max(1, round(duration * true_fps))
        if max_frames is not None:
            count = max_frames if count is None else min(count, max_frames)

        declared = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)   # <= 0: the container does not say

        def past_end(n_frames: int) -> VideoError:
            broken = (f", of the {declared} the container declares: truncated or corrupt file"
                      if n_frames < declared else "")
            return VideoError(f"{path}: start {start:g} s (frame {first}) is past the end "
                              f"({n_frames} frames decodable = {n_frames / true_fps:.3f} s at "
                              f"{true_fps:g} fps{broken})")

        for skipped in range(first):                  # grab(): exact, unlike seeking
            if not cap.grab():
                raise past_end(skipped)
        frames: list[np.ndarray] = []
        crop_checked = False
        stopped_early = False
        while count is None or len(frames) < count:
            ok, bgr = cap.read()
            if not ok or bgr is None:
                stopped_early = True
                break
            if not crop_checked:
                orig_h, orig_w = bgr.shape[:2]
                if crop is None:
                    crop = (0, 0, orig_w, orig_h) if size is None else \
                        centre_crop_box(orig_w, orig_h, size[0] / size[1])
                else:
                    cx, cy, cw, ch = (int(round(c)) for c in crop)
                    cx, cy = min(max(cx, 0), orig_w - 1), min(max(cy, 0), orig_h - 1)
                    crop = (cx, cy, max(1, min(cw, orig_w - cx)), max(1, min(ch, orig_h - cy)))
                crop_checked = True
            x, y, w, h = crop
            bgr = bgr[y:y + h, x:x + w]
            if size is not None and (w, h) != tuple(size):
                bgr = cv2.resize(bgr, tuple(size), interpolation=cv2.INTER_AREA)
            frames.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
    except cv2.error as exc:
        raise VideoError(f"{path}: cannot decode: {str(exc).strip().splitlines()[-1]}") from None
    finally:
        cap.release()

    if not frames:
        if first > 0:
            raise past_end(first)
        raise VideoError(f"{path}: no decodable frame")
    if stopped_early and first + len(frames) < declared:
        # FFmpeg stops at the first undecodable packet; the container's frame count is exact for
        # every intact file we have (6 real clips, 5 synthetic ones), so a shortfall means a
        # truncated or corrupt file
        warnings.warn(VideoWarning(
            f"{path}: truncated or corrupt: decoding stopped after frame {first + len(frames)} of the "
            f"{declared} the container declares; read {len(frames)} frames ({len(frames) / true_fps:.3f} s) "
            f"from frame {first}"), stacklevel=2)
    return Clip(frames=np.stack(frames), fps=float(true_fps), source=path,
                original_size=(orig_w, orig_h), crop=crop, start_frame=first,
                container_fps=container_fps)


def resample(
    frames: np.ndarray, src_fps: float, dst_fps: float, duration: float | None = None
) -> np.ndarray:
    """Pick the frames nearest to a regular time grid at ``dst_fps``.

    Frame ``k`` of the result is source frame ``round(k * src_fps / dst_fps)``, for
    ``k < round(duration * dst_fps)``; e.g. 1 s of a 240 fps clip becomes 30 frames at
    30 fps (every 8th frame). No blending: each output frame is a real frame.

    Args:
        frames: ``(T, ...)`` array, time first (RGB, masks, anything per frame).
        src_fps: frame rate of ``frames``, frames per second.
        dst_fps: wanted frame rate, frames per second.
        duration: length of the result in s; ``None`` covers the whole input.

    Returns:
        ``(round(duration * dst_fps), ...)`` array, same dtype as ``frames``.

    Raises:
        ValueError: a rate or duration is not positive, or the input is shorter than
            ``duration`` (by more than half a source frame).
    """
    frames = np.asarray(frames)
    if not (src_fps > 0 and dst_fps > 0):
        raise ValueError(f"fps: must be > 0, got src_fps={src_fps}, dst_fps={dst_fps}")
    if len(frames) == 0:
        raise ValueError("frames: must hold at least one frame, got 0")
    if duration is None:
        count = math.floor((len(frames) - 1) / src_fps * dst_fps + 1e-9) + 1
    elif duration > 0:
        count = max(1, round(duration * dst_fps))
    else:
        raise ValueError(f"duration: must be > 0 s, got {duration}")
    index = np.rint(np.arange(count) * (src_fps / dst_fps)).astype(np.int64)
    if index[-1] >= len(frames):
        raise ValueError(f"frames: {len(frames)} frames at {src_fps:g} fps cover "
                         f"{len(frames) / src_fps:.3f} s, need {count / dst_fps:.3f} s")
    return frames[index]

