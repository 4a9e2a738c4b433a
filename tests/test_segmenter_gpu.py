"""``scripts/segmenter_gpu.py`` (issue 36), run on the CPU at toy size: generators render clips for
a fixed time and stop, two networks train on them at once with a schedule that ends at the
deadline, and each sends back a checkpoint the observation loads, with its card."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.segmenter import Segmenter

ROOT = Path(__file__).resolve().parents[1]


def test_gpu_segmenter_script_renders_trains_two_networks_and_sends_back_checkpoints(tmp_path):
    out = tmp_path / "out"
    p = subprocess.run([sys.executable, str(ROOT / "scripts" / "segmenter_gpu.py"), "--out", str(out),
                        "--work", str(tmp_path / "work"), "--budget-s", "30", "--gen-s", "8", "--gen-procs", "2",
                        "--reserve-s", "10", "--device", "cpu", "--batch", "2", "--per-clip", "4",
                        "--run", "a:8,16,24:0.5", "--run", "b:8,16:0"],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    numbers = json.loads((out / "numbers.json").read_text())
    assert numbers["clips"] >= 1
    for name, channels, realism in (("a", (8, 16, 24), 0.5), ("b", (8, 16), 0.0)):
        card = numbers["runs"][name]["card"]
        assert card["schedule"] == "time" and card["steps"] >= 1 and card["realism_fraction"] == realism
        assert card["clips"] == numbers["clips"]
        assert Segmenter(out / f"{name}.pt").net.channels == channels
    # what comes back from a lent machine: at most 8 files
    assert len([f for f in out.iterdir() if f.is_file()]) <= 8


def test_run_specs_are_checked():
    sys.path.insert(0, str(ROOT / "scripts"))
    try:
        import segmenter_gpu
    finally:
        sys.path.pop(0)
    assert segmenter_gpu.parse_run("wide:24,48,64,96:0.5") == ("wide", [24, 48, 64, 96], 0.5)
    with pytest.raises(Exception, match="NAME:C1,C2"):
        segmenter_gpu.parse_run("wide:24:2")
