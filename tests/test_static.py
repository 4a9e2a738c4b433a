"""Static geometry (issue 9, item 1): the ``static:`` list of the scene language, its MJCF, its
rendering, the ramp helpers, the sampler's ramps and the exported JSON Schema.

Physics checks against closed-form mechanics on an inclined plane (any mechanics text):
a block with Coulomb coefficient mu on a slope theta > atan(mu) accelerates at
``g (sin theta - mu cos theta)`` and stays put when ``mu > tan theta``; a solid sphere rolling
without slip accelerates at ``5/7 g sin theta``.
"""

import pipeline  # noqa: F401  (MUJOCO_GL before mujoco)

import hashlib
import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

from pipeline.codec import CodecError, SceneCodec
from pipeline.effects import REGISTRY
from pipeline.mjcf import STATIC_COLOUR, SimOptions, compile_model, to_xml
from pipeline.render import render_scene
from pipeline.sample_config import SampleConfig, scene_seed
from pipeline.sampler import SceneFilter, iter_dataset, sample_scene
from pipeline.scene import STATIC_RESTITUTION, Decimals, Scene, SceneError, StaticBox, StaticPlane, json_schema_text
from pipeline.simulate import simulate
from pipeline.rotation import quat_to_mat as rotation_matrix
from pipeline.static import ramp, support_height, support_normal

G = 9.81
ROOT = Path(__file__).resolve().parents[1]
CAMERA = {"height": 1.2, "pitch": 35.0, "fov": 45.0}
BALL = {"shape": "sphere", "size": {"radius": 0.1}, "mass": 1.0, "position": [0.0, 0.0, 0.1]}
STATIC_BOX = {"shape": "box", "size": {"width": 1.2, "depth": 0.4, "height": 0.02},
              "position": [0.0, 0.3, 0.1], "orientation": [0.996, 0.0, 0.087, 0.0]}


def scene_with(static, objects=None, **kw):
    return Scene.from_dict({"camera": CAMERA, "objects": objects or [BALL], "static": static, **kw})


# --------------------------------------------------------------------------- 1. validation
@pytest.mark.parametrize("entry,message", [
    ({**STATIC_BOX, "size": {"width": -1, "depth": 0.4, "height": 0.02}}, "<scene>: static[0].size.width: must be >= 0.001"),
    ({**STATIC_BOX, "shape": "cone"}, "<scene>: static[0].shape: unknown shape, must be one of box, plane, got 'cone'"),
    ({k: v for k, v in STATIC_BOX.items() if k != "shape"}, "<scene>: static[0].shape: must be given (required field missing: shape)"),
    ({k: v for k, v in STATIC_BOX.items() if k != "position"}, "<scene>: static[0].position: must be given (required field missing)"),
    ({**STATIC_BOX, "orientation": [1, 1, 0, 0]}, "<scene>: static[0].orientation: must be a unit quaternion"),
    ({**STATIC_BOX, "mass": 1.0}, "<scene>: static[0].mass: must not be given (unknown key)"),
    ({"shape": "plane", "size": {"width": 1.0, "depth": 1.0, "height": 0.1}, "position": [0, 0, 0]},
     "<scene>: static[0].size.height: must not be given (unknown key)"),
    ({"shape": "plane", "size": {"width": 1.0}, "position": [0, 0, 0]}, "<scene>: static[0].size.depth: must be given (required field missing)"),
    ({**STATIC_BOX, "position": [0, 0, float("nan")]}, "<scene>: static[0].position[2]: must be a finite number"),
])
def test_bad_static_entries_give_one_line_naming_the_field(entry, message):
    with pytest.raises(SceneError) as err:
        scene_with([entry])
    msg = str(err.value)
    assert msg.startswith(message), msg
    assert "\n" not in msg


def test_static_round_trips_and_is_omitted_when_empty():
    plane = {"shape": "plane", "size": {"width": 1.0, "depth": 0.8}, "position": [0.0, 1.0, 0.4],
             "orientation": [0.70710678, -0.70710678, 0.0, 0.0]}
    s = scene_with([STATIC_BOX, plane])
    assert isinstance(s.static[0], StaticBox) and isinstance(s.static[1], StaticPlane)
    assert s.static_names == ["static_0", "static_1"]
    text = s.to_yaml()
    assert text.index("objects:") < text.index("static:") < text.index("effects:")
    assert "  - shape: plane\n    size: {width: 1.0, depth: 0.8}\n    position: [0.0, 1.0, 0.4]\n" \
           "    orientation: [0.707107, -0.707107, 0.0, 0.0]\n" in text
    assert Scene.from_yaml(text) == s.rounded()
    assert Scene.from_yaml(text).to_yaml() == text
    assert s.replace(static=[]).to_yaml() == scene_with([]).to_yaml()
    assert "static" not in scene_with([]).to_yaml()  # v1 texts (and their hashes) unchanged


