"""DVC stage `preference`: label-free preference optimisation (DPO) of the fine-tuned model on
videos (issue 37; :mod:`pipeline.adapt`, the same code as ``dynamics adapt``).

Reads ``paths.model`` and params ``preference``. With ``preference.enabled: false`` (the
default) it writes ``paths.model_adapted`` as a copy of ``paths.model`` (``preference.json``
says so), so the rest of the pipeline is unchanged; with ``true`` (the ablation
``dvc exp run -S preference.enabled=true``) it adapts ``paths.model`` on ``preference.videos``
(files or folders of videos; no labels are read) for ``preference.rounds`` rounds and writes the
adapted checkpoint there, with ``adapt_log.csv`` / ``adapt_curve.png`` (beta, reward margin, KL,
guard per round), copied to ``paths.reports``/``preference/``. The ``predict`` stage reads
``paths.model_adapted``.
"""

import json
import shutil
from pathlib import Path

from pipeline.adapt import CURVE_PNG, LOG_FILE, adapt, preference_config
from pipeline.atomic import replace_path, temp_dir_for
from pipeline.entry import run_stage
from pipeline.params import load_params, path_of


def main() -> None:
    p = load_params()
    pc = preference_config(p)
    src, out = Path(path_of(p, "model")), Path(path_of(p, "model_adapted"))
    reports = Path(path_of(p, "reports")) / "preference"
    if not pc.enabled:
        tmp = temp_dir_for(out)
        try:
            shutil.copytree(src, tmp, dirs_exist_ok=True)
            (tmp / "preference.json").write_text(json.dumps({"enabled": False, "base": str(src),
                                                             "note": "preference.enabled is false: the fine-tuned "
                                                                     "model, unchanged"}, indent=1) + "\n")
            replace_path(tmp, out)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        print(f"preference: disabled: {out} is {src} unchanged (dvc exp run -S preference.enabled=true adapts it)")
        return
    root = Path(getattr(p, "root", None) or ".")
    videos = [str(v if Path(v).is_absolute() else root / v) for v in pc.videos]
    shutil.rmtree(out, ignore_errors=True)   # DVC clears outputs before a run; a manual rerun starts over too
    state = adapt(videos, out, p, base=src)
    (out / "preference.json").write_text(json.dumps({"enabled": True, "base": str(src), "rounds_done":
                                                     state["rounds_done"], "stopped": state["stopped"]}, indent=1) + "\n")
    reports.mkdir(parents=True, exist_ok=True)
    for name in (LOG_FILE, CURVE_PNG):
        if (out / name).exists():
            shutil.copy2(out / name, reports / name)


if __name__ == "__main__":
    run_stage(main)
