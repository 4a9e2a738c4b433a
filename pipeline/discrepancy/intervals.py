"""Add: confidence intervals of the named effects' coefficients. The profile-likelihood
interval of each fitted coefficient of a converged joint fit (:func:`profile_intervals`,
checking the fit's Gauss-Newton interval ``fit.ci_gn`` where it can), their display
(:func:`format_interval`) and their coverage of the simulated truth over benchmark trials
(:func:`interval_coverage`).

The Gauss-Newton intervals themselves come with the joint fit (``fit.ci_gn``, computed in
:mod:`pipeline.discrepancy.fit` from its Jacobian)."""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np
from scipy.stats import chi2 as chi2_dist
from scipy.stats import t as student_t

from pipeline import effects as fx
from pipeline.discrepancy.fit import Fit
from pipeline.discrepancy.workspace import Workspace


PROFILE_ACCEPT_GN = 0.25
"""The predicted end of an interval (the parabola through the profile's centre points, else
the Gauss-Newton end) is accepted when the profile's rise there is within this fraction of
the threshold (the profile is quadratic enough)."""
PROFILE_PROBE = 2.0
"""Several coefficients (joint-fit profile points): the first point on each side lies this
many Gauss-Newton half-widths from the centre, where a quadratic profile has risen by this
squared times the threshold (4x), beyond the joint refits' scatter."""
PROFILE_GROW = 3.0
"""Outward step factor when the profile has not yet risen to the threshold."""
PROFILE_BISECT = 3
"""Most interpolation steps (Illinois regula falsi on the square root of the rise) to locate
a crossing (stops earlier when the rise is within :data:`PROFILE_TOL` of the threshold). Three:
the refits' own scatter sets the precision (on 8 clips of drag data, points 0.001 kg/m^3
apart differ by up to ~20 in chi-square, several times the threshold), not more steps."""
PROFILE_TOL = 0.1
"""A crossing is located when the profile's rise is within this fraction of the threshold
(10 % of the threshold in chi-square moves a quadratic profile's end by about 5 % of the
half-width)."""


