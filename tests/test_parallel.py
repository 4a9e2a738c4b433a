"""Scale out on Ray (issue 13): params ``compute`` picks the backend of ``pipeline.parallel``.

* ``compute`` errors are one line naming the key.
* The data stages write sha256-identical shards with ``local`` on 1 and 2 workers and with
  ``ray`` on a local 2-CPU cluster (``ray start --head``).
* A Ray worker killed (SIGKILL, by pid) in the middle of a render task: Ray runs the task
  again and the render shards equal the reference, every scene exactly once.
* A scene whose simulation diverges is listed by id in render's meta.json, not dropped silently.
"""

import pipeline  # noqa: F401  (MUJOCO_GL before mujoco)

import hashlib
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from pipeline import shards
from pipeline.params import ParamsError
from pipeline.parallel import ComputeConfig, compute_from_params, parallel_map

ROOT = Path(__file__).resolve().parents[1]
DATA_STAGES = ("sample_configs", "compile_mjcf", "render", "flow", "events")
RAY = shutil.which("ray", path=os.path.dirname(sys.executable)) or shutil.which("ray")


@pytest.mark.parametrize("section, message", [
    ({"backend": "x"}, "params.yaml: compute.backend: must be one of local, ray, got 'x'"),
    ({"workers": 0}, "params.yaml: compute.workers: must be a positive integer or null, got 0"),
    ({"workers": "2"}, "params.yaml: compute.workers: must be a positive integer or null, got '2'"),
    ({"address": "cluster"}, "params.yaml: compute.address: must be null, auto, ray://host:port or host:port, "
                             "got 'cluster'"),
    ({"nodes": 3}, "params.yaml: compute.nodes: unknown key (known: backend, address, workers)"),
])
def test_compute_errors_are_one_line(section, message):
    with pytest.raises(ParamsError) as exc:
        compute_from_params({"compute": section})
    assert str(exc.value) == message


def test_compute_defaults_and_local_map_order():
    assert compute_from_params({}) == ComputeConfig(backend="local", address=None, workers=2)   # the default profile
    cfg = compute_from_params({"compute": {"backend": "ray", "address": "ray://head:10001", "workers": 4}})
    assert (cfg.backend, cfg.address, cfg.workers) == ("ray", "ray://head:10001", 4)
    assert list(parallel_map(abs, [-3, 2, -1], 1)) == [3, 2, 1]


# ---------------------------------------------------------------------------- workspaces
def _env() -> dict:
    return {**os.environ, "MUJOCO_GL": "egl", "PYTHONPATH": str(ROOT), "RAY_USAGE_STATS_ENABLED": "0",
            "RAY_AUTH_MODE": "disabled"}  # a test cluster without token auth (Ray 2.60 enables it on `ray start`)


