#!/usr/bin/env bash
# Rebuild the shipped checkpoint pipeline/checkpoints/dynamics-tiny from scratch (issue 8): the `pretrain`
# profile (profiles/pretrain.yaml: 20,000 training scenes) through the same stage scripts as
# `dvc repro`, then export. Resumable: a stage whose output is complete is skipped, training
# continues from data/pretrain/model. Logs: data/pretrain/logs/. Hours on 2 CPU cores.
#   bash scripts/pretrain.sh            # everything
#   bash scripts/pretrain.sh data       # only the data stages
# The checkpoint for real clips (issue 30), warm-started from dynamics-tiny:
#   PROFILE=profiles/pretrain_wide.yaml DATA=data/pretrain_wide DEST=pipeline/checkpoints/dynamics-wide \
#     CARD=model_card_wide.md bash scripts/pretrain.sh
set -euo pipefail
cd "$(dirname "$0")/.."
PROFILE=${PROFILE:-profiles/pretrain.yaml} DATA=${DATA:-data/pretrain} DEST=${DEST:-pipeline/checkpoints/dynamics-tiny}
CARD=${CARD:-model_card.md}
export DYNAMICS_PARAMS=$PROFILE MUJOCO_GL=${MUJOCO_GL:-egl} HF_HUB_OFFLINE=1 TOKENIZERS_PARALLELISM=false
PY=${PY:-.venv/bin/python}
mkdir -p $DATA/logs
run() {  # run STAGE OUTPUT_DIR: skip when OUTPUT_DIR/meta.json exists (stages write it last)
  if [ -f "$DATA/$2/meta.json" ]; then echo "skip $1 ($DATA/$2 complete)"; return; fi
  echo "$(date +%T) $1"; nice -n 5 $PY stages/$1.py > "$DATA/logs/$1.log" 2>&1
}
run sample_configs configs
run compile_mjcf mjcf
run render traces
run flow flow
run events events
[ "${1:-all}" = data ] && exit 0
run tokenize_targets examples
echo "$(date +%T) finetune"
resume=""; [ -f $DATA/model/trainer_state.pt ] && resume="--resume"
nice -n 5 $PY stages/finetune.py $resume --no-progress 2>&1 | tee -a $DATA/logs/finetune.log
echo "$(date +%T) export"
$PY scripts/export_checkpoint.py $DATA/model $DEST --params $PROFILE --card $CARD
