#!/usr/bin/env bash
# One GPU call, time-boxed (default 530 s): probe the device, env steps/s of both physics backends
# (MJX-JAX and MuJoCo Warp) at 1k, 4k and 16k envs pressing on the block, then the paper preset (MATCH,
# 5 seeds x 256 envs, 3M env steps per seed) on the faster backend until the deadline. Writes into OUT_DIR:
#   backend_throughput.json   per backend and batch: env steps/s, compile s (benchmarks/backend_throughput.py)
#   paper/config.json, paper/metrics.csv, paper/actors/   the paper-preset run: metrics, best actors only
#   summary.json              device, faster backend, the run's compile estimate, wall clock and env steps
#   logs/                     every step's output
#
#   bash benchmarks/gpu_backends.sh OUT_DIR [DEADLINE_S]
#   SMOKE=1 bash benchmarks/gpu_backends.sh /tmp/gpu_smoke 280     # on a CPU: tiny sizes, checks the script
#
# MuJoCo Warp is measured only where it imports (the `warp` extra); otherwise its rows hold the one-line
# error and the paper run uses MJX-JAX. Env: PROBE_S (default 60), BATCHES (default 1024,4096,16384),
# BACKEND (force the paper run's backend), SEEDS (default 5).
set -uo pipefail
OUT=${1:?usage: gpu_backends.sh OUT_DIR [DEADLINE_S]}
DEADLINE=${2:-530}
cd "$(dirname "$0")/.."
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"  # this checkout, installed or not
mkdir -p "$OUT/logs"
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
export JAX_DEFAULT_MATMUL_PRECISION=${JAX_DEFAULT_MATMUL_PRECISION:-highest}
T0=$(date +%s)
elapsed() { echo $(( $(date +%s) - T0 )); }
stamp() { echo "[$(elapsed) s] $*" | tee -a "$OUT/logs/steps.log"; }

BATCHES=${BATCHES:-1024,4096,16384}; PRESET=paper; STEPS=20; PRESS=40; SEEDS=${SEEDS:-5}
if [ "${SMOKE:-0}" = 1 ]; then BATCHES=4; PRESET=tiny; STEPS=2; PRESS=3; SEEDS=1; fi

DEVICES=$(timeout "${PROBE_S:-60}" python -c 'import match_jax, jax; print(jax.devices(), jax.__version__)' 2>&1 | tail -1)
[ "${PIPESTATUS[0]:-0}" = 0 ] || { stamp "probe failed: $DEVICES"; exit 3; }
stamp "devices: $DEVICES"

# Throughput: at most half of the time left; no measurement starts in its last fifth.
BENCH_S=$(( (DEADLINE - $(elapsed)) / 2 ))
timeout "$BENCH_S" python benchmarks/backend_throughput.py --batches "$BATCHES" --steps "$STEPS" \
  --press-steps "$PRESS" --deadline-s $(( BENCH_S * 4 / 5 )) --json "$OUT/backend_throughput.json" \
  > "$OUT/logs/backend_throughput.log" 2>&1
stamp "throughput done (rc $?): $(grep -c 'env steps/s' "$OUT/logs/backend_throughput.log") rows"
FASTER=$(python - "$OUT/backend_throughput.json" <<'EOF'
import json, sys
try:
    rows = json.load(open(sys.argv[1]))["rows"]
except (OSError, ValueError, KeyError):
    rows = []
best = {}
for r in rows:
    if "env_steps_per_s" in r:
        best[r["backend"]] = max(best.get(r["backend"], 0.0), r["env_steps_per_s"])
print(max(best, key=best.get) if best else "jax")
EOF
)
BACKEND=${BACKEND:-$FASTER}
stamp "paper preset on the $BACKEND backend"

# Training: the rest, less 60 s for the export and the summary; the process is killed 30 s after its budget.
BUDGET_S=$(( DEADLINE - $(elapsed) - 60 ))
BUDGET_MIN=$(python -c "print(max(0.2, ($BUDGET_S - 30) / 60))")
RUN=$OUT/run_with_checkpoints
TRAIN_START=$(date +%s)
timeout "$BUDGET_S" python train.py --method match --preset "$PRESET" --seeds "$SEEDS" --physics-backend "$BACKEND" \
  --out "$RUN" --time-budget-min "$BUDGET_MIN" --no-progress > "$OUT/logs/paper_train.log" 2>&1
stamp "training done (rc $?)"
TRAIN_S=$(( $(date +%s) - TRAIN_START ))
mkdir -p "$OUT/paper"
python - "$RUN" "$OUT" "$DEVICES" "$BACKEND" "$TRAIN_S" <<'EOF' 2>&1 | tee -a "$OUT/logs/steps.log"
import json, pathlib, sys
from match_jax.training.runs import export_actors, read_metrics
run, out, devices, backend, train_s = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2]), sys.argv[3], sys.argv[4], int(sys.argv[5])
summary = {"devices": devices, "backend": backend, "train_process_s": train_s}
rows = read_metrics(run) if (run / "config.json").exists() else []
if rows:
    export_actors(run, out / "paper")  # config, metrics and best actors; no critic or optimiser state
    # wall_clock_s: seconds since the process started, at the end of each chunk (the first holds compiling)
    ends = sorted({float(r["wall_clock_s"]) for r in rows})
    steps = max(int(r["env_steps"]) for r in rows)
    chunk_s = ends[1] - ends[0] if len(ends) > 1 else None
    summary.update(env_steps_per_seed=steps, seeds=1 + max(int(r["seed_index"]) for r in rows),
                   first_chunk_s=ends[0], later_chunk_s=chunk_s,
                   compile_estimate_s=None if chunk_s is None else ends[0] - chunk_s,
                   best_success=max(float(r["success_rate"] or 0) for r in rows))
(out / "summary.json").write_text(json.dumps(summary, indent=1))
print(json.dumps(summary))
EOF
du -sh "$OUT"/* | tee -a "$OUT/logs/steps.log"
rm -rf "$RUN"  # checkpoints stay behind (every env's physics state)
stamp "done"
