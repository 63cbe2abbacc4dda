"""What one env step costs beyond MuJoCo-MJX's own physics step: the pieces timed separately.

    python benchmarks/step_breakdown.py --json results/step_breakdown.json

One process, one CPU device, the hybrid env at the cpu preset's batch (128 envs), each piece a
jitted vmapped function timed after compilation, in two sets of states:
- `free`: the reset states (the arm above the hole, nothing in contact);
- `contact`: the states after 40 policy steps pressing down (position action z = -0.5, unbreakable),
  the peg on the block or in the hole.

Pieces: `env.step` (8 control substeps: control law, physics step, contact force; then kinematics,
reward, break check, observations), `mjx_step_scan` (8 bare physics steps in one `lax.scan`, torques
held at gravity compensation: the physics of an env step without the env), `mjx.step` (one physics step), `fwd_position` (kinematics,
inertia, collision, constraint set-up of one step), `arm_dynamics` (Jacobian and mass matrix for the
law), `arm_dynamics + law` (the hybrid control law's torques), `peg_contact_force` (the force read
after every physics step) and `kinematics + com_pos` (the refresh after the last substep). The
shares are per env step: 8 x the per-substep pieces over `env.step` (separate calls carry their own
dispatch overhead, so the per-substep shares are upper bounds; `mjx_step_scan` has none).
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import time

import match_jax  # noqa: F401  (fast XLA CPU flag)

import jax
import jax.numpy as jnp
import numpy as np

from match_jax.envs import sim
from match_jax.envs.controllers.osc import hybrid_torque
from match_jax.envs import FPiHConfig, FPiHEnv
from match_jax.envs.sim import mjx


def timed_rounds(calls: dict, rounds: int) -> dict:
    """Median seconds per call of each jitted `calls[name] = (fn, args)`, after one compiling call each,
    timed in interleaved rounds (every function once per round), so a drift of the machine's speed
    affects them alike."""
    for fn, args in calls.values():
        jax.block_until_ready(fn(*args))
    times = {name: [] for name in calls}
    for _ in range(rounds):
        for name, (fn, args) in calls.items():
            start = time.perf_counter()
            jax.block_until_ready(fn(*args))
            times[name].append(time.perf_counter() - start)
    return {name: float(np.median(t)) for name, t in times.items()}


def pressed_states(env: FPiHEnv, states, steps: int = 40):
    """`states` after `steps` policy steps with the position action z = -0.5, unbreakable."""
    task = env.with_values(break_force=math.inf)
    action = env.neutral_action().at[env.action_space.position[2]].set(-0.5)
    batch = states.obs["state"].shape[0]

    def body(s, _):
        return jax.vmap(task.step)(s, jnp.tile(action, (batch, 1))), None

    return jax.jit(lambda s: jax.lax.scan(body, s, None, length=steps)[0])(states)


def breakdown(env: FPiHEnv, states, rounds: int) -> dict:
    m, ids, cfg = env.mjx_model, env.ids, env.config
    data, batch = states.pipeline_state, states.obs["state"].shape[0]
    actions = jnp.tile(env.neutral_action(), (batch, 1))
    targets = jax.vmap(lambda s, a: env._control_target(s.pipeline_state, s.info, a))(states, actions)
    forces = states.info["ee_force"]

    def held_physics(d):
        """8 bare physics steps, the torques held at gravity compensation of the first state."""
        d = mjx.forward(m, d)
        d = d.replace(ctrl=d.qfrc_bias[:m.nu])
        return jax.lax.scan(lambda x, _: (mjx.step(m, x), None), d, None, length=cfg.control_substeps)[0]

    def law(d, target, force):
        return hybrid_torque(sim.arm_dynamics(m, d, ids, force), target, cfg.controller)

    calls = {
        "env_step": (jax.jit(jax.vmap(env.step)), (states, actions)),
        "mjx_step_scan": (jax.jit(jax.vmap(held_physics)), (data,)),
        "mjx_step": (jax.jit(jax.vmap(lambda d: mjx.step(m, d))), (data,)),
        "fwd_position": (jax.jit(jax.vmap(lambda d: mjx.fwd_position(m, d))), (data,)),
        "arm_dynamics": (jax.jit(jax.vmap(lambda d, f: sim.arm_dynamics(m, d, ids, f))), (data, forces)),
        "arm_dynamics_and_law": (jax.jit(jax.vmap(law)), (data, targets, forces)),
        "peg_contact_force": (jax.jit(jax.vmap(lambda d: sim.peg_contact_force(m, d, ids.peg_geoms))), (data,)),
        "kinematics_com_pos": (jax.jit(jax.vmap(lambda d: mjx.com_pos(m, mjx.kinematics(m, d)))), (data,)),
    }
    ms = timed_rounds(calls, rounds)
    ms = {k: 1000.0 * v for k, v in ms.items()}
    substeps = cfg.control_substeps
    once = ("env_step", "mjx_step_scan", "kinematics_com_pos")  # the others run once per substep
    shares = {f"{k}_share_of_env_step": (1 if k in once else substeps) * v
              / ms["env_step"] for k, v in ms.items() if k != "env_step"}
    return {"ms_per_call": ms, **shares, "contact_fraction": float(jnp.mean(states.info["in_contact"]))}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--batch", type=int, default=128)
    parser.add_argument("--rounds", type=int, default=15, help="timed calls of each piece (median)")
    parser.add_argument("--json", type=pathlib.Path, default=None)
    args = parser.parse_args(argv)
    env = FPiHEnv(FPiHConfig(control="hybrid"))
    free = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), args.batch))
    results = {"batch": args.batch, "device": str(jax.devices()[0]),
               "free": breakdown(env, free, args.rounds),
               "contact": breakdown(env, pressed_states(env, free), args.rounds)}
    for name in ("free", "contact"):
        row = results[name]
        print(f"{name} (contact on {100 * row['contact_fraction']:.0f} % of envs): "
              + ", ".join(f"{k} {v:.2f} ms" for k, v in row["ms_per_call"].items()))
        print("  per env step: " + ", ".join(f"{k.replace('_share_of_env_step', '')} {100 * v:.1f} %"
                                           for k, v in row.items() if k.endswith("_share_of_env_step")))
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
