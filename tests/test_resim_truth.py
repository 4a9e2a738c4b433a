"""``benchmarks/resim_truth.py``: a rendered clip the main job refuses is a scored miss, not a crash."""

import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import resim_truth  # noqa: E402
from conftest import still_textured_mp4  # noqa: E402
from pipeline.params import load_params  # noqa: E402


def test_a_clip_with_nothing_in_view_scores_zero_against_its_true_object(tmp_path):
    """A still, textured clip whose truth holds one object the observation cannot see (it never
    moves and looks like the background): the main job stops (nothing seen in the window), and
    the benchmark row scores the re-simulation and the observation 0 against the truth, with no
    object written, instead of the whole benchmark failing."""
    clip = tmp_path / "clip-00000"
    clip.mkdir()
    still_textured_mp4(clip / "video.mp4", 160, 120)
    seg = np.full((45, 120, 160), -1, np.int8)
    seg[:, 50:70, 60:80] = 0
    np.savez(clip / "truth.npz", seg=seg, fps=np.float64(30.0))
    (clip / "meta.json").write_text(json.dumps({"objects": [{"shape": "box"}]}))
    row = resim_truth.run_clip(clip, load_params(ROOT / "params.yaml"), tmp_path / "work")
    assert row["resim_vs_truth"] == 0.0 and row["observation_vs_truth"] == 0.0
    assert row["objects_written"] == 0 and row["objects_true"] == 1 and row["shapes_true"] == ["box"]
    assert "nothing to reconstruct" in row["error"]
    written = tmp_path / "work" / "clip-00000"
    assert (written / "observation.npz").is_file() and not (written / "scene.yaml").exists()
    summary = resim_truth.summarize([row])
    assert summary["resim_vs_truth"] == 0.0 and summary["count_right"] == 0.0
