"""Seconds of the main job's observation per 1-s clip (issue 36 target: <= 10 s at working size on 2 cores).

Times step 1 of ``dynamics infer`` (:func:`pipeline.reconstruct.observe_window`: window choice, the
detection pass, crop, masks at working size, tracks, flow) with the main job's settings
(params.yaml: ``realvideo``, ``flow``, the shipped segmenter), in this process, on

* the 19 real clips (``scripts/realvideo_all.py``'s list: the six shared clips and the thirteen of
  ``dev/``), each in its automatic window, and
* optionally ``--rendered N`` clips of each rendered truth set given with ``--sets``
  (``data/truthsets/<engine>/<split>``, ``python -m pipeline.truthsets generate``).

Each clip is observed ``--repeats`` times (the first run also loads the segmenter and warms the
caches: the minimum is reported, and the first). The split of the time by phase comes from
``cProfile`` (cumulative seconds of the phase's function, the last run): reading and resizing
frames (``pipeline.video.read_video``), choosing the window (``window_starts``), the masks
(``segment_objects``; the segmenter's network alone in ``Segmenter.__call__``) and the flow
(``pipeline.flow.estimate_flow``). The phases overlap: frames are read inside the window choice
and the masks, and the network is part of the masks. The machine may be shared: the load average before and after is
written beside the seconds, so compare runs taken on the same machine and day.

Writes ``REPORT.json`` and ``REPORT.md`` (default ``reports/observation_speed``)::

    MUJOCO_GL=egl nice python benchmarks/observation_speed.py
    MUJOCO_GL=egl nice python benchmarks/observation_speed.py --rendered 6 --sets mujoco/dev,pybullet/dev
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import io
import os
import pstats
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for p in (ROOT, ROOT / "benchmarks", ROOT / "scripts"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

from provenance import tree_id  # noqa: E402
from pipeline.atomic import write_json, write_text  # noqa: E402
from pipeline.params import load_params  # noqa: E402
from pipeline.reconstruct import job_settings, observe_window  # noqa: E402

TARGET_S = 10.0
"""Issue 36: at most this many seconds per 1-s clip at working size on 2 cores."""

PHASES = {
    "read frames": ("pipeline/video.py", "read_video"),
    "choose window": ("pipeline/observe.py", "window_starts"),
    "masks": ("pipeline/observe.py", "segment_objects"),
    "segmenter network": ("pipeline/segmenter.py", "__call__"),
    "flow": ("pipeline/flow.py", "estimate_flow"),
}
"""Phase name -> (file suffix, function name) whose cumulative time ``cProfile`` reports."""


def phase_seconds(prof: cProfile.Profile) -> dict[str, float]:
    """Cumulative seconds of each of :data:`PHASES` in a profile (0 where not called)."""
    stats = pstats.Stats(prof).stats   # {(file, line, name): (cc, nc, tottime, cumtime, callers)}
    out = {}
    for phase, (suffix, fn) in PHASES.items():
        # the outermost calls only: a recursive or nested call is inside its caller's cumtime
        out[phase] = round(sum(v[3] for (f, _, n), v in stats.items() if n == fn and f.endswith(suffix)), 3)
    return out


def time_clip(video: Path, fps: float | None, job, repeats: int) -> dict:
    """Observe ``video`` ``repeats`` times; seconds of each run, the window and size, and the phases
    of the fastest run, the one whose seconds are reported (so that each phase is a part of them
    even when the machine's load varies between runs)."""
    runs, obs, profiles = [], None, []
    for _ in range(max(1, repeats)):
        prof = cProfile.Profile()
        t0 = time.perf_counter()
        prof.enable()
        with contextlib.redirect_stdout(io.StringIO()):
            obs = observe_window(video, job, fps)
        prof.disable()
        runs.append(round(time.perf_counter() - t0, 3))
        profiles.append(prof)
    fastest = int(np.argmin(runs))
    return {"seconds": runs[fastest], "first_s": runs[0], "runs": runs, "window_s": [round(obs.start, 3), round(obs.duration, 3)],
            "frames": int(len(obs.frames)), "size": list(obs.size), "phases": phase_seconds(profiles[fastest])}


def real_clips() -> list[tuple[str, Path, float | None]]:
    """The 19 real clips of ``scripts/realvideo_all.py``: (name, file, true fps or None)."""
    from realvideo_all import CLIPS, REAL
    return [(name, REAL / rel, fps) for name, rel, fps in CLIPS]


def rendered_clips(root: Path, sets: list[str], n: int) -> list[tuple[str, Path, float | None]]:
    """The first ``n`` clips of each rendered set (``engine/split``) that exists under ``root``."""
    out = []
    for s in sets:
        folder = root / s
        if not folder.is_dir():
            print(f"{folder}: no such set (python -m pipeline.truthsets generate), skipped")
            continue
        for clip in sorted(p for p in folder.iterdir() if (p / "video.mp4").exists())[:n]:
            out.append((f"{s}/{clip.name}", clip / "video.mp4", None))
    return out


def markdown(report: dict) -> str:
    """The report as a Markdown table (per clip, then a summary per group)."""
    lines = ["# The main job's observation: seconds per clip (issue 36)", "",
             f"Command: `{report['command']}` (tree `{report['commit']}`), {report['cpu_count']} cores, load "
             f"{report['load_before'][0]:.2f} before and {report['load_after'][0]:.2f} after, "
             f"torch threads {report['torch_threads']}. Step 1 of `dynamics infer` "
             "(`pipeline.reconstruct.observe_window`: window choice, detection pass, crop, masks, tracks, flow) with the "
             f"main job's settings; the minimum of {report['repeats']} run(s) per clip, and the first run (it also loads "
             f"the segmenter). Target: <= {TARGET_S:g} s per 1-s clip at working size on 2 cores.", "",
             "| clip | window (s) | frames | working size | s (min) | s (first run) | "
             + " | ".join(PHASES) + " |",
             "|---|---|---|---|---|---|" + "---|" * len(PHASES)]
    for r in report["clips"]:
        lines.append(f"| {r['clip']} | {r['window_s'][0]:.2f}+{r['window_s'][1]:.2f} | {r['frames']} | "
                     f"{r['size'][0]}x{r['size'][1]} | {r['seconds']:.2f} | {r['first_s']:.2f} | "
                     + " | ".join(f"{r['phases'][p]:.2f}" for p in PHASES) + " |")
    lines += ["", "| group | clips | mean s | max s | clips <= target |", "|---|---|---|---|---|"]
    for g, s in report["summary"].items():
        lines.append(f"| {g} | {s['clips']} | {s['mean_s']:.2f} | {s['max_s']:.2f} | {s['within_target']}/{s['clips']} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=2, help="runs per clip (the minimum is reported)")
    ap.add_argument("--only", nargs="*", default=None, help="real clip names (substrings) to time (default: all 19)")
    ap.add_argument("--rendered", type=int, default=0, help="also the first N clips of each set in --sets")
    ap.add_argument("--sets", default="mujoco/dev,pybullet/dev", help="rendered sets, comma list of engine/split")
    ap.add_argument("--sets-root", type=Path, default=ROOT / "data/truthsets", help="rendered sets' root")
    ap.add_argument("--params", default=None, help="params.yaml (default ./params.yaml)")
    ap.add_argument("--report", type=Path, default=ROOT / "reports/observation_speed", help="report path stem")
    args = ap.parse_args(argv)
    import torch

    job = job_settings(load_params(args.params))
    clips = [c for c in real_clips() if not args.only or any(o in c[0] for o in args.only)]
    groups = {c[0]: "real (19)" for c in clips}
    if args.rendered:
        rendered = rendered_clips(args.sets_root, args.sets.split(","), args.rendered)
        clips += rendered
        groups.update({c[0]: "rendered " + c[0].rsplit("/", 1)[0] for c in rendered})
    load0 = os.getloadavg()
    rows = []
    for name, video, fps in clips:
        row = {"clip": name, **time_clip(video, fps, job, args.repeats)}
        rows.append(row)
        print(f"{name:32s} {row['seconds']:6.2f} s (first {row['first_s']:.2f})  window {row['window_s']}  "
              f"size {row['size']}  " + ", ".join(f"{k} {v:.2f}" for k, v in row["phases"].items()), flush=True)
    summary = {}
    for g in dict.fromkeys(groups[r["clip"]] for r in rows):
        s = [r["seconds"] for r in rows if groups[r["clip"]] == g]
        summary[g] = {"clips": len(s), "mean_s": round(float(np.mean(s)), 3), "max_s": round(float(np.max(s)), 3),
                      "within_target": int(sum(x <= TARGET_S for x in s))}
    given = sys.argv[1:] if argv is None else argv
    report = {"command": " ".join(["python benchmarks/observation_speed.py", *given]),
              "commit": tree_id(), "cpu_count": os.cpu_count(), "torch_threads": torch.get_num_threads(),
              "repeats": args.repeats, "load_before": list(load0), "load_after": list(os.getloadavg()),
              "target_s": TARGET_S, "summary": summary, "clips": rows}
    write_json(args.report.with_suffix(".json"), report)
    write_text(args.report.with_suffix(".md"), markdown(report))
    for g, s in summary.items():
        print(f"{g}: mean {s['mean_s']:.2f} s, max {s['max_s']:.2f} s, {s['within_target']}/{s['clips']} <= {TARGET_S:g} s")
    print(f"wrote {args.report.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
