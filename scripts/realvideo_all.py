"""The main job on every real clip (the six shared ones and the thirteen of ``dev/``), then the
project's own simulator on each written scene, as a new user would run them.

For every clip: ``dynamics infer CLIP [--fps F] --out OUT/<name>`` and then
``dynamics simulate OUT/<name>/scene.yaml --width W --height H --out OUT/<name>/simulate`` with
no flag, at the working size of the main job. One row per clip in ``OUT/summary.json`` and a
Markdown table on stdout:

* ``best_of_k``: full IoU (pseudo ground truth) of the Best@K pick the search started from;
* ``written``: full IoU of the scene written to ``scene.yaml`` (what ``metrics.json`` reports
  as ``best_of_k_cmaes``);
* ``simulate``: ``ok`` when ``dynamics simulate`` accepts the written scene as it is, else its
  one-line error;
* ``resim_iou``: mask IoU of ``dynamics simulate``'s masks against the masks the main job
  scored (``masks.npz`` of the main job's output, when it writes one): 1.0 means the file
  re-simulates to what was scored;
* against ``tests/fixtures/realvideo/content.yaml`` (what each clip shows, issue 29):
  ``objects_written`` / ``objects_true``, ``shapes_right`` (the written scene's multiset of
  shapes equals the clip's), ``support_written`` (``incline`` when a static geom is tilted
  2-60 deg or the floor is tilted, else ``floor``) against ``support_true``, and the view.

``--table-only`` rebuilds ``table.md`` (and the content columns of ``summary.json``) from an
earlier run's folders without running anything.

A JPEG copy of every clip's contact sheet goes to ``OUT/contact_sheets/<clip>.jpg``.

Usage (``OUT/table.md``, ``OUT/summary.json`` and ``OUT/contact_sheets/``; copies of a full run are in
``reports/realvideo_all/``)::

    python scripts/realvideo_all.py --out outputs/realvideo_all [--only dev09_ball_rolling_on_desk]

True frame rates are those of ``shared/data/real/*/SOURCES.md`` (240 fps PhysTrack clips,
1000 fps ``dev/01``); every other clip uses its container rate.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from pipeline.atomic import write_text  # noqa: E402
from pipeline.rotation import quat_to_mat  # noqa: E402
from pipeline.scene import load_scene  # noqa: E402

REAL = Path(os.environ.get("REAL_ROOT", Path(__file__).resolve().parents[2] / "shared" / "data" / "real"))
LABELS = Path(__file__).resolve().parents[1] / "tests" / "fixtures" / "realvideo"
CLIPS = [  # (name, file relative to REAL, true fps or None)
    ("01_bouncing_green_ball", "video/01_bouncing_green_ball_1080p30.avi", None),
    ("02_ball_on_ramp", "video/02_tracker_BallOnRamp_30fps.mp4", None),
    ("04_collision_pucks", "video/04_tracker_collision-pucks_30fps.mp4", None),
    ("05_carom_puck", "video/05_phystrack_CaromPuck_HeadOn_240fps.mp4", 240),
    ("07_rolling_cylinder", "video/07_phystrack_RollingCylinder_240fps.mp4", 240),
    ("08_sliding_block", "video/08_phystrack_SlidingFriction_R1_240fps.mp4", 240),
    ("dev01_steel_ball_freefall", "dev/01_steel_ball_freefall_tape_measure_1000fps.mp4", 1000),
    ("dev02_pingpong_drop", "dev/02_pingpong_drop_bounce_30cm_ruler.mov", None),
    ("dev03_tennis_ball_drop", "dev/03_tennis_ball_drop_bounce_marked_backdrop.mp4", None),
    ("dev04_red_ball_drop_roll", "dev/04_red_ball_drop_bounce_roll.mp4", None),
    ("dev05_pingpong_table", "dev/05_pingpong_drop_bounce_table.mp4", None),
    ("dev06_red_ball_thrown", "dev/06_red_ball_thrown_projectile.mp4", None),
    ("dev07_tennis_ball_toss", "dev/07_tennis_ball_toss_projectile.mp4", None),
    ("dev08_ball_vertical_toss", "dev/08_ball_vertical_toss.mp4", None),
    ("dev09_ball_rolling_on_desk", "dev/09_ball_rolling_on_desk.mp4", None),
    ("dev10_glider_air_track", "dev/10_glider_inclined_air_track_tape_measure.mp4", None),
    ("dev11_tennis_ball_rolling", "dev/11_tennis_ball_rolling_tabletop.mp4", None),
    ("dev12_can_sliding", "dev/12_can_sliding_spinning_tabletop.mp4", None),
    ("dev13_rubiks_cube", "dev/13_rubiks_cube_sliding_tabletop.mp4", None),
]


def _last_line(text: str) -> str:
    lines = [l for l in text.strip().splitlines() if l.strip()]
    return lines[-1][:200] if lines else ""


def _mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Foreground IoU over the whole sequence, (T, H, W) int8 masks (-1 = background); 0 when
    both are empty (no free credit)."""
    fa, fb = a >= 0, b >= 0
    union = np.logical_or(fa, fb).sum()
    same = np.logical_and(fa, fb) & (a == b)
    return float(same.sum() / union) if union else 0.0


