"""``scripts/pretrain_gpu.py`` (issue 30), run on the CPU at toy size: the data stages of the wide
profile, a warm start from the shipped checkpoint across codecs, and the model folder sent back in
pieces of at most 15 MB that reassemble into a checkpoint ``load_model`` reads."""

import json
import subprocess
import sys
import tarfile
from pathlib import Path

import pipeline  # noqa: F401  (MUJOCO_GL before mujoco)
from pipeline import model as M

ROOT = Path(__file__).resolve().parents[1]


def test_gpu_pretraining_script_runs_and_sends_back_a_checkpoint(tmp_path):
    out = tmp_path / "out"
    p = subprocess.run([sys.executable, str(ROOT / "scripts" / "pretrain_gpu.py"), "--out", str(out),
                        "--work", str(tmp_path / "work"), "--profile", str(ROOT / "profiles" / "pretrain_wide.yaml"),
                        "--device", "cpu", "--workers", "1", "--batch-size", "2", "--n-train", "12",
                        "--max-steps", "2", "--init", "shipped", "--budget-s", "600"],
                       capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    numbers = json.loads((out / "numbers.json").read_text())
    assert numbers["n_train"] == 12 and numbers["result"]["step"] == 2
    parts = sorted(out.glob("model.tar.part*"))
    assert parts and all(q.stat().st_size <= 15 * 2**20 for q in parts)
    tar = tmp_path / "model.tar"
    tar.write_bytes(b"".join(q.read_bytes() for q in parts))
    with tarfile.open(tar) as tf:
        tf.extractall(tmp_path / "back", filter="data")
    model_dir = tmp_path / "back" / "model"
    model, tok = M.load_model(model_dir)
    codec, _ = M.load_codec(model_dir)
    shipped, _ = M.load_codec(M.SHIPPED_CHECKPOINT)
    assert codec.max_objects == 6 and codec.to_dict() != shipped.to_dict()   # the wide profile's codec
    assert (model_dir / "profile.yaml").exists() and (model_dir / "trainer_state.pt").exists()
