"""The hidden-effect benchmark: naming accuracy, false positives and gap shrink over trials
with a known hidden effect (``dynamics discrepancy-benchmark``)."""

from __future__ import annotations

import json
import time
from typing import Any, Mapping, Sequence

import numpy as np

from pipeline import effects as fx
from pipeline.discrepancy.config import DiscrepancyConfig
from pipeline.discrepancy.hidden import HiddenConfig, generate_hidden
from pipeline.discrepancy.independent import IndependentConfig, generate_independent
from pipeline.discrepancy.intervals import interval_coverage, with_model_error
from pipeline.discrepancy.readers import clips_from_columns
from pipeline.discrepancy.report import table_lines
from pipeline.discrepancy.workflow import run_workflow
from pipeline.mjcf import SimOptions
from pipeline.parallel import ComputeConfig, parallel_map


ENGINES = ("mujoco", "independent")
"""Generators of hidden-effect data: ``mujoco`` (the project's own scene -> MJCF -> MuJoCo
bridge, :func:`generate_hidden`) and ``independent`` (a hand-written integrator sharing nothing
with it, with outliers and dropped frames, :func:`generate_independent`)."""


def null_value(effect: str) -> dict[str, float]:
    """``{parameter: value}`` at which ``effect`` vanishes or is weakest: the first value of
    each fitted parameter's profile grid (:class:`pipeline.effects.ParamSpec`)."""
    return {p: spec.grid[0] for p, spec in fx.REGISTRY[effect].parameters.items() if spec.fit and spec.grid}


def null_valued(named: Sequence[Mapping[str, Any]]) -> list[str]:
    """The named effects that sit at their null value (:func:`null_value`): every fitted
    coefficient within 1e-3 of its scale of it, or inside its profile-likelihood interval
    (``ci_profile``, else ``ci``; an open side reaches the bound): the interval of the
    statistical test, not the reported one widened for model mismatch. Such a name adds
    nothing the data ask for.

    Args:
        named: ``Result.named`` entries (``effect``, ``parameters``, ``ci_profile`` / ``ci``).
    """
    out = []
    for n in named:
        specs = fx.REGISTRY[n["effect"]].parameters
        at_null = []
        for p, v0 in null_value(n["effect"]).items():
            v = n["parameters"].get(p, v0)
            ci = n.get("ci_profile", n.get("ci")) or {}
            lo, hi = ci.get(p) or (None, None)
            inside = (lo is None or lo <= v0) and (hi is None or v0 <= hi) and ci.get(p) is not None
            at_null.append(abs(v - v0) <= 1e-3 * specs[p].scale or inside)
        if at_null and all(at_null):
            out.append(n["effect"])
    return out


def run_trial(seed: int, effect: str, cfg: DiscrepancyConfig | None = None, hidden: HiddenConfig | None = None,
              options: SimOptions | None = None, engine: str = "mujoco",
              independent: IndependentConfig | None = None) -> dict[str, Any]:
    """One hidden-effect trial: generate data with ``effect`` (``none`` or a name) at a
    random strength, run the workflow on the measurements only, compare with the truth.

    Args:
        seed: data seed. effect: ``none`` or an effect name.
        cfg: workflow settings. options: simulation options of the workflow (and of the
            ``mujoco`` generator).
        engine: ``mujoco`` (data from :func:`generate_hidden` with ``hidden``) or
            ``independent`` (:func:`generate_independent` with ``independent``).

    Returns:
        ``{seed, engine, truth, truth_parameters, named, named_parameters, named_ci,
        named_ci_gauss_newton, null_valued, correct, gap_before, gap_after, shrink, noise,
        excess_shrink, outliers_dropped, runtime_s}`` (intervals ``{effect: {parameter:
        [low|None, high|None]}}``, ``None`` an open side; ``null_valued``: named effects at
        their null value, :func:`null_valued`).

    Raises:
        ValueError: unknown ``engine``.
    """
    t0 = time.perf_counter()
    if engine == "mujoco":   # the generator's base contact is the fits' (fit_options)
        cols, truth = generate_hidden(seed, hidden, options, effect=effect, fit=cfg)
    elif engine == "independent":
        cols, truth = generate_independent(seed, independent, effect=effect)
    else:
        raise ValueError(f"engine: must be one of {', '.join(ENGINES)}, got {engine!r}")
    clips = clips_from_columns(cols, f"<hidden seed {seed}>")
    result = run_workflow(clips, cfg, options)                  # never sees ``truth``
    named = [n["effect"] for n in result.named]
    expected = [truth["effect"]] if truth["effect"] else []
    gap = result.gap
    return {"seed": seed, "engine": engine, "truth": truth["effect"], "truth_parameters": truth["parameters"],
            "named": named, "null_valued": null_valued(result.named),
            "outliers_dropped": sum(len(v) for o in result.outliers.values() for v in o.values()),
            "named_parameters": {n["effect"]: n["parameters"] for n in result.named},
            "named_ci": {n["effect"]: n["ci"] for n in result.named},
            "named_ci_gauss_newton": {n["effect"]: n.get("ci_gauss_newton") or {} for n in result.named},
            "named_ci_profile": {n["effect"]: n.get("ci_profile", n["ci"]) for n in result.named},
            "named_ci_jackknife": {n["effect"]: n.get("ci_jackknife") or {} for n in result.named},
            "correct": named == expected, "gap_before": gap["before"], "gap_after": gap["after"],
            "shrink": gap["shrink"], "noise": gap["noise"], "excess_shrink": gap["excess_shrink"],
            "runtime_s": time.perf_counter() - t0}


