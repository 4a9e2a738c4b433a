"""DVC stage `tokenize`: target texts and the tokenizer that spells them.

(Not named ``stages/tokenize.py``: ``python stages/<any>.py`` puts stages/ first on sys.path,
where a ``tokenize.py`` would shadow the standard library module of that name for every stage.)

Reads ``paths.configs`` (scene YAML, split) and ``paths.events`` (``think-*.parquet``: motion
events as text); writes ``paths.tokenizer`` (a ``save_pretrained`` tokenizer folder, byte-level
BPE trained on the train and val targets) and ``paths.examples`` (Parquet, one shard per
configs shard: scene_id, split, target). ``model.reasoning=false`` drops the think part.
"""

import numpy as np

from pipeline import shards
from pipeline.model import ModelConfig, target_text, train_tokenizer
from pipeline.params import load_params, path_of


def main() -> None:
    p = load_params()
    cfg = ModelConfig.from_params(p)
    configs_dir, events_dir = path_of(p, "configs"), path_of(p, "events")
    thinks = {r["scene_id"]: r["think"] for r in shards.read_table(events_dir, prefix="think").to_pylist()}
    out = shards.reset_dir(path_of(p, "examples"))
    examples = []
    for i, shard in enumerate(shards.list_shards(configs_dir, "parquet")):
        rows = shards.read_table(shard, columns=["scene_id", "split", "scene"]).to_pylist()
        if cfg.reasoning and (missing := [r["scene_id"] for r in rows if r["scene_id"] not in thinks]):
            raise shards.ShardError(f"{events_dir}: no think text for {len(missing)} scenes, e.g. {missing[0]!r}")
        rows = [{"scene_id": r["scene_id"], "split": r["split"],
                 "target": target_text(r["scene"], thinks.get(r["scene_id"], ""), cfg.reasoning)} for r in rows]
        shards.write_table(shards.shard_path(out, i, "parquet"), rows, metadata={"params": p.get("model")})
        examples += rows
    texts = [r["target"] for r in examples if r["split"] in ("train", "val")] or [r["target"] for r in examples]
    tokenizer = train_tokenizer(texts, cfg.vocab_size, shards.reset_dir(path_of(p, "tokenizer")))
    lengths = [len(tokenizer.encode(t, add_special_tokens=False)) for t in texts]
    shards.write_meta(out, {
        "shards": {"shard": i + 1}, "params": p.get("model"),
        "features": {"scene_id": "str", "split": "train|val|test|test_comp", "target": "str"},
        "vocab_size": len(tokenizer), "target_tokens": {"mean": float(np.mean(lengths)), "max": max(lengths)},
    })
    print(f"tokenize: {len(examples)} examples, vocab {len(tokenizer)}, "
          f"target tokens mean {np.mean(lengths):.0f} max {max(lengths)}")


if __name__ == "__main__":
    main()
