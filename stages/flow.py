"""DVC stage `flow`: observed optical flow of every rendered clip.

``flow.method``: ``dis`` (OpenCV DIS, default), ``farneback``, or ``gt`` (the simulator's exact
flow, for the ablation `dvc exp run -S flow.method=gt`). Reads ``paths.video``, writes
``paths.flow`` (Zarr shards: flow (N, T-1, H, W, 2) float16 px, scene_id).
"""

import numpy as np
from tqdm import tqdm

from pipeline import shards
from pipeline.flow import FlowConfig, estimate_flow
from pipeline.params import load_params, path_of


def main() -> None:
    p = load_params()
    cfg = FlowConfig(**p["flow"])
    video_dir, out = path_of(p, "video"), shards.reset_dir(path_of(p, "flow"))
    video_shards = shards.list_shards(video_dir, "zarr")
    for i, shard in enumerate(tqdm(video_shards, desc="flow shards", unit="shard")):
        group = shards.open_arrays(shard)
        ids = shards.scene_ids_of(group)
        if cfg.method == "gt":
            flow = np.asarray(group["flow"][...], dtype=np.float16)
        else:
            flow = np.stack([
                estimate_flow(group["rgb"][j], method=cfg.method, preset=cfg.preset).astype(np.float16)
                for j in tqdm(range(len(ids)), desc=f"shard {i}", unit="scene", leave=False)
            ])
        shards.write_arrays(shards.shard_path(out, i, "zarr"), {"flow": flow}, scene_ids=ids,
                            attrs={"units": {"flow": "px (u, v) forward"}, "params": p["flow"],
                                   "max_magnitude": cfg.max_magnitude})
    shards.write_meta(out, {"shards": {"shard": len(video_shards)}, "params": p["flow"],
                            "features": {"flow": "(N, T-1, H, W, 2) float16 px"}})


if __name__ == "__main__":
    main()
