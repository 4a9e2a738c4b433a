"""Tests for pipeline.video (reading real clips, fps override, resampling) and pipeline.masks (pseudo masks)."""

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

import cv2

from conftest import moving_disc_avi
from pipeline.masks import BACKGROUND, label_objects, median_area, pseudo_ground_truth, pseudo_masks
from pipeline.video import VideoError, VideoWarning, read_video, resample

_ROOT = Path(__file__).resolve().parents[1]
REAL_VIDEO = next((p for p in [Path(os.environ.get("DYNAMICS_REAL_DATA", "/nonexistent")),
                               _ROOT / "shared/data/real", _ROOT.parent / "shared/data/real"]
                   if p.is_dir()), _ROOT / "shared/data/real") / "video"
BALL = REAL_VIDEO / "01_bouncing_green_ball_1080p30.avi"
PUCKS = REAL_VIDEO / "05_phystrack_CaromPuck_HeadOn_240fps.mp4"
needs_real = pytest.mark.skipif(not BALL.exists() or not PUCKS.exists(),
                                reason=f"real videos not found under {REAL_VIDEO}")


def _centroid_rows(seg: np.ndarray, obj: int) -> np.ndarray:
    """Mean row of object ``obj`` per frame (NaN where absent)."""
    return np.array([np.argwhere(s == obj)[:, 0].mean() if (s == obj).any() else np.nan
                     for s in seg])


@needs_real
def test_ball_clip_mask_falls_during_first_bounce():
    # 1.8 s .. 2.8 s: the ball is held at the top edge, dropped (~2.2 s), hits the floor
    # (~2.5 s) and bounces up; a hand enters at the top right near the end.
    clip = read_video(BALL, start=1.8, duration=1.0, size=(240, 160))
    assert clip.frames.shape == (30, 160, 240, 3) and clip.frames.dtype == np.uint8
    assert clip.fps == pytest.approx(29.97, abs=0.01) and clip.original_size == (1920, 1080)
    assert clip.crop == (150, 0, 1620, 1080)              # centre crop to 3:2
    assert clip.start_frame == 54

    # The median of this window also flags the ball's shadow on the board while it is
    # held, and fingers at the top late on: keep the largest object (the ball).
    seg = label_objects(pseudo_masks(clip.frames), max_objects=1)
    assert seg.dtype == np.int8 and seg.shape == (30, 160, 240)
    rows = _centroid_rows(seg, 0)
    assert not np.isnan(rows).any()
    fall = rows[13:23]                                    # free fall until the floor
    assert (np.diff(fall) > 0).all(), fall
    assert fall[-1] - fall[0] > 100                       # px of the 160 px frame
    assert rows[-1] < rows[22] - 30                       # back up after the bounce
    # the ball is green: its masked pixels are greener than red or blue
    mean = clip.frames[seg == 0].mean(0)
    assert mean[1] > mean[0] and mean[1] > mean[2]


@needs_real
def test_240fps_override_and_resample():
    container = read_video(PUCKS, max_frames=2)
    assert container.fps == pytest.approx(29.97, abs=0.01)
    clip = read_video(PUCKS, fps=240, start=0.6, duration=1.0, size=(96, 64))
    assert clip.fps == 240 and clip.container_fps == pytest.approx(29.97, abs=0.01)
    assert clip.frames.shape == (240, 64, 96, 3) and clip.start_frame == 144
    frames = resample(clip.frames, clip.fps, 30.0, duration=1.0)
    assert frames.shape == (30, 64, 96, 3)
    np.testing.assert_array_equal(frames[1], clip.frames[8])       # every 8th frame

    full = read_video(PUCKS, fps=240, size=(48, 32))               # the whole clip
    assert len(full.frames) == 752 and full.duration == pytest.approx(752 / 240)

    # the struck puck slides right, out of view: centroid x grows (pseudo masks)
    seg = label_objects(pseudo_masks(frames), max_objects=4)
    moving = [i for i in range(4) if (seg[15] == i).any()]
    assert len(moving) == 1
    cols = [np.argwhere(s == moving[0])[:, 1].mean() for s in seg[6:16]]
    assert (np.diff(cols) > 0).all() and cols[-1] - cols[0] > 20


