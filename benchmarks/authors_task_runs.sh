#!/usr/bin/env bash
# Trains (or resumes) MATCH, Pose and Hybrid-Basic on the authors' task (train.py's default --task), cpu
# preset sizes, 3 seeds, STEPS env steps per seed, one method after the other, with the learning settings
# chosen by measurement (docs/training.md: Adam 1e-3, gamma 0.99, untrained force-z target 0 N). Each call
# continues a run from its latest checkpoint, so re-run it after an interruption until all are finished.
#   bash benchmarks/authors_task_runs.sh RUNS_DIR [STEPS] [METHODS]
#   nohup bash benchmarks/authors_task_runs.sh ~/runs/authors_task > ~/runs/authors_task.log 2>&1 &
set -euo pipefail
cd "$(dirname "$0")/.."
runs=${1:?usage: authors_task_runs.sh RUNS_DIR [STEPS] [METHODS]}
steps=${2:-2500000}
methods=${3:-match pose hybrid}
mkdir -p "$runs"
for method in $methods; do
  dir="$runs/$method"
  # A run resumes from its latest checkpoint; a directory without one (stopped before its first) starts again.
  if compgen -G "$dir/checkpoints/latest/*/commit_success.txt" > /dev/null; then
    python train.py --resume --total-steps "$steps" --out "$dir" --no-progress
  else
    python train.py --method "$method" --preset cpu --seeds 3 --total-steps "$steps" --learning-rate 1e-3 \
      --gamma 0.99 --initial-force-z 0 --out "$dir" --no-progress
  fi
  echo "[authors_task_runs] $method done at $(date -u +%FT%TZ)"
done
