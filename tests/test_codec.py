"""Tests of pipeline.codec: quantised scene tokens, detokenising to canonical YAML, grammar."""

import math

import numpy as np
import pytest

from pipeline.codec import (ANSWER, END_ANSWER, RAMP_FIELDS, RAMP_TOKEN, CodecError, SceneCodec, composition_of,
                            split_completion, target_tokens, think_tokens)
from pipeline.sample_config import SampleConfig
from pipeline.sampler import iter_dataset
from pipeline.scene import Decimals, Scene
from pipeline.static import ramp_parameters, support_height

CODEC = SceneCodec.from_params({})


@pytest.fixture(scope="module")
def scenes():
    cfg = SampleConfig(n_train=24, n_val=0, n_test=0, n_test_comp=0, width=96, height=64)
    return [s for _, _, s in iter_dataset(cfg, 11, decimals=Decimals())]


def test_round_trip_within_half_a_bin(scenes):
    for scene in scenes:
        toks = CODEC.encode(scene)
        assert toks[0] == ANSWER and toks[-1] == END_ANSWER
        assert len(toks) == 5 + sum(1 + len(CODEC.object_fields(o.shape)) for o in scene.objects)
        back = CODEC.decode(toks)
        assert back.composition == scene.composition
        assert (back.duration, back.fps, back.gravity, back.effects) == (scene.duration, scene.fps, scene.gravity, [])
        for a, b in zip(scene.objects, back.objects):
            half = {ax: CODEC.q[f"position.{ax}"].step / 2 for ax in "xyz"}
            for i, ax in enumerate("xyz"):
                assert abs(a.position[i] - b.position[i]) <= half[ax] + 1e-3  # + canonical rounding
            assert abs(np.linalg.norm(b.orientation) - 1) < 2e-3          # renormalised
            # same rotation up to sign and quantisation
            assert abs(abs(np.dot(a.orientation, b.orientation)) - 1) < 1e-3
        assert Scene.from_yaml(back.to_yaml()) == back                    # canonical YAML
    err = CODEC.quantisation_error(scenes)
    for f, e in err.items():
        assert e["max_abs"] <= e["half_bin"] + 1e-9 or e["clipped"] > 0, f
        assert e["clipped"] == 0, f  # the sampler's scenes are inside the ranges


def test_a_four_box_answer_has_89_tokens():
    assert CODEC.max_answer_tokens() == 89


def test_decode_errors_name_the_position():
    with pytest.raises(CodecError, match=r"token 3: expected a shape token, got '<5>'"):
        CODEC.decode(["<1>", "<2>", "<3>", "<5>"])
    with pytest.raises(CodecError, match="got the end"):
        CODEC.decode(["<1>", "<2>", "<3>", "<sphere>", "<4>"])
    with pytest.raises(CodecError, match="no objects"):
        CODEC.decode(["<1>", "<2>", "<3>"])
    small = SceneCodec.from_params({"tokens": {"bins": 8}})
    with pytest.raises(CodecError, match="bin 9 out of range"):
        small.decode(["<9>", "<2>", "<3>"])


def test_values_outside_the_range_are_clipped_and_reported():
    scene = Scene.from_dict({"camera": {"height": 3.0, "pitch": 35, "fov": 45},
                             "objects": [{"shape": "sphere", "size": {"radius": 0.1}, "mass": 1.0,
                                          "position": [0.0, 0.0, 0.1]}]})
    back = CODEC.roundtrip(scene)
    assert back.camera.height == pytest.approx(1.4)  # sample.camera_height max
    assert CODEC.quantisation_error([scene])["camera.height"]["clipped"] == 1.0
    with pytest.raises(CodecError, match="6-DoF"):
        CODEC.encode(scene.replace(camera={"position": [0, -2, 1], "yaw": 0, "pitch": 30, "roll": 0, "fov": 45}))