def profile_intervals(ws: "Workspace", idx: Sequence[int], fit: Fit, log=None,
                      clip_profile: dict[float, list[float]] | None = None
                      ) -> tuple[dict[str, dict[str, list[float | None]]], dict[str, dict[str, str]], Fit | None]:
    """Profile-likelihood intervals of the fitted coefficients of ``fit`` (a converged joint fit
    with Gauss-Newton intervals ``fit.ci_gn``).

    The threshold is ``Δχ² = q s²``: ``q`` the chi-square(1) quantile at ``cfg.ci_level``
    (3.84 for 95 %), ``s² = χ²/dof`` of the fit (the residual variance factor; 1 when the
    noise model is right). A profile point fixes the coefficient, refits every other parameter
    (all clips' parameters and the other coefficients) to the tolerance from the fit's
    optimum, and its rise is ``χ²(point) − χ²(minimum)`` (with one coefficient the clips
    separate and are refitted one by one: small, well-conditioned fits). The minimum is the
    profile's own: the joint fit's value ``v`` and ``v ± h`` (``h`` the Gauss-Newton
    half-width) are profiled, and the vertex of the parabola through them too (at most ``h``
    beyond them); the lowest is the centre and its χ² the reference. (A joint fit of many clips stalls short of its
    optimum by a few χ² units, comparable with the threshold; measured with the joint fit as
    the reference, a 3-clip drag interval came out [7.505, 7.814] around 7.785 while the
    profile at 7.708 was already 4.4 below it.) With several coefficients (every point a joint
    fit) the centre is ``v`` and the reference the joint fit's own χ² (a refit there with the
    coefficient held gained 0.04 χ² on the 8-clip wind set of
    ``benchmarks/discrepancy_speed.py``; a stalled joint fit only widens the ends), unless a
    profile point comes out lower; each side's first point (step 1) of every coefficient in
    one pool map. Each side of each coefficient, from the centre:

    1. the predicted end is checked with one profile point: where the parabola through the
       centre and its two neighbouring profile points (:func:`_curvature`) rises by the
       threshold (``quadratic``), else the Gauss-Newton end (``gauss-newton``); a rise within
       :data:`PROFILE_ACCEPT_GN` of the threshold accepts it. (The Gauss-Newton half-width
       comes from the joint fit's Jacobian; with the clips refitted one by one the profile
       can be several times narrower, and then every end took several regula-falsi points.)
       With several coefficients the point lies :data:`PROFILE_PROBE` Gauss-Newton
       half-widths out instead, and where the profile has risen past the threshold there the
       end is where the parabola with its vertex at the centre through it crosses
       (``quadratic (profile at 2 Gauss-Newton half-widths)``): the joint refits scatter by
       a few chi-square units, as much as the threshold, so points at the threshold cannot
       locate it (on the 8-clip wind set of ``benchmarks/discrepancy_speed.py`` the search
       of step 2 took 20 joint fits, 119 s of the workflow's 278, and made wind_x's interval
       a sixth of the Gauss-Newton width).
    2. else the crossing is bracketed (outwards by :data:`PROFILE_GROW` up to the search
       bound) and located by Illinois regula falsi on the square root of the rise (exact for a
       quadratic profile; at most :data:`PROFILE_BISECT` steps) (``profile``);
    3. where the profile has not risen by the threshold at the search bound, the data cannot
       bound the coefficient on that side: it is ``None`` (open), never the bound (``open``).

    ``clip_profile``: where given and ``fit`` has one coefficient, filled with every profiled
    value ``{x: [chi2 of each clip of idx]}`` (each clip's own converged refit at ``x``: the
    per-clip profiles, from which :func:`_converged_heldout` takes the leave-one-clip-out
    coefficient). (Several coefficients: a least-squares quadratic through every clip's own
    refits at a stencil of values was tried for the intervals and the held-out coefficients;
    on 3 wind clips its residuals were 10 chi-square RMS, above the threshold of 6.3: the
    refits' basin scatter, see the known limit in ``docs/discrepancy.md``.)

    Returns:
        ``(ci, method, better)``: ``{effect: {parameter: [low|None, high|None]}}``,
        ``{effect: {parameter: "low method / high method"}}``, and the lowest-χ² profile point
        as a :class:`Fit` (all clips' parameters and every coefficient, ``k`` and
        ``theta_keys`` of ``fit``) where it is lower than ``fit`` by more than ``cfg.ftol``
        relative, else ``None``.
    """
    cfg = ws.cfg
    dof = max(fit.n - fit.k, 1)
    s2 = fit.rss / dof
    thr = float(chi2_dist.ppf(cfg.ci_level, 1)) * s2
    ci: dict[str, dict[str, list[float | None]]] = {}
    method: dict[str, dict[str, str]] = {}
    better: Fit | None = None
    joint = len(fit.theta_keys) > 1   # other coefficients free: every point a joint fit
    caches: dict[tuple[str, str], dict[float, float]] = {key: {} for key in fit.theta_keys}

    def half_width(e: str, p: str) -> float:
        """The Gauss-Newton half-width of ``e.p`` (mean of its finite sides), else 0.1 scale."""
        v0 = float(fit.effects[e][p])
        gn = (fit.ci_gn.get(e) or {}).get(p) or [None, None]
        h = [abs(g - v0) for g in gn if g is not None and np.isfinite(g) and abs(g - v0) > 0]
        return float(np.mean(h)) if h else 0.1 * fx.REGISTRY[e].parameters[p].scale

    def run(points: Sequence[tuple[str, str, float]], origin: Fit) -> None:
        """Profile the points ``(effect, parameter, value)`` not yet profiled, each from
        ``origin`` (with one coefficient every clip at every point in one pool map; with
        several, one joint fit per point, all in one pool map)."""
        nonlocal better
        new = list(dict.fromkeys((e, p, float(x)) for e, p, x in points if float(x) not in caches[(e, p)]))
        if not new:
            return
        # every point starts from one origin: the fit, or its refit at its own value where
        # that is lower (warm-starting from the nearest profiled point walked the clips
        # into other basins: on the DVC stage a point at the interval's end came out
        # lowest, lift 1.075 for a true 0.978)
        effs = [{k: {**dict(d), **({p: x} if k == e else {})} for k, d in origin.effects.items()}
                for e, p, x in new]
        if not joint:   # nothing else shared: the clips separate
            parts = ws.refit_each(list(idx) * len(new), list(origin.nuisance) * len(new),
                                  [eff for eff in effs for _ in idx], converge=True)
            n = len(idx)
            fits = []
            for j, ((e, p, _), eff) in enumerate(zip(new, effs)):
                part = parts[j * n:(j + 1) * n]
                fits.append(Fit(eff, [f.nuisance[0] for f in part], [f.chi2[0] for f in part],
                                [f.sq_pos[0] for f in part], [f.n_res[0] for f in part],
                                [f.n_pos[0] for f in part], fit.k, list(fit.theta_keys)))
                if clip_profile is not None:
                    clip_profile[float(eff[e][p])] = [f.chi2[0] for f in part]
        else:
            fits = ws.fit_joint_many([dict(idx=idx, starts=origin.nuisance, effects=eff, converge=True,
                                           fixed=[(e, p)]) for (e, p, _), eff in zip(new, effs)])
            for point in fits:
                point.k, point.theta_keys = fit.k, list(fit.theta_keys)
        for (e, p, x), point in zip(new, fits):
            caches[(e, p)][x] = point.rss
            if point.rss < (better or fit).rss - cfg.ftol * fit.rss:
                point.start = f"profile minimum ({e}.{p})"
                better = point
        if better is not None and joint:
            # a lower point found on one coefficient's profile bounds every other
            # coefficient's profile at its values (the profile minimises over the rest)
            for key, cache in caches.items():
                x = float(better.effects[key[0]][key[1]])
                cache[x] = min(cache.get(x, math.inf), better.rss)

    if joint:
        # Several coefficients: a first point on each side of each coefficient at
        # PROFILE_PROBE Gauss-Newton half-widths, all in one pool map. The centre is the
        # converged joint fit itself (the profile at v0 is at most its chi-square): refitting
        # it with one coefficient held gained 0.04 chi-square on the 8-clip wind set of
        # ``benchmarks/discrepancy_speed.py`` (for 2 of its 6 joint fits, 6 s of the workflow's
        # 74); a joint fit that stalled short would only widen the ends (its chi-square is the
        # reference), and a lower probe point becomes the reference (``better``).
        first = []
        for e, p in fit.theta_keys:
            spec, v0, h = fx.REGISTRY[e].parameters[p], float(fit.effects[e][p]), half_width(e, p)
            caches[(e, p)][v0] = fit.rss
            first += [(e, p, x) for x in (v0 - PROFILE_PROBE * h, v0 + PROFILE_PROBE * h)
                      if spec.low <= x <= spec.high]
        run(first, fit)

    for e, p in fit.theta_keys:
        spec = fx.REGISTRY[e].parameters[p]
        v0 = float(fit.effects[e][p])
        gn = (fit.ci_gn.get(e) or {}).get(p) or [None, None]
        cache = caches[(e, p)]
        origin = fit

        def totals(xs: Sequence[float]) -> list[float]:
            """The profile at each of ``xs`` (those not yet profiled, :func:`run`)."""
            run([(e, p, x) for x in xs], origin)
            return [cache[float(x)] for x in xs]

        def total(x: float) -> float:
            return totals([x])[0]

        # the profile's own minimum (centre) and its chi-square (reference)
        h = half_width(e, p)
        total(v0)   # one coefficient: the origin of the other points, the fit refitted at its own value
        if better is not None and (joint or better.effects[e][p] == v0):
            origin = better   # (one coefficient: this point, not an earlier coefficient's)
        if not joint:   # one coefficient (cheap per-clip points): the parabola through v0 +- h
            pts = [x for x in (v0 - h, v0, v0 + h) if spec.low <= x <= spec.high]
            totals(pts)
            curv = _curvature(cache)
            if curv is not None:   # the parabola's vertex, at most one step h beyond the points
                xm = float(np.clip(curv[1], min(pts) - h, max(pts) + h))
                if spec.low <= xm <= spec.high:
                    total(xm)
        v = min(cache, key=cache.get)
        ref = cache[v]
        curv = _curvature(cache) if not joint else None

        def side(sign: float, bound: float, g: float | None):
            """One side's search (a generator: yields each point whose rise it needs, is sent
            the rise, returns ``(end, how)``), so that both sides' points are profiled
            together (one pool map) without changing which points are profiled."""
            room = sign * (bound - v)
            if room <= 1e-9 * spec.scale:        # at the search bound: nothing beyond it to test
                return None, "open (at the search bound)"
            if curv is not None:   # where the parabola through the centre points crosses
                step, label = math.sqrt(thr / curv[0]), "quadratic (profile-checked)"
            elif g is not None and np.isfinite(g) and abs(g - v0) > 0:
                step, label = abs(g - v0), "gauss-newton (profile-checked)"
            else:
                step, label = spec.scale, ""
            if joint:
                # Several coefficients: the point at PROFILE_PROBE Gauss-Newton half-widths
                # (profiled with the centres); where the profile has risen past the threshold
                # there, the end is where the parabola with its vertex at the centre through that
                # point crosses it (the joint refits scatter by a few chi-square units, like the
                # threshold; at ~4x the threshold the scatter moves the end by ~10 %). Where a
                # lower point moved the centre off v0, a profiled point on this side at least
                # one half-width from it serves (the farthest), else a new one.
                near = [x for x in cache if sign * (x - v) >= h]
                x = max(near, key=lambda x: sign * (x - v)) if near else v + sign * min(PROFILE_PROBE * h, room)
                r = yield x
                if abs(x - v) > 0 and r >= thr and abs(x - bound) > 1e-12:
                    return float(v + sign * abs(x - v) * math.sqrt(thr / r)), \
                        f"quadratic (profile at {PROFILE_PROBE:g} Gauss-Newton half-widths)"
                label = ""
            else:
                x = v + sign * min(step, room)
                r = yield x
            if abs(x - bound) > 1e-12 and abs(r - thr) <= PROFILE_ACCEPT_GN * thr and label:
                return float(x), label
            inner, r_in = v, 0.0
            while r < thr and abs(x - bound) > 1e-12:
                inner, r_in = x, r
                x = v + sign * min(PROFILE_GROW * abs(x - v), room)
                r = yield x
            if r < thr:                           # never rose by the threshold before the bound
                return None, f"open (profile rise {r:.3g} < {thr:.3g} at the search bound {bound:g})"
            outer, r_out = x, r
            # Illinois regula falsi on g = sqrt(rise) - sqrt(threshold) (linear for a quadratic
            # profile); the end kept twice in a row has its g halved, so a steep far end (a
            # bound of another parameter becoming active) cannot stall it.
            g_in, g_out, kept = math.sqrt(r_in) - math.sqrt(thr), math.sqrt(r_out) - math.sqrt(thr), 0
            for _ in range(PROFILE_BISECT):
                xm = inner + (outer - inner) * (-g_in) / (g_out - g_in) if g_out > g_in else 0.5 * (inner + outer)
                rm = yield xm
                gm = math.sqrt(rm) - math.sqrt(thr)
                if abs(rm - thr) <= PROFILE_TOL * thr:
                    inner = outer = xm
                    break
                if gm < 0:
                    inner, g_in = xm, gm
                    kept = kept + 1 if kept > 0 else 1
                    if kept >= 2:
                        g_out *= 0.5
                else:
                    outer, g_out = xm, gm
                    kept = kept - 1 if kept < 0 else -1
                    if kept <= -2:
                        g_in *= 0.5
            t = (-g_in) / (g_out - g_in) if g_out > g_in else 0.5
            return float(inner + min(max(t, 0.0), 1.0) * (outer - inner)), "profile"

        # both sides in lockstep: their next points profiled together
        searches = [side(-1.0, spec.low, gn[0]), side(1.0, spec.high, gn[1])]
        found: list[tuple[float | None, str]] = [(None, ""), (None, "")]
        asks: dict[int, float] = {}
        for i, gen in enumerate(searches):
            try:
                asks[i] = next(gen)
            except StopIteration as stop:
                found[i] = stop.value
        while asks:
            rises = [max(t - ref, 0.0) for t in totals(list(asks.values()))]
            nxt: dict[int, float] = {}
            for (i, _), r in zip(asks.items(), rises):
                try:
                    nxt[i] = searches[i].send(r)
                except StopIteration as stop:
                    found[i] = stop.value
            asks = nxt
        ends, how = [f[0] for f in found], [f[1] for f in found]
        ci.setdefault(e, {})[p] = ends
        method.setdefault(e, {})[p] = " / ".join(how)
        if log:
            log(f"interval {e}.{p} = {v:.4g}: {format_interval(ends)} (joint fit {v0:.4g}, Gauss-Newton "
                f"{format_interval(gn)}; {len(cache)} profile fits; {method[e][p]})")
    return ci, method, better


