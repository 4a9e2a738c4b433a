#!/usr/bin/env bash
# Rebuild the shipped checkpoint pipeline/checkpoints/dynamics-tiny from scratch (issue 8): the `pretrain`
# profile (profiles/pretrain.yaml: 20,000 training scenes) through the same stage scripts as
# `dvc repro`, then export. Resumable: a stage whose output is complete is skipped, training
# continues from data/pretrain/model. Logs: data/pretrain/logs/. Hours on 2 CPU cores.
#   bash scripts/pretrain.sh            # everything
#   bash scripts/pretrain.sh data       # only the data stages
set -euo pipefail
cd "$(dirname "$0")/.."
export DYNAMICS_PARAMS=profiles/pretrain.yaml MUJOCO_GL=${MUJOCO_GL:-egl} HF_HUB_OFFLINE=1 TOKENIZERS_PARALLELISM=false
PY=${PY:-.venv/bin/python}
mkdir -p data/pretrain/logs
run() {  # run STAGE OUTPUT_DIR: skip when OUTPUT_DIR/meta.json exists (stages write it last)
  if [ -f "data/pretrain/$2/meta.json" ]; then echo "skip $1 (data/pretrain/$2 complete)"; return; fi
  echo "$(date +%T) $1"; nice -n 5 $PY stages/$1.py > "data/pretrain/logs/$1.log" 2>&1
}
run sample_configs configs
run compile_mjcf mjcf
run render traces
run flow flow
run events events
[ "${1:-all}" = data ] && exit 0
run tokenize_targets examples
echo "$(date +%T) finetune"
resume=""; [ -f data/pretrain/model/trainer_state.pt ] && resume="--resume"
nice -n 5 $PY stages/finetune.py $resume --no-progress 2>&1 | tee -a data/pretrain/logs/finetune.log
echo "$(date +%T) export"
$PY scripts/export_checkpoint.py data/pretrain/model pipeline/checkpoints/dynamics-tiny --params profiles/pretrain.yaml
