"""DVC stage `tokenize`: compact token targets and the word-level tokenizer that spells them.

(Not named ``stages/tokenize.py``: ``python stages/<any>.py`` puts stages/ first on sys.path,
where a ``tokenize.py`` would shadow the standard library module of that name for every stage.)

Reads ``paths.configs`` (scene YAML, split) and ``paths.events`` (``think-*.parquet``: motion
events as text); writes ``paths.tokenizer`` (the fixed word-level vocabulary of params
``tokens``/``sample``/``events``, :func:`pipeline.model.build_tokenizer`) and ``paths.examples``
(Parquet, one shard per configs shard: scene_id, split, target = space-separated tokens:
``<think> events </think> <answer> quantised scene </answer>``; ``model.reasoning=false`` drops
the think part). meta.json reports target lengths and the quantisation error per field
against ``scene.decimals``.
"""

from collections import defaultdict

import numpy as np

from pipeline import shards
from pipeline.codec import SceneCodec, target_tokens, text_of
from pipeline.entry import run_stage
from pipeline.model import ModelConfig, build_tokenizer, think_vocab
from pipeline.params import load_params, path_of
from pipeline.scene import Scene


def main() -> None:
    p = load_params()
    cfg = ModelConfig.from_params(p)
    codec = SceneCodec.from_params(p)
    configs_dir, events_dir = path_of(p, "configs"), path_of(p, "events")
    thinks = {r["scene_id"]: r["think"] for r in shards.read_table(events_dir, prefix="think").to_pylist()}
    out = shards.reset_dir(path_of(p, "examples"))
    tokenizer = build_tokenizer(codec, think_vocab(p, codec.max_objects), shards.reset_dir(path_of(p, "tokenizer")))
    lengths: dict[int, list[int]] = defaultdict(list)
    scenes = []
    n_shards = 0
    for i, shard in enumerate(shards.list_shards(configs_dir, "parquet")):
        rows = shards.read_table(shard, columns=["scene_id", "split", "scene"]).to_pylist()
        if cfg.reasoning and (missing := [r["scene_id"] for r in rows if r["scene_id"] not in thinks]):
            raise shards.ShardError(f"{events_dir}: no think text for {len(missing)} scenes, e.g. {missing[0]!r}")
        examples = []
        for r in rows:
            scene = Scene.from_yaml(r["scene"], source=f"{shard}: {r['scene_id']}")
            toks = target_tokens(codec, scene, thinks[r["scene_id"]] if cfg.reasoning else None)
            examples.append({"scene_id": r["scene_id"], "split": r["split"], "target": text_of(toks)})
            lengths[len(scene.objects)].append(len(toks) + 1)  # + EOS
            if r["split"] in ("train", "val"):
                scenes.append(scene)
        shards.write_table(shards.shard_path(out, i, "parquet"), examples,
                           metadata={"params": p.get("model"), "tokens": p.get("tokens")})
        n_shards = i + 1
    all_lengths = [n for v in lengths.values() for n in v]
    error = codec.quantisation_error(scenes)
    shards.write_meta(out, {
        "shards": {"shard": n_shards}, "params": {"model": p.get("model"), "tokens": p.get("tokens")},
        "features": {"scene_id": "str", "split": "train|val|test|test_comp", "target": "space-separated tokens"},
        "vocab_size": len(tokenizer), "codec": codec.to_dict(),
        "target_tokens": {"mean": float(np.mean(all_lengths)), "max": max(all_lengths),
                          "by_objects": {str(k): {"mean": float(np.mean(v)), "max": max(v)}
                                         for k, v in sorted(lengths.items())}},
        "quantisation_error": error,
    })
    worst = max(error, key=lambda f: error[f]["max_abs"] / error[f]["decimals_step"])
    print(f"tokenize: {len(all_lengths)} examples, vocab {len(tokenizer)}, target tokens (with EOS) "
          f"mean {np.mean(all_lengths):.0f} max {max(all_lengths)}; by objects "
          + ", ".join(f"{k}: {max(v)}" for k, v in sorted(lengths.items()))
          + f"; largest quantisation error vs decimals: {worst} {error[worst]['max_abs']:.4g} "
            f"(step {error[worst]['decimals_step']:g})")


if __name__ == "__main__":
    run_stage(main)
