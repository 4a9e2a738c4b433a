"""The package runs outside the checkout (issue 32): a non-editable ``pip install`` into a fresh
venv, then ``dynamics infer clip.mp4 --out out`` in an empty folder uses the shipped default
params and the shipped checkpoint, both package data."""

import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import cv2
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _clip(path: Path, fps: int = 30, seconds: float = 1.5, size: tuple[int, int] = (320, 240)) -> None:
    """A red disc rolling left to right across a grey floor (mp4v)."""
    w, h = size
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
    for i in range(int(fps * seconds)):
        img = np.full((h, w, 3), 170, np.uint8)
        cv2.circle(img, (40 + 5 * i, 150), 18, (30, 30, 220), -1)
        writer.write(img)
    writer.release()


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """A fresh venv holding a non-editable install of a copy of the project (only what the
    wheel is built from: pyproject.toml, README.md, params.yaml, pipeline/). Its dependencies come from this
    interpreter's site-packages through a .pth file (no download; pip and setuptools too); this checkout's own
    ``pipeline`` is not importable there (the editable finder is not loaded from a .pth path)."""
    tmp = tmp_path_factory.mktemp("install")
    src = tmp / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md", "params.yaml"):
        shutil.copy(ROOT / name, src / name)
    shutil.copytree(ROOT / "pipeline", src / "pipeline", symlinks=True,   # defaults/params.yaml stays a link
                    ignore=shutil.ignore_patterns("__pycache__"))
    venv = tmp / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)   # pip via the .pth
    py = venv / "bin" / "python"
    site = Path(subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               check=True, capture_output=True, text=True).stdout.strip())
    (site / "zz_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    proc = subprocess.run([str(py), "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation", str(src)],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return venv


def _env() -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "DYNAMICS_PARAMS", "VIRTUAL_ENV")}
    return {**env, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "HF_HUB_OFFLINE": "1",
            "TRANSFORMERS_OFFLINE": "1", "TOKENIZERS_PARALLELISM": "false"}


@pytest.mark.slow
def test_installed_package_imports_from_the_venv_not_the_checkout(installed, tmp_path):
    py = installed / "bin" / "python"
    code = ("import pipeline, pipeline.params as p, pipeline.model as m; "
            "print(pipeline.__file__); print(p.DEFAULTS_FILE.is_file() and not p.DEFAULTS_FILE.is_symlink()); "
            "print((m.SHIPPED_CHECKPOINT / 'model.safetensors').is_file())")
    out = subprocess.run([str(py), "-c", code], cwd=tmp_path, env=_env(), capture_output=True, text=True, check=True)
    where, defaults_copied, checkpoint = out.stdout.split()
    assert Path(where).is_relative_to(installed), where       # not this checkout
    assert defaults_copied == "True" and checkpoint == "True"
    help_ = subprocess.run([str(py), "-m", "pipeline", "--help"], cwd=tmp_path, env=_env(), capture_output=True,
                           text=True)
    assert help_.returncode == 0 and "infer" in help_.stdout


@pytest.mark.slow
def test_installed_infer_runs_in_an_empty_folder_and_uses_the_model(installed, tmp_path):
    work = tmp_path / "empty"
    work.mkdir()
    _clip(work / "clip.mp4")
    proc = subprocess.run([str(installed / "bin" / "dynamics"), "infer", "clip.mp4", "--out", "out"], cwd=work,
                          env=_env(), capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    metrics = json.loads((work / "out" / "metrics.json").read_text())
    assert metrics["model_note"] is None                        # the shipped checkpoint was found
    assert metrics["sources"]["model"]["proposals"] >= 1
    assert (work / "out" / "scene.yaml").is_file()
    assert sorted(p.name for p in work.iterdir()) == ["clip.mp4", "out"]   # nothing written beside it
