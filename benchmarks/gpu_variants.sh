#!/usr/bin/env bash
# One GPU call, time-boxed: train several train.py variants side by side on the one GPU (one process
# each, CUDA MPS) and pack their metrics and configs (no checkpoints):
#
#   bash benchmarks/gpu_variants.sh VARIANTS_FILE WORK_DIR [DEADLINE_S] [PACK_DIR]
#
# VARIANTS_FILE: one variant per line, `NAME train.py-arguments` (blank lines and # comments skipped),
# e.g. `match_b0.1 --method match --ssl-coef 0.1 --total-steps 3000000`. Every process gets
# --out WORK_DIR/runs/NAME, --no-progress and a time budget that ends about 100 s before DEADLINE_S
# (default 540); it is killed 40 s before it. A second call with the same WORK_DIR on the same (warm)
# machine resumes every run (XLA's persistent cache in WORK_DIR/xla_cache spares the recompile).
# PACK_DIR (default WORK_DIR) receives variants.tgz (runs/*/metrics.csv and config.json, logs) for
# `tar xzf`. Env variables as in gpu_suite.sh: MPS=0, PROBE_S, GPU_XLA_FLAGS.
set -uo pipefail
VARIANTS=${1:?usage: gpu_variants.sh VARIANTS_FILE WORK_DIR [DEADLINE_S] [PACK_DIR]}
WORK=${2:?usage: gpu_variants.sh VARIANTS_FILE WORK_DIR [DEADLINE_S] [PACK_DIR]}
DEADLINE=${3:-540}
PACK=${4:-$WORK}
[ -f "$VARIANTS" ] || { echo "no variants file $VARIANTS"; exit 2; }
mkdir -p "$WORK/logs" "$WORK/runs" "$PACK"
source "$(dirname "$0")/gpu_common.sh"
gpu_start
while read -r name args; do
  case "$name" in ""|\#*) continue;; esac
  if [ -f "$WORK/runs/$name/config.json" ]; then run_args=(--resume); else read -ra run_args <<< "$args"; fi
  timeout "$KILL_AT" python train.py "${run_args[@]}" --out "$WORK/runs/$name" --time-budget-min "$BUDGET_MIN" \
    --no-progress >> "$WORK/logs/$name.log" 2>&1 &
done < "$VARIANTS"
wait $(jobs -p | grep -v "^$SMI$")
stamp "training processes done"
for f in "$WORK"/logs/*.log; do echo "== $f"; grep -v "^\s*$" "$f" | tail -2; done
for run in "$WORK"/runs/*; do [ -f "$run/metrics.csv" ] && echo "== $run: $(tail -1 "$run/metrics.csv")"; done
tar czf "$PACK/variants.tgz" -C "$WORK" --exclude=checkpoints runs logs
gpu_stop
stamp "packed: $(ls -la "$PACK" | tail -n +2 | awk '{print $5, $9}' | tr '\n' ' ')"
