"""DVC stage `predict`: K sampled scene descriptions per test video.

Reads ``paths.model`` (checkpoint with its codec.json), ``paths.examples`` (which scenes are
test / test_comp) and the model's input frames (``paths.flow`` and/or ``paths.video``, as
``model.input``). Writes ``paths.predictions`` (Parquet, one shard per examples shard:
scene_id, split, sample, text = the sampled tokens, scene = canonical YAML of the detokenised
answer or null, error = one-line error or null), sampling ``model.k`` completions at
``model.temperature`` / ``model.top_p`` under the scene grammar (``model.constrained``).
"""

import zlib

import pyarrow as pa
from tqdm import tqdm

from pipeline import shards
from pipeline.entry import run_stage
from pipeline.model import (ModelConfig, checkpoint_config, generate, load_codec, load_model, read_inputs,
                            to_scene)
from pipeline.params import load_params, path_of
from pipeline.sample_config import TEST_SPLITS

SCHEMA = pa.schema([("scene_id", pa.string()), ("split", pa.string()), ("sample", pa.int32()),
                    ("text", pa.string()), ("scene", pa.string()), ("error", pa.string())])


def main() -> None:
    import torch

    # decoding batches of K short sequences: one thread is as fast as two here, and immune to
    # the OpenMP oversubscription that slowed sampling ~40x on a busy 2-core machine
    torch.set_num_threads(1)
    p = load_params()
    cfg = ModelConfig.from_params(p)
    model, tokenizer = load_model(path_of(p, "model"))
    codec, _ = load_codec(path_of(p, "model"))
    cfg = checkpoint_config(path_of(p, "model"), cfg)
    examples_dir, out = path_of(p, "examples"), shards.reset_dir(path_of(p, "predictions"))
    examples = shards.list_shards(examples_dir, "parquet")
    for i, shard in enumerate(examples):
        scenes = [r for r in shards.read_table(shard, columns=["scene_id", "split"]).to_pylist()
                  if r["split"] in TEST_SPLITS]
        frames = read_inputs(path_of(p, "flow"), path_of(p, "video"), cfg,
                             [r["scene_id"] for r in scenes]) if scenes else {}
        rows = []
        for r in tqdm(scenes, desc=f"predict shard {i}", unit="scene"):
            seed = cfg.seed + zlib.crc32(r["scene_id"].encode())  # per scene, independent of order
            for j, toks in enumerate(generate(model, tokenizer, frames[r["scene_id"]], cfg, codec, k=cfg.k, seed=seed)):
                scene, error = to_scene(toks, codec)
                rows.append({"scene_id": r["scene_id"], "split": r["split"], "sample": j, "text": " ".join(toks),
                             "scene": scene.to_yaml(codec.decimals) if scene else None, "error": error})
        shards.write_table(shards.shard_path(out, i, "parquet"), rows, schema=SCHEMA,
                           metadata={"params": p.get("model"), "model": str(path_of(p, "model"))})
    shards.write_meta(out, {"shards": {"shard": len(examples)}, "params": p.get("model"),
                            "features": {c: str(SCHEMA.field(c).type) for c in SCHEMA.names}})


if __name__ == "__main__":
    run_stage(main)
