"""Observed tracks of a reconstructed video in the scene's world frame (issue 10, item 5):
``dynamics infer`` writes ``tracks.csv``, ``dynamics discrepancy DIR`` reads it back."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from pipeline import discrepancy as D
from pipeline import infer_tracks
from pipeline.camera import project
from pipeline.mjcf import SimOptions, compile_model
from pipeline.scene import Scene
from pipeline.simulate import rollout

W, H, FPS = 160, 120, 30


def _ball_scene(effects=()) -> Scene:
    """A 4 cm ball thrown sideways in front of a side-view camera (looking along +y)."""
    return Scene.from_dict({
        "duration": 1.0, "fps": FPS, "camera": {"height": 0.3, "pitch": 0.0, "fov": 45.0},
        "objects": [{"shape": "sphere", "size": {"radius": 0.04}, "mass": 0.05, "position": [-0.25, -1.0, 0.45],
                     "linear_velocity": [0.5, 0.0, 0.0],
                     "material": {"sliding_friction": 0.3, "rolling_friction": 0.0, "damping": 0.0}}],
        "effects": list(effects)})


def _observe(scene: Scene, width: int = W, height: int = H, noise_px: float = 0.0, seed: int = 0):
    """Simulate a scene and track its ball as perception would: (frames, centre px)."""
    opts = SimOptions(textured=False)
    trace = rollout(compile_model(scene, opts), len(scene.objects), int(scene.duration * scene.fps) + 1, scene.fps)
    uv, _ = project(trace.qpos[:, 0, :3], scene.camera, width, height)
    uv = uv + np.random.default_rng(seed).normal(0.0, noise_px, uv.shape)
    return trace, [SimpleNamespace(frames=np.arange(len(uv)), centre=uv)]


def test_side_view_observes_x_and_z_and_top_view_x_and_y():
    assert infer_tracks.observed_axes(_ball_scene()).tolist() == [True, False, True]
    top = _ball_scene().replace(camera={"height": 2.0, "pitch": 89.0, "fov": 45.0})
    assert infer_tracks.observed_axes(top).tolist() == [True, True, False]


def test_tracks_of_the_resimulated_scene_itself_round_trip_to_its_positions(tmp_path):
    """Tracks that are the scene's own projections give back its positions (project ->
    unproject at the simulated depth) and a zero re-simulation gap."""
    scene = _ball_scene()
    trace, tracks = _observe(scene)
    table = infer_tracks.tracks_table(scene, trace.qpos, tracks, FPS, W, H, clip="ball")
    obs = np.column_stack([table[k] for k in "xyz"])
    np.testing.assert_allclose(obs, trace.qpos[:, 0, :3], atol=1e-9)
    gap = infer_tracks.resimulation_gap(table, infer_tracks.observed_axes(scene))
    assert gap["rmse_m"] < 1e-9 and gap["rmse_px"] < 1e-9
    (tmp_path / "scene.yaml").write_text(scene.to_yaml())
    infer_tracks.write_tracks(tmp_path / "tracks.csv", table)
    clips, video, gravity = D.clips_from_infer_dir(tmp_path)
    assert len(clips) == 1 and clips[0].tracks[0].axes.tolist() == [True, False, True]
    assert clips[0].tracks[0].spec.shape == "sphere" and clips[0].tracks[0].spec.size["radius"] == pytest.approx(0.04)
    assert gravity == pytest.approx(9.81) and video["camera_axes"] == "xz"


def test_tracks_are_matched_to_objects_by_pixel_distance():
    sim = np.zeros((5, 2, 2))
    sim[:, 0] = [10.0, 10.0]
    sim[:, 1] = [100.0, 50.0]
    near_1 = np.column_stack([np.arange(5), np.full(5, 98.0), np.full(5, 51.0)])
    near_0 = np.column_stack([np.arange(5), np.full(5, 12.0), np.full(5, 9.0)])
    assert infer_tracks.match_tracks([near_1, near_0], sim) == [1, 0]


def test_discrepancy_names_restitution_on_a_video_folder(tmp_path, capsys):
    """`dynamics discrepancy DIR` on an infer-style folder whose video bounced with restitution
    0.7 while the re-simulated scene has none: the re-simulation gap is reported and
    restitution is named near 0.7 and the forward gap shrinks by more than half."""
    from pipeline.cli import main

    truth = _ball_scene([{"effect": "restitution", "parameters": {"e": 0.7}}])
    _, tracks = _observe(truth, 320, 240, noise_px=0.3)
    resim = _ball_scene()                          # what `dynamics infer` would have left: no bounce
    trace, _ = _observe(resim, 320, 240)
    table = infer_tracks.tracks_table(resim, trace.qpos, tracks, FPS, 320, 240, clip="ball")
    folder = tmp_path / "infer"
    folder.mkdir()
    (folder / "scene.yaml").write_text(resim.to_yaml())
    infer_tracks.write_tracks(folder / "tracks.csv", table)
    code = main(["discrepancy", str(folder), "--out", str(tmp_path / "rep"), "--no-recording", "--quiet",
                 "--candidates", "restitution,quadratic_drag"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "named: restitution" in out, out
    rep = __import__("json").loads((tmp_path / "rep" / "discrepancy.json").read_text())
    assert rep["video"]["resimulation_gap"]["rmse_m"] > 0.01          # the bounce the scene missed
    # within 5 % of the truth (the restitution chi-square is rugged at 30 fps: the impact falls
    # between frames, so the profile interval can be narrower than the error; see docs/discrepancy.md)
    assert rep["named"][0]["parameters"]["e"] == pytest.approx(0.7, abs=0.035), rep["named"][0]
    assert rep["gap"]["after"] < 0.5 * rep["gap"]["before"], rep["gap"]
    assert "## Video reconstruction" in (tmp_path / "rep" / "discrepancy.md").read_text()


def test_missing_tracks_file_is_one_line(tmp_path):
    (tmp_path / "scene.yaml").write_text(_ball_scene().to_yaml())
    with pytest.raises(infer_tracks.InferTracksError, match=r"tracks\.csv: missing"):
        infer_tracks.read_infer_dir(tmp_path)
