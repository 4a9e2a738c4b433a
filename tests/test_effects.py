"""Effect library (pipeline.effects): MuJoCo mechanisms against closed forms, in-place model
edits against rebuilt models, and one-line errors."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from pipeline import effects as fx
from pipeline import engine
from pipeline.mjcf import SimOptions, compile_model, to_xml
from pipeline.scene import Scene, SceneError
from pipeline.simulate import rollout

OPTS = SimOptions(textured=False)
BALL = {"shape": "sphere", "size": {"radius": 0.03}, "mass": 0.01}


def _scene(objects, effects=(), gravity=9.81):
    return Scene.from_dict({"camera": {"height": 1.2}, "gravity": gravity, "duration": 1.0, "fps": 30,
                            "objects": list(objects), "effects": list(effects)})


def _forward(scene):
    model = compile_model(scene, OPTS)
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    mujoco.mj_forward(model, data)
    return model, data


VALUES = {"quadratic_drag": {"density": 3.0}, "wind": {"wind_x": 2.0, "wind_y": -1.0},
          "restitution": {"e": 0.7}, "floor_tilt": {"tilt_x": 3.0, "tilt_y": -2.0},
          "magnus_lift": {"lift": 1.5}, "torsional_friction": {"mu_torsion": 0.02}}


def test_every_effect_has_values_here():
    assert set(VALUES) == set(fx.EFFECTS)


@pytest.mark.parametrize("combo", [[k] for k in VALUES] + [["quadratic_drag", "magnus_lift"],
                                                           ["wind", "magnus_lift"], ["quadratic_drag", "wind"],
                                                           ["restitution", "floor_tilt", "torsional_friction"]])
def test_in_place_edit_equals_rebuilt_model(combo):
    """configure_model on a model compiled once == the MJCF rebuilt with the effects (exact)."""
    objects = [{**BALL, "position": [0, 0, 0.5], "linear_velocity": [1, 0.3, 2], "angular_velocity": [3, -40, 10]},
               {**BALL, "position": [0.5, 0, 0.03], "linear_velocity": [1, 0, 0], "angular_velocity": [0, 0, 20]}]
    scene = _scene(objects, [{"effect": k, "parameters": VALUES[k]} for k in combo])
    rebuilt = rollout(compile_model(scene, OPTS), 2, 30, 30, record_contacts=False)
    model, base, geoms = engine.compile_for_fit(scene, combo, OPTS)
    engine.configure_model(model, base, geoms, {k: fx.resolve_params(k, {}, "x") for k in combo})  # other values first
    engine.configure_model(model, base, geoms, {k: fx.resolve_params(k, VALUES[k], "x") for k in combo})
    fast = rollout(model, 2, 30, 30, record_contacts=False)
    np.testing.assert_allclose(fast.qpos, rebuilt.qpos, rtol=0, atol=1e-12)
    plain = rollout(compile_model(scene.replace(effects=[]), OPTS), 2, 30, 30, record_contacts=False)
    assert np.abs(plain.qpos[..., :3] - rebuilt.qpos[..., :3]).max() > 1e-3  # the effect does something


def test_quadratic_drag_matches_inertia_box_formula():
    # MuJoCo docs, "Fluid forces", inertia model: f_i = -2 rho r_j r_k |v_i| v_i with
    # r = sqrt(3/5) R for a solid sphere, i.e. f = -1.2 rho R^2 |v| v along a body axis.
    rho, R, v = 3.0, 0.03, 2.0
    _, d = _forward(_scene([{**BALL, "position": [0, 0, 1], "linear_velocity": [v, 0, 0]}],
                           [{"effect": "quadratic_drag", "parameters": {"density": rho}}], gravity=0))
    np.testing.assert_allclose(d.qfrc_passive[:3], [-1.2 * rho * R * R * v * v, 0, 0], rtol=1e-9)


@pytest.mark.parametrize("direction", [(1, 1, 0), (1, 1, 1), (0.3, -0.8, 0.5)])
def test_quadratic_drag_on_a_sphere_is_isotropic(direction):
    """f = -1.2 rho R^2 |v| v in any direction, spinning or not (the ellipsoid model's blunt
    drag; the added-mass lift of a spinning sphere is cancelled, to ~2e-6 of the drag). MuJoCo's inertia-box model
    gives a sphere moving along (1, 1, 1) 58 % of it: the spheres no longer use it."""
    rho, R = 3.0, 0.03
    v = 2.0 * np.asarray(direction, float) / np.linalg.norm(direction)
    for w in ([0, 0, 0], [0, 0, 40.0], [15.0, -20.0, 5.0]):
        _, d = _forward(_scene([{**BALL, "position": [0, 0, 1], "linear_velocity": v.tolist(), "angular_velocity": w}],
                               [{"effect": "quadratic_drag", "parameters": {"density": rho}}], gravity=0))
        np.testing.assert_allclose(d.qfrc_passive[:3], -1.2 * rho * R * R * np.linalg.norm(v) * v, rtol=1e-5, atol=1e-8)


def test_wind_pushes_a_ball_at_rest_with_air_density():
    # relative velocity v - w = -w: f = -1.2 rho R^2 |-w| (-w), rho = air (1.2 kg/m^3)
    w, R = np.array([2.0, -1.0, 0.0]), 0.03
    _, d = _forward(_scene([{**BALL, "position": [0, 0, 1]}],
                           [{"effect": "wind", "parameters": {"wind_x": 2.0, "wind_y": -1.0}}], gravity=0))
    expected = 1.2 * fx.AIR_DENSITY * R * R * np.linalg.norm(w) * w  # isotropic on a sphere
    np.testing.assert_allclose(d.qfrc_passive[:3], expected, rtol=1e-9)


def test_drag_sets_the_wind_density():
    m, _ = _forward(_scene([{**BALL, "position": [0, 0, 1]}],
                           [{"effect": "wind", "parameters": {"wind_x": 1.0}},
                            {"effect": "quadratic_drag", "parameters": {"density": 5.0}}]))
    assert m.opt.density == 5.0 and m.opt.wind[0] == 1.0


@pytest.mark.parametrize("e", [0.3, 0.6, 0.9])
def test_restitution_rebound_matches_e(e):
    # Without gravity the contact is a linear spring-damper; its restitution is
    # restitution_of_dampratio(zeta) (Schwager & Poeschel 2008). Measured within 0.02.
    scene = _scene([{**BALL, "mass": 0.05, "position": [0, 0, 0.031], "linear_velocity": [0, 0, -3.0]}],
                   [{"effect": "restitution", "parameters": {"e": e}}], gravity=0)
    model = compile_model(scene, OPTS)
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    for i in range(300):
        mujoco.mj_step(model, data)
        if i > 3 and data.ncon == 0 and data.qvel[2] > 0:
            break
    assert data.qvel[2] / 3.0 == pytest.approx(e, abs=0.02)


def test_restitution_mapping_round_trip_and_limits():
    assert fx.restitution_of_dampratio(0.0) == pytest.approx(1.0)
    for e in (0.14, 0.3, 0.8, 0.95):
        assert fx.restitution_of_dampratio(fx.dampratio_of_restitution(e)) == pytest.approx(e, abs=1e-9)
    tau, zeta = fx.restitution_solref(0.5, 0.002)
    # half-period of the damped contact = RESTITUTION_CONTACT_STEPS steps
    wn = 1.0 / (tau * zeta)
    assert math.pi / (wn * math.sqrt(1 - zeta ** 2)) == pytest.approx(fx.RESTITUTION_CONTACT_STEPS * 0.002)


def test_floor_tilt_leans_gravity():
    m, d = _forward(_scene([{**BALL, "position": [0, 0, 1]}],
                           [{"effect": "floor_tilt", "parameters": {"tilt_x": 5.0}}]))
    t = math.tan(math.radians(5.0))
    np.testing.assert_allclose(m.opt.gravity, 9.81 * np.array([t, 0, -1]) / math.hypot(t, 1), rtol=1e-12)
    np.testing.assert_allclose(d.qacc[0], 9.81 * math.sin(math.radians(5.0)), rtol=1e-9)


def test_scale_error_scales_what_is_measured_not_the_physics():
    """A scale error leaves the model as it is (MJCF and in-place edit: the same rollout as
    without it) and multiplies the measured positions by 1 + scale (a clip model's
    simulated measurements, origin fixed); orientations are unchanged."""
    from pipeline.discrepancy import ClipModel
    from pipeline.discrepancy.trajectories import Clip, ObjectSpec, Track
    ball = {**BALL, "position": [0, 0, 0.5], "linear_velocity": [1.0, 0.2, 1.5], "angular_velocity": [0, 5, 0]}
    scene = _scene([ball])
    plain = rollout(compile_model(scene, OPTS), 1, 30, 30, record_contacts=False)
    scaled = rollout(compile_model(scene.replace(effects=[fx_block("scale_error", {"scale": 0.05})]), OPTS), 1, 30, 30,
                     record_contacts=False)
    np.testing.assert_array_equal(scaled.qpos, plain.qpos)
    t = np.arange(13) / 30.0
    clip = Clip("c", "<test>", [Track("sphere_0", t, np.zeros((13, 3)), None, np.ones(3, bool),
                                      ObjectSpec("sphere", {"radius": 0.03}, 0.01))])
    cm = ClipModel(clip, ["scale_error"], OPTS)
    nuis = np.zeros((1, 14))
    nuis[0, :3], nuis[0, 3:6] = [0, 0, 0.5], [1.0, 0.2, 1.5]
    q0 = cm.simulate(nuis, {"scale_error": {"scale": 0.0}})
    q1 = cm.simulate(nuis, {"scale_error": {"scale": 0.05}})
    np.testing.assert_allclose(q1[..., :3], 1.05 * q0[..., :3], rtol=1e-12)
    np.testing.assert_array_equal(q1[..., 3:], q0[..., 3:])
    # in flight the measured path is a fall at 1.05 g: z = 1.05 (0.5 + 1.5 t - g t (t + dt) / 2)
    # (MuJoCo's semi-implicit Euler at timestep dt: the closed form of its free fall)
    dt = float(cm.model.opt.timestep)
    np.testing.assert_allclose(q1[:, 0, 2], 1.05 * (0.5 + 1.5 * t - 0.5 * 9.81 * t * (t + dt)), atol=1e-9)


def fx_block(name, params):
    """An ``effects:`` entry of a scene."""
    return {"effect": name, "parameters": params}


def test_nuisance_terms_are_not_physical_effects():
    """``EFFECTS`` (naming candidates, benchmark effects) is the registry without nuisance
    terms, in registry order; the workflow refuses a nuisance term as a candidate and a
    physical effect as a mismatch term."""
    from pipeline.discrepancy import DiscrepancyConfig
    assert fx.EFFECTS == tuple(n for n in fx.REGISTRY if n != "scale_error")
    assert fx.REGISTRY["scale_error"].nuisance and not any(fx.REGISTRY[n].nuisance for n in fx.EFFECTS)
    assert DiscrepancyConfig().candidates == fx.EFFECTS
    with pytest.raises(ValueError, match="candidates: unknown effect 'scale_error'"):
        DiscrepancyConfig(candidates=("scale_error",))
    with pytest.raises(ValueError, match="mismatch_terms: 'wind' is not a nuisance term"):
        DiscrepancyConfig(mismatch_terms=("wind",))


@pytest.mark.parametrize("lift", [0.0, 1.5])
def test_magnus_force_is_lift_rho_volume_omega_cross_v(lift):
    # MuJoCo docs, "Fluid forces", ellipsoid model: f_M = C_M rho V omega x v; its added-mass
    # term adds -1/2 rho V omega x v on a sphere, which the effect cancels.
    R, v, w = 0.03, np.array([2.0, 0, 0]), np.array([0, -50.0, 0])
    _, d = _forward(_scene([{**BALL, "position": [0, 0, 1], "linear_velocity": v.tolist(), "angular_velocity": w.tolist()}],
                           [{"effect": "magnus_lift", "parameters": {"lift": lift}}], gravity=0))
    expected = lift * fx.AIR_DENSITY * (4 / 3 * math.pi * R ** 3) * np.cross(w, v)
    np.testing.assert_allclose(d.qfrc_passive[:3], expected, rtol=1e-6, atol=1e-8)  # MuJoCo integrates the
    # added-mass coefficients numerically: the cancellation holds to ~2e-7 relative


def test_torsional_friction_decelerates_spin():
    # A ball resting on the floor (normal force m g) spinning about z: torque mu_t m g,
    # so d omega/dt = -mu_t m g / I with I = 2/5 m R^2 (MuJoCo docs, "Contact": condim 4+).
    mt, m_, R = 0.002, 0.05, 0.03
    scene = _scene([{**BALL, "mass": m_, "position": [0, 0, 0.03]}],
                   [{"effect": "torsional_friction", "parameters": {"mu_torsion": mt}}])
    model = compile_model(scene, OPTS)
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    for _ in range(300):                      # settle on the soft floor
        mujoco.mj_step(model, data)
    data.qvel[5] = 100.0
    w0, t0 = data.qvel[5], data.time
    for _ in range(20):
        mujoco.mj_step(model, data)
    rate = (data.qvel[5] - w0) / (data.time - t0)
    assert rate == pytest.approx(-mt * m_ * 9.81 / (0.4 * m_ * R * R), rel=0.1)


def test_effects_block_builds_and_serialises():
    scene = _scene([{**BALL, "position": [0, 0, 1]}], [{"effect": "magnus_lift", "parameters": {"lift": 1.0}},
                                                         {"effect": "quadratic_drag", "parameters": {"density": 1.2}}])
    xml = to_xml(scene, OPTS)
    assert 'fluidshape="ellipsoid"' in xml and 'density="1.2"' in xml
    assert Scene.from_yaml(scene.to_yaml()).effects == scene.rounded().effects


@pytest.mark.parametrize("effects, message", [
    ([{"effect": "glue"}], "effects[0].effect: unknown effect"),
    ([{"effect": "wind", "parameters": {"speed": 1.0}}], "effects[0].parameters.speed: unknown parameter"),
    ([{"effect": "restitution", "parameters": {"e": 1.5}}], "effects[0].parameters.e: must be in [0.14, 0.95]"),
    ([{"effect": "wind"}, {"effect": "wind"}], "effects[1].effect: 'wind' appears twice"),
])
def test_bad_effects_give_one_line_errors(effects, message):
    with pytest.raises(SceneError) as info:
        compile_model(_scene([{**BALL, "position": [0, 0, 1]}], effects), OPTS)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_configure_model_refuses_missing_structure():
    scene = _scene([{**BALL, "position": [0, 0, 1]}])
    model, base, geoms = engine.compile_for_fit(scene, [], OPTS)
    with pytest.raises(ValueError, match="structural"):
        engine.configure_model(model, base, geoms, {"magnus_lift": fx.MagnusLift.defaults()})
