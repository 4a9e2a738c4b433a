"""DVC stage `sample_configs`: random scenes that pass the paper's filters.

Reads params ``sample`` (:class:`pipeline.sampler.SampleConfig`), ``seed``, ``sim``, ``render`` and
``scene.decimals``; writes ``paths.configs``: Parquet shards of ``shard_size`` scenes with
columns scene_id, split, seed (the scene's own seed), scene (canonical YAML), composition
(comma-joined sorted shapes), n_objects; and meta.json (shard count, split counts, rejections).
"""

from collections import Counter

from tqdm import tqdm

from pipeline import shards
from pipeline.mjcf import SimOptions
from pipeline.params import load_params, path_of
from pipeline.sampler import SampleConfig, SceneFilter, iter_dataset, scene_seed
from pipeline.scene import Decimals


def main() -> None:
    p = load_params()
    # the visibility filter checks objects at the render size (params `render`)
    cfg = SampleConfig(**{**p["sample"], "width": p["render"]["width"], "height": p["render"]["height"]})
    seed = int(p.get("seed", 0))
    decimals = Decimals(**(p.get("scene") or {}).get("decimals", {}))
    out = shards.reset_dir(path_of(p, "configs"))
    rows = []
    with SceneFilter(cfg, SimOptions(**p["sim"])) as filt:
        for i, (sid, split, scene) in enumerate(tqdm(iter_dataset(cfg, seed, filt, decimals), total=cfg.n_scenes,
                                                     desc="sample_configs", unit="scene")):
            rows.append({"scene_id": sid, "split": split, "seed": scene_seed(seed, i),
                         "scene": scene.to_yaml(decimals), "composition": ",".join(scene.composition),
                         "n_objects": len(scene.objects)})
        rejected = dict(filt.rejected)
    meta = {"params": p["sample"], "seed": seed, "units": "scene language v1 (SI, camera angles in deg)"}
    ranges = shards.chunked(len(rows), cfg.shard_size)
    for k, r in enumerate(ranges):
        shards.write_table(shards.shard_path(out, k, "parquet"), rows[r.start:r.stop], metadata=meta)
    shards.write_meta(out, {**meta, "shards": {"shard": len(ranges)}, "rejected": rejected,
                            "splits": dict(Counter(r["split"] for r in rows))})
    print(f"sample_configs: {len(rows)} scenes in {len(ranges)} shards; rejected layouts {rejected}")


if __name__ == "__main__":
    main()
