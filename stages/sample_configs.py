"""DVC stage `sample_configs`: random scenes that pass the paper's filters.

Reads params ``sample`` (:class:`pipeline.sample_config.SampleConfig`), ``seed``, ``sim``, ``render`` and
``scene.decimals``; writes ``paths.configs``: Parquet shards of ``shard_size`` scenes with
columns scene_id, split, seed (the scene's own seed), scene (canonical YAML), composition
(comma-joined sorted shapes), n_objects; and meta.json (shard count, split counts, rejections).

Scenes are drawn in chunks on the ``compute`` backend (``pipeline.parallel``); scene i
depends only on (seed, i), so the output is the same for any worker count.
"""

from collections import Counter

from tqdm import tqdm

from pipeline import shards
from pipeline.entry import run_stage
from pipeline.mjcf import SimOptions
from pipeline.parallel import compute_from_params, parallel_map
from pipeline.params import load_params, path_of, section, typed_section
from pipeline.sample_config import SampleConfig, scene_seed
from pipeline.sampler import SampleChunk, sample_chunk
from pipeline.scene import Decimals

CHUNK = 20
"""Scenes per unit of work (~0.5 s each)."""


def main() -> None:
    p = load_params()
    # the visibility filter checks objects at the render size (params `render`)
    render = section(p, "render")
    cfg = typed_section(p, "sample", SampleConfig, required=True,
                        overrides={"width": render["width"], "height": render["height"]})
    seed = int(p.get("seed", 0))
    decimals = typed_section(p, "scene.decimals", Decimals)
    options = typed_section(p, "sim", SimOptions, required=True)
    out = shards.reset_dir(path_of(p, "configs"))
    rows = []
    rejected: Counter[str] = Counter()
    tasks = [SampleChunk(cfg, seed, r.start, r.stop, decimals, options) for r in shards.chunked(cfg.n_scenes, CHUNK)]
    with tqdm(total=cfg.n_scenes, desc="sample_configs", unit="scene") as bar:
        for scenes, chunk_rejected in parallel_map(sample_chunk, tasks, compute_from_params(p)):
            for sid, split, scene in scenes:
                i = len(rows)
                rows.append({"scene_id": sid, "split": split, "seed": scene_seed(seed, i),
                             "scene": scene.to_yaml(decimals), "composition": ",".join(scene.composition),
                             "n_objects": len(scene.objects)})
            rejected.update(chunk_rejected)
            bar.update(len(scenes))
    rejected = dict(rejected)
    meta = {"params": p["sample"], "seed": seed, "units": "scene language v1 (SI, camera angles in deg)"}
    ranges = shards.chunked(len(rows), cfg.shard_size)
    for k, r in enumerate(ranges):
        shards.write_table(shards.shard_path(out, k, "parquet"), rows[r.start:r.stop], metadata=meta)
    shards.write_meta(out, {**meta, "shards": {"shard": len(ranges)}, "rejected": rejected,
                            "splits": dict(Counter(r["split"] for r in rows))})
    print(f"sample_configs: {len(rows)} scenes in {len(ranges)} shards; rejected layouts {rejected}")


if __name__ == "__main__":
    run_stage(main)