def test_codec_refuses_static_geometry_clearly():
    codec = SceneCodec.from_params({})
    with pytest.raises(CodecError, match="static geometry is not part of this codec's token target"):
        codec.encode(scene_with([STATIC_BOX]))
    codec.encode(scene_with([]))
    # a codec with ramps (sample.p_ramp > 0) writes a ramp, but no other static geometry
    ramps = SceneCodec.from_params({"sample": {"p_ramp": 0.5}})
    rolled = {**STATIC_BOX, "orientation": [0.996, 0.087, 0.0, 0.0]}          # tilted about its local x
    plane = {"shape": "plane", "size": {"width": 1.0, "depth": 1.0}, "position": [0.0, 0.3, 0.1]}
    with pytest.raises(CodecError, match="not a ramp"):
        ramps.encode(scene_with([rolled]))
    with pytest.raises(CodecError, match="a ramp is a box, got a plane"):
        ramps.encode(scene_with([plane]))
    with pytest.raises(CodecError, match="0.03 m thick"):                      # STATIC_BOX is 0.02 m thick
        ramps.encode(scene_with([STATIC_BOX]))
    ramps.encode(scene_with([{**STATIC_BOX, "size": {**STATIC_BOX["size"], "height": 0.03}}]))


def test_committed_json_schema_is_the_generated_one():
    committed = (ROOT / "docs" / "scene.schema.json").read_text()
    assert committed == json_schema_text(), "regenerate with: dynamics schema --out docs/scene.schema.json"
    defs = Scene.model_json_schema()["$defs"]
    assert {"StaticBox", "StaticPlane", "PlaneSize"} <= set(defs)


def test_schema_cli_writes_the_schema(tmp_path, capsys):
    from pipeline.cli import main

    assert main(["schema", "--out", str(tmp_path / "s.json")]) == 0
    assert (tmp_path / "s.json").read_text() == json_schema_text()
    assert main(["schema"]) == 0
    assert capsys.readouterr().out == json_schema_text()


# --------------------------------------------------------------------------- 2. MJCF
def test_static_geoms_are_world_geoms_with_floor_contact_parameters():
    opt = SimOptions(floor_friction=0.7, floor_solref=(0.03, 0.9))
    s = scene_with([STATIC_BOX, {"shape": "plane", "size": {"width": 1.0, "depth": 0.5}, "position": [0, 1, 0.3]}])
    m = compile_model(s, opt)
    assert m.nbody == 1 + len(s.objects)  # no body per static geom: bodies 1..n are the objects
    for i, name in enumerate(s.static_names):
        g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, name)
        assert g >= 0 and m.geom_bodyid[g] == 0
        assert m.geom_priority[g] == 0 and m.geom_condim[g] == 3
        np.testing.assert_allclose(m.geom_friction[g], [0.7, 0, 0])
        np.testing.assert_allclose(m.geom_solref[g], [0.03, 0.9])
        np.testing.assert_allclose(m.geom_rgba[g], STATIC_COLOUR)
    g0 = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "static_0")
    assert m.geom_type[g0] == mujoco.mjtGeom.mjGEOM_BOX
    np.testing.assert_allclose(m.geom_size[g0], [0.6, 0.2, 0.01])
    np.testing.assert_allclose(m.geom_pos[g0], [0.0, 0.3, 0.1])
    g1 = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "static_1")
    assert m.geom_type[g1] == mujoco.mjtGeom.mjGEOM_PLANE
    np.testing.assert_allclose(m.geom_size[g1], [0.5, 0.25, 0.1])
    assert to_xml(scene_with([])) == to_xml(Scene.from_dict({"camera": CAMERA, "objects": [BALL]}))