def _trial_job(args: tuple) -> dict[str, Any]:
    """:func:`run_trial` of ``(seed, effect, cfg, hidden, options, engine, independent)`` (one
    picklable task)."""
    seed, effect, cfg, hidden, options, engine, independent = args
    return run_trial(seed, effect, cfg, hidden, options, engine, independent)


def run_benchmark(trials: int, null_trials: int, seed: int = 1000, jobs: int | ComputeConfig = 1,
                  cfg: DiscrepancyConfig | None = None, hidden: HiddenConfig | None = None,
                  options: SimOptions | None = None, log=None, single_trials: int = 0,
                  single_duration: float = 1.5, engine: str = "mujoco",
                  independent: IndependentConfig | None = None,
                  only: Sequence[str] | None = None) -> dict[str, Any]:
    """Naming accuracy over hidden-effect trials and false-positive rate over no-effect trials.

    Effect trials cycle through the library (so each effect gets ``trials / 6`` trials), each
    with a fresh seed (``seed + i``) and a random strength; no-effect trials use seeds after
    them.

    Args:
        trials: number of trials with a hidden effect.
        null_trials: number of trials without one.
        seed: first seed.
        jobs: local worker processes, or a :class:`pipeline.parallel.ComputeConfig` (e.g. Ray).
        cfg, hidden, options: workflow, data and simulation settings.
        log: optional ``print``-like callable (one line per finished trial).
        single_trials: further trials with a hidden effect (cycling the library) on ONE clip
            of ``single_duration`` s (the shown gap is then the forward gap), seeds after the
            no-effect trials; scored apart (``summary["single"]``, ``per_effect_single``).
        engine: data generator (:data:`ENGINES`); ``independent`` uses ``independent``'s
            settings (clips, noise, outliers, dropped frames) instead of ``hidden``'s.
        only: run only the trials whose hidden effect is one of these (``"none"``: the
            no-effect trials), with the seeds they have in the whole plan, e.g. to rerun one
            effect's trials after a change and :func:`merge` them into the earlier run.

    Naming is scored as the exact set: a trial is correct when the named effects are exactly
    the hidden one (or none), so an extra effect is a miss. ``gap_within_1p5_noise`` is the
    fraction of effect trials whose shown gap after naming is at most 1.5x the noise floor
    (the pooled noise estimate).

    Returns:
        ``{summary: {...}, per_effect: {...}, per_effect_single: {...}, trials: [...]}``
        (each trial has ``group``: ``effect``, ``null`` or ``single``).
    """
    if engine not in ENGINES:
        raise ValueError(f"engine: must be one of {', '.join(ENGINES)}, got {engine!r}")
    names = list(fx.EFFECTS)
    hidden = hidden or HiddenConfig()
    independent = independent or IndependentConfig()
    data = hidden if engine == "mujoco" else independent
    single = data.model_copy(update={"n_clips": 1, "duration": single_duration})
    plan = [(seed + i, names[i % len(names)], data) for i in range(trials)]
    plan += [(seed + trials + i, "none", data) for i in range(null_trials)]
    plan += [(seed + trials + null_trials + i, names[i % len(names)], single) for i in range(single_trials)]
    if only is not None:
        unknown = sorted(set(only) - set(names) - {"none"})
        if unknown:
            raise ValueError(f"only: unknown effect(s) {', '.join(unknown)}, must be among {', '.join(names)}, none")
        plan = [p for p in plan if p[1] in set(only)]
    cfg = cfg or DiscrepancyConfig()
    compute = jobs if isinstance(jobs, ComputeConfig) else ComputeConfig(workers=jobs)
    if compute.backend == "ray" or compute.n_workers > 1:  # one rollout thread per worker process
        cfg = cfg.model_copy(update={"threads": 1, "workers": 1})
    args = [(s, e, cfg, h if engine == "mujoco" else None, options, engine, h if engine == "independent" else None)
            for s, e, h in plan]
    t0 = time.perf_counter()
    results = []
    for r in parallel_map(_trial_job, args, compute):  # one trial per task: each takes seconds
        results.append(r)
        if log:
            log(f"[{len(results)}/{len(args)}] seed {r['seed']}: truth {r['truth']}, named {r['named']}, "
                f"gap {r['gap_before'] * 1e3:.2f} -> {r['gap_after'] * 1e3:.2f} mm")
    results.sort(key=lambda r: r["seed"])
    first_single = seed + trials + null_trials
    for r in results:
        r["group"] = "single" if r["seed"] >= first_single else ("effect" if r["truth"] else "null")
    bench = {"summary": {"engine": engine, "runtime_s": time.perf_counter() - t0,
                         "jobs": jobs if isinstance(jobs, int) else compute.model_dump(), "first_seed": seed,
                         "single": {"duration_s": single_duration}},
             "trials": results, "config": json.loads(cfg.model_dump_json()),
             "hidden": json.loads(data.model_dump_json())}
    return summarize(bench)


