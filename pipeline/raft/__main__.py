"""``python -m pipeline.raft train ...``: train the RAFT weights shipped with the project
(see :mod:`pipeline.raft.train`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from pipeline.raft.estimator import DEFAULT_WEIGHTS
from pipeline.raft.pairs import texture_bank
from pipeline.raft.train import export_data, train


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m pipeline.raft", description=__doc__)
    sub = ap.add_subparsers(dest="cmd", required=True)
    t = sub.add_parser("train", help="train on the render stage's ground-truth flow + procedural chairs pairs")
    t.add_argument("--video", type=Path, default=Path("data/video"), help="render stage shards (paths.video)")
    t.add_argument("--configs", type=Path, default=Path("data/configs"), help="sample_configs shards (splits)")
    t.add_argument("--out", type=Path, default=DEFAULT_WEIGHTS, help="weights file to write (default: %(default)s)")
    t.add_argument("--steps", type=int, default=4000)
    t.add_argument("--batch", type=int, default=6)
    t.add_argument("--iters", type=int, default=8, help="GRU updates per pair while training")
    t.add_argument("--lr", type=float, default=4e-4, help="peak learning rate of the one-cycle schedule")
    t.add_argument("--chairs-fraction", type=float, default=0.5, help="share of procedural pairs per batch")
    t.add_argument("--still-fraction", type=float, default=0.0,
                   help="share of still-camera pairs (small objects over a still background) per batch")
    t.add_argument("--max-minutes", type=float, default=60.0, help="stop (and save) after this much training time")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--resume", action="store_true", help="continue from OUT.ckpt")
    t.add_argument("--init", type=Path, default=None, help="start from these weights (.pth, or a run's .ckpt); new schedule")
    t.add_argument("--crop", type=int, nargs=2, default=None, metavar=("H", "W"),
                   help="train on H x W windows of the working-size pairs (multiples of 8; default whole frames)")
    t.add_argument("--data", type=Path, default=None,
                   help="an `export` .npz used instead of --video/--configs (for machines without the shards)")
    t.add_argument("--textures", type=Path, default=None,
                   help="a `textures` .npz: half the chairs layers are cut from these real frames")
    t.add_argument("--device", default="cpu", help="torch device of the network, e.g. cuda (default: %(default)s)")
    t.add_argument("--workers", type=int, default=0,
                   help="DataLoader processes making batches (0: in this process, resumable exactly)")
    t.add_argument("--eval-every", type=int, default=500, help="validate every this many steps")
    t.add_argument("--checkpoint-every", type=int, default=100, help="write OUT.ckpt and OUT every this many steps")
    e = sub.add_parser("export", help="pack the train/val clips of the render shards into one .npz for --data")
    e.add_argument("--video", type=Path, default=Path("data/video"))
    e.add_argument("--configs", type=Path, default=Path("data/configs"))
    e.add_argument("--out", type=Path, required=True)
    x = sub.add_parser("textures", help="frames of real videos as a texture bank for chairs pairs (.npz, array 'bank')")
    x.add_argument("videos", type=Path, nargs="+")
    x.add_argument("--out", type=Path, required=True)
    x.add_argument("--per-video", type=int, default=24, help="frames per video, evenly spaced (default: %(default)s)")
    args = ap.parse_args(argv)
    if args.cmd == "export":
        print(f"wrote {export_data(args.video, args.configs, args.out)}")
        return 0
    if args.cmd == "textures":
        bank = texture_bank(args.videos, per_video=args.per_video)
        tmp = args.out.with_name(args.out.name + ".tmp.npz")
        np.savez_compressed(tmp, bank=bank, sources=np.array([p.name for p in args.videos]))
        tmp.replace(args.out)
        print(f"wrote {args.out}: {len(bank)} frames of {len(args.videos)} videos")
        return 0
    train(args.video, args.configs, args.out, steps=args.steps, batch=args.batch, iters=args.iters, lr=args.lr,
          chairs_fraction=args.chairs_fraction, max_minutes=args.max_minutes, seed=args.seed, resume=args.resume,
          crop=tuple(args.crop) if args.crop else None, init=args.init, data=args.data, textures=args.textures,
          device=args.device, workers=args.workers, eval_every=args.eval_every,
          checkpoint_every=args.checkpoint_every, still_fraction=args.still_fraction)
    return 0


if __name__ == "__main__":
    sys.exit(main())
