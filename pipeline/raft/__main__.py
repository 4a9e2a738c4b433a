"""``python -m pipeline.raft train ...``: train the RAFT weights shipped with the project
(see :mod:`pipeline.raft.train`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pipeline.raft.estimator import DEFAULT_WEIGHTS
from pipeline.raft.train import train


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
    t.add_argument("--max-minutes", type=float, default=60.0, help="stop (and save) after this much training time")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--resume", action="store_true", help="continue from OUT.ckpt")
    t.add_argument("--init", type=Path, default=None, help="start from these weights (.pth, or a run's .ckpt); new schedule")
    t.add_argument("--crop", type=int, nargs=2, default=None, metavar=("H", "W"),
                   help="train on H x W windows of the working-size pairs (multiples of 8; default whole frames)")
    args = ap.parse_args(argv)
    train(args.video, args.configs, args.out, steps=args.steps, batch=args.batch, iters=args.iters, lr=args.lr,
          chairs_fraction=args.chairs_fraction, max_minutes=args.max_minutes, seed=args.seed, resume=args.resume,
          crop=tuple(args.crop) if args.crop else None, init=args.init)
    return 0


if __name__ == "__main__":
    sys.exit(main())
