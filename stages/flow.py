"""DVC stage `flow`: observed optical flow of every rendered clip.

``flow.method``: ``dis`` (OpenCV DIS, default), ``farneback``, or ``gt`` (the simulator's exact
flow, for the ablation `dvc exp run -S flow.method=gt`). Reads ``paths.video``, writes
``paths.flow`` (Zarr shards: flow (N, T-1, H, W, 2) float16 px, scene_id). Shards are
processed on the ``compute`` backend (``pipeline.parallel``), one task per shard; each worker
writes the shards it computes (temp-then-rename: a retried task leaves one complete shard).
"""

import numpy as np
from tqdm import tqdm

from pipeline import shards
from pipeline.entry import run_stage
from pipeline.flow import FlowConfig, estimate_flow
from pipeline.parallel import compute_from_params, parallel_map
from pipeline.params import load_params, path_of, typed_section


def flow_shard(task: tuple[str, int, str, dict]) -> int:
    """Flow of video shard ``(video shard, index i, flow dir, params flow)``, written as flow
    shard i. Returns the number of clips."""
    shard, i, out, flow_params = task
    cfg = FlowConfig(**flow_params)
    group = shards.open_arrays(shard)
    ids = shards.scene_ids_of(group)
    if cfg.method == "gt":
        flow = np.asarray(group["flow"][...], dtype=np.float16)
    else:
        flow = np.stack([estimate_flow(group["rgb"][j], method=cfg.method, preset=cfg.preset).astype(np.float16)
                         for j in range(len(ids))])
    path = shards.shard_path(out, i, "zarr")
    shards.remove_stale_temps(path)  # what an earlier attempt of this task left (a killed worker)
    shards.write_arrays(path, {"flow": flow}, scene_ids=ids,
                        attrs={"units": {"flow": "px (u, v) forward"}, "params": flow_params,
                               "max_magnitude": cfg.max_magnitude})
    return len(ids)


def main() -> None:
    p = load_params()
    typed_section(p, "flow", FlowConfig, required=True)  # validate before starting workers
    video_dir, out = path_of(p, "video"), shards.reset_dir(path_of(p, "flow"))
    video_shards = shards.list_shards(video_dir, "zarr")
    tasks = [(str(s), i, str(out), p["flow"]) for i, s in enumerate(video_shards)]
    compute = compute_from_params(p) if p["flow"].get("method", "dis") != "gt" else 1  # gt: a copy
    for _ in tqdm(parallel_map(flow_shard, tasks, compute), total=len(tasks), desc="flow shards", unit="shard"):
        pass
    shards.write_meta(out, {"shards": {"shard": len(video_shards)}, "params": p["flow"],
                            "features": {"flow": "(N, T-1, H, W, 2) float16 px"}})


if __name__ == "__main__":
    run_stage(main)
