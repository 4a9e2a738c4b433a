"""Peak memory of `dynamics simulate` against the clip length (issue 35, item 3).

Runs ``python -m pipeline.cli simulate`` in a fresh child process per run on a one-sphere scene
(the round-3 reproducer ``scene_1000_frames_10GB.yaml``: a ball rolling on the floor, its camera)
at 300, 1,000 and 3,000 frames (1 s of simulated time at ``fps`` = frames, so the physics is the
same at every length) and measures the child's peak resident set size from ``os.wait4``
(``ru_maxrss``, KiB on Linux: the child alone, sampled by the kernel, no polling) and its wall
time. Targets (streamed rendering: memory must not grow with the number of frames): the peak at
the longest clip within 1.2x of the 300-frame peak, and at most 1.5 GB.

Writes ``reports/bench_sim_memory.json`` and ``reports/bench_sim_memory.md`` (a table and the
command that re-runs it)::

    MUJOCO_GL=egl nice python benchmarks/sim_memory.py                   # 160 x 120, the targets
    MUJOCO_GL=egl nice python benchmarks/sim_memory.py --info-size       # also 480 x 320, for information
    # the code before streaming, for comparison (a git worktree of that commit):
    git worktree add /tmp/membase <commit>
    MUJOCO_GL=egl nice python benchmarks/sim_memory.py --code /tmp/membase --name bench_sim_memory_before
"""

from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
for p in (ROOT, ROOT / "benchmarks"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

from provenance import tree_id  # noqa: E402
from pipeline.atomic import write_json, write_text  # noqa: E402

SCENE = """\
version: 1
duration: 1.0
fps: {fps}
gravity: 9.81
camera:
  height: 0.844
  pitch: 48.9
  fov: 37.1
objects:
  - shape: sphere
    size: {{radius: 0.159}}
    mass: 0.927
    position: [0.23, -1.229, 0.159]
    orientation: [0.089, 0.0, 0.0, 0.996]
    linear_velocity: [-1.17, -0.06, 0.0]
    angular_velocity: [0.0, 0.0, 2.79]
    material: {{sliding_friction: 0.482, rolling_friction: 0.0004, damping: 0.033}}
effects: []
"""
"""The round-3 reproducer (``shared/repro/round3/scene_1000_frames_10GB.yaml``) with ``fps`` free."""

RATIO_TARGET = 1.2
"""Peak RSS at the longest clip / peak RSS at the shortest: at most this."""
PEAK_TARGET_MB = 1500.0
"""Peak RSS at the longest clip, MB (10^6 bytes): at most this."""


def run_simulate(frames: int, width: int, height: int, work: Path, code: Path | None) -> dict:
    """One ``dynamics simulate`` of a ``frames``-frame clip in a fresh child process.

    Returns:
        ``{"frames", "width", "height", "peak_mb" (ru_maxrss of the child, MB), "seconds" (wall),
        "exit"}``.
    Raises:
        RuntimeError: the child exited with a non-zero status (its stderr's last line).
    """
    scene = work / f"scene_{frames}.yaml"
    scene.write_text(SCENE.format(fps=frames))
    out = work / f"out_{frames}_{width}x{height}"
    # -P: the working folder stays off sys.path, so PYTHONPATH (--code) decides which pipeline runs
    cmd = [sys.executable, "-P", "-m", "pipeline.cli", "simulate", str(scene), "--out", str(out),
           "--width", str(width), "--height", str(height)]
    env = dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    if code is not None:  # another checkout of the project comes first on the import path
        env["PYTHONPATH"] = str(code)
    t0 = time.perf_counter()
    with tempfile.TemporaryFile() as err:
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err, env=env, cwd=work)
        _, status, usage = os.wait4(proc.pid, 0)   # this child's own rusage
        proc.returncode = os.waitstatus_to_exitcode(status)
        seconds = time.perf_counter() - t0
        err.seek(0)
        stderr = err.read().decode(errors="replace").strip()
    if proc.returncode != 0:
        raise RuntimeError(f"dynamics simulate ({frames} frames) exited {proc.returncode}: "
                           f"{stderr.splitlines()[-1] if stderr else ''}")
    return {"frames": frames, "width": width, "height": height,
            "peak_mb": round(usage.ru_maxrss * 1024 / 1e6, 1), "seconds": round(seconds, 2), "exit": 0}


def pipeline_origin(code: Path | None) -> str:
    """The ``pipeline`` package the children import (checks that ``--code`` took effect)."""
    env = dict(os.environ)
    if code is not None:
        env["PYTHONPATH"] = str(code)
    return subprocess.run([sys.executable, "-P", "-c", "import pipeline, os; print(os.path.dirname(pipeline.__file__))"],
                          env=env, capture_output=True, text=True, check=True).stdout.strip()


