"""Physical sanity and time stamps (issue 12, items 3 and 4), from the reproducers in
../shared/repro and closed forms."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import yaml
from numpy.testing import assert_allclose

from pipeline import sanity
from pipeline.cli import main
from pipeline.mjcf import DEFAULT_TIMESTEP, SimOptions, compile_model, frame_timestep, steps_per_frame
from pipeline.scene import Scene
from pipeline.simulate import rollout

ROOT = Path(__file__).resolve().parents[1]
REPRO = ROOT.parent / "shared" / "repro"
G = 9.81


def _simulate(tmp_path, capsys, name_or_text, *extra):
    """Run `dynamics simulate` on a reproducer (copied into tmp_path) or on scene text;
    returns (exit status, stderr, out folder)."""
    scene = tmp_path / "scene.yaml"
    if name_or_text.endswith(".yaml") and "\n" not in name_or_text:
        shutil.copy(REPRO / name_or_text, scene)
    else:
        scene.write_text(name_or_text)
    out = tmp_path / "out"
    rc = main(["simulate", str(scene), "--out", str(out), "--width", "32", "--height", "32", *extra])
    return rc, capsys.readouterr().err, out


# --------------------------------------------------------------------------- item 4: time stamps
def test_cli_library_and_params_share_one_timestep():
    # params.yaml sim.timestep is the one default: SimOptions (CLI without --params, library) agrees
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    assert SimOptions().timestep == params["sim"]["timestep"] == DEFAULT_TIMESTEP == 1 / 600


@pytest.mark.parametrize("fps,dt,steps,expected", [
    (30, 1 / 600, 20, 1 / 600),      # whole number of steps: unchanged, bit for bit
    (60, 1 / 600, 10, 1 / 600),
    (25, 1 / 600, 24, 1 / 600),      # 1/25 s = 24 steps exactly
    (240, 1 / 600, 3, 1 / 720),      # 2.5 steps -> 3 steps of 1/720 s
    (30, 0.002, 17, 1 / 510),        # the CLI's old default: 16.7 steps -> 17 of 1/510 s
    (7, 0.5, 1, 1 / 7),              # timestep longer than a frame: one step per frame
])
def test_frame_timestep_divides_the_frame_interval(fps, dt, steps, expected):
    assert steps_per_frame(fps, dt) == steps
    got = frame_timestep(fps, dt)
    assert got <= dt * (1 + 1e-12)
    assert_allclose(got, expected, rtol=1e-12)
    assert_allclose(1 / (fps * got), steps, rtol=1e-9)   # frame interval = whole number of steps
    if expected == dt:
        assert got == dt  # identical float: default-profile MJCF and shards unchanged


FREE_FALL = """version: 1
duration: 1.0
fps: {fps}
gravity: 9.81
camera: {{height: 1.2, pitch: 35.0, fov: 45.0}}
objects:
  - shape: sphere
    size: {{radius: 0.05}}
    mass: 1.0
    position: [0.0, 0.3, 10.0]
