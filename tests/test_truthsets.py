"""Truth sets (pipeline.truthsets): masks, states and labels checked against geometry and physics."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from pipeline.truthsets import mujoco_scenes
from pipeline.truthsets.__main__ import main
from pipeline.truthsets.common import (TruthClip, TruthsetError, category_of, generate_clip, load_clip, motion_labels,
                                       project, write_clip)
from pipeline.truthsets.planning import GRAVITY, roll, slide
from pipeline.truthsets.scenario import CATEGORIES, CameraSpec, Look, ObjectSpec, Scenario

W, H = 160, 120


def _look(kind: str = "noise") -> Look:
    d = np.array([0.3, 0.2, -1.0])
    return Look(floor_kind=kind, floor_rgb1=(0.4, 0.42, 0.4), floor_rgb2=(0.6, 0.55, 0.5), floor_tile=0.8,
                light_dir=d / np.linalg.norm(d), light_diffuse=0.6, light_ambient=0.1, light_specular=0.1,
                headlight_ambient=0.3, headlight_diffuse=0.3, shadows=False, object_checker=True, texture_seed=3)


def _scenario(pitch: float, kind: str = "noise", duration: float = 1.0) -> Scenario:
    """A rolling sphere (object 0) and a box resting out of its way (object 1)."""
    cam = CameraSpec(yaw=20.0, pitch=pitch, fov=45.0, distance=2.2, look_at=np.array([0.0, 0.0, 0.15]))
    ball = ObjectSpec("sphere", {"radius": 0.15}, 1.0, np.array([-0.4, -0.1, 0.15]), np.array([1.0, 0, 0, 0]),
                      rgb=(0.9, 0.2, 0.2))
    roll(ball, np.array([0.6, 0.0, 0.0]))
    box = ObjectSpec("box", {"width": 0.3, "depth": 0.2, "height": 0.25}, 1.0, np.array([0.3, 0.5, 0.125]),
                     np.array([1.0, 0, 0, 0]), rgb=(0.2, 0.3, 0.9))
    return Scenario("moving", cam, _look(kind), [ball, box], W, H, 30, duration)


def _engines() -> list:
    return [pytest.param("mujoco", id="mujoco"), pytest.param("pybullet", id="pybullet")]


def _engine(name: str):
    if name == "pybullet":
        pytest.importorskip("pybullet")
        from pipeline.truthsets import pybullet_scenes

        return pybullet_scenes
    return mujoco_scenes


def _free(seg: np.ndarray, k: int) -> bool:
    """Object k's mask in one frame touches neither another mask nor the image border."""
    m = seg == k
    if not m.any() or m[0].any() or m[-1].any() or m[:, 0].any() or m[:, -1].any():
        return False
    grown = m.copy()
    grown[1:] |= m[:-1]
    grown[:-1] |= m[1:]
    grown[:, 1:] |= m[:, :-1]
    grown[:, :-1] |= m[:, 1:]
    return not ((seg >= 0) & (seg != k) & grown).any()


@pytest.mark.parametrize("engine", _engines())
@pytest.mark.parametrize("pitch", [12.0, 75.0])
def test_sphere_mask_centroid_is_projected_centre(engine, pitch):
    # The silhouette of a sphere is an ellipse whose centre lies within (r/d)^2 x (distance to
    # the principal point) of the projected centre: < 0.3 px here (r = 0.15 m, d >= 1.8 m).
    eng = _engine(engine)
    roll_ = eng.run(_scenario(pitch))
    uv, _ = project(roll_.pos[:, 0], roll_.intrinsics, roll_.extrinsics)
    checked = 0
    for t in range(roll_.seg.shape[0]):
        if not _free(roll_.seg[t], 0):
            continue
        ys, xs = np.nonzero(roll_.seg[t] == 0)
        centroid = np.array([xs.mean() + 0.5, ys.mean() + 0.5])   # pixel centres at +0.5
        np.testing.assert_allclose(centroid, uv[t], atol=1.5, err_msg=f"{engine} frame {t}")
        checked += 1
    assert checked >= 10


@pytest.mark.parametrize("engine", _engines())
def test_still_and_stopping_objects_against_closed_form(engine):
    eng = _engine(engine)
    sc = _scenario(35.0, kind="checker", duration=1.5)
    ball, box = sc.objects
    ball.position = np.array([-0.6, -0.3, 0.15])            # rolls along x, clear of both boxes
    slider = ObjectSpec("box", {"width": 0.2, "depth": 0.2, "height": 0.1}, 1.0, np.array([-0.3, 0.25, 0.05]),
                        np.array([1.0, 0, 0, 0]), friction=0.5, rgb=(0.2, 0.8, 0.2))
    v0 = 1.5
    slide(slider, np.array([v0, 0.0, 0.0]))
    sc.objects = [ball, box, slider]
    r = eng.run(sc)
    motion = motion_labels(r.pos, r.quat, sc.fps)
    assert list(motion) == ["moving", "still", "stops"]
    # still: the box never leaves its first position by 1 mm
    assert np.linalg.norm(r.pos[:, 1] - r.pos[0, 1], axis=-1).max() < 1e-3
    # stops: Coulomb friction decelerates at mu g, rests after v0 / (mu g) = 0.31 s, having slid
    # v0^2 / (2 mu g) = 0.229 m (constant deceleration kinematics); at rest over the last 0.5 s
    tail = np.linalg.norm(np.diff(r.pos[-15:, 2], axis=0), axis=-1) * sc.fps
    assert tail.max() < 0.01
    slid = float(np.linalg.norm(r.pos[-1, 2, :2] - r.pos[0, 2, :2]))
    np.testing.assert_allclose(slid, v0 ** 2 / (2 * 0.5 * GRAVITY), rtol=0.1)
    # the rolling ball keeps its speed (rolling friction 0): v = 0.6 m/s within 5 %
    v = np.linalg.norm(r.pos[-1, 0, :2] - r.pos[-11, 0, :2]) * sc.fps / 10
    np.testing.assert_allclose(v, 0.6, rtol=0.05)


