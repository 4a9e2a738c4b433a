"""Cheap screens of candidate effects before their full fits: grid scans and the linearised
(variable-projection) prediction of the chi-square gain."""

from __future__ import annotations

import itertools
from typing import Any, Mapping, Sequence

import numpy as np

from pipeline import effects as fx
from pipeline.discrepancy.clip_model import Weights, clip_residuals_many
from pipeline.discrepancy.fit import Fit, free_mask, nuisance_bounds, nuisance_scales
from pipeline.discrepancy.trajectories import Clip
from pipeline.discrepancy.workspace import Workspace


def screen_candidates(ws: "Workspace", idx: Sequence[int], current: Fit, names: Sequence[str]
                      ) -> dict[str, dict[str, Any]]:
    """Cheap screen of candidate effects before their full fits: the chi-square each one could
    gain, predicted by linearising the clips' own parameters at the current optimum.

    Per clip ``c``, with the current parameters ``x_c`` and the Jacobian ``J_c`` of its
    residuals with respect to its free parameters (forward differences, one batched rollout),
    the effect at each point ``s`` of its grid (``ParamSpec.grid``, full product without the
    null point) gives residuals ``r_c(s)``; re-fitting ``x_c`` to first order leaves
    ``|(I - J_c J_c^+) r_c(s)|^2`` (variable projection, Golub & Pereyra 1973). The predicted
    gain is that sum over clips at the null point minus its minimum over the grid, computed
    twice: over all residuals, and over the position residuals alone (orientation errors of a
    fast spin wrap around and are far from linear in the parameters: an effect that slows the
    spin, like drag, would otherwise look harmful). The larger of the two is reported. Costs
    one rollout per free parameter of each clip once, plus one per grid point and clip per
    candidate; a full candidate fit costs hundreds of times more.

    Args:
        ws: workspace. idx: clips. current: the converged current model.
        names: candidate effects (not in ``current.effects``).

    Returns:
        ``{name: {"predicted_gain": float (chi-square) or None (no grid), "position_gain",
        "full_gain", "best": {parameter: value}}}``.
    """
    h = ws.cfg.diff_step
    proj: list[list[np.ndarray]] = []
    rows_pos: list[np.ndarray] = []
    null = np.zeros(2)

    def leftover(r: np.ndarray, Qs: Sequence[np.ndarray], pos: np.ndarray) -> np.ndarray:
        full = r - Qs[0] @ (Qs[0].T @ r)
        rp = r[pos]
        part = rp - Qs[1] @ (Qs[1].T @ rp)
        return np.array([float(full @ full), float(part @ part)])

    def basis(J: np.ndarray) -> np.ndarray:
        if not J.size:
            return np.zeros((J.shape[0], 0))
        U, sv, _ = np.linalg.svd(J, full_matrices=False)
        return U[:, sv > sv[0] * 1e-9] if sv[0] > 0 else np.zeros((J.shape[0], 0))

    for c in idx:
        clip, nuis, w = ws.clips[c], current.nuisance[c], ws.weights[c]
        model = ws.model(c, current.effects)
        mask = free_mask(clip, tuple(current.effects), ws.cfg)
        scale = nuisance_scales(clip, mask)
        lo, hi = nuisance_bounds(clip)
        variants, steps = [], []
        for flat in np.flatnonzero(mask.ravel()):
            x = nuis.copy().ravel()
            step = h * scale.ravel()[flat]
            step = step if x[flat] + step <= hi.ravel()[flat] else -step
            x[flat] += step
            variants.append(x.reshape(nuis.shape))
            steps.append(step)
        qs = model.simulate_many([nuis] + variants, [current.effects] * (1 + len(variants)))
        res = clip_residuals_many(clip, qs, w)[0]
        r0 = res[0]
        J = np.stack([(r - r0) / st for r, st in zip(res[1:], steps)], 1) if variants else np.zeros((len(r0), 0))
        pos = _position_rows(clip, w)
        Qs = [basis(J), basis(J[pos])]
        proj.append(Qs)
        rows_pos.append(pos)
        null += leftover(r0, Qs, pos)
    out: dict[str, dict[str, Any]] = {}
    for name in names:
        cls = fx.REGISTRY[name]
        keys = [k for k, sp in cls.parameters.items() if sp.fit and sp.grid]
        if not keys:
            out[name] = {"predicted_gain": None, "best": cls.defaults()}   # nothing to screen on
            continue
        grids = [cls.parameters[k].grid for k in keys]
        points = [{**cls.defaults(), **dict(zip(keys, v))} for v in itertools.product(*grids)
                  if not all(a == g[0] for a, g in zip(v, grids))]
        effs = [{**current.effects, name: pt} for pt in points]
        total = np.zeros((len(points), 2))
        for c, Qs, pos in zip(idx, proj, rows_pos):
            qs = ws.model(c, effs[0]).simulate_many([current.nuisance[c]] * len(points), effs)
            for j, r in enumerate(clip_residuals_many(ws.clips[c], qs, ws.weights[c])[0]):
                total[j] += leftover(r, Qs, pos)
        gains = null[None, :] - total
        b = int(np.argmax(gains.max(1)))
        out[name] = {"predicted_gain": float(gains.max()), "full_gain": float(gains[:, 0].max()),
                     "position_gain": float(gains[:, 1].max()), "best": points[b]}
    return out


def second_chance_point(name: str, best: Mapping[str, float]) -> dict[str, float]:
    """Strength at which a candidate the linearised screen rejected is refitted from the data:
    for one fitted parameter the middle of its non-null grid (``(len - 1) // 2``, e.g. drag
    density 3 kg/m^3, Magnus lift 1, restitution 0.5), for several the screen's best grid point
    (its direction).

    Args:
        name: an effect of ``pipeline.effects.REGISTRY`` (``KeyError`` otherwise).
        best: the screen's best grid point ``{parameter: value}`` of ``name``.

    Returns:
        ``{parameter: value}`` of the effect (its defaults with the fitted one set).
    """
    cls = fx.REGISTRY[name]
    keys = [k for k, sp in cls.parameters.items() if sp.fit and sp.grid]
    if len(keys) != 1:
        return dict(best)
    grid = [v for v in cls.parameters[keys[0]].grid[1:]]
    return {**cls.defaults(), keys[0]: float(sorted(grid, key=abs)[(len(grid) - 1) // 2])}


def _position_rows(clip: Clip, weights: Weights) -> np.ndarray:
    """Indices of the position rows of :func:`clip_residuals` (per object: positions first,
    then orientation rows where measured and weighted)."""
    rows, at = [], 0
    for tr in clip.tracks:
        k = len(tr.t) * int(np.sum(tr.axes))
        rows.append(np.arange(at, at + k))
        at += k
        if tr.quat is not None and weights.angle:
            at += 3 * len(tr.t)
    return np.concatenate(rows) if rows else np.zeros(0, int)
