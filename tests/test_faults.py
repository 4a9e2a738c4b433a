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
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None:
        if video.is_dir() and any(p.name.startswith("shard-") for p in video.iterdir()):
            break
        time.sleep(0.05)
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
    started the shell ends the script within seconds (pipeline.orphan), where it used to keep
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
