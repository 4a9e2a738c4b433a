"""Observed object tracks of a reconstructed video, in the scene's world frame.

``dynamics infer`` re-simulates a scene and scores it against masks; to ask the discrepancy
workflow (docs/design.md §8) *where the re-simulation leaves the observed motion, and which effect
closes the gap*, the observed motion has to be a trajectory table in the world frame of the
scene. A monocular track gives two coordinates per frame (the mask centroid ``(u, v)``, px);
the third, the depth along the optical axis, is borrowed from the re-simulated object at the
same frame (the object is placed on the plane through it parallel to the image plane,
:func:`pipeline.camera.unproject`). The world axes that the camera sees face-on (``|forward_i|
< cos 45°``) are marked observed; the axis along the view is not fitted (it carries the
simulated value, which only fixes the depth).

``dynamics infer`` writes ``tracks.csv`` (:func:`write_tracks`) with the columns of a
trajectory table (``clip, object, t, x, y, z`` and the object's ``shape, radius, width, depth,
height, mass`` from the scene), plus ``u, v`` (observed centroid, px at the working size),
``u_sim, v_sim`` (the re-simulated centre projected, px) and ``x_sim, y_sim, z_sim``;
``dynamics discrepancy DIR`` reads it back with :func:`clips_from_infer_dir`.

Limits: static geometry (``static:`` ramps) and the perception's gravity scale are taken from
``scene.yaml`` only for the re-simulation gap; the discrepancy fit itself simulates free
objects over the floor (no ramps) under the scene's gravity.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from pipeline.errors import UserError
from pipeline import shards
from pipeline.camera import camera_pose, project, unproject
from pipeline.scene import Scene, load_scene

TRACK_COLUMNS = ("clip", "object", "t", "x", "y", "z", "shape", "radius", "width", "depth", "height", "mass",
                 "u", "v", "u_sim", "v_sim", "x_sim", "y_sim", "z_sim")
"""Columns of ``tracks.csv`` (m, s, px; world frame of the scene, z up)."""
FACE_ON = math.cos(math.radians(45.0))
"""A world axis is observed when the optical axis' component along it is below this."""


class InferTracksError(UserError, ValueError):
    """An infer output folder that cannot be read as trajectories (one line: file and field)."""


def observed_axes(scene: Scene) -> np.ndarray:
    """``(3,)`` bool: which world axes the scene's camera sees face-on (``|forward_i| <
    cos 45°``); e.g. ``[True, False, True]`` for a side view along +y, ``[True, True, False]``
    for a top view."""
    f = camera_pose(scene.camera).forward
    axes = np.abs(f) < FACE_ON
    return axes


def match_tracks(observed: Sequence[np.ndarray], simulated: np.ndarray) -> list[int]:
    """Scene object for each observed track: Hungarian assignment (scipy
    ``linear_sum_assignment``) on the mean pixel distance over the frames where the track is
    visible.

    Args:
        observed: per track ``(N_k, 3)`` float rows ``(frame, u, v)``.
        simulated: ``(T, n, 2)`` float projected centres of the scene's ``n`` objects, px.

    Returns:
        ``[object index or -1]`` per observed track (-1: more tracks than objects).
    """
    n_obs, n_obj = len(observed), simulated.shape[1]
    cost = np.zeros((n_obs, n_obj))
    for k, rows in enumerate(observed):
        f = np.clip(rows[:, 0].astype(int), 0, simulated.shape[0] - 1)
        cost[k] = np.linalg.norm(simulated[f] - rows[None, :, 1:3].transpose(1, 0, 2), axis=-1).mean(0)
    out = [-1] * n_obs
    r, c = linear_sum_assignment(cost)
    for i, j in zip(r, c):
        out[int(i)] = int(j)
    return out


def tracks_table(scene: Scene, qpos: np.ndarray, tracks: Sequence[Any], fps: float, width: int, height: int,
                 clip: str = "video") -> dict[str, list]:
    """Observed tracks as trajectory-table columns (:data:`TRACK_COLUMNS`).

    Args:
        scene: the re-simulated scene (camera, objects).
        qpos: ``(T, n, 7)`` float re-simulated poses at the frames (m, quaternion w, x, y, z).
        tracks: perception tracks (``frames (N,)`` int, ``centre (N, 2)`` px at the working size).
        fps: frames per second of the window. width, height: working size, px.
        clip: clip id written in the table.

    Returns:
        ``{column: list}``; a track matched to no object is left out.
    """
    cols: dict[str, list] = {c: [] for c in TRACK_COLUMNS}
    uv_sim, depth = project(qpos[..., :3], scene.camera, width, height)          # (T, n, 2), (T, n)
    rows = [np.column_stack([np.asarray(tr.frames, float), np.asarray(tr.centre, float)]) for tr in tracks]
    owner = match_tracks(rows, uv_sim) if rows and len(scene.objects) else []
    for k, obj_i in enumerate(owner):
        if obj_i < 0:
            continue
        obj = scene.objects[obj_i]
        name = f"{obj.shape}_{obj_i}"
        frames = rows[k][:, 0].astype(int)
        keep = (frames >= 0) & (frames < qpos.shape[0])
        frames, uv = frames[keep], rows[k][keep, 1:3]
        sim = qpos[frames, obj_i, :3]
        world = unproject(uv, depth[frames, obj_i], scene.camera, width, height)
        size = obj.size.model_dump() if hasattr(obj.size, "model_dump") else dict(obj.size)
        for j, f in enumerate(frames):
            cols["clip"].append(clip)
            cols["object"].append(name)
            cols["t"].append(round(f / fps, 9))
            for a, key in enumerate("xyz"):
                cols[key].append(float(world[j, a]))
                cols[f"{key}_sim"].append(float(sim[j, a]))
            cols["shape"].append(obj.shape)
            for key in ("radius", "width", "depth", "height"):
                cols[key].append(size.get(key))
            cols["mass"].append(float(obj.mass))
            cols["u"].append(float(uv[j, 0]))
            cols["v"].append(float(uv[j, 1]))
            cols["u_sim"].append(float(uv_sim[f, obj_i, 0]))
            cols["v_sim"].append(float(uv_sim[f, obj_i, 1]))
    return cols


