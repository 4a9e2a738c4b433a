"""DVC stage `flow`: observed optical flow of every rendered clip.

``flow.method``: ``dis`` (OpenCV DIS, default), ``farneback``, ``raft`` (``pipeline.raft``, weights
``flow.raft_weights`` or the shipped ones; `dvc exp run -S flow.method=raft`) or ``gt`` (the
simulator's exact flow, for the ablation `dvc exp run -S flow.method=gt`). Reads ``paths.video``, writes
``paths.flow`` (Zarr shards: flow (N, T-1, H, W, 2) float16 px, scene_id). Shards are
processed on the ``compute`` backend (``pipeline.parallel``), one task per shard; each worker
writes the shards it computes (temp-then-rename: a retried task leaves one complete shard).
"""

import numpy as np
from tqdm import tqdm

from pipeline import shards
from pipeline.entry import run_stage
from pipeline.flow import FlowConfig, flow_config, flow_of
from pipeline.parallel import compute_from_params, parallel_map
from pipeline.params import load_params, path_of


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
        flow = np.stack([flow_of(group["rgb"][j], cfg).astype(np.float16) for j in range(len(ids))])
    path = shards.shard_path(out, i, "zarr")
    shards.remove_stale_temps(path)  # what an earlier attempt of this task left (a killed worker)
    shards.write_arrays(path, {"flow": flow}, scene_ids=ids,
                        attrs={"units": {"flow": "px (u, v) forward"}, "params": flow_params,
                               "max_magnitude": cfg.max_magnitude})
    return len(ids)


def main() -> None:
    p = load_params()
    cfg = flow_config(p)  # validate before starting workers; raft_weights made relative to the params file
    video_dir, out = path_of(p, "video"), shards.reset_dir(path_of(p, "flow"))
    video_shards = shards.list_shards(video_dir, "zarr")
    tasks = [(str(s), i, str(out), cfg.model_dump()) for i, s in enumerate(video_shards)]
    compute = compute_from_params(p) if cfg.method != "gt" else 1  # gt: a copy
    for _ in tqdm(parallel_map(flow_shard, tasks, compute), total=len(tasks), desc="flow shards", unit="shard"):
        pass
    shards.write_meta(out, {"shards": {"shard": len(video_shards)}, "params": p["flow"],
                            "features": {"flow": "(N, T-1, H, W, 2) float16 px"}})


if __name__ == "__main__":
    run_stage(main)
