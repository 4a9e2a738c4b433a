"""Hand labels of the real clips, written as PNG label images (test fixtures).

There is no display to click on, so each label is a *rule* written by a person who looked
at the frame (``--dump`` writes the frames with a pixel ruler, ``--overlay`` the result):
``tests/fixtures/realvideo/labels.yaml`` lists, per clip, the source frame indices and, per
object and frame, one of

* ``circle: [cx, cy, r]``: a disc read off the frame (round objects);
* ``polygon: [[x, y], ...]``: a filled polygon;
* ``hsv: {roi: [x0, y0, x1, y1], lo: [h, s, v], hi: [h, s, v], open: k, close: k}``: pixels
  of the box whose OpenCV HSV (H 0-179, S and V 0-255) lies in ``[lo, hi]``, cleaned by a
  morphological opening then closing (elliptical, side ``k`` px), holes filled, largest
  8-connected component kept; ``clip: [cx, cy, r]`` optionally limits it to a disc and
  ``hull: true`` replaces the mask by its convex hull (convex objects with dark marks).

All coordinates are in px of the ORIGINAL frame; a per-object ``default`` rule is merged
under each frame's rule (so a frame only needs its ``roi`` or ``circle``). Labels are
rasterised at the clip's ``label_size`` (``[width, height]``; the original size unless
given), uint8: 0 background, 1..n the objects in the order of ``objects``. An object
missing from a frame's rules is absent there (an all-background label is allowed).

Two specs: ``labels.yaml`` (the six clips of ``<real data root>/video``, the default) and
``labels_dev.yaml`` (the 13 development clips ``dev01`` ... ``dev13``; its top-level
``video_dir: dev`` names their folder under the real-data root, ``$DYNAMICS_REAL_DATA`` or
``shared/data/real``). PNGs go to ``tests/fixtures/realvideo/<clip>/<frame:04d>.png``.

Usage::

    python scripts/label_masks.py                     # (re)write the six clips' fixtures
    python scripts/label_masks.py --spec tests/fixtures/realvideo/labels_dev.yaml  # dev clips
    python scripts/label_masks.py --dev --clip dev05 --overlay /tmp/overlays  # --dev: that spec
    python scripts/label_masks.py --clip 05 --overlay /tmp/overlays
    python scripts/label_masks.py --clip 05 --dump /tmp/frames --frames 100,200
    python scripts/label_masks.py --clip 07 --propose 300 --roi 0,100,120,240 --radius 10,30
"""

from __future__ import annotations

import argparse
import copy
import os
import sys
from pathlib import Path

import cv2
import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from pipeline.atomic import atomic_path  # noqa: E402

FIXTURES = ROOT / "tests" / "fixtures" / "realvideo"
SPEC = FIXTURES / "labels.yaml"
DEV_SPEC = FIXTURES / "labels_dev.yaml"


def write_png(path: Path, img: np.ndarray, flags: list[int] | None = None) -> None:
    """Write a BGR or label image as PNG, atomically (``cv2.imwrite`` on a temporary sibling).

    Raises:
        OSError: OpenCV could not encode or write it.
    """
    with atomic_path(path, suffix=".png") as tmp:
        if not cv2.imwrite(str(tmp), img, flags or []):
            raise OSError(f"{path}: cannot write PNG")


def real_data_root() -> Path:
    """Root of the real data: ``$DYNAMICS_REAL_DATA`` or ``shared/data/real`` next to (or
    inside) the repository."""
    for p in [Path(os.environ.get("DYNAMICS_REAL_DATA", "/nonexistent")),
              ROOT / "shared/data/real", ROOT.parent / "shared/data/real"]:
        if p.is_dir():
            return p
    return ROOT.parent / "shared/data/real"


def real_video_dir(sub: str = "video") -> Path:
    """Folder of the real clips: ``<real data root>/video`` (or ``/<sub>``, e.g. ``dev``)."""
    return real_data_root() / sub


def load_spec(path: Path = SPEC) -> dict:
    """The labelling spec: ``{clip: {file, fps, objects, frames: {index: {obj: rule}}, ...}}``."""
    return yaml.safe_load(path.read_text())["clips"]


def spec_video_dir(path: Path = SPEC) -> Path:
    """Folder of a spec's clips: its top-level ``video_dir`` (relative to the real-data root;
    ``video`` when absent)."""
    return real_video_dir(yaml.safe_load(path.read_text()).get("video_dir", "video"))


