"""Optical flow benchmark (issue 33): OpenCV DIS, Farneback and RAFT against ground truth,
photometric error on real clips, and time per frame pair on 2 cores.

1. **Synthetic test split** (the render stage's ``test`` clips, 96x64, the simulator's exact
   flow): end-point error over all pixels and over object pixels of frame t (foreground).
2. **PyBullet cross-engine clips** (``data/truthsets/pybullet/{dev,heldout}``, 320x240, another
   engine and renderer, never trained on): EPE against the analytic flow of the true poses
   (:func:`pipeline.truthsets.flow.truth_flow`), valid pixels only.
3. **Real clips** (the 19 of ``../shared/data/real``; no true flow): the photometric warping error
   ``|I_t(x) - I_{t+1}(x + f(x))|`` (grey levels, 0-255) over the pixels where the frames differ
   by more than 10 grey levels (where zero flow is wrong), at 30 frames per true second in the
   main job's window (:func:`pipeline.observe.choose_window`), 160 px wide; and the per-pixel
   minimum of it and the backward error (:func:`min_reprojection_error`), which does not punish
   the true flow where an object moves onto the background. Both are checked against the true
   flow on the PyBullet clips. Zero flow is listed as the floor to beat.
4. **Time** per pair on a 16-frame clip at 96x64 and 160x120 (wall clock, this machine, best of
   3 runs; RAFT encodes each frame once and refines 8 pairs per batch).

Usage::

    MUJOCO_GL=egl python benchmarks/flow_epe.py                 # writes reports/flow_epe.{md,json}
    MUJOCO_GL=egl python benchmarks/flow_epe.py --raft-weights raft-things=/path/raft-things.pth
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import torch
from tqdm import tqdm

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from provenance import tree_id  # noqa: E402
from pipeline.atomic import write_bytes, write_json, write_text  # noqa: E402
from pipeline.flow import estimate_flow, flow_to_rgb  # noqa: E402
from pipeline.observe import choose_window  # noqa: E402
from pipeline.raft.estimator import DEFAULT_WEIGHTS, RaftFlow  # noqa: E402
from pipeline.raft.train import epe, load_split  # noqa: E402
from pipeline.video import VideoError, read_video, resample  # noqa: E402

REAL = ROOT.parent / "shared" / "data" / "real"
PHOTO_THRESHOLD = 10
"""Grey levels: pixels whose frames differ by more are where flow matters (zero flow fails)."""


def estimators(raft_weights: dict[str, Path]) -> dict:
    """Name -> ``frames (T, H, W, 3) uint8 -> flow (T-1, H, W, 2)``."""
    out = {"DIS (medium)": lambda f: estimate_flow(f, "dis", "medium"),
           "Farneback": lambda f: estimate_flow(f, "farneback")}
    for name, path in raft_weights.items():
        out[name] = RaftFlow.from_file(path)
    return out


def synthetic(methods: dict, test: tuple[np.ndarray, np.ndarray, np.ndarray]) -> dict:
    """EPE (px) on the test split ``(rgb, flow, seg)`` (:func:`load_split`): all pixels, foreground."""
    rgb, flow, seg = test
    fg = seg[:, :-1] >= 0
    rows = {}
    for name, fn in methods.items():
        pred = np.stack([fn(c) for c in tqdm(rgb, desc=f"synthetic {name}", leave=False)])
        rows[name] = {"epe_all": epe(pred, flow), "epe_fg": epe(pred, flow, fg)}
    rows["zero flow"] = {"epe_all": epe(np.zeros_like(flow, np.float32), flow),
                         "epe_fg": epe(np.zeros_like(flow, np.float32), flow, fg)}
    return {"clips": int(len(rgb)), "pairs": int(flow.shape[0] * flow.shape[1]), "size": [rgb.shape[3], rgb.shape[2]],
            "rows": rows}


def pybullet(methods: dict, root: Path, stride: int) -> dict:
    """EPE (px) on the PyBullet truth-set clips (every ``stride``-th pair), and the photometric
    errors of the real-clip section on the same frames, for each method and for the true flow:
    a warping error that scores the truth worse than a method does not measure flow."""
    from pipeline.truthsets.flow import truth_flow
    folders = sorted(p for s in ("dev", "heldout") for p in (root / s).glob("clip-*") if (p / "truth.npz").is_file())
    if not folders:
        return {"clips": 0, "note": f"no clips under {root} (python -m pipeline.truthsets generate --engine pybullet)"}
    errs = {name: {"all": [], "fg": []} for name in [*methods, "zero flow"]}
    photo = {name: np.zeros(4) for name in ["true flow", *methods, "zero flow"]}   # sum fwd, n fwd, sum min, n min
    for folder in tqdm(folders, desc="pybullet clips", leave=False):
        frames = read_video(folder / "video.mp4").frames
        gt, valid = truth_flow(folder)
        gt_back, _ = truth_flow(folder, backward=True)
        seg = np.load(folder / "truth.npz")["seg"]
        idx = np.arange(0, len(gt), stride)
        zero = np.zeros_like(gt[0])
        for name, fn in [*methods.items(), ("true flow", None), ("zero flow", None)]:
            if fn is not None:
                pred = np.concatenate([fn(frames[t:t + 2]) for t in idx])
                _accumulate(errs[name], pred, gt[idx], valid[idx], seg[idx] >= 0)
            for i, t in enumerate(idx):
                if t < 1:
                    continue
                if name == "true flow":
                    fwd, bwd = gt[t], gt_back[t - 1]
                elif name == "zero flow":
                    fwd, bwd = zero, zero
                else:
                    fwd, bwd = pred[i], fn(frames[[t, t - 1]])[0]
                e, n = photometric_error(frames[t:t + 2], fwd[None])
                em, nm = min_reprojection_error(frames[t - 1:t + 2], np.stack([zero, fwd]), np.stack([bwd, zero]))
                photo[name] += [e * n if n else 0.0, n, em * nm if nm else 0.0, nm]
        _accumulate(errs["zero flow"], np.zeros_like(gt[idx]), gt[idx], valid[idx], seg[idx] >= 0)
    return {"clips": len(folders), "pair_stride": stride, "size": [int(frames.shape[2]), int(frames.shape[1])],
            "rows": {n: {"epe_all": float(np.mean(e["all"])), "epe_fg": float(np.nanmean(e["fg"]))}
                     for n, e in errs.items()},
            "photometric": {n: {"forward": float(p[0] / max(p[1], 1)), "min_reprojection": float(p[2] / max(p[3], 1))}
                            for n, p in photo.items()}}


def _accumulate(acc: dict, pred: np.ndarray, gt: np.ndarray, valid: np.ndarray, fg: np.ndarray) -> None:
    acc["all"].append(epe(pred, gt, valid))
    acc["fg"].append(epe(pred, gt, valid & fg))


def photometric_error(frames: np.ndarray, flow: np.ndarray) -> tuple[float, int]:
    """Mean ``|I_t(x) - I_{t+1}(x + f(x))|`` (grey, 0-255) over pixels that differ by more than
    :data:`PHOTO_THRESHOLD` between t and t+1 and whose target lies in the frame; and their count."""
    grey = _grey(frames)
    total, count = 0.0, 0
    for t in range(len(flow)):
        err, inside = _warp_error(grey[t], grey[t + 1], flow[t])
        m = (np.abs(grey[t] - grey[t + 1]) > PHOTO_THRESHOLD) & inside
        total += float(err[m].sum())
        count += int(m.sum())
    return (total / count if count else float("nan")), count


def min_reprojection_error(frames: np.ndarray, flow: np.ndarray, back: np.ndarray) -> tuple[float, int]:
    """The per-pixel minimum of the forward and the backward warping error (grey, 0-255), for the
    frames t = 1..T-2 that have both neighbours: ``min(|I_t(x) - I_{t+1}(x + f(x))|,
    |I_t(x) - I_{t-1}(x + b(x))|)`` over the pixels that differ by more than
    :data:`PHOTO_THRESHOLD` from *both* neighbours, and their count.

    The forward error alone punishes a *correct* flow where an object moves onto the background:
    there the background's true flow is 0, but frame t+1 shows the object, so the error is large,
    and a flow smeared over the object's surroundings scores better than the truth. Such a pixel
    is usually visible in frame t-1, so the minimum over both directions removes that penalty
    (the per-pixel minimum reprojection loss of Godard et al., "Digging Into Self-Supervised
    Monocular Depth Estimation", ICCV 2019, sec. 3.3). Counting only pixels that change both ways
    keeps zero flow from scoring there by that same minimum (a pixel one neighbour explains
    unwarped), as Godard et al.'s auto-masking of pixels the identity explains. The PyBullet
    section of the report checks it against the true flow.

    Args:
        frames: ``(T, H, W, 3)`` uint8.
        flow: ``(T-1, H, W, 2)`` px, pair t forward from frame t to t+1.
        back: ``(T-1, H, W, 2)`` px, pair t backward from frame t+1 to t (a method's flow of the
            clip played backwards, reversed: :func:`backward_flow`).
    """
    grey = _grey(frames)
    total, count = 0.0, 0
    for t in range(1, len(flow)):
        fwd, inside = _warp_error(grey[t], grey[t + 1], flow[t])
        bwd, inside_back = _warp_error(grey[t], grey[t - 1], back[t - 1])
        err = np.minimum(np.where(inside, fwd, np.inf), np.where(inside_back, bwd, np.inf))
        m = ((np.abs(grey[t] - grey[t + 1]) > PHOTO_THRESHOLD) & (np.abs(grey[t] - grey[t - 1]) > PHOTO_THRESHOLD)
             & (inside | inside_back))
        total += float(err[m].sum())
        count += int(m.sum())
    return (total / count if count else float("nan")), count


def backward_flow(fn, frames: np.ndarray) -> np.ndarray:
    """``(T-1, H, W, 2)``: pair t's flow from frame t+1 back to frame t, by ``fn`` on the clip
    played backwards."""
    return np.ascontiguousarray(fn(np.ascontiguousarray(frames[::-1]))[::-1])


def _grey(frames: np.ndarray) -> np.ndarray:
    return frames.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)


def _warp_error(grey_t: np.ndarray, grey_other: np.ndarray, flow: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``|I_t(x) - I_other(x + f(x))|`` (bilinear) and where ``x + f(x)`` lies in the frame."""
    H, W = grey_t.shape
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    mx, my = xx + flow[..., 0], yy + flow[..., 1]
    warped = cv2.remap(grey_other, mx.astype(np.float32), my.astype(np.float32), cv2.INTER_LINEAR)
    return np.abs(grey_t - warped), (mx >= 0) & (mx <= W - 1) & (my >= 0) & (my <= H - 1)


def real(methods: dict) -> dict:
    """Photometric errors per real clip (forward warping, :func:`photometric_error`, and the
    per-pixel minimum over both directions, :func:`min_reprojection_error`) and their means."""
    sys.path.insert(0, str(ROOT / "scripts"))
    from realvideo_all import CLIPS
    per_clip, per_clip_min, skipped, names = {}, {}, {}, [*methods, "zero flow"]
    for clip, rel, fps in tqdm(CLIPS, desc="real clips", leave=False):
        path = REAL / rel
        if not path.is_file():
            continue
        try:
            start, length = choose_window(path, fps, 30, 1.0)
        except VideoError as e:   # the main job refuses it too (dev/01: 0.2 s, 6 frames at 30 fps)
            skipped[clip] = str(e).split(": ", 1)[-1]
            continue
        probe = read_video(path, fps=fps, max_frames=1)
        W0, H0 = probe.original_size
        c = read_video(path, fps=fps, start=start, duration=length + 1 / 30, size=(160, max(2, round(160 * H0 / W0 / 2) * 2)))
        frames = resample(c.frames, c.fps, 30, length)
        per_clip[clip], per_clip_min[clip] = {}, {}
        zero = np.zeros((len(frames) - 1, *frames.shape[1:3], 2), np.float32)
        for name in names:
            flow = zero if name == "zero flow" else methods[name](frames)
            back = zero if name == "zero flow" else backward_flow(methods[name], frames)
            per_clip[clip][name] = photometric_error(frames, flow)[0]
            per_clip_min[clip][name] = min_reprojection_error(frames, flow, back)[0]
    out = {"clips": len(per_clip), "skipped": skipped}
    for key, table in (("", per_clip), ("_min", per_clip_min)):
        out["mean" + key] = {n: float(np.nanmean([table[c][n] for c in table])) for n in names}
        out["best_on" + key] = {n: int(sum(table[c][n] <= min(table[c][m] for m in names if m != "zero flow") + 1e-9
                                           for c in table)) for n in names if n != "zero flow"}
        out["per_clip" + key] = table
    return out


def timing(methods: dict, rgb: np.ndarray) -> dict:
    """ms per pair at 96x64 and 160x120 (16 frames of the first test clip ``rgb[0]``, best of 3)."""
    clip = rgb[0, :16]
    out = {}
    for W, H in ((96, 64), (160, 120)):
        frames = np.stack([cv2.resize(f, (W, H), interpolation=cv2.INTER_LINEAR) for f in clip])
        for name, fn in methods.items():
            fn(frames[:2])                                   # warm-up (model load, allocations)
            best = min(_seconds(fn, frames) for _ in range(3))
            out.setdefault(name, {})[f"{W}x{H}"] = 1000 * best / (len(frames) - 1)
    return {"threads": torch.get_num_threads(), "ms_per_pair": out}


def _seconds(fn, frames) -> float:
    t = time.perf_counter()
    fn(frames)
    return time.perf_counter() - t


def figure(methods: dict, test: tuple[np.ndarray, np.ndarray, np.ndarray], pybullet_root: Path, out: Path) -> Path:
    """``out`` (PNG): per row a test clip (synthetic, then a PyBullet clip when there is one),
    frame t, then the true flow and each method's, Middlebury colours on one scale per row."""
    rows = []
    rgb, flow, _ = test
    n = int(np.argmax(np.abs(flow[:, 3].astype(np.float32)).sum(axis=(1, 2, 3))))   # the clip moving most
    rows.append(("synthetic test", np.asarray(rgb[n, 3:5]), flow[n, 3].astype(np.float32)))
    folders = sorted((pybullet_root / "heldout").glob("clip-*"))
    if folders:
        from pipeline.truthsets.flow import truth_flow
        frames = read_video(folders[0] / "video.mp4").frames
        gt, _ = truth_flow(folders[0])
        t = int(np.argmax(np.abs(gt).sum(axis=(1, 2, 3))))
        rows.append(("PyBullet held-out", frames[t:t + 2], gt[t]))
    panels = []
    for title, pair, gt in rows:
        h, w = 128, round(128 * pair.shape[2] / pair.shape[1])
        scale = max(float(np.abs(gt).max()), 1.0)
        cells = [("frame t", pair[0]), ("truth", flow_to_rgb(gt[None], scale)[0])]
        cells += [(name, flow_to_rgb(fn(pair), scale)[0]) for name, fn in methods.items()]
        row = []
        for label, img in cells:
            img = cv2.resize(np.ascontiguousarray(img), (w, h), interpolation=cv2.INTER_NEAREST)
            img = cv2.copyMakeBorder(img, 18, 2, 2, 2, cv2.BORDER_CONSTANT, value=(255, 255, 255))
            cv2.putText(img, f"{title}: {label}" if label == "frame t" else label, (3, 13), cv2.FONT_HERSHEY_SIMPLEX,
                        0.38, (0, 0, 0), 1, cv2.LINE_AA)
            row.append(img)
        panels.append(np.concatenate(row, axis=1))
    width = max(p.shape[1] for p in panels)
    sheet = np.concatenate([cv2.copyMakeBorder(p, 0, 0, 0, width - p.shape[1], cv2.BORDER_CONSTANT, value=(255, 255, 255))
                            for p in panels])
    write_bytes(out, cv2.imencode(".png", sheet[..., ::-1])[1].tobytes())
    return out


def markdown(res: dict) -> str:
    s, p, r, t = res["synthetic"], res["pybullet"], res["real"], res["timing"]
    names = list(t["ms_per_pair"])
    fmt = lambda d, k: f"{d[k]:.3f}" if k in d else "-"  # noqa: E731
    lines = ["# Optical flow: DIS, Farneback and RAFT", "",
             f"`{res['command']}` on tree `{res['tree']}` ({res['date']}, {t['threads']} torch threads).", "",
             f"RAFT weights: {', '.join(f'{k} = `{v}`' for k, v in res['raft_weights'].items())}.", "",
             "![flow of two test pairs](flow_epe.png)", "",
             "| method | synthetic EPE fg / all (px) | PyBullet EPE fg / all (px) | real min-reprojection error (grey) | "
             "real clips best on | real forward warping error | ms/pair 96x64 | ms/pair 160x120 |",
             "|---|---|---|---|---|---|---|---|"]
    for n in [*names, "zero flow"]:
        sy, pb, tm = s["rows"].get(n, {}), p.get("rows", {}).get(n, {}), t["ms_per_pair"].get(n, {})
        best = f"{r['best_on_min'][n]} of {r['clips']}" if n in r["best_on_min"] else "-"
        ms = [f"{tm[k]:.1f}" if k in tm else "-" for k in ("96x64", "160x120")]
        lines.append(f"| {n} | {fmt(sy, 'epe_fg')} / {fmt(sy, 'epe_all')} | {fmt(pb, 'epe_fg')} / {fmt(pb, 'epe_all')} | "
                     f"{r['mean_min'][n]:.2f} | {best} | {r['mean'][n]:.2f} | {ms[0]} | {ms[1]} |")
    lines += ["", f"- Synthetic: the render stage's `test` split, {s['clips']} clips, {s['pairs']} pairs at "
              f"{s['size'][0]}x{s['size'][1]}, simulator flow; foreground = object pixels of frame t.",
              f"- PyBullet: {p.get('clips', 0)} clips (dev + held-out) at {p.get('size', ['?', '?'])[0]}x"
              f"{p.get('size', ['?', '?'])[1]}, one pair in {p.get('pair_stride', '?')}, flow of the true poses "
              "(`pipeline/truthsets/flow.py`), valid pixels only. Never used for training.",
              f"- Real: {r['clips']} clips, 30 frames per true second in the main job's window, 160 px wide, over the "
              f"pixels that change by more than {PHOTO_THRESHOLD} grey levels from frame t to t+1. *Forward warping "
              "error*: `|I_t(x) - I_t+1(x + f(x))|`. *Min-reprojection error*: the per-pixel minimum of that and "
              "`|I_t(x) - I_t-1(x + b(x))|`, b the method's flow of the clip played backwards (Godard et al., ICCV "
              "2019): the forward error alone punishes the true flow wherever an object moves onto the background "
              "(next section). 'best on' counts the clips where a method has the lowest min-reprojection error."
              + "".join(f" Skipped {c}: {why}." for c, why in r.get("skipped", {}).items())]
    if "photometric" in p:
        ph = p["photometric"]
        lines += ["", "## Do the warping errors measure flow? The true flow on the PyBullet clips", "",
                  "The same two errors on the PyBullet frames (those with a frame before and after), for each method "
                  "and for the flow of the true poses. A fair error would rank the truth first.", "",
                  "| flow | forward warping error | min-reprojection error |", "|---|---|---|"]
        for n, row in ph.items():
            lines.append(f"| {n} | {row['forward']:.2f} | {row['min_reprojection']:.2f} |")
        methods_only = [n for n in ph if n not in ("true flow", "zero flow")]
        for key, label in (("forward", "forward warping error"), ("min_reprojection", "min-reprojection error")):
            best = min(methods_only, key=lambda n: ph[n][key])
            if ph["true flow"][key] > ph[best][key]:
                lines.append(f"\nBy the {label} the true flow scores {ph['true flow'][key] / ph[best][key]:.1f} times "
                             f"{best}'s error.")
        lines.append("\nA method that minimises brightness constancy (DIS, Farneback) can score below the true flow, "
                     "which pays for shading that changes as a surface turns and for occlusion edges; the forward error "
                     "also charges the truth for every pixel an object moves onto. So a warping error on real clips "
                     "favours the classical methods over a learned flow by construction: read the real-clip columns "
                     "with this table, and the EPE columns as the measure of flow.")
    lines += ["", "## Real clips: the six shared clips apart from the dev clips", "",
              "The shipped RAFT weights saw frames of the 13 dev clips as chairs-pair textures (their appearance "
              "under synthetic motion, not their own motion; card `pipeline/weights/raft-small-dynamics.md`); the "
              "six shared clips never entered training. Min-reprojection error (forward warping error).", "",
              "| method | shared clips | dev clips |", "|---|---|---|"]
    groups = {g: [c for c in r["per_clip"] if c.startswith("dev") == (g == "dev")] for g in ("shared", "dev")}
    for n in [*names, "zero flow"]:
        cells = [f"{np.nanmean([r['per_clip_min'][c][n] for c in cs]):.2f} ({np.nanmean([r['per_clip'][c][n] for c in cs]):.2f}), "
                 f"{len(cs)} clips" if cs else "-" for cs in groups.values()]
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    lines += ["", "## Real clips per clip: min-reprojection error (forward warping error)", "",
              "| clip | " + " | ".join([*names, "zero flow"]) + " |", "|---" * (len(names) + 2) + "|"]
    for clip, row in r["per_clip"].items():
        lines.append(f"| {clip} | " + " | ".join(f"{r['per_clip_min'][clip][n]:.2f} ({row[n]:.2f})"
                                                for n in [*names, "zero flow"]) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--video", type=Path, default=Path("data/video"), help="render stage shards")
    ap.add_argument("--configs", type=Path, default=Path("data/configs"), help="sample_configs shards")
    ap.add_argument("--pybullet", type=Path, default=Path("data/truthsets/pybullet"), help="PyBullet truth sets")
    ap.add_argument("--raft-weights", action="append", default=[], metavar="NAME=PTH",
                    help="extra RAFT checkpoints to compare (e.g. raft-small=/path/raft-small.pth)")
    ap.add_argument("--pair-stride", type=int, default=3, help="PyBullet: every n-th pair")
    ap.add_argument("--report", type=Path, default=Path("reports/flow_epe"), help="report path stem")
    ap.add_argument("--markdown-only", action="store_true", help="rewrite REPORT.md from REPORT.json (no runs)")
    ap.add_argument("--figure-only", action="store_true", help="only draw REPORT.png (flow of two test pairs)")
    ap.add_argument("--timing-only", action="store_true",
                    help="re-measure only the time per pair (on an idle machine) into REPORT.json and rewrite REPORT.md")
    args = ap.parse_args(argv)
    if args.markdown_only:
        write_text(args.report.with_suffix(".md"), markdown(json.loads(args.report.with_suffix(".json").read_text())))
        return 0
    torch.set_num_threads(2)
    weights = {"RAFT (trained here)": DEFAULT_WEIGHTS}
    for item in args.raft_weights:
        name, _, path = item.partition("=")
        weights[f"RAFT ({name})"] = Path(path)
    methods = estimators(weights)
    test = load_split(args.video, args.configs, "test")
    if args.timing_only:
        res = json.loads(args.report.with_suffix(".json").read_text())
        res["timing"] = timing(methods, test[0])
        res["timing"]["date"] = time.strftime("%Y-%m-%d %H:%M")
        write_json(args.report.with_suffix(".json"), res)
        write_text(args.report.with_suffix(".md"), markdown(res))
        return 0
    figure(methods, test, args.pybullet, args.report.with_suffix(".png"))
    if args.figure_only:
        return 0
    tree = tree_id()
    res = {"command": "MUJOCO_GL=egl python benchmarks/flow_epe.py" + "".join(f" --raft-weights {w}" for w in args.raft_weights),
           "tree": tree, "date": time.strftime("%Y-%m-%d"),
           "raft_weights": {k: str(v.relative_to(ROOT) if v.is_relative_to(ROOT) else v) for k, v in weights.items()}}
    res["timing"] = timing(methods, test[0])
    res["synthetic"] = synthetic(methods, test)
    res["pybullet"] = pybullet(methods, args.pybullet, args.pair_stride)
    res["real"] = real(methods)
    write_json(args.report.with_suffix(".json"), res)
    write_text(args.report.with_suffix(".md"), markdown(res))
    print(markdown(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
