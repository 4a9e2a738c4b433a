"""DVC stage `compile_mjcf`: scene language -> MJCF XML text.

Reads ``paths.configs`` and params ``sim`` (:class:`pipeline.mjcf.SimOptions`); writes
``paths.mjcf``: one Parquet shard per configs shard with columns scene_id, split, mjcf (XML),
n_objects, n_frames, fps (what the render stage needs besides the XML). Scenes are converted
in chunks on the ``compute`` backend (``pipeline.parallel``).
"""

from tqdm import tqdm

from pipeline import shards
from pipeline.mjcf import SimOptions, to_xml
from pipeline.parallel import chunks, compute_from_params, parallel_map
from pipeline.params import load_params, path_of
from pipeline.scene import Scene

CHUNK = 100
"""Scenes per unit of work (~0.5 s each)."""


def compile_chunk(task: tuple[str, list[dict], SimOptions]) -> list[dict]:
    """MJCF rows of ``(shard path, configs rows (scene_id, split, scene), options)``."""
    shard, rows, options = task
    out = []
    for r in rows:
        scene = Scene.from_yaml(r["scene"], source=f"{shard}:{r['scene_id']}")
        out.append({"scene_id": r["scene_id"], "split": r["split"], "mjcf": to_xml(scene, options),
                    "n_objects": len(scene.objects), "n_frames": scene.n_frames, "fps": scene.fps})
    return out


def main() -> None:
    p = load_params()
    options = SimOptions(**p["sim"])
    configs, out = path_of(p, "configs"), shards.reset_dir(path_of(p, "mjcf"))
    config_shards = shards.list_shards(configs, "parquet")
    tasks, owner = [], []  # units of work and the shard each belongs to
    for i, shard in enumerate(config_shards):
        rows = shards.read_table(shard, columns=["scene_id", "split", "scene"]).to_pylist()
        for part in chunks(rows, CHUNK) or [[]]:
            tasks.append((str(shard), part, options))
            owner.append(i)
    done: list[dict] = []
    results = parallel_map(compile_chunk, tasks, compute_from_params(p))
    for k, rows in enumerate(tqdm(results, total=len(tasks), desc="compile_mjcf", unit="chunk")):
        done += rows
        if k + 1 == len(tasks) or owner[k + 1] != owner[k]:  # the shard is complete
            shards.write_table(shards.shard_path(out, owner[k], "parquet"), done, metadata={"params": {"sim": p["sim"]}})
            done = []
    shards.write_meta(out, {"shards": {"shard": len(config_shards)}, "params": {"sim": p["sim"]}})


if __name__ == "__main__":
    main()
