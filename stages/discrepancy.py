"""DVC stage `discrepancy`: find -> name -> add -> show on the measured trajectories
(docs/design.md §8), which it reads from ``paths.hidden`` without the truth beside them.

Writes ``paths.reports``/discrepancy.{md,json}, discrepancy_residuals.png,
discrepancy_trajectories.png, and ``paths.discrepancy``: extended scenes
(``scenes/<clip>.yaml`` with an ``effects:`` block), ``effects.yaml``, ``discrepancy.rrd``.
"""

from pipeline import shards
from pipeline.discrepancy import load_config, read_trajectories, run_workflow, write_report
from pipeline.entry import run_stage
from pipeline.params import load_params, path_of


def main() -> None:
    p = load_params()
    cfg, _, sim = load_config(p)
    clips = read_trajectories(path_of(p, "hidden"), default=cfg.default_object)
    result = run_workflow(clips, cfg, sim, log=print)
    rep = write_report(result, path_of(p, "reports"), shards.reset_dir(path_of(p, "discrepancy")))
    print(f"named: {[n['effect'] for n in rep['named']]}; held-out gap {rep['gap']['before'] * 1e3:.2f} -> "
          f"{rep['gap']['after'] * 1e3:.2f} mm")


if __name__ == "__main__":
    run_stage(main)
