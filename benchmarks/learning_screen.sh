#!/usr/bin/env bash
# The learning screen on the authors' task: MATCH, cpu sizes (128 envs per seed), 3 seeds x 1M env steps per
# arm, each arm adding one piece of the authors' learning recipe to the one before (arm gae: a change beside the
# recipe, on forcez; arms lowstd and gaecritic: one change each on gae;
# arm g995: one change on forcez; arm soft: forcez on a softer contact, a calibration, not the authors' task).
# The "cpu preset as it was"
# arm is the first 1M env steps of results/suite_authors/runs/match (same seeds), so it is not trained here.
# Each arm trains into RUNS_DIR/<arm> (resumed where a checkpoint exists) and, the minute it finishes, its
# config.json and metrics go to results/learning_screen/<arm>/ and the screen table and figure are rewritten.
#   bash benchmarks/learning_screen.sh RUNS_DIR [ARMS]
#   nohup bash benchmarks/learning_screen.sh ~/runs/screen > ~/runs/screen.log 2>&1 &
set -euo pipefail
cd "$(dirname "$0")/.."
runs=${1:?usage: learning_screen.sh RUNS_DIR [ARMS]}
arms=${2:-forcez update std critic gamma}
out=results/learning_screen
base=(--method match --preset cpu --seeds 3 --total-steps 1000000 --no-progress)
# The cpu preset as it was: force-z target 0 N (the top of its range), learning rate 1e-3, gamma 0.99.
old=(--initial-force-z 0 --learning-rate 1e-3 --gamma 0.99)
forcez=(--initial-force-z -2)
update=(--learning-rate 1e-5 --minibatches 150 --set adam_b1=0.999 adam_b2=0.999 adam_eps=1e-8 critic_steps=2
        kl_threshold=0.05 value_loss=huber normalize_returns=true value_coef=1)
declare -A flags=(
  [forcez]="${old[*]} ${forcez[*]}"
  [update]="${old[*]} ${forcez[*]} ${update[*]}"
  [std]="${old[*]} ${forcez[*]} ${update[*]} --initial-log-std 0"
  [critic]="${old[*]} ${forcez[*]} ${update[*]} --initial-log-std 0 --critic-hidden 256 --critic-blocks 3"
  [gamma]="${old[*]} ${forcez[*]} ${update[*]} --initial-log-std 0 --critic-hidden 256 --critic-blocks 3 --gamma 0.995"
  # beside the recipe: forcez with the shorter credit horizon that learned fastest on the earlier task
  [gae]="${old[*]} ${forcez[*]} --gamma 0.98 --gae-lambda 0.9"
  # on gae: a smaller initial pre-tanh std (0.05 instead of 0.135), less exploration noise at first contact
  [lowstd]="${old[*]} ${forcez[*]} --gamma 0.98 --gae-lambda 0.9 --initial-log-std -3"
  # on gae: a larger critic (SimBa 3 x 256 instead of 2 x 128)
  [gaecritic]="${old[*]} ${forcez[*]} --gamma 0.98 --gae-lambda 0.9 --critic-hidden 256 --critic-blocks 3"
  # on forcez: the authors' discount 0.995 (forcez 0.99, gae 0.98)
  [g995]="${old[*]} ${forcez[*]} --gamma 0.995"
  # CALIBRATION, not the authors' task: forcez trained on a softer contact (solref time constant 0.05 s, the
  # task's 0.02 s), the setting under which the trained actors stop breaking pegs at first contact
  [soft]="${old[*]} ${forcez[*]} --contact-timeconst 0.05"
)
mkdir -p "$runs" "$out"
for arm in $arms; do
  [ -n "${flags[$arm]+x}" ] || { echo "unknown arm $arm; arms: ${!flags[*]}" >&2; exit 2; }
  dir="$runs/$arm"
  if [ -e "$dir/config.json" ]; then
    python train.py --resume --total-steps 1000000 --no-progress --out "$dir"
  else
    # shellcheck disable=SC2086  # the arm's flags are words
    python train.py "${base[@]}" ${flags[$arm]} --out "$dir"
  fi
  mkdir -p "$out/$arm"
  cp "$dir/config.json" "$dir/metrics.jsonl" "$dir/metrics.csv" "$out/$arm/"
  echo "$arm: python train.py ${base[*]} ${flags[$arm]} --out RUN_DIR" > "$out/$arm/command.txt"
  echo "[learning_screen] $arm done at $(date -u +%FT%TZ)"
done
args=("cpu preset as it was (force-z 0 N, lr 1e-3, gamma 0.99)=results/suite_authors/runs/match")
for arm in forcez update std critic gamma gae lowstd gaecritic g995 soft; do
  [ -e "$out/$arm/metrics.jsonl" ] && args+=("$arm=$out/$arm")
done
python benchmarks/learning_settings.py "${args[@]}" --up-to 1000000 --json "$out/summary.json" \
  --plot "$out/curves.png" | tee "$out/summary.md"