def test_think_words_and_completion_split():
    assert think_tokens("t=0.23 sphere_0 hits floor; t=0.57 box_1 stops") == [
        "t=0.23", "sphere_0", "hits", "floor", ";", "t=0.57", "box_1", "stops"]
    scene = Scene.from_dict({"camera": {"height": 1.0, "pitch": 35, "fov": 45},
                             "objects": [{"shape": "box", "size": {"width": 0.2, "depth": 0.2, "height": 0.2},
                                          "mass": 1.0, "position": [0.0, 0.0, 0.1]}]})
    toks = target_tokens(CODEC, scene, "no events")
    think, answer = split_completion(toks)
    assert think == ["no", "events"] and composition_of(answer) == ("box",)
    assert split_completion(toks[:-1]) == (["no", "events"], None)  # cut off before </answer>


def test_codec_spec_round_trips():
    assert SceneCodec.from_dict(CODEC.to_dict()).to_dict() == CODEC.to_dict()
    with pytest.raises(CodecError, match="sample.mass: must be a range"):
        SceneCodec.from_params({"sample": {"mass": [2.0, 1.0]}})


# ----------------------------------------------------------------------------- ramps (issue 30)
RAMP_PARAMS = {"sample": {"p_ramp": 1.0}}
RAMP_CODEC = SceneCodec.from_params(RAMP_PARAMS)


@pytest.fixture(scope="module")
def ramp_scenes():
    cfg = SampleConfig(n_train=12, n_val=0, n_test=0, n_test_comp=0, width=96, height=64, p_ramp=1.0)
    return [s for _, _, s in iter_dataset(cfg, 5, decimals=Decimals())]


def test_a_codec_has_ramps_only_when_the_sampler_draws_them():
    assert not CODEC.has_ramps and RAMP_TOKEN not in CODEC.answer_vocab and "ramp" not in CODEC.grammar()
    assert RAMP_CODEC.has_ramps and RAMP_TOKEN in RAMP_CODEC.answer_vocab
    assert RAMP_CODEC.max_answer_tokens() == CODEC.max_answer_tokens() + 1 + len(RAMP_FIELDS)
    # the spec saved beside a checkpoint keeps the ramp fields and the thickness
    again = SceneCodec.from_dict(RAMP_CODEC.to_dict())
    assert again.has_ramps and again.constants["ramp_thickness"] == pytest.approx(0.03)


def test_ramp_scenes_round_trip_within_half_a_bin_and_keep_their_object_on_the_ramp(ramp_scenes):
    """The ramp's numbers come back within half a bin, and the object the sampler put on it still
    rests on the decoded ramp (its lowest point within the quantisation of the two positions)."""
    assert all(len(s.static) == 1 for s in ramp_scenes)
    for scene in ramp_scenes:
        toks = RAMP_CODEC.encode(scene)
        assert toks[4] == RAMP_TOKEN
        back = RAMP_CODEC.decode(toks)
        assert len(back.static) == 1 and back.composition == scene.composition
        a, b = ramp_parameters(scene.static[0]), ramp_parameters(back.static[0])
        for f, key in zip(RAMP_FIELDS, ("angle_deg", "length", "width", "x", "y", "yaw_deg")):
            # + the canonical text's rounding: quaternion components to 1e-3 (~0.1 deg), positions to 1 mm
            extra = 0.15 if key.endswith("deg") else 2e-3
            assert abs(a[key] - b[key]) <= RAMP_CODEC.q[f].step / 2 + extra, (f, a[key], b[key])
        assert b["thickness"] == pytest.approx(a["thickness"])
        assert Scene.from_yaml(back.to_yaml()) == back
        for o, p in zip(scene.objects, back.objects):
            z0, z1 = support_height(scene.static[0], *o.position[:2]), support_height(back.static[0], *p.position[:2])
            if z0 is None or o.position[2] - z0 > 0.5:          # not on the ramp
                continue
            assert z1 is not None, "the object fell off the decoded ramp"
            gap0, gap1 = o.position[2] - z0, p.position[2] - z1  # centre above the top face, m
            # half a bin of x, y (times the slope) and of z, plus the rotation of the slope
            slope = math.tan(math.radians(a["angle_deg"]))
            tol = (RAMP_CODEC.q["position.x"].step + RAMP_CODEC.q["ramp.x"].step) * slope \
                + RAMP_CODEC.q["position.z"].step / 2 + 0.005
            assert abs(gap1 - gap0) <= tol, (gap0, gap1, tol)
    err = RAMP_CODEC.quantisation_error(ramp_scenes)
    for f in RAMP_FIELDS:
        assert err[f]["clipped"] == 0 and err[f]["max_abs"] <= err[f]["half_bin"] + 1e-9, f


