"""The camera's exposure (``camera.exposure``, :mod:`pipeline.exposure`): masks swept over the
time the shutter is open, checked against a camera that really integrates (the union of
instantaneous renders at 8 times the frame rate), and recovered by the search."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline import traces
from pipeline.exposure import expose
from pipeline.metrics import sequence_iou
from pipeline.mjcf import SimOptions
from pipeline.scene import Scene, SceneError
from pipeline.search import SearchConfig, cmaes_refine, evaluate_scene

W, H = 96, 128
FINE = 8   # sub-frames per frame of the integrating camera
SIM = SimOptions(timestep=1.0 / 960)   # a whole number of steps per frame at 30 and at 240 fps: one trajectory


def drop(exposure: float = 0.0, fps: int = 30) -> Scene:
    """A 4 cm ball dropped 0.4 m in a side view, bouncing (e = 0.8): up to 2.8 m/s, ~6 px/frame."""
    return Scene.from_dict({"duration": 1.0, "fps": fps,
                            "camera": {"height": 0.25, "pitch": 0.0, "fov": 45.0, "exposure": exposure},
                            "objects": [{"shape": "sphere", "size": {"radius": 0.04}, "mass": 0.1,
                                         "position": [0.0, -1.2, 0.4]}],
                            "effects": [{"effect": "restitution", "parameters": {"e": 0.8}}]})


def integrating_camera(exposure: float) -> np.ndarray:
    """``(30, H, W)`` int8: what a 30 fps camera open for ``exposure`` s records, the union of the
    instantaneous masks at 240 fps over ``[t - E/2, t + E/2]`` (independent of the sweep model)."""
    fine, _ = evaluate_scene(drop(fps=30 * FINE), W, H, options=SIM, flow=False)
    half = int(round(exposure * 30 * FINE / 2))
    out = np.full((30, H, W), -1, np.int8)
    for t in range(30):
        k = t * FINE
        window = fine[max(k - half, 0): k + half + 1]
        out[t][(window == 0).any(axis=0)] = 0
    return out


def test_swept_masks_match_a_camera_that_integrates_over_its_exposure():
    """A falling, bouncing ball seen with the shutter open half a frame: the instantaneous render
    misses the smear (strict IoU below 0.85 against the integrating camera), the linear sweep of
    the render at 30 fps matches it (above 0.93), in the fast frames too, and an exposure of 0
    leaves the render unchanged."""
    E = 0.5 / 30
    truth = integrating_camera(E)
    sharp, _ = evaluate_scene(drop(), W, H, options=SIM, flow=False)
    swept, _ = evaluate_scene(drop(E), W, H, options=SIM, flow=False)
    assert np.array_equal(swept, expose(sharp, 0.5))
    assert np.array_equal(expose(sharp, 0.0), sharp)
    before = sequence_iou(truth, sharp)["strict_iou"]
    after = sequence_iou(truth, swept)["strict_iou"]
    assert before < 0.85 and after > 0.93
    fast = [t for t in range(1, 29) if (truth[t] == 0).sum() > 1.3 * (sharp[t] == 0).sum()]
    assert len(fast) >= 5
    per_frame = [((truth[t] == 0) & (swept[t] == 0)).sum() / ((truth[t] == 0) | (swept[t] == 0)).sum() for t in fast]
    assert min(per_frame) > 0.75   # the bounce frame (0.82): the sweep is piecewise linear, the path curves


def test_the_search_recovers_the_exposure_from_the_blurred_masks():
    """``search.free: exposure`` (the staged search frees it with the sizes): started at an
    instantaneous shutter on the true trajectory, CMA-ES finds the integrating camera's exposure
    of half a frame within a fifth of a frame, and the fit improves."""
    E = 0.5 / 30
    truth = integrating_camera(E)
    cfg = SearchConfig(popsize=6, iterations=6, sigma=0.3, free=["exposure"], lambda_epe=0.0, epe_pixels="observed")
    best, hist = cmaes_refine(drop(), truth, None, cfg, SIM, seed=0)
    assert best.camera.exposure * 30 == pytest.approx(0.5, abs=0.2)
    assert hist[-1]["best_fitness"] > hist[0]["best_fitness"] + 0.05


def test_dynamics_simulate_writes_the_masks_the_search_scored(tmp_path, monkeypatch):
    """``dynamics simulate`` renders in chunks; each chunk sees its neighbours' frames, so its
    swept masks equal the search's at every chunk boundary (chunks of 7 frames here)."""
    scene = drop(0.8 / 30)
    monkeypatch.setattr(traces, "chunk_frames", lambda w, h: 7)
    paths = traces.write_simulation(scene, tmp_path / "sim", W, H)
    with np.load(paths["masks"]) as f:
        written = f["seg"]
    scored, _ = evaluate_scene(scene, W, H, flow=False)
    assert np.array_equal(written, scored)


def test_exposure_is_checked_and_written_only_when_set():
    """The shutter cannot stay open longer than a frame (one-line error naming the field); an
    exposure of 0 leaves the canonical text as before, a set one round-trips."""
    with pytest.raises(SceneError, match=r"camera\.exposure: must be at most one frame interval"):
        drop(0.05)
    with pytest.raises(SceneError, match=r"camera\.exposure"):
        drop(-0.001)
    assert "exposure" not in drop().to_yaml()
    s = drop(0.01)
    assert "  exposure: 0.01\n" in s.to_yaml() and Scene.from_yaml(s.to_yaml()) == s
    with pytest.raises(ValueError, match="exposure_frames"):
        expose(np.zeros((2, 4, 4), np.int8), 1.5)
