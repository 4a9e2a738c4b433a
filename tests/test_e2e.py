"""Tiny end-to-end run: a few scenes through every DVC stage, then the main job on a real video.

Checks the pipeline contract rather than model quality: `dvc repro` builds every stage, a
second `dvc repro` does nothing, changing one param marks only the stages downstream of it,
and the reports have the paper-style rows (with the trivial baseline).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "real" / "video"

sys.path.insert(0, str(ROOT / "scripts"))
from tiny_profile import compare, make_workspace, run  # noqa: E402  (the tiny profile: profiles/tiny.yaml)


def _run(cmd: list[str], cwd: Path, env: dict, timeout: int = 900) -> subprocess.CompletedProcess:
    try:
        return run(cmd, cwd, env, timeout)
    except RuntimeError as exc:
        raise AssertionError(str(exc)) from None


@pytest.fixture(scope="module")
def workspace(tmp_path_factory) -> tuple[Path, dict]:
    ws = tmp_path_factory.mktemp("e2e")
    env = make_workspace(ws)
    _run([sys.executable, "-m", "dvc", "repro"], ws, env)
    return ws, env


@pytest.mark.slow
def test_repro_builds_every_stage_and_reports(workspace):
    ws, _ = workspace
    for stage_dir in ("configs", "mjcf", "video", "traces", "flow", "events", "tokenizer", "examples", "model",
                      "model_adapted", "predictions", "best_of_k", "cmaes", "hidden", "hidden_truth", "discrepancy"):
        assert (ws / "data" / stage_dir).is_dir(), stage_dir
    metrics = json.loads((ws / "reports" / "metrics.json").read_text())
    assert metrics, "empty metrics"
    table = (ws / "reports" / "table.md").read_text()
    assert "Trivial baseline" in table and "CMA-ES" in table
    # the committed tiny report is current (python scripts/tiny_profile.py regenerates it)
    committed = json.loads((ROOT / "reports" / "tiny" / "metrics.json").read_text())
    assert not compare(metrics, committed), "\n".join(compare(metrics, committed))
    report = json.loads((ws / "reports" / "discrepancy.json").read_text())
    assert {"named", "gap"} <= set(report) and report["gap"]["before"] >= 0
    # the configs hold the held-out compositions only in test_comp
    from pipeline.shards import read_table

    configs = read_table(ws / "data" / "configs").to_pylist()
    assert {r["split"] for r in configs} == {"train", "val", "test", "test_comp"}
    held = {",".join(sorted(c)) for c in yaml.safe_load((ws / "params.yaml").read_text())["sample"]["held_out"]}
    assert all(r["composition"] not in held for r in configs if r["split"] == "train")


@pytest.mark.slow
def test_second_repro_is_a_noop_and_params_invalidate_downstream_only(workspace):
    ws, env = workspace
    out = _run([sys.executable, "-m", "dvc", "repro"], ws, env).stdout
    assert "Running stage" not in out, out
    params = yaml.safe_load((ws / "params.yaml").read_text())
    params["search"]["popsize"] = 5
    (ws / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    status = json.loads(_run([sys.executable, "-m", "dvc", "status", "--json"], ws, env).stdout)
    # preference reads the search's fitness when enabled (issue 37); disabled, it reruns as a copy of the
    # same model, so predict and best_of_k stay cached
    assert set(status) == {"preference", "cmaes", "score"}, status
    params["search"]["popsize"] = 4
    (ws / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    params["model"]["reasoning"] = False
    (ws / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    status = json.loads(_run([sys.executable, "-m", "dvc", "status", "--json"], ws, env).stdout)
    # stages that read model.reasoning directly (best_of_k/cmaes rerun later only if predictions change)
    assert set(status) == {"tokenize", "finetune", "preference", "predict", "score"}, status
    params["model"]["reasoning"] = True
    (ws / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))


@pytest.mark.slow
@pytest.mark.parametrize("mask_method", [
    "median",
    pytest.param("hybrid", marks=pytest.mark.xfail(
        reason="known failure (README, docs/observation.md): with the default hybrid observation the striker's "
               "blurred entry at the left edge gives extra movers on clip 05, and perception reads a side view",
        strict=False)),
])
def test_main_job_on_real_video(workspace, mask_method):
    """The main job on real clip 05 finds and places its two pucks (a known answer measured with
    ``median`` masks; with the default ``hybrid`` this clip is a known failure)."""
    ws, env = workspace
    video = REAL / "05_phystrack_CaromPuck_HeadOn_240fps.mp4"
    if not video.exists():
        pytest.skip("../shared/data/real not present")
    out = ws / f"out05_{mask_method}"
    _run([sys.executable, "-m", "pipeline.cli", "infer", str(video), "--fps", "240", "--start", "0.5",
          "--mask-method", mask_method, "--out", str(out), "--params", str(ws / "params.yaml")], ws, env)
    for name in ("scene.yaml", "side_by_side.mp4", "metrics.json", "recording.rrd"):
        assert (out / name).stat().st_size > 0, name
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["fps_used"] == 240 and metrics["window"]["frames"] == 30
    # known answer: two pucks, found and placed. Measured on this tiny profile (2026-11-23, same
    # window, identical before and after the issue-11 restructuring): 2 objects, Best@K initial
    # IoU 0.473, full IoU 0.097 -> refined full IoU 0.341, whose first frame scores 0.0 (the
    # sequence fitness trades the first frame, where the struck puck has not moved yet, for the
    # rest); the placement is checked on the Best@K pick, the refinement on the whole sequence
    from pipeline.scene import load_scene

    scene = load_scene(out / "scene.yaml")
    assert metrics["objects_found"] == 2 and len(scene.objects) == 2, metrics["objects_found"]
    assert metrics["best_of_k"]["initial_iou"] > 0.3, metrics["best_of_k"]
    # the refinement starts from the Best@K pick: scored at full size it must not be worse
    assert metrics["best_of_k_cmaes"]["full_iou"] >= metrics["best_of_k"]["full_iou"] - 0.02, metrics
    assert scene.fps == 30


@pytest.mark.slow
def test_bad_inputs_give_one_line_errors(workspace, tmp_path):
    ws, env = workspace
    bad = tmp_path / "bad.yaml"
    bad.write_text("version: 1\ncamera: {height: 1.2}\nobjects:\n  - shape: sphere\n    size: {radius: -1}\n"
                   "    mass: 1\n    position: [0, 0, 1]\n")
    cases = [
        (["simulate", str(bad), "--out", str(tmp_path / "sim")], "objects[0].size.radius"),
        (["infer", str(tmp_path / "missing.mp4"), "--out", str(tmp_path / "inf"), "--params", str(ws / "params.yaml")],
         "missing.mp4"),
        (["view", str(ws / "data" / "video" / "shard-00099.zarr"), "--save", str(tmp_path / "v.rrd"),
          "--params", str(ws / "params.yaml")], "shard-00099.zarr"),
    ]
    for args, needle in cases:
        proc = subprocess.run([sys.executable, "-m", "pipeline.cli", *args], cwd=ws, env=env, capture_output=True,
                              text=True, timeout=300)
        assert proc.returncode == 2, (args, proc.stderr)
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and needle in lines[0], proc.stderr
    assert not (tmp_path / "sim").exists() and not (tmp_path / "inf").exists() and not (tmp_path / "v.rrd").exists()


@pytest.mark.slow
def test_view_writes_a_recording(workspace, tmp_path):
    ws, env = workspace
    out = tmp_path / "scene.rrd"
    _run([sys.executable, "-m", "pipeline.cli", "view", str(ws / "data" / "video" / "shard-00000.zarr"),
          "--save", str(out), "--params", str(ws / "params.yaml")], ws, env)
    from pipeline.viz import recording_entities

    entities = recording_entities(out)
    assert any("world/objects" in e for e in entities) and any("camera/rgb" in e for e in entities)
