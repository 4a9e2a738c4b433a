#!/usr/bin/env bash
# The preference ablation (issue 37): `dvc repro` of the default profile, then
# `dvc exp run -S preference.enabled=true` (the preference stage adapts the fine-tuned model on
# preference.videos, the six shared real clips by default, and predict reads the adapted model),
# in one fresh DVC workspace beside this repository (so this tree's committed reports stay as they
# are), on one machine in one run. Writes reports/ablation_preference.md and the two metrics.json
# copies plus the adapt log under reports/ablation_preference/.
#   bash scripts/preference_ablation.sh          # ~35 min on 2 cores
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
WS=${WS:-$ROOT/../preference_ablation_ws}   # beside the repository: params' ../shared resolves the same
export PATH="$ROOT/.venv/bin:$PATH" MUJOCO_GL=${MUJOCO_GL:-egl} HF_HUB_OFFLINE=1 TOKENIZERS_PARALLELISM=false \
       PYTHONPATH="$WS" DVC_NO_ANALYTICS=1
rm -rf "$WS" && mkdir -p "$WS"
cp dvc.yaml params.yaml .gitignore "$WS"/ && cp -r stages pipeline "$WS"/
cd "$WS"
git init -q && git add -A && git -c user.email=ci@example.com -c user.name=ci commit -qm init
dvc init -q && dvc config core.analytics false
OUT=$ROOT/reports/ablation_preference
mkdir -p "$OUT"
dvc repro
cp reports/metrics.json "$OUT/preference_off.json"
dvc exp run -S preference.enabled=true
cp reports/metrics.json "$OUT/preference_on.json"
cp reports/preference/* "$OUT/"
python - "$OUT" > "$ROOT/reports/ablation_preference.md" <<'PY'
import json, sys
from pathlib import Path
out = Path(sys.argv[1])
rows = ["# Preference ablation (issue 37): `dvc exp run -S preference.enabled=true` against the default", "",
        "Command: `bash scripts/preference_ablation.sh` (one workspace, one machine, one run). The preference stage "
        "adapts the fine-tuned model on `preference.videos` (the six shared real clips, videos only); the test "
        "splits are the default profile's synthetic renders.", "",
        "| preference | method | split | composition | initial IoU | full IoU (strict) | full IoU (all frames) | EPE | valid |",
        "|---|---|---|---|---|---|---|---|---|"]
for name in ("off", "on"):
    m = json.loads((out / f"preference_{name}.json").read_text())
    for key, label in (("first_sample", "first sample"), ("best_of_k", "Best@K"), ("best_of_k_cmaes", "Best@K + CMA-ES")):
        for split, r in m["methods"][key].items():
            strict = r.get("strict_full_iou")
            rows.append(f"| {name} | {label} | {split} | {r['composition_accuracy']:.3f} | {r['initial_iou']:.3f} | "
                        f"{'–' if strict is None else f'{strict:.3f}'} | {r['full_iou']:.3f} | {r['epe']:.2f} | "
                        f"{r['n_valid']}/{r['n']} |")
log = out / "adapt_log.csv"
if log.exists():
    rows += ["", "Adapt log (`adapt_log.csv`):", "", "```", log.read_text().strip(), "```"]
print("\n".join(rows))
PY
cat "$ROOT/reports/ablation_preference.md"
