"""What the vision tower sees: frame selection, flow/RGB input, Qwen2-VL patch layout.

The video patches are laid out exactly as transformers' Qwen2-VL video processor does it
(without torchvision, which it needs and which does not install here; docs/design.md §10).
"""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path
from typing import Iterable

import numpy as np
from PIL import Image
from tqdm.auto import tqdm

from pipeline.flow import flow_to_rgb
from pipeline.model.config import ModelConfig, ModelError
from pipeline.shards import iter_array_shards, list_shards, open_arrays, scene_ids_of

IMAGE_MEAN = (0.48145466, 0.4578275, 0.40821073)
IMAGE_STD = (0.26862954, 0.26130258, 0.27577711)
"""Per-channel normalisation of Qwen2-VL's processors (``OPENAI_CLIP_MEAN`` / ``_STD``), on [0, 1] RGB."""


def frame_indices(n_total: int, n: int) -> np.ndarray:
    """``n`` uniformly spaced indices into a clip of ``n_total`` frames (first and last included).

    The paper samples 10 frames uniformly from each 1 s clip.

    Returns:
        ``(n,) int64`` increasing indices in ``[0, n_total)`` (repeats when ``n > n_total``).

    Raises:
        ModelError: ``n_total < 1`` or ``n < 1``.
    """
    if n_total < 1 or n < 1:
        raise ModelError(f"frame_indices: need n_total >= 1 and n >= 1, got n_total={n_total}, n={n}")
    return np.round(np.linspace(0, n_total - 1, n)).astype(np.int64)


def model_input(
    rgb: np.ndarray | None,
    flow: np.ndarray | None,
    cfg: ModelConfig,
    max_magnitude: float | None = None,
) -> np.ndarray:
    """The frames the model sees for one clip.

    Args:
        rgb: ``(T, H, W, 3) uint8`` video (needed for ``rgb`` and ``flow+rgb``).
        flow: ``(T-1, H, W, 2)`` float forward flow in px (needed for ``flow`` and ``flow+rgb``);
            colour-coded with ``pipeline.flow.flow_to_rgb(flow, max_magnitude)``.
        cfg: model config (``input``, ``n_frames``, patch geometry).
        max_magnitude: flow magnitude (px) mapped to full saturation; ``None`` = per clip.

    Returns:
        ``(cfg.n_input_frames, H', W', 3) uint8``: ``flow``/``rgb``: ``n_frames`` frames
        uniformly sampled over the clip; ``flow+rgb``: the first RGB frame repeated
        ``temporal_patch_size`` times (one temporal patch), then the ``n_frames`` flow frames.
        Resized (bicubic) to the nearest multiples of ``cfg.grid_factor`` if needed.

    Raises:
        ModelError: the input that ``cfg.input`` names is missing or has the wrong shape.
    """
    parts = []
    if cfg.input in ("rgb", "flow+rgb"):
        if rgb is None:
            raise ModelError(f"model.input is {cfg.input!r} but no rgb video was given")
        rgb = np.asarray(rgb)
        if rgb.ndim != 4 or rgb.shape[-1] != 3 or rgb.dtype != np.uint8:
            raise ModelError(f"rgb: must be (T, H, W, 3) uint8, got {rgb.shape} {rgb.dtype}")
        if cfg.input == "rgb":
            parts.append(rgb[frame_indices(len(rgb), cfg.n_frames)])
        else:
            parts.append(np.repeat(rgb[:1], cfg.temporal_patch_size, axis=0))
    if cfg.input in ("flow", "flow+rgb"):
        if flow is None:
            raise ModelError(f"model.input is {cfg.input!r} but no flow was given")
        flow = np.asarray(flow)
        if flow.ndim != 4 or flow.shape[-1] != 2:
            raise ModelError(f"flow: must have shape (T-1, H, W, 2), got {flow.shape}")

        idx = frame_indices(len(flow), cfg.n_frames)
        parts.append(flow_to_rgb(flow[idx].astype(np.float32), max_magnitude))
    shapes = {p.shape[1:3] for p in parts}
    if len(shapes) > 1:
        raise ModelError(f"rgb and flow: must have the same frame size, got {sorted(shapes)}")
    return fit_to_grid(np.concatenate(parts), cfg.grid_factor)


