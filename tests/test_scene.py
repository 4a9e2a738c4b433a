"""Scene language v1: canonical YAML round trip and one-line errors naming the field path."""

from pathlib import Path

import pytest

from pipeline.scene import Decimals, Scene, SceneError, load_scene

SCENE = """\
version: 1
duration: 1.0
fps: 30
gravity: 9.81
camera:
  height: 1.2
  pitch: 35.0
  fov: 45.0
objects:
  - shape: box
    size: {width: 0.2, depth: 0.1, height: 0.1}
    mass: 0.8
    position: [0.1, 0.3, 0.05]
    orientation: [1.0, 0.0, 0.0, 0.0]
    linear_velocity: [0.0, 1.2, 0.0]
    angular_velocity: [0.0, 0.0, 0.0]
    material: {sliding_friction: 0.4, rolling_friction: 0.001, damping: 0.1}
  - shape: sphere
    size: {radius: 0.05}
    mass: 0.2
    position: [-0.3, 0.2, 0.4]
    orientation: [1.0, 0.0, 0.0, 0.0]
    linear_velocity: [0.5, 0.0, 1.0]
    angular_velocity: [0.0, 3.0, 0.0]
    material: {sliding_friction: 0.6, rolling_friction: 0.0, damping: 0.0}
  - shape: cylinder
    size: {radius: 0.08, height: 0.2}
    mass: 1.5
    position: [0.4, 0.0, 0.1]
    orientation: [0.707, 0.707, 0.0, 0.0]
    linear_velocity: [0.0, 0.0, 0.0]
    angular_velocity: [0.0, 0.0, 0.0]
    material: {sliding_friction: 0.3, rolling_friction: 0.002, damping: 0.05}
effects: []
"""


def _edit(old: str, new: str, count: int = 1) -> str:
    assert old in SCENE
    return SCENE.replace(old, new, count)


def test_canonical_text_round_trips_exactly():
    scene = Scene.from_yaml(SCENE)
    assert scene.to_yaml() == SCENE
    assert Scene.from_yaml(scene.to_yaml()) == scene
    assert scene.object_names == ["box_0", "sphere_1", "cylinder_2"]
    assert scene.composition == ("box", "cylinder", "sphere")


def test_canonical_text_rounds_and_orders_keys():
    messy = """objects:
  - {material: {damping: 0.0}, position: [0.1234564, 0, 0.1], mass: 1.23456789, size: {radius: 0.1}, shape: sphere}
camera: {fov: 45, pitch: 35, height: 1.2}
"""
    scene = Scene.from_yaml(messy)
    text = scene.to_yaml()
    assert text.index("camera:") < text.index("objects:")
    # six significant digits whatever the field (issue 35)
    assert "position: [0.123456, 0.0, 0.1]" in text and "mass: 1.23457" in text
    assert scene.rounded() == Scene.from_yaml(text)
    assert Scene.from_yaml(text).to_yaml() == text  # idempotent
    # the quantised form (model targets): fixed decimals per field
    quantised = scene.to_yaml(Decimals())
    assert "position: [0.123, 0.0, 0.1]" in quantised and "mass: 1.235" in quantised
    assert Scene.from_yaml(quantised).to_yaml(Decimals()) == quantised


@pytest.mark.parametrize("value", [1e-5, 2.5e-7, 1e16, 123456789.0, 0.00012345678, -3e-9])
def test_canonical_text_reads_back_every_magnitude_as_a_number(value):
    """A float in exponent form must read back as a number: YAML 1.1 reads ``1e-05`` as a
    string, so the canonical text writes ``1.0e-05``."""
    scene = Scene.from_yaml(f"camera: {{height: 1.2}}\nobjects: [{{shape: sphere, size: {{radius: 0.1}}, mass: 1.0, "
                            f"position: [{value!r}, 0.0, 0.5], linear_velocity: [0.0, {value!r}, 0.0]}}]\n")
    again = Scene.from_yaml(scene.to_yaml())
    assert again.objects[0].position[0] == pytest.approx(value, rel=5e-6)
    assert again.objects[0].linear_velocity[1] == pytest.approx(value, rel=5e-6)
    assert Scene.from_yaml(scene.to_yaml(Decimals())).objects[0].mass == 1.0


@pytest.mark.parametrize("text,message", [
    (_edit("size: {radius: 0.08, height: 0.2}", "size: {radius: -1.0, height: 0.2}"),
     "<scene>: objects[2].size.radius: must be >= 0.001"),
    (_edit("mass: 0.2", "mass: -0.2"), "<scene>: objects[1].mass: must be >= 1e-06"),
    (_edit("  - shape: sphere", "  - shape: cone"), "<scene>: objects[1].shape: unknown shape"),
    (_edit("    mass: 0.8", "    mass: 0.8\n    colour: red"), "<scene>: objects[0].colour: must not be given (unknown key)"),
    (_edit("fps: 30", "fps: 30\nwind: 3"), "<scene>: wind: must not be given (unknown key)"),
    (_edit("pitch: 35.0", "pitch: 120.0"), "<scene>: camera.pitch: must be <= 89"),
    (_edit("orientation: [1.0, 0.0, 0.0, 0.0]", "orientation: [1.0, 1.0, 0.0, 0.0]"),
     "<scene>: objects[0].orientation: must be a unit quaternion"),
    (_edit("size: {radius: 0.05}", "size: {width: 0.05}"), "<scene>: objects[1].size.radius: must be given (required field missing)"),
    ("objects: [\n  - {shape: box\n", "<scene>: line "),
    ("- just a list\n", "<scene>: <root>: must be a mapping"),
])
def test_errors_are_one_line_and_name_the_field(text, message):
    with pytest.raises(SceneError) as err:
        Scene.from_yaml(text)
    msg = str(err.value)
    assert msg.startswith(message), msg
    assert "\n" not in msg


