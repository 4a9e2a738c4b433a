"""One base class for the mistakes a user can make (issue 11, item 4).

Every error that comes from what the user gave (a scene file, a video, params.yaml, a
trajectory table, a model folder, a stage's input shards) derives from :class:`UserError`, with
one line ``<file>: <field path>: must be <rule>, got <value>`` as its message. The ``dynamics``
CLI catches :class:`UserError` for every subcommand, prints ``error: <line>`` to stderr and
exits with status 2; anything else is a bug and keeps its traceback.

Each module keeps its own subclass (``SceneError``, ``VideoError``, ``ParamsError``, ...), which
also derives from the built-in it always was (``ValueError`` or ``RuntimeError``), so existing
``except ValueError`` code keeps working.
"""

from __future__ import annotations


class UserError(Exception):
    """A mistake in the user's input; the message is one line naming the file and field."""
