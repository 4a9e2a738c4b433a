"""Command line of the workflow: the ``dynamics discrepancy`` and ``dynamics
discrepancy-benchmark`` subcommands (registered by :mod:`pipeline.cli`, the one entry point),
and the typed configs of params.yaml."""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path
from typing import Any, Mapping

from pydantic import ValidationError

from pipeline import effects as fx
from pipeline import infer_tracks
from pipeline.discrepancy.benchmark import benchmark_markdown, merge, rescore, run_benchmark
from pipeline.discrepancy.config import DiscrepancyConfig
from pipeline.discrepancy.hidden import HiddenConfig
from pipeline.discrepancy.readers import clips_from_infer_dir, read_trajectories
from pipeline.discrepancy.report import write_report
from pipeline.discrepancy.trajectories import DiscrepancyInputError
from pipeline.discrepancy.workflow import run_workflow
from pipeline.mjcf import SimOptions
from pipeline.parallel import ComputeConfig
from pipeline.params import load_params, typed_section
from pipeline.atomic import write_json, write_text


logger = logging.getLogger(__name__)

def load_config(params: Mapping[str, Any] | None) -> tuple[DiscrepancyConfig, HiddenConfig, SimOptions]:
    """Typed configs from parsed params (sections ``discrepancy``, ``measure_hidden``, ``sim``;
    a missing section takes the defaults), read by :func:`pipeline.params.typed_section`.

    Raises:
        DiscrepancyInputError: a section fails validation, one line
            ``<file>: <section>.<field>: must be <rule>, got <value>``.
    """
    params = params if params is not None else {}
    return (typed_section(params, "discrepancy", DiscrepancyConfig, error=DiscrepancyInputError),
            typed_section(params, "measure_hidden", HiddenConfig, error=DiscrepancyInputError),
            typed_section(params, "sim", SimOptions, error=DiscrepancyInputError))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``dynamics discrepancy``."""
    parser.add_argument("trajectories", nargs="+", metavar="TRAJECTORIES",
                        help="trajectory files (CSV/Parquet with clip, object, t, x, y, z [m, s, z up]; or 2-D Tracker "
                             "exports with t and x, y [y up]) or directories of them; or ONE output folder of "
                             "`dynamics infer` (scene.yaml + tracks.csv): where does its re-simulation leave the video")
    parser.add_argument("--out", required=True, help="output directory (report, plots, extended scenes, .rrd)")
    parser.add_argument("--objects", default=None,
                        help="object sizes/masses: YAML/JSON file or inline YAML "
                             "'{CLIP: {OBJECT: {shape: sphere, radius: 0.02, mass: 0.0027}}}' ('*' = any)")
    parser.add_argument("--scale", type=float, default=1.0,
                        help="metres per unit of the files' coordinates (0.001: millimetres; a table in pixels: "
                             "its calibration)")
    parser.add_argument("--up", choices=("z", "y"), default="z",
                        help="vertical axis of 3-D tables (y: a y-up export, world x, y, z = file x, -z, y); "
                             "2-D Tracker exports are always y up")
    parser.add_argument("--candidates", default=None,
                        help=f"comma-separated effects to try (default: all: {','.join(fx.EFFECTS)})")
    parser.add_argument("--max-effects", type=int, default=None, help="most effects named (greedy forward selection)")
    parser.add_argument("--bic-threshold", type=float, default=None, help="BIC drop needed to name an effect")
    parser.add_argument("--heldout-threshold", type=float, default=None, help="held-out chi-square drop needed")
    parser.add_argument("--params", default=None,
                        help="params.yaml to read sections discrepancy and sim from (default: ./params.yaml if present)")
    parser.add_argument("--no-recording", action="store_true", help="skip the rerun recording")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")


def _config_from_args(args: argparse.Namespace) -> tuple[DiscrepancyConfig, HiddenConfig, SimOptions]:
    path = getattr(args, "params", None)
    params = {}
    if path or Path("params.yaml").exists():
        params = load_params(path or "params.yaml")
    cfg, hidden, sim = load_config(params)
    update: dict[str, Any] = {}
    if getattr(args, "candidates", None):
        update["candidates"] = tuple(c.strip() for c in args.candidates.split(",") if c.strip())
    for key in ("max_effects", "bic_threshold", "heldout_threshold"):
        if getattr(args, key, None) is not None:
            update[key] = getattr(args, key)
    if getattr(args, "no_recording", False):
        update["recording"] = False
    if update:
        try:
            cfg = DiscrepancyConfig(**{**cfg.model_dump(), **update})
        except ValidationError as exc:
            err = exc.errors()[0]
            field = str(err["loc"][0]) if err.get("loc") else "candidates"
            msg = str(err.get("msg", "invalid")).removeprefix("Value error, ").removeprefix(f"{field}: ")
            raise DiscrepancyInputError(f"--{field.replace('_', '-')}: {msg}") from None
        except ValueError as exc:
            raise DiscrepancyInputError(f"--candidates: {str(exc).splitlines()[0].strip()}") from None
    return cfg, hidden, sim


def main_cli(args: argparse.Namespace) -> int:
    """``dynamics discrepancy TRAJECTORIES... --out DIR``: run the workflow and write the report.

    Raises:
        DiscrepancyInputError: bad trajectories, objects or options (the CLI prints it, exit 2).
    """
    cfg, _, sim = _config_from_args(args)
    if args.quiet:  # progress lines are INFO records of pipeline.discrepancy (stderr, pipeline.entry)
        logging.getLogger("pipeline.discrepancy").setLevel(logging.WARNING)
    video, gravity = None, 9.81
    if any(infer_tracks.is_infer_dir(t) for t in args.trajectories):
        if len(args.trajectories) != 1:
            raise DiscrepancyInputError(f"{args.trajectories[0]}: a `dynamics infer` folder must be the only input")
        clips, video, gravity = clips_from_infer_dir(args.trajectories[0], cfg.default_object)
        # the video's scene was re-simulated (and its camera fitted) on the scenes' own contact
        # (params sim): the base model of its tracks is that simulator, not the stiffer contact
        # the workflow fits measured trajectories with
        cfg = cfg.model_copy(update={"contact_timeconst": float(sim.object_solref[0]), "friction_cone": sim.cone})
        g = video["resimulation_gap"]
        print(f"video reconstruction {args.trajectories[0]}: the re-simulated scene leaves "
              f"{g['rmse_m'] * 1e3:.2f} mm ({g['rmse_px']:.1f} px) RMSE on the observed tracks "
              f"(axes {video['camera_axes']})")
    else:
        clips = read_trajectories(args.trajectories, args.objects, cfg.default_object, args.scale, args.up)
    result = run_workflow(clips, cfg, sim, gravity=gravity, log=None)
    rep = write_report(result, args.out, video=video)
    named = ", ".join(f"{n['effect']} ({', '.join(f'{k}={v:.4g}' for k, v in n['parameters'].items())})"
                      for n in rep["named"]) or "none"
    print(f"named: {named}")
    g = rep["gap"]
    print(f"{g.get('label', 'held-out gap')}: {g['before'] * 1e3:.2f} mm -> {g['after'] * 1e3:.2f} mm "
          f"(noise floor {rep['noise_floor'] * 1e3:.2f} mm; above the noise {g['excess_before'] * 1e3:.2f} -> "
          f"{g['excess_after'] * 1e3:.2f} mm, shrink {100 * g['excess_shrink']:.0f} %; {g.get('why', '')})")
    ins = rep["in_sample"]
    print(f"in-sample RMSE: {ins['before'] * 1e3:.2f} mm (k={ins['k_before']}) -> {ins['after'] * 1e3:.2f} mm "
          f"(k={ins['k_after']})")
    print(f"report: {Path(args.out) / 'discrepancy.md'}")
    return 0


def add_benchmark_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``dynamics discrepancy-benchmark`` (:func:`benchmark_cli`)."""
    parser.add_argument("--trials", type=int, default=60, help="trials with a hidden effect (cycling the library)")
    parser.add_argument("--null-trials", type=int, default=12, help="trials without an effect")
    parser.add_argument("--single-trials", type=int, default=12,
                        help="trials with a hidden effect on ONE clip (forward gap), scored apart")
    parser.add_argument("--single-duration", type=float, default=1.5, help="s, length of the single clip")
    parser.add_argument("--seed", type=int, default=1000, help="first seed")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes (Ray: tasks in flight)")
    parser.add_argument("--backend", choices=("local", "ray"), default="local", help="pipeline.parallel backend")
    parser.add_argument("--address", default=None, help="Ray address (auto, ray://host:port); default: local Ray")
    parser.add_argument("--engine", choices=("mujoco", "independent"), default="mujoco",
                        help="data generator: the project's MuJoCo model (default) or an independent hand-written "
                             "integrator with outliers and dropped frames (pipeline/discrepancy/independent.py)")
    parser.add_argument("--out", default=None,
                        help="JSON output (.md written beside it; default reports/discrepancy_benchmark.json, "
                             "with --engine independent reports/discrepancy_benchmark_independent.json)")
    parser.add_argument("--params", default=None, help="params.yaml (sections discrepancy, measure_hidden, sim)")
    parser.add_argument("--only", default=None, metavar="EFFECT[,EFFECT]",
                        help="run only the trials of these hidden effects (none: the no-effect trials), with the "
                             "seeds they have in the whole plan; with --merge, put them in place in an earlier run")
    parser.add_argument("--merge", default=None, metavar="JSON",
                        help="with --only: the earlier whole run (same plan) whose trials of those seeds are "
                             "replaced by the rerun; its summary is recomputed and the rerun recorded (reruns)")
    parser.add_argument("--rescore", default=None, metavar="JSON",
                        help="instead of running trials, recompute an earlier run's reported intervals, null-valued "
                             "names and summary with the current interval rule (discrepancy.ci_model_error); the naming "
                             "does not depend on them. Writes --out (default: the same file) and its .md")


