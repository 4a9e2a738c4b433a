"""The tree id every benchmark report is stamped with (``benchmarks/provenance.py``)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from provenance import tree_id  # noqa: E402


def _git(repo: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(repo), "-c", "user.email=t@example.com", "-c", "user.name=t", *args],
                          capture_output=True, text=True, check=True).stdout.strip()


def test_tree_id_names_the_commit_and_says_when_tracked_files_differ(tmp_path):
    """A clean checkout is its short commit; an edit to a tracked file marks it ``-dirty``; an
    untracked file does not (reports and data are written beside the code); outside a checkout
    the tree is ``unknown``, never a made-up id."""
    repo = tmp_path / "repo"
    repo.mkdir()
    _git(repo, "init", "-q")
    (repo / "a.py").write_text("x = 1\n")
    _git(repo, "add", "a.py")
    _git(repo, "commit", "-q", "-m", "one")
    sha = _git(repo, "rev-parse", "--short", "HEAD")
    assert tree_id(repo) == sha
    (repo / "report.json").write_text("{}")
    assert tree_id(repo) == sha
    (repo / "a.py").write_text("x = 2\n")
    assert tree_id(repo) == sha + "-dirty"
    outside = tmp_path / "plain"
    outside.mkdir()
    assert tree_id(outside) == "unknown"
