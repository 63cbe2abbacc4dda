# Shared set-up of the GPU scripts (sourced by gpu_suite.sh and gpu_variants.sh; needs WORK and
# DEADLINE set): environment, a time-boxed JAX probe, CUDA MPS with a fallback, and an nvidia-smi
# sampler. After `gpu_start`: MPS_ON (0/1), SMI (the sampler's pid), elapsed and stamp.
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

gpu_start() {  # several processes share one GPU; MPS lets their kernels run concurrently
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
}

gpu_stop() {
  kill "$SMI" 2> /dev/null
  [ "$MPS_ON" = 1 ] && echo quit | nvidia-cuda-mps-control
  return 0
}
