"""DVC stage `render`: simulate every scene and render its clip.

Reads ``paths.mjcf`` and params ``render`` (width, height). Writes per mjcf shard:

* ``paths.video``: Zarr shard with rgb (N, T, H, W, 3) uint8, seg (N, T, H, W) int8 (object
  index, -1 background), depth (N, T, H, W) float16 m, flow (N, T-1, H, W, 2) float16
  ground-truth forward flow px, scene_id;
* ``paths.traces``: Parquet shard, one row per scene (``pipeline.traces.TRACES_SCHEMA``).

One task per mjcf shard (``shard_size`` scenes) on the ``compute`` backend (``pipeline.parallel``:
local processes or Ray tasks), each worker with one GL context reused for all its scenes
(``pipeline.render.shared_gl``). A worker writes the shards it renders itself (temp-then-rename,
so a task Ray retries after its worker died leaves one complete shard): sending ~1.8 MB of
arrays per scene back to one writer process would make that process the bottleneck on 2 cores.
The video shard is streamed scene by scene (``pipeline.shards.ArrayShardWriter``), so a worker
holds one scene's arrays at a time, not a whole shard's.

A scene whose MJCF does not compile or whose simulation diverges is left out of the shards and
listed by id in ``meta.json`` of both outputs (``failed``: [{scene_id, error}]), never dropped
silently; the stage fails only when no scene at all could be rendered.

With ``render.camera_effects`` = p > 0, each clip's RGB frames are, with probability p, degraded
as a camera records them (blur, exposure drift, sensor noise, JPEG:
``pipeline.frame_realism.camera_effects``; issue 30), drawn from a generator seeded by the
project ``seed`` and the scene id, so a rerun writes the same pixels; masks, depth and flow stay
the rendered truth. 0 (the default) writes the renders as they are.

Every rendered rollout goes through the physical sanity checks (``pipeline.sanity.rollout_problems``
and MuJoCo's warnings): a scene that fails one is kept and flagged, by scene id and check, in
``paths.traces``'s ``meta.json`` (``sanity``: scenes checked, flagged, counts per check); the
stage prints the count.
"""

import zlib
from collections import Counter

import numpy as np
from tqdm import tqdm

from pipeline import shards
from pipeline.entry import run_stage
from pipeline.frame_realism import camera_effects
from pipeline.parallel import compute_from_params, parallel_map
from pipeline.params import load_params, path_of
from pipeline.mjcf import compile_model
from pipeline.render import render_mjcf
from pipeline.sanity import rollout_problems
from pipeline.simulate import SimulationError
from pipeline.traces import TRACES_SCHEMA, trace_to_row

UNITS = {"rgb": "uint8 RGB", "seg": "object index, -1 = floor/background", "depth": "m along the optical axis",
         "flow": "px, forward (u, v), ground truth"}


def render_shard(task: tuple[str, int, str, str, dict]) -> tuple[list[dict], dict[str, list[str]]]:
    """Render mjcf shard ``(mjcf shard, index i, video dir, traces dir, params)`` and write
    video and traces shard i (without the scenes that failed).

    Returns:
        ``(failed, flags)``: the failed scenes ``[{scene_id, error}]`` (error: one line), and
        ``{scene_id: [failed sanity checks]}`` for every rendered scene (empty: all pass).
    """
    shard, i, video, traces, p = task
    W, H = int(p["render"]["width"]), int(p["render"]["height"])
    p_camera = camera_effects_probability(p["render"])
    rows, failed = [], []
    flags: dict[str, list[str]] = {}
    table = shards.read_table(shard).to_pylist()
    if not table:
        raise SimulationError(f"{shard}: no scene could be rendered, e.g. empty shard")
    attrs = {"units": UNITS, "params": {"render": p["render"]}, "width": W, "height": H, "fps": int(table[0]["fps"])}
    out_video, out_traces = shards.shard_path(video, i, "zarr"), shards.shard_path(traces, i, "parquet")
    for path in (out_video, out_traces):  # what an earlier attempt of this task left (a killed worker)
        shards.remove_stale_temps(path)
    with shards.ArrayShardWriter(out_video, attrs) as arrays:  # one scene in memory at a time
        for r in table:
            try:
                trace, frames = render_mjcf(r["mjcf"], r["n_objects"], r["n_frames"], r["fps"], W, H)
            except (ValueError, SimulationError) as exc:  # this scene's MJCF or its simulation
                failed.append({"scene_id": r["scene_id"], "error": str(exc).splitlines()[0]})
                continue
            flags[r["scene_id"]] = [*(["mujoco_warning"] if trace.warnings else []),
                                    *rollout_problems(compile_model(r["mjcf"]), trace.qpos, trace.qvel)]
            if p_camera > 0:
                rng = np.random.default_rng([int(p.get("seed", 0)), zlib.crc32(str(r["scene_id"]).encode())])
                if rng.random() < p_camera:
                    frames.rgb = camera_effects(frames.rgb, rng)
            arrays.append({"rgb": frames.rgb, "seg": frames.seg, "depth": frames.depth.astype(np.float16),
                           "flow": frames.flow.astype(np.float16)}, scene_id=r["scene_id"])
            rows.append({"scene_id": r["scene_id"], "split": r["split"],
                         **trace_to_row(trace, frames.visible_pixels(r["n_objects"]))})
            del frames
        if not rows:  # leaves no video shard (the writer removes its temporary folder)
            raise SimulationError(f"{shard}: no scene could be rendered, e.g. {failed[0]}")
    shards.write_table(out_traces, rows, schema=TRACES_SCHEMA,
                       metadata={"units": "t s; qpos m + quaternion wxyz; qvel m/s, rad/s (world); "
                                          "contacts N; visible px", "params": {"render": p["render"]}})
    return failed, flags


