"""Generate a truth set: rendered clips of rigid objects with their true instance masks.

    python -m pipeline.truthsets generate --engine mujoco --n 24 --seed 0 --out /work/truthsets/mujoco/dev

Each clip is a folder ``DIR/clip-00000`` holding ``video.mp4`` (what ``dynamics infer`` reads),
``truth.npz`` (true masks, states, labels, camera) and ``meta.json`` (see
:mod:`pipeline.truthsets.common`); ``DIR/index.json`` lists the clips with their categories.

Seed convention: ``--seed 0`` is the development split (look at it, tune on it); ``--seed 1``
is the held-out split (report it apart, never tune on it). Other seeds are further splits.
Clip ``i`` of a split depends only on (engine, seed, i, width, height, fps, duration): the
same command gives the same masks, a larger ``--n`` extends a set, and a killed run resumes
where it stopped (complete clip folders are kept; a clip folder appears whole or not at all).

Engines: ``mujoco`` (the project's own MJCF builder, simulator and renderer) and ``pybullet``
(PyBullet 3.2.7: its own physics and TinyRenderer, sharing no physics code with the MuJoCo
path: the independent engine). Categories (one per clip, every six consecutive clips hold all):
moving, stopping, at_rest, entering_leaving, touching, occluding.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from pathlib import Path

from tqdm import tqdm

from pipeline.atomic import remove_stale_temps, write_json
from pipeline.truthsets.common import (CLIP_DIR, GENERATOR_VERSION, TruthsetError, clip_complete, generate_clip,
                                       write_clip)

ENGINES = {"mujoco": "pipeline.truthsets.mujoco_scenes", "pybullet": "pipeline.truthsets.pybullet_scenes"}


def engine_module(name: str):
    """The engine module of ``name`` (imported lazily: pybullet is only needed for its clips)."""
    return importlib.import_module(ENGINES[name])


def generate_set(engine: str, n: int, seed: int, out: str | Path, width: int = 320, height: int = 240,
                 fps: int = 30, duration: float = 2.0, progress: bool = True) -> list[Path]:
    """Generate clips ``0..n-1`` of split ``seed`` into ``out`` (complete clips are skipped).

    Returns:
        the clip folders.
    Raises:
        TruthsetError: a clip folder there was made with other parameters.
    """
    out = Path(out)
    params = {"width": width, "height": height, "fps": fps, "duration": duration, "generator": GENERATOR_VERSION}
    module = engine_module(engine)
    folders, index = [], []
    for i in tqdm(range(n), desc=f"{engine} seed {seed}", unit="clip", disable=not progress):
        folder = out / CLIP_DIR.format(i)
        remove_stale_temps(folder)
        if clip_complete(folder):
            meta = json.loads((folder / "meta.json").read_text())
            made = {k: meta.get(k) for k in ("engine", "seed", "index")}
            if made != {"engine": engine, "seed": seed, "index": i} or meta.get("params") != params:
                raise TruthsetError(f"{folder / 'meta.json'}: params: must match this run "
                                    f"({engine}, seed {seed}, {params}), got ({made}, {meta.get('params')}); "
                                    f"use another --out")
        else:
            clip = generate_clip(module, seed, i, width, height, fps, duration)
            write_clip(folder, clip)
            meta = clip.meta
        folders.append(folder)
        index.append({"clip": folder.name, "category": meta["category"], "tags": meta["tags"],
                      "objects": len(meta["objects"]), "motion": [o["motion"] for o in meta["objects"]]})
    write_json(out / "index.json", {"engine": engine, "seed": seed, "params": params, "clips": index})
    return folders


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pipeline.truthsets", description=__doc__.split("\n\n")[0],
                                     epilog="seed 0 = development split, seed 1 = held-out split",
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    gen = sub.add_parser("generate", help="generate (or resume) a truth set",
                         description="Generate clips 0..N-1 of a split into DIR/clip-00000, ... (complete clips "
                                     "are kept, so a killed run resumes). Seed 0 = development split, seed 1 = "
                                     "held-out split.")
    gen.add_argument("--engine", choices=sorted(ENGINES), required=True, help="simulator and renderer")
    gen.add_argument("--n", type=int, required=True, help="number of clips")
    gen.add_argument("--seed", type=int, required=True, help="split: 0 = development, 1 = held-out")
    gen.add_argument("--out", type=Path, required=True, help="set folder (clip-00000, ... inside)")
    gen.add_argument("--width", type=int, default=320, help="px (default %(default)s)")
    gen.add_argument("--height", type=int, default=240, help="px (default %(default)s)")
    gen.add_argument("--fps", type=int, default=30, help="frames per second (default %(default)s)")
    gen.add_argument("--duration", type=float, default=2.0, help="s (default %(default)s)")
    args = parser.parse_args(argv)
    for name in ("n", "width", "height", "fps"):
        if getattr(args, name) <= 0:
            parser.error(f"--{name}: must be > 0, got {getattr(args, name)}")
    if not 0 < args.duration <= 60:
        parser.error(f"--duration: must be in (0, 60] s, got {args.duration}")
    if args.fps * args.duration < 2:
        parser.error("--fps x --duration: must give at least 2 frames")
    try:
        folders = generate_set(args.engine, args.n, args.seed, args.out, args.width, args.height, args.fps,
                               args.duration)
    except TruthsetError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as exc:
        print(f"error: {exc.name} is not installed (pip install -e . installs it)", file=sys.stderr)
        return 2
    print(f"{len(folders)} clips in {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
