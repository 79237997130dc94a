#!/bin/bash
# Few-demonstration landmark route (digail/LandmarkRoute-v0): one job of the benchmark, resumable. From the
# repository root:
#   benchmarks/route_fewdemo.sh DEMOS METHOD SEED [ITERATIONS]
# DEMOS: the first N demonstrations of digail/landmarkroute/expert-v0; METHOD names a variant, the file
# benchmarks/variants/route/METHOD.variant (`ls benchmarks/variants/route` lists them), whose lines are `digail train`
# flags and the directives `pretrain K` (the job is the VAE with K codes itself -> runs/routefew/dN/bc_kK_sS; bc:
# K = 4, flatbc: K = 1, a flat behaviour-cloned policy) and `vae K` (the training starts from that VAE, pre-trained
# first: q frozen, pi from its decoder; without it a fresh policy, --method gail). The -l2 variants add the BC / L2
# term (weight 1.0), the -gp ones a gradient penalty of weight 10 on D, the -rel ones D on the relative view.
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
  local run="$ROOT/$1_s$S"; shift
  [ -f "$run/eval.json" ] && return 0
  if [ -f "$run/config.json" ]; then
    digail train --resume "$run"
  else
    digail train --demos $D --demos-episodes "$N" --seed "$S" --train.iterations "$ITERS" --train.eval-every 100 \
        --train.eval-episodes 20 --train.checkpoint-every 100 --out "$run" "$@"
  fi
  digail evaluate "$run" --episodes 100
}

VARIANT=benchmarks/variants/route/$METHOD.variant
if [ ! -f "$VARIANT" ]; then
  echo "unknown method $METHOD: there is no $VARIANT (ls benchmarks/variants/route)" >&2; exit 2
fi
ARGS=(); PRETRAIN=; START=
while read -r word rest; do
  case $word in
    ''|'#'*) ;;
    pretrain) PRETRAIN=$rest ;;
    vae) START=$rest ;;
    --*) read -ra words <<< "$word $rest"; ARGS+=("${words[@]}") ;;
    *) echo "$VARIANT: unknown line '$word $rest'" >&2; exit 2 ;;
  esac
done < "$VARIANT"
if [ -n "$PRETRAIN" ]; then
  vae "$PRETRAIN"
elif [ -n "$START" ]; then
  train "$METHOD" --vae "$(vae "$START")" "${ARGS[@]}"
else
  train "$METHOD" "${ARGS[@]}"
fi
