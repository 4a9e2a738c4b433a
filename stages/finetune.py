"""DVC stage `finetune`: train the vision-language model on (frames, target text) pairs.

Reads ``paths.examples`` (scene_id, split, target), ``paths.tokenizer`` and the model's input
frames: ``paths.flow`` when ``model.input=flow`` (colour-coded flow), else ``paths.video`` (RGB).
Writes ``paths.model``: a ``save_pretrained`` folder with tokenizer, trainer state,
``train_curve.csv`` and ``train_curve.png``. ``--resume`` continues from a checkpoint there
(outside DVC, which clears its outputs before a run).
"""

import argparse
import json

from pipeline import shards
from pipeline.model import ModelConfig, load_tokenizer, plot_curve, read_inputs, train
from pipeline.params import load_params, path_of


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resume", action="store_true", help="continue from the checkpoint in paths.model")
    args = parser.parse_args()
    p = load_params()
    cfg = ModelConfig.from_params(p)
    rows = [r for r in shards.read_table(path_of(p, "examples")).to_pylist() if r["split"] in ("train", "val")]
    frames = read_inputs(path_of(p, "flow" if cfg.input == "flow" else "video"), cfg, [r["scene_id"] for r in rows])
    train_set = [(frames[r["scene_id"]], r["target"]) for r in rows if r["split"] == "train"]
    val_set = [(frames[r["scene_id"]], r["target"]) for r in rows if r["split"] == "val"]
    out = path_of(p, "model")
    if not args.resume:
        shards.reset_dir(out)
    tokenizer = load_tokenizer(cfg.pretrained or path_of(p, "tokenizer"))
    print(f"finetune: {len(train_set)} train / {len(val_set)} val scenes, input {cfg.input}, "
          f"frames {next(iter(frames.values())).shape}")
    result = train(train_set, val_set, cfg, out, tokenizer=tokenizer, resume=args.resume)
    plot_curve(out)
    print("finetune:", json.dumps(result))


if __name__ == "__main__":
    main()
