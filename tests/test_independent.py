"""Independent hidden-effect generator (pipeline.discrepancy.independent): the hand-written sphere
integrator against closed forms of free fall, quadratic drag, bounces, sliding-to-rolling,
rolling down a slope, torsional friction, Magnus lift and spin kinematics; then the data
sets: deterministic, every effect, dropped samples and outliers as configured, accepted by the
trajectory readers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from pipeline.discrepancy.independent import (EFFECTS, GRAVITY, LIFT_DENSITY, IndependentConfig,
                                              generate_independent, simulate_sphere, tilted_gravity)
from pipeline.discrepancy.readers import clips_from_columns
from pipeline.rotation import quat_angle, quat_mul, rotvec_to_quat

G = GRAVITY
CD = 2.4 / math.pi


# --------------------------------------------------------------------------- integrator
def test_free_fall_is_exact_before_impact():
    t = np.linspace(0.0, 0.44, 45)            # impact of a 3 cm ball dropped from 1 m at 0.444 s
    tr = simulate_sphere([0.1, -0.2, 1.0], [0, 0, 0], [0, 0, 0], 0.03, 0.01, 0.5, t)
    assert np.max(np.abs(tr.positions[:, 2] - (1.0 - G * t ** 2 / 2))) < 1e-9
    assert np.max(np.abs(tr.velocities[:, 2] + G * t)) < 1e-9
    assert np.array_equal(tr.positions[:, :2], np.tile([0.1, -0.2], (len(t), 1)))


def test_quadratic_drag_fall_and_isotropic_wind():
    r, m, rho = 0.03, 0.01, 10.0
    k = 0.5 * rho * CD * math.pi * r ** 2
    vt = math.sqrt(m * G / k)                  # terminal speed sqrt(2 m g / (rho C_d pi r^2)), 3.0 m/s
    t = np.linspace(0.0, 2.5, 26)
    tr = simulate_sphere([0, 0, 50.0], [0, 0, 0], [0, 0, 0], r, m, 0.5, t, air_density=rho)
    # v(t) = v_t tanh(g t / v_t), fallen distance (v_t^2 / g) ln cosh(g t / v_t)
    assert np.max(np.abs(tr.velocities[:, 2] + vt * np.tanh(G * t / vt))) < 1e-9
    assert np.max(np.abs(tr.positions[:, 2] - (50.0 - vt ** 2 / G * np.log(np.cosh(G * t / vt))))) < 1e-9
    assert abs(-tr.velocities[-1, 2] / vt - 1) < 0.01
    # the law is isotropic, F = -k |u| u with u = v - wind (not per axis): first-step acceleration
    v0, wind = np.array([1.0, 0.0, 0.0]), np.array([0.0, 3.0, 0.0])
    h = 1e-6
    tr = simulate_sphere([0, 0, 1.0], v0, [0, 0, 0], r, m, 0.5, [h], air_density=rho, wind=wind)
    u = v0 - wind
    expected = -k * np.linalg.norm(u) * u / m + [0, 0, -G]
    np.testing.assert_allclose((tr.velocities[0] - v0) / h, expected, rtol=1e-5)


def test_bounces_rebound_to_e2_h_and_settle():
    r, h, e = 0.02, 0.2, 0.5
    ti = math.sqrt(2 * h / G)                 # first impact
    # rebound apexes e^2k h at t_i (1 + 2e + ... + 2e^(k-1) + e^k); the 5th rebound (hop
    # e^10 h = 0.2 mm < 0.5 mm) ends the bouncing at t_i (1 + 2 (e + e^2 + e^3 + e^4))
    apex_t = [ti * (1 + 2 * sum(e ** j for j in range(1, k)) + e ** k) for k in range(1, 5)]
    rest_t = ti * (1 + 2 * sum(e ** j for j in range(1, 5)))
    t = np.array([ti - 1e-6, ti + 1e-6, *apex_t, rest_t + 1e-3, rest_t + 0.2])
    tr = simulate_sphere([0, 0, r + h], [0, 0, 0], [0, 0, 0], r, 0.01, 0.5, t, restitution=e)
    z, vz = tr.positions[:, 2], tr.velocities[:, 2]
    assert vz[0] < 0 < vz[1] and abs(vz[1] - e * G * ti) < 1e-4      # impact within 1e-6 s of sqrt(2h/g)
    heights = z[2:6] - r
    np.testing.assert_allclose(heights, h * e ** (2 * np.arange(1, 5)), rtol=1e-6)
    np.testing.assert_allclose(vz[2:6], 0.0, atol=1e-7)              # apexes where expected
    assert np.all(z[6:] == r) and np.all(vz[6:] == 0.0)              # resting after the last hop


@pytest.mark.parametrize("mu, grips", [(0.6, True), (0.05, False)])
def test_oblique_bounce_friction_impulse(mu, grips):
    """Ball falling vertically with backspin: gripping (Cross 2002), the slip stops and the
    ball leaves rolling, ``v_x = 2/7 r w_y``; slipping, ``|dv_x| = mu (1 + e) |v_n|``."""
    r, m, e, h, wy = 0.03, 0.01, 0.5, 0.3, -60.0
    vn = math.sqrt(2 * G * h)
    t_after = math.sqrt(2 * h / G) + 1e-6
    tr = simulate_sphere([0, 0, r + h], [0, 0, 0], [0, wy, 0], r, m, mu, [t_after], restitution=e)
    vx, w_after = tr.velocities[0, 0], tr.angular_velocities[0, 1]
    if grips:
        assert abs(vx - 2 / 7 * r * wy) < 1e-9 and abs(vx - r * w_after) < 1e-9
    else:
        assert abs(abs(vx) - mu * (1 + e) * vn) < 1e-9 and np.sign(vx) == np.sign(wy)
        assert abs((w_after - wy) * 0.4 * m * r ** 2 - (-r * m * vx)) < 1e-12   # torque (-r z) x J


def test_pushed_ball_slides_then_rolls():
    r, m, v0, mu = 0.03, 0.05, 2.0, 0.3
    ts = 2 * v0 / (7 * mu * G)                # slip stops at t* = 2 v0 / (7 mu g)
    t = np.sort(np.append(np.arange(0.0, 0.6, 0.005), ts))
    tr = simulate_sphere([0, 0, r], [v0, 0, 0], [0, 0, 0], r, m, mu, t)
    vx, wy, x = tr.velocities[:, 0], tr.angular_velocities[:, 1], tr.positions[:, 0]
    sliding, k = t < ts, int(np.searchsorted(t, ts))
    np.testing.assert_allclose(vx[sliding], v0 - mu * G * t[sliding], atol=1e-9)
    np.testing.assert_allclose(vx[~sliding], 5 / 7 * v0, rtol=1e-9)   # then rolls at 5/7 v0 (no rolling friction)
    np.testing.assert_allclose(wy[~sliding], 5 / 7 * v0 / r, rtol=1e-9)
    assert abs(x[k] / (12 * v0 ** 2 / (49 * mu * G)) - 1) < 1e-9         # sliding distance 12 v0^2 / (49 mu g)
    assert np.all(tr.positions[:, 2] == r) and np.all(tr.positions[:, 1] == 0)


@pytest.mark.parametrize("tilt_x, tilt_y, mu, rolls", [(4.0, 0.0, 0.5, True), (3.0, -2.0, 0.5, True),
                                                       (20.0, 0.0, 0.05, False)])
def test_ball_on_slope(tilt_x, tilt_y, mu, rolls):
    """From rest on a tilted floor: rolls with ``5/7 g sin(theta)`` downhill, or (past the
    friction cone, ``tan theta > 7/2 mu``) slides with ``g (sin theta - mu cos theta)``."""
    r, gv = 0.02, tilted_gravity(tilt_x, tilt_y)
    tr = simulate_sphere([0, 0, r], [0, 0, 0], [0, 0, 0], r, 0.05, mu, [0.5, 1.0], gravity=gv)
    downhill = gv[:2] / np.linalg.norm(gv[:2])
    sin_t, cos_t = np.linalg.norm(gv[:2]) / G, -gv[2] / G
    assert np.dot(downhill, [math.tan(math.radians(tilt_x)), math.tan(math.radians(tilt_y))]) > 0
    a = 5 / 7 * G * sin_t if rolls else G * (sin_t - mu * cos_t)
    np.testing.assert_allclose(tr.positions[:, :2], np.outer([0.125, 0.5], a * downhill), rtol=1e-9, atol=1e-12)
    slip = tr.velocities[:, :2] + r * np.stack([-tr.angular_velocities[:, 1], tr.angular_velocities[:, 0]], 1)
    assert (np.max(np.abs(slip)) < 1e-9) == rolls


def test_torsional_friction_stops_spin_linearly():
    r, m, mut, w0 = 0.02, 0.05, 0.01, 30.0
    rate = mut * m * G / (0.4 * m * r ** 2)   # mu_torsion N / I, rad/s^2
    t = np.linspace(0.0, 0.3, 61)            # stops at w0 / rate = 0.049 s
    tr = simulate_sphere([0, 0, r], [0, 0, 0], [0, 0, w0], r, m, 0.5, t, mu_torsion=mut)
    np.testing.assert_allclose(tr.angular_velocities[:, 2], np.maximum(w0 - rate * t, 0.0), atol=1e-9)
    assert np.all(tr.angular_velocities[t > w0 / rate, 2] == 0.0)     # stops, no reversal
    assert np.all(tr.positions == [0, 0, r])
    # none in flight
    tr = simulate_sphere([0, 0, 1.0], [0, 0, 0], [0, 0, w0], r, m, 0.5, [0.2], mu_torsion=mut)
    assert tr.angular_velocities[0, 2] == w0


@pytest.mark.parametrize("mut", [0.002, 0.02])
def test_torsional_friction_through_a_bounce(mut):
    """The Coulomb torsional law integrated over the impact: the spin about z loses
    mu_torsion J_n / I (J_n = m (1 + e) |v_n|), stopping at zero; constant in flight before
    and after."""
    r, m, e, w0, h = 0.03, 0.01, 0.9, 40.0, 0.5
    vn = math.sqrt(2 * G * (h - r))
    t_hit = vn / G
    tr = simulate_sphere([0, 0, h], [0, 0, 0], [0, 0, w0], r, m, 0.5, [0.5 * t_hit, t_hit + 0.05],
                         restitution=e, mu_torsion=mut)
    dw = mut * m * (1 + e) * vn / (0.4 * m * r ** 2)
    assert tr.angular_velocities[0, 2] == w0
    assert tr.positions[1, 2] > r + 0.01                      # back in flight after the bounce
    np.testing.assert_allclose(tr.angular_velocities[1, 2], max(w0 - dw, 0.0), rtol=1e-6, atol=1e-9)


def test_magnus_lift_initial_acceleration():
    r, m, lift, v0, w0 = 0.03, 0.01, 1.5, np.array([2.0, 0, 0]), np.array([0, 0, 50.0])
    h = 1e-6
    tr = simulate_sphere([0, 0, 1.0], v0, w0, r, m, 0.5, [h], lift=lift)
    a_lat = tr.velocities[0, 1] / h
    expected = lift * LIFT_DENSITY * 4 / 3 * math.pi * r ** 3 * np.linalg.norm(np.cross(w0, v0)) / m
    assert abs(a_lat / expected - 1) < 1e-5                              # along w x v = +y
    np.testing.assert_allclose(tr.angular_velocities[0], w0)          # no air torque
    assert simulate_sphere([0, 0, 1.0], v0, w0, r, m, 0.5, [h]).velocities[0, 1] == 0


def test_orientation_follows_spin():
    q0 = rotvec_to_quat([0.3, -0.2, 1.0])
    w = np.array([10.0, -40.0, 25.0])
    t = np.linspace(0.0, 0.3, 7)
    tr = simulate_sphere([0, 0, 2.0], [0, 0, 0], w, 0.02, 0.01, 0.5, t, q0=q0)
    assert np.max(quat_angle(tr.quaternions, quat_mul(rotvec_to_quat(w * t[:, None]), q0))) < 1e-7
    # rolling at v along x: rotation v t / r about y
    r, v = 0.025, 1.2
    tr = simulate_sphere([0, 0, r], [v, 0, 0], [0, v / r, 0], r, 0.01, 0.5, t)
    assert np.max(quat_angle(tr.quaternions, rotvec_to_quat(np.outer(t, [0, v / r, 0])))) < 1e-7


def test_start_below_floor_and_bad_times_are_refused():
    with pytest.raises(ValueError, match="p0"):
        simulate_sphere([0, 0, 0.01], [0, 0, 0], [0, 0, 0], 0.02, 0.01, 0.5, [0.1])
    with pytest.raises(ValueError, match="times"):
        simulate_sphere([0, 0, 1.0], [0, 0, 0], [0, 0, 0], 0.02, 0.01, 0.5, [0.2, 0.1])


# --------------------------------------------------------------------------- data sets
CLEAN = dict(noise_position=0.0, noise_angle=0.0, outlier_rate=0.0)


def test_generate_is_deterministic_and_has_the_contract():
    cfg = IndependentConfig(n_clips=2, duration=0.4)
    cols, truth = generate_independent(4, cfg, effect="wind")
    again = generate_independent(4, cfg, effect="wind")
    assert (cols, truth) == again
    assert generate_independent(5, cfg, effect="wind")[0]["x"] != cols["x"]
    assert set(cols) == {"clip", "object", "t", "x", "y", "z", "qw", "qx", "qy", "qz",
                         "shape", "radius", "width", "depth", "height", "mass"}
    assert truth["engine"] == "independent" and truth["seed"] == 4 and truth["effect"] == "wind"
    assert set(truth["parameters"]) == {"wind_x", "wind_y"}
    assert 2.0 <= math.hypot(truth["parameters"]["wind_x"], truth["parameters"]["wind_y"]) <= 5.0
    assert [c["clip"] for c in truth["clips"]] == ["clip_00_throw", "clip_01_spin_slide"]
    assert set(cols["object"]) == {"sphere_0"} and set(cols["shape"]) == {"sphere"}
    assert cols["width"][0] is None and cols["radius"][0] == truth["clips"][0]["object"]["size"]["radius"]
    no_quat, _ = generate_independent(4, cfg.model_copy(update={"orientation": False}), effect="wind")
    assert "qw" not in no_quat and no_quat["x"] == cols["x"]


def test_drops_and_outliers_as_configured():
    cfg = IndependentConfig(n_clips=4)
    cols, truth = generate_independent(11, cfg, effect="none")
    clean, _ = generate_independent(11, cfg.model_copy(update=CLEAN), effect="none")
    n = int(round(cfg.duration * cfg.fps)) + 1
    grid = np.arange(n) / cfg.fps
    clip = np.array(cols["clip"])
    assert cols["t"] == clean["t"]                                    # same drops whatever the noise
    dev = np.linalg.norm(np.array([cols[a] for a in "xyz"]) - np.array([clean[a] for a in "xyz"]), axis=0)
    for info in truth["clips"]:
        rows = clip == info["clip"]
        t = np.array(cols["t"])[rows]
        missing = np.setdiff1d(np.arange(n), np.round(t * cfg.fps).astype(int))
        assert len(missing) == round(cfg.drop_rate * n) == 2            # 5 % of 49
        assert missing.min() >= 3 and missing.max() <= n - 2 and np.all(np.diff(missing) > 1)
        np.testing.assert_allclose(grid[missing], info["dropped_t"])
        big = dev[rows] >= 0.005
        assert big.sum() == round(cfg.outlier_rate * n) == 1            # 2 % of 49, >= 1 cm each
        np.testing.assert_allclose(t[big], info["outlier_t"])
        assert not big[:3].any()
    # the rest is Gaussian noise of 1 mm per coordinate
    small = np.concatenate([np.array(cols[a]) - np.array(clean[a]) for a in "xyz"])[np.tile(dev < 0.005, 3)]
    assert 0.0009 < np.std(small) < 0.0011


def test_every_effect_changes_the_data_and_reads_back():
    cfg = IndependentConfig(n_clips=4, **CLEAN)
    base, base_truth = generate_independent(21, cfg, effect="none")
    names = {"quadratic_drag": {"density"}, "wind": {"wind_x", "wind_y"}, "restitution": {"e"},
             "floor_tilt": {"tilt_x", "tilt_y"}, "magnus_lift": {"lift"}, "torsional_friction": {"mu_torsion"}}
    assert set(names) == set(EFFECTS) and base_truth["effect"] is None and base_truth["parameters"] == {}
    for effect in EFFECTS:
        cols, truth = generate_independent(21, cfg, effect=effect)
        assert truth["effect"] == effect and set(truth["parameters"]) == names[effect]
        assert [c["object"] for c in truth["clips"]] == [c["object"] for c in base_truth["clips"]]
        pos = np.array([cols[a] for a in "xyz"])
        gap = np.max(np.linalg.norm(pos - np.array([base[a] for a in "xyz"]), axis=0))
        angle = np.max(quat_angle(np.array([cols[a] for a in ("qw", "qx", "qy", "qz")]).T,
                                  np.array([base[a] for a in ("qw", "qx", "qy", "qz")]).T))
        # torsional friction only slows the spin about z: visible in the orientation alone
        assert (angle > 0.1) if effect == "torsional_friction" else (gap > 0.003), (effect, gap, angle)
        clips = clips_from_columns(cols, f"<{effect}>")
        assert [c.name for c in clips] == [c["clip"] for c in truth["clips"]]
        assert all(c.fps == 60 and c.tracks[0].spec.shape == "sphere" and not c.tracks[0].spec.assumed for c in clips)
    noisy, _ = generate_independent(21, IndependentConfig(n_clips=4), effect="random")
    assert len(clips_from_columns(noisy, "<random>")) == 4


def test_config_is_checked():
    with pytest.raises(ValidationError):
        IndependentConfig(effect="gravity_waves")
    with pytest.raises(ValidationError):
        IndependentConfig(kinds=("throw", "bounce"))
    with pytest.raises(ValidationError):
        IndependentConfig(noise=0.1)
    with pytest.raises(ValueError, match="effect"):
        generate_independent(0, effect="gravity_waves")
