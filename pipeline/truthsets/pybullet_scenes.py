"""Truth clips simulated and rendered by PyBullet: the independent engine.

Nothing of the MuJoCo path is used here (no MJCF, no ``pipeline.simulate``, no
``pipeline.render``): Bullet's rigid-body solver moves the objects and PyBullet's
TinyRenderer (``p.getCameraImage(..., renderer=ER_TINY_RENDERER)``) draws the RGB frames and
the segmentation buffer (``objectUniqueId`` per pixel), which becomes the truth masks (floor
and sky -1, object ``k`` = index ``k`` of the scenario). Shared with MuJoCo are only the
engine-neutral scenario (:mod:`pipeline.truthsets.scenario`) and the camera conventions
(:mod:`pipeline.camera`), which define intrinsics and extrinsics.

Engine specifics (PyBullet 3.2.7, ``DIRECT`` mode, one physics client per clip):

* timestep ``1 / (fps * k)`` with ``k = round(240 / fps)`` (1/240 s at 30 fps), states read
  after every ``k`` steps, so frame ``t`` is the state at ``t / fps``;
* Bullet combines the friction of two bodies as their product and rolling friction as
  ``rolling_a * friction_b + rolling_b * friction_a``: the floor has friction 1 and rolling
  friction 0, so an object's coefficients are its coefficients against the floor; restitution
  also multiplies (floor 1: an object's ``restitution`` is its bounce on the floor);
  linear and angular damping are 0 (PyBullet's default 0.04 would slow every object);
* the floor is a collision plane with a 40 m x 40 m textured quad (texture repeated every
  ``look.floor_tile`` m): ``checker``, ``noise``, ``stripes`` are generated images
  (:func:`pipeline.truthsets.scenario.floor_image`), ``flat`` a plain colour;
* the stored intrinsics carry TinyRenderer's half-pixel offset (:data:`TINY_RENDERER_SHIFT`);
* one light (``lightDirection`` toward the light, TinyRenderer's shadow map when
  ``look.shadows``); objects are plain-coloured, or wear a two-tone checker texture.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import cv2
import numpy as np
import pybullet

from pipeline.camera import camera_pose, extrinsics, intrinsics
from pipeline.truthsets.common import Accept, Rollout, TOUCH_DISTANCE
from pipeline.truthsets.scenario import EngineLimits, ObjectSpec, Scenario, floor_image

NAME = "pybullet"
SALT = 2
"""First entry of every random seed of this engine's clips."""
LIMITS = EngineLimits(pitch=(15.0, 89.0), floor_kinds={"checker": 0.35, "noise": 0.3, "stripes": 0.2, "flat": 0.15},
                      p_shadows=0.5)
BASE_RATE = 240.0
"""Hz: physics steps per second aimed at (PyBullet's default timestep 1/240 s)."""
FLOOR_HALF = 20.0
"""m: half side of the drawn floor quad."""
NEAR, FAR = 0.02, 100.0
"""m: clipping planes of the rendering camera."""
TINY_RENDERER_SHIFT = (0.5, -0.5)
"""px: where TinyRenderer draws a point, minus where ``pipeline.camera`` projects it (pixel
centres at +0.5): it samples pixels at integer coordinates and flips rows, so its images sit
half a pixel right and up. Added to the principal point of the stored intrinsics, so that
they project onto the masks as drawn (measured: mask centroids of a sphere were off by
(+0.53, -0.52) px before, ``tests/test_truthsets.py`` checks the match)."""


def _xyzw(q: np.ndarray) -> list[float]:
    w, x, y, z = (float(c) for c in q / np.linalg.norm(q))
    return [x, y, z, w]


def _wxyz(q) -> list[float]:
    x, y, z, w = q
    return [w, x, y, z]


def _png(path: Path, rgb: np.ndarray) -> str:
    cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    return str(path)


def _checker(rgb: tuple[float, float, float], size: int = 64, squares: int = 4) -> np.ndarray:
    """(size, size, 3) uint8 checker of ``rgb`` and a darker tone (as the MuJoCo objects)."""
    y, x = np.mgrid[0:size, 0:size] * squares // size
    dark = (x + y) % 2 == 1
    c = np.asarray(rgb, dtype=np.float64)
    img = np.where(dark[..., None], c * 0.55, c)
    return np.clip(np.round(img * 255), 0, 255).astype(np.uint8)


