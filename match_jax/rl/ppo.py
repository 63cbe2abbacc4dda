"""Pure-JAX PPO for the fPiH env: rollout, GAE and the update epochs in one XLA program.

In the style of PureJaxRL: `make_trainer(config, env)` returns pure functions over a `TrainState`
pytree. One *iteration* (`iteration`) = `rollout` (a `lax.scan` of `rollout_steps` env steps across
`num_envs` envs), `advantages` (GAE), then `update` (`epochs` x `minibatches` steps on
`losses.ppo_loss`); each is a module-level function of a `Learner` (the configuration's networks,
distribution, optimizer and env step). `Trainer.train_chunk` runs
`iterations_per_chunk` iterations inside one jitted call and returns their metrics. Several seeds
train in the same program: every TrainState leaf has a leading seed axis; the networks and updates
are vmapped over it and the envs of all seeds step as one batch (split over the local devices under
`shard_map` when `make_trainer` gets a mesh).

Asymmetric actor-critic: the actor reads the running-normalised policy observation; the critic the
running-normalised privileged observation plus the episode-time fraction (the time limit is part of
the state the critic needs). Time-outs bootstrap with the critic's value of the episode's last
observation; breaks (and NaN resets) are terminal.

MATCH's supervised selection loss: beta * sum over axes of BCE(p_force, psi), psi the env's per-axis
contact label of the state that produced the action.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from brax.training.acme import running_statistics
from brax.training.acme import specs

from match_jax.rl.distributions import METHODS, METHOD_CONTROL, ProductDistribution, Sample, make_distribution
from match_jax.rl.losses import critic_loss, ppo_loss, selection_loss, selection_rates
from match_jax.envs import sim
from match_jax.envs import AutoResetEnv, FPiHConfig, FPiHEnv, contract
from match_jax.rl.networks import Actor, Critic, NetworkConfig


# Default SSL weights, on the axis-mean BCE (`selection_loss`): MATCH with the selection term in the PPO
# ratio 0.3, every other method 1.0 (the authors' weight).
MATCH_IN_RATIO_SSL_BETA = 0.3
SSL_BETA = 1.0


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """Method, sizes and learning hyperparameters. Steps are env (policy) steps per seed."""

    method: str = "match"  # 'pose' | 'vices' | 'hybrid' (Hybrid-Basic) | 'match'
    # beta of the supervised selection loss (weight of the axis-mean BCE); 0 = the no-SSL ablations;
    # None = the method's default (`ssl_beta`): 0.3 for MATCH with the selection term in the ratio, else 1
    ssl_coef: float | None = None
    selection_in_ratio: bool = True  # MATCH: Bernoulli term in the PPO ratio (paper) or not (authors' code)
    # 'joint': the SSL is added to every PPO minibatch loss; 'after': SSL-only minibatch steps follow the
    # PPO epochs, so the PPO ratio sees only PPO's own change of p(selection) (experimental)
    ssl_phase: str = "joint"
    # which samples the SSL averages over: 'all' (the paper) or 'contact' (only steps with at least one
    # axis in contact: the SSL then only pulls p_force up in contact and leaves free space to PPO; experimental)
    ssl_samples: str = "all"
    num_envs: int = 256  # parallel envs per seed
    rollout_steps: int = 150  # env steps per env per PPO iteration
    total_steps: int = 3_000_000  # env steps per seed, the run's budget
    iterations_per_chunk: int = 4  # iterations per jitted call (between logging / checkpoints)
    epochs: int = 4  # passes over the rollout per iteration
    minibatches: int = 8  # per epoch
    learning_rate: float = 3e-4  # Adam step size (of both networks unless set apart below)
    # None: a constant step size; else Adam's step size decays linearly from learning_rate to this value
    # over the run's budget (num_iterations x optimizer_steps_per_iteration updates)
    learning_rate_end: float | None = None
    # None: no adaptation; else the KL-adaptive step size (rsl_rl's 'adaptive' schedule): before each minibatch
    # step, the step size is divided by KL_LR_FACTOR when that minibatch's approximate KL to the rollout policy
    # is above 2 x desired_kl, multiplied by it when below desired_kl / 2, and kept in [KL_LR_MIN, KL_LR_MAX];
    # it starts at learning_rate, is per seed, shared by actor and critic, and lives in the optimizer state
    desired_kl: float | None = None
    adam_b1: float = 0.9  # Adam beta1
    adam_b2: float = 0.999  # Adam beta2
    adam_eps: float = 1e-5  # Adam epsilon
    # Adam step sizes of the actor and the critic (None: learning_rate); the same schedule scales both
    actor_learning_rate: float | None = None
    critic_learning_rate: float | None = None
    max_grad_norm: float = 0.5  # per network (actor and critic are clipped separately)
    gamma: float = 0.995  # discount per policy step
    gae_lambda: float = 0.95  # GAE lambda
    clip_eps: float = 0.2  # PPO ratio clip
    value_coef: float = 0.5  # weight of the value loss
    entropy_coef: float = 0.0  # weight of the entropy bonus
    reward_scale: float = 0.25  # rewards are multiplied by this before GAE
    normalize_advantages: bool = True  # per minibatch, to mean 0 and std 1
    # critic Adam steps per minibatch: the joint actor-critic step, then critic_steps - 1 value-loss-only
    # steps on the same minibatch (the authors' value_update_ratio)
    critic_steps: int = 1
    # None: off; else per seed, once a minibatch's approximate KL to the rollout policy (before its step)
    # exceeds this, the actor takes no further step in this update; the critic goes on
    kl_threshold: float | None = None
    # 'mse': 0.5 (V - R)^2; 'huber': Huber loss with delta = 1.35 x the median absolute deviation of the
    # critic's change since the rollout (the authors' adaptive delta)
    value_loss: str = "mse"
    # the critic predicts returns normalised by their running mean and std (per seed); GAE reads its values
    # back in return units
    normalize_returns: bool = False
    network: NetworkConfig = NetworkConfig()  # the actor and critic networks

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"unknown method {self.method!r}; choose one of {list(METHODS)}")
        if self.ssl_phase not in ("joint", "after"):
            raise ValueError(f"ssl_phase must be 'joint' or 'after', got {self.ssl_phase!r}")
        if self.ssl_samples not in ("all", "contact"):
            raise ValueError(f"ssl_samples must be 'all' or 'contact', got {self.ssl_samples!r}")
        if self.value_loss not in ("mse", "huber"):
            raise ValueError(f"value_loss must be 'mse' or 'huber', got {self.value_loss!r}")
        for name in ("num_envs", "rollout_steps", "total_steps", "iterations_per_chunk", "epochs", "minibatches",
                     "critic_steps"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 1):
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if (self.num_envs * self.rollout_steps) % self.minibatches:
            raise ValueError(f"num_envs * rollout_steps ({self.num_envs * self.rollout_steps}) must divide into "
                             f"minibatches ({self.minibatches})")
        for name in ("learning_rate", "max_grad_norm", "clip_eps", "reward_scale"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)!r}")
        for name in ("gamma", "gae_lambda"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)!r}")
        if self.learning_rate_end is not None and not 0 <= self.learning_rate_end < float("inf"):
            raise ValueError(f"learning_rate_end must be a finite number >= 0 or None, got {self.learning_rate_end!r}")
        if self.desired_kl is not None:
            if not 0 < self.desired_kl < float("inf"):
                raise ValueError(f"desired_kl must be a finite number > 0 or None, got {self.desired_kl!r}")
            if self.learning_rate_end is not None:
                raise ValueError(f"desired_kl ({self.desired_kl!r}) and learning_rate_end ({self.learning_rate_end!r}) "
                                 "are two step-size schedules; choose one")
        for name in ("actor_learning_rate", "critic_learning_rate"):
            if getattr(self, name) is not None and not 0 < getattr(self, name) < float("inf"):
                raise ValueError(f"{name} must be a finite number > 0 or None, got {getattr(self, name)!r}")
        if self.desired_kl is not None and self.actor_lr != self.critic_lr:
            raise ValueError(f"desired_kl ({self.desired_kl!r}) sets one step size for both networks; it cannot "
                             f"start from two (actor {self.actor_lr!r}, critic {self.critic_lr!r})")
        if self.kl_threshold is not None and not 0 < self.kl_threshold < float("inf"):
            raise ValueError(f"kl_threshold must be a finite number > 0 or None, got {self.kl_threshold!r}")
        for name in ("ssl_coef", "value_coef", "entropy_coef"):
            if getattr(self, name) is not None and not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")

    @property
    def actor_lr(self) -> float:
        """The actor's base Adam step size."""
        return self.learning_rate if self.actor_learning_rate is None else self.actor_learning_rate

    @property
    def critic_lr(self) -> float:
        """The critic's base Adam step size."""
        return self.learning_rate if self.critic_learning_rate is None else self.critic_learning_rate

    @property
    def control(self) -> str:
        return METHOD_CONTROL[self.method]

    @property
    def steps_per_iteration(self) -> int:
        return self.num_envs * self.rollout_steps

    @property
    def num_iterations(self) -> int:
        return -(-self.total_steps // self.steps_per_iteration)

    @property
    def optimizer_steps_per_iteration(self) -> int:
        """Adam updates per network per PPO iteration: epochs x minibatches, plus one SSL epoch when
        ssl_phase is 'after'."""
        ssl_steps = self.minibatches if self.ssl_phase == "after" and self.uses_ssl else 0
        return self.epochs * self.minibatches + ssl_steps

    @property
    def uses_ssl(self) -> bool:
        return self.method in ("hybrid", "match") and self.ssl_beta > 0

    @property
    def ssl_beta(self) -> float:
        """The SSL weight in use: ssl_coef, or where that is None 0.3 for MATCH with the selection term in
        the PPO ratio and 1 otherwise (docs/training.md gives the evidence)."""
        if self.ssl_coef is not None:
            return float(self.ssl_coef)
        return MATCH_IN_RATIO_SSL_BETA if self.method == "match" and self.selection_in_ratio else SSL_BETA


class Transition(NamedTuple):
    """One env step of the rollout, (T, B, ...) after the scan. Observations are normalised."""

    policy_obs: jax.Array
    critic_obs: jax.Array
    final_critic_obs: jax.Array  # the finished episode's last observation where done
    sample: Sample
    log_prob: jax.Array
    reward: jax.Array
    done: jax.Array
    truncation: jax.Array
    contact_label: jax.Array  # per-axis contact of the state that produced the action (0/1)


class TrainState(NamedTuple):
    """Everything training carries, as a pytree with a leading seed axis on every leaf."""

    params: dict
    opt_state: Any
    policy_stats: running_statistics.RunningStatisticsState
    critic_stats: running_statistics.RunningStatisticsState
    env_state: Any
    episode_success: jax.Array  # (num_envs,) success seen so far in the running episode
    key: jax.Array
    iteration: jax.Array
    env_steps: jax.Array
    # running statistics of the returns (PPOConfig.normalize_returns; None otherwise, so a run without them
    # has the checkpoint layout it always had)
    return_stats: Any = None


class Trainer(NamedTuple):
    """The pure functions of one configuration (see module docstring)."""

    config: PPOConfig
    env: FPiHEnv
    init: Any  # keys (num_seeds, 2)[, RuntimeValues] -> TrainState with a leading seed axis
    train_chunk: Any  # TrainState[, RuntimeValues] -> (TrainState, metrics (iterations_per_chunk, num_seeds))
    policy_head: Any  # (params, policy_stats, obs['state']) -> PolicyHead
    distribution: Any


def generalized_advantages(reward, value, final_value, last_value, done, truncation, gamma: float,
                           gae_lambda: float) -> tuple[jax.Array, jax.Array]:
    """GAE over a (T, B) rollout that may cross episode boundaries; returns (advantages, returns).

    value[t]: V(s_t); last_value: V(s_T) after the last step. Where done[t], the episode ended at step
    t: on a time-out (truncation[t] = 1) it bootstraps from final_value[t], the value of that
    episode's last observation; on a termination (a break) from 0. The advantage recursion never
    crosses an episode boundary.
    """
    next_value = jnp.concatenate([value[1:], last_value[None]], axis=0)
    bootstrap = jnp.where(done > 0, final_value, next_value)
    terminal = done * (1.0 - truncation)
    deltas = reward + gamma * bootstrap * (1.0 - terminal) - value

    def backward(gae, x):
        delta, d = x
        gae = delta + gamma * gae_lambda * (1.0 - d) * gae
        return gae, gae

    _, adv = jax.lax.scan(backward, jnp.zeros_like(last_value), (deltas, done), reverse=True)
    return adv, adv + value


def initial_mean_bias(config: PPOConfig, env) -> tuple[float, ...]:
    """Initial pre-tanh means: 0, except the force-z component of hybrid policies, set so the untrained
    mean commands `network.initial_force_z` N (see NetworkConfig)."""
    space = make_distribution(config.method).space
    bias = [0.0] * len(space.continuous)
    force_z = config.network.initial_force_z
    actions = getattr(getattr(env, "config", None), "actions", None)
    if space.force and force_z is not None and actions is not None:
        a = float(np.clip(actions.force_z_action(force_z), -0.999, 0.999))
        bias[space.continuous.index(space.force[2])] = float(np.arctanh(a))
    return tuple(bias)


def initial_stats(size: int) -> running_statistics.RunningStatisticsState:
    """Brax's observation normaliser for `size` features, its std_eps a float32 array instead of a
    weakly typed Python float: the initial TrainState then has the types a chunk returns, so the jitted
    chunk compiles once for a run, not once for the initial state and again for every later one."""
    stats = running_statistics.init_state(specs.Array((size,), jnp.float32))
    return stats.replace(std_eps=jnp.asarray(stats.std_eps, jnp.float32))


class RuntimeValues(NamedTuple):
    """Settings the trainer takes as arguments, not as constants of its program: configurations that
    differ only in these share one compiled program (`runs.programs`)."""

    ssl_beta: Any  # weight of the selection loss ('joint' phase)
    break_force: Any  # N; inf = unbreakable
    hole_obs_noise: Any  # m, the hole-position observation noise (sd or half-width)

    @classmethod
    def of(cls, config: PPOConfig, env_config: Any) -> "RuntimeValues":
        """The values of a configuration, as float32 arrays (env_config None: FPiHConfig's defaults;
        an env config without a break force or hole noise, such as PointMassEnv's: inf and 0)."""
        env_config = FPiHConfig() if env_config is None else env_config
        values = (config.ssl_beta, getattr(env_config, "break_force", math.inf),
                  getattr(env_config, "hole_obs_noise", 0.0))
        return cls(*(jnp.asarray(v, jnp.float32) for v in values))


class Learner(NamedTuple):
    """The fixed parts of one configuration that a PPO iteration uses (`make_trainer` builds it)."""

    config: PPOConfig
    actor: Actor
    critic: Critic
    dist: ProductDistribution
    optimizer: optax.GradientTransformation
    env: Any  # the AutoResetEnv-wrapped env (reset of a batch of keys)
    env_step: Any  # (env state, action) with (seeds, envs, ...) leaves -> next env state (`seed_batch_step`)
    env_name: str  # in contract errors
    ssl_beta: Any  # the selection loss's weight (a traced scalar when given as a RuntimeValues)


def learning_rate_schedule(config: PPOConfig, network: str = "actor") -> float | optax.Schedule:
    """Adam's step size for `network` ('actor' | 'critic'): its constant base step size, or a linear decay
    from it to base x learning_rate_end / learning_rate over the run's budget of optimizer updates (held
    there after it)."""
    base = config.actor_lr if network == "actor" else config.critic_lr
    if config.learning_rate_end is None:
        return base
    return optax.linear_schedule(base, base * config.learning_rate_end / config.learning_rate,
                                 config.num_iterations * config.optimizer_steps_per_iteration)


# The KL-adaptive step size (`PPOConfig.desired_kl`): factor per minibatch step and bounds (rsl_rl's values).
KL_LR_FACTOR = 1.5
KL_LR_MIN = 1e-5
KL_LR_MAX = 1e-2


def kl_adapted_learning_rate(learning_rate: jax.Array, approx_kl: jax.Array, desired_kl: float) -> jax.Array:
    """The next KL-adaptive step size: / KL_LR_FACTOR above 2 x desired_kl, x KL_LR_FACTOR below half of it,
    unchanged between, clipped to [KL_LR_MIN, KL_LR_MAX]."""
    scaled = jnp.where(approx_kl > 2.0 * desired_kl, learning_rate / KL_LR_FACTOR,
                       jnp.where(approx_kl < 0.5 * desired_kl, learning_rate * KL_LR_FACTOR, learning_rate))
    return jnp.clip(scaled, KL_LR_MIN, KL_LR_MAX)


def optimizer_learning_rate(opt_state) -> jax.Array:
    """The step size held in the optimizer state of a KL-adaptive config (actor and critic share it)."""
    return optax.tree_utils.tree_get_all_with_path(opt_state, "learning_rate")[0][1]


def make_optimizer(config: PPOConfig) -> optax.GradientTransformation:
    """Adam with global-norm clipping, one per network (actor and critic clipped separately). With desired_kl
    the step size is a hyperparameter in the optimizer state (`optax.inject_hyperparams`), set per minibatch."""
    def one(network):
        adam = optax.inject_hyperparams(optax.adam) if config.desired_kl is not None else optax.adam
        return optax.chain(optax.clip_by_global_norm(config.max_grad_norm),
                           adam(learning_rate_schedule(config, network), b1=config.adam_b1, b2=config.adam_b2,
                                eps=config.adam_eps))
    return optax.multi_transform({"actor": one("actor"), "critic": one("critic")},
                                 {"actor": "actor", "critic": "critic"})


def apply_gradients(optimizer: optax.GradientTransformation, params: dict, opt_state, grads: dict,
                    actor_on: Any = True, critic_on: Any = True) -> tuple[dict, Any]:
    """One Adam step of `make_optimizer`'s optimizer, applied to the networks whose flag (a bool or a
    traced boolean) is on: a network that is off keeps its parameters and its Adam state unchanged."""
    updates, new_state = optimizer.update(grads, opt_state, params)
    new_params = optax.apply_updates(params, updates)
    if actor_on is True and critic_on is True:
        return new_params, new_state

    def keep(on, new, old):
        return jax.tree_util.tree_map(lambda n, o: jnp.where(on, n, o), new, old)

    flags = {"actor": actor_on, "critic": critic_on}
    params = {k: keep(flags[k], new_params[k], params[k]) for k in params}
    inner = {k: keep(flags[k], new_state.inner_states[k], opt_state.inner_states[k]) for k in flags}
    return params, new_state._replace(inner_states=inner)


def normalize(x: jax.Array, stats: running_statistics.RunningStatisticsState) -> jax.Array:
    """Running-normalised observation, clipped to +-10."""
    return running_statistics.normalize(x, stats, max_abs_value=10.0)


def critic_observation(privileged: jax.Array, steps: jax.Array, episode_steps: int) -> jax.Array:
    """The critic's raw input: the privileged observation and the fraction of the episode elapsed."""
    return jnp.concatenate([privileged, (steps / float(episode_steps))[..., None]], axis=-1)


def _merge_seeds(d, lead: tuple[int, int]):
    """Physics data with (seeds, envs, ...) world leaves as one batch of seeds x envs worlds. MuJoCo Warp's
    once-per-batch leaves (contact buffer, counters: `sim.world_axis_leaves`) hold one copy per seed, each
    sized for the whole merged batch (FPiHConfig.warp_worlds); the step gets the first."""
    return jax.tree_util.tree_map(lambda x, world: x.reshape((lead[0] * lead[1],) + x.shape[2:]) if world else x[0],
                                  d, sim.world_axis_leaves(d))


def _split_seeds(d, like):
    """`_merge_seeds` undone: leaves shaped as in `like` (the (seeds, envs, ...) data before the step)."""
    return jax.tree_util.tree_map(lambda x, old, world: x.reshape(old.shape) if world else
                                  jnp.broadcast_to(x, old.shape), d, like, sim.world_axis_leaves(like))


def seed_batch_step(benv: AutoResetEnv, num_envs: int, mesh: jax.sharding.Mesh | None = None):
    """`benv.step` on (seeds, envs, ...) state and action leaves, stepped as one flat batch: a vmap over
    seeds would turn the auto-reset's lax.cond into a select that runs the reset on every step.

    mesh: the 1-D device mesh ('envs') the env batch is split over (`runs.batch_mesh`). The step
    then runs under `shard_map`: every device steps its own block of envs (of every seed) with no
    cross-device work (its own auto-reset `lax.cond`, its own MJX solver loops), as Brax's pmap does;
    measured on 2 CPU devices that stepped a contact-heavy batch 1.2x faster than leaving the
    partitioning to XLA. mesh=None: a plain step.
    """
    def step_seeds(state, action):
        lead = action.shape[:2]
        flat_state = jax.tree_util.tree_map(lambda x: x.reshape((lead[0] * lead[1],) + x.shape[2:]),
                                            state.replace(pipeline_state=None))
        flat_state = flat_state.replace(pipeline_state=_merge_seeds(state.pipeline_state, lead))
        next_state = benv.step(flat_state, action.reshape((lead[0] * lead[1],) + action.shape[2:]))
        split = jax.tree_util.tree_map(lambda x: x.reshape(lead + x.shape[1:]), next_state.replace(pipeline_state=None))
        return split.replace(pipeline_state=_split_seeds(next_state.pipeline_state, state.pipeline_state))

    if mesh is None:
        return step_seeds
    if mesh.axis_names != ("envs",) or (num_envs % mesh.size):
        raise ValueError(f"mesh must be 1-D over 'envs' with num_envs ({num_envs}) a multiple of its "
                         f"size, got axes {mesh.axis_names} of size {mesh.size}")
    by_env = jax.sharding.PartitionSpec(None, "envs")
    return jax.shard_map(step_seeds, mesh=mesh, in_specs=(by_env, by_env), out_specs=by_env, check_vma=False)


def init_seed(learner: Learner, key: jax.Array) -> TrainState:
    """The TrainState of one seed (no seed axis)."""
    config, env = learner.config, learner.env
    k_actor, k_critic, k_env, key = jax.random.split(key, 4)
    sizes = env.observation_size
    policy_size, critic_size = sizes["state"][0], sizes["privileged_state"][0] + 1
    params = {"actor": learner.actor.init(k_actor, jnp.zeros((1, policy_size))),
              "critic": learner.critic.init(k_critic, jnp.zeros((1, critic_size)))}
    env_state = env.reset(jax.random.split(k_env, config.num_envs))
    contract.check_state(env_state, f"{learner.env_name}.reset")  # at trace time: free
    return TrainState(
        params=params,
        opt_state=learner.optimizer.init(params),
        policy_stats=initial_stats(policy_size),
        critic_stats=initial_stats(critic_size),
        env_state=env_state,
        episode_success=jnp.zeros(config.num_envs),
        key=key,
        iteration=jnp.zeros((), jnp.int32),
        env_steps=jnp.zeros((), jnp.int32),
        return_stats=initial_stats(1) if config.normalize_returns else None,
    )


class Rollout(NamedTuple):
    """What `rollout` returns for every seed (leading seed axis)."""

    env_state: Any  # after the last step
    episode_success: jax.Array  # (S, envs) of the running episodes
    policy_stats: running_statistics.RunningStatisticsState  # updated with the rollout's observations
    critic_stats: running_statistics.RunningStatisticsState
    counts: dict  # per seed: episodes, successes, breaks, reward and contact steps summed over the rollout
    traj: Transition  # (S, T, envs, ...), observations normalised with the statistics before the update
    last_critic_obs: jax.Array  # (S, envs, critic size), normalised: the state after the last step


def rollout(learner: Learner, ts: TrainState, keys: jax.Array) -> Rollout:
    """`rollout_steps` env steps of every seed's envs (keys: (S, 2), one per seed).

    Env state, observations and transitions keep a (seeds, envs, ...) layout; the networks are vmapped
    over the seed axis and the env steps every seed's envs as one batch (`learner.env_step`). The scan
    body has no reduction over envs (episode counters are kept per env, the observation statistics are
    updated from the whole rollout after the scan): with the envs split over devices, a reduction there
    would be a cross-device all-reduce at every step, making each device wait for the other's slowest env.
    """
    config, dist = learner.config, learner.dist
    episode_steps = learner.env.config.episode_steps
    v_normalize = jax.vmap(normalize)
    v_actor = jax.vmap(learner.actor.apply)

    @jax.named_scope("rollout_step")
    def step(carry, step_keys):
        env_state, ep_success, counts = carry
        raw_policy = env_state.obs["state"]
        raw_critic = critic_observation(env_state.obs["privileged_state"], env_state.info["steps"], episode_steps)
        policy_obs = v_normalize(raw_policy, ts.policy_stats)
        head = v_actor(ts.params["actor"], policy_obs)
        sample = jax.vmap(dist.sample)(step_keys, head)
        log_prob = dist.log_prob(sample, head)
        next_state = learner.env_step(env_state, dist.to_action(sample))
        contract.check_state(next_state, f"{learner.env_name}.step")  # at trace time: free
        final_raw = critic_observation(next_state.info["final_obs"]["privileged_state"],
                                       env_state.info["steps"] + 1, episode_steps)
        done, broken = next_state.done, next_state.info["broken"]
        ep_success = jnp.maximum(ep_success, next_state.info["success"] * (1.0 - broken))
        counts = {
            "episodes": counts["episodes"] + done,
            "successes": counts["successes"] + done * ep_success,
            "breaks": counts["breaks"] + done * broken,
            "reward": counts["reward"] + next_state.reward,
            "contact_steps": counts["contact_steps"] + next_state.info["in_contact"],
        }
        ep_success = jnp.where(done > 0, 0.0, ep_success)
        transition = Transition(
            policy_obs=policy_obs,
            critic_obs=v_normalize(raw_critic, ts.critic_stats),
            final_critic_obs=v_normalize(final_raw, ts.critic_stats),
            sample=sample,
            log_prob=log_prob,
            reward=next_state.reward * config.reward_scale,
            done=done,
            truncation=next_state.info["truncation"],
            contact_label=env_state.info["contact_axes"],
        )
        return (next_state, ep_success, counts), (transition, raw_policy, raw_critic)

    counts0 = {k: jnp.zeros_like(ts.episode_success)
               for k in ("episodes", "successes", "breaks", "reward", "contact_steps")}
    carry0 = (ts.env_state, ts.episode_success, counts0)
    step_keys = jax.vmap(lambda k: jax.random.split(k, config.rollout_steps), out_axes=1)(keys)
    (env_state, ep_success, counts), (traj, raw_policy, raw_critic) = jax.lax.scan(step, carry0, step_keys)

    def to_seed_major(x):  # (T, S, ...) -> (S, T, ...)
        return jnp.swapaxes(x, 0, 1)

    last_critic = critic_observation(env_state.obs["privileged_state"], env_state.info["steps"], episode_steps)
    return Rollout(
        env_state=env_state,
        episode_success=ep_success,
        policy_stats=jax.vmap(running_statistics.update)(ts.policy_stats, to_seed_major(raw_policy)),
        critic_stats=jax.vmap(running_statistics.update)(ts.critic_stats, to_seed_major(raw_critic)),
        counts={k: v.sum(-1) for k, v in counts.items()},
        traj=jax.tree_util.tree_map(to_seed_major, traj),
        last_critic_obs=v_normalize(last_critic, ts.critic_stats),
    )


def to_return_units(value: jax.Array, return_stats) -> jax.Array:
    """A critic output in return units (return_stats None: the critic predicts returns directly)."""
    return value if return_stats is None else value * return_stats.std[0] + return_stats.mean[0]


def to_critic_units(returns: jax.Array, return_stats) -> jax.Array:
    """Returns in the critic's output units: normalised by the running statistics, or as they are."""
    return returns if return_stats is None else (returns - return_stats.mean[0]) / return_stats.std[0]


class Targets(NamedTuple):
    """What the update fits, each (T, envs), of one seed's rollout."""

    advantages: jax.Array
    returns: jax.Array  # in the critic's units
    old_values: jax.Array  # the rollout's values, in the critic's units
    return_stats: Any  # updated with this rollout's returns (None without return normalisation)


def advantages(learner: Learner, params: dict, traj: Transition, last_critic_obs: jax.Array,
               return_stats=None) -> Targets:
    """GAE of one seed's rollout under its critic, and the critic's targets. With return normalisation the
    critic's values are read in return units for GAE, the statistics are updated with the rollout's returns,
    and returns and values are normalised with the updated statistics."""
    config, critic = learner.config, learner.critic

    def value(obs):
        return to_return_units(critic.apply(params["critic"], obs), return_stats)

    values = value(traj.critic_obs)
    adv, returns = generalized_advantages(traj.reward, values, value(traj.final_critic_obs), value(last_critic_obs),
                                          traj.done, traj.truncation, config.gamma, config.gae_lambda)
    if return_stats is not None:
        return_stats = running_statistics.update(return_stats, returns.reshape(-1, 1))
    return Targets(adv, to_critic_units(returns, return_stats), to_critic_units(values, return_stats), return_stats)


def update(learner: Learner, params: dict, opt_state, traj: Transition, targets: Targets, key: jax.Array):
    """`epochs` x `minibatches` steps on `ppo_loss` over one seed's rollout, each followed by
    critic_steps - 1 value-only steps and, with kl_threshold, none for the actor once a minibatch's KL
    exceeded it (then, with ssl_phase 'after', an epoch of SSL-only steps). Returns (params, opt_state,
    metrics: the loss metrics' means, the fraction of minibatches the actor stepped on ('actor_steps') and
    the p_force rates of `losses.selection_rates`, NaN for policies without selection)."""
    config, optimizer = learner.config, learner.optimizer
    n = config.steps_per_iteration
    flat = jax.tree_util.tree_map(lambda x: x.reshape((n,) + x.shape[2:]),
                                  (traj, targets.advantages, targets.returns, targets.old_values))
    loss_fn = functools.partial(ppo_loss, actor=learner.actor, critic=learner.critic, dist=learner.dist,
                                config=config, ssl_beta=learner.ssl_beta)

    def shuffled_minibatches(perm_key, tree):
        """`tree` (leading axis n) shuffled and split into (minibatches, n / minibatches, ...)."""
        perm = jax.random.permutation(perm_key, n)
        return jax.tree_util.tree_map(
            lambda x: x[perm].reshape((config.minibatches, n // config.minibatches) + x.shape[1:]), tree)

    def apply_grads(params, opt_state, grads, actor_on=True):
        return apply_gradients(optimizer, params, opt_state, grads, actor_on=actor_on)

    def value_step_loss(params, batch, adv, returns, old_values):  # the value half of loss_fn
        return config.value_coef * critic_loss(params, batch, returns, old_values, critic=learner.critic, config=config)

    def minibatch(carry, mb):
        params, opt_state, actor_on = carry
        grads, aux = jax.grad(loss_fn, has_aux=True)(params, *mb)
        if config.kl_threshold is not None:  # the KL at the pre-step params; once above, the actor stops
            actor_on = actor_on & (aux[0]["approx_kl"] <= config.kl_threshold)
        if config.desired_kl is not None:  # this step's size from its KL (the loss's, at the pre-step params)
            step_size = kl_adapted_learning_rate(optimizer_learning_rate(opt_state), aux[0]["approx_kl"],
                                                 config.desired_kl)
            opt_state = optax.tree_utils.tree_set(opt_state, learning_rate=step_size)
            aux = ({**aux[0], "learning_rate": step_size}, aux[1])
        params, opt_state = apply_grads(params, opt_state, grads,
                                        actor_on if config.kl_threshold is not None else True)
        for _ in range(config.critic_steps - 1):
            params, opt_state = apply_grads(params, opt_state, jax.grad(value_step_loss)(params, *mb),
                                            actor_on=False)
        aux = ({**aux[0], "actor_steps": actor_on.astype(jnp.float32)}, aux[1])
        return (params, opt_state, actor_on), aux

    def epoch(carry, epoch_key):
        return jax.lax.scan(minibatch, carry, shuffled_minibatches(epoch_key, flat))

    (params, opt_state, _), (metrics, counts) = jax.lax.scan(epoch, (params, opt_state, jnp.asarray(True)),
                                                             jax.random.split(key, config.epochs))
    if config.uses_ssl and config.ssl_phase == "after":
        def ssl_step(carry, mb):  # SSL-only steps, after PPO has finished with this rollout
            (params, opt_state), (obs, labels) = carry, mb
            grads = jax.grad(lambda p: learner.ssl_beta * selection_loss(
                learner.actor.apply(p["actor"], obs).logits, labels, config.ssl_samples == "contact"))(params)
            return apply_grads(params, opt_state, grads), None

        batches = shuffled_minibatches(jax.random.fold_in(key, config.epochs),
                                       (flat[0].policy_obs, flat[0].contact_label))
        (params, opt_state), _ = jax.lax.scan(ssl_step, (params, opt_state), batches)
    metrics = jax.tree_util.tree_map(jnp.mean, metrics)
    if counts is not None:
        metrics.update(selection_rates(jax.tree_util.tree_map(jnp.sum, counts), learner.dist.num_selections))
    else:
        metrics["p_force"] = jnp.zeros(())
        for name in ("p_force_contact", "p_force_free", "p_force_contact_axis", "p_force_free_axis"):
            metrics[name] = jnp.full((), jnp.nan)
    return params, opt_state, metrics


def iteration(learner: Learner, ts: TrainState) -> tuple[TrainState, dict]:
    """One PPO iteration for every seed (the leading axis of each TrainState leaf): rollout, GAE, update."""
    config = learner.config
    keys = jax.vmap(lambda k: jax.random.split(k, 3))(ts.key)
    out = rollout(learner, ts, keys[:, 1])
    targets = jax.vmap(functools.partial(advantages, learner))(ts.params, out.traj, out.last_critic_obs,
                                                               ts.return_stats)
    params, opt_state, metrics = jax.vmap(functools.partial(update, learner))(
        ts.params, ts.opt_state, out.traj, targets, keys[:, 2])
    counts, episodes = out.counts, out.counts["episodes"]
    metrics.update(
        episodes=episodes,
        success_rate=jnp.where(episodes > 0, counts["successes"] / jnp.maximum(episodes, 1.0), jnp.nan),
        break_rate=jnp.where(episodes > 0, counts["breaks"] / jnp.maximum(episodes, 1.0), jnp.nan),
        mean_reward=counts["reward"] / config.steps_per_iteration,
        contact_fraction=counts["contact_steps"] / config.steps_per_iteration,
        action_std=jnp.exp(params["actor"]["params"]["log_std"]).mean(-1),
    )
    if config.desired_kl is None:  # this iteration's first Adam step size (KL-adaptive: the mean of its PPO steps')
        step_size = learning_rate_schedule(config, "actor")
        metrics["learning_rate"] = (step_size(ts.iteration * config.optimizer_steps_per_iteration)
                                    if callable(step_size) else jnp.full(ts.iteration.shape, step_size))
    env_steps = ts.env_steps + config.steps_per_iteration
    metrics.update(iteration=ts.iteration + 1, env_steps=env_steps)
    ts = TrainState(params, opt_state, out.policy_stats, out.critic_stats, out.env_state, out.episode_success,
                    keys[:, 0], ts.iteration + 1, env_steps, targets.return_stats)
    return ts, metrics


def make_trainer(config: PPOConfig, env: FPiHEnv, mesh: jax.sharding.Mesh | None = None) -> Trainer:
    """The pure, jit-able init and train_chunk of one configuration (mesh: see `seed_batch_step`).

    Both take an optional `RuntimeValues` (None: the configuration's own, as constants): the SSL weight,
    and for an env with `with_values` (FPiHEnv) its break force and hole-observation noise.
    """
    contract.check_interface(env)
    dist = make_distribution(config.method, config.selection_in_ratio)
    actor = Actor(dist.num_continuous, dist.num_selections, config.network, initial_mean_bias(config, env))
    critic, optimizer = Critic(config.network), make_optimizer(config)

    def learner(values: RuntimeValues | None) -> Learner:
        ssl_beta = config.ssl_beta
        task_env = env
        if values is not None:
            ssl_beta = values.ssl_beta
            if hasattr(env, "with_values"):
                task_env = env.with_values(values.break_force, values.hole_obs_noise)
        benv = AutoResetEnv(task_env)
        return Learner(config=config, actor=actor, critic=critic, dist=dist, optimizer=optimizer, env=benv,
                       env_step=seed_batch_step(benv, config.num_envs, mesh), env_name=type(env).__name__,
                       ssl_beta=ssl_beta)

    def init(keys: jax.Array, values: RuntimeValues | None = None) -> TrainState:
        """The TrainState of len(keys) seeds (leading seed axis on every leaf).

        A loop over seeds, not a vmap: a vmapped orthogonal initialiser is a batched LAPACK QR, whose
        parallel batch map deadlocked XLA's CPU thread pool (jaxlib 0.10.2; docs/troubleshooting.md)."""
        return jax.lax.map(functools.partial(init_seed, learner(values)), keys)

    def train_chunk(ts: TrainState, values: RuntimeValues | None = None):
        """`iterations_per_chunk` iterations; metrics are (iterations_per_chunk, num_seeds) arrays."""
        learn = learner(values)
        return jax.lax.scan(lambda t, _: iteration(learn, t), ts, None, length=config.iterations_per_chunk)

    def policy_head(params, policy_stats, policy_obs):
        return actor.apply(params["actor"], normalize(policy_obs, policy_stats))

    return Trainer(config=config, env=env, init=init, train_chunk=train_chunk, policy_head=policy_head,
                   distribution=dist)


def deterministic_action(trainer: Trainer, params: dict, policy_stats, policy_obs: jax.Array,
                         squash: bool = True) -> jax.Array:
    """The env action of the deterministic policy: tanh of the mean (squash=False: the pre-tanh mean),
    force control where p_force > 0.5."""
    dist = trainer.distribution
    return dist.to_action(dist.mode(trainer.policy_head(params, policy_stats, policy_obs)), squash)


def deterministic_policy(trainer: Trainer, squash: bool = True) -> Any:
    """`policy(obs, (params, policy_stats), key) -> (action, same state)` for match_jax.training.evaluation: the
    deterministic action (`deterministic_action`), with the parameters as the policy state, so one
    compiled rollout serves every seed."""

    def policy(obs, policy_state, key):
        return deterministic_action(trainer, *policy_state, obs["state"], squash), policy_state

    return policy
