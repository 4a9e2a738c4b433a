"""DVC stage `measure_hidden`: measured trajectories with a hidden effect (docs/design.md §8).

One effect is drawn from the library (or none, ``measure_hidden.effect: random``) at a random
strength; every clip is simulated with it and measured with noise. Writes ``paths.hidden``
(``trajectories.parquet``: clip, object, t, x, y, z [m, s, z up], qw..qz, shape, radius,
width, depth, height, mass; ``meta.json``) and, apart, ``paths.hidden_truth``
(``truth.json``: the effect and its parameters), which the `discrepancy` stage never reads.
"""

from pipeline import shards
from pipeline.discrepancy import generate_hidden, load_config
from pipeline.entry import run_stage
from pipeline.params import load_params, path_of


def main() -> None:
    p = load_params()
    cfg, hidden, sim = load_config(p)
    seed = int(p.get("seed", 0))
    columns, truth = generate_hidden(seed, hidden, sim, fit=cfg)   # with the fits' base contact
    out, truth_dir = shards.reset_dir(path_of(p, "hidden")), shards.reset_dir(path_of(p, "hidden_truth"))
    meta = {"params": hidden.model_dump(), "seed": seed,
            "units": {"t": "s", "x": "m", "y": "m", "z": "m", "radius": "m", "width": "m", "depth": "m",
                      "height": "m", "mass": "kg", "qw..qz": "unit quaternion, world from body"}}
    shards.write_table(out / "trajectories.parquet", [dict(zip(columns, row)) for row in zip(*columns.values())],
                       metadata=meta)
    shards.write_meta(out, {**meta, "files": ["trajectories.parquet"], "clips": len(truth["clips"])})
    shards.write_json(truth_dir / "truth.json", truth)


if __name__ == "__main__":
    run_stage(main)
