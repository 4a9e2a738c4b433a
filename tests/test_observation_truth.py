"""The observation scored against truth (issue 36): the metric gives no free credit, counts
identity switches as CLEAR MOT does, and labels map onto the observation's window exactly."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from pipeline.labels import LabelsError, labels_in_window, load_labels, score_against_labels
from pipeline.metrics import identity_switches, observation_scores, track_iou
from pipeline.observe import source_frames, truth_in_window


def _disc(seg, t, k, cx, cy, r):
    yy, xx = np.mgrid[: seg.shape[1], : seg.shape[2]]
    seg[t][(xx - cx) ** 2 + (yy - cy) ** 2 <= r * r] = k


def test_frames_where_both_are_absent_give_no_credit():
    """An object visible in 2 of 10 frames, predicted exactly there: IoU 1 over those 2 frames; a
    prediction that is empty everywhere scores 0, not the 8/10 that counting absent frames gives."""
    true = np.full((10, 20, 20), -1, np.int8)
    for t in (3, 4):
        _disc(true, t, 0, 10, 10, 4)
    assert observation_scores(true, true.copy())["matched_iou"] == 1.0
    empty = np.full_like(true, -1)
    s = observation_scores(true, empty)
    assert s["matched_iou"] == 0.0 and s["n_pred"] == 0 and not s["count_right"]
    # a ghost in the 8 frames where the object is absent halves nothing it should not: 2 of 10 frames right
    ghost = true.copy()
    for t in range(10):
        if t not in (3, 4):
            _disc(ghost, t, 0, 10, 10, 4)
    assert observation_scores(true, ghost)["matched_iou"] == pytest.approx(0.2)


def test_track_iou_is_mean_over_frames_where_either_is_visible():
    true = np.full((4, 10, 10), -1, np.int8)
    pred = np.full_like(true, -1)
    true[0, :2, :2] = 0          # frame 0: true 4 px, pred 2 of them -> 0.5
    pred[0, :1, :2] = 0
    true[1, :2, :2] = 0          # frame 1: true only -> 0
    pred[2, 5:7, 5:7] = 0        # frame 2: pred only -> 0; frame 3: neither -> skipped
    iou, frames = track_iou(true, pred)
    assert frames[0, 0] == 3 and iou[0, 0] == pytest.approx(0.5 / 3)


def test_still_and_moving_objects_are_reported_apart():
    true = np.full((6, 40, 40), -1, np.int8)
    pred = np.full_like(true, -1)
    for t in range(6):
        _disc(true, t, 0, 8 + 4 * t, 10, 4)      # moving
        _disc(true, t, 1, 30, 30, 5)             # still
        _disc(pred, t, 0, 8 + 4 * t, 10, 4)      # the mover found, the still object missed
    s = observation_scores(true, pred, still=[False, True])
    assert s["moving_iou"] == 1.0 and s["still_iou"] == 0.0 and s["still_found"] == 0.0
    assert s["matched_iou"] == 0.5 and s["n_true"] == 2 and s["n_pred"] == 1


def test_identity_switch_is_counted_once_per_change():
    true = np.full((6, 20, 40), -1, np.int8)
    for t in range(6):
        _disc(true, t, 0, 5 + 5 * t, 10, 3)
    pred = np.where(true >= 0, np.where(np.arange(6)[:, None, None] < 3, 0, 1), -1).astype(np.int8)
    assert identity_switches(true, pred) == 1
    assert identity_switches(true, true.copy()) == 0


def _obs(start_frame=5, fps=60.0, scene_fps=30, T=4, crop=(10, 20, 40, 30), size=(20, 15), orig=(80, 60)):
    clip = SimpleNamespace(start_frame=start_frame, fps=fps, original_size=orig)
    return SimpleNamespace(frames=np.zeros((T, size[1], size[0], 3), np.uint8), clip=clip, scene_fps=scene_fps,
                           crop=crop, size=size, seg=np.full((T, size[1], size[0]), -1, np.int8))


def test_truth_maps_to_the_window_frames_crop_and_size():
    """Window frame k of a 60 fps clip at 30 fps is source frame start + 2k; a true object at a
    known pixel of the original frame lands at (pixel - crop corner) * size / crop size."""
    obs = _obs()
    assert source_frames(obs).tolist() == [5, 7, 9, 11]
    seg = np.full((20, 60, 80), -1, np.int8)
    for i in range(20):
        seg[i, 30:34, 20 + i: 24 + i] = 0              # moves 1 px per source frame
    win, idx = truth_in_window(seg, obs)
    assert win.shape == (4, 15, 20) and idx.tolist() == [5, 7, 9, 11]
    for k, i in enumerate(idx):
        vs, us = np.nonzero(win[k] == 0)
        assert us.mean() == pytest.approx((20 + i + 1.5 - 10) * 0.5, abs=0.6)
        assert vs.mean() == pytest.approx((31.5 - 20) * 0.5, abs=0.6)
    with pytest.raises(ValueError, match="whole clip"):
        truth_in_window(seg[:8], obs)


def test_png_labels_score_the_observation_and_the_resimulation(tmp_path):
    obs = _obs()
    lab = np.zeros((30, 40), np.uint8)                  # label images at half the video's size
    lab[15:17, 10:12] = 1
    cv2.imwrite(str(tmp_path / "0007.png"), lab)
    cv2.imwrite(str(tmp_path / "0100.png"), lab)        # outside the window: ignored
    labels = load_labels(tmp_path, (80, 60))
    assert set(labels) == {7, 100} and labels[7].shape == (60, 80) and (labels[7] == 0).sum() == 16
    ks, seg = labels_in_window(labels, obs)
    assert ks.tolist() == [1] and (seg[0] == 0).sum() == 4
    resim = obs.seg.copy()
    resim[1][seg[0] == 0] = 0
    r = score_against_labels(labels, obs, resim)
    assert r["resim_vs_labels"] == 1.0 and r["observation_vs_labels"] == 0.0 and r["n_labelled"] == 1


def test_bad_labels_name_the_file(tmp_path):
    with pytest.raises(LabelsError, match="no such labels"):
        load_labels(tmp_path / "missing.npz", (8, 8))
    bad = tmp_path / "bad.npz"
    np.savez(bad, seg=np.zeros((2, 3), np.int8))
    with pytest.raises(LabelsError, match="bad.npz: seg"):
        load_labels(bad, (8, 8))
    with pytest.raises(LabelsError, match="no label image"):
        load_labels(tmp_path, (8, 8))


def test_no_true_object_gives_nan_not_a_score():
    empty = np.full((3, 5, 5), -1, np.int8)
    assert math.isnan(observation_scores(empty, empty)["matched_iou"])


def test_update_replaces_only_the_rerun_rows_and_keeps_their_provenance(tmp_path):
    """``observation_truth.py --update``: rows a run recomputes replace the old ones in place, the
    others keep the command and tree that made them, and the report names both runs."""
    import json
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from observation_truth import load_report, markdown, updated

    def row(clip, iou):
        return {"clip": clip, "seconds": 1.0, "matched_iou": iou, "count_right": True, "id_switches": 0,
                "per_object": [{"iou": iou, "still": False}]}

    old = {"command": "old cmd", "commit": "aaa", "method": "m", "summary": {},
           "sets": {"hybrid: a": [row("c0", 0.5)], "segmenter: a": [row("c0", 0.7)]}}
    path = tmp_path / "r.json"
    path.write_text(json.dumps(old))
    new = {"command": "new cmd", "commit": "bbb", "method": "m", "summary": {},
           "sets": {"hybrid: a": [row("c0", 0.9)], "hybrid: b": [row("c1", 0.2)]},
           "runs": [{"command": "new cmd", "commit": "bbb", "sets": ["hybrid: a", "hybrid: b"]}]}
    rep = updated(load_report(path), new)
    assert list(rep["sets"]) == ["hybrid: a", "segmenter: a", "hybrid: b"]
    assert rep["summary"]["hybrid: a"]["matched_iou"] == 0.9
    assert rep["summary"]["segmenter: a"]["matched_iou"] == 0.7
    assert rep["runs"] == [{"command": "old cmd", "commit": "aaa", "sets": ["segmenter: a"]}, new["runs"][0]]
    text = markdown(rep)
    assert "`old cmd` (tree `aaa`) for segmenter: a" in text and "`new cmd` (tree `bbb`) for hybrid: a, hybrid: b" in text
    path.write_text("{not json")
    with pytest.raises(SystemExit, match="r.json"):
        load_report(path)
