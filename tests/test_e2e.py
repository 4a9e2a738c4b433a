"""Tiny end-to-end run: a few scenes through every DVC stage, then the main job on a real video.

Checks the pipeline contract rather than model quality: `dvc repro` builds every stage, a
second `dvc repro` does nothing, changing one param marks only the stages downstream of it,
and the reports have the paper-style rows (with the trivial baseline).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "real" / "video"

TINY = {
    "sample": {"n_train": 8, "n_val": 2, "n_test": 2, "n_test_comp": 2, "shard_size": 4},
    "render": {"width": 48, "height": 32},
    # max_new_tokens stays at its default: it must cover the longest target (tests/test_model.py)
    "model": {"max_steps": 4, "eval_interval": 2, "eval_batches": 1, "eval_samples": 2, "batch_size": 2,
              "warmup_steps": 1, "k": 2},
    "search": {"k": 2, "popsize": 4, "iterations": 1},
    "measure_hidden": {"effect": "quadratic_drag", "n_clips": 2, "duration": 0.5},
    "discrepancy": {"max_effects": 1, "max_nfev": 6, "max_nfev_warm": 4, "recording": False},
}


def _merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(base[k], v) if isinstance(v, dict) and isinstance(base.get(k), dict) else v
    return out


def _run(cmd: list[str], cwd: Path, env: dict, timeout: int = 900) -> subprocess.CompletedProcess:
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    if proc.returncode != 0:
        raise AssertionError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stdout[-4000:]}\n{proc.stderr[-4000:]}")
    return proc


@pytest.fixture(scope="module")
def workspace(tmp_path_factory) -> tuple[Path, dict]:
    ws = tmp_path_factory.mktemp("e2e")
    for name in ("dvc.yaml", ".gitignore"):
        shutil.copy(ROOT / name, ws / name)
    for name in ("stages", "pipeline"):  # pipeline/checkpoints: the shipped checkpoint (model.init: shipped)
        if (ROOT / name).exists():
            shutil.copytree(ROOT / name, ws / name, ignore=shutil.ignore_patterns("__pycache__"))
    params = _merge(yaml.safe_load((ROOT / "params.yaml").read_text()), TINY)
    (ws / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    bindir = str(Path(sys.executable).parent)
    env = {**os.environ, "PATH": bindir + os.pathsep + os.environ.get("PATH", ""), "HF_HUB_OFFLINE": "1",
           "TOKENIZERS_PARALLELISM": "false", "PYTHONPATH": str(ws), "DVC_NO_ANALYTICS": "1"}
    _run(["git", "init", "-q"], ws, env)
    _run(["git", "-c", "user.email=ci@example.com", "-c", "user.name=ci", "commit", "-q", "--allow-empty", "-m", "init"], ws, env)
    _run([sys.executable, "-m", "dvc", "init", "-q"], ws, env)
    _run([sys.executable, "-m", "dvc", "config", "core.analytics", "false"], ws, env)
    _run([sys.executable, "-m", "dvc", "repro"], ws, env)
    return ws, env


@pytest.mark.slow
def test_repro_builds_every_stage_and_reports(workspace):
    ws, _ = workspace
    for stage_dir in ("configs", "mjcf", "video", "traces", "flow", "events", "tokenizer", "examples", "model",
                      "predictions", "best_of_k", "cmaes", "hidden", "hidden_truth", "discrepancy"):
        assert (ws / "data" / stage_dir).is_dir(), stage_dir
    metrics = json.loads((ws / "reports" / "metrics.json").read_text())
    assert metrics, "empty metrics"
    table = (ws / "reports" / "table.md").read_text()
    assert "Trivial baseline" in table and "CMA-ES" in table
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
    assert set(status) == {"cmaes", "score"}, status
    params["search"]["popsize"] = 4
    (ws / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    params["model"]["reasoning"] = False
    (ws / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    status = json.loads(_run([sys.executable, "-m", "dvc", "status", "--json"], ws, env).stdout)
    # stages that read model.reasoning directly (best_of_k/cmaes rerun later only if predictions change)
    assert set(status) == {"tokenize", "finetune", "predict", "score"}, status
    params["model"]["reasoning"] = True
    (ws / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))


@pytest.mark.slow
def test_main_job_on_real_video(workspace):
    ws, env = workspace
    video = REAL / "05_phystrack_CaromPuck_HeadOn_240fps.mp4"
    if not video.exists():
        pytest.skip("../shared/data/real not present")
    out = ws / "out05"
    _run([sys.executable, "-m", "pipeline.cli", "infer", str(video), "--fps", "240", "--start", "0.5",
          "--out", str(out), "--params", str(ws / "params.yaml")], ws, env)
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