# --------------------------------------------------------------------------- 3. ramp helpers
def test_ramp_descends_along_x_and_meets_the_floor():
    th = math.radians(20)
    r = ramp(20, length=1.0, width=0.4, thickness=0.03, x=0.1, y=0.3)
    assert r.size.width == 1.0 and r.size.depth == 0.4 and r.size.height == 0.03
    for x in (-0.3, 0.0, 0.3):  # the top surface: z = (x_foot - x) tan(theta)
        assert support_height(r, 0.1 + x, 0.3) == pytest.approx((0.5 * math.cos(th) - x) * math.tan(th), abs=1e-9)
    np.testing.assert_allclose(support_normal(r, 0.1, 0.3), [math.sin(th), 0, math.cos(th)], atol=1e-12)
    assert support_height(r, 0.1, 0.3 + 0.25) is None  # beside the ramp
    foot = 0.1 + 0.5 * math.cos(th)  # downhill edge of the top surface, on the floor
    assert support_height(r, foot - 1e-6, 0.3) == pytest.approx(0.0, abs=1e-5)
    np.testing.assert_allclose(rotation_matrix(r.orientation)[:, 0], [math.cos(th), 0, -math.sin(th)], atol=1e-12)
    r90 = ramp(20, 1.0, 0.4, 0.03, 0.0, 0.0, yaw_deg=90)  # descends along +y
    assert support_height(r90, 0.0, 0.3) < support_height(r90, 0.0, -0.3)
    plane = StaticPlane(shape="plane", size={"width": 2, "depth": 2}, position=(0, 0, 0.5))
    assert support_height(plane, 0.3, -0.2) == pytest.approx(0.5)
    assert support_height(plane, 1.5, 0.0) is None
    with pytest.raises(ValueError, match="angle"):
        ramp(95, 1, 1, 0.1, 0, 0)


# --------------------------------------------------------------------------- 4. physics
def _on_ramp(r, obj, s_up=0.6):
    """``obj`` (scene dict) resting on ramp ``r``, ``s_up`` m up the slope from the top centre."""
    R = rotation_matrix(r.orientation)
    d, n = R[:, 0], R[:, 2]
    p = np.asarray(r.position) + r.size.height / 2 * n - s_up * d
    lift = obj["size"]["radius"] if obj["shape"] == "sphere" else obj["size"]["height"] / 2
    return {**obj, "position": (p + lift * n).tolist(), "orientation": list(r.orientation)}, d


def _downhill_acceleration(scene, d, t0=0.1, t1=0.9):
    """Fitted acceleration along ``d`` (m/s^2) of object 0 between t0 and t1, and its travel (m)."""
    _, trace = simulate(scene, SimOptions(timestep=0.001))
    s = (trace.position[:, 0] - trace.position[0, 0]) @ d
    keep = (trace.t >= t0) & (trace.t <= t1)
    a2 = np.polyfit(trace.t[keep], s[keep], 2)[0]
    off = (trace.position[:, 0] - trace.position[0, 0]) - np.outer(s, d)
    return 2 * a2, s, float(np.abs(off).max())


BOX = {"shape": "box", "size": {"width": 0.2, "depth": 0.2, "height": 0.1}, "mass": 1.0}


@pytest.mark.parametrize("theta,mu", [(25.0, 0.2), (30.0, 0.4)])
def test_box_slides_down_ramp_at_g_sin_minus_mu_cos(theta, mu):
    r = ramp(theta, length=3.0, width=0.6, thickness=0.05, x=0.0, y=0.0)
    obj, d = _on_ramp(r, {**BOX, "material": {"sliding_friction": mu}}, s_up=1.2)
    a, s, off = _downhill_acceleration(scene_with([r.model_dump()], [obj], fps=50), d)
    th = math.radians(theta)
    expected = G * (math.sin(th) - mu * math.cos(th))
    assert a == pytest.approx(expected, rel=0.03)
    assert s[-1] < 2.2 and off < 0.005  # still on the ramp, moving straight down the slope


def test_box_with_mu_above_tan_theta_stays_put():
    r = ramp(20.0, length=2.0, width=0.6, thickness=0.05, x=0.0, y=0.0)
    obj, d = _on_ramp(r, {**BOX, "material": {"sliding_friction": 0.6}})  # tan 20 deg = 0.36
    _, trace = simulate(scene_with([r.model_dump()], [obj], fps=50))
    s = (trace.position[:, 0] - trace.position[0, 0]) @ d
    # static friction holds it; MuJoCo's soft contacts let it creep a few mm/s (a sliding box
    # at mu = 0.2 would cover ~0.8 m in this second)
    assert np.abs(s).max() < 0.005 and np.linalg.norm(trace.qvel[-1, 0, :3]) < 0.005


