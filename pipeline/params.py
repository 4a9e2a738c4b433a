"""Read ``params.yaml``: the one place where stage parameters and output paths live.

Each module owns a typed config (a frozen pydantic model) for its section; this module finds
and parses the file and reads a section into its config with one-line errors::

    p = load_params()
    cfg = typed_section(p, "search", SearchConfig)   # params.yaml: search.popsize: must be > 0, got -1
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Mapping, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from pipeline.errors import UserError, format_validation_error, short_repr

C = TypeVar("C", bound=BaseModel)

PARAMS_FILE = "params.yaml"


class ParamsError(UserError, ValueError):
    """params.yaml is missing, malformed or lacks a section (one line naming file and key)."""


class Params(dict):
    """Parsed params.yaml (a plain ``dict`` of its sections) that remembers its file
    (``source``), so that :func:`typed_section` errors name the file that was read."""

    def __init__(self, data: Mapping[str, Any], source: str = PARAMS_FILE):
        super().__init__(data)
        self.source = str(source)


def load_params(path: str | Path | None = None) -> Params:
    """Parse params.yaml (``$DYNAMICS_PARAMS`` or ./params.yaml by default).

    Returns:
        the sections, as a :class:`Params` dict whose ``source`` is the file's path.

    Raises:
        ParamsError: the file is missing or not a YAML mapping.
    """
    path = Path(path or os.environ.get("DYNAMICS_PARAMS", PARAMS_FILE))
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise ParamsError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except yaml.YAMLError as exc:
        raise ParamsError(f"{path}: malformed YAML: {str(exc).splitlines()[0]}") from None
    if not isinstance(data, dict):
        raise ParamsError(f"{path}: must be a mapping")
    return Params(data, source=str(path))


def section(params: Mapping[str, Any], key: str, source: str | None = None) -> dict[str, Any]:
    """``params[key]`` (raw, untyped) with a one-line error if it is missing; prefer
    :func:`typed_section` for a section that has a config class."""
    source = source or getattr(params, "source", PARAMS_FILE)
    try:
        value = params[key]
    except KeyError:
        raise ParamsError(f"{source}: {key}: required section missing") from None
    return value if value is not None else {}


def typed_section(params: Mapping[str, Any], key: str, cls: type[C], source: str | None = None, *,
                  required: bool = False, defaults: Mapping[str, Any] | None = None,
                  overrides: Mapping[str, Any] | None = None, error: type[UserError] = ParamsError,
                  unknown: str | None = None) -> C:
    """Section ``key`` of parsed params validated into ``cls``.

    Args:
        params: parsed params.yaml (:func:`load_params`).
        key: section name, e.g. ``"search"``; dots for a nested section (``"scene.decimals"``).
        cls: the section's pydantic model (``extra="forbid"``, frozen).
        source: file named in errors (default: ``params.source`` of a :func:`load_params`
            result, else ``params.yaml``).
        required: a missing (or null) section is an error; otherwise it takes ``cls``'s
            defaults (and fails only if ``cls`` has required fields, naming the first).
        defaults: values used where the section does not give the key (e.g. the top-level
            ``seed`` for ``model.seed``).
        overrides: values that replace the section's (e.g. ``sample.width`` from
            ``render.width``, or a benchmark's command-line option).
        error: the :class:`UserError` subclass raised (``ParamsError`` unless the owning module
            has its own, e.g. ``ModelError``).
        unknown: wording of an unknown key (see :func:`pipeline.errors.format_validation_error`;
            default ``must not be given (unknown key), got <value>``).

    Returns:
        The validated ``cls`` instance.

    Raises:
        ParamsError (or ``error``): one line ``<source>: <key>.<field path>: must be <rule>, got
            <value>``, e.g. ``params.yaml: search.popsize: must be > 0, got -1``; the section is
            missing while ``required``; or it is not a mapping.
    """
    source = source or getattr(params, "source", PARAMS_FILE)
    data: Any = params
    for depth, name in enumerate(key.split(".")):
        where = ".".join(key.split(".")[:depth + 1])
        data = data.get(name)
        if data is None:
            if required:
                raise error(f"{source}: {where}: required section missing")
            data = {}
        if not isinstance(data, Mapping):
            raise error(f"{source}: {where}: must be a mapping, got {short_repr(data)}")
    data = {**(defaults or {}), **data, **(overrides or {})}
    try:
        return cls.model_validate(data)
    except ValidationError as exc:
        extra = {} if unknown is None else {"unknown": unknown, "known": tuple(cls.model_fields)}
        raise error(format_validation_error(exc, source, key.split("."), **extra)) from None


def path_of(params: dict[str, Any], name: str) -> Path:
    """Output directory ``paths.<name>`` (e.g. ``data/video``)."""
    source = getattr(params, "source", PARAMS_FILE)
    return Path(section(section(params, "paths"), name, source=f"{source}: paths"))