def test_resample_grid():
    x = np.arange(100)
    np.testing.assert_array_equal(resample(x, 240, 30, 0.25), [0, 8, 16, 24, 32, 40, 48, 56])
    np.testing.assert_array_equal(resample(x[:30], 29.97, 30, 1.0), np.arange(30))
    assert len(resample(x, 60, 30)) == 50                 # whole input: frames 0, 2, .., 98
    with pytest.raises(ValueError, match="need 2.000 s"):
        resample(x, 60, 30, 2.0)


def test_read_video_errors(tmp_path):
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(np.random.default_rng(0).bytes(4096))
    cases = [(tmp_path / "missing.mp4", {}, "no such file"),
             (junk, {}, "cannot open"),
             (tmp_path, {}, "not a file")]
    if PUCKS.exists():
        cases += [(PUCKS, {"fps": 240, "start": 4.0}, "past the end"),
                  (PUCKS, {"fps": -1}, "fps: must be > 0")]
    for path, kwargs, message in cases:
        with pytest.raises(VideoError, match=message) as err:
            read_video(path, **kwargs)
        assert "\n" not in str(err.value) and str(path) in str(err.value)


def _moving_disc(T=20, H=64, W=96, r=8, seed=0):
    """Disc moving right across static noise; returns frames and the true masks."""
    rng = np.random.default_rng(seed)
    bg = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    yy, xx = np.mgrid[:H, :W]
    truth = np.stack([(yy - 30) ** 2 + (xx - (12 + 3.5 * t)) ** 2 <= r * r for t in range(T)])
    frames = np.repeat(bg[None], T, axis=0)
    frames[truth] = (40, 200, 60)
    return frames, truth


@pytest.mark.parametrize("method", ["median", "mog2"])
def test_pseudo_masks_synthetic_disc(method):
    # The clip is the first 20 frames of an 80 frame window (the disc leaves the view at
    # frame ~25). The median works on the clip alone; MOG2 needs the longer window: in 20
    # frames the disc covers a pixel often enough to count as a background mode.
    window, window_truth = _moving_disc(T=80)
    frames, truth = window[:20], window_truth[:20]
    background = window if method == "mog2" else None
    masks = pseudo_masks(frames, method=method, background=background)
    assert masks.shape == truth.shape and masks.dtype == bool
    iou = (masks & truth).sum((1, 2)) / (masks | truth).sum((1, 2))
    # uniform noise behind the disc: rim pixels whose own background is close to the disc
    # colour fall below half the local contrast and are lost by the median's edge rule
    assert iou.min() >= 0.75 and iou.mean() >= 0.85, iou

    seg = label_objects(masks, max_objects=3)
    assert set(np.unique(seg)) == {BACKGROUND, 0}         # one object, id 0 throughout


def test_label_objects_keeps_ids_through_a_crossing():
    # two squares moving towards each other on rows apart: ids stay attached to each square
    T, H, W = 12, 40, 80
    masks = np.zeros((T, H, W), bool)
    for t in range(T):
        masks[t, 5:13, 4 + 5 * t:12 + 5 * t] = True      # a: left -> right (first at left)
        masks[t, 25:33, 68 - 5 * t:76 - 5 * t] = True   # b: right -> left
    masks[5, 25:33] = False                               # b missing for one frame
    seg = label_objects(masks, max_objects=2)
    assert (seg[:, 5:13][masks[:, 5:13]] == 0).all()
    assert (seg[:, 25:33][masks[:, 25:33]] == 1).all()
    assert label_objects(masks, max_objects=1).max() == 0
    with pytest.raises(ValueError, match="max_objects"):
        label_objects(masks, max_objects=0)