def summarize(bench: dict[str, Any]) -> dict[str, Any]:
    """Fill ``bench``'s ``summary`` (accuracy, false positives, null-valued names, gap shrink,
    interval coverage), ``per_effect`` and ``per_effect_single`` from its ``trials`` (each
    with ``group``: ``effect``, ``null`` or ``single``); returns ``bench``."""
    results = bench["trials"]
    names = list(fx.EFFECTS)
    eff = [r for r in results if r["group"] == "effect"]
    null = [r for r in results if r["group"] == "null"]
    one = [r for r in results if r["group"] == "single"]
    s = bench["summary"]
    s.update({**_bench_summary(eff), "effect_trials": len(eff), "null_trials": len(null),
              "false_positive_rate": sum(bool(r["named"]) for r in null) / len(null) if null else None,
              "null_valued_names": sum(len(r["null_valued"]) for r in results)})
    s["single"] = {**_bench_summary(one), "trials": len(one), "duration_s": s.get("single", {}).get("duration_s")}
    bench["per_effect"], bench["per_effect_single"] = _per_effect(eff, names), _per_effect(one, names)
    return bench


def merge(bench: dict[str, Any], rerun: dict[str, Any], command: str = "") -> dict[str, Any]:
    """``bench`` with the trials of ``rerun`` (a run of the same plan restricted with
    ``only``) put in place of those with the same seeds, and its summary recomputed.

    Args:
        bench: the whole earlier run (:func:`run_benchmark`'s output).
        rerun: the partial run; its trials' seeds must be in ``bench``, with the same group.
        command: the rerun's command line, recorded in ``bench["reruns"]`` with its seeds and
            runtime.

    Raises:
        ValueError: a rerun trial whose seed or group ``bench`` does not have (another plan).
    """
    by_seed = {r["seed"]: i for i, r in enumerate(bench["trials"])}
    for r in rerun["trials"]:
        i = by_seed.get(r["seed"])
        if i is None or bench["trials"][i]["group"] != r["group"]:
            raise ValueError(f"rerun: trial seed {r['seed']} ({r['group']}) is not in the earlier run's plan")
        bench["trials"][i] = r
    bench.setdefault("reruns", []).append({"command": command, "seeds": [r["seed"] for r in rerun["trials"]],
                                          "runtime_s": rerun["summary"]["runtime_s"]})
    return summarize(bench)


