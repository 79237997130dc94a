#!/bin/bash
# Few-demonstration FetchPickAndPlace: one job of the benchmark, resumable. Run from the repository root:
#   benchmarks/fetch_fewdemo.sh DEMOS METHOD SEED [ITERATIONS]
# DEMOS: how many expert demonstrations (the first N of digail/fetchpickandplace/expert-v0); METHOD names a variant,
# the file benchmarks/variants/fetch/METHOD.variant (`ls benchmarks/variants/fetch` lists them), whose lines are
# `digail train` flags and these directives (`#` starts a comment line):
#   pretrain K      the job is the fetch preset's VAE with K codes itself -> runs/fetchfew/dN/bc_kK_sS (bc: K = 4,
#                   flatbc: K = 1, a flat behaviour-cloned policy)
#   vae K           the training starts from that VAE (pre-trained first, once): q frozen, pi from its decoder
#                   (without it, a fresh policy: the gail-l2 variants pass --method gail)
#   budget I E      ITERATIONS defaults to I instead of 100, with a 20-episode evaluation every E iterations
#   continue BASE U the variant BASE trained first (or found done), copied to METHOD_sS and continued there with
#                   `digail train --resume --until U`: the same numbers as a run started with U iterations
# e.g. digail-l2-rel-nobonus, flatbc-l2-rel, gail-l2-sac, digail-l2-rel-argmax-1m
# FETCH_OBS=relative: the same on digail/FetchPickAndPlaceRelative-v4 (observed in the relative view, its own copy of
#   the demonstrations: digail/fetchpickandplacerelative/expert-v0), run folders under runs/fetchfew-rel/dN; D sees
#   all of that observation, so methods there take no -rel.
# A job whose eval.json exists is done; a training with a config.json is resumed from its last checkpoint, and one
# made with fewer than ITERATIONS is continued to ITERATIONS (`digail train --resume RUN --until ITERATIONS`).
# Every training: PPO (the fetch preset: batch 4096 over 8 envs), BC / L2 weight 1.0, ITERATIONS (default 100, i.e.
# 409,600 env steps), a 20-episode evaluation every 5 iterations (the learning curve), then 100 episodes.
set -euo pipefail
N=$1; METHOD=$2; S=$3
ITERS=${4:-100}; EVERY=5  # a variant's `budget` line changes both
case ${FETCH_OBS:-flat} in
  flat) D=digail/fetchpickandplace/expert-v0; ROOT=runs/fetchfew/d$N ;;
  relative) D=digail/fetchpickandplacerelative/expert-v0; ROOT=runs/fetchfew-rel/d$N ;;
  *) echo "FETCH_OBS must be flat or relative" >&2; exit 2 ;;
esac
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
  local run="$ROOT/$1_s$S" have; shift
  if [ -f "$run/config.json" ]; then
    have=$(python3 -c 'import json, sys; print(json.load(open(sys.argv[1]))["train"]["iterations"])' "$run/config.json")
    if [ "$have" -lt "$ITERS" ]; then  # a shorter run (done or not) is continued to ITERS
      digail train --resume "$run" --until "$ITERS"
    elif [ -f "$run/eval.json" ]; then
      return 0
    else
      digail train --resume "$run"
    fi
  else
    digail train --demos $D --demos-episodes "$N" --train.bc-weight 1.0 --seed "$S" --train.iterations "$ITERS" \
        --train.eval-every "$EVERY" --train.eval-episodes 20 --train.checkpoint-every 5 --out "$run" "$@"
  fi
  digail evaluate "$run" --episodes 100
}

VARIANT=benchmarks/variants/fetch/$METHOD.variant
if [ ! -f "$VARIANT" ]; then
  echo "unknown method $METHOD: there is no $VARIANT (ls benchmarks/variants/fetch)" >&2; exit 2
fi
ARGS=(); PRETRAIN=; START=; BASE=; UNTIL=
while read -r word rest; do
  case $word in
    ''|'#'*) ;;
    pretrain) PRETRAIN=$rest ;;
    vae) START=$rest ;;
    budget) read -r DEFAULT_ITERS EVERY <<< "$rest"; ITERS=${4:-$DEFAULT_ITERS} ;;
    continue) read -r BASE UNTIL <<< "$rest" ;;
    --*) read -ra words <<< "$word $rest"; ARGS+=("${words[@]}") ;;
    *) echo "$VARIANT: unknown line '$word $rest'" >&2; exit 2 ;;
  esac
done < "$VARIANT"
if [ -n "$BASE" ]; then  # the base run first, then a copy of it continued to UNTIL iterations
  LONG="$ROOT/${METHOD}_s$S"
  bash "$0" "$N" "$BASE" "$S"
  [ -f "$LONG/eval.json" ] && exit 0
  [ -d "$LONG" ] || { cp -a "$ROOT/${BASE}_s$S" "$LONG.tmp" && mv "$LONG.tmp" "$LONG"; }
  digail train --resume "$LONG" --until "$UNTIL"
  digail evaluate "$LONG" --episodes 100
elif [ -n "$PRETRAIN" ]; then
  vae "$PRETRAIN"
elif [ -n "$START" ]; then
  train "$METHOD" --vae "$(vae "$START")" "${ARGS[@]}"
else
  train "$METHOD" "${ARGS[@]}"
fi
