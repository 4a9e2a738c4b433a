"""Offscreen rendering: RGB, segmentation, depth and exact ground-truth optical flow.

Rendering uses MuJoCo's OpenGL renderer (``mjr_render``) with ``MUJOCO_GL=egl`` (set in
``pipeline/__init__``). A :class:`FrameRenderer` per compiled model; for many models pass one
:class:`GLResources` (:func:`shared_gl` in a process) so that they share the GL context and
the ``MjrContext`` objects: a private one costs ~100 ms to create plus ~30 ms of shader
compilation on its first frame, a shared one nothing after its first use. Output is bit-identical
to a fresh ``mujoco.Renderer`` per model (``tests/test_render.py``). Close renderers and
private :class:`GLResources` explicitly (or use ``with``) or EGL errors print at exit.

Ground-truth flow (docs/design.md §3): for a pixel of object k at frame t with depth d, the world
point ``X = unproject(uv, d)`` moves rigidly with body k, ``X' = R_{t+1} R_t^T (X - p_t) +
p_{t+1}``, and the flow is ``project(X') - uv`` (pixels, forward, (u, v) = (x, y)). The floor
and background are static (flow 0) because the camera is fixed.
"""

from __future__ import annotations

import atexit
import hashlib
from dataclasses import dataclass

import mujoco
import numpy as np

import pipeline  # noqa: F401  (MUJOCO_GL)
from pipeline.camera import intrinsics
from pipeline.exposure import expose
from pipeline.mjcf import compile_model
from pipeline.rotation import quat_to_mat
from pipeline.simulate import Trace, check_rollout, rollout, simulate

BACKGROUND = -1
"""Segmentation label of the floor and background."""


@dataclass
class Frames:
    """Rendered clip. Any field may be None when not requested.

    Attributes:
        rgb: (T, H, W, 3) uint8.
        seg: (T, H, W) int8 object index, -1 = floor/background.
        depth: (T, H, W) float32 distance along the optical axis, m.
        flow: (T-1, H, W, 2) float32 ground-truth forward flow, px.
    """

    rgb: np.ndarray | None = None
    seg: np.ndarray | None = None
    depth: np.ndarray | None = None
    flow: np.ndarray | None = None

    def visible_pixels(self, n_objects: int | None = None) -> np.ndarray:
        """(T, n) int64 pixel count per object per frame (from ``seg``).

        Args:
            n_objects: number of objects n; without it n is inferred from the labels seen,
                which drops trailing objects that are never visible.
        """
        if self.seg is None:
            raise ValueError("segmentation was not rendered")
        n = int(self.seg.max()) + 1 if self.seg.size else 0
        n = n if n_objects is None else n_objects
        return np.stack([(self.seg == k).sum(axis=(1, 2)) for k in range(max(n, 0))], axis=-1) if n else \
            np.zeros((self.seg.shape[0], 0), dtype=np.int64)


