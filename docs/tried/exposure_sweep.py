"""A lead, not a feature: how much a simulated exposure could give the re-simulation's masks.

A camera integrates over its exposure, so a fast ball's silhouette is the region it sweeps (motion blur), while
``dynamics infer`` renders the simulated ball at one instant per frame. This script sweeps each written scene's
re-simulated masks (``masks.npz`` of a ``scripts/realvideo_all.py`` run) along the mask centroid's velocity over a
fraction ``e`` of a frame interval (9 shifted copies, nearest pixel), without refitting anything, and prints the strict
IoU (:func:`pipeline.metrics.sequence_iou`, objects matched) against the observation (``observation.npz``, every
object it holds, at rest too) for e = 0, 0.5 and 1.

Usage: ``python docs/tried/exposure_sweep.py outputs/realvideo_all [clip ...]``
"""
import sys
from pathlib import Path

import numpy as np
from scipy import ndimage

from pipeline.metrics import sequence_iou


def swept(sim: np.ndarray, k: int, e: float) -> np.ndarray:
    """``(T, H, W)`` bool: object ``k`` of ``sim`` (``(T, H, W)`` int8 ids) swept over ``e`` frame intervals."""
    T = len(sim)
    cs = [ndimage.center_of_mass(sim[t] == k) if (sim[t] == k).any() else None for t in range(T)]
    out = np.zeros(sim.shape, bool)
    for t in range(T):
        m = sim[t] == k
        if not m.any():
            continue
        a = cs[t - 1] if t > 0 else None
        b = cs[t + 1] if t + 1 < T else None
        if a is not None and b is not None:
            v = np.subtract(b, a) / 2
        elif b is not None:
            v = np.subtract(b, cs[t])
        elif a is not None:
            v = np.subtract(cs[t], a)
        else:
            v = np.zeros(2)
        acc = m.copy()
        for s in np.linspace(-e / 2, e / 2, 9) if e > 0 else []:
            acc |= ndimage.shift(m.astype(float), s * v, order=0) > 0.5
        out[t] = acc
    return out


def swept_labels(sim: np.ndarray, e: float) -> np.ndarray:
    """``(T, H, W)`` int8 ids, -1 background: every object of ``sim`` swept over ``e`` frame intervals."""
    out = np.full(sim.shape, -1, np.int8)
    for k in range(int(sim.max()) + 1):
        out[swept(sim, k, e) & (out < 0)] = k
    return out


def main() -> None:
    root = Path(sys.argv[1])
    clips = sys.argv[2:] or sorted(p.name for p in root.iterdir() if (p / "masks.npz").exists())
    print("clip".ljust(30), "e=0    e=0.5  e=1")
    for c in clips:
        obs = np.load(root / c / "observation.npz")["seg"]
        sim = np.load(root / c / "masks.npz")["seg"]
        row = [sequence_iou(obs, swept_labels(sim, e))["strict_iou"] for e in (0.0, 0.5, 1.0)]
        print(c.ljust(30), " ".join(f"{x:.3f}" for x in row))


if __name__ == "__main__":
    main()
