#!/usr/bin/env bash
# One GPU session, time-boxed: the experiment suite (cpu preset, 3 seeds, every method as its own
# process on the one GPU), a paper-preset MATCH run, evaluation, REPORT.md, and env throughput.
#
#   bash benchmarks/gpu_suite.sh OUT_DIR [TRAIN_MINUTES]
#
# Each training process stops after the chunk that ends past TRAIN_MINUTES (default 5) of wall
# clock and is resumable (`python -m match_jax.experiments ... --out OUT_DIR/suite` continues it).
# Results: OUT_DIR/suite (runs, eval/*.json, REPORT.md, plots), OUT_DIR/paper_match, OUT_DIR/logs.
# Env variables: SUITE_STEPS (env steps per seed, default 2000000), SEEDS (default 3),
# SMOKE=1 (tiny preset: checks the script itself in a minute on a CPU).
set -uo pipefail
OUT=${1:?usage: gpu_suite.sh OUT_DIR [TRAIN_MINUTES]}
MINUTES=${2:-5}
STEPS=${SUITE_STEPS:-2000000}
SEEDS=${SEEDS:-3}
PRESET=cpu; PAPER=paper; EPIS=100; SWEEP=200
if [ "${SMOKE:-0}" = 1 ]; then PRESET=tiny; PAPER=tiny; STEPS=64; EPIS=2; SWEEP=2; fi
mkdir -p "$OUT/logs"
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
# MJX's docs recommend full-precision matmuls on GPU (TF32 hurts the contact solve).
export JAX_DEFAULT_MATMUL_PRECISION=${JAX_DEFAULT_MATMUL_PRECISION:-highest}
T0=$(date +%s)
stamp() { echo "[$(( $(date +%s) - T0 )) s] $*"; }

# Probe first: on the one H200 lent so far, JAX's backend never started (no result in 525 s). Fail fast.
if ! DEVICES=$(timeout "${PROBE_S:-90}" python -c 'import match_jax, jax; print(jax.devices(), jax.__version__)' 2>&1); then
  stamp "JAX did not start within ${PROBE_S:-90} s (or failed): $(echo "$DEVICES" | tail -2)"; exit 3
fi
stamp "devices: $(echo "$DEVICES" | tail -1)"

SUITE_ARGS=(--preset "$PRESET" --seeds "$SEEDS" --total-steps "$STEPS" --selection-not-in-ratio
            --episodes "$EPIS" --sweep-episodes "$SWEEP" --out "$OUT/suite")
NAMES=(pose vices hybrid match match_nossl hybrid_nossl pose_noise2.5)
for name in "${NAMES[@]}"; do
  python -m match_jax.experiments "${SUITE_ARGS[@]}" --only "$name" --time-budget-min "$MINUTES" \
    > "$OUT/logs/$name.log" 2>&1 &
done
( python train.py --method match --selection-not-in-ratio --preset "$PAPER" --seeds "$SEEDS" \
    --out "$OUT/paper_match" --time-budget-min "$MINUTES" --no-progress \
  && python eval.py "$OUT/paper_match" --episodes "$EPIS" --json "$OUT/paper_match/eval.json" ) \
  > "$OUT/logs/paper_match.log" 2>&1 &
wait
stamp "training and evaluation processes done"
for f in "$OUT"/logs/*.log; do echo "== $f"; grep -E "^\[|error|Error|success" "$f" | tail -4; done

python -m match_jax.experiments "${SUITE_ARGS[@]}" --skip-training > "$OUT/logs/report.log" 2>&1
stamp "report: $(tail -1 "$OUT/logs/report.log")"
python benchmarks/throughput.py --batch-sizes ${BATCHES:-128,384,1024,4096} --repeats 3 \
  --json "$OUT/throughput_gpu.json" > "$OUT/logs/throughput.log" 2>&1
stamp "throughput done"; tail -8 "$OUT/logs/throughput.log"
