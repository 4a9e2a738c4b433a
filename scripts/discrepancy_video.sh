#!/usr/bin/env bash
# The discrepancy workflow on a real video (issue 10 item 5): `dynamics infer` on the shared
# bouncing-ball clip, then `dynamics discrepancy` on its output folder (scene.yaml + tracks.csv):
# where does the re-simulation leave the observed motion, and which effect closes the gap.
# Copies the report (Markdown, JSON, plots, rerun recording) to reports/discrepancy_video/.
# ~1 min on 2 cores: `bash scripts/discrepancy_video.sh` (after `make setup`).
set -euo pipefail
cd "$(dirname "$0")/.."
REAL=${REAL:-../shared/data/real/video}
OUT=${OUT:-outputs}
export MUJOCO_GL=${MUJOCO_GL:-egl} HF_HUB_OFFLINE=1
export PATH="$PWD/.venv/bin:$PATH"
CLIP=01_bouncing_green_ball
dynamics infer "$REAL/01_bouncing_green_ball_1080p30.avi" --out "$OUT/realvideo/$CLIP"
dynamics discrepancy "$OUT/realvideo/$CLIP" --out "$OUT/discrepancy_video/$CLIP"
mkdir -p reports/discrepancy_video
cp "$OUT/discrepancy_video/$CLIP"/{discrepancy.md,discrepancy.json,discrepancy_residuals.png,discrepancy_trajectories.png,discrepancy.rrd,effects.yaml} \
   reports/discrepancy_video/
cp "$OUT/realvideo/$CLIP/scene.yaml" reports/discrepancy_video/infer_scene.yaml
cp "$OUT/realvideo/$CLIP/tracks.csv" reports/discrepancy_video/tracks.csv
