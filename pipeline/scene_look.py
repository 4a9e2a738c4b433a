"""Randomised looks of the synthetic training scenes (``sample.look: random``; issue 30).

The scene language says nothing about how a scene looks. With ``sample.look: fixed`` every
training clip is drawn with the project's one look (grey checker floor, fixed object colours,
one light): real clips look nothing like it. With ``random`` the ``compile_mjcf`` stage draws,
per scene, a floor texture (MuJoCo builtin ``checker``, ``gradient`` or ``flat``) with random
colours and tile size, object colours (some close to the floor's), a checker on the objects or
not, the light's direction and strengths, the headlight and, sometimes, shadows. The draw uses
the truth sets' look sampler (:func:`pipeline.truthsets.scenario.sample_look`, the benchmark of
the observation) restricted to textures that live in the MJCF text (the generated ``noise`` and
``stripes`` images are assets, which the ``mjcf`` shards do not carry).

Every scene's look is a function of ``(seed, scene_id)`` alone, so any one clip re-renders alike.
"""

from __future__ import annotations

import zlib

import cv2
import numpy as np

from pipeline.mjcf import Appearance
from pipeline.truthsets.scenario import EngineLimits, Look, floor_image, object_colour, sample_look

FLOOR_SIZE = 20.0
"""m: side of the drawn floor (``pipeline.mjcf``: a plane of half size 10 m)."""

FLOOR_KINDS = {"checker": 0.4, "gradient": 0.2, "flat": 0.4}
"""Floor textures of training looks (builtin ones only) and their probabilities."""
P_LOW_CONTRAST = 0.15
"""Chance that an object's colour is close to the floor's mean colour."""


def random_appearance(seed: int, scene_id: str, n_objects: int, p_shadows: float = 0.0) -> Appearance:
    """The random look of one training scene.

    Args:
        seed: the run's seed (params ``seed``).
        scene_id: the scene's id (``pipeline.shards.scene_id``); hashed with CRC-32.
        n_objects: number of objects (one colour each).
        p_shadows: chance that the light casts shadows (``sample.look_shadows``; a shadowed frame
            costs ~15x the RGB render time on the CPU, docs/design.md §10).

    Returns:
        An :class:`pipeline.mjcf.Appearance` for :func:`pipeline.mjcf.build_mjcf`.
    """
    rng = np.random.default_rng([int(seed), zlib.crc32(scene_id.encode())])
    look = sample_look(rng, EngineLimits(pitch=(0.0, 89.0), floor_kinds=FLOOR_KINDS, p_shadows=p_shadows))
    rgb = tuple(object_colour(rng, look, bool(rng.random() < P_LOW_CONTRAST)) for _ in range(n_objects))
    return appearance_of(look, rgb)


def appearance_of(look: Look, object_rgb: tuple[tuple[float, float, float], ...]) -> Appearance:
    """The MJCF look of a :class:`Look` and one RGB colour per object (``noise`` and ``stripes``
    floors become a PNG asset, :func:`floor_image`)."""
    repeat = FLOOR_SIZE / look.floor_tile
    tex: dict = {"floor_texture": look.floor_kind, "floor_rgb1": look.floor_rgb1, "floor_rgb2": look.floor_rgb2}
    if look.floor_kind in ("noise", "stripes"):
        ok, png = cv2.imencode(".png", cv2.cvtColor(floor_image(look), cv2.COLOR_RGB2BGR))
        tex = {"floor_texture": "png", "floor_png": png.tobytes()}
    elif look.floor_kind == "flat":
        tex["floor_rgb2"] = look.floor_rgb1
    grey = lambda x: (x, x, x)  # noqa: E731
    return Appearance(**tex, floor_texrepeat=(repeat, repeat), object_rgb=object_rgb,
                      object_checker=look.object_checker, light_dir=tuple(float(c) for c in look.light_dir),
                      light_diffuse=grey(look.light_diffuse), light_ambient=grey(look.light_ambient),
                      light_specular=grey(look.light_specular), light_castshadow=look.shadows,
                      headlight_ambient=grey(look.headlight_ambient), headlight_diffuse=grey(look.headlight_diffuse))
