"""Curves of the MATCH ratio/SSL variants trained on one H100 (benchmarks/variants_match_ratio.txt):

    python benchmarks/investigations/plot_ratio_variants.py   # reads and writes results/match_ratio_variants_h100/
"""

import csv
import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

HERE = pathlib.Path(__file__).resolve().parents[2] / "results" / "match_ratio_variants_h100"


def column(rows, key):
    return np.array([float(r[key]) if r[key] not in ("", None) else np.nan for r in rows])


def main():
    panels = [("success_rate", "training success %"), ("contact_fraction", "steps in contact %"),
              ("p_force_contact", "p_force on in-contact steps %"), ("p_force_free", "p_force on free-space steps %")]
    fig, axes = plt.subplots(1, len(panels), figsize=(17, 4))
    for path in sorted(HERE.glob("*_metrics.csv")):
        rows = list(csv.DictReader(path.open()))
        steps = column(rows, "env_steps") / 1e6
        name = path.name.removesuffix("_metrics.csv")
        style = "--" if name.startswith(("authors", "inratio_nossl")) else "-"
        for ax, (key, _) in zip(axes, panels):
            ax.plot(steps, 100 * column(rows, key), style, label=name)
    for ax, (_, label) in zip(axes, panels):
        ax.set_xlabel("env steps (M), one seed")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[3].set_yscale("log")
    axes[0].legend(fontsize=7)
    fig.suptitle("MATCH, paper's ratio (selection term in the PPO ratio) vs SSL weight and samples; "
                 "dashed: controls (authors' ratio, no SSL)")
    fig.tight_layout()
    fig.savefig(HERE / "variants.png", dpi=100)


if __name__ == "__main__":
    main()
