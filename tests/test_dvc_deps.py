"""dvc.yaml tells the truth (issue 11, item 5): every project module a stage's script imports,
directly or through other project modules, at module level or inside a function, is among the
stage's deps, so editing it makes ``dvc status`` show the stage as changed and ``dvc repro``
rerun it. A new import cannot silently break reproducibility: this test fails first.

Imports are read with :mod:`ast` (no code runs). A dep that is a folder (``pipeline/model``)
covers every module under it. Exempt, because they change no output: ``pipeline/__init__.py``
(environment defaults for rendering and logging: ``MUJOCO_GL``, FFmpeg's log level) and
``pipeline/stage_watchdog.py`` (the watchdog that ends a stage script when dvc dies).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
EXEMPT = {"pipeline/__init__.py", "pipeline/stage_watchdog.py"}


def _module_file(name: str) -> Path | None:
    """``pipeline.x.y`` -> ``pipeline/x/y.py`` or ``pipeline/x/y/__init__.py`` (None if absent)."""
    base = ROOT.joinpath(*name.split("."))
    for cand in (base.with_suffix(".py"), base / "__init__.py"):
        if cand.is_file():
            return cand
    return None


def _imports(path: Path) -> set[Path]:
    """Project module files imported by ``path`` (any level, any scope)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    rel = path.relative_to(ROOT) if path.is_relative_to(ROOT) else Path(path.name)   # a probe outside the tree
    pkg = ".".join(rel.with_suffix("").parts[:-1])
    if path.name == "__init__.py":
        pkg = ".".join(rel.parent.parts)
    out: set[Path] = set()
    for node in ast.walk(tree):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            mod = node.module or ""
            if node.level:   # relative import
                parts = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                mod = ".".join([p for p in parts if p] + ([mod] if mod else []))
            names = [mod] + [f"{mod}.{a.name}" for a in node.names]
        for name in names:
            if not (name == "pipeline" or name.startswith("pipeline.") or name.startswith("stages.")):
                continue
            parts = name.split(".")
            for i in range(1, len(parts) + 1):      # a.b.c imports a, a.b and a.b.c
                f = _module_file(".".join(parts[:i]))
                if f is not None:
                    out.add(f)
    return out


def _closure(script: Path) -> set[str]:
    seen: set[Path] = set()
    todo = [script]
    while todo:
        f = todo.pop()
        if f in seen:
            continue
        seen.add(f)
        todo.extend(_imports(f) - seen)
    return {str(f.relative_to(ROOT)) for f in seen}


def _stages() -> list[tuple[str, dict]]:
    spec = yaml.safe_load((ROOT / "dvc.yaml").read_text())
    return list(spec["stages"].items())


@pytest.mark.parametrize("name,stage", _stages(), ids=[n for n, _ in _stages()])
def test_stage_deps_cover_every_imported_project_module(name, stage):
    cmd = stage["cmd"] if isinstance(stage["cmd"], str) else stage["cmd"][0]
    script = next((w for w in cmd.split() if w.endswith(".py")), None)
    assert script, f"{name}: cmd does not run a Python script: {cmd}"
    deps = [str(d) for d in stage.get("deps", [])]
    assert script in deps, f"{name}: its own script {script} is not a dep"
    missing = []
    for module in sorted(_closure(ROOT / script) - EXEMPT):
        if not any(module == d or module.startswith(d.rstrip("/") + "/") for d in deps):
            missing.append(module)
    assert not missing, f"dvc.yaml: stages.{name}.deps: must list every imported project module, missing {missing}"


def test_the_closure_sees_function_level_and_transitive_imports(tmp_path):
    """The import reader itself: an import inside a function is found (a probe script), and
    the discrepancy stage reaches viz only through the pipeline.discrepancy package (its
    ``__init__`` -> ``plots`` -> ``viz``) and mjcf and scene only through other modules; all
    are found. A folder dep (``pipeline/discrepancy``) covers the package's modules."""
    probe = tmp_path / "probe.py"
    probe.write_text("def f():\n    from pipeline import shards\n")
    assert ROOT / "pipeline" / "shards.py" in _imports(probe)
    closure = _closure(ROOT / "stages" / "discrepancy.py")
    assert "pipeline/discrepancy/plots.py" in closure and "pipeline/viz.py" in closure
    assert "pipeline/mjcf.py" in closure and "pipeline/scene.py" in closure
