"""Bounded memory (issue 35, item 3): `dynamics simulate` and the render stage stream their outputs.

What is checked here is behaviour: streamed files equal what the whole-clip writers wrote (masks,
videos, Zarr shards), the videos have every frame, and a run that fails or is killed midway
leaves no output folder and no complete-looking files. Memory itself is measured by
``benchmarks/sim_memory.py``, not asserted here.
"""

import pipeline  # noqa: F401  (MUJOCO_GL before mujoco)

import argparse
import hashlib
import io
import json
import os
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import cv2
import numpy as np
import pytest

from pipeline import cli, shards, traces
from pipeline.atomic import publish_dir
from pipeline.mjcf import SimOptions, compile_model
from pipeline.npz import NpzWriter
from pipeline.render import FrameRenderer
from pipeline.scene import Scene
from pipeline.simulate import rollout
from pipeline.viz import Mp4Writer, mask_colours, mask_overlay, side_by_side_mp4

ROOT = Path(__file__).resolve().parents[1]

SCENE = """\
duration: 1.0
fps: 40
camera: {height: 1.1, pitch: 35.0, fov: 50.0}
objects:
  - shape: cylinder
    size: {radius: 0.08, height: 0.2}
    mass: 0.7
    position: [-0.2, 0.1, 0.5]
    linear_velocity: [0.4, 0.0, 0.0]
  - shape: sphere
    size: {radius: 0.12}
    mass: 0.3
    position: [0.3, 0.0, 0.12]
    linear_velocity: [-0.3, 0.1, 0.0]
"""
W, H = 50, 34


def _simulate(argv) -> int:
    parser = cli.add_simulate_arguments(argparse.ArgumentParser(prog="dynamics simulate"))
    return cli.simulate_cli(parser.parse_args(argv))


def _decode(path: Path) -> tuple[int, list[np.ndarray]]:
    """(container frame count, decoded BGR frames) of an mp4."""
    cap = cv2.VideoCapture(str(path))
    count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame)
    cap.release()
    return count, frames


def _siblings(out: Path) -> list[str]:
    """Entries beside ``out`` that belong to it (``out`` itself, its temporaries)."""
    return sorted(p.name for p in out.parent.iterdir() if p.name == out.name or p.name.startswith(f".{out.name}."))


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# --------------------------------------------------------------------------- npz
def test_streamed_npz_reads_back_as_savez_compressed(tmp_path):
    rng = np.random.default_rng(0)
    seg = rng.integers(-1, 3, (23, 7, 9), dtype=np.int8)
    names = np.asarray(["sphere_0", "box_1", "cylinder_2"])
    path = tmp_path / "masks.npz"
    with NpzWriter(path) as npz:
        with npz.stream("seg", seg.shape, np.int8) as stream:
            for a, b in ((0, 5), (5, 5), (5, 6), (6, 23)):  # uneven chunks, an empty one, one frame
                stream.write(seg[a:b])
        npz.write("names", names)
    ref = io.BytesIO()
    np.savez_compressed(ref, seg=seg, names=names)
    got, want = np.load(path), np.load(io.BytesIO(ref.getvalue()))
    assert got.files == want.files == ["seg", "names"]
    assert got["seg"].dtype == np.int8 and np.array_equal(got["seg"], want["seg"])
    assert np.array_equal(got["names"], want["names"])
    # the same archive, member by member: the .npy bytes (header included) and the compression
    with zipfile.ZipFile(path) as a, zipfile.ZipFile(io.BytesIO(ref.getvalue())) as b:
        for x, y in zip(a.infolist(), b.infolist()):
            assert (x.filename, x.compress_type, x.CRC) == (y.filename, y.compress_type, y.CRC)
            assert a.read(x) == b.read(y)
    assert [p.name for p in tmp_path.iterdir()] == ["masks.npz"]  # no temporary left


