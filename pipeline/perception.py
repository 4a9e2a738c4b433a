"""Perception proposals: scene-language guesses from a video with no trained model (issue 9).

The classical route from pixels to a scene, used next to the model's samples in Best@K. The
image half, object tracks and their motion in px (detect and track, initial motion, gravity in
the image and so the view), is :mod:`pipeline.image_tracks`; this module lifts it to metric
scenes:

1. **Camera and ground plane** (:func:`pipeline.image_tracks.estimate_view`): where gravity
   shows in the image the view is a *side* view (camera pitch 0, image up = world up);
   otherwise objects move in the ground plane (constant velocity, friction decelerates them)
   and the view is *top-down* (pitch :data:`TOP_DOWN_PITCH`); the same objects on the ground
   seen *obliquely* (pitch :data:`OBLIQUE_PITCH`) are proposed beside it, and the re-simulation
   chooses. The field of view is a prior for the whole frame (:data:`FOV_PRIOR`), narrowed to the
   crop the image is (:func:`crop_fov`): with one view and unknown intrinsics it trades off with
   depth.
2. **Metric scale** (:func:`lift_side`, :func:`lift_top`): where an object falls, the parabola's
   curvature is g (``a_px = g * f / depth``); where it rolls down a slope of angle theta without
   slipping, ``a = k g sin(theta)`` with ``k = 5/7`` (sphere) or ``2/3`` (cylinder); otherwise
   the object's apparent size and a size prior (:data:`SIZE_PRIOR`, objects of 2-10 cm).
3. **Proposals** (:func:`propose`): one scene per shape hypothesis (a circle is a sphere or a
   cylinder seen end-on / from above; a rectangle is a box), with a ramp (static box under the
   path, ``Scene.static``) where an object moves along an inclined straight line, the floor
   under the lowest contact seen, restitution from a bounce, and friction from the deceleration.

Conventions: pixel coordinates as in :mod:`pipeline.camera` (u right, v down, px); times in s
from the first frame of the window; world frame z up, SI units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from pipeline.camera import intrinsics, pixel_to_plane, pixel_to_surface, project
from pipeline.errors import UserError
from pipeline.geometry import volume
from pipeline.image_tracks import (BOX_FILL, CIRCLE_FILL, ELONGATED, Motion, Track, View, gravity_vote,
                                   round_silhouette, bounce_restitution, estimate_view, find_tracks, first_bounce, fit_tolerance, flight_gravity, gravity_evidence, initial_motion, initial_state_given, object_tracks,
                                   SMALL_SILHOUETTE, speed_after_bounce, still_tracks, whole_frames)
from pipeline.mjcf import compile_model
from pipeline.rotation import axis_angle_quat, quat_mul
from pipeline.scene import Camera, Scene
from pipeline.simulate import rollout

G = 9.81
"""Standard gravity, m/s^2 (the scene language's default ``gravity``)."""
SIZE_PRIOR = 0.05
"""Prior object diameter / longest side, m, when gravity gives no scale (issue 9: objects of 2-10 cm)."""
SIZE_RANGE = (0.01, 0.15)
"""Plausible object sizes, m: a gravity scale implying a size outside falls back to the prior."""
FOV_PRIOR = 45.0
"""Prior vertical field of view of a whole video frame, deg (a phone or webcam at its widest is 40-60
deg)."""


def crop_fov(crop_height: float, frame_height: float, fov: float = FOV_PRIOR) -> float:
    """Vertical field of view (deg) of a crop ``crop_height`` px tall of a frame ``frame_height`` px
    tall whose vertical field of view is ``fov`` deg (pinhole, centred principal point:
    ``tan(fov_crop / 2) = tan(fov / 2) * crop_height / frame_height``). The main job's working image
    is the region of motion cropped out of the frame (:func:`pipeline.observe.motion_crop`): seen
    through the whole frame's prior, a crop of half its height would get twice its focal length's
    perspective.

    Raises:
        ValueError: a height <= 0, or a crop taller than the frame.
    """
    if not 0 < crop_height <= frame_height:
        raise ValueError(f"crop_fov: crop height must be in (0, {frame_height}], got {crop_height}")
    return math.degrees(2.0 * math.atan(math.tan(math.radians(fov) / 2.0) * crop_height / frame_height))
TOP_DOWN_PITCH = 89.0
"""Camera pitch of a top-down view, deg (the scene language allows at most 89)."""
OBLIQUE_PITCH = 45.0
"""Camera pitch of the oblique proposals, deg: wherever top-down proposals are made, the same objects
on the floor seen from halfway between the side and above are proposed too, and the re-simulation
decides (real clips dev/05, dev/09, dev/11-13 are filmed from 20-60 deg)."""
DENSITY = 1000.0
"""Prior density of the objects, kg/m^3 (masses only matter relative to each other here)."""
COLLISION_RESTITUTION = 0.8
"""Restitution tried for objects that may collide in a top-down view (a second proposal)."""
ROLL_FACTOR = {"sphere": 5.0 / 7.0, "cylinder": 2.0 / 3.0}
"""``a / (g sin theta)`` of a solid sphere / cylinder rolling without slipping down a slope:
``1 / (1 + I / (m r^2))`` with ``I = 2/5 m r^2`` and ``1/2 m r^2`` (any mechanics text)."""
ROLLING_GRIP = 0.5
"""Sliding friction of a shape proposed rolling (a ball from above or on the floor): its deceleration
measures its rolling resistance (:func:`rolling_resistance`), not its sliding friction, which only
has to hold it rolling; 0.5 is the side view's default."""
ROLLING_RESISTANCE_MAX = 0.1
"""Largest rolling-resistance coefficient ``C_rr = mu_r / r`` (dimensionless) a proposal gives a
rolling shape: a ball rolling on a golf green (stimpmeter speeds) decelerates at about 0.5 m/s^2,
``C_rr`` about 0.07; hard balls on hard floors are 0.001-0.01 (rolling-resistance tables, e.g.
Wikipedia "Rolling resistance"). A disc that decelerates faster than ``ROLL_FACTOR * C_rr * g`` is
sliding, and the sphere hypothesis of it keeps the excess."""

MU_SLIDE_MIN = 0.05
"""Smallest sliding friction a proposal believes of an object sliding on its face: dry pairs of
common solids (wood, metal, plastic, rubber, paper) are 0.1-1, PTFE on PTFE about 0.04 (tables of
friction coefficients, e.g. Wikipedia "Friction"); only ice or an air cushion is more slippery. A
round silhouette that travels on the floor decelerating less than ``MU_SLIDE_MIN * g`` is a ball
rolling, not a puck sliding (:func:`rolling_tracks`)."""
SIZE_PRIOR_DOUBT = 8.0
"""Largest factor by which a top-down view's scale (:data:`SIZE_PRIOR`, 5 cm for the median object)
may overstate the px per m: objects up to 40 cm (the synthetic scenes' largest, a basketball's
24 cm). A deceleration read at the prior's scale is that much too small for such an object, so
:func:`rolling_tracks` asks for less than ``MU_SLIDE_MIN * g / SIZE_PRIOR_DOUBT`` there."""
ROLL_MIN_FRAMES = 10
"""Frames of a motion fit (:attr:`Motion.n`) below which :func:`rolling_tracks` does not judge a
deceleration (a third of a second at 30 fps)."""
ROLL_MIN_TRAVEL = 0.5
"""Diameters an object must travel in the window before :func:`rolling_tracks` judges that it
keeps its speed (a track at rest keeps a speed of zero and says nothing)."""


PUCK_HEIGHT = 0.3
"""Height / diameter of a cylinder seen straight from above (a puck): the top-down silhouette of an
upright cylinder is its disc and says nothing of its height."""
UPRIGHT_HEIGHT = (0.2, 3.0)
"""Range of height / diameter an upright cylinder seen obliquely is given (:func:`upright_height`):
a coin-like puck to a tall can; outside it the silhouette is more likely blurred or merged."""


def upright_height(track: Track, pitch: float) -> float:
    """Height / diameter of an upright cylinder (axis vertical) whose silhouette is ``track``,
    seen from a camera pitched ``pitch`` deg below the horizon.

    Orthographic projection of an upright cylinder of diameter ``d`` and height ``h``: its image is
    ``d`` wide and ``d sin(pitch) + h cos(pitch)`` tall (the top disc foreshortened to an ellipse of
    minor axis ``d sin(pitch)``, plus the side). So ``h / d = (tall / d - sin(pitch)) / cos(pitch)``,
    with ``d`` the silhouette's short side (:attr:`Track.diameter`, unstretched by motion blur) and
    ``tall`` its vertical extent (:attr:`Track.tall`; a rotated box's angle is arbitrary for a
    near-round silhouette). A round silhouette gives ``(1 - sin p) / cos p`` (0.41 at 45 deg): a
    puck; an upright can's tall silhouette gives its height. Clipped to :data:`UPRIGHT_HEIGHT`;
    straight from above (``cos(pitch)`` below 0.1) or without a vertical extent
    :data:`PUCK_HEIGHT`.

    Returns:
        height / diameter, dimensionless.
    """
    c, s = math.cos(math.radians(pitch)), math.sin(math.radians(pitch))
    if c < 0.1 or not math.isfinite(track.tall):
        return PUCK_HEIGHT
    ratio = (track.tall / max(track.diameter, 1e-6) - s) / c
    return float(np.clip(ratio, *UPRIGHT_HEIGHT))


STANDING_TALL = 0.9
"""A silhouette seen obliquely whose vertical extent (:attr:`Track.tall`) is at least this share of its
rotated box's long side is an object standing on its footprint, its side in view (:func:`standing`)."""


def standing(track: Track) -> bool:
    """Whether an obliquely seen silhouette is as tall as it is long (its long side within ~25 deg
    of the image vertical, or round: :data:`STANDING_TALL`): an upright cylinder, a cube, a can,
    whose height adds to the foreshortened footprint (:func:`upright_height`), rather than a bar
    lying across the view, whose silhouette is mostly its footprint."""
    return math.isfinite(track.tall) and track.tall >= STANDING_TALL * track.size[0]


class PerceptionError(UserError, ValueError):
    """Nothing usable was found in the user's video (no moving object)."""


# --------------------------------------------------------------------------------- lifting
@dataclass
class Lifted:
    """One object of a proposal: scene-language fields (world frame, SI)."""

    shape: str
    size: dict[str, float]
    position: list[float]
    orientation: list[float]
    linear_velocity: list[float]
    friction: float
    mass: float
    kind: str = "floor"                       # fall | ramp | floor (side view) or plane (top)
    ramp: dict | None = None                  # static box under the path (side view)
    bumper: dict | None = None                # static box where the path turns back up the ramp
    restitution: float | None = None
    angular_velocity: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    rolling_friction: float = 0.0             # MuJoCo rolling coefficient, m (a ball that slows as it rolls)
    after_bounce: float | None = None         # m/s along x after the first bounce, where it changed (bounce_spin)
    notes: list[str] = field(default_factory=list)


def _mass(shape: str, size: dict[str, float]) -> float:
    return max(DENSITY * volume(shape, size), 1e-3)


def _side_motion_kind(track: Track, m: Motion) -> str:
    na = float(np.linalg.norm(m.a))
    if m.n >= 5 and m.a[1] > 0.8 * na and na > 30.0 * track.diameter:
        return "fall"
    if gravity_vote(track, m):
        return "ramp"
    return "floor"


def _side_body(track: Track, shape: str) -> str:
    """How a shape moves in :func:`lift_side`: a cylinder whose silhouette is not round stands on
    its end and slides as a box does (``"box"``); otherwise the shape itself."""
    return "box" if shape == "cylinder" and not round_silhouette(track) else shape


def side_scale(track: Track, m: Motion, kind: str, shape: str, fps: float) -> tuple[float, str]:
    """Pixels per metre at the object's depth for a side view, and where it came from.

    ``fall``: ``a_v / g``; ``ramp`` with a rolling shape: ``a / (k g sin theta)``, with the slope
    the path's (:func:`slope_direction`) and ``a`` the acceleration along it over the run down
    (:func:`slope_acceleration`), as the ramp is built; ``ramp`` with a sliding shape that comes
    back up the slope after a stop turns it (:func:`slide_down_and_up`): ``a / (g (sin theta -
    mu cos theta))`` with the friction ``mu`` the two accelerations give (its thickness, the
    silhouette's short side, is then the size checked); else (or when the implied size leaves
    :data:`SIZE_RANGE`) the size prior ``diameter / SIZE_PRIOR``.
    """
    prior = track.diameter / SIZE_PRIOR if shape != "box" else track.size[0] / SIZE_PRIOR
    ppm, source = prior, "size prior"
    extent_px = track.diameter if shape != "box" else track.size[0]
    if kind == "fall":
        ppm, source = float(m.a[1]) / G, "gravity (parabola)"
    elif kind == "ramp" and shape in ROLL_FACTOR:
        d = slope_direction(track, m)
        a = slope_acceleration(whole_frames(track), d, m, fps)[0]
        if d[1] > 0.05 and a > 0:
            ppm, source = a / (ROLL_FACTOR[shape] * G * float(d[1])), "gravity (rolling down a slope)"
    elif kind == "ramp":
        d = slope_direction(track, m)
        both = slide_down_and_up(whole_frames(track), d, m, fps)
        sin_t = float(d[1])
        if both is not None and sin_t > 0.05:
            mu, a = both
            cos_t = math.sqrt(1.0 - sin_t ** 2)
            if sin_t - mu * cos_t > 0.02:
                ppm = a / (G * (sin_t - mu * cos_t))
                source = f"gravity (sliding down a slope and back up it: friction {mu:.3f})"
                extent_px = track.diameter   # its thickness: the long side of a glider or a bar may pass 0.15 m
    extent = extent_px / ppm
    if not SIZE_RANGE[0] <= extent <= SIZE_RANGE[1]:
        ppm, source = prior, "size prior (gravity scale implied an object of %.3f m)" % extent
    return ppm, source


def lift_side(tracks: list[Track], motions: list[Motion], width: int, height: int, fps: float,
              shape_of: dict[int, str], fov: float = FOV_PRIOR) -> tuple[Camera, list[Lifted], list[str]]:
    """Metric scene of a side view (camera pitch 0, vertical field of view ``fov`` deg: the prior's,
    or that of the crop the image is, :func:`crop_fov`).

    Each object lies in the vertical plane at its own depth ``D = f / ppm`` (:func:`side_scale`);
    the camera height puts the floor ``z = 0`` under the lowest contact seen (the bottom of a
    falling track, one radius under a bounce's impact, and never above the main object's start)
    or at the image bottom. Returns ``(camera, objects, notes)``.
    """
    K = intrinsics(fov, width, height)
    f, cu, cv = K[0, 0], K[0, 2], K[1, 2]
    notes: list[str] = []
    scales, kinds, by_gravity = [], [], []
    whole = [whole_frames(t) for t in tracks]   # the frames with the whole silhouette in view
    for tr, m in zip(tracks, motions):
        kind = _side_motion_kind(tr, m)
        ppm, src = side_scale(tr, m, kind, _side_body(tr, shape_of[tr.label]), fps)
        scales.append(ppm)
        kinds.append(kind)
        by_gravity.append(src.startswith("gravity"))
        notes.append(f"object {tr.label}: {kind}, {tr.shape} -> {shape_of[tr.label]}, scale {ppm:.0f} px/m from {src}")
    # camera height from the floor row of the main object: the fall read from the most samples
    # (its bounce shows the floor; an object at rest shows only its own bottom row), else the
    # largest object. A fall whose gravity gives a plausible size (side_scale) outranks one whose
    # curvature would make it an object of metres (a flickering piece of scenery, dev/02's ruler):
    # the floor row holds at the main object's depth only
    falling = [i for i, k in enumerate(kinds) if k == "fall"]
    main = max(falling, key=lambda i: (by_gravity[i], motions[i].n, float(np.median(tracks[i].area)))) \
        if falling else int(np.argmax([np.median(t.area) for t in tracks]))
    D0 = f / scales[main]
    lowest = max(float(t.bottom.max()) for t in tracks)
    if kinds[main] == "fall":
        # a bounce seen puts the floor one radius under the impact, also when the impact
        # itself is cut off by the image border (the bottom row seen is then only the border)
        hit = first_bounce(whole[main], fps)
        if hit is not None:
            lowest = max(lowest, hit.v + 0.5 * tracks[main].diameter)
        else:
            # without one, nor can a fall start under the floor: a ball thrown up from below the
            # view starts where its first arc, extrapolated to t = 0, is. A measured bounce
            # outranks that inference: a first arc extrapolated back over frames where a hand
            # still held the ball (dev/02) lies under the floor the ball then bounces on
            lowest = max(lowest, float(motions[main].p0[1]) + 0.5 * tracks[main].diameter)
    v_floor = lowest if kinds[main] == "fall" else max(lowest + 1.0, float(height))
    v_floor = max(v_floor, cv + 0.05 * height)
    cam_h = (v_floor - cv) * D0 / f
    cam = Camera(height=round(max(cam_h, 0.01), 4), pitch=0.0, fov=fov)
    # restitution of every fall from its bounces, read once (the main one also undoes a bounce)
    restitution = [bounce_restitution(w, fps) if k == "fall" else None for w, k in zip(whole, kinds)]
    if kinds[main] == "fall":   # a start under the floor: the window opens just before a bounce
        e = restitution[main]
        undone = before_bounce(motions[main], v_floor - 0.5 * tracks[main].diameter, e or BOUNCE_PRIOR)
        if undone is not None:
            motions = list(motions)
            motions[main] = undone[0]
            notes.append(f"object {tracks[main].label}: its first arc, extrapolated to t = 0, starts under the "
                         f"floor: it bounced at t = {undone[1]:.3f} s (e {e or BOUNCE_PRIOR:.2f}), its state at "
                         "t = 0 is on the arc before")
    objects = []
    for tr, w, m, ppm, kind, fell, e in zip(tracks, whole, motions, scales, kinds, by_gravity, restitution):
        shape = shape_of[tr.label]
        D = f / ppm
        px = 1.0 / ppm  # m per px at this depth
        x = (m.p0[0] - cu) * px
        z = cam.height - (m.p0[1] - cv) * px
        y = D - 2.0  # the paper camera sits at y = -2 looking along +y
        vel = [float(m.v0[0] * px), 0.0, float(-m.v0[1] * px)]
        if shape == "sphere":
            size = {"radius": tr.diameter / 2 * px}
            quat = [1.0, 0.0, 0.0, 0.0]
            half_h = size["radius"]
        elif shape == "cylinder" and round_silhouette(tr):  # a disc seen end-on: axis along the line of sight (y)
            size = {"radius": tr.diameter / 2 * px, "height": 0.4 * tr.diameter * px}
            quat = axis_angle_quat((1.0, 0.0, 0.0), -math.pi / 2).tolist()
            half_h = size["radius"]
        elif shape == "cylinder":  # standing on its end: the rectangle's side nearest the vertical is its axis
            long_, short = tr.size
            across, along, tilt = (long_, short, tr.angle) if abs(tr.angle) <= 45.0 else \
                (short, long_, tr.angle - math.copysign(90.0, tr.angle))
            size = {"radius": across / 2 * px, "height": along * px}
            quat = axis_angle_quat((0.0, 1.0, 0.0), -math.radians(tilt)).tolist()
            half_h = along / 2 * px
        else:  # box in the image plane, turned by the silhouette's angle about -y
            long_, short = tr.size
            size = {"width": long_ * px, "depth": short * px, "height": short * px}
            quat = axis_angle_quat((0.0, 1.0, 0.0), -math.radians(tr.angle)).tolist()
            half_h = short / 2 * px
        z = max(z, half_h + 1e-3)
        friction = 0.5
        lifted = Lifted(shape, size, [float(x), float(y), float(z)], quat, vel, friction, _mass(shape, size), kind)
        body = _side_body(tr, shape)
        if kind == "ramp":
            lifted.ramp, lifted.friction = _ramp_under(tr, m, px, cu, cv, cam.height, y, half_h, body, fps)
            turn = bumper_on_ramp(w, m, px, cu, cv, cam.height, y, half_h, fps)
            if turn is not None:   # a springy stop with the restitution seen (bumper_on_ramp)
                lifted.bumper = turn[0]
                notes.append(f"object {tr.label}: turns back up the slope: a bumper there (restitution "
                             f"{turn[1]:.2f})")
        if kind in ("ramp", "floor") and body in ROLL_FACTOR:
            # already rolling, not skidding: a ball launched without spin slides until friction
            # has spun it up, losing 2/7 of its speed (sphere; 1/3 for a cylinder)
            normal = np.array([0.0, 0.0, 1.0])
            if lifted.ramp is not None:
                q = lifted.ramp["orientation"]
                normal = np.array([2 * (q[1] * q[3] + q[0] * q[2]), 2 * (q[2] * q[3] - q[0] * q[1]),
                                   1 - 2 * (q[1] ** 2 + q[2] ** 2)])  # local +z of the ramp box
            lifted.angular_velocity = rolling_spin(normal, np.asarray(vel), size["radius"]).tolist()
            if kind == "floor" and m.n >= 5:   # slowing as it rolls along the floor: rolling resistance
                lifted.rolling_friction = rolling_resistance(-float(m.a[0]) * math.copysign(px, m.v0[0]),
                                                             size["radius"], shape)
        elif kind == "fall" and fell:   # not a "fall" whose curvature gives an object of metres
            lifted.restitution = e
            after = speed_after_bounce(w, fps)
            if after is not None and (shape == "sphere" or (shape == "cylinder" and round_silhouette(tr))):
                lifted.after_bounce = after * px
        objects.append(lifted)
    return cam, objects, notes


SPIN_MAX = 300.0
"""rad/s, the largest spin :func:`bounce_spin` gives (a table-tennis serve spins at 100-150 rad/s)."""


def _speed_after_first_bounce(scene: Scene, index: int, spin: float) -> float | None:
    """x velocity (m/s) of object ``index`` simulated alone in ``scene`` (its static geometry and
    effects kept) with angular velocity ``(0, spin, 0)`` rad/s, two frames after its first bounce
    (the first frame whose vertical velocity turns from down to up); None without a bounce."""
    obj = scene.objects[index].model_dump()
    obj["angular_velocity"] = [0.0, float(spin), 0.0]
    alone = scene.replace(objects=[obj])
    tr = rollout(compile_model(alone), 1, alone.n_frames, alone.fps, record_contacts=False)
    vz = tr.qvel[:, 0, 2]
    up = np.flatnonzero((vz[1:] > 0) & (vz[:-1] < 0))
    if not len(up) or up[0] + 3 >= len(vz):
        return None
    return float(tr.qvel[up[0] + 3, 0, 0])


def bounce_spin(scene: Scene, index: int, speed_after: float, iterations: int = 12
                ) -> tuple[Scene, float] | None:
    """The spin about the line of sight (world y in a side view) that makes object ``index``
    leave its first bounce at the observed sideways speed ``speed_after`` (m/s).

    A spinning ball's contact point slides on impact, and friction trades spin for sideways
    speed: leaving the floor rolling, a sphere's speed becomes ``(5 v + 2 r w) / 7`` (angular
    momentum about the contact point conserved; any mechanics text, e.g. Cross, "The bounce of a
    ball", Am. J. Phys. 67, 1999). MuJoCo's soft contact stops short of rolling (a ball dropped
    from 0.3 m keeps 44-69 % of the change), so the spin is found in the simulator itself: the
    sideways speed after the bounce grows with the spin (topspin carries it forward), and a
    bisection over ``[-SPIN_MAX, SPIN_MAX]`` (:data:`SPIN_MAX`) matches it. The spin at ``t = 0``
    is the spin before the bounce: nothing changes it in flight.

    Given to a sphere and to a disc seen end-on (a side view's round cylinder, its axis on the
    line of sight), whose first two flight arcs move sideways at speeds apart by more than their
    noise (:func:`pipeline.image_tracks.speed_after_bounce`).

    Args:
        scene: a side-view proposal; index: the object; speed_after: m/s along world x.
        iterations: bisection steps.
    Returns:
        ``(scene with that spin, spin in rad/s)``, or None when the simulated object does not
        bounce, or no spin within the range reaches the speed.
    """
    def miss(w: float) -> float | None:
        v = _speed_after_first_bounce(scene, index, w)
        return None if v is None else v - speed_after

    lo, hi = -SPIN_MAX, SPIN_MAX
    f_lo, f_hi = miss(lo), miss(hi)
    if f_lo is None or f_hi is None or f_lo > 0 or f_hi < 0:
        return None
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        f = miss(mid)
        if f is None:
            return None
        lo, hi = (mid, hi) if f < 0 else (lo, mid)
    w = 0.5 * (lo + hi)
    objects = [o.model_dump() for o in scene.objects]
    objects[index]["angular_velocity"] = [0.0, w, 0.0]
    return scene.replace(objects=objects), w


BOUNCE_PRIOR = 0.8
"""Restitution assumed by :func:`before_bounce` where the track gives none (a ball on a hard floor)."""


def before_bounce(m: Motion, contact: float, e: float) -> tuple[Motion, float] | None:
    """The state at ``t = 0`` of a fall whose first fitted arc, extrapolated back to ``t = 0``,
    starts under the floor: the window opened just before a bounce (real clip dev/02, a ping-pong
    ball bouncing every 7 frames), and the arc before it holds the start.

    The arc ``v(t) = p0 + v0 t + a t^2 / 2`` (image rows, down positive) meets the contact row
    (the centroid's row when the object touches the floor) going up at ``t_b``, the earlier root
    of ``a/2 t^2 + v0 t + (p0 - contact) = 0``. Undone through an impulse bounce of restitution
    ``e`` (Newton's law of restitution: the normal speed before is the speed after over ``e``;
    the sideways velocity is kept), the arc before reaches ``t = 0`` at
    ``contact - w t_b + a t_b^2 / 2`` with row speed ``w - a t_b``, ``w = -(v0 + a t_b) / e``.

    Args:
        m: the fall's motion at ``t = 0`` (:class:`pipeline.image_tracks.Motion`, px, px/s).
        contact: image row of the centroid at contact with the floor, px.
        e: restitution of the bounce, in (0, 1].
    Returns:
        ``(motion, t_b)``: the motion with ``p0`` and ``v0`` of the arc before the bounce, and the
        bounce time (s); None when the start is not under the contact row, the acceleration is
        not downward, or the arc never rises through the row after ``t = 0``.
    """
    a, v0, p0 = float(m.a[1]), float(m.v0[1]), float(m.p0[1])
    if p0 <= contact or a <= 0 or not 0 < e <= 1:
        return None
    disc = v0 * v0 - 2.0 * a * (p0 - contact)
    if disc < 0:
        return None
    t_b = (-v0 - math.sqrt(disc)) / a
    if t_b <= 0:
        return None
    w = -(v0 + a * t_b) / e
    p0_y = contact - w * t_b + 0.5 * a * t_b * t_b
    if p0_y > contact:
        return None
    return replace(m, p0=np.array([float(m.p0[0]), p0_y]), v0=np.array([float(m.v0[0]), w - a * t_b])), t_b


def rolling_resistance(decel: float, radius: float, shape: str = "sphere") -> float:
    """MuJoCo rolling coefficient ``mu_r`` (m, geom ``friction[2]``; the resisting torque is
    ``mu_r * N``, MuJoCo docs "Contact") that slows a ``shape`` rolling without slipping on a level
    plane by ``decel`` m/s^2.

    Energy balance: the torque dissipates ``mu_r N w = mu_r m g v / r`` of the kinetic energy
    ``1/2 (m + I / r^2) v^2``, so ``decel = ROLL_FACTOR * mu_r * g / r`` and
    ``mu_r = decel * r / (ROLL_FACTOR * g)`` (:data:`ROLL_FACTOR`: 5/7 for a solid sphere, 2/3 for
    a solid cylinder on its side). ``mu_r / r`` is capped at :data:`ROLLING_RESISTANCE_MAX`; a
    negative ``decel`` (speeding up) gives 0. MuJoCo's elliptic cone meets the closed form; its
    pyramidal cone (``sim.cone``'s default) gives a small ``mu_r / r`` only part of its torque (at
    0.3 m/s: 0.51x at 0.01, 0.79x at 0.0175, 0.96x at 0.05; ``docs/physics.md`` check 3b).

    Args:
        decel: deceleration along the velocity, m/s^2; radius: m (> 0); shape: a key of
            :data:`ROLL_FACTOR`.
    Returns:
        ``mu_r``, m.
    Raises:
        KeyError: ``shape`` does not roll.
    """
    crr = min(max(decel, 0.0) / (ROLL_FACTOR[shape] * G), ROLLING_RESISTANCE_MAX)
    return float(crr * radius)


def rolling_spin(normal: np.ndarray, velocity: np.ndarray, radius: float) -> np.ndarray:
    """World angular velocity (3,) rad/s of a ball or cylinder rolling without slipping with
    ``velocity (3,)`` m/s on a surface of unit normal ``normal (3,)``: the contact point is at
    rest when ``v + w x (-r n) = 0``, i.e. ``w = (n x v) / r``."""
    return np.cross(normal, velocity) / radius


def slope_direction(tr: Track, m: Motion) -> np.ndarray:
    """``(2,)`` unit image direction down the slope an object moves on: the principal direction of
    its centroid path (total least squares, as :func:`pipeline.image_measure.path_angle`), turned
    to point along its acceleration. An object on a straight ramp moves along it, so its path
    gives the slope; the acceleration's direction, fitted on a few frames, is noisier (the edges
    read by hand on a frame, `tests/fixtures/realvideo/physical_truth.yaml`: dev/10's air track
    9.3 deg, its path 10.1, the gravity window's acceleration 18.6; 07's shelf 4.2, path 4.9,
    window 10.0; 08's incline 21.8, path 21.3, window 23.3). The acceleration's direction where
    the path is shorter than one diameter."""
    a = m.a / max(float(np.linalg.norm(m.a)), 1e-9)
    pts = tr.centre - tr.centre.mean(axis=0)
    if len(pts) < 3 or float(np.ptp(pts @ a)) < tr.diameter:
        return a
    d = np.linalg.svd(pts, full_matrices=False)[2][0]
    return d if float(d @ a) >= 0 else -d


def _turn_back(tr: Track, s: np.ndarray) -> int | None:
    """Index of the first sample furthest down a slope (``s (N,)``: px down it) where the object
    turns back up: at least 2 samples on each side moving :data:`BUMPER_SPEED` diameters per
    frame or faster, down before and up after; None if it never does."""
    step = np.diff(s) / np.maximum(np.diff(tr.frames), 1)
    fast = BUMPER_SPEED * tr.diameter
    return next((i for i in range(2, len(s) - 2)
                 if s[i] >= s[i - 1] and s[i] >= s[i + 1] and (step[i - 2:i] > fast).all()
                 and (step[i:i + 2] < -fast).all()), None)


def slope_acceleration(tr: Track, d: np.ndarray, m: Motion, fps: float, min_frames: int = 6
                       ) -> tuple[float, float, int]:
    """Acceleration down the slope: a parabola fitted to the path's position along the slope
    direction ``d (2,)`` over the longest first stretch of consecutive samples it explains (RMS
    within :func:`pipeline.image_tracks.fit_tolerance`): the whole run down, until the object hits
    a bumper or the bottom and stops. So a slide is read from all of it, as
    :func:`pipeline.image_tracks.flight_gravity` reads a fall from all its arcs: the gravity
    window is the steepest of many, biased high (dev/10's glider: 0.51 px/frame^2 pointing 18.6
    deg down in the window, 0.42 along its 10.1 deg path over its 16 frames down; 07's cylinder
    0.27 at 10.0 deg there, 0.23 along 4.9 deg over 26 frames; a synthetic ball rolling down 10
    deg: the window's acceleration points 28 deg down).

    Returns:
        ``(a, a_sd, n)``: px/s^2 along ``d``, its standard deviation from the fit (px/s^2) and the
        samples fitted; ``(m.a @ d, m.a_sd, m.n)`` when fewer than ``min_frames`` samples fit.
    """
    s = tr.centre @ d
    t = tr.frames / fps
    tol = fit_tolerance(tr)
    best = None
    for j in range(min_frames, len(s) + 1):
        if tr.frames[j - 1] - tr.frames[0] != j - 1:
            break
        coef, cov = np.polyfit(t[:j], s[:j], 2, cov="unscaled")
        res = np.polyval(coef, t[:j]) - s[:j]
        if float(np.sqrt(np.mean(res ** 2))) > tol:
            break
        sd = 2.0 * math.sqrt(max(float(np.sum(res ** 2)) / (j - 3), 0.3 ** 2) * float(cov[0, 0]))
        best = (2.0 * float(coef[0]), sd, j)
    return (float(m.a @ d), float(m.a_sd), int(m.n)) if best is None else best


def slide_down_and_up(tr: Track, d: np.ndarray, m: Motion, fps: float, min_frames: int = 5
                      ) -> tuple[float, float] | None:
    """Friction of an object that slides down a slope and, turned by a stop at the bottom (a
    bumper, :func:`_turn_back`), back up it, and its acceleration down, px/s^2.

    Down the slope ``a_down = g (sin theta - mu cos theta)``, up it ``a_up = g (sin theta + mu cos
    theta)`` (both pointing down the slope, the friction against the motion each way), in any
    length unit, so ``mu = tan(theta) (a_up - a_down) / (a_up + a_down)`` whatever the scale (an
    air-track glider, dev/10: 379 px/s^2 down, 443 up over 10 deg, ``mu`` 0.014). Each is the
    parabola of :func:`slope_acceleration` along ``d`` over its stretch: the run down, and from
    the sample after the turn the run up (at least ``min_frames`` samples).

    Args:
        tr: the track (whole frames); d: ``(2,)`` unit image direction down the slope
        (:func:`slope_direction`); m: its motion; fps: frames per second.
    Returns:
        ``(mu, a_down)``, ``mu >= 0``; None without a turn, without ``min_frames`` samples on each
        run, or where either acceleration does not point down the slope.
    """
    s = (tr.centre - tr.centre[0]) @ d
    k = _turn_back(tr, s)
    if k is None or len(tr.frames) - (k + 1) < min_frames:
        return None
    up = replace(tr, frames=tr.frames[k + 1:], centre=tr.centre[k + 1:], area=tr.area[k + 1:],
                 bottom=tr.bottom[k + 1:], clipped=None if tr.clipped is None else tr.clipped[k + 1:])
    a_down, _, n_down = slope_acceleration(tr, d, m, fps)
    a_up, _, n_up = slope_acceleration(up, d, m, fps, min_frames=min_frames)
    if n_down < min_frames or n_up < min_frames or a_down <= 0 or a_up <= 0:
        return None
    sin_t = min(max(float(d[1]), 0.0), 0.99)
    tan_t = sin_t / math.sqrt(1.0 - sin_t ** 2)
    return max(0.0, tan_t * (a_up - a_down) / (a_up + a_down)), float(a_down)


def _ramp_under(tr: Track, m: Motion, px: float, cu: float, cv: float, cam_h: float, y: float,
                half_h: float, shape: str, fps: float) -> tuple[dict, float]:
    """A static box whose top face runs under the track (contact line = path offset by the
    object's half height along the slope normal, slope along :func:`slope_direction`), and a
    friction estimate: 0.5 for a rolling shape, ``tan(theta) - a / (g cos(theta))`` for a sliding
    box, ``a`` the acceleration along the slope."""
    d = slope_direction(tr, m)                                 # image direction of the slope (down it)
    theta = math.asin(min(max(float(d[1]), 0.0), 0.99))       # inclination, rad
    sgn = 1.0 if d[0] >= 0 else -1.0                           # descends towards +x or -x
    # world points of the path (first and last visible centres)
    pts = np.array([[(u - cu) * px, cam_h - (v - cv) * px] for u, v in tr.centre])
    along = np.array([sgn * math.cos(theta), -math.sin(theta)])  # down the slope, (x, z)
    normal = np.array([math.sin(theta) * sgn, math.cos(theta)])  # up from the surface, (x, z)
    s = pts @ along
    centre_line = pts[np.argmin(s)] - normal * half_h            # contact point at the top of the path
    length = float(s.max() - s.min()) + 20 * half_h + 0.3
    thickness = 0.02
    mid = centre_line + along * (length / 2 - 10 * half_h - 0.15) - normal * thickness / 2
    angle = sgn * theta  # rotation about +y that tilts +x down by theta for sgn = +1
    quat = axis_angle_quat((0.0, 1.0, 0.0), angle).tolist()
    ramp = {"shape": "box", "size": {"width": round(length, 4), "depth": 0.3, "height": thickness},
            "position": [float(mid[0]), float(y), float(mid[1])], "orientation": quat}
    if shape == "box":
        a_m = max(slope_acceleration(whole_frames(tr), d, m, fps)[0], 0.0) * px
        mu = math.tan(theta) - a_m / (G * math.cos(theta))
        return ramp, float(np.clip(mu, 0.0, 1.5))
    return ramp, ROLLING_GRIP


BUMPER_SPEED = 0.1
"""Fewest diameters per frame an object must move along a slope, down it before a turn and up it
after, for :func:`bumper_on_ramp` to read the turn as a hit (slower, it is noise or a stop)."""


def bumper_on_ramp(tr: Track, m: Motion, px: float, cu: float, cv: float, cam_h: float, y: float,
                   half_h: float, fps: float) -> tuple[dict, float] | None:
    """A static bumper where an object sliding or rolling down a slope turns back up it, and the
    coefficient of restitution of that hit; None if it never does.

    On an incline gravity can turn an object only at the top of its path (it slows going up and
    comes back down): a turn at the *bottom*, from moving down the slope to moving up it, needs
    something there to push it back (dev/10: an air-track glider rebounds off a spring bumper at
    the low end, again and again). The track's centres are projected on the slope's image
    direction (:func:`slope_direction`, down the slope); the turn is :func:`_turn_back`'s. The
    bumper is a box standing on the ramp across the path (2 cm thick along the slope, 0.3 m deep,
    four half heights of the object tall), its face one half length of the object (the
    silhouette's long side) beyond the centre at the turn; ``e`` is the speed along the slope
    after the turn over the speed before it (lines through the 2-3 samples on each side), clamped
    to [0.2, 0.95] as :func:`pipeline.image_tracks.first_bounce` does.

    The bumper carries ``e`` as its own ``restitution`` (a static geom's springy stop,
    :class:`pipeline.scene.StaticBox`): the ``restitution`` effect is the object's, on every
    contact (:mod:`pipeline.effects`), and a contact that springy slid dev/10's box down its ramp
    at 2.5 times the acceleration its friction gives (about 1 m/s^2 against 0.41); the bumper's
    own leaves the ramp's contact as it is (``tests/test_static.py``).

    Args:
        tr: the track (whole frames); m: its motion (``a``: px/s^2, towards down the slope);
        px: m per px at its depth; cu, cv: principal point, px; cam_h: camera height, m;
        y: the object's depth coordinate, m; half_h: its half height over the ramp, m;
        fps: frames per second.
    Returns:
        ``(static_box, e)``: a scene-language static box (dict) and the restitution, or None.
    """
    if not np.any(m.a) or len(tr.frames) < 5:
        return None
    d = slope_direction(tr, m)
    s = (tr.centre - tr.centre[0]) @ d                                   # px down the slope
    k = _turn_back(tr, s)           # 2 <= k <= N - 3: at least 2 samples on each side
    if k is None:
        return None
    t = tr.frames / fps
    before = np.arange(max(0, k - 3), k)
    after = np.arange(k + 1, min(len(s), k + 4))
    v_in = float(np.polyfit(t[before], s[before], 1)[0])
    v_out = float(np.polyfit(t[after], s[after], 1)[0])
    if v_in <= 0 or v_out >= 0:
        return None
    e = float(np.clip(-v_out / v_in, 0.2, 0.95))
    theta = math.asin(min(max(float(d[1]), 0.0), 0.99))
    sgn = 1.0 if d[0] >= 0 else -1.0
    along = np.array([sgn * math.cos(theta), -math.sin(theta)])         # down the slope, (x, z)
    centre = np.array([(tr.centre[k, 0] - cu) * px, cam_h - (tr.centre[k, 1] - cv) * px])
    thickness = 0.02
    mid = centre + along * (0.5 * tr.size[0] * px + 0.5 * thickness)
    quat = axis_angle_quat((0.0, 1.0, 0.0), sgn * theta).tolist()
    box = {"shape": "box", "size": {"width": thickness, "depth": 0.3, "height": round(4.0 * half_h, 4)},
           "position": [float(mid[0]), float(y), float(mid[1])], "orientation": quat, "restitution": e}
    return box, e


SLOPE_MIN_DEG = 2.0
"""deg: the gentlest ramp :func:`ground_slope` reads from a speed-up seen from above (a ball rolls
down it at ``(5/7) g sin(2 deg) = 0.24 m/s^2``), the incline the real-clip table counts as one
(``scripts/realvideo_all.py``: a static geom tilted 2-60 deg). Below it, a speed-up on the ground
plane is as likely the perspective of a camera pitched otherwise than the proposal's 45 or 89 deg
(a rendered ball rolling away from a camera at 29 deg read as 1.1 deg down a ramp) as a slope."""

SLOPE_MAX_DEG = 30.0
"""deg: the steepest ramp :func:`ramp_on_ground` builds."""


def ground_slope(tr: Track, points: np.ndarray, fps: float, tol: float, min_frames: int = 6
                 ) -> tuple[np.ndarray, float, int] | None:
    """A slope under an object seen from above, from its speed-up on the ground plane.

    On a level floor nothing speeds an object up (friction and rolling resistance slow it); one
    that speeds up along a straight line, seen from above, rolls or slides down a slope. The track's
    points on the horizontal plane of its centre (``points``, perspective undone) are projected on
    their principal direction ``s``, over its first run of consecutive samples. The run down may
    end before the track does, where the object leaves the ramp for the floor (real clip 02), so
    ``s(t)`` is fitted with a constant acceleration ``a`` up to a change point ``t_n`` and the speed
    reached there after it (basis ``1, t, min(t, t_n)^2 / 2 + t_n max(t - t_n, 0)``, least squares),
    ``n`` from ``min_frames`` to all samples, the ``n`` of least squared residual. A slope needs
    the fit within ``tol`` (RMS), ``a`` along the motion of at least
    three standard deviations (:data:`SLOPE_MIN_DEG` for a ball rolling down it), and a speed at
    ``t_n`` above the starting one.

    Args:
        tr: the track (whole frames); points: ``(N, 3)`` float64 world points of its centroids, m.
        fps: frames per second; tol: RMS tolerance, m; min_frames: fewest samples of the run down.
    Returns:
        ``(direction, a, n)``: ``(2,)`` unit ground direction down the slope, the acceleration along
        it (m/s^2) and the samples of the run down (the first ``n`` of the track); None without a
        slope.
    """
    xy = np.asarray(points, dtype=np.float64)[:, :2]
    run = int(np.argmax(np.diff(tr.frames) != 1)) + 1 if np.any(np.diff(tr.frames) != 1) else len(tr.frames)
    if run < min_frames or not np.all(np.isfinite(xy[:run])):
        return None
    xy = xy[:run]
    d = np.linalg.svd(xy - xy.mean(axis=0), full_matrices=False)[2][0]
    s = xy @ d
    t = (tr.frames[:run] - tr.frames[0]) / fps
    best = None
    for n in range(min_frames, run + 1):
        tn = t[n - 1]
        X = np.stack([np.ones_like(t), t, 0.5 * np.minimum(t, tn) ** 2 + tn * np.maximum(t - tn, 0.0)], axis=1)
        coef, sse = np.linalg.lstsq(X, s, rcond=None)[:2]
        sse = float(sse[0]) if len(sse) else float(np.sum((X @ coef - s) ** 2))
        if best is None or sse < best[1] - 1e-15:
            best = (coef, sse, n, X)
    coef, sse, n, X = best
    if math.sqrt(sse / run) > tol or run <= 3:
        return None
    cov = np.linalg.pinv(X.T @ X) * max(sse / (run - 3), 1e-12)
    a, sd = float(coef[2]), math.sqrt(max(float(cov[2, 2]), 0.0))
    v_start, v_end = float(coef[1]), float(coef[1] + coef[2] * t[n - 1])
    if a < 0:                               # the direction down the slope is the acceleration's
        d, a, v_start, v_end = -d, -a, -v_start, -v_end
    if a < max(ROLL_FACTOR["sphere"] * G * math.sin(math.radians(SLOPE_MIN_DEG)), 3.0 * sd) \
            or abs(v_end) <= abs(v_start) or v_end <= 0:
        return None
    return d, a, n


def ramp_on_ground(points: np.ndarray, direction: np.ndarray, a: float, n: int, shape: str, half_h: float,
                   diameter: float) -> tuple[dict, np.ndarray, float]:
    """A static ramp under an object seen from above rolling down it (:func:`ground_slope`), its
    low end on the floor.

    The incline follows from the acceleration down it, ``a = k g sin(theta)`` (rolling without
    slipping, ``k`` :data:`ROLL_FACTOR`), up to :data:`SLOPE_MAX_DEG`. Its low end is where the run
    down ends: the object leaves the ramp for the floor there (real clip 02: a ball rolls off a
    tilted board); where it rolls down to the end of the window, two diameters past its last
    point. The ramp is a box 2 cm thick whose top face holds the object's contact points, from
    that end up the slope to two diameters plus 0.1 m beyond its first point, 0.3 m wide or
    four diameters if wider.

    Args:
        points: ``(N, 3)`` world points of the centroids on the horizontal plane of the centre, m;
        direction: ``(2,)`` unit ground direction down the slope; a: m/s^2 along it; n: samples of
        the run down; shape: ``sphere`` or ``cylinder`` (:data:`ROLL_FACTOR`); half_h: the
        object's centre height over its support, m; diameter: its size, m.
    Returns:
        ``(static_box, normal, theta)``: a scene-language static box (dict), the ramp's unit
        normal ``(3,)`` and its inclination, rad.
    """
    theta = math.asin(min(a / (ROLL_FACTOR[shape] * G), math.sin(math.radians(SLOPE_MAX_DEG))))
    dx, dy = float(direction[0]), float(direction[1])
    down = np.array([math.cos(theta) * dx, math.cos(theta) * dy, -math.sin(theta)])   # down the slope, 3-D
    normal = np.array([math.sin(theta) * dx, math.sin(theta) * dy, math.cos(theta)])
    xy = np.asarray(points, dtype=np.float64)[:, :2]
    s = xy @ np.asarray(direction, dtype=np.float64)               # m down the slope, on the ground
    end = float(s[n - 1]) + (2.0 * diameter if n >= len(s) else 0.0)
    low = np.array([*(xy[n - 1] + (end - s[n - 1]) * np.asarray(direction)), 0.0])   # the low end, on the floor
    length = (end - float(s.min())) / math.cos(theta) + 2.0 * diameter + 0.1
    thickness = 0.02
    mid = low - down * (length / 2) - normal * (thickness / 2)
    quat = quat_mul(axis_angle_quat((0.0, 0.0, 1.0), math.atan2(dy, dx)), axis_angle_quat((0.0, 1.0, 0.0), theta))
    across = max(0.3, 4.0 * diameter)
    box = {"shape": "box", "size": {"width": round(length, 4), "depth": round(across, 4), "height": thickness},
           "position": [float(v) for v in mid], "orientation": [float(v) for v in quat]}
    return box, normal, theta


def lift_top(tracks: list[Track], motions: list[Motion], width: int, height: int,
             shape_of: dict[int, str], pitch: float = TOP_DOWN_PITCH, fov: float = FOV_PRIOR,
             fps: float | None = None) -> tuple[Camera, list[Lifted], list[str]]:
    """Metric scene of a top-down view (pitch :data:`TOP_DOWN_PITCH`, vertical field of view ``fov``
    deg as :func:`lift_side`), or of
    an oblique view of the objects on the floor at another ``pitch`` (deg): the camera then sits at
    the size prior's distance from the objects' plane along its optical axis.

    The scale is the size prior (median object diameter = :data:`SIZE_PRIOR`); a cylinder stands
    upright, as tall as its silhouette says (:func:`upright_height`: a puck from above, a can
    obliquely); so does a box seen obliquely whose silhouette stands (:func:`standing`: a square
    footprint as wide as the silhouette, yaw 0), else its footprint is the silhouette's rotated box
    (yaw its angle); positions are
    the rays through the centroids met with the plane of the object centres; friction from the
    deceleration along the velocity, ``mu = -a.v_hat / g``, for a sliding shape (cylinder, box); a
    sphere rolls (:func:`rolling_spin`) and its deceleration is rolling resistance
    (:func:`rolling_resistance`, sliding friction :data:`ROLLING_GRIP`).

    With ``fps`` (frames per second) a sphere that speeds up along a line on the ground plane
    (:func:`ground_slope`) rolls down a ramp instead (:func:`ramp_on_ground`): its centre on the
    plane parallel to the ramp, its velocity along it, spinning as it rolls; ``kind`` ``ramp``.
    """
    K = intrinsics(fov, width, height)
    f = K[0, 0]
    d_px = float(np.median([t.diameter for t in tracks]))
    ppm = d_px / SIZE_PRIOR
    oblique = pitch < TOP_DOWN_PITCH
    notes = [f"{'oblique view (pitch %g deg)' % pitch if oblique else 'top-down view'}: scale {ppm:.0f} px/m "
             f"from the size prior ({SIZE_PRIOR} m for {d_px:.1f} px)"]
    dist = f / ppm  # camera to the objects' plane, m

    def spec(tr: Track, shape: str, px: float) -> tuple[dict, float]:
        if shape == "sphere":
            return {"radius": tr.diameter / 2 * px}, tr.diameter / 2 * px
        if shape == "cylinder":  # axis vertical: a puck from above, its height from the silhouette obliquely
            size = {"radius": tr.diameter / 2 * px, "height": upright_height(tr, pitch) * tr.diameter * px}
            return size, size["height"] / 2
        long_, short = tr.size
        if oblique and standing(tr):   # its height shows: a square footprint as wide as the silhouette
            d = tr.diameter * px
            size = {"width": d, "depth": d, "height": upright_height(tr, pitch) * d}
        else:                          # its footprint shows: the silhouette's rotated box
            size = {"width": long_ * px, "depth": short * px, "height": 0.5 * short * px}
        return size, size["height"] / 2

    specs = [(shape_of[tr.label],) + spec(tr, shape_of[tr.label], 1.0 / ppm) for tr in tracks]
    z_c = float(np.median([s[2] for s in specs]))
    # straight above at TOP_DOWN_PITCH the objects' plane is fronto-parallel (sin 89 deg = 0.99985):
    # one scale; at a lower pitch the optical axis meets the objects' plane at the distance ``dist``,
    # and each object's scale is that of its own depth (pinhole: m per px = Z / f), found by
    # fixed-point iteration from the size prior's (its depth depends on its height, its size)
    rise = dist if not oblique else dist * math.sin(math.radians(pitch))
    cam = Camera(height=round(rise + z_c, 4), pitch=pitch, fov=fov)
    scales = [ppm] * len(tracks)
    objects: list[Lifted] = []
    if oblique:
        for k, (tr, m) in enumerate(zip(tracks, motions)):
            shape, size, half_h = specs[k]
            for _ in range(4):
                point = pixel_to_plane(m.p0, half_h, cam, width, height)
                if not np.all(np.isfinite(point)):
                    break
                depth = float(project(point, cam, width, height)[1])
                scales[k] = f / depth
                size, half_h = spec(tr, shape, 1.0 / scales[k])
            specs[k] = (shape, size, half_h)
    for tr, m, (shape, size, half_h), ppm_k in zip(tracks, motions, specs, scales):
        dt = 0.05
        p = pixel_to_plane(np.stack([m.p0, m.p0 + m.v0 * dt]), half_h, cam, width, height)
        vel = (p[1] - p[0]) / dt
        quat = [1.0, 0.0, 0.0, 0.0]
        if shape == "box" and not (oblique and standing(tr)):  # silhouette angle ccw from above = yaw
            quat = axis_angle_quat((0.0, 0.0, 1.0), math.radians(tr.angle)).tolist()
        decel = deceleration(m)
        mu = float(np.clip(decel / ppm_k / G, 0.0, 1.0)) if m.n >= 5 else 0.2
        lifted = Lifted(shape, size, [float(p[0][0]), float(p[0][1]), float(half_h)], quat,
                        [float(vel[0]), float(vel[1]), 0.0], mu, _mass(shape, size), "plane")
        if shape == "sphere":  # a ball on a table rolls, slowed by rolling resistance, not sliding friction
            lifted.angular_velocity = rolling_spin(np.array([0.0, 0.0, 1.0]),
                                                   np.asarray(lifted.linear_velocity), size["radius"]).tolist()
            lifted.rolling_friction = rolling_resistance(decel / ppm_k if m.n >= 5 else 0.0, size["radius"])
            lifted.friction = ROLLING_GRIP
            if fps is not None and _roll_down_ramp(lifted, tr, m, half_h, ppm_k, cam, width, height, fps):
                notes.append(f"object {tr.label}: speeds up along a line on the ground: rolls down a ramp of "
                             f"{lifted.notes[-1]}")
        objects.append(lifted)
    return cam, objects, notes


def _roll_down_ramp(lifted: Lifted, tr: Track, m: Motion, half_h: float, ppm: float, cam: Camera, width: int,
                    height: int, fps: float) -> bool:
    """Put a ball lifted on the floor (:func:`lift_top`) on the ramp its ground-plane speed-up shows
    (:func:`ground_slope`, :func:`ramp_on_ground`), in place; False (unchanged) without one."""
    w = whole_frames(tr)
    pts = pixel_to_plane(w.centre, half_h, cam, width, height)
    slope = ground_slope(w, pts, fps, fit_tolerance(w) / ppm)
    if slope is None:
        return False
    d, a, n = slope
    box, normal, theta = ramp_on_ground(pts, d, a, n, "sphere", half_h, w.diameter / ppm)
    # the plane of the centre: the ramp's top face (the box centre + half its thickness) + half_h
    centre_plane = np.asarray(box["position"], dtype=np.float64) + normal * (0.5 * box["size"]["height"] + half_h)
    dt = 0.05
    p = pixel_to_surface(np.stack([m.p0, m.p0 + m.v0 * dt]), centre_plane, normal, cam, width, height)
    if not np.all(np.isfinite(p)):
        return False
    vel = (p[1] - p[0]) / dt
    lifted.position = [float(v) for v in p[0]]
    lifted.linear_velocity = [float(v) for v in vel]
    lifted.angular_velocity = rolling_spin(normal, vel, lifted.size["radius"]).tolist()
    lifted.rolling_friction = 0.0
    lifted.ramp, lifted.kind = box, "ramp"
    lifted.notes.append(f"{math.degrees(theta):.1f} deg ({a:.2f} m/s^2 over {n} frames)")
    return True


# --------------------------------------------------------------------------------- proposals
def shape_candidates(track: Track, view: View) -> list[str]:
    """Shapes to try for a silhouette, most likely first.

    * A round silhouette (:func:`pipeline.image_tracks.round_silhouette`: an ellipse, not
      elongated) is a sphere or a disc seen along its axis: side view, sphere first; top view, a
      puck, cylinder first.
    * Any other silhouette is not a sphere (a sphere's outline is an ellipse from every view): a
      box first where a polygon of few corners fits it better than an ellipse
      (:attr:`Track.polygon` > :attr:`Track.ellipse`: corners), else a cylinder first (straight
      sides and elliptical ends). In a side view the cylinder stands on its end (its outline a
      rectangle, :func:`lift_side`). In a top view an elongated silhouette is a box only:
      perception writes a cylinder there as a puck, whose outline is a disc.
    * Without an ellipse fit (every frame cut by the border) the rotated box's fill decides:
      below :data:`CIRCLE_FILL` round, above :data:`BOX_FILL` a box, in between both.
    * A silhouette narrower than :data:`pipeline.image_tracks.SMALL_SILHOUETTE` does not tell
      (rasterisation alone crosses the tests): the list above comes first, then every other shape,
      so the re-simulation decides (:func:`pipeline.search.simplest_within` on ties).
    """
    cands = _outline_candidates(track, view)
    if track.diameter < SMALL_SILHOUETTE:
        cands += [s for s in (["sphere", "cylinder", "box"] if view == "side" else ["cylinder", "sphere", "box"])
                  if s not in cands]
    return cands


def _outline_candidates(track: Track, view: View) -> list[str]:
    """:func:`shape_candidates` as the outline alone reads it, whatever its size."""
    round_ = ["sphere", "cylinder"] if view == "side" else ["cylinder", "sphere"]
    if math.isfinite(track.ellipse):
        if round_silhouette(track):
            return round_
        if view == "top" and track.elongation >= ELONGATED:
            return ["box"]
        return ["box", "cylinder"] if track.polygon > track.ellipse else ["cylinder", "box"]
    if track.elongation >= ELONGATED:
        return ["box"]
    if track.fill < CIRCLE_FILL:
        return round_
    if track.fill > BOX_FILL:
        return ["box"]
    return round_[:1] + ["box"] + round_[1:] if track.fill < 0.5 * (CIRCLE_FILL + BOX_FILL) \
        else ["box"] + round_


def silhouette_rank(track: Track, shape: str, view: View) -> int:
    """How far down the silhouette's list of shapes (:func:`shape_candidates`) ``shape`` is: 0 for
    its first choice. A round silhouette is a ball's or a disc's seen along its axis, which no
    outline tells apart, so there sphere and cylinder both rank 0; a shape not on the list (an
    upright cylinder tried for a standing silhouette, :func:`_hypotheses`) ranks after it.
    A silhouette narrower than :data:`pipeline.image_tracks.SMALL_SILHOUETTE` ranks every shape 0.
    Used to break ties the re-simulation cannot (:func:`pipeline.search.simplest_within`)."""
    cands = shape_candidates(track, view)
    if shape in ("sphere", "cylinder") and round_silhouette(track) or track.diameter < SMALL_SILHOUETTE:
        return 0
    return cands.index(shape) if shape in cands else len(cands)


def deceleration(m: Motion) -> float:
    """Deceleration along the velocity at ``t = 0``, ``-a . v / |v|`` in px/s^2 (negative: speeding
    up); 0.0 for a motion at rest (``|v| <= 1e-6`` px/s). The quantity :func:`lift_top` turns into a
    slider's friction and :func:`rolling_tracks` into a rolling test."""
    nv = float(np.linalg.norm(m.v0))
    return -float(m.a @ m.v0) / nv if nv > 1e-6 else 0.0


def rolling_tracks(tracks: list[Track], motions: list[Motion]) -> frozenset[int]:
    """Labels of the tracks whose motion says *ball*, not *puck*, where the silhouette cannot.

    A round silhouette (:func:`pipeline.image_tracks.round_silhouette`) on the floor seen from
    above is a ball or a disc seen along its axis (:func:`shape_candidates`), and the outline
    cannot tell them apart. Their motion can: a puck slides on its face and dry friction slows
    it by ``mu g`` with ``mu >=`` :data:`MU_SLIDE_MIN`, while a ball rolls and rolling resistance
    slows it by a few hundredths of g or less (:data:`ROLLING_RESISTANCE_MAX`). A round track that
    travels at least :data:`ROLL_MIN_TRAVEL` diameters over a motion fit of :data:`ROLL_MIN_FRAMES`
    frames or more and decelerates along its velocity by less than
    ``MU_SLIDE_MIN * g / SIZE_PRIOR_DOUBT`` at the top-down proposal's scale (:func:`lift_top`: the
    median diameter is :data:`SIZE_PRIOR`; a puck 8x larger than the prior would read 8x too slow)
    rolls. An air-table puck keeps its speed too: it is called a ball here.

    Args:
        tracks: the clip's tracks; motions: their :func:`pipeline.image_tracks.initial_motion`
            (px, px/s, px/s^2), in the same order.
    Returns:
        the labels (:attr:`Track.label`) of the rolling tracks.
    """
    if not tracks:
        return frozenset()
    ppm = float(np.median([t.diameter for t in tracks])) / SIZE_PRIOR     # px per m
    out = set()
    for t, m in zip(tracks, motions):
        w = whole_frames(t)
        if not round_silhouette(t) or m.n < ROLL_MIN_FRAMES or len(w.centre) < 2:
            continue
        if float(np.linalg.norm(w.centre[-1] - w.centre[0])) < ROLL_MIN_TRAVEL * t.diameter:
            continue
        if deceleration(m) / ppm < MU_SLIDE_MIN * G / SIZE_PRIOR_DOUBT:
            out.add(t.label)
    return frozenset(out)


def _hypotheses(tracks: list[Track], view: View, oblique: bool = False,
                falling: frozenset[int] = frozenset(), rolling: frozenset[int] = frozenset()) -> list[dict[int, str]]:
    """Shape assignments to try: the j-th proposal gives every track its j-th candidate (or its
    last one), so a clip yields at most 3 proposals whatever the number of objects. Seen
    obliquely (``view`` top), a silhouette too elongated for a puck that stands
    (:func:`standing`) may be an upright cylinder as tall as it (:func:`upright_height`): a tall
    can's silhouette is as elongated as a bar's. Seen from the side, a round silhouette of a
    track in ``falling`` (labels whose motion is a fall) is a sphere only: a disc is round from the
    side only while its axis stays on the line of sight, which nothing holds in flight (the
    generic-viewpoint assumption); a disc end-on is kept for a round object that rolls. Seen from
    above (``view`` top), a round silhouette of a track in ``rolling`` (:func:`rolling_tracks`:
    it keeps its speed as no sliding puck can) is a sphere only."""
    cands = {t.label: shape_candidates(t, view) for t in tracks}
    if oblique:
        cands = {t.label: c + ["cylinder"] if "cylinder" not in c and standing(t) else c
                 for t, c in zip(tracks, cands.values())}
    drop = falling if view == "side" else rolling
    cands = {t.label: [x for x in c if x != "cylinder"] if t.label in drop and "sphere" in c else c
             for t, c in zip(tracks, cands.values())}
    n = max(len(c) for c in cands.values())
    out = []
    for j in range(n):
        h = {k: c[min(j, len(c) - 1)] for k, c in cands.items()}
        if h not in out:
            out.append(h)
    return out


@dataclass
class Proposals:
    """What perception found and the scenes it proposes.

    Attributes:
        scenes: proposals, most plausible first.
        labels: a short name per proposal (e.g. ``side: sphere``).
        view: ``"side"`` or ``"top"``.
        tracks, motions: per object.
        notes: how each quantity was obtained (for metrics.json).
        silhouette_ranks: per scene, :func:`silhouette_rank` summed over its objects (0: every
            shape is its silhouette's first choice).
    """

    scenes: list[Scene]
    labels: list[str]
    view: View
    tracks: list[Track]
    motions: list[Motion]
    notes: list[str]
    silhouette_ranks: list[int] = field(default_factory=list)


def propose(seg: np.ndarray, flow: np.ndarray | None, fps: float, duration: float,
            max_objects: int = 4, still: bool = False, fov: float = FOV_PRIOR) -> Proposals:
    """Scene-language proposals for a labelled clip (see module docstring).

    Args:
        seg: ``(T, H, W)`` int8 object ids of the observed clip, -1 background.
        flow: ``(T-1, H, W, 2)`` float32 observed flow, px/frame, or None.
        fps: frame rate of ``seg``, frames per second (the scene's ``fps``; an int).
        duration: scene duration, s.
        max_objects: keep at most this many tracks (largest first).
        still: the masks come from the segmenter, which sees objects at rest too: every track
            seen often enough is an object, moving or not (:func:`still_tracks`);
            otherwise only tracks that move (:func:`object_tracks`: background-subtraction masks
            also hold shadows and flicker).
        fov: vertical field of view of the image ``seg`` covers, deg (:func:`crop_fov` of the
            main job's crop; the prior for a whole frame).
    Returns:
        :class:`Proposals` with at least one valid scene.
    Raises:
        PerceptionError: no (moving) object in the clip.
    """
    T, H, W = np.shape(seg)
    if still:
        tracks = still_tracks(seg, max_objects)
    else:
        tracks = object_tracks(seg, flow, max_objects)
    if not tracks:
        raise PerceptionError("no object found (segmenter)" if still else
                              "no moving object found (background subtraction + flow)")
    # motion is read from the frames where the whole silhouette is in view (whole_frames): a
    # part cut by the border biases the centroid
    whole = [whole_frames(t) for t in tracks]
    motions = [initial_motion(t, fps) for t in whole]
    gravity = [gravity_evidence(t, fps) for t in whole]
    view, shows = estimate_view(tracks, gravity)
    # a track that shows gravity somewhere takes its acceleration from there (the start of the
    # window may be a release by hand), and its state at t = 0 from its first stretch with
    # that acceleration (initial_state_given); the acceleration's evidence is the gravity
    # window's frames, even when only a few frames precede the first bounce. In a fall the
    # simulator's only acceleration is gravity, straight down: a sideways curvature fitted to a
    # noisy track would bend the horizontal velocity read at t = 0. A fall's curvature is then
    # read from all its flight arcs at once (flight_gravity: the window is the steepest of many,
    # biased upward); a track whose arcs together do not curve like a fall is no fall. Any other
    # gravity is a slope's: along the path, from the whole run down (slope_acceleration).
    side_motions = []
    for t, m, g, ok in zip(whole, motions, gravity, shows):
        if ok:
            if _side_motion_kind(t, g) == "fall":
                flight = flight_gravity(t, fps)
                g = flight if flight is not None and flight.n > g.n else replace(g, a=np.array([0.0, g.a[1]]))
            else:   # on a straight slope the acceleration is along the path, over the whole run down
                d = slope_direction(t, g)
                along, sd, n = slope_acceleration(t, d, g, fps)
                if along > 0:
                    g = replace(g, a=along * d, a_sd=sd * float(abs(d[1])), n=n)
            m = replace(initial_state_given(t, fps, g.a), n=g.n, a_sd=g.a_sd)
        side_motions.append(m)
    falling = frozenset(t.label for t, m, ok in zip(tracks, side_motions, shows) if ok and _side_motion_kind(t, m) == "fall")
    falls = bool(falling)
    rolling = rolling_tracks(tracks, motions)
    # a clear fall settles it; a speed-up along a line may also be perspective (an object
    # rolling towards an oblique camera), so the top-down reading is tried as well
    views: list[str] = ["side"] if falls else (["side", "top", "oblique"] if view == "side" else ["top", "oblique"])
    scenes, labels, ranks = [], [], []
    notes = [f"view: {view} (gravity {'seen' if view == 'side' else 'not seen'} in the tracks)"
             + ("" if len(views) == 1 else "; top-down proposals tried too")]
    spin_noted: set[int] = set()   # one note per spinning object (from the first proposal that spins it)
    for v in views:
        first = True
        for shape_of in _hypotheses(tracks, "side" if v == "side" else "top", oblique=v == "oblique", falling=falling,
                                    rolling=rolling):
            if v == "side":
                lifts = [lift_side(tracks, side_motions, W, H, fps, shape_of, fov)]
            else:   # on the floor, and where a ball speeds up along the ground, also down a ramp
                pitch = TOP_DOWN_PITCH if v == "top" else OBLIQUE_PITCH
                lifts = [lift_top(tracks, motions, W, H, shape_of, pitch, fov)]
                on_ramp = lift_top(tracks, motions, W, H, shape_of, pitch, fov, fps=fps)
                if any(o.ramp is not None for o in on_ramp[1]):
                    lifts.append(on_ramp)
            for cam, objs, n in lifts:
                if first:
                    notes += n
                    first = False
                elif n is not lifts[0][2]:
                    notes += [x for x in n if "rolls down a ramp" in x and x not in notes]
                more = _proposal(_to_scene(cam, objs, fps, duration), objs, tracks, v, shape_of, spin_noted, notes)
                scenes += more[0]
                labels += more[1]
                ranks += more[2]
    motions = side_motions if view == "side" else motions
    return Proposals(scenes, labels, view, tracks, motions, notes, ranks)


def _proposal(scene: Scene, objs: list[Lifted], tracks: list[Track], v: str, shape_of: dict[int, str],
              spin_noted: set[int], notes: list[str]) -> tuple[list[Scene], list[str], list[int]]:
    """The proposal(s) of one lift in view ``v``: its scene with the spin its first bounces show
    (:func:`bounce_spin`; one note per object, into ``notes``), its label and silhouette rank, and
    for several objects seen from above also with elastic-ish contacts."""
    for i, o in enumerate(objs):
        if o.after_bounce is not None:
            spun = bounce_spin(scene, i, o.after_bounce)
            if spun is not None:
                scene = spun[0]
                if tracks[i].label not in spin_noted:
                    notes.append(f"object {tracks[i].label}: its sideways speed changes at its first "
                                 f"bounce: spin {spun[1]:.1f} rad/s about the line of sight")
                    spin_noted.add(tracks[i].label)
    label = f"{v}: " + ", ".join(o.shape + (" on a ramp" if o.ramp else "") for o in objs)
    rank = sum(silhouette_rank(t, shape_of[t.label], "side" if v == "side" else "top") for t in tracks)
    scenes, labels, ranks = [scene], [label], [rank]
    if v != "side" and len(objs) > 1 and not scene.effects:
        # objects that may collide: also try elastic-ish contacts (MuJoCo's default
        # contact is critically damped, e ~ 0; air-table pucks, billiard balls ~ 0.9)
        scenes.append(scene.replace(effects=[{"effect": "restitution",
                                              "parameters": {"e": COLLISION_RESTITUTION}}]))
        labels.append(label + f", restitution {COLLISION_RESTITUTION}")
        ranks.append(rank)
    return scenes, labels, ranks


AT_REST_PITCH = 45.0
"""deg: a camera pitched less than this sees objects at rest from the side (a disc is a sphere
first), more from above (a disc is a puck first): :func:`shape_candidates`."""


def place_at_rest(scene: Scene, seg: np.ndarray, moving, width: int, height: int) -> tuple[Scene, list[str]]:
    """Add the observed objects at rest to a scene fitted to the movers, seen by its camera.

    Each object whose ``moving`` flag is False becomes a scene object at rest on the floor: the
    viewing ray of its silhouette's median centroid meets the horizontal plane at the object's
    centre height (the radius, half the height; found by fixed-point iteration from the floor,
    since the size depends on the depth), its size is its median image diameter (the short side
    of the rotated box, :class:`pipeline.image_tracks.Track`) times depth over focal length
    (pinhole: size = px * Z / f), its shape the first of :func:`shape_candidates` for the view
    the camera's pitch gives (an elongated box as long as its silhouette, turned with it:
    :func:`_box_on_floor`), its mass from :data:`DENSITY`, its velocity 0. An object whose
    ray does not meet the floor (above the horizon) is left out, with a note.

    Args:
        scene: the scene fitted to the movers (its camera is used as it is).
        seg: ``(T, H, W)`` int8 observed object ids, -1 background, at ``width x height`` px.
        moving: per object id of ``seg``, whether it moves (``Observation.moving``).
        width, height: the working image size, px.
    Returns:
        ``(scene, notes)``: the scene with the objects at rest appended (the same scene when
        there is none to add), and one note per object.
    """
    cam = scene.camera
    f = float(intrinsics(cam.fov, width, height)[1, 1])
    view: View = "side" if cam.pitch < AT_REST_PITCH else "top"
    added, notes = [], []
    for k, m in enumerate(moving or ()):
        if m:
            continue
        tracks = find_tracks(np.where(seg == k, 0, -1).astype(np.int8), None, min_frames=1)
        if not tracks:
            continue
        tr = tracks[0]
        uv = np.median(tr.centre, axis=0)
        shape = shape_candidates(tr, view)[0]
        z, size, yaw = 0.0, None, 0.0
        for _ in range(4):
            point = pixel_to_plane(uv, z, cam, width, height)
            if not np.all(np.isfinite(point)):
                break
            depth = float(np.linalg.norm(point - np.asarray(cam.eye, dtype=np.float64)))
            d = tr.diameter * depth / f                       # m, the silhouette's short side
            size = ({"radius": d / 2} if shape == "sphere" else
                    {"radius": d / 2, "height": d / 2} if shape == "cylinder" else
                    {"width": d, "depth": d, "height": d})
            if shape == "box" and tr.elongation >= ELONGATED:   # a bar, not a cube: its length
                size["width"], yaw = _box_on_floor(tr, uv, z, cam, width, height, view, tr.size[0] * depth / f)
            z = d / 2 if shape == "sphere" else 0.5 * size["height"]
        if size is None or not np.all(np.isfinite(point)):
            notes.append(f"object {k} at rest: its ray misses the floor (above the horizon), left out")
            continue
        obj = {"shape": shape, "size": size, "mass": _mass(shape, size),
               "position": [float(point[0]), float(point[1]), float(z)]}
        if yaw:
            obj["orientation"] = axis_angle_quat((0.0, 0.0, 1.0), yaw).tolist()
        added.append(obj)
        notes.append(f"object {k} at rest: {shape} of {d:.3f} m on the floor at "
                     f"({point[0]:.2f}, {point[1]:.2f}) m")
    if not added:
        return scene, notes
    return scene.replace(objects=[o.model_dump() for o in scene.objects] + added), notes


def _box_on_floor(tr: Track, uv: np.ndarray, z: float, cam: Camera, width: int, height: int, view: View,
                  long_m: float) -> tuple[float, float]:
    """Length (m) and yaw (rad) of an elongated box at rest (:data:`ELONGATED`; a squarer
    silhouette's long side holds as much of the box's side faces as of its top, so a cube keeps
    the short side for every edge) whose silhouette is ``tr`` (median centroid ``uv``, px): its
    long side lies along the silhouette's long side. Seen from above
    (``view`` ``top``), the long side's two ends are cast onto the plane at height ``z`` (m)
    through ``cam`` and give both; seen from the side, the depth of two points of one image row
    is ill-conditioned, so the box lies along x (yaw 0) with the long side's length at the
    centroid's depth, ``long_m``. A length below ``long_m / 2`` or above ``2 long_m`` (a ray
    nearly parallel to the floor) falls back to ``long_m``, yaw 0."""
    if view != "top":
        return long_m, 0.0
    a = math.radians(tr.angle)                      # counter-clockwise from +u towards -v
    half = 0.5 * tr.size[0] * np.array([math.cos(a), -math.sin(a)])
    ends = pixel_to_plane(np.stack([uv - half, uv + half]), z, cam, width, height)
    if not np.all(np.isfinite(ends)):
        return long_m, 0.0
    dx, dy = float(ends[1][0] - ends[0][0]), float(ends[1][1] - ends[0][1])
    length = math.hypot(dx, dy)
    if not 0.5 * long_m <= length <= 2.0 * long_m:
        return long_m, 0.0
    return length, math.atan2(dy, dx)


def _to_scene(cam: Camera, objs: list[Lifted], fps: float, duration: float) -> Scene:
    objects, static, effects = [], [], []
    for o in objs:
        objects.append({"shape": o.shape, "size": o.size, "mass": o.mass, "position": o.position,
                        "orientation": o.orientation, "linear_velocity": o.linear_velocity,
                        "angular_velocity": o.angular_velocity,
                        "material": {"sliding_friction": o.friction, "rolling_friction": o.rolling_friction}})
        if o.ramp is not None:
            static.append(o.ramp)
        if o.bumper is not None:
            static.append(o.bumper)
    es = [o.restitution for o in objs if o.restitution is not None]
    if es:
        effects.append({"effect": "restitution", "parameters": {"e": float(np.median(es))}})
    data = {"fps": int(round(fps)), "duration": duration, "camera": cam.model_dump(exclude_none=True),
            "objects": objects, "effects": effects}
    if static:
        data["static"] = static
    return Scene.from_dict(data, source="<perception>")
