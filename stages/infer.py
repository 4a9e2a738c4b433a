"""DVC stage `infer`: K sampled scene descriptions per test video.

Reads ``paths.model``, ``paths.examples`` (which scenes are test / test_comp) and the model's
input frames (``paths.flow`` or ``paths.video``, as ``model.input``). Writes
``paths.predictions`` (Parquet, one shard per examples shard: scene_id, split, sample, text,
scene = canonical YAML of the parsed answer or null, error = one-line parse/validation error or
null), sampling ``model.k`` completions at ``model.temperature`` / ``model.top_p``.
"""

import zlib

import pyarrow as pa
from tqdm import tqdm

from pipeline import shards
from pipeline.model import ModelConfig, generate, load_model, parse_output, read_inputs
from pipeline.params import load_params, path_of
from pipeline.scene import Decimals, Scene, SceneError

SCHEMA = pa.schema([("scene_id", pa.string()), ("split", pa.string()), ("sample", pa.int32()),
                    ("text", pa.string()), ("scene", pa.string()), ("error", pa.string())])


def predict(text: str, decimals: Decimals) -> tuple[str | None, str | None]:
    """``(canonical scene YAML, None)`` or ``(None, one-line error)`` for one completion."""
    _, answer = parse_output(text)
    if answer is None:
        return None, "no complete <answer>...</answer> in the output"
    try:
        return Scene.from_yaml(answer, source="answer").to_yaml(decimals), None
    except SceneError as exc:
        return None, str(exc)


def main() -> None:
    import torch

    # decoding batches of K short sequences: one thread is as fast as two here, and immune to
    # the OpenMP oversubscription that slowed sampling ~40x on a busy 2-core machine
    torch.set_num_threads(1)
    p = load_params()
    cfg = ModelConfig.from_params(p)
    decimals = Decimals(**(p.get("scene") or {}).get("decimals", {}))
    model, tokenizer = load_model(path_of(p, "model"))
    examples_dir, out = path_of(p, "examples"), shards.reset_dir(path_of(p, "predictions"))
    data_dir = path_of(p, "flow" if cfg.input == "flow" else "video")
    examples = shards.list_shards(examples_dir, "parquet")
    for i, shard in enumerate(examples):
        scenes = [r for r in shards.read_table(shard, columns=["scene_id", "split"]).to_pylist()
                  if r["split"] in ("test", "test_comp")]
        frames = read_inputs(data_dir, cfg, [r["scene_id"] for r in scenes]) if scenes else {}
        rows = []
        for r in tqdm(scenes, desc=f"infer shard {i}", unit="scene"):
            seed = cfg.seed + zlib.crc32(r["scene_id"].encode())  # per scene, independent of order
            texts = generate(model, tokenizer, frames[r["scene_id"]], cfg, k=cfg.k, seed=seed)
            for j, text in enumerate(texts):
                scene, error = predict(text, decimals)
                rows.append({"scene_id": r["scene_id"], "split": r["split"], "sample": j,
                             "text": text, "scene": scene, "error": error})
        shards.write_table(shards.shard_path(out, i, "parquet"), rows, schema=SCHEMA,
                           metadata={"params": p.get("model"), "model": str(path_of(p, "model"))})
    shards.write_meta(out, {"shards": {"shard": len(examples)}, "params": p.get("model"),
                            "features": {c: str(SCHEMA.field(c).type) for c in SCHEMA.names}})


if __name__ == "__main__":
    main()
