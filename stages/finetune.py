"""DVC stage `finetune`: train the vision-language model on (frames, target tokens) pairs.

Reads ``paths.examples`` (scene_id, split, target), ``paths.tokenizer`` and the model's input
frames (``paths.flow`` and/or ``paths.video``, as ``model.input``). Starts from the checkpoint
``model.init`` (the shipped one by default; ``scratch`` = random weights) and trains
``model.max_steps`` optimiser steps. Writes ``paths.model`` (a ``save_pretrained`` folder with
tokenizer, codec.json, trainer state, ``train_curve.csv``/``.png``) and copies the curve to
``paths.reports``/``train_curve.{csv,png}``. ``--resume`` continues from a checkpoint in
``paths.model`` (outside DVC, which clears its outputs before a run).
"""

import argparse
import json
import logging
import shutil
from pathlib import Path

import torch

from pipeline import shards
from pipeline.atomic import atomic_path
from pipeline.codec import SceneCodec
from pipeline.entry import run_stage
from pipeline.model import (CURVE_FILE, CURVE_PNG, ModelConfig, extend_tokenizer, load_tokenizer, plot_curve,
                            read_inputs, think_vocab, train)
from pipeline.parallel import compute_from_params
from pipeline.params import load_params, path_of

log = logging.getLogger(__name__)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resume", action="store_true", help="continue from the checkpoint in paths.model")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar (log lines only)")
    args = parser.parse_args()
    p = load_params()
    cfg = ModelConfig.from_params(p)
    torch.set_num_threads(cfg.threads)
    codec = SceneCodec.from_params(p)
    rows = [r for r in shards.read_table(path_of(p, "examples")).to_pylist() if r["split"] in ("train", "val")]
    frames = read_inputs(path_of(p, "flow"), path_of(p, "video"), cfg, [r["scene_id"] for r in rows],
                         workers=compute_from_params(p).n_workers)
    train_set = [(frames[r["scene_id"]], r["target"]) for r in rows if r["split"] == "train"]
    val_set = [(frames[r["scene_id"]], r["target"]) for r in rows if r["split"] == "val"]
    out = path_of(p, "model")
    if not args.resume:
        shards.reset_dir(out)
    if cfg.pretrained:  # real weights: their tokenizer, plus the scene tokens and event words
        tokenizer = load_tokenizer(cfg.pretrained)
        extend_tokenizer(tokenizer, codec, think_vocab(p, codec.max_objects))
    else:
        tokenizer = load_tokenizer(path_of(p, "tokenizer"))
    print(f"finetune: {len(train_set)} train / {len(val_set)} val scenes, input {cfg.input}, "
          f"frames {next(iter(frames.values())).shape}, init {cfg.init}, {cfg.max_steps} steps")
    result = train(train_set, val_set, cfg, out, tokenizer=tokenizer, codec=codec,
                   think_words=think_vocab(p, codec.max_objects), resume=args.resume,
                   progress=not args.no_progress)
    plot_curve(out)
    reports = Path(path_of(p, "reports"))
    reports.mkdir(parents=True, exist_ok=True)
    for name in (CURVE_FILE, CURVE_PNG):
        if (out / name).exists():
            with atomic_path(reports / name) as tmp:
                shutil.copyfile(out / name, tmp)
    if result["stopped_by"] == "max_minutes":
        log.warning(f"WARNING: the safety cap model.max_minutes={cfg.max_minutes} stopped training at "
                    f"step {result['step']} of {cfg.max_steps}")
    shards.write_json(out / "result.json", result)
    print("finetune:", json.dumps(result))


if __name__ == "__main__":
    run_stage(main)
