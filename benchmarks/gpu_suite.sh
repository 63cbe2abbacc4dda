#!/usr/bin/env bash
# One GPU session, time-boxed: train the experiment suite (cpu preset, 3 seeds, every method as its
# own process on the one GPU) and a paper-preset MATCH run, then pack the run directories so that
# evaluation (and further training) can go on elsewhere:
#
#   bash benchmarks/gpu_suite.sh WORK_DIR [DEADLINE_S] [PACK_DIR]
#
# DEADLINE_S (default 540) bounds the whole script: every training process gets a time budget that
# ends about 100 s before it and is killed 40 s before it (checkpoints are written after each chunk,
# so a kill loses only the chunk in flight). A second call with the same WORK_DIR on the same (warm)
# machine resumes every run, and XLA's persistent compilation cache (WORK_DIR/xla_cache) spares it
# the ~4 minutes of compilation. PACK_DIR (default WORK_DIR) receives:
#   suite_best.tgz.partNN  WORK_DIR/suite/runs with metrics, configs and the best checkpoint of each
#                          seed, split in 15 MiB parts (the device tool returns files up to 16 MiB);
#                          `cat suite_best.tgz.part* | tar xz` then evaluate and report them with
#                          `python -m match_jax.experiments --preset cpu --seeds 3 --total-steps 2000000
#                          --selection-not-in-ratio --out suite --skip-training`
#   paper_match.tgz        the paper-preset run's metrics and config (its checkpoints are ~100 MB)
#   logs.tgz               every process's log and nvidia-smi samples
# The latest checkpoints (for resuming) hold every env's MJX state (~5 MB per seed) and stay behind.
# Env variables: SUITE_STEPS (env steps per seed, default 2000000), SEEDS (default 3), ONLY (suite runs,
# default all seven), PAPER=0 (no paper-preset run), MPS=0 (no CUDA MPS daemon), PROBE_S (default 60),
# SMOKE=1 (tiny preset: checks the script itself on a CPU), GPU_XLA_FLAGS (added to XLA_FLAGS, e.g.
# --xla_gpu_autotune_level=0 to cut compilation; untested here).
set -uo pipefail
WORK=${1:?usage: gpu_suite.sh WORK_DIR [DEADLINE_S] [PACK_DIR]}
DEADLINE=${2:-540}
PACK=${3:-$WORK}
STEPS=${SUITE_STEPS:-2000000}
SEEDS=${SEEDS:-3}
PRESET=cpu; PAPER_PRESET=paper
if [ "${SMOKE:-0}" = 1 ]; then PRESET=tiny; PAPER_PRESET=tiny; STEPS=64; fi
mkdir -p "$WORK/logs" "$PACK"
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
# MJX's docs recommend full-precision matmuls on GPU (TF32 hurts the contact solve).
export JAX_DEFAULT_MATMUL_PRECISION=${JAX_DEFAULT_MATMUL_PRECISION:-highest}
# Persistent compilation cache: a resumed call on the same machine skips recompiling.
export JAX_COMPILATION_CACHE_DIR=${JAX_COMPILATION_CACHE_DIR:-$WORK/xla_cache}
export JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS=0 JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES=-1
[ -n "${GPU_XLA_FLAGS:-}" ] && export XLA_FLAGS="${XLA_FLAGS:-} $GPU_XLA_FLAGS"
T0=$(date +%s)
elapsed() { echo $(( $(date +%s) - T0 )); }
stamp() { echo "[$(elapsed) s] $*"; }

probe() {  # JAX's backend start, time-boxed (on the first H200 lent, it never returned)
  timeout "${PROBE_S:-60}" python -c 'import match_jax, jax; print(jax.devices(), jax.__version__)' 2>&1 | tail -2
  return "${PIPESTATUS[0]}"
}
# Eight processes share one GPU; MPS lets their kernels run concurrently instead of time-sliced.
MPS_ON=0
if [ "${MPS:-1}" = 1 ] && command -v nvidia-cuda-mps-control > /dev/null; then
  nvidia-cuda-mps-control -d && MPS_ON=1 && stamp "CUDA MPS daemon started"
fi
if ! DEVICES=$(probe); then
  stamp "probe failed (MPS=$MPS_ON): $DEVICES"
  if [ $MPS_ON = 1 ]; then echo quit | nvidia-cuda-mps-control; MPS_ON=0; sleep 2; DEVICES=$(probe) || {
    stamp "probe failed without MPS too: $DEVICES"; exit 3; }
  else exit 3; fi
fi
stamp "devices: $DEVICES (MPS=$MPS_ON)"
( while sleep 20; do echo "[$(elapsed) s] $(nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv,noheader 2>&1)"; done ) \
  > "$WORK/logs/nvidia_smi.log" 2>&1 &
SMI=$!

KILL_AT=$(( DEADLINE - 40 - $(elapsed) ))
BUDGET_MIN=$(python -c "print(max(0.5, ($DEADLINE - 100 - $(elapsed)) / 60))")
stamp "training: budget $BUDGET_MIN min per process, killed after $KILL_AT s"
NAMES=${ONLY:-pose,vices,hybrid,match,match_nossl,hybrid_nossl,pose_noise2.5}
for name in ${NAMES//,/ }; do
  timeout "$KILL_AT" python -m match_jax.experiments --preset "$PRESET" --seeds "$SEEDS" --total-steps "$STEPS" \
    --selection-not-in-ratio --out "$WORK/suite" --only "$name" --train-only --time-budget-min "$BUDGET_MIN" \
    >> "$WORK/logs/$name.log" 2>&1 &
done
if [ "${PAPER:-1}" = 1 ]; then
  if [ -f "$WORK/paper_match/config.json" ]; then PAPER_ARGS=(--resume)
  else PAPER_ARGS=(--method match --selection-not-in-ratio --preset "$PAPER_PRESET" --seeds "$SEEDS"); fi
  timeout "$KILL_AT" python train.py "${PAPER_ARGS[@]}" --out "$WORK/paper_match" --time-budget-min "$BUDGET_MIN" \
    --no-progress >> "$WORK/logs/paper_match.log" 2>&1 &
fi
wait $(jobs -p | grep -v "^$SMI$")
kill $SMI 2> /dev/null
stamp "training processes done"
for f in "$WORK"/logs/*.log; do echo "== $f"; grep -v "^\s*$" "$f" | tail -2; done
for run in "$WORK"/suite/runs/* "$WORK/paper_match"; do
  [ -f "$run/metrics.csv" ] && echo "== $run: $(tail -1 "$run/metrics.csv")"
done
tar czf - -C "$WORK" --exclude=latest suite/runs 2> /dev/null | split -b 15M -d - "$PACK/suite_best.tgz.part"
tar czf "$PACK/logs.tgz" -C "$WORK" logs
[ -d "$WORK/paper_match" ] && tar czf "$PACK/paper_match.tgz" -C "$WORK" --exclude=checkpoints paper_match
[ $MPS_ON = 1 ] && echo quit | nvidia-cuda-mps-control
stamp "packed: $(ls -la "$PACK" | tail -n +2 | awk '{print $5, $9}' | tr '\n' ' ')"
