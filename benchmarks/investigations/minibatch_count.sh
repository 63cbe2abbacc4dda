#!/usr/bin/env bash
# The authors' minibatch count against ours on the authors' task: MATCH, cpu preset, 3 seeds, 1M env steps
# per seed, 150 minibatches x 4 epochs (128 samples each: one policy step of every env) against the
# preset's 8 x 4 (2,400 samples each). The 8 x 4 run is the first 1M env steps of authors_task_runs.sh's
# MATCH run. Resumable: re-run the same command after an interruption. Each run must have had the cores
# to itself for its env steps/s to compare.
# Then, in one process on the idle cores, whole PPO iterations of both settings (3 seeds), compiled apart:
# the wall-clock ratio within one run (OUT_JSON with _throughput before .json).
#   bash benchmarks/investigations/minibatch_count.sh RUNS_DIR [OUT_JSON]
#   (RUNS_DIR/match: authors_task_runs.sh's MATCH run; RUNS_DIR/match_mb150 is trained here)
set -euo pipefail
cd "$(dirname "$0")/../.."
runs=${1:?usage: minibatch_count.sh RUNS_DIR [OUT_JSON]}
out=${2:-results/authors_task/minibatch_count.json}
dir="$runs/match_mb150"
if compgen -G "$dir/checkpoints/latest/*/commit_success.txt" > /dev/null; then
  python train.py --resume --total-steps 1000000 --out "$dir" --no-progress
else
  python train.py --method match --preset cpu --seeds 3 --total-steps 1000000 --minibatches 150 \
    --learning-rate 1e-3 --gamma 0.99 --initial-force-z 0 --out "$dir" --no-progress
fi
python benchmarks/learning_settings.py "8 minibatches x 4 epochs (cpu preset)=$runs/match" \
  "150 minibatches x 4 epochs (authors')=$dir" --up-to 1000000 --json "$out"
python benchmarks/throughput.py --training cpu --method match --seeds 3 --minibatches 8,150 --chunks 3 \
  --json "${out%.json}_throughput.json"