CONTENT = LABELS / "content.yaml"
"""What each clip shows (objects, support, view): written by hand, never read by the main job."""


@functools.lru_cache(maxsize=1)
def _content() -> dict:
    """:data:`CONTENT`, read once."""
    return yaml.safe_load(CONTENT.read_text())


def content_columns(name: str, clip_out: Path) -> dict:
    """The written scene (``clip_out/scene.yaml``, ``metrics.json``) against :data:`CONTENT`."""
    truth = _content().get(name)
    if truth is None or not (clip_out / "scene.yaml").exists():
        return {}
    scene = load_scene(clip_out / "scene.yaml")
    shapes = sorted(o.shape for o in scene.objects)
    tilts = [float(np.degrees(np.arccos(np.clip(quat_to_mat(g.orientation)[2, 2], -1.0, 1.0)))) for g in scene.static]
    incline = any(2.0 < t < 60.0 for t in tilts) or any(e.effect == "floor_tilt" for e in scene.effects)
    support = "incline" if incline else "floor"
    m = json.loads((clip_out / "metrics.json").read_text())
    view = m.get("view_written") or m.get("view")   # the written camera's view (older runs: perception's)
    return {"objects_written": len(shapes), "objects_true": len(truth["objects"]),
            "shapes_written": shapes, "shapes_true": sorted(truth["objects"]),
            "shapes_right": shapes == sorted(truth["objects"]),
            "support_written": support, "support_true": truth["support"],
            "support_right": None if truth["support"] == "none" else support == truth["support"],
            "view_written": view, "view_true": truth["view"]}


def run_clip(name: str, rel: str, fps: int | None, out: Path, mask_method: str | None = None,
             model: str | None = None, scenery: str | None = None) -> dict:
    """Run ``dynamics infer`` then ``dynamics simulate`` on one clip; one summary row
    (``mask_method``: the observation, default params ``realvideo.mask_method``; ``model``: a
    checkpoint folder instead of the shipped one; ``scenery``: ``dynamics infer --scenery``)."""
    clip_out = out / name
    row: dict = {"clip": name, "file": rel, "fps": fps}
    cmd = ["dynamics", "infer", str(REAL / rel), "--out", str(clip_out)] + (["--fps", str(fps)] if fps else [])
    cmd += ["--mask-method", mask_method] if mask_method else []
    cmd += ["--model", model] if model else []
    cmd += ["--scenery", scenery] if scenery else []
    labels = LABELS / name.split("_")[0]          # hand labels (issue 36): scored against, never fitted
    if labels.is_dir():
        cmd += ["--labels", str(labels)]
    t0 = time.time()
    p = subprocess.run(cmd, capture_output=True, text=True)
    row["seconds"] = round(time.time() - t0, 1)
    if p.returncode != 0:
        row["error"] = _last_line(p.stderr)
        return row
    m = json.loads((clip_out / "metrics.json").read_text())
    row["best_of_k"] = m["best_of_k"]["full_iou"]
    row["best_of_k_strict"] = m["best_of_k"].get("strict_full_iou")
    row["written"] = m["best_of_k_cmaes"]["full_iou"]
    row["written_strict"] = m["best_of_k_cmaes"].get("strict_full_iou")
    row["window_s"] = m["window"]["duration_s"]
    row["search_gain"] = m.get("search_gain")
    row["model_best"] = m.get("sources", {}).get("model", {})   # the model's best proposal (issue 30)
    row["best_of_k_source"] = m.get("best_of_k_source")
    row["against_labels"] = m.get("against_labels")
    W, H = m["window"]["width"], m["window"]["height"]
    sim_out = clip_out / "simulate"
    p = subprocess.run(["dynamics", "simulate", str(clip_out / "scene.yaml"), "--width", str(W), "--height", str(H),
                        "--out", str(sim_out)], capture_output=True, text=True)
    row["simulate"] = "ok" if p.returncode == 0 else _last_line(p.stderr)
    scored = clip_out / "masks.npz"
    if p.returncode == 0 and scored.exists():
        with np.load(scored) as a, np.load(sim_out / "masks.npz") as b:
            row["resim_iou"] = round(_mask_iou(a["seg"], b["seg"]), 4)
    row.update(content_columns(name, clip_out))
    return row