def test_label_objects_split_keeps_touching_objects_apart():
    # two squares slide together and stay in contact (one connected blob from frame 6 on):
    # without split the blob is one track; with split each square keeps its id, every pixel
    T, H, W = 12, 30, 80
    masks = np.zeros((T, H, W), bool)
    truth = np.full((T, H, W), -1, np.int8)
    for t in range(T):
        xa = min(10 + 4 * t, 34)                      # a stops at 34..44, b at 44..54
        xb = max(60 - 4 * t, 44)
        masks[t, 10:20, xa:xa + 10] = True
        masks[t, 10:20, xb:xb + 10] = True
        truth[t, 10:20, xa:xa + 10] = 0
        truth[t, 10:20, xb:xb + 10] = 1
    merged = label_objects(masks, max_objects=2)
    assert (merged[-1][masks[-1]] == merged[-1][10, 35]).all()        # one id over both squares
    seg = label_objects(masks, max_objects=2, split=True)
    np.testing.assert_array_equal(seg, truth)


def test_pseudo_masks_shadow_and_blur():
    # a dark disc with a soft grey shadow beside it, on a light textured floor: the mask
    # is the disc (edge at half contrast), not the shadow
    rng = np.random.default_rng(1)
    H, W = 64, 96
    bg = (200 + rng.integers(-5, 6, (H, W, 3))).astype(np.uint8)
    yy, xx = np.mgrid[:H, :W]
    frames, truth = [], []
    for t in range(12):
        cx = 15 + 6 * t
        disc = (yy - 30) ** 2 + (xx - cx) ** 2 <= 64
        shadow = ((yy - 40) ** 2 + (xx - cx - 6) ** 2 <= 100) & ~disc
        f = bg.astype(np.float32)
        f[shadow] *= 0.7                                  # same colour, darker
        f[disc] = (30, 60, 160)
        frames.append(cv2.GaussianBlur(f, (0, 0), 1.0).clip(0, 255).astype(np.uint8))
        truth.append(disc)
    frames, truth = np.stack(frames), np.stack(truth)
    masks = pseudo_masks(frames)
    iou = (masks & truth).sum((1, 2)) / (masks | truth).sum((1, 2))
    assert iou.min() >= 0.8, iou
    plain = pseudo_masks(frames, shadows=False, edge=0)
    assert plain.sum() > 1.3 * masks.sum()               # the shadow would be foreground


@needs_real
def test_pseudo_ground_truth_crop_and_ids():
    # the main job's call: a crop box, a working size, source frames of a window
    idx = list(range(150, 240, 8))
    seg = pseudo_ground_truth(PUCKS, 240, idx, size=(96, 64), crop=(40, 20, 240, 160),
                              max_objects=4)
    assert seg.shape == (len(idx), 64, 96) and seg.dtype == np.int8
    ids = [k for s in seg for k in np.unique(s) if k >= 0]
    first = list(dict.fromkeys(ids))
    assert first == list(range(len(first))) and len(first) >= 1   # 0..n-1, first seen
    assert seg.min() == BACKGROUND
    with pytest.raises(VideoError, match="frame_indices"):
        pseudo_ground_truth(PUCKS, 240, [10_000], size=(96, 64))


def test_hold_resting_keeps_an_object_that_stops_inside_the_frame():
    """Background subtraction loses an object where it comes to rest; hold_resting keeps its
    last mask until the end, but not for an object that left through the border."""
    from pipeline.masks import hold_resting

    seg = np.full((6, 20, 30), -1, dtype=np.int8)
    seg[:3, 8:12, 5:9] = 0      # object 0 seen in frames 0-2, inside the frame, then lost
    seg[:2, 0:4, 26:30] = 1     # object 1 leaves through the top-right border
    held = hold_resting(seg)
    for t in range(3, 6):
        assert (held[t] == 0).sum() == (seg[2] == 0).sum()
        assert (held[t] == 1).sum() == 0
    np.testing.assert_array_equal(held[:3], seg[:3])
    # the main job's window holds only what it saw in 3 frames (HELD_MIN_FRAMES): a blob seen in
    # 2 (a hand flicking through the view, dev/07) was a still ghost for the rest of the clip
    from pipeline.observe import HELD_MIN_FRAMES

    flick = np.full((6, 20, 30), -1, dtype=np.int8)
    flick[1:3, 8:12, 5:9] = 0
    np.testing.assert_array_equal(hold_resting(flick, min_frames=HELD_MIN_FRAMES), flick)
    assert (hold_resting(flick)[3:] == 0).sum() == 3 * 16   # sparse frames (the default) still hold it


