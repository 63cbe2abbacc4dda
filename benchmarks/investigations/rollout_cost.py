"""Where a training rollout's time goes: policy network vs physics, and what contact costs.

    python benchmarks/investigations/rollout_cost.py --json results/rollout_cost.json

All in one process, each a jitted 150-step `lax.scan` of the auto-reset Pose env at the cpu preset's
batch (128 envs), timed after compilation:
- `neutral`: the neutral action (hold pose) every step: no env ever touches the block;
- `policy_neutral`: as `neutral`, plus the cpu preset's untrained actor, normalisation and sampling
  every step (their results are kept, the env still gets the neutral action): the policy's cost;
- `random`: actions tanh(0.135 N(0, 1)) (the cpu preset's initial std), no network: some envs
  touch the block; reported with the fraction of env-steps in contact and the fraction of batch
  steps in which at least one env was in contact.
MJX's constraint solver runs inside the vmapped step as a while loop, which iterates until the
slowest env of the batch has converged, so one env in contact makes the whole batch step cost a
contact step.

`--solver` also presses every env's peg onto the block for 60 steps (Pose action z = -0.5) with the
scene's solver settings (Newton, 8 iterations, 8 line-search iterations) and with fewer, reporting
steps/s, the mean peak contact force of the last 20 steps, and the largest difference of any env's
per-step peak force from the first setting's (the scene's).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

import match_jax  # noqa: F401  (fast XLA CPU flag)

import jax
import jax.numpy as jnp
import numpy as np
from brax.training.acme import running_statistics, specs

from match_jax.rl.distributions import make_distribution
from match_jax.envs import AutoResetEnv, FPiHConfig, FPiHEnv
from match_jax.rl.networks import Actor
from match_jax.training.presets import get_preset
from match_jax.envs.sim import mjx
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/, for throughput.py
from throughput import _timed  # noqa: E402


def rollout_costs(batch: int, steps: int, repeats: int) -> list[dict]:
    env = FPiHEnv(FPiHConfig(control="pose"))
    benv = AutoResetEnv(env)
    network = get_preset("cpu").network
    dist = make_distribution("pose")
    actor = Actor(dist.num_continuous, dist.num_selections, network)
    obs_size = env.observation_size["state"][0]
    params = actor.init(jax.random.PRNGKey(0), jnp.zeros((1, obs_size)))
    stats = running_statistics.init_state(specs.Array((obs_size,), jnp.float32))
    neutral = jnp.tile(env.neutral_action(), (batch, 1))
    std = float(np.exp(network.initial_log_std))

    def make(kind):
        def body(state, key):
            out = ()
            action = neutral
            if kind == "policy_neutral":
                head = actor.apply(params, running_statistics.normalize(state.obs["state"], stats, max_abs_value=10.0))
                sample = dist.sample(key, head)
                out = (dist.to_action(sample), dist.log_prob(sample, head))
            elif kind == "random":
                action = jnp.tanh(std * jax.random.normal(key, neutral.shape))
            state = benv.step(state, action)
            return state, (state.info["in_contact"], out)

        @jax.jit
        def run(carry):
            state, key = carry
            key, sub = jax.random.split(key)
            state, (contact, out) = jax.lax.scan(body, state, jax.random.split(sub, steps))
            # return a reduction of the policy's outputs: unused scan outputs would be dead code under jit
            return state, key, contact, jax.tree_util.tree_map(jnp.sum, out)

        return run

    state0 = benv.reset(jax.random.split(jax.random.PRNGKey(0), batch))
    rows = []
    for kind in ("neutral", "policy_neutral", "random"):
        run = make(kind)
        contact = []

        def call(carry, run=run, contact=contact):
            state, key, c, out = run(carry[:2])
            contact.append(c)
            return state, key, out

        seconds = _timed(call, (state0, jax.random.PRNGKey(1)), repeats)
        c = np.asarray(jnp.stack(contact[-repeats:]))  # (repeats, steps, batch)
        rows.append({"rollout": kind, "seconds_per_rollout": seconds, "env_steps_per_s": batch * steps / seconds,
                     "contact_env_step_fraction": float(c.mean()),
                     "batch_steps_with_contact_fraction": float(c.max(-1).mean())})
        print(f"{kind:15s} {seconds:6.2f} s / {steps}-step rollout of {batch} envs = {batch * steps / seconds:6.0f} "
              f"env steps/s | env-steps in contact {100 * c.mean():5.1f} %, batch steps with any contact "
              f"{100 * c.max(-1).mean():5.1f} %", flush=True)
    return rows


def solver_costs(batch: int, settings: list[tuple[int, int]], steps: int = 60) -> list[dict]:
    env = FPiHEnv(FPiHConfig(control="pose"))
    state0 = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), batch))
    press = jnp.zeros((batch, env.action_size)).at[:, 2].set(-0.5)
    rows, reference = [], None
    for iterations, ls_iterations in settings:
        model = env.mj_model
        model.opt.iterations, model.opt.ls_iterations = iterations, ls_iterations
        env.mjx_model = mjx.put_model(model)  # the step below is traced after this, so it uses these settings

        @jax.jit
        def run(state):
            def body(s, _):
                s = jax.vmap(env.step)(s, press)
                return s, (s.info["max_force"], s.info["in_contact"])
            return jax.lax.scan(body, state, None, length=steps)

        seconds = _timed(lambda s: run(state0)[0], state0, 1)
        _, (force, contact) = run(state0)
        force = np.asarray(force)
        reference = force if reference is None else reference
        rows.append({"iterations": iterations, "ls_iterations": ls_iterations, "env_steps_per_s": batch * steps / seconds,
                     "mean_peak_force_last20_N": float(np.nanmean(force[-20:])),
                     "max_abs_peak_force_difference_N": float(np.nanmax(np.abs(force - reference))),
                     "contact_env_step_fraction": float(np.asarray(contact).mean())})
        print(f"solver iterations {iterations} / line search {ls_iterations}: {batch * steps / seconds:6.0f} env steps/s "
              f"pressing, mean peak force of the last 20 steps {rows[-1]['mean_peak_force_last20_N']:.3f} N, largest "
              f"difference from the first setting {rows[-1]['max_abs_peak_force_difference_N']:.3f} N", flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batch", type=int, default=128)
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--solver", action="store_true", help="also the pressing test at several solver settings")
    parser.add_argument("--json", type=pathlib.Path, default=None)
    args = parser.parse_args()
    for name in ("batch", "steps", "repeats"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be a positive integer, got {getattr(args, name)}")
    result = {"device": str(jax.devices()[0]), "batch": args.batch, "steps": args.steps,
              "rollouts": rollout_costs(args.batch, args.steps, args.repeats)}
    if args.solver:
        result["solver"] = solver_costs(args.batch, [(8, 8), (4, 4), (2, 4)])
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
