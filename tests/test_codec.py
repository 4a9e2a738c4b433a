"""Tests of pipeline.codec: quantised scene tokens, detokenising to canonical YAML, grammar."""

import numpy as np
import pytest

from pipeline.codec import (ANSWER, END_ANSWER, CodecError, SceneCodec, composition_of, split_completion,
                            target_tokens, think_tokens)
from pipeline.sample_config import SampleConfig
from pipeline.sampler import iter_dataset
from pipeline.scene import Decimals, Scene

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