def with_ratios(runs: list[dict]) -> list[dict]:
    """Add ``ratio`` (peak / the first run's peak at the same size) to each run."""
    base: dict[tuple[int, int], float] = {}
    for r in runs:
        base.setdefault((r["width"], r["height"]), r["peak_mb"])
        r["ratio"] = round(r["peak_mb"] / base[(r["width"], r["height"])], 2)
    return runs


def table(runs: list[dict]) -> str:
    """Markdown table of the runs."""
    lines = ["| size | frames | peak MB | seconds | ratio to first |", "|---|---:|---:|---:|---:|"]
    lines += [f"| {r['width']}x{r['height']} | {r['frames']} | {r['peak_mb']:.1f} | {r['seconds']:.1f} | "
              f"{r['ratio']:.2f} |" for r in runs]
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, nargs="+", default=[300, 1000, 3000],
                        help="clip lengths, frames (1 s at fps = frames; default 300 1000 3000)")
    parser.add_argument("--width", type=int, default=160, help="render width, px (default 160)")
    parser.add_argument("--height", type=int, default=120, help="render height, px (default 120)")
    parser.add_argument("--info-size", action="store_true",
                        help="also run 480 x 320 (the default render size), for information (no target)")
    parser.add_argument("--info-frames", type=int, nargs="+", default=None,
                        help="clip lengths at 480 x 320 (default: --frames)")
    parser.add_argument("--code", type=Path, default=None,
                        help="run the `pipeline` of another checkout (e.g. a git worktree of an older commit)")
    parser.add_argument("--name", default="bench_sim_memory", help="report name in reports/ (default %(default)s)")
    args = parser.parse_args()

    code_dir = args.code.resolve() if args.code is not None else ROOT
    origin = pipeline_origin(args.code)
    print(f"pipeline from {origin} ({tree_id(code_dir)})")
    jobs = [(f, args.width, args.height) for f in args.frames]
    if args.info_size:
        jobs += [(f, 480, 320) for f in (args.info_frames or args.frames)]
    runs = []
    with tempfile.TemporaryDirectory(prefix="sim_memory_") as tmp:
        for frames, w, h in jobs:
            r = run_simulate(frames, w, h, Path(tmp), args.code)
            print(f"{w}x{h} {frames:6d} frames: peak {r['peak_mb']:8.1f} MB, {r['seconds']:6.1f} s", flush=True)
            runs.append(r)
    runs = with_ratios(runs)
    target_runs = [r for r in runs if (r["width"], r["height"]) == (args.width, args.height)]
    longest, shortest = max(target_runs, key=lambda r: r["frames"]), min(target_runs, key=lambda r: r["frames"])
    ratio = round(longest["peak_mb"] / shortest["peak_mb"], 2)
    targets = {"ratio_longest_to_shortest": ratio, "ratio_target": RATIO_TARGET,
               "peak_longest_mb": longest["peak_mb"], "peak_target_mb": PEAK_TARGET_MB,
               "met": bool(ratio <= RATIO_TARGET and longest["peak_mb"] <= PEAK_TARGET_MB)}
    command = "MUJOCO_GL=egl nice python benchmarks/sim_memory.py " + shlex.join(sys.argv[1:])
    report = {"command": command.strip(), "pipeline": origin, "commit": tree_id(code_dir),
              "scene": "shared/repro/round3/scene_1000_frames_10GB.yaml with duration 1 s, fps = frames",
              "measure": "peak RSS of the child process (os.wait4 ru_maxrss), MB = 10^6 bytes; wall seconds",
              "cpu_count": os.cpu_count(), "load_after": list(os.getloadavg()), "runs": runs, "targets": targets}
    write_json(ROOT / "reports" / f"{args.name}.json", report)
    md = (f"# `dynamics simulate` peak memory against clip length\n\n"
          f"Code: `{report['commit']}` (`{origin}`). Scene: {report['scene']}. "
          f"Measure: {report['measure']}.\n\n{table(runs)}\n\n"
          f"Targets at {args.width}x{args.height}: peak at {longest['frames']} frames / peak at "
          f"{shortest['frames']} frames = {ratio} (target <= {RATIO_TARGET}); peak {longest['peak_mb']:.1f} MB "
          f"(target <= {PEAK_TARGET_MB:.0f} MB): {'met' if targets['met'] else 'NOT met'}.\n\n"
          f"Re-run: `{report['command']}`\n")
    write_text(ROOT / "reports" / f"{args.name}.md", md)
    print(table(runs))
    print(f"targets {'met' if targets['met'] else 'NOT met'}: ratio {ratio} (<= {RATIO_TARGET}), "
          f"peak {longest['peak_mb']} MB (<= {PEAK_TARGET_MB:.0f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
