"""Markdown table of the main job on the real clips: one row per reports/realvideo/<clip>/metrics.json.

Usage: python scripts/realvideo_table.py reports/realvideo > reports/realvideo/table.md
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pandas as pd


def row(m: dict, name: str) -> dict:
    w = m["window"]
    src = m["sources"]
    return {
        "clip": name,
        "window (s)": f"{w['start_s']:.2f}-{w['start_s'] + w['duration_s']:.2f}",
        "fps used": f"{m['fps_used']:g}",
        "crop -> px": f"{w['crop'][2]}x{w['crop'][3]} -> {w['width']}x{w['height']}",
        "objects": m["objects_found"],
        "view": m["view"],
        "proposals model / perception (valid)": f"{src['model']['valid']}/{src['model']['proposals']} / "
                                                f"{src['perception']['valid']}/{src['perception']['proposals']}",
        "best IoU model / perception": f"{src['model']['best_full_iou'] if src['model']['best_full_iou'] is not None else '-'} / "
                                       f"{src['perception']['best_full_iou'] if src['perception']['best_full_iou'] is not None else '-'}",
        "first sample IoU / EPE": f"{m['first_sample']['full_iou']:.3f} / {m['first_sample']['epe']:.2f}",
        "Best@K IoU / EPE": f"{m['best_of_k']['full_iou']:.3f} / {m['best_of_k']['epe']:.2f}",
        "+ CMA-ES IoU / EPE": f"{m['best_of_k_cmaes']['full_iou']:.3f} / {m['best_of_k_cmaes']['epe']:.2f}",
        "s": m["seconds"],
    }


def main(root: str) -> None:
    rows = [row(json.loads(p.read_text()), p.parent.name) for p in sorted(Path(root).glob("*/metrics.json"))]
    df = pd.DataFrame(rows)
    print(df.to_markdown(index=False))
    ious = [json.loads(p.read_text())["best_of_k_cmaes"]["full_iou"] for p in sorted(Path(root).glob("*/metrics.json"))]
    if ious:
        print(f"\nmean full-sequence IoU after CMA-ES: {sum(ious) / len(ious):.3f}; "
              f"clips >= 0.5: {sum(i >= 0.5 for i in ious)}/{len(ious)}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "reports/realvideo")