def test_a_decoded_ramp_scene_rolls_downhill_as_the_original_does(ramp_scenes):
    """Physics of the round trip: a ball the sampler put on the ramp, released at rest, rolls down the decoded
    ramp as on the original (0.25 s; a solid sphere rolling without slip: s = 5/14 g sin(theta) t^2)."""
    from pipeline.simulate import simulate
    checked = 0
    for scene in ramp_scenes:
        r = scene.static[0]
        theta = math.radians(ramp_parameters(r)["angle_deg"])

        def on_ramp(o) -> bool:   # a ball whose centre is r / cos(theta) above the top face
            z = support_height(r, *o.position[:2])
            return (o.shape == "sphere" and z is not None
                    and abs(o.position[2] - z - o.size.radius / math.cos(theta)) < 0.005)
        balls = [k for k, o in enumerate(scene.objects) if on_ramp(o)]
        if not balls:
            continue
        k = balls[0]
        # released at rest, rolling freely (no damping, no rolling friction) with enough grip not
        # to slip (mu >= 2/7 tan(theta)), for 0.25 s: still on the ramp
        ball = scene.objects[k].model_copy(update={
            "linear_velocity": (0.0, 0.0, 0.0), "angular_velocity": (0.0, 0.0, 0.0),
            "material": scene.objects[k].material.model_copy(
                update={"sliding_friction": 0.6, "rolling_friction": 0.0, "damping": 0.0})})
        short = scene.replace(duration=0.25, objects=[ball if i == k else o for i, o in enumerate(scene.objects)])
        back = RAMP_CODEC.decode(RAMP_CODEC.encode(short)).replace(duration=short.duration)   # a codec constant
        _, t0 = simulate(short)
        _, t1 = simulate(back)
        d0 = t0.position[-1, k] - t0.position[0, k]
        d1 = t1.position[-1, k] - t1.position[0, k]
        expect = 5 / 14 * 9.81 * math.sin(theta) * 0.25 ** 2
        assert np.linalg.norm(d0) == pytest.approx(expect, rel=0.15)
        assert np.linalg.norm(d1 - d0) <= 0.1 * expect + 0.01
        checked += 1
    assert checked >= 1


def test_the_ramp_grammar_accepts_ramp_answers_and_refuses_a_second_ramp(ramp_scenes):
    import xgrammar as xgr
    vocab = RAMP_CODEC.answer_vocab + ["</s>"]
    info = xgr.TokenizerInfo(vocab, vocab_type=xgr.VocabType.RAW, vocab_size=len(vocab), stop_token_ids=[len(vocab) - 1])
    compiled = xgr.GrammarCompiler(info, max_threads=1).compile_grammar(RAMP_CODEC.grammar())
    ids = {t: i for i, t in enumerate(vocab)}
    scene = ramp_scenes[0]
    for toks in (RAMP_CODEC.encode(scene), RAMP_CODEC.encode(scene.replace(static=[]))):
        m = xgr.GrammarMatcher(compiled)
        assert all(m.accept_token(ids[t]) for t in toks) and m.accept_token(ids["</s>"]) and m.is_terminated()
    toks = RAMP_CODEC.encode(scene)
    m = xgr.GrammarMatcher(compiled)
    assert all(m.accept_token(ids[t]) for t in toks[:11])          # <answer>, camera, the ramp
    assert not m.accept_token(ids[RAMP_TOKEN])                      # one ramp at most, before the objects
    with pytest.raises(CodecError, match="codec without ramps"):
        CODEC.decode(toks)
    with pytest.raises(CodecError, match="at most one ramp"):
        RAMP_CODEC.encode(scene.replace(static=[scene.static[0], scene.static[0]]))
