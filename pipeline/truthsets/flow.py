"""Exact ground-truth forward optical flow of a truth clip, by ray casting the known primitives.

Neither engine's renderer saves flow for the truth sets (PyBullet's TinyRenderer has none), but
every clip folder (:mod:`pipeline.truthsets.common`) holds what defines it exactly: the objects'
primitives (``meta.json`` ``objects[k]``: ``shape``, ``size``), their poses per frame
(``truth.npz`` ``pos``, ``quat``), the static camera (``intrinsics``, ``extrinsics``) and the
renderer's instance mask (``seg``). For a pixel of frame ``t`` owned by object ``k``, the
camera ray through the pixel centre is intersected with object ``k``'s primitive at its pose
``t`` (nearest hit in front of the camera); the hit point, fixed in the body frame, is carried
to the body pose of frame ``t + 1`` and projected: flow = that projection - the pixel centre.
Floor and background pixels (``seg == -1``) have flow 0: the camera and the floor are static.

Conventions:

* Primitives (:class:`pipeline.truthsets.scenario.ObjectSpec`, as both engines build them:
  :func:`pipeline.geometry.geom_size` for MuJoCo, half extents in
  :mod:`pipeline.truthsets.pybullet_scenes`): ``sphere`` ``{radius}``; ``cylinder``
  ``{radius, height}``, axis = body z, ``height`` the full length, capped; ``box``
  ``{width, depth, height}`` = full extents along body x, y, z. Centre = body origin.
* Poses: ``pos (T, n, 3)`` world centre, m; ``quat (T, n, 4)`` (w, x, y, z) body -> world
  (:func:`pipeline.rotation.quat_to_mat`).
* Camera: ``X_cam = E @ [X_world, 1]`` (OpenCV frame: x right, y down, z forward), pixel
  ``(u, v) = (fx X / Z + cx, fy Y / Z + cy)`` with ``K`` as stored (PyBullet's already holds
  TinyRenderer's half-pixel shift).
* Pixel centres: the centre of pixel (column ``x``, row ``y``) is at ``(x + 0.5, y + 0.5)`` in
  K's frame (:data:`PIXEL_CENTRE`), as :mod:`pipeline.camera` states, for both engines.
  Measured on ``data/truthsets/{mujoco,pybullet}/dev`` (24 clips each): silhouettes ray cast
  through pixel centres at +0.5 disagree with the rendered masks on 0.4 % (MuJoCo) and 2.8 %
  (PyBullet) of the mask pixels, against 4.1 % and 5.5 % at +0; of the offsets 0, 0.25, 0.5,
  0.75, 1 px per axis, 0.5 fits best on both axes for both engines. Sphere centres projected
  with K, E sit (0.52, 0.63) px (MuJoCo) and (0.48, 0.54) px (PyBullet) right of and below the
  mean pixel index of their masks (median over ~550 unoccluded frames each), i.e. at the mask
  centroid in +0.5 coordinates (the rest: perspective, the silhouette's centre lies off the
  projected centre).
* Flow ``(u, v)``: u = x to the right, v = y down, px, from frame t to frame t + 1, so that
  pixel ``(x, y)`` of frame t shows the surface point seen at ``(x + u, y + v)`` in frame t+1
  (the point's projection there, whether or not another object hides it in frame t+1).

Accuracy: the flow is exact for the primitives. The renderers draw tessellated surfaces inside
them: MuJoCo's sit within a fraction of a pixel (inside the masks this flow matches MuJoCo's
depth-buffer flow, :func:`pipeline.render.rigid_flow`, to ~0.001 px:
``tests/test_truthset_flow.py``);
PyBullet's TinyRenderer draws spheres ~4 % smaller in radius (mask area ~7.5 % below the
primitive's) and cylinders slightly smaller too (1.9 % of their mask pixels), so on a rolling PyBullet sphere the drawn texture
point under a pixel differs a little from the primitive's: up to ~4 % of that sphere's flow
(median 0.85 px on a sphere moving 21 px per frame; a translating sphere is not affected).
Boxes are exact in both engines. Sizes in ``meta.json`` are rounded to 0.1 mm (< 0.01 px here).
Object pixels whose ray misses are rare (median 0.1 % of the object pixels on the PyBullet dev
clips, none on MuJoCo's: the drawn surfaces lie inside the primitives).

Example::

    flow, valid = truth_flow("data/truthsets/pybullet/dev/clip-00003")
    flow.shape, valid.mean()        # (59, 240, 320, 2), ~1.0
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from pipeline.rotation import quat_to_mat

__all__ = ["truth_flow", "PIXEL_CENTRE", "SHAPES"]

PIXEL_CENTRE = 0.5
"""px: the centre of pixel (column x, row y) is at (x + PIXEL_CENTRE, y + PIXEL_CENTRE) in the
frame of the stored intrinsics (checked empirically, module docstring)."""

SHAPES = {"sphere": ("radius",), "cylinder": ("radius", "height"), "box": ("width", "depth", "height")}
"""Primitive shapes and the ``size`` keys each needs (m, full extents)."""

_FIELDS = ("seg", "pos", "quat", "intrinsics", "extrinsics")
_MIN_DEPTH = 1e-9
"""m: a point this close to the camera plane (or behind it) cannot be projected."""


def truth_flow(folder: str | Path, backward: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth forward (or backward) optical flow of a truth clip (module docstring for the method).

    Args:
        folder: a clip folder holding ``meta.json`` and ``truth.npz``
            (``data/truthsets/<engine>/<split>/clip-00000``).
        backward: give the flow of pair t from frame t+1 back to frame t instead (the same
            construction on the clip played backwards: rays through frame t+1, poses of frame t).
    Returns:
        ``flow (T-1, H, W, 2) float32``: px, forward from frame t to t+1 (backward: from t+1
        to t), ``[..., 0]`` = u (x, right), ``[..., 1]`` = v (y, down); 0 where not valid.
        ``valid (T-1, H, W) bool``: True on floor/background pixels (``seg == -1``, flow 0:
        static camera and floor) and on object pixels whose ray through the pixel centre hits
        the object's primitive (and whose point stays in front of the camera at t+1); False
        on object pixels whose ray misses (mask edge aliasing, rounding of the sizes).
        With T = 1 both are empty (first axis 0).
    Raises:
        FileNotFoundError: ``folder`` is not a folder, or ``meta.json`` / ``truth.npz`` is
            missing (the message names the path).
        ValueError: a file cannot be read, or a field is missing or malformed: ``seg`` not
            (T, H, W) int8, ``pos`` / ``quat`` not (T, n, 3) / (T, n, 4) finite floats with
            n = the number of ``objects`` in meta.json, a zero quaternion, ``intrinsics`` /
            ``extrinsics`` not (3, 3) / (4, 4) finite, ``seg`` holding an id outside -1..n-1,
            an object with an unknown ``shape`` or a missing or non-positive ``size`` entry
            (the message names the file and the field).
    """
    folder = Path(folder)
    objects, seg, pos, quat, K, E = _read(folder)
    if backward:
        flow, valid = _flow(objects, seg[::-1], pos[::-1], quat[::-1], K, E)
        return np.ascontiguousarray(flow[::-1]), np.ascontiguousarray(valid[::-1])
    return _flow(objects, seg, pos, quat, K, E)