class _World:
    """One PyBullet physics client holding a scenario's floor and objects."""

    def __init__(self, sc: Scenario, tmp: Path) -> None:
        p = self.p = pybullet
        self.sc = sc
        self.cid = p.connect(p.DIRECT)
        cid = self.cid
        self.substeps = max(1, int(round(BASE_RATE / sc.fps)))
        p.setPhysicsEngineParameter(fixedTimeStep=1.0 / (sc.fps * self.substeps), numSubSteps=0,
                                    deterministicOverlappingPairs=1, physicsClientId=cid)
        p.setGravity(0, 0, -9.81, physicsClientId=cid)
        self.floor = self._floor(tmp)
        self.bodies = [self._body(o, k, tmp) for k, o in enumerate(sc.objects)]

    def _floor(self, tmp: Path) -> int:
        p, cid, look = self.p, self.cid, self.sc.look
        L, rep = FLOOR_HALF, 2 * FLOOR_HALF / look.floor_tile
        vis = p.createVisualShape(p.GEOM_MESH, vertices=[[-L, -L, 0], [L, -L, 0], [L, L, 0], [-L, L, 0]],
                                  indices=[0, 1, 2, 0, 2, 3], uvs=[[0, 0], [rep, 0], [rep, rep], [0, rep]],
                                  normals=[[0, 0, 1]] * 4, physicsClientId=cid)
        col = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=cid)
        floor = p.createMultiBody(0, col, vis, [0, 0, 0], physicsClientId=cid)
        p.changeDynamics(floor, -1, lateralFriction=1.0, rollingFriction=0.0, spinningFriction=0.0, restitution=1.0,
                         physicsClientId=cid)
        if look.floor_kind == "flat":
            p.changeVisualShape(floor, -1, rgbaColor=[*look.floor_rgb1, 1.0], physicsClientId=cid)
        else:
            tex = p.loadTexture(_png(tmp / "floor.png", floor_image(look)), physicsClientId=cid)
            p.changeVisualShape(floor, -1, textureUniqueId=tex, rgbaColor=[1, 1, 1, 1], physicsClientId=cid)
        return floor

    def _body(self, o: ObjectSpec, k: int, tmp: Path) -> int:
        p, cid, s = self.p, self.cid, o.size
        if o.shape == "sphere":
            col = p.createCollisionShape(p.GEOM_SPHERE, radius=s["radius"], physicsClientId=cid)
            vis = p.createVisualShape(p.GEOM_SPHERE, radius=s["radius"], rgbaColor=[*o.rgb, 1], physicsClientId=cid)
        elif o.shape == "cylinder":
            col = p.createCollisionShape(p.GEOM_CYLINDER, radius=s["radius"], height=s["height"], physicsClientId=cid)
            vis = p.createVisualShape(p.GEOM_CYLINDER, radius=s["radius"], length=s["height"], rgbaColor=[*o.rgb, 1],
                                      physicsClientId=cid)
        else:
            half = [s["width"] / 2, s["depth"] / 2, s["height"] / 2]
            col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=cid)
            vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=[*o.rgb, 1], physicsClientId=cid)
        body = p.createMultiBody(o.mass, col, vis, o.position.tolist(), _xyzw(o.quat), physicsClientId=cid)
        p.changeDynamics(body, -1, lateralFriction=o.friction, rollingFriction=o.rolling_friction,
                         spinningFriction=0.0, restitution=o.restitution, linearDamping=0.0, angularDamping=0.0,
                         physicsClientId=cid)
        p.resetBaseVelocity(body, o.linear_velocity.tolist(), o.angular_velocity.tolist(), physicsClientId=cid)
        if self.sc.look.object_checker:
            tex = p.loadTexture(_png(tmp / f"object_{k}.png", _checker(o.rgb)), physicsClientId=cid)
            p.changeVisualShape(body, -1, textureUniqueId=tex, rgbaColor=[1, 1, 1, 1], physicsClientId=cid)
        return body

    def simulate(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``pos (T, n, 3)``, ``quat (T, n, 4)`` (w, x, y, z) and ``touch (T, n, n)`` per frame."""
        p, cid, T, n = self.p, self.cid, self.sc.n_frames, len(self.bodies)
        pos, quat = np.zeros((T, n, 3)), np.zeros((T, n, 4))
        touch = np.zeros((T, n, n), dtype=bool)
        for t in range(T):
            if t:
                for _ in range(self.substeps):
                    p.stepSimulation(physicsClientId=cid)
            for k, b in enumerate(self.bodies):
                xyz, q = p.getBasePositionAndOrientation(b, physicsClientId=cid)
                pos[t, k], quat[t, k] = xyz, _wxyz(q)
            for a in range(n):
                for b in range(a + 1, n):
                    close = p.getClosestPoints(self.bodies[a], self.bodies[b], TOUCH_DISTANCE, physicsClientId=cid)
                    touch[t, a, b] = touch[t, b, a] = bool(close)
        return pos, quat, touch

    def render(self, pos: np.ndarray, quat: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """RGB ``(T, H, W, 3) uint8`` and seg ``(T, H, W) int8`` of the poses, with K (3, 3)
        and world-to-camera E (4, 4)."""
        p, cid, sc = self.p, self.cid, self.sc
        W, H, T = sc.width, sc.height, pos.shape[0]
        cam = sc.camera.camera()
        pose = camera_pose(cam)
        view = p.computeViewMatrix(pose.eye.tolist(), (pose.eye + pose.forward).tolist(), pose.up.tolist(),
                                   physicsClientId=cid)
        proj = p.computeProjectionMatrixFOV(cam.fov, W / H, NEAR, FAR, physicsClientId=cid)
        look = sc.look
        light = {"lightDirection": (-look.light_dir * 10.0).tolist(), "lightColor": [1.0, 1.0, 1.0],
                 "lightDistance": 10.0, "shadow": int(look.shadows),
                 "lightAmbientCoeff": 0.3 + look.headlight_ambient, "lightDiffuseCoeff": look.light_diffuse,
                 "lightSpecularCoeff": 0.5 * look.light_specular}
        lut = np.full(max(self.floor, *self.bodies) + 2, -1, dtype=np.int8)   # uid + 1 -> index
        lut[np.asarray(self.bodies) + 1] = np.arange(len(self.bodies))
        rgb = np.empty((T, H, W, 3), dtype=np.uint8)
        seg = np.empty((T, H, W), dtype=np.int8)
        for t in range(T):
            for k, b in enumerate(self.bodies):
                p.resetBasePositionAndOrientation(b, pos[t, k].tolist(), _xyzw(quat[t, k]), physicsClientId=cid)
            _, _, img, _, ids = p.getCameraImage(W, H, view, proj, renderer=p.ER_TINY_RENDERER,
                                                 physicsClientId=cid, **light)
            rgb[t] = np.reshape(np.asarray(img, dtype=np.uint8), (H, W, 4))[..., :3]
            ids = np.reshape(np.asarray(ids, dtype=np.int64), (H, W))
            seg[t] = lut[np.clip(ids, -1, lut.size - 2) + 1]
        R, tr = extrinsics(cam)
        E = np.eye(4)
        E[:3, :3], E[:3, 3] = R, tr
        K = intrinsics(cam.fov, W, H)
        K[0, 2] += TINY_RENDERER_SHIFT[0]
        K[1, 2] += TINY_RENDERER_SHIFT[1]
        return rgb, seg, K, E

    def close(self) -> None:
        self.p.disconnect(physicsClientId=self.cid)


def run(sc: Scenario, accept: Accept | None = None) -> Rollout | None:
    """Simulate a scenario with Bullet; if ``accept(pos, quat, touch)`` (or no ``accept``),
    render it with TinyRenderer.

    Returns:
        the :class:`~pipeline.truthsets.common.Rollout`, or None when not accepted.
    Raises:
        RuntimeError: the simulation produced non-finite states.
    """
    with tempfile.TemporaryDirectory(prefix="truthsets-pybullet-") as tmp:
        world = _World(sc, Path(tmp))
        try:
            pos, quat, touch = world.simulate()
            if not (np.isfinite(pos).all() and np.isfinite(quat).all()):
                raise RuntimeError(f"pybullet: {sc.category}: the simulation diverged (non-finite states)")
            if accept is not None and not accept(pos, quat, touch):
                return None
            rgb, seg, K, E = world.render(pos, quat)
        finally:
            world.close()
    return Rollout(rgb=rgb, seg=seg, pos=pos, quat=quat, touch=touch, intrinsics=K, extrinsics=E)

