"""`dynamics` command line: one entry point, `--help` on every subcommand.

    dynamics simulate SCENE.yaml --out DIR        run your own scene (trace, video, masks, events)
    dynamics infer VIDEO --out DIR [--fps F] [--start S]   the main job on any video
    dynamics discrepancy TRAJECTORIES --out DIR   find -> name -> add -> show (docs/design.md §8)
    dynamics discrepancy-benchmark [--trials N]   naming accuracy on hidden-effect data
    dynamics view SHARD [--scene ID] [--save FILE.rrd]     rerun recording of a shard
    dynamics schema [--out FILE]                  JSON Schema of a scene file (for editors)

User mistakes (bad scene, unreadable video, missing shard, bad params or trajectories) print
one line ``<file>: <field>: <problem>`` to stderr and exit with status 2; nothing is written.
So does any ``mujoco.FatalError`` (a scene past MuJoCo's limits, e.g. its arena memory).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import mujoco

from absl import logging as absl_logging

from pipeline import adapt, discrepancy, reconstruct, shard_viewer
from pipeline.atomic import write_text
from pipeline.entry import USER_ERROR_STATUS, configure_logging, user_error_line
from pipeline.errors import UserError
from pipeline.events import EventConfig
from pipeline.mjcf import SimOptions
from pipeline.params import ParamsError, load_params, typed_section
from pipeline.sanity import PhysicsError, SanityConfig, resolve_overlaps
from pipeline.scene import SceneError, json_schema_text, load_scene
from pipeline.traces import OUTPUT_FILES, write_simulation
from pipeline.video import VideoWarning

_python_showwarning = warnings.showwarning


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dynamics", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("simulate", help="simulate a scene YAML: trace.parquet, rgb.mp4, masks, events.json",
                       description="Simulate and render one scene of scene language v1.")
    add_simulate_arguments(p)
    p.set_defaults(func=simulate_cli)

    p = sub.add_parser("infer", help="main job: video -> scene YAML, side-by-side mp4, metrics, .rrd",
                       description=reconstruct.__doc__.split("\n\n")[0])
    reconstruct.add_arguments(p)
    p.set_defaults(func=reconstruct.main_cli)

    p = sub.add_parser("adapt", help="label-free preference optimisation (DPO) of the scene writer on videos",
                       description=adapt.__doc__.split("\n\n")[0])
    adapt.add_arguments(p)
    p.set_defaults(func=adapt.main_cli)

    p = sub.add_parser("discrepancy", help="find, name and add missing physical effects (docs/design.md §8)",
                       description="Discrepancy workflow on measured trajectories (CSV/Parquet/Tracker txt).")
    discrepancy.add_arguments(p)
    p.set_defaults(func=discrepancy.main_cli)

    p = sub.add_parser("discrepancy-benchmark", help="naming accuracy of the discrepancy workflow on hidden-effect data",
                       description="Hidden-effect benchmark of the discrepancy workflow (JSON + Markdown summary).")
    discrepancy.add_benchmark_arguments(p)
    p.set_defaults(func=discrepancy.benchmark_cli)

    p = sub.add_parser("view", help="open or save a rerun recording of a shard",
                       description=shard_viewer.__doc__.split("\n\n")[0])
    shard_viewer.add_arguments(p)
    p.set_defaults(func=shard_viewer.main_cli)

    p = sub.add_parser("schema", help="print or write the JSON Schema of a scene file (editors validate with it)",
                       description="JSON Schema of scene language v1 (docs/scene.schema.json is a copy).")
    p.add_argument("--out", metavar="FILE", help="write the schema here (atomically) instead of stdout")
    p.set_defaults(func=_schema_cli)
    return parser


MIN_SIZE, MAX_SIZE = 2, 4096
"""Render sizes ``dynamics simulate`` accepts, px (the mp4 encoder needs >= 2). Memory grows with
the frame size, not with the clip's length: ~0.6 GB at 160 x 120 or 480 x 320 (mostly the
imported libraries), ~2.6 GB at 4096 x 4096 (one frame per chunk; MuJoCo's offscreen buffers
included)."""


def add_simulate_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Arguments of ``dynamics simulate``."""
    parser.add_argument("scene", type=Path, help="scene language YAML file")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--width", type=int, default=480, help="render width, px (default 480)")
    parser.add_argument("--height", type=int, default=320, help="render height, px (default 320)")
    parser.add_argument("--params", type=Path, default=None,
                        help="params.yaml whose `sim`, `events` and `sanity` sections to use (default: built-in "
                             "defaults, the same values as the project's params.yaml)")
    parser.add_argument("--resolve-overlaps", action="store_true",
                        help="separate objects that start interpenetrating (each other, the floor, static geometry) "
                             "by moving them apart along the contact normal, and say so on stderr; without it "
                             "such a scene is refused with the pair and the depth")
    return parser


