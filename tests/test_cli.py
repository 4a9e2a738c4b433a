"""Every ``dynamics`` subcommand answers a user mistake with one stderr line and exit status 2
(pipeline.errors.UserError, caught once in pipeline.cli), never a traceback."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
GOOD_SCENE = "camera: {height: 1.0}\nobjects:\n  - {shape: sphere, size: {radius: 0.1}, mass: 0.5, position: [0, 0, 0.1]}\n"


def _case(name: str, tmp: Path) -> list[str]:
    (tmp / "scene.yaml").write_text(GOOD_SCENE)
    (tmp / "bad_scene.yaml").write_text("objects: 3\n")
    (tmp / "text.mp4").write_text("not a video\n")
    (tmp / "a_file").write_text("")
    (tmp / "bad_params.yaml").write_text("sim: {foo: 1}\n")
    if name in ("infer_nothing_in_view", "infer_negative_start"):   # 1.5 s of a still, textured scene: nothing moves, no object
        from conftest import still_textured_mp4
        still_textured_mp4(tmp / "still.mp4")
    params = str(ROOT / "params.yaml")
    return {
        "simulate_missing_scene": ["simulate", str(tmp / "missing.yaml"), "--out", str(tmp / "o")],
        "simulate_bad_scene": ["simulate", str(tmp / "bad_scene.yaml"), "--out", str(tmp / "o")],
        "simulate_bad_params": ["simulate", str(tmp / "scene.yaml"), "--out", str(tmp / "o"),
                                "--params", str(tmp / "bad_params.yaml")],
        "simulate_missing_params": ["simulate", str(tmp / "scene.yaml"), "--out", str(tmp / "o"),
                                    "--params", str(tmp / "none.yaml")],
        "infer_missing_video": ["infer", str(tmp / "missing.mp4"), "--out", str(tmp / "o"), "--params", params],
        "infer_not_a_video": ["infer", str(tmp / "text.mp4"), "--out", str(tmp / "o"), "--params", params],
        "infer_nothing_in_view": ["infer", str(tmp / "still.mp4"), "--out", str(tmp / "o"), "--params", params],
        "infer_negative_start": ["infer", str(tmp / "still.mp4"), "--out", str(tmp / "o"), "--params", params,
                                 "--start", "-1"],
        "infer_negative_k": ["infer", str(tmp / "text.mp4"), "--out", str(tmp / "o"), "--params", params,
                             "-k", "-1"],
        "infer_missing_model": ["infer", str(tmp / "text.mp4"), "--out", str(tmp / "o"), "--params", params,
                                "--model", str(tmp / "no_model")],
        "infer_missing_params": ["infer", str(tmp / "text.mp4"), "--out", str(tmp / "o"),
                                 "--params", str(tmp / "none.yaml")],
        "infer_bad_params": ["infer", str(tmp / "text.mp4"), "--out", str(tmp / "o"),
                             "--params", str(tmp / "bad_params.yaml")],
        "discrepancy_missing_file": ["discrepancy", str(tmp / "missing.csv"), "--out", str(tmp / "o"),
                                     "--params", params],
        "view_missing_shard": ["view", str(tmp / "shard-00000.zarr"), "--save", str(tmp / "x.rrd")],
        "schema_unwritable_out": ["schema", "--out", str(tmp / "a_file" / "schema.json")],
    }[name]


CASES = ["simulate_missing_scene", "simulate_bad_scene", "simulate_bad_params", "simulate_missing_params",
         "infer_missing_video", "infer_not_a_video", "infer_negative_start",
         "infer_negative_k", "infer_missing_model", "infer_missing_params",
         "infer_bad_params", "discrepancy_missing_file", "view_missing_shard", "schema_unwritable_out"]


@pytest.mark.parametrize("case", CASES)
def test_user_mistake_is_one_line_and_exit_2(tmp_path, case):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": "egl"}
    env.pop("DYNAMICS_PARAMS", None)
    proc = subprocess.run([sys.executable, "-m", "pipeline.cli", *_case(case, tmp_path)], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr
    assert proc.stderr.count("\n") == 1 and proc.stderr.endswith("\n"), proc.stderr
    assert not (tmp_path / "o").exists()


def test_infer_on_a_window_with_nothing_in_view_writes_the_observation_and_no_scene(tmp_path):
    """A still clip: nothing to reconstruct, said in one line with exit status 2 (every scene
    would score 0, since a frame where nothing is seen gives no credit), and the output folder
    holds the observation (every pixel of every frame background, at the working size) and
    metrics.json with the error, but no scene.yaml: a check against the truth still reads
    observation.npz."""
    import numpy as np
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": "egl"}
    env.pop("DYNAMICS_PARAMS", None)
    proc = subprocess.run([sys.executable, "-m", "pipeline.cli", *_case("infer_nothing_in_view", tmp_path)],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr and proc.stderr.count("\n") == 1, proc.stderr
    assert "nothing to reconstruct" in proc.stderr
    out = tmp_path / "o"
    assert sorted(p.name for p in out.iterdir()) == ["metrics.json", "observation.npz"]
    with np.load(out / "observation.npz") as z:
        seg, size = z["seg"], z["size"]
        assert seg.dtype == np.int8 and seg.ndim == 3 and (seg == -1).all()
        assert seg.shape[1:] == (size[1], size[0]) and z["moving"].shape == (0,)
    metrics = json.loads((out / "metrics.json").read_text())
    assert "nothing to reconstruct" in metrics["error"] and metrics["objects_observed"] == {"moving": 0, "at_rest": 0}


def test_infer_mask_method_is_one_of_the_observation_methods(capsys):
    import argparse

    from pipeline.observe import MASK_METHODS
    from pipeline.reconstruct import add_arguments
    p = argparse.ArgumentParser()
    add_arguments(p)
    assert p.parse_args(["v.mp4", "--out", "o"]).mask_method is None          # params realvideo.mask_method
    for m in MASK_METHODS:
        assert p.parse_args(["v.mp4", "--out", "o", "--mask-method", m]).mask_method == m
    with pytest.raises(SystemExit):
        p.parse_args(["v.mp4", "--out", "o", "--mask-method", "grabcut"])
    assert "invalid choice: 'grabcut'" in capsys.readouterr().err


def test_infer_scenery_is_keep_or_drop_and_a_bad_param_names_the_field(capsys):
    """``dynamics infer --scenery`` takes keep or drop (default: params ``realvideo.scenery``,
    ``keep``); a bad value in params is one error naming ``realvideo.scenery``."""
    import argparse

    from pipeline.params import ParamsError
    from pipeline.reconstruct import add_arguments, realvideo_config
    p = argparse.ArgumentParser()
    add_arguments(p)
    assert p.parse_args(["v.mp4", "--out", "o"]).scenery is None
    assert p.parse_args(["v.mp4", "--out", "o", "--scenery", "drop"]).scenery == "drop"
    with pytest.raises(SystemExit):
        p.parse_args(["v.mp4", "--out", "o", "--scenery", "hide"])
    assert "invalid choice: 'hide'" in capsys.readouterr().err
    assert realvideo_config({}).scenery == "keep"
    assert realvideo_config({"realvideo": {"scenery": "drop"}}).scenery == "drop"
    with pytest.raises(ParamsError, match="scenery"):
        realvideo_config({"realvideo": {"scenery": "hide"}})
    # the silhouette tie-break of shapes is opt-in (it cost the rendered held-out sets' shapes)
    assert realvideo_config({}).shape_tiebreak == "parameters"
    assert realvideo_config({"realvideo": {"shape_tiebreak": "silhouette"}}).shape_tiebreak == "silhouette"
    with pytest.raises(ParamsError, match="shape_tiebreak"):
        realvideo_config({"realvideo": {"shape_tiebreak": "outline"}})
