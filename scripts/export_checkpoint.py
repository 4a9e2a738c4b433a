"""Export a trained checkpoint as the shipped default (fp16 weights, no optimizer state) with a
model card, and measure it on the profile's test splits.

    python scripts/export_checkpoint.py data/pretrain/model pipeline/checkpoints/dynamics-tiny --params profiles/pretrain.yaml

Writes DST/{config.json, model.safetensors (fp16), tokenizer files, codec.json, dynamics_model.json,
composition_head.pt, train_curve.csv, train_curve.png, metrics.json, README.md}. The metrics are
greedy and K-sample constrained decoding on the test and test_comp splits of the profile:
valid fraction and composition accuracy (first sample).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline import model as M  # noqa: E402
from pipeline import shards  # noqa: E402
from pipeline.atomic import atomic_dir  # noqa: E402
from pipeline.codec import composition_of, split_completion  # noqa: E402
from pipeline.params import load_params, path_of  # noqa: E402

COPY = ("codec.json", "dynamics_model.json", "composition_head.pt", "train_curve.csv", "train_curve.png", "result.json")


def evaluate(model_dir: Path, params: dict, limit: int) -> dict:
    """Composition accuracy and valid fraction of the first of K samples per test scene."""
    cfg = M.ModelConfig.from_params(params)
    model, tok = M.load_model(model_dir)
    codec, _ = M.load_codec(model_dir)
    cfg = M.checkpoint_config(model_dir, cfg)
    rows = [r for r in shards.read_table(path_of(params, "examples")).to_pylist() if r["split"] in ("test", "test_comp")]
    out = {}
    for split in ("test", "test_comp"):
        sel = [r for r in rows if r["split"] == split][:limit]
        if not sel:
            continue
        frames = M.read_inputs(path_of(params, "flow"), path_of(params, "video"), cfg, [r["scene_id"] for r in sel])
        comp = valid = 0
        for i, r in enumerate(sel):
            samples = M.generate(model, tok, frames[r["scene_id"]], cfg, codec, k=cfg.k, seed=i)
            valid += sum(M.to_scene(s, codec)[0] is not None for s in samples)
            _, ans = split_completion(samples[0])
            comp += ans is not None and composition_of(ans) == composition_of(r["target"].split())
        out[split] = {"scenes": len(sel), "composition_accuracy": round(comp / len(sel), 3),
                      "valid": f"{valid}/{len(sel) * cfg.k}"}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("src")
    ap.add_argument("dst")
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--limit", type=int, default=100, help="test scenes per split to measure")
    ap.add_argument("--card", default="model_card.md", help="model card template in scripts/ "
                    "(model_card_wide.md for dynamics-wide)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    src, dst = Path(args.src), Path(args.dst)
    params = load_params(args.params)
    model, tok = M.load_model(src)
    with atomic_dir(dst) as tmp:
        model.half().save_pretrained(str(tmp))
        tok.save_pretrained(str(tmp))
        for name in COPY:
            if (src / name).exists():
                shutil.copyfile(src / name, tmp / name)
        metrics = evaluate(src, params, args.limit)
        (tmp / "metrics.json").write_text(json.dumps(metrics, indent=1) + "\n")
        size = sum(p.stat().st_size for p in tmp.iterdir())
        if (src / "result.json").exists():
            result = json.loads((src / "result.json").read_text())
        else:  # an intermediate checkpoint of a run still training: its last curve row
            last = M.read_curve(src)[-1]
            result = {"step": last["step"], "seconds": last["seconds"], "stopped_by": "an intermediate checkpoint",
                      "examples_per_s": round(last["step"] * 8 / last["seconds"], 1)}
        cfg = json.loads((src / "dynamics_model.json").read_text())
        card = Path(__file__).with_name(args.card).read_text().format(
            params=args.params, seed=cfg.get("seed"), steps=result.get("step"), max_steps=cfg.get("max_steps"),
            hours=round(result.get("seconds", 0) / 3600, 2), ex_s=result.get("examples_per_s"),
            n_params=M.n_parameters(model), size_mb=round(size / 2**20, 1), input=cfg.get("input"),
            reasoning=cfg.get("reasoning"), stopped_by=result.get("stopped_by"),
            metrics=json.dumps(metrics, indent=1), n_train=params["sample"]["n_train"])
        (tmp / "README.md").write_text(card)
        tmp.chmod(0o755)  # the checkpoint is for everyone
        for f in tmp.iterdir():
            f.chmod(0o644)
    print(f"exported {dst} ({size / 2**20:.1f} MB): {json.dumps(metrics)}")


if __name__ == "__main__":
    main()
