"""Single-clip foam-ball drop (issue 10 item 1): what the discrepancy workflow names, with its
value, interval and forward gap, on the clip of ``tests/test_discrepancy.py::_foam_drop``
(a simulated 1 m drop of a 0.4 g, r = 15 mm ball in air, 3 mm noise, 30 fps) at the params
timestep. Prints JSON.

Usage::

    MUJOCO_GL=egl .venv/bin/python benchmarks/foam_drop.py
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import test_discrepancy as T  # noqa: E402  (the clip is built by the test's helper)

from pipeline import discrepancy as D  # noqa: E402


def main() -> None:
    result = D.run_workflow(T._foam_drop(seed=0), D.DiscrepancyConfig(threads=1), T.OPTS)
    gap = result.gap
    print(json.dumps({"named": [{"effect": n["effect"], "parameters": n["parameters"], "ci": n["ci"],
                                 "ci_method": n["ci_method"]} for n in result.named],
                      "gap": {k: gap[k] for k in ("kind", "before", "after", "noise", "excess_shrink")},
                      "timestep": T.OPTS.timestep, "runtime_s": result.runtime_s}, indent=1))


if __name__ == "__main__":
    main()
