#!/bin/bash
# Few-demonstration FetchPickAndPlace: one job of the benchmark, resumable. Run from the repository root:
#   benchmarks/fetch_fewdemo.sh DEMOS METHOD SEED [ITERATIONS]
# DEMOS: how many expert demonstrations (the first N of digail/fetchpickandplace/expert-v0); METHOD one of
#   bc       the VAE's policy (K = 4, the fetch preset), closed-loop q           -> runs/fetchfew/dN/bc_k4_sS
#   flatbc   the same pre-training with one code: a flat behaviour-cloned policy -> runs/fetchfew/dN/bc_k1_sS
#   digail-l2  Directed-Info GAIL + L2 from bc's VAE (q frozen, pi from its decoder)
#   flatbc-l2  GAIL + L2 from flatbc's policy (one code, so no bonus; same network, data, learner and steps)
#   gail-l2    GAIL + L2 from a fresh policy
#   digail-l2-shuffle  the ablations of digail-l2: codes drawn uniformly each step (--train.shuffle-codes),
#   digail-l2-qtrain   q trained with the policy (--train.q-lr 3e-4), digail-l2-nobonus  the bonus off
#   digail-l2-k2, digail-l2-k8  K = 2 or 8 codes (their own VAE, bc_k2 / bc_k8); one code is flatbc-l2
#   digail-l2-rel, flatbc-l2-rel, gail-l2-rel  digail-l2, flatbc-l2 and gail-l2 with D on Fetch's relative view
#              (--train.disc-obs relative: no horizontal positions of gripper, object or goal)
#   digail-l2-rel-gp-logit, flatbc-l2-rel-gp-logit  the same two on the relative view, with D's gradient penalty 10
#              and the logit reward log D - log(1 - D) (which keeps grading where D is sure)
#   digail-l2-sac, flatbc-l2-sac, gail-l2-sac   the same three with the off-policy learner (SAC: 1000 env steps an
#              iteration, its discriminator with a gradient penalty, as DAC); ITERATIONS default 400 (400k env steps),
#              a 20-episode evaluation every 20 iterations
# A job whose eval.json exists is done; a training with a config.json is resumed from its last checkpoint.
# Every training: PPO (the fetch preset: batch 4096 over 8 envs), BC / L2 weight 1.0, ITERATIONS (default 100, i.e.
# 409,600 env steps), a 20-episode evaluation every 5 iterations (the learning curve), then 100 episodes.
set -euo pipefail
N=$1; METHOD=$2; S=$3
case $METHOD in *-sac) ITERS=${4:-400}; EVERY=20 ;; *) ITERS=${4:-100}; EVERY=5 ;; esac
D=digail/fetchpickandplace/expert-v0
ROOT=runs/fetchfew/d$N
mkdir -p "$ROOT"
export MUJOCO_GL=${MUJOCO_GL:-egl}

vae() {  # vae K -> the VAE run folder, pre-trained (and evaluated) once
  local k=$1 run="$ROOT/bc_k$1_s$S"
  if [ ! -f "$run/eval.json" ]; then
    [ -f "$run/model.pt" ] || digail pretrain --demos $D --demos-episodes "$N" --preset fetch --codes "$k" \
        --seed "$S" --out "$run" --force >/dev/null
    digail evaluate "$run" --episodes 100 >/dev/null
  fi
  echo "$run"
}

train() {  # train NAME ARGS... -> trains RUN = ROOT/NAME_sS (or resumes it), then evaluates it on 100 episodes
  local run="$ROOT/$1_s$S"; shift
  [ -f "$run/eval.json" ] && return 0
  if [ -f "$run/config.json" ]; then
    digail train --resume "$run"
  else
    digail train --demos $D --demos-episodes "$N" --bc-weight 1.0 --seed "$S" --train.iterations "$ITERS" \
        --train.eval-every "$EVERY" --train.eval-episodes 20 --train.checkpoint-every 5 --out "$run" "$@"
  fi
  digail evaluate "$run" --episodes 100
}

case $METHOD in
  bc) vae 4 ;;
  flatbc) vae 1 ;;
  digail-l2) train digail-l2 --vae "$(vae 4)" ;;
  flatbc-l2) train flatbc-l2 --vae "$(vae 1)" ;;
  gail-l2) train gail-l2 --method gail ;;
  digail-l2-rel) train digail-l2-rel --vae "$(vae 4)" --train.disc-obs relative ;;
  flatbc-l2-rel) train flatbc-l2-rel --vae "$(vae 1)" --train.disc-obs relative ;;
  gail-l2-rel) train gail-l2-rel --method gail --train.disc-obs relative ;;
  digail-l2-rel-gp-logit) train digail-l2-rel-gp-logit --vae "$(vae 4)" --train.disc-obs relative \
      --train.disc-grad-penalty 10 --train.reward logit ;;
  flatbc-l2-rel-gp-logit) train flatbc-l2-rel-gp-logit --vae "$(vae 1)" --train.disc-obs relative \
      --train.disc-grad-penalty 10 --train.reward logit ;;
  digail-l2-shuffle) train digail-l2-shuffle --vae "$(vae 4)" --train.shuffle-codes ;;
  digail-l2-qtrain) train digail-l2-qtrain --vae "$(vae 4)" --train.q-lr 3e-4 ;;
  digail-l2-nobonus) train digail-l2-nobonus --vae "$(vae 4)" --train.bonus-weight 0 ;;
  digail-l2-k2) train digail-l2-k2 --vae "$(vae 2)" ;;
  digail-l2-k8) train digail-l2-k8 --vae "$(vae 8)" ;;
  digail-l2-sac) train digail-l2-sac --vae "$(vae 4)" --train.learner sac ;;
  flatbc-l2-sac) train flatbc-l2-sac --vae "$(vae 1)" --train.learner sac ;;
  gail-l2-sac) train gail-l2-sac --method gail --train.learner sac ;;
  *) echo "unknown method $METHOD" >&2; exit 2 ;;
esac