def _dynamics(*args: str) -> "subprocess.CompletedProcess":
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "pipeline.cli", *args], capture_output=True, text=True,
                          timeout=300)


def test_unreadable_and_truncated_videos(tmp_path):
    """A file that is not a video ends in exactly one stderr line and exit 2 (FFmpeg's own log
    is silenced); a video cut in half is read up to where it breaks, with a one-line warning
    naming how many frames were read (../shared/repro/video/truncated50.*)."""
    text = tmp_path / "text.mp4"
    text.write_text("not a video\n" * 100)
    proc = _dynamics("infer", str(text), "--out", str(tmp_path / "o"))
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [f"error: {text}: cannot open as a video"]
    assert not (tmp_path / "o").exists()

    full = moving_disc_avi(tmp_path / "full.avi")
    data = full.read_bytes()
    cut = tmp_path / "cut.avi"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.warns(VideoWarning, match=r"cut.avi: truncated or corrupt: decoding stopped after frame (\d+) "
                                          r"of the 60 the container declares; read \1 frames") as rec:
        clip = read_video(cut)
    assert 10 <= len(clip.frames) < 60
    assert f"read {len(clip.frames)} frames" in str(rec[0].message)
    # the decoded frames are the file's first frames (the last one may be cut mid-frame)
    good = read_video(full)
    np.testing.assert_array_equal(clip.frames[:-1], good.frames[: len(clip.frames) - 1])
    # an intact file and a window inside the readable part warn about nothing
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_video(full)
        read_video(cut, duration=len(clip.frames) / 30 / 2)

    # through the CLI: the warning is one line; the cut clip (under 1 s) is its own window and the
    # scene's duration follows it (issue 29: a clip shorter than the window no longer fails)
    proc = _dynamics("infer", str(cut), "--no-model", "--out", str(tmp_path / "o"))
    warned = [line for line in proc.stderr.strip().splitlines() if line.startswith("warning:")]
    assert proc.returncode == 0, proc.stderr
    assert len(warned) == 1 and warned[0].startswith(f"warning: {cut}: truncated or corrupt"), warned
    window = json.loads((tmp_path / "o" / "metrics.json").read_text())["window"]
    assert window["frames"] == len(clip.frames) and window["duration_s"] == pytest.approx(len(clip.frames) / 30)
    assert f"duration: {len(clip.frames) / 30:g}" in (tmp_path / "o" / "scene.yaml").read_text()
    shutil.rmtree(tmp_path / "o")
    # a clip too short to observe (5 frames) is one error line
    tiny = moving_disc_avi(tmp_path / "tiny.avi", n=5)
    proc = _dynamics("infer", str(tiny), "--no-model", "--out", str(tmp_path / "o"))
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        f"error: {tiny}: only 0.167 s long at 30 fps, need at least 0.267 s (8 frames at 30 fps)"]
    # a header cut short: FFmpeg cannot open it, OpenCV's own AVI parser (tried next) must not add
    # its "Unexpected element. Expected: LIST" line to ours
    head = tmp_path / "head.avi"
    head.write_bytes(data[: len(data) // 10])
    proc = _dynamics("infer", str(head), "--no-model", "--out", str(tmp_path / "o"))
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [f"error: {head}: cannot open as a video"]
    # a start past the decodable part names the truncation
    proc = _dynamics("infer", str(cut), "--no-model", "--start", "1.5", "--out", str(tmp_path / "o"))
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        f"error: {cut}: start 1.5 s (frame 45) is past the end ({len(clip.frames)} frames decodable = "
        f"{len(clip.frames) / 30:.3f} s at 30 fps, of the 60 the container declares: truncated or corrupt file)"]
    assert not (tmp_path / "o").exists()


def test_a_slower_clip_runs_at_its_own_rate_without_repeated_frames(tmp_path):
    """dev/06 is filmed at 25 fps: a 30 fps scene repeated every fifth frame, and the repeats read
    as stops in the track (a parabola through them gave 2567 px/s^2 sideways). The scene runs at
    the clip's rate, and every observed frame is a different recorded one."""
    from pipeline.flow import FlowConfig
    from pipeline.observe import observe, scene_rate, source_frames

    clip = moving_disc_avi(tmp_path / "slow.avi", n=60)
    assert scene_rate(clip, 25.0, 30) == 25
    assert scene_rate(clip, 29.97, 30) == 30                   # a container's NTSC rate is 30
    obs = observe(clip, 25.0, None, scene_rate(clip, 25.0, 30), 1.0, FlowConfig())
    src = source_frames(obs)
    assert len(src) == 25 and np.all(np.diff(src) == 1)
    # at 30 fps the same clip repeats frames
    assert np.any(np.diff(source_frames(observe(clip, 25.0, None, 30, 1.0, FlowConfig()))) == 0)


def test_a_short_high_speed_clip_gets_a_higher_scene_rate(tmp_path):
    """50 frames filmed at 240 fps are 0.208 s: 6 frames at the default 30 fps, fewer than the 8 a
    window needs; the scene rate doubles to 60 fps (12 frames) and the main job runs (issue 29,
    dev/01: 0.209 s at 1000 fps). The clip's own rate caps it."""
    from pipeline.observe import MIN_WINDOW_FRAMES, scene_rate

    clip = moving_disc_avi(tmp_path / "fast.avi", n=50)
    assert scene_rate(clip, 240.0, 30) == 60
    assert scene_rate(clip, 1000.0, 30) == 240                 # 0.05 s: 8 frames need 160+ fps
    assert scene_rate(clip, None, 30) == 30                    # 1.67 s at the container's 30 fps
    assert scene_rate(moving_disc_avi(tmp_path / "tiny.avi", n=5), None, 30) == 30   # nothing helps
    proc = _dynamics("infer", str(clip), "--fps", "240", "--no-model", "--out", str(tmp_path / "o"))
    assert proc.returncode == 0, proc.stderr[-2000:]
    window = json.loads((tmp_path / "o" / "metrics.json").read_text())["window"]
    assert window["fps"] == 60 and window["frames"] == 12 >= MIN_WINDOW_FRAMES
    assert "fps: 60" in (tmp_path / "o" / "scene.yaml").read_text()


@pytest.mark.parametrize("where", [0.3, 0.5, 0.7])
def test_video_with_broken_frames_is_read_up_to_the_damage(tmp_path, where):
    """10 % of the bytes overwritten with noise at 30/50/70 % of the file: never an exception
    other than VideoError, and a warning naming the frames read whenever frames are lost."""
    import warnings

    data = bytearray(moving_disc_avi(tmp_path / "full.avi").read_bytes())
    n = len(data)
    a = int(n * where)
    data[a:a + n // 10] = np.random.default_rng(0).integers(0, 256, n // 10, dtype=np.uint8).tobytes()
    broken = tmp_path / "broken.avi"
    broken.write_bytes(bytes(data))
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        clip = read_video(broken)
    ours = [w for w in rec if issubclass(w.category, VideoWarning)]
    assert 1 <= len(clip.frames) <= 60
    if len(clip.frames) < 60:
        assert len(ours) == 1 and f"read {len(clip.frames)} frames" in str(ours[0].message)
    else:
        assert ours == []


def _fake_checkpoint(tmp_path: Path, edit) -> Path:
    """A copy of the shipped checkpoint (7 MB) with ``edit(folder)`` applied."""
    import shutil

    from pipeline.model import SHIPPED_CHECKPOINT

    folder = tmp_path / "model"
    shutil.copytree(SHIPPED_CHECKPOINT, folder)
    edit(folder)
    return folder


def _json_edit(name: str, change):
    import json

    def edit(folder: Path) -> None:
        data = json.loads((folder / name).read_text())
        change(data)
        (folder / name).write_text(json.dumps(data))
    return edit


@pytest.mark.parametrize("edit, message", [
    (_json_edit("dynamics_model.json", lambda d: d.update(patch_frames=4)),
     "dynamics_model.json: written by another version of the project (model.patch_frames: extra inputs"),
    (_json_edit("dynamics_model.json", lambda d: d.pop("input")),     # a field of this version missing
     "dynamics_model.json: written by another version of the project (model.input: missing)"),
    (_json_edit("codec.json", lambda d: d.pop("quantizers")), "codec.json: written by another version"),
    (_json_edit("config.json", lambda d: d.update(model_type="qwen3_vl")),
     "config.json: model_type: must be 'qwen2_5_vl' (this version), got 'qwen3_vl'"),
    (lambda f: (f / "codec.json").unlink(), "no codec.json"),
    (lambda f: (f / "model.safetensors").unlink(), "no weights"),
    (lambda f: (f / "config.json").write_text("{not json"), "config.json: must be a JSON object"),
])
def test_model_folder_from_another_version_is_refused_before_decoding(tmp_path, edit, message):
    """``dynamics infer --model DIR`` with a folder this version cannot load: one line, exit 2,
    and before the video is read (the video here is not a video: its error would come first if
    it were decoded first)."""
    from pipeline.model import ModelError, check_checkpoint

    folder = _fake_checkpoint(tmp_path, edit)
    with pytest.raises(ModelError) as err:
        check_checkpoint(folder)
    assert str(err.value).startswith(f"{folder}: ") and "\n" not in str(err.value)
    assert message in str(err.value)
    text = tmp_path / "text.mp4"
    text.write_text("not a video\n")
    proc = _dynamics("infer", str(text), "--model", str(folder), "--out", str(tmp_path / "o"))
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [f"error: {err.value}"]
    assert not (tmp_path / "o").exists()


def test_shipped_checkpoint_passes_the_check_and_no_model_is_a_note(tmp_path, monkeypatch):
    """The committed checkpoint is usable; with no trained model and no shipped one,
    ``resolve_model_dir`` returns None (infer then says so in one line and uses perception)."""
    import pipeline.model as vlm
    from pipeline.reconstruct import resolve_model_dir

    vlm.check_checkpoint(vlm.SHIPPED_CHECKPOINT)
    params = {"paths": {"root": str(tmp_path), "model": str(tmp_path / "model")}}
    monkeypatch.setattr(vlm, "SHIPPED_CHECKPOINT", tmp_path / "none")
    monkeypatch.setattr(vlm, "WIDE_CHECKPOINT", tmp_path / "none")
    assert resolve_model_dir(None, params) is None
    with pytest.raises(vlm.ModelError, match="no such model folder"):
        resolve_model_dir(tmp_path / "missing", params)


def test_realvideo_model_picks_the_scene_writer(tmp_path, monkeypatch):
    """realvideo.model: trained (default) is paths.model after dvc repro; wide is the shipped
    checkpoint trained on real-looking scenes when the package holds it, else as trained; a folder:
    that folder."""
    import pipeline.model as vlm
    from pipeline.reconstruct import default_model_dir

    trained, wide = tmp_path / "model", tmp_path / "wide"
    for d in (trained, wide):
        d.mkdir()
        (d / "config.json").write_text("{}")
    params = {"paths": {"root": str(tmp_path), "model": str(trained)}}
    monkeypatch.setattr(vlm, "WIDE_CHECKPOINT", wide)
    assert default_model_dir(params) == trained
    assert default_model_dir({**params, "realvideo": {"model": "wide"}}) == wide
    assert default_model_dir({**params, "realvideo": {"model": str(tmp_path / "mine")}}) == tmp_path / "mine"
    monkeypatch.setattr(vlm, "WIDE_CHECKPOINT", tmp_path / "none")
    assert default_model_dir({**params, "realvideo": {"model": "wide"}}) == trained


def test_model_samples_restores_the_torch_thread_count():
    """Decoding the model's samples runs on one torch thread (as fast for K samples), but the
    process's thread count is restored after it: the segmenter of a later observation in the same
    process runs on every core again. K samples come back, each a scene or an error."""
    import torch

    from pipeline.model.config import WIDE_CHECKPOINT
    from pipeline.params import load_params
    from pipeline.reconstruct import model_samples

    params = load_params(Path(__file__).resolve().parents[1] / "params.yaml")
    frames = np.random.default_rng(0).integers(0, 255, (31, 120, 160, 3), dtype=np.uint8)
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        scenes, errors = model_samples(WIDE_CHECKPOINT, frames, params, 2, 0, 30, 1.0)
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
    assert len(scenes) == len(errors) == 2
    assert all((s is None) != (e is None) for s, e in zip(scenes, errors))
    assert all(s.fps == 30 and s.duration == 1.0 for s in scenes if s is not None)


def test_median_area_is_taken_over_the_frames_where_the_object_is_seen():
    """Areas 10, 20 and 40 px in three frames and absent in two: 20 px, not the 10 px a median
    over all five frames would give; an object never seen has area 0."""
    masks = np.zeros((5, 8, 8), bool)
    masks[0].flat[:10] = True
    masks[2].flat[:20] = True
    masks[4].flat[:40] = True
    assert median_area(masks) == 20.0
    assert median_area(np.zeros((3, 4, 4), bool)) == 0.0


def test_pseudo_masks_keep_a_grey_object_in_a_greyscale_clip(monkeypatch):
    """In a greyscale clip (a monochrome high-speed camera) every darker pixel has the background's
    chromaticity, so the photometric shadow test would take a grey disc on a light floor for a
    shadow; the clip is recognised as greyscale and the disc kept whole (a colour clip's cast
    shadow is still removed: :func:`test_pseudo_masks_shadow_and_blur`)."""
    from pipeline.masks import greyscale

    rng = np.random.default_rng(2)
    H, W = 64, 96
    bg = np.repeat((190 + rng.integers(-6, 7, (H, W, 1))), 3, axis=2).astype(np.uint8)   # grey texture
    yy, xx = np.mgrid[:H, :W]
    frames, truth = [], []
    for t in range(12):
        cx = 15 + 6 * t
        disc = (yy - 30) ** 2 + (xx - cx) ** 2 <= 64
        f = bg.astype(np.float32)
        f[disc] = 120.0                                   # 0.63 times the floor: inside the shadow factor
        frames.append(cv2.GaussianBlur(f, (0, 0), 1.0).clip(0, 255).astype(np.uint8))
        truth.append(disc)
    frames, truth = np.stack(frames), np.stack(truth)
    assert greyscale(frames) and not greyscale(np.dstack([frames[0][..., :2], frames[0][..., :1] // 2]))
    masks = pseudo_masks(frames)
    iou = (masks & truth).sum((1, 2)) / (masks | truth).sum((1, 2))
    assert iou.min() >= 0.8, iou
    # without the greyscale rule the photometric test calls the disc a shadow, and it is lost
    from pipeline import masks as masks_module
    assert np.stack([masks_module.shadow_like(f, bg) for f in frames])[truth].mean() > 0.9
    monkeypatch.setattr(masks_module, "greyscale", lambda frames: False)
    lost = pseudo_masks(frames)
    assert ((lost & truth).sum((1, 2)) / np.maximum(1, (lost | truth).sum((1, 2)))).max() < 0.5