def simulate_cli(args: argparse.Namespace) -> int:
    """Run ``dynamics simulate``. Returns the exit status (2: invalid scene, nothing written)."""
    def fail(msg: str) -> int:
        print(msg, file=sys.stderr)
        return 2

    # MuJoCo's per-step "simulation is unstable" log lines (via absl): check_simulation reports
    absl_logging.set_verbosity(absl_logging.ERROR)

    for name, value in (("width", args.width), ("height", args.height)):
        if not MIN_SIZE <= value <= MAX_SIZE:
            return fail(f"--{name}: must be in {MIN_SIZE}..{MAX_SIZE} px, got {value}")
    if Path(args.out).exists() and not Path(args.out).is_dir():
        return fail(f"{args.out}: --out: must be a folder (or not exist yet), got an existing file")
    for name in OUTPUT_FILES.values():
        if (Path(args.out) / name).is_dir():
            return fail(f"{Path(args.out) / name}: --out: must not hold a folder named {name}, got one")
    try:
        scene = load_scene(args.scene)
        options, events, sanity = SimOptions(), EventConfig(), SanityConfig()
        if args.params is not None:
            p = load_params(args.params)
            try:
                options, events, sanity = (typed_section(p, key, cls, str(args.params)) for key, cls in
                                           (("sim", SimOptions), ("events", EventConfig), ("sanity", SanityConfig)))
            except ParamsError as exc:
                return fail(str(exc))
        # the offscreen buffer must hold the image (MuJoCo's default here is 640 px)
        options = options.model_copy(update={"offscreen_size": max(options.offscreen_size, args.width, args.height)})
        if args.resolve_overlaps:
            scene, moves = resolve_overlaps(scene, options, sanity)
            for move in moves:
                print(f"warning: {args.scene}: --resolve-overlaps: {move}", file=sys.stderr)
        paths = write_simulation(scene, args.out, args.width, args.height, options, events, sanity,
                                 source=str(args.scene))
    except (SceneError, PhysicsError) as exc:
        msg = str(exc)
        if msg.startswith("<scene>: "):  # raised while building the MJCF (effects)
            msg = f"{args.scene}: {msg.removeprefix('<scene>: ')}"
        return fail(msg)
    for name, path in paths.items():
        print(f"{name}: {path}")
    return 0


def _schema_cli(args: argparse.Namespace) -> int:
    text = json_schema_text()
    if args.out is None:
        sys.stdout.write(text)
        return 0
    try:
        write_text(args.out, text)
    except OSError as exc:
        raise UserError(f"{args.out}: --out: cannot write: {exc.strerror or exc}") from None
    return 0


_warned: set[str] = set()


def _one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Our own warnings (e.g. a truncated video) as one stderr line ``warning: <message>``, each
    message once per run (the main job reads a video several times); others keep Python's format."""
    if issubclass(category, VideoWarning):
        if str(message) not in _warned:
            _warned.add(str(message))
            print(f"warning: {message}", file=file or sys.stderr)
    else:
        _python_showwarning(message, category, filename, lineno, file, line)


def main(argv: list[str] | None = None) -> int:
    _warned.clear()   # "once per run": a second main() in one process warns again
    warnings.showwarning = _one_line_warning
    configure_logging("dynamics")
    args = build_parser().parse_args(argv)
    try:
        result = args.func(args)
    except UserError as exc:   # every subcommand: one line, exit 2 (pipeline.entry)
        print(user_error_line(exc), file=sys.stderr)
        return USER_ERROR_STATUS
    except mujoco.FatalError as exc:  # e.g. mj_stackAlloc out of memory: MuJoCo's limit, not a bug
        print(user_error_line(UserError(f"{_input_of(args)}: MuJoCo: must stay within MuJoCo's limits, got "
                                        f"{' '.join(str(exc).split())[:200]}")), file=sys.stderr)
        return USER_ERROR_STATUS
    except KeyboardInterrupt:
        return 130
    return int(result or 0)


def _input_of(args: argparse.Namespace) -> str:
    """The input file a subcommand was given (for a one-line error), else the subcommand."""
    for key in ("scene", "video", "videos", "trajectories", "shard", "path"):
        value = getattr(args, key, None)
        if value:
            return str(value[0] if isinstance(value, (list, tuple)) else value)
    return str(args.command)


if __name__ == "__main__":
    sys.exit(main())
