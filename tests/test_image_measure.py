"""pipeline.image_measure against closed forms: a ball falling and bouncing under a known g drawn at a
known scale and frame rate, and a path along a line of known angle."""

import math

import numpy as np
import pytest

from pipeline.image_measure import MIN_ARC_SAMPLES, fit_gravity, flight_arcs, image_track, path_angle


def _bouncing_ball(g=9.81, m_per_px=0.002, fps=60.0, T=60, e=0.8, H=240, W=320, r=5):
    """(T, H, W) int8 masks of a disc dropped from rest 0.4 m above a floor at row 220, bouncing
    with restitution e; returns (seg, true rows of the centre)."""
    floor_y, y0 = 220.0 - r, 220.0 - r - 0.4 / m_per_px
    seg = np.full((T, H, W), -1, np.int8)
    rows = []
    pos, vel, dt = 0.0, 0.0, 1.0 / fps                 # m below the release, m/s down
    sub = 200
    yy, xx = np.mgrid[0:H, 0:W]
    for i in range(T):
        cy = y0 + pos / m_per_px
        cx = 60.0 + 2.0 * i
        seg[i][(yy + 0.5 - cy) ** 2 + (xx + 0.5 - cx) ** 2 <= r * r] = 0
        rows.append(cy)
        for _ in range(sub):                           # exact enough: 200 substeps per frame
            vel += g * dt / sub
            pos += vel * dt / sub
            if y0 + pos / m_per_px > floor_y and vel > 0:
                vel = -e * vel
    return seg, np.array(rows)


def test_gravity_from_a_drawn_free_fall_with_bounces():
    seg, rows = _bouncing_ball()
    t, x, y = image_track(seg, [0, 0, 320, 240], [320, 240], np.arange(60), 60.0)
    assert np.allclose(y, rows, atol=0.3)             # centroid of a drawn disc: within a third of a px
    fit = fit_gravity(t, y, 0.002)
    assert len(fit["arcs"]) >= 2                      # the drop and at least one flight after a bounce
    assert fit["g"] == pytest.approx(9.81, rel=0.02)
    assert all(a["g"] == pytest.approx(9.81, rel=0.05) for a in fit["arcs"])
    # a wrong frame rate gives a wrong g: at half the true rate time doubles, g falls 4x
    slow = fit_gravity(t * 2.0, y, 0.002)
    assert slow["g"] == pytest.approx(9.81 / 4, rel=0.03)


def test_working_size_crop_and_source_frames_map_back_to_original_pixels():
    seg, rows = _bouncing_ball()
    half = seg[:, ::2, ::2]                            # a working size of half the crop
    t, x, y = image_track(half, [100, 50, 320, 240], [160, 120], np.arange(0, 120, 2), 120.0)
    assert np.allclose(t, np.arange(60) / 60.0)        # every 2nd source frame at 120 fps
    assert np.allclose(y, rows + 50, atol=1.0)
    # frames picked by capture time (dropped frames repaired, observation.npz `times`): those times
    times = np.arange(60) / 60.0 + 0.001 * (np.arange(60) % 3)
    t2, _, y2 = image_track(half, [100, 50, 320, 240], [160, 120], np.arange(0, 120, 2), 120.0, times=times)
    assert np.allclose(t2, times) and np.allclose(y2, y)


def test_arcs_skip_the_contact_frame_and_short_pieces():
    t = np.arange(12) / 30.0
    y = np.array([0, 5, 14, 27, 44, 65, 50, 39, 32, 29, 30, 35], float)   # falls, bounces at index 5, rises, falls
    arcs = flight_arcs(t, y)
    assert [a.tolist() for a in arcs] == [[0, 1, 2, 3, 4], [6, 7, 8, 9, 10, 11]]
    assert flight_arcs(t[:MIN_ARC_SAMPLES - 1], y[:MIN_ARC_SAMPLES - 1]) == []
    assert math.isnan(fit_gravity(t[:4], y[:4], 0.001)["g"])


def test_held_and_border_masks_are_not_measurements():
    seg, _ = _bouncing_ball(T=20)
    seg[10:] = seg[9]                                  # held at its last mask from frame 10 (hold_resting)
    t, _, _ = image_track(seg, [0, 0, 320, 240], [320, 240], np.arange(20), 60.0)
    assert len(t) == 10
    cut = np.full((3, 20, 20), -1, np.int8)
    cut[:, 0:4, 5:9] = 0                               # touches the top border in every frame
    with pytest.raises(ValueError, match="no observed object"):
        image_track(np.full((2, 5, 5), -1, np.int8), [0, 0, 5, 5], [5, 5], np.arange(2), 30.0)
    assert len(image_track(cut, [0, 0, 20, 20], [20, 20], np.arange(3), 30.0, label=0)[0]) == 0


@pytest.mark.parametrize("deg", [0.0, 9.3, 21.8, 45.0, 90.0])
def test_path_angle_of_a_line(deg):
    s = np.linspace(0, 200, 15)
    x, y = 10 + s * math.cos(math.radians(deg)), 300 - s * math.sin(math.radians(deg))
    rng = np.random.default_rng(0)
    assert path_angle(x + rng.normal(0, 0.3, 15), y + rng.normal(0, 0.3, 15)) == pytest.approx(deg, abs=0.5)
    assert path_angle(x[::-1], 600 - y) == pytest.approx(deg, abs=0.5)     # direction and mirror do not matter
    assert math.isnan(path_angle(x[:2], y[:2]))
