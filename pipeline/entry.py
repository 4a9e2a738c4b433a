"""What every entry point does around its work: the ``dynamics`` CLI and each ``stages/*.py``.

* Logging is configured once, here (:func:`configure_logging`): library modules only call
  ``logging.getLogger(__name__)``; messages go to stderr as ``<stage>: <message>``.
* A :class:`pipeline.errors.UserError` (a mistake in the user's input) becomes one line
  ``error: <file>: <field path>: <problem>`` on stderr and exit status 2
  (:func:`user_error_line`); anything else is a bug and keeps its traceback.

Example (the last lines of a stage script)::

    if __name__ == "__main__":
        run_stage(main)
"""

from __future__ import annotations

import logging
import sys
from typing import Any, Callable

from pipeline.errors import UserError

USER_ERROR_STATUS = 2
"""Exit status of a user mistake (argparse uses the same for a bad command line)."""


class _StderrHandler(logging.StreamHandler):
    """A StreamHandler on whatever ``sys.stderr`` is when a record is emitted (pytest's capture,
    an embedding program's redirect), not the one at configuration time."""

    def emit(self, record: logging.LogRecord) -> None:
        self.stream = sys.stderr
        super().emit(record)


LOGGERS = ("pipeline", "__main__", "stages")
"""Loggers configured by :func:`configure_logging`: the library's modules
(``logging.getLogger(__name__)`` under ``pipeline``) and the running script; third-party
loggers keep Python's default (warnings and above)."""


def configure_logging(name: str | None = None, level: int = logging.INFO) -> None:
    """Send the project's log records of level ``level`` and above to stderr as
    ``<name>: <message>`` (the record's logger name when ``name`` is None). Call once, in an
    entry point; calling it again changes nothing."""
    fmt = logging.Formatter(f"{name}: %(message)s" if name else "%(name)s: %(message)s")
    for logger_name in LOGGERS:
        logger = logging.getLogger(logger_name)
        if any(getattr(h, "_dynamics", False) for h in logger.handlers):
            continue
        handler = _StderrHandler()
        handler.setFormatter(fmt)
        handler._dynamics = True  # type: ignore[attr-defined]
        logger.addHandler(handler)
        logger.setLevel(level)
        logger.propagate = False


def user_error_line(exc: UserError) -> str:
    """The one line printed for a user error: ``error: <first line of its message>``."""
    text = str(exc)
    return f"error: {text.splitlines()[0] if text else type(exc).__name__}"


def run_stage(main: Callable[[], Any], name: str | None = None) -> None:
    """Run a stage's ``main()``; on a :class:`UserError` print :func:`user_error_line` to stderr
    (e.g. ``error: params.yaml: search.popsize: must be >= 2, got -1``) and exit with status 2.
    Returns normally when ``main`` does (the script then ends with status 0).

    Args:
        main: the stage's ``main`` (no arguments; it reads params.yaml itself).
        name: prefix of log lines (default: the script's file name without ``.py``).
    """
    configure_logging(name or sys.argv[0].rsplit("/", 1)[-1].removesuffix(".py"))
    try:
        main()
    except UserError as exc:
        print(user_error_line(exc), file=sys.stderr)
        sys.exit(USER_ERROR_STATUS)
