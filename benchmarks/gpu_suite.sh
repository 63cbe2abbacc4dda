#!/usr/bin/env bash
# One call on a GPU machine, time-boxed: train the experiment suite (cpu preset, 3 seeds, every method as its
# own process on the one GPU, so each compiles its own programs) and a paper-preset MATCH run, then
# pack the run directories so that evaluation (and further training) can go on elsewhere:
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
#                          `python -m match_jax.experiments --preset cpu --seeds 3 --total-steps 2500000
#                          --episodes 200 --sweep-episodes 200 --out suite --skip-training`
#   paper_match.tgz        the paper-preset run's metrics and config (its checkpoints are ~100 MB)
#   logs.tgz               every process's log and nvidia-smi samples
# The latest checkpoints (for resuming) hold every env's MJX state (~5 MB per seed) and stay behind.
# Env variables: SUITE_STEPS (env steps per seed, default 2500000), SEEDS (default 3), ONLY (suite runs,
# default all twelve; ONLY=none: no suite run), RATIO=code (MATCH with the authors'-code ratio,
# --selection-not-in-ratio), PAPER=0 (no paper-preset run), PAPER_PRESET (the preset of that run, default
# paper; PAPER_PRESET=authors trains the authors' recipe at their network sizes, still into paper_match),
# MPS=0 (no CUDA MPS daemon), PROBE_S (default 60),
# SMOKE=1 (tiny preset: checks the script itself on a CPU), GPU_XLA_FLAGS (added to XLA_FLAGS, e.g.
# --xla_gpu_autotune_level=0 to cut compilation; untested here).
set -uo pipefail
WORK=${1:?usage: gpu_suite.sh WORK_DIR [DEADLINE_S] [PACK_DIR]}
DEADLINE=${2:-540}
PACK=${3:-$WORK}
STEPS=${SUITE_STEPS:-2500000}
RATIO_ARGS=(); [ "${RATIO:-paper}" = code ] && RATIO_ARGS=(--selection-not-in-ratio)
SEEDS=${SEEDS:-3}
PRESET=cpu; PAPER_PRESET=${PAPER_PRESET:-paper}
if [ "${SMOKE:-0}" = 1 ]; then PRESET=tiny; PAPER_PRESET=tiny; STEPS=64; fi
mkdir -p "$WORK/logs" "$PACK"
source "$(dirname "$0")/gpu_common.sh"
gpu_start
NAMES=${ONLY:-pose,vices,hybrid,match,match_damped,match_nossl,hybrid_nossl,pose_noise2.5,pose_unbreakable,vices_unbreakable,hybrid_unbreakable,match_unbreakable}
[ "$NAMES" = none ] && NAMES=""
for name in ${NAMES//,/ }; do
  timeout "$KILL_AT" python -m match_jax.experiments --preset "$PRESET" --seeds "$SEEDS" --total-steps "$STEPS" \
    "${RATIO_ARGS[@]}" --out "$WORK/suite" --only "$name" --train-only --time-budget-min "$BUDGET_MIN" \
    >> "$WORK/logs/$name.log" 2>&1 &
done
if [ "${PAPER:-1}" = 1 ]; then
  if [ -f "$WORK/paper_match/config.json" ]; then PAPER_ARGS=(--resume)
  else PAPER_ARGS=(--method match "${RATIO_ARGS[@]}" --preset "$PAPER_PRESET" --seeds "$SEEDS"); fi
  timeout "$KILL_AT" python train.py "${PAPER_ARGS[@]}" --out "$WORK/paper_match" --time-budget-min "$BUDGET_MIN" \
    --no-progress >> "$WORK/logs/paper_match.log" 2>&1 &
fi
wait $(jobs -p | grep -v "^$SMI$")
stamp "training processes done"
for f in "$WORK"/logs/*.log; do echo "== $f"; grep -v "^\s*$" "$f" | tail -2; done
for run in "$WORK"/suite/runs/* "$WORK/paper_match"; do
  [ -f "$run/metrics.csv" ] && echo "== $run: $(tail -1 "$run/metrics.csv")"
done
tar czf - -C "$WORK" --exclude=latest suite/runs 2> /dev/null | split -b 15M -d - "$PACK/suite_best.tgz.part"
tar czf "$PACK/logs.tgz" -C "$WORK" logs
[ -d "$WORK/paper_match" ] && tar czf "$PACK/paper_match.tgz" -C "$WORK" --exclude=checkpoints paper_match
gpu_stop
stamp "packed: $(ls -la "$PACK" | tail -n +2 | awk '{print $5, $9}' | tr '\n' ' ')"
