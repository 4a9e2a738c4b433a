"""Add and show: the extended scenes, the JSON and Markdown reports, and :func:`write_report`,
which writes them with the plots and the rerun recording."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import yaml
from tabulate import tabulate

from pipeline.atomic import write_json, write_text
from pipeline.discrepancy.clip_model import clip_scene
from pipeline.discrepancy.config import DISCREPANCY_DECIMALS
from pipeline.discrepancy.intervals import format_interval
from pipeline.discrepancy.plots import plot_residuals, plot_trajectories, record, safe_file_name
from pipeline.discrepancy.workflow import Result
from pipeline.scene import Decimals, Scene


def extended_scenes(result: Result) -> dict[str, Scene]:
    """One scene per clip: the final fit's initial state and material for every object and
    the named effects' ``effects:`` block (all parameters, fixed ones included)."""
    out = {}
    for c, clip in enumerate(result.clips):
        qref = np.array([tr.quat[0] if tr.quat is not None else np.array([1.0, 0, 0, 0]) for tr in clip.tracks])
        effects = {n["effect"]: n["parameters"] for n in result.named}
        out[clip.name] = clip_scene(clip, result.final.nuisance[c], effects, qref)
    return out


def _fmt(x: float | None, scale: float = 1.0, nd: int = 2) -> str:
    return "—" if x is None else f"{x * scale:.{nd}f}"


