"""The committed real-video report is current (issue 32): one clip of ``make realvideo`` rerun on
this tree with the project's params gives the numbers ``reports/realvideo/`` holds.

Runs on one machine repeat exactly; between machines the staged CMA-ES can end up to ~0.09 IoU
apart on a clip (docs/design.md §11), so the stated tolerance is :data:`TOLERANCE`. A change in
the main job's code that moves this clip further means the report (and README's table) must be
regenerated: ``make realvideo``.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "real" / "video"
CLIP, FILE = "02_ball_on_ramp", "02_tracker_BallOnRamp_30fps.mp4"   # 30 fps, 4 labelled frames, ~20 s
TOLERANCE = 0.15
"""Largest accepted difference of an IoU of the search from the committed report (machine to
machine; on one machine it repeats exactly)."""
OBSERVATION_TOLERANCE = 0.02
"""The same for the observation (background subtraction and tracking: integer image operations,
nearly exact across machines)."""


@pytest.mark.slow
def test_one_real_clip_reproduces_the_committed_report(tmp_path):
    video = REAL / FILE
    if not video.exists():
        pytest.skip("../shared/data/real not present")
    committed = json.loads((ROOT / "reports" / "realvideo" / CLIP / "metrics.json").read_text())
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"),
           "HF_HUB_OFFLINE": "1", "TOKENIZERS_PARALLELISM": "false"}
    env.pop("DYNAMICS_PARAMS", None)
    out = tmp_path / CLIP
    proc = subprocess.run([sys.executable, "-m", "pipeline", "infer", str(video), "--out", str(out),
                           "--labels", str(ROOT / "tests" / "fixtures" / "realvideo" / "02")],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    now = json.loads((out / "metrics.json").read_text())
    # the same window, crop and objects: the observation is (nearly) deterministic
    assert now["window"] == committed["window"]
    assert now["against_labels"]["observation_vs_labels"] == pytest.approx(
        committed["against_labels"]["observation_vs_labels"], abs=OBSERVATION_TOLERANCE)
    for key in ("best_of_k", "best_of_k_cmaes"):
        assert now[key]["full_iou"] == pytest.approx(committed[key]["full_iou"], abs=TOLERANCE), key
    assert now["against_labels"]["resim_vs_labels"] == pytest.approx(
        committed["against_labels"]["resim_vs_labels"], abs=TOLERANCE)