def write_tracks(path: str | Path, cols: dict[str, list]) -> Path:
    """Write :func:`tracks_table` columns as CSV (temp file, then rename)."""
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(TRACK_COLUMNS)
    for i in range(len(cols["t"])):
        w.writerow(["" if cols[c][i] is None else cols[c][i] for c in TRACK_COLUMNS])
    shards.write_text(Path(path), buf.getvalue())
    return Path(path)


def resimulation_gap(cols: dict[str, list], axes: np.ndarray) -> dict[str, Any]:
    """RMSE (m) between the observed positions and the re-simulated scene over the observed
    axes, and in pixels, per object and over all (the gap ``dynamics infer`` leaves)."""
    obj = np.array(cols["object"])
    obs = np.column_stack([cols[k] for k in "xyz"]).astype(float)
    sim = np.column_stack([cols[f"{k}_sim"] for k in "xyz"]).astype(float)
    px = np.column_stack([cols["u"], cols["v"]]).astype(float) - np.column_stack([cols["u_sim"], cols["v_sim"]]).astype(float)
    d = (obs - sim)[:, axes]
    out = {"rmse_m": float(np.sqrt(np.mean(d ** 2))) if len(d) else None,
           "rmse_px": float(np.sqrt(np.mean(px ** 2))) if len(px) else None, "per_object": {}}
    for name in dict.fromkeys(obj.tolist()):
        m = obj == name
        out["per_object"][name] = {"rmse_m": float(np.sqrt(np.mean(d[m] ** 2))),
                                   "rmse_px": float(np.sqrt(np.mean(px[m] ** 2))), "samples": int(m.sum())}
    return out


def is_infer_dir(path: str | Path) -> bool:
    """Whether ``path`` is a ``dynamics infer`` output folder (``scene.yaml`` and ``tracks.csv``)."""
    p = Path(path)
    return p.is_dir() and (p / "scene.yaml").is_file() and (p / "tracks.csv").is_file()


def read_infer_dir(path: str | Path) -> tuple[Scene, dict[str, list], np.ndarray]:
    """``(scene, tracks.csv columns, observed axes (3,) bool)`` of an infer output folder.

    Raises:
        InferTracksError: a file is missing or unreadable (one line naming it).
    """
    p = Path(path)
    for name in ("scene.yaml", "tracks.csv"):
        if not (p / name).is_file():
            raise InferTracksError(f"{p / name}: missing (is {p} a `dynamics infer` output folder?)")
    try:
        scene = load_scene(p / "scene.yaml")
    except Exception as exc:  # the scene loader's own one-line errors
        raise InferTracksError(str(exc).splitlines()[0]) from None
    with open(p / "tracks.csv", newline="", encoding="utf-8") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None:
            raise InferTracksError(f"{p / 'tracks.csv'}: empty file")
        missing = [c for c in TRACK_COLUMNS if c not in header]
        if missing:
            raise InferTracksError(f"{p / 'tracks.csv'}: {missing[0]}: required column missing")
        body = list(reader)
    if not body:
        raise InferTracksError(f"{p / 'tracks.csv'}: t: no rows (no object was tracked in the video)")
    cols: dict[str, list] = {}
    for i, c in enumerate(header):
        vals = [r[i] if i < len(r) else "" for r in body]
        if c in ("clip", "object", "shape"):
            cols[c] = vals
        else:
            try:
                cols[c] = [None if v == "" else float(v) for v in vals]
            except ValueError:
                bad = next(v for v in vals if v != "" and not _is_float(v))
                raise InferTracksError(f"{p / 'tracks.csv'}: {c}: must be a number, got {bad!r}") from None
    return scene, cols, observed_axes(scene)


def _is_float(v: str) -> bool:
    try:
        float(v)
        return True
    except ValueError:
        return False
