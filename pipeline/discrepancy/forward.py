"""The forward gap of a single clip: fitted on its first part, the rest forecast."""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from pipeline import effects as fx
from pipeline.discrepancy.clip_model import NUISANCE_DAMPING
from pipeline.discrepancy.fit import initial_nuisance
from pipeline.discrepancy.profile import profile_candidate, refit_from_data
from pipeline.discrepancy.trajectories import Clip, truncate_clip
from pipeline.discrepancy.workspace import Workspace


def _late_sq(clip: Clip, qpos: np.ndarray, t_split: float) -> tuple[float, int]:
    """Sum of squared position residuals (m^2) and their count over the observed coordinates
    of the samples after ``t_split`` (s); ``qpos (T, n, 7)`` at ``clip.times``."""
    sq, n = 0.0, 0
    for i, tr in enumerate(clip.tracks):
        late = tr.t > t_split + 1e-9
        idx = np.searchsorted(clip.times, tr.t[late])
        d = (qpos[idx, i, :3] - tr.pos[late])[:, tr.axes]
        sq += float(np.sum(d * d))
        n += int(d.size)
    return sq, n


def forward_gap(ws: "Workspace", c: int, effects: Sequence[str], log=None) -> dict[str, Any] | None:
    """Forward gap of clip ``c``: fit on its first part, forecast the rest.

    The clip is cut at ``cfg.forward_split`` of its duration (:func:`truncate_clip`). On the first
    part the base model is fitted (:meth:`Workspace.fit_each`, per-clip continuation from the
    data), then each of ``effects`` is added in the order named, with its coefficients
    fitted on the first part alone (:func:`profile_candidate` from the effect's grid, then
    :func:`refit_from_data`), so nothing of the later part enters. The prediction simulates
    the *whole* clip from the fitted initial state with the fitted parameters (one
    :class:`ClipModel` rollout of the full clip); the samples after the split are a true
    forecast (the same as simulating from the model's own state at the split) and only they
    are scored. The noise weights are those of the whole clip (:func:`estimate_noise`).

    An effect with ``Effect.replaces_damping`` (quadratic drag) is fitted twice on the first
    part: added to the base model (damping still fitted) and in place of the damping (held
    at 0, one parameter fewer per object); the variant with the lower BIC on the first part
    is kept (``variants`` says which and why). Both are honest forecasts: the choice uses
    the first part only.

    Returns:
        ``{before, after, k_before, k_after, t_split, fit_s, predict_s, n_fit, n_predicted,
        effects, variants, label}`` (RMSE in m over the predicted samples' observed
        coordinates), or
        ``None`` if the first part keeps fewer than :data:`MIN_SAMPLES` samples of an object or
        nothing is left after it.
    """
    clip = ws.clips[c]
    duration = float(clip.times[-1])
    t_split = ws.cfg.forward_split * duration
    first = truncate_clip(clip, t_split)
    if first is None or not np.any(clip.times > t_split + 1e-9):
        return None
    part = Workspace([first], ws.cfg, ws.options, ws.gravity)
    part.noise, part.weights = [ws.noise[c]], [ws.weights[c]]
    base = part.fit_each([0], [initial_nuisance(first)], {}, converge=True)
    current = base
    held: Workspace | None = None   # the same first part with every damping held at 0
    variants: list[dict[str, Any]] = []
    for e in effects:
        joint, _, _ = profile_candidate(part, [0], current, e)
        cand = refit_from_data(part, [0], joint)
        if fx.REGISTRY[e].replaces_damping and not ws.cfg.hold_damping:
            # The effect instead of the base model's linear damping: on a short first part the
            # two are nearly collinear (quadratic vs linear in speed), so fitted together the
            # coefficient is poorly fixed and the forecast inherits that; fitted alone it
            # carries the law. The lower BIC on the first part decides (nothing after the split).
            if held is None:
                held = Workspace([first], ws.cfg.model_copy(update={"hold_damping": True}), ws.options, ws.gravity)
                held.noise, held.weights = part.noise, part.weights
            start = current.nuisance[0].copy()
            start[:, NUISANCE_DAMPING] = 0.0
            cur_held = held.fit([0], [start], current.effects, converge=True)
            j2, _, _ = profile_candidate(held, [0], cur_held, e)
            alt = refit_from_data(held, [0], j2)
            use = alt.bic < cand.bic
            variants.append({"effect": e, "damping": "held at 0" if use else "fitted",
                             "bic_fitted": round(float(cand.bic), 3), "bic_held": round(float(alt.bic), 3)})
            if log:
                log(f"forward gap: {e} with the damping fitted (BIC {cand.bic:.1f}) or held at 0 "
                    f"(BIC {alt.bic:.1f}): {variants[-1]['damping']}")
            if use:
                cand = alt
        current = cand
    out: dict[str, Any] = {"variants": variants}
    for key, fit in (("before", base), ("after", current)):
        qpos = ws.model(c, fit.effects).simulate(fit.nuisance[0], fit.effects)
        sq, n = _late_sq(clip, qpos, t_split)
        out[key] = math.sqrt(sq / max(n, 1))
        out[f"k_{key}"] = int(fit.k)            # free per-clip parameters + effect coefficients
    t_last_fit = float(first.times[-1])
    n_pred = int(np.sum(clip.times > t_split + 1e-9))
    out.update(t_split=t_split, fit_s=t_last_fit, predict_s=duration - t_last_fit, n_fit=int(len(first.times)),
               n_predicted=n_pred, effects={k: dict(v) for k, v in current.effects.items()},
               label=f"forward gap (fit on the first {t_last_fit:.3g} s, predict the last "
                     f"{duration - t_last_fit:.3g} s)")
    if log:
        log(f"forward gap: fit on {t_last_fit:.3f} s, predict {n_pred} samples: "
            f"{out['before'] * 1e3:.2f} -> {out['after'] * 1e3:.2f} mm")
    return out