def benchmark_cli(args: argparse.Namespace) -> int:
    """``dynamics discrepancy-benchmark [--trials N ...]``: run :func:`run_benchmark` and write
    its JSON (``--out``) and Markdown summary (beside it, ``.md``); the JSON records the
    command (``command``).

    Raises:
        DiscrepancyInputError: bad params or options (the CLI prints it, exit 2).
    """
    cfg, hidden, sim = _config_from_args(args)
    if args.rescore:
        src = Path(args.rescore)
        try:
            bench = json.loads(src.read_text())
        except (OSError, ValueError) as exc:
            raise DiscrepancyInputError(f"{src}: cannot read a benchmark JSON: {exc}") from None
        bench = rescore(bench, cfg)
        out = Path(args.out or src)
        command = bench.get("command", "")
        write_json(out, bench)
        write_text(out.with_suffix(".md"), benchmark_markdown(bench, command))
        c = bench["summary"]["ci_coverage"]["reported"]
        print(f"rescored {src}: reported intervals hold the truth in {c['held']}/{c['coefficients']}; "
              f"null-valued names {bench['summary']['null_valued_names']}; wrote {out}")
        return 0
    jobs = args.jobs if args.backend == "local" else ComputeConfig(backend="ray", address=args.address,
                                                                        workers=args.jobs)
    if args.out is None:
        args.out = ("reports/discrepancy_benchmark.json" if args.engine == "mujoco"
                    else "reports/discrepancy_benchmark_independent.json")
    only = [e.strip() for e in args.only.split(",") if e.strip()] if args.only else None
    if args.merge and only is None:
        raise DiscrepancyInputError("--merge: needs --only (the effects whose trials are rerun)")
    earlier = None
    if args.merge:
        try:
            earlier = json.loads(Path(args.merge).read_text())
        except (OSError, ValueError) as exc:
            raise DiscrepancyInputError(f"{args.merge}: cannot read a benchmark JSON: {exc}") from None
    try:
        bench = run_benchmark(args.trials, args.null_trials, args.seed, jobs, cfg, hidden, sim,
                              log=logger.info, single_trials=args.single_trials,
                              single_duration=args.single_duration, engine=args.engine, only=only)
    except ValueError as exc:
        raise DiscrepancyInputError(f"--only: {exc}") from None
    out = Path(args.out)
    command = "dynamics discrepancy-benchmark " + " ".join(
        f"--{k.replace('_', '-')} {v}" for k, v in (("trials", args.trials), ("null_trials", args.null_trials),
                                                   ("single_trials", args.single_trials),
                                                   ("single_duration", args.single_duration),
                                                   ("seed", args.seed), ("jobs", args.jobs), ("engine", args.engine),
                                                   ("only", args.only), ("merge", args.merge), ("out", args.out))
        if v is not None)
    if earlier is not None:
        try:
            bench = merge(earlier, bench, command)
        except ValueError as exc:
            raise DiscrepancyInputError(f"{args.merge}: {exc}") from None
        command = bench.get("command", command)
    else:
        bench["command"] = command
    write_json(out, bench)
    write_text(out.with_suffix(".md"), benchmark_markdown(bench, command))
    s = bench["summary"]
    def rate(x: float | None) -> str:
        return "-" if x is None else f"{x:.3f}"
    print(f"naming accuracy {rate(s['naming_accuracy'])} over {s['effect_trials']} trials; false-positive rate "
          f"{rate(s['false_positive_rate'])} over {s['null_trials']}; one clip {rate(s['single']['naming_accuracy'])} "
          f"over {s['single']['trials']}; wrote {out}")
    return 0
