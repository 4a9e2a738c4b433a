"""Look at a shard: a rerun recording of RGB, segmentation, flow, depth and the 3D scene.

``dynamics view data/video/shard-00000.zarr --scene scene-000003 --save scene3.rrd`` writes a
recording on a headless machine; without ``--save`` it writes one next to the shard and opens
the rerun viewer when a display is available. Any stage shard can be given (``configs``,
``traces``, ``video`` ...): the matching video/traces/configs shards are found through the
``paths`` of params.yaml (same shard index).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np

from pipeline import shards, viz
from pipeline.camera import extrinsics, intrinsics
from pipeline.params import load_params, path_of
from pipeline.scene import Scene


def _shard_index(path: Path) -> int:
    m = re.search(r"-(\d{5})\.(zarr|parquet)$", path.name)
    if not m:
        raise shards.ShardError(f"{path}: not a shard (expected <prefix>-NNNNN.zarr|parquet)")
    return int(m.group(1))


def scene_objects(scene: Scene) -> list[dict]:
    """``[{name, shape, size}]`` of a scene, the object description ``viz.record_clip`` takes."""
    return [{"name": n, "shape": o.shape, "size": o.size.model_dump()} for n, o in zip(scene.object_names, scene.objects)]


def camera_dict(scene: Scene, width: int, height: int) -> dict:
    """Camera of a scene as ``viz.record_clip`` takes it (K, world-from-camera RDF rotation, eye)."""
    R, t = extrinsics(scene.camera)
    return {"K": intrinsics(scene.camera.fov, width, height), "rotation": R.T, "translation": -R.T @ t,
            "resolution": (width, height)}


def record_shard(shard: str | Path, scene_id: str | None, out: str | Path, params: dict) -> Path:
    """Write a rerun recording of one scene of a shard.

    Args:
        shard: any stage shard path (``data/<stage>/shard-NNNNN.{zarr,parquet}``).
        scene_id: scene key; ``None`` = first scene of the shard.
        out: ``.rrd`` path to write (atomically).
    Raises:
        ShardError: a shard is missing or does not hold ``scene_id``.
    """
    shard = Path(shard)
    if not shard.exists():
        raise shards.ShardError(f"{shard}: missing shard")
    idx = _shard_index(shard)
    video = shards.open_arrays(shards.shard_path(path_of(params, "video"), idx, "zarr"))
    ids = shards.scene_ids_of(video)
    sid = scene_id or ids[0]
    if sid not in ids:
        raise shards.ShardError(f"{shard}: no scene {sid!r} (has {ids[0]} .. {ids[-1]})")
    j = ids.index(sid)
    rgb, seg = np.asarray(video["rgb"][j]), np.asarray(video["seg"][j])
    depth, flow = np.asarray(video["depth"][j], np.float32), np.asarray(video["flow"][j], np.float32)
    T, H, W = seg.shape

    configs = shards.read_table(path_of(params, "configs")).to_pylist()
    row = next((r for r in configs if r["scene_id"] == sid), None)
    if row is None:
        raise shards.ShardError(f"{path_of(params, 'configs')}: no scene {sid!r}")
    scene = Scene.from_yaml(row["scene"], source=f"{path_of(params, 'configs')}:{sid}")

    traces = shards.read_table(shards.shard_path(path_of(params, "traces"), idx, "parquet")).to_pylist()
    trow = next(r for r in traces if r["scene_id"] == sid)
    n = len(scene.objects)
    qpos = np.asarray(trow["qpos"], dtype=np.float64).reshape(T, n, 7)
    visible = np.asarray(trow["visible"], dtype=np.float64).reshape(T, n)
    return viz.record_clip(out, rgb=rgb, seg=seg, flow=flow, depth=depth, positions=qpos[..., :3],
                           quaternions=qpos[..., 3:], objects=scene_objects(scene),
                           camera=camera_dict(scene, W, H), fps=scene.fps, app_id=f"dynamics_{sid}",
                           scalars={f"visible_px/{name}": visible[:, k] for k, name in enumerate(scene.object_names)})


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("shard", help="a stage shard, e.g. data/video/shard-00000.zarr")
    p.add_argument("--scene", default=None, help="scene id (default: the shard's first scene)")
    p.add_argument("--save", default=None, help="write the recording here (.rrd) instead of opening a viewer")
    p.add_argument("--params", default=None, help="params.yaml to take the paths from (default ./params.yaml)")


def main_cli(args: argparse.Namespace) -> int:
    params = load_params(args.params)
    out = Path(args.save) if args.save else Path(args.shard).with_suffix("").with_name(
        f"{Path(args.shard).with_suffix('').name}-{args.scene or 'first'}.rrd")
    path = record_shard(args.shard, args.scene, out, params)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB)")
    if args.save is None and os.environ.get("DISPLAY") and shutil.which("rerun"):
        subprocess.Popen(["rerun", str(path)])
    elif args.save is None:
        print(f"no display: open it elsewhere with `rerun {path}`")
    return 0
