"""Which tree a benchmark report was made on: the one helper every benchmark stamps its report with.

A report's numbers are only re-runnable from the tree that made them, so each report records the
commit, and says so when the working tree had uncommitted changes to tracked files (``-dirty``):
such numbers come from code no commit holds.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def tree_id(where: Path = ROOT) -> str:
    """Short commit of the checkout at ``where``, plus ``-dirty`` when tracked files differ from it.

    Args:
        where: any folder inside the checkout (default: this repository).
    Returns:
        e.g. ``"b5defac"`` or ``"b5defac-dirty"``; ``"unknown"`` outside a git checkout or without git.
    """
    try:
        sha = subprocess.run(["git", "-C", str(where), "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(where), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return sha + ("-dirty" if dirty else "")
