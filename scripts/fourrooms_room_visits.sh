#!/usr/bin/env bash
# Four Rooms with the room-visit start (docs/experiments.md, "Four Rooms"): the preset's VAE and
# Directed-Info GAIL, but the VAE starts from one code per room visit (`--vae.init-pieces env`) found by linear
# sub-task policies on the agent's position (`--vae.init-obs 0 26 --vae.init-ridge 0.01`), no ELBO epochs.
#   bash scripts/fourrooms_room_visits.sh SEED [ITERATIONS]   (ITERATIONS of Directed-Info GAIL, default 1000)
#   bash scripts/fourrooms_room_visits.sh collect             -> benchmarks/studies/results/fourrooms_room_visits.json
#   CODES=5 (default 4) runs K = 5 into runs/fourrooms_room_visits/k5 (collected as k5/...)
# Runs under runs/fourrooms_room_visits: vae_sSEED (its segmentation.json; evaluated too) and digail_iITERATIONS_sSEED
# (eval.json over 300 episodes, segmentation.json of the macro-policy q it keeps). Steps already done are skipped.
set -euo pipefail
out=runs/fourrooms_room_visits
codes=${CODES:-4}
bin=${BIN:-.venv/bin}
export MUJOCO_GL=${MUJOCO_GL:-egl} OMP_NUM_THREADS=1
if [ "$1" = collect ]; then
  exec "$bin/python" - "$out" <<'PY'
import json, sys
from pathlib import Path
out = Path(sys.argv[1])
keys = ("accuracy", "nmi", "boundary_f1", "switches_per_episode", "true_switches_per_episode")
rows = {}
for run in sorted(p for p in [*out.iterdir(), *out.glob("k*/*")] if (p / "eval.json").is_file()):
    ev, seg = json.loads((run / "eval.json").read_text()), json.loads((run / "segmentation.json").read_text())
    rows[str(run.relative_to(out))] = {**{k: ev[k] for k in ("success_rate", "path_length_ratio", "normalized_return")},
                      **{k: seg[k] for k in keys}}
result = {"command": "bash scripts/fourrooms_room_visits.sh SEED [ITERATIONS] for SEED in 0 1 2, ITERATIONS "
                     "1000 and 2000, and CODES=5 bash scripts/fourrooms_room_visits.sh SEED 2000; then bash "
                     "scripts/fourrooms_room_visits.sh collect", "runs": rows}
path = Path("benchmarks/studies/results/fourrooms_room_visits.json")
path.write_text(json.dumps(result, indent=1) + "\n")
print(f"wrote {path}")
PY
fi
seed=$1
iterations=${2:-1000}
[ "$codes" = 4 ] || out=$out/k$codes
vae=$out/vae_s$seed
run=$out/digail_i${iterations}_s$seed
mkdir -p "$out"
if [ ! -f "$vae/segmentation.json" ]; then
  "$bin/digail" pretrain --demos digail/fourrooms/expert-v0 --seed "$seed" --out "$vae" --force --codes "$codes" \
      --vae.init em --vae.epochs 0 --vae.init-pieces env --vae.init-obs 0 26 --vae.init-ridge 0.01
fi
[ -f "$vae/eval.json" ] || "$bin/digail" evaluate "$vae" --episodes 300
if [ -f "$run/checkpoint.pt" ] && [ ! -f "$run/model.pt" ]; then
  "$bin/digail" train --resume "$run"
elif [ ! -f "$run/model.pt" ]; then
  "$bin/digail" train --demos digail/fourrooms/expert-v0 --method digail --vae "$vae" --seed "$seed" \
      --out "$run" --train.iterations "$iterations"
fi
[ -f "$run/eval.json" ] || "$bin/digail" evaluate "$run" --episodes 300
[ -f "$run/segmentation.json" ] || "$bin/digail" segment "$run"
