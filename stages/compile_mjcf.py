"""DVC stage `compile_mjcf`: scene language -> MJCF XML text.

Reads ``paths.configs`` and params ``sim`` (:class:`pipeline.mjcf.SimOptions`); writes
``paths.mjcf``: one Parquet shard per configs shard with columns scene_id, split, mjcf (XML),
n_objects, n_frames, fps (what the render stage needs besides the XML).
"""

from tqdm import tqdm

from pipeline import shards
from pipeline.mjcf import SimOptions, to_xml
from pipeline.params import load_params, path_of
from pipeline.scene import Scene


def main() -> None:
    p = load_params()
    options = SimOptions(**p["sim"])
    configs, out = path_of(p, "configs"), shards.reset_dir(path_of(p, "mjcf"))
    config_shards = shards.list_shards(configs, "parquet")
    for i, shard in enumerate(tqdm(config_shards, desc="compile_mjcf", unit="shard")):
        rows = []
        for r in shards.read_table(shard, columns=["scene_id", "split", "scene"]).to_pylist():
            scene = Scene.from_yaml(r["scene"], source=f"{shard}:{r['scene_id']}")
            rows.append({"scene_id": r["scene_id"], "split": r["split"], "mjcf": to_xml(scene, options),
                         "n_objects": len(scene.objects), "n_frames": scene.n_frames, "fps": scene.fps})
        shards.write_table(shards.shard_path(out, i, "parquet"), rows, metadata={"params": {"sim": p["sim"]}})
    shards.write_meta(out, {"shards": {"shard": len(config_shards)}, "params": {"sim": p["sim"]}})


if __name__ == "__main__":
    main()
