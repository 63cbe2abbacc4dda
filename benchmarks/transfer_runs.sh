#!/usr/bin/env bash
# The paper's real-robot protocol on the MuJoCo C stand-in, for policies trained with dynamics randomisation:
# trains (or resumes) each method with --dynamics-randomization on the authors' task (cpu preset, 3 seeds, STEPS
# env steps per seed), exports every seed to ONNX (Pose and Hybrid-Basic with the stochastic output at 5 % of
# the std, which the protocol samples, as the paper's robot ran them), evaluates each run in the training
# simulator without noise and on the four shells (200 episodes per seed and level), runs the stand-in protocol
# (30 noiseless trials per seed, then the best seed with 50 trials per shell) and writes OUT_DIR/TRANSFER.md
# and transfer.png. The report is rewritten after each method, over the methods done so far. Every stage resumes
# or skips what is done, so re-run it after an interruption until it reports the report written.
#   bash benchmarks/transfer_runs.sh RUNS_DIR OUT_DIR [STEPS] [METHODS] [TRAIN_FLAGS]
#   bash benchmarks/transfer_runs.sh ~/runs/transfer_arm results/transfer/arm_model_error 2500000 "pose match" \
#     --arm-model-error      # extra train.py flags for a fresh run, recorded in its config
#   nohup bash benchmarks/transfer_runs.sh ~/runs/transfer results/transfer > ~/runs/transfer.log 2>&1 &
set -euo pipefail
cd "$(dirname "$0")/.."
runs=${1:?usage: transfer_runs.sh RUNS_DIR OUT_DIR [STEPS] [METHODS] [TRAIN_FLAGS]}
out=${2:?usage: transfer_runs.sh RUNS_DIR OUT_DIR [STEPS] [METHODS] [TRAIN_FLAGS]}
steps=${3:-2500000}
methods=${4:-pose vices hybrid match}
train_flags=("${@:5}")
mkdir -p "$runs" "$out/sim"
sims=()
join() { local IFS=,; echo "$*"; }
for method in $methods; do
  dir="$runs/$method"
  if compgen -G "$dir/checkpoints/latest/*/commit_success.txt" > /dev/null; then
    python train.py --resume --total-steps "$steps" --out "$dir" --no-progress
  else
    python train.py --method "$method" --preset cpu --seeds 3 --total-steps "$steps" --dynamics-randomization \
      "${train_flags[@]}" --out "$dir" --no-progress
  fi
  stochastic=()
  case $method in pose|hybrid) stochastic=(--stochastic --std-scale 0.05) ;; esac
  for seed in 0 1 2; do
    [ -f "$dir/onnx/policy_seed$seed.onnx" ] || \
      python -m match_jax.transfer.export "$dir" "$dir/onnx" --seed-index "$seed" "${stochastic[@]}"
  done
  # The stand-in (MuJoCo C, one core) runs beside the simulator evaluation.
  python benchmarks/standin_protocol.py --policies "$method=$dir/onnx" --out "$out/standin.json" &
  standin=$!
  [ -f "$out/sim/$method.json" ] || python eval.py "$dir" --noise-sweep 0,1,2.5,5,7.5 --episodes 200 \
    --json "$out/sim/$method.json"
  wait "$standin"
  sims+=("$method=$out/sim/$method.json")
  python -m match_jax.transfer.report "$out/standin.json" --sim "$(join "${sims[@]}")" --out "$out"
  echo "[transfer_runs] $method trained, exported, evaluated and run on the stand-in at $(date -u +%FT%TZ)"
done
echo "[transfer_runs] report written at $(date -u +%FT%TZ)"