def test_npz_stream_refuses_a_wrong_row_count_and_leaves_nothing(tmp_path):
    path = tmp_path / "masks.npz"
    with pytest.raises(ValueError, match="seg: must have 4 rows, got 3"):
        with NpzWriter(path) as npz:
            with npz.stream("seg", (4, 2, 2), np.int8) as stream:
                stream.write(np.zeros((3, 2, 2), np.int8))
    with pytest.raises(ValueError, match=r"seg: a chunk must be \(k, 2, 2\) int8, got \(1, 2, 2\) int16"):
        with NpzWriter(path) as npz:
            with npz.stream("seg", (4, 2, 2), np.int8) as stream:
                stream.write(np.zeros((1, 2, 2), np.int16))
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- mp4
def test_mp4_writer_keeps_every_frame_and_equals_the_whole_clip_writer(tmp_path):
    rng = np.random.default_rng(1)
    rgb = rng.integers(0, 256, (17, 21, 30, 3), dtype=np.uint8)   # odd sizes: padded
    seg = rng.integers(-1, 2, (17, 21, 30), dtype=np.int8)
    streamed = tmp_path / "streamed.mp4"
    with Mp4Writer(streamed, ["rgb", "seg"], fps=25) as video:
        video.write([rgb[0], mask_overlay(rgb[0], seg[0])])          # one frame
        for a in range(1, 17, 6):                                     # chunks of 6, 6, 4
            video.write([rgb[a:a + 6], mask_overlay(rgb[a:a + 6], seg[a:a + 6])])
        assert video.frames == 17
    whole = side_by_side_mp4(tmp_path / "whole.mp4", [rgb, mask_overlay(rgb, seg)], ["rgb", "seg"], fps=25)
    count, frames = _decode(streamed)
    assert count == len(frames) == 17 and frames[0].shape == (22, 60, 3)
    assert streamed.read_bytes() == whole.read_bytes()               # the same encoder input, frame by frame
    assert sorted(p.name for p in tmp_path.iterdir()) == ["streamed.mp4", "whole.mp4"]


def test_mp4_writer_removes_its_temporary_on_error(tmp_path):
    path = tmp_path / "v.mp4"
    frame = np.zeros((8, 8, 3), np.uint8)
    with pytest.raises(ValueError, match="must keep height and widths"):
        with Mp4Writer(path, [""], fps=10) as video:
            video.write([frame])
            video.write([np.zeros((8, 10, 3), np.uint8)])
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ValueError, match="labels: must have one per column"):
        side_by_side_mp4(path, [frame[None], frame[None]], ["a"], fps=10)
    assert list(tmp_path.iterdir()) == []


def test_mask_colours_is_the_overlay_on_black():
    seg = np.random.default_rng(2).integers(-1, 25, (3, 11, 13), dtype=np.int8)
    assert np.array_equal(mask_colours(seg), mask_overlay(np.zeros(seg.shape + (3,), np.uint8), seg, alpha=1.0))


# --------------------------------------------------------------------------- dynamics simulate
@pytest.fixture
def scene_file(tmp_path):
    path = tmp_path / "scene.yaml"
    path.write_text(SCENE)
    return path


