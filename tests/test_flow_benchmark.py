"""``benchmarks/flow_epe.py``: the real-clip warping errors against a clip whose true flow is known.

A textured square slides over a textured, static background. The forward warping error punishes
the true flow on the background the square moves onto (frame t+1 shows the square there, the true
flow is 0), and prefers a flow smeared over the square's surroundings; the per-pixel minimum over
both directions (Godard et al., ICCV 2019), over the pixels that change both ways, does not: the
true flow scores ~0 there, zero flow at least the change threshold.
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

T, H, W, SIDE, STEP = 8, 64, 96, 12, 4


def _clip() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frames ``(T, H, W, 3)`` uint8, true forward flow and true backward flow ``(T-1, H, W, 2)``."""
    rng = np.random.default_rng(0)
    bg = cv2.GaussianBlur(rng.uniform(60, 200, (H, W)).astype(np.float32), (0, 0), 1.5)
    frames = np.repeat(bg[None, ..., None], T, axis=0).repeat(3, axis=-1)
    fwd, back = np.zeros((T - 1, H, W, 2), np.float32), np.zeros((T - 1, H, W, 2), np.float32)
    skin = rng.uniform(0, 255, (SIDE, SIDE))                   # the square's own texture, moving with it
    for t in range(T):
        x = 10 + STEP * t
        frames[t, 26:26 + SIDE, x:x + SIDE] = skin[..., None]
        if t < T - 1:
            fwd[t, 26:26 + SIDE, x:x + SIDE, 0] = STEP          # the square of frame t moves right
        if t > 0:
            back[t - 1, 26:26 + SIDE, x:x + SIDE, 0] = -STEP    # the square of frame t came from the left
    return frames.astype(np.uint8), fwd, back


def test_min_reprojection_ranks_the_true_flow_first_where_the_forward_error_does_not():
    from flow_epe import min_reprojection_error, photometric_error

    frames, fwd, back = _clip()
    zero = np.zeros_like(fwd)
    # a "smeared" flow: the square's motion spread over a band twice its size (what a smooth
    # classical method does), so the background it moves onto is warped to the background beyond
    smear, smear_back = np.zeros_like(fwd), np.zeros_like(back)
    for t in range(T - 1):
        x = 10 + STEP * t
        smear[t, 20:44, max(x - 6, 0):x + SIDE + 6, 0] = STEP
        smear_back[t, 20:44, max(x + STEP - 6, 0):x + STEP + SIDE + 6, 0] = -STEP
    truth_fwd, n = photometric_error(frames, fwd)
    truth_min, n_min = min_reprojection_error(frames, fwd, back)
    smear_fwd, _ = photometric_error(frames, smear)
    smear_min, _ = min_reprojection_error(frames, smear, smear_back)
    zero_min, _ = min_reprojection_error(frames, zero, zero)
    assert n > 0 and n_min > 0
    assert truth_fwd > 10                       # the true flow pays for the background the square covers
    assert smear_fwd < truth_fwd                # ... and the forward error prefers the smear
    assert truth_min == pytest.approx(0.0, abs=1.0)
    assert truth_min <= smear_min + 1e-6 and zero_min > 20


def test_min_reprojection_uses_the_backward_flow_it_is_given():
    from flow_epe import backward_flow, min_reprojection_error

    frames, fwd, back = _clip()
    # a "method" that returns the true flow of whichever way the clip runs
    def method(clip):
        return fwd if np.array_equal(clip, frames) else np.ascontiguousarray(back[::-1])
    np.testing.assert_array_equal(backward_flow(method, frames), back)
    zero = np.zeros_like(fwd)                   # a forward flow that explains nothing ...
    good, _ = min_reprojection_error(frames, zero, back)
    bad, _ = min_reprojection_error(frames, zero, -back)
    assert good < 1.0 < 20 < bad                # ... is rescued by the true backward flow only