def _flow(objects: list[dict], seg: np.ndarray, pos: np.ndarray, quat: np.ndarray, K: np.ndarray,
          E: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`truth_flow` of arrays read by :func:`_read`: from each frame to the next one."""
    T, H, W = seg.shape
    flow = np.zeros((max(T - 1, 0), H, W, 2), dtype=np.float32)
    valid = np.ones((max(T - 1, 0), H, W), dtype=bool)
    if T < 2:
        return flow, valid
    R_cam, t_cam = E[:3, :3], E[:3, 3]
    eye = -R_cam.T @ t_cam                                          # camera centre, world, m
    # world direction of the ray through every pixel centre (not normalised: camera z = 1)
    xs = np.arange(W, dtype=np.float64) + PIXEL_CENTRE
    ys = np.arange(H, dtype=np.float64) + PIXEL_CENTRE
    pix = np.stack(np.broadcast_arrays(xs[None, :], ys[:, None], 1.0), axis=-1)   # (H, W, 3)
    rays = pix @ np.linalg.inv(K).T @ R_cam                          # (H, W, 3) = R^T K^-1 pix
    rot = quat_to_mat(quat)                                          # (T, n, 3, 3) body -> world
    head = seg[:-1]
    for k, obj in enumerate(objects):
        t, y, x = np.nonzero(head == k)
        if t.size == 0:
            continue
        R0 = rot[t, k]                                               # (N, 3, 3)
        # ray in the body frame of pose t: origin R^T (eye - p), direction R^T d
        o = np.einsum("nji,nj->ni", R0, eye - pos[t, k])
        d = np.einsum("nji,nj->ni", R0, rays[y, x])
        s = _hit(obj["shape"], obj["size"], o, d)
        body = o + s[:, None] * d                                    # hit point, body frame (nan: miss)
        world = np.einsum("nij,nj->ni", rot[t + 1, k], body) + pos[t + 1, k]
        cam = world @ R_cam.T + t_cam
        z = cam[:, 2]
        ok = np.isfinite(s) & (z > _MIN_DEPTH)
        zs = np.where(ok, z, 1.0)
        u = K[0, 0] * cam[:, 0] / zs + K[0, 1] * cam[:, 1] / zs + K[0, 2] - (x + PIXEL_CENTRE)
        v = K[1, 1] * cam[:, 1] / zs + K[1, 2] - (y + PIXEL_CENTRE)
        flow[t, y, x, 0] = np.where(ok, u, 0.0)
        flow[t, y, x, 1] = np.where(ok, v, 0.0)
        valid[t, y, x] = ok
    return flow, valid


# ---------------------------------------------------------------------------------------------
# Ray casting (body frame: primitive centred at the origin, axes = body axes)
# ---------------------------------------------------------------------------------------------


def _hit(shape: str, size: dict[str, float], o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Ray parameter ``s (N,)`` of the nearest hit in front of the origin (``o + s d``, s > 0)
    of rays ``o, d (N, 3)`` with a primitive; nan where a ray misses. Each primitive is the
    intersection of slabs / a quadratic region, so the ray's inside interval is ``[near, far]``
    and the hit is ``near`` (``far`` when the origin is inside)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        if shape == "sphere":
            near, far = _quadratic(o, d, size["radius"])
        elif shape == "cylinder":
            near, far = _quadratic(o[:, :2], d[:, :2], size["radius"])
            zn, zf = _slab(o[:, 2], d[:, 2], size["height"] / 2.0)
            near, far = np.maximum(near, zn), np.minimum(far, zf)
        else:
            near = np.full(o.shape[0], -np.inf)
            far = np.full(o.shape[0], np.inf)
            for axis, key in enumerate(("width", "depth", "height")):
                an, af = _slab(o[:, axis], d[:, axis], size[key] / 2.0)
                near, far = np.maximum(near, an), np.minimum(far, af)
        s = np.where(near > 0, near, far)
        return np.where((near <= far) & (s > 0) & np.isfinite(s), s, np.nan)


def _quadratic(o: np.ndarray, d: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray]:
    """Interval of ``s`` where ``|o + s d| <= r`` (o, d (N, m)); empty (near > far) on a miss,
    everything when ``d`` is 0 and ``|o| <= r`` (a ray along a cylinder's axis)."""
    a = np.einsum("ni,ni->n", d, d)
    b = np.einsum("ni,ni->n", o, d)
    c = np.einsum("ni,ni->n", o, o) - r * r
    disc = b * b - a * c
    root = np.sqrt(np.maximum(disc, 0.0))
    par = a <= 1e-300
    safe = np.where(par, 1.0, a)
    near = np.where(disc >= 0, (-b - root) / safe, np.inf)
    far = np.where(disc >= 0, (-b + root) / safe, -np.inf)
    near = np.where(par, np.where(c <= 0, -np.inf, np.inf), near)
    far = np.where(par, np.where(c <= 0, np.inf, -np.inf), far)
    return near, far


def _slab(o: np.ndarray, d: np.ndarray, half: float) -> tuple[np.ndarray, np.ndarray]:
    """Interval of ``s`` where ``|o + s d| <= half`` (scalars per ray, (N,))."""
    par = d == 0
    safe = np.where(par, 1.0, d)
    s1, s2 = (-half - o) / safe, (half - o) / safe
    inside = np.abs(o) <= half
    near = np.where(par, np.where(inside, -np.inf, np.inf), np.minimum(s1, s2))
    far = np.where(par, np.where(inside, np.inf, -np.inf), np.maximum(s1, s2))
    return near, far


# ---------------------------------------------------------------------------------------------
# Reading a clip folder
# ---------------------------------------------------------------------------------------------


def _read(folder: Path) -> tuple[list[dict], np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``objects, seg, pos, quat, K, E`` of a clip folder, checked (errors as :func:`truth_flow`)."""
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: must be a clip folder (meta.json, truth.npz), got no folder")
    meta_path, npz_path = folder / "meta.json", folder / "truth.npz"
    for path in (meta_path, npz_path):
        if not path.is_file():
            raise FileNotFoundError(f"{path}: missing (a clip folder holds meta.json and truth.npz)")
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{meta_path}: cannot be read as JSON ({exc})") from None
    objects = _objects(meta_path, meta)
    try:
        with np.load(npz_path, allow_pickle=False) as npz:
            missing = [name for name in _FIELDS if name not in npz.files]
            if missing:
                raise ValueError(f"{npz_path}: {missing[0]}: missing (fields: {', '.join(npz.files) or 'none'})")
            arrays = {name: npz[name] for name in _FIELDS}
    except ValueError as exc:
        if str(exc).startswith(str(npz_path)):
            raise
        raise ValueError(f"{npz_path}: cannot be read as .npz (ValueError: {exc})") from None
    except (OSError, EOFError, zipfile.BadZipFile, KeyError) as exc:
        raise ValueError(f"{npz_path}: cannot be read as .npz ({type(exc).__name__}: "
                         f"{str(exc).splitlines()[0] if str(exc) else 'corrupt'})") from None
    seg = arrays["seg"]
    if seg.ndim != 3 or seg.dtype != np.int8:
        raise ValueError(f"{npz_path}: seg: must be (T, H, W) int8, got {seg.shape} {seg.dtype}")
    T, n = seg.shape[0], len(objects)
    for name, width in (("pos", 3), ("quat", 4)):
        a = arrays[name]
        if a.shape != (T, n, width) or a.dtype.kind != "f" or not np.isfinite(a).all():
            raise ValueError(f"{npz_path}: {name}: must be (T, n, {width}) finite float with T = {T} frames of seg "
                             f"and n = {n} objects of meta.json, got {a.shape} {a.dtype}")
    if (np.linalg.norm(arrays["quat"], axis=-1) < 1e-12).any():
        raise ValueError(f"{npz_path}: quat: must be non-zero quaternions (w, x, y, z), got a zero one")
    for name, shape in (("intrinsics", (3, 3)), ("extrinsics", (4, 4))):
        a = arrays[name]
        if a.shape != shape or a.dtype.kind != "f" or not np.isfinite(a).all():
            raise ValueError(f"{npz_path}: {name}: must be {shape} finite float, got {a.shape} {a.dtype}")
    K = arrays["intrinsics"]
    if not (K[0, 0] > 0 and K[1, 1] > 0) or np.linalg.matrix_rank(K) < 3:
        raise ValueError(f"{npz_path}: intrinsics: must be a pinhole K with fx, fy > 0, got {K.tolist()}")
    if seg.size and (seg.min() < -1 or seg.max() >= n):
        bad = int(seg.min()) if seg.min() < -1 else int(seg.max())
        raise ValueError(f"{npz_path}: seg: must hold -1 or an object index 0..{n - 1} of meta.json, got {bad}")
    return objects, seg, arrays["pos"].astype(np.float64), arrays["quat"].astype(np.float64), \
        K.astype(np.float64), arrays["extrinsics"].astype(np.float64)


def _objects(path: Path, meta: object) -> list[dict]:
    """Checked ``objects`` of meta.json: ``[{"shape": str, "size": {key: float m}}]``."""
    objects = meta.get("objects") if isinstance(meta, dict) else None
    if not isinstance(objects, list):
        raise ValueError(f"{path}: objects: must be a list of objects (shape, size), got {type(objects).__name__}")
    out = []
    for k, obj in enumerate(objects):
        shape = obj.get("shape") if isinstance(obj, dict) else None
        if shape not in SHAPES:
            raise ValueError(f"{path}: objects[{k}].shape: must be one of {', '.join(SHAPES)}, got {shape!r}")
        size = obj.get("size")
        if not isinstance(size, dict):
            raise ValueError(f"{path}: objects[{k}].size: must be a mapping, got {type(size).__name__}")
        dims = {}
        for key in SHAPES[shape]:
            value = size.get(key)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value <= 0:
                raise ValueError(f"{path}: objects[{k}].size.{key}: must be a positive number (m), got {value!r}")
            dims[key] = float(value)
        out.append({"shape": shape, "size": dims})
    return out