def camera_effects_probability(render: dict) -> float:
    """``render.camera_effects``: probability per clip of :func:`pipeline.frame_realism.camera_effects`.

    Raises:
        ValueError: not a number in [0, 1] (one line naming the field).
    """
    try:
        value = float(render.get("camera_effects", 0.0))
    except (TypeError, ValueError):
        raise ValueError(f"params.yaml: render.camera_effects: must be a probability in [0, 1], "
                         f"got {render.get('camera_effects')!r}") from None
    if not 0.0 <= value <= 1.0:
        raise ValueError(f"params.yaml: render.camera_effects: must be a probability in [0, 1], got {value}")
    return value


def main() -> None:
    p = load_params()
    W, H = int(p["render"]["width"]), int(p["render"]["height"])
    mjcf_dir = path_of(p, "mjcf")
    video, traces = shards.reset_dir(path_of(p, "video")), shards.reset_dir(path_of(p, "traces"))
    mjcf_shards = shards.list_shards(mjcf_dir, "parquet")
    attrs = {"units": UNITS, "params": {"render": p["render"]}, "width": W, "height": H}
    camera_effects_probability(p["render"])   # a bad value fails before any work
    params = {"render": p["render"], "seed": int(p.get("seed", 0))}
    tasks = [(str(s), i, str(video), str(traces), params) for i, s in enumerate(mjcf_shards)]
    failed: list[dict] = []
    flags: dict[str, list[str]] = {}
    for lost, shard_flags in tqdm(parallel_map(render_shard, tasks, compute_from_params(p)), total=len(tasks),
                                  desc="render shards", unit="shard"):
        failed += lost
        flags.update(shard_flags)
    if failed:
        print(f"render: {len(failed)} scene(s) failed and are left out (meta.json 'failed'): "
              f"{', '.join(f['scene_id'] for f in failed[:10])}{' ...' if len(failed) > 10 else ''}")
    flagged = {sid: checks for sid, checks in flags.items() if checks}
    sanity = {"checked": len(flags), "flagged": len(flagged),
              "by_check": dict(sorted(Counter(c for checks in flagged.values() for c in checks).items())),
              "scenes": dict(sorted(flagged.items()))}
    print(f"render: {len(flags)} scenes, {len(flagged)} flagged by the physical sanity checks {sanity['by_check']}")
    n = len(mjcf_shards)
    shards.write_meta(video, {"shards": {"shard": n}, **attrs, "failed": failed,
                              "features": {"rgb": "(N, T, H, W, 3) uint8", "seg": "(N, T, H, W) int8",
                                           "depth": "(N, T, H, W) float16", "flow": "(N, T-1, H, W, 2) float16"}})
    shards.write_meta(traces, {"shards": {"shard": n}, "params": {"render": p["render"]}, "failed": failed,
                               "sanity": sanity})


if __name__ == "__main__":
    run_stage(main)
