#!/bin/bash
# Few-demonstration FetchPickAndPlace: one job of the benchmark, resumable. Run from the repository root:
#   benchmarks/fetch_fewdemo.sh DEMOS METHOD SEED [ITERATIONS]
# DEMOS: how many expert demonstrations (the first N of digail/fetchpickandplace/expert-v0); METHOD one of
#   bc       the VAE's policy (K = 4, the fetch preset), closed-loop q           -> runs/fetchfew/dN/bc_k4_sS
#   flatbc   the same pre-training with one code: a flat behaviour-cloned policy -> runs/fetchfew/dN/bc_k1_sS
#   bc2, bc8 the same with K = 2 or 8 codes                                      -> runs/fetchfew/dN/bc_k2_sS, ...
#   digail-l2  Directed-Info GAIL + L2 from bc's VAE (q frozen, pi from its decoder)
#   flatbc-l2  GAIL + L2 from flatbc's policy (one code, so no bonus; same network, data, learner and steps)
#   gail-l2    GAIL + L2 from a fresh policy
#   each of the three with suffixes, in this order:
#     -rel        D on Fetch's relative view (--train.disc-obs relative: no horizontal positions)
#     -dist       D on Fetch's distances view (how far things are, not in which direction: distances_view)
#     -gp-logit   D's gradient penalty 10 and the logit reward log D - log(1 - D)
#     -argmax     (digail-l2 only) every training env takes q's argmax code on its own states, as evaluation
#                 does (--train.replay-fraction 0 --train.closed-loop-codes argmax), instead of replaying the
#                 demonstrations' codes in half the envs and sampling q in the other half
#     -pu, -noise, -noise5, -sn, -ot, -ots, -otst   the imitation reward (--train.imitation.*): D trained as a
#                 positive-unlabeled classifier (prior 0.5), D's inputs noised (sigma 0.15, or 0.5 for -noise5), D
#                 spectrally normalised, optimal transport on D's view (no D), the same sub-task-aware (codes must
#                 match, else cost +1), and that in order (time weight 1)
#     -ote, -otse the transport of -ot / -ots with the Euclidean cost on Fetch's placing view (positions, heights
#                 and fingers; no velocities) in place of the cosine on the relative view
#     -otd, -otsd the same on Fetch's distances view (how far things are, not in which direction)
#     -otl        the same on the distances view with the distances on a log scale (log_distances_view)
#     -relabel    D's expert inputs also hold 4 copies of every demonstration step with the goal replaced by where
#                 the block is later in that demonstration (--train.imitation.relabel-goals 4, goalGAIL's)
#     -sonly      D judges states alone, not actions (--train.imitation.no-disc-actions)
#     -anneal, -qf  the BC weight annealed linearly to 0 over the run, or (SAC) Q-filtered
#     -shuffle, -qtrain, -nobonus, -k2, -k8   (digail-l2 only) the ablations: codes drawn uniformly each step, q
#                 trained with the policy (lr 3e-4), the bonus off, K = 2 or 8 codes (their own VAE, bc_k2 / bc_k8)
#     -1m         the same run trained on to 244 iterations (999,424 env steps, within the benchmark's 1M): the
#                 100-iteration run is trained first (or found done), copied to METHOD-1m_sS and continued there
#                 with `digail train --resume --until 244`, the same numbers as a run started with 244
#     -sac        the off-policy learner (SAC: 1000 env steps an iteration, its discriminator with a gradient
#                 penalty, as DAC); ITERATIONS default 400 (400k env steps), a 20-episode evaluation every 20
#     -sacfast    the same on the cheaper schedule of benchmarks/studies/sac_fetch_speed.py: one update every 4 env steps
#                 (--train.sac.utd 0.25), D every 4 on a minibatch of 1024
#   e.g. digail-l2-rel-nobonus, flatbc-l2-rel, gail-l2-sac, digail-l2-rel-argmax-1m
# FETCH_OBS=relative: the same on digail/FetchPickAndPlaceRelative-v4 (observed in the relative view, its own copy of
#   the demonstrations: digail/fetchpickandplacerelative/expert-v0), run folders under runs/fetchfew-rel/dN; D sees
#   all of that observation, so methods there take no -rel.
# A job whose eval.json exists is done; a training with a config.json is resumed from its last checkpoint, and one
# made with fewer than ITERATIONS is continued to ITERATIONS (`digail train --resume RUN --until ITERATIONS`).
# Every training: PPO (the fetch preset: batch 4096 over 8 envs), BC / L2 weight 1.0, ITERATIONS (default 100, i.e.
# 409,600 env steps), a 20-episode evaluation every 5 iterations (the learning curve), then 100 episodes.
set -euo pipefail
N=$1; METHOD=$2; S=$3
case $METHOD in *-sac|*-sacfast) ITERS=${4:-400}; EVERY=20 ;; *) ITERS=${4:-100}; EVERY=5 ;; esac
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

