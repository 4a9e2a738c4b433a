"""Property-based fuzzing of the scene language (issue 12, item 2).

Generates bad and odd scene documents with hypothesis (wrong types, NaN/inf, huge and tiny
numbers, missing and extra fields, non-unit quaternions, deep nesting, alias bombs, non-UTF-8
bytes, empty and 10 MB files) and feeds each, as a file, to ``pipeline.scene.load_scene`` (the
loader ``dynamics simulate`` uses). Each must end in exactly one of:

* ``SceneError`` with one line ``<file>: <field path>: ...`` of at most 300 characters;
* accepted, compiled by MuJoCo without error, and round-tripping: load -> canonical YAML ->
  load gives an equal scene, whose canonical text is the same.

Anything else (another exception, a long or multi-line message, a failed round trip, a compile
error) is a failure. Writes ``reports/fuzz_scenes.json`` (temp-then-rename).

    MUJOCO_GL=egl python benchmarks/fuzz_scenes.py --examples 10000

``tests/test_fuzz_scenes.py`` runs the same property on a few hundred examples.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from pipeline.atomic import write_json  # noqa: E402
from pipeline.scene import MAX_SCENE_BYTES, Scene, SceneError, load_scene  # noqa: E402

MAX_LINE = 300
"""Longest acceptable error line, characters."""

BASE = {
    "version": 1, "duration": 1.0, "fps": 30, "gravity": 9.81,
    "camera": {"height": 1.2, "pitch": 35.0, "fov": 45.0},
    "objects": [
        {"shape": "sphere", "size": {"radius": 0.1}, "mass": 1.0, "position": [0.0, 0.3, 0.1],
         "orientation": [1.0, 0.0, 0.0, 0.0], "linear_velocity": [1.0, 0.0, 0.0],
         "angular_velocity": [0.0, 0.0, 0.0],
         "material": {"sliding_friction": 0.5, "rolling_friction": 0.0, "damping": 0.0}},
        {"shape": "box", "size": {"width": 0.2, "depth": 0.2, "height": 0.2}, "mass": 2.0,
         "position": [0.5, 0.3, 0.1]},
        {"shape": "cylinder", "size": {"radius": 0.1, "height": 0.2}, "mass": 0.5, "position": [-0.5, 0.3, 0.1]},
    ],
    "static": [{"shape": "box", "size": {"width": 1.0, "depth": 1.0, "height": 0.1},
                "position": [0.0, 2.0, 0.05], "orientation": [1.0, 0.0, 0.0, 0.0]}],
    "effects": [{"effect": "quadratic_drag", "parameters": {"density": 1.2}}],
}

HUGE_INT = "HUGEINT"  # placeholder: yaml cannot dump a >4300-digit int, the text gets one


def _paths(node: Any, prefix: tuple = ()) -> list[tuple]:
    """Every path (keys and list indices) into ``node``, the root excluded."""
    out = []
    if isinstance(node, dict):
        for k, v in node.items():
            out.append(prefix + (k,))
            out += _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out.append(prefix + (i,))
            out += _paths(v, prefix + (i,))
    return out


PATHS = _paths(BASE)

odd_numbers = st.sampled_from([
    math.nan, math.inf, -math.inf, 0.0, -0.0, -1.0, 1e308, -1e308, 1.7976931348623157e308, 5e-324,
    1e-320, 1e-20, 1e-9, 1e-7, 4e-4, 0.0004, 1e-6, 0.99, 1.01, 1e6, 1e19, 1e30, 10 ** 30, -(10 ** 19), 127, 128,
    10000, 10001, 60.0, 60.0001, 2 ** 63, HUGE_INT,
]) | st.floats(allow_nan=True, allow_infinity=True) | st.integers(min_value=-(10 ** 30), max_value=10 ** 30)
odd_values = (odd_numbers | st.none() | st.booleans() | st.text(max_size=20)
              | st.sampled_from(["", "1.0", "nan", ".inf", "sphere", "box", "plane", "cone", "yes", "~", "0x10"])
              | st.lists(odd_numbers, max_size=6) | st.dictionaries(st.text(max_size=5), odd_numbers, max_size=3)
              | st.builds(lambda: [[[[[[]]]]]]))  # a fresh object: edits may go inside it


@st.composite
def edited_documents(draw) -> bytes:
    """A valid scene with 1-4 edits: a field replaced, deleted or renamed, an extra key, a
    quaternion scaled, a list lengthened or shortened."""
    doc = json.loads(json.dumps(BASE))
    for _ in range(draw(st.integers(1, 4))):
        paths = _paths(doc)
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        key = path[-1]
        kind = draw(st.sampled_from(["replace", "replace", "replace", "delete", "extra", "quaternion", "length"]))
        if kind == "replace":
            parent[key] = draw(odd_values)
        elif kind == "delete":
            del parent[key]
        elif kind == "extra":
            target = parent if isinstance(parent, dict) else doc
            target[draw(st.sampled_from(["colour", "Mass", "size2", "", "null", "objects "]))] = draw(odd_values)
        elif kind == "quaternion":
            objs = doc.get("objects")
            if isinstance(objs, list) and objs and isinstance(objs[0], dict):
                s = draw(st.sampled_from([0.0, 0.5, 0.98, 0.995, 1.005, 1.02, 2.0, 1e300]))
                objs[0]["orientation"] = [s, 0.0, 0.0, 0.0]
        elif kind == "length":
            value = parent[key]
            if isinstance(value, list):
                parent[key] = value[:-1] if draw(st.booleans()) else value + value[-1:] * draw(st.integers(1, 130))
    text = yaml.safe_dump(doc, sort_keys=draw(st.booleans()), default_flow_style=draw(st.sampled_from([None, True, False])))
    return text.replace(HUGE_INT, "9" * draw(st.integers(4290, 5000))).encode()


def _bomb(levels: int, width: int) -> str:
    lines = ["a0: &a0 [1, 2, 3]"]
    for i in range(1, levels + 1):
        lines.append(f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * width)}]")
    return "\n".join(lines) + "\n"


@st.composite
def raw_documents(draw) -> bytes:
    """Whole-file oddities: empty, whitespace, non-UTF-8 bytes, random bytes, alias bombs, deep
    nesting (flow and block), scalars and lists as the root, 10 MB files, BOM, tabs."""
    valid = yaml.safe_dump(BASE, sort_keys=False)
    kind = draw(st.sampled_from(["empty", "space", "nonutf8", "bytes", "bomb", "deep_flow", "deep_block", "root",
                                 "big", "bom", "tab", "truncated", "dup_key", "anchor_ok", "tags"]))
    if kind == "empty":
        return b""
    if kind == "space":
        return draw(st.sampled_from([b" ", b"\n\n", b"---\n", b"...\n", b"# only a comment\n", b"~\n"]))
    if kind == "nonutf8":
        pos = draw(st.integers(0, len(valid)))
        bad = draw(st.sampled_from([b"\xff", b"\xfe\xff", b"\xc3\x28", b"\xed\xa0\x80", b"\x80", b"\xf8\x88\x80\x80\x80"]))
        return valid.encode()[:pos] + bad + valid.encode()[pos:]
    if kind == "bytes":
        return draw(st.binary(max_size=300))
    if kind == "bomb":
        return (_bomb(draw(st.integers(2, 12)), draw(st.integers(2, 10))) + valid).encode()
    if kind == "deep_flow":
        n = draw(st.integers(5, 5000))
        open_, close = draw(st.sampled_from([("[", "]"), ("{a: ", "}")]))
        return (f"duration: {open_ * n}{close * n}\n" + valid).encode()
    if kind == "deep_block":
        n = draw(st.integers(5, 300))
        return ("".join(" " * i + f"k{i}:\n" for i in range(n)) + " " * n + "1\n").encode()
    if kind == "root":
        return draw(st.sampled_from([b"1\n", b"- 1\n- 2\n", b"'text'\n", b"null\n", b"[]\n", b"{}\n", b"!!binary aGVsbG8=\n"]))
    if kind == "big":
        size = draw(st.sampled_from([MAX_SCENE_BYTES + 1, 10 * 1024 * 1024]))
        return (valid + "#" * (size - len(valid))).encode()
    if kind == "bom":
        return b"\xef\xbb\xbf" + valid.encode()
    if kind == "tab":
        return valid.replace("  ", "\t", 1).encode()
    if kind == "truncated":
        return valid.encode()[: draw(st.integers(0, len(valid)))]
    if kind == "dup_key":
        return (valid + "fps: 60\n").encode()
    if kind == "anchor_ok":
        return valid.replace("position: [0.5, 0.3, 0.1]", "position: &p [0.5, 0.3, 0.1]").encode()
    return valid.replace("gravity: 9.81", draw(st.sampled_from(
        ["gravity: !!python/object:os.system 'ls'", "gravity: !!float '9.81'", "gravity: !custom 1"]))).encode()


documents = st.one_of(edited_documents(), edited_documents(), raw_documents())
"""Every kind of generated document (two thirds field edits, one third whole-file oddities)."""

LINE = re.compile(r"^(?P<file>[^:]+): (?P<where>[^:]+?): (?P<rule>.+)$")


def check_document(content: bytes, folder: Path) -> tuple[str, str]:
    """Run one document through the CLI's loader; returns ``(outcome, detail)``.

    ``outcome`` is ``error`` (one good line), ``accepted`` (accepted, compiles, round-trips)
    or ``failure:<kind>`` (traceback, bad message, round trip, compile).
    """
    from pipeline.mjcf import compile_model

    path = folder / "doc.yaml"
    path.write_bytes(content)
    try:
        scene = load_scene(path)
    except SceneError as exc:
        msg = str(exc)
        if "\n" in msg or len(msg) > MAX_LINE or not msg.startswith(f"{path}: ") or not LINE.match(msg):
            return "failure:message", msg[:400]
        return "error", msg
    except RecursionError as exc:
        return "failure:traceback", f"RecursionError: {str(exc)[:200]}"
    except Exception as exc:  # noqa: BLE001 - any other exception is what we are looking for
        return "failure:traceback", f"{type(exc).__name__}: {str(exc)[:200]}"
    try:
        text = scene.to_yaml()
        again = Scene.from_yaml(text)
        if again.to_yaml() != text or Scene.from_yaml(again.to_yaml()) != again:
            return "failure:round_trip", text[:300]
    except Exception as exc:  # noqa: BLE001
        return "failure:round_trip", f"{type(exc).__name__}: {str(exc)[:200]}"
    try:
        compile_model(scene)
    except SceneError as exc:  # e.g. an unknown effect name: checked when the MJCF is built, one line
        msg = str(exc).replace("<scene>", str(path), 1)
        if "\n" in msg or len(msg) > MAX_LINE or not LINE.match(msg):
            return "failure:message", msg[:400]
        return "error", msg
    except Exception as exc:  # noqa: BLE001
        return "failure:compile", f"{type(exc).__name__}: {str(exc)[:200]}"
    return "accepted", ""


def run(examples: int, seed: int | None = None) -> dict[str, Any]:
    """Check ``examples`` generated documents; returns the counts and up to 20 failures."""
    counts: Counter[str] = Counter()
    failures: list[dict[str, str]] = []
    slowest = [0.0, ""]
    longest = [0, ""]
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)

        @settings(max_examples=examples, deadline=None, database=None, derandomize=seed is None,
                  suppress_health_check=list(HealthCheck))
        @given(documents)
        def one(content: bytes) -> None:
            t0 = time.perf_counter()
            outcome, detail = check_document(content, folder)
            dt = time.perf_counter() - t0
            counts[outcome] += 1
            if outcome == "error" and ": must " in detail:
                counts["error_in_must_wording"] += 1
            if outcome.startswith("failure") and len(failures) < 20:
                failures.append({"outcome": outcome, "detail": detail, "document": content[:3000].decode("latin-1")})
            if dt > slowest[0]:
                slowest[:] = [dt, content[:80].decode("latin-1")]
            if outcome == "error" and len(detail) > longest[0]:
                longest[:] = [len(detail), detail]

        one()
    n = sum(v for k, v in counts.items() if k != "error_in_must_wording")
    return {"documents": n, "outcomes": dict(sorted(counts.items())),
            "failures": sum(v for k, v in counts.items() if k.startswith("failure")),
            "note": "error_in_must_wording counts the error lines (a subset of error) that read "
                    "'<file>: <field path>: must ...'; documents = accepted + error + failures",
            "slowest_s": round(slowest[0], 3), "slowest_document": slowest[1],
            "longest_error_chars": longest[0], "longest_error": longest[1], "failure_examples": failures}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--examples", type=int, default=10_000)
    parser.add_argument("--out", type=Path, default=ROOT / "reports" / "fuzz_scenes.json")
    args = parser.parse_args()
    t0 = time.time()
    report = run(args.examples)
    report["seconds"] = round(time.time() - t0, 1)
    write_json(args.out, report)
    print(json.dumps({k: v for k, v in report.items() if k != "failure_examples"}, indent=2))
    for f in report["failure_examples"][:5]:
        print(f)
    return 1 if report["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