def rescore(bench: dict[str, Any], cfg: DiscrepancyConfig) -> dict[str, Any]:
    """A benchmark's reported intervals and null-valued names recomputed with ``cfg``'s rule
    (:func:`pipeline.discrepancy.intervals.with_model_error` of each trial's profile interval,
    ``named_ci_profile``), and its summary with them. Exact: the naming, the fits and the
    profile intervals do not depend on the reported interval, so a rerun of the trials would
    name the same effects with the same values and profile intervals.

    Args:
        bench: :func:`run_benchmark`'s output (trials with ``named_ci_profile``).
        cfg: settings (``ci_model_error``).

    Returns:
        ``bench`` with ``named_ci``, ``null_valued`` and the summary replaced and ``config``'s
        ``ci_model_error`` set; ``rescored`` records it.
    """
    for r in bench["trials"]:
        prof = r.get("named_ci_profile") or r["named_ci"]
        r["named_ci"] = {e: with_model_error(e, r["named_parameters"][e], prof.get(e) or {}, cfg.ci_model_error)
                         for e in r["named"]}
        r["null_valued"] = null_valued([{"effect": e, "parameters": r["named_parameters"][e],
                                         "ci_profile": prof.get(e) or {}} for e in r["named"]])
    bench["config"] = {**bench.get("config", {}), "ci_model_error": cfg.ci_model_error}
    bench["rescored"] = {"ci_model_error": cfg.ci_model_error}
    return summarize(bench)


