"""Label-free preference optimisation on the real clips (issue 37 item 5): ``dynamics adapt`` on
some real clips, the main job with the adapted model on the others (inductive), and ``dynamics
adapt`` on the judged clips themselves (transductive); every row against the unadapted model.

Split by clip: by default the thirteen clips of ``shared/data/real/dev`` adapt and the six shared
clips are judged. Adapt reads the videos only (each clip's true frame rate from
``scripts/realvideo_all.py``'s list, SOURCES.md). The judging is ``scripts/realvideo_all.py
--only <judged> --model M`` per model: the model's best proposal (strict and all-frames IoU
against the observation's masks, as Best@K scores it), whether Best@K picked a model sample,
and the written scene against the hand labels (``tests/fixtures/realvideo``).

Usage::

    MUJOCO_GL=egl python benchmarks/preference_real.py --rounds 2 -k 8
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
for p in (ROOT, ROOT / "scripts"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

from benchmarks.cross_engine import save_report  # noqa: E402
from pipeline.adapt import adapt, log_markdown  # noqa: E402
from pipeline.metrics import mean_ci95  # noqa: E402
from pipeline.params import load_params  # noqa: E402
from pipeline.reconstruct import resolve_model_dir  # noqa: E402
from realvideo_all import CLIPS, REAL  # noqa: E402

SHARED = [name for name, _, _ in CLIPS if not name.startswith("dev")]
DEV = [name for name, _, _ in CLIPS if name.startswith("dev")]


def judge(model: Path, clips: list[str], out: Path) -> list[dict]:
    """``scripts/realvideo_all.py --only CLIPS --model MODEL --out OUT``; its summary rows."""
    if not (out / "summary.json").exists():
        subprocess.run([sys.executable, str(ROOT / "scripts" / "realvideo_all.py"), "--only", *clips, "--model",
                        str(model), "--out", str(out)], check=True, cwd=ROOT)
    return json.loads((out / "summary.json").read_text())


def rows_of(summary: list[dict]) -> dict[str, dict]:
    out = {}
    for r in summary:
        if "error" in r:
            out[r["clip"]] = {"error": r["error"]}
            continue
        mb = r.get("model_best") or {}
        out[r["clip"]] = {"model_best_strict": mb.get("best_strict_iou") or 0.0,
                          "model_best_full": mb.get("best_full_iou") or 0.0,
                          "picked_model": r.get("best_of_k_source") == "model",
                          "written_strict": r.get("written_strict"),
                          "written_vs_labels": (r.get("against_labels") or {}).get("resim_vs_labels")}
    return out


def markdown(report: dict) -> str:
    lines = ["# Label-free preference optimisation on the real clips (issue 37)", "",
             f"Command: `{report['command']}` (tree `{report['commit']}`). Adapt (videos only) on "
             f"{len(report['adapt_clips'])} clips ({', '.join(report['adapt_clips'])}); judged on "
             f"{', '.join(report['judged_clips'])} by `scripts/realvideo_all.py --model`: the model's best proposal "
             "(IoU against the observation's masks, strict / all frames), whether Best@K picked a model sample, the "
             "written scene's strict IoU and its IoU against the hand labels.", "",
             "| clip | model | best proposal strict | best proposal all frames | Best@K picked | written strict | "
             "written vs labels |", "|---|---|---|---|---|---|---|"]
    for clip in report["judged_clips"]:
        for name, rows in report["rows"].items():
            r = rows.get(clip, {})
            if "error" in r or not r:
                lines.append(f"| {clip} | {name} | {r.get('error', 'missing')[:60]} | | | | |")
                continue
            lines.append(f"| {clip} | {name} | {r['model_best_strict']:.3f} | {r['model_best_full']:.3f} | "
                         f"{'model' if r['picked_model'] else 'perception'} | {r['written_strict']} | "
                         f"{r['written_vs_labels']} |")
    lines += ["", "| model | mean best proposal strict [95 %] | Best@K picked a model sample | mean written vs labels |",
              "|---|---|---|---|"]
    for name, s in report["summary"].items():
        v = s["model_best_strict"]
        lines.append(f"| {name} | {v['mean']:.3f} [{v['ci95'][0]:.3f}, {v['ci95'][1]:.3f}] | {s['picked_model']} | "
                     f"{s['written_vs_labels']} |")
    lines += ["", "Per round (adapt logs):", ""]
    lines += log_markdown(report["adapt_logs"], report["adapt_stopped"])
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--adapt-clips", default=",".join(DEV), help="comma list of clip names to adapt on (inductive)")
    ap.add_argument("--judged-clips", default=",".join(SHARED), help="comma list of clip names to judge")
    ap.add_argument("--model", default=None, help="the model to adapt (default: the one `dynamics infer` uses)")
    ap.add_argument("--rounds", type=int, default=None)
    ap.add_argument("-k", type=int, default=None)
    ap.add_argument("--skip", default="", help="comma list of inductive,transductive to leave out")
    ap.add_argument("--work", type=Path, default=ROOT / "data/preference_real")
    ap.add_argument("--params", default=None)
    ap.add_argument("--report", type=Path, default=ROOT / "reports/preference_real")
    args = ap.parse_args(argv)
    os.environ.setdefault("LP_NUM_THREADS", "0")
    params = load_params(args.params)
    base = resolve_model_dir(args.model, params)
    where = {name: (REAL / rel, fps) for name, rel, fps in CLIPS}
    adapt_clips, judged = args.adapt_clips.split(","), args.judged_clips.split(",")
    runs = {"inductive": adapt_clips, "transductive": judged}
    models = {f"{base.name} (unadapted)": base}
    logs, stopped = {}, {}
    for run, clips in runs.items():
        if run in args.skip.split(","):
            continue
        t0 = time.time()
        videos = [where[c][0] for c in clips]
        rates = {str(where[c][0]): where[c][1] for c in clips if where[c][1]}
        state = adapt(videos, args.work / run, params, base=base, rounds=args.rounds, k=args.k, fps=rates)
        print(f"[preference_real] {run}: {state['rounds_done']} rounds in {time.time() - t0:.0f} s", flush=True)
        logs[run], stopped[run] = state["log"], state["stopped"]
        models[f"adapted, {run}"] = args.work / run
    rows = {name: rows_of(judge(Path(m), judged, args.work / f"judge_{name.split(' ')[0].strip(',')}_{i}"))
            for i, (name, m) in enumerate(models.items())}
    summary = {}
    for name, rr in rows.items():
        ok = [r for r in rr.values() if "error" not in r]
        labels = [r["written_vs_labels"] for r in ok if r["written_vs_labels"] is not None]
        summary[name] = {"model_best_strict": mean_ci95([r["model_best_strict"] for r in ok]),
                         "picked_model": f"{sum(r['picked_model'] for r in ok)}/{len(ok)}",
                         "written_vs_labels": round(sum(labels) / len(labels), 3) if labels else None}
    save_report(args.report, "preference_real.py", argv,
                {"adapt_clips": adapt_clips, "judged_clips": judged, "rows": rows, "summary": summary,
                 "adapt_logs": logs, "adapt_stopped": stopped}, markdown)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