def _workspace(root: Path, name: str, compute: dict) -> Path:
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    params["sample"].update(n_train=6, n_val=2, n_test=2, n_test_comp=2, shard_size=4)  # 12 scenes, 3 shards
    params["compute"] = compute
    ws = root / name
    ws.mkdir()
    (ws / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    return ws


def _run(ws: Path, stage: str) -> subprocess.CompletedProcess:
    proc = subprocess.run([sys.executable, str(ROOT / "stages" / f"{stage}.py")], cwd=ws, env=_env(),
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"{ws.name} {stage}:\n{proc.stderr[-3000:]}"
    return proc


def _hashes(root: Path) -> dict[str, str]:
    """sha256 of every file under ``root`` (zarr stores are folders of files)."""
    return {str(f.relative_to(root)): hashlib.sha256(f.read_bytes()).hexdigest()
            for f in sorted(root.rglob("*")) if f.is_file()}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def ray_cluster(tmp_path_factory):
    """A local 2-CPU Ray cluster (``ray start --head``); yields its address; ``ray stop`` after."""
    if RAY is None:
        pytest.fail("the `ray` command is missing: pip install -e . installs ray (pyproject.toml)")
    port = _free_port()
    start = subprocess.run([RAY, "start", "--head", "--num-cpus", "2", "--port", str(port),
                            "--node-ip-address", "127.0.0.1", "--include-dashboard=false", "--disable-usage-stats"],
                           env=_env(), capture_output=True, text=True, timeout=180)
    assert start.returncode == 0, start.stderr[-3000:]
    try:
        yield f"127.0.0.1:{port}"
    finally:
        subprocess.run([RAY, "stop", "--force"], env=_env(), capture_output=True, timeout=120)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The data stages with ``local`` on 1 worker: the workspace and the sha256 of its data/."""
    ws = _workspace(tmp_path_factory.mktemp("reference"), "local1", {"backend": "local", "workers": 1})
    for stage in DATA_STAGES:
        _run(ws, stage)
    return ws, _hashes(ws / "data")


def test_same_shards_on_local_1_local_2_and_ray(tmp_path, reference, ray_cluster):
    ref_ws, ref = reference
    # 3 shards of configs, mjcf, video (zarr: many files), traces, flow, events (+ think), meta.json each
    assert sum(k.endswith("meta.json") for k in ref) == 6
    for out in ("configs", "mjcf", "traces"):
        assert sum(k.startswith(f"{out}/shard-") for k in ref) == 3, out
    assert any(k.startswith("video/shard-00002.zarr/") for k in ref)
    for name, compute in (("local2", {"backend": "local", "workers": 2}),
                          ("ray2", {"backend": "ray", "address": ray_cluster, "workers": 2})):
        ws = _workspace(tmp_path, name, compute)
        for stage in DATA_STAGES:
            _run(ws, stage)
        got = _hashes(ws / "data")
        assert got.keys() == ref.keys(), name
        assert [k for k in ref if got[k] != ref[k]] == [], name


def _render_task_pids() -> list[int]:
    """Processes whose title is a running render task (Ray names them ``ray::<function>``)."""
    pids = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            except OSError:
                continue
            if cmd.startswith("ray::render_shard"):
                pids.append(int(d.name))
    return pids


def test_ray_worker_killed_mid_render_task_is_retried(tmp_path, reference, ray_cluster):
    ref_ws, ref = reference
    ws = _workspace(tmp_path, "killed", {"backend": "ray", "address": ray_cluster, "workers": 2})
    for name in ("configs", "mjcf"):  # render's inputs, as the reference made them
        shutil.copytree(ref_ws / "data" / name, ws / "data" / name)
    proc = subprocess.Popen([sys.executable, str(ROOT / "stages" / "render.py")], cwd=ws, env=_env(),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    killed = None
    deadline = time.time() + 300
    while killed is None and time.time() < deadline and proc.poll() is None:
        pids = _render_task_pids()
        if pids:
            os.kill(pids[0], signal.SIGKILL)  # the worker process, in the middle of a render task
            killed = pids[0]
        time.sleep(0.02)
    _, err = proc.communicate(timeout=600)
    assert killed is not None, "no render task was seen running"
    assert proc.returncode == 0, err[-3000:]
    assert not Path(f"/proc/{killed}").exists()
    got = _hashes(ws / "data")
    for out in ("video", "traces"):
        keys = [k for k in ref if k.startswith(f"{out}/")]
        assert sorted(k for k in got if k.startswith(f"{out}/")) == sorted(keys), out  # no temp left behind
        assert [k for k in keys if got[k] != ref[k]] == [], out
    ids = [i for s in shards.list_shards(ws / "data" / "video", "zarr") for i in shards.scene_ids_of(shards.open_arrays(s))]
    configs = [r["scene_id"] for s in shards.list_shards(ws / "data" / "configs", "parquet")
               for r in shards.read_table(s, columns=["scene_id"]).to_pylist()]
    assert sorted(ids) == sorted(configs) and len(ids) == len(set(ids)) == 12  # none lost, none twice


def test_failed_simulation_is_listed_in_meta(tmp_path, reference):
    ref_ws, _ = reference
    ws = _workspace(tmp_path, "diverge", {"backend": "local", "workers": 1})
    shutil.copytree(ref_ws / "data" / "mjcf", ws / "data" / "mjcf")
    shard = shards.list_shards(ws / "data" / "mjcf", "parquet")[1]
    table = shards.read_table(shard)
    rows = table.to_pylist()
    bad = rows[2]["scene_id"]
    rows[2]["mjcf"] = re.sub(r'gravity="[^"]*"', 'gravity="0 0 -1e300"', rows[2]["mjcf"], count=1)  # diverges
    shards.write_table(shard, rows, schema=table.schema)
    proc = _run(ws, "render")
    assert bad in proc.stdout
    for out in ("video", "traces"):
        meta = json.loads((ws / "data" / out / "meta.json").read_text())
        assert [f["scene_id"] for f in meta["failed"]] == [bad], out
        assert "simulation diverged" in meta["failed"][0]["error"]
    ids = [i for s in shards.list_shards(ws / "data" / "video", "zarr") for i in shards.scene_ids_of(shards.open_arrays(s))]
    assert len(ids) == 11 and bad not in ids
