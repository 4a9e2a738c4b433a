"""Benchmark: bad videos and trajectories in, one line out (issue 12, docs/reliability.md).

Trajectories: for ``--seeds`` seeds x 7 hidden effects (none and the six of the library), a
4-clip data set from :func:`pipeline.discrepancy.generate_hidden` (1 mm noise) is read as it
is (must be accepted: false alarms) and in 8 wrong-unit variants (must be refused in one line):
positions in mm, cm, mm with x, y (and z) taken from each track's start; times in ms, us, ns;
a 60 s pause in the middle of every track. Also reports the largest typical acceleration
(:func:`pipeline.discrepancy.readers.typical_acceleration`) among the accepted tracks.

Videos: every file of ``../shared/repro/video`` and a synthetic MJPG avi, cut at 10 %, 20 %,
..., 90 % of their bytes, and with 10 % of the bytes overwritten by noise at the same places,
read with :func:`pipeline.video.read_video`: each must give frames (with a ``VideoWarning``
when frames were lost) or a one-line ``VideoError``, never another exception.

Usage::

    MUJOCO_GL=egl .venv/bin/python benchmarks/input_faults.py --seeds 150

Prints the counts (cases tried, refused, accepted, tracebacks).
"""

from __future__ import annotations

import argparse
import collections
import tempfile
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
EFFECTS = ("none", "quadratic_drag", "wind", "restitution", "floor_tilt", "magnus_lift", "torsional_friction")
VARIANTS = ("mm", "cm", "mm_centred_xy", "mm_centred_xyz", "ms", "us", "ns", "gap_60s")


def wrong_units(cols: dict, kind: str) -> dict:
    """A copy of trajectory columns with one unit mistake (see module docstring)."""
    c = {k: list(v) for k, v in cols.items()}
    if kind in ("mm", "cm", "mm_centred_xy", "mm_centred_xyz"):
        f = 100.0 if kind == "cm" else 1000.0
        for a in "xyz":
            c[a] = [f * v for v in c[a]]
        if kind.startswith("mm_centred"):
            start: dict = {}
            for i, key in enumerate(zip(c["clip"], c["object"])):
                s = start.setdefault(key, (c["x"][i], c["y"][i], c["z"][i]))
                c["x"][i] -= s[0]
                c["y"][i] -= s[1]
                if kind == "mm_centred_xyz":
                    c["z"][i] -= s[2] - 20.0
    elif kind in ("ms", "us", "ns"):
        f = {"ms": 1e3, "us": 1e6, "ns": 1e-6}[kind]
        c["t"] = [f * v for v in c["t"]]
    elif kind == "gap_60s":
        t = np.asarray(c["t"])
        c["t"] = list(np.where(t > np.median(t), t + 60.0, t))
    return c


def trajectories(seeds: int) -> None:
    from pipeline import discrepancy as D
    from pipeline.discrepancy.readers import typical_acceleration
    from pipeline.mjcf import SimOptions

    opts = SimOptions(textured=False)
    cfg = D.HiddenConfig(n_clips=4, kinds=("throw", "spin_slide", "roll", "throw"), noise_position=0.001)
    false_alarms, worst, n = [], 0.0, 0
    caught, other = collections.Counter(), collections.Counter()
    for seed in range(seeds):
        for effect in EFFECTS:
            cols, _ = D.generate_hidden(1000 + seed, cfg, opts, effect=effect)
            n += 1
            try:
                for clip in D.clips_from_columns(cols, "hidden"):
                    for tr in clip.tracks:
                        worst = max(worst, float(np.linalg.norm(typical_acceleration(tr.t, tr.pos))))
            except D.DiscrepancyInputError as exc:
                false_alarms.append(f"seed {seed} {effect}: {exc}")
            for kind in VARIANTS:
                try:
                    D.clips_from_columns(wrong_units(cols, kind), "bad")
                except D.DiscrepancyInputError as exc:
                    caught[kind] += "\n" not in str(exc)
                except Exception as exc:  # noqa: BLE001 - counted, that is the point
                    other[f"{kind}: {type(exc).__name__}"] += 1
    print(f"trajectories: {n} data sets ({4 * n} clips) accepted {n - len(false_alarms)}, false alarms "
          f"{len(false_alarms)}; largest typical acceleration {worst:.2f} m/s^2 ({worst / 9.81:.2f} g)")
    for kind in VARIANTS:
        print(f"  {kind:15s} refused in one line {caught[kind]}/{n}")
    print(f"  tracebacks {sum(other.values())} {dict(other)}")
    for line in false_alarms[:5]:
        print("  false alarm:", line)


def videos() -> None:
    from pipeline.video import VideoError, VideoWarning, read_video
    from tests.conftest import moving_disc_avi

    rng = np.random.default_rng(0)
    results = collections.Counter()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        sources = sorted((ROOT.parent / "shared" / "repro" / "video").glob("*")) + [moving_disc_avi(tmp / "disc.avi")]
        for src in sources:
            data = src.read_bytes()
            if not data:
                continue
            for k in range(1, 10):
                cut = int(len(data) * k / 10)
                noisy = bytearray(data)
                noisy[cut:cut + len(data) // 10] = rng.integers(0, 256, len(noisy[cut:cut + len(data) // 10]),
                                                                dtype=np.uint8).tobytes()
                for name, payload in (("cut", data[:cut]), ("noise", bytes(noisy))):
                    path = tmp / f"{name}{src.suffix}"
                    path.write_bytes(payload)
                    with warnings.catch_warnings(record=True) as rec:
                        warnings.simplefilter("always")
                        try:
                            clip = read_video(path)
                            warned = any(issubclass(w.category, VideoWarning) for w in rec)
                            results[f"{name}: frames read" + (", warned" if warned else "")] += 1
                            del clip
                        except VideoError as exc:
                            results[f"{name}: one-line error"] += "\n" not in str(exc)
                        except Exception as exc:  # noqa: BLE001 - counted, that is the point
                            results[f"{name}: traceback {type(exc).__name__}"] += 1
    print(f"videos: {sum(results.values())} damaged files from {len(sources)} sources")
    for key, count in sorted(results.items()):
        print(f"  {key}: {count}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=150, help="seeds per effect for the trajectory sweep")
    args = parser.parse_args()
    videos()
    trajectories(args.seeds)


if __name__ == "__main__":
    main()
