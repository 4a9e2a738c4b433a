"""`dynamics` command line: one entry point, `--help` on every subcommand.

    dynamics simulate SCENE.yaml --out DIR        run your own scene (trace, video, masks, events)
    dynamics infer VIDEO --out DIR [--fps F] [--start S]   the main job on any video
    dynamics discrepancy TRAJECTORIES --out DIR   find -> name -> add -> show (DESIGN §8)
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

import mujoco

from pipeline import discrepancy, reconstruct, traces, view
from pipeline.atomic import write_text
from pipeline.entry import USER_ERROR_STATUS, configure_logging, user_error_line
from pipeline.errors import UserError
from pipeline.scene import json_schema_text
from pipeline.video import VideoWarning

_python_showwarning = warnings.showwarning


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dynamics", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("simulate", help="simulate a scene YAML: trace.parquet, rgb.mp4, masks, events.json",
                       description="Simulate and render one scene of scene language v1.")
    traces.add_simulate_arguments(p)
    p.set_defaults(func=traces.simulate_cli)

    p = sub.add_parser("infer", help="main job: video -> scene YAML, side-by-side mp4, metrics, .rrd",
                       description=reconstruct.__doc__.split("\n\n")[0])
    reconstruct.add_arguments(p)
    p.set_defaults(func=reconstruct.main_cli)

    p = sub.add_parser("discrepancy", help="find, name and add missing physical effects (DESIGN §8)",
                       description="Discrepancy workflow on measured trajectories (CSV/Parquet/Tracker txt).")
    discrepancy.add_arguments(p)
    p.set_defaults(func=discrepancy.main_cli)

    p = sub.add_parser("discrepancy-benchmark", help="naming accuracy of the discrepancy workflow on hidden-effect data",
                       description="Hidden-effect benchmark of the discrepancy workflow (JSON + Markdown summary).")
    discrepancy.add_benchmark_arguments(p)
    p.set_defaults(func=discrepancy.benchmark_cli)

    p = sub.add_parser("view", help="open or save a rerun recording of a shard",
                       description=view.__doc__.split("\n\n")[0])
    view.add_arguments(p)
    p.set_defaults(func=view.main_cli)

    p = sub.add_parser("schema", help="print or write the JSON Schema of a scene file (editors validate with it)",
                       description="JSON Schema of scene language v1 (docs/scene.schema.json is a copy).")
    p.add_argument("--out", metavar="FILE", help="write the schema here (atomically) instead of stdout")
    p.set_defaults(func=_schema_cli)
    return parser


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


def _one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Our own warnings (e.g. a truncated video) as one stderr line ``warning: <message>``;
    others keep Python's format."""
    if issubclass(category, VideoWarning):
        print(f"warning: {message}", file=file or sys.stderr)
    else:
        _python_showwarning(message, category, filename, lineno, file, line)


def main(argv: list[str] | None = None) -> int:
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
    for key in ("scene", "video", "trajectories", "shard", "path"):
        value = getattr(args, key, None)
        if value:
            return str(value[0] if isinstance(value, (list, tuple)) else value)
    return str(args.command)


if __name__ == "__main__":
    sys.exit(main())
