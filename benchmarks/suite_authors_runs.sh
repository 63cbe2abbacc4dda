#!/usr/bin/env bash
# The suite on the authors' task, continued from its committed results (results/authors_task's Pose,
# Hybrid-Basic and MATCH runs, results/suite_authors' runs): copies those exported runs and evaluations into
# RUNS_DIR (a run directory already there is kept), then trains and evaluates the NAMES one after the other
# (cpu preset, 3 seeds, 2.5M env steps per seed, 500 episodes per seed and setting), exporting each run to
# results/suite_authors as soon as it is evaluated and rewriting the report there over every run evaluated so
# far. Runs already evaluated are skipped; an interrupted run resumes from its checkpoint in RUNS_DIR.
#   bash benchmarks/suite_authors_runs.sh RUNS_DIR [NAMES]
#   nohup bash benchmarks/suite_authors_runs.sh ~/runs/suite_authors > ~/runs/suite.log 2>&1 &
#   bash benchmarks/suite_authors_runs.sh ~/runs/suite_authors "pose hybrid match"   # the 500-episode re-evaluations
set -euo pipefail
cd "$(dirname "$0")/.."
runs=${1:?usage: suite_authors_runs.sh RUNS_DIR [NAMES]}
names=${2:-pose hybrid match match_nossl hybrid_nossl pose_noise2.5 pose_unbreakable vices_unbreakable \
hybrid_unbreakable match_unbreakable}
export_dir=results/suite_authors
# --initial-force-z 0: the untrained force-z target these runs were trained with (the cpu preset's then).
sizes=(--total-steps 2500000 --episodes 500 --sweep-episodes 500 --initial-force-z 0)
mkdir -p "$runs/runs" "$runs/eval"
for src in results/authors_task/runs/{pose,hybrid,match} "$export_dir"/runs/*; do
  [ -d "$src/actors" ] && [ ! -e "$runs/runs/$(basename "$src")" ] && cp -r "$src" "$runs/runs/"
done
for src in "$export_dir"/eval/*.json; do
  [ -e "$runs/eval/$(basename "$src")" ] || cp "$src" "$runs/eval/"
done
for name in $names; do
  python -m match_jax.experiments --out "$runs" --only "$name" "${sizes[@]}" --export "$export_dir"
  # The report over every run evaluated so far (no --only: every run of the task; the run's own call reports
  # only itself).
  python -m match_jax.experiments --out "$runs" "${sizes[@]}" --export "$export_dir" --report-only
  echo "[suite_authors_runs] $name evaluated and exported at $(date -u +%FT%TZ)"
done
