"""Figures of one training run from its metrics and its eval.py JSONs.

    python benchmarks/run_figures.py RUN_DIR OUT [LABEL]
(reads RUN_DIR/metrics.csv, OUT/eval.json and OUT/noise_sweep*.json; writes learning_curve.png,
selection_profile.png, noise_robustness.png and unbreakable_robustness.png into OUT)
"""
import json
import pathlib
import sys

import numpy as np

from match_jax.experiments import plots
from match_jax.training.runs import read_metrics

run_dir, out = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2])
label = sys.argv[3] if len(sys.argv) > 3 else "MATCH"
rows = read_metrics(run_dir)
steps = np.array([r["env_steps"] for r in rows if r["seed_index"] == 0])
success = np.array([[r["success_rate"] for r in rows if r["seed_index"] == 0]])
plots.learning_curves({label: {"env_steps": steps, "success_rate": success}},
                      out / "learning_curve.png")
evaluation = json.loads((out / "eval.json").read_text())
if "selection_profile" in evaluation:
    plots.selection_profile({label: evaluation["selection_profile"]}, out / "selection_profile.png")
sweep = []
for name in ("noise_sweep.json", "noise_sweep_unbreakable.json"):  # breakable and unbreakable rows
    if (out / name).exists():
        sweep += json.loads((out / name).read_text())["noise_sweep"]
if sweep:
    plots.noise_robustness({label: sweep}, out / "noise_robustness.png")
    plots.unbreakable_robustness({label: sweep}, out / "unbreakable_robustness.png")
print("wrote", sorted(p.name for p in out.glob("*.png")))