@pytest.mark.parametrize("theta", [15.0, 25.0])
def test_sphere_rolls_down_ramp_at_five_sevenths_g_sin(theta):
    r = ramp(theta, length=3.0, width=0.6, thickness=0.05, x=0.0, y=0.0)
    ball = {"shape": "sphere", "size": {"radius": 0.08}, "mass": 1.0, "material": {"sliding_friction": 0.8}}
    obj, d = _on_ramp(r, ball, s_up=1.2)
    a, s, off = _downhill_acceleration(scene_with([r.model_dump()], [obj], fps=50), d)
    assert a == pytest.approx(5 / 7 * G * math.sin(math.radians(theta)), rel=0.05)
    assert off < 0.005


# --------------------------------------------------------------------------- 5. rendering
def test_static_geoms_are_visible_in_rgb_and_background_in_segmentation():
    r = ramp(15.0, length=1.2, width=0.8, thickness=0.04, x=0.45, y=0.4)
    ball = {**BALL, "position": [-0.35, 0.2, 0.1]}
    with_ramp = scene_with([r.model_dump()], [ball], duration=0.1)
    without = scene_with([], [ball], duration=0.1)
    _, fr = render_scene(with_ramp, 96, 64, flow=False)
    _, f0 = render_scene(without, 96, 64, flow=False)
    changed = np.abs(fr.rgb[0].astype(int) - f0.rgb[0].astype(int)).sum(-1) > 30
    assert changed.sum() > 200  # the ramp is seen
    assert (fr.seg[0][changed] == -1).all()  # ... as background
    assert ((fr.seg[0] == 0) == (f0.seg[0] == 0)).all()  # the ball's mask is unchanged
    colour = np.array(STATIC_COLOUR[:3]) * 255
    assert np.abs(fr.rgb[0][changed].mean(0) - colour).max() < 60  # lit ramp colour


# --------------------------------------------------------------------------- 6. sampler
RAMP_CFG = SampleConfig(n_train=6, n_val=0, n_test=0, n_test_comp=0, p_ramp=1.0)


def test_sampler_with_p_ramp_one_puts_an_object_on_a_ramp():
    codec = SceneCodec.from_params({})
    with SceneFilter(RAMP_CFG) as filt:
        for i in range(RAMP_CFG.n_scenes):
            scene = sample_scene(np.random.default_rng(scene_seed(3, i)), RAMP_CFG, "train", filt)
            assert Scene.from_yaml(scene.to_yaml()) == scene
            assert len(scene.static) == 1 and scene.static[0].shape == "box"
            r = scene.static[0]
            assert RAMP_CFG.ramp_length[0] <= r.size.width <= RAMP_CFG.ramp_length[1] + 0.002
            assert 0 < r.position[2] < 0.6
            on = []
            for o in scene.objects:
                z = support_height(r, o.position[0], o.position[1])
                if z is not None and o.position[2] > z:
                    on.append(o)
            assert on, scene.to_yaml()
            assert filt.check(scene) is None  # passes the filters (ramp occlusion and contact included)
            seg, overlap = filt.static_first_frame(scene)
            assert overlap <= RAMP_CFG.overlap_tolerance
            with pytest.raises(CodecError):
                codec.encode(scene)


GOLDEN_P_RAMP_0 = "1472db5b0a5c43e0be0bf944fc33ef7239911a54e51c7d65ec8d918c0b8dced8"
"""sha256 of the canonical texts of these 24 scenes, made by the sampler before ramps existed
(commit aea0f0e): with ``p_ramp = 0`` every sampled scene stays byte-identical. Remade in issue
12 (item 4) when the library's default timestep became the params value 1/600 s (was 2 ms,
whose 30 fps frames fell between steps; the filter's rollout changed with it); the value is
main's sampler output at ``timestep = 1/600``, which the default DVC profile always used."""


def test_sampler_with_p_ramp_zero_is_unchanged():
    cfg = SampleConfig(n_train=16, n_val=2, n_test=2, n_test_comp=4)
    assert cfg.p_ramp == 0.0
    text = "".join(s.to_yaml(Decimals()) for _, _, s in iter_dataset(cfg, seed=11))  # quantised, as the stage writes
    assert hashlib.sha256(text.encode()).hexdigest() == GOLDEN_P_RAMP_0
    assert "static" not in text


