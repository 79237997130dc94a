#!/bin/bash
# Few-demonstration landmark route (digail/LandmarkRoute-v0): one job of the benchmark, resumable. From the
# repository root:
#   benchmarks/route_fewdemo.sh DEMOS METHOD SEED [ITERATIONS]
# DEMOS: the first N demonstrations of digail/landmarkroute/expert-v0; METHOD one of
#   bc       the VAE's policy (K = 4, the landmark-route preset), closed-loop q   -> runs/routefew/dN/bc_k4_sS
#   flatbc   the same pre-training with one code: a flat behaviour-cloned policy -> runs/routefew/dN/bc_k1_sS
#   digail   Directed-Info GAIL from bc's VAE (q frozen, pi from its decoder)
#   flatbc-gail  GAIL from flatbc's policy (one code, so no bonus; same network, data, learner and steps)
#   gail     GAIL from a fresh policy
#   digail-l2, flatbc-gail-l2, gail-l2   the same with the BC / L2 term (weight 1.0)
#   digail-l2-gp, flatbc-gail-l2-gp      the L2 ones with a gradient penalty of weight 10 on D
#   digail-l2-rel, flatbc-gail-l2-rel, gail-l2-rel   the L2 ones with D on the relative view (--train.disc-obs
#            relative: each landmark seen from the point, and the touch sensors)
# A job whose eval.json exists is done; a training with a config.json is resumed from its last checkpoint.
# Every training: PPO (the preset's: 8 envs, batch 512), ITERATIONS (default 2000, i.e. 1,024,000 env steps), a
# 20-episode evaluation every 100 iterations (the learning curve), then 100 episodes.
set -euo pipefail
N=$1; METHOD=$2; S=$3; ITERS=${4:-2000}
D=digail/landmarkroute/expert-v0
ROOT=runs/routefew/d$N
mkdir -p "$ROOT"
export MUJOCO_GL=${MUJOCO_GL:-egl}

vae() {  # vae K -> the VAE run folder, pre-trained (and evaluated) once
  local k=$1 run="$ROOT/bc_k$1_s$S"
  if [ ! -f "$run/eval.json" ]; then
    [ -f "$run/model.pt" ] || digail pretrain --demos $D --demos-episodes "$N" --codes "$k" --seed "$S" \
        --out "$run" --force >/dev/null
    digail evaluate "$run" --episodes 100 >/dev/null
  fi
  echo "$run"
}

train() {  # train NAME ARGS... -> trains RUN = ROOT/NAME_sS (or resumes it), then evaluates it on 100 episodes
  local name=$1 run="$ROOT/$1_s$S" bc=0 gp=0; shift
  case $name in *-l2|*-l2-gp|*-l2-rel) bc=1.0 ;; esac
  case $name in *-gp) gp=10 ;; esac
  [ -f "$run/eval.json" ] && return 0
  if [ -f "$run/config.json" ]; then
    digail train --resume "$run"
  else
    digail train --demos $D --demos-episodes "$N" --train.bc-weight "$bc" --train.disc-grad-penalty "$gp" --seed "$S" \
        --train.iterations "$ITERS" --train.eval-every 100 --train.eval-episodes 20 --train.checkpoint-every 100 --out "$run" "$@"
  fi
  digail evaluate "$run" --episodes 100
}

case $METHOD in
  bc) vae 4 ;;
  flatbc) vae 1 ;;
  digail|digail-l2|digail-l2-gp) train "$METHOD" --vae "$(vae 4)" ;;
  flatbc-gail|flatbc-gail-l2|flatbc-gail-l2-gp) train "$METHOD" --vae "$(vae 1)" ;;
  gail|gail-l2) train "$METHOD" --method gail ;;
  digail-l2-rel) train "$METHOD" --vae "$(vae 4)" --train.disc-obs relative ;;
  flatbc-gail-l2-rel) train "$METHOD" --vae "$(vae 1)" --train.disc-obs relative ;;
  gail-l2-rel) train "$METHOD" --method gail --train.disc-obs relative ;;
  *) echo "unknown method $METHOD" >&2; exit 2 ;;
esac
