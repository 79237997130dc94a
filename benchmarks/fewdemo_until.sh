#!/bin/bash
# Run one training of the few-demonstration benchmark to a set number of env steps, then evaluate it:
#   benchmarks/fewdemo_until.sh STEPS RUN_DIR -- digail train ... --out RUN_DIR
# The training is stopped with SIGTERM (it writes its checkpoint; `digail train --resume RUN_DIR` continues it) once
# RUN_DIR/metrics.csv reaches STEPS env steps, and its last checkpoint is evaluated on 100 closed-loop episodes
# (RUN_DIR/eval.json). The SAC runs of benchmarks/results/few-demos/fewdemo.json marked "stopped with SIGTERM at N" ran so.
set -u
N=$1; RUN=$2; shift 3
"$@" &
PID=$!
while kill -0 $PID 2>/dev/null; do
  sleep 20
  last=$(tail -1 "$RUN/metrics.csv" 2>/dev/null | cut -d, -f1)
  if [ -n "$last" ] && python3 -c "import sys; sys.exit(0 if float('$last') >= $N else 1)" 2>/dev/null; then
    kill -TERM $PID
    break
  fi
done
wait $PID
digail evaluate "$RUN" --episodes 100
