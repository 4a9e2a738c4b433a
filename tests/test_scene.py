"""Scene language v1: canonical YAML round trip and one-line errors naming the field path."""

import pytest

from pipeline.scene import Scene, SceneError, load_scene

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
  - {material: {damping: 0.0}, position: [0.123456, 0, 0.1], mass: 1.23456, size: {radius: 0.1}, shape: sphere}
camera: {fov: 45, pitch: 35, height: 1.2}
"""
    scene = Scene.from_yaml(messy)
    text = scene.to_yaml()
    assert text.index("camera:") < text.index("objects:")
    assert "position: [0.123, 0.0, 0.1]" in text and "mass: 1.235" in text
    assert scene.rounded() == Scene.from_yaml(text)
    assert Scene.from_yaml(text).to_yaml() == text  # idempotent


@pytest.mark.parametrize("text,message", [
    (_edit("size: {radius: 0.08, height: 0.2}", "size: {radius: -1.0, height: 0.2}"),
     "<scene>: objects[2].size.radius: must be > 0"),
    (_edit("mass: 0.2", "mass: -0.2"), "<scene>: objects[1].mass: must be > 0"),
    (_edit("  - shape: sphere", "  - shape: cone"), "<scene>: objects[1].shape: unknown shape"),
    (_edit("    mass: 0.8", "    mass: 0.8\n    colour: red"), "<scene>: objects[0].colour: unknown key"),
    (_edit("fps: 30", "fps: 30\nwind: 3"), "<scene>: wind: unknown key"),
    (_edit("pitch: 35.0", "pitch: 120.0"), "<scene>: camera.pitch: must be <= 89"),
    (_edit("orientation: [1.0, 0.0, 0.0, 0.0]", "orientation: [1.0, 1.0, 0.0, 0.0]"),
     "<scene>: objects[0].orientation: must be a unit quaternion"),
    (_edit("size: {radius: 0.05}", "size: {width: 0.05}"), "<scene>: objects[1].size.radius: required field missing"),
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
    with pytest.raises(SceneError, match=r"objects\[2\]\.size\.radius: must be > 0(\.0)?, got -1"):
        Scene.from_yaml(_edit("size: {radius: 0.08, height: 0.2}", "size: {radius: -1.0, height: 0.2}"))
    with pytest.raises(SceneError, match="got 'cone'"):
        Scene.from_yaml(_edit("  - shape: sphere", "  - shape: cone"))


def test_load_scene_names_the_file(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(_edit("mass: 0.2", "mass: -0.2"))
    with pytest.raises(SceneError, match=rf"^{path}: objects\[1\]\.mass: must be > 0"):
        load_scene(path)
    with pytest.raises(SceneError, match="cannot read"):
        load_scene(tmp_path / "missing.yaml")
    malformed = tmp_path / "malformed.yaml"
    malformed.write_text("camera: {height: 1.2\nobjects: [")
    with pytest.raises(SceneError, match=rf"^{malformed}: line \d+: malformed YAML"):
        load_scene(malformed)
