"""Events from traces against constructed scenes (issue 4, check 8).

Each event must be reported within one frame of the time the construction gives: a contact
during (t_{k-1}, t_k] is reported at t_k (pipeline/events.py).
"""

import pipeline  # noqa: F401  (MUJOCO_GL before mujoco)

import numpy as np
import pytest
from numpy.testing import assert_allclose

from pipeline.camera import extrinsics, intrinsics
from pipeline.events import (NO_EVENTS, Event, EventConfig, events_from_rows, events_to_rows,
                             events_to_text, extract_events)
from pipeline.render import render_scene
from pipeline.scene import Scene
from pipeline.simulate import simulate

G = 9.81
CAMERA = {"height": 1.2, "pitch": 30.0, "fov": 50.0}


def make_scene(objects, gravity=G, duration=1.0, fps=30):
    return Scene.from_dict({"duration": duration, "fps": fps, "gravity": gravity, "camera": CAMERA,
                            "objects": objects})


def of_kind(events, kind):
    return [e for e in events if e.kind == kind]


@pytest.mark.parametrize("h", [0.2, 0.5, 1.0])
def test_dropped_ball_first_hits_floor_at_free_fall_time(h):
    # Free fall from rest: the ball's bottom falls h in sqrt(2 h / g).
    r = 0.1
    scene = make_scene([{"shape": "sphere", "size": {"radius": r}, "mass": 0.5, "position": [0, 0, h + r]}])
    _, trace = simulate(scene)
    hits = [e for e in of_kind(extract_events(trace), "collision") if e.objects == ("sphere_0", "floor")]
    assert hits, "no floor collision"
    expected = np.sqrt(2 * h / G)
    assert 0 <= hits[0].t - expected <= 1 / scene.fps + 1e-3, (hits[0].t, expected)
    assert hits[0].force > 0.5 * G  # an impact, stronger than the ball's weight


def test_resting_objects_make_no_collisions():
    # Objects placed on the floor (z = half height) touch it at distance 0 from t = 0.
    box = {"shape": "box", "size": {"width": 0.2, "depth": 0.2, "height": 0.1}, "mass": 1.0, "position": [0, 0, 0.05]}
    ball = {"shape": "sphere", "size": {"radius": 0.1}, "mass": 1.0, "position": [0.5, 0, 0.1]}
    _, trace = simulate(make_scene([box, ball]))
    assert extract_events(trace) == []


def test_sliding_box_stops_at_friction_time():
    # Coulomb deceleration mu g: at rest at v0 / (mu g); reported when |v| < stop_speed
    # (0.05 m/s, i.e. 0.05 / (mu g) = 17 ms early) and within one frame.
    v0, mu = 2.0, 0.3
    box = {"shape": "box", "size": {"width": 0.2, "depth": 0.2, "height": 0.1}, "mass": 1.0,
           "position": [0, 0, 0.05], "linear_velocity": [v0, 0, 0], "material": {"sliding_friction": mu}}
    scene = make_scene([box])
    _, trace = simulate(scene)
    stops = of_kind(extract_events(trace), "stop")
    assert [e.objects for e in stops] == [("box_0",)]
    assert abs(stops[0].t - v0 / (mu * G)) <= 1 / scene.fps


def test_head_on_spheres_collide_at_contact_time():
    # Constant velocities until the gap closes: t = (d - 2 r) / (v_a - v_b).
    r, d, v = 0.1, 0.8, 1.5
    a = {"shape": "sphere", "size": {"radius": r}, "mass": 1.0, "position": [-d / 2, 0, 0.5], "linear_velocity": [v, 0, 0]}
    b = {"shape": "sphere", "size": {"radius": r}, "mass": 1.0, "position": [d / 2, 0, 0.5], "linear_velocity": [-v, 0, 0]}
    scene = make_scene([a, b], gravity=0.0)
    _, trace = simulate(scene)
    hits = of_kind(extract_events(trace), "collision")
    assert [e.objects for e in hits] == [("sphere_0", "sphere_1")]
    assert 0 <= hits[0].t - (d - 2 * r) / (2 * v) <= 1 / scene.fps + 1e-3


