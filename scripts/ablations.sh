#!/usr/bin/env bash
# The paper's two ablations on our data (issue 8): input (flow | rgb | flow+rgb) and reasoning
# on/off, each a `dvc exp run -S ...` of the default small profile. Each copies its
# reports/metrics.json to reports/ablations/<name>.json; scripts/ablation_table.py then writes
# reports/ablations.md. Run after `dvc repro` (the default row: flow+rgb, reasoning on).
# Note: every variant fine-tunes the shipped checkpoint (pretrained with flow+rgb and reasoning)
# for model.max_steps steps on the small profile; it is not a from-scratch pretraining per variant.
set -euo pipefail
cd "$(dirname "$0")/.."
export PATH="$PWD/.venv/bin:$PATH" MUJOCO_GL=${MUJOCO_GL:-egl} HF_HUB_OFFLINE=1 TOKENIZERS_PARALLELISM=false
mkdir -p reports/ablations
dvc repro
cp params.yaml reports/ablations/.params.yaml.default
cp reports/metrics.json reports/ablations/flow+rgb.json
for spec in ${ABLATIONS:-"model.input=flow" "model.input=rgb" "model.reasoning=false"}; do
  name=${spec#model.}; name=${name/=/_}
  echo "== dvc exp run -S $spec"
  cp reports/ablations/.params.yaml.default params.yaml   # each variant differs from the default in one key
  dvc exp run -S "$spec"
  cp reports/metrics.json "reports/ablations/$name.json"
done
mv reports/ablations/.params.yaml.default params.yaml
dvc repro   # back to the default params (outputs restored from DVC's run cache)
python scripts/ablation_table.py reports/ablations/*.json > reports/ablations.md
cat reports/ablations.md