def read_frames(path: Path, indices: list[int]) -> dict[int, np.ndarray]:
    """Source frames ``indices`` of a video, decoded in order (exact), as BGR uint8."""
    want, out = set(indices), {}
    cap = cv2.VideoCapture(str(path))
    try:
        i = 0
        while len(out) < len(want):
            ok, bgr = cap.read()
            if not ok:
                break
            if i in want:
                out[i] = bgr
            i += 1
    finally:
        cap.release()
    missing = sorted(want - set(out))
    if missing:
        raise ValueError(f"{path}: frames {missing} past the end")
    return out


def _merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def _fill_holes(m: np.ndarray) -> np.ndarray:
    contours, _ = cv2.findContours(m.astype(np.uint8), cv2.RETR_EXTERNAL,
                                   cv2.CHAIN_APPROX_NONE)
    out = np.zeros(m.shape, np.uint8)
    cv2.drawContours(out, contours, -1, 1, thickness=cv2.FILLED)
    return out.astype(bool)


def rule_mask(bgr: np.ndarray, rule: dict) -> np.ndarray:
    """``(H, W)`` bool mask of one object in an original-size BGR frame under ``rule``."""
    h, w = bgr.shape[:2]
    m = np.zeros((h, w), np.uint8)
    if "circle" in rule:
        cx, cy, r = rule["circle"]
        cv2.circle(m, (round(cx * 16), round(cy * 16)), round(r * 16), 1, cv2.FILLED,
                   lineType=cv2.LINE_8, shift=4)
    elif "polygon" in rule:
        pts = np.round(np.asarray(rule["polygon"], float) * 16).astype(np.int32)
        cv2.fillPoly(m, [pts], 1, lineType=cv2.LINE_8, shift=4)
    elif "hsv" in rule:
        r = rule["hsv"]
        x0, y0, x1, y1 = r.get("roi", [0, 0, w, h])
        hsv = cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV)
        inside = cv2.inRange(hsv, np.array(r["lo"], np.uint8), np.array(r["hi"], np.uint8)) > 0
        box = np.zeros((h, w), bool)
        box[max(0, y0):y1, max(0, x0):x1] = True
        m = (inside & box).astype(np.uint8)
        if "clip" in r:
            disc = np.zeros((h, w), np.uint8)
            cx, cy, rad = r["clip"]
            cv2.circle(disc, (round(cx), round(cy)), round(rad), 1, cv2.FILLED)
            m &= disc
        for op, key in ((cv2.MORPH_OPEN, "open"), (cv2.MORPH_CLOSE, "close")):
            k = int(r.get(key, 0))
            if k > 1:
                m = cv2.morphologyEx(m, op, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
        n, lab, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
        if n > 1:
            m = (lab == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))).astype(np.uint8)
        m = _fill_holes(m).astype(np.uint8)
        if r.get("hull") and m.any():
            hull = cv2.convexHull(cv2.findNonZero(m))
            cv2.fillPoly(m, [hull], 1)
    else:
        raise ValueError(f"unknown rule {sorted(rule)}")
    return m.astype(bool)


def label_image(bgr: np.ndarray, rules: list[dict], size: tuple[int, int]) -> np.ndarray:
    """``(height, width)`` uint8 label (0 background, i + 1 object i) at ``size``."""
    h, w = bgr.shape[:2]
    out = np.zeros((h, w), np.uint8)
    for i, rule in enumerate(rules):
        if rule:
            out[rule_mask(bgr, rule) & (out == 0)] = i + 1
    if (w, h) != tuple(size):
        out = cv2.resize(out, tuple(size), interpolation=cv2.INTER_NEAREST)
    return out


COLOURS = [(0, 0, 255), (255, 128, 0), (0, 255, 255), (255, 0, 255)]