def fit_to_grid(frames: np.ndarray, factor: int) -> np.ndarray:
    """Resize ``(T, H, W, 3) uint8`` frames (bicubic) so that H and W are multiples of ``factor``.

    Each side goes to the nearest multiple (at least ``factor``), as Qwen2-VL's ``smart_resize``
    does for small images. Frames that already fit are returned unchanged.
    """
    _, h, w, _ = frames.shape
    new_h, new_w = max(factor, round(h / factor) * factor), max(factor, round(w / factor) * factor)
    if (new_h, new_w) == (h, w):
        return frames

    return np.stack([np.asarray(Image.fromarray(f).resize((new_w, new_h), Image.BICUBIC)) for f in frames])


def video_patches(frames: np.ndarray, cfg: ModelConfig) -> tuple[np.ndarray, np.ndarray]:
    """Flatten a video into Qwen2-VL vision patches, in transformers' order.

    Same result as ``Qwen2VLVideoProcessor`` with ``do_resize=False`` (rescale to [0, 1],
    normalise with :data:`IMAGE_MEAN` / :data:`IMAGE_STD`, then its ``patchify``): patches are
    ordered (t, h-block, w-block, h-in-block, w-in-block) with ``merge_size`` x ``merge_size``
    blocks, and each patch is flattened (channel, time, row, column).

    Args:
        frames: ``(T, H, W, 3) uint8`` with ``T`` a multiple of ``cfg.temporal_patch_size`` and
            ``H, W`` multiples of ``cfg.patch_size * cfg.spatial_merge_size``.
        cfg: patch geometry (``patch_size``, ``spatial_merge_size``, ``temporal_patch_size``).

    Returns:
        ``pixel_values_videos (T/tp * H/p * W/p, 3 * tp * p * p) float32`` and
        ``video_grid_thw (1, 3) int64`` = ``[[T/tp, H/p, W/p]]``.

    Raises:
        ModelError: wrong dtype or shape, or sizes that do not divide.
    """
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8:
        raise ModelError(f"frames: must be (T, H, W, 3) uint8, got {frames.shape} {frames.dtype}")
    t, h, w, c = frames.shape
    p, m, tp = cfg.patch_size, cfg.spatial_merge_size, cfg.temporal_patch_size
    if t % tp or h % (p * m) or w % (p * m):
        raise ModelError(
            f"frames: T must be a multiple of {tp} and H, W multiples of {p * m}, got T={t}, H={h}, W={w}"
        )
    x = frames.astype(np.float32) / 255.0
    x = (x - np.asarray(IMAGE_MEAN, np.float32)) / np.asarray(IMAGE_STD, np.float32)
    x = x.transpose(0, 3, 1, 2)  # (T, C, H, W)
    gt, gh, gw = t // tp, h // p, w // p
    x = x.reshape(gt, tp, c, gh // m, m, p, gw // m, m, p)
    # transformers: permute(0, 1, 4, 7, 5, 8, 3, 2, 6, 9) on the same view with a batch axis in front
    x = x.transpose(0, 3, 6, 4, 7, 2, 1, 5, 8)
    patches = np.ascontiguousarray(x.reshape(gt * gh * gw, c * tp * p * p))
    return patches, np.array([[gt, gh, gw]], dtype=np.int64)


def n_video_tokens(grid_thw: np.ndarray, cfg: ModelConfig) -> int:
    """Number of ``<|video_pad|>`` tokens for a video grid: ``t * h * w / merge**2``."""
    return int(np.prod(grid_thw)) // cfg.spatial_merge_size**2


def _read_flow_shard(task: tuple[str, dict[str, tuple[str, int]], ModelConfig, set[str] | None]) -> dict[str, np.ndarray]:
    """Model frames of the wanted scenes of one flow shard (``(flow shard, scene_id -> (video
    shard, index)), cfg, wanted``)."""
    flow_shard, rgb_at, cfg, wanted = task
    group = open_arrays(flow_shard)
    max_magnitude = group.attrs.get("max_magnitude")
    use_rgb = cfg.input == "flow+rgb"
    videos: dict[str, object] = {}
    out: dict[str, np.ndarray] = {}
    for i, sid in enumerate(scene_ids_of(group)):
        if (wanted is not None and sid not in wanted) or (use_rgb and sid not in rgb_at):
            continue
        rgb = None
        if use_rgb:
            shard, j = rgb_at[sid]
            if shard not in videos:
                videos[shard] = open_arrays(shard)
            rgb = np.asarray(videos[shard]["rgb"][j, :1])
        out[sid] = model_input(rgb, np.asarray(group["flow"][i]), cfg, max_magnitude)
    return out


def read_inputs(
    flow_dir: str | Path | None,
    video_dir: str | Path | None,
    cfg: ModelConfig,
    scene_ids: Iterable[str] | None = None,
    workers: int = 1,
) -> dict[str, np.ndarray]:
    """Model frames for scenes of the flow and video stage directories.

    Args:
        flow_dir: flow stage output (Zarr shards with ``flow (N, T-1, H, W, 2)`` and attribute
            ``max_magnitude`` px); needed for ``flow`` and ``flow+rgb``.
        video_dir: video stage output (``rgb (N, T, H, W, 3) uint8``); needed for ``rgb`` and
            ``flow+rgb``. Shards of both stages hold the same scenes in the same order.
        cfg: model config.
        scene_ids: scenes to read (default: all).
        workers: processes reading flow shards at once (~12 ms a scene in one process; the
            result is the same for any number).

    Returns:
        ``scene_id -> (cfg.n_input_frames, H, W, 3) uint8`` (see :func:`model_input`).

    Raises:
        ModelError: a requested scene is in no shard, or a needed directory is not given.
        pipeline.shards.ShardError: missing or unreadable shards.
    """
    use_flow, use_rgb = cfg.input in ("flow", "flow+rgb"), cfg.input in ("rgb", "flow+rgb")
    if (use_flow and flow_dir is None) or (use_rgb and video_dir is None):
        raise ModelError(f"model.input {cfg.input!r}: needs {'flow and video' if use_flow and use_rgb else cfg.input} shards")
    wanted = None if scene_ids is None else set(scene_ids)
    rgb_at: dict[str, tuple[str, int]] = {}
    if use_rgb:
        for shard, group in iter_array_shards(video_dir):
            for i, sid in enumerate(scene_ids_of(group)):
                if wanted is None or sid in wanted:
                    rgb_at[sid] = (str(shard), i)
    out: dict[str, np.ndarray] = {}
    bar = tqdm(total=len(wanted) if wanted is not None else None, desc=f"read {cfg.input} inputs", unit="scene",
               disable=wanted is not None and len(wanted) < 500)
    if use_flow:
        tasks = [(str(shard), rgb_at, cfg, wanted) for shard in list_shards(flow_dir, "zarr")]
        if workers > 1 and len(tasks) > 1:
            with ProcessPoolExecutor(min(workers, len(tasks)), mp_context=get_context("spawn")) as pool:
                parts = pool.map(_read_flow_shard, tasks)
                for part in parts:
                    out.update(part)
                    bar.update(len(part))
        else:
            for task in tasks:
                part = _read_flow_shard(task)
                out.update(part)
                bar.update(len(part))
    else:
        groups: dict[str, object] = {}
        for sid, (shard, j) in rgb_at.items():
            g = groups.setdefault(shard, open_arrays(shard))
            out[sid] = model_input(np.asarray(g["rgb"][j]), None, cfg)
            bar.update(1)
    bar.close()
    if wanted is not None and (missing := sorted(wanted - out.keys())):
        raise ModelError(f"{flow_dir if use_flow else video_dir}: no {cfg.input} input for {len(missing)} scenes, "
                         f"e.g. {missing[0]!r}")
    return out
