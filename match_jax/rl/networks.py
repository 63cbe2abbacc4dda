"""SimBa actor and critic networks (Flax linen) for the asymmetric actor-critic.

SimBa (Lee et al. 2024): inputs normalised by running mean/std (kept outside the network, see
`match_jax.rl.ppo`), Dense(H), N residual blocks x + Dense(H)(relu(Dense(4H)(LayerNorm(x)))), a final
LayerNorm, then a linear head. The actor reads the policy observation ('state'); the critic reads
the privileged observation ('privileged_state', plus the episode-time fraction).
"""

from __future__ import annotations

import dataclasses

import flax.linen as nn
import jax
import jax.numpy as jnp

from match_jax.rl.distributions import INITIAL_P_POSITION, PolicyHead, selection_bias


@dataclasses.dataclass(frozen=True)
class NetworkConfig:
    """Sizes of the SimBa trunks (paper: actor 2 x 256, critic 3 x 1024) and the actor's initial std."""

    actor_hidden: int = 256  # actor SimBa width
    actor_blocks: int = 2  # actor SimBa residual blocks
    critic_hidden: int = 1024  # critic SimBa width
    critic_blocks: int = 3  # critic SimBa residual blocks
    initial_log_std: float = -0.7  # pre-tanh std ~0.5 at the start
    # Hybrid: the force-z target the untrained policy's mean commands (N, robot on environment). A
    # gentle -1 N instead of the mid-range -10 N: early random force selections then do not dive.
    initial_force_z: float | None = -1.0
    # Hybrid: the untrained policy's probability of position control per axis (paper: ~0.93).
    initial_p_position: float = INITIAL_P_POSITION
    min_log_std: float = -5.0  # lower bound of the actor's pre-tanh log std
    max_log_std: float = 1.0  # upper bound of the actor's pre-tanh log std
    # orthogonal-init gain of the actor's last layers (means, selection logits); the authors' He-normal
    # init scaled by 0.1 has the same weight scale as a gain of 0.1 x sqrt(2)
    head_scale: float = 0.01
    # the untrained critic's output (its last layer's bias), in the critic's output units
    critic_init_value: float = 0.0

    def __post_init__(self):
        for name in ("actor_hidden", "actor_blocks", "critic_hidden", "critic_blocks"):
            value = getattr(self, name)
            least = 1 if "hidden" in name else 0
            if not (isinstance(value, int) and value >= least):
                raise ValueError(f"NetworkConfig.{name} must be an integer >= {least}, got {value!r}")
        if not 0.0 < self.initial_p_position < 1.0:
            raise ValueError(f"NetworkConfig.initial_p_position must be in (0, 1), got {self.initial_p_position!r}")
        if not 0.0 < self.head_scale < float("inf"):
            raise ValueError(f"NetworkConfig.head_scale must be a finite number > 0, got {self.head_scale!r}")
        if not abs(self.critic_init_value) < float("inf"):
            raise ValueError(f"NetworkConfig.critic_init_value must be finite, got {self.critic_init_value!r}")
        if not self.min_log_std < self.max_log_std:
            raise ValueError(
                f"NetworkConfig needs min_log_std < max_log_std, got {self.min_log_std}, {self.max_log_std}")
        if not self.min_log_std < self.initial_log_std < self.max_log_std:
            raise ValueError(f"NetworkConfig.initial_log_std must be in ({self.min_log_std:g}, {self.max_log_std:g}) "
                             f"(min_log_std, max_log_std), got {self.initial_log_std!r}")


class SimBaTrunk(nn.Module):
    """Dense(H) -> blocks x [x + Dense(H)(relu(Dense(4H)(LayerNorm(x))))] -> LayerNorm."""

    hidden: int
    blocks: int

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        x = nn.Dense(self.hidden, kernel_init=nn.initializers.orthogonal(1.0))(x)
        for _ in range(self.blocks):
            y = nn.LayerNorm()(x)
            y = nn.relu(nn.Dense(4 * self.hidden, kernel_init=nn.initializers.he_normal())(y))
            x = x + nn.Dense(self.hidden, kernel_init=nn.initializers.he_normal())(y)
        return nn.LayerNorm()(x)


class Actor(nn.Module):
    """Policy head: means and selection logits from the observation; a state-independent log std.

    The selection bias starts at log(0.07 / 0.93), so p(position) ~ 0.93 on every axis at first.
    """

    num_continuous: int
    num_selections: int
    config: NetworkConfig
    mean_bias: tuple[float, ...] = ()  # initial pre-tanh means (default 0)

    @nn.compact
    def __call__(self, obs: jax.Array) -> PolicyHead:
        cfg = self.config
        x = SimBaTrunk(cfg.actor_hidden, cfg.actor_blocks)(obs)
        bias = jnp.asarray(self.mean_bias if self.mean_bias else (0.0,) * self.num_continuous, jnp.float32)
        mean = nn.Dense(self.num_continuous, kernel_init=nn.initializers.orthogonal(cfg.head_scale),
                        bias_init=lambda *_: bias)(x)
        log_std = self.param("log_std", nn.initializers.constant(cfg.initial_log_std), (self.num_continuous,))
        log_std = jnp.clip(log_std, cfg.min_log_std, cfg.max_log_std)
        if self.num_selections:
            logits = nn.Dense(self.num_selections, kernel_init=nn.initializers.orthogonal(cfg.head_scale),
                              bias_init=nn.initializers.constant(selection_bias(cfg.initial_p_position)))(x)
        else:  # pose / VICES: no selection head (a zero-width Dense breaks some jax versions' initialisers)
            logits = jnp.zeros(x.shape[:-1] + (0,), x.dtype)
        return PolicyHead(logits=logits, mean=mean, log_std=jnp.broadcast_to(log_std, mean.shape))


class Critic(nn.Module):
    """State value from the privileged observation."""

    config: NetworkConfig

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        x = SimBaTrunk(self.config.critic_hidden, self.config.critic_blocks)(obs)
        return nn.Dense(1, kernel_init=nn.initializers.orthogonal(1.0),
                        bias_init=nn.initializers.constant(self.config.critic_init_value))(x)[..., 0]
