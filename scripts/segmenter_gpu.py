"""Train the object segmenter on one GPU machine within a wall-clock budget (issue 36).

On the CPU the segmenter (``pipeline/segmenter.py``) saw ~220,000 crops in two hours. On a lent
machine (16 cores, one GPU, ~9 minutes a call) the same code sees several times that:

1. **data**: ``--gen-procs`` processes render fresh randomised MuJoCo truth-set clips
   (``python -m pipeline.truthsets generate --engine mujoco``, one split seed per process, seeds
   ``--first-seed`` upward; the benchmark's splits are seeds 0 and 1) for ``--gen-s`` seconds, then
   stop (a clip folder appears whole or not at all, so a stopped generator leaves no half clip);
2. **training**: every ``--run`` trains its own network from scratch on those clips at the same time,
   sharing the GPU and splitting the cores for batch making
   (``python -m pipeline.segmenter train --device cuda --workers N --time-schedule``): the cosine
   schedule ends at the deadline whatever the machine's speed.

Each run writes ``<name>.pt`` (the checkpoint, saved every 500 steps too, so a run stopped at the
limit still returns weights), ``<name>.json`` (its card) and ``<name>.log`` under ``--out``; the
script's own log and numbers go to ``segmenter_gpu.log`` and ``numbers.json``: with two runs, the
eight files a lent machine sends back (write nothing else under ``$OUT``), so at most two runs.

    python scripts/segmenter_gpu.py --out OUT --budget-s 540 \\
        --run wide:24,48,64,96:0.5 --run mid:16,32,48,64:0.5

A run is ``NAME:CHANNELS:REALISM_FRACTION`` (channels finest first; the fraction of batches with
:mod:`pipeline.frame_realism` scenery and camera noise, 0 for renders only).

Needs: the project's Python dependencies, ``MUJOCO_GL=egl`` with a working EGL, torch with CUDA
(``--device cpu`` tries the script out at toy size).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:   # run as a script from any folder, with or without the package installed
    sys.path.insert(0, str(ROOT))
from pipeline.segmenter import clip_folders  # noqa: E402
RUN_RE = re.compile(r"([A-Za-z0-9_-]+):(\d+(?:,\d+)+):([0-9.]+)")


class Log:
    """Lines with the elapsed time, to stdout and ``OUT/segmenter_gpu.log``."""

    def __init__(self, out: Path, budget_s: float) -> None:
        self.t0 = time.monotonic()
        self.budget_s = budget_s
        self.fh = open(out / "segmenter_gpu.log", "a")

    @property
    def left(self) -> float:
        return self.budget_s - (time.monotonic() - self.t0)

    def __call__(self, msg: str) -> None:
        line = f"[{time.monotonic() - self.t0:6.1f} s] {msg}"
        print(line, flush=True)
        self.fh.write(line + "\n")
        self.fh.flush()


def parse_run(text: str) -> tuple[str, list[int], float]:
    """``NAME:C1,C2,...:FRACTION`` -> ``(name, channels, realism fraction)``.

    Raises:
        argparse.ArgumentTypeError: malformed.
    """
    m = RUN_RE.fullmatch(text)
    if not m or not 0.0 <= float(m.group(3)) <= 1.0:
        raise argparse.ArgumentTypeError(f"--run: expected NAME:C1,C2,...:FRACTION (fraction in [0, 1]), got {text!r}")
    return m.group(1), [int(c) for c in m.group(2).split(",")], float(m.group(3))


def count_clips(folder: Path) -> int:
    """Complete clip folders in the set folders under ``folder`` (:func:`pipeline.segmenter.clip_folders`)."""
    return len(clip_folders([d for d in folder.iterdir() if d.is_dir()]))


def generate(log: Log, work: Path, procs: int, seconds: float, first_seed: int, env: dict) -> list[Path]:
    """Render clips in ``procs`` processes (one split seed each) for ``seconds``; the set folders."""
    sets = [work / f"seed-{first_seed + k}" for k in range(procs)]
    logs = [open(work / f"gen-{first_seed + k}.log", "w") for k in range(procs)]
    ps = [subprocess.Popen([sys.executable, "-m", "pipeline.truthsets", "generate", "--engine", "mujoco",
                            "--n", "100000", "--seed", str(first_seed + k), "--out", str(s)],
                           cwd=ROOT, env=env, stdout=fh, stderr=subprocess.STDOUT, start_new_session=True)
          for k, (s, fh) in enumerate(zip(sets, logs))]
    t = time.monotonic()
    while time.monotonic() - t < seconds and any(p.poll() is None for p in ps):
        time.sleep(min(10.0, max(0.1, seconds - (time.monotonic() - t))))
        log(f"data: {count_clips(work)} clips")
    for p in ps:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGTERM)
    for p in ps:
        p.wait()
    for fh in logs:
        fh.close()
    failed = [p.returncode for p in ps if p.returncode not in (0, -signal.SIGTERM)]
    if failed:
        tail = (work / f"gen-{first_seed}.log").read_text()[-600:]
        log(f"data: {len(failed)} generator(s) failed (rc {failed}); first log ends: {tail!r}")
    return [s for s in sets if s.is_dir()]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python scripts/segmenter_gpu.py", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True, help="folder for the weights, cards and logs")
    ap.add_argument("--work", type=Path, default=ROOT / "data" / "segmenter_gpu", help="folder for the clips")
    ap.add_argument("--budget-s", type=float, default=540.0, help="wall-clock budget of the whole run, s")
    ap.add_argument("--gen-s", type=float, default=150.0, help="seconds of clip rendering")
    ap.add_argument("--gen-procs", type=int, default=max(1, (os.cpu_count() or 2) - 2))
    ap.add_argument("--first-seed", type=int, default=100, help="split seed of the first generator (0, 1: benchmark)")
    ap.add_argument("--run", type=parse_run, action="append", required=True,
                    help="NAME:C1,C2,...:REALISM_FRACTION, one per network (repeat)")
    ap.add_argument("--device", default="cuda", help="cuda, or cpu to try the script out")
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--lr", type=float, default=3e-3)
    ap.add_argument("--per-clip", type=int, default=16, help="frames taken per clip")
    ap.add_argument("--reserve-s", type=float, default=75.0,
                    help="time kept for reading the clips and saving, beside the training time")
    args = ap.parse_args(argv)
    if len(args.run) > 2:
        ap.error(f"--run: at most 2 (3 files each + 2: the 8 files a lent machine sends back), got {len(args.run)}")
    args.out.mkdir(parents=True, exist_ok=True)
    args.work.mkdir(parents=True, exist_ok=True)
    log = Log(args.out, args.budget_s)
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "PYTHONUNBUFFERED": "1"}
    log(f"torch {torch.__version__}, cuda {torch.cuda.is_available()}"
        f"{' ' + torch.cuda.get_device_name(0) if torch.cuda.is_available() else ''}, {os.cpu_count()} cores")
    numbers: dict = {"budget_s": args.budget_s, "runs": {}}
    sets = generate(log, args.work, args.gen_procs, args.gen_s, args.first_seed, env)
    numbers["clips"] = count_clips(args.work)
    numbers["data_s"] = round(args.budget_s - log.left, 1)
    log(f"data: {numbers['clips']} clips in {numbers['data_s']} s from {len(sets)} splits")
    if numbers["clips"] == 0:
        log("no clip was made: nothing to train on")
        return 1
    minutes = max(0.2, (log.left - args.reserve_s) / 60)
    workers = max(1, ((os.cpu_count() or 2) - len(args.run)) // len(args.run))
    numbers.update(train_minutes=round(minutes, 2), workers_per_run=workers)
    ps = {}
    for k, (name, channels, fraction) in enumerate(args.run):
        cmd = [sys.executable, "-m", "pipeline.segmenter", "train", "--data", *map(str, sets),
               "--out", str(args.out / f"{name}.pt"), "--steps", "1000000", "--batch", str(args.batch),
               "--lr", str(args.lr), "--max-minutes", f"{minutes:.3f}", "--time-schedule", "--seed", str(k),
               "--per-clip", str(args.per_clip), "--channels", *map(str, channels), "--device", args.device,
               "--workers", str(workers), "--mp-context", "fork"]   # a fresh process: copy-on-write frames
        if fraction > 0:
            cmd += ["--realism", "--realism-fraction", str(fraction)]
        ps[name] = (subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=open(args.out / f"{name}.log", "w"),
                                     stderr=subprocess.STDOUT), cmd)
        log(f"train {name}: channels {channels}, realism {fraction}, {minutes:.2f} min, {workers} workers")
    for name, (p, cmd) in ps.items():
        rc = p.wait()
        card = args.out / f"{name}.json"
        numbers["runs"][name] = {"rc": rc, "command": " ".join(cmd[1:]),
                                 "card": json.loads(card.read_text()) if card.is_file() else None}
        tail = (args.out / f"{name}.log").read_text().strip().splitlines()[-2:]
        log(f"train {name}: rc {rc} | {' / '.join(tail)}")
    (args.out / "numbers.json").write_text(json.dumps(numbers, indent=1))
    return 0 if all(r["rc"] == 0 for r in numbers["runs"].values()) else 1


if __name__ == "__main__":
    sys.exit(main())
