"""Import structure of the project (issue 11): no import cycles among the modules of
``pipeline/``, and no imports inside functions in ``pipeline/`` and ``stages/`` except of heavy
optional libraries (so a cycle can't hide in a function body, and every dependency of a module
shows at its top, where ``tests/test_dvc_deps.py`` and readers see it).

Read with ``ast`` only: nothing is imported.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

HEAVY = {
    "torch", "transformers",       # the vision-language model: seconds to import
    "rerun",                        # viewer, only for .rrd recordings
    "matplotlib",                   # plots of curves and histories
    "ray",                          # optional compute backend (compute.backend: ray)
    "zarr",                         # optional array store of the shards
    "xgrammar",                     # grammar-constrained sampling
    "cma",                          # CMA-ES: imports matplotlib.pyplot and scipy.stats (~0.5 s)
    "mujoco.rendering.classic.gl_context",  # the GL context (pipeline/render.py): created on first render
    "pipeline.model",               # the project's model package: imports torch at its top
    "pipeline.raft",                # RAFT optical flow: imports torch at its top (flow.method: raft only)
}
"""Modules that may be imported inside a function (dotted prefixes)."""

FUNCTION_IMPORTS_PENDING: set[str] = set()
"""Modules (and packages, by prefix) exempt from the function-level check: none (the
discrepancy package was the last; issue 11)."""


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _files() -> dict[str, Path]:
    files = sorted((ROOT / "pipeline").rglob("*.py")) + sorted((ROOT / "stages").glob("*.py"))
    return {_module_name(p): p for p in files}


MODULES = _files()


def _matches(name: str, prefixes: set[str]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


def _allowed_in_function(name: str, module: str) -> bool:
    """Whether ``module`` may import ``name`` inside a function: a heavy library, or a heavy
    project package imported from outside it (inside, its modules import each other at the top)."""
    if name == "pipeline" or name.startswith("pipeline."):
        return any(_matches(name, {p}) and not _matches(module, {p}) for p in HEAVY if p.startswith("pipeline."))
    return _matches(name, HEAVY)


def _imported(node: ast.Import | ast.ImportFrom, module: str) -> list[str]:
    """Absolute names a statement imports (``from a import b``: ``a.b`` when that is a
    project module, else ``a``)."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    base = node.module or ""
    if node.level:  # relative import
        pkg = module.split(".")
        if not MODULES.get(module, Path()).name == "__init__.py":
            pkg = pkg[:-1]
        pkg = pkg[: len(pkg) - (node.level - 1)]
        base = ".".join(pkg + ([base] if base else []))
    out = []
    for a in node.names:
        full = f"{base}.{a.name}"
        out.append(full if full in MODULES else base)
    return out


def _walk(tree: ast.AST, in_function: bool = False):
    """``(import node, inside a function?)`` for every import statement."""
    for child in ast.iter_child_nodes(tree):
        if isinstance(child, (ast.Import, ast.ImportFrom)):
            yield child, in_function
        inner = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
        yield from _walk(child, inner)


def _imports(module: str) -> tuple[set[str], list[tuple[int, str]]]:
    """Project modules imported at module level, and ``(line, name)`` of function-level imports."""
    tree = ast.parse(MODULES[module].read_text(), filename=str(MODULES[module]))
    top, inner = set(), []
    for node, in_function in _walk(tree):
        for name in _imported(node, module):
            if in_function:
                inner.append((node.lineno, name))
            elif name in MODULES and name != module:
                top.add(name)
    return top, inner


def _graph() -> dict[str, set[str]]:
    return {m: _imports(m)[0] for m in MODULES if m.startswith("pipeline")}


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as a path ``[a, b, ..., a]``, or None (depth-first search)."""
    state: dict[str, int] = {}  # 1: on the stack, 2: done
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for n in sorted(graph.get(m, ())):
            if state.get(n) == 1:
                return stack[stack.index(n):] + [n]
            if n not in state and (found := visit(n)):
                return found
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state and (found := visit(m)):
            return found
    return None


def test_the_checker_sees_a_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_no_import_cycles_in_pipeline():
    graph = _graph()
    assert "pipeline.mjcf" in graph and "pipeline.effects" in graph["pipeline.mjcf"]
    assert "pipeline.mjcf" not in graph["pipeline.effects"]
    cycle = _cycle(graph)
    assert cycle is None, f"import cycle: {' -> '.join(cycle)}"


def test_no_function_level_imports_but_heavy_optional_libraries():
    found = []
    for module, path in MODULES.items():
        if _matches(module, FUNCTION_IMPORTS_PENDING):
            continue
        for line, name in sorted(set(_imports(module)[1])):
            if not _allowed_in_function(name, module):
                found.append(f"{path.relative_to(ROOT)}:{line}: {name}")
    assert not found, "imports inside functions (move them to the module's top):\n" + "\n".join(found)