def _curvature(cache: Mapping[float, float]) -> tuple[float, float] | None:
    """``(A, vertex)`` of the parabola ``A (x - vertex)^2 + c`` through the lowest profile
    point and its two neighbours in ``x`` (``cache``: ``{x: chi2}``); ``None`` with fewer
    than 3 points or where the parabola does not open upwards."""
    xs = np.array(sorted(cache))
    if len(xs) < 3:
        return None
    ys = np.array([cache[x] for x in xs])
    b = int(np.clip(np.argmin(ys), 1, len(xs) - 2))
    A, B, _ = np.polyfit(xs[b - 1:b + 2] - xs[b], ys[b - 1:b + 2], 2)
    if not A > 0:
        return None
    return float(A), float(xs[b] - B / (2 * A))


JACKKNIFE_MIN_CLIPS = 3
"""Fewest clips for a jackknife interval (with two, Student's t_1 makes it ~13 standard errors
wide and rests on one difference)."""


def jackknife_intervals(estimate: Mapping[str, Mapping[str, float]],
                        replicates: Sequence[Mapping[str, Mapping[str, float]] | None],
                        level: float = 0.95) -> dict[str, dict[str, list[float]]]:
    """Leave-one-clip-out jackknife intervals of the named coefficients.

    With ``n`` clips and ``theta_(i)`` the coefficient fitted without clip ``i`` (the shown
    gap's held-out coefficients), the jackknife standard error is
    ``sqrt((n-1)/n sum_i (theta_(i) - mean)^2)`` (Quenouille 1956, Tukey 1958; Efron & Stein
    1981) and the interval ``estimate +- t_{n-1}(1 - (1-level)/2) SE``. It measures how much
    the estimate moves with the data clip by clip, which the profile likelihood does not:
    per-clip refits that land in different basins (bounces between samples) make the profile
    scatter and its interval hug a stalled estimate (docs/discrepancy.md, "Known limit").

    Args:
        estimate: ``{effect: {parameter: value}}`` of the fit on all clips.
        replicates: per clip, the same fitted without that clip (``None``: not available).
        level: confidence level.

    Returns:
        ``{effect: {parameter: [low, high]}}`` for the fitted parameters of every effect of
        ``estimate`` (none with fewer than :data:`JACKKNIFE_MIN_CLIPS` replicates).
    """
    reps = [r for r in replicates if r]
    n = len(reps)
    out: dict[str, dict[str, list[float]]] = {}
    if n < JACKKNIFE_MIN_CLIPS:
        return out
    q = float(student_t.ppf(1.0 - (1.0 - level) / 2.0, n - 1))
    for e, params in estimate.items():
        for p, spec in fx.REGISTRY[e].parameters.items():
            if not spec.fit or p not in params or any(p not in r.get(e, {}) for r in reps):
                continue
            vals = np.array([float(r[e][p]) for r in reps])
            se = math.sqrt((n - 1) / n * float(np.sum((vals - vals.mean()) ** 2)))
            out.setdefault(e, {})[p] = [float(params[p]) - q * se, float(params[p]) + q * se]
    return out


