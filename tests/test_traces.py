"""Trace tables and `dynamics simulate` (issue 4: run your own scene)."""

import pipeline  # noqa: F401  (MUJOCO_GL before mujoco)

import argparse
import json

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from numpy.testing import assert_allclose

from pipeline.events import extract_events
from pipeline.scene import Scene
from pipeline.simulate import simulate
from pipeline.cli import add_simulate_arguments, simulate_cli
from pipeline.traces import (OBJECT_FRAME_COLUMNS, TRACES_SCHEMA, object_frame_table,
                             trace_from_row, trace_to_row)

SCENE = """\
camera: {height: 1.0, pitch: 30.0, fov: 45.0}
objects:
  - shape: sphere
    size: {radius: 0.1}
    mass: 0.5
    position: [0.0, 0.0, 0.6]
    linear_velocity: [0.5, 0.0, 0.0]
  - shape: box
    size: {width: 0.2, depth: 0.2, height: 0.2}
    mass: 1.0
    position: [0.4, 0.1, 0.1]
"""


def _run(argv):
    parser = add_simulate_arguments(argparse.ArgumentParser(prog="dynamics simulate"))
    return simulate_cli(parser.parse_args(argv))


def test_trace_row_round_trip():
    _, trace = simulate(Scene.from_yaml(SCENE))
    visible = np.arange(trace.qpos.shape[0] * 2).reshape(-1, 2)
    row = {"scene_id": "scene-000000", "split": "train", **trace_to_row(trace, visible)}
    table = pa.Table.from_pylist([row], schema=TRACES_SCHEMA)
    back, vis = trace_from_row(table.to_pylist()[0])
    assert_allclose(back.qpos, trace.qpos, rtol=0, atol=0)
    assert_allclose(back.qvel, trace.qvel, rtol=0, atol=0)
    assert back.names == trace.names and np.array_equal(vis, visible)
    assert extract_events(back) == extract_events(trace)  # contacts survive exactly


def test_object_frame_table_layout():
    _, trace = simulate(Scene.from_yaml(SCENE))
    table = object_frame_table(trace)
    assert tuple(table.column_names) == OBJECT_FRAME_COLUMNS
    assert table.num_rows == trace.qpos.shape[0] * 2
    rows = table.to_pylist()
    assert rows[3]["object"] == "box_1" and rows[3]["t"] == trace.t[1]
    assert_allclose([rows[3][c] for c in OBJECT_FRAME_COLUMNS[2:9]], trace.qpos[1, 1])
    assert_allclose([rows[3][c] for c in OBJECT_FRAME_COLUMNS[9:]], trace.qvel[1, 1])


def test_simulate_command_writes_everything(tmp_path):
    scene_file = tmp_path / "ball.yaml"
    scene_file.write_text(SCENE)
    out = tmp_path / "out"
    assert _run([str(scene_file), "--out", str(out), "--width", "96", "--height", "64"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["events.json", "masks.mp4", "masks.npz", "rgb.mp4", "trace.parquet"]
    table = pq.read_table(out / "trace.parquet")
    assert tuple(table.column_names) == OBJECT_FRAME_COLUMNS and table.num_rows == 30 * 2
    masks = np.load(out / "masks.npz")
    assert masks["seg"].shape == (30, 64, 96) and masks["seg"].dtype == np.int8
    assert set(np.unique(masks["seg"])) == {-1, 0, 1}
    video = cv2.VideoCapture(str(out / "rgb.mp4"))
    n = 0
    while video.read()[0]:
        n += 1
    assert n == 30
    events = json.loads((out / "events.json").read_text())
    assert events["names"] == ["sphere_0", "box_1"]
    assert "sphere_0 hits floor" in events["text"]


@pytest.mark.parametrize("edit,message", [
    (("radius: 0.1", "radius: -1.0"), "objects[0].size.radius: must be >= 0.001"),
    (("mass: 1.0", "mass: 1.0\n    colour: red"), "objects[1].colour: must not be given (unknown key)"),
    (("camera:", "effects: [{effect: no_such_effect}]\ncamera:"), "effects[0].effect: unknown effect"),
])
def test_simulate_command_rejects_bad_scenes_with_one_line(tmp_path, capsys, edit, message):
    scene_file = tmp_path / "bad.yaml"
    scene_file.write_text(SCENE.replace(*edit))
    out = tmp_path / "out"
    assert _run([str(scene_file), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"{scene_file}: {message}"), err
    assert err.count("\n") == 1
    assert not out.exists()


@pytest.mark.parametrize("case", ["width0", "out_is_file", "unknown_sim_key"])
def test_simulate_command_rejects_bad_options_with_one_line(tmp_path, capsys, case):
    """Issue 12 reproducers: `--width 0` left a partial trace.parquet, `--out` naming a file and a
    params file with an unknown `sim` key printed tracebacks."""
    scene_file = tmp_path / "ball.yaml"
    scene_file.write_text(SCENE)
    out = tmp_path / "out"
    args, needle = {
        "width0": (["--out", str(out), "--width", "0"], "--width: must be in 2..4096 px, got 0"),
        "out_is_file": (["--out", str(tmp_path / "file")], "--out: must be a folder"),
        "unknown_sim_key": (["--out", str(out), "--params", str(tmp_path / "p.yaml")], "sim.foo: must not be given (unknown key)"),
    }[case]
    (tmp_path / "file").write_text("keep me")
    (tmp_path / "p.yaml").write_text("sim: {timestep: 0.002, foo: 1}\n")
    assert _run([str(scene_file), *args]) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1, err
    assert not out.exists()
    assert (tmp_path / "file").read_text() == "keep me"


def test_simulate_command_renders_wider_than_the_default_buffer(tmp_path):
    """`--width 1000` exceeded MuJoCo's 640 px offscreen buffer (traceback); the buffer grows."""
    scene_file = tmp_path / "ball.yaml"
    scene_file.write_text(SCENE.replace("duration: 1.0", "duration: 0.2") if "duration: 1.0" in SCENE else SCENE)
    out = tmp_path / "out"
    assert _run([str(scene_file), "--out", str(out), "--width", "1000", "--height", "100"]) == 0
    assert np.load(out / "masks.npz")["seg"].shape[1:] == (100, 1000)


@pytest.mark.parametrize("edit", [("position: [0.0, 0.0, 0.6]", "position: [1.0e+308, 0.0, 0.6]"),
                                  ("linear_velocity: [0.5, 0.0, 0.0]",
                                   "linear_velocity: [0.5, 0.0, 0.0]\n    angular_velocity: [1.0e+30, 0.0, 0.0]")])
def test_simulate_command_refuses_unstable_simulations(tmp_path, capsys, edit):
    """Issue 12: a trace 84 % NaN and MuJoCo's silent resets (bad qacc / qvel) came back with exit
    0; now one line naming the problem, exit 2, nothing written."""
    text = SCENE.replace(*edit, 1)
    assert text != SCENE
    scene_file = tmp_path / "bad.yaml"
    scene_file.write_text(text)
    out = tmp_path / "out"
    assert _run([str(scene_file), "--out", str(out), "--width", "32", "--height", "32"]) == 2
    err = capsys.readouterr().err
    assert "simulation: must stay stable" in err and err.count("\n") == 1, err
    assert not out.exists()
