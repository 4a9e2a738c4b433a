"""Tests for pipeline.viz: mp4 columns, rerun recordings, curves."""

import cv2
import numpy as np
import pytest

from pipeline.flow import flow_to_rgb
from pipeline.viz import (PALETTE, mask_overlay, plot_curves, rdf_rotation_from_mujoco,
                          record_clip, recording_entities, side_by_side_mp4)

T, H, W = 6, 32, 48


@pytest.fixture
def clip():
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (T, H, W, 3), dtype=np.uint8)
    seg = np.full((T, H, W), -1, dtype=np.int8)
    seg[:, 5:15, 5:15] = 0
    seg[:, 20:30, 30:40] = 1
    flow = rng.normal(size=(T - 1, H, W, 2)).astype(np.float32)
    depth = rng.uniform(1, 3, (T, H, W)).astype(np.float32)
    return rgb, seg, flow, depth


def test_mask_overlay(clip):
    rgb, seg, _, _ = clip
    out = mask_overlay(rgb, seg, alpha=1.0)
    assert out.shape == rgb.shape and out.dtype == np.uint8
    np.testing.assert_array_equal(out[seg < 0], rgb[seg < 0])      # background untouched
    np.testing.assert_array_equal(out[seg == 1], np.broadcast_to(PALETTE[1], out[seg == 1].shape))
    with pytest.raises(ValueError):
        mask_overlay(rgb, seg[0])


def test_side_by_side_mp4(tmp_path, clip):
    rgb, seg, flow, _ = clip
    path = tmp_path / "sub" / "cmp.mp4"
    wide = np.zeros((T, H, 2 * W, 3), np.uint8)
    flow_rgb = np.concatenate([flow_to_rgb(flow), np.full((1, H, W, 3), 255, np.uint8)])
    cols = [rgb, mask_overlay(rgb, seg), flow_rgb, wide]
    before = [c.copy() for c in cols]
    side_by_side_mp4(path, cols, ["rgb", "seg", "flow", ""], fps=30)
    for c, b in zip(cols, before):
        np.testing.assert_array_equal(c, b)               # labels drawn on copies only
    assert path.exists() and not [p for p in path.parent.iterdir() if p != path]  # no temp left
    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame)
    cap.release()
    assert len(frames) == T
    assert frames[0].shape == (H, 5 * W, 3)               # width = sum of the columns
    # content, not just a file: each column lands at its place (below the label band, mean
    # colour per column and frame within the codec's error), RGB order kept
    band = 12
    x = 0
    for c in cols:
        w = c.shape[2]
        for t in range(T):
            got = cv2.cvtColor(frames[t], cv2.COLOR_BGR2RGB)[band:, x:x + w].reshape(-1, 3).mean(0)
            np.testing.assert_allclose(got, c[t, band:].reshape(-1, 3).mean(0), atol=12)
        x += w
    with pytest.raises(ValueError, match="columns\\[1\\]"):
        side_by_side_mp4(path, [rgb, rgb[:2]], ["a", "b"], fps=30)


def test_record_clip_rrd(tmp_path, clip):
    rgb, seg, flow, depth = clip
    objects = [{"name": "sphere_0", "shape": "sphere", "size": {"radius": 0.1}},
               {"name": "cylinder_1", "shape": "cylinder",
                "size": {"radius": 0.05, "height": 0.2}},
               {"name": "box_2", "shape": "box",
                "size": {"width": 0.2, "depth": 0.1, "height": 0.1}}]
    pos = np.zeros((T, 3, 3))
    pos[:, :, 2] = 0.1 + 0.01 * np.arange(T)[:, None]
    quat = np.tile([1.0, 0, 0, 0], (T, 3, 1))
    # MuJoCo camera at (0, -2, 1.2) looking along +y, pitched 35 deg down (docs/design.md §2)
    p = np.radians(35)
    forward, up = np.array([0, np.cos(p), -np.sin(p)]), np.array([0, np.sin(p), np.cos(p)])
    r_mj = np.column_stack([[1, 0, 0], up, -forward])    # columns: camera x, y, z in world
    r_rdf = rdf_rotation_from_mujoco(r_mj)
    np.testing.assert_allclose(r_rdf[:, 2], forward)      # RDF camera looks along +z
    np.testing.assert_allclose(r_rdf[:, 1], -up)          # image y points down
    K = np.array([[40.0, 0, W / 2], [0, 40.0, H / 2], [0, 0, 1]])
    path = tmp_path / "clip.rrd"
    record_clip(path, rgb=rgb, seg=seg, flow=flow, depth=depth, positions=pos,
                quaternions=quat, objects=objects,
                camera={"K": K, "rotation": r_rdf, "translation": [0, -2, 1.2]},
                scalars={"iou": np.linspace(0, 1, T)}, fps=30)
    assert path.stat().st_size > 1000
    assert path.read_bytes()[:4] == b"RRF2"                 # rerun's file magic
    entities = recording_entities(path)
    for e in ["/world", "/world/camera", "/world/camera/rgb", "/world/camera/seg",
              "/world/camera/flow", "/world/camera/depth", "/world/objects/sphere_0",
              "/world/objects/cylinder_1", "/world/objects/box_2", "/metrics/iou"]:
        assert e in entities, (e, entities)

    with pytest.raises(ValueError, match="shape must be"):
        record_clip(tmp_path / "bad.rrd", positions=pos[:, :1], quaternions=quat[:, :1],
                    objects=[{"name": "x", "shape": "cone", "size": {}}])
    assert not (tmp_path / "bad.rrd").exists()


def test_plot_curves(tmp_path):
    path = tmp_path / "curves.png"
    x = np.arange(10)
    plot_curves(path, {"train": (x, np.exp(-x)), "val": (x, np.exp(-x) + 0.1)},
                title="loss", xlabel="step", ylabel="loss", logy=True)
    img = cv2.imread(str(path))
    assert img is not None and img.shape[0] > 100 and img.shape[1] > 100
    # both series are drawn, in matplotlib's first two colours (C0 blue, C1 orange), and the
    # train curve falls from left to right (exp(-x) on a log axis is a descending line)
    rgb = cv2.cvtColor(img, cv2.COLOR_BGR2RGB).astype(int)
    for colour in ((31, 119, 180), (255, 127, 14)):
        assert (np.abs(rgb - colour).sum(-1) < 30).sum() > 200, colour
    rows, cols = np.nonzero(np.abs(rgb - (31, 119, 180)).sum(-1) < 30)
    left, right = cols < np.percentile(cols, 20), cols > np.percentile(cols, 80)
    assert rows[left].mean() < rows[right].mean() - 100      # image rows grow downwards
    with pytest.raises(ValueError, match="train"):
        plot_curves(path, {"train": (x, x[:3])})