effects: []
"""


@pytest.mark.parametrize("fps", [30, 24, 240])
def test_free_fall_through_dynamics_simulate_matches_its_time_stamps(tmp_path, capsys, fps):
    """Issue 12: vz(0.0333 s) was -g * 0.034 s (states at rounded steps of a 2 ms timestep,
    rows stamped with frame times). Now every row is the state at its stamp.

    Closed form (uniform acceleration): vz(t) = -g t. MuJoCo's implicitfast integrator is
    semi-implicit Euler for a free body (v_{n+1} = v_n - g dt, z_{n+1} = z_n + v_{n+1} dt), so
    vz is exact at the steps and z_n = z0 - g t^2 / 2 - g t dt / 2: it lags the parabola by
    g t dt / 2 (4.9e-3 m at t = 1 s, dt = 1/600 s).
    """
    rc, err, out = _simulate(tmp_path, capsys, FREE_FALL.format(fps=fps))
    assert rc == 0, err
    table = pq.read_table(out / "trace.parquet")
    dt = float(json.loads(table.schema.metadata[b"dynamics"])["timestep"])
    assert_allclose(1 / (fps * dt), round(1 / (fps * dt)), rtol=1e-9)  # frames fall on steps
    t, z, vz = (table.column(c).to_numpy() for c in ("t", "z", "vz"))
    assert len(t) == fps
    assert_allclose(t, np.arange(fps) / fps, rtol=0, atol=1e-12)
    assert_allclose(vz, -G * t, rtol=0, atol=1e-3)
    assert_allclose(z, 10.0 - G * t**2 / 2 - G * t * dt / 2, rtol=0, atol=1e-6)


# --------------------------------------------------------------------------- item 3: reproducers
@pytest.mark.parametrize("name,needle", [
    ("scene_overlap_4_spheres_explodes.yaml", "objects: must not interpenetrate at t = 0 (tolerance 0.001 m"),
    ("scene_deep_in_floor_launch.yaml", "got floor and box_0 1 m deep"),
    ("scene_below_floor_launch.yaml", "got floor and sphere_0 0.6 m deep"),
    ("scene_friction_10_sinks.yaml", "simulation.penetration: must not sink more than 0.05 m"),
    ("scene_speed_1e3_tunnels.yaml", "simulation.step_travel: must move less than the smallest half size"),
    ("scene_nan_pos_1e308.yaml", "simulation: must stay stable"),
    ("scene_spin_1e30_silent_reset.yaml", "simulation: must stay stable"),
    ("scene_gravity_1e19_through_floor.yaml", "simulation: must stay stable"),
    ("scene_fps10000_dur2_hang.yaml", "must be at most 10000 frames, got 20000"),
])
def test_unphysical_reproducers_end_in_one_line(tmp_path, capsys, name, needle):
    """Issue 12: each ran with exit 0 (energy from nothing, thrown 13.8 m, sinking 0.585 m,
    tunnelling, NaN traces, silent resets) or for minutes; now one line, exit 2, nothing written."""
    rc, err, out = _simulate(tmp_path, capsys, name)
    assert rc == 2
    assert needle in err and err.count("\n") == 1, err
    assert len(err) < 400
    assert not out.exists()


def test_valid_reproducer_passes_every_check(tmp_path, capsys):
    rc, err, out = _simulate(tmp_path, capsys, "scene_valid_seed0.yaml")
    assert rc == 0, err
    assert (out / "trace.parquet").exists()


@pytest.mark.parametrize("name,moved", [("scene_overlap_4_spheres_explodes.yaml", "sphere_"),
                                        ("scene_deep_in_floor_launch.yaml", "box_0 moved 1.001 m along (0, 0, 1)"),
                                        ("scene_below_floor_launch.yaml", "sphere_0 moved 0.601 m along (0, 0, 1)")])
def test_resolve_overlaps_separates_and_says_so(tmp_path, capsys, name, moved):
    rc, err, out = _simulate(tmp_path, capsys, name, "--resolve-overlaps")
    assert rc == 0, err
    assert moved in err and "warning:" in err
    scene = Scene.from_yaml(json.loads(pq.read_table(out / "trace.parquet").schema.metadata[b"dynamics"])["scene"])
    model = compile_model(scene)
    assert sanity.initial_overlaps(model, 1e-3) == []     # separated, as the canonical text stores it
    trace = rollout(model, len(scene.objects), scene.n_frames, scene.fps)
    assert sanity.rollout_problems(model, trace.qpos, trace.qvel) == {}


def test_step_budget_is_refused_before_the_rollout(tmp_path, capsys):
    p = tmp_path / "p.yaml"
    p.write_text("sanity: {max_steps: 100}\n")
    rc, err, out = _simulate(tmp_path, capsys, "scene_valid_seed0.yaml", "--params", str(p))
    assert rc == 2 and "must need at most 100 physics steps (sanity.max_steps), got 580" in err, err
    assert not out.exists()


# --------------------------------------------------------------------------- the checks themselves
def _ball(z=0.1, v=(0.0, 0.0, 0.0), **extra):
    return Scene.from_dict({"camera": {"height": 1.2}, "duration": 0.5, "objects": [
        {"shape": "sphere", "size": {"radius": 0.1}, "mass": 2.0, "position": [0.0, 0.0, z],
         "linear_velocity": list(v), **extra}]})


def test_mechanical_energy_matches_closed_form():
    # E = m v^2 / 2 + I w^2 / 2 + m g z, solid sphere I = 2 m r^2 / 5 (any mechanics text)
    scene = _ball(z=1.0, v=(3.0, 0.0, 0.0), angular_velocity=[0.0, 0.0, 5.0])
    model = compile_model(scene)
    qpos = np.array([[[0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0]]])
    qvel = np.array([[[3.0, 0.0, 0.0, 0.0, 0.0, 5.0]]])
    E = sanity.mechanical_energy(model, qpos, qvel)
    assert_allclose(E, [2.0 * 9 / 2 + 0.4 * 2.0 * 0.01 * 25 / 2 + 2.0 * G * 1.0], rtol=1e-9)


def test_energy_check_flags_energy_from_nothing_and_passes_a_bounce():
    model = compile_model(_ball(z=1.0))
    trace = rollout(model, 1, 15, 30)
    assert sanity.rollout_problems(model, trace.qpos, trace.qvel) == {}
    qvel = trace.qvel.copy()
    qvel[-1, 0, 2] += 10.0          # 100 J from nowhere at the last frame
    found = sanity.rollout_problems(model, trace.qpos, qvel)
    assert list(found) == ["energy"] and "at frame 14" in found["energy"], found
