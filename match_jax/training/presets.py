"""Training presets. A preset sets sizes, step budget and learning hyperparameters only: it never
changes the task or the physics (geometry, contact, physics rate, break threshold, noise), so a cpu
run and a paper run solve the same task.

- `paper`: 256 envs per seed, 150-step rollouts (one episode), 3M env steps per seed, SimBa actor
  2 x 256 and critic 3 x 1024 (paper). For GPUs. Initial pre-tanh std 0.135 (log -2) as in `cpu`: with
  0.5 the policy learned to hover above the block, at this preset (5 of 5 seeds on an H100, no contact
  by 1.38M steps) and at the cpu preset alike (docs/training.md).
- `cpu`: sized for a 2-core CPU (measured: docs/benchmarks.md): 128 envs per seed, smaller SimBa networks
  (actor 1 x 128, critic 2 x 128), 2.5M env steps budget, and the learning settings that trained fastest at
  this size (docs/training.md): Adam 1e-3, gamma 0.99. The untrained hybrid policy's force-z target is
  -2 N, where tanh still responds (slope 0.36; the earlier 0 N sat at the top of the range, slope 0.002, and
  a force-selected z axis could never learn to press) and the untrained policy breaks 5 % of episodes
  (-5 N: 42 %; docs/training.md).
- `authors`: the learning recipe of the authors' public code, for GPUs: 256 envs per seed, 3M env steps,
  SimBa actor 2 x 512 and critic 4 x 1024 (their code; the paper's text says 2 x 256 and 3 x 1024), Adam
  1e-5 for actor and critic with betas (0.999, 0.999) and eps 1e-8, 4 epochs x 150 minibatches, 2 critic
  steps per minibatch, the actor stopped for the rest of an update once a minibatch's KL exceeds 0.05,
  Huber value loss (adaptive delta) on running-normalised returns, value coefficient 1, gamma 0.995,
  initial pre-tanh std 1.0 and mean 0 on every component (force-z target -10 N, the middle of its range),
  the actor's last layers at a tenth of He scale, the critic's output starting at 12.5, p(position) 0.924
  (selection bias 2.5). docs/protocol.md lists each setting beside the paper's and ours.
- `tiny`: a few envs and short rollouts, for smoke tests; it learns nothing.
"""

from __future__ import annotations

import dataclasses
import math

from match_jax.rl.networks import NetworkConfig
from match_jax.rl.ppo import PPOConfig

PRESETS: dict[str, PPOConfig] = {
    "paper": PPOConfig(num_envs=256, rollout_steps=150, total_steps=3_000_000, iterations_per_chunk=2,
                       minibatches=8, network=NetworkConfig(256, 2, 1024, 3, initial_log_std=-2.0)),
    "cpu": PPOConfig(num_envs=128, rollout_steps=150, total_steps=2_500_000, iterations_per_chunk=4,
                     minibatches=8, learning_rate=1e-3, gamma=0.99,
                     network=NetworkConfig(128, 1, 128, 2, initial_log_std=-2.0, initial_force_z=-2.0)),
    "authors": PPOConfig(num_envs=256, rollout_steps=150, total_steps=3_000_000, iterations_per_chunk=2,
                         epochs=4, minibatches=150, learning_rate=1e-5, adam_b1=0.999, adam_b2=0.999,
                         adam_eps=1e-8, gamma=0.995, value_coef=1.0, critic_steps=2, kl_threshold=0.05,
                         value_loss="huber", normalize_returns=True,
                         network=NetworkConfig(512, 2, 1024, 4, initial_log_std=0.0, initial_force_z=None,
                                               initial_p_position=1.0 / (1.0 + math.exp(-2.5)),
                                               head_scale=0.1 * math.sqrt(2.0), critic_init_value=12.5)),
    "tiny": PPOConfig(num_envs=4, rollout_steps=8, total_steps=64, iterations_per_chunk=1, epochs=2,
                      minibatches=2, network=NetworkConfig(16, 1, 16, 1)),
}


def get_preset(name: str, **overrides) -> PPOConfig:
    """The preset `name` with some fields replaced (e.g. method='pose', total_steps=10**6)."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose one of {sorted(PRESETS)}")
    return dataclasses.replace(PRESETS[name], **overrides)
