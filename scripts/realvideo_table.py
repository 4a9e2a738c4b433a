"""Markdown table of the main job on the real clips: one row per reports/realvideo/<clip>/metrics.json.

Usage: python scripts/realvideo_table.py reports/realvideo > reports/realvideo/table.md
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pandas as pd


def _one(a: dict | None, key: str) -> str:
    return "-" if not a or a.get(key) is None else f"{a[key]:.3f}"


def _pair(a: dict | None, k1: str, k2: str) -> str:
    return f"{_one(a, k1)} / {_one(a, k2)}"


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
        # headline: strict IoU, no free credit (frames where an object and its match are both
        # absent are skipped; issue 29 item 7); beside it docs/design.md §7's all-frames IoU
        "first sample IoU strict / all frames": _pair(m["first_sample"], "strict_full_iou", "full_iou"),
        "Best@K IoU strict / all frames": _pair(m["best_of_k"], "strict_full_iou", "full_iou"),
        "+ CMA-ES IoU strict / all frames": _pair(m["best_of_k_cmaes"], "strict_full_iou", "full_iou"),
        "+ CMA-ES EPE": f"{m['best_of_k_cmaes']['epe']:.2f}",
        # issue 36: against the hand labels on the window's labelled frames (matched IoU over frames
        # where either is visible), beside the same metric against the observation the search fits
        "labelled frames": (m.get("against_labels") or {}).get("n_labelled", "-"),
        "re-sim vs labels / vs observation": _pair(m.get("against_labels"), "resim_vs_labels", "resim_vs_observation"),
        "observation vs labels": _one(m.get("against_labels"), "observation_vs_labels"),
        "s": m["seconds"],
    }


def main(root: str) -> None:
    rows = [row(json.loads(p.read_text()), p.parent.name) for p in sorted(Path(root).glob("*/metrics.json"))]
    df = pd.DataFrame(rows)
    print(df.to_markdown(index=False))
    ious = [json.loads(p.read_text())["best_of_k_cmaes"]["full_iou"] for p in sorted(Path(root).glob("*/metrics.json"))]
    strict = [v for p in sorted(Path(root).glob("*/metrics.json"))
              if (v := json.loads(p.read_text())["best_of_k_cmaes"].get("strict_full_iou")) is not None]
    if ious:
        print("\nmean full-sequence IoU after CMA-ES (against the observation): "
              + (f"strict (no free credit) {sum(strict) / len(strict):.3f}, clips >= 0.5: "
                 f"{sum(i >= 0.5 for i in strict)}/{len(strict)}; " if strict else "")
              + f"all frames (docs/design.md §7) {sum(ious) / len(ious):.3f}, clips >= 0.5: "
              f"{sum(i >= 0.5 for i in ious)}/{len(ious)}")
    lab = [a for p in sorted(Path(root).glob("*/metrics.json"))
           if (a := json.loads(p.read_text()).get("against_labels")) and a.get("resim_vs_labels") is not None]
    if lab:
        print(f"mean matched IoU against the hand labels: re-simulation {sum(a['resim_vs_labels'] for a in lab) / len(lab):.3f}, "
              f"observation {sum(a['observation_vs_labels'] for a in lab) / len(lab):.3f} ({len(lab)} clips with "
              f"labelled frames in the window)")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "reports/realvideo")
