"""Read ``params.yaml``: the one place where stage parameters and output paths live.

The package ships the default params (:data:`DEFAULTS_FILE`, the repository's params.yaml; in a
checkout a link to it, in an installed wheel a copy), so every command runs from any folder. A
project's params.yaml (``./params.yaml``, ``$DYNAMICS_PARAMS`` or ``--params``) only overrides
them: it is merged key by key over the defaults. Relative paths in ``paths`` are relative to
the folder of the project's params file (the working folder when there is none).

Each module owns a typed config (a frozen pydantic model) for its section; this module finds
and parses the files and reads a section into its config with one-line errors::

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
DEFAULTS_FILE = Path(__file__).resolve().parent / "defaults" / "params.yaml"
"""The default params shipped as package data (a link to the repository's params.yaml in a checkout)."""


class ParamsError(UserError, ValueError):
    """params.yaml is missing, malformed or lacks a section (one line naming file and key)."""


class Params(dict):
    """Parsed params (a plain ``dict`` of its sections) that remembers its file (``source``), so
    that :func:`typed_section` errors name the file that was read, and the folder its relative
    paths are relative to (``root``; None = the working folder)."""

    def __init__(self, data: Mapping[str, Any], source: str = PARAMS_FILE, root: Path | None = None):
        super().__init__(data)
        self.source = str(source)
        self.root = root


def read_params_file(path: str | Path) -> dict[str, Any]:
    """One params YAML file as a dict.

    Raises:
        ParamsError: the file is missing, malformed or not a YAML mapping (one line naming it).
    """
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise ParamsError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except yaml.YAMLError as exc:
        raise ParamsError(f"{path}: malformed YAML: {str(exc).splitlines()[0]}") from None
    if not isinstance(data, dict):
        raise ParamsError(f"{path}: must be a mapping")
    return data


def merge_params(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    """``override`` merged over ``base``: mappings key by key (recursively), any other value
    (lists, scalars, null) replaces the base's. Neither input is modified."""
    out = dict(base)
    for key, value in override.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merge_params(out[key], value)
        else:
            out[key] = value
    return out


def load_params(path: str | Path | None = None) -> Params:
    """The package's default params (:data:`DEFAULTS_FILE`) with the project's params file
    merged over them (:func:`merge_params`).

    The project's file is ``path``, else ``$DYNAMICS_PARAMS``, else ``./params.yaml`` if it
    exists; with none of them the defaults alone are returned.

    Returns:
        the sections, as a :class:`Params` dict whose ``source`` is the project's file (or the
        defaults file) and whose ``root`` is the project file's folder (None when that is the
        working folder, or with the defaults alone).

    Raises:
        ParamsError: a file that was named (``path``, ``$DYNAMICS_PARAMS``) is missing, or a file
            is malformed or not a YAML mapping.
    """
    named = path or os.environ.get("DYNAMICS_PARAMS")
    project = Path(named) if named else (Path(PARAMS_FILE) if Path(PARAMS_FILE).is_file() else None)
    defaults = read_params_file(DEFAULTS_FILE)
    if project is None:
        return Params(defaults, source=str(DEFAULTS_FILE))
    data = merge_params(defaults, read_params_file(project))
    folder = project.resolve().parent
    return Params(data, source=str(project), root=None if folder == Path.cwd().resolve() else folder)


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
    """Output directory ``paths.<name>`` (e.g. ``data/video``); a relative path is taken
    relative to the params file's folder (``params.root``) when that is not the working folder."""
    source = getattr(params, "source", PARAMS_FILE)
    path = Path(section(section(params, "paths"), name, source=f"{source}: paths"))
    root = getattr(params, "root", None)
    return path if root is None or path.is_absolute() else root / path
