#!/usr/bin/env bash
# Four Rooms with the room-visit start (issue 14, item 5; docs/experiments.md, "Four Rooms"): the preset's VAE and
# Directed-Info GAIL, but the VAE starts from one code per room visit (`--vae.init-pieces env`) found by linear
# sub-task policies on the agent's position (`--vae.init-obs 0 26 --vae.init-ridge 0.01`), no ELBO epochs.
#   bash scripts/fourrooms_room_visits.sh SEED [OUT]     (OUT defaults to runs/fourrooms_room_visits)
# writes OUT/vae_sSEED (segmentation.json), OUT/digail_sSEED (eval.json after 300 episodes) and, for the
# codes, OUT/digail_sSEED/segmentation.json.
set -euo pipefail
seed=$1
out=${2:-runs/fourrooms_room_visits}
digail=${DIGAIL:-.venv/bin/digail}
export MUJOCO_GL=${MUJOCO_GL:-egl} OMP_NUM_THREADS=1
mkdir -p "$out"
if [ ! -f "$out/vae_s$seed/segmentation.json" ]; then
  $digail pretrain --demos digail/fourrooms/expert-v0 --seed "$seed" --out "$out/vae_s$seed" --force --codes 4 \
      --vae.init em --vae.epochs 0 --vae.init-pieces env --vae.init-obs 0 26 --vae.init-ridge 0.01
fi
if [ -f "$out/digail_s$seed/model.pt" ] && [ ! -f "$out/digail_s$seed/eval.json" ]; then
  $digail train --resume "$out/digail_s$seed"
elif [ ! -f "$out/digail_s$seed/model.pt" ]; then
  $digail train --demos digail/fourrooms/expert-v0 --method digail --vae "$out/vae_s$seed" --seed "$seed" \
      --out "$out/digail_s$seed"
fi
$digail evaluate "$out/digail_s$seed" --episodes 300
$digail segment "$out/digail_s$seed"
