"""Pseudo ground-truth masks of the real clips against hand labels (issue 9, item 6).

Labels: ``tests/fixtures/realvideo/<clip>/<frame>.png`` (uint8, 0 background, 1..n
objects), written by ``scripts/label_masks.py`` from the rules in ``labels.yaml`` (read off
the frames, checked on overlays). Pseudo masks: :func:`pipeline.masks.pseudo_ground_truth`
with the background fitted over the whole clip and ``max_objects`` = labelled objects.

Target: mean per-object IoU >= 0.8 per clip, with one method and one set of defaults
for all clips. Clips that do not reach it (as of this commit) are marked ``xfail`` with
the reason, so a fix shows up as XPASS:

* 02: the glass ball is transparent: its pixels differ little from the board/floor
  behind it, and its dark refraction/shadow below it on the board is not a plain shadow
  (its colour changes), so the mask runs over it; the person's legs move too;
* 05: the struck puck rests at its final place for 75 % of the clip, so the median
  background holds it and it is background in the labelled frames where it rests (and a
  ghost of it merges with the other puck's blob early on); part of that place is covered
  by a puck in every frame, so no per-pixel background model can see the empty table.
"""

import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

from label_masks import DEV_SPEC, FIXTURES, load_spec, real_video_dir  # noqa: E402
from pseudo_mask_report import clip_scores, frame_scores  # noqa: E402

SPECS = load_spec()
VIDEO = real_video_dir()
KNOWN_SHORT = {"02", "05"}      # see module docstring


def test_fixtures_are_labels():
    total = 0
    for clip, spec, i, p, lab in _label_images(SPECS):
        total += p.stat().st_size
        assert 1 <= lab.max() <= len(spec["objects"])
    assert total < 2_000_000


def _label_images(specs: dict):
    """``(clip, spec, frame, path, label image)`` of every labelled frame of ``specs``, after
    checking that each clip has >= 5 frames and each image is a 2-D uint8 label image."""
    import cv2
    for clip, spec in specs.items():
        frames = sorted(int(i) for i in spec["frames"])
        assert len(frames) >= 5, clip
        for i in frames:
            p = FIXTURES / clip / f"{i:04d}.png"
            lab = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
            assert lab is not None and lab.dtype == np.uint8 and lab.ndim == 2, p
            yield clip, spec, i, p, lab


def test_dev_fixtures_are_labels():
    """Hand labels of the 13 development clips (``labels_dev.yaml``): present, uint8 label
    images with ids in 0..n_objects, and every object a frame lists has pixels there (frames
    listing none are all background: the object has left the view). No accuracy targets."""
    specs = load_spec(DEV_SPEC)
    assert sorted(specs) == [f"dev{k:02d}" for k in range(1, 14)]
    total = 0
    for clip, spec, i, p, lab in _label_images(specs):
        n = len(spec["objects"])
        total += p.stat().st_size
        if "label_size" in spec:
            assert lab.shape == tuple(spec["label_size"][::-1]), p
        assert lab.max() <= n, p
        listed = spec["frames"][i] or {}
        for k, name in enumerate(spec["objects"], 1):
            if listed.get(name):
                assert (lab == k).any(), (clip, i, name)
            else:
                assert not (lab == k).any(), (clip, i, name)
    assert total < 3_000_000


def test_frame_scores():
    label = np.zeros((4, 6), np.uint8)
    label[:2, :2], label[2:, 3:] = 1, 2
    pred = np.full((4, 6), -1, np.int8)
    pred[2:, 3:], pred[:2, :2] = 0, 1                     # swapped ids: matching undoes it
    assert frame_scores(pred, label) == (1.0, 1.0)
    pred[:2, :2] = -1
    fg, obj = frame_scores(pred, label)
    assert fg == pytest.approx(6 / 10) and obj == pytest.approx(0.5)
    # no free credit: both empty is no evidence (NaN, skipped by the clip means); a prediction
    # where nothing is labelled scores 0
    empty = np.zeros((4, 6), np.uint8)
    assert all(np.isnan(frame_scores(np.full((4, 6), -1, np.int8), empty)))
    assert frame_scores(pred, empty) == (0.0, 0.0)


@pytest.mark.parametrize("clip", sorted(SPECS))
def test_pseudo_masks_match_hand_labels(clip):
    spec = SPECS[clip]
    if not (VIDEO / spec["file"]).exists():
        pytest.skip(f"real video not found under {VIDEO}")
    r = clip_scores(clip, spec, VIDEO)
    print(clip, r["mean_foreground_iou"], r["mean_object_iou"])
    if clip in KNOWN_SHORT and r["mean_object_iou"] < 0.8:
        pytest.xfail(f"{clip}: object IoU {r['mean_object_iou']:.3f} < 0.8 (see docstring)")
    assert r["mean_object_iou"] >= 0.8, r
