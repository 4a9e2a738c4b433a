"""Observed clips and prediction rows: what Best@K and CMA-ES score against."""

from __future__ import annotations

from typing import Any, Iterable

import numpy as np

from pipeline import shards
from pipeline.scene import Scene
from pipeline.shards import ShardError


def at_clip_timing(scene: Scene, n_frames: int, fps: int | None) -> Scene:
    """The scene on the observed clip's time base: ``fps`` and ``duration = n_frames / fps``.

    The frame rate and length of a video are known, not inferred (as in the main job), so a
    candidate that states other values is re-timed before it is scored. ``fps=None`` keeps
    the scene's own rate.
    """
    fps = int(fps or scene.fps)
    duration = n_frames / fps
    if scene.fps == fps and abs(scene.duration - duration) < 1e-9:
        return scene
    return scene.replace(fps=fps, duration=duration)


def samples_by_scene(rows: Any, splits: Iterable[str] | None = None,
                     k: int | None = None) -> dict[str, list[dict[str, Any]]]:
    """Prediction rows (``paths.predictions``) grouped by scene, sorted by ``sample``.

    Args:
        rows: a ``pyarrow.Table`` or list of dicts with scene_id, split, sample, scene, ...
        splits: keep only these splits (default all).
        k: keep the first ``k`` samples of each scene (default all).
    Returns:
        ``{scene_id: [row, ...]}`` in order of first appearance.
    """
    if hasattr(rows, "to_pylist"):
        rows = rows.to_pylist()
    keep = None if splits is None else set(splits)
    out: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        if keep is None or r["split"] in keep:
            out.setdefault(r["scene_id"], []).append(r)
    return {sid: sorted(rs, key=lambda r: r["sample"])[:k] for sid, rs in out.items()}


def parse_sample(row: dict[str, Any]) -> Scene | None:
    """The scene of a prediction row (None when the model's output did not parse)."""
    if not row.get("scene"):
        return None
    return Scene.from_yaml(row["scene"], source=f"{row.get('scene_id', '<prediction>')}/sample {row.get('sample')}")


class Observations:
    """Observed clips of the synthetic dataset, by scene id.

    Segmentation: the render stage's ``seg`` (rendered ground truth, ``paths.video``); flow:
    the flow stage's ``flow`` (estimated from RGB by params ``flow.method``, ``paths.flow``);
    frame rate: the video shard's ``fps`` attribute. Only scene-id arrays are read up front.

    Args:
        video_dir, flow_dir: stage directories (``paths.video``, ``paths.flow``).
    Raises:
        ShardError: a directory or shard is missing or unreadable.
    """

    def __init__(self, video_dir, flow_dir):
        self._video: dict[str, tuple[Any, int]] = {}
        self._flow: dict[str, tuple[Any, int]] = {}
        for _, group in shards.iter_array_shards(video_dir):
            for j, sid in enumerate(shards.scene_ids_of(group)):
                self._video[sid] = (group, j)
        for _, group in shards.iter_array_shards(flow_dir):
            for j, sid in enumerate(shards.scene_ids_of(group)):
                self._flow[sid] = (group, j)
        self.video_dir, self.flow_dir = video_dir, flow_dir

    def __contains__(self, sid: str) -> bool:
        return sid in self._video

    @property
    def frame_size(self) -> tuple[int, int]:
        """``(width, height)`` px of the clips (of the first shard; every shard is rendered alike)."""
        if not self._video:
            raise ValueError(f"{self.video_dir}: no scenes")
        group, _ = next(iter(self._video.values()))
        shape = group["seg"].shape  # (N, T, H, W)
        return int(shape[3]), int(shape[2])

    def get(self, sid: str) -> tuple[np.ndarray, np.ndarray, int | None]:
        """``seg (T, H, W) int8``, ``flow (T-1, H, W, 2) float32`` px and fps (None if unknown).

        Raises:
            ShardError: the scene is missing from the video or flow shards.
        """
        if sid not in self._video:
            raise ShardError(f"{self.video_dir}: no scene {sid!r}")
        if sid not in self._flow:
            raise ShardError(f"{self.flow_dir}: no scene {sid!r}")
        vg, i = self._video[sid]
        fg, j = self._flow[sid]
        fps = vg.attrs.get("fps")
        return (np.asarray(vg["seg"][i], dtype=np.int8), np.asarray(fg["flow"][j], dtype=np.float32),
                int(fps) if fps else None)