def test_ramp_params_are_validated():
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match="ramp_angle"):
        SampleConfig(ramp_angle=(10.0, 95.0))
    with pytest.raises(ValidationError):
        SampleConfig(p_ramp=1.5)


def test_scene_language_doc_examples_are_valid_scenes():
    import re

    text = (ROOT / "docs" / "scene_language.md").read_text()
    blocks = [b for b in re.findall(r"```yaml\n(.*?)```", text, re.S) if "objects:" in b]
    assert len(blocks) >= 3
    scenes = [Scene.from_yaml(b, source="docs/scene_language.md") for b in blocks]
    on_ramp = next(s for s in scenes if s.static and s.objects[0].shape == "sphere")
    assert on_ramp.to_yaml() in text  # printed canonically
    assert sum(1 for s in scenes if s.static) >= 2


def test_ramp_parameters_invert_ramp():
    """``ramp_parameters`` reads back the numbers ``ramp`` was built from (the codec's ramp fields)."""
    from pipeline.static import ramp_parameters
    rng = np.random.default_rng(0)
    for _ in range(50):
        args = dict(angle_deg=float(rng.uniform(0, 60)), length=float(rng.uniform(0.3, 1.5)),
                    width=float(rng.uniform(0.2, 0.8)), thickness=0.03, x=float(rng.uniform(-1, 1)),
                    y=float(rng.uniform(-1, 1)), yaw_deg=float(rng.uniform(-179, 179)))
        got = ramp_parameters(ramp(**args))
        for k, v in args.items():
            assert got[k] == pytest.approx(v, abs=1e-9), k


@pytest.mark.parametrize("e", [0.5, 0.85])
def test_a_springy_stop_at_the_foot_of_a_ramp_bounces_the_box_back_and_leaves_the_slide_alone(e):
    """dev/10: an air-track glider slides down and rebounds off a spring bumper. A static box with
    ``restitution: e`` across the ramp's foot sends the sliding box back up at e times its
    impact speed (Newton's law of restitution, within 0.06: MuJoCo's soft contact), while the
    slide down keeps ``g (sin theta - mu cos theta)`` (3 %): the ramp's contact is not springy. A
    stop without restitution (the object's material, critically damped) keeps under 0.2 of it."""
    theta, mu = 20.0, 0.1
    r = ramp(theta, length=3.0, width=0.6, thickness=0.05, x=0.0, y=0.0)
    obj, d = _on_ramp(r, {**BOX, "material": {"sliding_friction": mu}}, s_up=0.5)
    R = rotation_matrix(r.orientation)
    n = R[:, 2]
    foot = np.asarray(r.position) + r.size.height / 2 * n + 1.2 * d + 0.15 * n   # 1.2 m down the slope
    stop = {"shape": "box", "size": {"width": 0.02, "depth": 0.5, "height": 0.3}, "position": foot.tolist(),
            "orientation": list(r.orientation)}

    def run(restitution):
        st = {**stop, "restitution": restitution} if restitution is not None else stop
        scene = scene_with([r.model_dump(), st], [obj], fps=200, duration=1.5)
        _, trace = simulate(scene, SimOptions(timestep=0.0005))
        v = trace.qvel[:, 0, :3] @ d                                     # down-slope speed, m/s
        k = int(np.argmax(v))                                           # just before the impact
        return v, k, trace

    v, k, trace = run(e)
    th = math.radians(theta)
    early = trace.t < trace.t[k] - 0.05
    a = np.polyfit(trace.t[early], v[early], 1)[0]
    assert a == pytest.approx(G * (math.sin(th) - mu * math.cos(th)), rel=0.03)
    after = v[k:k + 40]
    assert -after.min() / v[k] == pytest.approx(e, abs=0.06)
    v0, k0, _ = run(None)
    assert -v0[k0:k0 + 40].min() / v0[k0] < 0.2
    assert Scene.from_yaml(scene_with([r.model_dump(), {**stop, "restitution": e}], [obj]).to_yaml()).static[1].restitution == e
    with pytest.raises(SceneError, match=r"static\[0\]\.restitution"):
        scene_with([{**stop, "restitution": 1.5}])
    spec = REGISTRY["restitution"].parameters["e"]
    assert STATIC_RESTITUTION == (spec.low, spec.high)   # the restitution effect's range
