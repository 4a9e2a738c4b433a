"""Motion read from image tracks against analytic trajectories (issue 29: drops whose start and
bounce are cut by the image border).

A disc of known radius falls into the view from above its top edge with a known image
acceleration, bounces off a floor that lies *below* the bottom edge with a known coefficient
of restitution, and rises again: the label maps are drawn directly (no renderer, no video), so
every number below is known in closed form.
"""

from __future__ import annotations

import math
from dataclasses import replace

import cv2
import numpy as np
import pytest

from pipeline.image_tracks import (BOX_FILL, CIRCLE_FILL, ELLIPSE_FIT, ELONGATED, Track, find_tracks, first_bounce,
                                   estimate_view, flight_gravity, gravity_evidence, gravity_motion, initial_motion, initial_state_given, jitter, net_shift, object_tracks,
                                   round_silhouette, silhouette_fit, speed_after_bounce, whole_frames)

W, H, FPS = 80, 120, 30.0
R = 6.0                        # disc radius, px
A = 1350.0                     # image acceleration, px/s^2 (dev/03's, measured on whole frames)
V0, VEL0, U0, UVEL = -4.0, 30.0, 40.0, 20.0   # start above the top edge, px and px/s
V_IMPACT = 118.0               # centre row at the impact: the disc is cut by the bottom edge
E = 0.5                        # coefficient of restitution