def camera_matrices(model: mujoco.MjModel, data: mujoco.MjData, width: int, height: int,
                    camera: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Intrinsics K (3, 3) and OpenCV-frame extrinsics R (3, 3), t (3,) of an MJCF camera.

    Read from ``data.cam_xpos`` / ``data.cam_xmat`` (call ``mj_kinematics`` + ``mj_camlight``
    first) and ``model.cam_fovy``; conventions as in ``pipeline.camera``.
    """
    K = intrinsics(model.cam_fovy[camera], width, height)
    axes = data.cam_xmat[camera].reshape(3, 3)  # columns: x right, y up, z backward (world)
    R = np.stack([axes[:, 0], -axes[:, 1], -axes[:, 2]])
    return K, R, -R @ data.cam_xpos[camera]


def rigid_flow(seg: np.ndarray, depth: np.ndarray, qpos0: np.ndarray, qpos1: np.ndarray,
               K: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Exact forward flow of rigid bodies between two frames seen by a static camera.

    Args:
        seg: (H, W) int object index at frame t (-1 = static background).
        depth: (H, W) float depth along the optical axis at frame t, m.
        qpos0, qpos1: (n, 7) float body poses (x, y, z, qw, qx, qy, qz) at t and t+1.
        K, R, t: camera intrinsics and world-to-camera extrinsics (OpenCV frame).
    Returns:
        (H, W, 2) float32 flow in pixels; 0 on the background.
    """
    # Per-pixel arithmetic as in the straightforward form (stacks of u + 0.5, back-projection,
    # ``(xc - t) @ R``, the two einsums, projection), with fewer temporaries: bit-identical.
    H, W = seg.shape
    flow = np.zeros((H, W, 2), dtype=np.float32)
    idx = np.flatnonzero(seg >= 0)  # row-major, as np.nonzero
    if not idx.size:
        return flow
    v, u = np.divmod(idx, W)
    n = idx.size
    uv = np.empty((n, 2))
    np.add(u, 0.5, out=uv[:, 0])
    np.add(v, 0.5, out=uv[:, 1])
    d = depth.reshape(-1)[idx].astype(np.float64)
    xc = np.empty((n, 3))
    np.multiply((uv[:, 0] - K[0, 2]) / K[0, 0], d, out=xc[:, 0])
    np.multiply((uv[:, 1] - K[1, 2]) / K[1, 1], d, out=xc[:, 1])
    xc[:, 2] = d
    X = (xc - t) @ R
    k = seg.reshape(-1)[idx].astype(np.intp)
    Rs = quat_to_mat(np.concatenate([qpos0[:, 3:], qpos1[:, 3:]]))
    m = qpos0.shape[0]
    local = np.einsum("nji,nj->ni", Rs[:m][k], X - qpos0[k, :3])
    X1 = np.einsum("nij,nj->ni", Rs[m:][k], local) + qpos1[k, :3]
    xc1 = X1 @ R.T + t
    out = flow.reshape(-1, 2)
    out[idx, 0] = K[0, 0] * xc1[:, 0] / xc1[:, 2] + K[0, 2] - uv[:, 0]
    out[idx, 1] = K[1, 1] * xc1[:, 1] / xc1[:, 2] + K[1, 2] - uv[:, 1]
    return flow


def _context_key(model: mujoco.MjModel, multisample: bool) -> bytes | None:
    """Digest of everything ``mjr_makeContext`` uploads for ``model`` (MuJoCo 3.x
    ``render_context.c``): offscreen buffer size and samples, shadow map size, builtin-geometry
    quality, materials' texture bindings, texture pixels, plane grids. Two models with the same
    key render identically with one ``MjrContext``. None for models with meshes, height fields,
    skins or flexes (their GPU data is not compared: such models get a context of their own).

    The context fields that depend on ``stat.extent`` (``shadowClip``, ``fogStart``,
    ``fogEnd``) are set per model by :meth:`GLResources.context`; fog stays off (default
    ``MjvScene`` flags), so the GL fog state made with another model's extent is never used.
    """
    if model.nmesh or model.nhfield or model.nskin or getattr(model, "nflex", 0):
        return None
    h = hashlib.blake2b(digest_size=20)
    vis = model.vis
    h.update(np.array([vis.global_.offwidth, vis.global_.offheight,
                       vis.quality.offsamples if multisample else 0, vis.quality.shadowsize,
                       vis.quality.numslices, vis.quality.numstacks, vis.quality.numquads],
                      dtype=np.int64).tobytes())
    h.update(np.array([vis.global_.linewidth, vis.map.fogstart, vis.map.fogend, vis.map.shadowclip,
                       vis.map.shadowscale, *vis.rgba.fog], dtype=np.float64).tobytes())
    for name in ("tex_type", "tex_width", "tex_height", "tex_nchannel", "tex_colorspace", "tex_adr",
                 "tex_data", "mat_texid", "mat_texuniform", "mat_texrepeat"):
        arr = getattr(model, name, None)
        if arr is not None:
            h.update(name.encode())
            h.update(np.ascontiguousarray(arr).tobytes())
    planes = np.flatnonzero(model.geom_type == int(mujoco.mjtGeom.mjGEOM_PLANE))
    h.update(np.ascontiguousarray(model.geom_size[planes]).tobytes())
    h.update(np.ascontiguousarray(model.geom_matid[planes]).tobytes())
    if (model.geom_size[planes, :2] <= 0).any():  # infinite planes: grid spans zfar * extent
        h.update(np.array([vis.map.zfar, model.stat.extent], dtype=np.float64).tobytes())
    return h.digest()


class GLResources:
    """One offscreen OpenGL (EGL) context and the ``MjrContext`` objects made in it, shared by
    the :class:`FrameRenderer` objects of a process.

    Creating a ``mujoco.Renderer`` costs ~100 ms (GL context, ``MjrContext`` with fonts and
    textures, a 10,000-geom ``MjvScene``) plus ~30 ms for llvmpipe to compile its shaders on the
    first frame. Models that upload the same GPU data (same textures, materials, buffer size:
    :func:`_context_key`; in this project every scene with the same number of objects) share
    one ``MjrContext`` here, so a scene costs only its frames. Renders equal a fresh
    ``mujoco.Renderer`` per model bit for bit (``tests/test_render.py``).

    One per process (:func:`shared_gl`), or a private one owned by a single renderer. Not
    thread-safe. Close it (or use ``with``) before the process exits.

    At most ``max_contexts`` shared contexts are kept (least recently used first out, and only
    those no open renderer holds: :meth:`release`). A context holds the offscreen buffers and a
    shadow map (~80 MB at MuJoCo's default 4096 px shadow size), so scenes that each look
    different (``sample.look: random``) would otherwise fill the memory of a worker.
    """

    def __init__(self, max_contexts: int = 8) -> None:
        self._gl = None
        self._contexts: dict[bytes, mujoco.MjrContext] = {}   # insertion order = last use
        self._users: dict[int, int] = {}                       # id(context) -> open renderers
        self.max_contexts = max_contexts
        self._bound: mujoco.MjrContext | None = None

    def make_current(self) -> None:
        """Create the GL context on first use and make it current."""
        if self._gl is None:
            from mujoco.rendering.classic.gl_context import GLContext

            self._gl = GLContext(_GL_SIZE[0], _GL_SIZE[1])
        self._gl.make_current()

    def context(self, model: mujoco.MjModel, multisample: bool = True) -> tuple[mujoco.MjrContext, bool]:
        """``(MjrContext, owned)`` for ``model``, bound as the offscreen target.

        Args:
            multisample: False makes the offscreen buffer single-sampled (used for
                segmentation and depth, which MuJoCo renders without multisampling).
        Returns:
            the context and whether the caller owns it (must ``free()`` it: models that
            cannot share a context).
        """
        self.make_current()
        key = _context_key(model, multisample)
        con = self._contexts.pop(key, None) if key is not None else None
        if con is not None:
            self._contexts[key] = con   # most recently used last
        owned = False
        if con is None:
            samples = model.vis.quality.offsamples
            if not multisample:
                model.vis.quality.offsamples = 0
            try:
                con = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150.value)
            finally:
                model.vis.quality.offsamples = samples
            con.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR  # as mujoco.Renderer
            if key is None:
                owned = True
            else:
                self._evict()
                self._contexts[key] = con
        if not owned:
            self._users[id(con)] = self._users.get(id(con), 0) + 1
        # model-dependent scalars that mjr_makeContext copies (render_context.c)
        con.shadowClip = model.stat.extent * model.vis.map.shadowclip
        con.fogStart = float(np.float32(model.stat.extent * model.vis.map.fogstart))
        con.fogEnd = float(np.float32(model.stat.extent * model.vis.map.fogend))
        self._bound = None
        self.bind(con)
        return con, owned

    def release(self, con: mujoco.MjrContext) -> None:
        """A renderer is done with a shared context (it may be freed once more than
        ``max_contexts`` are cached)."""
        n = self._users.get(id(con), 0) - 1
        if n > 0:
            self._users[id(con)] = n
        else:
            self._users.pop(id(con), None)

    def _evict(self) -> None:
        """Free least recently used contexts that no renderer holds, down to ``max_contexts - 1``."""
        for key in list(self._contexts):
            if len(self._contexts) < self.max_contexts:
                break
            con = self._contexts[key]
            if self._users.get(id(con), 0) == 0:
                if self._bound is con:
                    self._bound = None
                con.free()
                del self._contexts[key]

    def bind(self, con: mujoco.MjrContext) -> None:
        """Make the GL context current and ``con``'s offscreen buffer the render target."""
        self.make_current()
        if self._bound is not con:
            mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, con)
            self._bound = con

    @property
    def n_contexts(self) -> int:
        """Number of shared ``MjrContext`` objects made so far."""
        return len(self._contexts)

    def close(self) -> None:
        """Free every ``MjrContext`` and the GL context (renderers using them must be closed)."""
        if self._gl is not None:
            self._gl.make_current()
            for con in self._contexts.values():
                con.free()
            self._contexts.clear()
            self._users.clear()
            self._gl.free()
            self._gl = None
        self._bound = None

    def __enter__(self) -> "GLResources":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


