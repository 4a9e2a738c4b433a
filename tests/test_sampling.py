"""Sampling a rollout at given times (pipeline.simulate.sample_steps / interpolate_qpos): the
project's one rule. On-grid times are exact states; off-grid times interpolate the two states
around them, within the closed-form error of a linear interpolation."""

import math

import mujoco
import numpy as np
import pytest

from pipeline.mjcf import SimOptions, compile_model, frame_timestep, steps_per_frame, to_xml
from pipeline.rotation import axis_angle_quat
from pipeline.scene import Scene
from pipeline.simulate import SNAP_STEPS, frame_times, interpolate_qpos, reset_to_scene, rollout, sample_steps

DT = SimOptions().timestep


def _scene(fps: float = 30.0, **obj) -> Scene:
    o = {"shape": "box", "size": {"width": 0.2, "depth": 0.15, "height": 0.1}, "mass": 0.7,
         "position": [0.0, 0.0, 0.05], "linear_velocity": [0.8, 0.2, 0.0], "angular_velocity": [0.0, 0.0, 3.0],
         "material": {"sliding_friction": 0.3}}
    o.update(obj)
    return Scene.from_dict({"duration": 0.5, "fps": fps, "camera": {"height": 1.0}, "objects": [
        o, {"shape": "sphere", "size": {"radius": 0.08}, "mass": 0.3, "position": [0.3, 0.2, 0.4],
            "linear_velocity": [-0.5, 0.0, 1.0], "angular_velocity": [2.0, 0.0, 0.0]}]})


@pytest.mark.parametrize("fps", [30, 60, 25, 24, 50, 240])
def test_frame_times_are_on_the_grid_of_the_mjcf_timestep(fps):
    """Frame k of a pipeline.mjcf model is the state after exactly k * steps_per_frame steps
    (frame_timestep makes the frame interval a whole number of steps; 25 and 240 fps lower it)."""
    dt = frame_timestep(fps, DT)
    steps, frac = sample_steps(frame_times(301, fps), dt)
    n = steps_per_frame(fps, DT)
    np.testing.assert_array_equal(steps, np.arange(301) * n)
    np.testing.assert_array_equal(frac, 1.0)
    np.testing.assert_array_equal(steps, np.rint(frame_times(301, fps) / dt).astype(np.int64))


@pytest.mark.parametrize("fps", [30, 25, 240])
def test_rollout_frames_are_the_states_after_round_t_over_dt_steps(fps):
    """rollout == stepping MuJoCo by hand, bit for bit (30 fps at 1/600 s: 20 steps a frame; 25
    and 240 fps: the timestep pipeline.mjcf adjusts)."""
    scene = _scene(fps)
    model = compile_model(scene)
    trace = rollout(model, 2, scene.n_frames, fps)
    data = mujoco.MjData(model)
    reset_to_scene(model, data)
    step = 0
    for k, t in enumerate(trace.t):
        target = int(round(t / model.opt.timestep))
        while step < target:
            mujoco.mj_step(model, data)
            step += 1
        np.testing.assert_array_equal(trace.qpos[k].reshape(-1), data.qpos[:14])
    fast = rollout(model, 2, scene.n_frames, fps, record_contacts=False)
    np.testing.assert_array_equal(fast.qpos, trace.qpos)
    np.testing.assert_array_equal(fast.qvel, trace.qvel)


def test_snap_tolerance():
    """Within SNAP_STEPS steps of a step: that step exactly; beyond: interpolation."""
    k = np.arange(1, 200)
    for rel in (1e-12, -1e-12, 0.5e-9 / 200, -0.5e-9 / 200):
        steps, frac = sample_steps(k * DT * (1 + rel), DT)
        np.testing.assert_array_equal(steps, k)
        np.testing.assert_array_equal(frac, 1.0)
    steps, frac = sample_steps(np.array([0.0, (7 + 1e-6) * DT, (7 - 1e-6) * DT, 7.5 * DT, (7 + 3 * SNAP_STEPS) * DT]), DT)
    np.testing.assert_array_equal(steps, [0, 8, 7, 8, 8])
    np.testing.assert_allclose(frac, [1.0, 1e-6, 1 - 1e-6, 0.5, 3 * SNAP_STEPS], rtol=1e-6)
    with pytest.raises(ValueError, match="times"):
        sample_steps(np.array([0.1, -0.01]), DT)
    with pytest.raises(ValueError, match="timestep"):
        sample_steps(np.array([0.1]), 0.0)


def test_off_grid_free_fall_is_within_the_lerp_error_bound():
    """A free fall sampled between steps. MuJoCo's Euler steps (no damping: semi-implicit
    Euler, see tests/test_physics.py) put z_n = z0 + v0 n dt - g dt^2 n (n + 1) / 2 on the
    parabola z(s) = z0 + v0 s dt - g dt^2 s (s + 1) / 2 in the step count s; linear
    interpolation of a parabola of curvature g dt^2 between neighbouring points errs by at
    most g dt^2 / 8 (the lerp error bound |f''| h^2 / 8). Here the MJCF text's timestep (1/600 s)
    does not divide the 1/35 s frame interval, so most frames fall between steps."""
    z0, v0, g = 3.0, 1.5, 9.81
    scene = Scene.from_dict({"duration": 0.5, "fps": 30, "gravity": g, "camera": {"height": 1.0}, "objects": [
        {"shape": "sphere", "size": {"radius": 0.05}, "mass": 1.0, "position": [0.0, 0.0, z0],
         "linear_velocity": [0.0, 0.0, v0]}]})
    model = compile_model(to_xml(scene))  # 1/600 s: on the grid of 30 fps, not of 35 fps
    fps = 35.0
    trace = rollout(model, 1, 13, fps)
    steps, frac = sample_steps(trace.t, model.opt.timestep)
    assert (frac < 1).sum() >= 8
    dt = float(model.opt.timestep)
    s = trace.t / dt
    z_euler = z0 + v0 * s * dt - g * dt * dt * s * (s + 1) / 2
    err = np.abs(trace.position[:, 0, 2] - z_euler)
    assert err.max() <= g * dt * dt / 8 + 1e-12, err.max()
    assert err[frac == 1].max() <= 1e-12                       # on-grid frames: the Euler points
    vz = v0 - g * dt * np.where(frac < 1, steps - 1 + frac, steps)  # velocity lerps exactly (linear in n)
    np.testing.assert_allclose(trace.qvel[:, 0, 2], vz, atol=1e-12)


def test_interpolate_qpos():
    q0 = axis_angle_quat((0.0, 0.0, 1.0), 0.2)
    q1 = axis_angle_quat((0.0, 0.0, 1.0), 0.4)
    prev = np.array([0.0, 0.0, 1.0, *q0])
    cur = np.array([1.0, 2.0, 3.0, *(-q1)])                      # the same rotation as q1, other sign
    out = interpolate_qpos(prev, cur, 0.5)
    np.testing.assert_allclose(out[:3], [0.5, 1.0, 2.0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(out[3:], axis_angle_quat((0.0, 0.0, 1.0), 0.3), atol=1e-15)  # nlerp, shorter arc
    np.testing.assert_array_equal(interpolate_qpos(prev, cur, 1.0), cur)    # frac = 1: cur exactly
    batch = interpolate_qpos(np.stack([prev, prev]), np.stack([cur, cur]), np.array([0.5, 1.0]))
    np.testing.assert_array_equal(batch[1], cur)
    np.testing.assert_allclose(batch[0], out, atol=0)
    assert math.isclose(np.linalg.norm(interpolate_qpos(prev, cur, 0.3)[3:]), 1.0, rel_tol=1e-15)
