"""Fraction of episodes that start inside the lateral capture range, per hole-noise level, with the peg
moved in the hand (uniform +-3 mm across the fingers, the hand yawed U(+-45 deg)) and held rigidly.

    python benchmarks/investigations/capture_fractions.py --json results/authors_task/capture_fractions.json

An episode "starts inside" when the peg tip's lateral distance from the bore axis, once the end effector
is placed over the observed hole, is below the capture range (2.5 mm: docs/task.md's self-centring
range). A policy that succeeds more often than this fraction found the hole by searching, not by luck.
Monte Carlo, 200,000 draws per level.
"""

from __future__ import annotations

import argparse
import json
import pathlib

import numpy as np

SHELL_EDGES_MM = (0.0, 1.0, 2.5, 5.0, 7.5)  # as match_jax.training.evaluation.SHELL_EDGES_MM


def lateral_error_mm(kind: str, level: float, peg_offset: bool, n: int, rng) -> np.ndarray:
    if kind == "gaussian":
        hole = level * rng.normal(size=(n, 2))
    else:  # shell out to `level`
        inner = max([e for e in SHELL_EDGES_MM if e < level], default=0.0)
        direction = rng.normal(size=(n, 3))
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        hole = (direction * rng.uniform(inner, level, n)[:, None])[:, :2]
    peg = np.zeros((n, 2))
    if peg_offset:
        yaw, across = rng.uniform(-0.785, 0.785, n), rng.uniform(-3.0, 3.0, n)
        peg = np.stack([across * np.cos(yaw), across * np.sin(yaw)], axis=1)
    return np.linalg.norm(hole - peg, axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--capture-mm", type=float, default=2.5)
    parser.add_argument("--json", type=pathlib.Path, default=None)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    rows = []
    for kind, level in [("gaussian", 1.0)] + [("shell", e) for e in SHELL_EDGES_MM[1:]]:
        row = {"noise_type": kind, "noise_mm": level}
        for grasp, offset in (("peg_offset", True), ("rigid", False)):
            row[grasp] = float(np.mean(lateral_error_mm(kind, level, offset, 200_000, rng) < args.capture_mm))
        rows.append(row)
        print(f"{kind} {level:g} mm: inside {args.capture_mm:g} mm: peg offset {row['peg_offset']:.3f}, "
              f"rigid {row['rigid']:.3f}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