def _clip(T: int = 4, n: int = 2) -> TruthClip:
    rng = np.random.default_rng(0)
    return TruthClip(seg=rng.integers(-1, n, size=(T, 24, 32)).astype(np.int8), fps=30.0,
                     motion=np.array(["moving", "still"][:n]), enters=np.array([True, False][:n]),
                     leaves=np.zeros(n, bool), pos=rng.normal(size=(T, n, 3)), quat=np.tile([1.0, 0, 0, 0], (T, n, 1)),
                     speed=np.abs(rng.normal(size=(T, n))), touch=np.zeros((T, n, n), bool),
                     intrinsics=np.eye(3), extrinsics=np.eye(4), engine="mujoco",
                     meta={"category": "moving", "tags": []},
                     rgb=rng.integers(0, 255, size=(T, 24, 32, 3)).astype(np.uint8))


def test_write_load_round_trip(tmp_path):
    clip = _clip()
    write_clip(tmp_path / "clip-00000", clip)
    back = load_clip(tmp_path / "clip-00000", rgb=True)
    for name in ("seg", "motion", "enters", "leaves", "pos", "quat", "speed", "touch", "intrinsics", "extrinsics"):
        np.testing.assert_array_equal(getattr(back, name), getattr(clip, name), err_msg=name)
    assert back.fps == 30.0 and back.engine == "mujoco" and back.meta == clip.meta
    assert back.rgb.shape == clip.rgb.shape and back.rgb.dtype == np.uint8


def test_missing_or_corrupt_truth_names_the_file(tmp_path):
    folder = tmp_path / "clip-00000"
    write_clip(folder, _clip())
    npz = folder / "truth.npz"
    data = dict(np.load(npz))
    del data["motion"]
    np.savez(npz, **data)
    with pytest.raises(TruthsetError, match=r"truth\.npz: motion: missing"):
        load_clip(folder)
    npz.write_bytes(b"not a zip archive")
    with pytest.raises(TruthsetError, match=r"clip-00000/truth\.npz: cannot be read"):
        load_clip(folder)
    npz.unlink()
    with pytest.raises(TruthsetError, match=r"clip-00000/truth\.npz: missing"):
        load_clip(folder)


def test_wrong_dtype_names_the_field(tmp_path):
    folder = tmp_path / "clip-00000"
    write_clip(folder, _clip())
    data = dict(np.load(folder / "truth.npz"))
    data["seg"] = data["seg"].astype(np.int32)
    np.savez(folder / "truth.npz", **data)
    with pytest.raises(TruthsetError, match=r"truth\.npz: seg: must be \(T, H, W\) int8"):
        load_clip(folder)


def test_categories_cover_every_six_clips():
    for seed in (0, 1):
        assert sorted(category_of(seed, i) for i in range(6)) == sorted(CATEGORIES)


@pytest.mark.parametrize("engine", _engines())
def test_same_seed_same_masks(engine):
    eng = _engine(engine)
    a = generate_clip(eng, seed=0, index=4, width=96, height=72, fps=15, duration=1.0)
    b = generate_clip(eng, seed=0, index=4, width=96, height=72, fps=15, duration=1.0)
    assert a.seg.tobytes() == b.seg.tobytes()
    np.testing.assert_array_equal(a.pos, b.pos)
    c = generate_clip(eng, seed=1, index=4, width=96, height=72, fps=15, duration=1.0)
    assert c.seg.tobytes() != a.seg.tobytes()
    assert a.meta["category"] in a.meta["tags"]


def test_cli_generates_and_resumes(tmp_path, capsys):
    out = tmp_path / "set"
    args = ["generate", "--engine", "mujoco", "--n", "2", "--seed", "0", "--out", str(out), "--width", "96",
            "--height", "72", "--fps", "15", "--duration", "1.0"]
    assert main(args) == 0
    first = (out / "clip-00001" / "truth.npz").stat().st_mtime_ns
    index = json.loads((out / "index.json").read_text())
    assert [c["clip"] for c in index["clips"]] == ["clip-00000", "clip-00001"]
    assert main(args) == 0                                   # complete clips are kept
    assert (out / "clip-00001" / "truth.npz").stat().st_mtime_ns == first
    assert main([*args[:-8], "--width", "64", "--height", "48", "--fps", "15", "--duration", "1.0"]) == 2
    assert "params: must match" in capsys.readouterr().err
    clip = load_clip(out / "clip-00000")
    assert clip.seg.shape == (15, 72, 96) and clip.pos.shape[0] == 15
    assert math.isclose(clip.fps, 15.0)