def report_dict(result: Result, files: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The JSON report (see ``docs/discrepancy.md`` for the fields). Lengths in m, angles in
    deg; ``gap`` is the shown gap, position RMSE before (base model) and after (named
    effects): leave-one-clip-out held-out with >= 2 clips, forward in time with one
    (``gap.kind``, ``gap.label``, ``gap.why``, :attr:`Result.gap`); ``in_sample`` is the
    in-sample RMSE before/after with the number of fitted parameters ``k`` of each."""
    clips = []
    for c, clip in enumerate(result.clips):
        nz = result.noise[c]
        clips.append({
            "clip": clip.name, "source": clip.source, "t0": clip.t0, "z_offset": clip.z_offset,
            "n_samples": int(len(clip.times)),
            "outliers_dropped": result.outliers.get(clip.name, {}),
            "duration": float(clip.times[-1]), "orientation_measured": clip.has_orientation,
            "objects": [{"object": tr.object, "shape": tr.spec.shape, "size": tr.spec.size, "mass": tr.spec.mass,
                         "assumed": tr.spec.assumed, "observed_axes": "".join(a for a, o in zip("xyz", tr.axes) if o)}
                        for tr in clip.tracks],
            "noise": {"position": nz.position, "angle_deg": None if nz.angle is None else math.degrees(nz.angle)},
            "rmse_base": math.sqrt(result.base.sq_pos[c] / max(result.base.n_pos[c], 1)),
            "rmse_final": math.sqrt(result.final.sq_pos[c] / max(result.final.n_pos[c], 1)),
            # one clip: nothing held out (the shown gap is the forward gap, ``gap``)
            "heldout_rmse_before": result.base_heldout.clip_rmse(c) if len(result.clips) >= 2 else None,
            "heldout_rmse_after": result.final_heldout.clip_rmse(c) if len(result.clips) >= 2 else None,
            # the named effects' values this clip was predicted with, fitted to the other clips
            "heldout_effects": (result.final_heldout.theta[c] if len(result.clips) >= 2 and result.named
                                and len(result.final_heldout.theta) > c else None),
        })
    noise_floor = float(np.sqrt(np.mean([n.position ** 2 for n in result.noise])))
    return {
        "workflow": "discrepancy (docs/design.md §8)",
        "inputs": sorted({c.source for c in result.clips}),
        "clips": clips,
        "noise_floor": noise_floor,
        "base": {"rmse": result.base.rmse, "bic": result.base.bic, "chi2": result.base.rss,
                 "chi2_per_residual": result.base.rss / result.base.n, "optimizer": result.base.optimizer()},
        "segments": result.segments,
        "segments_after": result.segments_after,
        "steps": result.steps,
        "named": [{"effect": n["effect"], "parameters": n["parameters"], "ci": n["ci"],
                   "ci_gauss_newton": n.get("ci_gauss_newton", {}), "ci_method": n.get("ci_method", {}),
                   "ci_profile": n.get("ci_profile", n["ci"]), "ci_jackknife": n.get("ci_jackknife", {}),
                   "units": n["units"],
                   "fitted": n["fitted"], "mechanism": n["mechanism"]} for n in result.named],
        "dropped": result.dropped,
        "gap": result.gap,
        "in_sample": result.in_sample,
        "final": {"rmse": result.final.rmse, "bic": result.final.bic, "chi2": result.final.rss,
                  "chi2_per_residual": result.final.rss / result.final.n, "optimizer": result.final.optimizer()},
        "config": json.loads(result.config.model_dump_json()),
        "runtime_s": result.runtime_s,
        "files": dict(files or {}),
    }


def _gap_lines(rep: Mapping[str, Any]) -> list[str]:
    """Markdown lines of the shown gap (which one and why) and the in-sample fit."""
    mm, g = 1e3, rep["gap"]
    kind = g.get("kind", "leave_one_clip_out")
    label = g.get("label", "held-out gap (leave one clip out)")
    after = ", ".join(n["effect"] for n in rep["named"]) or "nothing named"
    how = {"leave_one_clip_out": "Held-out: the effects' coefficients are fitted on the other clips (leave one clip "
                                 "out, from the effect's profile); only the clip's own initial state, damping and "
                                 "friction are refitted.",
           "forward": f"Forward: the base model and the base model + {after} are fitted (initial state, damping, "
                      f"friction and the effects' coefficients) on the samples up to {g.get('fit_s', 0):.3g} s "
                      f"({g.get('n_fit', 0)} samples, {100 * rep['config'].get('forward_split', 0.6):.0f} % of the "
                      f"clip), the whole clip is simulated from the fitted initial state, and only the "
                      f"{g.get('n_predicted', 0)} samples after the split are scored (a forecast).",
           "in_sample": "In sample: the models are fitted to the whole clip (no data left to forecast)."}[kind]
    lines = [f"## Gap: {label}", "", f"Which gap and why: {g.get('why', '>= 2 clips: leave one clip out')}.", "",
             *table_lines(["", "RMSE (mm)"], [["before (base model)", _fmt(g['before'], mm)],
                                         [f"after ({after})", _fmt(g['after'], mm)],
                                         ["noise floor (measurement sigma)", _fmt(rep['noise_floor'], mm)]]), "",
             f"Shrink: {100 * g['shrink']:.1f} % (of the part above the noise, "
             f"sqrt(RMSE² − σ²): {mm * g['excess_before']:.2f} → {mm * g['excess_after']:.2f} mm, "
             f"{100 * g['excess_shrink']:.1f} %). {how}", ""]
    ins = rep.get("in_sample")
    if ins:
        lines += ["In-sample fit (all samples, every clip), for comparison: it always improves with more "
                  "parameters, so it is not the evidence.", "",
                  *table_lines(["model", "in-sample RMSE (mm)", "fitted parameters k"],
                          [["base", _fmt(ins['before'], mm), ins['k_before']],
                           [f"base + {after}", _fmt(ins['after'], mm), ins['k_after']]]), ""]
        if kind == "forward":
            lines += [f"Forward fits: k = {g['k_before']} (base) and {g['k_after']} (with the effects).", ""]
    for v in g.get("variants") or []:
        lines += [f"Forward fit of {v['effect']}: fitted with the base model's linear damping (BIC "
                  f"{v['bic_fitted']:.1f} on the first part) and instead of it (damping held at 0, BIC "
                  f"{v['bic_held']:.1f}): kept with the damping {v['damping']} (lower BIC; the two laws are "
                  f"nearly collinear over a short first part).", ""]
    return lines


def table_lines(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> list[str]:
    """Lines of a GitHub-flavoured Markdown table (tabulate; cells exactly as formatted by the
    caller: no number parsing)."""
    return tabulate([list(r) for r in rows], list(header), tablefmt="github", disable_numparse=True).splitlines()


def _video_lines(rep: Mapping[str, Any]) -> list[str]:
    """Report lines for a `dynamics infer` input: the gap its re-simulated scene leaves."""
    v = rep.get("video")
    if not v:
        return []
    g = v["resimulation_gap"]
    lines = ["## Video reconstruction", "",
             f"Input: the `dynamics infer` output `{v['folder']}`. Observed tracks (mask centroids) are placed in the "
             f"scene's world frame at the re-simulated object's depth; observed axes: {v['camera_axes']}. "
             f"The re-simulated scene (`scene.yaml`) leaves the observed motion at "
             f"{_fmt(g['rmse_m'], 1e3)} mm ({_fmt(g['rmse_px'], 1, 1)} px) RMSE:", "",
             *table_lines(["object", "samples", "RMSE (mm)", "RMSE (px)"],
                     [[name, o['samples'], f"{o['rmse_m'] * 1e3:.2f}", f"{o['rmse_px']:.1f}"]
                      for name, o in g["per_object"].items()])]
    return lines + ["", "The base model below is refitted to the tracks; the named effects close what it leaves.", ""]


def report_markdown(rep: Mapping[str, Any]) -> str:
    """Human-readable report (Markdown) from :func:`report_dict` (lengths in mm, angles in
    deg): the gap, the named effects with intervals, every step's candidates, the clips, the
    residual segments and the method."""
    mm = 1e3
    lines = ["# Discrepancy report", "",
             "Workflow of docs/design.md §8: fit the base model (scene language v1 in MuJoCo) per clip, find where it "
             "disagrees with the measurements beyond their noise, name the missing effect(s) from the library, add "
             "them and show the gap shrink (held-out with >= 2 clips, forward in time with one).", "",
             f"Inputs: {', '.join(rep['inputs'])}", "",
             *_video_lines(rep),
             *_gap_lines(rep),
             "## Named effects", ""]
    if rep["named"]:
        lines += table_lines(["effect", "mechanism", "parameter", "value", "95 % CI", "profile", "jackknife", "unit"],
                        [[n['effect'], n['mechanism'], p, f"{v:.4g}", format_interval(n["ci"].get(p)),
                          format_interval((n.get("ci_profile") or n["ci"]).get(p)),
                          format_interval((n.get("ci_jackknife") or {}).get(p)) if n.get("ci_jackknife") else "—",
                          n['units'].get(p, '')] for n in rep["named"] for p, v in n["parameters"].items()])
    else:
        lines.append("None: no candidate cleared the noise floor (BIC and held-out gates).")
    for d in rep.get("dropped") or []:
        lines += ["", f"Dropped from the final model: {d['effect']} "
                      f"({', '.join(f'{k}={v:.3g}' for k, v in d['parameters'].items())}), named during the selection, "
                      f"does not beat its null value once the other effects are refitted (likelihood ratio "
                      f"{d['statistic']:.1f} < {d['threshold']:.2f})."]
    lines += ["", "## Candidates", ""]
    for st in rep["steps"]:
        model = " + ".join(["base"] + st["model"])
        lines += [f"### Step {st['step']}: {model} + candidate -> named: {st['named'] or 'none'}", "",
                  *table_lines(["candidate", "fit gain (mm)", "fit gain (%)", "ΔBIC", "profile Δχ²", "held-out RMSE (mm)",
                           "held-out gain (mm)", "held-out Δχ²", "named?"],
                          [[f"{cd['effect']} ({', '.join(f'{k}={v:.3g}' for k, v in cd['parameters'].items())})",
                            _fmt(cd['fit_gain'], mm), f"{cd['fit_gain_pct']:.1f}", f"{cd['delta_bic']:.1f}",
                            f"{cd['profile_gain']:.1f}", _fmt(cd['heldout_rmse'], mm), _fmt(cd['heldout_gain'], mm),
                            _fmt(cd['heldout_delta_chi2'], 1, 1),
                            'yes' if cd['named'] else 'no: ' + cd['reason'] if not cd['eligible'] else 'eligible']
                           for cd in sorted(st["candidates"], key=lambda d: d["delta_bic"])])]
        out = {e: v for e, v in (st.get("screen") or {}).items()
               if v.get("passed", True) is False}
        if out:
            lines.append("")
            lines.append("Screened out before the full fits (linearised prediction of the χ² gain below "
                         "`screen_gain`): " + ", ".join(f"{e} ({v['predicted_gain']:.1f})" for e, v in out.items()) + ".")
        if st.get("deferred"):
            lines.append("")
            lines.append(f"Not fitted (`race`: {st.get('race_stopped_by')} leaves nothing to explain, every clip at "
                         "the noise floor or at most `race_excess` of the χ² excess, and the "
                         "screen predicts each of these less than `race_margin` of its χ² gain): "
                         + ", ".join(f"{e} ({st['screen'][e]['predicted_gain']:.1f})" for e in st["deferred"]) + ".")
        checked = [cd for cd in st["candidates"] if cd.get("mismatch")]
        if checked:
            lines.append("")
            lines.append("Mismatch check (an eligible effect's profile must gain `mismatch_margin` more χ² than a "
                         "nuisance term's, every clip refitted from the data): " + ", ".join(
                             f"{cd['effect']} {cd['profile_gain']:.1f} against {cd['mismatch']['term']} "
                             f"{cd['mismatch']['gain']:.1f}"
                             + (f" (its profile stopped at its two inner points: its gain is at most "
                                f"{cd['mismatch']['bound']:.1f} if the profile is convex)" if "bound" in cd["mismatch"] else "")
                             for cd in checked) + ".")
        lines.append("")
        clip_names = list(st["candidates"][0].get("per_clip_gain", {})) if st["candidates"] else []
        if clip_names:
            lines += ["Per-clip evidence: χ² drop when the effect's strength is chosen for each clip alone "
                      "(profile minimum; about 4 is the 95 % level for one parameter).", "",
                      *table_lines(["candidate", *clip_names],
                              [[cd['effect'], *(f"{cd['per_clip_gain'][c]:.1f}" for c in clip_names)]
                               for cd in st["candidates"]])]
            lines.append("")
    rows = []
    for c in rep["clips"]:
        objs = ", ".join(f"{o['object']} ({o['shape']}, {o['mass'] * 1e3:.3g} g{', assumed ' + '/'.join(o['assumed']) if o['assumed'] else ''})"
                         for o in c["objects"])
        n_out = sum(map(len, c.get("outliers_dropped", {}).values()))
        rows.append([c['clip'], objs, f"{c['n_samples']}" + (f" ({n_out} outliers dropped)" if n_out else ""), _fmt(c['noise']['position'], mm, 3), _fmt(c['noise']['angle_deg']),
                     _fmt(c['rmse_base'], mm), _fmt(c['rmse_final'], mm),
                     f"{_fmt(c['heldout_rmse_before'], mm)} / {_fmt(c['heldout_rmse_after'], mm)}"])
    lines += ["## Clips", "", *table_lines(["clip", "objects", "samples", "noise (mm)", "noise (deg)", "base RMSE (mm)",
                                      "extended RMSE (mm)", "held-out before / after (mm)"], rows)]
    lines += ["", "## Where the base model disagrees (residual segments above the noise)", ""]
    if rep["segments"]:
        rows = []
        for s in rep["segments"][:60]:
            unit, k = ("mm", mm) if s["channel"] == "position" else ("deg", 1.0)
            rows.append([s['clip'], s['object'], s['channel'], f"{s['t_start']:.3f}–{s['t_end']:.3f}", s['phase'],
                         s['n_samples'], f"{s['max'] * k:.2f} {unit}", f"{s['threshold'] * k:.2f} {unit}"])
        if len(rep["segments"]) > 60:
            rows.append([f"… {len(rep['segments']) - 60} more in discrepancy.json", "", "", "", "", "", "", ""])
        lines += table_lines(["clip", "object", "channel", "time (s)", "phase", "samples", "max", "threshold"], rows)
    else:
        lines.append("None: the base model fits every clip within the noise.")
    lines += ["", f"After adding the named effects: {len(rep['segments_after'])} segments remain "
              f"(base model: {len(rep['segments'])}).", ""]
    files = rep.get("files") or {}
    if files:
        lines += ["## Files", ""] + [f"- {k}: `{v}`" for k, v in files.items() if v] + [""]
    lines += ["## Method", "",
              "- Base model: scene language v1 in MuJoCo; per clip and object the initial position, orientation, linear "
              "and angular velocity, `material.damping` (linear, i.e. viscous drag is part of the base model) and "
              "`material.sliding_friction` are fitted by least squares (finite-difference Jacobian over rollouts; "
              "continuation over the clip's length).",
              "- Noise: from the data alone (residuals of local quadratic fits; orientation from differences of "
              "rotation increments), robust scale 1.4826·MAD. Residuals are divided by it.",
              f"- Naming: ΔBIC ≤ −{rep['config']['bic_threshold']:g}, profile Δχ² (every clip refitted from the data "
              f"with the effect vs. without) ≥ {rep['config']['heldout_threshold']:g}, held-out Δχ² ≥ "
              f"{rep['config']['heldout_threshold']:g} and a smaller held-out RMSE, and (null test) the effect removed "
              "with every clip refitted must be worse by the χ² quantile × χ²/dof (its interval excludes its null "
              "value), and (mismatch check) its profile must gain more than a nuisance term's (`mismatch_terms`: "
              "`scale_error`, the measured positions off by a factor) by `mismatch_margin`; among eligible "
              "candidates the lowest BIC is named; greedy forward selection until nothing is eligible, every clip "
              "is at the noise floor, or the named model leaves at most `race_excess` of the base model's χ² "
              "excess above the noise.",
              "- Outliers: samples more than `outlier_sigma` prediction SDs from a quadratic through their six "
              "neighbours (which fit it within the noise) are dropped before any fit (counted per clip above).",
              "- Confidence intervals: profile likelihood (the coefficient fixed, everything else refitted; threshold "
              "χ²₁ quantile × χ²/dof), where the Gauss-Newton interval s²(JᵀJ)⁻¹ (Student-t, "
              "`mujoco.sysid.calculate_intervals`) is accepted when the profile confirms its ends within 25 %; a side "
              "the data cannot bound before the search bound is shown open. The reported interval is the "
              f"profile's widened by ±{100 * float(rep['config'].get('ci_model_error', 0.0)):g} % of max(|value|, "
              "scale) for model mismatch (`ci_model_error`); the leave-one-clip-out jackknife interval (estimate ± "
              "t·SE over the held-out coefficients, >= 3 clips) is shown beside it as a diagnostic.",
              f"- Runtime: {rep['runtime_s']:.0f} s."]
    return "\n".join(lines) + "\n"


def write_report(result: Result, report_dir: str | Path, artifacts_dir: str | Path | None = None,
                 decimals: Decimals | None = None, video: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Write the report and the extended model.

    ``report_dir``: ``discrepancy.md``, ``discrepancy.json``, ``discrepancy_residuals.png``,
    ``discrepancy_trajectories.png``. ``artifacts_dir`` (default: ``report_dir``):
    ``scenes/<clip>.yaml`` (extended scenes), ``effects.yaml`` (the named effects' block),
    ``discrepancy.rrd`` (rerun). Every file is written atomically.

    Returns:
        The JSON report dict.
    """
    report_dir = Path(report_dir)
    art = Path(artifacts_dir) if artifacts_dir is not None else report_dir
    files: dict[str, Any] = {}
    scenes = extended_scenes(result)
    paths = []
    for name, scene in scenes.items():
        p = art / "scenes" / f"{safe_file_name(name)}.yaml"
        write_text(p, scene.to_yaml(decimals or DISCREPANCY_DECIMALS))
        paths.append(str(p))
    files["extended_scenes"] = str(art / "scenes")
    eff = {"effects": [{"effect": n["effect"], "parameters": {k: round(v, 6) for k, v in n["parameters"].items()}}
                       for n in result.named]}
    files["effects_yaml"] = str(write_text(art / "effects.yaml", yaml.safe_dump(eff, sort_keys=False)))
    files["residual_plot"] = str(plot_residuals(result, report_dir / "discrepancy_residuals.png"))
    files["trajectory_plot"] = str(plot_trajectories(result, report_dir / "discrepancy_trajectories.png"))
    if result.config.recording:
        files["recording"] = str(record(result, art / "discrepancy.rrd"))
    rep = report_dict(result, files)
    if video:   # input was a `dynamics infer` folder: the gap its re-simulation left
        rep["video"] = dict(video)
    write_json(report_dir / "discrepancy.json", rep)
    write_text(report_dir / "discrepancy.md", report_markdown(rep))
    return rep
