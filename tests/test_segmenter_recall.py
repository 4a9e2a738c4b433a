"""``benchmarks/segmenter_recall.py``: an object's recall is the share of its true pixels the
segmenter marks, still and moving objects apart."""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))


def test_recall_is_the_share_of_true_pixels_marked(tmp_path):
    from segmenter_recall import clip_recall

    T, H, W = 10, 120, 160
    seg = np.full((T, H, W), -1, np.int8)
    rgb = np.zeros((T, H, W, 3), np.uint8)
    pos = np.zeros((T, 2, 3))
    for t in range(T):
        x = 20 + 6 * t                              # object 0 slides 6 px / frame, drawn white
        seg[t, 30:50, x:x + 20] = 0
        rgb[t, 30:50, x:x + 20] = 255
        pos[t, 0, 0] = 0.01 * t
        seg[t, 80:100, 100:120] = 1                 # object 1 at rest, drawn as the background
    folder = tmp_path / "clip-00000"
    folder.mkdir()
    np.savez(folder / "truth.npz", seg=seg, pos=pos)
    out = cv2.VideoWriter(str(folder / "video.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 30, (W, H))
    for f in rgb:
        out.write(f[..., ::-1])
    out.release()

    def bright(frames, background):                 # a segmenter that marks what is bright
        fg = (frames.max(axis=-1) > 128).astype(np.float32)
        return fg, np.zeros_like(fg)

    rows = {r["object"]: r for r in clip_recall(folder, bright, (W, H), 5)}
    assert rows[0]["recall"] > 0.9 and not rows[0]["still"]
    assert rows[1]["recall"] == 0.0 and rows[1]["still"]
    assert abs(rows[1]["area"] - 400) < 1
