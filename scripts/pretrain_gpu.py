"""Pretrain the shipped checkpoint on one GPU machine within a wall-clock budget (issue 30).

The same stages as ``scripts/pretrain.sh`` (``profiles/pretrain.yaml``: sample_configs ->
compile_mjcf -> render -> flow -> events -> tokenize_targets -> finetune), run on a machine with
many cores and one GPU, where the run must end by a deadline (a lent machine: ~9 minutes a call).
Because the data rate and the training speed of that machine are unknown beforehand, the run
measures both and sizes itself:

1. **calibration**: the data stages on ``--calib-scenes`` scenes, then ``--calib-steps``
   optimiser steps on them: scenes per second and steps per second on this machine;
2. **data**: ``n_train`` = what the data stages make in ``--data-share`` of the time left;
3. **training** from scratch with ``max_steps`` = what fits in the rest (the cosine schedule ends
   at the last step; ``max_minutes`` is only the safety cap).

Everything else is the profile's (seed, ranges, looks, model). The profile actually run is
written next to the model (``profile.yaml``), so the same run can be repeated on the CPU with
``DYNAMICS_PARAMS=<that file> bash scripts/pretrain.sh`` (hours). The model folder comes back as
``model.tar.partNN`` pieces of at most 15 MB (the lent machine returns files of <= 16 MB), with
the optimiser state, so training can be resumed elsewhere (``stages/finetune.py --resume``).

    python scripts/pretrain_gpu.py --budget-s 520 --out OUT   # on the GPU machine (see README)

Needs: the project's Python dependencies, ``MUJOCO_GL=egl`` with a working EGL, torch with CUDA.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import subprocess
import sys
import tarfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
DATA_STAGES = ("sample_configs", "compile_mjcf", "render", "flow", "events", "tokenize_targets")
PART_BYTES = 15 * 2**20


class Run:
    """Log lines with the elapsed time, to stdout and ``OUT/pretrain_gpu.log``."""

    def __init__(self, out: Path, budget_s: float):
        self.t0 = time.monotonic()
        self.budget_s = budget_s
        self.out = out
        self.log_file = open(out / "pretrain_gpu.log", "a")

    @property
    def elapsed(self) -> float:
        return time.monotonic() - self.t0

    @property
    def left(self) -> float:
        return self.budget_s - self.elapsed

    def log(self, msg: str) -> None:
        line = f"[{self.elapsed:6.1f} s] {msg}"
        print(line, flush=True)
        self.log_file.write(line + "\n")
        self.log_file.flush()


def write_profile(base: dict, folder: Path, sample: dict, model: dict, workers: int) -> Path:
    """The base profile with paths under ``folder`` and the given overrides; returns its path."""
    p = json.loads(json.dumps(base))
    for key, value in p["paths"].items():
        p["paths"][key] = str(folder / Path(value).name)
    p["sample"].update(sample)
    p["model"].update(model)
    p["compute"] = {"workers": workers}
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "profile.yaml"
    path.write_text(yaml.safe_dump(p, sort_keys=False))
    return path


def stage(run: Run, name: str, profile: Path, *args: str) -> float:
    """Run one stage script with ``DYNAMICS_PARAMS=profile``; its output goes to the log folder.

    Raises:
        RuntimeError: the stage failed (the last lines of its output in the message).
    """
    t = time.monotonic()
    log = profile.parent / f"{name}.log"
    env = {**os.environ, "DYNAMICS_PARAMS": str(profile)}
    with open(log, "w") as fh:
        rc = subprocess.call([sys.executable, str(ROOT / "stages" / f"{name}.py"), *args], cwd=ROOT, env=env,
                             stdout=fh, stderr=subprocess.STDOUT)
    dt = time.monotonic() - t
    tail = log.read_text().strip().splitlines()[-3:]
    run.log(f"{name}: {dt:.1f} s{'' if rc == 0 else f' FAILED rc={rc}'} | {' / '.join(x[-160:] for x in tail)}")
    if rc != 0:
        raise RuntimeError(f"stage {name} failed: {' / '.join(tail)}")
    return dt


def data(run: Run, profile: Path) -> float:
    return sum(stage(run, s, profile) for s in DATA_STAGES)


def csv_rows(path: Path) -> list[dict]:
    with open(path) as fh:
        return list(csv.DictReader(fh))


def pack(model_dir: Path, out: Path) -> list[Path]:
    """``model_dir`` as an uncompressed tar split into ``PART_BYTES`` pieces under ``out``."""
    tar = out / "model.tar"
    with tarfile.open(tar, "w") as tf:
        tf.add(model_dir, arcname="model")
    parts = []
    with open(tar, "rb") as fh:
        while chunk := fh.read(PART_BYTES):
            parts.append(out / f"model.tar.part{len(parts):02d}")
            parts[-1].write_bytes(chunk)
    tar.unlink()
    return parts


def train_and_pack(run: Run, prof: Path, final: Path, out: Path, numbers: dict, max_steps: int) -> int:
    """The finetune stage with ``prof``, then its result, curve and profile into ``out`` and the
    model folder in pieces (:func:`pack`)."""
    stage(run, "finetune", prof, "--no-progress")
    result = json.loads((final / "model" / "result.json").read_text())
    numbers.update(max_steps=max_steps, result=result)
    shutil.copy2(prof, final / "model" / "profile.yaml")
    for name in ("train_curve.csv", "result.json"):
        shutil.copy2(final / "model" / name, out / name)
    parts = pack(final / "model", out)
    numbers["parts"] = [p.name for p in parts]
    run.log(f"done: {result}; model in {len(parts)} pieces")
    return 0


def fixed_run(run: Run, args: argparse.Namespace, base: dict, work: Path, out: Path, train_model: dict,
              numbers: dict) -> int:
    """No calibration: ``--n-train`` scenes, then ``--max-steps`` steps capped by the time left."""
    final = work / "run"
    shutil.rmtree(final, ignore_errors=True)
    sample = {"n_train": args.n_train, "n_val": 100, "n_test": 0, "n_test_comp": 0,
              "shard_size": max(20, (args.n_train + 100) // (2 * args.workers))}
    prof = write_profile(base, final, sample, {}, args.workers)
    numbers.update(n_train=args.n_train, data_s=round(data(run, prof), 1))
    left = run.left - args.reserve_s - 25.0
    model = {**train_model, "max_steps": args.max_steps, "eval_interval": max(25, args.max_steps // 4),
             "warmup_steps": min(50, args.max_steps // 10), "max_minutes": round(max(0.5, left) / 60, 2)}
    prof = write_profile(base, final, sample, model, args.workers)
    run.log(f"train: max_steps {args.max_steps}, cap {model['max_minutes']} min")
    return train_and_pack(run, prof, final, out, numbers, args.max_steps)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="folder for the log, the run's numbers and the model pieces")
    ap.add_argument("--budget-s", type=float, default=520.0, help="wall-clock budget of the whole run, s")
    ap.add_argument("--profile", default=str(ROOT / "profiles" / "pretrain.yaml"))
    ap.add_argument("--work", default=str(ROOT / "data" / "pretrain_gpu"), help="data and model folder")
    ap.add_argument("--workers", type=int, default=max(1, (os.cpu_count() or 2) - 1))
    ap.add_argument("--device", default="cuda", help="cuda, or cpu to try the script out")
    ap.add_argument("--batch-size", type=int, default=128)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--calib-scenes", type=int, default=600)
    ap.add_argument("--calib-steps", type=int, default=60)
    ap.add_argument("--data-share", type=float, default=0.5, help="share of the time left after calibration for data")
    ap.add_argument("--max-train", type=int, default=40000, help="cap on n_train")
    ap.add_argument("--reserve-s", type=float, default=25.0, help="time kept for packing the model")
    ap.add_argument("--init", default="scratch", help="model.init: scratch, shipped or a folder (a different codec is "
                                                      "taken over: model.init_new_codec)")
    ap.add_argument("--n-train", type=int, default=None, help="skip the calibration: this many training scenes ...")
    ap.add_argument("--max-steps", type=int, default=None, help="... and this many steps (max_minutes = what is left)")
    args = ap.parse_args(argv)

    out, work = Path(args.out), Path(args.work)
    out.mkdir(parents=True, exist_ok=True)
    run = Run(out, args.budget_s)
    base = yaml.safe_load(Path(args.profile).read_text())
    shard = 200
    train_model = {"device": args.device, "batch_size": args.batch_size, "lr": args.lr, "threads": min(16, args.workers + 1),
                   "eval_samples": 0, "constrained": False, "init": args.init, "init_new_codec": args.init != "scratch"}
    numbers: dict = {"budget_s": args.budget_s, "workers": args.workers, "batch_size": args.batch_size}
    try:
        import torch
        run.log(f"torch {torch.__version__}, cuda {torch.cuda.is_available()} "
                f"{torch.cuda.get_device_name(0) if torch.cuda.is_available() else ''}, {os.cpu_count()} cores")
        if args.n_train is not None:
            return fixed_run(run, args, base, work, out, train_model, numbers)
        # 1. calibration: data rate, then training speed
        calib = work / "calib"
        n_cal = args.calib_scenes
        prof = write_profile(base, calib, {"n_train": n_cal, "n_val": 40, "n_test": 0, "n_test_comp": 0,
                                           "shard_size": max(20, n_cal // (2 * args.workers))},
                             {**train_model, "max_steps": args.calib_steps, "eval_interval": args.calib_steps // 2,
                              "warmup_steps": 5, "max_minutes": 3.0}, args.workers)
        t_data = data(run, prof)
        rate = (n_cal + 40) / t_data
        t = time.monotonic()
        stage(run, "finetune", prof, "--no-progress")
        t_ft = time.monotonic() - t
        curve = csv_rows(calib / "model" / "train_curve.csv")
        steps_s = float(curve[-1]["examples_per_s"]) / args.batch_size   # second half: warm kernels
        overhead = max(5.0, t_ft - args.calib_steps / steps_s)
        numbers.update(calib_scenes_per_s=round(rate, 2), calib_steps_per_s=round(steps_s, 2),
                       calib_finetune_overhead_s=round(overhead, 1))
        run.log(f"calibration: {rate:.1f} scenes/s (data stages), {steps_s:.2f} steps/s at batch {args.batch_size}, "
                f"finetune start-up {overhead:.0f} s")
        shutil.rmtree(calib, ignore_errors=True)

        # 2. data sized to the time left
        left = run.left - args.reserve_s
        n_train = int(min(args.max_train, max(1000, args.data_share * left * rate - 200)))
        n_train -= n_train % shard
        final = work / "run"
        shutil.rmtree(final, ignore_errors=True)
        prof = write_profile(base, final, {"n_train": n_train, "n_val": 200, "n_test": 0, "n_test_comp": 0,
                                           "shard_size": shard}, {}, args.workers)
        run.log(f"data: n_train {n_train} (+200 val) in ~{(n_train + 200) / rate:.0f} s")
        t_data = data(run, prof)
        numbers.update(n_train=n_train, data_s=round(t_data, 1), data_scenes_per_s=round((n_train + 200) / t_data, 2))

        # 3. training sized to the rest
        load_s = overhead + 0.002 * (n_train + 200)   # reading the inputs: ~12 ms a scene per worker
        train_s = run.left - args.reserve_s - load_s
        max_steps = int(max(100, train_s * steps_s * 0.92))
        model = {**train_model, "max_steps": max_steps, "eval_interval": max(50, max_steps // 10),
                 "max_minutes": round(max(1.0, train_s + 20) / 60, 2)}
        prof = write_profile(base, final, {"n_train": n_train, "n_val": 200, "n_test": 0, "n_test_comp": 0,
                                           "shard_size": shard}, model, args.workers)
        run.log(f"train: max_steps {max_steps} (~{train_s:.0f} s at {steps_s:.2f} steps/s; start-up ~{load_s:.0f} s)")
        return train_and_pack(run, prof, final, out, numbers, max_steps)
    except Exception as exc:  # the log must come back whatever happened
        run.log(f"ERROR {type(exc).__name__}: {exc}")
        for log in sorted(work.glob("*/*.log"))[-5:]:   # at most 8 files come back
            shutil.copy2(log, out / f"{log.parent.name}-{log.name}")
        return 1
    finally:
        numbers["elapsed_s"] = round(run.elapsed, 1)
        (out / "numbers.json").write_text(json.dumps(numbers, indent=1))


if __name__ == "__main__":
    sys.exit(main())
