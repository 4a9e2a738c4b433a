"""Tests for pipeline.flow: DIS/Farneback recover a known shift; the Middlebury colour wheel."""

import numpy as np
import pytest

from pipeline.flow import FlowConfig, estimate_flow, flow_to_rgb


def _shifted_square(h: int, w: int, shift: tuple[int, int], seed: int = 0) -> np.ndarray:
    """Two frames: a 32 px textured square on grey, then the same square moved by ``shift``."""
    import cv2

    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur((rng.random((32, 32)) * 255).astype(np.uint8), (0, 0), 1.0)
    frames = np.full((2, h, w, 3), 100, dtype=np.uint8)
    y0, x0 = h // 2 - 16, w // 2 - 16
    frames[0, y0:y0 + 32, x0:x0 + 32] = tex[..., None]
    dx, dy = shift
    frames[1, y0 + dy:y0 + dy + 32, x0 + dx:x0 + dx + 32] = tex[..., None]
    return frames


@pytest.mark.parametrize("method", ["dis", "farneback"])
@pytest.mark.parametrize("hw", [(64, 96), (128, 128)])
def test_estimate_flow_recovers_translation(method, hw):
    h, w = hw
    frames = _shifted_square(h, w, (3, -2))
    flow = estimate_flow(frames, method=method)
    assert flow.shape == (1, h, w, 2) and flow.dtype == np.float32
    y0, x0 = h // 2 - 16, w // 2 - 16
    inner = flow[0, y0 + 4:y0 + 28, x0 + 4:x0 + 28]       # inside the square, off its edges
    np.testing.assert_allclose(inner.reshape(-1, 2).mean(0), [3.0, -2.0], atol=0.5)
    assert np.abs(inner - [3.0, -2.0]).max() < 0.5


def test_estimate_flow_rejects_bad_input():
    with pytest.raises(ValueError, match="at least 2 frames"):
        estimate_flow(np.zeros((1, 8, 8, 3), np.uint8))
    with pytest.raises(ValueError, match="uint8"):
        estimate_flow(np.zeros((2, 8, 8, 3), np.float32))
    with pytest.raises(ValueError, match="render stage"):
        estimate_flow(np.zeros((2, 8, 8, 3), np.uint8), method="gt")


def test_flow_to_rgb_middlebury_wheel():
    # Directions at full saturation, per the Middlebury colour code (Baker et al. 2011):
    # +x red, +y (down) yellow-orange, -x cyan, -y blue; zero flow white.
    flow = np.array([[[1, 0], [0, 1], [-1, 0], [0, -1], [0, 0]]], dtype=np.float32)
    rgb = flow_to_rgb(flow, max_magnitude=1.0)
    assert rgb.shape == (1, 5, 3) and rgb.dtype == np.uint8
    red, down, left, up, zero = rgb[0].astype(int)
    assert red[0] == 255 and red[1] < 40 and red[2] < 60
    assert down[0] == 255 and down[1] > 150 and down[2] < 40
    assert left[0] < 40 and left[1] > 150 and left[2] == 255
    assert up[2] == 255 and up[0] < 160 and up[1] < 40
    np.testing.assert_array_equal(zero, [255, 255, 255])


def test_flow_to_rgb_saturation_and_shapes():
    flow = np.zeros((3, 4, 5, 6, 2))
    flow[..., 0] = 2.0
    half = flow_to_rgb(flow, max_magnitude=4.0)           # half saturation: pale red
    full = flow_to_rgb(flow, max_magnitude=1.0)           # clipped to full saturation
    auto = flow_to_rgb(flow)                              # per-call max -> full
    assert half.shape == (3, 4, 5, 6, 3) and half.dtype == np.uint8
    np.testing.assert_array_equal(full, auto)
    assert half[0, 0, 0, 0, 0] == 255 and 120 < half[0, 0, 0, 0, 1] < 135
    assert (flow_to_rgb(np.zeros((2, 2, 2))) == 255).all()             # all-zero: white
    assert (flow_to_rgb(np.full((2, 2, 2), np.nan)) == 255).all()      # unknown: white
    with pytest.raises(ValueError, match="H, W, 2"):
        flow_to_rgb(np.zeros((4, 4, 3)))


def test_flow_config():
    assert FlowConfig().method == "dis"
    with pytest.raises(ValueError):
        FlowConfig(method="raft2")
    with pytest.raises(ValueError):
        FlowConfig(max_magnitude=0)
