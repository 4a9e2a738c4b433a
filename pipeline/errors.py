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

import re
import reprlib
from typing import Any, Collection, Sequence

from pydantic import ValidationError


class UserError(Exception):
    """A mistake in the user's input; the message is one line naming the file and field."""


# ------------------------------------------------------------------ pydantic errors, one line
MAX_VALUE_CHARS = 60
"""A quoted value (``got ...``) is cut to about this many characters (issue 12: a repr of a
996-deep list recursed past Python's limit; a 72 MB error line is no help)."""

UNKNOWN_KEY = "must not be given (unknown key)"
"""Default wording of a key the model does not know (``extra="forbid"``)."""

IDENTIFIER_PATTERN = r"^[A-Za-z_][A-Za-z0-9_]*$"
_PATTERN_RULES = {IDENTIFIER_PATTERN: "must be an identifier (letters, digits, _; not starting with a digit)"}
_BOUNDS = {"greater_than": (">", "gt"), "greater_than_equal": (">=", "ge"),
           "less_than": ("<", "lt"), "less_than_equal": ("<=", "le")}
_ROOT_FIELD = re.compile(r"^([^:,]+): (must .*)$", re.DOTALL)

_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxstring, _REPR.maxother = 2, MAX_VALUE_CHARS, MAX_VALUE_CHARS
_REPR.maxlist = _REPR.maxtuple = _REPR.maxdict = 4


def short_repr(value: Any) -> str:
    """``repr`` of a user's value cut to ~:data:`MAX_VALUE_CHARS` characters and 2 levels of
    nesting (never raises: a value whose repr fails prints as ``<type>``)."""
    try:
        return _REPR.repr(value)
    except (RecursionError, ValueError):
        return f"<{type(value).__name__}>"


def _choices(expected: str) -> list[str]:
    """``"'a', 'b' or 'c'"`` (pydantic's ``expected`` / ``expected_tags``) -> ``['a', 'b', 'c']``."""
    items = re.split(r", | or ", expected)
    return [item[1:-1] if len(item) >= 2 and item[0] == item[-1] == "'" else item for item in items]


def format_validation_error(exc: ValidationError, source: str | None = None, prefix: Sequence[str] = (), *,
                            tags: Collection[str] = (), unknown: str = UNKNOWN_KEY,
                            known: Sequence[str] = ()) -> str:
    """The first error of a pydantic ``ValidationError`` as one line
    ``<source>: <field path>: must be <rule>, got <value>``.

    The field path joins ``prefix`` and pydantic's location with dots and list indices in
    brackets (``objects[2].size.radius``); ``<root>`` when both are empty. Pydantic's wording
    becomes the project's: ``greater_than_equal`` -> ``must be >= 0.001``, ``literal_error`` ->
    ``must be one of local, ray`` (``must be 1`` for one choice), ``missing`` -> ``must be given
    (required field missing)``, ``too_long`` -> ``must have at most 4 items, got 5``, a
    validator's ``ValueError("must be ...")`` -> its message, ``Input should be a valid number``
    -> ``must be a valid number``. A model validator (empty location) may name its field by
    starting its message with ``<field>: ``; that extends the path. The value is quoted with
    :func:`short_repr` (bounded length) unless it is a mapping or the message quotes it already.

    Args:
        exc: the error pydantic raised.
        source: file (or ``<scene>``) the data came from, first on the line; none: no prefix.
        prefix: path of the validated mapping inside the file, e.g. ``("search",)`` for a
            params section.
        tags: discriminator values of tagged unions (e.g. shape names): pydantic puts the tag
            in the location after a list index; it is not a field and is left out of the path.
        unknown: wording of an unknown key (``extra_forbidden``); may use ``{value}`` (the
            value, shortened) and ``{known}`` (``known`` joined with ``, ``). The default is
            followed by ``, got <value>`` like any other rule.
        known: the keys the model accepts (for ``{known}``).

    Returns:
        One line, no trailing newline.
    """
    err = exc.errors()[0]
    parts: list[str] = [str(p) for p in prefix]
    prev_int = False
    for item in err["loc"]:
        if isinstance(item, int):
            parts[-1:] = [f"{parts[-1]}[{item}]"] if parts else [f"[{item}]"]
            prev_int = True
            continue
        if prev_int and item in tags:  # discriminated-union tag, not a field
            prev_int = False
            continue
        prev_int = False
        parts.append(str(item))
    kind, msg = err["type"], err["msg"]
    ctx = err.get("ctx") or {}
    inp = err.get("input")
    quote = "input" in err and not isinstance(inp, dict)
    if kind in _BOUNDS:
        op, key = _BOUNDS[kind]
        msg = f"must be {op} {ctx.get(key)}"
    elif kind in ("too_long", "too_short"):
        bound, limit = (("at most", ctx.get("max_length")) if kind == "too_long"
                        else ("at least", ctx.get("min_length")))
        msg, quote = f"must have {bound} {limit} items, got {ctx.get('actual_length')}", False
    elif kind == "extra_forbidden":
        msg = unknown.format(value=short_repr(inp), known=", ".join(known))
        quote = quote and unknown == UNKNOWN_KEY
    elif kind == "missing":
        msg, quote = "must be given (required field missing)", False
    elif kind == "literal_error":
        choices = _choices(str(ctx.get("expected", "")))
        msg = f"must be {choices[0]}" if len(choices) == 1 else f"must be one of {', '.join(choices)}"
    elif kind in ("union_tag_invalid", "union_tag_not_found"):
        field = _choices(str(ctx.get("discriminator", "")))[0]
        parts.append(field) if not parts or parts[-1] != field else None
        if kind == "union_tag_invalid":  # the input is the whole object: quote the tag
            choices = ", ".join(_choices(str(ctx.get("expected_tags", ""))))
            msg, inp, quote = f"unknown {field}, must be one of {choices}", ctx.get("tag", inp), True
        else:
            msg, quote = f"must be given (required field missing: {field})", False
    elif kind == "value_error":
        msg = msg.removeprefix("Value error, ")
        root = _ROOT_FIELD.match(msg) if not err["loc"] else None
        if root:  # a model validator naming its field
            parts.append(root.group(1))
            msg = root.group(2)
        quote = quote and ", got " not in msg
    elif kind == "string_pattern_mismatch":
        pattern = str(ctx.get("pattern", ""))
        msg = _PATTERN_RULES.get(pattern, f"must match {pattern}")
    elif msg.startswith("Input should be "):   # pydantic's type errors in the project's wording
        msg = "must be " + msg.removeprefix("Input should be ")
    msg = msg[0].lower() + msg[1:] if msg else msg
    if quote:
        msg += f", got {short_repr(inp)}"
    path = ".".join(parts) or "<root>"
    line = f"{path}: {msg}"
    return f"{source}: {line}" if source is not None else line
