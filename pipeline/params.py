"""Read ``params.yaml``: the one place where stage parameters and output paths live.

Each module owns a typed config for its section (e.g. ``model.ModelConfig(**p["model"])``);
this module only finds and parses the file.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

from pipeline.errors import UserError

PARAMS_FILE = "params.yaml"


class ParamsError(UserError, ValueError):
    """params.yaml is missing, malformed or lacks a section (one line naming file and key)."""


def load_params(path: str | Path | None = None) -> dict[str, Any]:
    """Parse params.yaml (``$DYNAMICS_PARAMS`` or ./params.yaml by default).

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
    return data


def section(params: dict[str, Any], key: str, source: str = PARAMS_FILE) -> dict[str, Any]:
    """``params[key]`` with a one-line error if it is missing."""
    try:
        value = params[key]
    except KeyError:
        raise ParamsError(f"{source}: {key}: required section missing") from None
    return value if value is not None else {}


def path_of(params: dict[str, Any], name: str) -> Path:
    """Output directory ``paths.<name>`` (e.g. ``data/video``)."""
    return Path(section(section(params, "paths"), name, source=f"{PARAMS_FILE}: paths"))