def test_error_quotes_the_bad_value():
    with pytest.raises(SceneError, match=r"objects\[2\]\.size\.radius: must be >= 0\.001, got -1"):
        Scene.from_yaml(_edit("size: {radius: 0.08, height: 0.2}", "size: {radius: -1.0, height: 0.2}"))
    with pytest.raises(SceneError, match="got 'cone'"):
        Scene.from_yaml(_edit("  - shape: sphere", "  - shape: cone"))


def test_load_scene_names_the_file(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(_edit("mass: 0.2", "mass: -0.2"))
    with pytest.raises(SceneError, match=rf"^{path}: objects\[1\]\.mass: must be >= 1e-06"):
        load_scene(path)
    with pytest.raises(SceneError, match="cannot read"):
        load_scene(tmp_path / "missing.yaml")
    malformed = tmp_path / "malformed.yaml"
    malformed.write_text("camera: {height: 1.2\nobjects: [")
    with pytest.raises(SceneError, match=rf"^{malformed}: line \d+: must be well-formed YAML"):
        load_scene(malformed)


# ------------------------------------------------------------- hostile input (issue 12)
REPRO = Path(__file__).resolve().parents[1].parent / "shared" / "repro"


def _valid_text(mass: float = 1.0) -> str:
    return ("camera: {height: 1.2}\nobjects:\n  - shape: sphere\n    size: {radius: 0.1}\n"
            f"    mass: {mass:.1e}\n    position: [0, 0, 0.1]\n")


@pytest.mark.parametrize("content, needle", [
    (b"\xff" + _valid_text().encode(), "must be UTF-8 text, got byte 0xff at offset 0"),
    (("duration: " + "[" * 996 + "]" * 996 + "\n" + _valid_text()).encode(), "must nest at most 32 levels"),
    (("duration: " + "9" * 4301 + "\n" + _valid_text()).encode(), "must have numbers of at most 4300 digits"),
    (("a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1]\n" + "".join(
        f"{chr(98 + i)}: &{chr(98 + i)} [{', '.join(['*' + chr(97 + i)] * 9)}]\n" for i in range(8))
      + _valid_text()).encode(), "aliases"),
    (_valid_text(1e-20).encode(), "objects[0].mass: must be >= 1e-06, got 1e-20"),
])
def test_hostile_scene_files_get_one_short_line(tmp_path, content, needle):
    path = tmp_path / "bad.yaml"
    path.write_bytes(content)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    msg = str(info.value)
    assert needle in msg and "\n" not in msg and len(msg) < 300, msg


def test_tiny_mass_round_trips():
    """0.0004 kg used to print as 0.0 in the canonical text and then fail validation."""
    scene = Scene.from_yaml(_valid_text(0.0004))
    text = scene.to_yaml()
    assert "mass: 0.0004" in text
    assert Scene.from_yaml(text) == scene.rounded()


@pytest.mark.skipif(not REPRO.exists(), reason="../shared/repro not present")
@pytest.mark.parametrize("name", ["scene_nonutf8", "scene_deep_list", "scene_bigint", "scene_billion_laughs_8",
                                  "scene_mass_1e-20_compile_traceback"])
def test_repro_scene_files(name):
    with pytest.raises(SceneError) as info:
        load_scene(REPRO / f"{name}.yaml")
    assert "\n" not in str(info.value) and len(str(info.value)) < 300


def test_object_count_and_frame_budget():
    """Issue 12: objects 128+ wrapped around in the int8 segmentation; 2 s at 10,000 fps ran for
    minutes. Both are rejected up front with one line."""
    ball = {"shape": "sphere", "size": {"radius": 0.01}, "mass": 0.1}
    many = {"camera": {"height": 1.0}, "objects": [{**ball, "position": [0.03 * i, 0, 0.01]} for i in range(128)]}
    with pytest.raises(SceneError, match=r"^<scene>: objects: must have at most 127 items, got 128$"):
        Scene.from_dict(many)
    long = {"camera": {"height": 1.0}, "fps": 10000, "duration": 2.0, "objects": [{**ball, "position": [0, 0, 0.01]}]}
    with pytest.raises(SceneError, match=r"duration \* fps: must be at most 10000 frames, got 20000"):
        Scene.from_dict(long)
