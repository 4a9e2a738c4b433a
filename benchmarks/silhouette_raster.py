"""From what size a silhouette's outline tells a ball from a box: ideal rasterisations, no clip.

The shape test of perception (:func:`pipeline.image_tracks.round_silhouette`) calls a silhouette
round where its least-squares ellipse covers it at IoU >= :data:`pipeline.image_tracks.ELLIPSE_FIT`
(:func:`pipeline.image_tracks.silhouette_fit`). On a silhouette a few pixels across, rasterisation
alone moves that IoU by more than the gap between the classes. This benchmark measures by how much,
on ideal silhouettes that share nothing with any clip or generator: a disc (a sphere's outline) and
a near-square rectangle (a box's; aspect 0.8-1.0), each at a random angle and sub-pixel offset,
drawn at ``--supersample`` x resolution and thresholded at half coverage (the pixel is the object's
where the object covers half of it). The size of each silhouette is measured by the
function that gives :attr:`pipeline.image_tracks.Track.diameter` (``_box_stats``: the short side of
the rotated bounding box of the pixels, in pixel extents).

Per 1-px bin of that size: the discs' 5th percentile of ellipse IoU, the boxes' 95th, and the
error of the test both ways (a disc called not round, a box called round). The smallest size from
which every bin up to the largest errs on at most ``--max-error`` of each class is
:data:`pipeline.image_tracks.SMALL_SILHOUETTE`: real silhouettes add blur and segmentation error
to rasterisation, so an outline smaller than that does not tell even in the ideal case.

Writes ``REPORT.json`` and ``REPORT.md`` (default ``reports/silhouette_raster``)::

    python benchmarks/silhouette_raster.py
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for p in (ROOT, ROOT / "benchmarks"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

from provenance import tree_id  # noqa: E402
from pipeline.atomic import write_json, write_text  # noqa: E402
from pipeline.image_tracks import ELLIPSE_FIT, SMALL_SILHOUETTE, _box_stats, silhouette_fit  # noqa: E402


def raster(kind: str, size: float, rng: np.random.Generator, supersample: int = 8) -> np.ndarray:
    """An ideal silhouette: ``(n, n)`` bool, a disc of diameter ``size`` px (``kind`` ``disc``) or a
    rectangle ``size`` x ``size * U(0.8, 1)`` px (``box``), at a random angle and sub-pixel offset,
    each pixel set where the shape covers at least half of it."""
    n, s = int(2 * size + 12), supersample
    yy, xx = np.mgrid[0:n * s, 0:n * s] / s
    cx, cy = n / 2 + rng.uniform(-0.5, 0.5), n / 2 + rng.uniform(-0.5, 0.5)
    a = rng.uniform(0.0, np.pi)
    x = (xx - cx) * np.cos(a) + (yy - cy) * np.sin(a)
    y = -(xx - cx) * np.sin(a) + (yy - cy) * np.cos(a)
    if kind == "disc":
        inside = x ** 2 + y ** 2 <= (size / 2) ** 2
    else:
        inside = (np.abs(x) <= size / 2) & (np.abs(y) <= size / 2 * rng.uniform(0.8, 1.0))
    return inside.reshape(n, s, n, s).mean(axis=(1, 3)) >= 0.5


def measure(sizes: np.ndarray, per_size: int, seed: int, supersample: int) -> list[dict]:
    """One row per silhouette: ``kind``, drawn ``size``, measured ``short_side``, ``ellipse`` IoU."""
    rng = np.random.default_rng(seed)
    rows = []
    for kind in ("disc", "box"):
        for size in sizes:
            for _ in range(per_size):
                m = raster(kind, float(size), rng, supersample)
                fit = silhouette_fit(m)
                if fit is not None:
                    rows.append({"kind": kind, "size": float(size), "short_side": _box_stats(m)[1], "ellipse": fit[0]})
    return rows


def by_bin(rows: list[dict], lo: int, hi: int) -> list[dict]:
    """Per 1-px bin of the measured short side in ``[lo, hi)``: counts, the discs' 5th and boxes'
    95th percentile of ellipse IoU, and the errors of the test at :data:`ELLIPSE_FIT`."""
    out = []
    for b in range(lo, hi):
        e = {k: np.array([r["ellipse"] for r in rows if r["kind"] == k and b <= r["short_side"] < b + 1])
             for k in ("disc", "box")}
        if not len(e["disc"]) or not len(e["box"]):
            continue
        out.append({"short_side_px": [b, b + 1], "discs": int(len(e["disc"])), "boxes": int(len(e["box"])),
                    "disc_ellipse_p5": round(float(np.percentile(e["disc"], 5)), 3),
                    "box_ellipse_p95": round(float(np.percentile(e["box"], 95)), 3),
                    "disc_not_round": round(float(np.mean(e["disc"] < ELLIPSE_FIT)), 3),
                    "box_round": round(float(np.mean(e["box"] >= ELLIPSE_FIT)), 3)})
    return out


def smallest_reliable(bins: list[dict], max_error: float) -> int | None:
    """Lower edge (px) of the first bin from which every bin errs on at most ``max_error`` of each
    class; None if the largest bin already errs more."""
    size = None
    for b in reversed(bins):
        if b["disc_not_round"] > max_error or b["box_round"] > max_error:
            break
        size = b["short_side_px"][0]
    return size


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--per-size", type=int, default=60, help="silhouettes per drawn size and class")
    ap.add_argument("--max-error", type=float, default=0.01, help="error of each class a reliable size allows")
    ap.add_argument("--supersample", type=int, default=8, help="sub-pixels per pixel side")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--report", type=Path, default=ROOT / "reports" / "silhouette_raster")
    args = ap.parse_args(argv)
    rows = measure(np.linspace(3.0, 16.0, 53), args.per_size, args.seed, args.supersample)
    bins = by_bin(rows, 3, 17)
    reliable = smallest_reliable(bins, args.max_error)
    report = {"command": "python benchmarks/silhouette_raster.py " + " ".join(argv if argv is not None else sys.argv[1:]),
              "commit": tree_id(), "ellipse_fit": ELLIPSE_FIT, "max_error": args.max_error,
              "smallest_reliable_px": reliable, "small_silhouette_px": SMALL_SILHOUETTE, "bins": bins}
    lines = ["# From what size the outline tells a ball from a box (ideal rasterisations)", "",
             f"Command: `{report['command']}` (tree `{report['commit']}`). Discs and near-square rectangles at random "
             f"angles and sub-pixel offsets, thresholded at half coverage; size = short side of the rotated bounding "
             f"box; the test calls a silhouette round at ellipse IoU >= {ELLIPSE_FIT}.", "",
             "| short side (px) | discs | boxes | disc ellipse IoU p5 | box ellipse IoU p95 | discs called not round "
             "| boxes called round |", "|---|---|---|---|---|---|---|"]
    lines += [f"| {b['short_side_px'][0]}-{b['short_side_px'][1]} | {b['discs']} | {b['boxes']} | {b['disc_ellipse_p5']} "
              f"| {b['box_ellipse_p95']} | {b['disc_not_round']} | {b['box_round']} |" for b in bins]
    lines += ["", f"Smallest size from which every bin errs on at most {args.max_error:.0%} of each class: "
              f"**{reliable} px** (`pipeline.image_tracks.SMALL_SILHOUETTE` = {SMALL_SILHOUETTE} px)."]
    write_json(args.report.with_suffix(".json"), report, indent=1)
    text = "\n".join(lines) + "\n"
    write_text(args.report.with_suffix(".md"), text)
    print(text)
    return 0 if reliable == SMALL_SILHOUETTE else 1


if __name__ == "__main__":
    sys.exit(main())