def interval_union(a: Sequence[float | None] | None, b: Sequence[float | None] | None) -> list[float | None] | None:
    """The smallest interval holding both ``a`` and ``b`` (``[low, high]``, ``None`` an open
    side, which stays open); either may be ``None`` (absent)."""
    if a is None or b is None:
        return list(a if b is None else b) if (a is not None or b is not None) else None
    lo = None if a[0] is None or b[0] is None else min(a[0], b[0])
    hi = None if a[1] is None or b[1] is None else max(a[1], b[1])
    return [lo, hi]


def with_model_error(effect: str, parameters: Mapping[str, float], ci: Mapping[str, Sequence[float | None]],
                     rel: float) -> dict[str, list[float | None]]:
    """Intervals widened by an allowance for model mismatch.

    Each fitted coefficient ``v`` with an interval gets the smallest interval holding it and
    ``v +- rel * max(|v|, scale)`` (``scale``: the parameter's typical magnitude,
    :class:`pipeline.effects.ParamSpec`); an open side stays open. The profile likelihood
    measures the noise's effect on the estimate in a model taken as true; when the data come
    from elsewhere (another engine, the real world) the estimate also carries the model's
    systematic error, which no amount of data shrinks. On the independent benchmark
    (``--engine independent``) the profile intervals held the truth in 25 of 79 correctly
    named coefficients, with an allowance of 30 % (``DiscrepancyConfig.ci_model_error``) in
    71 of 79.

    Args:
        effect: effect name. parameters: its fitted values. ci: ``{parameter: [low, high]}``
            (``None``: open). rel: the allowance, a fraction (0: the intervals as given).

    Returns:
        ``{parameter: [low, high]}`` for the parameters of ``ci``.
    """
    specs = fx.REGISTRY[effect].parameters
    out: dict[str, list[float | None]] = {}
    for p, interval in ci.items():
        if interval is None or p not in parameters:
            continue
        v = float(parameters[p])
        a = rel * max(abs(v), specs[p].scale if p in specs else 0.0)
        lo, hi = interval
        out[p] = [None if lo is None else min(float(lo), v - a), None if hi is None else max(float(hi), v + a)]
    return out


