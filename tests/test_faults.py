"""Killed stages and reruns (issue 12 item 6): ``kill -9`` of a stage in the middle leaves no
partial shard and no readable output, the rerun completes it, and the same seed gives
byte-identical files (sha256) for every data stage; a stage script ends when dvc dies."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from pipeline import shards

ROOT = Path(__file__).resolve().parents[1]
DATA_STAGES = ("sample_configs", "compile_mjcf", "render", "flow", "events", "tokenize_targets")
OUTPUTS = {"sample_configs": ["configs"], "compile_mjcf": ["mjcf"], "render": ["video", "traces"], "flow": ["flow"],
           "events": ["events"], "tokenize_targets": ["tokenizer", "examples"]}


def _workspace(tmp_path: Path, name: str) -> tuple[Path, dict]:
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    params["sample"].update(n_train=6, n_val=2, n_test=2, n_test_comp=2, shard_size=4)
    params["compute"] = {"workers": 1}
    ws = tmp_path / name
    ws.mkdir()
    (ws / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    return ws, {**os.environ, "MUJOCO_GL": "egl", "PYTHONPATH": str(ROOT)}


def _run(ws: Path, env: dict, stage: str) -> None:
    proc = subprocess.run([sys.executable, str(ROOT / "stages" / f"{stage}.py")], cwd=ws, env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"{stage}:\n{proc.stderr[-2000:]}"


def _hashes(root: Path) -> dict[str, str]:
    """sha256 of every file under ``root`` (zarr stores are folders of files)."""
    return {str(f.relative_to(root)): hashlib.sha256(f.read_bytes()).hexdigest()
            for f in sorted(root.rglob("*")) if f.is_file()}


def _wait_for_a_shard(proc: subprocess.Popen, folder: Path, timeout: float = 300) -> None:
    """Until a finished shard (renamed into place: ``shard-*``) is in ``folder`` or ``proc`` ends."""
    deadline = time.time() + timeout
    while time.time() < deadline and proc.poll() is None:
        if folder.is_dir() and any(p.name.startswith("shard-") for p in folder.iterdir()):
            return
        time.sleep(0.05)


def test_render_killed_midway_then_rerun_equals_an_uninterrupted_run(tmp_path):
    """Workspace A runs the six data stages; workspace B the same, but render is killed with
    SIGKILL once it has written its first shard. After the kill: no meta.json, every visible
    shard is complete (its sha256 is A's), readers refuse the folder; then B reruns render and
    the rest, and every file of every data stage has A's sha256 (same seed, byte-identical)."""
    a, env = _workspace(tmp_path, "a")
    for stage in DATA_STAGES:
        _run(a, env, stage)
    ref = _hashes(a / "data")
    for stage in DATA_STAGES:
        for out in OUTPUTS[stage]:
            assert any(k.startswith(f"{out}/") for k in ref), out
            assert f"{out}/meta.json" in ref or out == "tokenizer", out

    b, env = _workspace(tmp_path, "b")
    _run(b, env, "sample_configs")
    _run(b, env, "compile_mjcf")
    proc = subprocess.Popen([sys.executable, str(ROOT / "stages" / "render.py")], cwd=b, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    video = b / "data" / "video"
    _wait_for_a_shard(proc, video)
    assert proc.poll() is None, "render finished before it could be killed (make the profile larger)"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (video / "meta.json").exists()
    for out in ("video", "traces"):
        folder = b / "data" / out
        if not folder.exists():
            continue
        for f in folder.rglob("*"):
            rel = str(f.relative_to(b / "data"))
            if f.is_file() and not any(part.startswith(".") for part in f.relative_to(folder).parts):
                assert _hashes(b / "data").get(rel) == ref.get(rel), f"partial file {rel}"
    with pytest.raises(shards.ShardError, match="meta.json: missing"):
        shards.list_shards(video, "zarr")
    for stage in DATA_STAGES[2:]:
        _run(b, env, stage)
    got = _hashes(b / "data")
    assert got.keys() == ref.keys()
    different = [k for k in ref if got[k] != ref[k]]
    assert not different, different


def test_stage_script_exits_when_dvc_dies(tmp_path):
    """``sh -c "python ..."`` with DVC_STAGE set (as dvc runs a stage): killing the process that
    started the shell ends the script within seconds (pipeline.stage_watchdog), where it used to keep
    running for minutes."""
    script = tmp_path / "stage.py"
    marker = tmp_path / "survived"
    script.write_text(f"import pipeline, time\nfor _ in range(60):\n    time.sleep(0.5)\n"
                      f"open({str(marker)!r}, 'w').close()\n")
    env = {**os.environ, "DVC_STAGE": "render", "PYTHONPATH": str(ROOT)}
    # the "dvc" here: a python process that starts the shell like dvc and then waits
    starter = subprocess.Popen([sys.executable, "-c", f"import subprocess, sys, time\n"
                                f"subprocess.Popen({sys.executable + ' ' + str(script)!r}, shell=True)\n"
                                "time.sleep(120)"], env=env)
    time.sleep(3)
    found = subprocess.run(["pgrep", "-f", str(script)], capture_output=True, text=True).stdout.split()
    assert found, "the stage script did not start"
    starter.kill()
    starter.wait()
    deadline = time.time() + 15
    while time.time() < deadline and any(Path(f"/proc/{p}").exists() and
                                         "stage.py" in Path(f"/proc/{p}/cmdline").read_text(errors="replace")
                                         for p in found):
        time.sleep(0.2)
    alive = [p for p in found if Path(f"/proc/{p}").exists()
             and "stage.py" in Path(f"/proc/{p}/cmdline").read_text(errors="replace")]
    assert not alive, alive
    assert not marker.exists()


# --------------------------------------------------------------------------- finetune
FINETUNE_MODEL = dict(n_frames=4, input="flow+rgb", hidden_size=64, intermediate_size=128, num_layers=2, num_heads=4,
                      num_kv_heads=2, vision_depth=2, vision_hidden_size=32, vision_intermediate_size=64,
                      vision_num_heads=2, batch_size=2, lr=3e-3, min_lr=1e-3, warmup_steps=2, max_steps=16,
                      eval_interval=2, eval_batches=1, eval_samples=0, max_new_tokens=160, k=2, threads=1,
                      init="scratch")
"""A ~190k-parameter model that saves a checkpoint every 2 of its 16 steps."""
TIMED = {"train_curve.csv", "trainer_state.pt", "result.json", "train_curve.png"}
"""Checkpoint files that hold wall-clock seconds (compared by content, not bytes)."""


def _finetune_workspace(tmp_path: Path, name: str) -> tuple[Path, dict]:
    """Six synthetic scenes (configs, think events, random flow and RGB) and the params of a
    tokenize + finetune run; the tokenize stage has run."""
    from pipeline.scene import Scene

    from conftest import write_model_inputs

    ws = tmp_path / name
    ws.mkdir()
    scenes = [Scene.from_dict({"camera": {"height": 1.2, "pitch": 35.0, "fov": 45.0},
                               "objects": [{"shape": "sphere", "size": {"radius": 0.1}, "mass": 0.5,
                                            "position": [0.0, 0.3, 0.1 * (i + 1)]}]}).to_yaml() for i in range(6)]
    data = ws / "data"
    write_model_inputs(data, scenes, "t=0.23 sphere_0 hits floor")
    paths = {k: str(data / k) for k in ("configs", "events", "flow", "video", "tokenizer", "examples", "model")}
    paths["reports"] = str(ws / "reports")
    (ws / "params.yaml").write_text(yaml.safe_dump({"seed": 1, "paths": paths, "model": FINETUNE_MODEL}))
    env = {**os.environ, "PYTHONPATH": str(ROOT), "DYNAMICS_PARAMS": str(ws / "params.yaml"),
           "HF_HUB_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1"}
    _run(ws, env, "tokenize_targets")
    return ws, env


def _finetune(ws: Path, env: dict) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(ROOT / "stages" / "finetune.py"), "--no-progress"], cwd=ws, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


@pytest.fixture(scope="module")
def finetune_reference(tmp_path_factory) -> tuple[Path, dict[str, str]]:
    """An uninterrupted finetune run: its workspace and the sha256 of its model folder."""
    a, env = _finetune_workspace(tmp_path_factory.mktemp("finetune"), "a")
    proc = _finetune(a, env)
    assert proc.wait(timeout=600) == 0, proc.stderr.read()[-2000:]
    ref = _hashes(a / "data" / "model")
    assert {"model.safetensors", "composition_head.pt", "codec.json", "trainer_state.pt", "result.json"} <= set(ref)
    return a, ref


@pytest.mark.parametrize("moment", ["after_a_checkpoint", "during_a_save"])
def test_finetune_killed_midway_then_rerun_equals_an_uninterrupted_run(tmp_path, finetune_reference, moment):
    """Finetune killed with SIGKILL just after its first checkpoint, or while a checkpoint is being
    written (its temporary folder exists): the model folder holds one whole checkpoint (it loads,
    passes check_checkpoint, its trainer state is readable) or none, never a mix, and no
    result.json; the rerun removes the leftovers and gives the uninterrupted run's bytes (weights,
    head, tokenizer, codec, config) and the same curve but for the seconds."""
    import csv

    import torch

    from pipeline.model import check_checkpoint, load_model

    a, ref = finetune_reference
    b, env = _finetune_workspace(tmp_path, "b")
    model = b / "data" / "model"

    def reached() -> bool:
        if moment == "after_a_checkpoint":
            return (model / "trainer_state.pt").exists()
        return any(p.name.startswith(".model.") for p in model.parent.iterdir())

    proc = _finetune(b, env)
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None and not reached():
        time.sleep(0.005)
    assert proc.poll() is None, "finetune ended before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (model / "result.json").exists()
    if moment == "during_a_save":    # the kill did hit the save: its temporary folder is left
        assert [p.name for p in model.parent.iterdir() if p.name.startswith(".model.")]
    if (model / "config.json").exists():
        check_checkpoint(model)
        load_model(model)
        state = torch.load(model / "trainer_state.pt", map_location="cpu", weights_only=False)
        assert 2 <= state["step"] < FINETUNE_MODEL["max_steps"]
        assert ref.keys() - TIMED - {"result.json"} <= set(_hashes(model)), "a checkpoint without some files"
    else:   # killed in the first save: no checkpoint at all, only what precedes it
        assert not model.exists() or {p.name for p in model.iterdir()} <= {"codec.json"}

    proc = _finetune(b, env)
    assert proc.wait(timeout=600) == 0, proc.stderr.read()[-2000:]
    got = _hashes(model)
    assert got.keys() == ref.keys()
    different = [k for k in ref if k not in TIMED and got[k] != ref[k]]
    assert not different, different

    def curve(ws: Path) -> list[dict]:
        with open(ws / "data" / "model" / "train_curve.csv", newline="") as f:
            return [{k: v for k, v in row.items() if k not in ("seconds", "examples_per_s")} for row in csv.DictReader(f)]
    assert curve(b) == curve(a) and len(curve(a)) == FINETUNE_MODEL["max_steps"] // 2
    # no temporary folder of the killed run is left beside the model
    assert not [p.name for p in (b / "data").iterdir() if p.name.startswith(".")]


# --------------------------------------------------------------------------- through dvc
DVC_FINETUNE = {"max_steps": 12, "eval_interval": 2, "eval_batches": 1, "eval_samples": 0, "batch_size": 2,
                "warmup_steps": 1}
"""model params of the DVC test: the shipped checkpoint (model.init) trained 12 steps, saved every 2."""


def _dvc_repo(tmp_path: Path) -> tuple[Path, dict]:
    """A fresh git + DVC repository of the project with the 12-scene profile."""
    import shutil

    ws, env = _workspace(tmp_path, "repo")
    params = yaml.safe_load((ws / "params.yaml").read_text())
    params["model"].update(DVC_FINETUNE)
    (ws / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    for name in ("stages", "pipeline"):   # pipeline/checkpoints: the shipped checkpoint (model.init: shipped)
        shutil.copytree(ROOT / name, ws / name, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "dvc.yaml", ws / "dvc.yaml")
    env = {**env, "PYTHONPATH": str(ws), "DVC_NO_ANALYTICS": "1", "HF_HUB_OFFLINE": "1",
           "TRANSFORMERS_OFFLINE": "1", "TOKENIZERS_PARALLELISM": "false",
           "PATH": str(Path(sys.executable).parent) + os.pathsep + os.environ.get("PATH", "")}
    for cmd in (["git", "init", "-q"],
                ["git", "-c", "user.email=ci@example.com", "-c", "user.name=ci", "commit", "-q", "--allow-empty",
                 "-m", "init"],
                [sys.executable, "-m", "dvc", "init", "-q"]):
        subprocess.run(cmd, cwd=ws, env=env, check=True, capture_output=True, timeout=120)
    return ws, env


@pytest.mark.slow
@pytest.mark.parametrize("stage, script, written", [
    ("render", "stages/render.py", lambda ws: any(p.name.startswith("shard-") for p in (ws / "data" / "video").glob("*"))),
    ("finetune", "stages/finetune.py", lambda ws: (ws / "data" / "model" / "trainer_state.pt").exists()),
])
def test_kill_dvc_during_a_stage_then_status_and_repro(tmp_path, stage, script, written):
    """In a fresh DVC repository of the project (12-scene profile): ``kill -9`` of ``dvc repro``
    once the stage has written (render: its first shard; finetune: its first checkpoint) ends
    the stage script within seconds (pipeline.stage_watchdog; it used to keep writing for minutes) and
    leaves it unfinished (no meta.json / result.json); ``dvc status`` lists the stage as changed;
    the next ``dvc repro`` completes it (render: with the bytes of a direct run; finetune: all
    steps, a loadable checkpoint) and ``dvc status`` is clean."""
    import json

    ws, env = _dvc_repo(tmp_path)
    dvc = [sys.executable, "-m", "dvc"]

    def run(*cmd: str) -> str:
        proc = subprocess.run(list(cmd), cwd=ws, env=env, capture_output=True, text=True, timeout=900)
        assert proc.returncode == 0, f"{cmd}:\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}"
        return proc.stdout

    upstream = {"render": "compile_mjcf", "finetune": "tokenize"}[stage]
    run(*dvc, "repro", upstream)
    if stage == "finetune":
        run(*dvc, "repro", "flow")
    repro = subprocess.Popen([*dvc, "repro", "--single-item", stage], cwd=ws, env=env, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
    deadline = time.time() + 600
    while time.time() < deadline and repro.poll() is None and not written(ws):
        time.sleep(0.02)
    children = subprocess.run(["ps", "-o", "pid=", "--ppid", str(repro.pid)], capture_output=True,
                              text=True).stdout.split()
    pids = [int(p) for p in children if script in Path(f"/proc/{p}/cmdline").read_text(errors="replace")]
    assert repro.poll() is None and pids, f"{stage} finished before dvc could be killed"
    repro.kill()
    repro.wait()
    killed = time.time()
    while time.time() < killed + 15 and Path(f"/proc/{pids[0]}").exists():
        time.sleep(0.05)
    assert not Path(f"/proc/{pids[0]}").exists(), "the stage script outlived dvc by 15 s"
    unfinished = ws / "data" / ("video/meta.json" if stage == "render" else "model/result.json")
    assert not unfinished.exists()
    assert stage in json.loads(run(*dvc, "status", "--json", stage))
    run(*dvc, "repro", "--single-item", stage)
    assert json.loads(run(*dvc, "status", "--json", stage)) == {}

    if stage == "render":
        direct, env_d = _workspace(tmp_path, "direct")
        for name in ("sample_configs", "compile_mjcf", "render"):
            _run(direct, env_d, name)
        ref = _hashes(direct / "data")
        got = {k: v for k, v in _hashes(ws / "data").items() if k != ".gitignore" and not k.startswith(("flow/", "events/"))}
        assert got == ref
    else:
        from pipeline.model import check_checkpoint

        check_checkpoint(ws / "data" / "model")
        result = json.loads((ws / "data" / "model" / "result.json").read_text())
        assert result["step"] == DVC_FINETUNE["max_steps"], result
        assert not [p.name for p in (ws / "data").iterdir() if p.name.startswith(".model.")]
