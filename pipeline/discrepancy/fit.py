"""Least-squares fits of clips' base parameters and the effects' shared coefficients
(:func:`fit_clips`), their starting values, scales, bounds and free masks, and the
Gauss-Newton confidence intervals."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np
from scipy import stats
from scipy.optimize import least_squares
from threadpoolctl import threadpool_limits

from pipeline import effects as fx
from pipeline import geometry
from pipeline.discrepancy.clip_model import (NUISANCE, NUISANCE_ANGULAR_VELOCITY, NUISANCE_DAMPING, NUISANCE_FRICTION,
                                             NUISANCE_POSITION, NUISANCE_ROTATION, NUISANCE_VELOCITY, ClipModel,
                                             Weights, clip_residuals, clip_residuals_many, simulate_clips)
from pipeline.discrepancy.config import DiscrepancyConfig
from pipeline.discrepancy.trajectories import Clip, Track
from pipeline.rotation import quat_conj, quat_mul, quat_to_mat, quat_to_rotvec

try:   # an optional extra of MuJoCo; without it the same formula runs on a pseudo-inverse
    from mujoco import sysid
except ImportError:  # pragma: no cover
    sysid = None


def single_threaded_blas() -> threadpool_limits:
    """Context manager: every loaded BLAS (numpy's and scipy's OpenBLAS) on one thread inside
    the block, the previous counts restored after (``threadpoolctl``). The fits make thousands
    of small SVDs (scipy's trust region): on a loaded 2-core machine a threaded SVD of an
    880 x 45 Jacobian took 606 ms instead of 1.2 ms."""
    return threadpool_limits(limits=1, user_api="blas")


def nuisance_scales(clip: Clip, mask: np.ndarray) -> np.ndarray:
    """``(n, 14)`` typical magnitudes of the per-object parameters (normalisation); ``mask``
    the clip's free parameters (:func:`free_mask`).

    The free joint's damping ``b`` acts on all 6 DoF: its decay rate is ``b/m`` on linear and
    ``b/I`` on angular velocity (MuJoCo ``dof_damping``); it is scaled by the faster of the
    two that can act (0.01 s^-1 per unit). Where the ``mask`` (:func:`free_mask`) holds an
    object's spin at 0 (free flight, orientation unmeasured) only ``b/m`` acts: scaling by
    ``I`` there (a 0.4 g, 15 mm ball: I/m = 9e-5 m^2) put the drag-like damping 1e6 scale
    units away, beyond the trust region's reach, and the base fit stalled at 20 mm RMSE on a
    foam-ball drop.

    Args:
        clip: the clip (object shapes, sizes, masses).
        mask: ``(n, 14)`` bool free parameters (:func:`free_mask`).

    Returns:
        ``(n, 14)`` float64 scales in each parameter's units (:data:`NUISANCE`): 0.01 m,
        0.1 m/s, 0.1 rad, 1 rad/s, ``0.01 * rate`` N s/m and 0.1 (friction).
    """
    out = []
    for i, tr in enumerate(clip.tracks):
        inertia = geometry.min_inertia(tr.spec.shape, tr.spec.size, tr.spec.mass)
        rate = min(tr.spec.mass, inertia) if mask[i, NUISANCE_ANGULAR_VELOCITY].any() else tr.spec.mass
        s = np.array([0.01] * 3 + [0.1] * 3 + [0.1] * 3 + [1.0] * 3 + [0.01 * rate, 0.1])
        out.append(s)
    return np.array(out)


def nuisance_bounds(clip: Clip) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the per-object parameters: only damping (>= 0) and friction ([0.01, 3]: a
    zero coefficient switches MuJoCo to condim 1) are bounded; far artificial bounds on the
    others would distort scipy's reflective trust region (Coleman-Li scaling).

    Returns:
        ``(lower, upper)``: two ``(n, 14)`` float64 arrays (``n`` objects of ``clip``;
        ``±inf`` where unbounded), in the parameters' units (:data:`NUISANCE`).
    """
    inf = math.inf
    lo = [[-inf] * 12 + [0.0, 0.01] for _ in clip.tracks]
    hi = [[inf] * 12 + [inf, 3.0] for _ in clip.tracks]
    return np.array(lo), np.array(hi)


def _near_floor(tr: Track, tol: float) -> bool:
    """Whether the measured object ever comes within ``tol`` of the floor (contacts possible)."""
    if not tr.axes[2]:
        return False
    R = quat_to_mat(tr.quat) if tr.quat is not None else np.eye(3)[None].repeat(len(tr.t), 0)
    h = tr.pos[:, 2] - tr.spec.support_height(R)
    return bool(np.min(h) < max(tol, 0.02))


def free_mask(clip: Clip, effects: Sequence[str], cfg: DiscrepancyConfig) -> np.ndarray:
    """``(n, 14)`` bool: which base parameters are fitted for this clip.

    Frozen: the damping when ``cfg.hold_damping``; position/velocity of unobserved axes; for
    objects that never come near the floor
    the friction (no contact), and, without measured orientation, the orientation and the
    angular velocity (held at 0): they cannot change the measured positions, except through
    ``magnus_lift``, whose lift multiplies the spin; with the spin unobserved the two are not
    separately identifiable, so Magnus lift cannot be named from positions of a free flight.
    """
    masks = []
    for tr in clip.tracks:
        m = np.ones(len(NUISANCE), bool)
        m[NUISANCE_POSITION] = tr.axes
        m[NUISANCE_VELOCITY] = tr.axes
        contact = _near_floor(tr, cfg.contact_tolerance) or len(clip.tracks) > 1
        if not contact:
            m[NUISANCE_FRICTION] = False
        if cfg.hold_damping:
            m[NUISANCE_DAMPING] = False
        if tr.quat is None:
            if not contact or tr.spec.shape == "sphere":
                m[NUISANCE_ROTATION] = False
            if not contact:  # spin unobserved: held at 0 (so magnus_lift cannot act either)
                m[NUISANCE_ANGULAR_VELOCITY] = False
        masks.append(m)
    return np.array(masks)


def initial_nuisance(clip: Clip) -> np.ndarray:
    """``(n, 14)`` starting values from the data: position and velocity from a quadratic over
    the first 6 samples (an object starting on the floor: vertical velocity 0), orientation =
    first measured sample, angular velocity = slope of the world-frame rotation over the
    first 6 samples, no damping, friction 0.5."""
    out = []
    for tr in clip.tracks:
        x = np.zeros(len(NUISANCE))
        k = min(len(tr.t), 6)
        tt = tr.t[:k] - tr.t[0]
        A = np.stack([np.ones(k), tt, tt * tt], 1)
        coef = np.linalg.lstsq(A, tr.pos[:k], rcond=None)[0]
        x[NUISANCE_POSITION] = np.where(tr.axes, coef[0], 0.0)
        x[NUISANCE_VELOCITY] = np.where(tr.axes, coef[1], 0.0)
        if tr.quat is not None:  # slope of the accumulated world-frame rotation increments
            inc = quat_to_rotvec(quat_mul(tr.quat[1:k], quat_conj(tr.quat[:k - 1])))
            rv = np.concatenate([np.zeros((1, 3)), np.cumsum(inc, 0)])
            x[NUISANCE_ANGULAR_VELOCITY] = np.linalg.lstsq(tt[:, None], rv, rcond=None)[0][0]
        if tr.axes[2]:  # starting on the floor: no vertical velocity, not below its support
            R = quat_to_mat(tr.quat[0]) if tr.quat is not None else np.eye(3)
            hc = float(tr.spec.support_height(R))
            if x[2] - hc < 0.005:
                x[2], x[5] = max(x[2], hc), 0.0
        x[NUISANCE_FRICTION] = 0.5
        out.append(x)
    return np.array(out)


@dataclass
class Fit:
    """Result of a least-squares fit over clips.

    Attributes:
        effects: ``{name: all parameter values}`` of the model's effects.
        nuisance: per clip ``(n, 14)`` fitted base parameters.
        chi2: per clip sum of squared noise-normalised residuals.
        sq_pos: per clip sum of squared position residuals, m^2.
        n_res: per clip number of residual scalars; n_pos: of position residuals.
        k: number of fitted parameters.
        theta_keys: ``(effect, parameter)`` of the fitted effect coefficients.
        ci: ``{effect: {parameter: [low, high]}}`` confidence intervals (joint fits only).
        nfev: function evaluations (each = one rollout per clip).
        status: scipy ``least_squares`` status of the last optimiser run (0: the evaluation
            cap was reached; 1-4: a tolerance was met; -2: no free parameter / not run).
        iterations: the optimiser's function evaluations (``sol.nfev``; Jacobians not counted).
        converged: fitted with the converged settings (``cfg.ftol``) and stopped on a tolerance.
        start: which start the fit came from (candidates: ``profile`` or ``base optimum``).
        ci_gn: Gauss-Newton intervals (unclipped, may pass the search bounds).
        ci_method: ``{effect: {parameter: how its interval was found}}``.
        stages: per-clip continuation fits only: ``{horizon index: nuisance}`` after each
            early horizon (resume points, :meth:`Workspace.fit_clip`).
        clip_info: joint fits ``with_ci`` only: each clip's Gauss-Newton information on the
            coefficients at the fit's point (:func:`clip_information`: ``theta`` ``(m,)``,
            ``H`` ``(clips, m, m)``, ``g`` ``(clips, m)``), from which
            :func:`newton_leave_one_out` predicts each clip's held-out coefficients.
    """

    effects: dict[str, dict[str, float]]
    nuisance: list[np.ndarray]
    chi2: list[float]
    sq_pos: list[float]
    n_res: list[int]
    n_pos: list[int]
    k: int
    theta_keys: list[tuple[str, str]] = field(default_factory=list)
    ci: dict[str, dict[str, list[float]]] = field(default_factory=dict)
    nfev: int = 0
    status: int = -2
    iterations: int = 0
    converged: bool = False
    start: str = ""
    ci_gn: dict[str, dict[str, list[float | None]]] = field(default_factory=dict)
    ci_method: dict[str, dict[str, str]] = field(default_factory=dict)
    stages: dict[int, np.ndarray] = field(default_factory=dict)
    clip_info: dict[str, np.ndarray] = field(default_factory=dict)

    def optimizer(self) -> dict[str, Any]:
        """``{status, iterations, rollouts, converged, start}`` of the fit (report)."""
        return {"status": int(self.status), "iterations": int(self.iterations), "rollouts": int(self.nfev),
                "converged": bool(self.converged), "start": self.start}

    @property
    def n(self) -> int:
        """Number of residual scalars over all clips."""
        return int(sum(self.n_res))

    @property
    def rss(self) -> float:
        """Chi-square over all clips: sum of squared noise-normalised residuals."""
        return float(sum(self.chi2))

    @property
    def rmse(self) -> float:
        """m, position RMSE over all clips."""
        return math.sqrt(sum(self.sq_pos) / max(sum(self.n_pos), 1))

    @property
    def bic(self) -> float:
        """Gaussian BIC with the noise scale profiled out: ``n ln(RSS/n) + k ln n``
        (Schwarz 1978; RSS of noise-normalised residuals)."""
        n = self.n
        return n * math.log(max(self.rss, 1e-300) / n) + self.k * math.log(n)


def coefficient_keys(effects: Sequence[str]) -> list[tuple[str, str]]:
    """The fitted coefficients of ``effects`` (effect names): ``[(effect, parameter)]`` for every
    parameter with ``ParamSpec.fit``, in registry order (the order of a fit's ``theta``);
    names not in ``pipeline.effects.REGISTRY`` are ignored."""
    return [(e, p) for e in fx.REGISTRY if e in effects for p, s in fx.REGISTRY[e].parameters.items() if s.fit]


def _effect_values(start: Mapping[str, Mapping[str, float]], keys: Sequence[tuple[str, str]],
                   theta: np.ndarray) -> dict[str, dict[str, float]]:
    vals = {e: dict(p) for e, p in start.items()}
    for (e, p), v in zip(keys, theta):
        vals[e][p] = float(v)
    return vals


def bounded_effect_values(start: Mapping[str, Mapping[str, float]], keys: Sequence[tuple[str, str]],
                          theta: np.ndarray) -> dict[str, dict[str, float]]:
    """``start`` with the coefficients ``keys`` set to ``theta``, each clipped to its search
    bounds (``ParamSpec.low``/``high``): e.g. a leave-one-out Newton step.

    Args:
        start: ``{effect: {parameter: value}}`` (copied, not changed).
        keys: ``(effect, parameter)`` per coefficient (:func:`coefficient_keys`); each effect
            must be in ``start`` (``KeyError`` otherwise).
        theta: ``(len(keys),)`` float coefficient values in the parameters' own units.

    Returns:
        A new ``{effect: {parameter: value}}`` with plain floats.
    """
    specs = [fx.REGISTRY[e].parameters[p] for e, p in keys]
    return _effect_values(start, keys, np.clip(theta, [s.low for s in specs], [s.high for s in specs]))


def broyden_blocks(J: np.ndarray, du: np.ndarray, dr: np.ndarray, rows: np.ndarray, offs: np.ndarray
                   ) -> np.ndarray:
    """Broyden's rank-one update of a block-sparse least-squares Jacobian, block by block.

    ``J_new = J + (dr - J du) du^T / (du^T du)`` (Broyden, Math. Comp. 19, 1965, the "good"
    update; Nocedal & Wright, *Numerical Optimization*, eq. 11.28) applied to each clip's rows
    with only that clip's own columns and the shared coefficients' columns, so that the zeros
    between clips (a clip's residuals do not depend on another clip's parameters) stay zero.

    Args:
        J: ``(n_res, n_par)`` float64 Jacobian at the previous point.
        du: ``(n_par,)`` step from the previous point; dr: ``(n_res,)`` change of the residuals.
        rows: ``(n_clips + 1,)`` int row offsets of the clips; offs: ``(n_clips + 1,)`` int column
            offsets of their own parameters (the shared coefficients follow ``offs[-1]``).
    Returns:
        ``(n_res, n_par)`` float64 updated Jacobian (a copy; blocks whose step is zero unchanged).
    """
    J = J.copy()
    shared = np.arange(offs[-1], J.shape[1])
    for c in range(len(rows) - 1):
        cols = np.concatenate([np.arange(offs[c], offs[c + 1]), shared])
        d = du[cols]
        dd = float(d @ d)
        if dd <= 0.0:
            continue
        blk = J[rows[c]:rows[c + 1]][:, cols]
        J[rows[c]:rows[c + 1], cols] = blk + np.outer(dr[rows[c]:rows[c + 1]] - blk @ d, d) / dd
    return J


def fit_clips(clips: Sequence[Clip], models: Sequence[ClipModel], weights: Sequence[Weights],
              start_nuisance: Sequence[np.ndarray], start_effects: Mapping[str, Mapping[str, float]],
              cfg: DiscrepancyConfig, fit_effects: bool = True, with_ci: bool = False,
              max_nfev: int | None = None, converge: bool = False,
              fixed: Sequence[tuple[str, str]] = ()) -> Fit:
    """Least-squares fit of the clips' base parameters, and (``fit_effects``) the effects'
    shared coefficients, to the measured trajectories.

    The Jacobian is computed by forward differences clip by clip (a clip's residuals depend
    only on its own parameters and the shared coefficients), so one Jacobian costs one
    rollout per free parameter of each clip plus one rollout of every clip per coefficient;
    all clips' rollouts of one evaluation (or one Jacobian) go to MuJoCo in one batched call
    (:func:`simulate_clips`, on the models' ``threads``).
    Parameters are normalised by their scale (:func:`nuisance_scales`, ``ParamSpec.scale``).

    Args:
        clips, models, weights: per clip, aligned.
        start_nuisance: per clip ``(n, 14)`` starting values.
        start_effects: ``{effect: all parameters}`` starting (or fixed) values.
        cfg: settings (``max_nfev``, ``diff_step``, ``ci_level``).
        fit_effects: fit the effects' coefficients (else they stay at ``start_effects``).
        with_ci: compute confidence intervals of the coefficients.
        max_nfev: overrides ``cfg.max_nfev`` (``cfg.max_nfev_converged`` if ``converge``).
        converge: stop on the tolerance ``cfg.ftol`` (``xtol``, ``gtol`` 100x smaller) with
            ``cfg.max_nfev_converged`` as a safety cap only; else the screening settings
            (``cfg.screen_ftol``, ``max_nfev``).
        fixed: ``(effect, parameter)`` coefficients held at ``start_effects`` (profile
            likelihood).

    Returns:
        :class:`Fit`.
    """
    effects = list(start_effects)
    keys = [k for k in coefficient_keys(effects) if k not in set(fixed)] if fit_effects else []
    masks = [free_mask(c, effects, cfg) for c in clips]
    scales = [nuisance_scales(c, m) for c, m in zip(clips, masks)]
    bounds = [nuisance_bounds(c) for c in clips]
    starts = [np.clip(s.copy(), b[0], b[1]) for s, b in zip(start_nuisance, bounds)]
    for s0, sc, m in zip(starts, scales, masks):  # off the damping bound: trf stalls on an active bound
        s0[:, NUISANCE_DAMPING] = np.where(m[:, NUISANCE_DAMPING],
                                           np.maximum(s0[:, NUISANCE_DAMPING], 1e-3 * sc[:, NUISANCE_DAMPING]),
                                           s0[:, NUISANCE_DAMPING])
    n_theta = len(keys)
    th_spec = [fx.REGISTRY[e].parameters[p] for e, p in keys]
    th_scale = np.array([s.scale for s in th_spec])
    th_lo = np.array([s.low for s in th_spec])
    th_hi = np.array([s.high for s in th_spec])
    th0 = np.array([start_effects[e][p] for e, p in keys])
    th0 = np.clip(th0, th_lo + 1e-3 * th_scale, th_hi - 1e-3 * th_scale) if n_theta else th0  # off bounds

    sizes = [int(m.sum()) for m in masks]
    offs = np.concatenate([[0], np.cumsum(sizes)]).astype(int)

    # Normalised coordinates relative to the start: u = (x - x_start) / scale, so the trust
    # region starts at radius 1 (one typical magnitude) and scipy's xtol test, relative to
    # |u|, cannot stop the fit at its first rejected steps.
    x_start = np.concatenate([starts[c][masks[c]] for c in range(len(clips))] + [th0])
    x_scale = np.concatenate([scales[c][masks[c]] for c in range(len(clips))] + [th_scale])
    x_lo = np.concatenate([bounds[c][0][masks[c]] for c in range(len(clips))] + [th_lo])
    x_hi = np.concatenate([bounds[c][1][masks[c]] for c in range(len(clips))] + [th_hi])

    def unpack(u: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
        xs = x_start + u * x_scale
        nuis = []
        for c in range(len(clips)):
            x = starts[c].copy()
            x[masks[c]] = xs[offs[c]:offs[c + 1]]
            nuis.append(x)
        return nuis, xs[offs[-1]:]

    u0 = np.zeros(len(x_start))
    lo, hi = (x_lo - x_start) / x_scale, (x_hi - x_start) / x_scale
    counter = {"nfev": 0}

    threads = max(m.threads for m in models) if models else 1
    cache: dict[bytes, list[np.ndarray]] = {}

    def all_res(u: np.ndarray) -> list[np.ndarray]:
        key = u.tobytes()
        if key not in cache:
            nuis, theta = unpack(u)
            values = _effect_values(start_effects, keys, theta)
            cache.clear()
            counter["nfev"] += len(clips)
            qs = simulate_clips([(models[c], [nuis[c]], [values]) for c in range(len(clips))], threads)
            cache[key] = [clip_residuals(clips[c], qs[c][0], weights[c])[0] for c in range(len(clips))]
        return cache[key]

    def fun(u: np.ndarray) -> np.ndarray:
        return np.concatenate(all_res(u))

    rows = np.concatenate([[0], np.cumsum([len(r) for r in all_res(u0)])]).astype(int)
    h = cfg.diff_step

    last: dict[str, Any] = {}                          # the last Jacobian, for Broyden updates
    refresh = cfg.jac_refresh

    def jac(u: np.ndarray) -> np.ndarray:
        base = all_res(u)
        if refresh == 1:                               # the default: no Broyden bookkeeping
            return fd_jac(u, base)
        r = np.concatenate(base)
        if last and last["age"] < refresh - 1:
            J, age = broyden_blocks(last["J"], u - last["u"], r - last["r"], rows, offs), last["age"] + 1
        else:
            J, age = fd_jac(u, base), 0
        last.update(J=J, u=u.copy(), r=r, age=age)
        return J

    def fd_jac(u: np.ndarray, base: list[np.ndarray]) -> np.ndarray:
        nuis, theta = unpack(u)
        values = _effect_values(start_effects, keys, theta)
        J = np.zeros((rows[-1], len(u)))
        th_steps = [h if u[offs[-1] + j] + h <= hi[offs[-1] + j] else -h for j in range(n_theta)]
        th_values = []
        for j in range(n_theta):
            th = theta.copy()
            th[j] += th_steps[j] * th_scale[j]
            th_values.append(_effect_values(start_effects, keys, th))
        requests, columns = [], []
        for c in range(len(clips)):  # every clip's variants: its columns + the coefficients
            free = np.flatnonzero(masks[c].ravel())
            variants, steps = [], []
            for j, flat in enumerate(free):
                col = offs[c] + j
                step = h if u[col] + h <= hi[col] else -h
                x = nuis[c].copy().ravel()
                x[flat] += step * scales[c].ravel()[flat]
                variants.append(x.reshape(nuis[c].shape))
                steps.append(step)
            effs = [values] * len(variants) + th_values
            variants += [nuis[c]] * n_theta
            counter["nfev"] += len(variants)
            requests.append((models[c], variants, effs))
            columns.append(([offs[c] + j for j in range(len(free))] + [offs[-1] + j for j in range(n_theta)],
                            steps + th_steps))
        # one rollout call for all clips' variants (both cores busy; same numbers as per clip)
        for c, qs in enumerate(simulate_clips(requests, threads)):
            if len(qs):
                cols, steps = columns[c]
                res = clip_residuals_many(clips[c], qs, weights[c])[0]
                J[rows[c]:rows[c + 1], cols] = ((res - base[c][None]) / np.asarray(steps)[:, None]).T
        return J

    status, iterations = -2, 0
    if len(u0):
        if converge:
            cap, ftol = max_nfev or cfg.max_nfev_converged, cfg.ftol
        else:
            cap, ftol = max_nfev or cfg.max_nfev, cfg.screen_ftol
        sol = least_squares(fun, u0, jac=jac, bounds=(lo, hi), method="trf", x_scale=1.0,
                            max_nfev=cap, ftol=ftol, xtol=min(1e-8, ftol * 1e-2), gtol=min(1e-8, ftol * 1e-2))
        u, status, iterations = sol.x, int(sol.status), int(sol.nfev)
    else:
        u = u0
    nuis, theta = unpack(u)
    values = _effect_values(start_effects, keys, theta)
    chi2, sq, n_res, n_pos = [], [], [], []
    final = simulate_clips([(models[c], [nuis[c]], [values]) for c in range(len(clips))], threads)
    for c in range(len(clips)):
        r, d = clip_residuals(clips[c], final[c][0], weights[c])
        chi2.append(float(r @ r))
        sq.append(float(d @ d))
        n_res.append(int(r.size))
        n_pos.append(int(d.size))
    fit = Fit(values, nuis, chi2, sq, n_res, n_pos, k=len(u), theta_keys=keys, nfev=counter["nfev"],
              status=status, iterations=iterations, converged=bool(converge and status > 0))
    if with_ci and n_theta:
        J, r = fd_jac(u, all_res(u)), fun(u)
        fit.ci_gn = _intervals(J, r, keys, th_scale, theta, offs[-1], cfg.ci_level)
        fit.clip_info = clip_information(J, r, rows, offs, th_scale, theta)
        fit.ci = {e: {p: list(v) for p, v in d.items()} for e, d in fit.ci_gn.items()}
        fit.ci_method = {e: {p: "gauss-newton" for p in d} for e, d in fit.ci_gn.items()}
    return fit


def clip_information(J: np.ndarray, r: np.ndarray, rows: np.ndarray, offs: np.ndarray, th_scale: np.ndarray,
                     theta: np.ndarray) -> dict[str, np.ndarray]:
    """Each clip's Gauss-Newton information on the shared coefficients, its own parameters
    profiled out to first order.

    For clip ``c`` with residuals ``r_c`` and Jacobian blocks ``A`` (its own parameters) and
    ``B`` (the coefficients, physical units): ``B_perp = (I - P_A) B`` (``P_A`` the projection
    onto ``A``'s columns), ``H_c = B_perp^T B_perp`` (Schur complement of ``A^T A`` in the
    clip's ``J^T J``) and ``g_c = B_perp^T r_c`` (gradient of ``chi2_c / 2`` over the
    coefficients with the clip's parameters refitted, to first order).

    Args:
        J: ``(N, P)`` Jacobian of the stacked residuals in the fit's normalised coordinates
            (clips' columns at ``offs``, the coefficients last, normalised by ``th_scale``).
        r: ``(N,)`` noise-normalised residuals; rows: ``(clips + 1,)`` clip row offsets.
        offs: ``(clips + 1,)`` column offsets; th_scale: ``(m,)``; theta: ``(m,)`` the
            coefficients at this point.

    Returns:
        ``{"theta": (m,), "H": (clips, m, m), "g": (clips, m)}`` float64.
    """
    first = int(offs[-1])
    H, g = [], []
    for c in range(len(rows) - 1):
        Jc, rc = J[rows[c]:rows[c + 1]], r[rows[c]:rows[c + 1]]
        A, B = Jc[:, offs[c]:offs[c + 1]], Jc[:, first:] / th_scale
        if A.shape[1]:
            B = B - A @ np.linalg.lstsq(A, B, rcond=None)[0]
        H.append(B.T @ B)
        g.append(B.T @ rc)
    return {"theta": np.asarray(theta, float).copy(), "H": np.array(H), "g": np.array(g)}


def newton_leave_one_out(info: Mapping[str, np.ndarray], c: int) -> np.ndarray:
    """``(m,)`` the coefficients fitted to every clip but ``c``, predicted by one Gauss-Newton
    step from the joint fit's point with the other clips' information alone
    (:func:`clip_information`): ``theta - (sum_{k != c} H_k)^+ sum_{k != c} g_k``
    (approximate leave-one-out, Rad & Maleki 2020, JRSS-B 82(4), "A scalable estimate of the
    out-of-sample prediction error via approximate leave-one-out"; exact where each clip's
    profile is quadratic in the coefficients). Nothing of clip ``c`` enters but the point the
    step starts from."""
    keep = np.arange(len(info["g"])) != c
    H, g = info["H"][keep].sum(0), info["g"][keep].sum(0)
    return info["theta"] - np.linalg.pinv(H) @ g


def _intervals(J: np.ndarray, r: np.ndarray, keys: Sequence[tuple[str, str]], th_scale: np.ndarray,
               theta: np.ndarray, first: int, level: float) -> dict[str, dict[str, list[float]]]:
    """Confidence intervals of the coefficients from the Jacobian at the optimum:
    covariance ``s^2 (J^T J)^-1`` with ``s^2 = RSS / (n - p)`` (nuisance parameters
    marginalised by the full inverse), half-width ``t_{n-p}(1 - alpha/2) sqrt(diag)``;
    computed by ``mujoco.sysid.calculate_intervals`` (falls back to the same formula with a
    pseudo-inverse where that is not finite). Not clipped to the search bounds (``None`` where
    not finite); :func:`profile_intervals` checks them against the profile."""
    alpha = 1.0 - level
    Jp = J.copy()
    Jp[:, first:] = Jp[:, first:] / th_scale  # normalised -> physical units
    half = np.full(len(keys), np.nan)
    if sysid is not None:
        _, half = sysid.calculate_intervals([r], Jp, alpha=alpha)
        half = np.asarray(half)[first:]
    if not np.all(np.isfinite(half)):
        # e.g. a parameter without effect on the data (spin of a sphere in free flight) makes
        # J^T J singular and sysid's inverse non-finite: pseudo-inverse (the same formula)
        dof = max(len(r) - J.shape[1], 1)
        cov = float(r @ r) / dof * np.linalg.pinv(Jp.T @ Jp)
        half = np.sqrt(np.maximum(np.diag(cov)[first:], 0)) * stats.t.ppf(1 - alpha / 2, dof)
    out: dict[str, dict[str, list[float | None]]] = {}
    for (e, p), v, hw in zip(keys, theta, half):   # not clipped to the search bounds
        out.setdefault(e, {})[p] = [float(v - hw), float(v + hw)] if np.isfinite(hw) else [None, None]
    return out