_GL_SIZE = (64, 64)
"""Size of the EGL surface, px; rendering goes to the model's offscreen buffer instead."""
_SHARED: GLResources | None = None


def shared_gl() -> GLResources:
    """The process-wide :class:`GLResources` (made on first use, closed at exit)."""
    global _SHARED
    if _SHARED is None:
        _SHARED = GLResources()
        _SHARED.make_current()  # EGL registers its display's atexit termination here: close before it
        atexit.register(_close_shared)
    return _SHARED


def _close_shared() -> None:
    global _SHARED
    if _SHARED is not None:
        _SHARED.close()
        _SHARED = None


class FrameRenderer:
    """Renders frames of one compiled model from its camera ``main``.

    Per frame it draws twice: the RGB image (multisampled, as the model asks) and one
    segmentation pass whose colour buffer gives the object ids and whose depth buffer gives
    the depth (the same pixels as ``mujoco.Renderer``'s separate segmentation and depth
    renders, which both draw with segmentation flags).

    Args:
        model: compiled scene model (objects are bodies 1..n, one geom each).
        width, height: image size, px (at most the model's offscreen buffer).
        gl: GL resources to share with other renderers (:func:`shared_gl`); None makes a
            private GL context that :meth:`close` frees (~100 ms to create, as before).
    """

    def __init__(self, model: mujoco.MjModel, width: int, height: int, gl: GLResources | None = None):
        if width > model.vis.global_.offwidth or height > model.vis.global_.offheight:
            raise ValueError(f"image {width}x{height} px exceeds the model's offscreen buffer "
                             f"{model.vis.global_.offwidth}x{model.vis.global_.offheight} px")
        self.model = model
        self.width, self.height = width, height
        self.data = mujoco.MjData(model)
        self._own_gl = gl is None
        self._gl = GLResources() if gl is None else gl
        self._owned: list[mujoco.MjrContext] = []
        self._shared: list[mujoco.MjrContext] = []
        self._con_rgb, owned = self._gl.context(model, multisample=True)
        (self._owned if owned else self._shared).append(self._con_rgb)
        self._con_ids, owned = self._gl.context(model, multisample=False)
        (self._owned if owned else self._shared).append(self._con_ids)
        # room for every model geom plus decorations; checked after each scene update
        self._scene = mujoco.MjvScene(model, maxgeom=max(1000, 4 * model.ngeom + 100))
        self._option = mujoco.MjvOption()
        self._camera = mujoco.MjvCamera()
        self._camera.fixedcamid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, "main")
        if self._camera.fixedcamid < 0:
            raise ValueError('the model has no camera "main"')
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._rect = mujoco.MjrRect(0, 0, width, height)
        # geom id -> object index (-1 for the floor / world geoms)
        self.geom_object = np.full(model.ngeom, BACKGROUND, dtype=np.int16)
        for g in range(model.ngeom):
            b = model.geom_bodyid[g]
            if b > 0:
                self.geom_object[g] = b - 1
        self.n_objects = model.nbody - 1
        self._closed = False

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        for con in self._shared:
            self._gl.release(con)
        self._shared.clear()
        if self._owned:
            self._gl.make_current()
            for con in self._owned:
                con.free()
            self._owned.clear()
        if self._own_gl:
            self._gl.close()

    def __enter__(self) -> "FrameRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def set_pose(self, qpos: np.ndarray) -> None:
        """Place the objects at ``qpos (n, 7)`` and update kinematics and the camera."""
        self.data.qpos[: 7 * self.n_objects] = np.asarray(qpos, dtype=np.float64).reshape(-1)
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)  # mj_kinematics alone does not move cameras

    # ------------------------------------------------------------------ drawing
    def _update_scene(self) -> None:
        if self._closed:
            raise RuntimeError("render called after close")
        scn = self._scene
        mujoco.mjv_updateScene(self.model, self.data, self._option, None, self._camera,
                               mujoco.mjtCatBit.mjCAT_ALL.value, scn)
        if scn.ngeom >= scn.maxgeom:
            raise RuntimeError(f"MjvScene full ({scn.maxgeom} geoms): raise maxgeom")

    def _draw_rgb(self, out: np.ndarray) -> None:
        """Draw the current scene; ``out (H, W, 3) uint8`` gets it bottom row first."""
        self._gl.bind(self._con_rgb)
        mujoco.mjr_render(self._rect, self._scene, self._con_rgb)
        mujoco.mjr_readPixels(out, None, self._rect, self._con_rgb)

    def _draw_ids(self, ids: np.ndarray, depth: np.ndarray | None) -> np.ndarray:
        """Segmentation pass. ``ids (H, W, 3) uint8`` gets the id colours and ``depth (H, W)
        float32`` the raw depth buffer, bottom row first. Returns the lookup table
        ``(ngeom + 1,) int8``: id colour (segid + 1, 0 = nothing) -> object index or -1."""
        scn = self._scene
        flags = scn.flags.copy()
        scn.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = True
        scn.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = True
        self._gl.bind(self._con_ids)
        mujoco.mjr_render(self._rect, scn, self._con_ids)
        mujoco.mjr_readPixels(ids, depth, self._rect, self._con_ids)
        np.copyto(scn.flags, flags)
        lut = np.full(scn.ngeom + 1, BACKGROUND, dtype=np.int8)
        geom_type = int(mujoco.mjtObj.mjOBJ_GEOM)
        for g in scn.geoms[: scn.ngeom]:
            if g.segid != -1 and g.objtype == geom_type and g.objid >= 0:
                lut[g.segid + 1] = self.geom_object[g.objid]
        return lut

    def _ids_to_seg(self, ids: np.ndarray, lut: np.ndarray) -> np.ndarray:
        """``(..., H, W, 3) uint8`` id colours -> ``(..., H, W) int8`` object index."""
        code = ids[..., 0].astype(np.int64) | (ids[..., 1].astype(np.int64) << 8) | (ids[..., 2].astype(np.int64) << 16)
        return lut[code]

    def _linear_depth(self, raw: np.ndarray) -> np.ndarray:
        """Raw depth buffer values (mjDEPTH_ZEROFAR) -> distance along the optical axis, m,
        float32; the same arithmetic as ``mujoco.Renderer.render``."""
        extent = self.model.stat.extent
        near = self.model.vis.map.znear * extent
        far = self.model.vis.map.zfar * extent
        zfar, znear = np.float32(far), np.float32(near)
        out_64 = raw.astype(np.float64)
        if self._scene.camera[0].orthographic:
            out_64 = zfar - out_64 * (zfar - znear)
        else:
            c_coef = -(zfar + znear) / (zfar - znear)
            d_coef = -(np.float32(2) * zfar * znear) / (zfar - znear)
            c_coef = np.float32(-0.5) * c_coef - np.float32(0.5)
            d_coef = np.float32(-0.5) * d_coef
            out_64 = d_coef / (out_64 + c_coef)
        return out_64.astype(np.float32)

    def segmentation(self) -> np.ndarray:
        """(H, W) int8 object index of the current pose (-1 background)."""
        self._update_scene()
        ids = np.empty((self.height, self.width, 3), dtype=np.uint8)
        lut = self._draw_ids(ids, None)
        return self._ids_to_seg(ids[::-1], lut)

    def _render_ids_only(self, qpos: np.ndarray, ids_buf: np.ndarray, depth_buf: np.ndarray | None,
                         seg_out: np.ndarray | None) -> None:
        """Segmentation passes of every frame of ``qpos (T, n, 7)`` (no RGB): ``ids_buf (T, H, W,
        3)`` and ``depth_buf (T, H, W)`` get the raw buffers bottom row first, ``seg_out (T, H,
        W)`` the object index. Pixel for pixel what :meth:`_draw_ids` per frame gives."""
        scn, con, rect, model, data = self._scene, self._con_ids, self._rect, self.model, self.data
        n7 = 7 * self.n_objects
        flat = qpos.reshape(qpos.shape[0], -1)
        flags = scn.flags.copy()
        geom_type = int(mujoco.mjtObj.mjOBJ_GEOM)
        self._gl.bind(con)
        try:
            scn.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = True
            scn.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = True
            for k in range(qpos.shape[0]):
                data.qpos[:n7] = flat[k]
                mujoco.mj_kinematics(model, data)
                mujoco.mj_camlight(model, data)
                self._update_scene()
                mujoco.mjr_render(rect, scn, con)
                mujoco.mjr_readPixels(ids_buf[k], None if depth_buf is None else depth_buf[k], rect, con)
                if seg_out is None:
                    continue
                lut = np.full(scn.ngeom + 1, BACKGROUND, dtype=np.int8)
                for g in scn.geoms[: scn.ngeom]:
                    if g.segid != -1 and g.objtype == geom_type and g.objid >= 0:
                        lut[g.segid + 1] = self.geom_object[g.objid]
                if lut.size <= 256:  # id colours fit the red channel (green and blue are 0)
                    np.take(lut, ids_buf[k, ::-1, :, 0], out=seg_out[k])
                else:
                    seg_out[k] = self._ids_to_seg(ids_buf[k, ::-1], lut)
        finally:
            np.copyto(scn.flags, flags)

    def render(self, qpos: np.ndarray, rgb: bool = True, seg: bool = True, depth: bool = True,
               flow: bool = True, progress: bool = False) -> Frames:
        """Render a pose sequence.

        Args:
            qpos: (T, n, 7) float body poses per frame (``Trace.qpos``).
            rgb, seg, depth, flow: which outputs to produce (flow needs seg and depth, which
                are then rendered even if not returned).
        Returns:
            :class:`Frames`.
        """
        qpos = np.asarray(qpos, dtype=np.float64)
        T, H, W = qpos.shape[0], self.height, self.width
        need_seg, need_depth = seg or flow, depth or flow
        rgb_buf = np.empty((T, H, W, 3), dtype=np.uint8) if rgb else None
        ids_buf = np.empty((T, H, W, 3), dtype=np.uint8) if need_seg or need_depth else None
        depth_buf = np.empty((T, H, W), dtype=np.float32) if need_depth else None
        seg_out = np.empty((T, H, W), dtype=np.int8) if need_seg else None
        K = R = t = None
        if not rgb and ids_buf is not None:
            # segmentation pass only: the same draws as _draw_ids, without its per-frame flag
            # toggling and rebinding (nothing else draws in between)
            self._render_ids_only(qpos, ids_buf, depth_buf, seg_out)
            if flow:
                self.set_pose(qpos[0])
                K, R, t = camera_matrices(self.model, self.data, W, H)
        else:
            for k in range(T):
                self.set_pose(qpos[k])
                if k == 0 and flow:
                    K, R, t = camera_matrices(self.model, self.data, W, H)
                self._update_scene()
                if rgb:
                    self._draw_rgb(rgb_buf[k])
                if ids_buf is not None:
                    lut = self._draw_ids(ids_buf[k], depth_buf[k] if need_depth else None)
                    if need_seg:
                        seg_out[k] = self._ids_to_seg(ids_buf[k, ::-1], lut)
        frames = Frames(
            rgb=np.ascontiguousarray(rgb_buf[:, ::-1]) if rgb else None,
            seg=seg_out,
            depth=self._linear_depth(depth_buf[:, ::-1]) if need_depth else None,
        )
        if flow:
            frames.flow = np.stack([
                rigid_flow(frames.seg[k], frames.depth[k], qpos[k], qpos[k + 1], K, R, t) for k in range(T - 1)
            ]) if T > 1 else np.zeros((0, H, W, 2), np.float32)
        if not seg:
            frames.seg = None
        if not depth:
            frames.depth = None
        return frames