def _bench_summary(rs: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Accuracy (exact set), gap-shrink figures and the fraction of trials whose shown gap after
    naming is within 1.5x the noise floor, over trials ``rs`` (``None`` where empty)."""
    coverage = interval_coverage(rs)
    if not rs:
        return {**coverage, "naming_accuracy": None, "shrink_at_least_50pct": None, "median_shrink": None,
                "excess_shrink_at_least_50pct": None, "median_excess_shrink": None, "gap_within_1p5_noise": None}
    n = len(rs)
    return {**coverage, "naming_accuracy": sum(r["correct"] for r in rs) / n,
            "shrink_at_least_50pct": sum(r["shrink"] >= 0.5 for r in rs) / n,
            "median_shrink": float(np.median([r["shrink"] for r in rs])),
            "excess_shrink_at_least_50pct": sum(r["excess_shrink"] >= 0.5 for r in rs) / n,
            "median_excess_shrink": float(np.median([r["excess_shrink"] for r in rs])),
            "gap_within_1p5_noise": sum(r["gap_after"] <= 1.5 * r["noise"] for r in rs) / n}


def _per_effect(rs: Sequence[Mapping[str, Any]], names: Sequence[str]) -> dict[str, dict[str, Any]]:
    per = {}
    for name in names:
        sub = [r for r in rs if r["truth"] == name]
        if sub:
            per[name] = {"trials": len(sub), "correct": sum(r["correct"] for r in sub),
                         "accuracy": sum(r["correct"] for r in sub) / len(sub),
                         "median_shrink": float(np.median([r["shrink"] for r in sub])),
                         "min_shrink": float(np.min([r["shrink"] for r in sub])),
                         "gap_within_1p5_noise": sum(r["gap_after"] <= 1.5 * r["noise"] for r in sub) / len(sub)}
    return per


def benchmark_markdown(bench: Mapping[str, Any], command: str = "") -> str:
    """Markdown summary of :func:`run_benchmark` (``reports/discrepancy_benchmark.md``):
    accuracy, false-positive rate and gap shrink (percent), per-effect tables and the misnamed
    trials; ``command`` is shown in a code block when given."""
    s = bench["summary"]
    pct = lambda x: "—" if x is None else f"{100 * x:.1f} %"  # noqa: E731
    h = bench["hidden"]
    engine = s.get("engine", "mujoco")
    source = ("the project's own MuJoCo model" if engine == "mujoco" else
              f"an independent hand-written integrator (`pipeline/discrepancy/independent.py`: step "
              f"{h['timestep'] * 1e3:g} ms, impulse bounces, isotropic drag; {100 * h['outlier_rate']:g} % outliers of "
              f"{h['outlier_size'][0] * 1e3:g}-{h['outlier_size'][1] * 1e3:g} mm, {100 * h['drop_rate']:g} % dropped frames)")
    lines = [f"# Discrepancy workflow: hidden-effect benchmark ({engine})", "",
             f"Each trial generates measured trajectories ({h['n_clips']} clips of {h['duration']:g} s, "
             f"noise {h['noise_position'] * 1e3:g} mm / {h['noise_angle']:g}°) with {source}, with one effect from the library "
             "at a random strength (or none), runs the workflow without telling it, and checks what it names.", ""]
    if command:
        lines += ["```", command, "```", ""]
    rows = [[f"naming accuracy ({s['effect_trials']} trials with a hidden effect)", pct(s['naming_accuracy'])],
            [f"false-positive rate ({s['null_trials']} trials without)", pct(s['false_positive_rate'])],
            ["named effects at their null value (all trials)", str(s.get('null_valued_names', '—'))],
            ["held-out gap shrink >= 50 % (effect trials)", pct(s['shrink_at_least_50pct'])],
            ["held-out gap above the noise shrink >= 50 %", pct(s.get('excess_shrink_at_least_50pct'))],
            ["median held-out gap shrink", pct(s['median_shrink'])],
            ["median shrink of the gap above the noise", pct(s.get('median_excess_shrink'))],
            ["held-out gap after naming within 1.5x the noise floor", pct(s.get('gap_within_1p5_noise'))]]
    one = s.get("single") or {}
    if one.get("trials"):
        rows += [[f"single clip ({one['trials']} trials, 1 clip of {one['duration_s']:g} s, forward gap): naming accuracy",
                  pct(one['naming_accuracy'])],
                 ["single clip: median forward-gap shrink / above the noise",
                  f"{pct(one['median_shrink'])} / {pct(one['median_excess_shrink'])}"],
                 ["single clip: forward gap after naming within 1.5x the noise floor", pct(one['gap_within_1p5_noise'])]]
    for kind, label in (("reported", "reported: profile widened by the model-mismatch allowance"), ("profile", "profile likelihood"),
                        ("gauss_newton", "Gauss-Newton"), ("jackknife", "leave-one-clip-out jackknife")):
        c = (s.get("ci_coverage") or {}).get(kind) or {}
        if c.get("coefficients"):
            rows.append([f"95 % intervals ({label}) holding the truth, correctly named effect trials",
                         f"{c['held']}/{c['coefficients']} = {pct(c['fraction'])}"])
    rows.append(["runtime", f"{s['runtime_s'] / 60:.1f} min ({s['jobs']} jobs)"])
    if bench.get("rescored"):
        rows.append(["reported intervals", f"rescored with ci_model_error {bench['rescored']['ci_model_error']:g} "
                                           "(`--rescore`: the naming does not depend on them)"])
    for rr in bench.get("reruns", []):
        rows.append(["rerun and merged", f"{len(rr['seeds'])} trials (seeds {', '.join(map(str, rr['seeds']))}), "
                                         f"{rr['runtime_s'] / 60:.1f} min: `{rr['command']}`"])
    lines += [*table_lines(["metric", "value"], rows), "",
              "Naming is scored as the exact set of named effects (an extra effect is a miss).", ""]
    for title, per in (("", bench["per_effect"]), ("single clip ", bench.get("per_effect_single") or {})):
        if not per:
            continue
        lines += table_lines([f"{title}effect", "trials", "correct", "accuracy", "median shrink", "min shrink",
                              "gap ≤ 1.5x noise"],
                             [[name, p['trials'], p['correct'], pct(p['accuracy']), pct(p['median_shrink']),
                               pct(p['min_shrink']), pct(p.get('gap_within_1p5_noise'))] for name, p in per.items()])
        lines.append("")
    wrong = [r for r in bench["trials"] if not r["correct"]]
    if wrong:
        lines += ["", "Misnamed trials:", "",
                  *table_lines(["seed", "group", "truth", "named", "gap before → after (mm)"],
                               [[r['seed'], r.get('group', ''), r['truth'] or 'none', ', '.join(r['named']) or 'none',
                                 f"{r['gap_before'] * 1e3:.2f} → {r['gap_after'] * 1e3:.2f}"] for r in wrong])]
    return "\n".join(lines) + "\n"