def overlay(bgr: np.ndarray, label: np.ndarray) -> np.ndarray:
    """Frame (at the label's size) with each object's outline drawn in its colour."""
    img = cv2.resize(bgr, label.shape[::-1], interpolation=cv2.INTER_AREA).copy()
    for i in range(1, int(label.max()) + 1):
        contours, _ = cv2.findContours((label == i).astype(np.uint8), cv2.RETR_EXTERNAL,
                                       cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(img, contours, -1, COLOURS[(i - 1) % len(COLOURS)], 1)
    return img


def clip_rules(spec: dict, index: int) -> list[dict]:
    """Merged rule per object for one labelled frame (``{}`` where the object is absent)."""
    frame = spec["frames"][index] or {}
    rules = []
    for name in spec["objects"]:
        if name not in frame or frame[name] is None:
            rules.append({})
        else:
            rules.append(_merge(spec.get("default", {}).get(name, {}), frame[name]))
    return rules


def write_clip(clip: str, spec: dict, video_dir: Path, out_dir: Path,
               overlay_dir: Path | None = None) -> list[Path]:
    """Write ``out_dir/<clip>/<frame>.png`` for every labelled frame of one clip."""
    path = video_dir / spec["file"]
    indices = sorted(int(i) for i in spec["frames"])
    frames = read_frames(path, indices)
    written = []
    (out_dir / clip).mkdir(parents=True, exist_ok=True)
    for i in indices:
        bgr = frames[i]
        size = tuple(spec.get("label_size", (bgr.shape[1], bgr.shape[0])))
        label = label_image(bgr, clip_rules(spec, i), size)
        target = out_dir / clip / f"{i:04d}.png"
        write_png(target, label, [cv2.IMWRITE_PNG_COMPRESSION, 9])
        written.append(target)
        if overlay_dir is not None:
            overlay_dir.mkdir(parents=True, exist_ok=True)
            big = overlay(bgr, label)
            if big.shape[1] < 640:
                big = cv2.resize(big, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
            write_png(overlay_dir / f"{clip}_{i:04d}.png", big)
    return written


def dump(clip: str, spec: dict, video_dir: Path, out: Path, indices: list[int]) -> None:
    """Frames with a pixel ruler every 10 px (long tick every 50), to read rules off."""
    out.mkdir(parents=True, exist_ok=True)
    for i, bgr in read_frames(video_dir / spec["file"], indices).items():
        img = bgr.copy()
        h, w = img.shape[:2]
        step = 10 if w <= 800 else 50
        for x in range(0, w, step):
            cv2.line(img, (x, 0), (x, 8 if x % (5 * step) else 16), (0, 0, 255), 1)
        for y in range(0, h, step):
            cv2.line(img, (0, y), (8 if y % (5 * step) else 16, y), (0, 0, 255), 1)
        write_png(out / f"{clip}_{i:04d}.png", img)


def propose(clip: str, spec: dict, video_dir: Path, index: int, roi: list[int],
            radius: list[int]) -> None:
    """Print Hough circle candidates ``cx cy r`` (original px) inside ``roi``."""
    bgr = read_frames(video_dir / spec["file"], [index])[index]
    x0, y0, x1, y1 = roi
    gray = cv2.GaussianBlur(cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)[y0:y1, x0:x1], (5, 5), 1.2)
    found = cv2.HoughCircles(gray, cv2.HOUGH_GRADIENT, dp=1, minDist=radius[0],
                             param1=80, param2=12, minRadius=radius[0], maxRadius=radius[1])
    for cx, cy, r in ([] if found is None else found[0][:5]):
        print(f"circle: [{cx + x0:.1f}, {cy + y0:.1f}, {r:.1f}]")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spec", type=Path, default=SPEC, help="labelling spec (default labels.yaml)")
    ap.add_argument("--dev", action="store_true", help=f"use the dev spec {DEV_SPEC.name}")
    ap.add_argument("--clip", action="append", help="clip key(s), e.g. 05 (default: all)")
    ap.add_argument("--out", type=Path, default=FIXTURES)
    ap.add_argument("--overlay", type=Path, help="also write outline overlays here")
    ap.add_argument("--dump", type=Path, help="only dump frames with a ruler here")
    ap.add_argument("--frames", help="comma-separated frames for --dump")
    ap.add_argument("--propose", type=int, help="frame: print circle candidates")
    ap.add_argument("--roi", default=None, help="x0,y0,x1,y1 for --propose")
    ap.add_argument("--radius", default="5,40", help="rmin,rmax for --propose")
    args = ap.parse_args(argv)
    spec_path = DEV_SPEC if args.dev else args.spec
    specs = load_spec(spec_path)
    video_dir = spec_video_dir(spec_path)
    for clip in args.clip or sorted(specs):
        spec = specs[clip]
        if args.dump:
            idx = [int(i) for i in args.frames.split(",")] if args.frames else \
                sorted(int(i) for i in spec["frames"])
            dump(clip, spec, video_dir, args.dump, idx)
        elif args.propose is not None:
            propose(clip, spec, video_dir, args.propose,
                    [int(v) for v in args.roi.split(",")] if args.roi else [0, 0, 10 ** 5, 10 ** 5],
                    [int(v) for v in args.radius.split(",")])
        else:
            for p in write_clip(clip, spec, video_dir, args.out, args.overlay):
                print(p.relative_to(ROOT) if p.is_relative_to(ROOT) else p)


if __name__ == "__main__":
    main()
