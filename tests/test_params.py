"""One way to read a params section (pipeline.params.typed_section) and one formatter for
pydantic errors (pipeline.errors.format_validation_error): one line
``<file>: <section>.<field path>: must be <rule>, got <value>``; a stage exits 2 with it."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from pipeline.errors import MAX_VALUE_CHARS, format_validation_error
from pipeline.params import ParamsError, load_params, typed_section
from pipeline.scene import Decimals
from pipeline.search import SearchConfig

ROOT = Path(__file__).resolve().parents[1]


class Inner(BaseModel):
    model_config = ConfigDict(extra="forbid")
    n: int = Field(default=1, gt=0)


class Outer(BaseModel):
    model_config = ConfigDict(extra="forbid")
    mode: str = "a"
    items: list[Inner] = []


@pytest.mark.parametrize("section, message", [
    ({"popsize": -1}, "params.yaml: search.popsize: must be >= 2, got -1"),
    ({"popsiz": 8}, "params.yaml: search.popsiz: must not be given (unknown key), got 8"),
    ({"popsize": "many"}, "params.yaml: search.popsize: must be a valid integer, unable to parse string as an "
                          "integer, got 'many'"),
    (3, "params.yaml: search: must be a mapping, got 3"),
])
def test_section_errors_are_one_line(section, message):
    with pytest.raises(ParamsError) as err:
        typed_section({"search": section}, "search", SearchConfig)
    assert str(err.value) == message


def test_nested_sections_required_sections_and_the_file_name(tmp_path):
    assert typed_section({}, "scene.decimals", Decimals) == Decimals()
    with pytest.raises(ParamsError, match=r"^params.yaml: scene.decimals.mass: must be a valid integer, .*got 'x'$"):
        typed_section({"scene": {"decimals": {"mass": "x"}}}, "scene.decimals", Decimals)
    with pytest.raises(ParamsError, match=r"^params.yaml: sim: required section missing$"):
        typed_section({}, "sim", SearchConfig, required=True)
    path = tmp_path / "mine.yaml"
    path.write_text("search: {popsize: -1}\n")
    with pytest.raises(ParamsError, match=rf"^{path}: search.popsize: must be >= 2, got -1$"):
        typed_section(load_params(path), "search", SearchConfig)   # the file that was read is named
    assert typed_section({"search": {"k": 3}}, "search", SearchConfig, overrides={"k": 5}).k == 5


def test_formatter_paths_rules_and_bounded_values():
    def line(data, **kw):
        with pytest.raises(ValidationError) as err:
            Outer.model_validate(data)
        return format_validation_error(err.value, "f.yaml", ("top",), **kw)

    assert line({"items": [{"n": 1}, {"n": 0}]}) == "f.yaml: top.items[1].n: must be > 0, got 0"
    assert line({"items": [{"m": 1}]}) == "f.yaml: top.items[0].m: must not be given (unknown key), got 1"
    assert line({"bogus": 1}, unknown="unknown key (known: {known})", known=("mode", "items")) == \
        "f.yaml: top.bogus: unknown key (known: mode, items)"
    long = line({"mode": list(range(10_000))})
    assert long.startswith("f.yaml: top.mode: must be a valid string, got [0, 1, 2, 3, ...]")
    assert len(long) < 60 + MAX_VALUE_CHARS


def _stage(tmp_path: Path, script: str, params: dict) -> subprocess.CompletedProcess:
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params))
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": "egl"}
    env.pop("DYNAMICS_PARAMS", None)
    return subprocess.run([sys.executable, str(ROOT / "stages" / script)], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("script", ["best_of_k.py", "cmaes.py"])
def test_stage_with_a_bad_param_prints_one_line_and_exits_2(tmp_path, script):
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    params["search"]["popsize"] = -1
    proc = _stage(tmp_path, script, params)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr == "error: params.yaml: search.popsize: must be >= 2, got -1\n"


def test_stage_names_an_unknown_key(tmp_path):
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    params["sim"]["timestepp"] = 0.002
    proc = _stage(tmp_path, "compile_mjcf.py", params)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr == "error: params.yaml: sim.timestepp: must not be given (unknown key), got 0.002\n"


def test_a_project_params_file_overrides_the_shipped_defaults_key_by_key(tmp_path, monkeypatch):
    from pipeline.params import DEFAULTS_FILE, merge_params
    defaults = yaml.safe_load(DEFAULTS_FILE.read_text())
    assert merge_params({"a": {"b": 1, "c": [1, 2]}, "d": 0}, {"a": {"c": [3]}, "e": None}) == \
        {"a": {"b": 1, "c": [3]}, "d": 0, "e": None}
    monkeypatch.delenv("DYNAMICS_PARAMS", raising=False)
    monkeypatch.chdir(tmp_path)                                    # no ./params.yaml: the defaults alone
    p = load_params()
    assert dict(p) == defaults and p.source == str(DEFAULTS_FILE) and p.root is None
    (tmp_path / "params.yaml").write_text("search: {popsize: 12}\n")
    p = load_params()                                              # ./params.yaml over the defaults
    assert p["search"]["popsize"] == 12 and p.source == "params.yaml"
    assert {k: v for k, v in p["search"].items() if k != "popsize"} == \
        {k: v for k, v in defaults["search"].items() if k != "popsize"}
    assert typed_section(p, "search", SearchConfig).popsize == 12
    with pytest.raises(ParamsError, match=r"none.yaml: cannot read"):
        load_params(tmp_path / "none.yaml")                        # a file that was named must exist


def test_relative_paths_are_relative_to_the_params_file(tmp_path, monkeypatch):
    from pipeline.params import path_of
    project = tmp_path / "project"
    project.mkdir()
    (project / "params.yaml").write_text("paths: {model: runs/model}\n")
    monkeypatch.delenv("DYNAMICS_PARAMS", raising=False)
    monkeypatch.chdir(tmp_path)
    assert path_of(load_params(project / "params.yaml"), "model") == project.resolve() / "runs/model"
    monkeypatch.chdir(project)                                     # in its own folder: kept relative
    assert path_of(load_params("params.yaml"), "model") == Path("runs/model")
    (project / "abs.yaml").write_text(f"paths: {{model: {tmp_path / 'm'}}}\n")
    assert path_of(load_params(project / "abs.yaml"), "model") == tmp_path / "m"


def test_params_yaml_agrees_with_the_code_defaults(tmp_path):
    """One default per setting: every key params.yaml gives equals the default of the typed
    config that reads it (pipeline.param_defaults); a profile (profiles/*.yaml, dvc exp run -S)
    changes values, the code holds the defaults, and --write generates params.yaml's values."""
    from pipeline.param_defaults import differences, main, write_defaults
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    assert not differences(params), "\n".join(differences(params))
    assert main(["--check", "--params", str(ROOT / "params.yaml")]) == 0
    # a value that disagrees is named, and --write sets it from the class, comments kept
    text = (ROOT / "params.yaml").read_text()
    assert "\n  lr: 0.0002 " in text
    changed = tmp_path / "params.yaml"
    changed.write_text(text.replace("\n  lr: 0.0002 ", "\n  lr: 0.001 ", 1).replace("\n  bins: 256", "\n  bins: 64", 1))
    assert differences(yaml.safe_load(changed.read_text())) == [
        "tokens.bins: params 64, code 256", "model.lr: params 0.001, code 0.0002"]
    assert main(["--check", "--params", str(changed)]) == 1
    assert write_defaults(changed) == ["tokens.bins", "model.lr"]
    assert not differences(yaml.safe_load(changed.read_text()))
    assert "# fine-tuning the shipped checkpoint" in changed.read_text()
    assert yaml.safe_load(changed.read_text()) == params
