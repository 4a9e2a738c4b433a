"""Benchmark one optimiser step of the tiny Qwen2.5-VL on CPU: examples/s and where the time goes.

Compares, in one run (so that a busy machine affects both alike):

* ``before``: the round-1 set-up: fp32, 10 flow frames, digit-by-digit YAML targets
  (~271 tokens + EOS on average);
* ``after``: bf16 autocast, flow+rgb input (12 frames), compact token targets (4-object
  scenes: ~89 answer tokens + think; ``--target-tokens``), the aux composition head, and the
  vision windows attended in one batched call (``pipeline.model.network.batch_vision_attention``);
* ``after, window loop``: the same with transformers' own per-window attention loop.

Each setting runs ``--warmup`` steps, then ``--steps`` timed steps; the time of each phase
(collate, forward, backward, optimiser) is summed. Writes ``reports/bench_train_step.json``.

    python benchmarks/train_step.py                # ~1 min on 2 cores
    python benchmarks/train_step.py --threads 1 --steps 5
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import numpy as np
import torch

from pipeline import model as M
from pipeline.atomic import write_text
from pipeline.codec import SceneCodec, bin_token
from pipeline.model.network import CompositionHead, VisionTap, composition_targets


def _run(name: str, cfg: M.ModelConfig, n_target: int, steps: int, warmup: int, tok, codec,
         window_loop: bool = False) -> dict:
    rng = np.random.default_rng(0)
    model = M.build_model(cfg, tok)
    if window_loop:   # transformers' own vision attention: a Python loop over windows
        for m in model.modules():
            m.__dict__.pop("forward", None)
    head = CompositionHead(cfg.hidden_size, 4)
    tap = VisionTap(model)
    opt = M.training.configure_optimizer(list(model.parameters()) + list(head.parameters()), cfg)
    vocab = [bin_token(i) for i in range(256)]
    examples = [(rng.integers(0, 256, (cfg.n_input_frames, 64, 96, 3), dtype=np.uint8),
                 " ".join(rng.choice(vocab, n_target))) for _ in range(64)]
    times = {"collate": 0.0, "forward": 0.0, "backward": 0.0, "optimizer": 0.0}
    for step in range(warmup + steps):
        t0 = time.perf_counter()
        batch, _ = M.get_batch(examples, tok, cfg, step)
        comps = [("sphere",)] * cfg.batch_size
        t1 = time.perf_counter()
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=cfg.precision == "bf16"):
            loss = model(**batch, use_cache=False).loss.float()
            if cfg.aux_weight:
                logits = head(tap.pooled(batch["video_grid_thw"])).float()
                loss = loss + cfg.aux_weight * torch.nn.functional.cross_entropy(
                    logits.flatten(0, 1), composition_targets(comps, 4).flatten())
        t2 = time.perf_counter()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        t3 = time.perf_counter()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        t4 = time.perf_counter()
        if step >= warmup:
            for k, dt in zip(times, (t1 - t0, t2 - t1, t3 - t2, t4 - t3)):
                times[k] += dt
    total = sum(times.values())
    seq = int(batch["input_ids"].shape[1])
    return {"setting": name, "precision": cfg.precision, "input": cfg.input, "frames": cfg.n_input_frames,
            "target_tokens": n_target, "sequence_length": seq, "batch_size": cfg.batch_size,
            "threads": torch.get_num_threads(), "examples_per_s": round(steps * cfg.batch_size / total, 2),
            "s_per_step": round(total / steps, 4),
            "fraction": {k: round(v / total, 3) for k, v in times.items()}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--target-tokens", type=int, default=120, help="after: tokens per target (answer + think)")
    ap.add_argument("--out", default="reports/bench_train_step.json")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    codec = SceneCodec.from_params({})
    tok = M.build_tokenizer(codec, M.think_vocab({}, 4))
    base = M.ModelConfig()
    settings = [
        ("before", base.model_copy(update={"precision": "fp32", "input": "flow", "aux_weight": 0.0}), 272),
        ("after, fp32", base.model_copy(update={"precision": "fp32"}), args.target_tokens),
        ("after, window loop", base, args.target_tokens),
        ("after", base, args.target_tokens),
    ]
    rows = []
    for name, cfg, n in settings:
        row = _run(name, cfg, n, args.steps, args.warmup, tok, codec, window_loop=name.endswith("window loop"))
        rows.append(row)
        print(f"{name:12s} {row['examples_per_s']:7.2f} ex/s  {row['s_per_step']:.3f} s/step  seq {row['sequence_length']}  "
              + "  ".join(f"{k} {v:.0%}" for k, v in row["fraction"].items()))
    ratio = rows[-1]["examples_per_s"] / rows[0]["examples_per_s"]
    print(f"after / before: {ratio:.2f}x ({args.threads} threads)")
    out = Path(args.out)
    write_text(out, json.dumps({"rows": rows, "speedup_after_vs_before": round(ratio, 2),
                               "cpu_count": os.cpu_count(), "command": "python benchmarks/train_step.py"}, indent=1))


if __name__ == "__main__":
    main()