def test_streamed_simulate_equals_the_in_memory_render(tmp_path, scene_file, monkeypatch):
    """Chunks of 7 frames (40 frames: 6 chunks, the last short): masks, videos and events equal
    what one whole-clip render gives."""
    monkeypatch.setattr(traces, "RENDER_CHUNK_FRAMES", 7)
    assert traces.chunk_frames(W, H) == 7
    out = tmp_path / "out"
    assert _simulate([str(scene_file), "--out", str(out), "--width", str(W), "--height", str(H)]) == 0
    scene = Scene.from_yaml(SCENE)
    model = compile_model(scene, SimOptions())
    trace = rollout(model, 2, scene.n_frames, scene.fps)
    with FrameRenderer(model, W, H) as renderer:
        frames = renderer.render(trace.qpos, rgb=True, seg=True, depth=False, flow=False)
    masks = np.load(out / "masks.npz")
    assert masks["seg"].shape == (40, H, W) and masks["seg"].dtype == np.int8
    assert np.array_equal(masks["seg"], frames.seg)
    assert list(masks["names"]) == ["cylinder_0", "sphere_1"]
    ref = tmp_path / "ref"
    assert (out / "rgb.mp4").read_bytes() == side_by_side_mp4(ref / "rgb.mp4", [frames.rgb], [""], 40).read_bytes()
    preview = mask_overlay(np.zeros_like(frames.rgb), frames.seg, alpha=1.0)
    assert (out / "masks.mp4").read_bytes() == side_by_side_mp4(ref / "m.mp4", [preview], [""], 40).read_bytes()
    for name in ("rgb.mp4", "masks.mp4"):
        count, decoded = _decode(out / name)
        assert count == len(decoded) == 40, name
    events = json.loads((out / "events.json").read_text())
    found = traces.extract_events(trace, frames.visible_pixels(2), traces.EventConfig())
    assert events["events"] == json.loads(json.dumps(traces.events_to_json(found)))
    assert _siblings(out) == ["out"]


def test_a_failing_render_leaves_no_output_folder(tmp_path, scene_file, monkeypatch):
    """An error in the third chunk (as a kill would stop it): no --out folder, no temporary."""
    monkeypatch.setattr(traces, "RENDER_CHUNK_FRAMES", 7)
    calls = []

    def fail_on_third(seg):
        calls.append(1)
        if len(calls) == 3:
            raise RuntimeError("disk full")
        return mask_colours(seg)

    monkeypatch.setattr(traces, "mask_colours", fail_on_third)
    out = tmp_path / "out"
    with pytest.raises(RuntimeError, match="disk full"):
        _simulate([str(scene_file), "--out", str(out), "--width", str(W), "--height", str(H)])
    assert _siblings(out) == []


