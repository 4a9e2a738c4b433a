"""Markdown table of ablation runs from their reports/metrics.json copies.

    python scripts/ablation_table.py reports/ablations/*.json > reports/ablations.md
"""

import json
import sys
from pathlib import Path

from tabulate import tabulate

ROWS = (("first_sample", "Model (first sample)"), ("best_of_k", "Best@K"), ("best_of_k_cmaes", "Best@K + CMA-ES"),
        ("trivial_baseline_cmaes", "Trivial baseline + CMA-ES"))


HEADER = ["Method", "Input", "Reasoning", "Flow", "Split", "Composition acc.", "Initial IoU",
          "Full-sequence IoU (strict)", "Full-sequence IoU (all frames)", "EPE (px)", "valid"]


def main(paths: list[str]) -> None:
    rows = []
    for path in paths:
        m = json.loads(Path(path).read_text())
        for key, label in ROWS:
            for split, r in (m["methods"].get(key) or {}).items():
                epe = f"{r['epe']:.2f}" if r.get("epe") is not None else "–"
                rows.append([label, m["input"] if "baseline" not in key else "–", str(m["reasoning"]),
                             (m.get("observed") or {}).get("flow", "dis"), split,
                             f"{r['composition_accuracy']:.3f}", f"{r['initial_iou']:.3f}",
                             f"{r['strict_full_iou']:.3f}" if r.get("strict_full_iou") is not None else "–",
                             f"{r['full_iou']:.3f}",
                             epe, f"{r['n_valid']}/{r['n']}"])
    print(tabulate(rows, HEADER, tablefmt="github", disable_numparse=True))


if __name__ == "__main__":
    main(sys.argv[1:])
