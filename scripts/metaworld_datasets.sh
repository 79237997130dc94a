#!/usr/bin/env bash
# Records the shipped Meta-World demonstrations (50 episodes of each multi-stage task's scripted expert, random
# placements, episode i reset with seed i) and refreshes the shipped MANIFEST.json. Run from the repository root:
#   MUJOCO_GL=egl bash scripts/metaworld_datasets.sh
set -euo pipefail
DIGAIL=${DIGAIL:-digail}
PYTHON=${PYTHON:-python}
TASKS=${TASKS:-"pick-place assembly stick-pull shelf-place basketball disassemble peg-insert-side box-close hammer push-wall plate-slide-back stick-push door-lock hand-insert pick-out-of-hole coffee-pull"}
for task in $TASKS; do
    $DIGAIL demos "metaworld/$task-v3" --episodes 50 --seed 0 --force \
        --out "src/digail/datasets/digail/metaworld-$task/expert-v0"
done
$PYTHON -m digail.data.demos
