"""Label-free preference optimisation judged against the truth (issue 37 item 5): ``dynamics
adapt`` on the videos of one half of a rendered cross-engine set, the model then judged on the
other half (inductive), and ``dynamics adapt`` on the judged half itself (transductive,
test-time optimisation); every row against the unadapted model on the same clips.

The set's clips (``python -m pipeline.truthsets generate``, PyBullet by default) are split in
two halves balanced by true object count (within each count, by clip name, alternately). Adapt
reads the videos only (the ``video.mp4`` files are copied into folders of their own, so nothing
else is in reach); the judging reads the truth (``benchmarks/cross_engine.py``: composition and
true-mask IoU of the first sample, Best@K and Best@K + CMA-ES, bootstrap 95 % intervals). The
synthetic check is the adapt guard's (greedy first samples on ``preference.guard_scenes``
scenes drawn as the test split draws them), before and after each round.

Usage::

    MUJOCO_GL=egl python benchmarks/preference_eval.py --set pybullet/dev --rounds 2 -k 8
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path

from tqdm import tqdm

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.cross_engine import ROWS, run_clip, save_report, summarize  # noqa: E402
from pipeline.adapt import adapt, log_markdown  # noqa: E402
from pipeline.params import load_params  # noqa: E402
from pipeline.reconstruct import resolve_model_dir  # noqa: E402


def balanced_halves(clips: list[Path]) -> tuple[list[Path], list[Path]]:
    """Two halves of ``clips`` balanced by true object count (``meta.json``): sorted by count,
    then name, and dealt alternately, so each count splits within one clip and the halves'
    sizes within one."""
    def n_objects(c: Path) -> int:
        return len(json.loads((c / "meta.json").read_text())["objects"])

    ranked = sorted(clips, key=lambda c: (n_objects(c), c.name))
    return ranked[0::2], ranked[1::2]


def videos_only(clips: list[Path], folder: Path) -> Path:
    """A folder holding only the clips' videos (``<clip>.mp4``)."""
    folder.mkdir(parents=True, exist_ok=True)
    for c in clips:
        shutil.copy2(c / "video.mp4", folder / f"{c.name}.mp4")
    return folder


def markdown(report: dict) -> str:
    lines = ["# Label-free preference optimisation against the truth (issue 37)", "",
             f"Command: `{report['command']}` (tree `{report['commit']}`). Set `{report['set']}`, halves balanced by "
             f"object count: adapt half {report['halves']['adapt']}, judged half {report['halves']['judged']}. "
             "`dynamics adapt` reads the videos only; the judging reads the true scenes and masks "
             "(`benchmarks/cross_engine.py`: composition, true-mask IoU strict and over all frames, bootstrap 95 % "
             "intervals). Inductive: adapted on the other half; transductive: adapted on the judged clips "
             "themselves.", "",
             "| model | row | composition | object count | true-mask IoU (strict) | true-mask IoU (all frames) |",
             "|---|---|---|---|---|---|"]

    def cell(v):
        return f"{v['mean']:.3f} [{v['ci95'][0]:.2f}, {v['ci95'][1]:.2f}]"

    for name, s in report["summary"].items():
        for row in ROWS:
            r = s[row]
            lines.append(f"| {name} | {row.replace('_', ' ')} | {cell(r['composition'])} | {cell(r['count'])} | "
                         f"{cell(r['strict'])} | {cell(r['all_frames'])} |")
    lines += ["", "Per round (the adapt log: beta, DPO loss, implicit reward margin and accuracy, KL to the reference "
              "in nats per completion, the guard on synthetic scenes, seconds):", ""]
    lines += log_markdown(report["adapt_logs"], report["adapt_stopped"])
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sets", type=Path, default=ROOT / "data/truthsets")
    ap.add_argument("--set", default="pybullet/dev", help="ENGINE/SPLIT under --sets")
    ap.add_argument("--model", default=None, help="the model to adapt (default: the one `dynamics infer` uses)")
    ap.add_argument("--rounds", type=int, default=None, help="adapt rounds (params preference.rounds)")
    ap.add_argument("-k", type=int, default=None, help="adapt samples per video (params preference.k)")
    ap.add_argument("--eval-k", type=int, default=None, help="Best@K of the judging (params model.k)")
    ap.add_argument("--work", type=Path, default=ROOT / "data/preference_eval",
                    help="adapted checkpoints and the video-only folders (resumed)")
    ap.add_argument("--skip", default="", help="comma list of inductive,transductive to leave out")
    ap.add_argument("--params", default=None)
    ap.add_argument("--report", type=Path, default=ROOT / "reports/preference_eval")
    args = ap.parse_args(argv)
    os.environ.setdefault("LP_NUM_THREADS", "0")
    params = load_params(args.params)
    base = resolve_model_dir(args.model, params)
    eval_k = args.eval_k or int(params["model"]["k"])
    clips = sorted(p for p in (args.sets / args.set).iterdir() if (p / "truth.npz").exists())
    half_a, half_b = balanced_halves(clips)
    runs = {"inductive": half_a, "transductive": half_b}
    models = {f"{base.name} (unadapted)": base}
    logs, stopped = {}, {}
    for run, half in runs.items():
        if run in args.skip.split(","):
            continue
        out = args.work / run
        t0 = time.time()
        state = adapt([videos_only(half, args.work / f"videos_{run}")], out, params, base=base, rounds=args.rounds,
                      k=args.k)
        print(f"[preference_eval] {run}: {state['rounds_done']} rounds in {time.time() - t0:.0f} s")
        logs[run], stopped[run] = state["log"], state["stopped"]
        models[f"adapted, {run}"] = out
    rows = {}
    for name, mdir in models.items():
        rows[name] = [run_clip(c, params, Path(mdir), eval_k, 0, True) for c in tqdm(half_b, desc=name)]
    save_report(args.report, "preference_eval.py", argv,
                {"set": args.set, "halves": {"adapt": [c.name for c in half_a], "judged": [c.name for c in half_b]},
                 "summary": {k: summarize(v) for k, v in rows.items()}, "rows": rows, "adapt_logs": logs,
                 "adapt_stopped": stopped}, markdown)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
