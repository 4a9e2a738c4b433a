"""Stage processes end when the process that started them dies.

``dvc repro`` runs each stage as ``/bin/sh -c "python stages/<verb>.py"``; after ``kill -9`` of
``dvc`` the shell and the stage script live on, and the script would keep writing for minutes
into an output DVC no longer tracks (``dvc status`` already shows the stage as changed). Linux's
``prctl(PR_SET_PDEATHSIG)`` cannot help here: the script's parent is the shell, which survives.
So a daemon thread polls, once per :data:`POLL_S` seconds, the processes it descends from up to
the first one that is not a shell (``sh``, ``bash``, ``dash``, ``zsh``): when one of them is gone
(its pid no longer exists or now belongs to a process with another start time), the script
terminates its multiprocessing children and exits with status 143 (as after SIGTERM). Writes are
temp-then-rename (:mod:`pipeline.shards`), so nothing half-written stays visible, and the next
``dvc repro`` starts the stage over (its output directory is reset first).

:func:`exit_with_parent` is called by ``pipeline/__init__.py`` when ``DVC_STAGE`` is set (DVC sets
it for every stage command), so every stage script and its spawned workers have the watchdog
without a line in ``stages/``. Library and CLI use are unaffected.
"""

from __future__ import annotations

import multiprocessing
import os
import threading
import time
from pathlib import Path

POLL_S = 1.0
"""Seconds between checks of the watched processes."""
SHELLS = frozenset({"sh", "bash", "dash", "zsh", "ksh", "busybox"})
"""Process names that are looked through to the process that started them."""
EXIT_STATUS = 143
"""Exit status after the watched parent died (128 + SIGTERM, as a terminated process)."""

_started = False


def _start_time(pid: int) -> str | None:
    """Field 22 of ``/proc/<pid>/stat`` (start time in clock ticks), or None if gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return stat[stat.rindex(")") + 2:].split()[19]


def _parent_of(pid: int) -> int | None:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return int(stat[stat.rindex(")") + 2:].split()[1])


def _name(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/comm").read_text().strip()
    except OSError:
        return ""


def watched_ancestors(pid: int | None = None) -> list[tuple[int, str]]:
    """``[(pid, start time), ...]`` of the parent of ``pid`` (default: this process) and, while
    that one is a shell, of its parents, up to and including the first non-shell (not pid 1)."""
    out: list[tuple[int, str]] = []
    cur = os.getpid() if pid is None else pid
    while True:
        parent = _parent_of(cur)
        if parent is None or parent <= 1:
            return out
        start = _start_time(parent)
        if start is None:
            return out
        out.append((parent, start))
        if _name(parent) not in SHELLS:
            return out
        cur = parent


def _alive(pid: int, start: str) -> bool:
    return _start_time(pid) == start


def _exit_now() -> None:
    for child in multiprocessing.active_children():
        child.terminate()
    os._exit(EXIT_STATUS)


def exit_with_parent(poll_s: float = POLL_S) -> bool:
    """Start (once per process) the daemon thread that exits this process when one of
    :func:`watched_ancestors` dies.

    Returns:
        True if a watchdog runs (Linux with ``/proc`` and a parent other than init).
    """
    global _started
    if _started or not Path("/proc/self/stat").exists():
        return _started
    watched = watched_ancestors()
    if not watched:
        return False
    _started = True

    def watch() -> None:
        while True:
            time.sleep(poll_s)
            if not all(_alive(pid, start) for pid, start in watched):
                _exit_now()

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()
    return True
