"""Physics-facing numbers of the controller: end-effector stiffness and the self-centring range.

    python benchmarks/investigations/physics_probes.py --json results/physics_probes.json

Stiffness: settled end-effector displacement under 1 N along x, y, z at the spawn pose
(`probes.static_compliance`), for Factory's law (default) and the paper's J^T M_x law.
Self-centring: the peg lowered 1 mm above the block at a lateral offset, then pressed down with a 5 N
command (z force control) while x, y hold the offset with the default k_p; an offset "inserts" when the
tip ends more than 10 mm below the block top, i.e. the chamfer moved the compliant arm over the bore.
Force laws: the authors' literal k_f (f_d - f) (default; it settles at k_f / (1 + k_f) of the command,
1.7 N here) and the damped law with feed-forward (settles at the command). The peg is held at its
nominal pose in the hand: an in-hand offset shifts the tip, so offsets here are tip offsets.
"""

from __future__ import annotations

import argparse
import json
import pathlib

import match_jax  # noqa: F401  (fast XLA CPU flag before JAX starts)


from match_jax.envs.controllers import ControllerConfig
from match_jax.envs import FPiHConfig, FPiHEnv
from match_jax.envs.probes import press_down, static_compliance
from match_jax.envs.randomization import ModelRandomization

QUIET = dict(hole_xy_range=0.0, hole_yaw_range=0.0, spawn_noise=(0.0, 0.0, 0.0), hand_yaw_range=0.0,
             hole_obs_noise=0.0, force_obs_noise=0.0, torque_obs_noise=0.0, ee_pos_obs_noise=0.0,
             randomization=ModelRandomization(peg_offset_range=(0.0, 0.0, 0.0)))
LAWS = {"factory": (False, "literal"), "factory_damped": (False, "damped"), "paper_task_inertia": (True, "literal")}
OFFSETS_MM = (0.0, 1.0, 2.0, 2.5, 3.0, 3.5, 4.0, 5.0, 6.0)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", type=pathlib.Path, default=None, help="write the numbers here")
    args = parser.parse_args(argv)
    out = {"stiffness_n_per_m": {}, "self_centring": {}}
    for name, (uti, law) in LAWS.items():
        controller = ControllerConfig(use_task_inertia=uti).with_force_law(law)
        config = FPiHConfig(control="hybrid", controller=controller, **QUIET)
        env = FPiHEnv(config)
        stiffness = 1.0 / static_compliance(env, force_n=1.0, seconds=5.0)
        out["stiffness_n_per_m"][name] = [round(float(k), 1) for k in stiffness]
        kp_xy = config.controller.pos_stiffness[0]
        press = press_down(env, [(off * 1e-3, -5.0, kp_xy) for off in OFFSETS_MM], policy_steps=60)
        final_tip_z = press["tips"][:, -1, 2]
        inserted = [bool(z < press["block_top"] - 0.010) for z in final_tip_z]
        out["self_centring"][name] = {
            "offsets_mm": list(OFFSETS_MM), "inserted": inserted,
            "final_tip_height_mm": [round(float(z) * 1e3, 2) for z in final_tip_z],
            "max_force_n": [round(float(f), 2) for f in press["max_forces"][:, 13:].max(axis=1)],
            "final_force_z_n": [round(float(f), 2) for f in press["contact_forces"][:, -1, 2]],
            "largest_inserting_offset_mm": max((o for o, i in zip(OFFSETS_MM, inserted) if i), default=None)}
        print(f"{name}: stiffness {out['stiffness_n_per_m'][name]} N/m; self-centring inserts from "
              f"{[o for o, i in zip(OFFSETS_MM, inserted) if i]} mm", flush=True)
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
