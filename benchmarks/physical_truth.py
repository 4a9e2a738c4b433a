"""Physical truth where a real clip gives it (issue 29 item 8): gravity from a free fall at a known
frame rate and scale, object sizes against a stated size, incline angles against the image.

Reads the folders a ``scripts/realvideo_all.py`` run wrote (per clip ``observation.npz``: the
observation ``dynamics infer`` fitted; ``masks.npz``: the written scene's re-simulated masks;
``scene.yaml``) and the truths in ``tests/fixtures/realvideo/physical_truth.yaml`` (stated by the
clips' sources or read by hand on a frame; the main job never reads them). For each clip:

* **g** (free-fall clips with a scale): the observed object's image rows over the window, cut
  into flight arcs at bounces and fitted with parabolas (:func:`pipeline.image_measure.fit_gravity`),
  converted with the scale; against 9.81 m/s^2. The written scene has g = 9.81 by construction,
  so this measures the observation and the timing, not the search. The same fit on the hand
  labels' centres (``tests/fixtures/realvideo``, all labelled frames of the clip) checks the
  scale and the frame rate themselves.
* **size** (a stated object size): the observation's equivalent diameter (``2 sqrt(area / pi)``,
  median over the window) times the scale, or for a stated length (a box) the long side of its
  silhouette's rotated box, and the matched object of the written scene.
* **incline** (a stated incline edge in the image): the angle of the observed object's centroid
  path (:func:`pipeline.image_measure.path_angle`) and of the re-simulated one, against the edge.

Usage::

    python scripts/realvideo_all.py --out outputs/realvideo_all
    python benchmarks/physical_truth.py --runs outputs/realvideo_all   # -> reports/physical_truth.{md,json}
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import cv2
import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from pipeline.atomic import write_json, write_text  # noqa: E402
from pipeline.image_measure import fit_flight, fit_gravity, image_track, moving_label, path_angle  # noqa: E402
from pipeline.metrics import match_tracks, track_iou  # noqa: E402
from pipeline.scene import load_scene  # noqa: E402
from pipeline.video import read_video  # noqa: E402

FIXTURES = ROOT / "tests" / "fixtures" / "realvideo"
TRUTH = FIXTURES / "physical_truth.yaml"
REAL = ROOT.parent / "shared" / "data" / "real"
G = 9.81
"""m/s^2, standard gravity (the scene language's default)."""


def joint_gravity(t: np.ndarray, y: np.ndarray, m_per_px: float) -> float | None:
    """g (m/s^2) from all flight arcs with one shared curvature, as perception reads a fall
    (:func:`pipeline.image_measure.fit_flight`), on a row track ``y (N,)`` px at ``t (N,)`` s; the
    tolerance is twice the track's noise (MAD of second differences / sqrt 6, at least 0.75 px),
    as :func:`pipeline.image_tracks.fit_tolerance` takes it. None when no fit."""
    if len(y) < 5:
        return None
    d2 = np.diff(y, 2)
    noise = 1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / math.sqrt(6.0)
    fit = fit_flight(t, y, max(0.75, 2.0 * noise))
    return None if fit is None else fit["a"] * m_per_px


def labels_gravity(truth: dict) -> dict | None:
    """g from the hand labels of ``truth["labels"]`` (a folder of ``<frame>.png`` under
    :data:`FIXTURES`, 0 background, 1 the object): their centres' rows scaled to the original
    frame, at ``frame / truth["fps"]`` s; None without labels."""
    if "labels" not in truth:
        return None
    pngs = sorted((FIXTURES / truth["labels"]).glob("*.png"))
    W0, H0 = read_video(REAL / truth["file"], max_frames=1).original_size
    t, y = [], []
    for png in pngs:
        lab = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        rr, cc = np.nonzero(lab == 1)
        if rr.size and rr.min() > 0 and cc.min() > 0 and rr.max() < lab.shape[0] - 1 \
                and cc.max() < lab.shape[1] - 1:     # cut by the frame's edge: centre biased, left out
            t.append(int(png.stem) / float(truth["fps"]))
            y.append((rr.mean() + 0.5) * H0 / lab.shape[0])
    fit = fit_gravity(np.array(t), np.array(y), float(truth["m_per_px"]))
    return {**fit, "g_joint": joint_gravity(np.array(t), np.array(y), float(truth["m_per_px"]))}


def measure(folder: Path, truth: dict) -> dict:
    """One clip's recovered quantities against its truth (module docstring)."""
    obs = np.load(folder / "observation.npz")
    seg, crop, size = obs["seg"], obs["crop"], obs["size"]
    frames, fps = obs["source_frames"], float(obs["source_fps"])
    row: dict = {"clip": folder.name, "window_s": round(len(seg) / float(obs["fps"]), 3)}
    if not (seg >= 0).any():
        return {**row, "note": "no observed object"}
    k = moving_label(seg)
    t, x, y = image_track(seg, crop, size, frames, fps, label=k, times=obs["times"] if "times" in obs else None)
    row["observed_frames"] = int(len(t))
    resim = np.load(folder / "masks.npz")["seg"]
    iou, _ = track_iou(np.where(seg == k, 0, -1).astype(np.int8), resim)
    pair = match_tracks(iou, [0], [j for j in range(iou.shape[1]) if (resim == j).any()])
    j = pair.get(0)
    if "m_per_px" in truth and truth.get("free_fall"):
        fit = fit_gravity(t, y, float(truth["m_per_px"]))
        row["g"] = None if math.isnan(fit["g"]) else round(fit["g"], 3)
        row["g_error_pct"] = None if math.isnan(fit["g"]) else round(100.0 * (fit["g"] - G) / G, 1)
        row["arcs"] = [{k2: round(v, 4) if isinstance(v, float) else v for k2, v in a.items()} for a in fit["arcs"]]
        joint = joint_gravity(t, y, float(truth["m_per_px"]))
        row["g_joint"] = None if joint is None else round(joint, 3)
        lab = labels_gravity(truth)
        if lab is not None:
            row["g_labels"] = None if math.isnan(lab["g"]) else round(lab["g"], 3)
            row["g_labels_arcs"] = [a["samples"] for a in lab["arcs"]]
            row["g_labels_joint"] = None if lab["g_joint"] is None else round(lab["g_joint"], 3)
    if "object" in truth and "m_per_px" in truth:
        scale_x, scale_y = float(crop[2]) / float(size[0]), float(crop[3]) / float(size[1])
        areas = [(f == k).sum() * scale_x * scale_y for f in seg if (f == k).any()]
        if "length" in truth["object"]:   # a box: its long side, the silhouette's rotated box (original px)
            longs = [max(cv2.minAreaRect(np.stack([cc * scale_x, rr * scale_y], axis=1).astype(np.float32))[1])
                     for rr, cc in (np.nonzero(f == k) for f in seg) if len(rr) >= 5]
            row["true_length_m"] = truth["object"]["length"]
            row["observed_length_m"] = round(float(np.median(longs)) * float(truth["m_per_px"]), 4)
        else:
            row["true_diameter_m"] = truth["object"]["diameter"]
            row["observed_diameter_m"] = round(2.0 * math.sqrt(float(np.median(areas)) / math.pi)
                                               * float(truth["m_per_px"]), 4)
        if j is not None:
            o = load_scene(folder / "scene.yaml").objects[j]
            sz = o.size.model_dump() if hasattr(o.size, "model_dump") else dict(o.size)
            row["scene_object"] = {"shape": o.shape, **{n: round(float(v), 4) for n, v in sz.items()}}
            if "radius" in sz:
                row["scene_diameter_m"] = round(2.0 * float(sz["radius"]), 4)
            if "width" in sz:
                row["scene_length_m"] = round(max(float(sz["width"]), float(sz["depth"]), float(sz["height"])), 4)
    if "incline_deg" in truth:
        row["true_incline_deg"] = truth["incline_deg"]
        row["observed_path_deg"] = round(path_angle(x, y), 2)
        if j is not None:
            _, rx, ry = image_track(resim, crop, size, frames, fps, label=j)
            row["resim_path_deg"] = round(path_angle(rx, ry), 2)
    row["resim_match_iou"] = None if j is None else round(float(iou[0, j]), 3)
    return row


def _pct(g: float | None) -> str:
    return "" if g is None else f" ({100.0 * (g - G) / G:+.1f} %)"


def markdown(rows: list[dict], runs: Path) -> str:
    f = lambda v, nd=3: "–" if v is None else (f"{v:.{nd}f}" if isinstance(v, float) else str(v))  # noqa: E731
    out = ["# Physical truth on real clips (issue 29 item 8)", "",
           f"Command: `python benchmarks/physical_truth.py --runs {runs}` on the folders of "
           "`python scripts/realvideo_all.py` (the main job's observation and written scene per clip); truths: "
           "`tests/fixtures/realvideo/physical_truth.yaml` (stated by the sources or read by hand on a frame).", "",
           "## Gravity from a free fall (observation + true frame rate + scale)", "",
           "g: each arc fitted on its own, the mean weighted by samples; one curvature: all arcs at once with "
           "the samples that do not fit trimmed, as perception reads a fall (`pipeline.image_measure.fit_flight`).", "",
           "| clip | observed frames in window | arcs (samples) | g (m/s^2) | error vs 9.81 | fit rms per arc (px) "
           "| g, one curvature (error) | g from the hand labels (same scale and rate; arcs) | labels, one curvature |",
           "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "arcs" in r or "g" in r:
            out.append(f"| {r['clip']} | {r.get('observed_frames', '–')} | "
                       f"{', '.join(str(a['samples']) for a in r.get('arcs', [])) or 'none with 5+'} | {f(r.get('g'))} | "
                       f"{f(r.get('g_error_pct'), 1) + (' %' if r.get('g_error_pct') is not None else '')} | {', '.join(f(a['rms_px'], 1) for a in r.get('arcs', [])) or '–'} | "
                       f"{f(r.get('g_joint'))}{_pct(r.get('g_joint'))} | "
                       f"{f(r.get('g_labels'))} ({', '.join(map(str, r.get('g_labels_arcs', []))) or 'no arc of 5+'}) | "
                       f"{f(r.get('g_labels_joint'))}{_pct(r.get('g_labels_joint'))} |")
    out += ["", "## Size against a stated size", "",
            "| clip | true size (m) | observation (m) | written scene's matched object |", "|---|---|---|---|"]
    for r in rows:
        for what in ("diameter", "length"):
            if f"true_{what}_m" in r:
                so = r.get("scene_object")
                out.append(f"| {r['clip']} | {what} {r[f'true_{what}_m']} | {f(r.get(f'observed_{what}_m'), 4)} | "
                           + (f"{so['shape']} " + ", ".join(f"{n} {v}" for n, v in so.items() if n != "shape")
                              if so else "–") + " |")
    out += ["", "## Incline against the image", "",
            "| clip | incline edge in the image (deg) | observed path (deg) | re-simulated path (deg) |", "|---|---|---|---|"]
    for r in rows:
        if "true_incline_deg" in r:
            out.append(f"| {r['clip']} | {r['true_incline_deg']} | {f(r.get('observed_path_deg'), 1)} | "
                       f"{f(r.get('resim_path_deg'), 1)} |")
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=Path, default=Path("outputs/realvideo_all"), help="a realvideo_all.py output folder")
    ap.add_argument("--truth", type=Path, default=TRUTH, help="truth fixture (YAML)")
    ap.add_argument("--report", type=Path, default=ROOT / "reports" / "physical_truth", help="report path stem")
    args = ap.parse_args(argv)
    truths = yaml.safe_load(args.truth.read_text())
    rows = []
    for name, truth in truths.items():
        folder = args.runs / name
        if not (folder / "observation.npz").exists():
            rows.append({"clip": name, "note": f"no run in {folder}"})
            continue
        rows.append(measure(folder, truth))
    write_json(args.report.with_suffix(".json"), {"command": f"python benchmarks/physical_truth.py --runs {args.runs}",
                                                 "clips": rows})
    md = markdown(rows, args.runs)
    write_text(args.report.with_suffix(".md"), md)
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