def test_an_existing_out_folder_keeps_other_files_and_is_untouched_on_failure(tmp_path, scene_file, monkeypatch):
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    (out / "rgb.mp4").write_bytes(b"an older run")
    monkeypatch.setattr(traces, "mask_colours", lambda seg: (_ for _ in ()).throw(RuntimeError("killed")))
    with pytest.raises(RuntimeError, match="killed"):
        _simulate([str(scene_file), "--out", str(out), "--width", str(W), "--height", str(H)])
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt", "rgb.mp4"]
    assert (out / "rgb.mp4").read_bytes() == b"an older run" and _siblings(out) == ["out"]
    monkeypatch.undo()
    assert _simulate([str(scene_file), "--out", str(out), "--width", str(W), "--height", str(H)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["events.json", "masks.mp4", "masks.npz", "notes.txt", "rgb.mp4",
                                                     "trace.parquet"]
    assert (out / "notes.txt").read_text() == "mine" and _decode(out / "rgb.mp4")[0] == 40
    assert _siblings(out) == ["out"]


def test_a_folder_named_like_an_output_is_refused_in_one_line(tmp_path, scene_file, capsys):
    out = tmp_path / "out"
    (out / "masks.npz").mkdir(parents=True)
    assert _simulate([str(scene_file), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "masks.npz: --out: must not hold a folder named masks.npz" in err and err.count("\n") == 1
    assert [p.name for p in out.iterdir()] == ["masks.npz"]


def test_publish_dir_renames_or_merges(tmp_path):
    def made(name):
        tmp = tmp_path / name
        tmp.mkdir()
        (tmp / "a.txt").write_text(name)
        return tmp

    out = tmp_path / "out"
    publish_dir(made("t1"), out)
    assert [p.name for p in out.iterdir()] == ["a.txt"] and not (tmp_path / "t1").exists()
    (out / "keep.txt").write_text("keep")
    publish_dir(made("t2"), out)
    assert (out / "a.txt").read_text() == "t2" and (out / "keep.txt").read_text() == "keep"
    (out / "a.txt").unlink()
    (out / "a.txt").mkdir()
    with pytest.raises(FileExistsError, match="a.txt: must be a file"):
        publish_dir(made("t3"), out)
    assert (out / "a.txt").is_dir() and (tmp_path / "t3" / "a.txt").exists()


def test_simulate_killed_midway_leaves_no_output_and_the_next_run_cleans_up(tmp_path):
    """SIGKILL while the clip renders (its temporary folder holds trace.parquet): no --out, only
    the hidden temporary, which the next run removes before writing a complete folder."""
    scene = tmp_path / "long.yaml"
    scene.write_text(SCENE.replace("fps: 40", "fps: 4000"))        # 4,000 frames: seconds of rendering
    out = tmp_path / "out"
    env = {**os.environ, "MUJOCO_GL": "egl", "PYTHONPATH": str(ROOT)}
    cmd = [sys.executable, "-P", "-m", "pipeline.cli", "simulate", str(scene), "--out", str(out),
           "--width", "64", "--height", "48"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while not list(tmp_path.glob(".out.*.tmp/trace.parquet")) and time.monotonic() < deadline:
            assert proc.poll() is None, "dynamics simulate ended before it could be killed"
            time.sleep(0.02)
        time.sleep(0.3)                                             # into the rendering
        assert proc.poll() is None, "dynamics simulate finished before it could be killed"
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait()
    assert not out.exists()
    stale = [p for p in tmp_path.iterdir() if p.name.startswith(".out.")]
    assert len(stale) == 1 and stale[0].is_dir()
    short = tmp_path / "short.yaml"
    short.write_text(SCENE)
    assert _simulate([str(short), "--out", str(out), "--width", str(W), "--height", str(H)]) == 0
    assert _siblings(out) == ["out"]
    assert np.load(out / "masks.npz")["seg"].shape == (40, H, W)


# --------------------------------------------------------------------------- render stage (Zarr)
def test_array_shard_written_scene_by_scene_equals_write_arrays(tmp_path):
    rng = np.random.default_rng(3)
    scenes = [{"rgb": rng.integers(0, 256, (4, 6, 8, 3), dtype=np.uint8),
               "seg": rng.integers(-1, 2, (4, 6, 8), dtype=np.int8),
               "flow": rng.normal(size=(3, 6, 8, 2)).astype(np.float16)} for _ in range(3)]
    ids = [shards.scene_id(i) for i in range(3)]
    attrs = {"units": {"rgb": "uint8 RGB"}, "fps": 30, "width": 8}
    whole = shards.write_arrays(tmp_path / "whole.zarr", {k: np.stack([s[k] for s in scenes]) for k in scenes[0]},
                                attrs=attrs, scene_ids=ids)
    with shards.ArrayShardWriter(tmp_path / "streamed.zarr", attrs) as shard:
        for sid, scene in zip(ids, scenes):
            shard.append(scene, scene_id=sid)
    streamed = tmp_path / "streamed.zarr"

    def files(root):
        return {str(f.relative_to(root)): _sha(f) for f in sorted(root.rglob("*")) if f.is_file()}

    assert files(streamed) == files(whole)                          # arrays, chunks, attrs, scene_id: same bytes
    group = shards.open_arrays(streamed)
    assert shards.scene_ids_of(group) == ids and group["seg"].chunks == (1, 4, 6, 8)
    assert np.array_equal(group["flow"][...], np.stack([s["flow"] for s in scenes]))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["streamed.zarr", "whole.zarr"]


def test_array_shard_writer_refuses_a_mismatched_scene_and_leaves_nothing(tmp_path):
    path = tmp_path / "shard-00000.zarr"
    with pytest.raises(ValueError, match=r"scene scene-000001: rgb must be \(4, 6, 8, 3\) uint8"):
        with shards.ArrayShardWriter(path) as shard:
            shard.append({"rgb": np.zeros((4, 6, 8, 3), np.uint8)}, scene_id="scene-000000")
            shard.append({"rgb": np.zeros((5, 6, 8, 3), np.uint8)}, scene_id="scene-000001")
    assert list(tmp_path.iterdir()) == []
