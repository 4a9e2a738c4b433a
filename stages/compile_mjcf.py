"""DVC stage `compile_mjcf`: scene language -> MJCF XML text.

Reads ``paths.configs``, params ``sim`` (:class:`pipeline.mjcf.SimOptions`) and ``sample.look``
and ``sample.look_shadows`` (``random``: each scene's floor, colours and light drawn from ``(seed, scene_id)``,
:func:`pipeline.scene_look.random_appearance`; ``fixed``: the project's one look); writes
``paths.mjcf``: one Parquet shard per configs shard with columns scene_id, split, mjcf (XML),
n_objects, n_frames, fps (what the render stage needs besides the XML). Scenes are converted
in chunks on the ``compute`` backend (``pipeline.parallel``).
"""

from pipeline import shards
from pipeline.entry import run_stage
from pipeline.mjcf import SimOptions, to_xml
from pipeline.parallel import compute_from_params, map_shards
from pipeline.params import load_params, path_of, typed_section
from pipeline.sample_config import SampleConfig
from pipeline.scene import Scene
from pipeline.scene_look import random_appearance

CHUNK = 100
"""Scenes per unit of work (~0.5 s each)."""


def compile_chunk(task: tuple[str, list[dict], SimOptions, int | None, float]) -> list[dict]:
    """MJCF rows of ``(shard path, configs rows (scene_id, split, scene), options, look seed,
    shadow chance)``; look seed None = the fixed look."""
    shard, rows, options, look_seed, p_shadows = task
    out = []
    for r in rows:
        scene = Scene.from_yaml(r["scene"], source=f"{shard}:{r['scene_id']}")
        look = None if look_seed is None else random_appearance(look_seed, r["scene_id"], len(scene.objects), p_shadows)
        out.append({"scene_id": r["scene_id"], "split": r["split"], "mjcf": to_xml(scene, options, look),
                    "n_objects": len(scene.objects), "n_frames": scene.n_frames, "fps": scene.fps})
    return out


def main() -> None:
    p = load_params()
    options = typed_section(p, "sim", SimOptions, required=True)
    sample = typed_section(p, "sample", SampleConfig)
    look_seed = int(p.get("seed", 0)) if sample.look == "random" else None
    configs, out = path_of(p, "configs"), shards.reset_dir(path_of(p, "mjcf"))
    config_shards = shards.list_shards(configs, "parquet")
    groups = (shards.read_table(shard, columns=["scene_id", "split", "scene"]).to_pylist() for shard in config_shards)
    for i, rows in map_shards(compile_chunk, groups, lambda i, part: (str(config_shards[i]), part, options, look_seed, sample.look_shadows), CHUNK,
                              compute_from_params(p), desc="compile_mjcf"):
        shards.write_table(shards.shard_path(out, i, "parquet"), rows, metadata={"params": {"sim": p["sim"]}})
    shards.write_meta(out, {"shards": {"shard": len(config_shards)}, "params": {"sim": p["sim"]},
                            "look": "fixed" if look_seed is None else "random"})


if __name__ == "__main__":
    run_stage(main)