def test_enter_and_leave_view_times():
    # A sphere crossing the view from left to right with constant velocity (no gravity).
    # With a 1 px threshold it is in view once its silhouette covers the first pixel centre
    # (u = 0.5) and out of view once it has passed the last one (u = W - 0.5). Silhouette
    # edges: image columns are planes through the eye containing the camera's y axis; the
    # plane at angle phi (u = cx + f tan phi) touches the sphere (centre C in the camera
    # frame) when phi = atan2(Cx, Cz) +/- asin(r / sqrt(Cx^2 + Cz^2)).
    W, H, r, v = 96, 64, 0.1, 2.0
    x0 = -2.5
    scene = make_scene([{"shape": "sphere", "size": {"radius": r}, "mass": 1.0, "position": [x0, 0.3, 0.4],
                         "linear_velocity": [v, 0, 0]}], gravity=0.0, duration=2.5)
    trace, frames = render_scene(scene, W, H, depth=False, flow=False, rgb=False)
    events = extract_events(trace, frames.visible_pixels(1), EventConfig(min_visible_px=1))
    enter, leave = of_kind(events, "enter_view"), of_kind(events, "leave_view")
    assert len(enter) == 1 and len(leave) == 1
    t = np.linspace(0, scene.duration, 5001)
    centre = np.stack([x0 + v * t, np.full_like(t, 0.3), np.full_like(t, 0.4)], -1)
    R, tc = extrinsics(scene.camera)
    K = intrinsics(scene.camera.fov, W, H)
    c = centre @ R.T + tc
    psi, half = np.arctan2(c[:, 0], c[:, 2]), np.arcsin(r / np.hypot(c[:, 0], c[:, 2]))
    u_right = K[0, 2] + K[0, 0] * np.tan(psi + half)
    u_left = K[0, 2] + K[0, 0] * np.tan(psi - half)
    t_enter, t_leave = t[np.argmax(u_right >= 0.5)], t[np.argmax(u_left >= W - 0.5)]
    assert abs(enter[0].t - t_enter) <= 1 / scene.fps, (enter[0].t, t_enter)
    assert abs(leave[0].t - t_leave) <= 1 / scene.fps, (leave[0].t, t_leave)


def test_text_is_compact_and_deterministic():
    events = [Event("collision", 7, 0.2333, ("sphere_0", "floor"), 12.5), Event("stop", 17, 0.5667, ("box_1",)),
              Event("collision", 20, 0.6667, ("sphere_0", "box_1"), 3.0), Event("leave_view", 25, 0.8333, ("sphere_0",))]
    text = events_to_text(events, ["sphere_0", "box_1"])
    assert text == ("t=0.23 sphere_0 hits floor; t=0.57 box_1 stops; t=0.67 sphere_0 hits box_1; "
                    "t=0.83 sphere_0 leaves view")
    assert events_to_text([]) == NO_EVENTS
    with pytest.raises(ValueError, match="cylinder_2"):
        events_to_text([Event("stop", 1, 0.03, ("cylinder_2",))], ["sphere_0"])
    assert events_from_rows(events_to_rows("scene-000001", events)) == events


def test_extraction_is_deterministic_and_sorted():
    a = {"shape": "sphere", "size": {"radius": 0.1}, "mass": 1.0, "position": [0, 0, 0.6], "linear_velocity": [0.5, 0, 0]}
    b = {"shape": "box", "size": {"width": 0.2, "depth": 0.2, "height": 0.2}, "mass": 1.0, "position": [0.5, 0, 0.4]}
    _, t1 = simulate(make_scene([a, b]))
    _, t2 = simulate(make_scene([a, b]))
    e1, e2 = extract_events(t1), extract_events(t2)
    assert e1 == e2 and len(e1) >= 2
    assert [e.frame for e in e1] == sorted(e.frame for e in e1)
    assert_allclose([e.t for e in e1], [t1.t[e.frame] for e in e1])
