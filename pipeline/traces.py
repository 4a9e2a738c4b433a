"""Trace tables: a rollout as Parquet rows, and `dynamics simulate` (docs/design.md §4, §6).

Two layouts of the same :class:`pipeline.simulate.Trace`:

* the ``traces`` stage table, one row per scene (:func:`trace_to_row`,
  :func:`trace_from_row`): ``t`` (T,), ``qpos`` (T*n*7 flattened: x, y, z, qw, qx, qy, qz),
  ``qvel`` (T*n*6: vx, vy, vz, wx, wy, wz, world frame), ``n_objects``, ``names``,
  ``contacts`` (JSON text: per frame a list of ``{a, b, position, force}``) and ``visible``
  (T*n visible pixel counts at the rendered resolution);
* the user-facing ``trace.parquet`` of ``dynamics simulate``, one row per object per frame
  (:func:`object_frame_table`): ``t, object, x, y, z, qw, qx, qy, qz, vx, vy, vz, wx, wy, wz``
  (s, m, unit quaternion, m/s, rad/s; world frame).

``dynamics simulate SCENE.yaml --out DIR`` (:func:`pipeline.cli.simulate_cli`, then :func:`write_simulation`) writes ``trace.parquet``,
``rgb.mp4``, ``masks.npz`` (``seg (T, H, W) int8``, -1 = background, and ``names``), a
``masks.mp4`` preview, and ``events.json``. A scene that fails validation prints the scene
language's one-line error and exits with status 2, writing nothing. Frames are rendered and
written in chunks, so memory does not grow with the clip's length (issue 35:
``benchmarks/sim_memory.py``), and the files appear in ``DIR`` only once all are complete.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any, Mapping

import mujoco
import numpy as np
import pyarrow as pa

from pipeline import sanity as checks, shards
from pipeline.atomic import publish_dir, remove_stale_temps, temp_dir_for
from pipeline.events import EventConfig, events_to_json, events_to_text, extract_events
from pipeline.exposure import expose
from pipeline.mjcf import SimOptions
from pipeline.npz import NpzWriter
from pipeline.render import FrameRenderer, Frames
from pipeline.sanity import SanityConfig
from pipeline.scene import Scene
from pipeline.simulate import Contact, Trace
from pipeline.viz import Mp4Writer, mask_colours

TRACES_SCHEMA = pa.schema([
    ("scene_id", pa.string()),
    ("split", pa.string()),
    ("t", pa.list_(pa.float64())),
    ("qpos", pa.list_(pa.float64())),
    ("qvel", pa.list_(pa.float64())),
    ("n_objects", pa.int32()),
    ("names", pa.list_(pa.string())),
    ("contacts", pa.string()),
    ("visible", pa.list_(pa.int64())),
])
"""Schema of the ``traces`` stage table (one row per scene)."""

OBJECT_FRAME_COLUMNS = ("t", "object", "x", "y", "z", "qw", "qx", "qy", "qz",
                        "vx", "vy", "vz", "wx", "wy", "wz")
"""Columns of ``trace.parquet`` written by ``dynamics simulate`` (one row per object per frame)."""

UNITS = {"t": "s", "x": "m", "y": "m", "z": "m", "qw": "1", "qx": "1", "qy": "1", "qz": "1",
         "vx": "m/s", "vy": "m/s", "vz": "m/s", "wx": "rad/s", "wy": "rad/s", "wz": "rad/s",
         "frame": "world, z up, floor z = 0"}


# --------------------------------------------------------------------------- traces table
def trace_to_row(trace: Trace, visible: np.ndarray) -> dict[str, Any]:
    """One ``traces`` table row (without ``scene_id`` / ``split``) of a rollout.

    Args:
        trace: rollout with T frames of n objects.
        visible: (T, n) int visible pixel counts per frame and object.
    """
    T, n = trace.qpos.shape[:2]
    visible = np.asarray(visible)
    if visible.shape != (T, n):
        raise ValueError(f"visible must have shape ({T}, {n}), got {visible.shape}")
    contacts = [[{"a": c.a, "b": c.b, "position": [float(x) for x in c.position], "force": float(c.force)}
                 for c in frame] for frame in trace.contacts]
    return {
        "t": trace.t.astype(np.float64).tolist(),
        "qpos": trace.qpos.astype(np.float64).reshape(-1).tolist(),
        "qvel": trace.qvel.astype(np.float64).reshape(-1).tolist(),
        "n_objects": n,
        "names": list(trace.names),
        "contacts": json.dumps(contacts, separators=(",", ":")),
        "visible": visible.astype(np.int64).reshape(-1).tolist(),
    }


def trace_from_row(row: Mapping[str, Any]) -> tuple[Trace, np.ndarray]:
    """Inverse of :func:`trace_to_row`: ``(trace, visible (T, n) int64)``."""
    t = np.asarray(row["t"], dtype=np.float64)
    T, n = len(t), int(row["n_objects"])
    contacts = [[Contact(c["a"], c["b"], tuple(c["position"]), float(c["force"])) for c in frame]
                for frame in json.loads(row["contacts"])]
    trace = Trace(t, np.asarray(row["qpos"], dtype=np.float64).reshape(T, n, 7),
                  np.asarray(row["qvel"], dtype=np.float64).reshape(T, n, 6), contacts, list(row["names"]))
    return trace, np.asarray(row["visible"], dtype=np.int64).reshape(T, n)


# --------------------------------------------------------------------------- per-object table
def object_frame_table(trace: Trace) -> pa.Table:
    """``trace.parquet`` of ``dynamics simulate``: one row per object per frame (frame-major)."""
    T, n = trace.qpos.shape[:2]
    state = np.concatenate([trace.qpos, trace.qvel], axis=-1).reshape(T * n, 13)
    columns: dict[str, Any] = {
        "t": np.repeat(trace.t, n),
        "object": np.tile(np.asarray(trace.names, dtype=object), T),
    }
    for j, name in enumerate(OBJECT_FRAME_COLUMNS[2:]):
        columns[name] = state[:, j]
    return pa.table(columns)


# --------------------------------------------------------------------------- dynamics simulate
OUTPUT_FILES = {"trace": "trace.parquet", "rgb": "rgb.mp4", "masks": "masks.npz", "masks_preview": "masks.mp4",
                "events": "events.json"}
"""What ``dynamics simulate`` writes into ``--out``: key -> file name."""

RENDER_CHUNK_PIXELS = 1 << 22
"""Pixels rendered per chunk by :func:`write_simulation` (frames x H x W, at least one frame and at
most :data:`RENDER_CHUNK_FRAMES`): ~16 bytes of chunk buffers per pixel (RGB, id colours, masks,
the upright RGB copy, the preview), so ~70 MB whatever the clip's length (the whole clip in memory
cost ~9.6 MB per frame at 480 x 320, issue 35)."""
RENDER_CHUNK_FRAMES = 64
"""Most frames rendered per chunk."""


def chunk_frames(width: int, height: int) -> int:
    """Frames per render chunk at ``width`` x ``height`` px (:data:`RENDER_CHUNK_PIXELS`)."""
    return max(1, min(RENDER_CHUNK_FRAMES, RENDER_CHUNK_PIXELS // (width * height)))


def write_simulation(scene: Scene, out_dir: str | Path, width: int = 480, height: int = 320,
                     options: SimOptions | None = None, events: EventConfig | None = None,
                     sanity: "SanityConfig | None" = None, source: str = "<scene>") -> dict[str, Path]:
    """Simulate and render a scene and write what ``dynamics simulate`` promises
    (:data:`OUTPUT_FILES`).

    The scene is compiled and checked before anything is written (``pipeline.sanity``: step
    budget and initial interpenetration before the rollout; stability, energy, bounding region,
    sinking and per-step travel after it), so a bad scene raises with ``out_dir`` untouched.
    The timestep is ``options.timestep`` (params ``sim.timestep``, 1/600 s by default), lowered
    where needed so that the frame interval is a whole number of steps
    (``pipeline.mjcf.frame_timestep``); ``trace.parquet`` metadata records the one used.

    Memory does not grow with the clip's length: the rollout (``qpos``/``qvel``, T x n x 13
    floats) is kept, but frames are rendered :func:`chunk_frames` at a time and each chunk is
    appended to ``rgb.mp4``, ``masks.npz`` and ``masks.mp4`` (:class:`pipeline.viz.Mp4Writer`,
    :class:`pipeline.npz.NpzWriter`) before the next; only the per-object visible pixel counts
    (T, n) are accumulated for the events. What does grow is the trace, with frames x objects
    (bounded by the scene schema: ``MAX_FRAMES`` x ``MAX_OBJECTS``; ~1.3 GB peak at 10,000
    frames of 127 spheres). Every file goes into a temporary folder
    ``.<out>.XXXX.tmp`` beside ``out_dir`` (what a killed earlier run left there is removed
    first) that is published when all are complete (:func:`pipeline.atomic.publish_dir`):
    renamed onto ``out_dir`` if it does not exist, otherwise each file moved into it (other
    files there are kept). A run killed or failing midway leaves ``out_dir`` as it was (absent
    if it was), never complete-looking files; two runs into one ``out_dir`` at the same time are
    not supported (the second removes the first's temporary folder as stale).

    Args:
        scene: validated scene.
        out_dir: output folder (created, or the files put into it).
        width, height: render size, px.
        options: simulation options (params ``sim``).
        events: event thresholds (params ``events``).
        sanity: thresholds of the physical checks (params ``sanity``).
        source: scene file name for messages.
    Returns:
        name -> path of ``trace``, ``rgb``, ``masks``, ``masks_preview``, ``events``.
    Raises:
        SceneError: the scene's effects are unknown or out of range.
        pipeline.sanity.PhysicsError: an unstable simulation (MuJoCo) or a failed physical
            check (one line naming the check; :func:`pipeline.sanity.check_simulation`).
        FileExistsError: ``out_dir`` holds a folder named like one of the output files.
    """
    options = options or SimOptions()
    model, trace = checks.check_simulation(scene, options, sanity, source, record_contacts=True)

    out = Path(out_dir)
    remove_stale_temps(out)      # what a killed earlier run left beside out_dir
    tmp = temp_dir_for(out)
    try:
        paths = {key: tmp / name for key, name in OUTPUT_FILES.items()}
        shards.write_table(paths["trace"], object_frame_table(trace),
                           metadata={"units": UNITS, "scene": scene.to_yaml(), "sim": options.model_dump(),
                                     "timestep": float(model.opt.timestep)})
        visible = render_streamed(model, trace.qpos, width, height, scene.fps, scene.object_names,
                                  paths["rgb"], paths["masks"], paths["masks_preview"], scene.exposure_frames)
        cfg = events or EventConfig()
        found = extract_events(trace, visible, cfg)
        shards.write_json(paths["events"], {
            "names": scene.object_names, "fps": scene.fps, "n_frames": scene.n_frames,
            "width": width, "height": height, "events": events_to_json(found),
            "text": events_to_text(found, scene.object_names, cfg.decimals), "config": cfg.model_dump(),
        })
        publish_dir(tmp, out)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return {key: out / name for key, name in OUTPUT_FILES.items()}


def render_streamed(model: mujoco.MjModel, qpos: np.ndarray, width: int, height: int, fps: float,
                    names: list[str], rgb_path: Path, masks_path: Path, preview_path: Path,
                    exposure_frames: float = 0.0) -> np.ndarray:
    """Render ``qpos`` :func:`chunk_frames` frames at a time into ``rgb.mp4``, ``masks.npz`` and
    the ``masks.mp4`` preview (object colours on black), each written atomically. The masks are
    swept over the camera's exposure (``exposure_frames``: ``camera.exposure * fps``,
    :func:`pipeline.exposure.expose`) as the search scores them: each chunk is rendered with one
    frame of its neighbours on either side, whose centroids the sweep needs.

    Args:
        model: compiled scene (camera ``main``).
        qpos: (T, n, 7) float body poses per frame.
        width, height: render size W x H, px.
        fps: frames per second of the videos.
        names: the n object names (``masks.npz``'s ``names``).
        rgb_path, masks_path, preview_path: the three files.
    Returns:
        (T, n) int64 visible pixels per frame and object (``Frames.visible_pixels``).
    """
    T, n = qpos.shape[:2]
    step = chunk_frames(width, height)
    visible = np.zeros((T, n), dtype=np.int64)
    with (FrameRenderer(model, width, height) as renderer, Mp4Writer(rgb_path, [""], fps) as rgb_video,
          Mp4Writer(preview_path, [""], fps) as preview_video, NpzWriter(masks_path) as npz):
        with npz.stream("seg", (T, height, width), np.int8) as seg:
            for a in range(0, T, step):
                lo, hi = (max(a - 1, 0), min(a + step + 1, T)) if exposure_frames > 0 else (a, min(a + step, T))
                frames = renderer.render(qpos[lo:hi], rgb=True, seg=True, depth=False, flow=False)
                keep = slice(a - lo, a - lo + min(step, T - a))
                masks = expose(frames.seg, exposure_frames)[keep]
                visible[a:a + step] = Frames(seg=masks).visible_pixels(n)
                rgb_video.write([frames.rgb[keep]])
                seg.write(masks)
                preview_video.write([mask_colours(masks)])
        npz.write("names", np.asarray(names))
    return visible
