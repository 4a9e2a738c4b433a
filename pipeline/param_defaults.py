"""One default per setting: the typed config classes hold the defaults, and ``params.yaml`` (the
default profile, which DVC tracks key by key) is generated from them.

Each params section is read by one frozen pydantic class (:data:`SECTIONS`). ``params.yaml``
writes out the keys DVC tracks, with comments for people; their *values* come from the classes::

    python -m pipeline.param_defaults --check    # exit 1 and one line per key that disagrees
    python -m pipeline.param_defaults --write    # set those values from the classes (comments kept)

A profile (``profiles/*.yaml``, ``dvc exp run -S``, a project's own params.yaml) changes values;
it never changes a default. ``tests/test_params.py`` runs the check.
"""

from __future__ import annotations

import argparse
import importlib
import io
import sys
from pathlib import Path
from typing import Any, Mapping

from pydantic import BaseModel
from ruamel.yaml import YAML

from pipeline.atomic import write_text
from pipeline.params import read_params_file, typed_section

SECTIONS: dict[str, str] = {
    "compute": "pipeline.parallel:ComputeConfig",
    "discrepancy": "pipeline.discrepancy.config:DiscrepancyConfig",
    "measure_hidden": "pipeline.discrepancy.hidden:HiddenConfig",
    "events": "pipeline.events:EventConfig",
    "flow": "pipeline.flow:FlowConfig",
    "realvideo": "pipeline.reconstruct:RealVideoConfig",
    "sample": "pipeline.sample_config:SampleConfig",
    "sanity": "pipeline.sanity:SanityConfig",
    "scene.decimals": "pipeline.scene:Decimals",
    "search": "pipeline.search.config:SearchConfig",
    "sim": "pipeline.mjcf:SimOptions",
    "tokens": "pipeline.codec:TokenConfig",
    "model": "pipeline.model.config:ModelConfig",
    "preference": "pipeline.adapt:PreferenceConfig",
}
"""params section (dots for a nested one) -> ``module:Class`` of the config that reads it."""
UNTYPED = ("seed", "paths", "scene", "render")
"""Top-level keys read as plain values (``scene`` holds the typed ``scene.decimals``)."""


def config_classes() -> dict[str, type[BaseModel]]:
    """:data:`SECTIONS` imported: section -> config class."""
    out = {}
    for key, where in SECTIONS.items():
        module, name = where.split(":")
        out[key] = getattr(importlib.import_module(module), name)
    return out


def _section(params: Mapping[str, Any], key: str) -> Mapping[str, Any]:
    for name in key.split("."):
        params = params.get(name) or {}
    return params


def differences(params: Mapping[str, Any]) -> list[str]:
    """Keys of parsed params whose value (validated by its config class) differs from the class
    default, one line each ``<section>.<key>: params <value>, code <default>``; a top-level key
    that is neither typed nor in :data:`UNTYPED` is a difference too. Empty when they agree.

    Raises:
        pipeline.params.ParamsError: a section does not validate (one line naming the key).
    """
    classes = config_classes()
    known = {key.split(".")[0] for key in classes} | set(UNTYPED)
    out = [f"{key}: no config class reads it (add it to pipeline.param_defaults.SECTIONS)"
           for key in params if key not in known]
    for key, cls in classes.items():
        typed, default = typed_section(params, key, cls), cls()
        out += [f"{key}.{name}: params {getattr(typed, name)!r}, code {getattr(default, name)!r}"
                for name in _section(params, key) if getattr(typed, name) != getattr(default, name)]
    return out


def write_defaults(path: str | Path) -> list[str]:
    """Set every typed key of the params file at ``path`` to its class default, keeping its
    layout and comments (ruamel.yaml round trip); keys are neither added nor removed. Written
    atomically, and only if something changed. Returns the keys changed (``section.key``)."""
    path = Path(path)
    yaml = YAML()
    yaml.preserve_quotes = True
    yaml.width = 4096                      # keep flow mappings on the lines they were written on
    yaml.representer.add_representer(type(None), lambda r, _: r.represent_scalar("tag:yaml.org,2002:null", "null"))
    doc = yaml.load(path.read_text())
    params = read_params_file(path)
    changed = []
    for key, cls in config_classes().items():
        typed, default = typed_section(params, key, cls), cls()
        node = doc
        for name in key.split("."):
            node = node.get(name) if node is not None else None
        for name in list(node or {}):
            if getattr(typed, name) != getattr(default, name):
                node[name] = default.model_dump(mode="json")[name]
                changed.append(f"{key}.{name}")
    if changed:
        buf = io.StringIO()
        yaml.dump(doc, buf)
        write_text(path, buf.getvalue())
    return changed


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m pipeline.param_defaults", description=__doc__.split("\n\n")[0])
    ap.add_argument("--params", type=Path, default=Path("params.yaml"), help="params file (default ./params.yaml)")
    mode = ap.add_mutually_exclusive_group(required=True)
    mode.add_argument("--check", action="store_true", help="list the keys that disagree; exit 1 if any")
    mode.add_argument("--write", action="store_true", help="set their values from the config classes")
    args = ap.parse_args(argv)
    if args.check:
        diff = differences(read_params_file(args.params))
        for line in diff:
            print(f"{args.params}: {line}")
        return 1 if diff else 0
    for key in write_defaults(args.params):
        print(f"{args.params}: {key}: set from its config class")
    return 0


if __name__ == "__main__":
    sys.exit(main())