SHAPE='^(digail|flatbc|gail)-l2(-rel|-dist)?(-gp-logit)?(-argmax)?(-sonly)?'
SHAPE+='(-pu|-noise|-noise5|-sn|-ot|-ots|-otst|-ote|-otse|-otd|-otsd|-otl)?(-relabel)?(-anneal|-qf)?'
SHAPE+='(-shuffle|-qtrain|-nobonus|-k2|-k8)?(-sac|-sacfast|-1m)?$'
if ! [[ $METHOD =~ ^(bc|flatbc|bc2|bc8)$ || $METHOD =~ $SHAPE ]] \
    || [[ $METHOD =~ ^(flatbc|gail)-.*-(argmax|shuffle|qtrain|nobonus|k2|k8) ]]; then
  echo "unknown method $METHOD" >&2; exit 2
fi
if [[ $METHOD == *-1m ]]; then  # the 100-iteration run first, then a copy of it continued to 244
  BASE=${METHOD%-1m}; LONG="$ROOT/${METHOD}_s$S"
  bash "$0" "$N" "$BASE" "$S"
  [ -f "$LONG/eval.json" ] && exit 0
  [ -d "$LONG" ] || { cp -a "$ROOT/${BASE}_s$S" "$LONG.tmp" && mv "$LONG.tmp" "$LONG"; }
  digail train --resume "$LONG" --until 244
  digail evaluate "$LONG" --episodes 100
  exit 0
fi
ARGS=(); K=4
case $METHOD in
  *-ote*|*-otse*) ARGS+=(--train.disc-obs digail.envs.fetch:placing_view --train.imitation.ot-cost euclidean) ;;
  *-otd*|*-otsd*) ARGS+=(--train.disc-obs digail.envs.fetch:distances_view --train.imitation.ot-cost euclidean) ;;
  *-otl*) ARGS+=(--train.disc-obs digail.envs.fetch:log_distances_view --train.imitation.ot-cost euclidean) ;;
  *-rel*) ARGS+=(--train.disc-obs relative) ;;
  *-dist*) ARGS+=(--train.disc-obs digail.envs.fetch:distances_view) ;;
esac
case $METHOD in *-gp-logit*) ARGS+=(--train.disc-grad-penalty 10 --train.reward logit) ;; esac
case $METHOD in *-argmax*) ARGS+=(--train.replay-fraction 0 --train.closed-loop-codes argmax) ;; esac
case $METHOD in *-pu*) ARGS+=(--train.imitation.kind pu) ;; esac
case $METHOD in *-sonly*) ARGS+=(--train.imitation.no-disc-actions) ;; esac
case $METHOD in *-noise5*) ARGS+=(--train.imitation.disc-noise 0.5) ;; *-noise*) ARGS+=(--train.imitation.disc-noise 0.15) ;; esac
case $METHOD in *-relabel*) ARGS+=(--train.imitation.relabel-goals 4) ;; esac
case $METHOD in *-sn*) ARGS+=(--train.imitation.spectral-norm) ;; esac
case $METHOD in *-ot-*|*-ot|*-ote-*|*-ote|*-otd-*|*-otd|*-otl-*|*-otl) ARGS+=(--train.imitation.kind ot) ;; esac
case $METHOD in *-ots*) ARGS+=(--train.imitation.kind ot-subtask) ;; esac
case $METHOD in *-otst*) ARGS+=(--train.imitation.ot-time-weight 1.0) ;; esac
case $METHOD in *-anneal*) ARGS+=(--train.imitation.bc-schedule anneal) ;; esac
case $METHOD in *-qf*) ARGS+=(--train.imitation.bc-schedule qfilter) ;; esac
case $METHOD in *-shuffle*) ARGS+=(--train.shuffle-codes) ;; esac
case $METHOD in *-qtrain*) ARGS+=(--train.q-lr 3e-4) ;; esac
case $METHOD in *-nobonus*) ARGS+=(--train.bonus-weight 0) ;; esac
case $METHOD in *-k2*) K=2 ;; *-k8*) K=8 ;; esac
case $METHOD in *-sac) ARGS+=(--train.learner sac) ;; esac
case $METHOD in *-sacfast) ARGS+=(--train.learner sac --train.sac.utd 0.25 --train.sac.disc-every 4
                                  --train.disc-minibatch-size 1024) ;; esac
case $METHOD in
  bc) vae 4 ;;
  flatbc) vae 1 ;;
  bc2) vae 2 ;;
  bc8) vae 8 ;;
  digail-l2*) train "$METHOD" --vae "$(vae $K)" "${ARGS[@]}" ;;
  flatbc-l2*) train "$METHOD" --vae "$(vae 1)" "${ARGS[@]}" ;;
  gail-l2*) train "$METHOD" --method gail "${ARGS[@]}" ;;
esac