def render_mjcf(mjcf: str, n_objects: int, n_frames: int, fps: float, width: int, height: int,
                gl: GLResources | None = None) -> tuple["Trace", Frames]:
    """Compile MJCF text, roll it out and render every output (what the ``render`` stage does
    per scene).

    Args:
        mjcf: MJCF XML text (``compile_mjcf`` stage).
        n_objects, n_frames, fps: the scene's object count, frame count T and frame rate.
        width, height: image size W x H, px.
        gl: GL resources to reuse; default: this process's :func:`shared_gl`.
    Returns:
        (trace, frames): the :class:`pipeline.simulate.Trace` (T frames) and :class:`Frames`
        with rgb (T, H, W, 3) uint8, seg (T, H, W) int8, depth (T, H, W) float32 m and
        ground-truth flow (T-1, H, W, 2) float32 px.
    Raises:
        ValueError: MuJoCo rejects the MJCF.
        pipeline.simulate.SimulationError: the simulation diverged (see :func:`check_rollout`).
    """
    model = compile_model(mjcf)
    data = mujoco.MjData(model)
    trace = rollout(model, n_objects, n_frames, fps, data=data)
    check_rollout(data, trace)
    with FrameRenderer(model, width, height, gl or shared_gl()) as renderer:
        return trace, renderer.render(trace.qpos)


