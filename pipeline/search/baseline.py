"""The trivial baseline scene (most common training composition, mean parameters)."""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np

from pipeline.scene import Scene


def baseline_scene(configs: Any, split: str = "train") -> Scene:
    """The trivial baseline: the most common composition of the training split with the mean
    parameters of the training scenes of that composition, per shape slot.

    Slots: a scene's objects sorted by shape (stable, so same-shape objects keep their scene
    order); slot j of the baseline averages slot j of every training scene with the winning
    composition. Vectors are averaged component-wise; orientations by the normalised mean of
    sign-aligned quaternions; the camera per field (paper form when every scene uses it, else
    the 6-DoF form); duration and fps take the most common value. Ties between compositions go
    to the lexicographically smallest.

    Args:
        configs: a ``pyarrow.Table`` / list of rows with columns ``scene`` (YAML) and
            ``split``, or a list of :class:`Scene` / YAML strings (all used).
        split: split to learn from when rows carry one.
    Returns:
        the baseline :class:`Scene` (no effects).
    Raises:
        ValueError: no scene of that split.
    """
    scenes = _scenes_of(configs, split)
    if not scenes:
        raise ValueError(f"baseline_scene: no scene of split {split!r}")
    counts = Counter(s.composition for s in scenes)
    comp = min(counts, key=lambda c: (-counts[c], c))
    group = [s for s in scenes if s.composition == comp]
    slots = [sorted(s.objects, key=lambda o: o.shape) for s in group]  # stable sort
    objects = []
    for j, shape in enumerate(comp):
        objs = [sl[j] for sl in slots]
        dumps = [o.model_dump() for o in objs]
        mean = lambda key: [float(np.mean([d[key][k] for d in dumps])) for k in range(3)]  # noqa: E731
        qs = np.array([o.orientation for o in objs], dtype=np.float64)
        qs /= np.linalg.norm(qs, axis=1, keepdims=True)
        qs *= np.where(qs @ qs[0] < 0, -1.0, 1.0)[:, None]
        q = qs.mean(axis=0)
        q = q / np.linalg.norm(q) if np.linalg.norm(q) > 1e-9 else np.array([1.0, 0.0, 0.0, 0.0])
        objects.append({
            "shape": shape,
            "size": {k: float(np.mean([d["size"][k] for d in dumps])) for k in dumps[0]["size"]},
            "mass": float(np.mean([o.mass for o in objs])),
            "position": mean("position"), "orientation": q.tolist(),
            "linear_velocity": mean("linear_velocity"), "angular_velocity": mean("angular_velocity"),
            "material": {k: float(np.mean([d["material"][k] for d in dumps])) for k in dumps[0]["material"]},
        })
    cams = [s.camera for s in group]
    if all(not c.is_six_dof for c in cams):
        camera = {"height": float(np.mean([c.height for c in cams]))}
    else:
        camera = {"position": np.mean([c.eye for c in cams], axis=0).tolist(),
                  "yaw": float(np.mean([c.yaw or 0.0 for c in cams])),
                  "roll": float(np.mean([c.roll or 0.0 for c in cams]))}
    camera.update(pitch=float(np.mean([c.pitch for c in cams])), fov=float(np.mean([c.fov for c in cams])))
    mode = lambda xs: Counter(xs).most_common(1)[0][0]  # noqa: E731
    return Scene.from_dict({
        "duration": mode([s.duration for s in group]), "fps": mode([s.fps for s in group]),
        "gravity": float(np.mean([s.gravity for s in group])), "camera": camera, "objects": objects,
    }, source="<baseline>")


def _scenes_of(configs: Any, split: str) -> list[Scene]:
    if hasattr(configs, "to_pylist"):
        configs = configs.to_pylist()
    out = []
    for item in configs:
        if isinstance(item, Scene):
            out.append(item)
        elif isinstance(item, str):
            out.append(Scene.from_yaml(item))
        elif isinstance(item, dict):
            if item.get("split", split) == split and item.get("scene"):
                out.append(Scene.from_yaml(item["scene"], source=str(item.get("scene_id", "<configs>"))))
        else:
            raise TypeError(f"baseline_scene: cannot read a scene from {type(item).__name__}")
    return out