def table(rows: list[dict]) -> str:
    """Markdown table of the summary rows."""
    out = ["| clip | window (s) | objects written / true | shapes written (true) | support written / true | "
           "view written / true | Best@K IoU strict / all frames | written IoU strict / all frames | written - Best@K "
           "| simulate | re-sim vs scored masks | labelled frames | re-sim vs labels | observation vs labels | s |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    fmt = lambda v: "–" if v is None else f"{v:.3f}"  # noqa: E731
    for r in rows:
        if "error" in r:
            out.append(f"| {r['clip']} | – | – | – | – | – | – | – | – | main job failed: {r['error']} | – | – | – | – | "
                       f"{r['seconds']} |")
            continue
        d = r["written"] - r["best_of_k"]
        a = r.get("against_labels") or {}
        mark = lambda ok: "" if ok is None else (" ✓" if ok else " ✗")  # noqa: E731
        shapes = ", ".join(r.get("shapes_written", [])) or "–"
        out.append(f"| {r['clip']} | {fmt(r.get('window_s'))} | {r.get('objects_written', '–')} / {r.get('objects_true', '–')} | "
                   f"{shapes}{mark(r.get('shapes_right'))} ({', '.join(r.get('shapes_true', []))}) | "
                   f"{r.get('support_written', '–')} / {r.get('support_true', '–')}{mark(r.get('support_right'))} | "
                   f"{r.get('view_written', '–')} / {r.get('view_true', '–')} | "
                   f"{fmt(r.get('best_of_k_strict'))} / {r['best_of_k']:.3f} | {fmt(r.get('written_strict'))} / "
                   f"{r['written']:.3f} | {d:+.4f} | {r['simulate']} | "
                   f"{r.get('resim_iou', '–')} | {a.get('n_labelled', '–')} | {fmt(a.get('resim_vs_labels'))} | "
                   f"{fmt(a.get('observation_vs_labels'))} | {r['seconds']} |")
    ok = [r for r in rows if "error" not in r]
    if ok:
        worse = sum(r["written"] < r["best_of_k"] for r in ok)
        sim_ok = sum(r["simulate"] == "ok" for r in ok)
        out.append("")
        # a clip the main job fails on (e.g. nothing seen in its window) counts 0: no free credit by omission
        strict = [r.get("written_strict") or 0.0 for r in ok] + [0.0] * (len(rows) - len(ok))
        full = [r["written"] for r in ok] + [0.0] * (len(rows) - len(ok))
        out.append(f"clips run: {len(ok)}/{len(rows)}; mean written IoU over all {len(rows)} (a failed clip counts 0) "
                   f"{np.mean(full):.4f} (strict, no free credit: {np.mean(strict):.4f}); "
                   f"written below Best@K: {worse}; `dynamics simulate` accepts the written scene: {sim_ok}/{len(ok)}")
        with_content = [r for r in ok if "shapes_right" in r]
        supported = [r for r in with_content if r.get("support_right") is not None]
        failed = len(rows) - len(ok)      # counted wrong below (their content was not written)
        if with_content:
            n = len(with_content) + failed
            out.append(f"against the clips' content (`tests/fixtures/realvideo/content.yaml`): object count right "
                       f"{sum(r['objects_written'] == r['objects_true'] for r in with_content)}/{n}, "
                       f"shapes right {sum(r['shapes_right'] for r in with_content)}/{n}, support right "
                       f"{sum(r['support_right'] for r in supported)}/{len(supported)} (clips on a floor, table or "
                       f"incline, of those run), view right {sum(r['view_written'] == r['view_true'] for r in with_content)}/"
                       f"{n}; strict IoU >= 0.5: "
                       f"{sum((r.get('written_strict') or 0) >= 0.5 for r in ok)}/{len(rows)}")
        labelled = [r["against_labels"]["resim_vs_labels"] for r in ok
                    if (r.get("against_labels") or {}).get("resim_vs_labels") is not None]
        if labelled:
            out.append(f"against the hand labels (the clips with labelled frames in their window): mean "
                       f"{np.mean(labelled):.4f}, >= 0.5 on {sum(v >= 0.5 for v in labelled)}/{len(labelled)}")
    return "\n".join(out)


def shape_choice(metrics: dict) -> dict:
    """Why a clip's shapes are what they are (issue 29 item 4), from its ``metrics.json``: the
    perception hypotheses' Best@K fitness, the fittest proposal, the one refined (within
    ``realvideo.shape_margin`` of the fittest, the shapes the silhouettes favour, then the fewest
    shape parameters, :func:`pipeline.search.simplest_within`) and the
    source of the written scene."""
    props = metrics.get("proposals", [])
    hyps = [(p["label"].removeprefix("perception: "), p.get("fitness")) for p in props
            if p.get("source") == "perception" and p.get("valid")]
    picked, fittest = metrics.get("best_of_k_label"), metrics.get("best_of_k_fittest_label")
    rank = ({p["label"]: p.get("silhouette_rank") or 0 for p in props}
            if metrics.get("shape_tiebreak") == "silhouette" else {})
    why = ("a model sample was fittest" if metrics.get("best_of_k_source") == "model" else
           "fittest" if picked == fittest else
           f"silhouettes: shapes their outlines favour, within the margin of {fittest!r}"
           if rank.get(picked, 0) < rank.get(fittest, 0) else
           f"parsimony: fewer shape parameters within the margin of {fittest!r}")
    return {"hypotheses": hyps, "picked": picked, "fittest": fittest, "why": why}


def shape_table(rows: list[dict], out: Path) -> str:
    """Markdown table: per clip, the shapes written and why (:func:`shape_choice`)."""
    lines = ["| clip | shapes written (true) | perception hypotheses: Best@K fitness | refined | why |", "|---|---|---|---|---|"]
    for r in rows:
        f = out / r["clip"] / "metrics.json"
        if "error" in r or not f.exists():
            continue
        c = shape_choice(json.loads(f.read_text()))
        hyps = "; ".join(f"{lab} {fit:.3f}" for lab, fit in c["hypotheses"] if fit is not None) or "–"
        lines.append(f"| {r['clip']} | {', '.join(r.get('shapes_written', [])) or '–'} "
                     f"({', '.join(r.get('shapes_true', []))}) | {hyps} | {c['picked']} | {c['why']} |")
    return "\n".join(lines)


def model_table(rows: list[dict]) -> str:
    """Markdown table of what the scene-writing model proposes on each clip (issue 30): its best
    proposal's IoU against the pseudo ground truth (strict / all frames) and which source Best@K
    picked."""
    out = ["| clip | model's best proposal IoU strict / all frames | Best@K picked |", "|---|---|---|"]
    fmt = lambda v: "–" if v is None else f"{v:.3f}"  # noqa: E731
    ok = [r for r in rows if "error" not in r and r.get("model_best")]
    for r in ok:
        m = r["model_best"]
        out.append(f"| {r['clip']} | {fmt(m.get('best_strict_iou'))} / {fmt(m.get('best_full_iou'))} | "
                   f"{r.get('best_of_k_source', '–')} |")
    if ok:
        good = sum((r["model_best"].get("best_strict_iou") or 0) >= 0.3 for r in ok)
        picked = sum(r.get("best_of_k_source") == "model" for r in ok)
        out += ["", f"model's best proposal strict IoU >= 0.3: {good}/{len(ok)}; Best@K picked a model sample: "
                    f"{picked}/{len(ok)}"]
    return "\n".join(out)


SHEET_WIDTH = 1200
"""px: width of the contact-sheet copies in ``OUT/contact_sheets`` (JPEG), small enough to commit."""


def contact_sheets(rows: list[dict], out: Path) -> list[str]:
    """A JPEG copy of every clip's ``contact_sheet.png`` (observed + pseudo masks | observed +
    re-simulated masks | re-simulated, six instants) in ``out/contact_sheets/<clip>.jpg``,
    :data:`SHEET_WIDTH` px wide. Returns the clips that have one."""
    import cv2

    done = []
    for row in rows:
        src = out / row["clip"] / "contact_sheet.png"
        img = cv2.imread(str(src)) if src.exists() else None
        if img is None:
            continue
        h, w = img.shape[:2]
        if w > SHEET_WIDTH:
            img = cv2.resize(img, (SHEET_WIDTH, round(h * SHEET_WIDTH / w)), interpolation=cv2.INTER_AREA)
        dst = out / "contact_sheets" / f"{row['clip']}.jpg"
        dst.parent.mkdir(parents=True, exist_ok=True)
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 85])
        if ok:
            tmp = dst.with_suffix(".jpg.tmp")
            tmp.write_bytes(buf.tobytes())
            tmp.replace(dst)
            done.append(row["clip"])
    return done


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("outputs/realvideo_all"), help="output folder")
    ap.add_argument("--only", nargs="*", default=None, help="clip names to run (default: all)")
    ap.add_argument("--mask-method", default=None,
                    help="observation for every clip (dynamics infer --mask-method; default params realvideo.mask_method)")
    ap.add_argument("--model", default=None, help="checkpoint folder for every clip (dynamics infer --model; "
                                                   "default the shipped one)")
    ap.add_argument("--scenery", default=None, choices=("keep", "drop"),
                    help="objects at rest no mover touches, for every clip (dynamics infer --scenery; default params "
                         "realvideo.scenery)")
    ap.add_argument("--table-only", action="store_true",
                    help="rebuild table.md from OUT/summary.json and the clips' folders; run nothing")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    if args.table_only:
        for row in json.loads((args.out / "summary.json").read_text()):
            if "error" not in row:
                m = json.loads((args.out / row["clip"] / "metrics.json").read_text())
                row["best_of_k_strict"] = m["best_of_k"].get("strict_full_iou")
                row["model_best"] = m.get("sources", {}).get("model", {})
                row["best_of_k_source"] = m.get("best_of_k_source")
                row.update(content_columns(row["clip"], args.out / row["clip"]))
            rows.append(row)
    for name, rel, fps in ([] if args.table_only else CLIPS):
        if args.only and name not in args.only:
            continue
        row = run_clip(name, rel, fps, args.out, args.mask_method, args.model, args.scenery)
        print(json.dumps(row), flush=True, file=sys.stderr)
        rows.append(row)
    write_text(args.out / "summary.json", json.dumps(rows, indent=1) + "\n")
    sheets = contact_sheets(rows, args.out)
    text = (f"# Main job then dynamics simulate on all {len(CLIPS)} real clips\n\n"
            f"Command: `python scripts/realvideo_all.py --out {args.out}"
            f"{' --mask-method ' + args.mask_method if args.mask_method else ''}"
            f"{' --model ' + args.model if args.model else ''}"
            f"{' --scenery ' + args.scenery if args.scenery else ''}` (IoU against pseudo ground truth: "
            "full-sequence IoU as the search reports it, and strict, over the frames where an object or its match "
            "is visible; \"re-sim vs scored masks\": foreground IoU of `dynamics simulate`'s masks against the masks "
            "the main job scored; labels: the hand labels on the window's labelled frames).\n\n" + table(rows)
            + "\n\n## The shapes chosen and why (issue 29 item 4)\n\nThe written scene starts from the refined "
            "proposal (staged CMA-ES keeps its shapes; objects at rest may be added).\n\n" + shape_table(rows, args.out)
            + "\n\n## The scene-writing model's proposals\n\n" + model_table(rows)
            + f"\n\nContact sheets ({len(sheets)} clips): `contact_sheets/<clip>.jpg`.")
    write_text(args.out / "table.md", text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