def render_scene(scene, width: int, height: int, options=None, **kwargs) -> tuple["Trace", Frames]:
    """Simulate and render a scene in one call (convenience for tests and the CLI).

    Returns:
        (trace, frames): the :class:`pipeline.simulate.Trace` and rendered :class:`Frames`;
        ``frames.seg`` swept over the scene's ``camera.exposure`` as the search scores it
        (:func:`pipeline.exposure.expose`; RGB, depth and flow stay instantaneous).
    """
    model, trace = simulate(scene, options)
    with FrameRenderer(model, width, height) as r:
        frames = r.render(trace.qpos, **kwargs)
    if frames.seg is not None:
        frames.seg = expose(frames.seg, scene.exposure_frames)
    return trace, frames


def reference_frames(model: mujoco.MjModel, qpos: np.ndarray, width: int, height: int
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The naive render path (before issue 8), the reference the fast path is checked against:
    a new ``mujoco.Renderer`` and three draws per frame (RGB, segmentation, depth).

    Args:
        model: compiled scene (camera ``main``, one free body per object).
        qpos: ``(T, n, 7) float`` poses per frame.
        width, height: image size, px.

    Returns:
        ``rgb (T, H, W, 3) uint8``, ``seg (T, H, W) int8`` (object index, -1 background) and
        ``depth (T, H, W) float32`` (m).
    """
    n = model.nbody - 1
    data = mujoco.MjData(model)
    geom_object = np.where(model.geom_bodyid > 0, model.geom_bodyid - 1, -1).astype(np.int16)
    rgb, seg, depth = [], [], []
    with mujoco.Renderer(model, height=height, width=width) as r:
        for q in qpos:
            data.qpos[: 7 * n] = q.reshape(-1)
            mujoco.mj_kinematics(model, data)
            mujoco.mj_camlight(model, data)
            r.update_scene(data, camera="main")
            rgb.append(r.render().copy())
            r.enable_segmentation_rendering()
            r.update_scene(data, camera="main")
            ids = r.render()
            r.disable_segmentation_rendering()
            s = np.full(ids.shape[:2], -1, np.int8)
            is_geom = (ids[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)) & (ids[..., 0] >= 0)
            s[is_geom] = geom_object[ids[..., 0][is_geom]]
            seg.append(s)
            r.enable_depth_rendering()
            r.update_scene(data, camera="main")
            depth.append(r.render().astype(np.float32))
            r.disable_depth_rendering()
    return np.stack(rgb), np.stack(seg), np.stack(depth)
