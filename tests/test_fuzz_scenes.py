"""Property-based fuzzing of the scene language (issue 12, item 2): a few hundred generated bad
or odd documents through the CLI's loader; each ends in one short ``<file>: <field path>: ...``
line or is accepted, compiles and round-trips. ``benchmarks/fuzz_scenes.py`` runs >= 10,000."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("fuzz_scenes", ROOT / "benchmarks" / "fuzz_scenes.py")
fuzz = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(fuzz)


@settings(max_examples=300, deadline=None, database=None, derandomize=True,
          suppress_health_check=list(HealthCheck))
@given(fuzz.documents)
def test_generated_documents_end_in_one_line_or_round_trip(tmp_path_factory, content):
    outcome, detail = fuzz.check_document(content, tmp_path_factory.mktemp("doc"))
    assert outcome in ("error", "accepted"), (outcome, detail, content[:200])


@pytest.mark.parametrize("content,outcome", [
    (b"", "error"),
    (b"\xff", "error"),
    (("duration: " + "[" * 996 + "]" * 996 + "\n").encode(), "error"),
    (fuzz._bomb(8, 9).encode(), "error"),
    (b"#" * (10 * 1024 * 1024), "error"),
])
def test_known_hostile_documents(tmp_path, content, outcome):
    got, detail = fuzz.check_document(content, tmp_path)
    assert got == outcome, detail


def test_checker_catches_what_it_must(tmp_path, monkeypatch):
    """The property can fail: a loader that leaks a traceback, a long message or a scene that
    does not round-trip is reported as a failure."""
    import yaml

    from pipeline import scene as scene_mod

    valid = yaml.safe_dump(fuzz.BASE).encode()
    assert fuzz.check_document(valid, tmp_path)[0] == "accepted"
    monkeypatch.setattr(fuzz, "load_scene", lambda p: (_ for _ in ()).throw(UnicodeDecodeError("utf-8", b"", 0, 1, "x")))
    assert fuzz.check_document(valid, tmp_path)[0] == "failure:traceback"
    monkeypatch.setattr(fuzz, "load_scene", lambda p: (_ for _ in ()).throw(scene_mod.SceneError(f"{p}: x: " + "y" * 400)))
    assert fuzz.check_document(valid, tmp_path)[0] == "failure:message"
    monkeypatch.undo()
    monkeypatch.setattr(scene_mod, "_num", lambda x, nd, positive=False: repr(round(float(x), 1)))  # 0.0004 -> 0.0
    tiny = yaml.safe_dump({**fuzz.BASE, "objects": [{**fuzz.BASE["objects"][1], "mass": 0.0004}]}).encode()
    assert fuzz.check_document(tiny, tmp_path)[0] == "failure:round_trip"
