"""Brax's PPO vs our PPO on the Pose-control fPiH task: success rate vs env steps, and env steps/s.

Run it in its own virtual environment (Brax 0.14.2's PPO calls `jax.device_put_replicated`, which
jax 0.10 removed, so it cannot run on the repo's default jax 0.10.2):

    python3 -m venv /work/brax_venv
    /work/brax_venv/bin/pip install -r benchmarks/investigations/requirements-brax-comparison.txt
    /work/brax_venv/bin/python benchmarks/investigations/brax_comparison.py --json results/brax_comparison.json

(run from the repo root; the script puts the repo root on sys.path itself, so match_jax need not be
installed in that venv). A smoke run that exercises both trainers (~10 min on 2 busy CPU cores, almost
all of it XLA compiles):

    /work/brax_venv/bin/python benchmarks/investigations/brax_comparison.py --num-envs 8 --total-steps 3600 \
        --eval-episodes 8 --json /tmp/brax_comparison_tiny.json

Speed at equal contact load (both policies kept at their initialisation, which touch the block on
~1 % of env-steps; the trainers still do all their work, the updates are just ~1e-12 in size):

    /work/brax_venv/bin/python benchmarks/investigations/brax_comparison.py --learning-rate 1e-12 --total-steps 153600 \
        --evals 4 --eval-episodes 32 --json results/brax_comparison_frozen.json

What runs, in ONE process, on `FPiHEnv(FPiHConfig(control="pose"))` (150-step episodes):

- ours: `match_jax.training.runs.Run` on `get_preset("cpu", method="pose", num_envs=N, total_steps=S,
  iterations_per_chunk=K)`: rollouts of 150 steps per env per iteration, GAE, 4 epochs x 8
  minibatches, SimBa actor (1 x 128) and asymmetric critic (2 x 128), our `AutoResetEnv`.
- brax: `brax.training.agents.ppo.train` with the same number of envs, `unroll_length=150`,
  `batch_size * num_minibatches = num_envs` (so one Brax training step = one 150-step unroll of every
  env = exactly one of our iterations), `num_updates_per_batch` = our epochs, and our learning rate,
  discount, GAE lambda, clip epsilon, reward scale, value coefficient, entropy coefficient (0) and
  gradient-clip norm. Brax evaluates/reports every K training steps (`num_evals = iterations / K +
  1`), which is exactly our chunk of K iterations, so both trainers are measured at the same env
  steps and both run exactly `ceil(S / (N * 150 * K)) * N * 150 * K` env steps (the total is rounded
  up to whole evaluation intervals; the JSON records the steps actually run).

Success rate: measured the same way for both, by us, not by Brax's evaluator. Our env puts the
per-step 0/1 `success` in `state.metrics`; Brax's evaluator and training-metrics logger SUM metrics
over the episode (`eval/episode_success` is the mean number of success steps per episode), which is
not an episode success rate. So at step 0 and after every K iterations each trainer's current policy
is run deterministically (Brax: `make_policy(params, deterministic=True)`, i.e. tanh of the mean; ours:
`deterministic_policy`, the same) with `match_jax.training.evaluation.make_rollout` on the raw env for
`--eval-episodes` episodes from the SAME reset keys, and `episode_metrics` gives success (success
before any break) and break rates. For Brax this runs in `policy_params_fn`, which Brax calls at
step 0 and after every training epoch, outside its timed region; Brax's own evaluator is switched
off (`run_evals=False`). Our training-rollout success rate (stochastic policy, from our metrics) is
also recorded, as `train_success`; Brax has no equivalent rate.

Env steps/s: training only, compile and evaluation excluded, measured identically for both: the
wall time of each evaluation interval of K iterations (ours: one jitted `train_chunk` call, timed
on the host with `block_until_ready`; Brax: the increments of its own `training/walltime`, which
accumulates only the time of its pmapped `training_epoch` calls, also blocked on). A listener on
JAX's compile events (`jax.monitoring`, trace + lower + backend compile) records how many seconds
of compilation fell into each interval, and intervals with more than 1 s of it are dropped:
steps/s = steps of the clean intervals / their time. The first interval always compiles the
training program. Brax (0.14.2 on jax 0.9.2) also compiles its pmapped `training_epoch` a second
time on its second call (same shapes and dtypes in JAX's compile log; a Brax/pmap quirk, ~40 s on
2 cores), so its second interval is dropped too; therefore at least 3 intervals are run (`--evals`
and the iteration count are raised to 3 if needed). Every interval's time and compile seconds are
in the JSON (`intervals`), and `first_interval_s` is the first one (compile + one interval). Both
trainers run one after the other on the same machine; on a shared or busy machine they see
different background load (compare the per-interval times in the JSON).

Key clashes and how they are handled. Brax's `EpisodeWrapper` and `AutoResetWrapper` (the wrappers
of `brax.envs.training.wrap`) use `state.info['steps']` and `state.info['truncation']`, which our env
also sets. Left as is, both advance the same 'steps' counter (the env adds 1, EpisodeWrapper adds 1
to the env's result), so every episode ends after 75 policy steps instead of 150 (checked: done at
steps 75 and 150 of a 160-step run). Separating the counters alone is not enough: our env itself
sets done = 1 at its time limit, and EpisodeWrapper computes truncation = 1 - done there, i.e. 0, so
Brax would treat every time-out as a termination (value target without bootstrap). `BraxAdapter`
below fixes both: it keeps our env's whole info dict under `info['fpih']` (Brax's wrappers never see
our keys and we never see theirs), and it reports `done` only for terminations (break or divergence),
leaving the time limit to Brax's EpisodeWrapper (`episode_length=150`), which then sets done = 1 and
truncation = 1 at step 150 as Brax expects (checked: done only at step 150, truncation 1).

Auto-reset. Brax's `AutoResetWrapper` restarts a finished env from the state and observation of
that env's FIRST reset: the same hole pose, spawn and hole-observation noise forever, i.e. Brax
trains on only `num_envs` distinct episodes, while ours draws a fresh episode on every reset. It also
swaps only `pipeline_state` and `obs`, so our env's info (previous action of the EMA, last force
reading, had_contact, the episode step counter) would carry over from the previous episode.
Default `--brax-autoreset fresh` passes a `wrap_env_fn` to Brax's train (a documented hook) that uses
Brax's own VmapWrapper and EpisodeWrapper but replaces AutoResetWrapper with `FreshAutoResetWrapper`,
which does what our `AutoResetEnv` does: a new `env.reset` (new key) for every finished env,
including our info, under a batch-level `lax.cond` so steps with no finished env skip the reset.
`--brax-autoreset first` uses stock `brax.envs.training.wrap` (first-state restarts, stale info).

Other differences that remain (Brax as it is used here vs ours):
- networks: Brax's MLPs (swish; `--brax-policy-layers`, `--brax-value-layers`, default 128,128 and
  256,256,256) vs our SimBa trunks (LayerNorm residual blocks, relu). Brax's actor reads
  obs['state'] and its critic obs['privileged_state'] (the same asymmetric split as ours), but our
  critic also gets the episode-time fraction (steps / 150), Brax's does not.
- policy distribution: both tanh-squashed Gaussians with log-probs from the pre-tanh value; Brax's
  std is a state-dependent network output (softplus(x) + 0.001, ~0.7 for x near 0 at init), ours a
  state-independent parameter (the cpu preset's exp(-2) = 0.14 at init), so the two explore
  differently; how much each touches the block is measured (below).
- observation normalisation: both running mean/std per key; Brax updates the statistics with the
  new batch BEFORE its SGD epochs and clips nothing (std_eps 0), ours normalises a rollout with the
  statistics from before it and clips normalised values to +-10.
- GAE and value targets: Brax recomputes GAE inside every minibatch with the current critic; ours
  once per iteration. On a time-out Brax masks the last transition out of the loss and earlier steps
  bootstrap through V(s_149) (`bootstrap_on_timeout=False`, its default); ours bootstraps the last
  transition with V of the final observation.
- minibatches: Brax's are whole 150-step trajectories (num_envs / 8 envs each), ours random
  transitions; the same number of samples per minibatch.
- optimiser: Brax clips the global gradient norm over actor+critic together and uses Adam eps 1e-8;
  ours clips actor and critic separately and uses eps 1e-5.
- devices: `import match_jax` gives JAX one CPU device per core (`match_jax._xla`), and both trainers
  split the envs over them: Brax runs its training epoch under `jax.pmap` over all local devices (its
  default), ours under `jax.jit` with the env axis sharded (`runs.shard_envs`, as train.py does)
  and the env step under `shard_map` (`ppo.make_trainer(mesh=...)`).
  `config.host_devices` records the count; JAX_NUM_CPU_DEVICES=1 gives the one-device comparison.

Contact load. MJX's constraint solver is a while loop that, under vmap, runs until the slowest env of
the batch converges, so a batch step with any env touching the block costs up to ~2.3x a free-space
one (`benchmarks/investigations/rollout_cost.py`): env steps/s depends on how much a trainer's policy touches. At
each evaluation point both trainers' STOCHASTIC policies (their training-time sampling) are also run
on the same evaluation episodes, and the fraction of env-steps in contact is recorded
(`explore_contact_rate`), so per-interval speeds can be compared at similar contact loads (ours also
logs the contact fraction of its actual training rollouts, `train_contact`).

jax 0.9.2 workaround: our Actor always builds the selection-logit Dense layer, with 0 outputs for
the pose method, and jax 0.9.2's orthogonal initializer raises ZeroDivisionError on that zero-size
kernel (jax 0.10 returns an empty array). The script patches flax's `orthogonal` to return zeros
for zero-size shapes, only when the bug is present (recorded as `zero_size_orthogonal_patched`).
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import pathlib
import platform
import sys
import tempfile
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2]))  # the repo root

import match_jax  # noqa: E402,F401  (first: sets the fast XLA CPU flag before JAX starts)

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from match_jax.envs import FPiHConfig, FPiHEnv  # noqa: E402  (before brax.envs: imports mujoco.mjx quietly)

from brax.envs.base import State, Wrapper  # noqa: E402
from brax.envs.wrappers import training as brax_wrappers  # noqa: E402

from match_jax.training.evaluation import episode_metrics, make_rollout  # noqa: E402
from match_jax.training.presets import get_preset  # noqa: E402


def _patch_zero_size_orthogonal() -> bool:
    """Make flax's `orthogonal` initializer accept zero-size shapes, where jax's raises.

    Our Actor always builds a selection-logit Dense layer, with 0 outputs for pose/VICES; jax 0.9.2's
    orthogonal initializer divides by that 0 (ZeroDivisionError in `Actor.init`), jax 0.10 returns an
    empty array. Applied only when the bug is present; a zero-size kernel has no values, so the
    result is identical to jax 0.10's.
    """
    import flax.linen.initializers as flax_init

    try:
        jax.nn.initializers.orthogonal()(jax.random.PRNGKey(0), (2, 0))
        return False
    except ZeroDivisionError:
        pass
    original = flax_init.orthogonal

    def orthogonal(*args, **kwargs):
        init = original(*args, **kwargs)

        def safe(key, shape, dtype=jnp.float32):
            if math.prod(shape) == 0:
                return jnp.zeros(shape, dtype)
            return init(key, shape, dtype)

        return safe

    flax_init.orthogonal = orthogonal
    return True


ZERO_SIZE_ORTHOGONAL_PATCHED = _patch_zero_size_orthogonal()


# --------------------------------------------------------------------------------- env adapters
class BraxAdapter(Wrapper):
    """Our (unbatched) env under Brax's training wrappers without info-key clashes.

    Our env's info lives under info['fpih']; `done` is 1 only for terminations (break, divergence),
    time limits are left to Brax's EpisodeWrapper. reward, obs, metrics and pipeline_state pass
    through unchanged.
    """

    def reset(self, rng: jax.Array) -> State:
        state = self.env.reset(rng)
        return state.replace(info={"fpih": state.info})

    def step(self, state: State, action: jax.Array) -> State:
        inner = self.env.step(state.replace(info=state.info["fpih"]), action)
        info = dict(state.info)
        info["fpih"] = inner.info
        terminated = jnp.where(inner.info["truncation"] > 0, 0.0, inner.done)
        return inner.replace(info=info, done=terminated)


class FreshAutoResetWrapper(Wrapper):
    """Batched auto-reset that draws a NEW episode for finished envs (like match_jax's AutoResetEnv).

    Sits where Brax's AutoResetWrapper would (on top of EpisodeWrapper(VmapWrapper(BraxAdapter))),
    with the same handling of Brax's keys: 'steps' is zeroed at the start of the next step for envs
    that were done, and done is cleared before stepping. For envs finished by this step,
    pipeline_state, obs and our info (info['fpih']) are replaced by those of `adapter.reset` with
    a key derived from the env's own rng; reward, done, metrics and Brax's info keys (truncation,
    episode_metrics, episode_done) still describe the transition just taken.
    """

    def __init__(self, env, adapter: BraxAdapter):
        super().__init__(env)
        self._adapter = adapter

    def step(self, state: State, action: jax.Array) -> State:
        info = dict(state.info)
        info["steps"] = jnp.where(state.done > 0, jnp.zeros_like(info["steps"]), info["steps"])
        state = state.replace(done=jnp.zeros_like(state.done), info=info)
        state = self.env.step(state, action)
        done = state.done > 0

        def reset_finished(s: State) -> State:
            keys = jax.vmap(lambda k: jax.random.split(k)[1])(s.info["fpih"]["rng"])
            fresh = jax.vmap(self._adapter.reset)(keys)

            def pick(new, old):
                return jnp.where(done.reshape(done.shape + (1,) * (old.ndim - 1)), new, old)

            new_info = dict(s.info)
            new_info["fpih"] = jax.tree_util.tree_map(pick, fresh.info["fpih"], s.info["fpih"])
            return s.replace(pipeline_state=jax.tree_util.tree_map(pick, fresh.pipeline_state, s.pipeline_state),
                             obs=jax.tree_util.tree_map(pick, fresh.obs, s.obs), info=new_info)

        return jax.lax.cond(jnp.any(done), reset_finished, lambda s: s, state)


def fresh_wrap(env: BraxAdapter, episode_length: int = 150, action_repeat: int = 1, randomization_fn=None):
    """`wrap_env_fn` for Brax's train: Brax's VmapWrapper + EpisodeWrapper, then FreshAutoResetWrapper."""
    if randomization_fn is not None:
        raise ValueError("domain randomisation is not used in this benchmark")
    wrapped = brax_wrappers.EpisodeWrapper(brax_wrappers.VmapWrapper(env), episode_length, action_repeat)
    return FreshAutoResetWrapper(wrapped, env)


# ----------------------------------------------------------------------------------- evaluation
def _contact_rate(traj) -> float:
    """Fraction of env-steps in contact, over the steps before each episode ended."""
    live = 1.0 - np.asarray(traj["done_before"])
    return float((np.asarray(traj["in_contact"]) * live).sum() / max(live.sum(), 1.0))


def make_evaluator(env: FPiHEnv, policies_from_params, keys: jax.Array):
    """params -> {'success_rate', 'break_rate', 'contact_rate', 'explore_contact_rate'} over len(keys)
    episodes of the raw env.

    `policies_from_params(params)` returns (deterministic, stochastic) match_jax.training.evaluation policies;
    success, break and contact rates are the deterministic policy's, `explore_contact_rate` the
    stochastic one's on the same episodes. params is a jit argument, so this compiles once per trainer.
    """

    @jax.jit
    def run(params):
        deterministic, stochastic = policies_from_params(params)
        return tuple(make_rollout(env, policy)(keys, jnp.zeros(keys.shape[0])) for policy in (deterministic, stochastic))

    def evaluate(params) -> dict:
        # Host copies: the trainers' arrays differ in sharding / weak types between calls, which
        # would recompile `run`; numpy arrays always give the same signature.
        params = jax.tree_util.tree_map(np.asarray, jax.device_get(params))
        traj, explore = jax.device_get(run(params))
        m = episode_metrics(traj, env.config.policy_dt)
        return {"success_rate": float(np.mean(m["success"])), "break_rate": float(np.mean(m["broken"])),
                "contact_rate": _contact_rate(traj), "explore_contact_rate": _contact_rate(explore)}

    return evaluate


class CompileClock:
    """Seconds JAX has spent tracing, lowering and compiling so far (all threads, this process)."""

    seconds = 0.0

    @classmethod
    def install(cls):
        def listener(event, duration, **kwargs):
            if event.startswith("/jax/core/compile/"):
                cls.seconds += duration

        jax.monitoring.register_event_duration_secs_listener(listener)


COMPILE_LIMIT_S = 1.0  # an interval with more compile time than this is not used for steps/s


def steady_rate(intervals: list[dict]) -> tuple[float | None, int]:
    """(env steps/s over the intervals without compilation, how many such intervals)."""
    clean = [i for i in intervals if i["compile_s"] <= COMPILE_LIMIT_S]
    seconds = sum(i["seconds"] for i in clean)
    if not clean or seconds <= 0:
        return None, 0
    return sum(i["env_steps"] for i in clean) / seconds, len(clean)


# -------------------------------------------------------------------------------------- trainers
def run_ours(ppo, env_config: FPiHConfig, seed: int, evaluator_keys, eval_env, log) -> dict:
    from match_jax.rl.ppo import deterministic_policy
    from match_jax.training.runs import Run, RunSpec, shard_envs

    start = time.perf_counter()
    run = Run(RunSpec(ppo=ppo, env=env_config, num_seeds=1, seed=seed, preset="cpu"),
              pathlib.Path(tempfile.gettempdir()) / "brax_comparison_ours_unused")
    trainer = run.trainer

    def policies_from_params(p):
        def stochastic(obs, pstate, key):
            head = trainer.policy_head(p[0], p[1], obs["state"])
            return trainer.distribution.to_action(trainer.distribution.sample(key, head)), pstate
        def deterministic(obs, pstate, key):
            return deterministic_policy(trainer)(obs, p, key)[0], pstate
        return deterministic, stochastic

    evaluate = make_evaluator(eval_env, policies_from_params, evaluator_keys)

    def seed0(state):
        return jax.tree_util.tree_map(lambda x: x[0], (state.params, state.policy_stats))

    state = shard_envs(run.initial_state())
    jax.block_until_ready(state)
    curve = [{"env_steps": 0, **evaluate(seed0(state))}]
    log(f"ours  step {0:>9,}: eval success {curve[-1]['success_rate']:.3f} break {curve[-1]['break_rate']:.3f} "
        f"explore contact {curve[-1]['explore_contact_rate']:.3f}")
    chunks = ppo.num_iterations // ppo.iterations_per_chunk
    intervals, train_success = [], []
    for _ in range(chunks):
        t0, c0 = time.perf_counter(), CompileClock.seconds
        state, metrics = run.chunk(state)
        jax.block_until_ready((state, metrics))
        seconds, compile_s = time.perf_counter() - t0, CompileClock.seconds - c0
        metrics = jax.device_get(metrics)
        env_steps = int(np.asarray(state.env_steps)[0])
        intervals.append({"env_steps": ppo.steps_per_iteration * ppo.iterations_per_chunk, "seconds": seconds,
                          "compile_s": compile_s, "at_env_steps": env_steps,
                          "train_contact": float(np.mean(metrics["contact_fraction"]))})
        for it in range(ppo.iterations_per_chunk):
            rate = float(metrics["success_rate"][it, 0])
            train_success.append({"env_steps": int(metrics["env_steps"][it, 0]),
                                  "success_rate": None if math.isnan(rate) else rate})
        curve.append({"env_steps": env_steps, **evaluate(seed0(state))})
        log(f"ours  step {env_steps:>9,}: eval success {curve[-1]['success_rate']:.3f} "
            f"break {curve[-1]['break_rate']:.3f} explore contact {curve[-1]['explore_contact_rate']:.3f} "
            f"({seconds:.1f} s for the interval, train contact {intervals[-1]['train_contact']:.3f})")
    rate, clean = steady_rate(intervals)
    return {
        "success_curve": curve,
        "train_success": train_success,
        "env_steps_per_s": rate,
        "clean_intervals": clean,
        "first_interval_s": intervals[0]["seconds"] if intervals else None,
        "intervals": intervals,
        "env_steps_total": int(np.asarray(state.env_steps)[0]),
        "wall_s_total": time.perf_counter() - start,
        "network": "SimBa actor %dx%d, critic %dx%d" % (ppo.network.actor_blocks, ppo.network.actor_hidden,
                                                         ppo.network.critic_blocks, ppo.network.critic_hidden),
    }


def run_brax(ppo, env_config: FPiHConfig, seed: int, evaluator_keys, eval_env, log, autoreset: str,
             policy_layers, value_layers) -> dict:
    from brax.training.agents.ppo import networks as ppo_networks
    from brax.training.agents.ppo import train as ppo_train

    start = time.perf_counter()
    adapter = BraxAdapter(FPiHEnv(env_config))
    episode_length = env_config.episode_steps
    if ppo.rollout_steps != episode_length:
        raise ValueError("the benchmark matches Brax's unroll to our rollout of one episode")
    network_factory = functools.partial(
        ppo_networks.make_ppo_networks, policy_hidden_layer_sizes=tuple(policy_layers),
        value_hidden_layer_sizes=tuple(value_layers), policy_obs_key="state", value_obs_key="privileged_state")
    curve, progress = [], []
    evaluator = {}
    compile_marks = []  # (compile seconds when an epoch ended, when our evaluation after it ended)

    def policy_params_fn(current_step, make_policy, params):
        # Brax calls this at step 0 and right after every training epoch, before progress_fn.
        epoch_end = CompileClock.seconds
        if "fn" not in evaluator:
            def policies_from_params(p):
                def policy(deterministic):
                    inference = make_policy(p, deterministic=deterministic)
                    return lambda obs, pstate, key: (inference(obs, key)[0], pstate)
                return policy(True), policy(False)
            evaluator["fn"] = make_evaluator(eval_env, policies_from_params, evaluator_keys)
        curve.append({"env_steps": int(current_step), **evaluator["fn"](params)})
        log(f"brax  step {int(current_step):>9,}: eval success {curve[-1]['success_rate']:.3f} "
            f"break {curve[-1]['break_rate']:.3f} explore contact {curve[-1]['explore_contact_rate']:.3f}")
        compile_marks.append((epoch_end, CompileClock.seconds))

    def progress_fn(current_step, metrics):
        progress.append({"env_steps": int(current_step), "walltime": float(metrics["training/walltime"]),
                         "sps": float(metrics["training/sps"])})

    num_chunks = ppo.num_iterations // ppo.iterations_per_chunk
    _, params, _ = ppo_train.train(
        environment=adapter,
        num_timesteps=ppo.num_iterations * ppo.steps_per_iteration,
        wrap_env=True,
        wrap_env_fn=fresh_wrap if autoreset == "fresh" else None,
        num_envs=ppo.num_envs,
        episode_length=episode_length,
        action_repeat=1,
        learning_rate=ppo.learning_rate,
        entropy_cost=ppo.entropy_coef,
        discounting=ppo.gamma,
        unroll_length=ppo.rollout_steps,
        batch_size=ppo.num_envs // ppo.minibatches,
        num_minibatches=ppo.minibatches,
        num_updates_per_batch=ppo.epochs,
        normalize_observations=True,
        reward_scaling=ppo.reward_scale,
        clipping_epsilon=ppo.clip_eps,
        gae_lambda=ppo.gae_lambda,
        max_grad_norm=ppo.max_grad_norm,
        normalize_advantage=ppo.normalize_advantages,
        vf_loss_coefficient=ppo.value_coef,
        network_factory=network_factory,
        seed=seed,
        num_evals=num_chunks + 1,
        run_evals=False,
        deterministic_eval=True,
        progress_fn=progress_fn,
        policy_params_fn=policy_params_fn,
    )
    intervals, previous = [], 0.0
    for i, p in enumerate(progress):
        # compile_marks[0] is the step-0 call; epoch i ran between marks i and i + 1.
        compile_s = compile_marks[i + 1][0] - compile_marks[i][1]
        intervals.append({"env_steps": p["env_steps"] - (progress[i - 1]["env_steps"] if i else 0),
                          "seconds": p["walltime"] - previous, "compile_s": compile_s,
                          "at_env_steps": p["env_steps"]})
        previous = p["walltime"]
    rate, clean = steady_rate(intervals)
    return {
        "success_curve": curve,
        "env_steps_per_s": rate,
        "clean_intervals": clean,
        "first_interval_s": intervals[0]["seconds"] if intervals else None,
        "intervals": intervals,
        "env_steps_total": progress[-1]["env_steps"] if progress else 0,
        "wall_s_total": time.perf_counter() - start,
        "network": f"MLP policy {list(policy_layers)}, value {list(value_layers)} (swish)",
        "autoreset": autoreset,
    }


# ------------------------------------------------------------------------------------------ main
def _layers(text: str) -> list[int]:
    try:
        layers = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated layer sizes, got {text!r}") from None
    if not layers or any(v < 1 for v in layers):
        raise argparse.ArgumentTypeError(f"expected positive layer sizes, got {text!r}")
    return layers


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--num-envs", type=int, default=128, help="parallel envs for both trainers (multiple of 8)")
    parser.add_argument("--total-steps", type=int, default=1_000_000,
                        help="env steps per trainer (rounded up to whole evaluation intervals)")
    parser.add_argument("--evals", type=int, default=10, help="evaluation points after step 0 (at least 3)")
    parser.add_argument("--eval-episodes", type=int, default=128, help="deterministic episodes per evaluation point")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--brax-autoreset", choices=("fresh", "first"), default="fresh",
                        help="fresh: new episode on every reset (like ours); first: Brax's stock AutoResetWrapper")
    parser.add_argument("--brax-policy-layers", type=_layers, default=[128, 128])
    parser.add_argument("--brax-value-layers", type=_layers, default=[256, 256, 256])
    parser.add_argument("--learning-rate", type=float, default=None,
                        help="both trainers' learning rate (default: the cpu preset's); e.g. 1e-12 keeps both "
                             "policies at their initialisation, for a speed comparison at equal contact load")
    parser.add_argument("--trainers", default="brax,ours", help="which to run, in this order (default brax,ours)")
    parser.add_argument("--json", type=pathlib.Path, default=None, help="write the results here")
    args = parser.parse_args(argv)

    trainers = [t.strip() for t in args.trainers.split(",") if t.strip()]
    if not trainers or any(t not in ("brax", "ours") for t in trainers):
        parser.error("--trainers takes brax and/or ours, comma separated")
    base = get_preset("cpu", method="pose")
    if args.num_envs < base.minibatches or args.num_envs % base.minibatches:
        parser.error(f"--num-envs must be a positive multiple of {base.minibatches} (the minibatch count)")
    if args.total_steps < 1 or args.eval_episodes < 1:
        parser.error("--total-steps and --eval-episodes must be >= 1")
    steps_per_iteration = args.num_envs * base.rollout_steps
    iterations = max(-(-args.total_steps // steps_per_iteration), 3)
    evals = min(max(args.evals, 3), iterations)
    per_eval = -(-iterations // evals)
    iterations = per_eval * -(-iterations // per_eval)
    if args.learning_rate is not None and not (args.learning_rate > 0 and math.isfinite(args.learning_rate)):
        parser.error(f"--learning-rate must be a finite number > 0, got {args.learning_rate}")
    ppo = get_preset("cpu", method="pose", num_envs=args.num_envs, total_steps=iterations * steps_per_iteration,
                     iterations_per_chunk=per_eval, learning_rate=args.learning_rate or base.learning_rate)
    env_config = FPiHConfig(control="pose")
    eval_env = FPiHEnv(env_config)
    eval_keys = jax.random.split(jax.random.PRNGKey(10_000 + args.seed), args.eval_episodes)

    def log(msg):
        print(msg, flush=True)

    config = {
        "task": "FPiHEnv(FPiHConfig(control='pose'))",
        "num_envs": args.num_envs, "episode_steps": env_config.episode_steps, "rollout_steps": ppo.rollout_steps,
        "iterations": iterations, "iterations_per_eval": per_eval, "env_steps_per_trainer": ppo.total_steps,
        "total_steps_requested": args.total_steps, "eval_episodes": args.eval_episodes, "seed": args.seed,
        "brax_autoreset": args.brax_autoreset, "epochs": ppo.epochs, "minibatches": ppo.minibatches,
        "learning_rate": ppo.learning_rate, "gamma": ppo.gamma, "gae_lambda": ppo.gae_lambda,
        "clip_eps": ppo.clip_eps, "reward_scale": ppo.reward_scale,
        "device": str(jax.devices()[0]), "host_devices": len(jax.devices()), "cpu_count": os.cpu_count(), "python": platform.python_version(),
        "versions": _versions(),
        "zero_size_orthogonal_patched": ZERO_SIZE_ORTHOGONAL_PATCHED,
        "steps_per_s_method": "training only: per evaluation interval, ours = host time of one jitted train_chunk "
                              "(blocked), brax = its training/walltime increments; intervals with > "
                              f"{COMPILE_LIMIT_S} s of JAX trace/lower/compile time are dropped",
    }
    log(f"{args.num_envs} envs x {ppo.rollout_steps} steps per iteration, {iterations} iterations "
        f"({ppo.total_steps:,} env steps) per trainer, evaluated every {per_eval} iterations on "
        f"{args.eval_episodes} episodes")
    results = {"config": config}
    CompileClock.install()
    for name in trainers:
        log(f"--- {name}")
        if name == "brax":
            results["brax"] = run_brax(ppo, env_config, args.seed, eval_keys, eval_env, log, args.brax_autoreset,
                                       args.brax_policy_layers, args.brax_value_layers)
        else:
            results["ours"] = run_ours(ppo, env_config, args.seed, eval_keys, eval_env, log)

    if "brax" in results and "ours" in results:
        ours_sps, brax_sps = results["ours"]["env_steps_per_s"], results["brax"]["env_steps_per_s"]
        results["ratio_ours_over_brax"] = {
            "env_steps_per_s": ours_sps / brax_sps if ours_sps and brax_sps else None,
            "final_success_rate": _ratio(results["ours"]["success_curve"][-1]["success_rate"],
                                         results["brax"]["success_curve"][-1]["success_rate"]),
        }
    log("")
    log(f"{'trainer':<8}{'env steps/s':>14}{'first interval s':>18}{'final success':>15}{'final break':>13}")
    for name in trainers:
        r = results[name]
        sps = f"{r['env_steps_per_s']:,.0f}" if r["env_steps_per_s"] else "-"
        log(f"{name:<8}{sps:>14}{r['first_interval_s']:>18.1f}{r['success_curve'][-1]['success_rate']:>15.3f}"
            f"{r['success_curve'][-1]['break_rate']:>13.3f}")
    if "ratio_ours_over_brax" in results:
        ratio = results["ratio_ours_over_brax"]["env_steps_per_s"]
        log(f"ours / brax env steps/s: {ratio:.2f}" if ratio else "ours / brax env steps/s: -")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2, allow_nan=True))
        log(f"wrote {args.json}")
    return results


def _ratio(a, b):
    return a / b if b else None


def _versions() -> dict:
    from importlib import metadata

    out = {}
    for pkg in ("jax", "jaxlib", "brax", "mujoco", "mujoco-mjx", "flax", "optax"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = None
    return out


if __name__ == "__main__":
    main()
