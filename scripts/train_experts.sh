#!/usr/bin/env bash
# Train the RL experts that ship in src/digail/experts/weights/, one after the other (one process at a time:
# each uses a single CPU thread). The commands are exactly these; the script only adds --resume when a folder
# already holds checkpoints, so rerunning it after an interruption continues where it stopped, and it skips an
# env whose folder already holds a final eval.json.
#
#   usage: scripts/train_experts.sh [ENV ...]      (default: all four, cheapest first)
#   log:   experts_work/<env>/train.log; result: experts_work/<env>/eval.json and best_expert.pt
#
# After a run finishes (eval.json written), its best_expert.pt is copied to src/digail/experts/weights/<env>.pt
# and its 50-episode evaluation recorded in src/digail/experts/weights/EXPERTS.json (digail.experts.rl.ship_expert).
# The shipped demonstrations are then made with (commands also in src/digail/datasets/MANIFEST.json):
#   digail demos Pendulum-v1 --episodes 25 --seed 0 --out src/digail/datasets/digail/pendulum/expert-v0
#   digail demos InvertedPendulum-v5 --episodes 25 --seed 0 --out src/digail/datasets/digail/invertedpendulum/expert-v0
#   digail demos Hopper-v5 --episodes 50 --seed 0 --out src/digail/datasets/digail/hopper/expert-v0
#   digail demos Walker2d-v5 --episodes 50 --seed 0 --out src/digail/datasets/digail/walker2d/expert-v0
#   digail demos digail/FetchPickAndPlace-v4 --episodes 500 --seed 0 \
#       --out src/digail/datasets/digail/fetchpickandplace/expert-v0
#   python -m digail.data.demos        # rewrites MANIFEST.json (merges EXPERTS.json's evaluations)
set -euo pipefail
cd "$(dirname "$0")/.."
DIGAIL=${DIGAIL:-.venv/bin/digail}
export PYTHONWARNINGS=ignore MUJOCO_GL=${MUJOCO_GL:-egl} OMP_NUM_THREADS=1  # torch threads fight under load

envs=("$@")
[ ${#envs[@]} -eq 0 ] && envs=(Pendulum-v1 InvertedPendulum-v5 Hopper-v5 Walker2d-v5)

for env in "${envs[@]}"; do
    out="experts_work/${env}" seed=0
    # Pendulum's SAC expert is the better of seeds 0 and 1 by periodic evaluation (docs/experiments.md#rl-experts)
    [ "${env}" = Pendulum-v1 ] && out="experts_work/Pendulum-v1-sac-seed1" seed=1
    if [ -f "${out}/eval.json" ]; then
        echo "skip ${env}: ${out}/eval.json exists"
        continue
    fi
    resume=()
    compgen -G "${out}/checkpoints/step_*.pt" >/dev/null && resume=(--resume)
    mkdir -p "${out}"
    echo "$(date -u +%FT%TZ) start ${env} ${resume[*]:-}" | tee -a "${out}/train.log"
    # The exact training command (the env's default budget from digail.experts.recipes.EXPERT_SPECS):
    "${DIGAIL}" expert "${env}" --out "${out}" --seed "${seed}" "${resume[@]}" >>"${out}/train.log" 2>&1
    echo "$(date -u +%FT%TZ) done ${env}" | tee -a "${out}/train.log"
    "$(dirname "${DIGAIL}")/python" -c "import sys; from digail.experts.rl import ship_expert; \
print('shipped', ship_expert(sys.argv[1], sys.argv[2]))" "${env}" "${out}" | tee -a "${out}/train.log"
done