def format_interval(ci: Sequence[float | None] | None, nd: int = 4) -> str:
    """An interval as text: ``[lo, hi]`` with ``nd`` significant digits, an open side
    (``None``) shown as ``(open`` / ``open)``, and ``"fixed"`` for no interval (``None`` or
    empty, a coefficient that was not fitted).

    Args:
        ci: ``[low | None, high | None]`` in the coefficient's units, or ``None``.
        nd: significant digits (``g`` format).
    """
    if not ci:
        return "fixed"
    lo, hi = ci
    left = "(open" if lo is None else f"[{lo:.{nd}g}"
    right = "open)" if hi is None else f"{hi:.{nd}g}]"
    return f"{left}, {right}"


def interval_coverage(rs: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """How often the reported intervals hold the simulated truth, over the trials ``rs`` whose
    named set is exactly right: every fitted coefficient of the named effect that the truth
    gives a value for counts once (a wind or a tilt twice), an open side holds everything on
    its side.

    Returns:
        ``{"ci_coverage": {"reported": {"held", "coefficients", "fraction"}, "profile": {...},
        "gauss_newton": {...}, "jackknife": {...}}}`` (``fraction`` ``None`` where nothing was
        counted; trials from before the jackknife, without ``named_ci_profile``, count their
        ``named_ci`` as the profile's). A calibrated 95 % interval holds the truth in ~95 %
        of coefficients.
    """
    out = {}
    for kind, column in (("reported", "named_ci"), ("profile", "named_ci_profile"),
                         ("gauss_newton", "named_ci_gauss_newton"), ("jackknife", "named_ci_jackknife")):
        held = total = 0
        for r in rs:
            if column == "named_ci_profile" and column not in r:
                column_r = "named_ci"          # reports from before the jackknife
            else:
                column_r = column
            if not (r.get("correct") and r.get("named")) or column_r not in r:
                continue
            truths = r.get("truth_parameters") or {}
            for p, ci in ((r[column_r] or {}).get(r["truth"]) or {}).items():
                if truths.get(p) is None or ci is None:
                    continue
                lo, hi = ci
                total += 1
                held += (lo is None or lo <= truths[p]) and (hi is None or truths[p] <= hi)
        out[kind] = {"held": held, "coefficients": total, "fraction": held / total if total else None}
    return {"ci_coverage": out}