def _centre_rows(t: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre row v(t) px of the bouncing disc and the impact time, s (closed form)."""
    t_hit = (-VEL0 + math.sqrt(VEL0 ** 2 + 2 * A * (V_IMPACT - V0))) / A
    v_in = VEL0 + A * t_hit
    after = t - t_hit
    v = np.where(t <= t_hit, V0 + VEL0 * t + 0.5 * A * t ** 2,
                 V_IMPACT - E * v_in * after + 0.5 * A * after ** 2)
    return v, t_hit


def _clip(T: int = 22, t0: float = 0.0) -> tuple[np.ndarray, float]:
    """Label maps ``(T, H, W)`` int8 of the disc over frames at ``t0 + i / FPS``, and the impact time."""
    t = t0 + np.arange(T) / FPS
    v, t_hit = _centre_rows(t)
    seg = np.full((T, H, W), -1, np.int8)
    for i in range(T):
        canvas = np.zeros((H, W), np.uint8)
        cv2.circle(canvas, (int(round((U0 + UVEL * t[i]) * 16)), int(round(v[i] * 16))), int(R * 16), 1, -1,
                   lineType=cv2.LINE_8, shift=4)
        seg[i][canvas > 0] = 0
    return seg, t_hit


def test_whole_frames_keep_the_true_acceleration_of_a_drop_entering_from_the_top():
    seg, t_hit = _clip()
    (track,) = find_tracks(seg)
    v_true, _ = _centre_rows(track.frames / FPS)
    # the frames where the disc is cut by a border are flagged, and only those
    cut = (v_true - R < 0.5) | (v_true + R > H - 1.5)
    assert np.array_equal(track.clipped, cut)
    whole = whole_frames(track)
    assert len(whole.frames) == int((~cut).sum()) and not whole.clipped.any()
    # the first stretch one parabola explains: on whole frames it is the fall's acceleration
    m = initial_motion(whole, FPS)
    assert m.a[1] == pytest.approx(A, rel=0.05)
    assert m.p0[1] == pytest.approx(V0, abs=1.0)   # extrapolated to t = 0, above the view
    # the cut frames at the start bias the centroid downwards and so the curvature upwards
    biased = initial_motion(track, FPS)
    assert abs(biased.a[1] - A) > 3 * abs(m.a[1] - A)


def test_bounce_below_the_bottom_edge_gives_restitution_and_the_floor_row():
    seg, t_hit = _clip()
    (track,) = find_tracks(seg)
    bounce = first_bounce(whole_frames(track), FPS)
    assert bounce is not None
    assert bounce.e == pytest.approx(E, abs=0.05)
    assert bounce.t == pytest.approx(t_hit, abs=0.5 / FPS)
    assert bounce.v == pytest.approx(V_IMPACT, abs=2.0)    # below the last row the disc was seen whole
    assert bounce.v > whole_frames(track).centre[:, 1].max() + 2.0


def test_whole_frames_returns_the_track_when_too_few_frames_are_whole():
    seg = np.full((5, 20, 20), -1, np.int8)
    for i in range(5):   # a blob always touching the left border
        seg[i, 5:10, 0:4 + i] = 0
    (track,) = find_tracks(seg)
    assert track.clipped.all()
    assert whole_frames(track) is track


def test_window_starting_just_before_a_bounce_keeps_the_falling_state():
    """dev/02 (a ping-pong ball bouncing every 8 frames): the window opens 2 frames before an
    impact. The state at t = 0 comes from those 2 frames with the known acceleration, not from
    the next arc extrapolated back (which put the ball under the floor, moving up)."""
    _, t_hit = _centre_rows(np.zeros(1))
    t0 = t_hit - 1.5 / FPS                      # impact between the 2nd and 3rd frame
    seg, _ = _clip(T=14, t0=t0)
    (track,) = find_tracks(seg)
    m = initial_state_given(whole_frames(track), FPS, np.array([0.0, A]))
    assert m.n == 2
    v_start = V0 + VEL0 * t0 + 0.5 * A * t0 ** 2
    assert m.p0[1] == pytest.approx(v_start, abs=0.75)
    assert m.v0[1] == pytest.approx(VEL0 + A * t0, rel=0.05)   # still falling


def _track(centre: np.ndarray, diameter: float = 25.0) -> Track:
    n = len(centre)
    return Track(0, np.arange(n), centre, np.full(n, 400.0), centre[:, 1] + diameter / 2, diameter,
                 (diameter, diameter), 0.0, math.pi / 4, "circle", 5.0)


def test_noisy_track_velocity_is_averaged_over_many_frames():
    """dev/05 seen from above: a ping-pong ball drifting left while it bounces in place jitters
    by a few px, more than the fit tolerance (6 % of 25 px). Its velocity then came from a line
    through 4 frames (noise of ~30 px/s); with the track's own noise as tolerance it comes from
    all of them."""
    rng = np.random.default_rng(0)
    t = np.arange(20) / FPS
    truth = np.stack([40.0 - 30.0 * t, 96.0 + 8.0 * t], axis=1)
    noise = rng.normal(0.0, 2.0, truth.shape)
    tr = _track(truth + noise)
    assert jitter(tr) == pytest.approx(2.0 * math.sqrt(2.0), rel=0.4)   # 2 px per axis
    assert jitter(_track(truth + np.outer(t ** 2, [0.0, 600.0]))) < 1e-9   # a parabola is no noise
    m = initial_motion(tr, FPS)
    assert m.n >= 15
    assert np.linalg.norm(m.v0 - [-30.0, 8.0]) < 15.0
    # a clean track keeps the fine tolerance: the first stretch before a hit, not a long average
    hit = np.stack([200.0 - 240.0 * t, 96.0 + 8.0 * t], axis=1)
    hit[10:, 0] = hit[9, 0] + 120.0 * (t[10:] - t[9])     # struck back at frame 10
    m = initial_motion(_track(hit), FPS)
    assert m.n == 10 and m.v0[0] == pytest.approx(-240.0, abs=1.0)


def test_a_track_cut_by_the_border_throughout_is_not_an_object():
    """dev/07: a hand reaching in at the left edge moves with the toss and is as large as the
    ball; it is never seen whole, so it cannot be sized or fitted and is not an object while a
    whole one is there. Alone, it is kept (something must be reconstructed)."""
    T = 20
    seg = np.full((T, 60, 80), -1, np.int8)
    for t in range(T):
        seg[t, 30 + t // 4: 38 + t // 4, 0:4 + t % 3] = 0             # hand at the left border
        seg[t, 10 + t: 16 + t, 20 + 2 * t: 26 + 2 * t] = 1             # ball in flight, whole
    assert [t.label for t in object_tracks(seg, None)] == [1]
    hand = np.where(seg == 0, 0, -1).astype(np.int8)
    assert [t.label for t in object_tracks(hand, None)] == [0]


def _seg_of(shapes: list[tuple[tuple[float, float], tuple[float, float], float]], size=(160, 120)) -> np.ndarray:
    """``(T, H, W)`` int8 labels: per frame one filled rotated ellipse ``(centre, axes, angle)``
    as object 0 (axes: full lengths, px)."""
    W_, H_ = size
    seg = np.full((len(shapes), H_, W_), -1, np.int8)
    for t, (c, axes, ang) in enumerate(shapes):
        img = np.zeros((H_, W_), np.uint8)
        cv2.ellipse(img, (c, axes, ang), 1, -1)
        seg[t][img > 0] = 0
    return seg


def test_elongation_reads_the_silhouette_least_stretched_by_blur():
    """Issue 29 (shapes): a ball whose silhouette motion blur stretches to 2.6 times its width
    in its fast frames (a third of them) stays round by its elongation, the lower quartile of
    long / short over whole frames; a bar 3.5 times longer than wide, with a ragged outline
    that lowers its fill to a disc's, is elongated in every frame, and so a rectangle."""
    fast = [((30.0 + 10 * t, 60.0), (26.0, 10.0), 0.0) for t in range(4)]
    slow = [((70.0 + 2 * t, 60.0), (10.5, 10.0), 0.0) for t in range(8)]
    ball = find_tracks(_seg_of(fast + slow))[0]
    assert ball.elongation < 1.3 < ELONGATED
    assert ball.shape == "circle"
    # the bar: an ellipse (fill pi/4, a disc's) 3.5x longer than wide, turned 20 deg
    bar = find_tracks(_seg_of([((40.0 + 5 * t, 60.0), (42.0, 12.0), 20.0) for t in range(10)]))[0]
    assert bar.fill < 0.5 * (CIRCLE_FILL + BOX_FILL)
    assert bar.elongation == pytest.approx(3.5, rel=0.1)
    assert bar.shape == "rectangle"
    # a silhouette cut by the image border is not read (its visible part can be any ratio)
    clipped = find_tracks(_seg_of([((0.0, 60.0), (20.0, 20.0), 0.0)] * 5))[0]
    assert clipped.elongation == 1.0


def test_net_shift_keeps_a_slow_objects_displacement_and_not_an_occluded_outline():
    """Issue 36 (objects at rest are not slow objects): a disc 12 px wide pushed 9 px over the
    window travels 0.75 diameters and moves 0.61 net (between the means of its first and last 3
    frames: 9 px * 9 / 11), most of its travel; a bar at rest whose left half a mover
    covers in the middle frames has its centroid pulled aside (travel >= a quarter diameter) and
    back, so it has no net shift."""
    pushed = find_tracks(_seg_of([((40.0 + 9.0 * t / 11, 60.0), (12.0, 12.0), 0.0) for t in range(12)]))[0]
    assert net_shift(pushed) == pytest.approx(9.0 * 9 / 11 / 12, abs=0.05)
    assert net_shift(pushed) >= 0.75 * pushed.travel / pushed.diameter
    seg = _seg_of([((80.0, 60.0), (40.0, 12.0), 0.0)] * 12)
    seg[4:8, :, :80] = -1                                      # occluded from the left in 4 frames
    bar = find_tracks(seg)[0]
    assert bar.travel >= 0.25 * bar.diameter
    assert net_shift(bar) < 0.05
    assert net_shift(find_tracks(_seg_of([((40.0, 60.0), (12.0, 12.0), 0.0)] * 5))[0]) == 0.0   # too short


def _fit(draw) -> tuple[float, float]:
    m = np.zeros((120, 160), np.uint8)
    draw(m)
    fit = silhouette_fit(m > 0)
    assert fit is not None
    return fit


@pytest.mark.parametrize("radius", [4, 8, 25])
def test_silhouette_fit_reads_an_ellipse_as_round_at_every_size(radius):
    """A sphere's outline is an ellipse (a conic: Hartley & Zisserman): rasterised discs and
    ellipses of 4-25 px radius fit their ellipse above :data:`ELLIPSE_FIT`, so a ball is not
    excluded for being small."""
    ell, _ = _fit(lambda m: cv2.circle(m, (80, 60), radius, 1, -1))
    assert ell >= ELLIPSE_FIT
    ell, _ = _fit(lambda m: cv2.ellipse(m, ((80, 60), (2.6 * radius, 2 * radius), 30.0), 1, -1))
    assert ell >= ELLIPSE_FIT


@pytest.mark.parametrize("angle", [0.0, 20.0, 45.0])
@pytest.mark.parametrize("side", [10, 40])
def test_silhouette_fit_reads_a_square_as_a_polygon_not_an_ellipse(angle, side):
    """A square's corners lie outside its best ellipse: the ellipse fit falls below
    :data:`ELLIPSE_FIT` (a disc of the same area is above it) and the polygon fits better, at any
    rotation; so a box seen face-on is not a sphere candidate."""
    pts = cv2.boxPoints(((80.0, 60.0), (float(side), float(side)), angle)).astype(np.int32)
    ell, poly = _fit(lambda m: cv2.fillPoly(m, [pts], 1))
    assert ell < ELLIPSE_FIT and poly > ell + 0.05


def test_round_silhouette_needs_an_ellipse_and_falls_back_to_fill_without_one():
    """:func:`round_silhouette`: the ellipse fit decides where measured (a fill that says disc
    does not make a polygonal outline round), elongation vetoes, and without a fit the fill
    decides as :attr:`Track.shape` does."""
    tr = _track(np.zeros((6, 2)), diameter=20.0)
    assert round_silhouette(replace(tr, fill=0.78, ellipse=0.97, polygon=0.9))
    assert not round_silhouette(replace(tr, fill=0.78, ellipse=0.86, polygon=0.95))
    assert not round_silhouette(replace(tr, fill=0.78, ellipse=0.97, elongation=ELONGATED + 0.1))
    assert round_silhouette(replace(tr, fill=0.78, ellipse=math.nan))
    assert not round_silhouette(replace(tr, fill=0.95, ellipse=math.nan))


def _toss(seed: int, n_hand: int = 4, T: int = 30, u_speed: float = 15.0) -> np.ndarray:
    """``(T, 2)`` centroid (u, v) px of a ball tossed up at 30 fps: ``n_hand`` frames rising
    with the hand at a steady 150 px/s, then free flight at :data:`A` px/s^2 from 420 px/s up
    and ``u_speed`` px/s sideways, an impact on the floor row 110 with restitution 0.6, the next
    arc; 0.4 px of noise."""
    dt, floor = 1.0 / FPS, 110.0
    u, v, vel, rows = 30.0, 100.0, -150.0, []
    for k in range(T):
        if k < n_hand:
            rows.append((u, v))
            v += vel * dt
            continue
        if k == n_hand:
            vel = -420.0
        rows.append((u, v))
        u += u_speed * dt
        v_next, vel_next = v + vel * dt + 0.5 * A * dt ** 2, vel + A * dt
        if v_next > floor:   # the impact inside the step: the exact bounce (Newton's law)
            tc = (-vel + math.sqrt(vel ** 2 + 2 * A * (floor - v))) / A
            up = -0.6 * (vel + A * tc)
            v_next, vel_next = floor + up * (dt - tc) + 0.5 * A * (dt - tc) ** 2, up + A * (dt - tc)
        v, vel = v_next, vel_next
    return np.asarray(rows) + np.random.default_rng(seed).normal(0.0, 0.4, (T, 2))


@pytest.mark.parametrize("seed", range(6))
def test_speed_after_bounce_is_read_only_where_the_bounce_changed_it(seed):
    """A ball's sideways speed is constant in flight; a bounce changes it only when the ball
    spins (perception.bounce_spin). The toss (15 px/s sideways, 0.4 px of noise) keeps it through
    its bounce: no change is read. The same toss turned back at the bounce (-25 px/s after it)
    gives the new speed within 15 %."""
    rows = _toss(seed, T=40)                              # the bounce at frame 25, 15 frames after it
    same = _track(rows, diameter=12.0)
    assert speed_after_bounce(same, FPS) is None
    hit = int(np.argmax(rows[:30, 1]))                    # the frame nearest the impact
    turned = rows.copy()
    turned[hit:, 0] -= 40.0 * (np.arange(len(rows) - hit)) / FPS
    assert speed_after_bounce(_track(turned, diameter=12.0), FPS) == pytest.approx(-25.0, rel=0.15)


def test_flight_gravity_reads_the_true_acceleration_from_every_arc():
    """A ball tossed from the hand and bouncing once: the joint fit of both flight arcs with one
    curvature (:func:`flight_gravity`) trims the frames in the hand and gives the true image
    acceleration within 2 %, closer on average over noise draws than the steepest single window
    (:func:`gravity_motion`, which picks the largest of many noisy curvatures: dev/08 read
    4.45 px/frame^2 there against 3.38 from all arcs)."""
    err_flight, err_window = [], []
    for seed in range(12):
        tr = _track(_toss(seed), diameter=10.0)
        f = flight_gravity(tr, FPS)
        g = gravity_motion(tr, FPS)
        assert f is not None and f.n >= 20 and f.a[0] == 0.0
        assert abs(f.a[1] - A) < 0.02 * A
        assert f.a_sd < 0.02 * A
        err_flight.append(abs(f.a[1] - A))
        err_window.append(abs(g.a[1] - A))
    assert np.mean(err_flight) < 0.5 * np.mean(err_window)


@pytest.mark.parametrize("glitches,read", [(5, True), (12, False)])
def test_flight_gravity_trims_glitches_and_reads_no_fall_from_a_track_of_them(glitches, read):
    """One flight of 30 frames in which ``glitches`` frames show another blob (a hand) 30-60 px
    away. A glitch below both neighbours also cuts the flight into arcs
    (:func:`pipeline.image_measure.flight_arcs`). With 5 the fit trims them and reads gravity
    within 2 % from at least half the frames; with 12 (40 %) the arcs left are too short for
    ``min_samples``, and no fall is read from them."""
    rng = np.random.default_rng(7)
    t = np.arange(30) / FPS
    c = np.stack([40.0 + 60.0 * t, 200.0 - 700.0 * t + 0.5 * A * t ** 2], axis=1) + rng.normal(0.0, 0.4, (30, 2))
    bad = rng.choice(np.arange(1, 29), glitches, replace=False)
    c[bad] += rng.uniform(30.0, 60.0, (glitches, 2)) * rng.choice([-1.0, 1.0], (glitches, 2))
    f = flight_gravity(_track(c, diameter=10.0), FPS)
    if read:
        assert f is not None and abs(f.a[1] - A) < 0.02 * A and f.n >= 15
    else:
        assert f is None


def test_flight_gravity_of_a_roll_or_of_few_frames_is_none():
    """A ball rolling on a level floor with 0.3 px of noise has no flight arc of 5 samples (every
    noisy lowest point cuts it, :func:`pipeline.image_measure.flight_arcs`), so no curvature is
    read from it as a fall's; six frames of a flight are too few to fit at all."""
    t = np.arange(24) / FPS
    roll = np.stack([20.0 + 60.0 * t, np.full_like(t, 90.0)], axis=1)
    roll += np.random.default_rng(1).normal(0.0, 0.3, roll.shape)
    assert flight_gravity(_track(roll, diameter=10.0), FPS) is None
    assert flight_gravity(_track(_toss(0)[4:10], diameter=10.0), FPS) is None


def test_a_flight_seen_in_scattered_frames_still_shows_gravity():
    """Real clip dev/07: a ball a few px wide thrown across a picture on the wall is lost in 11 of
    27 frames and never seen in 6 frames in a row, so no :func:`gravity_motion` window exists and
    the clip was read as a top-down view. :func:`gravity_evidence` then reads the flight from every
    sample it is seen in (gaps counted in frames): gravity within 3 %, and the view is a side view.
    A roll on a level floor seen in the same frames shows no gravity either way."""
    seen = np.array([1, 2, 5, 7, 8, 9, 10, 13, 14, 15, 18, 20, 21, 22, 23, 24])   # dev/07's frames
    t = seen / FPS
    rng = np.random.default_rng(3)
    flight = np.stack([4.0 + 90.0 * t, 80.0 - 500.0 * t + 0.5 * A * t ** 2], axis=1) + rng.normal(0.0, 0.3, (len(t), 2))
    tr = replace(_track(flight, diameter=4.5), frames=seen)
    assert gravity_motion(tr, FPS) is None
    g = gravity_evidence(tr, FPS)
    assert g is not None and abs(g.a[1] - A) < 0.03 * A and g.a[0] == 0.0
    assert estimate_view([tr], [g]) == ("side", [True])

    roll = np.stack([20.0 + 60.0 * t, np.full_like(t, 60.0)], axis=1) + rng.normal(0.0, 0.3, (len(t), 2))
    tr = replace(_track(roll, diameter=4.5), frames=seen)
    g = gravity_evidence(tr, FPS)
    assert estimate_view([tr], [g])[0] == "top"


def test_first_bounce_passes_over_a_glitch_and_reads_the_true_bounce():
    """dev/02: two frames of a hand's blob at the start make a lowest point that is no bounce (the
    fitted arcs do not fall into it); the true bounce after it is still read: its restitution
    and the impact row (the floor) as simulated."""
    dt, floor = 1.0 / FPS, 110.0
    tr = _track(_toss(3, n_hand=0), diameter=10.0)
    clean = first_bounce(tr, FPS)
    glitch = tr.centre.copy()
    glitch[1:3, 1] = [60.0, 40.0]          # the hand's blob high up, then the ball again
    g = first_bounce(replace(tr, centre=glitch), FPS)
    assert clean is not None and g is not None
    assert g.e == pytest.approx(0.6, abs=0.08) and g.v == pytest.approx(floor, abs=2.0)
    assert g.t == pytest.approx(clean.t, abs=dt)
