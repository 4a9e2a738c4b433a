"""A Tracker-style 2-D export (``t``, ``x``, ``y`` in m, y up) of the object a ``dynamics infer``
run observed in a real video, scaled by a length read on the video (a ruler): real measured
trajectories of our own making for ``dynamics discrepancy``.

    python scripts/tracker_export.py outputs/realvideo_all/dev02_pingpong_drop --m-per-px 4.719e-4 \\
        --out reports/discrepancy_real_video/dev02_pingpong_drop.txt

The track is :func:`pipeline.image_measure.image_track` of the observation (the centroid in the
original frame's pixels, frames where the object is seen whole), times ``--m-per-px``, with the
image row turned into height (``y = -row * m_per_px``; the origin is arbitrary, as in Tracker).
The scale must come from the video (e.g. ``tests/fixtures/realvideo/physical_truth.yaml``),
never from the re-simulated scene.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from pipeline.atomic import write_text  # noqa: E402
from pipeline.image_measure import image_track, moving_label  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("infer_dir", type=Path, help="output folder of `dynamics infer` (observation.npz)")
    ap.add_argument("--m-per-px", type=float, required=True, help="metres per pixel of the original frame")
    ap.add_argument("--out", type=Path, required=True, help="the export (tab-separated t, x, y)")
    args = ap.parse_args(argv)
    if not args.m_per_px > 0:
        raise SystemExit(f"--m-per-px: must be > 0, got {args.m_per_px}")
    path = args.infer_dir / "observation.npz"
    if not path.is_file():
        raise SystemExit(f"{path}: no such file (run `dynamics infer VIDEO --out {args.infer_dir}` first)")
    obs = np.load(path)
    seg = obs["seg"]
    t, col, row = image_track(seg, obs["crop"], obs["size"], obs["source_frames"], float(obs["source_fps"]),
                              label=moving_label(seg), times=obs["times"] if "times" in obs else None)
    x, y = col * args.m_per_px, -row * args.m_per_px
    text = "t\tx\ty\n" + "".join(f"{a:.6f}\t{b:.6f}\t{c:.6f}\n" for a, b, c in zip(t, x, y))
    write_text(args.out, text)
    print(f"{len(t)} samples over {t[-1] - t[0]:.3f} s -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
